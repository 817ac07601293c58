"""How much of Omniglot's ink the photo preparation drops: the pen's dots taken for specks.

Every drawing of an Omniglot images zip (or a sample of ``--limit`` of them, spread over
all alphabets) is read twice: its raw PNG's ink (the black pixels, 8-connected
components), and the pen strokes :func:`img2dmp.data.images.prepare_image_found` finds in
it (its paper cleaning, :func:`img2dmp.data.paper.paper_ink`, the mask at the image's
resolution). A raw component is **lost** when none of its pixels is in the found mask;
ink lost is the raw ink pixels outside the mask. The strokes zip (same stems) tells which
lost components the writer drew as a dot: a stroke whose points lie within
``DOT_EXTENT_PX`` of each other (most are a single point), in a component of its own at
most ``DOT_COMPONENT_PX`` across. Reported per alphabet and in
total: drawings, drawings that lose a component, components lost (and of them the pen's
dots: components a dot stroke drew, lost / all; and the components lost in all, by
area), raw ink pixels lost.

``--specks N`` also adds N isolated specks to every drawing (squares of 1-3 pixels side
on the paper, ``--speck-gap LEAST MOST`` pixels from the ink, LEAST also from each other;
a seeded draw per drawing) and counts those that the preparation keeps: the other side of the
trade, what a rule that keeps dots must still remove.

    python experiments/pen_dots.py ../shared/data/omniglot [--limit 0] [--specks 6] \
        [--speck-gap 15 1e9] [--out DIR]

``--out DIR`` gets ``pen_dots.json``: the run's date, revision and command, the table and
every lost component (drawing, area, size, whether a dot stroke drew it).
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import time
import zipfile
from collections import defaultdict
from pathlib import Path

import numpy as np

from _provenance import format_record, run_record

#: A stroke whose points all lie within this many pixels of its first is a pen dot,
DOT_EXTENT_PX = 2.0
#: ... and a component it drew that is at most this many pixels across is a dot of its
#: own (Omniglot's dots are rendered 5 px across; larger: the dot touches a stroke).
DOT_COMPONENT_PX = 12
IMAGES_ZIP = "images_background_small1.zip"
STROKES_ZIP = "strokes_background_small1.zip"


def drawings(data: Path, limit: int) -> list[str]:
    """The PNG members of the images zip, all or ``limit`` spread evenly over them (the
    zip is ordered by alphabet, so a stride reaches every alphabet)."""
    with zipfile.ZipFile(data / IMAGES_ZIP) as z:
        names = sorted(n for n in z.namelist() if n.endswith(".png") and "__MACOSX" not in n)
    if limit and limit < len(names):
        names = [names[i] for i in np.linspace(0, len(names) - 1, limit).round().astype(int)]
    return names


def dot_points(text: str) -> list[tuple[float, float]]:
    """The (row, column) of every stroke of a stroke file that is a dot."""
    out, stroke = [], []
    for line in text.splitlines():
        line = line.strip()
        if line in ("START", "BREAK", ""):
            if stroke:
                p = np.array(stroke)
                if np.max(np.hypot(*(p - p[0]).T)) <= DOT_EXTENT_PX:
                    out.append((-float(p[:, 1].mean()), float(p[:, 0].mean())))
            stroke = []
            continue
        x, y, _ = (float(v) for v in line.split(","))
        stroke.append((x, y))
    return out


def with_specks(raw: np.ndarray, n: int, gap, seed: int) -> tuple[np.ndarray, list]:
    """``raw`` (bool ink) with ``n`` specks (squares of 1-3 px) at ``gap`` = (least,
    most) px from the ink (the least also from each other), and their boxes (r0, c0,
    side)."""
    from scipy.ndimage import distance_transform_edt

    rng = np.random.default_rng(seed)
    out, boxes, to_ink = raw.copy(), [], distance_transform_edt(~raw)
    for _ in range(200):
        if len(boxes) == n:
            break
        far = distance_transform_edt(~out)
        side = int(rng.integers(1, 4))
        r, c = (int(v) for v in rng.integers(3, np.array(raw.shape) - 3 - side))
        if far[r : r + side, c : c + side].min() >= gap[0] and (to_ink[r, c] <= gap[1]):
            out[r : r + side, c : c + side] = True
            boxes.append((r, c, side))
    return out, boxes


def measure(name: str, png: bytes, strokes: str | None, specks: int, gap: int, seed: int):
    """One drawing's counts: raw components, lost ones (each with its area, size and
    whether a dot stroke drew it), ink pixels raw and lost, specks added and kept."""
    from PIL import Image
    from scipy.ndimage import find_objects, label

    raw = np.asarray(Image.open(io.BytesIO(png)).convert("L")) < 128
    labels, n = label(raw, structure=np.ones((3, 3), bool))
    mask = _found(raw, name)
    kept = np.zeros(n + 1, bool)
    kept[np.unique(labels[mask])] = True
    dots = {int(labels[min(max(round(r), 0), raw.shape[0] - 1),
                       min(max(round(c), 0), raw.shape[1] - 1)])
            for r, c in (dot_points(strokes) if strokes else [])}  # fmt: skip
    lost, drawn = [], 0
    for lab, sl in enumerate(find_objects(labels), start=1):
        size = max(sl[0].stop - sl[0].start, sl[1].stop - sl[1].start)
        dot = lab in dots and size <= DOT_COMPONENT_PX
        drawn += dot
        if not kept[lab]:
            lost.append({"drawing": name, "area": int((labels[sl] == lab).sum()),
                         "size": int(size), "dot": dot})  # fmt: skip
    row = {"drawing": name, "components": int(n), "lost": lost, "dots": drawn,
           "ink": int(raw.sum()), "ink_lost": int((raw & ~mask).sum()),
           "specks": 0, "specks_kept": 0}  # fmt: skip
    if specks:
        noisy, boxes = with_specks(raw, specks, gap, seed)
        m = _found(noisy, name)
        row["specks"] = len(boxes)
        row["specks_kept"] = sum(bool(m[r : r + s, c : c + s].any()) for r, c, s in boxes)
        row["ink_lost_noisy"] = int((raw & ~m).sum())
    return row


def _found(raw: np.ndarray, name: str) -> np.ndarray:
    """The pen strokes that ``prepare_image_found`` finds in black-on-white ``raw``."""
    from img2dmp.data.images import prepare_image_found

    image = np.where(raw, 0.0, 1.0).astype(np.float32)
    try:
        return prepare_image_found(image, name=name)[2]
    except ValueError:  # no ink found at all
        return np.zeros(raw.shape, bool)


def summarise(rows: list[dict]) -> list[dict]:
    """Totals per alphabet and over all."""
    groups = defaultdict(list)
    for r in rows:
        groups[r["drawing"].split("/")[1]].append(r)
    table = []
    for name, sel in [*sorted(groups.items()), ("all", rows)]:
        lost = [c for r in sel for c in r["lost"]]
        table.append({
            "alphabet": name, "drawings": len(sel),
            "drawings_losing": sum(1 for r in sel if r["lost"]),
            "components": sum(r["components"] for r in sel),
            "lost": len(lost), "dots": sum(r["dots"] for r in sel),
            "lost_dots": sum(c["dot"] for c in lost),
            "lost_px": sum(c["area"] for c in lost),
            "ink": sum(r["ink"] for r in sel), "ink_lost": sum(r["ink_lost"] for r in sel),
            "specks": sum(r["specks"] for r in sel),
            "specks_kept": sum(r["specks_kept"] for r in sel),
        })  # fmt: skip
    return table


def _print(table: list[dict], rows: list[dict]) -> None:
    print("| alphabet | drawings | losing a component | components lost / all | dots lost / "
          "drawn | lost components' px | ink px lost / all | specks kept / added |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for e in table:
        print(f"| {e['alphabet']} | {e['drawings']} | {e['drawings_losing']} | "
              f"{e['lost']} / {e['components']} | {e['lost_dots']} / {e['dots']} | "
              f"{e['lost_px']} | "
              f"{e['ink_lost']} / {e['ink']} ({100 * e['ink_lost'] / max(1, e['ink']):.2f} %) "
              f"| {e['specks_kept']} / {e['specks']} |")  # fmt: skip
    areas = np.array([c["area"] for r in rows for c in r["lost"]], int)
    if areas.size:
        edges = [1, 4, 8, 16, 32, 64, 10**9]
        hist = np.histogram(areas, bins=edges)[0]
        bins = zip(edges[:-1], edges[1:], hist, strict=True)
        print("lost components by area (px): " + ", ".join(f"{a}-{b - 1}: {h}" for a, b, h in bins))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("data", help="folder holding the Omniglot zips")
    p.add_argument("--limit", type=int, default=0, help="drawings (0: all)")
    p.add_argument("--specks", type=int, default=0, help="specks added per drawing")
    p.add_argument("--speck-gap", type=float, nargs=2, default=(15, 1e9),
                   metavar=("LEAST", "MOST"), help="specks' distance from the ink, px")  # fmt: skip
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out")
    args = p.parse_args(argv)
    start = time.perf_counter()
    report = {"run": run_record(__file__, argv)}  # the revision the run starts from
    data = Path(args.data)
    names = drawings(data, args.limit)
    rows = []
    with zipfile.ZipFile(data / IMAGES_ZIP) as zi, zipfile.ZipFile(data / STROKES_ZIP) as zs:
        known = set(zs.namelist())
        for k, name in enumerate(names):
            stroke = name.replace("images_", "strokes_", 1)[: -len(".png")] + ".txt"
            text = zs.read(stroke).decode() if stroke in known else None
            rows.append(measure(name, zi.read(name), text, args.specks, args.speck_gap,
                                args.seed + k))  # fmt: skip
    report["table"] = summarise(rows)
    report["wall_s"] = round(time.perf_counter() - start, 1)
    report["lost"] = [c for r in rows for c in r["lost"]]
    print(format_record(report["run"]))
    _print(report["table"], rows)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "pen_dots.json").write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
