"""A prediction without torch (img2dmp.predict, "Backends"; docs/ARCHITECTURE.md).

The NumPy backend computes what the torch backend does: whole predictions and pages of
the shipped model, refined as its card recommends, agree to 1e-5 of each parameter's
spread over the training set (the network's output units). A prediction, a page and the
DMP file's check, and a stroke model's refined character, run in a fresh process without
importing torch at all.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import img2dmp
from img2dmp import cli
from img2dmp.export import normalised_difference
from img2dmp.predict import Predictor

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "examples" / "samples"
#: Largest difference of two backends' DMPs, in units of each parameter's spread.
TOLERANCE = 1e-5


@pytest.fixture(scope="module")
def both():
    """The default shipped model on each backend, with its card's refinement."""
    return {b: img2dmp.load_model(backend=b) for b in ("numpy", "torch")}


def _vectors(pred) -> np.ndarray:
    return pred.params.to_vector()  # [K, P], model frame, ranked


def test_auto_is_numpy_on_the_cpu_and_the_backends_are_named(both):
    assert img2dmp.load_model().backend == "numpy"
    assert both["numpy"].backend == "numpy" and both["numpy"].network is not None
    assert both["torch"].backend == "torch" and both["torch"].network is None
    assert both["numpy"].refine_options == both["torch"].refine_options  # the card's


@pytest.mark.parametrize("sample", ["digit_3.png", "digit_5_photo.jpg"])
def test_a_refined_prediction_is_the_same_on_numpy_and_torch(both, sample):
    a, b = (both[k].predict(SAMPLES / sample) for k in ("numpy", "torch"))
    norm = both["numpy"].normaliser
    assert normalised_difference(norm, _vectors(a), _vectors(b)) <= TOLERANCE
    assert np.abs(a.probabilities - b.probabilities).max() <= TOLERANCE
    assert np.abs(a.path_image - b.path_image).max() <= 1e-3  # px of the user's image
    assert a.flags == b.flags and a.fit == pytest.approx(b.fit, abs=0.02)
    assert a.refine_steps == b.refine_steps == 30


@pytest.mark.parametrize("backend", ["numpy", "torch"])
def test_many_images_are_refined_in_parts_with_the_numbers_of_one_batch(both, backend, monkeypatch):
    from img2dmp import predict

    m = both[backend]
    images = np.stack([m.prepare(SAMPLES / s)[0] for s in ("digit_3.png", "digit_5_photo.jpg")])
    images = np.concatenate([images, images[:, ::-1], images[:, :, ::-1]])  # 6 images, 24 DMPs
    whole, probs = m.predict_hypotheses(images)
    calls = []
    part = type(m)._refined_part
    monkeypatch.setattr(predict, "REFINE_ROWS", 5)
    monkeypatch.setattr(
        type(m), "_refined_part", lambda self, z, x, o: calls.append(len(z)) or part(self, z, x, o)
    )
    parts, probs_parts = m.predict_hypotheses(images)
    # each group of equal steps (an unfamiliar image's take more) in parts of 5 DMPs
    steps = np.repeat(m.refine_steps_for(images), 4)
    sizes = [int((steps == n).sum()) for n in np.unique(steps)]
    assert calls == [min(5, n - a) for n in sizes for a in range(0, n, 5)] and sum(calls) == 24
    np.testing.assert_allclose(parts.to_vector(), whole.to_vector(), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(probs_parts, probs)


def test_the_network_s_output_is_the_same_on_numpy_and_torch(both):
    images = np.stack([both["numpy"].prepare(SAMPLES / s)[0] for s in ("digit_3.png",
                       "digit_5_photo.jpg")])  # fmt: skip
    plain = {k: Predictor.load("digits-real", backend=k) for k in ("numpy", "torch")}
    (pa, qa), (pb, qb) = (plain[k].predict_hypotheses(images) for k in ("numpy", "torch"))
    norm = plain["numpy"].normaliser
    assert normalised_difference(norm, pa.to_vector(), pb.to_vector()) <= TOLERANCE
    assert np.abs(qa - qb).max() <= TOLERANCE
    # the torch network a NumPy predictor builds on demand is the one it computes
    z = plain["numpy"].predict_normalised(images).numpy()
    out = plain["numpy"].model(__import__("torch").from_numpy(images)).detach().numpy()
    assert out.shape[0] == 2 and np.isfinite(z).all()
    assert np.abs(plain["numpy"].network(images) - out).max() <= 1e-4 * (1 + np.abs(out).max())


def test_a_page_is_read_the_same_on_numpy_and_torch(both):
    a, b = (both[k].predict_page(SAMPLES / "page.jpg") for k in ("numpy", "torch"))
    assert len(a.characters) == len(b.characters) > 5
    norm = both["numpy"].normaliser
    for ca, cb in zip(a.characters, b.characters, strict=True):
        assert ca.character.box == cb.character.box
        pa, pb = ca.prediction, cb.prediction
        assert normalised_difference(norm, _vectors(pa)[:1], _vectors(pb)[:1]) <= TOLERANCE


def test_a_stroke_models_refined_character_is_the_same_on_numpy_and_torch():
    """The shipped stroke model's strokes refined as its card recommends: the same paths
    on both backends (tau, which shapes no stroke, left as the network gave it)."""
    import torch

    from img2dmp.nn._refine_numpy import refine_strokes_numpy
    from img2dmp.nn._stroke_layout import character_paths
    from img2dmp.nn.strokes import refine_strokes

    pred = {b: img2dmp.load_model("omniglot-strokes", backend=b) for b in ("numpy", "torch")}
    a, b = (pred[k].predict(SAMPLES / "character_f.png") for k in ("numpy", "torch"))
    assert a.n_strokes == b.n_strokes >= 2
    assert np.abs(a.path_image - b.path_image).max() <= 1e-3  # px; the networks differ ~1e-6
    p = pred["numpy"]
    x = np.asarray(a.image, dtype=np.float32)  # the prepared image the network read
    p.refine_options, o = None, p.refine_options
    raw = p.predict_strokes(x[None])
    via_numpy = refine_strokes_numpy(raw, x[None], p.normaliser, p.strokes, o)
    with torch.no_grad():
        via_torch = refine_strokes(raw, x[None], p.normaliser, p.strokes, o)
    (v0, _), (v1, _), (v2, _) = raw[0], via_numpy[0], via_torch[0]
    tau = p.normaliser.tau_index
    assert np.abs(v1 - v0).max() > 0.1  # refinement moved the strokes ...
    assert np.array_equal(v1[:, tau], v0[:, tau]) and np.array_equal(v2[:, tau], v0[:, tau])
    assert np.abs(v1 - v2).max() <= 1e-9  # ... the same way on both backends
    paths = [character_paths(s, p.normaliser, p.strokes)[0] for s in (via_numpy, via_torch)]
    assert np.abs(paths[0] - paths[1]).max() <= 1e-9


def test_bad_backends_are_one_line_errors(capsys):
    with pytest.raises(ValueError, match="backend must be one of auto, numpy, torch, got 'jax'"):
        img2dmp.load_model(backend="jax")
    with pytest.raises(ValueError, match="backend 'numpy' runs on the CPU"):
        Predictor.load("digits-real", device="cuda", backend="numpy")
    assert cli.main(["predict", str(SAMPLES / "digit_3.png"), "--backend", "jax"]) == 2
    assert "invalid choice: 'jax'" in capsys.readouterr().err


_NO_TORCH = """
import json, sys
sys.modules["torch"] = None  # any import of torch now fails, loudly
import img2dmp
from img2dmp.cli import main
from img2dmp.data.dmpfile import read_dmp_file
out = sys.argv[1]
assert main(["predict", sys.argv[2], "--out", out]) == 0
assert main(["predict", sys.argv[3], "--page", "--out", out]) == 0
read_dmp_file(out + "/digit_3_dmp.json")  # checked, its rollout included
assert main(["predict", sys.argv[4], "--model", "omniglot-strokes", "--out", out]) == 0
pred = img2dmp.load_model().predict(sys.argv[2])
print(json.dumps({"tau": float(pred.dmp.tau), "backend": "numpy"}))
"""


def test_predict_and_a_page_run_without_torch(tmp_path):
    code = [sys.executable, "-c", _NO_TORCH, str(tmp_path),
            str(SAMPLES / "digit_3.png"), str(SAMPLES / "page.jpg"),
            str(SAMPLES / "character_f.png")]  # fmt: skip
    proc = subprocess.run(code, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads(proc.stdout.strip().splitlines()[-1])["tau"] > 0
    assert (tmp_path / "page_page.json").exists() and (tmp_path / "digit_3_dmp.json").exists()
    letter = json.loads((tmp_path / "character_f_dmp.json").read_text())  # the card's steps:
    unfamiliar = "unfamiliar" in letter["flags"]  # 150 for an unfamiliar image, else 60
    assert letter["refinement"]["steps"] == (150 if unfamiliar else 60)
