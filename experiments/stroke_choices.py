"""The choices of a stroke model, on the validation drawers: refinement settings, how the
stroke count is read, and how often a class's most common stroke count is right (the
count's ceiling for a reader that knew the character).

A stroke model (docs/TRAINING.md, "Stroke models") is refined on its image by all its
strokes at once; this script evaluates one trained run on the validation split with each
refinement setting of ``SETTINGS`` (steps, learning rate, prior weight) and prints the
path measures and the stroke count; then the count read from one view of each image or
from ``COUNT_VIEWS`` (the image and small affine copies, their probabilities averaged),
each with and without the bound of the image's pieces of ink. It also prints, per split,
the share of characters whose stroke count equals their class's most common count among
the training drawers: what a model that recognised every character, and knew nothing
else, would score.

Run from the repository's root::

    python experiments/stroke_choices.py --model runs/omniglot/run \\
        --data runs/omniglot/data.safetensors [--out DIR]

It prints the date, the git revision and its command line first; with ``--out`` it also
writes ``DIR/stroke_choices.json``. About 3 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from img2dmp.data.store import load_dataset
from img2dmp.evaluate import class_modes, evaluate, stroke_counts
from img2dmp.nn.refine import RefineOptions
from img2dmp.nn.strokes import COUNT_VIEWS, ink_pieces
from img2dmp.predict import Predictor

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record

#: (steps, lr, prior_weight) tried; (0, ...) is the network's own output.
SETTINGS = ((0, 0.0, 0.0), (30, 0.02, 5.0), (60, 0.02, 1.0), (60, 0.04, 0.3), (100, 0.04, 0.3))


def class_mode_shares(data) -> dict:
    """Per split, the share of characters whose stroke count is their class's most
    common one among the training drawers (:func:`img2dmp.evaluate.class_modes`; for
    one split of an evaluation: :func:`img2dmp.evaluate.count_ceiling`)."""
    counts = stroke_counts(data)
    labels = np.asarray(data.labels)
    mode = class_modes(data, counts)
    out = {}
    for s, name in enumerate(("train", "validation", "test")):
        idx = np.flatnonzero((data.split == s) & np.isin(labels, list(mode)))
        if len(idx):
            out[name] = float(np.mean([counts[i] == mode[int(labels[i])] for i in idx]))
    return out


def count_readings(predictor, data, split: str = "validation") -> list[dict]:
    """The share of ``split``'s characters whose stroke count is read right from 1 or
    :data:`~img2dmp.nn.strokes.COUNT_VIEWS` views of each image, each with and without
    the bound of the image's pieces of ink (a one-hypothesis model)."""
    if predictor.n_hypotheses != 1:
        raise ValueError("count_readings reads one-hypothesis stroke models")
    idx = np.flatnonzero(data.split == {"train": 0, "validation": 1, "test": 2}[split])
    truth = np.array([len(data.stroke_spans(int(i))) for i in idx])
    images = data.images[idx]
    pieces = np.clip(ink_pieces(images), 1, predictor.strokes.slots)
    rows, kept = [], predictor.count_views
    try:
        for views in (1, COUNT_VIEWS):
            predictor.count_views = views
            p = predictor.stroke_count_probabilities(images)[:, 0]  # [B, S]
            at_least = np.arange(1, p.shape[-1] + 1)[None] >= pieces[:, None]
            for bound, q in ((False, p), (True, np.where(at_least, p, -1.0))):
                right = float(np.mean(q.argmax(-1) + 1 == truth))
                rows.append({"views": views, "pieces_bound": bound, "count_right": right})
    finally:
        predictor.count_views = kept
    return rows


def _row(res: dict) -> dict:
    return {
        "chamfer_px": res["chamfer"]["overall"]["mean"],
        "on_ink": res["on_ink"]["overall"]["mean"],
        "path_px": res["path_error"]["overall"]["mean"],
        "count_right": res["strokes"]["count_right"],
    }


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, help="a stroke model's run directory")
    parser.add_argument("--data", required=True, help="its data set (img2dmp import)")
    parser.add_argument("--out", type=Path, help="write stroke_choices.json here")
    args = parser.parse_args(argv)
    record = run_record(__file__, argv)
    print(format_record(record))
    predictor = Predictor.load(args.model)
    if predictor.strokes is None:
        parser.error(f"{args.model} is not a stroke model")
    if predictor.meta.get("train_config", {}).get("data", {}).get("train_on_validation"):
        parser.error(
            f"{args.model} trained on the validation split (data.train_on_validation): "
            "choices measured there would not be measurements; give a run trained without it"
        )
    rows = []
    print(f"{'steps':>5} {'lr':>5} {'prior':>5} {'Chamfer':>8} {'on ink %':>8} {'path':>6} "
          f"{'count %':>7}")  # fmt: skip
    for steps, lr, prior in SETTINGS:
        predictor.refine_options = (
            RefineOptions(steps=steps, lr=lr, prior_weight=prior) if steps else None
        )
        r = _row(evaluate(predictor, args.data, split="validation", n_figures=0))
        rows.append({"steps": steps, "lr": lr, "prior_weight": prior, **r})
        ink, count = 100 * r["on_ink"], 100 * r["count_right"]
        print(f"{steps:>5} {lr:>5g} {prior:>5g} {r['chamfer_px']:>8.3f} {ink:>8.1f} "
              f"{r['path_px']:>6.2f} {count:>7.1f}")  # fmt: skip
    data = load_dataset(args.data)
    readings = count_readings(predictor, data)
    print("the stroke count read right (validation):")
    for r in readings:
        bound = "no fewer strokes than pieces of ink" if r["pieces_bound"] else "count alone"
        print(f"  {r['views']:>2} view(s), {bound:<36} {100 * r['count_right']:5.1f} %")
    modes = class_mode_shares(data)
    print("a class's most common count (training drawers) is right for: "
          + ", ".join(f"{k} {100 * v:.1f} %" for k, v in modes.items()))  # fmt: skip
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        doc = {"record": record, "refinement": rows, "count_readings": readings,
               "class_mode_count_right": modes}  # fmt: skip
        (args.out / "stroke_choices.json").write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
