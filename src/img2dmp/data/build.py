"""The one build step: samples from a reader to a data set.

Every source (:mod:`img2dmp.data.sources`: MNIST with recorded or traced pen paths,
folders and manifests, web recordings, Omniglot) only reads; what becomes of its samples
happens here, in this order:

1. **frame**: the image brought to the stored size and the path moved along, either as a
   model's input is prepared (:func:`frame_pen_path`: crop to the ink, margin, pen width,
   resize; :func:`img2dmp.data.images.prepare_image_framed`) or, for MNIST's fixed 28 x 28
   frame, scaled or padded (:func:`frame_fixed`);
2. **resample**: the path at ``n_times`` instants (:mod:`img2dmp.data.resample` for a pen
   path with times; the MNIST readers time their own paths), optionally rescaled to
   ``duration_s``;
3. **augment**: ``augment`` random affine copies of every training sample
   (:func:`augment`; a share of them photographed on paper with ``paper``);
4. **fit**: a DMP fitted to every path and measured (:func:`fit_paths`);
5. **record**: the metadata every data set holds (:func:`build_dataset`), to which the
   source adds its own;
6. **data set**: the :class:`~img2dmp.data.store.DigitData`.

The fields every source shares are :class:`BuildOptions`; a source's own options
subclass it next to its reader (``ImportOptions``, ``PrepareOptions``). Splits a source
does not give are drawn here too (:func:`draw_splits`), per class or per split unit.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from .._progress import bar as progress_bar
from ..dmp import DMPConfig, DMPParams, fit_dmp, rollout
from ..metrics import on_ink_share
from .affine import AffineRanges, sample_affine, warp_images, warp_points
from .images import OUTPUT_SIDE_PX, ImageFrame, prepare_image_framed
from .resample import PenPath, resample
from .store import SPLITS, DigitData

#: Most affine copies per training sample.
MAX_AUGMENT = 1000
#: A point may lie beyond the image's border by at most this share of the image's side.
OUTSIDE_TOLERANCE = 0.1
#: The side of MNIST's images, the fixed frame of :func:`frame_fixed`.
MNIST_SIZE = 28
#: How images of a fixed frame reach another size (:func:`frame_fixed`).
RESIZE_MODES = ("scale", "pad")
#: Shortest and longest ``duration_s``: a path of less than a millisecond is no pen's
#: (its DMP's speeds grow as 1 / duration, its stored float32 instants toward their
#: smallest steps), and no DMP file holds a tau beyond 1e6 s.
MIN_DURATION_S = 1e-3
MAX_DURATION_S = 1e6
_FIT_CHUNK = 2048
_WARP_CHUNK = 4096  # bounds the memory of the warp


# --- options --------------------------------------------------------------------------


@dataclass
class BuildOptions:
    """The fields of a data set's build that every source shares.

    Attributes
    ----------
    image_size : int
        Side of the stored square images (the model's input), pixels.
    n_times : int
        Instants per trajectory (the DMP time grid).
    n_dims : int or None
        2 (x, y) or 3 (x, y, pen); None: the source decides.
    scaling : str or None
        DMP forcing-term scaling; None: ``"goal-start"`` (the paper) for d = 2, ``"none"``
        for d = 3, where it is required (the pen starts and ends down, so ``g - y0 = 0`` on
        that channel and the paper's scaling would switch its forcing term off).
    n_kernels : int
        Kernels per dimension (N, eq. 7).
    ridge : float
        Relative Tikhonov term of :func:`img2dmp.dmp.fit_dmp`.
    augment : int
        Random affine copies added per training sample (validation and test are never
        augmented).
    affine : AffineRanges
        Ranges of those copies' transforms.
    seed : int
        Seed of the augmentation (and of a drawn split).
    duration_s : float or None
        Rescale every path to last this long; None keeps the recorded timing.
    """

    image_size: int = 40
    n_times: int = 100
    n_dims: int | None = None
    scaling: str | None = None
    n_kernels: int = 25
    ridge: float = 1e-9
    augment: int = 0
    affine: AffineRanges = field(default_factory=AffineRanges)
    seed: int = 0
    duration_s: float | None = None

    def __post_init__(self) -> None:
        lo, hi = OUTPUT_SIDE_PX
        check_int("image_size", self.image_size, max(8, lo), hi)
        check_int("n_times", self.n_times, 2, 100_000)
        check_int("n_kernels", self.n_kernels, 1, 10_000)
        check_int("augment", self.augment, 0, MAX_AUGMENT)
        check_int("seed", self.seed, 0, 2**63 - 1)
        check_number("ridge", self.ridge, 0.0, 1.0)
        if self.duration_s is not None:
            _check_duration(self.duration_s)
        if self.n_dims not in (None, 2, 3):
            raise ValueError(f"n_dims must be 2 (x, y), 3 (x, y, pen) or None, got {self.n_dims!r}")
        if self.scaling not in (None, "goal-start", "none"):
            raise ValueError(f"scaling must be 'goal-start' or 'none', got {self.scaling!r}")
        if self.n_dims is not None:
            self.dmp_config()  # a pen channel needs the scaling "none"

    def dmp_config(self, n_dims: int | None = None) -> DMPConfig:
        """The DMP constants of a data set of ``n_dims`` dimensions (default ``n_dims``)."""
        n_dims = n_dims or self.n_dims
        scaling = self.scaling or ("goal-start" if n_dims == 2 else "none")
        if n_dims == 3 and scaling != "none":
            raise ValueError(
                "a pen channel (n_dims=3) needs scaling='none': the pen starts and ends down, "
                "so g - y0 = 0 and the paper's goal-start scaling would cancel its forcing term"
            )
        return DMPConfig(n_kernels=self.n_kernels, n_dims=n_dims, scaling=scaling)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["affine"] = self.affine.to_dict()
        return d


def _check_duration(value) -> None:
    """``duration_s`` (``--duration``) a number of seconds in ``[MIN_DURATION_S,
    MAX_DURATION_S]``, else ``ValueError`` saying why."""
    check_number("duration_s", value, 0.0, MAX_DURATION_S, open_low=True)
    if value < MIN_DURATION_S:
        raise ValueError(
            f"duration_s (--duration) must be at least {MIN_DURATION_S:g} s, got {value!r}: "
            "every path is rescaled to last that long, and a path of less than a "
            "millisecond is no pen's (its DMP's speeds would grow as 1 / duration)"
        )


def check_int(name: str, value, lo: int, hi: int) -> None:
    """``ValueError`` naming ``name`` unless ``value`` is an integer in ``[lo, hi]``."""
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")


def check_number(name: str, value, lo: float, hi: float, open_low: bool = False) -> None:
    """``ValueError`` naming ``name`` unless ``value`` is a finite number in ``[lo, hi]``
    (``(lo, hi]`` with ``open_low``)."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or value > hi or value < lo or (open_low and value == lo):
        bound = f"({lo}, {hi}]" if open_low else f"[{lo}, {hi}]"
        raise ValueError(f"{name} must be a number in {bound}, got {value!r}")


# --- frame and resample ---------------------------------------------------------------


@dataclass
class FramedSample:
    """One sample framed and resampled, as :func:`frame_pen_path` returns it."""

    image: np.ndarray  # [S, S] float32
    times: np.ndarray  # [n] s
    path: np.ndarray  # [n, 3] (x, y, pen) in the prepared image
    frame: ImageFrame  # the sample's image -> the prepared image
    spans: list[tuple[int, int]]  # each stroke's first and last instant
    shift: tuple[float, float] | None = None  # what ``place`` moved the path by (px)


#: How a reader puts its path on its prepared image: ``place(pen, image, frame, name)``
#: returns the pen path and the shift it was moved by (or None).
Place = Callable[[PenPath, np.ndarray, ImageFrame, str], tuple[PenPath, tuple | None]]


def frame_pen_path(
    image,
    pen: PenPath,
    options,
    *,
    name: str,
    clean: bool = True,
    place: Place | None = None,
) -> FramedSample:
    """Frame one image with its pen path and resample the path (module docstring, 1-2).

    ``options`` gives ``image_size``, ``margin``, ``stroke_width_px``, ``n_times``,
    ``resample``, ``min_on_ink`` and ``duration_s`` (``ImportOptions``); ``clean=False``
    reads a clean rendering without the paper cleaning of a photo; ``place`` puts the path
    on the prepared image (default: :func:`check_within_image`). At least ``min_on_ink`` of
    the pen-down path must lie on the prepared image's ink.
    """
    size = options.image_size
    prepared, frame = prepare_image_framed(
        image, (size, size), margin=options.margin, stroke_width_px=options.stroke_width_px,
        name=name, clean=clean,
    )  # fmt: skip
    shift = None
    if place is None:
        check_within_image(pen, frame.image_size, name)
    else:
        pen, shift = place(pen, prepared, frame, name)
    res = resample(pen, options.n_times, options.resample)
    times, path = res.times, frame.to_model(res.path)
    share = float(on_ink_share(prepared[None], path[None])[0])
    if share < options.min_on_ink:
        raise ValueError(
            f"{pen.name}: only {share:.0%} of its pen-down path lies on the ink of "
            f"{name} (at least {options.min_on_ink:.0%} needed, --min-on-ink); is it that "
            f"image's path, in its pixels, {pen.file_frame}?"
        )
    if options.duration_s is not None:
        times = times * (options.duration_s / times[-1])
    return FramedSample(prepared, times, path, frame, res.spans, shift)


def check_within_image(pen: PenPath, size: tuple[int, int], image_name: str) -> None:
    """Every point within the image of ``size = (H, W)``, or beyond its border by at most
    ``OUTSIDE_TOLERANCE`` of its longer side; else ``ValueError`` naming the point."""
    h, w = size
    tol = OUTSIDE_TOLERANCE * max(w, h)
    x, y = pen.xy[:, 0], pen.xy[:, 1]
    bad = (x < -0.5 - tol) | (x > w - 0.5 + tol) | (y < -0.5 - tol) | (y > h - 0.5 + tol)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(
            f"{pen.name}: {pen.point_name(k)} (x={x[k]:g}, y={y[k]:g}) lies outside the "
            f"{w} x {h} image {image_name} by more than {OUTSIDE_TOLERANCE:.0%} of its side "
            "(x = column, y = row, in pixels of the image)"
        )


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
    import torch
    import torch.nn.functional as F

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


def frame_fixed(images, paths, times, options, resize_mode: str):
    """Samples of MNIST's fixed 28 x 28 frame framed at ``options.image_size`` (module
    docstring, 1-2): images ``[M, S, S]``, paths ``[M, T, d]`` moved along, times ``[M, T]``
    rescaled to ``options.duration_s`` if set, and the map ``(s, o)`` of
    :func:`image_transform`."""
    s, o = image_transform(options.image_size, resize_mode)
    images = resize_images(images, options.image_size, resize_mode)  # [M, S, S]
    paths = paths.copy()  # [M, T, d]
    paths[..., :2] = s * paths[..., :2] + o
    if options.duration_s is not None:
        d = options.duration_s
        times = d * (times - times[:, :1]) / (times[:, -1:] - times[:, :1])
    return images, paths, times, (s, o)


# --- splits ---------------------------------------------------------------------------


def draw_splits(
    given: Sequence[str | None],
    labels: np.ndarray,
    units: Sequence[tuple[str, str]] | None,
    fractions: tuple[float, float],
    rng,
    names: Sequence[str],
) -> np.ndarray:
    """The split code of every sample: the source's own (``given``, all or none), else
    drawn with ``fractions = (val_fraction, test_fraction)``: per class, or, with
    ``units`` (``(stratum, unit)`` of every sample), whole units per stratum. ``names``
    name the samples in messages."""
    if all(g is not None for g in given):
        return np.array([SPLITS[g] for g in given], np.uint8)
    if any(g is not None for g in given):
        first = names[next(i for i, g in enumerate(given) if g is None)]
        raise ValueError(
            f"{first}: gives no split while other rows do; give every row a split or none"
        )
    if units is not None:
        return _unit_splits(units, fractions, rng)
    split = np.zeros(len(labels), np.uint8)
    for c in np.unique(labels):
        rows = rng.permutation(np.flatnonzero(labels == c))
        n_test, n_val = _split_counts(len(rows), fractions)
        split[rows[:n_test]] = SPLITS["test"]
        split[rows[n_test : n_test + n_val]] = SPLITS["validation"]
    return split


def _split_counts(n: int, fractions: tuple[float, float]) -> tuple[int, int]:
    """How many of ``n`` samples (or units) go to test and to validation: the fractions,
    rounded, at least one left to train on."""
    val_fraction, test_fraction = fractions
    n_test = min(int(math.floor(test_fraction * n + 0.5)), n - 1)
    n_val = int(math.floor(val_fraction * n + 0.5))
    return n_test, min(n_val, n - n_test - 1)


def _unit_splits(units, fractions, rng) -> np.ndarray:
    """The split of every sample when whole units go to one split (Omniglot by
    character or alphabet): the units of each stratum drawn with the fractions."""
    unit_split = {}
    for stratum in sorted({st for st, _ in units}):
        names = sorted({u for st, u in units if st == stratum})
        order = [names[i] for i in rng.permutation(len(names))]
        n_test, n_val = _split_counts(len(names), fractions)
        for i, name in enumerate(order):
            code = "test" if i < n_test else "validation" if i < n_test + n_val else "train"
            unit_split[(stratum, name)] = SPLITS[code]
    return np.array([unit_split[u] for u in units], np.uint8)


# --- augment --------------------------------------------------------------------------


def augment(images, paths, split, options, rng, *, paper: float = 0.0, progress: bool = False):
    """``options.augment`` random affine copies of every training sample appended
    (:func:`img2dmp.data.affine.sample_affine` / ``warp_images`` / ``warp_points``), a share
    ``paper`` of them photographed on generated paper (:func:`_on_paper`).

    Returns images ``[M', S, S]``, paths ``[M', T, d]``, the source row of every sample
    ``[M']`` and its copy number ``[M']`` (0 = the original).
    """
    rows = np.arange(len(paths))
    copy = np.zeros(len(paths), np.int64)
    train = np.flatnonzero(split == SPLITS["train"])
    if not options.augment or not len(train):
        return images, paths, rows, copy
    size = options.image_size
    src = np.repeat(train, options.augment)  # [A]
    mats = sample_affine(rng, len(src), size, options.affine)  # [A, 2, 3]
    out = np.empty((len(src), size, size), np.float32)
    chunks = range(0, len(src), _WARP_CHUNK)
    for lo in progress_bar(chunks, desc="augment", unit="chunk", enabled=progress):
        sl = slice(lo, lo + _WARP_CHUNK)
        out[sl] = warp_images(images[src[sl]], mats[sl]).clamp(0.0, 1.0).numpy()
    out_paths = warp_points(paths[src], mats)
    if paper:
        out, out_paths = _on_paper(rng, images[train], out, out_paths, paper, progress)
    return (
        np.concatenate([images, out]),
        np.concatenate([paths, out_paths]),
        np.concatenate([rows, src]),
        np.concatenate([copy, np.tile(np.arange(1, options.augment + 1), len(train))]),
    )


def _on_paper(rng, originals, images, paths, paper: float, progress: bool):
    """A share ``paper`` of the copies ``images [A, S, S]``, ``paths [A, T, d]``
    photographed on generated paper and read back (:func:`img2dmp.data.on_paper.paper_copies`),
    framed and as wide a pen as the original training images (``originals``) are."""
    from .images import ink_margin, typical_stroke_width
    from .on_paper import paper_copies

    pick = np.flatnonzero(rng.random(len(images)) < paper)
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


# --- fit ------------------------------------------------------------------------------


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
    import torch

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
    import torch

    y = rollout(params.to_torch(), torch.as_tensor(np.asarray(t, dtype=np.float64)), config)
    y = y.numpy()
    return y[..., :2], y[..., 2] > 0.5


def fit_statistics(fit: FitSummary, labels: np.ndarray, names: Sequence[str], by: str) -> dict:
    """The ``fit`` record of a data set's meta: fit errors (px), overall and per class
    (``mean_error_px_by_<by>``, keyed by ``names[label]``), and the pen's agreement for
    d = 3."""
    stats = {
        "mean_error_px": float(fit.error_px.mean()),
        "max_error_px": float(fit.max_error_px.max()),
        f"mean_error_px_by_{by}": {
            names[c]: float(fit.error_px[labels == c].mean()) for c in np.unique(labels)
        },
    }
    if fit.pen_agreement is not None:
        stats["pen_agreement_mean"] = float(fit.pen_agreement.mean())
        stats["pen_agreement_min"] = float(fit.pen_agreement.min())
    return stats


# --- the data set ---------------------------------------------------------------------


@dataclass
class Framed:
    """Samples framed and resampled, before augmentation: what :func:`build_dataset`
    builds from.

    Attributes
    ----------
    images : float32 [M, S, S]
    paths : float [M, T, d]
        In pixels of the stored images.
    times : float [M, T]
        Seconds.
    labels : int64 [M]
    split : uint8 [M]
        ``SPLITS`` codes.
    """

    images: np.ndarray
    paths: np.ndarray
    times: np.ndarray
    labels: np.ndarray
    split: np.ndarray


#: The source's part of the meta, from the stored rows' source rows, copy numbers and fits.
SourceMeta = Callable[[np.ndarray, np.ndarray, FitSummary], dict]


def build_dataset(
    framed: Framed,
    options: BuildOptions,
    config: DMPConfig,
    *,
    rng,
    source_meta: SourceMeta,
    paper: float = 0.0,
    progress: bool = False,
) -> DigitData:
    """Augment, fit and record framed samples as a data set (module docstring, 3-6).

    ``rng`` draws the augmentation; ``source_meta(rows, copy, fit)`` gives the source's
    part of the metadata (its options, files, per-row records, its ``fit`` record), merged
    over the part every data set holds (``dmp_config``, ``seed``, ``counts_by_split``).
    """
    images, paths, rows, copy = augment(
        framed.images, framed.paths, framed.split, options, rng, paper=paper, progress=progress
    )
    times = framed.times[rows]  # [M', T]
    fit = fit_paths(times, paths, config, ridge=options.ridge, progress=progress)
    split = framed.split[rows]
    meta = {
        "dmp_config": config.to_dict(),
        "seed": options.seed,
        "counts_by_split": {name: int((split == code).sum()) for name, code in SPLITS.items()},
        **source_meta(rows, copy, fit),
    }
    return DigitData(
        images=np.ascontiguousarray(images, dtype=np.float32),
        trajectories=paths.astype(np.float32),
        times=times.astype(np.float32),
        labels=framed.labels[rows].astype(np.int64),
        params=fit.params,
        fit_error_px=fit.error_px,
        split=split.astype(np.uint8),
        meta=meta,
    )
