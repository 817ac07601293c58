"""A sheet photographed on a desk: are its characters found as on the sheet alone?

The two photos of ``--photos`` (``../shared/data/photos``: white paper with 14 digits,
yellow paper with 64 and two marks at its corner) are put on desks as a phone sees them
(made here with a fixed seed, nothing saved): flat grey desks of several levels, lighter
than the paper too, 56 px of desk on each side, slightly blurred; textured desks (grey,
brown, light grey; noise of 4 levels) under the sheet sharp or turned 4 degrees; the
sheet turned with its corners on the image's border (the rest a light grey, lighter than
the paper's shade); a desk on one side only; a window of a turned sheet on a desk, its
edge and a corner inside the frame. Each image is read by
:func:`img2dmp.page.segment_page` (``predict --page``'s steps without a network), and its
boxes are compared with the boxes found on the photo as shipped (the reference), moved as
the photo was moved: *matched*, a reference character whose moved centre lies in exactly
one box found, which holds no other reference centre (two characters merged into one box
are neither matched); *extra*, a box that holds no reference centre (the desk, the
sheet's edge).

    python experiments/sheet_on_desk.py --photos ../shared/data/photos
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

SEED = 0


def _desk(size, colour, rng, noise=0.0) -> np.ndarray:
    h, w = size
    desk = np.empty((h, w, 3), np.float64)
    desk[...] = colour
    if noise:
        desk += rng.normal(0.0, noise, (h, w, 1))
    return desk


def _paste(photo, desk_rgb, angle=0.0, offset=(0, 0)):
    """``photo`` (PIL RGB) turned by ``angle`` degrees (counter-clockwise) about its centre
    and put with its centre at the desk's centre plus ``offset``; the image and the map of
    a photo point (x, y) into it."""
    from PIL import Image

    w, h = photo.size
    rgba = photo.convert("RGBA").rotate(angle, resample=Image.Resampling.BICUBIC, expand=True)
    desk = Image.fromarray(np.clip(desk_rgb, 0, 255).astype(np.uint8))
    x0 = (desk.width - rgba.width) // 2 + offset[0]
    y0 = (desk.height - rgba.height) // 2 + offset[1]
    desk.paste(rgba, (x0, y0), rgba)
    a = math.radians(angle)
    cx, cy = x0 + rgba.width / 2, y0 + rgba.height / 2

    def move(x, y):
        dx, dy = x - w / 2, y - h / 2
        return (cx + math.cos(a) * dx + math.sin(a) * dy, cy - math.sin(a) * dx + math.cos(a) * dy)

    return desk, move


def variants(photo, rng):
    """``(name, image, move)`` for every desk (module docstring)."""
    from PIL import ImageFilter

    w, h = photo.size
    out = [("as shipped", photo, lambda x, y: (x, y))]
    for grey in (40, 80, 120, 160, 190, 250):
        im, mv = _paste(photo, _desk((h + 112, w + 112), grey, rng))
        out.append((f"flat desk {grey}, blurred", im.filter(ImageFilter.GaussianBlur(1.0)), mv))
    for name, colour in (("grey", (120, 120, 125)), ("brown", (140, 100, 70)),
                         ("light grey", (205, 205, 205))):  # fmt: skip
        for angle in (0, 4):
            im, mv = _paste(photo, _desk((h + 110, w + 126), colour, rng, 4.0), angle)
            out.append((f"{name} desk, grain, turned {angle}", im, mv))
    for angle in (-5, 3, 10):
        frame = photo.rotate(angle, expand=True).size  # the turned sheet's corners on it
        im, mv = _paste(photo, _desk(frame[::-1], 240, rng), angle)
        out.append((f"turned {angle}, light corners", im, mv))
    im, mv = _paste(photo, _desk((h, w + 46), 122, rng, 3.0), 0, (23, 0))
    out.append(("desk on the left only", im, mv))
    big, mv = _paste(photo, _desk((h + 200, w + 200), 110, rng, 3.0), 6)
    x0, y0 = 60, 60  # a window: the sheet's top-left corner and two edges inside
    win = big.crop((x0, y0, x0 + w, y0 + h))
    out.append(
        ("window of a turned sheet", win, lambda x, y: tuple(np.subtract(mv(x, y), (x0, y0))))
    )
    return out


def score(boxes, centres):
    """``(matched, extra)``: reference centres in exactly one box that holds no other
    centre; boxes holding none."""
    inside = np.array([[b[0] <= x < b[2] and b[1] <= y < b[3] for b in boxes] for x, y in centres])
    if inside.size == 0:
        return 0, len(boxes)
    alone = inside[:, inside.sum(0) == 1]  # [references, boxes holding exactly one centre]
    matched = int(np.count_nonzero((inside.sum(1) == 1) & (alone.sum(1) == 1)))
    extra = int(np.count_nonzero(inside.sum(0) == 0))
    return matched, extra


def shipped_photos(folder):
    """``(file, RGB photo, reference centres)`` of the two photos in ``folder``: the
    centres of the boxes :func:`img2dmp.page.segment_page` finds on each as shipped.
    ``SystemExit`` naming a missing photo."""
    from PIL import Image

    from img2dmp.page import segment_page

    out = []
    for file in ("page_white_black_ink.png", "page_yellow_blue_ink.png"):
        path = Path(folder) / file
        if not path.exists():
            sys.exit(f"no {path}: --photos names the folder of the two photos")
        photo = Image.open(path).convert("RGB")
        ref = segment_page(photo)
        centres = [((b[0] + b[2]) / 2, (b[1] + b[3]) / 2)
                   for b in (ref.box_in_image(c) for c in ref.layout.characters)]  # fmt: skip
        out.append((file, photo, centres))
    return out


def main(argv=None) -> int:
    from img2dmp.page import segment_page

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--photos", default="../shared/data/photos")
    args = p.parse_args(argv)
    rng = np.random.default_rng(SEED)
    rows, start = [], time.time()
    for file, photo, ref_centres in shipped_photos(args.photos):
        for name, im, move in variants(photo, rng):
            seg = segment_page(im)
            boxes = [seg.box_in_image(c) for c in seg.layout.characters]
            matched, extra = score(boxes, [move(x, y) for x, y in ref_centres])
            desk = 0 if seg.ink is None else seg.ink.removed.get("desk_px", 0)
            rows.append((file.split("_")[1], name, len(ref_centres), len(boxes), matched, extra,
                         desk > 0))  # fmt: skip
    print("| photo | desk | reference | boxes | matched | extra | sheet found |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(str(v) for v in r) + " |")
    total = sum(r[2] for r in rows[1:])
    print(f"\nmatched {sum(r[4] for r in rows)} of {sum(r[2] for r in rows)}, "
          f"extra boxes {sum(r[5] for r in rows)} ({len(rows)} images, {time.time() - start:.0f} s;"
          f" {total} reference characters off the shipped photos)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
