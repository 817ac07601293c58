"""Finding the characters of generated pages, without a network (issue 30's "found").

The pages are :mod:`page_reading`'s (:func:`page_reading.generated_pages`: MNIST digits
of ``--split`` with their recorded pen paths, on ruled, squared, dotted and plain paper in
turn, page ``p`` from seed ``--seed + p``), each also on plain white paper (the control).
Each image goes through the segmentation steps of ``img2dmp predict --page``
(:func:`img2dmp.page.segment_page`: the page read as the command reads it,
:func:`img2dmp.data.paper.paper_ink`, :func:`img2dmp.data.pages.find_characters`) and
its boxes, in the photo's pixels, are matched to the true ones as
:func:`page_reading.match` does (one to one, IoU >= 0.5). Every true character is one of:

- **found**: matched;
- **merged**: not matched, and a found box holds half of its box and half of another
  true character's (neighbours taken as one);
- **split**: not matched, and two or more found boxes lie mostly (half their area)
  inside its box (one character taken as several);
- **missed**: none of these (its box found too small or large, or not at all).

**Extra**: found boxes matched to no true character and lying mostly inside none (a
piece of the paper taken for a character; the pieces of a split character are not
counted here). Reported per paper kind, for the cluttered (ruled, squared, dotted) pages
together, and for the pages written tightly (``meta["tight"]``: gaps of -3 to +6 % of the
character height) and the others; each row for the cluttered image and for its plain
control. ``--out DIR`` gets ``page_segmentation.json``: the run's date, revision and
command, the table, and every page's counts (seed, kind, tight, per class).

    python experiments/page_segmentation.py --pages 200 --seed 100 --out /tmp/seg
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from _provenance import format_record, run_record, write_report
from page_reading import KINDS, generated_pages, match, page_sources

CLASSES = ("found", "merged", "split", "missed")


def _overlap(a, b) -> float:
    """Area of the intersection of boxes ``a`` and ``b``."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    return float(max(0, w) * max(0, h))


def _area(b) -> float:
    return float(max(0, b[2] - b[0]) * max(0, b[3] - b[1]))


def classify(found_boxes, true_boxes) -> tuple[list[str], int]:
    """The class of every true character (module docstring) and the extra boxes."""
    m = match(found_boxes, true_boxes)
    inside = np.array([[_overlap(f, t) / max(1.0, _area(f)) for f in found_boxes]
                       for t in true_boxes]).reshape(len(true_boxes), len(found_boxes))  # fmt: skip
    holds = np.array([[_overlap(f, t) / max(1.0, _area(t)) for f in found_boxes]
                      for t in true_boxes]).reshape(len(true_boxes), len(found_boxes))  # fmt: skip
    classes = []
    for t in range(len(true_boxes)):
        if t in m:
            classes.append("found")
        elif any((holds[:, f] >= 0.5).sum() >= 2 for f in np.flatnonzero(holds[t] >= 0.5)):
            classes.append("merged")
        elif (inside[t] >= 0.5).sum() >= 2:
            classes.append("split")
        else:
            classes.append("missed")
    used = set(m.values())
    extra = sum(
        1 for f in range(len(found_boxes)) if f not in used and not (inside[:, f] >= 0.5).any()
    )
    return classes, int(extra)


def segment(image) -> list[tuple[int, int, int, int]]:
    """The boxes of the characters that ``img2dmp predict --page`` finds on ``image``, in
    its pixels."""
    from img2dmp.page import segment_page

    seg = segment_page(image)
    return [seg.box_in_image(c) for c in seg.layout.characters]


def scan(sources, pages: int, seed: int) -> list[dict]:
    """Per page and condition: its seed, kind, tightness, characters per class, extra."""
    rows = []
    for p, kind, page in generated_pages(sources, pages, seed):
        truth = [tuple(int(v) for v in b) for b in page.boxes]
        for cond, image in (("cluttered", page.image), ("plain", page.plain_image)):
            classes, extra = classify(segment(image), truth)
            rows.append({"seed": seed + p, "kind": kind, "condition": cond,
                         "tight": bool(page.meta["tight"]), "characters": len(truth),
                         **{c: classes.count(c) for c in CLASSES}, "extra": extra})  # fmt: skip
        print(f"page {p + 1}/{pages} ({kind}, {len(truth)} characters): "
              f"found {rows[-2]['found']} / plain {rows[-1]['found']}", flush=True)  # fmt: skip
    return rows


def summarise(rows: list[dict]) -> list[dict]:
    """Totals per paper kind, the cluttered kinds together, and tight / other pages."""
    groups = [(k, lambda r, k=k: r["kind"] == k) for k in KINDS]
    groups += [("cluttered (ruled, squared, dotted)", lambda r: r["kind"] != "plain"),
               ("tight pages, cluttered kinds", lambda r: r["kind"] != "plain" and r["tight"]),
               ("other pages, cluttered kinds", lambda r: r["kind"] != "plain" and not r["tight"]),
               ("all pages", lambda r: True)]  # fmt: skip
    table = []
    for name, keep in groups:
        entry = {"pages": name}
        for cond in ("cluttered", "plain"):
            sel = [r for r in rows if r["condition"] == cond and keep(r)]
            n = sum(r["characters"] for r in sel)
            counts = {c: sum(r[c] for r in sel) for c in (*CLASSES, "extra")}
            entry[cond] = {"pages": len(sel), "characters": n, **counts,
                           "found_share": round(counts["found"] / max(1, n), 4)}  # fmt: skip
        table.append(entry)
    return table


def _print_table(table: list[dict]) -> None:
    print("| pages | characters | found | merged | split | missed | extra |")
    print("|---|---|---|---|---|---|---|")
    for e in table:
        c, p = e["cluttered"], e["plain"]
        cells = [f"{c[k]} / {p[k]}" for k in ("merged", "split", "missed", "extra")]
        found = f"{100 * c['found_share']:.1f} % / {100 * p['found_share']:.1f} %"
        print(f"| {e['pages']} | {c['characters']} | {found} | " + " | ".join(cells) + " |")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default="../shared/data")
    p.add_argument("--pages", type=int, default=200)
    p.add_argument("--split", choices=("validation", "test"), default="validation")
    p.add_argument("--seed", type=int, default=100)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    start = time.perf_counter()
    report = {"run": run_record(__file__, argv)}
    rows = scan(page_sources(args.data, args.split), args.pages, args.seed)
    report["table"] = summarise(rows)
    report["wall_s"] = round(time.perf_counter() - start, 1)
    report["pages"] = rows
    write_report(args.out, "page_segmentation", report)
    print(format_record(report["run"]))
    _print_table(report["table"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
