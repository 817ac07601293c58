"""Draw a grid of data-set images with their pen paths over them (like Fig. 4 of the paper).

Reads a stored data set (--data), or, without one, generates a few fresh synthetic
samples. The demonstrated path is blue with a dot at its start; with --dmp the fitted
DMP's rollout is drawn over it in red. One column per digit of --digits. An existing
--out file is replaced only with --force.

  img2dmp preview --data digits.safetensors --out digits.png --dmp --digits 2,3
"""

from __future__ import annotations

import argparse

from . import _args

HELP = "PNG grid of images with their pen paths drawn over them"
SPLITS = ("train", "validation", "test")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, metavar="PNG", help="output PNG file")
    _args.add_force(p, "an existing --out file")
    _args.add_data(p, help="data-set file (.safetensors); default: fresh synthetic digits")
    p.add_argument(
        "--per-digit",
        metavar="N",
        type=_args.int_at_least(1),
        default=4,
        help="samples shown of each digit",
    )
    _args.add_digits(p, "digits to show (default: 0-9)")
    p.add_argument(
        "--image-size",
        type=_args.int_at_least(8),
        default=40,
        metavar="PX",
        help="image size of fresh samples (without --data)",
    )
    p.add_argument(
        "--seed",
        metavar="N",
        type=_args.int_at_least(0),
        default=0,
        help="seed for fresh samples and the pick",
    )
    p.add_argument("--split", choices=SPLITS, help="only this split of --data (default: all)")
    p.add_argument("--dmp", action="store_true", help="also draw the fitted DMP in red")
    p.add_argument(
        "--cell-inches", type=_args.positive_float, default=1.2, help="size of one image"
    )
    p.add_argument(
        "--dpi", metavar="N", type=_args.int_at_least(1), default=100, help="resolution of the PNG"
    )


def _pick(labels, digits, per_digit: int, rng):
    # Up to per_digit random samples of each digit, grouped by sample index so that each
    # row of the grid shows the digits in order.
    import numpy as np

    chosen = []
    for d in digits:
        idx = np.flatnonzero(labels == d)
        chosen.append(rng.permutation(idx)[:per_digit])
    width = max((len(c) for c in chosen), default=0)
    order = [c[k] for k in range(width) for c in chosen if k < len(c)]
    return np.asarray(order, dtype=np.int64)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..data.plotting import save_grid

    _args.check_outputs([(args.out, None)], args.force)
    if args.data:
        _args.check_inputs([args.data], "data set")
    digits = args.digits or tuple(range(10))
    rng = np.random.default_rng(args.seed)
    if args.data:
        from ..data.store import load_dataset

        data = load_dataset(args.data)
        if args.split:
            data = data.select_split(args.split)
    else:
        from ..data.plotting import check_grid_size
        from ..data.synthetic import SyntheticConfig, generate

        # before the samples are made: a grid too large to draw is refused at once
        check_grid_size(args.per_digit * len(digits), "--per-digit x digits")
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
