"""Reading pages (issue 30): generated pages with known pen paths, and real photos.

Generated pages (``--pages N``): MNIST digits with their recorded pen paths (the split
``--split``, validation by default: choices are made there; the test split for the
figures) written by :func:`img2dmp.data.clutter.generate_page` on ruled, squared, dotted
and plain paper in turn, and the same pages on plain white paper (the control). Each page
is read by ``predict_page`` and its characters matched one to one with the true ones
(intersection over union of the boxes >= 0.5). Reported per paper kind:

- **found**: the share of true characters matched by exactly one found character (not
  split, not merged with a neighbour, not missed);
- **Chamfer**: the order-free distance between the predicted path (top hypothesis) and
  the person's, in photo pixels per 20 px of character height (the box's), cluttered and
  plain, and their ratio;
- **on the pen's line**: the share of the predicted path within one pixel of MNIST's
  28-px frame (1/28 of the character's height, at least a pixel) of the true ink (> 0.5),
  as the MNIST evaluation's "on ink" is taken in that frame.

``--crops`` also measures the characters cropped by hand (the true box grown by 30 %,
where no neighbour reaches into it), each predicted alone with the paper-aware
preparation and with the plain one: what preparation does without segmentation (the
issue's "cropped by hand" row).

Real photos (``--photos DIR``: a folder with ``photos.json`` as in ``../shared/data/photos``):
the characters found per line against the digits written out (miscounted: characters
too many or too few, the lines found aligned with the true ones, over the characters;
:func:`miscounted`), and the path on ink / ink written, both
against the photo's own ink (:func:`img2dmp.data.paper.paper_ink` at the page's
resolution; on ink: within one pixel of it; written: ink pixels within half the pen width
and 1.5 px of a predicted path).

    python experiments/page_reading.py --model runs/real/run --refine 30 --pages 24 \\
        --photos ../shared/data/photos --out /tmp/pages
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from _provenance import format_record, run_record, write_report

KINDS = ("ruled", "squared", "dotted", "plain")


def _iou(a, b) -> float:
    x0, y0 = max(a[0], b[0]), max(a[1], b[1])
    x1, y1 = min(a[2], b[2]), min(a[3], b[3])
    inter = max(0, x1 - x0) * max(0, y1 - y0)
    area = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / area if area > 0 else 0.0


def match(found_boxes, true_boxes) -> dict[int, int]:
    """True index -> found index, for true characters that exactly one found box covers
    with IoU >= 0.5 and that box no other true character."""
    iou = np.array([[_iou(f, t) for f in found_boxes] for t in true_boxes]).reshape(
        len(true_boxes), len(found_boxes)
    )
    hits = iou >= 0.5
    out = {}
    for t in range(len(true_boxes)):
        f = np.flatnonzero(hits[t])
        if len(f) == 1 and hits[:, f[0]].sum() == 1:
            out[t] = int(f[0])
    return out


def _down(path: np.ndarray) -> np.ndarray:
    return path[path[:, 2] >= 0.5, :2] if path.shape[1] > 2 else path[:, :2]


def _scores(pred_path, true_path, ink, box) -> tuple[float, float]:
    """(Chamfer per 20 px of character height, share of the predicted path on the pen's
    line: within one pixel of MNIST's 28-px frame, 1/28 of the character's height but at
    least a pixel, of the true ink above 0.5)."""
    from scipy.ndimage import distance_transform_edt

    from img2dmp.metrics import chamfer_px, resample_by_arc_length

    height = max(1.0, box[3] - box[1])
    c = float(chamfer_px(pred_path[None, :, :2], _down(true_path)[None])[0]) * 20.0 / height
    pad = int(height)
    x0, y0 = max(0, box[0] - pad), max(0, box[1] - pad)
    crop = ink[y0 : box[3] + pad, x0 : box[2] + pad] > 0.5
    away = distance_transform_edt(~crop)
    pts = resample_by_arc_length(pred_path[None, :, :2], 128)[0] - [x0, y0]
    r = np.clip(np.round(pts[:, 1]).astype(int), 0, crop.shape[0] - 1)
    col = np.clip(np.round(pts[:, 0]).astype(int), 0, crop.shape[1] - 1)
    return c, float((away[r, col] <= max(1.0, height / 28.0)).mean())


def _read_generated(model, page, image, crops: bool):
    """Per true character of ``page`` read from ``image``: found (bool), Chamfer, on line,
    and with ``crops`` the same for the hand-cropped character (paper-aware, plain)."""
    result = model.predict_page(image)
    found = [c.box_image for c in result.characters]
    m = match(found, [tuple(b) for b in page.boxes])
    rows = []
    for t, box in enumerate(page.boxes):
        row = {"found": t in m}
        if t in m:
            pred = result.characters[m[t]].prediction.path_image[0]
            row["chamfer"], row["on_line"] = _scores(pred, page.paths[t], page.ink, box)
        if crops:
            row.update(_crop_scores(model, page, image, t))
        rows.append(row)
    return rows


def _crop_scores(model, page, image, t: int) -> dict:
    box = page.boxes[t]
    w, h = box[2] - box[0], box[3] - box[1]
    x0, y0 = max(0, int(box[0] - 0.3 * w)), max(0, int(box[1] - 0.3 * h))
    x1, y1 = int(box[2] + 0.3 * w), int(box[3] + 0.3 * h)
    others = [b for k, b in enumerate(page.boxes) if k != t]
    if any(_iou((x0, y0, x1, y1), b) > 0 for b in others):
        return {}  # a neighbour in the crop: not a character cropped by hand
    crop = image[y0:y1, x0:x1]
    out = {}
    for name, clean in (("crop_paper", True), ("crop_plain", False)):
        try:
            from img2dmp.data.images import prepare_image_framed

            prepared, frame = prepare_image_framed(crop, model.image_size, margin=model.margin,
                                                   stroke_width_px=model.stroke_width,
                                                   clean=clean)  # fmt: skip
        except ValueError:
            continue
        params, _ = model.predict_hypotheses(prepared[None])
        _, y = model.trajectories(params[0, 0])
        xy = frame.to_image(y) + [x0, y0]
        out[name], out[name + "_on_line"] = _scores(xy, page.paths[t], page.ink, box)
    return out


def page_sources(data: str, split: str) -> list:
    """The :class:`img2dmp.data.clutter.CharacterSource` of every recorded MNIST digit of
    ``split`` ("validation" or "test") in the data folder ``data``."""
    import warnings

    from img2dmp.data.clutter import page_sources_from_recorded
    from img2dmp.data.recorded import load_recorded, split_of_index

    archive = Path(data) / "ijs-mnist-trajectories" / "trajectories.tar.gz"
    if not archive.is_file():  # one line, not load_recorded's traceback
        sys.exit(f"no recorded pen paths at {archive}: --data names ../shared/data")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        recs = load_recorded(archive, progress=False)
    code = {"validation": 1, "test": 2}[split]
    return page_sources_from_recorded([r for r in recs if split_of_index(r.image_index) == code])


def generated_pages(sources: list, pages: int, seed: int):
    """Yield ``(p, kind, page)`` for the ``pages`` generated pages of ``seed``: page ``p``
    from ``numpy.random.default_rng(seed + p)``, 8 to 30 of ``sources``, on the paper
    kinds in turn (:data:`KINDS`)."""
    from img2dmp.data.clutter import generate_page

    for p in range(pages):
        rng = np.random.default_rng(seed + p)
        pick = rng.choice(len(sources), int(rng.integers(8, 31)), replace=False)
        kind = KINDS[p % len(KINDS)]
        yield p, kind, generate_page(rng, [sources[i] for i in pick], kind=kind)


def generated(model, args) -> dict:
    """Every page's rows, by paper kind and condition."""
    sources = page_sources(args.data, args.split)
    out: dict = {k: {"cluttered": [], "plain": []} for k in KINDS}
    for p, kind, page in generated_pages(sources, args.pages, args.seed):
        for cond, image in (("cluttered", page.image), ("plain", page.plain_image)):
            out[kind][cond] += _read_generated(
                model, page, image, args.crops and cond == "cluttered"
            )
        print(f"page {p + 1}/{args.pages} ({kind}, {len(page.boxes)} characters)", flush=True)
    return out


def _mean(rows, key):
    v = [r[key] for r in rows if key in r]
    return float(np.mean(v)) if v else float("nan")


def summarise_generated(out: dict) -> list[dict]:
    table = []
    for kind in [*KINDS, "cluttered (ruled, squared, dotted)"]:
        kinds = KINDS[:3] if kind.startswith("cluttered") else (kind,)
        clut = [r for k in kinds for r in out[k]["cluttered"]]
        plain = [r for k in kinds for r in out[k]["plain"]]
        if not clut:
            continue
        row = {"paper": kind, "characters": len(clut)}
        row["found"] = float(np.mean([r["found"] for r in clut]))
        row["found_plain"] = float(np.mean([r["found"] for r in plain]))
        for key in ("chamfer", "on_line"):
            row[key], row[key + "_plain"] = _mean(clut, key), _mean(plain, key)
        row["chamfer_ratio"] = row["chamfer"] / row["chamfer_plain"]
        for key in ("crop_paper", "crop_plain", "crop_paper_on_line", "crop_plain_on_line"):
            row[key] = _mean(clut, key)
        table.append(row)
    return table


def photos(model, folder: Path) -> list[dict]:
    """Per photo: characters per line found and true, miscounted share, path on ink, ink
    written (module docstring)."""
    from img2dmp.data.images import _levels_framed
    from img2dmp.data.paper import dilate3, paper_ink
    from img2dmp.page import PAGE_WORK_PIXELS

    spec = json.loads((folder / "photos.json").read_text())
    rows = []
    for photo in spec["photos"]:
        path = folder / photo["file"]
        result = model.predict_page(path)
        true = [len(line.replace(" ", "")) for line in photo["lines"]]
        found = [len(x) for x in result.lines]
        levels, reduction, _, _ = _levels_framed(path, None, PAGE_WORK_PIXELS)
        ink = paper_ink(levels)
        near = dilate3(ink.mask)
        paths = [(c.prediction.path_image[0][:, :2] + 0.5) / reduction - 0.5
                 for c in result.characters]  # fmt: skip
        on = _on_mask(near, paths)
        written = _written(ink.mask, paths, 0.5 * ink.pen_width_px + 1.5)
        rows.append({"photo": photo["file"], "true_per_line": true, "found_per_line": found,
                     "miscounted": miscounted(true, found) / sum(true),
                     "path_on_ink": on, "ink_written": written,
                     "flagged": len(result.flagged)})  # fmt: skip
    return rows


def miscounted(true: list[int], found: list[int]) -> int:
    """Characters too many or too few, the lines found aligned in order with the true
    ones (each found line matched to one true line or left over, its characters all
    extra; a true line left over, its characters all missing), the alignment that
    miscounts fewest."""
    n, m = len(true), len(found)
    cost = np.zeros((n + 1, m + 1))
    cost[1:, 0] = np.cumsum(true)
    cost[0, 1:] = np.cumsum(found)
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            matched = cost[i - 1, j - 1] + abs(true[i - 1] - found[j - 1])
            missing = cost[i - 1, j] + true[i - 1]
            extra = cost[i, j - 1] + found[j - 1]
            cost[i, j] = min(matched, missing, extra)
    return int(cost[n, m])


def _on_mask(mask, paths) -> float:
    from img2dmp.metrics import resample_by_arc_length

    pts = np.concatenate([resample_by_arc_length(p[None], 64)[0] for p in paths])
    r = np.clip(np.round(pts[:, 1]).astype(int), 0, mask.shape[0] - 1)
    c = np.clip(np.round(pts[:, 0]).astype(int), 0, mask.shape[1] - 1)
    return float(mask[r, c].mean())


def _written(mask, paths, radius) -> float:
    from scipy.ndimage import distance_transform_edt

    from img2dmp.metrics import resample_by_arc_length

    drawn = np.zeros(mask.shape, bool)
    for p in paths:
        pts = resample_by_arc_length(p[None], 256)[0]
        r = np.clip(np.round(pts[:, 1]).astype(int), 0, mask.shape[0] - 1)
        c = np.clip(np.round(pts[:, 0]).astype(int), 0, mask.shape[1] - 1)
        drawn[r, c] = True
    return float((distance_transform_edt(~drawn)[mask] <= radius).mean())


def fit_score_percentiles(model, data_path: str, limit: int = 600) -> dict:
    """Percentiles (1, 2, 5, 10, 50) of ``path_on_ink`` and ``ink_written``
    (:func:`img2dmp.predict.fit_score`) of the model's top hypothesis on the first
    ``limit`` validation images of a data set: where the flags' thresholds stand."""
    from img2dmp.data.store import load_dataset
    from img2dmp.predict import fit_score

    d = load_dataset(data_path)
    idx = np.flatnonzero(d.split == 1)[:limit]
    params, _ = model.predict_hypotheses(d.images[idx])
    _, paths = model.trajectories(params[:, 0], n_points=100)
    fits = [fit_score(x, y, model.stroke_width) for x, y in zip(d.images[idx], paths, strict=True)]
    q = [1, 2, 5, 10, 50]
    return {key: dict(zip(map(str, q), np.percentile([f[key] for f in fits], q).round(3).tolist(),
                          strict=True)) for key in ("path_on_ink", "ink_written")}  # fmt: skip


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", required=True)
    p.add_argument("--refine", type=int, default=30)
    p.add_argument("--data", default="../shared/data")
    p.add_argument("--pages", type=int, default=24)
    p.add_argument("--split", choices=("validation", "test"), default="validation")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--crops", action="store_true", help="also hand-cropped characters")
    p.add_argument("--photos", help="a folder of photos with photos.json")
    p.add_argument(
        "--fit-scores",
        metavar="DATA",
        help="also the fit scores' percentiles on this data set's validation images",
    )
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    import torch

    from img2dmp.predict import load_model

    torch.set_num_threads(args.threads)
    model = load_model(args.model, refine=args.refine)
    start = time.perf_counter()
    report = {"run": run_record(__file__, argv)}
    if args.pages:
        report["generated"] = summarise_generated(generated(model, args))
    if args.photos:
        report["photos"] = photos(model, Path(args.photos))
    if args.fit_scores:
        report["fit_scores"] = fit_score_percentiles(model, args.fit_scores)
    report["wall_s"] = round(time.perf_counter() - start, 1)
    write_report(args.out, "page_reading", report)
    print(format_record(report["run"]))
    print(json.dumps({k: v for k, v in report.items() if k != "run"}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
