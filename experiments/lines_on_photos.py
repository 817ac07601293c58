"""Paper's lines on real photos: are the characters found as on the photo alone?

The two photos of ``--photos`` (``../shared/data/photos``: white paper with 14 digits,
yellow paper with 64 and two marks at its corner) get the lines of ruled and squared
paper (made here, nothing saved; the anti-aliased lines' phase drawn with a fixed seed):
*drawn over* the photo (the line's colour replaces the pixel, ink included, as an
editor draws them) and *under* it (the photo multiplied by the lines, as printed paper
is: ink over a line stays ink), at several pitches, colours and widths, level or turned
a little (1 degree), with a margin line across the rules. Each image is read by
:func:`img2dmp.page.segment_page` (``predict --page``'s steps without a network) and its
boxes are compared with the boxes found on the photo as shipped (the reference) by
:func:`sheet_on_desk.score`: *matched*, a reference character whose centre lies in
exactly one box found, which holds no other reference centre; *extra*, a box that holds
no reference centre (a piece of a line, or of a character split at a rule).

Then each photo as a *legal pad* (:func:`legal_pads`, phases from a generator of their
own so the variants above stay as they were): the photo multiplied by a legal pad's
yellow, pale blue rules and a double red margin printed under the ink, saved as a PNG or,
as a phone saves it, a JPEG (4:2:0 chroma subsampling: the blue channel of yellow paper is
dim, and its JPEG noise is several times the other channels' against it).

    python experiments/lines_on_photos.py --photos ../shared/data/photos [--save DIR]

``--save DIR`` also writes every image read as a PNG, named after its photo and paper
(``DIR/yellow_legal_pad_24.png``; a JPEG variant as it was decoded): to time
``img2dmp predict IMAGE --page`` on one, or to look at it with ``--explain``.
"""

from __future__ import annotations

import argparse
import io
import math
import sys
import time
from pathlib import Path

import numpy as np

from sheet_on_desk import score, shipped_photos

SEED = 0
BLUE, GREY, RED = (150, 170, 220), (160, 160, 200), (220, 80, 80)
#: A legal pad's paper and its pale blue rules (RGB on white).
LEGAL_YELLOW, LEGAL_BLUE = (252, 238, 150), (140, 180, 230)


def _coverage(shape, pitch: float, width: float, angle_deg: float, phase: float, axis: int):
    """The share of every pixel ``[H, W]`` covered by lines ``width`` pixels thick every
    ``pitch`` pixels, across ``axis`` (0: rows, lines along the rows), turned by
    ``angle_deg``: the overlap of the pixel's span with the nearest line's."""
    rows, cols = np.mgrid[: shape[0], : shape[1]].astype(np.float64)
    t = math.tan(math.radians(angle_deg))
    pos = rows - cols * t if axis == 0 else cols + rows * t
    d = np.abs((pos - phase + pitch / 2) % pitch - pitch / 2)  # to the nearest line's middle
    return np.clip(np.minimum(d + 0.5, width / 2) - np.maximum(d - 0.5, -width / 2), 0.0, 1.0)


def _lines(photo: np.ndarray, cover: np.ndarray, colour, under: bool) -> np.ndarray:
    """``photo`` (float RGB [H, W, 3]) with lines of ``colour`` where ``cover`` [H, W]:
    multiplied under the ink (``under``) or drawn over it."""
    c = np.asarray(colour, np.float64)
    k = cover[..., None]
    if under:
        return photo * (1.0 - k * (1.0 - c / 255.0))
    return photo * (1.0 - k) + c * k


def variants(photo: np.ndarray, rng):
    """``(name, image)`` for every kind of paper (module docstring)."""
    shape = photo.shape[:2]
    kinds = [  # name, pitches (rows, columns; 0 none), width, colour, angle, margin
        ("ruled 28, blue", (28, 0), 1.0, BLUE, 0.0, False),
        ("ruled 28, blue, margin", (28, 0), 1.0, BLUE, 0.0, True),
        ("ruled 20, grey, 2 px", (20, 0), 2.0, GREY, 0.0, False),
        ("ruled 36, blue, turned 1", (36, 0), 1.0, BLUE, 1.0, False),
        ("squared 15, grey", (15, 15), 1.0, GREY, 0.0, False),
        ("squared 22, blue", (22, 22), 1.0, BLUE, 0.0, False),
        ("squared 30, grey, 2 px, turned 1", (30, 30), 2.0, GREY, 1.0, False),
    ]
    out = [("as shipped", photo)]
    for name, (p_rows, p_cols), width, colour, angle, margin in kinds:
        cover = np.zeros(shape)
        for axis, pitch in ((0, p_rows), (1, p_cols)):
            if pitch:
                phase = float(rng.uniform(0, pitch))
                cover = np.maximum(cover, _coverage(shape, pitch, width, angle, phase, axis))
        for under in (False, True):
            im = _lines(photo, cover, colour, under)
            if margin:  # a red line across the rules, 40 px from the left
                line = _coverage(shape, 10 * shape[1], 2.0, 0.0, 40.0, 1)
                im = _lines(im, line, RED, under)
            out.append((f"{name}, {'under' if under else 'over'}", im))
    return out


def legal_pads(photo: np.ndarray, rng):
    """``(name, image)``: ``photo`` (float RGB [H, W, 3]) on a legal pad (module
    docstring): multiplied by ``LEGAL_YELLOW``, 1-px ``LEGAL_BLUE`` rules and two red
    margin lines 4 px apart from column 60, all under the ink; as a PNG or a JPEG."""
    from PIL import Image

    shape = photo.shape[:2]
    kinds = [  # name, pitch, angle, JPEG quality (0: none)
        ("legal pad 24", 24, 0.0, 0),
        ("legal pad 24, JPEG 85", 24, 0.0, 85),
        ("legal pad 20, turned 1, JPEG 75", 20, 1.0, 75),
    ]
    out = []
    for name, pitch, angle, quality in kinds:
        im = photo * (np.asarray(LEGAL_YELLOW, np.float64) / 255.0)
        phase = float(rng.uniform(0, pitch))
        im = _lines(im, _coverage(shape, pitch, 1.0, angle, phase, 0), LEGAL_BLUE, True)
        for x in (60.0, 64.0):
            im = _lines(im, _coverage(shape, 10 * shape[1], 1.0, 0.0, x, 1), RED, True)
        if quality:
            buf = io.BytesIO()
            Image.fromarray(np.clip(np.round(im), 0, 255).astype(np.uint8)).save(
                buf, "JPEG", quality=quality
            )
            buf.seek(0)
            im = np.asarray(Image.open(buf).convert("RGB"), np.float64)
        out.append((name, im))
    return out


def main(argv=None) -> int:
    from PIL import Image

    from img2dmp.page import segment_page

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--photos", default="../shared/data/photos")
    p.add_argument("--save", metavar="DIR", help="also write every image read, as PNG")
    args = p.parse_args(argv)
    if args.save:
        Path(args.save).mkdir(parents=True, exist_ok=True)
    rng, legal_rng = np.random.default_rng(SEED), np.random.default_rng(SEED + 1)
    rows, start = [], time.time()
    for file, photo, centres in shipped_photos(args.photos):
        photo = np.asarray(photo, np.float64)
        for name, im in variants(photo, rng) + legal_pads(photo, legal_rng):
            image = Image.fromarray(np.clip(np.round(im), 0, 255).astype(np.uint8))
            if args.save:
                stem = "_".join([file.split("_")[1], *name.replace(",", "").split()])
                image.save(Path(args.save) / f"{stem}.png")
            seg = segment_page(image)
            boxes = [seg.box_in_image(c) for c in seg.layout.characters]
            matched, extra = score(boxes, centres)
            rows.append((file.split("_")[1], name, len(centres), len(boxes), matched, extra))
    print("| photo | paper | reference | boxes | matched | extra |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(str(v) for v in r) + " |")
    print()
    groups = [("lines under the ink", lambda r: r[1].endswith("under")),
              ("lines drawn over the ink", lambda r: r[1].endswith("over")),
              ("legal pads", lambda r: r[1].startswith("legal pad"))]  # fmt: skip
    for group, keep in groups:
        for photo in ("white", "yellow"):
            sel = [r for r in rows if r[0] == photo and keep(r)]
            print(f"{group}, {photo}: matched {sum(r[4] for r in sel)} of "
                  f"{sum(r[2] for r in sel)}, extra boxes {sum(r[5] for r in sel)}")  # fmt: skip
    lined = [r for r in rows if r[1] != "as shipped"]
    print(f"lined pages: matched {sum(r[4] for r in lined)} of {sum(r[2] for r in lined)}, "
          f"extra boxes {sum(r[5] for r in lined)} ({len(rows)} images, "
          f"{time.time() - start:.0f} s)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
