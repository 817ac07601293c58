"""Predict the DMP that writes the digit in each image (PNG/JPEG of any size).

--model is a shipped model's name (img2dmp models lists them), a run directory or a
checkpoint; without it the default shipped model digits-real reads the images, refined
with the 30 steps its card recommends (--refine 0 for the network's output as it is).

Each image is brought to the model's input as the training images were made (polarity
from the border, crop to the ink, pad to square, strokes thickened or thinned to the
training images' pen width, resize, ink = 1). Without --out the DMP files are printed;
with --out each image gets NAME_dmp.json, NAME_trajectory.csv and, with --overlay,
NAME_overlay.png and NAME_overlay_image.png.

NAME_dmp.json is the one DMP file of img2dmp (format "img2dmp-dmp", version 2; see
docs/ROBOT.md): `img2dmp write --dmp NAME_dmp.json` writes it with the robot. Its
"params" is the top hypothesis, in the MODEL frame (the prepared image, image_size
pixels); "hypotheses" lists every one ranked by probability with its DMP in the model
frame ("params") and in the frame of your own image ("params_image") and its sampled
trajectory in both ("xy_model_px", "xy_image_px"); "image_frame" holds the affine map
between the frames ("image_to_model", "model_to_image"). The CSV has the columns rank,
probability, t_s, x_model_px, y_model_px, x_image_px, y_image_px (and pen). Pixels:
x = column, y = row, the centre of pixel [i, j] at (j, i). NAME_overlay.png draws the
paths on the model's input, NAME_overlay_image.png on your image.

NAME is the image file's name without its extension, so two images of one name from
different folders (A/x.png and C/x.png) would write the same files: that is refused, naming
both, before anything is predicted; predict them into different --out directories. Files
already in --out are replaced only with --force, also checked before anything is done.

A network with several hypotheses (model.hypotheses) gives all of them, ranked; the
overlays draw the top one bold. --refine N pulls each DMP onto the ink of its image with N
gradient steps near the network's output (img2dmp.nn.refine); not given, a shipped model
uses its card's recommendation and a run directory its training configuration's reading
section (docs/TRAINING.md; 0 where it says nothing).

Every prediction carries a fit score ("fit": the share of its path on the ink and of the
ink its path writes) and "flags" for what looks wrong ("off_ink", "unexplained_ink",
"several_characters", "unfamiliar": unlike what the model learnt); a flagged image gets
a one-line warning on stderr.

--page reads every character of a photo or scan of a page (found, put in reading order,
each predicted where it stands) and writes NAME_page.json (format "img2dmp-page",
docs/PAGE.md) and NAME_page.png (the page with every box and path). --explain also writes
NAME_explain.png: each step that separates the ink from the paper.

  img2dmp predict examples/samples/digit_3.png --out pred --overlay
  img2dmp write --dmp pred/digit_3_dmp.json
  img2dmp predict --model runs/paper my_digit.jpg --out pred --overlay
  img2dmp predict examples/samples/page.jpg --page --out pages
"""

from __future__ import annotations

import argparse
from pathlib import Path

from . import _args

HELP = "DMP parameters and trajectory for image files"
#: Largest --points (img2dmp.predict.MAX_POINTS; a literal: this module must not import torch).
MAX_POINTS = 100_000


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("images", nargs="+", metavar="IMAGE", help="PNG or JPEG files")
    _args.add_model(p, default_shipped=True)
    p.add_argument(
        "--out", metavar="DIR", help="write JSON/CSV (and PNG) files here instead of printing"
    )
    p.add_argument(
        "--overlay",
        action="store_true",
        help="also draw the paths on the model's input (NAME_overlay.png, model frame) and "
        "on your image (NAME_overlay_image.png, image frame)",
    )
    _args.add_force(p, "files in --out")
    p.add_argument(
        "--points",
        metavar="N",
        type=_args.int_at_least(2, MAX_POINTS),
        default=100,
        help="trajectory samples over [0, tau]",
    )
    _args.add_refine(p)
    _args.add_count_views(p)
    _args.add_device(p, "the network")
    _args.add_backend(p)
    _args.add_no_progress(p)
    p.add_argument(
        "--keep-stroke-width",
        action="store_true",
        help="do not bring the strokes to the training images' pen width",
    )
    p.add_argument(
        "--page",
        action="store_true",
        help="each IMAGE is a page: read every character on it (NAME_page.json and "
        "NAME_page.png in --out; without --out the page document is printed)",
    )
    p.add_argument(
        "--explain",
        action="store_true",
        help="also draw each step that separates the ink from the paper (NAME_explain.png; "
        "needs --out)",
    )


def output_files(args: argparse.Namespace) -> list[tuple[Path, str]]:
    """(file written, its image) for every image, in order; none without --out."""
    if not args.out:
        return []
    if args.page:
        suffixes = ["_page.json", "_page.png"]
    else:
        suffixes = ["_dmp.json", "_trajectory.csv"]
        suffixes += ["_overlay.png", "_overlay_image.png"] if args.overlay else []
    suffixes += ["_explain.png"] if args.explain else []
    return [
        (Path(args.out) / f"{Path(path).stem}{suffix}", path)
        for path in args.images
        for suffix in suffixes
    ]


def _check_options(args: argparse.Namespace) -> None:
    if args.explain and not args.out:
        raise ValueError("--explain draws into a file: give --out DIR")
    if args.page and args.overlay:
        raise ValueError("--overlay is for single characters: --page always draws the page "
                         "(NAME_page.png)")  # fmt: skip


def _explain(args, path, photo_boxes=None) -> Path:
    """``NAME_explain.png``: the paper steps of ``path`` as read, with ``photo_boxes``
    (the characters' boxes in the photo's own pixels) drawn on them."""
    from ..data.images import paper_steps
    from ..data.plotting import paper_steps_figure
    from ..page import PAGE_WORK_PIXELS

    if args.page:
        found, reduction = paper_steps(path, max_pixels=PAGE_WORK_PIXELS, steady=True)
    else:
        found, reduction = paper_steps(path)
    out = Path(args.out) / f"{Path(path).stem}_explain.png"
    if found is None:
        raise ValueError(f"{path}: nothing stands out from the paper: no steps to draw")
    boxes = None
    if photo_boxes is not None:  # in the pixels of the steps (the photo as read)
        boxes = [[v / reduction for v in box] for box in photo_boxes]
    return paper_steps_figure(out, found, boxes, title=f"{path}: from the photo to the ink")


def _images_bar(args, unit: str = "image"):
    """``args.images``, with a live bar on a terminal when there are several (it leaves
    nothing behind, and prints nothing into a log: :func:`img2dmp._progress.bar`)."""
    from .._progress import bar

    several = len(args.images) > 1 and not args.no_progress
    return bar(args.images, desc="predict", unit=unit, enabled=several, leave=False)


def _run_pages(args, predictor) -> int:
    pages = []
    for path in _images_bar(args, "page"):  # all read before anything is written
        with _args.reading_image(path):
            pages.append((path, predictor.predict_page(path, n_points=args.points,
                          match_stroke_width=not args.keep_stroke_width)))  # fmt: skip
    if not args.out:
        texts = [page.to_json().rstrip() for _, page in pages]
        print(texts[0] if len(texts) == 1 else "[\n" + ",\n".join(texts) + "\n]")
    for path, page in pages:
        flagged = page.flagged
        _args.warn_page("predict", path, page)
        if not args.out:
            continue
        files = page.save(args.out, Path(path).stem)
        if args.explain:
            files.append(_explain(args, path, [c.box_image for c in page.characters]))
        strokes = [getattr(c.prediction, "n_strokes", None) for c in page.characters]
        n = "" if None in strokes or not strokes else f" ({sum(strokes)} strokes)"
        written = ", ".join(str(f) for f in files)
        print(f"{path}: {len(page.characters)} characters{n} in {len(page.lines)} lines"
              f"{_page_notes(page)}, {len(flagged)} flagged -> {written}")  # fmt: skip
    return 0


def _page_notes(page) -> str:
    """What the summary line of a page says was done to read it: turned, a glare's
    contrast given back, a shake undone."""
    d = page.turn_deg  # < 0: lines rising to the right, turned clockwise to lie level
    way = "clockwise" if d < 0 else "counter-clockwise"
    why = "to level them" if abs(d) < 45.0 else "to read it upright"  # sideways, upside down
    notes = [f"turned {abs(d):.1f} degrees {way} {why}"] if d else []
    if page.glare_gain > 1.0:
        notes.append(f"a glare's washed-out ink given back its contrast, up to "
                     f"{page.glare_gain:.1f}x")  # fmt: skip
    if page.shake is not None:
        length, degrees = page.shake
        notes.append(f"a shake of {length:.1f} px at {degrees:.0f} degrees undone")
    return "".join(f" ({note})" for note in notes)


def run(args: argparse.Namespace) -> int:
    _args.one_thread()  # first: before NumPy is imported, so that OpenBLAS takes it too
    from ..predict import Predictor, write_prediction

    _check_options(args)
    _args.check_inputs(args.images, "image")
    if args.out:
        _args.check_output_dir(args.out, "--out")
    model = _args.model_or_default(args.model)
    inputs = [("image", path) for path in args.images] + _args.model_inputs(model)
    _args.check_outputs(output_files(args), args.force, inputs)
    _args.check_images(args.images)
    predictor = Predictor.load(model, device=_args.check_device(args.device),
                               backend=args.backend)  # fmt: skip
    _args.set_count_views(args, predictor)
    _args.set_refinement(args, model, predictor, "predict")
    if args.page:
        return _run_pages(args, predictor)
    predictions = []
    for path in _images_bar(args):  # all predicted and checked before anything is written
        with _args.reading_image(path):
            pred = predictor.predict(
                path, n_points=args.points, match_stroke_width=not args.keep_stroke_width
            )
        name = Path(args.out) / f"{Path(path).stem}_dmp.json" if args.out else path
        predictions.append((path, pred, pred.to_json(name)))
    for path, pred, _ in predictions:
        _args.warn_flags("predict", path, pred)
    if not args.out:
        texts = [text.rstrip() for _, _, text in predictions]
        print(texts[0] if len(texts) == 1 else "[\n" + ",\n".join(texts) + "\n]")
        return 0
    for path, pred, text in predictions:
        files = write_prediction(args.out, Path(path).stem, pred, overlay=args.overlay, text=text)
        if args.explain:
            files.append(_explain(args, path))
        n = getattr(pred, "n_strokes", None)  # a stroke model's: its strokes' durations
        tau = float(pred.dmp.tau) if n is None else float(pred.strokes.tau.sum())
        what = f"tau = {tau:.3f} s" if n is None else f"{n} strokes, {tau:.3f} s of writing"
        sure = getattr(pred, "count_probability", None)
        if sure is not None:
            what += f" (the count's probability {sure:.2f})"
        elif pred.n_hypotheses > 1:
            what += f", top hypothesis of {pred.n_hypotheses}: p = {pred.probabilities[0]:.2f}"
        fit = pred.fit
        what += f"; path on ink {fit['path_on_ink']:.2f}, ink written {fit['ink_written']:.2f}"
        print(f"{path}: {what} -> " + ", ".join(str(f) for f in files))
    return 0
