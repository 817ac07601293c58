"""Real handwriting to the project's data-set format (``img2dmp prepare``).

Two sources, both paired with the real MNIST image they were drawn over:

``recorded``
    The human pen paths of the Jožef Stefan Institute (:mod:`.recorded`), one stroke
    each, over MNIST **training** images. Each path is resampled to ``n_times`` instants
    evenly spaced over its own recorded duration (linear interpolation between the real
    time stamps). ``d = 2`` by default; ``d = 3`` adds a pen channel that stays 1, so
    the data can fine-tune a model pre-trained on multi-stroke digits.
``strokes``
    Edwin de Jong's traced stroke sequences (:mod:`.strokes`) for all MNIST digits,
    timed by a :class:`.strokes.SpeedProfile` and sampled at ``n_times`` even instants as
    ``(x, y, pen)`` (``d = 3``). With ``d = 2`` only the single-stroke digits are kept.

Then, for every sample: the image is brought to ``image_size`` (``"scale"``: resized,
the path scaled about pixel centres; ``"pad"``: centred on a larger canvas, the path
shifted), ``augment`` random affine copies of every **training** sample are added with
:func:`img2dmp.data.affine.sample_affine` / ``warp_images`` / ``warp_points`` (the
synthetic pipeline's helper), and a DMP is fitted to every path. Errors
(``fit_error_px``) are on x, y only, in pixels of the stored images.

Split (``split`` field, docs/MNIST.md): :func:`.recorded.split_of_index` of the MNIST
training index, for both sources, so that a digit whose recorded path is in the test
part is in the test part of the traced-stroke data too (pre-training never sees it).
Traced digits of MNIST's own test set (``t10k``) are all test.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .._progress import bar as progress_bar
from ..dmp import DMPConfig, DMPParams, fit_dmp, rollout
from .affine import AffineRanges, sample_affine, warp_images, warp_points
from .mnist import load_mnist
from .recorded import (
    FRAME_OFFSET_PX as RECORDED_OFFSET_PX,
)
from .recorded import (
    SPLIT_FRACTIONS,
    load_recorded,
    resample_path,
    split_of_index,
)
from .store import DigitData
from .strokes import FRAME_OFFSET_PX as STROKES_OFFSET_PX
from .strokes import SpeedProfile, load_strokes, time_strokes

SOURCES = ("recorded", "strokes")
RESIZE_MODES = ("scale", "pad")
MNIST_SIZE = 28
#: Where ``img2dmp prepare`` looks by default (relative to the project root).
DEFAULT_DATA_DIR = Path("..") / "shared" / "data"
_FIT_CHUNK = 2048


@dataclass
class PrepareOptions:
    """Everything that decides the contents of a prepared data set.

    Attributes
    ----------
    source : {"recorded", "strokes"}
    digits : tuple of int
        Labels to keep.
    n_dims : int or None
        2 (x, y) or 3 (x, y, pen); None = 2 for ``recorded``, 3 for ``strokes``.
    n_times : int
        Instants per trajectory (the DMP time grid), evenly spaced over each movement.
    image_size : int
        Side of the stored square images (MNIST is 28).
    resize_mode : {"scale", "pad"}
        How images of another size are made: scaled, or the 28 x 28 image centred on a
        larger canvas (pixel units unchanged).
    augment : int
        Affine copies added per training sample (validation and test are never
        augmented).
    paper : float
        Share in [0, 1] of those copies photographed on generated paper and read back
        through the paper-aware preparation (:mod:`img2dmp.data.on_paper`: ruled,
        squared, dotted or plain paper, tints, shading, blur, noise, JPEG): training on
        cluttered paper, the paper's future work. 0: none.
    affine : AffineRanges
        Ranges of those transforms.
    seed : int
        Seed of the augmentation draws.
    scaling : str or None
        DMP forcing-term scaling; None = ``"goal-start"`` (the paper) for d = 2 and
        ``"none"`` for d = 3, where it is required (the pen starts and ends down, so
        ``g - y0 = 0`` on that channel and the paper's scaling would switch its forcing
        term off).
    n_kernels : int
        Kernels per dimension (N, eq. 7).
    ridge : float
        Relative Tikhonov term of :func:`img2dmp.dmp.fit_dmp`.
    mnist_split : {"train", "test", "both"}
        For ``strokes``: which MNIST split's traces to use (recorded paths exist for
        training images only).
    limit_per_digit : int or None
        Keep at most this many samples per digit (the lowest MNIST indices).
    speed_profile : SpeedProfile
        Timing of the traced strokes.
    duration_s : float or None
        If set, every path's time stamps are rescaled to last exactly this long before
        the DMP is fitted (``t' = duration_s (t - t_0) / (t_end - t_0)``): the shape and
        the relative speed profile stay, the writer's overall speed goes. A picture does
        not show how fast a digit was written, and Table I's error is measured at the
        demonstration's own time stamps, so with real durations that unknown dominates
        the error (see docs/MNIST.md, the ``-tn`` experiments). None keeps real timing.
    """

    source: str = "recorded"
    digits: tuple[int, ...] = tuple(range(10))
    n_dims: int | None = None
    n_times: int = 100
    image_size: int = MNIST_SIZE
    resize_mode: str = "scale"
    augment: int = 0
    paper: float = 0.0
    affine: AffineRanges = field(default_factory=AffineRanges)
    seed: int = 0
    scaling: str | None = None
    n_kernels: int = 25
    ridge: float = 1e-9
    mnist_split: str = "train"
    limit_per_digit: int | None = None
    speed_profile: SpeedProfile = field(default_factory=SpeedProfile)
    duration_s: float | None = None

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"source must be one of {SOURCES}, got {self.source!r}")
        self.digits = tuple(sorted({int(d) for d in self.digits}))
        if not self.digits or min(self.digits) < 0 or max(self.digits) > 9:
            raise ValueError(f"digits must be a non-empty set of 0-9, got {self.digits!r}")
        if self.n_dims is None:
            self.n_dims = 2 if self.source == "recorded" else 3
        if self.n_dims not in (2, 3):
            raise ValueError(f"n_dims must be 2 (x, y) or 3 (x, y, pen), got {self.n_dims!r}")
        if self.scaling is None:
            self.scaling = "goal-start" if self.n_dims == 2 else "none"
        if self.n_dims == 3 and self.scaling != "none":
            raise ValueError(
                "a pen channel (n_dims=3) needs scaling='none': the pen starts and ends down, "
                "so g - y0 = 0 and the paper's goal-start scaling would cancel its forcing term"
            )
        if not isinstance(self.n_times, int) or self.n_times < 2:
            raise ValueError(f"n_times must be an integer >= 2, got {self.n_times!r}")
        if not isinstance(self.image_size, int) or self.image_size < 8:
            raise ValueError(f"image_size must be an integer >= 8, got {self.image_size!r}")
        if self.resize_mode not in RESIZE_MODES:
            raise ValueError(f"resize_mode must be one of {RESIZE_MODES}, got {self.resize_mode!r}")
        if self.resize_mode == "pad" and self.image_size < MNIST_SIZE:
            raise ValueError(f"resize_mode='pad' needs image_size >= {MNIST_SIZE}")
        if not isinstance(self.augment, int) or self.augment < 0:
            raise ValueError(f"augment must be an integer >= 0, got {self.augment!r}")
        if isinstance(self.paper, bool) or not (
            isinstance(self.paper, (int, float)) and 0.0 <= self.paper <= 1.0
        ):
            raise ValueError(f"paper must be a share in [0, 1], got {self.paper!r}")
        if self.paper and not self.augment:
            raise ValueError("paper puts augmented copies on paper: it needs augment >= 1")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.mnist_split not in ("train", "test", "both"):
            raise ValueError(f"mnist_split must be train, test or both, got {self.mnist_split!r}")
        if self.source == "recorded" and self.mnist_split != "train":
            raise ValueError("recorded paths exist for MNIST training images only (mnist_split)")
        if self.limit_per_digit is not None and self.limit_per_digit < 1:
            raise ValueError(f"limit_per_digit must be >= 1, got {self.limit_per_digit!r}")
        if self.duration_s is not None and not (
            isinstance(self.duration_s, (int, float)) and 0 < self.duration_s < float("inf")
        ):
            raise ValueError(f"duration_s must be a number > 0 or None, got {self.duration_s!r}")

    @property
    def dmp_config(self) -> DMPConfig:
        return DMPConfig(n_kernels=self.n_kernels, n_dims=self.n_dims, scaling=self.scaling)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["digits"] = list(self.digits)
        d["affine"] = self.affine.to_dict()
        d["speed_profile"] = self.speed_profile.to_dict()
        return d


# --- geometry -------------------------------------------------------------------------


def image_transform(image_size: int, resize_mode: str) -> tuple[float, float]:
    """``(s, o)`` such that a 28 x 28 MNIST point x maps to ``s * x + o`` in the output.

    ``"scale"`` keeps pixel centres consistent with bilinear resizing
    (``x' = s (x + 0.5) - 0.5``, ``s = image_size / 28``); ``"pad"`` shifts by the border.
    """
    if resize_mode == "pad":
        return 1.0, float((image_size - MNIST_SIZE) // 2)
    s = image_size / MNIST_SIZE
    return s, 0.5 * s - 0.5


def resize_images(images: np.ndarray, image_size: int, resize_mode: str) -> np.ndarray:
    """MNIST images ``[M, 28, 28]`` to ``[M, S, S]`` with S = ``image_size``."""
    if images.shape[-1] == image_size and images.shape[-2] == image_size:
        return images.astype(np.float32)
    if resize_mode == "pad":
        lo = (image_size - MNIST_SIZE) // 2
        out = np.zeros((len(images), image_size, image_size), np.float32)
        out[:, lo : lo + MNIST_SIZE, lo : lo + MNIST_SIZE] = images
        return out
    x = torch.as_tensor(images, dtype=torch.float32)[:, None]  # [M, 1, 28, 28]
    y = F.interpolate(
        x,
        size=(image_size, image_size),
        mode="bilinear",
        align_corners=False,
        antialias=image_size < MNIST_SIZE,
    )
    return y[:, 0].clamp(0.0, 1.0).numpy()


# --- fitting --------------------------------------------------------------------------


@dataclass
class FitSummary:
    """DMP fits of a batch of paths, with errors measured the contract's way.

    Attributes
    ----------
    params : float32 [M, P]
        Flat parameter vectors.
    error_px : float32 [M]
        Mean Euclidean distance on x, y only between path and rollout.
    max_error_px : float32 [M]
    pen_agreement : float32 [M] or None
        For d = 3: share of instants where the rollout's pen (> 0.5) equals the path's.
    """

    params: np.ndarray
    error_px: np.ndarray
    max_error_px: np.ndarray
    pen_agreement: np.ndarray | None


def fit_paths(
    times: np.ndarray,
    paths: np.ndarray,
    config: DMPConfig,
    *,
    ridge: float = 1e-9,
    progress: bool = False,
) -> FitSummary:
    """Fit DMPs to paths ``[M, T, d]`` at times ``[M, T]`` and measure the fits.

    The fit is :func:`img2dmp.dmp.fit_dmp` (least squares in trajectory space, every
    channel, the pen one included, as one DMP dimension); the errors come from a
    :func:`img2dmp.dmp.rollout` of the fitted parameters, on x, y only.
    """
    m = len(paths)
    parts = []
    bar = progress_bar(total=m, desc="fit DMPs", unit="path", enabled=progress)
    for lo in range(0, m, _FIT_CHUNK):
        t = np.asarray(times[lo : lo + _FIT_CHUNK], dtype=np.float64)  # [B, T]
        y = np.asarray(paths[lo : lo + _FIT_CHUNK], dtype=np.float64)  # [B, T, d]
        fit = fit_dmp(t, y, config, ridge=ridge)
        p = fit.params.to_torch()
        roll = rollout(p, torch.as_tensor(t), config).numpy()  # [B, T, d]
        dist = np.linalg.norm(roll[..., :2] - y[..., :2], axis=-1)  # [B, T]
        pen = None
        if y.shape[-1] >= 3:
            pen = ((roll[..., 2] > 0.5) == (y[..., 2] > 0.5)).mean(-1)
        parts.append((fit.params.to_vector(), dist.mean(-1), dist.max(-1), pen))
        bar.update(len(y))
    bar.close()
    vec, err, emax, pen = zip(*parts, strict=True)
    return FitSummary(
        params=np.concatenate(vec).astype(np.float32),
        error_px=np.concatenate(err).astype(np.float32),
        max_error_px=np.concatenate(emax).astype(np.float32),
        pen_agreement=None if pen[0] is None else np.concatenate(pen).astype(np.float32),
    )


def pen_rollout(params: DMPParams, t, config: DMPConfig) -> tuple[np.ndarray, np.ndarray]:
    """Roll a d = 3 DMP out and split it into positions ``[*, T, 2]`` and pen-down ``[*, T]``.

    The pen is down where the third channel exceeds 0.5 (docs/CONTRACTS.md).
    """
    y = rollout(params.to_torch(), torch.as_tensor(np.asarray(t, dtype=np.float64)), config)
    y = y.numpy()
    return y[..., :2], y[..., 2] > 0.5


# --- sources --------------------------------------------------------------------------


@dataclass
class _Raw:
    images: np.ndarray  # [M, 28, 28] float32
    paths: np.ndarray  # [M, T, d] float64, 28 x 28 frame
    times: np.ndarray  # [M, T] float64
    labels: np.ndarray  # [M] int64
    split: np.ndarray  # [M] uint8
    mnist_split: list[str]
    mnist_index: np.ndarray  # [M] int64
    source: dict


def _limit(labels: np.ndarray, limit: int | None) -> np.ndarray:
    """Row mask keeping the first ``limit`` rows of each label."""
    if limit is None:
        return np.ones(len(labels), bool)
    keep = np.zeros(len(labels), bool)
    for d in np.unique(labels):
        keep[np.flatnonzero(labels == d)[:limit]] = True
    return keep


def _recorded_raw(recorded: Path, mnist_dir: Path, opt: PrepareOptions, progress: bool) -> _Raw:
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
    recs = [r for r, k in zip(recs, _limit(rec_labels, opt.limit_per_digit), strict=True) if k]
    grids = [resample_path(r.xy, r.t_s, opt.n_times) for r in recs]
    times = np.stack([g[0] for g in grids])  # [M, T]
    paths = np.stack([g[1] for g in grids])  # [M, T, 2]
    if opt.n_dims == 3:
        paths = np.concatenate([paths, np.ones_like(paths[..., :1])], axis=-1)  # pen down
    idx = np.array([r.image_index for r in recs], np.int64)
    repaired = [r.name for r in recs if r.time_repairs]
    return _Raw(
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
            "frame_offset_px": RECORDED_OFFSET_PX,
            "time_repaired_files": repaired,
            "durations_s": [float(np.min(times[:, -1])), float(np.max(times[:, -1]))],
        },
    )


def _strokes_raw(strokes_dir: Path, mnist_dir: Path, opt: PrepareOptions, progress: bool) -> _Raw:
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
        digits = [s for s, k in zip(digits, _limit(lab, opt.limit_per_digit), strict=True) if k]
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
    return _Raw(
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
            "frame_offset_px": STROKES_OFFSET_PX,
            "mnist_split": opt.mnist_split,
            "speed_profile": opt.speed_profile.to_dict(),
            "digits_by_stroke_count": {str(k): int(v) for k, v in enumerate(n_strokes) if v},
            "multi_stroke_digits_dropped": dropped_multi,
        },
    )


# --- the whole pipeline ---------------------------------------------------------------


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
    raw = _read_source(options, Path(data_dir), mnist_dir, recorded_path, strokes_dir, progress)
    s, o = image_transform(options.image_size, options.resize_mode)
    images = resize_images(raw.images, options.image_size, options.resize_mode)  # [M, S, S]
    paths = raw.paths.copy()  # [M, T, d]
    paths[..., :2] = s * paths[..., :2] + o
    images, paths, rows, copy = _augment(images, paths, raw.split, options, progress)
    times = raw.times[rows]  # [M', T]
    if options.duration_s is not None:
        times = options.duration_s * (times - times[:, :1]) / (times[:, -1:] - times[:, :1])
    fit = fit_paths(times, paths, options.dmp_config, ridge=options.ridge, progress=progress)
    split = raw.split[rows]
    labels = raw.labels[rows]
    meta = _dataset_meta(options, raw, rows, copy, split, (s, o), _fit_statistics(fit, labels))
    return DigitData(
        images=np.ascontiguousarray(images, dtype=np.float32),
        trajectories=paths.astype(np.float32),
        times=times.astype(np.float32),
        labels=labels.astype(np.int64),
        params=fit.params,
        fit_error_px=fit.error_px,
        split=split.astype(np.uint8),
        meta=meta,
    )


def _read_source(
    options: PrepareOptions, data_dir: Path, mnist_dir, recorded_path, strokes_dir, progress
) -> _Raw:
    """Images and pen paths of ``options.source``, from the given or default locations."""
    mnist_dir = Path(mnist_dir) if mnist_dir else data_dir / "mnist"
    if options.source == "recorded":
        path = (
            Path(recorded_path)
            if recorded_path
            else data_dir / "ijs-mnist-trajectories" / "trajectories.tar.gz"
        )
        return _recorded_raw(path, mnist_dir, options, progress)
    path = Path(strokes_dir) if strokes_dir else data_dir / "mnist-stroke-sequences"
    return _strokes_raw(path, mnist_dir, options, progress)


def _augment(images, paths, raw_split, options: PrepareOptions, progress: bool):
    """``options.augment`` random affine copies of every training sample appended.

    Returns images ``[M', S, S]``, paths ``[M', T, d]``, the source row of every sample
    ``[M']`` and its copy number ``[M']`` (0 = the original).
    """
    copy = np.zeros(len(paths), np.int64)
    rows = np.arange(len(paths))
    if not options.augment:
        return images, paths, rows, copy
    train = np.flatnonzero(raw_split == 0)
    rng = np.random.default_rng(options.seed)
    src = np.repeat(train, options.augment)  # [A]
    mats = sample_affine(rng, len(src), options.image_size, options.affine)  # [A, 2, 3]
    aug_images = np.empty((len(src), options.image_size, options.image_size), np.float32)
    chunk = 4096  # bounds the memory of the warp
    chunks = range(0, len(src), chunk)
    for lo in progress_bar(chunks, desc="augment", unit="chunk", enabled=progress):
        sl = slice(lo, lo + chunk)
        aug_images[sl] = warp_images(images[src[sl]], mats[sl]).clamp(0.0, 1.0).numpy()
    aug_paths = warp_points(paths[src], mats)
    if options.paper:
        aug_images, aug_paths = _on_paper(rng, images[train], aug_images, aug_paths, options,
                                          progress)  # fmt: skip
    return (
        np.concatenate([images, aug_images]),
        np.concatenate([paths, aug_paths]),
        np.concatenate([rows, src]),
        np.concatenate([copy, np.tile(np.arange(1, options.augment + 1), len(train))]),
    )


def _on_paper(rng, originals, images, paths, options: PrepareOptions, progress: bool):
    """A share ``options.paper`` of the copies ``images [A, S, S]``, ``paths [A, T, d]``
    photographed on generated paper and read back (:func:`img2dmp.data.on_paper.paper_copies`),
    framed and as wide a pen as the original training images (``originals``) are."""
    from .images import ink_margin, typical_stroke_width
    from .on_paper import paper_copies

    pick = np.flatnonzero(rng.random(len(images)) < options.paper)
    if pick.size == 0:
        return images, paths
    margin, width = ink_margin(originals[:500]), typical_stroke_width(originals[:500])
    got = paper_copies(rng, images[pick], paths[pick], margin=margin,
                       stroke_width_px=width or None, workers=os.cpu_count() or 1,
                       progress=progress)  # fmt: skip
    if progress:
        import sys

        print(f"on paper: {pick.size - got.failed} of {pick.size} copies photographed on "
              f"paper; {got.failed} stay plain affine copies (the clutter won)",
              file=sys.stderr)  # fmt: skip
    images, paths = images.copy(), np.array(paths, copy=True)
    images[pick], paths[pick] = got.images, got.paths.astype(paths.dtype)
    return images, paths


def _fit_statistics(fit, labels: np.ndarray) -> dict:
    """The ``fit`` record of the data set's meta: fit errors (px), overall and by digit."""
    stats = {
        "mean_error_px": float(fit.error_px.mean()),
        "max_error_px": float(fit.max_error_px.max()),
        "mean_error_px_by_digit": {
            str(d): float(fit.error_px[labels == d].mean()) for d in np.unique(labels)
        },
    }
    if fit.pen_agreement is not None:
        stats["pen_agreement_mean"] = float(fit.pen_agreement.mean())
        stats["pen_agreement_min"] = float(fit.pen_agreement.min())
    return stats


def _dataset_meta(options: PrepareOptions, raw: _Raw, rows, copy, split, transform, fit_stats):
    """The data set's ``meta`` record (see :func:`prepare_dataset`)."""
    s, o = transform
    return {
        "dmp_config": options.dmp_config.to_dict(),
        "seed": options.seed,
        "source": raw.source,
        "prepare": options.to_dict(),
        "split_rule": {
            "kind": "sha256 of MNIST training index",
            "function": "img2dmp.data.recorded.split_of_index",
            "fractions": list(SPLIT_FRACTIONS),
            "t10k": "test",
        },
        "counts_by_split": {
            name: int((split == code).sum())
            for code, name in enumerate(("train", "validation", "test"))
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
        "fit": fit_stats,
    }


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

    from .recorded import share_on_ink

    data_dir = Path(data_dir)
    mnist_dir = Path(mnist_dir) if mnist_dir else data_dir / "mnist"
    recorded_path = (
        Path(recorded_path)
        if recorded_path
        else data_dir / "ijs-mnist-trajectories" / "trajectories.tar.gz"
    )
    strokes_dir = Path(strokes_dir) if strokes_dir else data_dir / "mnist-stroke-sequences"
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
