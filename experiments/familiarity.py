"""How often a stroke model that carries a familiarity (``img2dmp.familiar``) flags
characters "unfamiliar", and how it reads those it flags.

For a model (default the shipped ``omniglot-strokes``) and the data set it trained on:
per split (validation drawers, on which its line was drawn, and test drawers) the share
of characters below the line, and the stroke count right and the path on the ink for
those below and above it (the data set's prepared images, refined as ``predict``
refines). With ``--omniglot DIR``, the same for the Omniglot PNGs of the test drawers
themselves, each through ``predict`` as a user's image goes (its own preparation and
refinement); with ``--mnist DIR``, the share of MNIST test digits (an alphabet the model
never saw; each through ``predict``, ink dark) it flags.

Run from the repository's root::

    python experiments/familiarity.py --data runs/omniglot/data.safetensors \\
        [--model omniglot-strokes] [--omniglot ../shared/data/omniglot] \\
        [--mnist ../shared/data/mnist] [--n-mnist 500]

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
from img2dmp.predict import load_model

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record
from stroke_page import characters

#: Omniglot's test drawers (the split by drawer).
TEST_DRAWERS = (18, 19, 20)


def split_rows(predictor, data, split: int) -> dict:
    """Familiarity, count right and on-ink share of every row of ``split`` (1, 2)."""
    rows = np.flatnonzero(np.asarray(data.split) == split)
    images = np.asarray(data.images[rows], dtype=np.float32)
    fam = predictor.familiarity(images)
    strokes = predictor.predict_strokes(images)
    paths = predictor.stroke_paths(images)
    ok = np.array([len(v) for v, _ in strokes]) == stroke_counts(data)[rows]
    ink = np.array([on_ink_share(x[None], p[None])[0] for x, p in zip(images, paths, strict=True)])
    return {"familiarity": fam, "ok": ok, "ink": ink}


def describe(name: str, r: dict, line: float) -> str:
    """One line: how many are below the line, and how those below and above it read."""
    low = r["familiarity"] < line
    out = (
        f"{name}: {len(low)} characters, below the line {int(low.sum())} ({100 * low.mean():.1f} %)"
    )
    for what, sel in (("below", low), ("above", ~low)):
        if sel.any() and "ok" in r:
            out += (f"; {what}: count right {100 * r['ok'][sel].mean():.1f} %, on the ink "
                    f"{100 * r['ink'][sel].mean():.1f} %")  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="the data set the model trained on")
    ap.add_argument("--model", default="omniglot-strokes", help="a model with a familiarity")
    ap.add_argument("--omniglot", help="Omniglot folder: its test drawers' PNGs via predict")
    ap.add_argument("--mnist", help="MNIST folder: its first test digits via predict")
    ap.add_argument("--n-mnist", type=int, default=500, help="MNIST test digits (first N)")
    args = ap.parse_args(argv)
    if args.n_mnist < 1:
        ap.error(f"--n-mnist must be >= 1, got {args.n_mnist}")
    print(format_record(run_record(__file__, argv)), flush=True)
    predictor = load_model(args.model)
    if predictor.familiar is None or predictor.strokes is None:
        ap.error(f"model {args.model} is not a stroke model carrying a familiarity")
    line = predictor.familiar.line
    print(f"model {args.model}: line {line:.4f} ({100 * predictor.familiar.quantile:g} % of "
          f"{predictor.familiar.n_validation} validation drawings below it)")  # fmt: skip
    data = load_dataset(args.data)
    for split, name in ((1, "validation drawers"), (2, "test drawers")):
        print(describe(name, split_rows(predictor, data, split), line), flush=True)
    if args.omniglot:
        fam, ok, ink = [], [], []
        for drawer in TEST_DRAWERS:
            for _, image, n in characters(Path(args.omniglot), drawer):
                p = predictor.predict(image)
                fam.append(p.familiarity)
                ok.append(p.n_strokes == n)
                ink.append(p.fit["path_on_ink"])
        r = {"familiarity": np.array(fam), "ok": np.array(ok), "ink": np.array(ink)}
        print(describe("test drawers' PNGs through predict", r, line), flush=True)
    if args.mnist:
        raw = read_idx(Path(args.mnist) / "t10k-images-idx3-ubyte.gz")[: args.n_mnist]
        r = {"familiarity": np.array([predictor.predict(255 - d).familiarity for d in raw])}
        print(describe(f"MNIST test digits (first {len(raw)})", r, line), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
