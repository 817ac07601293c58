"""A model-free reference for issue 15: the paths of the training images nearest in pixels.

For every image of a data set's evaluation split, the K training images nearest to it
(Euclidean distance of the pixels after a small Gaussian blur, training part of the split
only, augmented copies included) lend their people's paths as hypotheses, ranked by image
distance. Printed per digit and overall: the path error of the nearest one (the "top"
hypothesis), the best of the first K (K = 1, 2, 4, 5, 8, 16), the same when each
neighbour's path may also be taken reversed, the Chamfer distance of the nearest one, and
(where all samples share one time grid, e.g. durations normalised) Table I's error at the
same time stamps. ``--figure PNG`` draws the cases where another writer's path of
nearly the same curve is furthest from the person's in path error.
It answers whether a network's best of K is limited by the ambiguity of the images (then
the neighbours, which copy real writers, do no better) or by the network.

A second reference looks at the answer: among the 256 image neighbours, the people's
paths nearest in shape to the person's own path (order-free Chamfer distance, which no
predictor can know) are ranked first. Their path error says how far apart two real
writings of the same curve are once order, start and spacing along the path count.

Usage::

    python experiments/neighbour_paths.py --data runs/real/data.safetensors --split validation
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import torch

from img2dmp.data.store import load_dataset
from img2dmp.metrics import chamfer_px, resample_by_arc_length

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record

KS = (1, 2, 4, 5, 8, 16)


def blurred(images: np.ndarray, sigma: float) -> torch.Tensor:
    """``[M, H*W]`` images blurred with a separable Gaussian of ``sigma`` px, flattened."""
    x = torch.as_tensor(images, dtype=torch.float32)[:, None]  # [M, 1, H, W]
    if sigma > 0:
        r = int(np.ceil(3 * sigma))
        k = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=torch.float32) / sigma) ** 2)
        k = k / k.sum()
        x = torch.nn.functional.conv2d(x, k.view(1, 1, 1, -1), padding=(0, r))
        x = torch.nn.functional.conv2d(x, k.view(1, 1, -1, 1), padding=(r, 0))
    return x.flatten(1)


def nearest(query: torch.Tensor, pool: torch.Tensor, k: int, chunk: int = 256) -> np.ndarray:
    """Indices ``[Q, k]`` of the ``k`` pool rows nearest to each query row."""
    pool_sq = (pool**2).sum(1)
    out = []
    for s in range(0, len(query), chunk):
        q = query[s : s + chunk]
        d2 = pool_sq[None] - 2 * q @ pool.T  # + |q|^2, the same for every pool row
        out.append(torch.topk(d2, k, dim=1, largest=False).indices.numpy())
    return np.concatenate(out)


def ranked_errors(hyp: np.ndarray, ref: np.ndarray, order: np.ndarray, k: int):
    """Errors ``[M, k]`` of the hypotheses ``hyp [M, C, n, 2]`` against ``ref [M, n, 2]``
    in the order ``order [M, C]`` (first k kept): point by point as written and either
    way round; and the Chamfer distance ``[M]`` of each first-ranked one."""
    ranked = np.take_along_axis(hyp, order[:, :k, None, None], axis=1)  # [M, k, n, 2]
    err = np.linalg.norm(ranked - ref[:, None], axis=-1).mean(-1)
    rev = np.linalg.norm(ranked[:, :, ::-1] - ref[:, None], axis=-1).mean(-1)
    return err, np.minimum(err, rev), chamfer_px(ranked[:, 0], ref)


def shares_time_grid(*datasets) -> bool:
    """True when every sample of the data sets has the same time stamps."""
    first = datasets[0].times[:1]
    return all(
        d.times.shape[1:] == first.shape[1:] and not np.abs(d.times - first).max() for d in datasets
    )


def references(train, evalset, blur=1.0, points=64, candidates=256) -> tuple[dict, np.ndarray]:
    """``{title: (errors [M, k], chamfer [M])}``: the ranked neighbours' errors against
    each evaluation sample's path (see the module docstring), k = min(16, candidates);
    and the training row ``[M]`` of each sample's shape oracle (its first-ranked path)."""
    n_cand = min(max(candidates, 1), len(train))
    k = min(max(KS), n_cand)
    idx = nearest(blurred(evalset.images, blur), blurred(train.images, blur), n_cand)
    ref = resample_by_arc_length(evalset.trajectories, points)  # [M, n, 2]
    hyp = resample_by_arc_length(train.trajectories, points)[idx]  # [M, C, n, 2]
    by_image = np.broadcast_to(np.arange(n_cand), idx.shape)
    # The shape oracle: the candidates re-ranked by their Chamfer distance to the answer.
    to_ref = chamfer_px(hyp.reshape(-1, *hyp.shape[2:]), np.repeat(ref, n_cand, 0))
    by_shape = np.argsort(to_ref.reshape(idx.shape), axis=1, kind="stable")
    timed = shares_time_grid(train, evalset)
    out = {}
    for what, order in (("image neighbours", by_image), ("shape oracle", by_shape)):
        err, either, cham = ranked_errors(hyp, ref, order, k)
        out[f"path error (px), {what}, as written"] = err, cham
        out[f"path error (px), {what}, either direction"] = either, cham
        if timed:  # Table I's error: positions at the same time stamps
            rows = np.take_along_axis(idx, order, axis=1)[:, :k]  # [M, k]
            diff = train.trajectories[rows] - evalset.trajectories[:, None]  # [M, k, T, 2]
            out[f"Table I's error (px), {what}"] = np.linalg.norm(diff, axis=-1).mean(-1), cham
    return out, idx[np.arange(len(idx)), by_shape[:, 0]]


def oracle_figure(path, train, evalset, tables: dict, oracle_rows, n: int = 12) -> None:
    """The ``n`` evaluation samples whose shape oracle draws the curve most closely
    (Chamfer < 0.6 px) and is still furthest away in path error: the image with the
    person's path (blue) and the oracle's, another writer's (red)."""
    from img2dmp.data.plotting import overlay_figure

    err, cham = tables["path error (px), shape oracle, as written"]
    close = np.flatnonzero(cham < 0.6)
    pick = close[np.argsort(-err[close, 0], kind="stable")[:n]]
    titles = [
        f"{evalset.label_names[evalset.labels[i]]}: Chamfer {cham[i]:.2f}, path {err[i, 0]:.1f}"
        for i in pick
    ]
    overlay_figure(
        path,
        evalset.images[pick],
        evalset.trajectories[pick],
        train.trajectories[oracle_rows[pick]],
        titles,
        ncols=4,
        labels=("the person's path", "another writer's, nearest in shape"),
    )


def print_table(title: str, err: np.ndarray, cham: np.ndarray, labels: np.ndarray) -> None:
    ks = [k for k in KS if k <= err.shape[1]]
    print(f"\n{title}; chamfer = that of the first-ranked path")
    print(f"{'digit':>5} {'n':>4} {'chamfer':>8} " + " ".join(f"{'best' + str(k):>7}" for k in ks))
    rows = [(str(d), labels == d) for d in np.unique(labels)]
    for name, m in rows + [("all", np.ones(len(labels), bool))]:
        best = " ".join(f"{err[m, :k].min(1).mean():7.3f}" for k in ks)
        print(f"{name:>5} {m.sum():4d} {cham[m].mean():8.3f} {best}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="data-set file (with a split)")
    p.add_argument("--split", default="validation", choices=("validation", "test"))
    p.add_argument("--blur", type=float, default=1.0, help="Gaussian blur sigma (px)")
    p.add_argument("--points", type=int, default=64, help="arc-length points per path")
    p.add_argument("--candidates", type=int, default=256, help="image neighbours per image")
    p.add_argument("--figure", metavar="PNG", help="also draw the shape oracle's cases here")
    args = p.parse_args(argv)
    print(format_record(run_record(__file__, sys.argv[1:] if argv is None else list(argv))))
    data = load_dataset(args.data)
    train, evalset = data.select_split("train"), data.select_split(args.split)
    if not len(train) or not len(evalset):
        raise SystemExit(f"{args.data}: needs samples in the train and {args.split} parts")
    tables, oracle_rows = references(train, evalset, args.blur, args.points, args.candidates)
    for title, (err, cham) in tables.items():
        print_table(title, err, cham, evalset.labels)
    if args.figure:
        oracle_figure(args.figure, train, evalset, tables, oracle_rows)
        print(f"\nwrote {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
