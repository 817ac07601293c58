"""Train the encoder-decoder network on a stored data set or the on-the-fly generator.

Settings come from defaults, then ``--config`` (YAML or TOML), then the shortcuts below,
then ``--set section.key=value`` overrides. The run directory receives config.yaml,
metrics.csv, training_curve.png and checkpoints/{best,last}.safetensors (+ .json).
Data-parallel: ``torchrun --nproc_per_node 2 -m img2dmp.cli train ...``.
"""

from __future__ import annotations

import argparse

HELP = "train the image-to-DMP network with cost (9) or (10)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="YAML or TOML training config (default: built-in defaults)")
    p.add_argument("--data", help="data-set file (.safetensors); omit to use the generator")
    p.add_argument("--run-dir", default="runs/train", help="output directory")
    p.add_argument("--cost", help="parameter (eq. 9), trajectory (eq. 10) or combined")
    p.add_argument(
        "--epochs", type=int, help="number of epochs (with --resume: train the run on to this many)"
    )
    p.add_argument("--seed", type=int, help="random seed")
    p.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="config overrides, e.g. optim.lr=3e-4 model.activation=tanh",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in --run-dir from its last checkpoint",
    )
    p.add_argument("--overwrite", action="store_true", help="start afresh in an existing run dir")
    p.add_argument(
        "--init-from",
        metavar="RUN",
        help="start from the weights (and output normalisation) of this run directory or "
        "checkpoint instead of random weights: fine-tuning (config key init_from)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    from ..train import load_config, train

    over = list(args.set)
    for key, value in (
        ("data.path", args.data),
        ("cost.name", args.cost),
        ("seed", args.seed),
    ):
        if value is not None:
            over.append(f"{key}={value}")
    if args.no_progress:
        over.append("progress=false")
    cfg = load_config(args.config, over)
    if args.init_from is not None:
        cfg.init_from = args.init_from
    res = train(cfg, args.run_dir, resume=args.resume, overwrite=args.overwrite, epochs=args.epochs)
    print(
        f"{res.epochs_run} epochs in {res.wall_s:.1f} s; best validation trajectory error "
        f"{res.best_val_error_px:.4f} px (epoch {res.best_epoch}); run in {res.run_dir}"
    )
    return 0
