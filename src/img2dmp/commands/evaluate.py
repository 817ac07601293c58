"""Evaluate a trained network as in Table I: per-sample mean trajectory error in pixels.

Prints mean, standard deviation, median and 95th percentile overall and per digit, then a
second table of measures that ignore the writer's speed (img2dmp.metrics), per digit and
overall: the path error (both paths resampled by arc length), the Chamfer distance (free
of order and direction), the share of the network's path on the image's ink beside the
demonstration's own share (the human reference), the median ratio of enclosed areas
network / demonstration for the closed digits 0, 6, 8, 9, and the distance between the
start points. A model with several hypotheses is judged on its most probable one, with a
best-of-K line. Writes evaluation.json (every statistic and the per-sample values),
evaluation.txt, examples.png (image, demonstrated path in blue, DMP path in red, like
Fig. 4 of the paper) and worst.png (the 12 largest path errors) to --out; those files, if
already there, are replaced only with --force (checked before the evaluation starts).

  img2dmp evaluate --model runs/paper --data digits.safetensors --digits 2,3
  img2dmp evaluate --model digits-real --data runs/real/data.safetensors --split test
  img2dmp evaluate runs/paper digits.safetensors --digits 2 3     (the older form)

The model and the data are given with --model and --data, as in the other commands, or
as the two positional arguments MODEL DATA; if both forms are used they must agree.
Without DATA, a run (or checkpoint) is evaluated on the data-set file it trained on, as
its checkpoint records it, if that file is still there unchanged (SHA-256). MODEL
is a run directory, a checkpoint or a shipped model's name (img2dmp models), which is
evaluated with the refinement its card (a shipped model) or its training configuration's
reading section (a run) recommends unless --refine says otherwise.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from . import _args

HELP = (
    "Table I statistics, timing-free path measures and Fig. 4 pictures of a trained network "
    "on a data set"
)
SPLITS = ("auto", "all", "train", "validation", "test")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", nargs="?", metavar="MODEL", help="the same as --model")
    p.add_argument("data", nargs="?", metavar="DATA", help="the same as --data")
    # The options keep their own names; model_and_data() reconciles the two forms.
    _args.add_model(p, dest="model_option")
    _args.add_data(p, dest="data_option", help="data-set file (.safetensors)")
    p.add_argument(
        "--split",
        default="auto",
        choices=SPLITS,
        help="auto = the test split if the file has one, else all",
    )
    _args.add_digits_or_classes(
        p, "only these digits (default: all in the data)", "only the classes of these names"
    )
    p.add_argument(
        "--out",
        metavar="DIR",
        help="output directory (default: MODEL/evaluation for a run dir, ./evaluation for a "
        "shipped model or a checkpoint file)",
    )
    _args.add_force(p, "evaluation files in --out")
    p.add_argument(
        "--figures",
        metavar="N",
        type=_args.int_at_least(0),
        default=16,
        help="samples drawn in examples.png, at most 12 of them in worst.png (0 = no picture)",
    )
    _args.add_refine(p)
    _args.add_count_views(p)
    _args.add_device(p, "the network")
    _args.add_no_progress(p)


def model_and_data(args: argparse.Namespace) -> tuple[str, str]:
    """MODEL and DATA from the positional arguments or from --model / --data."""
    out = []
    for name in ("model", "data"):
        positional, option = getattr(args, name), getattr(args, f"{name}_option")
        if (
            positional is not None
            and option is not None
            and not _args.same_path(positional, option)
        ):
            raise ValueError(
                f"{name.upper()} is given twice and differently: {positional!r} and "
                f"--{name} {option!r}"
            )
        value = option if option is not None else positional
        if value is None and name == "data":
            value = recorded_data_set(out[0])
        if value is None:
            raise ValueError(f"no {name} given: {EVALUATE_USAGE}")
        out.append(value)
    return out[0], out[1]


EVALUATE_USAGE = "img2dmp evaluate --model RUN --data FILE (or img2dmp evaluate RUN FILE)"


def recorded_data_set(model: str) -> str:
    """The data-set file the run or checkpoint ``model`` trained on, as its checkpoint
    records it (``dataset.path``, still there and of the recorded SHA-256), for
    ``evaluate MODEL`` without DATA; ``ValueError`` ("no data given: ...") saying why
    that file cannot stand in."""
    from .._files import file_digest
    from ..checkpoint import CheckpointError, read_checkpoint_meta

    try:
        record = read_checkpoint_meta(model).get("dataset") or {}
    except (OSError, CheckpointError):  # no such run: the usage says what to give
        raise ValueError(f"no data given: {EVALUATE_USAGE}") from None
    path, sha256 = record.get("path"), record.get("sha256")
    if not isinstance(path, str) or not path:
        why = f"{model} records no data-set file (it trained on generated samples)"
    elif not Path(path).is_file():
        why = f"the data set {model} trained on, {path}, is not there (as given when it trained)"
    elif sha256 and file_digest(path) != sha256:
        why = f"the data set {model} trained on, {path}, has changed since (SHA-256 differs)"
    else:
        return path
    raise ValueError(f"no data given, and {why}: {EVALUATE_USAGE}")


def run(args: argparse.Namespace) -> int:
    from ..evaluate import evaluate, format_table

    model, data = model_and_data(args)
    if args.data is None and args.data_option is None:
        print(f"note: evaluating on the data set {model} trained on: {data}")
    out = args.out
    if out is None:
        out = Path(model) / "evaluation" if Path(model).is_dir() else "evaluation"
    if Path(data).exists():  # a missing one the library names itself
        _args.check_inputs([data], "data set")
    _args.check_output_dir(out, "--out")
    # every file it writes (worst.png was replaced without --force, and not said)
    names = ["evaluation.json", "evaluation.txt"] + (FIGURES if args.figures else [])
    inputs = [("data set", data), *_args.model_inputs(model)]
    _args.check_outputs([(Path(out) / n, None) for n in names], args.force, inputs)
    _args.check_device(args.device)
    refine, unfamiliar = _args.refine_steps(args, model, "evaluate")
    res = evaluate(
        model,
        data,
        split=args.split,
        out_dir=out,
        n_figures=args.figures,
        digits=list(args.digits) if args.digits is not None else None,
        classes=list(args.classes) if args.classes is not None else None,
        refine=refine,
        refine_unfamiliar=unfamiliar,
        count_views=args.count_views,
        device=args.device,
        progress=not args.no_progress,
    )
    # Table I's table, then (in the same text) the path measures' table.
    print(format_table(res, f"trajectory error (px), {data} [{args.split}]"))
    if res.get("trained_on_split"):
        seen = f"{data} [{args.split}]"
        print(f"note: the model trained on some of these samples ({seen}): not a test")
    if res.get("untrained_classes"):
        print(untrained_note(res["untrained_classes"], data))
    if not res.get("framing", {}).get("same", True):
        print(framing_note(res["framing"], data))
    print(f"written: {Path(out) / names[0]}, {', '.join(names[1:])}")
    return 0


def untrained_note(classes: list[str], data: str) -> str:
    """One line naming the classes of ``data`` the model never trained on."""
    shown = ", ".join(classes[:20]) + (
        f" and {len(classes) - 20} more" if len(classes) > 20 else ""
    )
    return (
        f"note: the model never trained on the class{'es' if len(classes) > 1 else ''} "
        f"{shown} of {data}: these figures include how it reads what it never learnt "
        "(--classes selects the ones it did)"
    )


#: The figures evaluate writes beside its tables (--figures > 0): Fig. 4 and the worst.
FIGURES = ["examples.png", "worst.png"]


def framing_note(framing: dict, data: str) -> str:
    """One line saying that a data set's images are framed unlike the model's."""
    ours, theirs = framing["data_ink_margin"], framing["model_ink_margin"]
    return (
        f"note: {data} frames its images with {ours:.3f} of the side around the ink, the "
        f"model learnt {theirs:.3f} (as img2dmp predict frames images): these figures are "
        f"for images framed unlike its own (img2dmp import --margin {theirs:.3f})"
    )
