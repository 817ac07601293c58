"""The ink separated from its paper (data/paper.py) and the characters of a page
(data/pages.py), on pages drawn here with known strokes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from img2dmp.data.pages import find_characters
from img2dmp.data.paper import dominant_angle, paper_ink
from img2dmp.data.render import render_paths


def _stroke(points, n: int = 60) -> np.ndarray:
    """A polyline through ``points`` resampled to ``n`` points ``[n, 2]``."""
    p = np.asarray(points, float)
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    s = np.concatenate([[0], np.cumsum(seg)])
    u = np.linspace(0, s[-1], n)
    return np.stack([np.interp(u, s, p[:, 0]), np.interp(u, s, p[:, 1])], -1)


def _ellipse(cx, cy, rx, ry, n: int = 80) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n)
    return np.stack([cx + rx * np.cos(t), cy + ry * np.sin(t)], -1)


def _ink(size, strokes, width: float = 3.0) -> np.ndarray:
    """The ink [H, W] of several strokes."""
    out = np.zeros(size, np.float32)
    for s in strokes:
        out = np.maximum(out, render_paths(np.asarray(s, np.float32), size, width).numpy())
    return out


def _on_paper(ink, paper, colour=(0.05, 0.05, 0.1)) -> np.ndarray:
    """RGB [H, W, 3]: the ink absorbing light on the paper."""
    c = np.asarray(colour, np.float32)
    return paper * (1.0 - ink[..., None] * (1.0 - c))


def _ruled(size, spacing: float, angle_deg: float = 0.0, vertical: bool = False,
           colour=(0.55, 0.7, 0.95), width: float = 1.6) -> np.ndarray:  # fmt: skip
    """Paper [H, W, 3] with lines every ``spacing`` pixels (and columns if ``vertical``)."""
    h, w = size
    rows, cols = np.mgrid[:h, :w].astype(np.float32)
    t = math.tan(math.radians(angle_deg))
    line = np.zeros(size, np.float32)
    for coord in [rows - cols * t] + ([cols + rows * t] if vertical else []):
        d = spacing / 2 - np.abs((coord % spacing) - spacing / 2)  # to the nearest line
        line = np.maximum(line, np.clip(width / 2 + 0.5 - d, 0.0, 1.0))
    paper = np.ones((h, w, 3), np.float32) * np.array([0.97, 0.96, 0.93], np.float32)
    return paper * (1.0 - line[..., None] * (1.0 - np.asarray(colour, np.float32)))


SIZE = (240, 320)
DIGIT = [_stroke([(100, 40), (150, 40), (115, 150)]), _ellipse(210, 95, 28, 50)]  # a 7, a 0


def _kept(found, truth) -> float:
    """Share of the true ink (> 0.5) kept as ink (> 0.2)."""
    t = truth > 0.5
    return float((found.ink[t] > 0.2).mean())


def test_ruled_lines_go_and_strokes_crossing_them_stay():
    truth = _ink(SIZE, DIGIT)
    found = paper_ink(_on_paper(truth, _ruled(SIZE, 30.0, angle_deg=1.5)))
    assert _kept(found, truth) > 0.97
    far = _ink(SIZE, DIGIT, width=14.0) < 0.01  # paper well away from the strokes
    assert (found.ink[far] > 0.2).mean() < 0.002, "rules left as ink"
    assert found.removed["rule_px"] > 1000
    # where the strokes cross a rule, they keep their pixels there
    cross = (truth > 0.5) & (_ruled(SIZE, 30.0, angle_deg=1.5)[..., 0] < 0.9)
    assert cross.sum() > 20 and (found.ink[cross] > 0.2).mean() > 0.9


def test_squared_paper_tint_and_a_lighting_gradient():
    truth = _ink(SIZE, DIGIT)
    paper = _ruled(SIZE, 24.0, angle_deg=-2.0, vertical=True, colour=(0.6, 0.6, 0.6))
    paper *= np.array([1.0, 0.95, 0.7], np.float32)  # yellow
    light = np.linspace(1.0, 0.55, SIZE[1], dtype=np.float32)[None, :, None]  # a shadow
    found = paper_ink(_on_paper(truth, paper * light, colour=(0.1, 0.2, 0.7)))  # blue ink
    assert _kept(found, truth) > 0.95
    far = _ink(SIZE, DIGIT, width=14.0) < 0.01
    assert (found.ink[far] > 0.2).mean() < 0.003


def test_text_from_the_back_specks_and_the_table_edge_go():
    rng = np.random.default_rng(3)
    truth = _ink(SIZE, DIGIT)
    paper = np.full((*SIZE, 3), 0.95, np.float32)
    faint = np.zeros(SIZE, np.float32)  # rows of blurred print showing through
    for r in range(20, SIZE[0] - 10, 18):
        for c in range(10, SIZE[1] - 20, 9):
            faint[r : r + 7, c : c + 5] = 0.12
    paper *= 1.0 - faint[..., None]
    paper[:, -14:] = 0.25  # the table beyond the sheet's edge
    img = _on_paper(truth, paper)
    specks = rng.integers(0, SIZE[0] * 300, 150)
    img.reshape(-1, 3)[specks] = 0.05
    found = paper_ink(img)
    assert _kept(found, truth) > 0.95
    far = _ink(SIZE, DIGIT, width=14.0) < 0.01
    assert (found.ink[far] > 0.2).mean() < 0.002


def test_nothing_but_paper_or_specks_is_no_ink():
    paper = np.full((200, 300, 3), 0.9, np.float32)
    assert paper_ink(paper) is None
    rng = np.random.default_rng(0)
    paper.reshape(-1, 3)[rng.integers(0, 60000, 400)] = 0.1
    assert paper_ink(paper) is None


def test_a_small_clean_image_keeps_its_strokes():
    """An MNIST-sized image (light ink on black) is read as before: every stroke kept."""
    truth = _ink((28, 28), [_stroke([(8, 6), (20, 6), (12, 22)])], width=2.5)
    found = paper_ink(truth)
    assert _kept(found, truth) == 1.0 and not found.dark_on_light


def _page(lines, height=40.0, angle_deg=0.0, size=(300, 520)):
    """A page of characters ``lines[k] = [(kind, x), ...]`` on lines 100 px apart; each
    kind a list of strokes in a unit box. Returns the ink and the true boxes, in order."""
    shapes = {
        "1": [[(0.5, 0), (0.5, 1)]],
        "7": [[(0.1, 0), (0.9, 0), (0.4, 1)]],
        "5": [
            [(0.15, 0), (0.85, 0)],
            [(0.2, 0.1), (0.15, 0.45), (0.8, 0.55), (0.7, 0.95), (0.1, 0.9)],
        ],
        "0": "ellipse",
    }
    t = math.tan(math.radians(angle_deg))
    strokes, boxes = [], []
    for k, line in enumerate(lines):
        for kind, x in line:
            y = 60 + 100 * k + x * t
            w = 0.6 * height
            parts = ([_ellipse(x + w / 2, y + height / 2, w / 2, height / 2)]
                     if shapes[kind] == "ellipse" else
                     [_stroke([(x + u * w, y + v * height) for u, v in s]) for s in shapes[kind]])  # fmt: skip
            strokes += parts
            pts = np.concatenate(parts)
            boxes.append((pts[:, 0].min(), pts[:, 1].min(), pts[:, 0].max(), pts[:, 1].max()))
    return _ink(size, strokes), boxes


def _matches(layout, boxes, tol=4.0) -> bool:
    found = [c.box for c in layout.characters]
    if len(found) != len(boxes):
        return False
    return all(abs(a - b) <= tol for f, t in zip(found, boxes, strict=True)
               for a, b in zip(f, t, strict=True))  # fmt: skip


def test_characters_found_in_reading_order_on_two_lines():
    ink, boxes = _page([[("1", 40), ("7", 110), ("0", 190), ("5", 270)],
                        [("0", 60), ("5", 150), ("7", 240)]])  # fmt: skip
    layout = find_characters(ink > 0.5)
    assert _matches(layout, boxes), [c.box for c in layout.characters]
    assert [c.line for c in layout.characters] == [0, 0, 0, 0, 1, 1, 1]
    assert [len(x) for x in layout.lines] == [4, 3]
    five = layout.characters[3]
    assert five.parts == 2  # the 5's bar and its body are one character


def test_a_line_rotated_a_few_degrees_stays_one_line():
    ink, boxes = _page([[("1", 30), ("7", 100), ("0", 170), ("5", 240), ("7", 310), ("0", 380)],
                        [("5", 30), ("0", 120), ("1", 210), ("7", 300), ("0", 390)]],
                       angle_deg=4.0)  # fmt: skip
    assert abs(dominant_angle(ink > 0.5) - 4.0) < 1.0
    layout = find_characters(ink > 0.5)
    assert [len(x) for x in layout.lines] == [6, 5]
    assert _matches(layout, boxes)


def test_touching_characters_are_cut_apart():
    line = [("0", 40), ("7", 100), ("0", 160), ("0", 183), ("7", 260), ("0", 320)]
    ink, boxes = _page([line])
    mask = ink > 0.5
    labels = __import__("scipy.ndimage", fromlist=["label"]).label(mask, np.ones((3, 3)))[1]
    assert labels == 5  # the two zeros at 160 and 183 touch
    layout = find_characters(mask)
    assert len(layout.characters) == 6
    assert sum(c.split for c in layout.characters) == 2
    assert _matches(layout, boxes, tol=6.0)


def test_an_empty_mask_has_no_characters_and_a_bad_one_is_refused():
    assert find_characters(np.zeros((50, 60), bool)).characters == []
    with pytest.raises(ValueError, match="2-D"):
        find_characters(np.zeros((2, 3, 4), bool))
