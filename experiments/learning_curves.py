"""Learning curves of several training runs side by side, against updates (issue 21).

Each run directory written by ``img2dmp train`` (or ``reproduce_table1.py``) holds a
``metrics.csv`` with one row per epoch: the optimiser steps so far, the training and
validation errors. Runs of different batch sizes or epoch counts compare fairly only
against updates, so this script draws every run's validation error (solid) and
training error (dashed) against the updates on one logarithmic axis, with the paper's
figure as a horizontal line, and prints a table: updates, the last training and
validation errors, the best validation error and where it was reached. A run that is
still training is read as far as it has come.

Usage::

    python experiments/learning_curves.py LABEL=RUN_DIR [LABEL=RUN_DIR ...] --out curves.png \
        [--paper 0.11] [--title "Table I, digit 2, cost (9)"]
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record

COLUMNS = ("step", "train_error_px", "val_error_px")


def read_curve(run_dir: str | Path) -> dict[str, np.ndarray]:
    """``{"step", "train_error_px", "val_error_px"}`` of a run's ``metrics.csv``, as float
    arrays, one entry per epoch; ``ValueError`` naming the file when it is missing, empty
    or lacks a column."""
    path = Path(run_dir) / "metrics.csv"
    if not path.is_file():
        raise ValueError(f"{path}: no such file (is {run_dir} a training run directory?)")
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f"{path}: holds no epoch yet")
    missing = [c for c in COLUMNS if c not in rows[0]]
    if missing:
        raise ValueError(f"{path}: lacks the column(s) {', '.join(missing)}")
    try:
        return {c: np.array([float(r[c]) for r in rows]) for c in COLUMNS}
    except (TypeError, ValueError) as e:
        raise ValueError(f"{path}: a value is not a number ({e})") from None


def summary(curve: dict[str, np.ndarray]) -> dict[str, float]:
    """Updates, last training and validation errors, best validation error and the
    updates where it was first reached."""
    best = int(np.argmin(curve["val_error_px"]))
    return {
        "updates": float(curve["step"][-1]),
        "train": float(curve["train_error_px"][-1]),
        "validation": float(curve["val_error_px"][-1]),
        "best": float(curve["val_error_px"][best]),
        "best_at": float(curve["step"][best]),
    }


def parse_run(text: str) -> tuple[str, str]:
    """``LABEL=RUN_DIR`` as ``(label, run_dir)``; a bare directory is its own label."""
    label, sep, run_dir = text.partition("=")
    if not sep:
        return text, text
    if not label or not run_dir:
        raise ValueError(f"expected LABEL=RUN_DIR, got {text!r}")
    return label, run_dir


def read_curve_pair(text: str) -> tuple[str, dict[str, np.ndarray]]:
    label, run_dir = parse_run(text)
    return label, read_curve(run_dir)


def plot(curves: dict[str, dict], out: str | Path, paper: float | None, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.5), constrained_layout=True)
    for k, (label, c) in enumerate(curves.items()):
        colour = f"C{k}"
        ax.plot(c["step"], c["val_error_px"], color=colour, lw=1.4, label=f"{label}")
        ax.plot(c["step"], c["train_error_px"], color=colour, lw=0.9, ls="--", alpha=0.8)
    if paper is not None:
        ax.axhline(paper, color="black", lw=1, ls=":", label=f"paper: {paper:g} px")
    ax.set_yscale("log")
    ax.set_xlabel("updates (optimiser steps)")
    ax.set_ylabel("trajectory error (px)")
    ax.set_title(f"{title}\nvalidation solid, training dashed", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(out, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", metavar="LABEL=RUN_DIR")
    p.add_argument("--out", required=True, help="PNG to write")
    p.add_argument("--paper", type=float, default=None, help="the paper's figure (px)")
    p.add_argument("--title", default="learning curves")
    args = p.parse_args(argv)
    try:
        curves = dict(read_curve_pair(r) for r in args.runs)
    except ValueError as e:
        print(f"learning_curves.py: error: {e}", file=sys.stderr)
        return 2
    print(format_record(run_record(__file__, argv)))
    print(f"{'run':40s} {'updates':>8s} {'train':>7s} {'valid.':>7s} {'best':>7s} {'at':>7s}")
    for label, c in curves.items():
        s = summary(c)
        print(
            f"{label:40s} {s['updates']:8.0f} {s['train']:7.3f} {s['validation']:7.3f} "
            f"{s['best']:7.3f} {s['best_at']:7.0f}"
        )
    plot(curves, args.out, args.paper, args.title)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
