"""The sample images in ``examples/samples/``, drawn by img2dmp itself (no MNIST, no
recorded paths): what the README's commands and the tutorial read.

- ``digit_3.png``: a 3 from the synthetic generator's template (its random variation and
  minimum-jerk timing), rendered with our own pen (``img2dmp.data.render.render_paths``)
  as dark ink on white, 160 x 160 pixels.
- ``digit_5_photo.jpg``: a 5 of the same kind written in blue on a generated photo of
  tinted ruled paper, unevenly lit, blurred, noisy, saved as JPEG
  (``img2dmp.data.clutter``: ``random_paper``, ``put_ink``, ``photo_finish``).
- ``page.jpg``: a generated photo of a page with two lines of synthetic digits on
  squared paper (``img2dmp.data.clutter.generate_page``), for ``predict --page``.
- ``character_f.png``: an "F" of three strokes (the bar down, the top bar, the middle
  bar), each a minimum-jerk line bent a little at random, as dark ink on white, 160 x 160
  pixels: for a stroke model (``--model omniglot-strokes``).
- ``letters_page.png``: two lines of capitals (A H T X, L E K V) drawn stroke by stroke
  with the same pen, for a stroke model's page (``predict --page --model
  omniglot-strokes``).

Every draw comes from one seeded generator, so the same versions of img2dmp and its
packages give the same images. Run from the repository's root:

    python examples/make_samples.py               # writes examples/samples/
    python examples/make_samples.py --out DIR     # elsewhere
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from img2dmp.data.clutter import (
    PageOptions,
    PaperOptions,
    generate_page,
    page_sources_from_synthetic,
    photo_finish,
    put_ink,
    random_paper,
)
from img2dmp.data.render import render_paths
from img2dmp.data.synthetic import SyntheticConfig, sample_unit_paths

HERE = Path(__file__).resolve().parent
SEED = 2026


def drawn_digit(rng, digit: int, size: int, pen_px: float, margin: float = 0.15) -> np.ndarray:
    """Ink ``float32 [size, size]`` (ink = 1) of one synthetic ``digit`` filling the
    image but for ``margin`` on each side."""
    path = sample_unit_paths(digit, 1, SyntheticConfig(), rng)[0]  # [T, 2], y down
    lo, hi = path.min(0), path.max(0)
    scale = (1 - 2 * margin) * size / float(max(hi - lo))
    xy = (path - (lo + hi) / 2) * scale + (size - 1) / 2
    return render_paths(xy[None], (size, size), pen_width_px=pen_px)[0].numpy()


def digit_on_white(rng) -> Image.Image:
    ink = drawn_digit(rng, 3, 160, pen_px=9.0)
    return Image.fromarray(np.round(255 * (1 - ink)).astype(np.uint8))


def digit_photo(rng) -> Image.Image:
    size = (200, 200)
    options = PaperOptions(tints=("cream",), spacing_px=(34.0, 34.0), margin_probability=0.0)
    paper = random_paper(rng, size, "ruled", options=options)
    ink = drawn_digit(rng, 5, size[0], pen_px=7.0, margin=0.22)
    scene = put_ink(paper.rgb, ink, (0.1, 0.15, 0.55), opacity=0.95)
    return Image.fromarray(photo_finish(rng, scene, jpeg_quality=85, blur_px=0.6, noise=0.01))


def page_photo(rng) -> Image.Image:
    digits = page_sources_from_synthetic(rng, 8)
    options = PageOptions(n_lines=(2, 2), char_height_px=(60.0, 60.0), word_length=(4, 4))
    page = generate_page(rng, digits, kind="squared", options=options, pen_width_px=4.0)
    return Image.fromarray(page.image)


#: The "F": each stroke from its first to its last point (pixels of the 160-px image).
F_STROKES = (((50, 30), (50, 130)), ((50, 30), (115, 30)), ((50, 80), (100, 80)))


def drawn_stroke(rng, a, b, n: int = 40, bend_px: float = 1.5) -> np.ndarray:
    """A pen's stroke ``[n, 2]`` from ``a`` to ``b``: minimum-jerk progress along the line,
    bowed sideways by a random few pixels at its middle."""
    f = np.linspace(0.0, 1.0, n)[:, None]
    progress = 10 * f**3 - 15 * f**4 + 6 * f**5
    line = (1 - progress) * np.asarray(a, float) + progress * np.asarray(b, float)
    return line + np.sin(np.pi * f) * rng.normal(0.0, bend_px, 2)


def character_on_white(rng, size: int = 160, pen_px: float = 9.0) -> Image.Image:
    ink = np.zeros((size, size), np.float32)
    for a, b in F_STROKES:
        xy = drawn_stroke(rng, a, b)
        ink = np.maximum(ink, render_paths(xy[None], (size, size), pen_width_px=pen_px)[0].numpy())
    return Image.fromarray(np.round(255 * (1 - ink)).astype(np.uint8))


#: Capital letters as their strokes, each from its first to its last point, in a unit box
#: (x right, y down), in a common writing order.
LETTER_STROKES = {
    "A": (((0.0, 1.0), (0.5, 0.0)), ((0.5, 0.0), (1.0, 1.0)), ((0.22, 0.6), (0.78, 0.6))),
    "H": (((0.0, 0.0), (0.0, 1.0)), ((1.0, 0.0), (1.0, 1.0)), ((0.0, 0.5), (1.0, 0.5))),
    "T": (((0.0, 0.0), (1.0, 0.0)), ((0.5, 0.0), (0.5, 1.0))),
    "X": (((0.0, 0.0), (1.0, 1.0)), ((1.0, 0.0), (0.0, 1.0))),
    "L": (((0.0, 0.0), (0.0, 1.0), (0.8, 1.0)),),
    "E": (((0.0, 0.0), (0.0, 1.0)), ((0.0, 0.0), (0.8, 0.0)), ((0.0, 0.5), (0.65, 0.5)),
          ((0.0, 1.0), (0.8, 1.0))),
    "K": (((0.0, 0.0), (0.0, 1.0)), ((0.9, 0.0), (0.0, 0.55)), ((0.3, 0.4), (0.95, 1.0))),
    "V": (((0.0, 0.0), (0.5, 1.0), (1.0, 0.0)),),
}  # fmt: skip
#: The letters page: two lines.
LETTER_LINES = ("AHTX", "LEKV")


def letters_page(rng, height_px: float = 70.0, pen_px: float = 6.0) -> Image.Image:
    """Two lines of capitals (:data:`LETTER_LINES`), each stroke a pen's minimum-jerk
    line through its corners with a small random bend, on white paper."""
    width_px, gap_px, margin = 0.7 * height_px, 0.6 * height_px, 40
    size = (margin * 2 + int(2 * height_px + gap_px),
            margin * 2 + int(4 * width_px + 3 * gap_px))  # fmt: skip
    ink = np.zeros(size, np.float32)
    for r, line in enumerate(LETTER_LINES):
        for c, letter in enumerate(line):
            x0 = margin + c * (width_px + gap_px) + rng.uniform(-4, 4)
            y0 = margin + r * (height_px + gap_px) + rng.uniform(-4, 4)
            scale = np.array([width_px, height_px]) * rng.uniform(0.9, 1.1)
            for stroke in LETTER_STROKES[letter]:
                corners = np.asarray(stroke) * scale + (x0, y0)
                xy = np.concatenate(
                    [
                        drawn_stroke(rng, a, b, n=30)
                        for a, b in zip(corners[:-1], corners[1:], strict=True)
                    ]
                )
                path = render_paths(xy[None], size, pen_width_px=pen_px)[0].numpy()
                ink = np.maximum(ink, path)
    return Image.fromarray(np.round(255 * (1 - ink)).astype(np.uint8))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=HERE / "samples", help="output folder")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(SEED)
    images = {
        "digit_3.png": digit_on_white(rng),
        "digit_5_photo.jpg": digit_photo(rng),
        "page.jpg": page_photo(rng),
        "character_f.png": character_on_white(rng),
        "letters_page.png": letters_page(rng),
    }
    for name, image in images.items():
        path = args.out / name
        image.save(path, quality=90) if path.suffix == ".jpg" else image.save(path)
        print(f"{path}: {image.width} x {image.height}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
