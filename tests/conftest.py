"""Shared test helpers."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "experiments"


@pytest.fixture
def experiment_script(monkeypatch):
    """``load(name)``: the module ``experiments/<name>.py``, imported from its file.

    The experiments directory goes on ``sys.path`` first, as it does when Python runs the
    script, so that its helpers (``_provenance``) import.
    """
    monkeypatch.syspath_prepend(str(EXPERIMENTS))

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, EXPERIMENTS / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod  # dataclasses look their module up there
        spec.loader.exec_module(mod)
        return mod

    return load


def _train_tiny_runs(work: Path, run_dir) -> dict[int, Path]:
    """Networks with one and with two hypotheses, one epoch each on 40 synthetic digits
    (a few seconds): ``{k: run_dir(k)}``."""
    from img2dmp.data.store import save_dataset
    from img2dmp.data.synthetic import generate_dataset
    from img2dmp.training import TrainConfig, train

    save_dataset(work / "d.safetensors", generate_dataset(4, seed=5, progress=False))
    out = {}
    for k in (1, 2):
        cfg = TrainConfig.from_dict(
            {
                "model": {"encoder_layers": [48, 20], "decoder_layers": [35], "hypotheses": k},
                "data": {"path": str(work / "d.safetensors")},
                "optim": {"epochs": 1, "batch_size": 16},
                "threads": 1,
                "progress": False,
            }
        )
        out[k] = Path(run_dir(k))
        train(cfg, out[k])
    return out


@pytest.fixture(scope="session")
def train_tiny_runs():
    """``train_tiny_runs(work, run_dir)``: run directories ``run_dir(k)`` of tiny networks
    with k = 1 and k = 2 hypotheses (for tests of prediction, serving and the browser)."""
    return _train_tiny_runs
