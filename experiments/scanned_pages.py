"""Pages from a scanner: 1-bit (bilevel) or grey, up to 300 dpi, no desk around the sheet.

A flatbed or document scanner gives a page as a 1-bit (black and white, PIL mode "1")
or grey image, at 200-300 dpi (an A4 sheet is 2480 x 3508 pixels at 300 dpi, digits
60-120 px tall), with nothing around the sheet. This reads such pages with
:func:`img2dmp.page.segment_page` (``predict --page``'s steps without a network):

**Generated pages** (``--pages N`` of ``--seed``: :func:`page_reading.generated_pages`,
the pages of ``page_segmentation.py``; MNIST digits of ``--split`` with their recorded
pen paths), each page's plain control (the same ink on white paper, evenly lit: what a
scanner sees of a plain sheet) rendered as a scanner gives it:

- ``grey``: its grey levels (PIL mode "L");
- ``1-bit T``: thresholded at ``T`` of white (``--thresholds``; a pixel darker is black),
  mode "1";
- ``1-bit faint``: the ink made fainter (``FAINT``: its darkness times 0.8) and a
  scanner's noise added (smooth, ``NOISE_SD`` grey levels) before thresholding at 0.5:
  thin and faint strokes thinned and broken by a pixel or two, as a scanner's
  threshold breaks them;
- ``300 dpi grey`` / ``300 dpi 1-bit``: enlarged (bilinear) so that the characters are
  ``DPI300_HEIGHT`` px tall and laid on a white A4-proportioned sheet (at least 2480 x
  3508), then grey or thresholded at 0.5.

Every true character is found / merged / split (broken: two or more boxes inside it) /
missed, and found boxes inside no true character are extra, as in
``page_segmentation.py`` (:func:`page_segmentation.classify`); *miscounted* are the
characters too many or too few in their lines (:func:`page_reading.miscounted`, the true
lines against the found ones); *s / page* the wall time of ``segment_page`` per page.

**The shared photos** (``--photos``: the two phone photos of ``../shared/data/photos``,
``photos.json``) in grey, thresholded at each of ``--thresholds`` (1-bit), each as it
stands (a photo: its sheet's dark edge and the desk are in it) and cropped inside the
sheet (``PHOTO_SHEETS``, by eye: what a scan of the sheet shows, no edge): boxes found,
*matched* / *extra* against the characters found on the photo as shipped
(:func:`sheet_on_desk.score`: a reference centre in exactly one box that holds no other;
a box that holds none), and miscounted against ``photos.json``.

``--out DIR`` gets ``scanned_pages.json`` (the run's date, revision, command and CPU,
every table and every page's row) and ``scanned_pages.md`` (the tables).

    python experiments/scanned_pages.py --pages 40 --seed 100 --photos ../shared/data/photos \\
        --out /tmp/scan
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from _provenance import cpu_name, format_record, run_record, write_report
from _provenance import markdown_table as _table
from page_reading import generated_pages, miscounted, page_sources
from page_segmentation import CLASSES, classify
from sheet_on_desk import score, shipped_photos

#: The faint scan: the ink's darkness scaled by this before the threshold ...
FAINT = 0.8
#: ... and a smooth noise of this many grey levels (standard deviation) added.
NOISE_SD = 20.0
#: ... smoothed over this many pixels (a Gaussian's sigma).
NOISE_SIGMA_PX = 2.0
#: Character height of the 300-dpi pages, pixels.
DPI300_HEIGHT = 100.0
#: A4 at 300 dpi, pixels (W, H).
A4_300DPI = (2480, 3508)
#: The sheet inside each shared photo (x0, y0, x1, y1), by eye: no edge, no desk.
PHOTO_SHEETS = {
    "page_white_black_ink.png": (12, 12, 580, 330),
    "page_yellow_blue_ink.png": (50, 20, 580, 395),
}


def bilevel(grey: np.ndarray, threshold: float):
    """A mode-"1" PIL image: black where ``grey`` (uint8) is below ``threshold`` of white."""
    from PIL import Image

    return Image.fromarray(grey >= threshold * 255.0).convert("1")


def faint_scan(grey: np.ndarray, rng) -> np.ndarray:
    """``grey`` (uint8) with its ink fainter (``FAINT``) and a scanner's noise added."""
    from scipy.ndimage import gaussian_filter

    noise = gaussian_filter(rng.normal(0.0, 1.0, grey.shape), NOISE_SIGMA_PX)
    noise *= NOISE_SD / max(1e-9, float(noise.std()))
    out = 255.0 - FAINT * (255.0 - grey.astype(np.float64)) + noise
    return np.clip(out, 0, 255).astype(np.uint8)


def at_300dpi(grey: np.ndarray, boxes: np.ndarray, char_height_px: float):
    """``grey`` enlarged so that its characters are ``DPI300_HEIGHT`` tall and laid on a
    white A4-proportioned sheet of at least ``A4_300DPI``; the sheet (uint8) and the
    boxes moved with it."""
    from PIL import Image

    s = DPI300_HEIGHT / char_height_px
    h, w = grey.shape
    big = np.asarray(Image.fromarray(grey).resize((round(w * s), round(h * s)),
                                                  Image.Resampling.BILINEAR))  # fmt: skip
    sheet_w = max(A4_300DPI[0], big.shape[1] + 200)
    sheet_h = max(A4_300DPI[1], big.shape[0] + 200, round(sheet_w * A4_300DPI[1] / A4_300DPI[0]))
    sheet = np.full((sheet_h, sheet_w), 255, np.uint8)
    x0, y0 = (sheet_w - big.shape[1]) // 2, 150
    sheet[y0 : y0 + big.shape[0], x0 : x0 + big.shape[1]] = big
    low, high = np.floor(boxes[:, :2] * s), np.ceil(boxes[:, 2:] * s)
    moved = np.column_stack([low, high]) + np.array([x0, y0, x0, y0])
    return sheet, moved.astype(np.int64)


def scans(page, thresholds, rng):
    """``(condition, PIL image, true boxes)`` of one generated page (module docstring)."""
    from PIL import Image

    grey = np.asarray(Image.fromarray(page.plain_image).convert("L"))
    boxes = np.asarray(page.boxes)
    yield "grey", Image.fromarray(grey), boxes
    for t in thresholds:
        yield f"1-bit {t:g}", bilevel(grey, t), boxes
    yield "1-bit faint", bilevel(faint_scan(grey, rng), 0.5), boxes
    big, moved = at_300dpi(grey, boxes, float(page.meta["char_height_px"]))
    yield "300 dpi grey", Image.fromarray(big), moved
    yield "300 dpi 1-bit", bilevel(big, 0.5), moved


def segment(image):
    """The boxes (photo pixels) and characters per line that ``segment_page`` finds."""
    from img2dmp.page import segment_page

    seg = segment_page(image)
    boxes = [seg.box_in_image(c) for c in seg.layout.characters]
    return boxes, [len(idx) for idx in seg.layout.lines]


def generated(args) -> list[dict]:
    """One row per page and condition."""
    rows = []
    rng = np.random.default_rng(args.seed)
    sources = page_sources(args.data, args.split)
    for p, kind, page in generated_pages(sources, args.pages, args.seed):
        truth = [tuple(int(v) for v in b) for b in page.boxes]
        true_lines = np.bincount(np.asarray(page.lines)).tolist()
        for cond, image, boxes in scans(page, args.thresholds, rng):
            start = time.perf_counter()
            found, lines = segment(image)
            wall = time.perf_counter() - start
            classes, extra = classify(found, [tuple(int(v) for v in b) for b in boxes])
            rows.append({"seed": args.seed + p, "kind": kind, "condition": cond,
                         "size_px": list(image.size), "characters": len(truth),
                         **{c: classes.count(c) for c in CLASSES}, "extra": extra,
                         "miscounted": miscounted(true_lines, lines),
                         "wall_s": round(wall, 4)})  # fmt: skip
        found = ", ".join(f"{r['condition']} {r['found']}" for r in rows[-7:])
        print(f"page {p + 1}/{args.pages} ({len(truth)} characters): {found}", flush=True)
    return rows


def summarise(rows: list[dict]) -> list[dict]:
    """Totals per condition."""
    table = []
    for cond in dict.fromkeys(r["condition"] for r in rows):
        sel = [r for r in rows if r["condition"] == cond]
        n = sum(r["characters"] for r in sel)
        walls = [r["wall_s"] for r in sel]
        entry = {"condition": cond, "pages": len(sel), "characters": n,
                 **{k: sum(r[k] for r in sel) for k in (*CLASSES, "extra", "miscounted")},
                 "wall_s_median": round(float(np.median(walls)), 3),
                 "wall_s_max": round(max(walls), 3)}  # fmt: skip
        entry["found_share"] = round(entry["found"] / max(1, n), 4)
        table.append(entry)
    return table


def photo_rows(folder: str, thresholds) -> list[dict]:
    """Each shared photo in grey and 1-bit, as it stands and cropped inside the sheet."""
    true = {p["file"]: [len(x.replace(" ", "")) for x in p["lines"]]
            for p in json.loads((Path(folder) / "photos.json").read_text())["photos"]}  # fmt: skip
    rows = []
    for file, photo, ref in shipped_photos(folder):
        grey_full = np.asarray(photo.convert("L"))
        for view in ("as it stands", "inside the sheet"):
            x0, y0, x1, y1 = (0, 0, *photo.size) if view == "as it stands" else PHOTO_SHEETS[file]
            grey = grey_full[y0:y1, x0:x1]
            centres = [(x - x0, y - y0) for x, y in ref if x0 <= x < x1 and y0 <= y < y1]
            from PIL import Image

            for name in ["grey", *(f"1-bit {t:g}" for t in thresholds)]:
                image = Image.fromarray(grey) if name == "grey" else bilevel(
                    grey, float(name.split()[1]))  # fmt: skip
                start = time.perf_counter()
                boxes, lines = segment(image)
                wall = time.perf_counter() - start
                matched, extra = score(boxes, centres)
                rows.append({"photo": file, "view": view, "condition": name,
                             "reference": len(centres), "boxes": len(boxes),
                             "matched": matched, "extra": extra, "lines": lines,
                             "miscounted": miscounted(true[file], lines),
                             "wall_s": round(wall, 4)})  # fmt: skip
    return rows


def markdown(report: dict) -> str:
    out = [format_record(report["run"]), f"CPU: {report['cpu']}", ""]
    if report.get("table"):
        out += _table(["scan", "pages", "characters", "found", "merged", "split (broken)",
                       "missed", "extra", "miscounted", "s / page (median, max)"],
                      [[e["condition"], e["pages"], e["characters"],
                        f"{e['found']} ({100 * e['found_share']:.1f} %)", e["merged"],
                        e["split"], e["missed"], e["extra"], e["miscounted"],
                        f"{e['wall_s_median']:.2f}, {e['wall_s_max']:.2f}"]
                       for e in report["table"]])  # fmt: skip
    if report.get("photos"):
        out += _table(["photo", "view", "scan", "reference", "boxes", "matched", "extra",
                       "per line", "miscounted", "s"],
                      [[r["photo"], r["view"], r["condition"], r["reference"], r["boxes"],
                        r["matched"], r["extra"], r["lines"], r["miscounted"],
                        f"{r['wall_s']:.2f}"] for r in report["photos"]])  # fmt: skip
    return "\n".join(out).rstrip("\n") + "\n"


def _thresholds(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if not values or not all(0.0 < v < 1.0 for v in values):
        raise argparse.ArgumentTypeError(
            f"--thresholds must be fractions of white in (0, 1), comma-separated, got {text!r}"
        )
    return values


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default="../shared/data")
    p.add_argument("--pages", type=int, default=40, help="generated pages (0: none)")
    p.add_argument("--split", choices=("validation", "test"), default="validation")
    p.add_argument("--seed", type=int, default=100)
    p.add_argument(
        "--thresholds",
        type=_thresholds,
        default=[0.35, 0.5, 0.65],
        help="1-bit thresholds, fractions of white (default 0.35,0.5,0.65)",
    )
    p.add_argument("--photos", default=None, help="the folder of the two shared photos")
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    if args.pages > 0 and not (Path(args.data) / "ijs-mnist-trajectories").is_dir():
        sys.exit(
            f"no {Path(args.data) / 'ijs-mnist-trajectories'}: --data names the shared "
            "data folder (or --pages 0)"
        )
    report = {"run": run_record(__file__, argv), "cpu": cpu_name()}
    print(format_record(report["run"]), f"\nCPU: {report['cpu']}", flush=True)
    start = time.perf_counter()
    rows = generated(args) if args.pages > 0 else []
    report["table"] = summarise(rows) if rows else []
    report["photos"] = photo_rows(args.photos, args.thresholds) if args.photos else []
    report["wall_s"] = round(time.perf_counter() - start, 1)
    report["pages"] = rows
    write_report(args.out, "scanned_pages", report, markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
