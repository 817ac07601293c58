"""experiments/mnist_timing_floor.py on made-up paths whose timing is known."""

from __future__ import annotations

import numpy as np

from img2dmp.data.store import DigitData


def _paths(profiles, t_count=50):
    """Straight 20 px strokes (in random directions) timed by the given arc-fraction laws."""
    rng = np.random.default_rng(0)
    u = np.linspace(0, 1, t_count)
    out = []
    for law in profiles:
        angle = rng.uniform(0, 2 * np.pi)
        out.append(20 * law(u)[:, None] * np.array([np.cos(angle), np.sin(angle)]) + 14)
    return np.stack(out).astype(np.float32), np.tile(u, (len(profiles), 1)).astype(np.float32)


def _data(profiles, split):
    y, t = _paths(profiles)
    n = len(profiles)
    return DigitData(
        images=np.zeros((n, 28, 28), np.float32),
        trajectories=y,
        times=t,
        labels=np.zeros(n, np.int64),
        params=np.zeros((n, 55), np.float32),
        fit_error_px=np.zeros(n, np.float32),
        split=np.asarray(split, np.uint8),
    )


def test_one_shared_speed_profile_leaves_no_timing_error(experiment_script):
    mod = experiment_script("mnist_timing_floor")
    smooth = lambda u: 3 * u**2 - 2 * u**3  # noqa: E731
    floor = mod.timing_floor(_data([smooth] * 6, [0, 0, 0, 0, 2, 2]), ks=(2,))
    for name in ("mean profile", "per-digit mean", "2 nearest shapes"):
        assert floor[name].max() < 1e-3, name
    assert floor["constant speed"].mean() > 0.5  # the wrong law costs pixels


def test_writers_with_different_speeds_leave_an_error_no_profile_removes(experiment_script):
    mod = experiment_script("mnist_timing_floor")
    fast_start, slow_start = (lambda u: np.sqrt(u)), (lambda u: u**2)
    data = _data([fast_start, slow_start] * 3 + [fast_start], [0] * 6 + [2])
    floor = mod.timing_floor(data, ks=(2,))
    # the mean of the two laws is wrong for the test path by a known amount
    u = np.linspace(0, 1, 50)
    expected = np.abs(20 * (np.sqrt(u) - (np.sqrt(u) + u**2) / 2)).mean()
    assert abs(floor["mean profile"][0] - expected) < 0.05 * expected
