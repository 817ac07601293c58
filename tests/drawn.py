"""Pages drawn with known strokes, for the tests of page reading (no data needed)."""

from __future__ import annotations

import math

import numpy as np

from img2dmp.data.render import render_paths


def stroke(points, n: int = 60) -> np.ndarray:
    """A polyline through ``points`` resampled to ``n`` points ``[n, 2]``."""
    p = np.asarray(points, float)
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    s = np.concatenate([[0], np.cumsum(seg)])
    u = np.linspace(0, s[-1], n)
    return np.stack([np.interp(u, s, p[:, 0]), np.interp(u, s, p[:, 1])], -1)


def ellipse(cx, cy, rx, ry, n: int = 80) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n)
    return np.stack([cx + rx * np.cos(t), cy + ry * np.sin(t)], -1)


def ink(size, strokes, width: float = 3.0) -> np.ndarray:
    """The ink [H, W] of several strokes."""
    out = np.zeros(size, np.float32)
    for s in strokes:
        out = np.maximum(out, render_paths(np.asarray(s, np.float32), size, width).numpy())
    return out


def on_paper(ink, paper, colour=(0.05, 0.05, 0.1)) -> np.ndarray:
    """RGB [H, W, 3]: the ink absorbing light on the paper."""
    c = np.asarray(colour, np.float32)
    return paper * (1.0 - ink[..., None] * (1.0 - c))


def ruled(size, spacing: float, angle_deg: float = 0.0, vertical: bool = False,
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


def page(lines, height=40.0, angle_deg=0.0, size=(300, 520)):
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
            if shapes[kind] == "ellipse":
                parts = [ellipse(x + w / 2, y + height / 2, w / 2, height / 2)]
            else:
                parts = [stroke([(x + u * w, y + v * height) for u, v in s]) for s in shapes[kind]]
            strokes += parts
            pts = np.concatenate(parts)
            boxes.append((pts[:, 0].min(), pts[:, 1].min(), pts[:, 0].max(), pts[:, 1].max()))
    return ink(size, strokes), boxes


def grainy_page(light=None, seed=0):
    """The two lines of :func:`page` on grey paper with a grain (5 % noise, smoothed
    over a pixel, as a sheet's fibres and a phone's noise), enlarged to 450 x 780 (read
    with cells), times ``light`` (``[H, W]``) when given; the image and the true boxes'
    centres."""
    from PIL import Image
    from scipy.ndimage import gaussian_filter

    lines = [[("1", 40), ("7", 110), ("0", 190), ("5", 270), ("7", 350)],
             [("0", 60), ("5", 150), ("7", 240), ("1", 330)]]  # fmt: skip
    ink, boxes = page(lines)
    im = Image.fromarray((ink * 255).astype(np.uint8)).resize((780, 450), Image.Resampling.BICUBIC)
    ink = np.asarray(im, np.float32) / 255.0
    grain = gaussian_filter(np.random.default_rng(seed).normal(0.0, 0.05, ink.shape), 0.7)
    paper = (0.78 * (1.0 + grain))[..., None] * np.array([1.0, 0.98, 0.94])
    img = on_paper(ink, paper.astype(np.float32))
    if light is not None:
        img = img * light[..., None]
    centres = [(0.75 * (b[0] + b[2]), 0.75 * (b[1] + b[3])) for b in boxes]
    return np.clip(img, 0.0, 1.0).astype(np.float32), centres


def moved(img, length: float, degrees: float):
    """``img`` as a camera moving ``length`` px at ``degrees`` (from the rows, down the
    image positive) sees it: the mean of copies shifted every tenth of a pixel along the
    line (bilinear), not :func:`img2dmp.data.shake.line`'s drawing of it."""
    from scipy.ndimage import shift

    theta = np.deg2rad(degrees)
    steps = np.linspace(-length / 2, length / 2, round(10 * length) + 1)
    offsets = [(t * np.sin(theta), t * np.cos(theta)) + (0.0,) * (img.ndim - 2) for t in steps]
    copies = [shift(img, o, order=1, mode="nearest") for o in offsets]
    return np.mean(copies, axis=0).astype(np.float32)


def glare(img, strength: float, at=(0.55, 0.45), radius=0.3):
    """``img`` brought towards white by ``strength`` at the centre of a Gaussian spot
    (``at``: its centre as shares of the width and height; ``radius``: its sigma as a
    share of the shorter side)."""
    h, w = img.shape[:2]
    rows, cols = np.mgrid[:h, :w].astype(np.float32)
    r = radius * min(h, w)
    spot = strength * np.exp(-((cols - at[0] * w) ** 2 + (rows - at[1] * h) ** 2) / (2 * r * r))
    return (img * (1.0 - spot[..., None]) + spot[..., None]).astype(np.float32)
