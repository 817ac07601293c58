"""experiments/noise_effect.py: paired noisy/clean samples and the error it reports."""

from __future__ import annotations

import numpy as np
import pytest

from img2dmp.data.synthetic import SyntheticConfig


class _Shifted:
    """Stands in for a Predictor: the true path, moved by (0.3, 0.4) px on an image that
    holds salt (a pixel at exactly 1, which the clean images never have)."""

    def __init__(self, trajectories):
        self.trajectories = trajectories

    def trajectories_for_images(self, images, times):
        salted = (np.asarray(images) >= 1.0).any(axis=(1, 2))
        return self.trajectories + salted[:, None, None] * np.float32([0.3, 0.4])


def test_paired_samples_share_paths_and_differ_by_the_noise(experiment_script):
    mod = experiment_script("noise_effect")
    labels = np.array([2, 2, 3, 7])
    noisy, clean = mod.paired_samples(labels, SyntheticConfig(), seed=5)
    np.testing.assert_array_equal(noisy.trajectories, clean.trajectories)
    assert (noisy.images == 1.0).any() and not (clean.images == 1.0).any()
    r = mod.noise_effect(_Shifted(noisy.trajectories), labels, SyntheticConfig(), seed=5)
    assert r["noisy"]["mean"] == pytest.approx(0.5, abs=1e-5)
    assert r["clean"]["mean"] == pytest.approx(0.0, abs=1e-6)
    assert r["filtered_image_rms"] < r["image_rms"] / 3
