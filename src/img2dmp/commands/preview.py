"""Draw a grid of data-set images with their pen paths over them (like Fig. 4 of the paper).

Reads a stored data set (--data), or, without one, generates a few fresh synthetic
samples. The demonstrated path is blue with a dot at its start; with --dmp the fitted
DMP's rollout is drawn over it in red. One column per digit of --digits (or class of
--classes, for a data set made by img2dmp import; default: every class of --data), each
image titled with its class's name. An existing --out file is replaced only with --force.

  img2dmp preview --data digits.safetensors --out digits.png --dmp --digits 2,3
  img2dmp preview --data letters.safetensors --out letters.png --classes L,T
"""

from __future__ import annotations

import argparse

from . import _args

HELP = "PNG grid of images with their pen paths drawn over them"
SPLITS = ("train", "validation", "test")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, metavar="PNG", help="output PNG file")
    _args.add_force(p, "--out file")
    _args.add_data(p, help="data-set file (.safetensors); default: fresh synthetic digits")
    p.add_argument(
        "--per-digit",
        metavar="N",
        type=_args.int_at_least(1),
        default=4,
        help="samples shown of each digit",
    )
    _args.add_digits_or_classes(
        p, "digits to show (default: 0-9, or every class of --data)", "classes to show"
    )
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


def _pick(labels, classes, per_digit: int, rng):
    # Up to per_digit random samples of each class (label), grouped by sample index so
    # that each row of the grid shows the classes in order.
    import numpy as np

    chosen = []
    for d in classes:
        idx = np.flatnonzero(labels == d)
        chosen.append(rng.permutation(idx)[:per_digit])
    width = max((len(c) for c in chosen), default=0)
    order = [c[k] for k in range(width) for c in chosen if k < len(c)]
    return np.asarray(order, dtype=np.int64)


def _shown_labels(data, args) -> list[int]:
    """The labels of the classes to show: --digits or --classes by name, else all."""
    import numpy as np

    wanted = data.labels_selected(args.digits, args.classes)
    return (np.unique(data.labels) if wanted is None else wanted).tolist()


def _samples(args, rng):
    """The data set to draw from: --data (its --split), or fresh synthetic digits."""
    import numpy as np

    if args.data:
        from ..data.store import load_dataset

        data = load_dataset(args.data)
        return data.select_split(args.split) if args.split else data
    from ..data.plotting import check_grid_size
    from ..data.store import digits_named
    from ..data.synthetic import SyntheticConfig, generate

    digits = args.digits or tuple(range(10))
    if args.classes is not None:
        digits = digits_named(args.classes, "--classes")
    # before the samples are made: a grid too large to draw is refused at once
    check_grid_size(args.per_digit * len(digits), "--per-digit x digits")
    config = SyntheticConfig(digits=digits, image_size=(args.image_size, args.image_size))
    return generate(np.tile(np.array(digits), args.per_digit), config, rng)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..data.plotting import save_grid

    _args.check_outputs([(args.out, None)], args.force, [("data set", args.data)])
    if args.data:
        _args.check_inputs([args.data], "data set")
    rng = np.random.default_rng(args.seed)
    data = _samples(args, rng)
    shown = _shown_labels(data, args)
    idx = _pick(data.labels, shown, args.per_digit, rng)
    if idx.size == 0:
        names = [data.label_names[k] for k in shown]
        raise ValueError(f"no samples of the classes {names} to show")
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
        titles=[data.label_names[v] for v in data.labels[idx]],
        ncols=len(shown) if len(shown) > 1 else min(idx.size, 10),
        cell_inches=args.cell_inches,
        dpi=args.dpi,
    )
    print(f"wrote {args.out} ({idx.size} samples)")
    return 0
