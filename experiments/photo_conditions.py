"""Phone photos as people take them: shadows, glare, blur, distance, JPEG, pen and light.

Each condition (:data:`CONDITIONS`; ``--conditions`` names a subset, by name or family)
is a function of an RGB image (float, 0-255, ``[H, W, 3]``) and a random generator,
seeded from the run's seed, the image and the condition alone (a subset gives the same
images as the full run):

- **shadow** across the page, the far side at 0.7, 0.5 or 0.3 of the light, its edge
  hard (a logistic of 0.75 % of the shorter side) or soft (10 %), straight down the
  middle or diagonal (through 0.5 of the width and 0.6 of the height, falling 0.3 of a
  pixel per pixel);
- **glare**: a bright spot (Gaussian, 0.25 of the shorter side at 0.3 of the width, or
  0.4 at 0.6), the image brought towards white by 0.5 or 0.8 at its centre, so that the
  ink keeps 50 or 20 % of its contrast there;
- **motion** blur, horizontal or vertical, 5 or 9 px (a box along the line);
- **slant**: a motion blur at 15, 30 or 120 degrees from the rows (9 px) or at 45 (5 or
  9 px): the image moved along a straight line, a copy every tenth of a pixel, each
  shifted by bilinear interpolation (:func:`slanted`; conditions added after the others,
  so that the others' generators are as they were);
- **dim shake**: the motion of 9 px along the rows, or the slant of 9 px at 30 degrees,
  then the warm, dim and noisy light (a shake is likeliest where the light is dim and
  the exposure long);
- **defocus**: a Gaussian of sigma 1, 1.5 or 2 px;
- **far** away: the photo scaled by 0.5, 0.35, 0.25 or 0.18 (Lanczos; the shared photos'
  digits about 10 px tall at 0.25);
- **jpeg**: saved at quality 20;
- **pen**: pencil (the ink at 0.35 of its darkness, grainy: 25 % noise) or a marker (the
  ink grown by 2 px, at the image's darkest colour), the ink separated from the paper
  by the paper's local level (85th percentile over 41 px);
- **light**: warm, dim and noisy (channels at 0.55, 0.42, 0.28; noise of 8 levels).

They are applied to

(a) the two shared photos (``--photos``, ``../shared/data/photos``), each read by
:func:`img2dmp.page.segment_page` and scored as ``sheet_on_desk.py`` and
``tilted_pages.py`` score them: *matched* / *extra* against the boxes found on the
photo as shipped (moved as the photo was scaled; :func:`sheet_on_desk.score`), and
*miscounted* against ``photos.json`` (:func:`page_reading.miscounted`);

(b) generated pages with known characters (``--pages N``: :func:`page_reading.generated_pages`,
the pages of ``page_segmentation.py``, MNIST digits of ``--split`` on ruled, squared,
dotted and plain paper in turn; validation seed 100 by default; ``--split test`` takes
the test digits and seed 500, kept apart for the figures): each true character
*found* / merged / split / missed (:func:`page_segmentation.classify`), *missed* in the
summary being all those not found, and *extra* boxes.

One summary table per part gives the totals per family, for a before/after comparison of
a change to the preparation. ``--model NAME`` reads every image with that model as
``predict --page`` does and counts the characters it flags. A page that
:func:`segment_page` finds too small to read (``too_small``) is counted in *too small*.
``--out DIR`` gets ``photo_conditions.json`` (date, revision, command, CPU, every row)
and ``photo_conditions.md`` (the tables).

    python experiments/photo_conditions.py --photos ../shared/data/photos --out /tmp/cond
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from _provenance import cpu_name, format_record, run_record, write_report
from _provenance import markdown_table as _table
from page_reading import generated_pages, miscounted, page_sources
from page_segmentation import CLASSES, classify
from sheet_on_desk import score, shipped_photos
from tilted_pages import _as_read, true_lines

#: The generated pages' seed per split (the test split's kept apart for the figures).
SEEDS = {"validation": 100, "test": 500}
#: Shadow edges, as a fraction of the image's shorter side (the logistic's scale).
SHADOW_EDGE = {"hard": 0.0075, "soft": 0.1}
#: Glare spots: (centre x as a fraction of the width, radius as a fraction of the shorter
#: side); the centre's row at 0.45 of the height.
GLARE_SPOTS = {"small": (0.3, 0.25), "large": (0.6, 0.4)}
#: Pencil: the ink's darkness kept, and its grain (relative noise).
PENCIL = (0.35, 0.25)
#: Marker: the ink grown by this many pixels.
MARKER_PX = 2
#: Warm, dim light: the channels' gains, and the noise (grey levels).
WARM_DIM = ((0.55, 0.42, 0.28), 8.0)


@dataclass(frozen=True)
class Condition:
    name: str  # no spaces: named on the command line
    family: str
    apply: object  # (rgb float [H, W, 3], rng) -> rgb float [h, w, 3]


def _paper_and_ink(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The paper's local colour ``[H, W, 3]`` (85th percentile over 41 px, on the image
    reduced 4 times, for speed) and the ink's share ``[H, W]`` in [0, 1] (its darkness
    against that paper, 0.5 of it counting as all ink)."""
    from scipy import ndimage as ndi

    h, w = rgb.shape[:2]
    small = rgb[: h - h % 4 or h, : w - w % 4 or w]
    if min(small.shape[:2]) >= 8:
        small = small.reshape(small.shape[0] // 4, 4, small.shape[1] // 4, 4, 3).max(axis=(1, 3))
    size = max(3, round(41 * small.shape[0] / max(1, h)))
    paper = np.stack([ndi.percentile_filter(small[..., c], 85, size=size) for c in range(3)], 2)
    paper = np.stack([ndi.zoom(paper[..., c], (h / paper.shape[0], w / paper.shape[1]), order=1,
                               grid_mode=True, mode="nearest") for c in range(3)], 2)  # fmt: skip
    paper = np.maximum(paper[:h, :w], rgb)
    grey, paper_grey = rgb.mean(2), paper.mean(2)
    alpha = np.clip((paper_grey - grey) / np.maximum(paper_grey, 1.0) / 0.5, 0.0, 1.0)
    return paper, alpha


def _grid(rgb):
    h, w = rgb.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    return yy, xx, h, w


def shadow(level: float, edge: str, diagonal: bool):
    def apply(rgb, rng):
        yy, xx, h, w = _grid(rgb)
        across = (yy - 0.6 * h + 0.3 * (xx - 0.5 * w)) if diagonal else (xx - 0.5 * w)
        soft = SHADOW_EDGE[edge] * min(h, w)
        light = 1.0 - (1.0 - level) / (1.0 + np.exp(-np.clip(across / soft, -50, 50)))
        return rgb * light[..., None]

    return apply


def glare(strength: float, spot: str):
    def apply(rgb, rng):
        yy, xx, h, w = _grid(rgb)
        cx, radius = GLARE_SPOTS[spot]
        r = radius * min(h, w)
        g = np.exp(-((xx - cx * w) ** 2 + (yy - 0.45 * h) ** 2) / (2.0 * r * r))[..., None]
        return rgb * (1.0 - strength * g) + 255.0 * strength * g

    return apply


def motion(length: int, axis: int):
    def apply(rgb, rng):
        from scipy.ndimage import uniform_filter1d

        return uniform_filter1d(rgb, length, axis=axis, mode="nearest")

    return apply


def slanted(length: float, degrees: float):
    def apply(rgb, rng):
        from scipy.ndimage import convolve

        t = np.linspace(-length / 2, length / 2, round(10 * length) + 1)
        theta = np.deg2rad(degrees)
        reach = int(np.ceil(length / 2)) + 1
        y, x = reach + 1 + t * np.sin(theta), reach + 1 + t * np.cos(theta)
        kernel = np.zeros((2 * reach + 3, 2 * reach + 3))  # odd: its centre at reach + 1
        y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
        for dy, dx in ((0, 0), (0, 1), (1, 0), (1, 1)):  # each copy's bilinear weights
            weight = np.abs(1 - dy - (y - y0)) * np.abs(1 - dx - (x - x0))
            np.add.at(kernel, (y0 + dy, x0 + dx), weight)
        kernel = (kernel / kernel.sum())[..., None]
        return convolve(rgb, kernel, mode="nearest")  # the line is symmetric

    return apply


def defocus(sigma: float):
    def apply(rgb, rng):
        from scipy.ndimage import gaussian_filter

        return gaussian_filter(rgb, (sigma, sigma, 0.0), mode="nearest")

    return apply


def far(scale: float):
    def apply(rgb, rng):
        from PIL import Image

        h, w = rgb.shape[:2]
        im = Image.fromarray(np.clip(rgb + 0.5, 0, 255).astype(np.uint8))
        size = (max(2, round(w * scale)), max(2, round(h * scale)))
        return np.asarray(im.resize(size, Image.Resampling.LANCZOS), np.float64)

    return apply


def jpeg(quality: int):
    def apply(rgb, rng):
        from PIL import Image

        buf = io.BytesIO()
        im = Image.fromarray(np.clip(rgb + 0.5, 0, 255).astype(np.uint8))
        im.save(buf, "JPEG", quality=quality)
        return np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB"), np.float64)

    return apply


def pencil(rgb, rng):
    paper, alpha = _paper_and_ink(rgb)
    keep, grain = PENCIL
    a = np.clip(alpha * keep * (1.0 + grain * rng.standard_normal(alpha.shape)), 0, 1)[..., None]
    return paper * (1.0 - a)


def marker(rgb, rng):
    from scipy.ndimage import grey_dilation

    paper, alpha = _paper_and_ink(rgb)
    a = grey_dilation(alpha, size=(2 * MARKER_PX + 1,) * 2)[..., None]
    return paper * (1.0 - a) + a * rgb.min(axis=(0, 1))


def warm_dim_noisy(rgb, rng):
    gains, noise = WARM_DIM
    return rgb * np.array(gains) + noise * rng.standard_normal(rgb.shape)


def _conditions() -> list[Condition]:
    out = [Condition("as-is", "as is", lambda rgb, rng: rgb)]
    for level in (0.7, 0.5, 0.3):
        for edge in ("hard", "soft"):
            for diagonal in (False, True):
                way = "diagonal" if diagonal else "straight"
                out.append(Condition(f"shadow-{level:g}-{edge}-{way}", "shadow",
                                     shadow(level, edge, diagonal)))  # fmt: skip
    for strength in (0.5, 0.8):
        for spot in GLARE_SPOTS:
            out.append(Condition(f"glare-{strength:g}-{spot}", "glare", glare(strength, spot)))
    for axis, way in ((1, "h"), (0, "v")):
        for length in (5, 9):
            out.append(Condition(f"motion-{way}{length}", "motion", motion(length, axis)))
    for sigma in (1.0, 1.5, 2.0):
        out.append(Condition(f"defocus-{sigma:g}", "defocus", defocus(sigma)))
    for scale in (0.5, 0.35, 0.25, 0.18):
        out.append(Condition(f"far-{scale:g}", "far", far(scale)))
    out.append(Condition("jpeg-20", "jpeg", jpeg(20)))
    out.append(Condition("pencil", "pen", pencil))
    out.append(Condition("marker", "pen", marker))
    out.append(Condition("warm-dim-noisy", "light", warm_dim_noisy))
    for degrees, length in ((15, 9), (30, 9), (45, 5), (45, 9), (120, 9)):
        out.append(Condition(f"slant-{degrees}-{length}", "slant", slanted(length, degrees)))
    for name, moved in (("motion-h9", motion(9, 1)), ("slant-30-9", slanted(9, 30))):
        out.append(Condition(f"{name}+dim", "dim shake", _then(moved, warm_dim_noisy)))
    return out


def _then(first, second):
    """A condition that applies ``first``, then ``second``."""
    return lambda rgb, rng: second(first(rgb, rng), rng)


#: Every condition, in the tables' order.
CONDITIONS = _conditions()
FAMILIES = tuple(dict.fromkeys(c.family for c in CONDITIONS))


def select(text: str | None) -> list[Condition]:
    """The conditions named in ``text`` (comma-separated names or families; None: all).
    ``ValueError`` naming an unknown one."""
    if not text:
        return list(CONDITIONS)
    names = [t.strip() for t in text.split(",") if t.strip()]
    known = {c.name for c in CONDITIONS} | set(FAMILIES)
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"--conditions: unknown {', '.join(unknown)} (names: "
                         f"{', '.join(c.name for c in CONDITIONS)}; families: "
                         f"{', '.join(FAMILIES)})")  # fmt: skip
    return [c for c in CONDITIONS if c.name in names or c.family in names]


def apply(condition: Condition, rgb: np.ndarray, seed: int, image: int) -> np.ndarray:
    """``condition`` applied to ``rgb`` (``uint8`` or float ``[H, W, 3]``, 0-255) with the
    generator of ``(seed, image, condition)``: ``uint8 [h, w, 3]``."""
    index = [c.name for c in CONDITIONS].index(condition.name)
    rng = np.random.default_rng([seed, image, index])
    out = condition.apply(np.asarray(rgb, np.float64), rng)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def _read(model, image):
    """``(segmentation or page prediction, boxes in the pixels as read, boxes in the
    image's pixels, characters per line, flagged, too small)``."""
    from img2dmp.page import segment_page

    seg = segment_page(image) if model is None else model.predict_page(image)
    chars = seg.layout.characters
    if model is None:
        in_image = [seg.box_in_image(c) for c in chars]
    else:
        in_image = [c.box_image for c in seg.characters]
    flagged = None if model is None else len(seg.flagged)
    small = bool(getattr(seg, "too_small", False)) or "too_small" in getattr(seg, "flags", [])
    return (seg, [c.box for c in chars], in_image, [len(i) for i in seg.layout.lines], flagged,
            small)  # fmt: skip


def photo_rows(folder, conditions, seed: int, model=None) -> list[dict]:
    """One row per shared photo and condition (module docstring, (a))."""
    truth = true_lines(Path(folder))
    rows = []
    for k, (file, photo, ref) in enumerate(shipped_photos(folder)):
        rgb = np.asarray(photo)
        for cond in conditions:
            image = apply(cond, rgb, seed, k)
            sy, sx = image.shape[0] / rgb.shape[0], image.shape[1] / rgb.shape[1]
            start = time.perf_counter()
            seg, boxes, _, lines, flagged, small = _read(model, image)
            wall = time.perf_counter() - start
            matched, extra = score(boxes, [_as_read(seg, x * sx, y * sy) for x, y in ref])
            rows.append({"photo": file, "condition": cond.name, "family": cond.family,
                         "size": [image.shape[1], image.shape[0]], "reference": len(ref),
                         "boxes": len(boxes), "matched": matched, "extra": extra,
                         "miscounted": miscounted(truth[file], lines), "lines": lines,
                         "too_small": small, "flagged": flagged,
                         "wall_s": round(wall, 3)})  # fmt: skip
            print(f"{file}: {cond.name}: {len(boxes)} boxes, matched {matched} of {len(ref)}, "
                  f"extra {extra}, miscounted {rows[-1]['miscounted']}", flush=True)  # fmt: skip
    return rows


def page_rows(data, split: str, pages: int, conditions, page_seed: int, seed: int,
              model=None) -> list[dict]:  # fmt: skip
    """One row per generated page (of ``page_seed``) and condition (its noise of ``seed``;
    module docstring, (b))."""
    rows = []
    for p, kind, page in generated_pages(page_sources(data, split), pages, page_seed):
        truth = np.array([[int(v) for v in b] for b in page.boxes], np.float64)
        for cond in conditions:
            image = apply(cond, page.image, seed, 1000 + p)
            sy, sx = image.shape[0] / page.image.shape[0], image.shape[1] / page.image.shape[1]
            true = [tuple(b) for b in truth * [sx, sy, sx, sy]]
            _, _, boxes, lines, flagged, small = _read(model, image)
            classes, extra = classify(boxes, true)
            rows.append({"seed": page_seed + p, "kind": kind, "condition": cond.name,
                         "family": cond.family, "characters": len(true), "boxes": len(boxes),
                         **{c: classes.count(c) for c in CLASSES}, "extra": extra,
                         "miscounted": miscounted(np.bincount(page.lines).tolist(), lines),
                         "too_small": small, "flagged": flagged})  # fmt: skip
        print(f"page {p + 1}/{pages} ({kind}, {len(truth)} characters)", flush=True)
    return rows


def _total(rows, keys) -> dict:
    out = {k: sum(r[k] for r in rows if r.get(k) is not None) for k in keys}
    out["images"], out["too_small"] = len(rows), sum(bool(r["too_small"]) for r in rows)
    if rows and rows[0].get("flagged") is not None:
        out["flagged"] = sum(r["flagged"] for r in rows)
    return out


def summarise(rows: list[dict], keys, by: str) -> list[dict]:
    """Totals of ``keys`` per ``by`` (``"family"`` or ``"condition"``), in the table order."""
    order = FAMILIES if by == "family" else [c.name for c in CONDITIONS]
    return [{by: g, **_total([r for r in rows if r[by] == g], keys)}
            for g in order if any(r[by] == g for r in rows)]  # fmt: skip


PHOTO_KEYS = ("reference", "boxes", "matched", "extra", "miscounted")
PAGE_KEYS = ("characters", "boxes", "found", "merged", "split", "missed", "extra")


def _photo_cells(e: dict) -> list:
    cells = [e["images"], e["reference"], e["boxes"], e["matched"], e["extra"], e["miscounted"],
             e["too_small"]]  # fmt: skip
    return cells + ([e["flagged"]] if "flagged" in e else [])


def _page_cells(e: dict) -> list:
    lost = e["characters"] - e["found"]
    share = 100.0 * e["found"] / max(1, e["characters"])
    cells = [e["images"], e["characters"], f"{e['found']} ({share:.1f} %)", e["extra"], lost,
             f"{e['merged']} / {e['split']} / {e['missed']}", e["too_small"]]  # fmt: skip
    return cells + ([e["flagged"]] if "flagged" in e else [])


def markdown(report: dict) -> str:
    out = [format_record(report["run"]), f"CPU: {report['cpu']}", ""]
    flag = ["flagged"] if report.get("model") else []
    photo_head = ["images", "reference", "boxes", "matched", "extra", "miscounted",
                  "too small", *flag]  # fmt: skip
    page_head = ["images", "characters", "found", "extra", "missed (all not found)",
                 "merged / split / missed", "too small", *flag]  # fmt: skip
    parts = (("photos", "The shared photos", photo_head, _photo_cells),
             ("pages", "Generated pages", page_head, _page_cells))  # fmt: skip
    for key, title, head, cells in parts:
        if not report.get(key):
            continue
        out += [f"{title}, per family:", ""]
        out += _table(["family", *head], [[e["family"], *cells(e)]
                                          for e in report[key]["families"]])  # fmt: skip
        out += [f"{title}, per condition:", ""]
        out += _table(["condition", *head], [[e["condition"], *cells(e)]
                                             for e in report[key]["conditions"]])  # fmt: skip
    return "\n".join(out).rstrip("\n") + "\n"


def add_photo_arguments(p: argparse.ArgumentParser) -> None:
    """``--photos`` (the two shared photos' folder, '' for none) and ``--data`` (the
    shared data folder, for generated pages), as the photo experiments take them."""
    p.add_argument("--photos", default="../shared/data/photos",
                   help="the folder of the two shared photos ('' for none)")  # fmt: skip
    p.add_argument("--data", default="../shared/data")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_photo_arguments(p)
    p.add_argument("--pages", type=int, default=4, help="generated pages (0: none)")
    p.add_argument("--split", choices=("validation", "test"), default="validation",
                   help="the generated pages' digits and seed (test: figures only)")  # fmt: skip
    p.add_argument("--conditions", default=None,
                   help="condition names or families, comma-separated (default: all)")  # fmt: skip
    p.add_argument("--model", default=None, help="read with this model; count flags")
    p.add_argument("--seed", type=int, default=0, help="the conditions' noise")
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    try:
        conditions = select(args.conditions)
    except ValueError as e:
        p.error(str(e))
    if args.pages < 0:
        p.error(f"--pages {args.pages}: give 0 or more")
    if args.pages and not (Path(args.data) / "ijs-mnist-trajectories").is_dir():
        sys.exit(f"no {Path(args.data) / 'ijs-mnist-trajectories'}: --data names the shared "
                 "data folder (or --pages 0)")  # fmt: skip
    if args.photos and not (Path(args.photos) / "photos.json").is_file():
        sys.exit(f"no {Path(args.photos) / 'photos.json'}: --photos names the folder of the "
                 "two shared photos (or --photos '')")  # fmt: skip
    model = None
    if args.model:
        from img2dmp import load_model

        model = load_model(args.model)
    report = {"run": run_record(__file__, argv), "cpu": cpu_name(), "model": args.model,
              "split": args.split}  # fmt: skip
    print(format_record(report["run"]), f"\nCPU: {report['cpu']}", flush=True)
    start = time.perf_counter()
    if args.photos:
        rows = photo_rows(args.photos, conditions, args.seed, model)
        report["photos"] = {"families": summarise(rows, PHOTO_KEYS, "family"),
                            "conditions": summarise(rows, PHOTO_KEYS, "condition"),
                            "rows": rows}  # fmt: skip
    if args.pages:
        seed = SEEDS[args.split]
        rows = page_rows(args.data, args.split, args.pages, conditions, seed, args.seed, model)
        report["pages"] = {"seed": seed,
                           "families": summarise(rows, PAGE_KEYS, "family"),
                           "conditions": summarise(rows, PAGE_KEYS, "condition"),
                           "rows": rows}  # fmt: skip
    report["wall_s"] = round(time.perf_counter() - start, 1)
    write_report(args.out, "photo_conditions", report, markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
