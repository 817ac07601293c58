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


def _stroke(*corners, n: int = 30):
    import numpy as np

    c = np.asarray(corners, dtype=np.float64)
    return np.concatenate([np.linspace(c[i], c[i + 1], n) for i in range(len(c) - 1)])


def _handwritten_page():
    """A page of five characters drawn in two lines on light paper: "1 7 0" above "L 7",
    the last touching the right border. ``(image uint8 [200, 360], boxes)``: each
    character's ink box ``(x0, y0, x1, y1)`` (half-open, ink > 1/2) in reading order."""
    import numpy as np

    from img2dmp.data.render import render_paths

    h, w = 200, 360
    t = np.linspace(0.0, 2.0 * np.pi, 80)
    chars = [
        _stroke((60, 30), (60, 80)),  # 1
        _stroke((128, 30), (154, 30), (138, 80)),  # 7
        np.stack([230 + 14 * np.cos(t), 55 + 25 * np.sin(t)], 1),  # 0
        _stroke((70, 120), (70, 170), (94, 170)),  # L
        _stroke((w - 26, 120), (w, 120), (w - 16, 170)),  # 7 cut by the border
    ]
    n = max(len(c) for c in chars)
    paths = np.stack([np.concatenate([c, np.repeat(c[-1:], n - len(c), 0)]) for c in chars])
    ink = render_paths(paths, (h, w), 5.0).numpy()  # [5, H, W]
    boxes = []
    for k in range(len(chars)):
        rows, cols = np.nonzero(ink[k] > 0.5)
        boxes.append((int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1))
    return np.clip(235.0 - 200.0 * ink.max(0), 0, 255).astype(np.uint8), boxes


@pytest.fixture(scope="session")
def handwritten_page():
    """``(image, boxes)`` of :func:`_handwritten_page`: a generated photo of a page."""
    return _handwritten_page()


@pytest.fixture(scope="session")
def omni_root(tmp_path_factory) -> Path:
    """A small Omniglot tree (``test_omniglot.write_tree``): two alphabets of two
    characters drawn by 20 drawers each, in two or three strokes."""
    from test_omniglot import write_tree

    return write_tree(tmp_path_factory.mktemp("omni") / "omniglot", characters=2, drawers=20)


@pytest.fixture(scope="session")
def small_omniglot(omni_root, tmp_path_factory) -> Path:
    """:func:`omni_root` imported as a data set with its strokes (``img2dmp import``)."""
    from img2dmp import cli

    out = tmp_path_factory.mktemp("data") / "omni.safetensors"
    code = cli.main(
        ["import", str(omni_root), "--out", str(out), "--no-progress", "--n-times", "120"]
    )
    assert code == 0
    return out


@pytest.fixture(scope="session")
def stroke_run(small_omniglot, tmp_path_factory) -> Path:
    """The run directory of a tiny stroke model (``--config omniglot``, 8 slots) trained
    60 epochs on :func:`small_omniglot` (about 15 s), for the tests of stroke models,
    serving them and the browser; it recommends no reading settings (``reading``
    emptied: its predictions are the network's, its count read from 8 views), which
    tests/test_reading.py takes up."""
    from img2dmp import cli

    run = tmp_path_factory.mktemp("strokes") / "run"
    args = ["train", "--config", "omniglot", "--data", str(small_omniglot), "--run-dir",
            str(run), "--epochs", "60", "--no-progress", "--set", "optim.batch_size=16",
            "--set", "cost.ink_weight=0", "--set", "cost.coverage_weight=0",
            "--set", "reading.refine=0", "--set", "reading.refine_unfamiliar=null",
            "--set", "reading.count_views=null"]  # fmt: skip
    assert cli.main(args) == 0
    return run
