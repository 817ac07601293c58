"""Synthetic handwritten digits as in the first experiments of Pahič et al. (ICRA 2018).

Each digit 0-9 is one continuous pen path built from straight segments and elliptic arcs
(:data:`DIGIT_TEMPLATES`), written along the path with a minimum-jerk speed profile,
rendered to a grey image, blurred, moved by a random affine transform together with its
path, and sprinkled with salt-and-pepper noise. A DMP (eqs. 3-8) is fitted to every path.

Geometry. Templates live in a *unit frame*: x to the right, y downwards (like image
rows), the digit spanning roughly y in [-1, 1]. A point ``u`` of that frame lands at
pixel ``c + (digit_height_rel * H / 2) * u`` with ``c`` the image centre.

Elements, each with nominal parameters that every sample draws uniformly around:

- ``Line(length, angle_deg)``: from the current pen position, ``length`` units in the
  direction ``(cos angle, sin angle)`` (0 = right, 90 = down).
- ``Arc(a, b, tilt_deg, start_deg, end_deg)``: an elliptic arc with semi-axes ``a``
  (first axis) and ``b`` (second axis), the first axis turned ``tilt_deg`` from the
  image x axis, traversed from ``start_deg`` to ``end_deg`` (increasing = clockwise on
  screen). Its centre is where the pen is minus the ellipse point at ``start_deg``, so
  the path stays continuous; only a digit's first arc has a free centre.

Ranges (all of :class:`SyntheticConfig`, uniform): a line's length is multiplied by
``U(1 - line_length_rel, 1 + line_length_rel)`` and its angle shifted by
``U(-line_angle_deg, line_angle_deg)``; an arc's axes are multiplied by
``U(1 - arc_axis_rel, 1 + arc_axis_rel)`` (each independently), its tilt shifted by
``U(-arc_tilt_deg, arc_tilt_deg)``, its start and end angles by
``U(-arc_angle_deg, arc_angle_deg)`` (independently); the first point (or the first
arc's centre) is shifted by ``U(-start_shift, start_shift)`` units in x and in y.

Timing. Arc length along the path follows the minimum-jerk profile
``s(t) = L (10 u^3 - 15 u^4 + 6 u^5)``, ``u = t / duration_s``, sampled every ``dt_s``.

Because the DMP's forcing term is scaled by ``g - y0`` (the paper's scaling), a path
whose start and end nearly coincide in x or y needs huge weights. The templates start and
end apart, like real writing, and a drawn sample whose start and end are closer than
``min_start_goal_rel * image size`` in x or in y (after the affine transform) is drawn
again, and so is one whose pen would leave the image (before or after the transform).

Visible ends. The image must determine the movement, so both ends of the pen path must
show in it: a sample where another part of the stroke passes within
``min_end_clearance_rel * image size`` of the first or the last point (parts within twice
that distance along the path excepted) is drawn again (:func:`end_clearance`). The
templates of 0, 6, 8 and 9 leave a gap between the stroke's ends for this reason; closed
the way many people write them, the stroke ran over its own start or end, and no image
could tell where the pen set down or lifted off.
"""

from __future__ import annotations

import math
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field

import numpy as np
import torch

from .._processes import children_ignore_interrupts
from .._progress import bar as progress_bar
from ..config import ConfigError, check_known, check_positive_fields, from_mapping
from ..dmp import DMPConfig, fit_dmp
from .affine import AffineRanges, sample_affine, warp_images, warp_points
from .render import gaussian_filter, render_paths, salt_and_pepper
from .store import DigitData

# ---------------------------------------------------------------------------------------
# Templates


@dataclass(frozen=True)
class Line:
    """A straight segment: ``length`` units (unit frame) at ``angle_deg`` (0 right, 90 down)."""

    length: float
    angle_deg: float


@dataclass(frozen=True)
class Arc:
    """An elliptic arc; see the module docstring for the meaning of each parameter."""

    a: float
    b: float
    tilt_deg: float
    start_deg: float
    end_deg: float


@dataclass(frozen=True)
class DigitTemplate:
    """A digit's pen path: where it starts, then a chain of elements.

    ``start`` is the first point (unit frame) when the path begins with a line;
    ``centre`` is the first arc's centre when it begins with an arc. Exactly one is set.
    """

    elements: tuple
    start: tuple[float, float] | None = None
    centre: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not self.elements or not all(isinstance(e, (Line, Arc)) for e in self.elements):
            raise ValueError("a digit template needs a non-empty chain of Line and Arc elements")
        if (self.start is None) == (self.centre is None):
            raise ValueError("a digit template sets exactly one of start and centre")
        if self.centre is not None and not isinstance(self.elements[0], Arc):
            raise ValueError("a template's centre is that of its first element, an Arc")


# Each written as one stroke, the way a person writes it (unit frame, y down).
DIGIT_TEMPLATES: dict[int, DigitTemplate] = {
    # One loop, anticlockwise from the top, open at the upper right (both ends visible).
    0: DigitTemplate(centre=(0.0, 0.0), elements=(Arc(0.6, 0.95, 8.0, -100.0, -400.0),)),
    # Up-stroke (the flag), then straight down.
    1: DigitTemplate(start=(-0.7, -0.45), elements=(Line(0.8, -42.0), Line(2.0, 94.0))),
    # Hook over the top, diagonal down to the left, base to the right.
    2: DigitTemplate(
        centre=(0.0, -0.45),
        elements=(Arc(0.5, 0.5, 0.0, -160.0, 20.0), Line(1.64, 128.0), Line(1.1, 0.0)),
    ),
    # Two bowls joined at a cusp in the middle.
    3: DigitTemplate(
        centre=(0.0, -0.5),
        elements=(Arc(0.42, 0.45, 0.0, -100.0, 90.0), Arc(0.5, 0.52, 0.0, -90.0, 165.0)),
    ),
    # Down, across, up to the top of the stem (the joining stroke), down the stem.
    4: DigitTemplate(
        start=(-0.35, -1.0),
        elements=(Line(1.32, 100.0), Line(1.0, 0.0), Line(1.206, -95.7), Line(1.95, 91.0)),
    ),
    # Top bar leftwards, down, then the bowl.
    5: DigitTemplate(
        start=(0.5, -1.0),
        elements=(Line(0.85, 180.0), Line(0.9, 97.0), Arc(0.5, 0.65, 0.0, -150.0, 150.0)),
    ),
    # Long curve down the left side, then the loop, ending at its upper right.
    6: DigitTemplate(
        centre=(0.35, 0.35),
        elements=(Arc(0.85, 1.3, 0.0, -80.0, -180.0), Arc(0.5, 0.6, 0.0, 180.0, -50.0)),
    ),
    # Top bar, then the long diagonal.
    7: DigitTemplate(start=(-0.6, -0.9), elements=(Line(1.2, -5.0), Line(2.05, 105.0))),
    # From the top of the upper loop anticlockwise, cross, lower loop clockwise, cross
    # back, up the right side of the upper loop (open at its upper right).
    8: DigitTemplate(
        centre=(0.0, -0.5),
        elements=(
            Arc(0.4, 0.47, 0.0, -90.0, -210.0),
            Line(0.81, 29.0),
            Arc(0.48, 0.5, 0.0, -40.0, 220.0),
            Line(0.82, -29.0),
            Arc(0.4, 0.47, 0.0, 30.0, -10.0),
        ),
    ),
    # Loop anticlockwise from its top, open at its upper right, then the stem down.
    9: DigitTemplate(
        centre=(0.0, -0.45),
        elements=(Arc(0.45, 0.5, 8.0, -80.0, -380.0), Line(1.6, 103.0)),
    ),
}

# Dense points per element before resampling by arc length (chord error < 0.03 px at
# 40 x 40; lines are exact with their two ends).
_LINE_POINTS = 2
_ARC_POINTS_PER_TURN = 64
# Generation happens in chunks with their own seeds, so results do not depend on the
# progress bar or the machine; changing this changes every data set.
CHUNK = 1000
#: Largest generated data set, bytes of its arrays (images, paths, times, parameters): a
#: 40 x 40 set of this size is 420,000 samples; its arrays are held in memory and copied
#: once more when saved.
MAX_DATASET_BYTES = 4 * 2**30


# ---------------------------------------------------------------------------------------
# Configuration


def _size2(value) -> tuple[int, int]:
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        value = (int(value), int(value))
    try:
        h, w = value
    except (TypeError, ValueError):
        raise ValueError(f"image_size must be an integer or a pair (H, W), got {value!r}") from None
    if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (h, w)):
        raise ValueError(f"image_size must hold integers, got {value!r}")
    if h < 8 or w < 8:
        raise ValueError(f"image_size must be at least 8 x 8 pixels, got {value!r}")
    return int(h), int(w)


@dataclass(frozen=True)
class SyntheticConfig:
    """Everything that shapes a synthetic digit; the defaults follow the paper.

    Sizes given as ``*_rel`` are fractions of the image height (so a config works at any
    image size); the pixel values quoted are those at the default 40 x 40.

    Parameters
    ----------
    digits : tuple of int
        Digits to draw (non-empty, each 0-9). Default all ten.
    image_size : (H, W)
        Image size in pixels; default (40, 40).
    duration_s, dt_s : float
        Movement duration tau and sampling step; default 3 s every 0.01 s (301 points).
    digit_height_rel : float
        Height of the template's unit-frame span [-1, 1]; default 0.55 (22 px).
    line_length_rel, line_angle_deg, arc_axis_rel, arc_tilt_deg, arc_angle_deg, start_shift
        Half-widths of the uniform ranges around each element's nominal parameters
        (see the module docstring). Defaults 0.15, 8 deg, 0.15, 8 deg, 12 deg, 0.08 units.
    pen_width_rel : float
        Pen diameter; default 0.06 (2.4 px).
    blur_sigma_rel : float
        Standard deviation of the Gaussian filter; default 0.015 (0.6 px). 0 = no blur.
    noise_amount : float
        Share of foreground pixels hit by salt-and-pepper noise; default 0.05.
    salt_fraction : float
        Share of hit pixels set to 1 (the rest to 0); default 0.5.
    affine : AffineRanges
        Ranges of the random affine transform; ``AffineRanges.identity()`` turns it off.
    min_start_goal_rel : float
        A sample whose start and end differ by less than this (times H) in x or in y is
        drawn again; default 0.04 (1.6 px). 0 disables the check.
    min_end_clearance_rel : float
        A sample where another part of its stroke passes closer than this (times H) to its
        first or last point (after the affine transform) is drawn again, so that the image
        shows where the pen set down and lifted off; default 0.09 (3.6 px, 1.5 pen
        widths). 0 disables the check.
    ridge : float
        Relative ridge of the DMP weight fit (:func:`img2dmp.dmp.fit_dmp`); default 1e-6.
    """

    digits: tuple[int, ...] = tuple(range(10))
    image_size: tuple[int, int] = (40, 40)
    duration_s: float = 3.0
    dt_s: float = 0.01
    digit_height_rel: float = 0.55
    line_length_rel: float = 0.15
    line_angle_deg: float = 8.0
    arc_axis_rel: float = 0.15
    arc_tilt_deg: float = 8.0
    arc_angle_deg: float = 12.0
    start_shift: float = 0.08
    pen_width_rel: float = 0.06
    blur_sigma_rel: float = 0.015
    noise_amount: float = 0.05
    salt_fraction: float = 0.5
    affine: AffineRanges = field(default_factory=AffineRanges)
    min_start_goal_rel: float = 0.04
    min_end_clearance_rel: float = 0.09
    ridge: float = 1e-6

    def __post_init__(self) -> None:
        digits = self.digits
        if isinstance(digits, (int, np.integer)):
            digits = (digits,)
        digits = tuple(digits)
        if not digits:
            raise ValueError("digits must name at least one digit, got an empty list")
        for d in digits:
            if not isinstance(d, (int, np.integer)) or isinstance(d, bool) or not 0 <= d <= 9:
                raise ValueError(f"digits must be integers 0-9, got {d!r}")
        if len(set(digits)) != len(digits):
            raise ValueError(f"digits must not repeat, got {digits!r}")
        object.__setattr__(self, "digits", tuple(int(d) for d in digits))
        object.__setattr__(self, "image_size", _size2(self.image_size))
        if isinstance(self.affine, dict):
            object.__setattr__(self, "affine", AffineRanges.from_dict(self.affine))
        if not isinstance(self.affine, AffineRanges):
            raise ValueError(f"affine must be an AffineRanges, got {type(self.affine).__name__}")
        positive = ("duration_s", "dt_s", "digit_height_rel", "pen_width_rel")
        non_negative = (
            "line_length_rel",
            "line_angle_deg",
            "arc_axis_rel",
            "arc_tilt_deg",
            "arc_angle_deg",
            "start_shift",
            "blur_sigma_rel",
            "min_start_goal_rel",
            "min_end_clearance_rel",
            "ridge",
        )
        check_positive_fields(self, positive)
        check_positive_fields(
            self, (*non_negative, "noise_amount", "salt_fraction"), allow_zero=True
        )
        for name in ("line_length_rel", "arc_axis_rel"):
            if getattr(self, name) >= 1:
                v = getattr(self, name)
                raise ValueError(f"{name} must be < 1 (lengths stay positive), got {v!r}")
        for name in ("noise_amount", "salt_fraction"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name} must lie in [0, 1], got {getattr(self, name)!r}")
        if self.n_times < 2:
            raise ValueError(
                f"duration_s / dt_s must give at least 2 time stamps, got "
                f"duration_s={self.duration_s}, dt_s={self.dt_s}"
            )
        if abs(self.duration_s / self.dt_s - round(self.duration_s / self.dt_s)) > 1e-6:
            raise ValueError(
                f"duration_s ({self.duration_s}) must be a whole number of dt_s ({self.dt_s})"
            )

    @property
    def n_times(self) -> int:
        """Number T of time stamps: ``duration_s / dt_s + 1``."""
        return int(round(self.duration_s / self.dt_s)) + 1

    def times(self) -> np.ndarray:
        """The shared time grid ``[T]`` in seconds, from 0 to ``duration_s``."""
        return np.arange(self.n_times, dtype=np.float64) * self.dt_s

    @property
    def unit_px(self) -> float:
        """Pixels per unit of the template frame."""
        return self.digit_height_rel * self.image_size[0] / 2.0

    def to_dict(self) -> dict:
        d = asdict(self)
        d["digits"] = list(self.digits)
        d["image_size"] = list(self.image_size)
        d["affine"] = self.affine.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> SyntheticConfig:
        """A config from a mapping of its fields (a file, ``--set`` overrides, a data
        set's metadata), typed by :func:`img2dmp.config.from_mapping`: unknown fields
        are refused, ``1e-6`` is a number, a wrong type is named. ``affine`` takes a
        mapping of :class:`AffineRanges` fields; one digit or one image side may be
        given as a plain integer."""
        if not isinstance(d, dict):
            raise ConfigError(f"a synthetic config must be a mapping of fields, got {d!r}")
        check_known(cls, d)  # worded as every config's: "unknown field(s) pen_size; known: ..."
        d = dict(d)
        for key, n in (("digits", 1), ("image_size", 2)):
            if isinstance(d.get(key), (int, np.integer)) and not isinstance(d[key], bool):
                d[key] = [int(d[key])] * n
        return from_mapping(cls, d)


# ---------------------------------------------------------------------------------------
# Pen paths


def _uniform(rng: np.random.Generator, n: int, half_width: float) -> np.ndarray:
    return (2.0 * rng.random(n) - 1.0) * half_width


def sample_element_params(
    template: DigitTemplate, n: int, config: SyntheticConfig, rng: np.random.Generator
) -> tuple[np.ndarray, list[dict[str, np.ndarray]]]:
    """Draw ``n`` sets of element parameters around a template's nominal values.

    Returns
    -------
    anchor : array [n, 2]
        The first point (line-first templates) or the first arc's centre (unit frame).
    elements : list of dict
        One dict per element of arrays ``[n]``: ``length``, ``angle_deg`` for a line;
        ``a``, ``b``, ``tilt_deg``, ``start_deg``, ``end_deg`` for an arc.
    """
    c = config
    nominal = np.asarray(template.start if template.start is not None else template.centre)
    anchor = nominal + np.stack([_uniform(rng, n, c.start_shift) for _ in range(2)], -1)
    out = []
    for e in template.elements:
        if isinstance(e, Line):
            out.append(
                {
                    "length": e.length * (1.0 + _uniform(rng, n, c.line_length_rel)),
                    "angle_deg": e.angle_deg + _uniform(rng, n, c.line_angle_deg),
                }
            )
        else:
            out.append(
                {
                    "a": e.a * (1.0 + _uniform(rng, n, c.arc_axis_rel)),
                    "b": e.b * (1.0 + _uniform(rng, n, c.arc_axis_rel)),
                    "tilt_deg": e.tilt_deg + _uniform(rng, n, c.arc_tilt_deg),
                    "start_deg": e.start_deg + _uniform(rng, n, c.arc_angle_deg),
                    "end_deg": e.end_deg + _uniform(rng, n, c.arc_angle_deg),
                }
            )
    return anchor, out


def _ellipse_points(p: dict, theta: np.ndarray) -> np.ndarray:
    # Points of the centred, tilted ellipse at angles theta [n, K] -> [n, K, 2].
    tilt = np.deg2rad(p["tilt_deg"])[:, None]
    ex, ey = p["a"][:, None] * np.cos(theta), p["b"][:, None] * np.sin(theta)
    ct, st = np.cos(tilt), np.sin(tilt)
    return np.stack([ct * ex - st * ey, st * ex + ct * ey], -1)


def build_paths(
    template: DigitTemplate, anchor: np.ndarray, elements: list[dict[str, np.ndarray]]
) -> np.ndarray:
    """Densely sampled pen paths ``[n, K, 2]`` (unit frame) from element parameters.

    Elements are chained: each starts where the previous one ended.
    """
    n = anchor.shape[0]
    pieces = []
    pen = anchor.copy()  # [n, 2]
    for i, (e, p) in enumerate(zip(template.elements, elements, strict=True)):
        if isinstance(e, Line):
            ang = np.deg2rad(p["angle_deg"])
            step = p["length"][:, None] * np.stack([np.cos(ang), np.sin(ang)], -1)  # [n, 2]
            step = step[:, None]  # [n, 1, 2]
            frac = np.linspace(0.0, 1.0, _LINE_POINTS)[None, :, None]
            pts = pen[:, None] + frac * step  # [n, K, 2]
        else:
            sweep = np.abs(p["end_deg"] - p["start_deg"]).max()
            k = max(8, int(math.ceil(_ARC_POINTS_PER_TURN * sweep / 360.0)) + 1)
            frac = np.linspace(0.0, 1.0, k)[None]
            a0, a1 = p["start_deg"][:, None], p["end_deg"][:, None]
            theta = np.deg2rad(a0 + frac * (a1 - a0))  # [n, K]
            rim = _ellipse_points(p, theta)  # [n, K, 2]
            centre = anchor if (i == 0 and template.centre is not None) else pen - rim[:, 0]
            pts = centre[:, None] + rim
        pieces.append(pts if not pieces else pts[:, 1:])
        pen = pts[:, -1]
    return np.concatenate(pieces, 1) if n else np.zeros((0, 1, 2))


def minimum_jerk_resample(dense: np.ndarray, times: np.ndarray, duration_s: float) -> np.ndarray:
    """Positions ``[n, T, 2]`` along dense paths ``[n, K, 2]`` at minimum-jerk arc length.

    Arc length ``s(t) = L (10 u^3 - 15 u^4 + 6 u^5)``, ``u = t / duration_s`` (zero speed
    and acceleration at both ends); linear interpolation between the dense points.
    """
    n, k = dense.shape[:2]
    seg = np.linalg.norm(np.diff(dense, axis=1), axis=-1)  # [n, K-1]
    cum = np.concatenate([np.zeros((n, 1)), np.cumsum(seg, 1)], 1)  # [n, K]
    frac = cum / np.maximum(cum[:, -1:], 1e-300)  # [n, K] in [0, 1]
    u = np.clip(times / duration_s, 0.0, 1.0)
    s = 10 * u**3 - 15 * u**4 + 6 * u**5  # [T] share of the length, same for every path
    # One sorted search for all rows: row r's values are shifted into [2r, 2r + 1].
    shift = 2.0 * np.arange(n)[:, None]
    j = np.searchsorted((frac + shift).ravel(), (s[None] + shift).ravel()).reshape(n, -1)
    j = np.clip(j - k * np.arange(n)[:, None], 1, k - 1)  # [n, T] index within the row
    rows = np.arange(n)[:, None]
    f0, f1 = frac[rows, j - 1], frac[rows, j]
    f = np.clip((s[None] - f0) / np.maximum(f1 - f0, 1e-300), 0.0, 1.0)[..., None]
    p0, p1 = dense[rows, j - 1], dense[rows, j]
    return p0 + f * (p1 - p0)


def sample_unit_paths(
    digit: int, n: int, config: SyntheticConfig, rng: np.random.Generator
) -> np.ndarray:
    """``n`` random pen paths of one digit, timed by minimum jerk: ``[n, T, 2]`` unit frame."""
    if digit not in DIGIT_TEMPLATES:
        raise ValueError(f"digit must be 0-9, got {digit!r}")
    template = DIGIT_TEMPLATES[digit]
    return timed_paths(template, *sample_element_params(template, n, config, rng), config)


def timed_paths(
    template: DigitTemplate,
    anchor: np.ndarray,
    elements: list[dict[str, np.ndarray]],
    config: SyntheticConfig,
) -> np.ndarray:
    """Pen paths ``[n, T, 2]`` (unit frame) from element parameters, timed by minimum jerk."""
    dense = build_paths(template, anchor, elements)
    return minimum_jerk_resample(dense, config.times(), config.duration_s)


# ---------------------------------------------------------------------------------------
# Samples


def _inside(paths: np.ndarray, h: int, w: int, margin: float) -> np.ndarray:
    # [n, T, 2] -> [n]: every point at least `margin` px inside the image's pixel centres.
    lo, hi = (v.numpy() for v in torch.aminmax(torch.from_numpy(paths), dim=1))  # [n, 2] each
    return (lo >= margin).all(-1) & (hi[:, 0] <= w - 1 - margin) & (hi[:, 1] <= h - 1 - margin)


def end_clearance(paths: np.ndarray, exclusion: float) -> tuple[np.ndarray, np.ndarray]:
    """How far the rest of each stroke stays from its first and from its last point.

    Parameters
    ----------
    paths : array [n, T, 2]
        Pen paths (a polyline each), in any length unit.
    exclusion : float
        The part of the stroke within this arc length of an end belongs to that end and
        is left out.

    Returns
    -------
    start, end : arrays [n]
        Smallest distance from the first (last) point to the polyline's segments beyond
        ``exclusion`` along the path; ``inf`` when the stroke is not longer than that.
    """
    paths = np.asarray(paths, dtype=np.float64)
    if paths.ndim != 3 or paths.shape[-1] != 2:
        raise ValueError(f"paths must have shape [n, T, 2], got {paths.shape}")
    a, b = paths[:, :-1], paths[:, 1:]  # segments [n, T-1, 2]
    ab = b - a
    length = np.linalg.norm(ab, axis=-1)
    cum = np.concatenate([np.zeros((paths.shape[0], 1)), np.cumsum(length, 1)], 1)  # [n, T]
    out = []
    for end, along in ((0, cum), (-1, cum[:, -1:] - cum)):
        ap = paths[:, end, None] - a
        f = np.clip((ap * ab).sum(-1) / np.maximum(length**2, 1e-300), 0.0, 1.0)
        dist = np.linalg.norm(ap - f[..., None] * ab, axis=-1)  # [n, T-1]
        far = np.minimum(along[:, :-1], along[:, 1:]) > exclusion  # the whole segment
        out.append(np.where(far, dist, np.inf).min(1, initial=np.inf))
    return out[0], out[1]


def _paths_and_transforms(labels: np.ndarray, config: SyntheticConfig, rng: np.random.Generator):
    # Pixel paths before [M, T, 2] and after [M, T, 2] the affine transform, and its matrices.
    h, w = config.image_size
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    m = labels.shape[0]
    raw = np.zeros((m, config.n_times, 2))
    mats = np.zeros((m, 2, 3))
    todo = np.arange(m)
    min_gap = config.min_start_goal_rel * h
    margin = 0.5 * config.pen_width_rel * h + 0.5
    clearance = config.min_end_clearance_rel * h
    for _ in range(100):
        for digit in np.unique(labels[todo]):
            idx = todo[labels[todo] == digit]
            unit = sample_unit_paths(int(digit), idx.size, config, rng)  # [n, T, 2]
            raw[idx] = centre + config.unit_px * unit
        mats[todo] = sample_affine(rng, todo.size, (h, w), config.affine)
        moved = warp_points(raw[todo], mats[todo])
        gap = np.abs(moved[:, -1] - moved[:, 0]).min(-1)  # [len(todo)]
        inside = _inside(raw[todo], h, w, margin) & _inside(moved, h, w, margin)
        redraw = (gap < min_gap) | ~inside
        if clearance > 0:
            start, end = end_clearance(moved, 2.0 * clearance)
            redraw |= (start < clearance) | (end < clearance)
        todo = todo[redraw]
        if todo.size == 0:
            break
    else:
        raise ValueError(
            f"could not draw samples whose start and end differ by {min_gap:.2f} px in x and "
            f"y, whose ends stay {clearance:.2f} px clear of the rest of the stroke and whose "
            f"pen stays {margin:.2f} px inside the image; lower min_start_goal_rel, "
            "min_end_clearance_rel, digit_height_rel or the affine ranges"
        )
    return raw, warp_points(raw, mats), mats


def generate(
    labels,
    config: SyntheticConfig | None = None,
    rng: np.random.Generator | None = None,
    dmp_config: DMPConfig | None = None,
) -> DigitData:
    """Draw one synthetic sample per label: image, pen path, times and fitted DMP.

    Steps: pen path (templates, uniform ranges, minimum-jerk timing) -> anti-aliased
    rendering -> random affine transform of image and path together -> Gaussian filter
    -> salt-and-pepper noise on the foreground -> DMP fit to the transformed path on the
    shared time grid.

    Parameters
    ----------
    labels : int array [M]
        Digits to draw; each must be in ``config.digits``.
    config : SyntheticConfig
    rng : numpy Generator
        Source of all randomness; default a fresh unseeded one.
    dmp_config : DMPConfig
        Constants of the fitted DMPs; default ``DMPConfig()`` (the paper's scaling).

    Returns
    -------
    DigitData
        ``split`` is all 0 (train); ``meta`` holds the configs (seed None).
    """
    config = config or SyntheticConfig()
    dmp_config = dmp_config or DMPConfig()
    rng = rng if rng is not None else np.random.default_rng()
    if dmp_config.n_dims != 2:
        raise ValueError(
            f"synthetic digits are 2-D paths; dmp_config.n_dims is {dmp_config.n_dims}"
        )
    labels = np.asarray(labels)
    if labels.ndim != 1 or (labels.size and not np.issubdtype(labels.dtype, np.integer)):
        raise ValueError(f"labels must be a 1-D integer array, got {labels.dtype} {labels.shape}")
    bad = sorted(set(labels.tolist()) - set(config.digits))
    if bad:
        raise ValueError(f"labels {bad} are not among the configured digits {list(config.digits)}")
    h = config.image_size[0]
    times = config.times()  # [T]
    raw, traj, mats = _paths_and_transforms(labels, config, rng)
    clean = render_paths(raw, config.image_size, config.pen_width_rel * h)  # [M, H, W]
    images = warp_images(clean, mats)
    images = gaussian_filter(images, config.blur_sigma_rel * h)
    images = salt_and_pepper(images, config.noise_amount, rng, salt_fraction=config.salt_fraction)
    images = images.clamp(0.0, 1.0)
    if labels.size:
        fit = fit_dmp(times, traj, dmp_config, ridge=config.ridge)
        params = fit.params.to_vector().astype(np.float32)
        error = fit.error_px.astype(np.float32)
    else:
        params = np.zeros((0, dmp_config.n_params), np.float32)
        error = np.zeros(0, np.float32)
    m = labels.size
    return DigitData(
        images=images.numpy(),
        trajectories=traj.astype(np.float32),
        times=np.broadcast_to(times.astype(np.float32), (m, times.size)).copy(),
        labels=labels.astype(np.int64),
        params=params,
        fit_error_px=error,
        split=np.zeros(m, np.uint8),
        meta={
            "dmp_config": dmp_config.to_dict(),
            "source": {"kind": "synthetic", "config": config.to_dict()},
            "seed": None,
        },
    )


def _split_counts(n: int, fractions) -> list[int]:
    counts = [int(math.floor(n * f + 1e-9)) for f in fractions]  # 0.9 * 10 is 9, not 8
    counts[0] += n - sum(counts)
    return counts


def check_dataset_size(samples_per_digit: int, config: SyntheticConfig,
                       dmp_config: DMPConfig) -> None:  # fmt: skip
    """``ValueError`` naming ``samples_per_digit`` (``--per-digit``) for a data set whose
    arrays would take more than :data:`MAX_DATASET_BYTES`, before any sample is drawn."""
    h, w = config.image_size
    n = samples_per_digit * len(config.digits)
    per_sample = 4 * (h * w + config.n_times * (dmp_config.n_dims + 1) + dmp_config.n_params)
    if n * per_sample > MAX_DATASET_BYTES:
        most = MAX_DATASET_BYTES // (per_sample * len(config.digits))
        raise ValueError(
            f"samples_per_digit (--per-digit) {samples_per_digit}: {n:,} samples of "
            f"{h} x {w} pixels would take {n * per_sample / 2**30:,.1f} GiB, over the "
            f"{MAX_DATASET_BYTES / 2**30:g} GiB a generated data set may; at most {most:,} "
            f"per digit here"
        )


def generate_dataset(
    samples_per_digit: int,
    config: SyntheticConfig | None = None,
    seed: int = 0,
    splits: tuple[float, float, float] = (0.8, 0.1, 0.1),
    dmp_config: DMPConfig | None = None,
    progress: bool = True,
    workers: int = 1,
) -> DigitData:
    """A whole data set: ``samples_per_digit`` of each configured digit, split per digit.

    The same ``seed`` (and config) gives bit-identical data: samples are drawn in chunks of
    :data:`CHUNK`, each from its own child of ``numpy.random.SeedSequence(seed)``.

    Parameters
    ----------
    samples_per_digit : int
        At least 1.
    seed : int
        Non-negative.
    splits : (train, validation, test)
        Fractions summing to 1; within each digit the counts are rounded down and the
        remainder goes to train.
    progress : bool
        Show progress (:func:`img2dmp._progress.bar`).
    workers : int
        Processes generating chunks in parallel (each with one torch thread); the data
        do not depend on it.
    """
    config = config or SyntheticConfig()
    dmp_config = dmp_config or DMPConfig()
    if not isinstance(samples_per_digit, (int, np.integer)) or samples_per_digit < 1:
        raise ValueError(f"samples_per_digit must be an integer >= 1, got {samples_per_digit!r}")
    check_dataset_size(int(samples_per_digit), config, dmp_config)
    if not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    splits = tuple(float(f) for f in splits)
    if len(splits) != 3 or min(splits) < 0 or abs(sum(splits) - 1.0) > 1e-6:
        raise ValueError(f"splits must be three fractions >= 0 summing to 1, got {splits!r}")
    seq = np.random.SeedSequence(seed)
    order_rng = np.random.default_rng(seq.spawn(1)[0])
    per = int(samples_per_digit)
    labels = np.repeat(np.array(config.digits, np.int64), per)  # [M]
    split_one = np.repeat(np.arange(3, dtype=np.uint8), _split_counts(per, splits))
    split = np.tile(split_one, len(config.digits))
    perm = order_rng.permutation(labels.size)
    labels, split = labels[perm], split[perm]
    # Each chunk's seed is a child of the same sequence, after the order's (spawn key 1).
    n_chunks = (labels.size + CHUNK - 1) // CHUNK
    chunk_seqs = np.random.SeedSequence(seed, spawn_key=(1,)).spawn(n_chunks)
    jobs = [
        (labels[i * CHUNK : (i + 1) * CHUNK], config, chunk_seqs[i], dmp_config)
        for i in range(n_chunks)
    ]
    with progress_bar(total=labels.size, desc="generate", unit="sample", enabled=progress) as bar:
        parts = _generate_chunks(jobs, workers, bar)
    arrays = {k: np.concatenate([p.arrays()[k] for p in parts]) for k in parts[0].arrays()}
    arrays["split"] = split
    meta = dict(parts[0].meta, seed=int(seed))
    meta["source"] = dict(meta["source"], samples_per_digit=per, splits=list(splits))
    return DigitData(**arrays, meta=meta)


def _generate_chunks(jobs: list, workers: int, bar) -> list[DigitData]:
    """Each job's chunk, in order: here, or in ``workers`` processes when there are enough
    chunks to pay for starting them (seconds)."""
    if workers <= 1 or len(jobs) < 2 * workers:
        pool, results = None, map(_generate_chunk, jobs)
    else:
        ctx = multiprocessing.get_context("spawn")
        pool = ProcessPoolExecutor(min(workers, len(jobs)), ctx, _init_worker)
        with children_ignore_interrupts():  # Ctrl-C is the parent's (it ends the pool)
            results = pool.map(_generate_chunk, jobs)  # starts the processes
    parts = []
    try:
        for part in results:
            parts.append(part)
            bar.update(len(part))
    except KeyboardInterrupt:
        if pool is not None:  # they ignore Ctrl-C; the interrupt need not wait for them
            _end_workers(pool)
        raise
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    return parts


def _end_workers(pool: ProcessPoolExecutor) -> None:
    """End a pool's processes at once (SIGTERM: no traceback), not after their chunks."""
    stop = getattr(pool, "terminate_workers", None)  # Python 3.14
    if stop is not None:
        stop()
        return
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.terminate()


def _init_worker() -> None:
    # Processes already share the cores; threads inside each would only contend.
    torch.set_num_threads(1)


def _generate_chunk(job) -> DigitData:
    labels, config, seed_seq, dmp_config = job
    return generate(labels, config, np.random.default_rng(seed_seq), dmp_config)
