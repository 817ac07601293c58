"""Predict the DMP that writes the digit in each image (PNG/JPEG of any size).

Each image is brought to the model's input as the training images were made (polarity
from the border, crop to the ink, pad to square, strokes thickened or thinned to the
training images' pen width, resize, ink = 1). Without --out the
predictions are printed as JSON; with --out each image gets NAME_dmp.json (parameters and
sampled trajectory), NAME_trajectory.csv and, with --overlay, NAME_overlay.png.

  img2dmp predict --model runs/paper my_digit.jpg --out pred --overlay
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from . import _args

HELP = "DMP parameters and trajectory for image files"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("images", nargs="+", metavar="IMAGE", help="PNG or JPEG files")
    _args.add_model(p, required=True)
    p.add_argument(
        "--out", metavar="DIR", help="write JSON/CSV (and PNG) files here instead of printing"
    )
    p.add_argument("--overlay", action="store_true", help="also draw NAME_overlay.png")
    p.add_argument(
        "--points",
        metavar="N",
        type=_args.int_at_least(2),
        default=100,
        help="trajectory samples over [0, tau]",
    )
    p.add_argument(
        "--keep-stroke-width",
        action="store_true",
        help="do not bring the strokes to the training images' pen width",
    )


def run(args: argparse.Namespace) -> int:
    from ..predict import Predictor, prediction_record, write_prediction

    predictor = Predictor.load(args.model)
    results = predictor.predict_paths(args.images, not args.keep_stroke_width)
    records = []
    for path, (params, image) in zip(args.images, results, strict=True):
        t, y = predictor.trajectories(params, n_points=args.points)
        rec = prediction_record(params, t, y, str(path))
        records.append(rec)
        if args.out:
            files = write_prediction(
                args.out, Path(path).stem, rec, image if args.overlay else None
            )
            print(f"{path}: tau = {float(params.tau):.3f} s -> " + ", ".join(str(f) for f in files))
    if not args.out:
        print(json.dumps(records if len(records) > 1 else records[0], indent=1))
    return 0
