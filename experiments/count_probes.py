"""Probes of a stroke model's stroke count on the validation drawers (RESULTS 8.2, 8.3,
8.15) and on alphabets held out (8.18): does it grow with more drawers, with an auxiliary
head that names the character, with more views, an ensemble or another way of reading
the count's probabilities (a lean, a quantile, the nearest training drawings' counts), by
the refined strokes' fit to the ink, or from the ink itself; what is the ceiling of a
count learnt per character? Subcommands:

``drop-drawers DATA OUT --drawers 14,15``
    A copy of an Omniglot data set (``img2dmp import``) whose drawings by these drawers
    (the ``_NN`` of the image's file name) leave the training split (they become test
    rows, which no training or validation reads): to see what two drawers more are worth.
``class-head --data DATA --run-dir RUN --weight W [--seed N] [--epochs E]``
    ``img2dmp train --config omniglot`` with an auxiliary linear head on the encoder's
    features that names the character (cross-entropy weight ``W`` beside the stroke cost;
    training only). A probe, not a feature: it patches the training code for the run, and
    the head is left out of ``best.safetensors`` so that ``Predictor`` loads the run.
``recognise --data DATA [--encoders NAME ...] [--epochs E]``
    How well the character itself is recognised from the image: a classifier (one of
    :data:`ENCODERS`, the package's convolutional encoder, and a linear layer over the
    classes) trained on the training drawers with the stroke models' augmentation, its
    accuracy on the training and validation drawers. The count can only be the class's
    where the class is recognised.
``ceilings --data DATA``
    Per split, what a reader that recognised every character and knew nothing else could
    score: the share of drawings whose count is their class's most common count among the
    training drawers, and the same with the image's pieces of ink seen too (the most
    common count among the class's training drawings of as many pieces, never fewer than
    the pieces). No model: the ceilings of a count learnt per character.
``fit --data DATA RUN``
    Whether the image settles the count where the network hesitates: per validation
    drawing the two most probable counts (1 view, no fewer than the pieces of ink), each
    read and refined on the image as ``predict`` does (60 steps), and the count taken as
    the larger one when its strokes write more of the ink than the smaller one's by more
    than a margin (``ink_written_share``, several margins).
``read --data DATA RUN [RUN ...]``
    Per run: the share of the validation drawings whose count is read right (from 8
    views, no fewer than the image's pieces of ink), with 1, 16 and 32 views, and by the
    smallest count whose cumulative probability reaches 0.4 (instead of the most
    probable count); every run's count probabilities averaged (an ensemble, from 8 views
    and from 1); the class-mode ceiling (:func:`stroke_choices.class_mode_shares`); and
    how often a run's count is its class's most common count among the training drawers.
``rules --data DATA RUN [--split validation|test]``
    Other rules for reading one run's count (1 view, no fewer than the pieces of ink):
    the most probable count after a lean toward more strokes (``beta`` added to the log
    probability per stroke: the model errs more by too few strokes than by too many); the
    smallest count whose cumulative probability reaches ``q``; the counts of the nearest
    training drawings in the encoder's feature space (the familiarity's cosine
    similarity; ``k`` of them, each weighted by ``exp(20 cos)``), alone and mixed with the
    network's probabilities (share ``a`` of the neighbours' votes). Choose on the
    validation drawers; ``--split test`` reads the test drawers with every rule.
``ink EVALUATION DATA [EVALUATION DATA ...]``
    A count read from the image's ink instead of the network's, where the network has
    least to go on: per ``img2dmp evaluate`` output (its ``evaluation.json``, with the
    familiarity: ``--refine-unfamiliar``) and the data set it evaluated (its evaluated
    split, in order), the count right by the network, by the pieces of ink, by the
    skeleton's ends (half of them, at least the pieces), and by those where the network
    is unsure (its count's probability below ``q``) or finds the image unfamiliar. For
    the alphabets held out in turn (``unseen_alphabets.py``, RESULTS 8.9) and the known
    alphabets' validation drawers, side by side. Last, per evaluation, the rule that the
    other evaluations of its split choose (the most characters right, pooled) and what
    it gives there: whether a choice made on some alphabets carries over to another.

Run from the repository's root, e.g.::

    python experiments/count_probes.py read --data runs/omniglot/data.safetensors RUN1 RUN2

Each prints the date, the git revision and its command line first. ``class-head`` takes
as long as a training run (5 minutes for 120 epochs on 2 cores), ``read`` a few seconds
a run.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

from img2dmp.data.store import SPLITS, DigitData, load_dataset, save_dataset
from img2dmp.evaluate import class_modes
from img2dmp.nn.strokes import ink_pieces
from img2dmp.predict import Predictor

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record
from stroke_choices import class_mode_shares

#: The share of the count's probability the ``read`` subcommand's other rule reaches.
QUANTILE = 0.4
_DRAWER = re.compile(r"_(\d+)\.png$")


def drawers(data: DigitData) -> np.ndarray:
    """The drawer (1-20) of each row of an Omniglot import, from its image's file name."""
    names = data.meta.get("rows", {}).get("image")
    if not names:
        raise ValueError("the data set records no image file per row: not an Omniglot import")
    found = [_DRAWER.search(n) for n in names]
    if not all(found):
        bad = next(n for n, m in zip(names, found, strict=True) if not m)
        raise ValueError(f"image {bad!r} does not end in _NN.png (an Omniglot drawer)")
    return np.array([int(m.group(1)) for m in found])


def drop_drawers(data: DigitData, gone: list[int]) -> DigitData:
    """``data`` with the training rows of the drawers ``gone`` moved to the test split."""
    arrays = data.arrays()
    split = arrays["split"].copy()
    split[np.isin(drawers(data), gone) & (split == 0)] = 2
    arrays["split"] = split
    return DigitData(**arrays, meta=data.meta)


def train_with_class_head(data: str, run_dir: str, weight: float, seed: int, epochs: int) -> int:
    """``img2dmp train --config omniglot`` with the auxiliary class head (module docstring).

    The character's class rides beside the count's target (one-hot columns after the S
    count columns of ``Split.z_target``); the stroke cost adds ``weight`` times the head's
    cross-entropy on the encoder's features of the batch it was called on."""
    import torch

    import img2dmp.nn.strokes as strokes
    import img2dmp.training.data as tdata
    import img2dmp.training.loop as loop
    import img2dmp.training.setup as setup
    from img2dmp import cli
    from img2dmp.checkpoint import load_checkpoint, save_checkpoint

    n_classes = int(np.asarray(load_dataset(data).labels).max()) + 1
    features: dict = {}
    count_targets, build_model = tdata.count_targets, setup.build_model
    cost_call, train_epoch, validate = strokes.StrokeCost.__call__, loop.train_epoch, loop.validate

    def targets(a, idx, train_idx, slots, w):
        labels = torch.as_tensor(np.asarray(a.labels)[idx])
        one_hot = torch.nn.functional.one_hot(labels, n_classes).float()
        return torch.cat([count_targets(a, idx, train_idx, slots, w), one_hot], 1)

    def model_with_head(cfg, seed=None):
        model = build_model(cfg, seed=seed)
        model.class_head = torch.nn.Linear(model.encoder.out_features, n_classes)
        model.encoder.register_forward_hook(lambda m, i, out: features.__setitem__("x", out))
        return model

    def cost(self, out, z_target, times, trajectories, images=None):
        s = self.layout.slots
        loss, err = cost_call(self, out, z_target[:, :s], times, trajectories, images)
        logits = features["head"](features["x"][: len(out)])
        ce = torch.nn.functional.cross_entropy(logits, z_target[:, s:].argmax(1))
        return loss + weight * ce, err

    def head_first(step):
        def run_step(run, *args, **kw):
            features["head"] = run.state.model.class_head
            return step(run, *args, **kw)

        return run_step

    patches = [
        (tdata, "count_targets", targets),
        (setup, "build_model", model_with_head),
        (strokes.StrokeCost, "__call__", cost),
        (loop, "train_epoch", head_first(train_epoch)),
        (loop, "validate", head_first(validate)),
    ]
    kept = [(obj, name, getattr(obj, name)) for obj, name, _ in patches]
    try:
        for obj, name, new in patches:
            setattr(obj, name, new)
        code = cli.main(["train", "--config", "omniglot", "--data", data, "--run-dir", run_dir,
                         "--seed", str(seed), "--epochs", str(epochs), "--no-progress",
                         "--force"])  # fmt: skip
    finally:
        for obj, name, old in kept:
            setattr(obj, name, old)
    if code == 0:
        best = Path(run_dir) / "checkpoints" / "best.safetensors"
        ck = load_checkpoint(best)
        state = {k: v for k, v in ck.model_state.items() if not k.startswith("class_head.")}
        save_checkpoint(best, state, ck.meta)
    return code


#: The encoders ``recognise`` compares: ConvEncoder's arguments (``omniglot`` was 8.1's
#: stroke model's: 3 convolutions of 32, 64, 128 channels, a layer of 128; ``chosen`` is
#: 8.2's, configs/omniglot.yaml), and for the classifier ``dropout`` (the share of the
#: code's units dropped in training) and ``elastic`` (RMS px, smoothing px of a random
#: displacement field applied after the affine transform, :func:`elastic`) and ``strokes``
#: (degrees, scale, px of each stroke's own small transform before the affine one,
#: :func:`stroke_jitter`). RESULTS 8.2, 8.4, 8.6.
ENCODERS = {
    "omniglot": {"channels": [32, 64, 128], "latent": 128},
    "stride1": {"channels": [32, 32, 64, 128], "latent": 128, "strides": [1, 2, 2, 2]},
    "batchnorm": {"channels": [32, 64, 128], "latent": 128, "norm": "batch"},
    "wide": {"channels": [64, 128, 256], "latent": 256},
    "deep-batchnorm": {"channels": [32, 64, 128, 128], "latent": 128, "strides": [1, 2, 2, 2],
                       "norm": "batch"},
    "chosen": {"channels": [32, 64, 128, 128], "latent": 96, "strides": [1, 2, 2, 2],
               "norm": "batch"},
    "chosen-dropout": {"channels": [32, 64, 128, 128], "latent": 96, "strides": [1, 2, 2, 2],
                       "norm": "batch", "dropout": 0.3},
    "five-batchnorm": {"channels": [32, 32, 64, 128, 128], "latent": 96,
                       "strides": [1, 1, 2, 2, 2], "norm": "batch"},
    "chosen-elastic": {"channels": [32, 64, 128, 128], "latent": 96, "strides": [1, 2, 2, 2],
                       "norm": "batch", "elastic": (2.0, 4.0)},
    "chosen-stride2": {"channels": [32, 64, 128, 128], "latent": 96, "strides": [2, 2, 2, 2],
                       "norm": "batch"},
    "wide-batchnorm": {"channels": [48, 96, 160, 160], "latent": 96, "strides": [1, 2, 2, 2],
                       "norm": "batch"},
    "chosen-strokes": {"channels": [32, 64, 128, 128], "latent": 96, "strides": [1, 2, 2, 2],
                       "norm": "batch", "strokes": (6.0, 0.08, 1.0)},
    "chosen-strokes-strong": {"channels": [32, 64, 128, 128], "latent": 96,
                              "strides": [1, 2, 2, 2], "norm": "batch",
                              "strokes": (12.0, 0.15, 2.0)},
}  # fmt: skip


def stroke_jitter(images, paths, deg: float, scale: float, px: float, rng):
    """``(images, paths)`` with every stroke moved by its own small affine transform about
    its centre (rotation within ``deg`` degrees, scale within 1 +- ``scale``, shift within
    ``px`` pixels): each pixel goes with the stroke of the nearest pen-down instant, the
    images are the strokes' moved pixels overlaid (their maximum). ``images [B, H, W]``,
    ``paths [B, T, 3]`` (x, y in pixels, pen) tensors."""
    import torch

    from img2dmp.data.affine import warp_images

    b, h, w = images.shape
    pen = paths[..., 2] > 0.5  # [B, T]
    start = pen & ~torch.cat([torch.zeros_like(pen[:, :1]), pen[:, :-1]], 1)
    stroke = torch.cumsum(start.long(), 1) - 1  # [B, T], the stroke of each instant
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij"
    )
    grid = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1)  # [HW, 2]
    d = torch.cdist(grid[None].expand(b, -1, -1), paths[..., :2].float())  # [B, HW, T]
    d = torch.where(pen[:, None, :], d, torch.full_like(d, 1e9))
    owner = torch.gather(stroke, 1, d.argmin(-1)).reshape(b, h, w)  # [B, H, W]
    n = int(stroke.max()) + 1
    out_images = torch.zeros_like(images)
    out_paths = paths.clone()
    for s in range(n):
        mine = stroke == s  # [B, T]
        has = mine.any(1)
        if not has.any():
            continue
        cnt = mine.sum(1).clamp_min(1)[:, None]
        centre = (paths[..., :2] * mine[..., None]).sum(1) / cnt  # [B, 2]
        a = np.radians(rng.uniform(-deg, deg, b))
        k = 1.0 + rng.uniform(-scale, scale, b)
        t = rng.uniform(-px, px, (b, 2))
        rot = (
            np.stack(
                [np.stack([np.cos(a), -np.sin(a)], -1), np.stack([np.sin(a), np.cos(a)], -1)], 1
            )
            * k[:, None, None]
        )  # [B,2,2]
        rot = torch.as_tensor(rot, dtype=torch.float64)
        c = centre.to(torch.float64)
        shift = c - (rot @ c[..., None])[..., 0] + torch.as_tensor(t)
        m = torch.cat([rot, shift[..., None]], -1)  # [B, 2, 3]: p' = R (p - c) + c + t
        m[~has] = torch.tensor([[1.0, 0, 0], [0, 1.0, 0]], dtype=torch.float64)
        moved = warp_images(images * (owner == s), m)
        out_images = torch.maximum(out_images, moved)
        xy = paths[..., :2].to(torch.float64)
        new = (xy @ m[:, :, :2].transpose(1, 2) + m[:, None, :, 2]).to(paths.dtype)
        out_paths[..., :2] = torch.where(mine[..., None], new, out_paths[..., :2])
    return out_images, out_paths


def elastic(images, alpha: float, sigma: float, rng):
    """``images`` [B, H, W] under a smooth random displacement field (pixels: each of
    its components white noise smoothed by a Gaussian of ``sigma`` px, scaled to an RMS
    of ``alpha`` px)."""
    import torch
    import torch.nn.functional as F

    b, h, w = images.shape
    noise = torch.as_tensor(rng.standard_normal((b, 2, h, w)), dtype=torch.float32)
    r = int(3 * sigma)
    k = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=torch.float32) / sigma) ** 2)
    k = k / k.sum()
    field = F.conv2d(noise.reshape(-1, 1, h, w), k.view(1, 1, 1, -1), padding=(0, r))
    field = F.conv2d(field, k.view(1, 1, -1, 1), padding=(r, 0)).reshape(b, 2, h, w)
    field = field * alpha / field.pow(2).mean((1, 2, 3), keepdim=True).sqrt().clamp_min(1e-6)
    ys, xs = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    src_x = xs[None] + field[:, 0]
    src_y = ys[None] + field[:, 1]
    grid = torch.stack([2 * src_x / (w - 1) - 1, 2 * src_y / (h - 1) - 1], -1)
    return F.grid_sample(images[:, None], grid, align_corners=True)[:, 0]


def recognise(data_path: str, encoder: str, epochs: int, seed: int = 0) -> tuple[float, float]:
    """(training, validation) accuracy of a character classifier with ``encoder``
    (:data:`ENCODERS`) trained ``epochs`` epochs (Adam 1e-3, cosine, batches of 64, one
    fresh affine transform per image and epoch, the ranges of configs/omniglot.yaml,
    then the encoder's ``elastic`` field if it has one)."""
    import torch

    from img2dmp.data.affine import AffineRanges, sample_affine, warp_images
    from img2dmp.nn.model import ConvEncoder
    from img2dmp.training import load_config

    data = load_dataset(data_path)
    labels = torch.as_tensor(np.asarray(data.labels))
    images = torch.as_tensor(data.images[:])
    paths = torch.as_tensor(data.trajectories[:])
    train, val = np.flatnonzero(data.split == 0), np.flatnonzero(data.split == 1)
    ranges = AffineRanges(**load_config("omniglot").data.augment)
    v = ENCODERS[encoder]
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    size = list(images.shape[1:])
    enc = ConvEncoder(
        size, v["channels"], v["latent"], "relu", v.get("strides"), v.get("norm", "none")
    )
    classes = torch.nn.Linear(v["latent"], int(labels.max()) + 1)
    model = torch.nn.Sequential(enc, torch.nn.Dropout(v.get("dropout", 0.0)), classes)
    opt = torch.optim.Adam(model.parameters(), 1e-3)
    steps = epochs * -(-len(train) // 64)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, 1e-6)
    for _ in range(epochs):
        model.train()
        order = rng.permutation(train)
        for lo in range(0, len(order), 64):
            b = order[lo : lo + 64]
            first = images[b]
            if "strokes" in v:  # each stroke moved first, then the whole character
                first, _ = stroke_jitter(first, paths[b], *v["strokes"], rng)
            moved = warp_images(first, torch.as_tensor(sample_affine(rng, len(b), size, ranges)))
            if "elastic" in v:
                moved = elastic(moved, *v["elastic"], rng)
            loss = torch.nn.functional.cross_entropy(model(moved), labels[b])
            opt.zero_grad()
            loss.backward()
            opt.step()
            schedule.step()
    model.eval()
    with torch.no_grad():
        return tuple(
            float((model(images[i]).argmax(1) == labels[i]).float().mean()) for i in (train, val)
        )


def count_probabilities(
    predictor: Predictor, images: np.ndarray, pieces: np.ndarray, views: int
) -> np.ndarray:
    """A stroke model's count probabilities ``[B, S]`` read from ``views`` views, those
    below the images' ``pieces`` of ink (:func:`ink_pieces`) set to 0 (as ``predict``
    reads them)."""
    predictor.count_views = views
    prob = predictor.stroke_count_probabilities(images)[:, 0]
    at_least = np.arange(1, prob.shape[-1] + 1)[None] >= np.clip(pieces, 1, prob.shape[-1])[:, None]
    return np.where(at_least, prob, 0.0)


def read(data_path: str, runs: list[str]) -> None:
    data = load_dataset(data_path)
    idx = np.flatnonzero(data.split == 1)
    if not len(idx):
        raise SystemExit(f"{data_path} has no validation split")
    counts = np.array([len(data.stroke_spans(int(i))) for i in range(len(data))])
    labels, images, truth = np.asarray(data.labels), data.images[idx], counts[idx]
    pieces = ink_pieces(images)
    mode = class_modes(data, counts)
    class_mode = np.array([mode.get(int(labels[i]), 0) for i in idx])  # 0: no training row

    def right(prob, rule="most probable"):
        if rule == "most probable":
            said = prob.argmax(1) + 1
        else:
            cum = np.cumsum(prob / prob.sum(1, keepdims=True), 1)
            said = (cum >= QUANTILE).argmax(1) + 1
        return 100 * np.mean(said == truth), said

    print(f"validation drawings: {len(idx)}; count right, % (8 views unless said):")
    print(f"{'run':>40} {'8 views':>8} {'1':>6} {'16':>6} {'32':>6} {'q ' + str(QUANTILE):>6} "
          f"{'= class mode':>13}")  # fmt: skip
    eight, one = [], []
    for run in runs:
        predictor = Predictor.load(run)
        per = {v: count_probabilities(predictor, images, pieces, v) for v in (1, 8, 16, 32)}
        eight.append(per[8])
        one.append(per[1])
        share, said = right(per[8])
        as_mode = 100 * np.mean(said == class_mode)
        others = [right(per[v])[0] for v in (1, 16, 32)] + [right(per[8], "quantile")[0]]
        print(f"{run[-40:]:>40} {share:>8.1f} " + " ".join(f"{v:>6.1f}" for v in others)
              + f" {as_mode:>13.1f}")  # fmt: skip
    if len(runs) > 1:
        print(f"{'all runs averaged':>40} {right(np.mean(eight, 0))[0]:>8.1f} "
              f"{right(np.mean(one, 0))[0]:>6.1f}")  # fmt: skip
    shares = class_mode_shares(data)
    print("a class's most common count (training drawers) is right for: "
          + ", ".join(f"{k} {100 * v:.1f} %" for k, v in shares.items()))  # fmt: skip


def ceilings(data_path: str) -> None:
    data = load_dataset(data_path)
    counts = np.array([len(data.stroke_spans(i)) for i in range(len(data))])
    labels, pieces = np.asarray(data.labels), ink_pieces(data.images)
    mode = class_modes(data, counts)
    train = data.split == 0
    by_pieces: dict[tuple[int, int], int] = {}
    for c, k in {(int(labels[i]), int(pieces[i])) for i in np.flatnonzero(train)}:
        seen = Counter(counts[train & (labels == c) & (pieces == k)].tolist())
        by_pieces[c, k] = min(seen, key=lambda n: (-seen[n], n))
    print(f"{'split':>10} {'n':>5} {'class mode':>11} {'class mode, pieces seen':>24}")
    for s, name in ((1, "validation"), (2, "test")):
        idx = np.flatnonzero((data.split == s) & np.isin(labels, list(mode)))
        plain = [mode[int(labels[i])] for i in idx]
        seen = [max(by_pieces.get((int(labels[i]), int(pieces[i])), mode[int(labels[i])]),
                    int(pieces[i])) for i in idx]  # fmt: skip
        print(
            f"{name:>10} {len(idx):>5} {100 * np.mean(plain == counts[idx]):>10.1f}% "
            f"{100 * np.mean(seen == counts[idx]):>23.1f}%"
        )


#: The ink-written margins :func:`fit` tries.
FIT_MARGINS = (0.0, 0.02, 0.05, 0.1, 0.2)


def fit(data_path: str, run: str, steps: int = 60) -> None:
    from img2dmp.metrics import ink_written_share
    from img2dmp.nn.strokes import character_paths, read_strokes, refine_strokes

    data = load_dataset(data_path)
    idx = np.flatnonzero(data.split == 1)
    truth = np.array([len(data.stroke_spans(int(i))) for i in idx])
    predictor = Predictor.load(run)
    predictor.refine_with(steps)
    images, pieces = data.images[idx], ink_pieces(data.images[idx])
    prob = count_probabilities(predictor, images, pieces, 1)
    x, out = predictor._raw_outputs(images, 4096)
    first, second = np.argsort(-prob, 1, kind="stable")[:, :2].T + 1

    def written(c):
        onehot = np.eye(prob.shape[1])[c - 1][:, None]  # [B, 1, S]
        strokes = read_strokes(out, predictor.strokes, 1, count_probs=onehot)
        strokes = refine_strokes(strokes, x, predictor.normaliser, predictor.strokes,
                                 predictor.refine_options)  # fmt: skip
        paths = character_paths(strokes, predictor.normaliser, predictor.strokes)
        width = predictor.stroke_width or 2.0
        return np.array([ink_written_share(x[b : b + 1], p[None], 0.5 * width + 0.5)[0]
                         for b, p in enumerate(paths)])  # fmt: skip

    w1, w2 = written(first), written(second)
    right = {"the most probable": first == truth, "the second": second == truth,
             "one of the two": (first == truth) | (second == truth)}  # fmt: skip
    print(f"validation drawings: {len(idx)}; count right: "
          + ", ".join(f"{k} {100 * np.mean(v):.1f} %" for k, v in right.items()))  # fmt: skip
    for margin in FIT_MARGINS:
        up = (second > first) & (w2 - w1 > margin)
        said = np.where(up, second, first)
        print(
            f"  the larger count where it writes > {margin:.2f} more of the ink: "
            f"{up.sum():>3} taken, count right {100 * np.mean(said == truth):.1f} %"
        )


#: The leans toward more strokes, quantiles, neighbours and mixes ``rules`` reads.
RULE_BETAS = (-0.3, -0.2, -0.1, 0.0, 0.1, 0.2, 0.3)
RULE_QUANTILES = (0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6)
RULE_NEIGHBOURS = (1, 3, 5, 10, 15)
RULE_MIXES = (0.25, 0.5, 0.75)


def neighbour_votes(
    features: np.ndarray, reference: np.ndarray, ref_counts: np.ndarray, k: int, slots: int
) -> np.ndarray:
    """Count votes ``[B, S]`` (rows sum to 1) of the ``k`` training drawings nearest to
    each image by the cosine similarity of their encoder features (unit rows), each
    weighted by ``exp(20 cos)``; counts beyond ``slots`` vote for ``slots``."""
    sim = features @ reference.T
    near = np.argsort(-sim, 1, kind="stable")[:, :k]
    rows = np.arange(len(features))[:, None]
    votes = np.zeros((len(features), slots))
    np.add.at(votes, (rows, np.clip(ref_counts[near], 1, slots) - 1), np.exp(20 * sim[rows, near]))
    return votes / votes.sum(1, keepdims=True)


def rules(data_path: str, run: str, split: str) -> None:
    from img2dmp.familiar import unit_rows

    data = load_dataset(data_path)
    s = {"validation": 1, "test": 2}[split]
    idx, train = np.flatnonzero(data.split == s), np.flatnonzero(data.split == 0)
    if not len(idx):
        raise SystemExit(f"{data_path} has no {split} split")
    counts = np.array([len(data.stroke_spans(i)) for i in range(len(data))])
    truth, images = counts[idx], data.images[idx]
    predictor = Predictor.load(run)
    prob = count_probabilities(predictor, images, ink_pieces(images), 1)
    allowed, k = prob > 0, np.arange(1, prob.shape[1] + 1)

    def share(said) -> str:
        return f"{100 * np.mean(said == truth):.1f}"

    print(f"{split} drawings: {len(idx)}; count right, % (1 view):")
    print("  most probable:", share(prob.argmax(1) + 1))
    lean = [f"{b:+.1f} {share((np.log(prob + 1e-12) + b * k).argmax(1) + 1)}" for b in RULE_BETAS]
    print("  leaning toward more strokes, beta:", ", ".join(lean))
    cum = np.cumsum(prob / prob.sum(1, keepdims=True), 1)
    print("  the smallest count of cumulative probability q:",
          ", ".join(f"{q} {share((cum >= q).argmax(1) + 1)}" for q in RULE_QUANTILES))  # fmt: skip
    feats = unit_rows(predictor.encoder_features(data.images[np.r_[idx, train]]))
    for n in RULE_NEIGHBOURS:
        near = neighbour_votes(feats[: len(idx)], feats[len(idx) :], counts[train], n,
                               prob.shape[1])  # fmt: skip
        votes = np.where(allowed, near, 0.0)
        mixed = [f"a {a} {share((a * votes + (1 - a) * prob).argmax(1) + 1)}" for a in RULE_MIXES]
        print(
            f"  the {n:>2} nearest training drawings: {share(votes.argmax(1) + 1)}; mixed:",
            ", ".join(mixed),
        )


#: ``ink``: the count's probabilities below which the ink's count is taken.
INK_BELOW = (0.3, 0.4, 0.5, 0.6)


def thinned(mask: np.ndarray) -> np.ndarray:
    """A boolean image's one-pixel skeleton by Zhang and Suen's thinning (1984): pixels
    that are neither ends nor bridges are peeled off, alternately from the south-east and
    the north-west, until none is."""
    m = np.pad(np.asarray(mask, bool).astype(np.uint8), 1)
    changed = True
    while changed:
        changed = False
        for step in (0, 1):
            # the 8 neighbours P2..P9, clockwise from north
            p = [m[:-2, 1:-1], m[:-2, 2:], m[1:-1, 2:], m[2:, 2:], m[2:, 1:-1], m[2:, :-2],
                 m[1:-1, :-2], m[:-2, :-2]]  # fmt: skip
            around = sum(q.astype(int) for q in p)
            rises = sum(((p[i] == 0) & (p[(i + 1) % 8] == 1)).astype(int) for i in range(8))
            n, e, s, w = p[0], p[2], p[4], p[6]
            side = (n * e * s == 0) & (e * s * w == 0) if step == 0 else \
                (n * e * w == 0) & (n * s * w == 0)  # fmt: skip
            peel = (m[1:-1, 1:-1] == 1) & (around >= 2) & (around <= 6) & (rises == 1) & side
            if peel.any():
                m[1:-1, 1:-1][peel] = 0
                changed = True
    return m[1:-1, 1:-1].astype(bool)


def skeleton_ends(images: np.ndarray, level: float = 0.5) -> np.ndarray:
    """Per image ``[B, H, W]`` the ends of its ink's skeleton (:func:`thinned`): skeleton
    pixels with one skeleton neighbour (8-connected)."""
    from scipy.ndimage import convolve

    ring = np.ones((3, 3), int)
    ring[1, 1] = 0
    out = np.zeros(len(images), int)
    for i, im in enumerate(images):
        sk = thinned(np.asarray(im) > level)
        out[i] = int((sk & (convolve(sk.astype(int), ring, mode="constant") == 1)).sum())
    return out


def ink_counts(evaluation: dict, images: np.ndarray) -> dict[str, np.ndarray]:
    """The counts of :func:`ink`'s rules for one evaluation's rows and their images."""
    st = evaluation["strokes"]
    net, prob = np.array(st["predicted_counts"]), np.array(st["count_probabilities"])
    pieces, ends = ink_pieces(images), skeleton_ends(images)
    skeleton = np.maximum(pieces, ends // 2)
    rules = {"the network": net, "pieces of ink": pieces, "skeleton (ends / 2, >= pieces)":
             skeleton}  # fmt: skip
    for q in INK_BELOW:
        rules[f"pieces where p < {q}"] = np.where(prob < q, pieces, net)
    u = evaluation.get("unfamiliar")
    if u and u.get("familiarity") is not None:
        below = np.array(u["familiarity"]) < u["line"]
        rules["pieces where unfamiliar"] = np.where(below, pieces, net)
        rules["skeleton where unfamiliar"] = np.where(below, skeleton, net)
    return rules


def ink(pairs: list[tuple[str, str]]) -> None:
    names, splits, right, sizes = [], [], {}, []
    for ev_path, data_path in pairs:
        evaluation = json.loads(Path(ev_path).read_text())
        data = load_dataset(data_path)
        split = evaluation["split"]
        rows = np.arange(len(data)) if split == "all" else np.flatnonzero(
            data.split == SPLITS[split])  # fmt: skip
        truth = np.array(evaluation["strokes"]["true_counts"])
        mine = np.array([len(data.stroke_spans(int(i))) for i in rows])
        if not np.array_equal(truth, mine):
            raise SystemExit(f"{ev_path}: its rows are not {data_path}'s {split} split")
        names.append(f"{Path(data_path).parent.name}/{split} ({len(rows)})")
        splits.append(split)
        sizes.append(len(rows))
        for rule, said in ink_counts(evaluation, data.images[rows]).items():
            right.setdefault(rule, {})[len(names) - 1] = int(np.sum(said == truth))
    print("count right, %: | rule | " + " | ".join(names) + " |")
    for rule, counts in right.items():  # a familiarity's rules: where it was evaluated
        cells = [f"{100 * counts[i] / n:.1f}" if i in counts else "-" for i, n in enumerate(sizes)]
        print(f"| {rule} | " + " | ".join(cells) + " |")
    chosen, common = [], [r for r in right if len(right[r]) == len(names)]
    for i in range(len(names)):
        others = [j for j in range(len(names)) if j != i and splits[j] == splits[i]]
        if not others:
            chosen.append("-")
            continue
        best = max(common, key=lambda r: sum(right[r][j] for j in others))
        chosen.append(f"{100 * right[best][i] / sizes[i]:.1f} ({best})")
    print("| chosen on the others of its split | " + " | ".join(chosen) + " |")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("drop-drawers")
    p.add_argument("data")
    p.add_argument("out")
    p.add_argument("--drawers", required=True, help="comma-separated, e.g. 14,15")
    p = sub.add_parser("class-head")
    p.add_argument("--data", required=True)
    p.add_argument("--run-dir", required=True)
    p.add_argument("--weight", type=float, required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--epochs", type=int, default=120)
    p = sub.add_parser("recognise")
    p.add_argument("--data", required=True)
    p.add_argument("--encoders", nargs="+", default=list(ENCODERS), choices=list(ENCODERS))
    p.add_argument("--epochs", type=int, default=60)
    p = sub.add_parser("ceilings")
    p.add_argument("--data", required=True)
    p = sub.add_parser("fit")
    p.add_argument("--data", required=True)
    p.add_argument("run")
    p = sub.add_parser("read")
    p.add_argument("--data", required=True)
    p.add_argument("runs", nargs="+")
    p = sub.add_parser("rules")
    p.add_argument("--data", required=True)
    p.add_argument("run")
    p.add_argument("--split", choices=("validation", "test"), default="validation")
    p = sub.add_parser("ink")
    p.add_argument("pairs", nargs="+", metavar="EVALUATION DATA")
    args = parser.parse_args(argv)
    if args.command == "ink" and len(args.pairs) % 2:
        parser.error("ink takes pairs: EVALUATION.json DATA.safetensors ...")
    print(format_record(run_record(__file__, argv)))
    if args.command == "drop-drawers":
        gone = [int(d) for d in args.drawers.split(",")]
        data = drop_drawers(load_dataset(args.data), gone)
        save_dataset(args.out, data)
        print(f"written: {args.out} (rows per split: {np.bincount(data.split, minlength=3)})")
        return 0
    if args.command == "class-head":
        return train_with_class_head(args.data, args.run_dir, args.weight, args.seed, args.epochs)
    if args.command == "recognise":
        import torch

        torch.set_num_threads(1)
        for name in args.encoders:
            t0 = time.perf_counter()
            acc_train, acc_val = recognise(args.data, name, args.epochs)
            print(f"{name:>15}: character recognised, training drawers {100 * acc_train:.1f} %, "
                  f"validation drawers {100 * acc_val:.1f} % ({time.perf_counter() - t0:.0f} s)",
                  flush=True)  # fmt: skip
        return 0
    if args.command == "ceilings":
        ceilings(args.data)
    elif args.command == "fit":
        fit(args.data, args.run)
    elif args.command == "rules":
        rules(args.data, args.run, args.split)
    elif args.command == "ink":
        ink(list(zip(args.pairs[::2], args.pairs[1::2], strict=True)))
    else:
        read(args.data, args.runs)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
