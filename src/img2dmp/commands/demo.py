"""Run the whole chain on a small built-in example: generate a synthetic data set, train
a small network briefly, evaluate it and draw the pictures (a few minutes on 2 cores).
"""

from __future__ import annotations

import argparse

HELP = "generate -> train -> evaluate -> pictures, on a small built-in example"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..pipeline import DEMO_EPOCHS, DEMO_SAMPLES_PER_DIGIT

    p.add_argument("--out", default="runs/demo", help="output directory")
    p.add_argument(
        "--samples-per-digit", type=int, default=DEMO_SAMPLES_PER_DIGIT, help="data set size"
    )
    p.add_argument("--epochs", type=int, default=DEMO_EPOCHS, help="training epochs")
    p.add_argument("--cost", default="trajectory", help="parameter (eq. 9) or trajectory (eq. 10)")
    p.add_argument("--seed", type=int, default=0)


def run(args: argparse.Namespace) -> int:
    from ..pipeline import run_demo

    run_demo(
        args.out,
        samples_per_digit=args.samples_per_digit,
        epochs=args.epochs,
        cost=args.cost,
        seed=args.seed,
    )
    return 0
