"""How often ``predict``'s ``several_characters`` flag fires for a digit model.

One-DMP digit models flag an image that holds two or more characters
(:func:`img2dmp.predict.count_characters` on the ink mask ``predict`` finds). Measured on
MNIST digits of ``--split`` (``--n`` drawn with seed 0 for ``train``, 1 for ``test``),
each padded by 12 px of paper and read as ``predict`` reads an image:

- **single**: one digit; the flag is a false alarm (and per digit 4, which the waist cuts
  part most);
- **pairs**: two digits side by side, cropped to their ink and placed ``gap`` pixels
  apart (negative: overlapping), for gaps -2, 0, +2, +5; the flag is right.

Four rules: ``digits (cut)``, the page's rule for digits (every mark cut into touching
digits and at its waists); ``no cut`` (marks as they are); ``cut if w/h >= A`` (cut only
a mark set at least A times as wide as tall, A = 1.0-1.4); and ``count_characters``, what
``predict`` does. ``--out DIR`` gets ``several_characters.json`` (date, revision,
command and the table).

    python experiments/several_characters.py --split train --data ../shared/data
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from img2dmp._files import atomic_write_text
from img2dmp.data.images import prepare_image_found
from img2dmp.data.mnist import load_mnist
from img2dmp.data.pages import find_characters
from img2dmp.predict import count_characters

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import run_record  # noqa: E402

ASPECTS = (1.0, 1.1, 1.2, 1.3, 1.4)
GAPS = (-2, 0, 2, 5)
PAD_PX = 12


def _tall(chars) -> int:
    tallest = max((c.box[3] - c.box[1] for c in chars), default=0)
    return int(sum(c.box[3] - c.box[1] >= 0.5 * tallest for c in chars))


def flags(mask) -> dict[str, bool]:
    """Whether each rule finds two or more characters in ``mask``."""
    cut = _tall(find_characters(mask).characters) >= 2
    whole = _tall(find_characters(mask, cut=False).characters) >= 2
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    aspect = (cols[-1] - cols[0] + 1) / (rows[-1] - rows[0] + 1)
    out = {"digits (cut)": cut, "no cut": whole}
    for a in ASPECTS:
        out[f"cut if w/h >= {a}"] = whole or (cut and aspect >= a)
    out["count_characters"] = count_characters(mask) >= 2
    return out


def _mask(image: np.ndarray) -> np.ndarray:
    return prepare_image_found(np.pad(image, PAD_PX), (28, 28))[2]


def _pair(a: np.ndarray, b: np.ndarray, gap: int) -> np.ndarray:
    """Two digits cropped to their ink columns, ``gap`` px apart, on one line."""

    def crop(img):
        cols = np.flatnonzero(img.max(0) > 0.2)
        return img[:, cols[0] : cols[-1] + 1]

    a, b = crop(a), crop(b)
    out = np.zeros((a.shape[0], max(a.shape[1] + gap + b.shape[1], a.shape[1])), np.float32)
    out[:, : a.shape[1]] = a
    s = a.shape[1] + gap
    out[:, s : s + b.shape[1]] = np.maximum(out[:, s : s + b.shape[1]], b)
    return out


def measure(images: np.ndarray, labels: np.ndarray, n: int, seed: int) -> dict:
    """The share of images each rule flags: single digits, 4s, and pairs per gap."""
    idx = np.random.default_rng(seed).choice(len(images), min(n, len(images)), replace=False)
    single, fours, n4 = {}, {}, 0
    for i in idx:
        for rule, hit in flags(_mask(images[i])).items():
            single[rule] = single.get(rule, 0) + hit
            fours[rule] = fours.get(rule, 0) + (hit and labels[i] == 4)
        n4 += int(labels[i] == 4)
    table = {"single": {r: v / len(idx) for r, v in single.items()},
             "fours": {r: v / max(n4, 1) for r, v in fours.items()}, "n": len(idx),
             "n_fours": n4}  # fmt: skip
    pairs = len(idx) // 2
    for gap in GAPS:
        hits = {}
        for j in range(pairs):
            m = _mask(_pair(images[idx[2 * j]], images[idx[2 * j + 1]], gap))
            for rule, hit in flags(m).items():
                hits[rule] = hits.get(rule, 0) + hit
        table[f"pairs gap {gap:+d}"] = {r: v / pairs for r, v in hits.items()}
    return table


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default="../shared/data", help="the data root (holds mnist/)")
    p.add_argument("--split", choices=("train", "test"), default="train")
    p.add_argument("--n", type=int, default=1500, help="digits drawn (pairs: half as many)")
    p.add_argument("--out", help="folder for several_characters.json")
    args = p.parse_args(argv)
    images, labels = load_mnist(Path(args.data) / "mnist", args.split)
    table = measure(images, labels, args.n, seed=0 if args.split == "train" else 1)
    for row, shares in table.items():
        if isinstance(shares, dict):
            print(f"{row:>13}: " + ", ".join(f"{r} {v:.1%}" for r, v in shares.items()))
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        argv = sys.argv[1:] if argv is None else list(argv)
        doc = {"run": run_record(__file__, argv), "split": args.split, "table": table}
        atomic_write_text(Path(args.out) / "several_characters.json", json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
