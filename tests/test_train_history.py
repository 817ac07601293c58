"""A training's numbers do not depend on what the process did besides training: the
training curve is redrawn at times that follow the machine's speed (``PLOT_EVERY_S``),
so drawing it (and importing matplotlib) must change no bit of the run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from img2dmp.checkpoint import read_checkpoint_meta
from img2dmp.data.store import save_dataset
from img2dmp.data.synthetic import generate_dataset
from img2dmp.train import TrainConfig, read_metrics_csv, train
from img2dmp.training import loop


@pytest.fixture(scope="module")
def small_data(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("data") / "small.safetensors"
    save_dataset(path, generate_dataset(12, seed=3, progress=False))
    return path


def _config(data_path) -> TrainConfig:
    return TrainConfig.from_dict(
        {
            "model": {"encoder_layers": [48, 20], "decoder_layers": [35]},
            "data": {"path": str(data_path)},
            "optim": {"epochs": 3, "batch_size": 16, "lr": 2e-3, "patience": 0},
            "threads": 1,
            "progress": False,
        }
    )


def test_when_the_curve_is_drawn_changes_no_bit_of_the_run(small_data, tmp_path, monkeypatch):
    """The curve drawn after every epoch: the same weights and the same metrics as the run
    drawn as the clock decides (after the first and the last epoch on a fast machine)."""
    ref = tmp_path / "ref"
    train(_config(small_data), ref)
    monkeypatch.setattr(loop, "PLOT_EVERY_S", 0.0)
    drawn = []
    plot = loop._plot
    monkeypatch.setattr(loop, "_plot", lambda run: drawn.append(1) or plot(run))
    run = tmp_path / "run"
    train(_config(small_data), run)
    assert len(drawn) == 3
    for name in ("best", "last"):
        ours, theirs = (
            read_checkpoint_meta(d / "checkpoints" / f"{name}.safetensors") for d in (ref, run)
        )
        assert ours["weights_sha256"] == theirs["weights_sha256"], name
    for a, b in zip(read_metrics_csv(ref / "metrics.csv"), read_metrics_csv(run / "metrics.csv"),
                    strict=True):  # fmt: skip
        assert {k: v for k, v in a.items() if k != "epoch_time_s"} == {
            k: v for k, v in b.items() if k != "epoch_time_s"
        }


_FP_STATE = """
import numpy as np
def state():
    # Flush-to-zero turns a subnormal result into 0; denormals-are-zero reads a subnormal
    # input as 0 (the SSE control register, which a library built with -ffast-math sets
    # when it is loaded).
    tiny = np.array([1e-30], np.float32) * np.float32(1e-9)
    read = np.array([1e-39], np.float32) * np.float32(1.0)
    return bool(tiny[0] != 0), bool(read[0] != 0)
before = state()
from pathlib import Path
from img2dmp.training.records import plot_training_curve
row = dict(epoch=0, step=1, lr=1e-3, train_cost=1.0, train_error_px=2.0, val_error_px=2.5,
           best_val_error_px=2.5, epoch_time_s=0.1)
plot_training_curve(Path(__import__("sys").argv[1]), [row, dict(row, epoch=1)], "t", "trajectory")
print(before, state())
"""


def test_drawing_the_curve_keeps_subnormal_arithmetic(tmp_path):
    """In a fresh process (matplotlib not yet imported): subnormal numbers are computed and
    read as such before and after the first training curve is drawn."""
    out = subprocess.run(
        [sys.executable, "-c", _FP_STATE, str(tmp_path / "curve.png")],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert (tmp_path / "curve.png").is_file()
    assert " ".join(out) == "(True, True) (True, True)"
