"""Edwin de Jong's traced stroke sequences of all MNIST digits (:mod:`img2dmp.data.strokes`)
as MNIST samples.

Timed by a :class:`~img2dmp.data.strokes.SpeedProfile` and sampled at ``n_times`` even
instants as ``(x, y, pen)`` (``d = 3``). With ``d = 2`` only the single-stroke digits are
kept.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..._progress import bar as progress_bar
from ..mnist import load_mnist
from ..recorded import split_of_index
from ..strokes import FRAME_OFFSET_PX, load_strokes, time_strokes
from .mnist import MnistSamples, PrepareOptions, limit_per_label


def read_traced(
    strokes_dir: Path, mnist_dir: Path, opt: PrepareOptions, progress: bool
) -> MnistSamples:
    """The traced digits of ``opt.digits`` in ``opt.mnist_split`` (at most
    ``opt.limit_per_digit`` each) with their MNIST images, timed by ``opt.speed_profile``."""
    splits = ["train", "test"] if opt.mnist_split == "both" else [opt.mnist_split]
    parts = []
    dropped_multi = 0
    for ms in splits:
        images, labels = load_mnist(mnist_dir, ms)
        digits = load_strokes(strokes_dir, ms, digits=opt.digits, progress=progress)
        if len(digits) and digits[-1].index >= len(images):
            raise ValueError(f"{digits[-1].name}: row beyond MNIST {ms}'s {len(images)} images")
        for s in digits:
            if s.label != labels[s.index]:
                raise ValueError(
                    f"{s.name}: label {s.label} but MNIST {ms} image {s.index} is a "
                    f"{labels[s.index]}"
                )
        if opt.n_dims == 2:
            n0 = len(digits)
            digits = [s for s in digits if s.n_strokes == 1]
            dropped_multi += n0 - len(digits)
        lab = np.array([s.label for s in digits], np.int64)
        digits = [
            s for s, k in zip(digits, limit_per_label(lab, opt.limit_per_digit), strict=True) if k
        ]
        parts.append((ms, images, digits))
    times, paths, imgs, labs, idxs, msplit, split = [], [], [], [], [], [], []
    n_strokes = np.zeros(10, np.int64)
    for ms, images, digits in parts:
        for s in progress_bar(digits, desc=f"time strokes ({ms})", unit="digit", enabled=progress):
            t, xyp = time_strokes(s.strokes, opt.n_times, opt.speed_profile)
            times.append(t)
            paths.append(xyp[:, : opt.n_dims])
            n_strokes[min(s.n_strokes, 9)] += 1
        idx = np.array([s.index for s in digits], np.int64)
        imgs.append(images[idx])
        labs.append(np.array([s.label for s in digits], np.int64))
        idxs.append(idx)
        msplit += [ms] * len(idx)
        split.append(split_of_index(idx) if ms == "train" else np.full(len(idx), 2, np.uint8))
    if not times:
        raise ValueError(f"{strokes_dir}: no traced digits of {list(opt.digits)}")
    return MnistSamples(
        images=np.concatenate(imgs),
        paths=np.stack(paths),
        times=np.stack(times),
        labels=np.concatenate(labs),
        split=np.concatenate(split),
        mnist_split=msplit,
        mnist_index=np.concatenate(idxs),
        source={
            "kind": "mnist-strokes",
            "strokes": str(strokes_dir),
            "mnist": str(mnist_dir),
            "frame_offset_px": FRAME_OFFSET_PX,
            "mnist_split": opt.mnist_split,
            "speed_profile": opt.speed_profile.to_dict(),
            "digits_by_stroke_count": {str(k): int(v) for k, v in enumerate(n_strokes) if v},
            "multi_stroke_digits_dropped": dropped_multi,
        },
    )
