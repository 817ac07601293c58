"""Pages from a scanner (docs/PAGE.md, "A scanned page"): 1-bit (black and white) or
grey files, strokes broken by the scanner's threshold or by a large scan's reduction."""

from __future__ import annotations

import numpy as np
import pytest

from drawn import ellipse, ink, stroke
from img2dmp.data.pages import find_characters

SIZE = (260, 560)


def _line(x0: float = 60.0) -> list[np.ndarray]:
    """A 0, a 1 slanted 15 degrees, a 7 and a 0, 80 px tall."""
    return [ellipse(x0 + 25, 130, 22, 40), stroke([(x0 + 110, 90), (x0 + 88, 170)]),
            stroke([(x0 + 150, 90), (x0 + 200, 90), (x0 + 165, 170)]),
            ellipse(x0 + 255, 130, 22, 40)]  # fmt: skip


def _cut(mask: np.ndarray, rows: slice, cols: slice) -> np.ndarray:
    out = mask.copy()
    out[rows, cols] = False
    return out


@pytest.mark.parametrize("gap_rows", [1, 2, 3])
def test_a_slanted_stroke_broken_by_a_threshold_is_one_character(gap_rows):
    mask = ink(SIZE, _line(), width=4.0) > 0.5
    broken = _cut(mask, slice(128, 128 + gap_rows), slice(140, 180))  # the 1 only
    labels = __import__("scipy.ndimage", fromlist=["label"]).label(broken, np.ones((3, 3)))[1]
    assert labels == 5  # the 1 in two pieces, the upper one's end over the lower one's
    layout = find_characters(broken)
    assert len(layout.characters) == 4, [c.box for c in layout.characters]
    assert layout.characters[1].parts == 2


def test_a_stroke_s_core_broken_by_a_large_scan_s_reduction_is_one_character():
    """A thin line of a large scan reduced to the page's working size: its core (the
    pixels inked at least CORE_LEVEL) broken on the diagonal, the mask whole."""
    mask = ink(SIZE, _line(), width=3.0) > 0.5
    core = _cut(mask, slice(125, 127), slice(140, 180))
    layout = find_characters(mask, core=core, grow=2)
    assert len(layout.characters) == 4, [c.box for c in layout.characters]


def test_strokes_side_by_side_or_an_end_at_a_bowl_s_side_stay_two_characters():
    """Neighbours 2-3 px apart face each other with a stroke's side (two 1s) or with an
    end at the side of a bowl (a 7's bar at a 0): no broken stroke to join."""
    strokes = [stroke([(60, 90), (60, 170)]), stroke([(67, 90), (67, 170)]),  # 1 1
               stroke([(120, 90), (170, 90), (140, 170)]), ellipse(196, 110, 22, 40),
               ellipse(280, 130, 22, 40), stroke([(340, 90), (340, 170)])]  # fmt: skip
    mask = ink(SIZE, strokes, width=3.0) > 0.5
    labels = __import__("scipy.ndimage", fromlist=["label"]).label(mask, np.ones((3, 3)))[1]
    assert labels == 6
    layout = find_characters(mask)
    assert len(layout.characters) == 6, [c.box for c in layout.characters]


def _scan_files(tmp_path):
    """The line on white paper, the 1's middle faint (a light pen stroke), as a grey PNG,
    1-bit PNG and TIFF (thresholded at half: the faint stretch is lost), and 16-bit PNG
    and TIFF."""
    from PIL import Image

    a = ink(SIZE, _line(), width=4.0)
    a[128:131, 150:175] = np.minimum(a[128:131, 150:175], 0.55)
    grey = np.clip((1.0 - 0.9 * a) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    files = {}
    for name, image, options in (
        ("grey.png", Image.fromarray(grey), {}),
        ("bw.png", Image.fromarray(grey >= 128).convert("1"), {}),
        ("bw.tif", Image.fromarray(grey >= 128).convert("1"), {"compression": "group4"}),
        ("grey16.png", Image.fromarray(grey.astype(np.uint16) * 257), {}),
        ("grey16.tif", Image.fromarray(grey.astype(np.uint16) * 257), {}),
    ):
        files[name] = tmp_path / name
        image.save(files[name], **options)
    assert Image.open(files["bw.tif"]).mode == "1"
    assert Image.open(files["grey16.png"]).mode == "I;16"
    return files


def test_a_1_bit_or_16_bit_png_or_tiff_page_is_read_like_its_grey_version(tmp_path):
    from img2dmp.page import segment_page

    files = _scan_files(tmp_path)
    grey = segment_page(files["grey.png"])
    boxes = [grey.box_in_image(c) for c in grey.layout.characters]
    assert len(boxes) == 4
    for name in ("bw.png", "bw.tif", "grey16.png", "grey16.tif"):
        seg = segment_page(files[name])
        found = [seg.box_in_image(c) for c in seg.layout.characters]
        assert len(found) == 4, (name, found)
        assert np.abs(np.array(found) - np.array(boxes)).max() <= 3, (name, found, boxes)


def test_two_letters_whose_ends_nearly_meet_stay_two_on_a_page_of_letters():
    """Two letters 80 px tall and 65 wide written close, the first's bar ending 3 px from the
    second's: ends facing across the break gap. A page of digits joins them (and cuts
    the pair at the pitch afterwards); a page of letters, which cuts nothing, keeps
    them two (``BREAK_WIDE``), and still mends a broken stroke of its own letters."""
    from scipy.ndimage import label

    letters = [
        stroke([(60, 90), (125, 90)]),
        stroke([(92, 90), (92, 170)]),  # a T
        stroke([(128, 90), (193, 90)]),
        stroke([(193, 90), (140, 170)]),
    ]  # a 7
    letters += [stroke([(x, 90), (x, 170)]) for x in (300, 360, 420)]  # three ls
    mask = ink(SIZE, letters, width=3.0) > 0.5
    assert label(mask, np.ones((3, 3)))[1] == 5
    pair = find_characters(mask, cut=False)
    assert len(pair.characters) == 4  # a page of digits: the T and the 7 joined
    apart = find_characters(mask, cut=False, join_sides=True)
    assert len(apart.characters) == 5, [c.box for c in apart.characters]
    broken = _cut(mask, slice(128, 130), slice(150, 180))  # the 7's downstroke broken
    assert label(broken, np.ones((3, 3)))[1] == 6
    assert len(find_characters(broken, cut=False, join_sides=True).characters) == 5
