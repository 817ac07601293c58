"""A page of Omniglot characters read by a stroke model (RESULTS 8.5, 8.6).

Puts ``--n`` characters drawn by one drawer (``--drawer``, the ``_NN`` of the image's
file name; 18-20 are the test drawers of ``make model-omniglot``) on a white page, as
they are in Omniglot's images (105 x 105, in cells of 130 px, rows of ``--per-line``),
reads the page with ``--model`` as ``img2dmp predict PAGE --page`` does, and prints how
many characters were found (each assigned to the placed character whose ink box holds
most of its box; one holding most of two placed characters' boxes joined them; a
character of pieces side by side may be found as several), and of those found as one
character how many were read with the stroke count their drawer drew (from the stroke
files, :func:`img2dmp.data.sources.omniglot.parse_strokes`) and the path's fit to the
ink. ``--paper ruled`` (plain, squared, dotted) writes the ink on generated paper and
photographs it first. Writes the page, its document and its picture into ``--out``.
``--cut yes|no`` reads the page with or without the digits' cutting of wide marks (the
choice of :data:`img2dmp.page.STROKE_PAGE_CUT`); ``--join yes|no`` with or without
joining neighbours of pieces side by side (:data:`img2dmp.page.STROKE_PAGE_JOIN`,
``--side-gap`` for :data:`img2dmp.data.pages.SIDE_GAP`, ``--side-width`` for
:data:`~img2dmp.data.pages.SIDE_WIDTH`). ``--gap G`` places the
characters ``G`` character heights apart, ink to ink, as handwriting spaces them,
instead of in cells.

Run from the repository's root::

    python experiments/stroke_page.py --omniglot ../shared/data/omniglot --out stroke_page

It prints the date, the git revision and its command line first. A few seconds.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import sys
import zipfile
from pathlib import Path

import numpy as np
from PIL import Image

from img2dmp.data.clutter import KINDS, PaperOptions, photo_finish, put_ink, random_paper
from img2dmp.data.sources.omniglot import parse_strokes
from img2dmp.predict import load_model

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record

#: The page's cell around each character, pixels (Omniglot's images are 105 x 105).
CELL = 130


def _members(path: Path) -> dict:
    """Every file of an archive or a folder: its name (the folder's own name first, as
    in Omniglot's zips) -> a function that reads its bytes."""
    if path.is_dir():
        return {p.relative_to(path.parent).as_posix(): p.read_bytes
                for p in sorted(path.rglob("*")) if p.is_file()}  # fmt: skip
    z = zipfile.ZipFile(path)
    return {n: (lambda n=n: z.read(n)) for n in z.namelist()}


def characters(root: Path, drawer: int) -> list[tuple[str, np.ndarray, int]]:
    """Every character of ``drawer`` under ``root`` (Omniglot's ``images_*`` and
    ``strokes_*``, zipped or unzipped): (``alphabet/character``, its image (ink dark),
    its drawer's stroke count)."""
    images = sorted(p for p in root.glob("images_*") if p.is_dir() or p.suffix == ".zip")
    if not images:
        raise SystemExit(f"{root}: no images_* archive or folder (Omniglot, as it unzips)")
    found = []
    for archive in images:
        partner = archive.with_name(archive.name.replace("images_", "strokes_", 1))
        if not partner.exists():
            raise SystemExit(f"{archive}: no {partner.name} beside it")
        pictures, texts = _members(archive), _members(partner)
        strokes = {Path(n).stem: n for n in texts if n.endswith(".txt")}
        for name in pictures:
            m = re.search(r"([^/]+)/([^/]+)/([^/]+)_(\d+)\.png$", name)
            if not m or "__MACOSX" in name or int(m.group(4)) != drawer:
                continue
            stem = Path(name).stem
            if stem not in strokes:
                continue
            pen = parse_strokes(texts[strokes[stem]]().decode(), strokes[stem])
            image = np.asarray(Image.open(io.BytesIO(pictures[name]())).convert("L"))
            found.append((f"{m.group(1)}/{m.group(2)}", image, len(np.unique(pen.stroke))))
    return found


def on_paper(rng, page: np.ndarray, kind: str) -> np.ndarray:
    """The white page's ink (dark) written in blue on generated paper of ``kind`` with a
    rule or grid about as far apart as a character is tall, then photographed (blur,
    noise, JPEG): uint8 ``[H, W, 3]``."""
    ink = 1.0 - page.astype(np.float32) / 255.0
    options = PaperOptions(spacing_px=(0.5 * CELL, 0.7 * CELL), margin_probability=0.0)
    paper = random_paper(rng, page.shape, kind, options=options)
    scene = put_ink(paper.rgb, ink, (0.1, 0.15, 0.55), opacity=0.95)
    return photo_finish(rng, scene, jpeg_quality=85, blur_px=0.6, noise=0.01)


def _ink_box(image: np.ndarray) -> tuple[int, int, int, int]:
    rows, cols = np.nonzero(image < 128)
    if rows.size == 0:
        return 0, 0, image.shape[1], image.shape[0]
    return int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1


def layout(chosen, per_line: int, gap: float | None):
    """The white page (uint8, ink dark) of the ``chosen`` characters in rows of
    ``per_line``, and each character's ink box on it ``(x0, y0, x1, y1)``.

    ``gap`` None: each image in a cell of :data:`CELL` px (the characters about a
    character's width apart); else each character's ink ``gap`` times the median ink
    height after the previous one's along its line (handwriting's spacing), the ink of a
    line on one middle row, lines :data:`CELL` px apart."""
    ink = [_ink_box(image) for _, image, _ in chosen]
    lines = -(-len(chosen) // per_line)
    height = float(np.median([b[3] - b[1] for b in ink]))
    if gap is None:
        width = per_line * CELL + 40
    else:
        rows = [ink[i : i + per_line] for i in range(0, len(ink), per_line)]
        longest = max(sum(b[2] - b[0] for b in r) + gap * height * (len(r) - 1) for r in rows)
        width = int(longest) + 2 * CELL  # an image's white beyond its ink on either end
    page = np.full((lines * CELL + 40, width), 255, np.uint8)
    boxes, x = [], float(CELL)
    for k, (name, image, _) in enumerate(chosen):
        h, w = image.shape
        if max(h, w) > CELL - 10:
            raise SystemExit(f"{name}: an image of {w} x {h} px does not fit a {CELL}-px cell")
        r, c = divmod(k, per_line)
        x0, y0, x1, y1 = ink[k]
        if gap is None:
            top, left = 20 + r * CELL, 20 + c * CELL
        else:
            x = float(CELL) if c == 0 else x
            top = int(20 + r * CELL + (CELL - 10) / 2 - (y0 + y1) / 2)
            left = int(round(x)) - x0
            x += (x1 - x0) + gap * height
        # the ink is written over the page (a neighbour's white margin hides nothing)
        view = page[top : top + h, left : left + w]
        np.minimum(view, image, out=view)
        boxes.append((left + x0, top + y0, left + x1, top + y1))
    return page, boxes


def match(found, boxes):
    """Which placed character each character found is: the one whose ink box holds most
    of its box (none: found outside every character), and whether it also holds most of
    another's (joined). Returns ``({placed: [found, ...]}, joined placed characters,
    found outside)``."""
    per: dict[int, list] = {k: [] for k in range(len(boxes))}
    b = np.asarray(boxes, float)
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    joined, extra = set(), 0
    for c in found:
        x0, y0, x1, y1 = c.box_image
        w = np.clip(np.minimum(b[:, 2], x1) - np.maximum(b[:, 0], x0), 0, None)
        h = np.clip(np.minimum(b[:, 3], y1) - np.maximum(b[:, 1], y0), 0, None)
        inter = w * h
        if inter.max() <= 0:
            extra += 1
            continue
        covers = np.flatnonzero(inter >= 0.5 * area)
        if len(covers) > 1:
            joined.update(int(k) for k in covers)
            continue
        per[int(np.argmax(inter))].append(c)
    for k in joined:
        per[k] = []
    return per, len(joined), extra


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--omniglot", type=Path, required=True, help="the folder of the zips")
    p.add_argument("--model", default="omniglot-strokes", help="a stroke model (name or run)")
    p.add_argument("--drawer", type=int, default=18)
    p.add_argument("--n", type=int, default=24, help="characters on the page")
    p.add_argument("--per-line", type=int, default=8)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--paper", choices=("white", *KINDS), default="white",
                   help="white: the images as they are; else the ink written on generated "
                   "paper of that kind and photographed (img2dmp.data.clutter)")  # fmt: skip
    p.add_argument("--gap", type=float, default=None,
                   help="characters this many character heights apart (ink to ink) along "
                   "a line, as handwriting spaces them (default: in cells of 130 px)")  # fmt: skip
    p.add_argument("--cut", choices=("yes", "no"), default=None,
                   help="cut wide marks at their waists as for digits (default: the "
                   "library's img2dmp.page.STROKE_PAGE_CUT)")  # fmt: skip
    p.add_argument("--join", choices=("yes", "no"), default=None,
                   help="join neighbours of pieces side by side into one character (default: "
                   "the library's img2dmp.page.STROKE_PAGE_JOIN)")  # fmt: skip
    p.add_argument("--side-gap", type=float, default=None,
                   help="the largest gap between neighbours joined, as a share of their "
                   "line's usual gap (default: img2dmp.data.pages.SIDE_GAP)")  # fmt: skip
    p.add_argument("--side-width", type=float, default=None,
                   help="the widest two neighbours joined may be together, in the line's "
                   "usual character widths (default: img2dmp.data.pages.SIDE_WIDTH)")  # fmt: skip
    args = p.parse_args(argv)
    for name in ("gap", "side_gap", "side_width"):
        value = getattr(args, name)
        if value is not None and not 0 <= value < 10:
            p.error(f"--{name.replace('_', '-')} must be at least 0 and under 10, got {value}")
    with library_settings(args):
        return _read_page(args, argv)


@contextlib.contextmanager
def library_settings(args):
    """The page reading's settings as ``--cut``, ``--join``, ``--side-gap`` and
    ``--side-width`` ask, for the run; the library's own again afterwards (the tests call
    :func:`main` in their process)."""
    import img2dmp.data.pages as pages
    import img2dmp.page as page

    def yes(value):
        return None if value is None else value == "yes"

    asked = [
        (page, "STROKE_PAGE_CUT", yes(args.cut)),
        (page, "STROKE_PAGE_JOIN", yes(args.join)),
        (pages, "SIDE_GAP", args.side_gap),
        (pages, "SIDE_WIDTH", args.side_width),
    ]
    kept = [(module, name, getattr(module, name)) for module, name, _ in asked]
    try:
        for module, name, value in asked:
            if value is not None:
                setattr(module, name, value)
        yield
    finally:
        for module, name, value in kept:
            setattr(module, name, value)


def _read_page(args, argv: list[str]) -> int:
    print(format_record(run_record(__file__, argv)))
    chars = characters(args.omniglot, args.drawer)
    if len(chars) < args.n:
        raise SystemExit(f"drawer {args.drawer} drew {len(chars)} characters, fewer than --n")
    rng = np.random.default_rng(args.seed)
    chosen = [chars[i] for i in rng.choice(len(chars), args.n, replace=False)]
    page, boxes = layout(chosen, args.per_line, args.gap)
    args.out.mkdir(parents=True, exist_ok=True)
    photo = args.out / f"drawer{args.drawer}_page.png"
    if args.paper != "white":
        page = on_paper(rng, page, args.paper)
    Image.fromarray(page).save(photo)
    model = load_model(args.model)  # its card's refinement and count views
    read = model.predict_page(photo)
    files = read.save(args.out, photo.stem)
    per_cell, joined, extra = match(read.characters, boxes)
    placed = {k: v for k, v in per_cell.items() if v}
    print(f"{photo}: {args.n} characters placed, {len(read.characters)} found in "
          f"{len(read.lines)} lines; {sum(len(v) == 1 for v in placed.values())} of the "
          f"characters found as one, {sum(len(v) > 1 for v in placed.values())} in pieces "
          f"(side by side: read as several), {joined} found joined to a neighbour, "
          f"{args.n - len(placed) - joined} not found; {extra} found outside every "
          "character")  # fmt: skip
    whole = [(k, v[0]) for k, v in sorted(placed.items()) if len(v) == 1]
    truth = np.array([chosen[k][2] for k, _ in whole])
    said = np.array([c.prediction.n_strokes for _, c in whole])
    on_ink = np.array([c.prediction.fit["path_on_ink"] for _, c in whole])
    written = np.array([c.prediction.fit["ink_written"] for _, c in whole])
    if not whole:
        print("none was found as one character: no stroke counts to compare")
    else:
        print(f"of the {len(whole)} found as one: stroke count right {np.sum(said == truth)} "
              f"({100 * np.mean(said == truth):.1f} %); strokes drawn {truth.sum()}, read "
              f"{said.sum()}; path on the ink {100 * on_ink.mean():.1f} %, ink written "
              f"{100 * written.mean():.1f} % (means over the characters)")  # fmt: skip
    for k in range(args.n):
        name, _, n = chosen[k]
        got = per_cell.get(k, [])
        if len(got) != 1:
            print(f"  cell {k:>2} {name:<32} drawn {n}: found as {len(got)} characters")
            continue
        c = got[0]
        mark = "" if c.prediction.n_strokes == n else "  <- count"
        print(f"  cell {k:>2} {name:<32} drawn {n}, read {c.prediction.n_strokes}, on ink "
              f"{100 * c.prediction.fit['path_on_ink']:.0f} %{mark}")  # fmt: skip
    print("wrote " + ", ".join(str(f) for f in [photo, *files]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
