"""How often a model that carries a familiarity (``img2dmp.familiar``) flags characters
"unfamiliar", and how it reads those it flags.

For a model (default the shipped ``omniglot-strokes``) and the data set it trained on:
per split (validation rows, on which its line was drawn, and test rows) the share of
characters below the line, and for those below and above it the path on the ink (the
top hypothesis, refined as ``predict`` refines) and, for a stroke model, the stroke
count right. Then, each image through ``predict`` as a user's image goes (its own
preparation and refinement):

``--omniglot DIR``
    Omniglot's test drawers' PNGs (18-20): known characters for a stroke model trained
    on them (with their count and ink), characters of no digit for a digit model.
``--mnist DIR``
    MNIST's first ``--n-mnist`` test digits (ink made dark).
``--photos DIR``
    Every ``*.png`` / ``*.jpg`` in DIR read as a page (``predict_page``): its characters
    flagged unfamiliar, and the page's own flags.

Run from the repository's root::

    python experiments/familiarity.py --data runs/omniglot/data.safetensors \\
        [--model omniglot-strokes] [--omniglot ../shared/data/omniglot] \\
        [--mnist ../shared/data/mnist] [--n-mnist 500] [--photos ../shared/data/photos]

Prints the date, revision and command first. About a minute on 2 cores.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from img2dmp.data.mnist import read_idx
from img2dmp.data.store import load_dataset
from img2dmp.evaluate import stroke_counts
from img2dmp.metrics import on_ink_share
from img2dmp.nn.strokes import character_paths
from img2dmp.predict import load_model

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record
from stroke_page import characters

#: Omniglot's test drawers (the split by drawer).
TEST_DRAWERS = (18, 19, 20)
#: Rows of a split read at most (a random choice, seed 0, when there are more).
MAX_ROWS = 4000


def split_rows(predictor, data, split: int) -> dict:
    """Familiarity and on-ink share (and a stroke model's count right) of the rows of
    ``split`` (1, 2), at most :data:`MAX_ROWS` of them."""
    rows = np.flatnonzero(np.asarray(data.split) == split)
    if len(rows) > MAX_ROWS:
        rows = np.sort(np.random.default_rng(0).choice(rows, MAX_ROWS, replace=False))
    images = np.asarray(data.images[rows], dtype=np.float32)
    fam = predictor.familiarity(images)
    if predictor.strokes is not None:
        strokes = predictor.predict_strokes(images)  # read and refined once
        paths = character_paths(strokes, predictor.normaliser, predictor.strokes)
        ok = np.array([len(v) for v, _ in strokes]) == stroke_counts(data)[rows]
    else:
        params, _ = predictor.predict_hypotheses(images)
        paths = predictor.trajectories(params[:, :1])[1][:, 0]  # the top hypothesis
        ok = None
    ink = np.array([on_ink_share(x[None], p[None])[0] for x, p in zip(images, paths, strict=True)])
    out = {"familiarity": fam, "ink": ink}
    if ok is not None:
        out["ok"] = ok
    return out


def describe(name: str, r: dict, line: float) -> str:
    """One line: how many are below the line, and how those below and above it read."""
    low = r["familiarity"] < line
    out = f"{name}: {len(low)} characters, below the line {int(low.sum())}"
    out += f" ({100 * low.mean():.1f} %)"
    for what, sel in (("below", low), ("above", ~low)):
        parts = []
        if sel.any() and "ok" in r:
            parts.append(f"count right {100 * r['ok'][sel].mean():.1f} %")
        if sel.any() and "ink" in r:
            parts.append(f"on the ink {100 * r['ink'][sel].mean():.1f} %")
        if parts:
            out += f"; {what}: " + ", ".join(parts)
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="the data set the model trained on")
    ap.add_argument("--model", default="omniglot-strokes", help="a model with a familiarity")
    ap.add_argument("--omniglot", help="Omniglot folder: its test drawers' PNGs via predict")
    ap.add_argument("--mnist", help="MNIST folder: its first test digits via predict")
    ap.add_argument("--n-mnist", type=int, default=500, help="MNIST test digits (first N)")
    ap.add_argument("--photos", help="a folder of photos of pages, each read as a page")
    args = ap.parse_args(argv)
    if args.n_mnist < 1:
        ap.error(f"--n-mnist must be >= 1, got {args.n_mnist}")
    print(format_record(run_record(__file__, argv)), flush=True)
    predictor = load_model(args.model)
    if predictor.familiar is None:
        ap.error(f"model {args.model} carries no familiarity")
    line = predictor.familiar.line
    print(f"model {args.model}: line {line:.4f} ({100 * predictor.familiar.quantile:g} % of "
          f"{predictor.familiar.n_validation} validation drawings below it)")  # fmt: skip
    data = load_dataset(args.data)
    for split, name in ((1, "validation rows"), (2, "test rows")):
        if (np.asarray(data.split) == split).any():
            print(describe(name, split_rows(predictor, data, split), line), flush=True)
    if args.omniglot:
        fam, ok, ink = [], [], []
        for drawer in TEST_DRAWERS:
            for _, image, n in characters(Path(args.omniglot), drawer):
                p = predictor.predict(image)
                fam.append(p.familiarity)
                ok.append(p.n_strokes == n if predictor.strokes is not None else False)
                ink.append(p.fit["path_on_ink"])
        r = {"familiarity": np.array(fam), "ink": np.array(ink)}
        if predictor.strokes is not None:
            r["ok"] = np.array(ok)
        print(describe("Omniglot test drawers' PNGs through predict", r, line), flush=True)
    if args.mnist:
        raw = read_idx(Path(args.mnist) / "t10k-images-idx3-ubyte.gz")[: args.n_mnist]
        r = {"familiarity": np.array([predictor.predict(255 - d).familiarity for d in raw])}
        print(describe(f"MNIST test digits (first {len(raw)})", r, line), flush=True)
    if args.photos:
        for photo in sorted(p for p in Path(args.photos).iterdir()
                            if p.suffix.lower() in (".png", ".jpg", ".jpeg")):  # fmt: skip
            page = predictor.predict_page(photo)
            n = len(page.characters)
            low = sum("unfamiliar" in c.flags for c in page.characters)
            print(f"{photo.name}: {n} characters, unfamiliar {low}, flagged "
                  f"{len(page.flagged)}; the page's flags {page.flags}", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
