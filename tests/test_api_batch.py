"""A researcher's loop from Python: many images at once, and the array layouts other
libraries hand over.

- ``Predictor.predict_batch`` gives, for each image of a list or a stacked array, what
  ``predict`` gives for it alone (to a batch's float32 rounding; bit for bit for a batch
  of one), for a one-DMP model and a stroke model, and names the image at fault;
- an array ``[H, W, 1]`` and a torch tensor channels first ``[C, H, W]`` (torchvision's
  layout) read as the same image as ``[H, W]`` / ``[H, W, C]``; a stacked array given to
  ``predict`` says to use ``predict_batch``.

Runs on the shipped models (no training): a few seconds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

import img2dmp

SAMPLES = Path(__file__).resolve().parents[1] / "examples" / "samples"
DIGIT = SAMPLES / "digit_3.png"
PHOTO = SAMPLES / "digit_5_photo.jpg"
LETTER = SAMPLES / "character_f.png"


@pytest.fixture(scope="module")
def model():
    return img2dmp.load_model(refine=5)  # fewer steps: the same code, a faster test


@pytest.fixture(scope="module")
def grey() -> np.ndarray:
    return np.asarray(Image.open(DIGIT).convert("L"))  # uint8 [H, W], dark on light


def _weights_close(a: img2dmp.DMPParams, b: img2dmp.DMPParams, what: str) -> None:
    """Equal to a batch's float32 rounding, which refinement may carry further (docs/API.md):
    every number within 1e-4 of its row's largest weight (weights reach thousands, tau
    about 1); another image's DMP would be off by far more."""
    va, vb = a.to_vector(), b.to_vector()
    scale = np.abs(vb).max(axis=-1, keepdims=True)
    assert np.all(np.abs(va - vb) <= 1e-4 * scale), what


def test_a_batch_gives_each_image_what_predict_gives_it(model, grey):
    images = [DIGIT, Image.open(PHOTO), grey, 1.0 - grey / 255.0, torch.from_numpy(grey.copy())]
    batch = model.predict_batch(images)
    assert len(batch) == len(images)
    for i, (image, got) in enumerate(zip(images, batch, strict=True)):
        alone = model.predict(image)
        assert isinstance(got, img2dmp.Prediction)
        _weights_close(got.params, alone.params, f"image {i}")
        np.testing.assert_allclose(got.probabilities, alone.probabilities, atol=1e-5)
        np.testing.assert_array_equal(got.image, alone.image)
        np.testing.assert_array_equal(got.frame.image_to_model, alone.frame.image_to_model)
        assert got.source == alone.source and got.refine_steps == alone.refine_steps
        assert got.flags == alone.flags and got.user_image is image
        assert got.familiarity == pytest.approx(alone.familiarity, abs=1e-6)
        assert got.path_image.shape == alone.path_image.shape
    assert batch[0].source == str(DIGIT) and batch[2].source is None
    # a batch of one is predict itself, bit for bit
    [one] = model.predict_batch([grey], n_points=30)
    alone = model.predict(grey, n_points=30)
    np.testing.assert_array_equal(one.params.to_vector(), alone.params.to_vector())
    np.testing.assert_array_equal(one.path_image, alone.path_image)
    assert one.times.shape == (model.n_hypotheses, 30)


def test_a_stacked_array_a_generator_and_small_chunks_read_as_the_list(model, grey):
    flipped = np.ascontiguousarray(grey[:, ::-1])
    by_list = model.predict_batch([grey, flipped, grey])
    stacked = model.predict_batch(np.stack([grey, flipped, grey]), chunk=2)
    generated = model.predict_batch(x for x in (grey, flipped, grey))
    for got in (stacked, generated):
        for a, b in zip(got, by_list, strict=True):
            _weights_close(a.params, b.params, "stacked")
    assert model.predict_batch([]) == []


def test_a_stroke_models_batch_reads_each_character_as_predict_does():
    strokes = img2dmp.load_model("omniglot-strokes", refine=5)
    letter = np.asarray(Image.open(LETTER).convert("L"))
    images = [LETTER, 255 - letter]
    batch = strokes.predict_batch(images)
    for image, got in zip(images, batch, strict=True):
        alone = strokes.predict(image)
        assert type(got).__name__ == "StrokePrediction"
        assert got.n_strokes == alone.n_strokes and got.flags == alone.flags
        _weights_close(got.strokes, alone.strokes, "strokes")


@pytest.mark.parametrize(
    "images, message",
    [
        (str(DIGIT), r"images must be several images .* got one str: predict takes one"),
        (np.zeros((5, 40, 3)), r"\[B, H, W\] or \[B, H, W, C\], got shape \(5, 40, 3\) \(one RGB"),
        (7, r"images must be a list of images or an array \[B, H, W\], got int"),
        ([DIGIT, np.zeros((20, 20))], r"^images\[1\] shows no ink"),
        ([DIGIT, None], r"^images\[1\] must be a file path, a PIL image or a NumPy array, got No"),
        ([DIGIT, "no/such.png"], r"image file no/such.png does not exist"),
    ],
)  # fmt: skip
def test_a_bad_batch_names_the_image_at_fault(model, images, message):
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        model.predict_batch(images)


def test_other_libraries_array_layouts_read_as_the_same_image(model, grey):
    ref = model.prepare(grey)[0]
    rgb = np.repeat(grey[..., None], 3, axis=-1)
    t = torch.from_numpy(grey.copy())
    layouts = {
        "[H, W, 1]": grey[..., None],
        "tensor [1, H, W]": t[None],
        "tensor [3, H, W]": torch.from_numpy(rgb.transpose(2, 0, 1).copy()),
        "tensor [H, W, 3]": torch.from_numpy(rgb),
        "tensor [1, H, W] float": t[None].float() / 255,
    }
    for what, image in layouts.items():
        np.testing.assert_array_equal(model.prepare(image)[0], ref, err_msg=what)
    # a layout that cannot be told apart from a batch or channels first is named
    with pytest.raises(ValueError, match=r"got shape \(2, \d+, \d+\) \(several images: predict_b"):
        model.predict(np.stack([grey, grey]))
    with pytest.raises(ValueError, match=r"got shape \(3, \d+, \d+\) \(channels first\? give \[H"):
        model.predict(rgb.transpose(2, 0, 1))


def test_reprs_say_what_a_researcher_checks_first(model):
    text = repr(model)
    for part in ("digits-real", f"{model.n_hypotheses} hypotheses", "input 28 x 28",
                 "refine 5", "numpy backend", "N = 25, d = 2", "scaling 'none'"):  # fmt: skip
        assert part in text, (part, text)
    strokes = repr(img2dmp.load_model("omniglot-strokes", refine=0))
    assert "omniglot-strokes: stroke model of 8 slots" in strokes and "refine 0" in strokes
    fam = model.familiar
    familiar = repr(fam)  # its sizes and line, not its thousands of feature rows
    n, f = fam.features.shape
    assert familiar.startswith(f"Familiar({n} training drawings x {f} features, line ")
    assert f"% of {fam.n_validation} validation drawings below it)" in familiar
    assert len(familiar) < 200
    frame = img2dmp.ImageFrame(np.array([[0.5, 0.0, -3.0], [0.0, 0.5, 2.0]]), (80, 60), (28, 28))
    assert repr(frame).endswith("x_m = 0.5 x + 0 y - 3, y_m = 0 x + 0.5 y + 2)"), repr(frame)
