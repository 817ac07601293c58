"""benchmarks/mnist_experiments.py --quick on the real data (skipped when it is absent)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data"
RECORDED = DATA / "ijs-mnist-trajectories" / "trajectories.tar.gz"


def _script():
    spec = importlib.util.spec_from_file_location(
        "mnist_experiments", ROOT / "benchmarks" / "mnist_experiments.py"
    )
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.skipif(
    not RECORDED.exists(), reason=f"real data not found at {RECORDED} (see docs/MNIST.md)"
)
def test_quick_experiment_evaluates_the_test_split_and_resumes(tmp_path, capsys):
    from img2dmp.data.store import load_dataset

    mod = _script()
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
