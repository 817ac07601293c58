"""Table I's "error in px" read four ways, for one trained network on one data set (issue 21).

The paper reports its trajectory errors in pixels without saying how a sample's error is
reduced over its time stamps and its two coordinates. This project's reading (``img2dmp
evaluate``) is the mean Euclidean distance. Three other readings are as natural, and this
script prints all four for the same predictions, averaged over the samples:

- mean Euclidean distance ``mean_t |d(t)|`` (ours);
- mean absolute error per coordinate ``mean_{t,c} |d_c(t)|``;
- root mean square distance ``sqrt(mean_t |d(t)|^2)``, the square root of cost (10);
- root mean square per coordinate ``sqrt(mean_{t,c} d_c(t)^2)``, the square root of cost
  (10) written as the mean over every element of the difference (as ``torch.mean`` or
  ``numpy.mean`` of ``(y - y*)**2`` computes it).

For errors of equal size in both coordinates the four stand roughly as 1 : 0.64 : 1.13 :
0.80 (Gaussian errors), so the reading decides whether a figure is within 10 % of another.

Usage::

    python experiments/metric_readings.py RUN DATA.safetensors [--split test] [--digits 2]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from img2dmp.data.store import load_dataset
from img2dmp.predict import Predictor

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record

READINGS = (
    "mean Euclidean distance (ours)",
    "mean absolute error per coordinate",
    "RMS distance",
    "RMS per coordinate",
)


def readings(y: np.ndarray, demo: np.ndarray) -> dict[str, np.ndarray]:
    """The four per-sample errors ``[M]`` of predictions ``y`` against ``demo`` (both
    ``[M, T, d]``, the same time stamps; x, y used), keyed by :data:`READINGS`."""
    diff = np.asarray(y, np.float64)[..., :2] - np.asarray(demo, np.float64)[..., :2]
    sq = (diff**2).sum(-1)  # [M, T]
    return dict(
        zip(
            READINGS,
            (
                np.sqrt(sq).mean(-1),
                np.abs(diff).mean(axis=(-1, -2)),
                np.sqrt(sq.mean(-1)),
                np.sqrt((diff**2).mean(axis=(-1, -2))),
            ),
            strict=True,
        )
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("model", help="run directory or checkpoint")
    p.add_argument("data", help="data-set file")
    p.add_argument("--split", default="auto", choices=("auto", "all", "test", "validation"))
    p.add_argument("--digits", help="only these digits, e.g. 2 or 3,5 (default: all)")
    args = p.parse_args(argv)
    print(format_record(run_record(__file__, sys.argv[1:] if argv is None else list(argv))))
    data = load_dataset(args.data)
    split = args.split
    if split == "auto":
        split = "test" if (data.split == 2).any() else "all"
    if split != "all":
        data = data.select_split(split)
    if args.digits:
        wanted = [int(d) for d in args.digits.split(",")]
        data = data.subset(np.isin(data.labels, data.labels_of_digits(wanted)))
    y = Predictor.load(args.model).trajectories_for_images(data.images, data.times)
    print(f"{args.model} on {len(data)} samples of {args.data} [{split}]:")
    for name, e in readings(y, data.trajectories).items():
        print(f"  {name:36s} {e.mean():.3f} +- {e.std():.3f} px")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
