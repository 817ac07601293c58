"""A shaken photo's blur, along a row, a column or at a slant, found and undone
(img2dmp.data.shake)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter, uniform_filter1d

from drawn import moved, on_paper, page
from img2dmp.data.shake import Shake, line, shake, steadied

# two lines of characters 4-12 px apart: a blur of 7-9 px along the line joins them
LINES = [[("1", 40), ("7", 62), ("0", 92), ("5", 124), ("7", 156), ("1", 184)],
         [("0", 40), ("5", 72), ("7", 104), ("1", 132), ("0", 150)]]  # fmt: skip


def _tight_page():
    """The two tight lines on grainy paper (4 % grain); the image and the true boxes."""
    ink, boxes = page(LINES, height=40.0)
    grain = gaussian_filter(np.random.default_rng(0).normal(0.0, 0.04, ink.shape), 0.7)
    paper = (0.8 * (1.0 + grain))[..., None] * np.array([1.0, 0.97, 0.92])
    return np.clip(on_paper(ink, paper.astype(np.float32)), 0.0, 1.0).astype(np.float32), boxes


def _one_box_each(seg, boxes) -> bool:
    found = [c.box for c in seg.layout.characters]
    centres = [((b[0] + b[2]) / 2, (b[1] + b[3]) / 2) for b in boxes]
    inside = [[f[0] <= x < f[2] and f[1] <= y < f[3] for f in found] for x, y in centres]
    return len(found) == len(boxes) and all(sum(row) == 1 for row in inside)


@pytest.mark.parametrize(("length", "axis"), [(9, 1), (5, 1), (7, 0), (9, 0)])
def test_a_shake_along_a_row_or_a_column_is_found_with_its_length(length, axis):
    img, _ = _tight_page()
    assert shake(uniform_filter1d(img, length, axis=axis)) == Shake(length, 90.0 * (1 - axis))


@pytest.mark.parametrize(("length", "degrees"), [(9, 30), (7, 45), (9, 120), (11, 165)])
def test_a_shake_at_a_slant_is_found_with_its_length_and_direction(length, degrees):
    img, _ = _tight_page()
    found = shake(moved(img, length, degrees))
    assert found is not None
    assert abs(found.length - length) <= 1.0 and abs(found.degrees - degrees) <= 3.0


def test_a_line_is_drawn_by_the_share_of_it_in_each_pixel():
    box = line(5, 0)
    assert np.allclose(box[4], [0, 0, 0.2, 0.2, 0.2, 0.2, 0.2, 0, 0]) and box.sum() == box[4].sum()
    assert np.array_equal(line(5, 90), box.T)
    slant = line(9.4, 31.5)
    assert slant.shape == (13, 13) and np.isclose(slant.sum(), 1.0)
    assert np.allclose(slant, slant[::-1, ::-1])  # symmetric about its centre
    ys, xs = np.nonzero(slant)
    assert abs(np.polyfit(xs - 6, ys - 6, 1, w=slant[ys, xs])[0] - np.tan(np.deg2rad(31.5))) < 0.05


def test_a_photo_in_focus_or_out_of_it_or_tiny_has_no_shake():
    img, _ = _tight_page()
    for sharp in (img, gaussian_filter(img, (2.0, 2.0, 0.0)), img[:40, :40], img.mean(axis=2)):
        assert shake(sharp) is None
        assert steadied(sharp) is sharp  # as it is, not a copy


@pytest.mark.parametrize(("length", "degrees"), [(9, 0), (7, 90), (9, 20)])
def test_a_shaken_page_s_characters_are_read_one_by_one_once_steadied(length, degrees,
                                                                      monkeypatch):  # fmt: skip
    """Shaken 9 px along its lines, two characters ran together (10 boxes for 11); 7 px
    across them, one split (12); 9 px at 20 degrees, ... Steadied: one box each. Without
    it, not (the test can fail)."""
    import img2dmp.page as page_module
    from img2dmp.page import segment_page

    img, boxes = _tight_page()
    if degrees in (0, 90):
        shaken = uniform_filter1d(img, length, axis=1 if degrees == 0 else 0)
    else:
        shaken = moved(img, length, degrees)
    assert _one_box_each(segment_page(shaken), boxes)
    steady = steadied(shaken)
    assert steady.shape == shaken.shape and steady.dtype == np.float32
    assert 0.0 <= steady.min() and steady.max() <= 1.0
    monkeypatch.setattr(page_module, "steadied", lambda levels, found=None: levels)
    assert not _one_box_each(segment_page(shaken), boxes)


def test_the_readings_experiment_scores_a_shake_s_length_and_direction(experiment_script):
    """experiments/shake_readings.py: a page moved 9 px at 30 degrees is read within its
    errors, the page as it is is not read as shaken, and the summary counts both."""
    sr = experiment_script("shake_readings")
    img, _ = _tight_page()
    rgb = (np.clip(img, 0, 1) * 255).astype(np.uint8)
    shaken = (moved(img, 9, 30) * 255).astype(np.uint8)
    rows = [{"image": "p", "kind": "page", "condition": c, **sr.reading(x, a)}
            for c, x, a in (("as-is", rgb, None), ("moved", shaken, (9, 30)))]  # fmt: skip
    assert rows[0]["found"] is None and "length_error" not in rows[0]
    assert rows[1]["length_error"] < 1 and rows[1]["direction_error"] < 3
    summary = {s["shaken"]: s for s in sr.summarise(rows)}
    assert summary[False]["read as shaken"] == 0 and summary[True]["read as shaken"] == 1
    with pytest.raises(SystemExit):
        sr.main(["--photos", "", "--pages", "0", "--more", "0", "--out", "unused"])


@pytest.mark.parametrize("found", [(0, 0), (-3, 10), (float("nan"), 0), (9, float("inf")),
                                   (500, 0), ("long", 0), (9,), 9.0])  # fmt: skip
def test_a_shake_given_that_cannot_be_undone_is_refused_by_name(found):
    img, _ = _tight_page()
    with pytest.raises(ValueError, match="shake"):
        steadied(img, found)


def test_a_shake_given_by_hand_is_undone_as_the_one_read():
    img, _ = _tight_page()
    shaken = moved(img, 9, 30)
    read = shake(shaken)
    assert np.array_equal(steadied(shaken, (read.length, read.degrees)), steadied(shaken))
    assert np.array_equal(steadied(shaken, (read.length, read.degrees - 180)), steadied(shaken))
    with pytest.raises(ValueError, match="length must be 1 to"):
        line(0.5, 0)


def test_a_flat_image_has_no_shake_and_no_warning():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a log of zero power warned, and read NaNs
        for flat in (np.ones((200, 300, 3), np.float32), np.zeros((200, 300), np.float32)):
            assert shake(flat) is None and steadied(flat) is flat
