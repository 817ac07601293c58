"""The recorded human pen paths of the Jožef Stefan Institute over MNIST training images
(:mod:`img2dmp.data.recorded`), one stroke each, as MNIST samples.

Each path is resampled to ``n_times`` instants evenly spaced over its own recorded
duration (linear interpolation between the real time stamps). ``d = 2`` by default;
``d = 3`` adds a pen channel that stays 1, so the data can fine-tune a model pre-trained
on multi-stroke digits.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..mnist import load_mnist
from ..recorded import (
    FRAME_OFFSET_PX,
    check_recorded_path,
    load_recorded,
    resample_path,
    split_of_index,
)
from .mnist import MnistSamples, PrepareOptions, limit_per_label


def read_recorded(
    recorded: Path, mnist_dir: Path, opt: PrepareOptions, progress: bool
) -> MnistSamples:
    """The recorded paths of ``opt.digits`` (at most ``opt.limit_per_digit`` each) with
    their MNIST training images, resampled to ``opt.n_times`` even instants."""
    check_recorded_path(recorded)  # before MNIST is read
    images, labels = load_mnist(mnist_dir, "train")
    recs = load_recorded(recorded, digits=opt.digits, progress=progress)
    if not recs:
        raise ValueError(f"{recorded}: no recorded paths of the digits {list(opt.digits)}")
    for r in recs:
        if r.image_index >= len(images):
            raise ValueError(f"{r.name}: image {r.image_index} is beyond MNIST's {len(images)}")
        if r.label != labels[r.image_index]:
            raise ValueError(
                f"{r.name}: label {r.label} but MNIST training image {r.image_index} is a "
                f"{labels[r.image_index]}"
            )
    rec_labels = np.array([r.label for r in recs], np.int64)
    recs = [
        r for r, k in zip(recs, limit_per_label(rec_labels, opt.limit_per_digit), strict=True) if k
    ]
    grids = [resample_path(r.xy, r.t_s, opt.n_times) for r in recs]
    times = np.stack([g[0] for g in grids])  # [M, T]
    paths = np.stack([g[1] for g in grids])  # [M, T, 2]
    if opt.n_dims == 3:
        paths = np.concatenate([paths, np.ones_like(paths[..., :1])], axis=-1)  # pen down
    idx = np.array([r.image_index for r in recs], np.int64)
    repaired = [r.name for r in recs if r.time_repairs]
    return MnistSamples(
        images=images[idx],
        paths=paths,
        times=times,
        labels=np.array([r.label for r in recs], np.int64),
        split=split_of_index(idx),
        mnist_split=["train"] * len(idx),
        mnist_index=idx,
        source={
            "kind": "mnist-recorded",
            "recorded": str(recorded),
            "mnist": str(mnist_dir),
            "frame_offset_px": FRAME_OFFSET_PX,
            "time_repaired_files": repaired,
            "durations_s": [float(np.min(times[:, -1])), float(np.max(times[:, -1]))],
        },
    )
