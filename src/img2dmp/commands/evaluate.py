"""Evaluate a trained network as in Table I: per-sample mean trajectory error in pixels.

Prints mean, standard deviation, median and 95th percentile overall and per digit, and
writes evaluation.json, evaluation.txt and examples.png (image, demonstrated path in
blue, DMP path in red, like Fig. 4 of the paper) to --out.
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "Table I statistics and Fig. 4 pictures of a trained network on a data set"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="run directory or checkpoint (.safetensors)")
    p.add_argument("data", help="data-set file (.safetensors)")
    p.add_argument(
        "--split",
        default="auto",
        help="auto (test split if any, else all), all, train, validation or test",
    )
    p.add_argument("--digits", type=int, nargs="*", help="only these digits")
    p.add_argument("--out", help="output directory (default: MODEL/evaluation for a run dir)")
    p.add_argument("--figures", type=int, default=16, help="samples drawn in examples.png")


def run(args: argparse.Namespace) -> int:
    from ..evaluate import evaluate, format_table

    out = args.out
    if out is None:
        out = Path(args.model) / "evaluation" if Path(args.model).is_dir() else "evaluation"
    res = evaluate(
        args.model,
        args.data,
        split=args.split,
        out_dir=out,
        n_figures=args.figures,
        digits=args.digits,
    )
    print(format_table(res, f"trajectory error (px), {args.data} [{args.split}]"))
    print(f"written: {Path(out) / 'evaluation.json'}, evaluation.txt, examples.png")
    return 0
