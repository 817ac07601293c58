"""ONNX export (img2dmp export) and docs/EXPORT.md's NumPy rollout of a DMP file.

The exported graph is run by onnxruntime and compared with torch's own prediction
(Predictor.predict_hypotheses: network, output normalisation, ranking) on images the
export's check did not use; docs/EXPORT.md's lines are taken from it and run as they
are, against img2dmp.dmp.rollout.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from img2dmp import cli
from img2dmp.data.store import load_dataset, save_dataset
from img2dmp.data.synthetic import generate, generate_dataset
from img2dmp.dmp import DMPConfig, DMPParams, rollout
from img2dmp.nn.model import ImpulseFilter
from img2dmp.predict import Predictor
from img2dmp.train import TrainConfig, train

onnx = pytest.importorskip("onnx", reason="the export extra is not installed")
ort = pytest.importorskip("onnxruntime", reason="the export extra is not installed")
pytest.importorskip("onnxscript", reason="the export extra is not installed")

from img2dmp.export import (  # noqa: E402 (after the extra's check)
    OPSET,
    DenseImpulseFilter,
    ExportCheckFailed,
    export_onnx,
    normalised_difference,
    vector_layout,
)

ROOT = Path(__file__).resolve().parents[1]
#: Largest difference onnxruntime vs torch the export must keep (float32 network).
EXPORT_TOLERANCE = 1e-5
#: docs/EXPORT.md's Runge-Kutta lines vs the exact rollout, in pixels: RK4 at 1000 steps per
#: movement is ~1e-6 px off, the rollout's cubic Hermite table ~2e-6 px.
NUMPY_TOLERANCE_PX = 1e-4

MODELS = {
    # The paper's kind: fully connected, one DMP, weights as outputs.
    "fc": ({"encoder_layers": [48, 20], "decoder_layers": [35]}, {}),
    # Everything the graph has to carry: the impulse filter, batch normalisation,
    # three hypotheses with scores, forcing amplitudes turned back into weights.
    "conv-k3": (
        {
            "encoder": "conv",
            "conv_channels": [8, 16],
            "conv_norm": "batch",
            "encoder_layers": [32],
            "input_filter": "impulse",
            "hypotheses": 3,
        },
        {"parameter_units": "amplitudes"},
    ),
}


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("export")
    data = root / "d.safetensors"
    save_dataset(data, generate_dataset(12, seed=5, progress=False))
    runs = {}
    for name, (model, cost) in MODELS.items():
        cfg = TrainConfig.from_dict(
            {
                "model": model,
                "cost": cost,
                "data": {"path": str(data)},
                "optim": {"epochs": 2, "batch_size": 16},
                "threads": 1,
                "progress": False,
            }
        )
        train(cfg, root / name)
        runs[name] = root / name
    return runs, data


def _fresh_images(size, n: int = 24) -> np.ndarray:
    """Digits the export's own check did not see (another seed), plus extremes."""
    rng = np.random.default_rng(123)
    from img2dmp.data.synthetic import SyntheticConfig

    images = generate(np.arange(n) % 10, SyntheticConfig(image_size=size), rng).images
    ones = np.ones((1, *size), np.float32)
    return np.concatenate([images, ones, 0 * ones]).astype(np.float32)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_onnxruntime_gives_torch_s_dmps(trained, tmp_path, name):
    runs, _ = trained
    out = tmp_path / f"{name}.onnx"
    report = export_onnx(runs[name], out)
    assert report.opset == OPSET and report.max_difference <= EXPORT_TOLERANCE
    pred = Predictor.load(runs[name])
    images = _fresh_images(pred.image_size)
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    dmp, prob = session.run(None, {"images": images})
    params, probs = pred.predict_hypotheses(images)  # torch, ranked, float64
    ref = params.to_vector()
    k, p = pred.n_hypotheses, pred.dmp_config.n_params
    assert dmp.shape == (len(images), k, p) and prob.shape == (len(images), k)
    assert dmp.dtype == np.float64 and prob.dtype == np.float64
    assert np.allclose(prob.sum(1), 1.0) and (np.diff(prob, axis=1) <= 0).all()
    # In the network's units (each parameter over its spread in the training set) ...
    diff = normalised_difference(pred.normaliser, dmp, ref)
    assert diff <= EXPORT_TOLERANCE, diff
    assert np.abs(prob - probs).max() <= EXPORT_TOLERANCE
    # ... in physical units, relative to the largest entry of each field (w, tau, g, y0) ...
    layout = vector_layout(pred.dmp_config.n_kernels, pred.dmp_config.n_dims)
    for lo, hi in (layout[f] for f in ("w", "tau", "g", "y0")):
        size = np.maximum(1.0, np.abs(ref[..., lo:hi]).max(-1, keepdims=True))
        assert (np.abs(dmp - ref)[..., lo:hi] / size).max() <= EXPORT_TOLERANCE
    # ... and as paths, to far below a pixel.
    cfg = pred.dmp_config
    tau = torch.as_tensor(ref[..., layout["tau"][0]])[..., None]  # [B, K, 1]
    t = torch.linspace(0, 1, 50, dtype=torch.float64) * tau
    y_onnx = rollout(DMPParams.from_vector(dmp, cfg.n_kernels, cfg.n_dims).to_torch(), t, cfg)
    y_torch = rollout(params.to_torch(), t, cfg)
    assert (y_onnx - y_torch).abs().max() < 1e-4


def test_the_description_is_in_the_graph_and_beside_it(trained, tmp_path):
    runs, _ = trained
    out = tmp_path / "m.onnx"
    report = export_onnx(runs["conv-k3"], out, n_check=5)
    model = onnx.load(str(out))
    onnx.checker.check_model(model)
    assert {o.domain: o.version for o in model.opset_import}[""] == OPSET
    meta = {m.key: m.value for m in model.metadata_props}
    side = json.loads((tmp_path / "m.json").read_text())
    assert json.loads(meta["img2dmp"]) == side == json.loads(json.dumps(report.description))
    pred = Predictor.load(runs["conv-k3"])
    n, d = pred.dmp_config.n_kernels, pred.dmp_config.n_dims
    assert side["format"] == "img2dmp-onnx" and side["opset"] == OPSET
    assert side["dmp_config"] == pred.dmp_config.to_dict()
    assert side["image_size"] == list(pred.image_size) and side["hypotheses"] == 3
    assert side["input"] == {"name": "images", "dtype": "float32", "shape": ["B", 40, 40]}
    assert [o["name"] for o in side["outputs"]] == ["dmp", "probability"]
    assert side["outputs"][0]["shape"] == ["B", 3, n * d + 1 + 2 * d]
    lay = side["vector_layout"]
    assert lay["tau"] == [n * d, n * d + 1] and lay["y0"][1] == lay["length"] == n * d + 1 + 2 * d
    assert side["framing"]["ink_margin"] == pred.margin
    assert side["source"]["record_sha256"] == pred.meta["record_sha256"]
    assert side["check"]["images"] == 5 and side["check"]["max_difference"] <= EXPORT_TOLERANCE
    # The batch size is free: one image and many.
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    for b in (1, 7):
        dmp, prob = session.run(None, {"images": np.zeros((b, 40, 40), np.float32)})
        assert dmp.shape == (b, 3, 55) and prob.shape == (b, 3)


def test_the_dense_impulse_filter_is_the_filter():
    rng = np.random.default_rng(0)
    x = torch.as_tensor(rng.uniform(0, 1, (6, 20, 17)).astype(np.float32))
    x[torch.as_tensor(rng.uniform(size=x.shape) < 0.1)] = 1.0
    x[torch.as_tensor(rng.uniform(size=x.shape) < 0.1)] = 0.0
    x[0] = 0.0  # blank: nothing changes
    want = ImpulseFilter()(x)
    assert not torch.equal(want, x)  # the filter does act on these images
    assert torch.equal(DenseImpulseFilter()(x), want)


def test_a_graph_that_differs_from_torch_is_refused(trained, tmp_path, monkeypatch):
    import img2dmp.export as export

    runs, _ = trained
    real = export.to_onnx

    def off_by_a_little(predictor):  # the graph of a network with one changed weight
        other = Predictor.load(runs["fc"])
        with torch.no_grad():
            other.model.decoder[-1].bias[0] += 1e-2
        return real(other)

    monkeypatch.setattr(export, "to_onnx", off_by_a_little)
    with pytest.raises(ExportCheckFailed, match="differs from torch"):
        export_onnx(runs["fc"], tmp_path / "m.onnx", n_check=4)
    assert not list(tmp_path.iterdir())  # nothing written


def test_cli_export_overwrite_rule_and_data_check(trained, tmp_path, capsys):
    runs, data = trained
    out = tmp_path / "m.onnx"
    argv = ["export", "--model", str(runs["fc"]), "--onnx", str(out), "--check", "4"]
    assert cli.main(argv) == 0
    line = capsys.readouterr().out.strip()
    assert f"ONNX opset {OPSET}" in line and "max difference" in line
    assert out.is_file() and (tmp_path / "m.json").is_file()
    before = out.read_bytes()
    assert cli.main(argv) == 2  # an existing output is never replaced without --force
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists; pass --force" in err[0] and out.read_bytes() == before
    assert cli.main([*argv, "--force", "--data", str(data)]) == 0
    n_test = int((load_dataset(data).split == 2).sum())
    assert f"on {min(4, n_test)} images" in capsys.readouterr().out
    assert json.loads((tmp_path / "m.json").read_text())["check"]["images"] == min(4, n_test)
    assert cli.main(["export", "--model", str(runs["fc"]), "--onnx", str(tmp_path / "m.txt")]) == 2
    assert "must name a file ending in .onnx" in capsys.readouterr().err


@pytest.mark.parametrize("missing", ["onnxruntime", "onnxscript"])
def test_without_the_extra_one_line_says_how_to_install_it(
    trained, tmp_path, capsys, monkeypatch, missing
):
    runs, _ = trained
    monkeypatch.setitem(sys.modules, missing, None)  # import raises ImportError
    out = tmp_path / "m.onnx"
    assert cli.main(["export", "--model", str(runs["fc"]), "--onnx", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("img2dmp export: error: ONNX export needs")
    assert f"missing: {missing}" in err[0] and "pip install -e '/path/to/img2dmp[export]'" in err[0]
    assert not out.exists()


# --- docs/EXPORT.md's NumPy lines -----------------------------------------------------


def readme_numpy_lines() -> str:
    """The code block after the ``numpy-rollout`` marker in docs/EXPORT.md, as it stands."""
    text = (ROOT / "docs" / "EXPORT.md").read_text(encoding="utf-8")
    found = re.search(r"<!-- numpy-rollout[^>]*-->\s*```python\n(.*?)```", text, re.S)
    assert found, "docs/EXPORT.md has no code block after the numpy-rollout marker"
    return found.group(1)


def _dmps():
    """DMPs fitted to synthetic digits with either scaling, and a pen (d = 3) DMP."""
    rng = np.random.default_rng(1)
    for scaling in ("goal-start", "none"):
        cfg = DMPConfig(scaling=scaling)
        d = generate(np.arange(6), rng=rng, dmp_config=cfg)
        for v in d.params:
            yield DMPParams.from_vector(v.astype(np.float64), 25, 2), cfg
    cfg = DMPConfig(n_kernels=10, n_dims=3, scaling="none")
    w = rng.normal(0, 200, (10, 3))
    yield DMPParams(w, np.float64(0.7), np.array([30.0, 12, 0]), np.array([5.0, 20, 1])), cfg


def test_readme_numpy_lines_integrate_the_dmp_file_as_the_rollout_does(tmp_path, monkeypatch):
    from img2dmp.robot.dmpfile import save_dmp_json

    code = readme_numpy_lines()
    assert "import torch" not in code and "img2dmp" not in code  # NumPy alone
    monkeypatch.chdir(tmp_path)
    (tmp_path / "pred").mkdir()
    worst = 0.0
    for params, cfg in _dmps():
        save_dmp_json("pred/digit_3_dmp.json", params, cfg, (40, 40))
        ns: dict = {}
        exec(compile(code, "docs/EXPORT.md", "exec"), ns)
        t, path = ns["t"], ns["path"]
        assert t[0] == 0 and t[-1] == pytest.approx(float(params.tau))
        y = rollout(params.to_torch(), torch.as_tensor(t), cfg).numpy()
        assert path.shape == y.shape
        worst = max(worst, float(np.abs(path - y).max()))
    assert worst <= NUMPY_TOLERANCE_PX, worst
