"""How well :func:`img2dmp.data.shake.shake` reads a shake, and how often it reads one
where there is none.

Images, each read as ``segment_page`` reads a page (at most 2,000,000 pixels):

- **not shaken**: the two shared photos (``--photos``) and ``--pages`` generated
  validation pages (:func:`page_reading.generated_pages`, seed 100) under every condition
  of ``photo_conditions.py`` but its motion, slant and dim shake families (as they are,
  shadows, glare, defocus, far away, JPEG, pencil, marker, warm light); and ``--more``
  further generated pages (from seed ``100 + --pages``), each on its paper and on plain
  white;
- **shaken**: the same photos and pages under ``photo_conditions.py``'s motion, slant and
  dim shake families, and moved along a line (:func:`photo_conditions.slanted`) of 5, 9
  and 15 px at 13 directions (10-170 degrees); each of the ``--more`` pages moved once,
  its length (4-15 px) and direction (0-180 degrees) drawn from ``--seed``.

Per image: the cepstrum's trough (its depth ``z``, length and direction), the directional
derivatives' correlations along and across it, and what :func:`shake` reads. The summary
gives, per kind of image, how many were read as shaken and, for the shaken ones read,
the length's and the direction's error against the shake as applied (scaled as the image
was reduced; the direction folded to 0-90 degrees apart). ``--out DIR`` gets
``shake_readings.json`` (date, revision, command, CPU, every row) and ``.md``.

    python experiments/shake_readings.py --pages 12 --more 200 --out /tmp/shake
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from _provenance import cpu_name, format_record, run_record, write_report
from _provenance import markdown_table as _table
from page_reading import generated_pages, page_sources
from photo_conditions import CONDITIONS, add_photo_arguments, apply, slanted

#: The line shakes applied to the photos and the ``--pages`` pages: lengths (px) ...
LENGTHS = (5, 9, 15)
#: ... and directions (degrees from the rows, down the image positive).
DIRECTIONS = (10, 15, 22.5, 30, 45, 60, 67.5, 80, 100, 120, 135, 150, 170)
#: The length and direction of a ``--more`` page's shake are drawn from these ranges.
MORE_LENGTH, MORE_DIRECTION = (4.0, 15.0), (0.0, 180.0)
#: ``photo_conditions.py``'s conditions that shake, and the shake each applies.
SHAKEN = {"motion-h5": (5, 0), "motion-h9": (9, 0), "motion-v5": (5, 90), "motion-v9": (9, 90),
          "slant-15-9": (9, 15), "slant-30-9": (9, 30), "slant-45-5": (5, 45),
          "slant-45-9": (9, 45), "slant-120-9": (9, 120),
          "motion-h9+dim": (9, 0), "slant-30-9+dim": (9, 30)}  # fmt: skip


def reading(image, applied: tuple[float, float] | None) -> dict:
    """The features of ``image`` (``uint8 [H, W, 3]``) and what :func:`shake` reads;
    with the length and direction ``applied`` (in the image's pixels), the errors."""
    from img2dmp.data import images
    from img2dmp.data import shake as sh

    read = images._read_levels(image, None, 2_000_000)
    grey = sh._grey(read.levels)
    longest = min(sh.SHAKE_MAX_PX, min(grey.shape) // 4)
    dy, dx, z = sh._trough(grey, longest)
    degrees = math.degrees(math.atan2(dy, dx)) % 180.0
    along, across = sh._along_across(grey, degrees)
    found = sh.shake(read.levels)
    row = {"z": round(z, 1), "trough_px": round(math.hypot(dy, dx), 2),
           "trough_deg": round(degrees, 1), "along": round(along, 3),
           "across": round(across, 3), "reduction": read.reduction,
           "found": None if found is None else [found.length, found.degrees]}  # fmt: skip
    if applied is not None:
        length, direction = applied[0] / read.reduction, applied[1]
        row["applied"] = [round(length, 2), direction]
        if found is not None:
            apart = abs(found.degrees - direction) % 180.0
            row["length_error"] = round(abs(found.length - length), 2)
            row["direction_error"] = round(min(apart, 180.0 - apart), 1)
    return row


def _images(photos: str, data: str, pages: int, more: int, seed: int):
    """Yield ``(image name, kind, condition, image, applied shake or None)``."""
    from PIL import Image

    sources = []
    for file in ("page_white_black_ink.png", "page_yellow_blue_ink.png") if photos else ():
        rgb = np.asarray(Image.open(Path(photos) / file).convert("RGB"))
        sources.append((file, "photo", rgb))
    chars = page_sources(data, "validation") if pages or more else []
    for p, _kind, page in generated_pages(chars, pages, 100):
        sources.append((f"page {100 + p}", "page", page.image))
    for index, (name, kind, image) in enumerate(sources):
        number = index if kind == "photo" else 1000 + index - (2 if photos else 0)
        for cond in CONDITIONS:
            yield name, kind, cond.name, apply(cond, image, 0, number), SHAKEN.get(cond.name)
        for length in LENGTHS:
            for direction in DIRECTIONS:
                moved = slanted(length, direction)(np.asarray(image, np.float64), None)
                moved = np.clip(moved + 0.5, 0, 255).astype(np.uint8)
                yield name, kind, f"line-{direction:g}-{length}", moved, (length, direction)
    if more:
        rng = np.random.default_rng(seed)
        for p, _kind, page in generated_pages(chars, more, 100 + pages):
            name = f"page {100 + pages + p}"
            yield name, "more", "as-is", page.image, None
            yield name, "more", "plain", page.plain_image, None
            length, direction = rng.uniform(*MORE_LENGTH), rng.uniform(*MORE_DIRECTION)
            moved = slanted(length, direction)(np.asarray(page.image, np.float64), None)
            moved = np.clip(moved + 0.5, 0, 255).astype(np.uint8)
            yield name, "more", "moved", moved, (round(length, 2), round(direction, 1))


def summarise(rows: list[dict]) -> list[dict]:
    """Per kind of image (photos, pages, more pages) and shaken or not: how many images,
    how many read as shaken, and the median and largest errors of those read."""
    out = []
    for kind in ("photo", "page", "more"):
        for shaken in (False, True):
            group = [r for r in rows if r["kind"] == kind and ("applied" in r) == shaken]
            if not group:
                continue
            found = [r for r in group if r["found"] is not None]
            lengths = [r["length_error"] for r in found if "length_error" in r]
            directions = [r["direction_error"] for r in found if "direction_error" in r]
            out.append({"images": kind, "shaken": shaken, "count": len(group),
                        "read as shaken": len(found),
                        "length error px (median / max)": _spread(lengths),
                        "direction error deg (median / max)": _spread(directions)})  # fmt: skip
    return out


def _spread(values: list[float]) -> str:
    return f"{np.median(values):.2f} / {max(values):.2f}" if values else "-"


def markdown(report: dict) -> str:
    lines = [format_record(report["run"]), "", f"CPU: {report['cpu']}", ""]
    table = report["summary"]
    lines += _table(list(table[0]), [list(r.values()) for r in table])
    missed = [r for r in report["rows"] if "applied" in r and r["found"] is None]
    lines += [f"Shaken images not read: {len(missed)}; not shaken read as shaken: "
              f"{sum(r['found'] is not None for r in report['rows'] if 'applied' not in r)}.",
              ""]  # fmt: skip
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_photo_arguments(p)
    p.add_argument("--pages", type=int, default=12, help="pages under every condition")
    p.add_argument("--more", type=int, default=200, help="pages as they are and moved once")
    p.add_argument("--seed", type=int, default=7, help="the --more pages' shakes")
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    if args.pages < 0 or args.more < 0:
        p.error("--pages and --more: give 0 or more")
    if not (args.photos or args.pages or args.more):
        p.error("nothing to read: give --photos, --pages or --more")
    if (args.pages or args.more) and not (Path(args.data) / "ijs-mnist-trajectories").is_dir():
        sys.exit(f"no {Path(args.data) / 'ijs-mnist-trajectories'}: --data names the shared "
                 "data folder (or --pages 0 --more 0)")  # fmt: skip
    if args.photos and not (Path(args.photos) / "page_white_black_ink.png").is_file():
        sys.exit(f"no {Path(args.photos) / 'page_white_black_ink.png'}: --photos names the "
                 "folder of the two shared photos (or --photos '')")  # fmt: skip
    report = {"run": run_record(__file__, argv), "cpu": cpu_name()}
    print(format_record(report["run"]), f"\nCPU: {report['cpu']}", flush=True)
    start, rows = time.perf_counter(), []
    for name, kind, cond, image, applied in _images(args.photos, args.data, args.pages,
                                                    args.more, args.seed):  # fmt: skip
        rows.append({"image": name, "kind": kind, "condition": cond, **reading(image, applied)})
        if len(rows) % 100 == 0:
            print(f"{len(rows)} images read", flush=True)
    report["summary"], report["rows"] = summarise(rows), rows
    report["wall_s"] = round(time.perf_counter() - start, 1)
    write_report(args.out, "shake_readings", report, markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
