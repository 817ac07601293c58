"""Predict the DMP that writes the digit in each image (PNG/JPEG of any size).

Each image is brought to the model's input as the training images were made (polarity
from the border, crop to the ink, pad to square, strokes thickened or thinned to the
training images' pen width, resize, ink = 1). Without --out the
predictions are printed as JSON; with --out each image gets NAME_dmp.json (parameters and
sampled trajectory), NAME_trajectory.csv and, with --overlay, NAME_overlay.png.

NAME is the image file's name without its extension, so two images of one name from
different folders (A/x.png and C/x.png) would write the same files: that is refused, naming
both, before anything is predicted; predict them into different --out directories. Files
already in --out are replaced only with --force, also checked before anything is done.

A network with several hypotheses (model.hypotheses) gives all of them, ranked by
probability: the JSON's "dmp" and "trajectory" are the top one's (the one `img2dmp write`
writes) and "hypotheses" lists every one; the CSV gets rank and probability columns; the
overlay draws the top one bold. --refine N pulls each DMP onto the ink of its image with N
gradient steps near the network's output (img2dmp.nn.refine).

  img2dmp predict --model runs/paper my_digit.jpg --out pred --overlay
"""

from __future__ import annotations

import argparse
import json
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
    p.add_argument("--overlay", action="store_true", help="also draw NAME_overlay.png")
    _args.add_force(p, "files in --out")
    p.add_argument(
        "--points",
        metavar="N",
        type=_args.int_at_least(2, MAX_POINTS),
        default=100,
        help="trajectory samples over [0, tau]",
    )
    _args.add_refine(p)
    p.add_argument(
        "--keep-stroke-width",
        action="store_true",
        help="do not bring the strokes to the training images' pen width",
    )


def output_files(args: argparse.Namespace) -> list[tuple[Path, str]]:
    """(file written, its image) for every image, in order; none without --out."""
    if not args.out:
        return []
    suffixes = ["_dmp.json", "_trajectory.csv"] + (["_overlay.png"] if args.overlay else [])
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
    _args.check_outputs(output_files(args), args.force)
    _args.check_images(args.images)
    predictor = Predictor.load(args.model)
    if args.refine:
        predictor.refine_options = RefineOptions(steps=args.refine)
    images = []
    for path in args.images:  # all read before anything is written
        with _args.reading_image(path):
            images.append(predictor.prepare_paths([path], not args.keep_stroke_width)[0])
    records = []
    for path, image in zip(args.images, images, strict=True):
        rec = _record(predictor, image, str(path), args.points)
        records.append(rec)
        if args.out:
            files = write_prediction(
                args.out, Path(path).stem, rec, image if args.overlay else None
            )
            tau = rec["dmp"]["tau"]
            print(f"{path}: tau = {float(tau):.3f} s -> " + ", ".join(str(f) for f in files))
    if not args.out:
        print(json.dumps(records if len(records) > 1 else records[0], indent=1))
    return 0


def _record(predictor, image, source: str, points: int) -> dict:
    """The prediction record of one prepared image: the top DMP, and with a
    multi-hypothesis network every hypothesis ranked."""
    from ..predict import hypothesis_record, prediction_record

    params, probs = predictor.predict_hypotheses(image[None])  # [1, K], ranked
    ranked = []
    for k in range(params.batch_shape[1]):
        t, y = predictor.trajectories(params[0, k], n_points=points)
        ranked.append((params[0, k], t, y, float(probs[0, k])))
    top, t, y, _ = ranked[0]
    hyps = None
    if len(ranked) > 1:
        hyps = [hypothesis_record(k + 1, p, q, tk, yk) for k, (q, tk, yk, p) in enumerate(ranked)]
    return prediction_record(top, t, y, source, hyps)
