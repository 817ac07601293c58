"""Real handwriting to the project's data-set format (``img2dmp prepare``).

MNIST's images with their recorded pen paths (``source="recorded"``,
:mod:`img2dmp.data.sources.mnist_recorded`) or traced stroke sequences (``"strokes"``,
:mod:`img2dmp.data.sources.mnist_traced`), read by those readers and built by the one
build step (:mod:`img2dmp.data.build`): the image brought to ``image_size``
(``"scale"``: resized, the path scaled about pixel centres; ``"pad"``: centred on a
larger canvas, the path shifted), ``augment`` random affine copies of every **training**
sample added (a share ``paper`` of them on generated paper), and a DMP fitted to every
path. Errors (``fit_error_px``) are on x, y only, in pixels of the stored images.

Split (``split`` field, docs/MNIST.md): :func:`img2dmp.data.recorded.split_of_index` of
the MNIST training index, for both sources; traced digits of MNIST's own test set
(``t10k``) are all test (:mod:`img2dmp.data.sources.mnist`).
"""

from __future__ import annotations

import os

import numpy as np

from .build import (
    MNIST_SIZE,
    RESIZE_MODES,
    FitSummary,
    Framed,
    build_dataset,
    fit_paths,
    fit_statistics,
    frame_fixed,
    image_transform,
    pen_rollout,
    resize_images,
)
from .recorded import SPLIT_FRACTIONS
from .sources.mnist import (
    DEFAULT_DATA_DIR,
    SOURCES,
    MnistSamples,
    PrepareOptions,
    frame_alignment,
    locations,
)
from .store import DIGIT_NAMES, DigitData

__all__ = [
    "DEFAULT_DATA_DIR",
    "MNIST_SIZE",
    "RESIZE_MODES",
    "SOURCES",
    "FitSummary",
    "PrepareOptions",
    "fit_paths",
    "frame_alignment",
    "image_transform",
    "pen_rollout",
    "prepare_dataset",
    "resize_images",
]


def prepare_dataset(
    options: PrepareOptions,
    *,
    data_dir: str | os.PathLike = DEFAULT_DATA_DIR,
    mnist_dir: str | os.PathLike | None = None,
    recorded_path: str | os.PathLike | None = None,
    strokes_dir: str | os.PathLike | None = None,
    progress: bool = True,
) -> DigitData:
    """Build a data set of real MNIST images with recorded or traced pen paths.

    Parameters
    ----------
    options : PrepareOptions
    data_dir : path-like
        Root of the real data (default ``../shared/data``); the other paths default to
        ``data_dir/mnist``, ``data_dir/ijs-mnist-trajectories/trajectories.tar.gz`` and
        ``data_dir/mnist-stroke-sequences``.
    mnist_dir, recorded_path, strokes_dir : path-like, optional
        Override one location.
    progress : bool
        progress bars (one line each when not on a terminal).

    Returns
    -------
    DigitData
        Not yet written; see :func:`img2dmp.data.store.save_dataset`. Its ``meta``
        holds the options, the files read, the split rule, the image transform
        (``pixel_scale``, ``pixel_offset``: a 28 x 28 point x is at ``s x + o``), per-row
        MNIST split / index / augmentation copy, and fit statistics.
    """
    raw = _read_source(options, data_dir, mnist_dir, recorded_path, strokes_dir, progress)
    images, paths, times, transform = frame_fixed(
        raw.images, raw.paths, raw.times, options, options.resize_mode
    )
    framed = Framed(images, paths, times, raw.labels, raw.split)

    def source_meta(rows, copy, fit):
        return _meta(options, raw, rows, copy, transform, fit)

    return build_dataset(
        framed,
        options,
        options.dmp_config(),
        rng=np.random.default_rng(options.seed),
        source_meta=source_meta,
        paper=options.paper,
        progress=progress,
    )


def _read_source(
    options: PrepareOptions, data_dir, mnist_dir, recorded_path, strokes_dir, progress
) -> MnistSamples:
    """Images and pen paths of ``options.source``, from the given or default locations."""
    from .sources.mnist_recorded import read_recorded
    from .sources.mnist_traced import read_traced

    mnist_dir, recorded_path, strokes_dir = locations(
        data_dir, mnist_dir, recorded_path, strokes_dir
    )
    if options.source == "recorded":
        return read_recorded(recorded_path, mnist_dir, options, progress)
    return read_traced(strokes_dir, mnist_dir, options, progress)


def _meta(options: PrepareOptions, raw: MnistSamples, rows, copy, transform, fit) -> dict:
    """The source's part of the data set's ``meta`` (see :func:`prepare_dataset`)."""
    s, o = transform
    return {
        "source": raw.source,
        "prepare": options.to_dict(),
        "split_rule": {
            "kind": "sha256 of MNIST training index",
            "function": "img2dmp.data.recorded.split_of_index",
            "fractions": list(SPLIT_FRACTIONS),
            "t10k": "test",
        },
        "pixel_scale": s,
        "pixel_offset": o,
        "units": "pixels of the stored images; divide errors by pixel_scale for MNIST pixels",
        "rows": {
            "mnist_split": (
                raw.mnist_split[0]
                if len(set(raw.mnist_split)) == 1
                else [raw.mnist_split[r] for r in rows]
            ),
            "mnist_index": raw.mnist_index[rows].tolist(),
            "augment_copy": copy.tolist(),
        },
        "fit": fit_statistics(fit, raw.labels[rows], DIGIT_NAMES, "digit"),
    }
