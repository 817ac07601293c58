"""Put a trained run into the package as a shipped model (``src/img2dmp/models/NAME/``).

Copies the run's best checkpoint byte for byte to ``model.safetensors`` and writes
``model.json`` (format ``img2dmp-shipped-model``): the file's size and SHA-256, the
figures of an ``img2dmp evaluate`` of that checkpoint (its ``evaluation.json``: the test
part, the refinement it ran with), the settings the card recommends and where the model
came from. ``CARD.md`` beside them is written by hand from these (``tests/test_models.py``
checks that its figures are ``model.json``'s). Each shipped file must stay under 3 MB.

Run from the repository's root, after ``make model-real`` (or ``make model-omniglot``,
a stroke model, whose figures add the share of characters whose stroke count is right)::

    python experiments/ship_model.py --run runs/real/run \\
        --evaluation runs/real/evaluation/evaluation.json --name digits-real --default \\
        --summary "handwritten digits 0-9 ..." --provenance train_revision=0d7c727 ...

A field of an existing ``model.json`` that is not given again (summary, provenance,
recommended settings, default) is kept; ``--refine``, ``--refine-unfamiliar`` and
``--count-views`` set the recommended settings of those names. A model shipped for the
first time recommends what its run's training configuration's ``reading`` does
(docs/TRAINING.md, "Reading settings") where these flags do not say. Without ``--evaluation``,
a model shipped before with the same weights is shipped again with its figures (to add
a familiarity, say).
``--familiar DATA`` (the data set the run trained on) adds ``familiar.safetensors``: the
training drawings' encoder features (at most 16,384 of them) and the line below which an
image is flagged unfamiliar, drawn on its validation drawings (:mod:`img2dmp.familiar`);
without it a familiarity file shipped before is kept only while the weights are the
same.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from _provenance import run_record
from img2dmp._files import atomic_write_text, file_digest
from img2dmp.checkpoint import read_checkpoint_meta, resolve_checkpoint
from img2dmp.familiar import fit_familiar
from img2dmp.models import (
    FAMILIAR_FILE,
    FORMAT,
    RECORD_FILE,
    VERSION,
    WEIGHTS_FILE,
    checkpoint_reading,
    is_model_name,
)
from img2dmp.predict import Predictor

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "src" / "img2dmp" / "models"
MAX_BYTES = 3 * 1024 * 1024


def figures(evaluation: dict, command: str) -> dict:
    """The card's figures from an ``evaluation.json`` (means over its samples); a one-DMP
    model's best of its hypotheses, a stroke model's share of characters whose stroke
    count is right (and its ceiling, the share whose count is their class's most common
    one among the training drawings, when the evaluation has it)."""
    out = {
        "data": evaluation["dataset"],
        "dataset_sha256": evaluation["dataset_sha256"],
        "split": evaluation["split"],
        "n": evaluation["overall"]["n"],
        "refine": evaluation["refine_steps"],
        "chamfer_px": round(evaluation["chamfer"]["overall"]["mean"], 4),
        # shares to 5 digits: their percentages to 0.1 round as the unrounded ones do
        "path_on_ink": round(evaluation["on_ink"]["overall"]["mean"], 5),
        "path_error_px": round(evaluation["path_error"]["overall"]["mean"], 4),
        "table1_error_px": round(evaluation["overall"]["mean"], 4),
        "human_on_ink": round(evaluation["on_ink_human"]["overall"]["mean"], 4),
        "command": command,
    }
    if evaluation.get("refine_unfamiliar_steps") is not None:
        out["refine_unfamiliar"] = evaluation["refine_unfamiliar_steps"]
    if evaluation.get("unfamiliar"):  # the share of the part below the familiarity line
        out["unfamiliar_share"] = round(evaluation["unfamiliar"]["share"], 5)
    if "best_of_k" in evaluation:
        best = evaluation["best_of_k"]["path_error"]["overall"]["mean"]
        out["best_of_k_path_error_px"] = round(best, 4)
    if "strokes" in evaluation:
        out["count_right"] = round(evaluation["strokes"]["count_right"], 5)
        out["count_views"] = evaluation["strokes"]["count_views"]
        if evaluation["strokes"].get("count_mode_right") is not None:  # its ceiling
            out["count_mode_right"] = round(evaluation["strokes"]["count_mode_right"], 5)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", required=True, help="run directory or checkpoint")
    p.add_argument("--evaluation", help="its evaluation.json (omitted: a model shipped "
                   "before with the same weights keeps its figures)")  # fmt: skip
    p.add_argument("--name", required=True)
    p.add_argument("--summary")
    p.add_argument("--default", action="store_true", help="the model used when none is given")
    p.add_argument("--refine", type=int, help="recommended refinement steps")
    p.add_argument(
        "--refine-unfamiliar",
        type=int,
        help="recommended refinement steps of the images a model finds unfamiliar",
    )
    p.add_argument(
        "--count-views", type=int, help="a stroke model's recommended views to read the count from"
    )
    p.add_argument("--familiar", metavar="DATA",
                   help="the data set the run trained on: ship its familiarity")  # fmt: skip
    p.add_argument("--provenance", nargs="*", default=[], metavar="KEY=VALUE")
    args = p.parse_args(argv)
    if not is_model_name(args.name):
        p.error(f"--name {args.name!r} is not a model name (letters, digits, - and _)")
    source = resolve_checkpoint(args.run)
    meta = read_checkpoint_meta(source)  # verified: a damaged checkpoint is not shipped
    if source.stat().st_size > MAX_BYTES:
        p.error(f"{source} has {source.stat().st_size:,} bytes, more than {MAX_BYTES:,}")
    folder = MODELS / args.name
    old_path = folder / RECORD_FILE
    old = json.loads(old_path.read_text(encoding="utf-8")) if old_path.is_file() else {}
    if args.evaluation is None:
        if old.get("weights", {}).get("sha256") != file_digest(source):
            p.error(f"--evaluation is needed: {source} is not the weights {args.name} was "
                    "shipped with (their figures would not be its)")  # fmt: skip
        shown = old["figures"]
    else:
        evaluation = json.loads(Path(args.evaluation).read_text(encoding="utf-8"))
        command = (
            f"img2dmp evaluate --model {evaluation['model']} --data {evaluation['dataset']} "
            f"--split {evaluation['split']} --refine {evaluation['refine_steps']}"
        )
        if evaluation.get("refine_unfamiliar_steps") is not None:
            command += f" --refine-unfamiliar {evaluation['refine_unfamiliar_steps']}"
        if "strokes" in evaluation:
            command += f" --count-views {evaluation['strokes']['count_views']}"
        shown = figures(evaluation, command)
    folder.mkdir(parents=True, exist_ok=True)
    if not (folder / WEIGHTS_FILE).is_file() or not source.samefile(folder / WEIGHTS_FILE):
        shutil.copyfile(source, folder / WEIGHTS_FILE)
    recommended = dict(old.get("recommended") or checkpoint_reading(meta).recommended())
    for key in ("refine", "refine_unfamiliar", "count_views"):
        if getattr(args, key) is not None:
            recommended[key] = getattr(args, key)
    provenance = dict(old.get("provenance", {}))
    provenance.update(kv.split("=", 1) for kv in args.provenance)
    record = {
        "format": FORMAT,
        "version": VERSION,
        "name": args.name,
        "default": bool(args.default or old.get("default", False)),
        "summary": args.summary or old.get("summary", ""),
        "weights": {
            "file": WEIGHTS_FILE,
            "bytes": (folder / WEIGHTS_FILE).stat().st_size,
            "sha256": file_digest(folder / WEIGHTS_FILE),
            "record_sha256": meta["record_sha256"],
        },
        "recommended": recommended,
        "figures": shown,
        "provenance": provenance,
        "shipped_by": run_record("ship_model.py", sys.argv[1:] if argv is None else argv),
        "card": "CARD.md",
    }
    familiar = folder / FAMILIAR_FILE
    if args.familiar:
        fam = fit_familiar(Predictor.load(folder / WEIGHTS_FILE), args.familiar)
        fam.save(familiar)
        record["familiar"] = {
            "file": FAMILIAR_FILE, "bytes": familiar.stat().st_size,
            "sha256": file_digest(familiar), "line": round(fam.line, 6),
            "quantile": fam.quantile, "n_train": len(fam.features),
            "n_validation": fam.n_validation, "data": args.familiar,
        }  # fmt: skip
    elif "familiar" in old and old["weights"]["sha256"] == record["weights"]["sha256"]:
        record["familiar"] = old["familiar"]
    elif familiar.is_file():
        familiar.unlink()  # another network's features
    record["card"] = record.pop("card")  # last, as before
    atomic_write_text(old_path, json.dumps(record, indent=1) + "\n")
    print(
        f"{folder}: {WEIGHTS_FILE} ({record['weights']['bytes']:,} bytes, sha256 "
        f"{record['weights']['sha256'][:12]}...), {RECORD_FILE}; write CARD.md from it"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
