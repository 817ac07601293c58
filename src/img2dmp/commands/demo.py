"""Run the whole chain on a small built-in example: generate a synthetic data set, train
a small network briefly, evaluate it and draw the pictures (about a minute on 2 cores).

The network and optimiser are the demo's own (the package's configs/demo.yaml);
--config FILE (TrainConfig sections) and --set section.key=value change them, checked as
img2dmp train checks its configuration before anything is generated. The data set, the
number of epochs, the cost, the seed and progress are the options below. An earlier demo in
--out is replaced only with --force (checked before anything starts).

  img2dmp demo --out runs/demo --epochs 20 --set optim.lr=3e-4
"""

from __future__ import annotations

import argparse
from pathlib import Path

# The pipeline module imports neither torch nor NumPy at module level (its demo config is
# a YAML file), so --help can show the real defaults.
from ..pipeline import DEMO_EPOCHS, DEMO_SAMPLES_PER_DIGIT
from . import _args

HELP = "generate -> train -> evaluate -> pictures, on a small built-in example"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="runs/demo", metavar="DIR", help="output directory")
    _args.add_force(p, "files of an earlier demo in --out")
    p.add_argument(
        "--samples-per-digit",
        metavar="N",
        type=_args.int_at_least(1),
        help=f"data set size (default {DEMO_SAMPLES_PER_DIGIT})",
    )
    p.add_argument(
        "--epochs",
        metavar="N",
        type=_args.int_at_least(1),
        help=f"training epochs (default {DEMO_EPOCHS}, from the demo's configuration)",
    )
    p.add_argument("--cost", default="trajectory", help="parameter (eq. 9) or trajectory (eq. 10)")
    p.add_argument("--seed", metavar="N", type=_args.int_at_least(0), default=0, help="random seed")
    _args.add_config(p, "TrainConfig sections merged over the demo's network and optimiser")
    _args.add_set(p, "--set optim.lr=3e-4 --set model.activation=tanh")
    _args.add_no_progress(p)


#: Files of an earlier demo that only --force replaces.
DEMO_OUTPUTS = (
    "data.safetensors",
    "summary.json",
    "run/checkpoints/best.safetensors",
    "run/checkpoints/last.safetensors",
    "evaluation/evaluation.json",
)

#: Settings the demo fixes itself -> the option that sets them.
OWN_SETTINGS = {
    ("data", "path"): "the demo's own data set",
    ("optim", "epochs"): "--epochs",
    ("cost", "name"): "--cost",
    ("seed",): "--seed",
    ("progress",): "--no-progress",
}


def demo_overrides(args: argparse.Namespace) -> dict:
    """``--config`` and ``--set`` as the section mapping :func:`run_demo` merges; refuses
    the settings the demo sets itself (they would be silently replaced)."""
    from ..config import ConfigError, apply_overrides, read_config_of
    from ..training.config import TrainConfig

    found = read_config_of(TrainConfig, args.config) if args.config else {}
    over = apply_overrides(found, args.set)
    for keys, instead in OWN_SETTINGS.items():
        node = over
        for k in keys[:-1]:
            node = node.get(k) if isinstance(node.get(k), dict) else {}
        if keys[-1] in node:
            raise ConfigError(f"{'.'.join(keys)} cannot be changed in the demo; use {instead}")
    return over


def run(args: argparse.Namespace) -> int:
    from ..pipeline import run_demo
    from ..train import load_config

    over = demo_overrides(args)
    if args.config or args.set:
        load_config(args.config, args.set)  # unknown keys and wrong types fail here
    _args.check_output_dir(args.out, "--out")
    _args.check_outputs([(Path(args.out) / f, None) for f in DEMO_OUTPUTS], args.force)
    given = {
        k: v
        for k, v in (("samples_per_digit", args.samples_per_digit), ("epochs", args.epochs))
        if v is not None
    }
    run_demo(
        args.out,
        **given,
        cost=args.cost,
        seed=args.seed,
        progress=not args.no_progress,
        overrides=over or None,
    )
    return 0
