"""Wall time until the ten-digit cost (10) model first reaches Table I's 0.23 px, then 0.15 px.

Trains the synthetic ten-digit model from scratch through :mod:`img2dmp.training`
(:func:`~img2dmp.training.open_run`, then one :func:`~img2dmp.training.train_epoch` per
epoch and the learning-rate schedule, i.e. :func:`~img2dmp.training.fit`'s epoch body
without its checkpoints, ``metrics.csv`` and internal validation, which have no hook for
an outside evaluation). Data come from the generator (``data.path: null``): every epoch
draws ``data.samples_per_epoch`` fresh samples seeded by ``(seed, epoch)``, or every
``data.refresh_epochs`` epochs (0: once; drawing them then counts once, in the setup).

What counts as training wall time: everything from just before ``open_run`` (generating
the fixed validation set and epoch 0's samples, fitting the output normalisation, numba's
first-call compilation unless cached, building the network) through every epoch
(generating its fresh samples, augmentation, optimiser steps, schedule). Not counted:
importing torch and the library, building the evaluation set, and the evaluations
themselves (reported apart).

The evaluation set is built like Table I's (``experiments/reproduce_table1.py``):
:func:`img2dmp.data.synthetic.generate_dataset` with seed 2, all in the test split, the
same DMP configuration as the training data, but ``--eval-per-digit`` samples per digit
(default 200, Table I: 2,000). It is measured with
:func:`img2dmp.nn.inference.dmp_trajectories` and
:func:`img2dmp.nn.costs.trajectory_error_px` after an epoch once ``--eval-every-s``
seconds of training have passed since the last evaluation (0, the default: every epoch).

Usage (from the repository's root)::

    python benchmarks/time_to_accuracy.py --budget-min 10 --out /tmp/tta
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch

from _machine import describe, load_average

ROOT = Path(__file__).resolve().parents[1]
#: Table I's cost (10) row (Pahic et al., ICRA 2018) and the project's own target (px).
TARGETS = (0.23, 0.15)
#: Evaluation images per forward pass.
EVAL_BATCH = 1024


@dataclass
class Curve:
    """The learning curve: one row per evaluation, and when each target was first met."""

    rows: list[dict] = field(default_factory=list)
    reached: dict[float, tuple[float, int]] = field(default_factory=dict)  # target: (s, epoch)
    eval_s: float = 0.0

    def add(self, train_s: float, epoch: int, error_px: float, eval_s: float) -> None:
        """Record one evaluation (``epoch`` counted from 1) and any target it meets."""
        self.eval_s += eval_s
        self.rows.append(
            {"train_wall_s": train_s, "epoch": epoch, "eval_error_px": error_px, "eval_s": eval_s}
        )
        for target in TARGETS:
            if error_px <= target and target not in self.reached:
                self.reached[target] = (train_s, epoch)


def parse_args(argv=None) -> argparse.Namespace:
    """Command-line options (see the module docstring)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", default="conv-wide", help="shipped configuration name or file")
    p.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="config overrides as for `img2dmp train --set` (after optim.patience=0, "
        "progress=false)",
    )
    p.add_argument("--out", type=Path, default=ROOT / "runs" / "time_to_accuracy")
    p.add_argument("--budget-min", type=float, default=45.0, help="training wall minutes")
    p.add_argument("--eval-per-digit", type=int, default=200)
    p.add_argument("--eval-every-s", type=float, default=0.0, help="0: after every epoch")
    return p.parse_args(argv)


def build_eval_set(per_digit: int, generator: dict) -> dict[str, torch.Tensor]:
    """Table I's evaluation set (seed 2, test split), ``per_digit`` samples of each digit.

    Parameters
    ----------
    per_digit : int
        Samples per digit.
    generator : dict
        The run's ``data.generator`` options (SyntheticConfig fields, ``dmp_config``).

    Returns
    -------
    dict
        ``images [M, H, W]``, ``times [M, T]``, ``trajectories [M, T, d]`` (float32).
    """
    from img2dmp.data.synthetic import SyntheticConfig, generate_dataset
    from img2dmp.dmp import DMPConfig

    opts = dict(generator)
    dmp = DMPConfig.from_dict(opts.pop("dmp_config", {}) or {})
    config = SyntheticConfig.from_dict(opts) if opts else None
    d = generate_dataset(
        per_digit, config, seed=2, splits=(0.0, 0.0, 1.0), dmp_config=dmp, progress=False
    )
    return {
        k: torch.as_tensor(getattr(d, k), dtype=torch.float32)
        for k in ("images", "times", "trajectories")
    }


def eval_error(run, ev: dict[str, torch.Tensor]) -> float:
    """Mean trajectory error (px) of the run's network on the evaluation set (Table I)."""
    from img2dmp.nn import trajectory_error_px
    from img2dmp.nn.inference import dmp_trajectories

    y = dmp_trajectories(
        run.state.model,
        run.data.normaliser,
        run.data.dmp_config,
        ev["images"],
        ev["times"],
        EVAL_BATCH,
    )
    return float(trajectory_error_px(y, ev["trajectories"]).double().mean())


def run_epoch(run, epoch: int) -> None:
    """One epoch as :func:`img2dmp.training.fit` runs it: fresh samples, steps, schedule."""
    from img2dmp.training import train_epoch, validate

    _, train_px = train_epoch(run, epoch)
    sched = run.state.scheduler
    if sched is None:
        return
    if run.cfg.optim.schedule == "plateau":  # the only schedule that needs validation
        sched.step(validate(run, epoch, fallback=train_px))
    else:
        sched.step()


def train_until(cfg, args, ev: dict[str, torch.Tensor]) -> tuple[Curve, int]:
    """Train from scratch until 0.15 px, the budget or ``optim.epochs``; the curve and epochs.

    An epoch is not started when the last epoch's duration says it would end past the
    budget (the first epoch always runs).
    """
    from img2dmp.training import open_run

    budget_s, curve = 60.0 * args.budget_min, Curve()
    t0 = time.perf_counter()  # the training clock starts here (evaluations subtracted)
    run = open_run(cfg, args.out / "run", overwrite=True)
    setup_s = time.perf_counter() - t0
    print(f"setup (data generator, normaliser, network): {setup_s:.1f} s", flush=True)
    last_eval, epoch_s, done = 0.0, 0.0, 0
    for epoch in range(cfg.optim.epochs):
        train_s = time.perf_counter() - t0 - curve.eval_s
        if epoch and train_s + epoch_s > budget_s:
            break
        t_epoch = time.perf_counter()
        run_epoch(run, epoch)
        epoch_s, done = time.perf_counter() - t_epoch, epoch + 1
        train_s = time.perf_counter() - t0 - curve.eval_s
        final = epoch == cfg.optim.epochs - 1 or train_s + epoch_s > budget_s
        if train_s - last_eval < args.eval_every_s and not final:
            continue
        t_eval = time.perf_counter()
        err = eval_error(run, ev)
        curve.add(train_s, epoch + 1, err, time.perf_counter() - t_eval)
        last_eval = train_s
        print(
            f"epoch {epoch + 1}: {train_s / 60:6.2f} min training, evaluation error "
            f"{err:.4f} px (epoch {epoch_s:.1f} s, evaluation {curve.rows[-1]['eval_s']:.1f} s)",
            flush=True,
        )
        if TARGETS[-1] in curve.reached:
            break
    return curve, done


def write_outputs(out: Path, curve: Curve, title: str) -> tuple[Path, Path]:
    """``metrics.csv`` (one row per evaluation) and ``learning_curve.png`` in ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from img2dmp._files import save_figure

    out.mkdir(parents=True, exist_ok=True)
    csv_path, png_path = out / "metrics.csv", out / "learning_curve.png"
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["train_wall_s", "epoch", "eval_error_px", "eval_s"])
        w.writeheader()
        w.writerows(curve.rows)
    fig, ax = plt.subplots(figsize=(6, 4))
    minutes = [r["train_wall_s"] / 60 for r in curve.rows]
    ax.plot(minutes, [r["eval_error_px"] for r in curve.rows], "o-", label="evaluation error")
    for target, style in zip(TARGETS, ("--", ":"), strict=True):
        ax.axhline(target, color="k", linestyle=style, label=f"{target} px")
    ax.set_yscale("log")
    ax.set_xlabel("training wall time (min, evaluations excluded)")
    ax.set_ylabel("mean trajectory error (px)")
    ax.set_title(title)
    ax.legend()
    save_figure(fig, png_path)
    return csv_path, png_path


def format_table(curve: Curve, budget_min: float) -> str:
    """Target, reached, wall minutes and epoch, one row per target."""
    lines = [
        f"{'target (px)':>11}  {'reached':>7}  {'wall min':>8}  {'epoch':>5}",
    ]
    for target in TARGETS:
        if target in curve.reached:
            s, epoch = curve.reached[target]
            lines.append(f"{target:>11.2f}  {'yes':>7}  {s / 60:>8.2f}  {epoch:>5d}")
        else:
            lines.append(f"{target:>11.2f}  {'no':>7}  {f'>{budget_min:g}':>8}  {'-':>5}")
    return "\n".join(lines)


def _refresh(every: int) -> str:
    if every == 1:
        return "drawn fresh every epoch"
    return "drawn once" if every == 0 else f"drawn fresh every {every} epochs"


def main(argv=None) -> int:
    """Run the benchmark; print the machine, the progress and the table."""
    from img2dmp.training import load_config

    args = parse_args(argv)
    print(describe(), flush=True)
    load_start = load_average()
    cfg = load_config(args.config, ["optim.patience=0", "progress=false", *args.set])
    print(
        f"config {args.config} with --set {' '.join(args.set) or '(none)'}; generator mode, "
        f"{cfg.data.samples_per_epoch} samples {_refresh(cfg.data.refresh_epochs)}; "
        f"{cfg.optim.epochs} epochs at most, {cfg.optim.schedule} schedule, "
        f"{cfg.threads} threads; budget {args.budget_min:g} "
        f"min of training; evaluation set: {args.eval_per_digit} per digit "
        f"(Table I: 2000), seed 2",
        flush=True,
    )
    t = time.perf_counter()
    ev = build_eval_set(args.eval_per_digit, cfg.data.generator)
    print(f"evaluation set: {len(ev['images'])} samples, built in "
          f"{time.perf_counter() - t:.1f} s (not counted)", flush=True)  # fmt: skip
    curve, epochs = train_until(cfg, args, ev)
    csv_path, png_path = write_outputs(
        args.out, curve, f"{Path(args.config).stem}: cost (10), ten digits, {epochs} epochs"
    )
    print(
        f"\n{epochs} epochs; evaluations: {len(curve.rows)}, {curve.eval_s:.1f} s in all "
        f"(not counted); wall time = training only (setup + epochs)"
    )
    print(format_table(curve, args.budget_min))
    print(f"load average at start {load_start}, at end {load_average()} (1/5/15 min)")
    print(f"wrote {csv_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
