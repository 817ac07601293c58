"""A page upside down (a sheet fed into a scanner the wrong way round): is it read upright?

Generated pages (``--pages N`` of ``--seed``, as ``page_reading.py`` makes them: MNIST
digits of ``--split`` with their recorded pen paths on ruled, squared, dotted and plain
paper) are read by ``predict_page`` as they are and turned half a turn (the photo, its
true boxes and pen paths). Per condition:

- *turned*: pages read turned half a turn (``|turned_deg|`` > 90; the rule of
  ``img2dmp.page.PAGE_UPSIDE_DOWN_SHARE``);
- *found*, *Chamfer* (per 20 px of character height), *on the line*: as in
  ``page_reading.py``, against the true characters of the page as given;
- *starts right*: the share of found characters whose predicted path starts within 5 px
  per 20 px of height of the person's own start (a path written from the wrong end
  starts at the other end);
- *flagged*: the share of characters the reading flags.

``--choose`` reads every page as it stands both ways (the rule switched off) and prints,
per threshold of the share of characters flagged, how many upright pages a rule at that
threshold would read twice (and turn) and how many upside-down pages it would read
upright (the turned reading kept when it flags below ``PAGE_SIDEWAYS_GAIN`` of the
share): how ``PAGE_UPSIDE_DOWN_SHARE`` was chosen, on the validation pages.

``--photos DIR`` (a folder with ``photos.json``, as ``../shared/data/photos``): each photo
as it is and turned half a turn: characters found, lines, flagged, the angle turned.

    python experiments/upside_down_pages.py --model digits-real --pages 96 --seed 7 \\
        --split validation [--photos ../shared/data/photos]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from _provenance import format_record, run_record
from page_reading import _scores, generated_pages, match, page_sources

CONDITIONS = ("as given", "upside down")
START_PX_PER_20 = 5.0


def upside_down(page) -> SimpleNamespace:
    """``page`` turned half a turn: photo, true ink, boxes (pixel bounds) and pen paths
    (pixel centres)."""
    h, w = page.ink.shape
    boxes = np.stack([w - page.boxes[:, 2], h - page.boxes[:, 3],
                      w - page.boxes[:, 0], h - page.boxes[:, 1]], axis=1)  # fmt: skip
    paths = [np.column_stack([w - 1 - p[:, 0], h - 1 - p[:, 1], p[:, 2:]]) for p in page.paths]
    return SimpleNamespace(image=np.ascontiguousarray(page.image[::-1, ::-1]),
                           ink=np.ascontiguousarray(page.ink[::-1, ::-1]), boxes=boxes,
                           paths=paths)  # fmt: skip


def read(model, page) -> dict:
    """One reading of ``page`` (a generated page or :func:`upside_down` of one)."""
    result = model.predict_page(page.image)
    m = match([c.box_image for c in result.characters], [tuple(b) for b in page.boxes])
    rows = []
    for t, box in enumerate(page.boxes):
        if t not in m:
            rows.append({"found": False})
            continue
        pred = result.characters[m[t]].prediction.path_image[0]
        chamfer, on_line = _scores(pred, page.paths[t], page.ink, box)
        true = page.paths[t][page.paths[t][:, 2] >= 0.5]  # its pen-down points
        gap = float(np.hypot(*(pred[0, :2] - true[0, :2]))) * 20.0 / max(1.0, box[3] - box[1])
        rows.append({"found": True, "chamfer": chamfer, "on_line": on_line,
                     "starts_right": gap <= START_PX_PER_20})  # fmt: skip
    return {
        "rows": rows,
        "turned": abs(result.turn_deg) > 90.0,
        "flagged": len(result.flagged),
        "characters": len(result.characters),
    }


def _share_flagged(readings: list[dict]) -> float:
    return sum(x["flagged"] for x in readings) / max(1, sum(x["characters"] for x in readings))


THRESHOLDS = (0.10, 0.15, 0.20, 0.25, 0.30)


def choose(readings: dict) -> list[dict]:
    """Per threshold: upright pages read twice and turned, upside-down pages read upright
    by a rule at that threshold, from readings made with the rule off."""
    from img2dmp.page import PAGE_SIDEWAYS_GAIN

    share = {c: [x["flagged"] / max(1, x["characters"]) for x in v] for c, v in readings.items()}
    up, down = share[CONDITIONS[0]], share[CONDITIONS[1]]
    pairs = list(zip(up, down, strict=True))
    rows = []
    for t in THRESHOLDS:
        twice = [(u, d) for u, d in pairs if u >= t]
        rows.append({"threshold": t, "upright_read_twice": len(twice),
                     "upright_turned": sum(d < PAGE_SIDEWAYS_GAIN * u for u, d in twice),
                     "upside_down_read_upright": sum(d >= t and u < PAGE_SIDEWAYS_GAIN * d
                                                     for u, d in pairs)})  # fmt: skip
    return rows


def summarise(readings: list[dict]) -> dict:
    rows = [r for x in readings for r in x["rows"]]
    found = [r for r in rows if r["found"]]
    return {
        "pages": len(readings),
        "turned": sum(x["turned"] for x in readings),
        "characters": len(rows),
        "found": float(np.mean([r["found"] for r in rows])),
        "chamfer": float(np.mean([r["chamfer"] for r in found])),
        "on_line": float(np.mean([r["on_line"] for r in found])),
        "starts_right": float(np.mean([r["starts_right"] for r in found])),
        "flagged": sum(x["flagged"] for x in readings)
        / max(1, sum(x["characters"] for x in readings)),
    }


def photos(model, folder: Path) -> list[dict]:
    from PIL import Image

    spec = json.loads((folder / "photos.json").read_text())
    out = []
    for photo in spec["photos"]:
        image = np.asarray(Image.open(folder / photo["file"]).convert("RGB"))
        for cond, im in zip(
            CONDITIONS, (image, np.ascontiguousarray(image[::-1, ::-1])), strict=True
        ):
            r = model.predict_page(im)
            out.append({"photo": photo["file"], "condition": cond,
                        "found_per_line": [len(x) for x in r.lines],
                        "true_per_line": [len(line.replace(" ", "")) for line in photo["lines"]],
                        "flagged": len(r.flagged), "turned_deg": round(r.turn_deg, 1)})  # fmt: skip
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--model", default="digits-real")
    p.add_argument("--data", default="../shared/data")
    p.add_argument("--pages", type=int, default=24)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--split", choices=("validation", "test"), default="validation")
    p.add_argument("--photos", help="a folder of photos with photos.json")
    p.add_argument("--choose", action="store_true", help="the rule off: the threshold's table")
    p.add_argument("--out", help="write the results as JSON here")
    args = p.parse_args(argv)

    import img2dmp.page
    from img2dmp import load_model

    if args.choose:  # every page read as it stands, both ways
        img2dmp.page.PAGE_UPSIDE_DOWN_SHARE = float("inf")
    record = run_record(__file__, sys.argv[1:] if argv is None else list(argv))
    t0 = time.perf_counter()
    model = load_model(args.model)
    readings: dict = {c: [] for c in CONDITIONS}
    if args.pages:
        sources = page_sources(args.data, args.split)
        for k, _kind, page in generated_pages(sources, args.pages, args.seed):
            for cond, pg in zip(CONDITIONS, (page, upside_down(page)), strict=True):
                readings[cond].append(read(model, pg))
            print(f"page {k + 1}/{args.pages}", file=sys.stderr, flush=True)
    result = {"generated": {c: summarise(v) for c, v in readings.items() if v}}
    if args.choose and args.pages:
        result["choose"] = choose(readings)
    if args.photos:
        result["photos"] = photos(model, Path(args.photos))
    result["run"] = {**record, "wall_s": round(time.perf_counter() - t0, 1)}
    for cond, s in result["generated"].items():
        print(f"{cond:12s} pages {s['pages']}, turned {s['turned']}; characters {s['characters']}: "
              f"found {100 * s['found']:.2f} %, Chamfer {s['chamfer']:.4f}, on the line "
              f"{100 * s['on_line']:.2f} %, starts right {100 * s['starts_right']:.2f} %, "
              f"flagged {100 * s['flagged']:.2f} %")  # fmt: skip
    for r in result.get("choose", []):
        print(f"threshold {r['threshold']:.2f}: upright pages read twice "
              f"{r['upright_read_twice']}, of them turned {r['upright_turned']}; upside-down "
              f"pages read upright {r['upside_down_read_upright']}")  # fmt: skip
    for r in result.get("photos", []):
        print(
            f"{r['photo']} {r['condition']}: lines {r['found_per_line']} (true "
            f"{r['true_per_line']}), flagged {r['flagged']}, turned {r['turned_deg']}"
        )
    print(format_record(result["run"]))
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
