"""A sheet photographed on a desk: are its characters found as on the sheet alone?

The two photos of ``--photos`` (``../shared/data/photos``: white paper with 14 digits,
yellow paper with 64 and two marks at its corner) are put on desks as a phone sees them
(made here with a fixed seed, nothing saved): flat grey desks of several levels, lighter
than the paper too, 56 px of desk on each side, slightly blurred; textured desks (grey,
brown, light grey; noise of 4 levels) under the sheet sharp or turned 4 degrees; the
sheet turned with its corners on the image's border (the rest a light grey, lighter than
the paper's shade); a desk on one side only; a window of a turned sheet on a desk, its
edge and a corner inside the frame. Then (:func:`near_shade`, a generator of its own so
that the desks above stay as they were) a light desk of nearly the white sheet's shade
(200, grain of 3 levels) with the sheet's shadow on it, as a phone sees a sheet lying on
a desk lit from the top left (the sheet's outline moved 5 px right and down, blurred,
darkening the desk by up to 30 %): the sheet turned 2 degrees, and seen in perspective
(its top edge 8 % shorter than its bottom). Each image is read by
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


def _homography(src, dst) -> np.ndarray:
    """The 3 x 3 map taking the four points ``src`` to ``dst`` (x, y)."""
    a, b = [], []
    for (x, y), (u, v) in zip(src, dst, strict=True):
        a += [[x, y, 1, 0, 0, 0, -u * x, -u * y], [0, 0, 0, x, y, 1, -v * x, -v * y]]
        b += [u, v]
    return np.append(np.linalg.solve(np.array(a, float), np.array(b, float)), 1.0).reshape(3, 3)


def _with_shadow(sheet_rgba, desk_rgb, x0, y0, rng):
    """``sheet_rgba`` (PIL RGBA) put at ``(x0, y0)`` on ``desk_rgb`` (grain of 3 levels
    added) with its shadow: its outline moved 5 px right and down, blurred (4 px), the desk
    there up to 30 % darker."""
    from PIL import Image, ImageFilter

    h, w = desk_rgb.shape[:2]
    alpha = Image.new("L", (w, h), 0)
    alpha.paste(sheet_rgba.getchannel("A"), (x0 + 5, y0 + 5))
    shade = np.asarray(alpha.filter(ImageFilter.GaussianBlur(4)), np.float64) / 255.0
    desk = (desk_rgb + rng.normal(0.0, 3.0, (h, w, 1))) * (1.0 - 0.3 * shade[..., None])
    im = Image.fromarray(np.clip(desk, 0, 255).astype(np.uint8))
    im.paste(sheet_rgba, (x0, y0), sheet_rgba)
    return im.filter(ImageFilter.GaussianBlur(0.8))


def near_shade(photo):
    """``(name, image, move)`` for the light desks with the sheet's shadow (module
    docstring), from a generator of their own."""
    from PIL import Image

    rng = np.random.default_rng(SEED + 1)
    w, h = photo.size
    out = []
    rgba = photo.convert("RGBA").rotate(2.0, resample=Image.Resampling.BICUBIC, expand=True)
    desk = np.full((h + 120, w + 130, 3), 200.0)
    x0, y0 = (desk.shape[1] - rgba.width) // 2, (desk.shape[0] - rgba.height) // 2
    a, cx, cy = math.radians(2.0), x0 + rgba.width / 2, y0 + rgba.height / 2

    def turned(x, y):
        dx, dy = x - w / 2, y - h / 2
        return (cx + math.cos(a) * dx + math.sin(a) * dy, cy - math.sin(a) * dx + math.cos(a) * dy)

    out.append(("light desk 200, the sheet's shadow, turned 2",
                _with_shadow(rgba, desk, x0, y0, rng), turned))  # fmt: skip
    corners = [(0, 0), (w, 0), (w, h), (0, h)]
    seen = [(0.04 * w, 0), (0.96 * w, 0), (w, h), (0, h)]  # the top edge farther away
    fwd = _homography(corners, seen)
    back = np.linalg.inv(fwd)
    warped = photo.convert("RGBA").transform(
        (w, h), Image.Transform.PERSPECTIVE, tuple((back / back[2, 2]).ravel()[:8]),
        resample=Image.Resampling.BICUBIC)  # fmt: skip
    desk = np.full((h + 120, w + 130, 3), 200.0)

    def seen_at(x, y):
        u, v, s = fwd @ (x, y, 1.0)
        return (u / s + 65, v / s + 60)

    out.append(("light desk 200, the sheet's shadow, in perspective",
                _with_shadow(warped, desk, 65, 60, rng), seen_at))  # fmt: skip
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
        for name, im, move in variants(photo, rng) + near_shade(photo):
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
    total = sum(r[2] for r in rows if r[1] != "as shipped")
    print(f"\nmatched {sum(r[4] for r in rows)} of {sum(r[2] for r in rows)}, "
          f"extra boxes {sum(r[5] for r in rows)} ({len(rows)} images, {time.time() - start:.0f} s;"
          f" {total} reference characters off the shipped photos)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
