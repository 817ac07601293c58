"""experiments/mnist_experiments.py --quick on the real data (skipped when it is absent)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data"
RECORDED = DATA / "ijs-mnist-trajectories" / "trajectories.tar.gz"


@pytest.mark.skipif(
    not RECORDED.exists(), reason=f"real data not found at {RECORDED} (see docs/MNIST.md)"
)
def test_quick_experiment_evaluates_the_test_split_and_resumes(tmp_path, capsys, experiment_script):
    from img2dmp.data.store import load_dataset

    mod = experiment_script("mnist_experiments")
    args = ["--quick", "--only", "35-cost10-tn", "--out", str(tmp_path), "--data", str(DATA)]
    args += ["--epochs", "1", "--set", "model.encoder_layers=[64,20]"]
    assert mod.main(args) == 0
    row = json.loads((tmp_path / "35-cost10-tn" / "result.json").read_text())
    base = load_dataset(tmp_path / "data" / "mnist35.safetensors")
    tn = load_dataset(tmp_path / "data" / "mnist35-tn.safetensors")
    # Scored on exactly the test part of the fixed split, never on validation.
    assert row["test"]["n"] == int((base.split == 2).sum()) > 0
    evaluation = json.loads(
        (tmp_path / "35-cost10-tn" / "evaluation" / "evaluation.json").read_text()
    )
    assert evaluation["split"] == "test"
    # Time normalisation: same points, images and split; every path lasts 1 s; DMPs refitted.
    np.testing.assert_array_equal(tn.trajectories, base.trajectories)
    np.testing.assert_array_equal(tn.split, base.split)
    np.testing.assert_allclose(tn.times[:, -1] - tn.times[:, 0], mod.TN_DURATION_S, rtol=1e-6)
    assert tn.fit_error_px.mean() < 0.1
    assert "| 35-cost10-tn (quick) |" in (tmp_path / "results.md").read_text()
    # Resumable: a finished experiment is not run again.
    capsys.readouterr()
    assert mod.main(args) == 0
    assert "done before" in capsys.readouterr().out


def test_init_from_starts_at_the_pretrained_network(tmp_path):
    """Fine-tuning (``init_from``, used by the pre-training experiments) starts from the
    checkpoint's predictions: with a vanishing learning rate the first epoch's validation
    error is the pre-trained one; another architecture is refused."""
    from img2dmp.checkpoint import CheckpointError
    from img2dmp.train import TrainConfig, train

    def config(**top):
        return TrainConfig.from_dict(
            {
                "model": {"image_size": [40, 40], "encoder_layers": [16, 8]},
                "data": {"samples_per_epoch": 64, "val_samples": 32},
                "optim": {"epochs": 1, "batch_size": 32, "lr": 1e-3},
                "threads": 1,
                "progress": False,
                **top,
            }
        )

    pre = train(config(), tmp_path / "pre")
    tuned_cfg = config(init_from=str(tmp_path / "pre"))  # same seed: same validation set
    tuned_cfg.optim.lr = 1e-12
    tuned = train(tuned_cfg, tmp_path / "tuned")
    assert tuned.history[0]["val_error_px"] == pytest.approx(pre.best_val_error_px, rel=1e-5)
    other = config(init_from=str(tmp_path / "pre"))
    other.model.encoder_layers = [16, 9]
    # the error names the setting in which the two runs differ
    with pytest.raises(
        CheckpointError, match=r"another architecture.*differs in model\.encoder_layers \[16, 8\]"
    ):
        train(other, tmp_path / "other")
    # the network's outputs mean weights; a run that wants amplitudes cannot start there
    amplitudes = config(init_from=str(tmp_path / "pre"))
    amplitudes.cost.parameter_units = "amplitudes"
    with pytest.raises(ValueError, match="parameter_units is 'amplitudes'"):
        train(amplitudes, tmp_path / "amplitudes")
