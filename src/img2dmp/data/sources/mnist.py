"""MNIST's images with their pen paths, as ``img2dmp prepare`` reads them.

Two readers, both pairing a pen path with the real MNIST image it was drawn over:
:mod:`.mnist_recorded` (the human pen paths of the Jožef Stefan Institute, one stroke
each, over MNIST **training** images) and :mod:`.mnist_traced` (Edwin de Jong's traced
stroke sequences of all MNIST digits). Each gives a :class:`MnistSamples` batch in
MNIST's 28 x 28 frame, on the data set's time grid, with its split:
:func:`img2dmp.data.recorded.split_of_index` of the MNIST training index for both, so
that a digit whose recorded path is in the test part is in the test part of the
traced-stroke data too; traced digits of MNIST's own test set (``t10k``) are all test.

:class:`PrepareOptions` holds the shared build fields and these sources' own;
:func:`frame_alignment` measures how well each source's raw frame lies on the ink.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import show
from ..build import MNIST_SIZE, RESIZE_MODES, BuildOptions
from ..mnist import load_mnist
from ..recorded import FRAME_OFFSET_PX as RECORDED_OFFSET_PX
from ..recorded import load_recorded
from ..strokes import FRAME_OFFSET_PX as STROKES_OFFSET_PX
from ..strokes import SpeedProfile, load_strokes

SOURCES = ("recorded", "strokes")
#: Where ``img2dmp prepare`` looks by default (relative to the project root).
DEFAULT_DATA_DIR = Path("..") / "shared" / "data"


@dataclass
class PrepareOptions(BuildOptions):
    """Everything that decides the contents of a prepared data set: the shared
    :class:`~img2dmp.data.build.BuildOptions` (``image_size``, MNIST's 28 by default;
    ``n_times``, evenly spaced over each movement; ``n_dims``, None = 2 for ``recorded``
    and 3 for ``strokes``; ``scaling``, ``n_kernels``, ``ridge``, ``augment``, ``affine``,
    ``seed``, ``duration_s``) and these.

    Attributes
    ----------
    source : {"recorded", "strokes"}
    digits : tuple of int
        Labels to keep.
    resize_mode : {"scale", "pad"}
        How images of another size are made: scaled, or the 28 x 28 image centred on a
        larger canvas (pixel units unchanged).
    paper : float
        Share in [0, 1] of the affine copies photographed on generated paper and read back
        through the paper-aware preparation (:mod:`img2dmp.data.on_paper`: ruled,
        squared, dotted or plain paper, tints, shading, blur, noise, JPEG): training on
        cluttered paper, the paper's future work. 0: none.
    mnist_split : {"train", "test", "both"}
        For ``strokes``: which MNIST split's traces to use (recorded paths exist for
        training images only).
    limit_per_digit : int or None
        Keep at most this many samples per digit (the lowest MNIST indices).
    speed_profile : SpeedProfile
        Timing of the traced strokes.

    ``duration_s``: a picture does not show how fast a digit was written, and Table I's
    error is measured at the demonstration's own time stamps, so with real durations that
    unknown dominates the error (see docs/MNIST.md, the ``-tn`` experiments).
    """

    source: str = "recorded"
    digits: tuple[int, ...] = tuple(range(10))
    image_size: int = MNIST_SIZE
    resize_mode: str = "scale"
    paper: float = 0.0
    mnist_split: str = "train"
    limit_per_digit: int | None = None
    speed_profile: SpeedProfile = field(default_factory=SpeedProfile)

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"source must be one of {SOURCES}, got {show(self.source)}")
        self.digits = tuple(sorted({int(d) for d in self.digits}))
        if not self.digits or min(self.digits) < 0 or max(self.digits) > 9:
            raise ValueError(f"digits must be a non-empty set of 0-9, got {self.digits!r}")
        if self.n_dims is None:
            self.n_dims = 2 if self.source == "recorded" else 3
        if self.n_dims in (2, 3) and self.scaling is None:
            self.scaling = "goal-start" if self.n_dims == 2 else "none"
        super().__post_init__()
        if self.resize_mode not in RESIZE_MODES:
            raise ValueError(
                f"resize_mode must be one of {RESIZE_MODES}, got {show(self.resize_mode)}"
            )
        if self.resize_mode == "pad" and self.image_size < MNIST_SIZE:
            raise ValueError(f"resize_mode='pad' needs image_size >= {MNIST_SIZE}")
        if isinstance(self.paper, bool) or not (
            isinstance(self.paper, (int, float)) and 0.0 <= self.paper <= 1.0
        ):
            raise ValueError(f"paper must be a share in [0, 1], got {show(self.paper)}")
        if self.paper and not self.augment:
            raise ValueError("paper puts augmented copies on paper: it needs augment >= 1")
        if self.mnist_split not in ("train", "test", "both"):
            raise ValueError(
                f"mnist_split must be train, test or both, got {show(self.mnist_split)}"
            )
        if self.source == "recorded" and self.mnist_split != "train":
            raise ValueError("recorded paths exist for MNIST training images only (mnist_split)")
        if self.limit_per_digit is not None and self.limit_per_digit < 1:
            raise ValueError(f"limit_per_digit must be >= 1, got {show(self.limit_per_digit)}")

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["digits"] = list(self.digits)
        d["speed_profile"] = self.speed_profile.to_dict()
        return d


@dataclass
class MnistSamples:
    """MNIST samples as a reader yields them: 28 x 28 images with their paths on the data
    set's time grid, in MNIST's pixels.

    Attributes
    ----------
    images : float32 [M, 28, 28]
    paths : float64 [M, T, d]
    times : float64 [M, T]
        Seconds since the first instant.
    labels : int64 [M]
    split : uint8 [M]
    mnist_split : list of str
        ``"train"`` or ``"test"``: the MNIST file of every row.
    mnist_index : int64 [M]
        The row's image in that file.
    source : dict
        What was read (the data set's ``meta["source"]``).
    """

    images: np.ndarray
    paths: np.ndarray
    times: np.ndarray
    labels: np.ndarray
    split: np.ndarray
    mnist_split: list[str]
    mnist_index: np.ndarray
    source: dict


def limit_per_label(labels: np.ndarray, limit: int | None) -> np.ndarray:
    """Row mask keeping the first ``limit`` rows of each label."""
    if limit is None:
        return np.ones(len(labels), bool)
    keep = np.zeros(len(labels), bool)
    for d in np.unique(labels):
        keep[np.flatnonzero(labels == d)[:limit]] = True
    return keep


def locations(data_dir, mnist_dir=None, recorded_path=None, strokes_dir=None):
    """``(mnist_dir, recorded_path, strokes_dir)``: the ones given, else their places under
    ``data_dir`` (``mnist``, ``ijs-mnist-trajectories/trajectories.tar.gz``,
    ``mnist-stroke-sequences``)."""
    data_dir = Path(data_dir)
    if data_dir.exists() and not data_dir.is_dir():
        raise NotADirectoryError(
            f"{data_dir}: --data (data_dir) must be the root folder of the real data, holding "
            "mnist/, ijs-mnist-trajectories/ and mnist-stroke-sequences/ (like ../shared/data), "
            "not a file"
        )
    return (
        Path(mnist_dir) if mnist_dir else data_dir / "mnist",
        (
            Path(recorded_path)
            if recorded_path
            else data_dir / "ijs-mnist-trajectories" / "trajectories.tar.gz"
        ),
        Path(strokes_dir) if strokes_dir else data_dir / "mnist-stroke-sequences",
    )


# --- frame check ------------------------------------------------------------------------


def frame_alignment(
    data_dir: str | os.PathLike = DEFAULT_DATA_DIR,
    *,
    mnist_dir: str | os.PathLike | None = None,
    recorded_path: str | os.PathLike | None = None,
    strokes_dir: str | os.PathLike | None = None,
    stroke_step: int = 20,
    shifts: tuple[float, ...] = (-1.5, -1.0, -0.5, 0.0, 0.5),
    progress: bool = False,
) -> dict:
    """Share of path points on ink for each source under trial shifts of its raw frame.

    For every source, the raw coordinates (as in the files) are shifted by ``(dx, dy)``
    for all pairs of ``shifts`` (and also transposed, x <-> y) and the mean over digits of
    :func:`.recorded.share_on_ink` is reported. The loaders' ``FRAME_OFFSET_PX`` is the
    best shift found this way (docs/MNIST.md).

    Returns
    -------
    dict
        ``{source: {"n_digits", "chosen_offset_px", "share_chosen", "share_raw",
        "share_transposed", "best_shift", "best_share", "grid": {"dx,dy": share}}}``.
    """
    import warnings

    from ..recorded import share_on_ink

    mnist_dir, recorded_path, strokes_dir = locations(
        data_dir, mnist_dir, recorded_path, strokes_dir
    )
    report = {}
    sets = []
    if recorded_path.exists():
        images, _ = load_mnist(mnist_dir, "train")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            recs = load_recorded(recorded_path, progress=progress)
        raw = [(images[r.image_index], r.xy - RECORDED_OFFSET_PX) for r in recs]
        sets.append(("recorded", RECORDED_OFFSET_PX, raw))
    if strokes_dir.exists():
        for ms in ("train", "test"):
            images, _ = load_mnist(mnist_dir, ms)
            n = len(images)
            digits = load_strokes(strokes_dir, ms, indices=range(0, n, stroke_step))
            raw = [(images[s.index], s.points() - STROKES_OFFSET_PX) for s in digits]
            sets.append((f"strokes-{ms}", STROKES_OFFSET_PX, raw))
    for name, chosen, raw in sets:

        def share(shift_xy, pairs=raw, transpose=False):
            return float(
                np.mean(
                    [
                        share_on_ink(im, (p[:, ::-1] if transpose else p) + shift_xy)
                        for im, p in pairs
                    ]
                )
            )

        grid = {f"{dx:+.1f},{dy:+.1f}": share(np.array([dx, dy])) for dx in shifts for dy in shifts}
        best = max(grid, key=grid.get)
        report[name] = {
            "n_digits": len(raw),
            "chosen_offset_px": chosen,
            "share_chosen": share(np.array([chosen, chosen])),
            "share_raw": share(np.zeros(2)),
            "share_transposed": share(np.array([chosen, chosen]), transpose=True),
            "best_shift": best,
            "best_share": grid[best],
            "grid": grid,
        }
    if not report:
        raise FileNotFoundError(f"no recorded paths or stroke sequences under {data_dir}")
    return report
