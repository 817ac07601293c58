"""How much of a model's path error is the writing direction, which an image rarely shows.

For every sample of a data set's split, the model's top (optionally refined) path is
compared with the person's path as it was written and reversed (the same curve written the
other way round): the path error against the person's path, and the smaller of the two.
Their difference is what choosing the direction alone costs. Per digit it also prints the
share of closed loops the people wrote clockwise on screen and the share the model writes
clockwise (the sign of the winding area).

Usage::

    python experiments/direction_ambiguity.py --model runs/real/run \
        --data runs/real/data.safetensors --split test [--refine 30]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from img2dmp.data.store import load_dataset
from img2dmp.metrics import path_error_px, resample_by_arc_length
from img2dmp.nn.refine import RefineOptions
from img2dmp.predict import Predictor

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record


def signed_area(paths: np.ndarray) -> np.ndarray:
    """Shoelace area ``[M]`` of the arc-length-resampled closed polygons (x right, y down:
    positive = clockwise on screen)."""
    p = resample_by_arc_length(paths, 128)  # [M, n, 2]
    x, y = p[..., 0], p[..., 1]
    return 0.5 * (x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y).sum(axis=1)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", required=True, help="run directory or checkpoint")
    p.add_argument("--data", required=True, help="data-set file")
    p.add_argument("--split", default="test", choices=("train", "validation", "test"))
    p.add_argument("--refine", type=int, default=0, help="refinement steps (0 = none)")
    args = p.parse_args(argv)
    print(format_record(run_record(__file__, sys.argv[1:] if argv is None else list(argv))))
    data = load_dataset(args.data).select_split(args.split)
    pred = Predictor.load(args.model)
    if args.refine:
        pred.refine_options = RefineOptions(steps=args.refine)
    y = pred.trajectories_for_images(data.images, data.times)  # [M, T, d]
    demo = data.trajectories
    as_written = path_error_px(y, demo)
    either_way = np.minimum(as_written, path_error_px(y, demo[:, ::-1]))
    cw_people, cw_model = signed_area(demo) > 0, signed_area(y) > 0
    print(f"{'digit':>5} {'n':>4} {'path':>7} {'either way':>10} {'people cw':>9} {'model cw':>8}")
    for d in np.unique(data.labels):
        m = data.labels == d
        print(
            f"{int(d):>5} {int(m.sum()):>4} {as_written[m].mean():7.3f} "
            f"{either_way[m].mean():10.3f} {cw_people[m].mean():9.0%} {cw_model[m].mean():8.0%}"
        )
    print(f"{'all':>5} {len(y):>4} {as_written.mean():7.3f} {either_way.mean():10.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
