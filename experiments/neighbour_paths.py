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

A third reference, the **known curve**, removes even the shape from the question: the
closest writers' paths (``--pool`` of them, one per source image) are moved point by
point onto the person's own curve (each point to its nearest point of the curve) and
resampled, so each becomes the person's curve written in another writer's order. A
predictor that knew the curve exactly, and only had to choose where to start, which way
to go and how to space the pen, is scored with a choice made from the pool alone: as its
one movement the pool's medoid or the pointwise geometric median of the pool (whichever
is closer to the pool on average; neither looks at the person's path), and as its best
of K the K medoids of the pool (greedy choice, then swaps). Like the timing floor
(``mnist_timing_floor.py``), it estimates what a predictor could reach that knew the
curve exactly while the writer's order is not in the image, with the pool's orders
standing in for the unknown one (an estimate, not a bound: a better guess of the order
than the pool's may exist). With ``--model`` the same is done on the model's
own top path instead of the person's (the pool ranked by Chamfer distance to it): a
predictor that never sees the answer, which takes the curve from the network and the
order from other writers. Between the two, the shape oracle's first path as the curve
says how close to the person's curve a curve must be: it is another person's writing of
nearly the same curve, on a nearly identical image. Where the samples share one time
grid the same is done with Table I's error: the pool's points keep their time stamps
when they are moved onto the curve, so the pool lends its timing as well as its order.

Usage::

    python experiments/neighbour_paths.py --data runs/real/data.safetensors --split validation \
        [--model runs/real/run --refine 30]
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


def neighbours(train, evalset, blur=1.0, points=64, count=256):
    """For every evaluation sample, its ``count`` image neighbours in the training part:
    their rows ``idx [M, C]``, the person's resampled path ``ref [M, n, 2]``, the
    neighbours' ``hyp [M, C, n, 2]`` and their order by Chamfer distance to the
    person's path ``by_shape [M, C]`` (the shape oracle's ranking)."""
    n_cand = min(max(count, 1), len(train))
    idx = nearest(blurred(evalset.images, blur), blurred(train.images, blur), n_cand)
    ref = resample_by_arc_length(evalset.trajectories, points)  # [M, n, 2]
    hyp = resample_by_arc_length(train.trajectories, points)[idx]  # [M, C, n, 2]
    to_ref = chamfer_px(hyp.reshape(-1, *hyp.shape[2:]), np.repeat(ref, n_cand, 0))
    by_shape = np.argsort(to_ref.reshape(idx.shape), axis=1, kind="stable")
    return idx, ref, hyp, by_shape


def references(
    train, evalset, blur=1.0, points=64, candidates=256, found=None
) -> tuple[dict, np.ndarray]:
    """``{title: (errors [M, k], chamfer [M])}``: the ranked neighbours' errors against
    each evaluation sample's path (see the module docstring), k = min(16, candidates);
    and the training row ``[M]`` of each sample's shape oracle (its first-ranked path).
    ``found``: :func:`neighbours`' result, if already computed."""
    idx, ref, hyp, by_shape = found or neighbours(train, evalset, blur, points, candidates)
    k = min(max(KS), idx.shape[1])
    by_image = np.broadcast_to(np.arange(idx.shape[1]), idx.shape)
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


def writers_of(data) -> np.ndarray:
    """The source (MNIST index) of every row, where the data set records it (augmented
    copies share their source), else every row its own source."""
    source = np.asarray((data.meta or {}).get("rows", {}).get("mnist_index", []))
    if data.file_rows is not None and len(source) > data.file_rows.max(initial=-1):
        return source[data.file_rows]  # a part of a data set read from a file
    return source if len(source) == len(data) else np.arange(len(data))


def on_curve(ref: np.ndarray, paths: np.ndarray, dense: int = 8, timed: bool = False):
    """``paths [J, n, 2]`` moved point by point onto the curve of ``ref [m, 2]`` (each
    point to the nearest of ``dense * m`` arc-length points of ``ref``) and resampled by
    arc length: the person's curve written in each path's order. With ``timed`` the
    points stay at their time stamps (not resampled): each path's order and timing."""
    fine = resample_by_arc_length(ref[None], dense * len(ref))[0]  # [F, 2]
    dist = np.linalg.norm(paths[:, :, None] - fine[None, None], axis=-1)  # [J, n, F]
    moved = fine[dist.argmin(-1)]
    return moved if timed else resample_by_arc_length(moved, paths.shape[1])


def geometric_median(points: np.ndarray, iters: int = 100) -> np.ndarray:
    """Pointwise geometric median ``[n, 2]`` of paths ``[J, n, 2]`` (Weiszfeld): the one
    path nearest to all of them on average, point by point."""
    m = points.mean(0)
    for _ in range(iters):
        w = 1.0 / np.maximum(np.linalg.norm(points - m, axis=-1), 1e-9)  # [J, n]
        m = (w[..., None] * points).sum(0) / w.sum(0)[:, None]
    return m


def k_medoids(cost: np.ndarray, k: int) -> np.ndarray:
    """Indices of ``k`` medoids for the pairwise costs ``cost [J, J]``: greedy choice of
    the one that lowers ``sum_i min_chosen cost[i, chosen]`` most, then single swaps
    while one lowers it."""
    k = min(k, len(cost))
    chosen: list[int] = []
    for _ in range(k):
        best = np.minimum(cost[:, chosen].min(1), cost.T) if chosen else cost.T  # [J, J]
        chosen.append(int(np.argmin(best.sum(1))))
    total = cost[:, chosen].min(1).sum()
    improved = True
    while improved:
        improved = False
        for slot in range(k):
            for j in range(len(cost)):
                if j in chosen:
                    continue
                trial = chosen[:slot] + [j] + chosen[slot + 1 :]
                value = cost[:, trial].min(1).sum()
                if value < total - 1e-12:
                    chosen, total, improved = trial, value, True
    return np.asarray(chosen)


def pool_rows(hyp, writers, curve, pool: int = 32, by_curve=None) -> list[np.ndarray]:
    """For every sample, the candidates (columns of ``hyp [M, C, n, 2]``) of the
    known-curve pool: the ``pool`` nearest in Chamfer distance to ``curve [M, n, 2]``,
    one per source (``writers [M, C]``). ``by_curve [M, C]``: that ranking, if known."""
    if by_curve is None:
        m_count, c_count, n_pts = hyp.shape[:3]
        to_curve = chamfer_px(hyp.reshape(-1, n_pts, 2), np.repeat(curve, c_count, 0))
        by_curve = np.argsort(to_curve.reshape(m_count, c_count), axis=1, kind="stable")
    rows = []
    for order, who in zip(by_curve, writers, strict=True):
        _, first = np.unique(who[order], return_index=True)
        rows.append(order[np.sort(first)][:pool])
    return rows


def known_curve(ref, hyp, writers, curve=None, pool: int = 32, timed=None, rows=None) -> np.ndarray:
    """Path errors ``[M, len(KS)]`` against the person's paths ``ref [M, n, 2]`` of the
    known-curve predictor (module docstring): its one movement (column for K = 1) and
    its best of K. The pool (:func:`pool_rows`, or ``rows`` if already chosen) is
    moved onto ``curve``: by default the person's own path (the known curve); a model's
    predicted path makes it a predictor that never sees the answer.

    ``timed = (ref_t [M, T, 2], train_t [N, T, 2], idx [M, C])``: Table I's error
    instead, positions at shared time stamps. The pool's timed trajectories (rows
    ``idx`` of ``train_t``) are moved onto the curve point by point, keeping their
    timing, and the errors are taken against ``ref_t``."""
    curve = ref if curve is None else curve
    rows = pool_rows(hyp, writers, curve, pool) if rows is None else rows
    errors = np.empty((len(ref), len(KS)))
    for m, r in enumerate(rows):
        if timed is None:
            target, v = ref[m], on_curve(curve[m], hyp[m, r])  # v: [J, n, 2]
        else:
            ref_t, train_t, idx = timed
            target = ref_t[m, :, :2]
            v = on_curve(curve[m], train_t[idx[m, r], :, :2], timed=True)  # [J, T, 2]
        errors[m] = _choices_of(v, target, resample=timed is None)
    return errors


def _choices_of(v: np.ndarray, target: np.ndarray, resample: bool) -> np.ndarray:
    """Errors ``[len(KS)]`` against ``target`` of the choices made from the pool's
    paths ``v [J, n, 2]`` alone: its medoid or pointwise geometric median (whichever is
    nearer to the pool on average; ``resample``: the median resampled by arc length
    first, as a path error compares), then the best of its K medoids."""
    cost = np.linalg.norm(v[:, None] - v[None], axis=-1).mean(-1)  # [J, J]
    to_target = np.linalg.norm(v - target, axis=-1).mean(-1)  # [J]
    med = geometric_median(v)
    if resample:
        med = resample_by_arc_length(med[None], len(med))[0]
    medoid = int(np.argmin(cost.sum(1)))
    out = np.empty(len(KS))
    if np.linalg.norm(v - med, axis=-1).mean() < cost[medoid].mean():
        out[0] = np.linalg.norm(med - target, axis=-1).mean()
    else:
        out[0] = to_target[medoid]
    for col, k in enumerate(KS[1:], start=1):
        out[col] = to_target[k_medoids(cost, k)].min()
    return out


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


def model_paths(model: str, refine: int, evalset, points: int) -> np.ndarray:
    """The model's top path ``[M, n, 2]`` for every image (``refine`` steps onto the ink)."""
    from img2dmp.nn.refine import RefineOptions
    from img2dmp.predict import Predictor

    pred = Predictor.load(model)
    if refine:
        pred.refine_options = RefineOptions(steps=refine)
    y = pred.trajectories_for_images(evalset.images, evalset.times)
    return resample_by_arc_length(y, points)


def print_table(title, err, cham, labels, by_k: bool = False) -> None:
    """Per digit and overall: the mean Chamfer and the best of k for k in KS, from
    ranked errors ``err [M, k]`` (best of k = min of the first k) or, with ``by_k``,
    from errors ``[M, len(KS)]`` that already are the best of each k."""
    ks = KS if by_k else [k for k in KS if k <= err.shape[1]]
    what = "that of the curve" if by_k else "that of the first-ranked path"
    print(f"\n{title}; chamfer = {what}")
    print(f"{'digit':>5} {'n':>4} {'chamfer':>8} " + " ".join(f"{'best' + str(k):>7}" for k in ks))
    rows = [(str(d), labels == d) for d in np.unique(labels)]
    for name, m in rows + [("all", np.ones(len(labels), bool))]:
        cols = err[m] if by_k else np.stack([err[m, :k].min(1) for k in ks], 1)
        best = " ".join(f"{v:7.3f}" for v in cols.mean(0))
        print(f"{name:>5} {m.sum():4d} {cham[m].mean():8.3f} {best}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="data-set file (with a split)")
    p.add_argument("--split", default="validation", choices=("validation", "test"))
    p.add_argument("--blur", type=float, default=1.0, help="Gaussian blur sigma (px)")
    p.add_argument("--points", type=int, default=64, help="arc-length points per path")
    p.add_argument("--candidates", type=int, default=256, help="image neighbours per image")
    p.add_argument(
        "--pool",
        type=int,
        default=32,
        help="writers of the closest shapes moved onto the curve (0: no known-curve tables)",
    )
    p.add_argument(
        "--model", help="also order other writers' paths on this model's top path (run dir)"
    )
    p.add_argument("--refine", type=int, default=30, help="the model's refinement steps")
    p.add_argument("--figure", metavar="PNG", help="also draw the shape oracle's cases here")
    args = p.parse_args(argv)
    print(format_record(run_record(__file__, sys.argv[1:] if argv is None else list(argv))))
    data = load_dataset(args.data)
    train, evalset = data.select_split("train"), data.select_split(args.split)
    if not len(train) or not len(evalset):
        raise SystemExit(f"{args.data}: needs samples in the train and {args.split} parts")
    found = neighbours(train, evalset, args.blur, args.points, args.candidates)
    tables, oracle_rows = references(train, evalset, found=found)
    for title, (err, cham) in tables.items():
        print_table(title, err, cham, evalset.labels)
    if args.pool > 0:
        idx, ref, hyp, by_shape = found
        writers = writers_of(train)[idx]  # [M, C]
        curves = {  # the curve, and its ranking of the candidates where already known
            "the person's own curve (known)": (ref, by_shape),
            "the shape oracle's first path": (hyp[np.arange(len(hyp)), by_shape[:, 0]], None),
        }
        if args.model:
            path = model_paths(args.model, args.refine, evalset, args.points)
            curves[f"{args.model}'s top path (a predictor)"] = (path, None)
        timed = shares_time_grid(train, evalset)
        for what, (curve, ranking) in curves.items():
            rows = pool_rows(hyp, writers, curve, args.pool, ranking)
            err = known_curve(ref, hyp, writers, curve, rows=rows)
            title = f"path error (px), other writers' order on {what}, pool of {args.pool}"
            print_table(title, err, chamfer_px(curve, ref), evalset.labels, by_k=True)
            if timed:
                stamps = (evalset.trajectories, train.trajectories, idx)
                err = known_curve(ref, hyp, writers, curve, timed=stamps, rows=rows)
                title = f"Table I's error (px), other writers' order and timing on {what}"
                print_table(title, err, chamfer_px(curve, ref), evalset.labels, by_k=True)
    if args.figure:
        oracle_figure(args.figure, train, evalset, tables, oracle_rows)
        print(f"\nwrote {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
