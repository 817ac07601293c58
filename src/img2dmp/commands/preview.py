"""Draw a grid of data-set images with their pen paths over them (like Fig. 4 of the paper).

Reads a stored data set (--data), or, without one, generates a few fresh synthetic
samples. The demonstrated path is blue with a dot at its start; with --dmp the fitted
DMP's rollout is drawn over it in red.
"""

from __future__ import annotations

import argparse

import numpy as np

HELP = "PNG grid of images with their pen paths drawn over them"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output PNG file")
    p.add_argument("--data", default=None, help="data-set file; default: fresh synthetic digits")
    p.add_argument("--per-digit", type=int, default=4, help="samples shown of each digit")
    p.add_argument("--digits", default="0-9", help="digits to show: 0-9, 2, 1,4,7 ...")
    p.add_argument("--image-size", type=int, default=40, help="image size of fresh samples")
    p.add_argument("--seed", type=int, default=0, help="seed for fresh samples and the pick")
    p.add_argument("--split", default=None, help="only this split of --data (train, ...)")
    p.add_argument("--dmp", action="store_true", help="also draw the fitted DMP in red")
    p.add_argument("--cell-inches", type=float, default=1.2, help="size of one image")
    p.add_argument("--dpi", type=int, default=100)


def _pick(labels: np.ndarray, digits, per_digit: int, rng) -> np.ndarray:
    # Up to per_digit random samples of each digit, grouped by sample index so that each
    # row of the grid shows the digits in order.
    chosen = []
    for d in digits:
        idx = np.flatnonzero(labels == d)
        chosen.append(rng.permutation(idx)[:per_digit])
    width = max((len(c) for c in chosen), default=0)
    order = [c[k] for k in range(width) for c in chosen if k < len(c)]
    return np.asarray(order, dtype=np.int64)


def run(args: argparse.Namespace) -> int:
    from ..data.plotting import save_grid
    from .generate import parse_digits

    digits = parse_digits(args.digits)
    if args.per_digit < 1:
        raise ValueError(f"--per-digit must be >= 1, got {args.per_digit}")
    rng = np.random.default_rng(args.seed)
    if args.data:
        from ..data.store import load_dataset

        data = load_dataset(args.data)
        if args.split:
            data = data.select_split(args.split)
    else:
        from ..data.synthetic import SyntheticConfig, generate

        config = SyntheticConfig(digits=digits, image_size=(args.image_size, args.image_size))
        data = generate(np.tile(np.array(digits), args.per_digit), config, rng)
    idx = _pick(data.labels, digits, args.per_digit, rng)
    if idx.size == 0:
        raise ValueError(f"no samples of digits {list(digits)} to show")
    second = None
    if args.dmp:
        import torch

        from ..dmp import DMPParams, rollout

        cfg = data.dmp_config
        p = DMPParams.from_vector(
            torch.from_numpy(data.params[idx]).double(), cfg.n_kernels, cfg.n_dims
        )
        second = rollout(p, torch.from_numpy(data.times[idx]).double(), cfg).numpy()
    save_grid(
        args.out,
        data.images[idx],
        data.trajectories[idx],
        second,
        titles=[str(v) for v in data.labels[idx]],
        ncols=len(digits) if len(digits) > 1 else min(idx.size, 10),
        cell_inches=args.cell_inches,
        dpi=args.dpi,
    )
    print(f"wrote {args.out} ({idx.size} samples)")
    return 0
