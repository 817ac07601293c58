"""A page photographed askew: are its characters found, in the right lines, at any tilt?

The two photos of ``--photos`` (``../shared/data/photos``: white paper with 14 digits in
two lines, yellow paper with 64 in three and two marks at its corner) are turned by each
angle of ``--angles`` (degrees, counter-clockwise as the eye sees it) about their centre
and put on a desk as a phone sees a sheet lying askew (:func:`sheet_on_desk._paste`: a
grey desk with grain, 110, ``--margin`` px (56) or more around the sheet; and, for
``--light``, a light grey one, 240, lighter than the paper; ``--margin 0``: the frame
just holds the turned photo, the desk shows in its corners only, as when the sheet
fills the phone's view). Each image is read by
:func:`img2dmp.page.segment_page` (``predict --page``'s steps without a network):

- *matched* / *extra*: as in ``sheet_on_desk.py``, the boxes against those found on the
  photo as shipped, moved as the photo was turned (a reference centre in exactly one
  box that holds no other; a box that holds none), in the pixels of the page as read
  (turned level when it was: there a tilted character's box holds none of its
  neighbours);
- *miscounted*: the characters found per line against the digits the photo's
  ``photos.json`` writes out per line (:func:`page_reading.miscounted`: characters too
  many or too few, lines aligned in order); a line broken in two, or two lines taken as
  one, count here;
- *turned*: the angle :func:`segment_page` turned the page by (0: read as it stands).

``--ruled PITCH`` prints pale blue rules (1 px, ``PITCH`` px apart) under the ink first,
as ruled paper is (``lines_on_photos.py``'s "under"); with ``--squared`` both ways.

``--model NAME`` reads every image with that model as ``predict --page`` does instead
(a page whose characters line up in columns is also read turned a quarter each way, and
the reading that flags fewest kept): the measures above are that page's, and the
characters flagged (any flag) are counted.

    python experiments/tilted_pages.py --photos ../shared/data/photos [--model digits-real]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from lines_on_photos import BLUE, _coverage, _lines
from page_reading import miscounted
from sheet_on_desk import SEED, _desk, _paste, score, shipped_photos

ANGLES = (-25, -20, -15, -10, -8, -6, -3, 0, 3, 6, 8, 10, 15, 20, 25)


def true_lines(folder: Path) -> dict[str, list[int]]:
    """Digits per line of each photo of ``photos.json``."""
    doc = json.loads((Path(folder) / "photos.json").read_text())
    return {p["file"]: [len(line.replace(" ", "")) for line in p["lines"]] for p in doc["photos"]}


def _as_read(seg, x: float, y: float) -> tuple[float, float]:
    """A photo point (pixel edges) in the pixels of the page as read (turned level when
    it was; only the part that holds the writing when a large photo was read finer, from
    ``origin``): the boxes there are level, so a tilted character's box holds no
    neighbour."""
    turn = getattr(seg, "turn", np.eye(3))
    ox, oy = getattr(seg, "origin", (0.0, 0.0))
    u, v, _ = turn @ ((x - ox) / seg.reduction, (y - oy) / seg.reduction, 1.0)
    return u, v


def main(argv=None) -> int:
    from img2dmp.page import segment_page

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--photos", default="../shared/data/photos")
    p.add_argument("--angles", default=",".join(str(a) for a in ANGLES))
    p.add_argument("--light", action="store_true", help="also on a light desk (240)")
    p.add_argument("--model", default=None, help="also read with this model; count flags")
    p.add_argument(
        "--ruled",
        type=float,
        default=0.0,
        metavar="PITCH",
        help="print blue rules PITCH px apart under the ink first (ruled paper)",
    )
    p.add_argument(
        "--squared",
        action="store_true",
        help="with --ruled: lines both ways (squared paper of PITCH px squares)",
    )
    p.add_argument(
        "--margin",
        type=int,
        default=56,
        metavar="PX",
        help="desk around the turned photo's frame (px; default 56; 0: the desk in the "
        "corners only, the sheet filling the view)",
    )
    p.add_argument("--save", metavar="DIR", help="also write every image read, as PNG")
    args = p.parse_args(argv)
    if args.margin < 0:
        p.error(f"--margin {args.margin}: give 0 or more pixels")
    angles = [float(a) for a in args.angles.split(",")]
    model = None
    if args.model:
        from img2dmp import load_model

        model = load_model(args.model)
    truth = true_lines(Path(args.photos))
    rng = np.random.default_rng(SEED)
    rows, start = [], time.time()
    desks = [("grey 110", (110, 110, 110), 3.0)] + ([("light 240", (240,) * 3, 0.0)]
                                                    if args.light else [])  # fmt: skip
    for file, photo, ref in shipped_photos(args.photos):
        if args.ruled:
            from PIL import Image

            rgb = np.asarray(photo, np.float64)
            cover = _coverage(rgb.shape[:2], args.ruled, 1.0, 0.0, 3.0, 0)
            if args.squared:
                cover = np.maximum(cover, _coverage(rgb.shape[:2], args.ruled, 1.0, 0.0, 3.0, 1))
            ruled = np.clip(_lines(rgb, cover, BLUE, True), 0, 255)
            photo = Image.fromarray(ruled.astype(np.uint8))
        for desk_name, colour, grain in desks:
            for angle in angles:
                w, h = np.add(photo.rotate(angle, expand=True).size, 2 * args.margin)
                im, move = _paste(photo, _desk((h, w), colour, rng, grain), angle)
                if args.save:
                    Path(args.save).mkdir(parents=True, exist_ok=True)
                    im.save(Path(args.save) / f"{file.split('_')[1]}_{desk_name.split()[0]}_"
                            f"{angle:g}.png")  # fmt: skip
                # with a model, its page (read turned a quarter where that flags fewer)
                seg = segment_page(im) if model is None else model.predict_page(im)
                boxes = [c.box for c in seg.layout.characters]
                matched, extra = score(boxes, [_as_read(seg, *move(x, y)) for x, y in ref])
                lines = [len(idx) for idx in seg.layout.lines]
                turned = getattr(seg, "turn_deg", 0.0)  # 0 before pages were turned level
                row = [file.split("_")[1], desk_name, f"{angle:g}", f"{turned:.1f}", len(ref),
                       len(boxes), matched, extra, miscounted(truth[file], lines)]  # fmt: skip
                if model is not None:
                    row.append(len(seg.flagged))
                rows.append(row)
    head = ["photo", "desk", "angle", "turned", "reference", "boxes", "matched", "extra",
            "miscounted"] + (["flagged"] if model is not None else [])  # fmt: skip
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for r in rows:
        print("| " + " | ".join(str(v) for v in r) + " |")
    tilted = [r for r in rows if abs(float(r[2])) > 6]
    for name, part in (("all", rows), ("tilted more than 6 degrees", tilted)):
        if not part:
            continue
        text = (
            f"{name}: matched {sum(r[6] for r in part)} of {sum(r[4] for r in part)}, "
            f"extra {sum(r[7] for r in part)}, miscounted {sum(r[8] for r in part)}"
        )
        if model is not None:
            text += f", flagged {sum(r[9] for r in part)} of {sum(r[5] for r in part)}"
        print(f"{text} ({len(part)} images)")
    print(f"({time.time() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
