"""Predict the DMP that writes the digit in each image (PNG/JPEG of any size).

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
gradient steps near the network's output (img2dmp.nn.refine).

  img2dmp predict --model runs/paper my_digit.jpg --out pred --overlay
  img2dmp write --dmp pred/my_digit_dmp.json
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
    _args.add_model(p, required=True)
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
    _args.add_device(p, "the network")
    p.add_argument(
        "--keep-stroke-width",
        action="store_true",
        help="do not bring the strokes to the training images' pen width",
    )


def output_files(args: argparse.Namespace) -> list[tuple[Path, str]]:
    """(file written, its image) for every image, in order; none without --out."""
    if not args.out:
        return []
    suffixes = ["_dmp.json", "_trajectory.csv"]
    suffixes += ["_overlay.png", "_overlay_image.png"] if args.overlay else []
    return [
        (Path(args.out) / f"{Path(path).stem}{suffix}", path)
        for path in args.images
        for suffix in suffixes
    ]


def run(args: argparse.Namespace) -> int:
    from ..nn.refine import RefineOptions
    from ..predict import Predictor, write_prediction

    _args.check_inputs(args.images, "image")
    if args.out:
        _args.check_output_dir(args.out, "--out")
    inputs = [("image", path) for path in args.images] + _args.model_inputs(args.model)
    _args.check_outputs(output_files(args), args.force, inputs)
    _args.check_images(args.images)
    predictor = Predictor.load(args.model, device=_args.check_device(args.device))
    if args.refine:
        predictor.refine_options = RefineOptions(steps=args.refine)
    predictions = []
    for path in args.images:  # all predicted and checked before anything is written
        with _args.reading_image(path):
            pred = predictor.predict(
                path, n_points=args.points, match_stroke_width=not args.keep_stroke_width
            )
        name = Path(args.out) / f"{Path(path).stem}_dmp.json" if args.out else path
        predictions.append((path, pred, pred.to_json(name)))
    if not args.out:
        texts = [text.rstrip() for _, _, text in predictions]
        print(texts[0] if len(texts) == 1 else "[\n" + ",\n".join(texts) + "\n]")
        return 0
    for path, pred, text in predictions:
        files = write_prediction(args.out, Path(path).stem, pred, overlay=args.overlay, text=text)
        tau = float(pred.dmp.tau)
        print(f"{path}: tau = {tau:.3f} s -> " + ", ".join(str(f) for f in files))
    return 0
