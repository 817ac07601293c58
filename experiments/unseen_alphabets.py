"""How the recommended stroke recipe does on an alphabet it never saw: leave one alphabet
out.

For each alphabet of an Omniglot import (``img2dmp import``, split by drawer), a copy of
the data set in which that alphabet's drawings, all 20 drawers, are the test split; the
other alphabets' drawers 1-15 stay the training split and their drawers 16-20 are the
validation split (which only picks the best epoch). The recommended configuration
(``--config omniglot``) is trained on it from random weights and evaluated on the
held-out alphabet as ``make model-omniglot`` evaluates (refined 60 steps, the count from
one view; ``--refine N`` evaluates the same runs with N steps instead). The table gives,
per held-out alphabet, the measures ``img2dmp evaluate`` reports: Chamfer and path on the
ink against the image, path error against the drawer's own pen path, and the share of
characters read with as many strokes as their drawer drew.

Run from the repository's root::

    python experiments/unseen_alphabets.py --data runs/omniglot/data.safetensors \\
        --out runs/unseen-alphabets [--alphabets Greek Latin] [--jobs 2] [--epochs N] \\
        [--refine STEPS]

Resumable: an alphabet whose evaluation is written is not run again, a training that
was stopped resumes from its last checkpoint (a finished one is only loaded).
``--familiarity`` adds, per held-out alphabet, whether the run's encoder can tell its
characters from the ones it learnt: each image's *familiarity*, the cosine similarity of
its encoder features to those of the nearest training drawing, for the other alphabets'
drawers 16-17 (known characters, unseen drawings) and for the held-out alphabet; the
area under the ROC curve of telling them apart, the share of the held-out alphabet below
the familiarity that 95 % of the known drawings reach, and the count and ink of those
below and above it (``OUT/familiarity.md``). ``--refine-unfamiliar N`` evaluates the
trained runs again (in this process) with a familiarity fitted to each run
(:func:`img2dmp.familiar.fit_familiar` on its data set: the line from the known
alphabets' drawers 16-20) and N refinement steps for the held-out images below its
line (``evaluation[_refineR]_unfamiliarN``, ``results[_refineR]_unfamiliarN.md``). Writes
``OUT/ALPHABET/`` (data set, run, evaluation) and ``OUT/results.md`` (the table with the
date, revision and command); with ``--refine N`` other than 60, ``evaluation_refineN``
and ``results_refineN.md``.
About 6 minutes of training an alphabet on one core; ``--jobs 2`` trains two at once.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from img2dmp._files import atomic_write_text
from img2dmp.data.store import DigitData, load_dataset, save_dataset
from img2dmp.evaluate import evaluate, row_alphabets
from img2dmp.familiar import Familiar, fit_familiar
from img2dmp.predict import Predictor

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record
from count_probes import drawers

#: The command line's start: this Python's img2dmp, whatever is on PATH.
IMG2DMP = (sys.executable, "-m", "img2dmp")
#: Drawers whose drawings (of the alphabets kept) only pick the best epoch.
VALIDATION_DRAWERS = (16, 17, 18, 19, 20)
#: The refinement steps ``make model-omniglot`` evaluates with.
REFINE = 60


def _suffix(refine: int, unfamiliar: int | None = None) -> str:
    """The evaluation's and table's name suffix for ``refine`` steps (none for 60) and
    ``unfamiliar`` steps for the images below the familiarity line (none for None)."""
    steps = "" if refine == REFINE else f"_refine{refine}"
    return steps + ("" if unfamiliar is None else f"_unfamiliar{unfamiliar}")


def alphabets_of(data: DigitData) -> np.ndarray:
    """The alphabet of every row (``alphabet/character`` class names)."""
    if data.class_names is None:
        raise ValueError("the data set has no class names: not an Omniglot import")
    return row_alphabets(data)


def held_out(data: DigitData, alphabet: str) -> DigitData:
    """``data`` with ``alphabet``'s rows as the test split, the others' drawers 1-15 as
    training and :data:`VALIDATION_DRAWERS` as validation."""
    alpha, drawer = alphabets_of(data), drawers(data)
    if alphabet not in set(alpha):
        raise ValueError(f"no alphabet {alphabet!r} in the data set; it has {sorted(set(alpha))}")
    split = np.where(np.isin(drawer, VALIDATION_DRAWERS), 1, 0).astype(data.split.dtype)
    split[alpha == alphabet] = 2
    arrays = data.arrays()
    arrays["split"] = split
    meta = dict(data.meta)
    names = ("train", "validation", "test")
    meta["counts_by_split"] = {n: int((split == i).sum()) for i, n in enumerate(names)}
    meta["held_out_alphabet"] = alphabet
    return DigitData(**arrays, meta=meta)


def _commands(folder: Path, epochs: int | None, refine: int) -> tuple[list[str], list[str]]:
    data, run = folder / "data.safetensors", folder / "run"
    if (run / "checkpoints" / "last.safetensors").is_file():
        train = [*IMG2DMP, "train", "--run-dir", str(run), "--resume", "--no-progress"]
    else:
        train = [*IMG2DMP, "train", "--config", "omniglot", "--data", str(data)]
        train += ["--run-dir", str(run), "--force", "--no-progress"]
        if epochs:
            train += ["--epochs", str(epochs)]
    evaluate = [*IMG2DMP, "evaluate", "--model", str(run), "--data", str(data), "--split"]
    evaluate += ["test", "--refine", str(refine), "--count-views", "1", "--figures", "0"]
    evaluate += ["--out", str(folder / f"evaluation{_suffix(refine)}"), "--force", "--no-progress"]
    return train, evaluate


def _run_alphabet(folder: Path, epochs: int | None, refine: int) -> subprocess.Popen:
    """Train then evaluate in one child shell, its output in ``folder/log.txt``."""
    train, evaluate = _commands(folder, epochs, refine)
    script = f"{shlex.join(train)} && {shlex.join(evaluate)}"
    with open(folder / "log.txt", "a") as log:  # the child keeps its own descriptor
        return subprocess.Popen(["sh", "-c", script], stdout=log, stderr=subprocess.STDOUT)


def evaluate_unfamiliar(folder: Path, refine: int, unfamiliar: int) -> Path:
    """The run in ``folder`` evaluated on its held-out alphabet with a familiarity fitted
    to it and ``unfamiliar`` steps for the images below its line (``refine`` for the
    others); the evaluation's folder."""
    data, out = folder / "data.safetensors", folder / f"evaluation{_suffix(refine, unfamiliar)}"
    predictor = Predictor.load(folder / "run")
    predictor.familiar = fit_familiar(predictor, data)
    evaluate(predictor, data, split="test", out_dir=out, n_figures=0, refine=refine,
             refine_unfamiliar=unfamiliar, count_views=1)  # fmt: skip
    return out


def _row(alphabet: str, ev: dict) -> dict:
    st = ev["strokes"]
    return {
        "alphabet": alphabet,
        "n": int(ev["overall"]["n"]),
        "chamfer_px": float(ev["chamfer"]["overall"]["mean"]),
        "on_ink": float(ev["on_ink"]["overall"]["mean"]),
        "path_px": float(ev["path_error"]["overall"]["mean"]),
        "count_right": float(st["count_right"]),
        "unfamiliar": ev.get("unfamiliar", {}).get("share"),  # with a familiarity
    }


def auc(negatives: np.ndarray, positives: np.ndarray) -> float:
    """The area under the ROC curve of scores that should be higher for ``positives``
    (the Mann-Whitney statistic; ties count a half)."""
    neg, pos = np.sort(np.asarray(negatives, float)), np.asarray(positives, float)
    below = np.searchsorted(neg, pos, side="left")
    ties = np.searchsorted(neg, pos, side="right") - below
    return float((below + 0.5 * ties).sum() / (len(neg) * len(pos)))


def familiarity_row(folder: Path, alphabet: str, quantile: float = 0.05) -> dict:
    """The familiarity (:meth:`img2dmp.familiar.Familiar.familiarity` against the
    training drawings' encoder features) of the known drawings (drawers 16-17 of the
    other alphabets) and of the held-out alphabet, for the run in ``folder``, beside its
    evaluation's per-drawing counts and ink shares."""
    data = load_dataset(folder / "data.safetensors")
    predictor = Predictor.load(folder / "run")
    drawer = drawers(data)
    train = np.flatnonzero(data.split == 0)
    known = np.flatnonzero((data.split == 1) & (drawer <= 17))
    unseen = np.flatnonzero(data.split == 2)
    ref = Familiar(predictor.encoder_features(data.images[train]), line=0.0)
    fam_known = ref.familiarity(predictor.encoder_features(data.images[known]))
    fam_unseen = ref.familiarity(predictor.encoder_features(data.images[unseen]))
    limit = float(np.quantile(fam_known, quantile))
    ev = json.loads((folder / "evaluation" / "evaluation.json").read_text())
    st = ev["strokes"]
    ok = np.asarray(st["true_counts"]) == np.asarray(st["predicted_counts"])
    ink = np.asarray(ev["on_ink_shares"], float)
    low = fam_unseen < limit
    share = lambda v, sel: float(v[sel].mean()) if sel.any() else float("nan")  # noqa: E731
    return {
        "alphabet": alphabet,
        "known_median": float(np.median(fam_known)),
        "unseen_median": float(np.median(fam_unseen)),
        "auc": auc(fam_unseen, fam_known),  # known drawings the more familiar
        "limit": limit,
        "below": float(low.mean()),
        "count_below": share(ok, low), "count_above": share(ok, ~low),
        "ink_below": share(ink, low), "ink_above": share(ink, ~low),
    }  # fmt: skip


def format_familiarity(rows: list[dict]) -> str:
    out = ["| held-out alphabet | familiarity, known / held out (medians) | AUC | held out "
           "below the known 5 % | count right, below / above | on ink, below / above |",
           "|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        out.append(
            f"| {r['alphabet']} | {r['known_median']:.3f} / {r['unseen_median']:.3f} | "
            f"{r['auc']:.3f} | {100 * r['below']:.1f} % | {100 * r['count_below']:.1f} / "
            f"{100 * r['count_above']:.1f} % | {100 * r['ink_below']:.1f} / "
            f"{100 * r['ink_above']:.1f} % |"
        )
    return "\n".join(out)


def format_table(rows: list[dict]) -> str:
    below = bool(rows) and all(r.get("unfamiliar") is not None for r in rows)
    head = "| held-out alphabet | n | Chamfer (px) | on ink | path (px) | count right |"
    out = [head + (" below the familiarity line |" if below else "")]
    out.append("|---|---|---|---|---|---|" + ("---|" if below else ""))
    for r in rows:
        out.append(
            f"| {r['alphabet']} | {r['n']} | {r['chamfer_px']:.3f} | {100 * r['on_ink']:.1f} % "
            f"| {r['path_px']:.2f} | {100 * r['count_right']:.1f} % |"
            + (f" {100 * r['unfamiliar']:.1f} % |" if below else "")
        )
    if rows:
        n = np.array([r["n"] for r in rows], float)
        mean = {k: float(np.average([r[k] for r in rows], weights=n))
                for k in ("chamfer_px", "on_ink", "path_px", "count_right")}  # fmt: skip
        share = np.average([r["unfamiliar"] for r in rows], weights=n) if below else 0.0
        out.append(
            f"| all ({len(rows)}) | {int(n.sum())} | {mean['chamfer_px']:.3f} | "
            f"{100 * mean['on_ink']:.1f} % | {mean['path_px']:.2f} | "
            f"{100 * mean['count_right']:.1f} % |" + (f" {100 * share:.1f} % |" if below else "")
        )
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="an Omniglot import split by drawer")
    ap.add_argument("--out", required=True, help="folder for the data sets, runs and table")
    ap.add_argument("--alphabets", nargs="+", help="only these (default: every alphabet)")
    ap.add_argument("--jobs", type=int, default=2, help="trainings at once (default 2)")
    ap.add_argument("--epochs", type=int, help="training epochs (default: the config's)")
    ap.add_argument("--familiarity", action="store_true",
                    help="also measure how far the encoder tells the held-out alphabet "
                    "from known characters (OUT/familiarity.md)")  # fmt: skip
    ap.add_argument("--refine", type=int, default=REFINE,
                    help=f"refinement steps of the evaluation (default {REFINE})")  # fmt: skip
    ap.add_argument("--refine-unfamiliar", type=int, metavar="N",
                    help="evaluate the trained runs again with N steps for the images "
                    "below a familiarity line fitted to each run")  # fmt: skip
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error(f"--jobs must be >= 1, got {args.jobs}")
    if args.epochs is not None and args.epochs < 1:
        ap.error(f"--epochs must be >= 1, got {args.epochs}")
    if args.refine < 0:
        ap.error(f"--refine must be >= 0, got {args.refine}")
    unfamiliar = args.refine_unfamiliar
    if unfamiliar is not None and unfamiliar < 0:
        ap.error(f"--refine-unfamiliar must be >= 0, got {unfamiliar}")
    evaluation = f"evaluation{_suffix(args.refine, unfamiliar)}"
    record = run_record(__file__, argv)
    print(format_record(record), flush=True)
    data = load_dataset(args.data)
    every = sorted(set(alphabets_of(data)))
    chosen = args.alphabets or every
    unknown = sorted(set(chosen) - set(every))
    if unknown:
        ap.error(f"no alphabet {unknown[0]!r} in {args.data}; it has {every}")
    out = Path(args.out)
    todo = []
    for a in chosen:
        folder = out / a
        if (folder / evaluation / "evaluation.json").is_file():
            print(f"{a}: done before", flush=True)
            continue
        if unfamiliar is not None:  # the trained runs, evaluated again in this process
            if not (folder / "run" / "checkpoints" / "best.safetensors").is_file():
                ap.error(f"{a}: no trained run in {folder}; run once without "
                         "--refine-unfamiliar first")  # fmt: skip
            print(f"{a}: evaluating ({evaluate_unfamiliar(folder, args.refine, unfamiliar)})",
                  flush=True)  # fmt: skip
            continue
        folder.mkdir(parents=True, exist_ok=True)
        if not (folder / "data.safetensors").is_file():
            save_dataset(folder / "data.safetensors", held_out(data, a))
        todo.append(a)
    running: dict[str, subprocess.Popen] = {}
    failed = []
    start = time.monotonic()
    while todo or running:
        while todo and len(running) < args.jobs:
            a = todo.pop(0)
            print(f"{a}: training and evaluating (log {out / a / 'log.txt'})", flush=True)
            running[a] = _run_alphabet(out / a, args.epochs, args.refine)
        for a, proc in list(running.items()):
            if proc.poll() is not None:
                del running[a]
                took = time.monotonic() - start
                if proc.returncode:
                    failed.append(a)
                    print(f"{a}: failed (exit {proc.returncode}); see {out / a / 'log.txt'}")
                else:
                    print(f"{a}: done, {took / 60:.1f} min since start", flush=True)
        time.sleep(2)
    rows = []
    for a in chosen:
        path = out / a / evaluation / "evaluation.json"
        if path.is_file():
            rows.append(_row(a, json.loads(path.read_text())))
    table = format_table(rows)
    print(table)
    results = out / f"results{_suffix(args.refine, unfamiliar)}.md"
    atomic_write_text(results, f"{format_record(record)}\n\n{table}\n")
    if args.familiarity:
        done = [a for a in chosen if (out / a / "evaluation" / "evaluation.json").is_file()]
        fam = format_familiarity([familiarity_row(out / a, a) for a in done])
        print(fam)
        atomic_write_text(out / "familiarity.md", f"{format_record(record)}\n\n{fam}\n")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
