"""How much of the trajectory error on recorded MNIST paths no image can remove.

The recorded pen paths are compared with a network's DMP at the demonstration's own time
stamps (Table I's metric). The image shows the path's shape but not how fast the writer
moved along it. This script measures the error of predictors that know every test path's
shape *exactly* and only have to guess the speed profile, i.e. the arc-length fraction
``lambda(u)`` reached at each time stamp ``u``:

- ``constant speed``: ``lambda(u) = u``;
- ``mean profile``: the mean of the training paths' ``lambda``;
- ``per-digit mean``: the mean over the training paths of the same digit;
- ``k nearest shapes``: the mean ``lambda`` of the k training paths closest in shape (each
  path resampled at 32 equal arc-length fractions, centred; Euclidean distance).

Profiles are functions of normalised time ``u = t / duration``. The duration is not in
the image either: the predictors use the median training duration, which for
duration-normalised data (the ``-tn`` sets) is every path's duration.

Each predicted point is the test path's own point at the predicted arc fraction, so the
shape error is zero and what remains is timing. A network that reads only the image
cannot, on average, beat the best of these by much: it would have to predict the writer's
speed from the shape better than the shapes' nearest neighbours do.

Run on a prepared data set (``img2dmp prepare``), e.g. the duration-normalised one that
``experiments/mnist_experiments.py`` builds, from the repository's root::

    python experiments/mnist_timing_floor.py runs/mnist/data/mnist35-tn.safetensors

It prints the date, the git revision and its command line first, to go with its table in
``experiments/RESULTS.md``.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from img2dmp.data.store import SPLITS, load_dataset
from img2dmp.evaluate import arc_fractions, points_at_fractions

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record


def timing_floor(data, ks=(5, 20, 50)) -> dict[str, np.ndarray]:
    """Per-test-sample mean error (px) of every speed-profile predictor, by name.

    Profiles live on normalised time ``u = t / duration``. The predictors know the test
    path's shape but not its duration: they use the median training duration (for
    duration-normalised data that is every path's duration).
    """
    paths = data.trajectories.astype(np.float64)[..., :2]  # a pen channel plays no part
    times = data.times.astype(np.float64)
    lam = arc_fractions(paths)
    train = np.flatnonzero(data.split == SPLITS["train"])
    test = np.flatnonzero(data.split == SPLITS["test"])
    if len(train) == 0 or len(test) == 0:
        raise ValueError("the data set needs a training and a test split")
    labels = data.labels
    duration = times[:, -1] - times[:, 0]
    u_grid = np.linspace(0.0, 1.0, paths.shape[1])
    # every path's profile on the common grid of normalised time
    prof = np.stack(
        [
            np.interp(u_grid, (times[i] - times[i, 0]) / duration[i], lam[i])
            for i in range(len(paths))
        ]
    )
    guess = np.median(duration[train])

    def errors(profile_of) -> np.ndarray:
        out = []
        for i in test:
            u = np.clip((times[i] - times[i, 0]) / guess, 0.0, 1.0)
            fraction = np.interp(u, u_grid, profile_of(i))
            predicted = points_at_fractions(paths[i], lam[i], fraction)
            out.append(np.linalg.norm(predicted - paths[i], axis=-1).mean())
        return np.array(out)

    mean = prof[train].mean(0)
    per_digit = {c: prof[train[labels[train] == c]].mean(0) for c in np.unique(labels[train])}
    shapes = np.stack(
        [points_at_fractions(paths[i], lam[i], np.linspace(0, 1, 32)) for i in range(len(paths))]
    )
    shapes = (shapes - shapes.mean(1, keepdims=True)).reshape(len(paths), -1)
    out = {
        "constant speed": errors(lambda i: u_grid),
        "mean profile": errors(lambda i: mean),
        "per-digit mean": errors(lambda i: per_digit.get(labels[i], mean)),
    }
    for k in ks:

        def nearest(i, k=k):
            dist = np.linalg.norm(shapes[train] - shapes[i], axis=1)
            return prof[train[np.argsort(dist)[:k]]].mean(0)

        out[f"{k} nearest shapes"] = errors(nearest)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("data", nargs="+", help="prepared data-set files (.safetensors)")
    argv = sys.argv[1:] if argv is None else list(argv)
    args = p.parse_args(argv)
    print(format_record(run_record(__file__, argv)))
    for path in args.data:
        data = load_dataset(path)
        n_test = int((data.split == SPLITS["test"]).sum())
        d = data.times[:, -1] - data.times[:, 0]
        print(
            f"\n{path}: test part, n = {n_test}; durations {d.min():.2f}-{d.max():.2f} s "
            f"(median {np.median(d):.2f}); errors in px, mean +- std (median)"
        )
        for name, e in timing_floor(data).items():
            print(
                f"  shape exact, {name:20s} {e.mean():6.3f} +- {e.std():.3f} ({np.median(e):.3f})"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
