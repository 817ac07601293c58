"""Train the encoder-decoder network on a stored data set or the on-the-fly generator.

Settings (img2dmp.training.TrainConfig: model, data, optim, cost, seed ...) come from the
defaults, then --config FILE (YAML, TOML or JSON) or NAME (a configuration shipped with
img2dmp: paper, conv-wide, real ...), then the shortcuts --data (data.path),
--cost (cost.name), --digits (data.digits), --classes (data.classes), --seed, --init-from
(init_from) and
--no-progress (progress), then --set section.key=value overrides, in order; unknown keys
are refused. The run directory receives config.yaml, metrics.csv, training_curve.png and
checkpoints/{best,last}.safetensors (+ .json).

  img2dmp train --config paper --data digits.safetensors --run-dir runs/paper \\
      --set optim.lr=3e-4 --set model.activation=tanh

--resume continues the run in --run-dir from its last checkpoint with the configuration
stored there; only --epochs (train on to this many epochs), --no-progress and --data (the
run's data set at another place: the same file, checked by its SHA-256) may be given
with it. A run directory that holds a model is never replaced without --force (the rule of
every command that writes; --overwrite is its older name); a --force restart deletes the
old run's checkpoints and records before it writes anything, so a restart stopped early
leaves nothing of the old run to resume.

--init-from RUN without --config takes the run's network, cost and reading settings
(model, strokes, cost, reading) from its checkpoint, the data, optimiser and seed from
the command line:

  img2dmp train --init-from runs/pre --data mine.safetensors --run-dir runs/tuned \\
      --epochs 20 --set optim.lr=1e-4

With --config, a network setting that differs from the run's is refused by name.

While a run trains, its directory is locked (the file DIR/.lock): a second run on the same
--run-dir stops at once with an error, and the lock goes with the first run (its end, an
error or a kill).
Data-parallel: torchrun --nproc_per_node 2 -m img2dmp train ...
--device cuda trains the network on a GPU (where the machine has one; the costs and the
DMP rollout stay on the CPU); a resumed run may change its device.
"""

from __future__ import annotations

import argparse
import errno
import json
import shlex
import time
from pathlib import Path

from . import _args

HELP = "train the image-to-DMP network with cost (9) or (10)"

#: Options that set the configuration, which a resumed run takes from its checkpoint.
CONFIG_OPTIONS = (
    "config", "set", "data", "cost", "seed", "digits", "classes", "init_from"
)  # fmt: skip


#: What a stroke model's error is, after it in the summary line (records.ERROR_MEASURES).
STROKE_SHAPE = (
    ": each true stroke against its matched predicted stroke, without the count, order, "
    "timing and pen-up travel that evaluate's trajectory error of the whole path includes"
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    _args.add_config(p, "TrainConfig sections (default: built-in defaults)")
    _args.add_data(p, help="data-set file (.safetensors) = data.path; omit to use the generator")
    p.add_argument("--run-dir", default="runs/train", metavar="DIR", help="output directory")
    p.add_argument(
        "--cost",
        metavar="NAME",
        help="cost.name: parameter (eq. 9), trajectory (eq. 10) or combined",
    )
    _args.add_digits_or_classes(
        p,
        "data.digits: train on these labels only (default: all)",
        "data.classes: train on the classes of these names only",
    )
    p.add_argument(
        "--epochs",
        metavar="N",
        type=_args.int_at_least(1),
        help="optim.epochs (with --resume: train the run on to this many epochs)",
    )
    p.add_argument("--seed", metavar="N", type=_args.int_at_least(0), help="random seed (= seed)")
    _args.add_set(p, "--set optim.lr=3e-4 model.activation=tanh --set optim.batch_size=32")
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in --run-dir from its last checkpoint, with its stored "
        "configuration (only --epochs may extend it; --data may give its data set's new "
        "place, the same file)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="start afresh in a run directory that holds a model, replacing it (without it "
        "an existing model is never replaced)",
    )
    p.add_argument("--overwrite", action="store_true", help="the older name of --force")
    p.add_argument(
        "--init-from",
        metavar="RUN|NAME",
        help="start from the weights (and output normalisation) of this run directory, "
        "checkpoint or shipped model (e.g. digits-real) instead of random weights: "
        "fine-tuning (= init_from). Without --config its model, strokes, cost and reading "
        "settings are the run's; with --config they must be its network's",
    )
    _args.add_device(p, "the network's training (its weights, forward and backward passes)")
    _args.add_no_progress(p)


def overrides(args: argparse.Namespace) -> list[str]:
    """The ``section.key=value`` overrides of the command line: the shortcuts, then every
    ``--set`` (all of them, in order; a later value of one key wins)."""
    over = []
    for key, value in (
        ("data.path", args.data),
        ("cost.name", args.cost),
        ("data.digits", list(args.digits) if args.digits is not None else None),
        ("data.classes", list(args.classes) if args.classes is not None else None),
        ("seed", args.seed),
        ("init_from", args.init_from),
    ):
        if value is not None:
            over.append(f"{key}={json.dumps(value)}")  # JSON is YAML: paths stay text
    if args.no_progress:
        over.append("progress=false")
    return over + list(args.set)


def check_resume(args: argparse.Namespace) -> None:
    """Refuse options that a resumed run would ignore."""
    if not args.resume:
        return
    given = [
        "--" + name.replace("_", "-")
        for name in CONFIG_OPTIONS
        if name != "data" and getattr(args, name) is not None and getattr(args, name) != []
    ]
    given += [f"--{flag}" for flag in ("force", "overwrite") if getattr(args, flag)]
    if given:
        raise ValueError(
            f"--resume continues the run in {args.run_dir} with the configuration stored in "
            f"its checkpoint, so {', '.join(given)} cannot be used with it (only --epochs can "
            "extend the run, and --data give its data set's new place); start a new run with "
            "another --run-dir or --force instead"
        )


#: What a run writes into --run-dir (the checkpoints' names as img2dmp.checkpoint has them).
RUN_OUTPUTS = ("config.yaml", "metrics.csv", "training_curve.png") + tuple(
    f"checkpoints/{name}{suffix}"
    for name in ("best", "last")
    for suffix in (".safetensors", ".json")
)


def check_run_outputs(args: argparse.Namespace) -> None:
    """No file a run writes may be one it reads (--data, --init-from, --config), whether
    the run directory holds a run or not: ``--init-from R --run-dir R --force`` would
    train over the network it starts from. (Existing runs: the training's own rule.)"""
    inputs = [("data set", args.data), *_args.model_inputs(args.init_from, "--init-from model")]
    outputs = [(Path(args.run_dir) / name, None) for name in RUN_OUTPUTS]
    _args.check_outputs(outputs, True, inputs + _args.config_inputs(args))


#: Failures to write a file that end a training whose earlier epochs may be saved.
WRITE_FAILURES = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EIO})


def saved_epochs(args: argparse.Namespace, started: float) -> str:
    """What an interrupted run keeps, and how to go on: the epochs its ``last`` checkpoint
    holds (written by this run, or the resumed run's own) and the command that resumes."""
    from ..checkpoint import CHECKPOINT_DIR, read_checkpoint_meta

    last = Path(args.run_dir) / CHECKPOINT_DIR / "last.safetensors"
    try:
        meta = read_checkpoint_meta(last)
        ours = args.resume or last.stat().st_mtime >= started
        done, total = meta["epoch"] + 1, meta["train_config"]["optim"]["epochs"]
    except (OSError, ValueError, KeyError, TypeError):
        ours = False
    if not ours:
        earlier = f"; the earlier run in {args.run_dir} is as it was" if last.is_file() else ""
        return f"no epoch of this run finished, so nothing of it is saved{earlier}"
    resume = shlex.join(["img2dmp", "train", "--run-dir", str(args.run_dir), "--resume"])
    return f"{done} of {total} epochs are saved in {last}; to continue: {resume}"


def _done_before(args: argparse.Namespace) -> int:
    """The epochs a resumed run had done (0 for a new run, or when its ``last`` checkpoint
    cannot be read: the training names what is wrong with it)."""
    from ..checkpoint import CHECKPOINT_DIR, read_checkpoint_meta

    if not args.resume:
        return 0
    try:
        return (
            int(
                read_checkpoint_meta(Path(args.run_dir) / CHECKPOINT_DIR / "last.safetensors")[
                    "epoch"
                ]
            )
            + 1
        )
    except (OSError, ValueError, KeyError, TypeError):
        return 0


def _reading(args: argparse.Namespace, cfg):
    """The run's reading settings: a resumed run's own (its ``config.yaml``, written as it
    resumed), not the command line's defaults."""
    if not args.resume:
        return cfg.reading
    from ..train import load_config

    try:
        return load_config(Path(args.run_dir) / "config.yaml", []).reading
    except (OSError, ValueError):
        return cfg.reading


def _epochs_run(before: int, after: int, wall_s: float) -> str:
    """What this command trained, numbered as the progress lines are (from 1)."""
    if after <= before:
        return (f"no epoch to train: the run has done its {after} epochs (--epochs N trains it "
                f"on to N)")  # fmt: skip
    if before:
        span = f"epoch {after}" if after == before + 1 else f"epochs {before + 1}-{after}"
        return f"{span} in {wall_s:.1f} s ({after} in all)"
    return f"{after} epoch{'s' if after != 1 else ''} in {wall_s:.1f} s"


def run(args: argparse.Namespace) -> int:
    check_resume(args)
    _args.check_device(args.device)
    from ..train import load_config, train
    from ..training.records import ERROR_MEASURES

    _args.check_output_dir(args.run_dir, "--run-dir")
    if args.data is not None:
        try:
            _args.check_inputs([args.data], "data set")
        except OSError as e:
            if not args.resume:
                raise
            raise type(e)(f"{e} (--resume --data names where the run's own data set is now; "
                          "only --epochs can extend the run)") from None  # fmt: skip
    check_run_outputs(args)
    cfg = load_config(args.config, overrides(args))
    if cfg.init_from and not args.config and not args.resume:  # the run's own network
        from ..training.config import run_sections

        cfg = load_config(None, overrides(args), base=run_sections(cfg.init_from))
    force = args.force or args.overwrite
    started, before = time.time(), _done_before(args)
    try:
        res = train(
            cfg,
            args.run_dir,
            resume=args.resume,
            overwrite=force,
            epochs=args.epochs,
            device=args.device,
            data=args.data if args.resume else None,
        )
    except KeyboardInterrupt as e:  # Ctrl-C or SIGTERM: the one line says what is kept
        e.args = (saved_epochs(args, started),)
        raise
    except OSError as e:  # a full disk, a quota: the same, after the file and the reason
        if e.errno not in WRITE_FAILURES:
            raise
        raise OSError(e.errno, f"{e.strerror}; {saved_epochs(args, started)}", e.filename) from None
    print(
        f"{_epochs_run(before, res.epochs_run, res.wall_s)}; best validation "
        f"{ERROR_MEASURES[res.error_measure]} {res.best_val_error_px:.4f} px (epoch "
        f"{res.best_epoch + 1}{STROKE_SHAPE if res.error_measure == 'stroke-shape' else ''}); "
        f"run in {res.run_dir}"
    )
    settings = {k: v for k, v in _reading(args, cfg).recommended().items() if v}
    if settings:
        flags = " ".join(f"--{k.replace('_', '-')} {v}" for k, v in settings.items())
        print(f"predict, write, evaluate and serve read it with {flags}, as its configuration's "
              "reading recommends (their own flags say otherwise)")  # fmt: skip
    return 0
