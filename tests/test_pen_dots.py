"""A pen's dot (an i's, a diacritic) is ink, not a speck (data/paper.py, ``_pen_dots``):
it survives the preparation on plain and ruled paper, while specks, grain and the dots of
dotted paper still go."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import label

from drawn import ink as _ink
from drawn import on_paper as _on_paper
from drawn import ruled as _ruled
from drawn import stroke as _stroke
from img2dmp.data.images import prepare_image, prepare_image_found
from img2dmp.data.paper import paper_ink

SIZE = (240, 320)
# an "i" and a "j": stems 50 px tall, their dots (a pen's dab: one point) above them
STEMS = [_stroke([(100, 95), (100, 145)]), _stroke([(200, 95), (200, 150), (185, 160)])]
DOTS = [(100, 78), (200, 78)]


def _with_dots(ink: np.ndarray, radius: float = 1.6) -> np.ndarray:
    """``ink`` with the pen's dabs at ``DOTS``: discs about one pen width across."""
    rows, cols = np.mgrid[: ink.shape[0], : ink.shape[1]].astype(np.float32)
    for x, y in DOTS:
        disc = np.clip(radius + 0.5 - np.hypot(rows - y, cols - x), 0.0, 1.0)
        ink = np.maximum(ink, disc)
    return ink


def _components(mask) -> int:
    return label(mask, structure=np.ones((3, 3), bool))[1]


def test_the_brief_s_dot_under_two_bars_is_kept():
    img = np.ones((80, 80), np.float32)
    img[20:23, 15:65] = 0.0
    img[40:43, 15:65] = 0.0
    img[55:58, 38:41] = 0.0  # a 3 x 3 dot, one pen width across
    out, frame, mask = prepare_image_found(img)
    assert _components(mask) == 3 and mask[55:58, 38:41].all()
    (x, y) = frame.to_model(np.array([[39.0, 56.0]]))[0]
    assert out[round(y), round(x)] > 0.5  # in the network's input too


@pytest.mark.parametrize("paper", ["plain", "ruled"])
def test_an_i_s_and_a_j_s_dots_survive_the_preparation(paper):
    truth = _with_dots(_ink(SIZE, STEMS))
    sheet = (
        np.full((*SIZE, 3), 0.95, np.float32)
        if paper == "plain"
        else _ruled(SIZE, 30.0, angle_deg=1.0)  # the dots between two rules
    )
    img = _on_paper(truth, sheet)
    found = paper_ink(img)
    for x, y in DOTS:
        assert found.mask[y - 1 : y + 2, x - 1 : x + 2].any(), (paper, x, y)
    assert _components(found.mask) == 4
    out = prepare_image(img, (64, 64))
    assert _components(out > 0.5) == 4  # two stems, two dots


def test_specks_far_from_the_writing_and_grain_near_it_still_go():
    rng = np.random.default_rng(5)
    truth = _with_dots(_ink(SIZE, STEMS))
    img = _on_paper(truth, np.full((*SIZE, 3), 0.95, np.float32))
    # dot-sized specks as dark as the pen, far (more than a stem's length) from it
    far = [(20, 20), (300, 30), (30, 220), (290, 215), (130, 230)]
    for x, y in far:
        img[y - 1 : y + 2, x - 1 : x + 2] = 0.05
    # grain beside the strokes: single pixels and 2 x 2 specks, a few px away
    for x, y in [(106, 120), (93, 100), (207, 110), (178, 150), (120, 70)]:
        img[y, x] = 0.05
    for x, y in [(110, 130), (215, 125)]:
        img[y : y + 2, x : x + 2] = 0.05
    img.reshape(-1, 3)[rng.integers(0, SIZE[0] * SIZE[1], 200)] = 0.1  # salt and pepper
    found = paper_ink(img)
    for x, y in far:
        assert not found.mask[y - 1 : y + 2, x - 1 : x + 2].any(), (x, y)
    assert _components(found.mask) == 4  # the stems and their dots only
    assert found.removed["specks"] >= 5


@pytest.mark.parametrize("short", [False, True])
def test_dotted_paper_s_dots_near_the_writing_still_go(short):
    # short: a mark 16 px tall, near which fewer dots lie than a lattice needs (MIN_DOTS):
    # the lattice is the one of all such marks on the page
    h, w = SIZE
    rows, cols = np.mgrid[:h, :w].astype(np.float32)
    dots = np.zeros(SIZE, np.float32)
    for cy in np.arange(10, h, 20.0):
        for cx in np.arange(10, w, 20.0):  # printed dots as dark and as wide as the pen
            dots = np.maximum(dots, np.clip(2.1 - np.hypot(rows - cy, cols - cx), 0.0, 1.0))
    paper = np.full((*SIZE, 3), 0.95, np.float32) * (1.0 - 0.9 * dots[..., None])
    strokes = [_stroke([(125, 112), (125, 128)])] if short else STEMS
    truth = _ink(SIZE, strokes)
    found = paper_ink(_on_paper(truth, paper))
    away = _ink(SIZE, strokes, width=8.0) < 0.01
    assert (found.mask & away).sum() == 0, "dotted paper's dots kept as pen dots"
    assert found.mask[truth > 0.5].mean() > 0.95
