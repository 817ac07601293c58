"""Photo-like paper, ink on it, and whole handwritten pages with known pen paths (issue 30).

What it is for:

- **Training on cluttered paper.** :func:`random_paper` draws a sheet as a camera sees it
  (ruled, squared, dotted or plain paper of some tint, its pattern slightly turned and
  wavy, lit unevenly, maybe with printed text showing through from the back or a table
  beyond the sheet's edge), :func:`put_ink` writes a character's ink on it and
  :func:`photo_finish` takes the photo (blur, sensor noise, JPEG). A 160 x 160 crop costs
  a few milliseconds, so it serves as an augmentation over tens of thousands of samples.
- **A page generator for tests and measurement of page reading.** :func:`generate_page`
  writes characters with known pen paths (:class:`CharacterSource`: MNIST's recorded
  paths, the synthetic digits, traced strokes) in lines and words on such a sheet and
  returns the photo with the truth: the ink, each character's box, path, line and place
  in the reading order, and the same page on plain white paper as the control.

Model. Paper, printed lines and ink are reflectances, and light multiplies them::

    photo = light * sheet * prod_k (1 - a_k * (1 - c_k))

with ``sheet`` the paper's tint (or the table's colour beyond the sheet's edge) and each
``a_k`` a coverage in [0, 1] of a colour ``c_k`` (the colour it has on white paper): the
printed pattern, a red margin line, text bleeding through, the pen's ink. Ink absorbs
light, so it darkens whatever is under it and keeps its hue on tinted paper. The camera's
blur and sensor noise act on the ink as well, so they belong to :func:`photo_finish`; the
paper itself brings soft (out-of-focus) line edges and the bleed-through's blur.

Coordinates follow ``docs/CONTRACTS.md``: a point ``(x, y)`` is column x, row y, and the
centre of pixel ``[i, j]`` is ``(x=j, y=i)``; boxes ``[x0, y0, x1, y1]`` are half-open
pixel bounds (``x0 <= j < x1``). Images are float32 in [0, 1] (RGB ``[H, W, 3]``) until
:func:`photo_finish` makes them uint8.

Speed and bounded memory. Sizes up to :data:`MAX_PIXELS` (6000 x 4000, 24 MP) are
accepted. Smooth fields (lighting, the table's texture, the bleed-through, the sensor
noise) are drawn on coarse grids and interpolated; the printed pattern is exact per pixel
but separable in the sheet's frame, so it is read from 1-D look-up tables (:class:`_Axis`);
and every float32 step at full resolution works on bands of :data:`_BAND_PIXELS` pixels,
so beyond the outputs only a few band-sized temporaries are alive. The camera's steps work
on uint8 images (PIL). A page adds its ink map (float32 [H, W]), and characters are
rendered on their own neighbourhoods only.
"""

from __future__ import annotations

import dataclasses
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from PIL import Image, ImageDraw, ImageFilter, ImageFont
from scipy import ndimage

from .recorded import RecordedPath
from .render import render_paths
from .strokes import StrokeDigit
from .synthetic import DIGIT_TEMPLATES, SyntheticConfig, sample_unit_paths

#: Kinds of paper :func:`random_paper` draws.
KINDS = ("plain", "ruled", "squared", "dotted")
#: Largest side and largest area of a generated image (a 24-megapixel photo).
MAX_SIDE = 8192
MAX_PIXELS = 6000 * 4000
#: Smallest side of a generated image.
MIN_SIDE = 8

#: Paper tints (reflectance in RGB), by name.
TINTS = {
    "white": (0.95, 0.95, 0.94),
    "cream": (0.96, 0.93, 0.84),
    "yellow": (0.98, 0.93, 0.62),
    "light blue": (0.83, 0.90, 0.97),
    "grey": (0.80, 0.80, 0.79),
}
#: Colours of printed rules, grids and dots at full strength, by name.
LINE_COLOURS = {
    "blue": (0.20, 0.45, 0.90),
    "grey": (0.45, 0.45, 0.47),
    "green": (0.45, 0.72, 0.55),
}
#: The red of a margin line at full strength.
MARGIN_COLOUR = (0.92, 0.25, 0.30)
#: Pen colours (what a fully inked stroke looks like on white paper) and how often each
#: is drawn by :func:`random_pen_colour`.
PEN_COLOURS = {
    "black": ((0.10, 0.10, 0.12), 0.35),
    "blue": ((0.12, 0.22, 0.62), 0.30),
    "dark blue": ((0.07, 0.09, 0.32), 0.15),
    "red": ((0.72, 0.10, 0.12), 0.10),
    "green": ((0.10, 0.42, 0.22), 0.10),
}
#: Table tops beyond the sheet's edge (RGB), by name.
TABLE_COLOURS = {
    "dark wood": (0.30, 0.19, 0.11),
    "wood": (0.50, 0.34, 0.20),
    "grey": (0.33, 0.34, 0.36),
    "black": (0.12, 0.12, 0.13),
}

# Pixels per band of rows in full-resolution steps (bounds the temporaries).
_BAND_PIXELS = 1 << 18
# Cells along the short side of the grid that smooth lighting is drawn on.
_LIGHT_CELLS = 64
# Cells along the short side of the table's texture grid.
_TABLE_CELLS = 256
# Height in grid cells of bleed-through text drawn at reduced resolution (the blur hides
# anything finer).
_BLEED_CELLS_PER_X_HEIGHT = 8.0
# Printed lines, dots and pen strokes narrower than this would vanish into the sensor.
_MIN_PRINT_WIDTH_PX = 0.7


# ---------------------------------------------------------------------------------------
# Checks


def _check_rng(rng) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    return rng


def _check_size(name: str, size_hw) -> tuple[int, int]:
    """``(H, W)`` if both are integers in [MIN_SIDE, MAX_SIDE] and H * W <= MAX_PIXELS."""
    try:
        h, w = size_hw
        ok = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (h, w))
    except (TypeError, ValueError):
        ok = False
    if not ok or not (MIN_SIDE <= h <= MAX_SIDE and MIN_SIDE <= w <= MAX_SIDE):
        raise ValueError(
            f"{name} must be two integers (H, W) in [{MIN_SIDE}, {MAX_SIDE}], got {size_hw!r}"
        )
    if int(h) * int(w) > MAX_PIXELS:
        raise ValueError(f"{name} must hold at most {MAX_PIXELS} pixels, got {size_hw!r}")
    return int(h), int(w)


def _check_number(name: str, value, lo: float, hi: float) -> float:
    if isinstance(value, (bool, str, bytes)) or not np.isscalar(value):
        raise ValueError(f"{name} must be a number in [{lo}, {hi}], got {value!r}")
    v = float(value)
    if not (math.isfinite(v) and lo <= v <= hi):
        raise ValueError(f"{name} must be a number in [{lo}, {hi}], got {value!r}")
    return v


def _check_range(name: str, value, lo: float, hi: float) -> tuple[float, float]:
    """A pair ``(a, b)`` with ``lo <= a <= b <= hi``."""
    try:
        a, b = value
        a = _check_number(name, a, lo, hi)
        b = _check_number(name, b, lo, hi)
    except (TypeError, ValueError):
        a, b = 1.0, 0.0
    if a > b:
        raise ValueError(
            f"{name} must be a pair (low, high) with {lo} <= low <= high <= {hi}, got {value!r}"
        )
    return a, b


def _check_rgb(name: str, value) -> np.ndarray:
    try:
        c = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        c = np.full(1, np.nan)
    if c.shape != (3,) or not np.all(np.isfinite(c)) or c.min() < 0 or c.max() > 1:
        raise ValueError(f"{name} must be an RGB triple in [0, 1], got {value!r}")
    return c.astype(np.float32)


def _check_names(name: str, value, known: dict | tuple) -> tuple[str, ...]:
    names = (value,) if isinstance(value, str) else tuple(value)
    if not names or any(n not in known for n in names):
        raise ValueError(f"{name} must be a non-empty choice of {list(known)}, got {value!r}")
    return names


def _uniform(rng: np.random.Generator, pair: tuple[float, float]) -> float:
    return float(rng.uniform(pair[0], pair[1]))


def _bands(h: int, w: int):
    """Row ranges ``(r0, r1)`` covering ``h`` rows, each of at most _BAND_PIXELS pixels."""
    rows = max(1, _BAND_PIXELS // max(w, 1))
    for r0 in range(0, h, rows):
        yield r0, min(h, r0 + rows)


# ---------------------------------------------------------------------------------------
# Paper


@dataclass(frozen=True)
class PaperOptions:
    """Ranges that :func:`random_paper` draws from (each uniformly unless said otherwise).

    Sizes ``*_rel`` are fractions of what the name says; probabilities are in [0, 1].

    Parameters
    ----------
    kinds : tuple of str
        Kinds drawn when ``kind`` is None (equally often); default all of :data:`KINDS`.
    tints : tuple of str
        Paper tints (keys of :data:`TINTS`) drawn equally often; each channel then moves
        by up to ``tint_jitter`` (default 0.02).
    spacing_rel : (low, high)
        Line spacing (the period of rules, squares and dots) as a fraction of the image's
        short side; default (0.06, 0.3). On plain paper it sets the bleed-through's size.
    spacing_px : (low, high) or None
        Line spacing in pixels, in [2, 4000]; when given it replaces ``spacing_rel``.
    angle_deg : (low, high)
        Rotation of the whole pattern, degrees in [-45, 45]; default (-3, 3).
    wave_rel : (low, high)
        Amplitude of the pattern's waviness (a bent sheet) as a fraction of the short
        side, in [0, 0.05]; default (0, 0.004). Its wavelength is 0.5-2 image sides.
    line_colours : tuple of str
        Colours of the pattern (keys of :data:`LINE_COLOURS`); default all.
    line_strength : (low, high)
        How far a line's colour goes from the paper towards its full colour, in [0, 1]:
        light to fairly dark; default (0.25, 0.9).
    line_width_rel : (low, high)
        Line width as a fraction of the spacing, in [0, 0.5]; default (0.015, 0.05); at
        least 0.7 px.
    dot_radius_rel : (low, high)
        Radius of the dots of dotted paper as a fraction of the spacing, in [0, 0.4];
        default (0.03, 0.08); at least 0.7 px.
    softness_px : (low, high)
        Width of the printed edges (focus), pixels in [0.3, 10]; default (0.8, 1.8).
    margin_probability : float
        Chance of a red margin line on ruled and squared paper; default 0.35.
    exposure : (low, high)
        Overall brightness factor, in [0.1, 2]; default (0.8, 1.05).
    colour_cast : float
        Largest white-balance error per channel (warm or cool light), in [0, 0.3];
        default 0.04.
    gradient : (low, high)
        Brightness change of a linear light gradient across half the diagonal, in [0, 1];
        default (0, 0.25).
    vignette : (low, high)
        Darkening at the corners, in [0, 1]; default (0, 0.3).
    shadow_probability : float
        Chance of a soft shadow (a half-plane with a soft edge, or a blob); default 0.4.
    shadow_depth : (low, high)
        How much the shadow darkens, in [0, 1]; default (0.1, 0.45).
    shadow_softness_rel : (low, high)
        Width of the shadow's edge as a fraction of the half-diagonal, in [0.005, 2];
        default (0.03, 0.25).
    bleed_probability : float
        Chance of printed text showing through from the back (mirrored, blurred, grey);
        default 0.2.
    bleed_strength : (low, high)
        Darkness of that text, in [0, 1]; default (0.04, 0.14).
    bleed_x_height_rel : (low, high)
        Its x-height as a fraction of the spacing, in [0.02, 2]; default (0.15, 0.35).
    edge_probability : float
        Chance that the sheet's edge shows, with a table beyond it; default 0.2.
    edge_two_sides_probability : float
        Chance, given an edge, that it shows on two sides; default 0.35.
    edge_depth_rel : (low, high)
        How far the edge reaches in from the image's border, as a fraction of the image's
        side across it, in [0, 0.45]; default (0.01, 0.1). The generator keeps characters
        out of this band.
    """

    kinds: tuple[str, ...] = KINDS
    tints: tuple[str, ...] = tuple(TINTS)
    tint_jitter: float = 0.02
    spacing_rel: tuple[float, float] = (0.06, 0.3)
    spacing_px: tuple[float, float] | None = None
    angle_deg: tuple[float, float] = (-3.0, 3.0)
    wave_rel: tuple[float, float] = (0.0, 0.004)
    line_colours: tuple[str, ...] = tuple(LINE_COLOURS)
    line_strength: tuple[float, float] = (0.25, 0.9)
    line_width_rel: tuple[float, float] = (0.015, 0.05)
    dot_radius_rel: tuple[float, float] = (0.03, 0.08)
    softness_px: tuple[float, float] = (0.8, 1.8)
    margin_probability: float = 0.35
    exposure: tuple[float, float] = (0.8, 1.05)
    colour_cast: float = 0.04
    gradient: tuple[float, float] = (0.0, 0.25)
    vignette: tuple[float, float] = (0.0, 0.3)
    shadow_probability: float = 0.4
    shadow_depth: tuple[float, float] = (0.1, 0.45)
    shadow_softness_rel: tuple[float, float] = (0.03, 0.25)
    bleed_probability: float = 0.2
    bleed_strength: tuple[float, float] = (0.04, 0.14)
    bleed_x_height_rel: tuple[float, float] = (0.15, 0.35)
    edge_probability: float = 0.2
    edge_two_sides_probability: float = 0.35
    edge_depth_rel: tuple[float, float] = (0.01, 0.1)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "kinds", _check_names("kinds", self.kinds, KINDS))
        set_(self, "tints", _check_names("tints", self.tints, TINTS))
        set_(self, "line_colours", _check_names("line_colours", self.line_colours, LINE_COLOURS))
        if self.spacing_px is not None:
            set_(self, "spacing_px", _check_range("spacing_px", self.spacing_px, 2.0, 4000.0))
        ranges = {
            "spacing_rel": (0.005, 1.0),
            "angle_deg": (-45.0, 45.0),
            "wave_rel": (0.0, 0.05),
            "line_strength": (0.0, 1.0),
            "line_width_rel": (0.0, 0.5),
            "dot_radius_rel": (0.0, 0.4),
            "softness_px": (0.3, 10.0),
            "exposure": (0.1, 2.0),
            "gradient": (0.0, 1.0),
            "vignette": (0.0, 1.0),
            "shadow_depth": (0.0, 1.0),
            "shadow_softness_rel": (0.005, 2.0),
            "bleed_strength": (0.0, 1.0),
            "bleed_x_height_rel": (0.02, 2.0),
            "edge_depth_rel": (0.0, 0.45),
        }
        for name, (lo, hi) in ranges.items():
            set_(self, name, _check_range(name, getattr(self, name), lo, hi))
        numbers = {
            "tint_jitter": 0.1,
            "colour_cast": 0.3,
            "margin_probability": 1.0,
            "shadow_probability": 1.0,
            "bleed_probability": 1.0,
            "edge_probability": 1.0,
            "edge_two_sides_probability": 1.0,
        }
        for name, hi in numbers.items():
            set_(self, name, _check_number(name, getattr(self, name), 0.0, hi))


@dataclass
class Paper:
    """A generated sheet as a camera sees it.

    Attributes
    ----------
    rgb : float32 [H, W, 3]
        Colour in [0, 1].
    kind : str
        One of :data:`KINDS`.
    meta : dict
        What was drawn: ``tint`` and ``tint_rgb``, ``spacing_px`` (the pattern's period;
        on plain paper only the bleed-through's scale), ``angle_deg``, ``offset_px``
        (where the pattern's rules sit, see :func:`pattern_phase`), ``wave`` (the
        waviness: ``amplitude_px``, ``wavelength_px``, ``phase_x``, ``phase_y``),
        ``line_colour``, ``line_rgb``, ``line_width_px`` (ruled and squared, else None),
        ``dot_radius_px`` (dotted, else None), ``margin`` (bool), ``shadow`` (None,
        ``"half-plane"`` or ``"blob"``), ``bleed`` (bool), ``edge`` (the sides where the
        table shows: a list of ``"top"``, ``"bottom"``, ``"left"``, ``"right"``),
        ``table`` and ``table_rgb`` (None without an edge) and ``sheet_mask`` (bool
        [H, W], True where paper is visible).
    """

    rgb: np.ndarray
    kind: str
    meta: dict = field(default_factory=dict)


@dataclass
class _PaperPlan:
    # Everything random_paper drew, before any pixel is painted.
    size_hw: tuple[int, int]
    kind: str
    tint: np.ndarray  # [3]
    spacing: float
    angle_rad: float
    offset: tuple[float, float]  # (u, v) of a grid line
    wave: tuple[float, float, float, float]  # amplitude, wavelength, phase in x; phase in y
    line_rgb: np.ndarray  # [3]
    line_width: float
    dot_radius: float
    softness: float
    margin_u: float | None  # u of the margin line
    light: dict
    edges: list  # [(nx, ny, c)]: signed distance nx x + ny y + c, > 0 on paper
    table_rgb: np.ndarray  # [3]
    bleed: dict | None
    names: dict  # tint, line_colour, table, edge (the sides)


def random_paper(rng, size_hw, kind: str | None = None, *, options: PaperOptions | None = None):
    """A photo-like sheet of paper (see the module docstring for the model).

    Parameters
    ----------
    rng : numpy.random.Generator
        The only source of randomness: the same state gives the same sheet.
    size_hw : (H, W)
        Integers in [8, 8192] with H * W <= 24,000,000.
    kind : {"plain", "ruled", "squared", "dotted"} or None
        None draws one of ``options.kinds``.
    options : PaperOptions
        The ranges everything is drawn from; default ``PaperOptions()``.

    Returns
    -------
    Paper
        ``rgb`` float32 [H, W, 3] in [0, 1], ``kind``, and ``meta`` (what was drawn).
    """
    _check_rng(rng)
    h, w = _check_size("size_hw", size_hw)
    options = _check_options("options", options, PaperOptions)
    if kind is not None and kind not in KINDS:
        raise ValueError(f"kind must be one of {list(KINDS)} or None, got {kind!r}")
    kind = kind or options.kinds[int(rng.integers(len(options.kinds)))]
    plan = _draw_paper_plan(rng, (h, w), kind, options)
    fields = _draw_fields(rng, plan)
    printed = _prepare_print(plan)
    rgb = np.empty((h, w, 3), np.float32)
    mask = np.ones((h, w), bool)
    for r0, r1 in _bands(h, w):
        _paint_band(plan, fields, printed, r0, r1, rgb[r0:r1], mask[r0:r1])
    return Paper(rgb=rgb, kind=kind, meta=dict(_paper_meta(plan), sheet_mask=mask))


def _check_options(name: str, options, cls):
    if options is None:
        return cls()
    if not isinstance(options, cls):
        raise ValueError(f"{name} must be a {cls.__name__} or None, got {type(options).__name__}")
    return options


def _draw_paper_plan(rng, size_hw, kind: str, o: PaperOptions) -> _PaperPlan:
    h, w = size_hw
    short = min(h, w)
    tint_name = o.tints[int(rng.integers(len(o.tints)))]
    tint = np.asarray(TINTS[tint_name]) + rng.uniform(-o.tint_jitter, o.tint_jitter, 3)
    spacing = _uniform(rng, o.spacing_px) if o.spacing_px else _uniform(rng, o.spacing_rel) * short
    angle = _uniform(rng, o.angle_deg)
    wave = (
        _uniform(rng, o.wave_rel) * short,
        float(rng.uniform(0.5, 2.0)) * max(h, w),
        float(rng.uniform(0, 2 * math.pi)),
        float(rng.uniform(0, 2 * math.pi)),
    )
    colour_name = o.line_colours[int(rng.integers(len(o.line_colours)))]
    line_rgb = _towards(LINE_COLOURS[colour_name], _uniform(rng, o.line_strength))
    line_width = max(_MIN_PRINT_WIDTH_PX, _uniform(rng, o.line_width_rel) * spacing)
    dot_radius = max(_MIN_PRINT_WIDTH_PX, _uniform(rng, o.dot_radius_rel) * spacing)
    offset = (float(rng.uniform(0, spacing)), float(rng.uniform(0, spacing)))
    margin = kind in ("ruled", "squared") and rng.random() < o.margin_probability
    margin_u = float(rng.uniform(0.06, 0.25) * w - w / 2) if margin else None
    cast = 1.0 + rng.uniform(-o.colour_cast, o.colour_cast, 3)
    light = _draw_light(rng, o)
    edges, sides = _draw_edges(rng, size_hw, o)
    table_name = list(TABLE_COLOURS)[int(rng.integers(len(TABLE_COLOURS)))]
    table = np.asarray(TABLE_COLOURS[table_name]) * rng.uniform(0.8, 1.2)
    bleed = _draw_bleed(rng, spacing, o) if rng.random() < o.bleed_probability else None
    return _PaperPlan(
        size_hw=size_hw,
        kind=kind,
        tint=np.clip(tint * cast, 0, 1).astype(np.float32),
        spacing=spacing,
        angle_rad=math.radians(angle),
        offset=offset,
        wave=wave,
        line_rgb=line_rgb,
        line_width=line_width,
        dot_radius=dot_radius,
        softness=_uniform(rng, o.softness_px),
        margin_u=margin_u,
        light=light,
        edges=edges,
        table_rgb=np.clip(table * cast, 0, 1).astype(np.float32),
        bleed=bleed,
        names={"tint": tint_name, "line_colour": colour_name, "table": table_name, "edge": sides},
    )


def _paper_meta(plan: _PaperPlan) -> dict:
    """What :attr:`Paper.meta` reports of a plan (the sheet mask is added when painted)."""
    names, kind, sides = plan.names, plan.kind, plan.names["edge"]
    wave_keys = ("amplitude_px", "wavelength_px", "phase_x", "phase_y")
    return {
        "tint": names["tint"],
        "tint_rgb": plan.tint.tolist(),
        "spacing_px": plan.spacing,
        "angle_deg": math.degrees(plan.angle_rad),
        "offset_px": plan.offset,
        "wave": dict(zip(wave_keys, plan.wave, strict=True)),
        "line_colour": names["line_colour"],
        "line_rgb": plan.line_rgb.tolist(),
        "line_width_px": plan.line_width if kind in ("ruled", "squared") else None,
        "dot_radius_px": plan.dot_radius if kind == "dotted" else None,
        "margin": plan.margin_u is not None,
        "shadow": plan.light["shadow"],
        "bleed": plan.bleed is not None,
        "edge": sides,
        "table": names["table"] if sides else None,
        "table_rgb": plan.table_rgb.tolist() if sides else None,
    }


def _towards(colour, strength: float) -> np.ndarray:
    # A printed colour mixed with white: at strength 0 it vanishes, at 1 it is full.
    return (1.0 - strength * (1.0 - np.asarray(colour))).astype(np.float32)


def _draw_light(rng, o: PaperOptions) -> dict:
    light = {
        "exposure": _uniform(rng, o.exposure),
        "gradient": _uniform(rng, o.gradient),
        "gradient_dir": float(rng.uniform(0, 2 * math.pi)),
        "vignette": _uniform(rng, o.vignette),
        "shadow": None,
    }
    if rng.random() < o.shadow_probability:
        light["shadow"] = "half-plane" if rng.random() < 0.6 else "blob"
        light["depth"] = _uniform(rng, o.shadow_depth)
        light["softness"] = _uniform(rng, o.shadow_softness_rel)
        light["dir"] = float(rng.uniform(0, 2 * math.pi))
        # Where the shadow's edge (or the blob's centre) lies, in half-diagonals.
        light["at"] = (float(rng.uniform(-0.6, 0.6)), float(rng.uniform(-0.6, 0.6)))
        light["radii"] = (float(rng.uniform(0.15, 0.5)), float(rng.uniform(0.15, 0.5)))
    return light


_SIDES = ("top", "bottom", "left", "right")
_OPPOSITE = {"top": "bottom", "bottom": "top", "left": "right", "right": "left"}


def _draw_edges(rng, size_hw, o: PaperOptions) -> tuple[list, list[str]]:
    """Lines of the sheet's edge as ``(nx, ny, c)`` (signed distance, > 0 on paper)."""
    if rng.random() >= o.edge_probability:
        return [], []
    first = _SIDES[int(rng.integers(4))]
    sides = [first]
    if rng.random() < o.edge_two_sides_probability:
        others = [s for s in _SIDES if s != first and s != _OPPOSITE[first]]
        sides.append(others[int(rng.integers(2))])
    h, w = size_hw
    edges = []
    for side in sides:
        across = w if side in ("left", "right") else h
        d0, d1 = (_uniform(rng, o.edge_depth_rel) * across for _ in range(2))
        # Two points of the edge, d0 and d1 in from the border at either end of the side.
        p0, p1 = {
            "left": ((d0, 0.0), (d1, h - 1.0)),
            "right": ((w - 1.0 - d0, 0.0), (w - 1.0 - d1, h - 1.0)),
            "top": ((0.0, d0), (w - 1.0, d1)),
            "bottom": ((0.0, h - 1.0 - d0), (w - 1.0, h - 1.0 - d1)),
        }[side]
        tx, ty = p1[0] - p0[0], p1[1] - p0[1]
        norm = math.hypot(tx, ty)
        nx, ny = -ty / norm, tx / norm
        if nx * (w / 2 - p0[0]) + ny * (h / 2 - p0[1]) < 0:  # point the normal inwards
            nx, ny = -nx, -ny
        edges.append((nx, ny, -(nx * p0[0] + ny * p0[1])))
    return edges, sides


def _draw_bleed(rng, spacing: float, o: PaperOptions) -> dict:
    return {
        "strength": _uniform(rng, o.bleed_strength),
        "x_height": max(2.0, _uniform(rng, o.bleed_x_height_rel) * spacing),
        "pitch": float(rng.uniform(2.2, 3.2)),  # row pitch in x-heights
        "angle_deg": float(rng.uniform(-2.0, 2.0)),
        "blur": float(rng.uniform(0.08, 0.25)),  # the paper's blur, in x-heights
    }


# --- smooth fields on coarse grids ----------------------------------------------------


@dataclass
class _Field:
    # A smooth field sampled on a coarse grid, interpolated band by band.
    image: Image.Image  # mode "F"
    grid_hw: tuple[int, int]


def _grid(size_hw, cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates ``y [h_lo]``, ``x [w_lo]`` of a coarse grid whose cells map onto
    the image the way PIL's bilinear resize maps them (cell k centred at
    ``(k + 0.5) * H / h_lo - 0.5``)."""
    h, w = size_hw
    step = max(1.0, min(h, w) / cells)
    hl, wl = max(2, math.ceil(h / step)), max(2, math.ceil(w / step))
    y = (np.arange(hl) + 0.5) * (h / hl) - 0.5
    x = (np.arange(wl) + 0.5) * (w / wl) - 0.5
    return y, x


def _field(values: np.ndarray) -> _Field:
    v = np.ascontiguousarray(values, dtype=np.float32)
    return _Field(Image.fromarray(v), v.shape)


def _field_rows(f: _Field, size_hw, r0: int, r1: int) -> np.ndarray:
    """The field at full resolution on rows ``r0:r1``: float32 [r1 - r0, W]."""
    return _field_rect(f, size_hw, (r0, r1), (0, size_hw[1]))


def _field_rect(f: _Field, size_hw, rows: tuple[int, int], cols: tuple[int, int]):
    """The field at full resolution on a rectangle of pixels: float32 [rows, cols]."""
    h, w = size_hw
    hl, wl = f.grid_hw
    box = (cols[0] * wl / w, rows[0] * hl / h, cols[1] * wl / w, rows[1] * hl / h)
    size = (cols[1] - cols[0], rows[1] - rows[0])
    return np.asarray(f.image.resize(size, Image.Resampling.BILINEAR, box=box))


def _draw_fields(rng, plan: _PaperPlan) -> dict[str, _Field]:
    fields = {"light": _light_field(plan)}
    if plan.edges:
        fields["table"] = _table_field(rng, plan)
    if plan.bleed is not None:
        fields["bleed"] = _bleed_field(rng, plan)
    return fields


def _light_field(plan: _PaperPlan) -> _Field:
    """Exposure x gradient x vignette x shadow on the coarse grid."""
    h, w = plan.size_hw
    y, x = _grid(plan.size_hw, _LIGHT_CELLS)
    half_diag = 0.5 * math.hypot(h, w)
    gx = ((x - (w - 1) / 2) / half_diag)[None, :]  # [1, w_lo]
    gy = ((y - (h - 1) / 2) / half_diag)[:, None]  # [h_lo, 1]
    p = plan.light
    a = p["gradient_dir"]
    light = p["exposure"] * (1.0 + p["gradient"] * (gx * math.cos(a) + gy * math.sin(a)))
    light = light * (1.0 - p["vignette"] * (gx**2 + gy**2))
    if p["shadow"] == "half-plane":
        b = p["dir"]
        s = (gx * math.cos(b) + gy * math.sin(b) - p["at"][0]) / p["softness"]
        light = light * (1.0 - p["depth"] * 0.5 * (1.0 + np.tanh(s)))
    elif p["shadow"] == "blob":
        b = p["dir"]
        dx, dy = gx - p["at"][0], gy - p["at"][1]
        u = (dx * math.cos(b) + dy * math.sin(b)) / p["radii"][0]
        v = (-dx * math.sin(b) + dy * math.cos(b)) / p["radii"][1]
        light = light * (1.0 - p["depth"] * np.exp(-0.5 * (u**2 + v**2)))
    return _field(np.broadcast_to(light, (y.size, x.size)))


def _table_field(rng, plan: _PaperPlan) -> _Field:
    """The table's brightness: wood-like grain, slow variation, the sheet's cast shadow."""
    y, x = _grid(plan.size_hw, _TABLE_CELLS)
    shape = (y.size, x.size)
    grain_sigma = (0.7, 8.0) if rng.random() < 0.5 else (8.0, 0.7)  # grain along x or y
    grain = ndimage.gaussian_filter(rng.standard_normal(shape), grain_sigma)
    coarse = ndimage.gaussian_filter(rng.standard_normal((12, 12)), 1.5)
    slow = np.asarray(_field(coarse).image.resize(shape[::-1], Image.Resampling.BILINEAR))
    texture = 1.0 + rng.uniform(0.06, 0.2) * grain / max(grain.std(), 1e-9)
    texture += rng.uniform(0.03, 0.1) * slow / max(slow.std(), 1e-9)
    length = rng.uniform(0.005, 0.03) * min(plan.size_hw)
    depth = rng.uniform(0.2, 0.6)
    for nx, ny, c in plan.edges:
        s = nx * x[None, :] + ny * y[:, None] + c  # < 0 on the table
        texture *= 1.0 - depth * np.exp(np.minimum(s, 0.0) / length)
    return _field(np.clip(texture, 0.2, 1.5))


def _bleed_field(rng, plan: _PaperPlan) -> _Field:
    """Text printed on the back: rows of random words in PIL's default font, mirrored,
    blurred by the paper, slightly turned; drawn at a resolution where the x-height is
    _BLEED_CELLS_PER_X_HEIGHT cells (the blur hides anything finer)."""
    h, w = plan.size_hw
    b = plan.bleed
    scale = max(1.0, b["x_height"] / _BLEED_CELLS_PER_X_HEIGHT)  # pixels per cell
    hl, wl = max(2, math.ceil(h / scale)), max(2, math.ceil(w / scale))
    xh = b["x_height"] * hl / h  # x-height in cells
    font = ImageFont.load_default(size=max(4, round(_FONT_SIZE_PER_X_HEIGHT * xh)))
    # Without FreeType PIL falls back to a bitmap font, which knows no anchors.
    anchor = "ls" if isinstance(font, ImageFont.FreeTypeFont) else None
    advance = max(font.getlength("etaoin shrdlu") / 13, 1.0)  # mean width of a character
    canvas = Image.new("L", (wl, hl), 0)
    draw = ImageDraw.Draw(canvas)
    left, right = rng.uniform(0.0, 0.15, 2) * wl
    top = rng.uniform(0.0, 0.1) * hl + 1.5 * xh
    for base in np.arange(top, hl - rng.uniform(0.0, 0.1) * hl, b["pitch"] * xh):
        if rng.random() < 0.12:  # a paragraph break
            continue
        end = wl - right if rng.random() < 0.8 else rng.uniform(left, wl - right)
        text = _random_words(rng, int((end - left) / advance) + 1)
        draw.text((float(left), float(base)), text, fill=255, font=font, anchor=anchor)
    canvas = canvas.filter(ImageFilter.GaussianBlur(b["blur"] * xh))
    canvas = canvas.rotate(b["angle_deg"], Image.Resampling.BILINEAR)
    marks = np.asarray(canvas, dtype=np.float32)[:, ::-1] * (b["strength"] / 255.0)
    return _field(marks)


# PIL's default font (Aileron) has an x-height of about half its size.
_FONT_SIZE_PER_X_HEIGHT = 2.0
_LETTERS = np.array(list("etaoinshrdlucmfwypvbgkqjxz"))
_LETTER_WEIGHTS = np.array(
    [12.7, 9.1, 8.2, 7.5, 7.0, 6.7, 6.3, 6.1, 6.0, 4.3, 4.0, 2.8, 2.8, 2.4, 2.2, 2.4, 2.0,
     1.9, 1.0, 1.5, 2.0, 0.8, 0.1, 0.2, 0.2, 0.1]
)  # fmt: skip


def _random_words(rng, n_chars: int) -> str:
    """About ``n_chars`` characters of random lower-case words (English letter counts)."""
    letters = rng.choice(_LETTERS, n_chars, p=_LETTER_WEIGHTS / _LETTER_WEIGHTS.sum())
    spaces = rng.random(n_chars) < 0.17
    return "".join(np.where(spaces, " ", letters))


# --- the printed pattern, as the camera sees it ---------------------------------------


def _sheet_coords(x, y, size_hw, angle_rad: float, wave) -> tuple[np.ndarray, np.ndarray]:
    """Sheet-frame coordinates ``u`` (along the rules) and ``v`` (across them) of image
    points ``(x, y)``: the pattern turned by ``angle_rad`` about the image's centre and
    bent by ``wave = (amplitude, wavelength, phase_x, phase_y)``.

    Each is a sum of a function of x and a function of y (the bend of a rule depends on
    x alone), which :class:`_Axis` exploits."""
    h, w = size_hw
    dx = np.asarray(x, np.float64) - (w - 1) / 2
    dy = np.asarray(y, np.float64) - (h - 1) / 2
    ca, sa = math.cos(angle_rad), math.sin(angle_rad)
    amp, length, phase_x, phase_y = wave
    k = 2 * math.pi / length
    u = dx * ca + (dy * sa + amp * np.sin(k * dy + phase_y))
    v = (dy * ca) + (amp * np.sin(k * dx + phase_x) - dx * sa)
    return u, v


@dataclass
class _Axis:
    """One sheet coordinate on the pixel grid, quantised to 1 / _SUBPIXEL px: pixel
    ``[i, j]`` has index ``rows[i] + cols[j]`` and coordinate ``origin + index /
    _SUBPIXEL``, so a printed profile becomes a 1-D look-up table read with one add."""

    rows: np.ndarray  # int32 [H]
    cols: np.ndarray  # int32 [W]
    origin: float

    @property
    def size(self) -> int:
        return int(self.rows.max() + self.cols.max()) + 1

    def coords(self) -> np.ndarray:
        return self.origin + np.arange(self.size) / _SUBPIXEL  # [size]

    def index(self, r0: int, r1: int, cols=slice(None)) -> np.ndarray:
        return self.rows[r0:r1, None] + self.cols[None, cols]  # [rows, cols]


# Steps per pixel of the pattern's look-up tables (positions are exact to 1/16 px).
_SUBPIXEL = 8


def _axes(plan: _PaperPlan) -> tuple[_Axis, _Axis]:
    """The sheet coordinates u and v of every pixel, as :class:`_Axis` tables."""
    h, w = plan.size_hw
    cx, cy = np.array([(w - 1) / 2]), np.array([(h - 1) / 2])

    def coords(x, y):
        return _sheet_coords(x, y, plan.size_hw, plan.angle_rad, plan.wave)

    # u(x, y) = u(cx, y) + (u(x, cy) - u(cx, cy)), exactly; the same for v.
    on_y = coords(cx, np.arange(h, dtype=np.float64))
    on_x = coords(np.arange(w, dtype=np.float64), cy)
    centre = coords(cx, cy)
    axes = []
    for which in (0, 1):  # u, v
        rows = np.round(on_y[which] * _SUBPIXEL).astype(np.int64)
        cols = np.round((on_x[which] - centre[which]) * _SUBPIXEL).astype(np.int64)
        origin = (rows.min() + cols.min()) / _SUBPIXEL
        rows, cols = (rows - rows.min()).astype(np.int32), (cols - cols.min()).astype(np.int32)
        axes.append(_Axis(rows, cols, float(origin)))
    return axes[0], axes[1]


def _distance_to_rules(c: np.ndarray, period: float, offset: float) -> np.ndarray:
    """``|c - nearest (offset + k period)|``."""
    return np.abs(np.remainder(c - (offset + period / 2), period) - period / 2)


def _coverage(distance: np.ndarray, half_width: float, softness: float) -> np.ndarray:
    # 1 inside the printed shape, 0 outside, a ramp `softness` px wide across its edge.
    return np.clip(0.5 + (half_width - distance) / softness, 0.0, 1.0)


def _to_u8(cover: np.ndarray) -> np.ndarray:
    return (cover * 255.0 + 0.5).astype(np.uint8)


@dataclass
class _Print:
    """The printed pattern of a sheet, ready to be read band by band."""

    u: _Axis
    v: _Axis
    rules_u: np.ndarray | None  # uint8 [u.size] coverage of the columns' lines (squared)
    rules_v: np.ndarray | None  # uint8 [v.size] coverage of the rules (ruled, squared)
    dots: tuple | None  # (distance index along u [u.size], along v [v.size], table [n, n])
    margin: np.ndarray | None  # float32 [u.size] coverage of the red margin line
    rgb: np.ndarray  # float32 [256, 3]: the sheet's colour at each coverage level


def _prepare_print(plan: _PaperPlan) -> _Print | None:
    if plan.kind == "plain":
        return None
    u, v = _axes(plan)
    s, (off_u, off_v), soft = plan.spacing, plan.offset, plan.softness
    half = plan.line_width / 2
    rules_u = rules_v = dots = margin = None
    if plan.kind in ("ruled", "squared"):
        rules_v = _to_u8(_coverage(_distance_to_rules(v.coords(), s, off_v), half, soft))
    if plan.kind == "squared":
        rules_u = _to_u8(_coverage(_distance_to_rules(u.coords(), s, off_u), half, soft))
    if plan.kind == "dotted":
        dots = _dot_tables(plan, u, v)
    if plan.margin_u is not None:
        d = np.abs(u.coords() - plan.margin_u)
        margin = _coverage(d, 0.75 * plan.line_width, soft).astype(np.float32)
    levels = (np.arange(256) / 255.0)[:, None]
    rgb = (plan.tint * (1.0 - levels * (1.0 - plan.line_rgb))).astype(np.float32)
    return _Print(u, v, rules_u, rules_v, dots, margin, rgb)


def _dot_tables(plan: _PaperPlan, u: _Axis, v: _Axis) -> tuple:
    # A dot's coverage depends on the distances to the nearest dot column and row; both
    # are quantised and capped just beyond the dot, so a small 2-D table holds it.
    s, (off_u, off_v) = plan.spacing, plan.offset
    cap = math.ceil((plan.dot_radius + plan.softness) * _SUBPIXEL) + 1
    du = np.minimum(np.round(_distance_to_rules(u.coords(), s, off_u) * _SUBPIXEL), cap)
    dv = np.minimum(np.round(_distance_to_rules(v.coords(), s, off_v) * _SUBPIXEL), cap)
    steps = np.arange(cap + 1) / _SUBPIXEL
    table = _to_u8(
        _coverage(np.hypot(steps[:, None], steps[None, :]), plan.dot_radius, plan.softness)
    )
    return du.astype(np.int32) * (cap + 1), dv.astype(np.int32), table.ravel()


def _pattern_rows(p: _Print, r0: int, r1: int) -> np.ndarray:
    """Coverage of the printed rules, grid or dots on rows ``r0:r1``: uint8 [rows, W]."""
    if p.dots is not None:
        du, dv, table = p.dots
        cell = du[p.u.index(r0, r1)]
        cell += dv[p.v.index(r0, r1)]
        return table[cell]
    cover = p.rules_v[p.v.index(r0, r1)]
    if p.rules_u is not None:
        np.maximum(cover, p.rules_u[p.u.index(r0, r1)], out=cover)
    return cover


def _paint_margin(plan: _PaperPlan, p: _Print, r0: int, r1: int, out) -> None:
    # The margin line is nearly vertical: only the columns it can reach in these rows.
    reach = p.margin > 0
    lo, hi = np.flatnonzero(reach)[[0, -1]] if reach.any() else (0, -1)
    need = (lo - p.u.rows[r0:r1].max(), hi - p.u.rows[r0:r1].min())
    cols = np.flatnonzero((p.u.cols >= need[0]) & (p.u.cols <= need[1]))
    if cols.size == 0:
        return
    j0, j1 = cols[0], cols[-1] + 1
    red = _towards(MARGIN_COLOUR, 0.5 + 0.5 * float(plan.line_rgb.min()))
    _absorb(out[:, j0:j1], p.margin[p.u.index(r0, r1, slice(j0, j1))], red)


# --- lighting, bleed-through and the table, band by band -------------------------------


def _absorb(rgb: np.ndarray, cover: np.ndarray, colour, strength=1.0) -> None:
    # In place: rgb *= 1 - strength * cover * (1 - colour)  (a layer that absorbs light).
    k = (np.float32(-strength) * (1.0 - np.asarray(colour, np.float32))).astype(np.float32)
    factor = cover[..., None] * k
    factor += np.float32(1.0)
    rgb *= factor


def _paint_band(plan: _PaperPlan, fields: dict, printed, r0: int, r1: int, out, mask) -> None:
    if printed is None:
        out[:] = plan.tint
    else:
        np.take(printed.rgb, _pattern_rows(printed, r0, r1), axis=0, out=out)
        if printed.margin is not None:
            _paint_margin(plan, printed, r0, r1, out)
    light = _field_rows(fields["light"], plan.size_hw, r0, r1)  # [rows, W]
    if "bleed" in fields:
        # Grey marks: their absorption is the same in every channel, so it joins the light.
        out *= (light * (1.0 - _field_rows(fields["bleed"], plan.size_hw, r0, r1)))[..., None]
    else:
        out *= light[..., None]
    if plan.edges:  # the table beyond the edge, lit by the same light (no bleed-through)
        _paint_table(plan, fields["table"], light, r0, r1, out, mask)
    np.minimum(out, np.float32(1.0), out=out)


def _paint_table(plan: _PaperPlan, table: _Field, light, r0: int, r1: int, out, mask) -> None:
    """Beyond the sheet's edge the table; one pixel of anti-aliasing across the edge."""
    w = plan.size_hw[1]
    y = np.arange(r0, r1, dtype=np.float32)[:, None]
    x = np.arange(w, dtype=np.float32)[None, :]
    inside = None
    for nx, ny, c in plan.edges:
        s = np.float32(nx) * x + (np.float32(ny) * y + np.float32(c))
        inside = s if inside is None else np.minimum(inside, s, out=inside)
    mask[:] = inside > 0
    # Only the rectangle where the table shows through is mixed (a strip along a side).
    rows = np.flatnonzero((inside < 0.5).any(axis=1))
    cols = np.flatnonzero((inside < 0.5).any(axis=0))
    if rows.size == 0:
        return
    i0, i1, j0, j1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    alpha = np.clip(inside[i0:i1, j0:j1] + 0.5, 0.0, 1.0)[..., None]  # [rows, cols, 1]
    shade = _field_rect(table, plan.size_hw, (r0 + i0, r0 + i1), (j0, j1))[..., None]
    sub = out[i0:i1, j0:j1]
    sub *= alpha
    sub += (1.0 - alpha) * (shade * light[i0:i1, j0:j1, None] * plan.table_rgb)


def pattern_phase(paper_meta: dict, size_hw, x, y) -> np.ndarray:
    """Where points sit relative to the rules of a sheet drawn by :func:`random_paper`.

    Parameters
    ----------
    paper_meta : dict
        ``Paper.meta``.
    size_hw : (H, W)
        The sheet's size.
    x, y : arrays of the same shape
        Points (pixels).

    Returns
    -------
    float64 array
        The signed distance in the sheet's frame from each point to the nearest rule
        (horizontal line of ruled or squared paper, row of dots), pixels, in
        ``[-spacing / 2, spacing / 2)``; 0 on a rule, > 0 below it.
    """
    wave = paper_meta["wave"]
    wave = (wave["amplitude_px"], wave["wavelength_px"], wave["phase_x"], wave["phase_y"])
    _, v = _sheet_coords(x, y, size_hw, math.radians(paper_meta["angle_deg"]), wave)
    s = paper_meta["spacing_px"]
    return np.remainder(v - paper_meta["offset_px"][1] + s / 2, s) - s / 2


# ---------------------------------------------------------------------------------------
# Ink and the camera


def random_pen_colour(rng) -> np.ndarray:
    """A pen's colour on white paper: black, blue, dark blue, red or green, slightly varied.

    Drawn with the weights of :data:`PEN_COLOURS`; each channel moves by up to 0.04.

    Returns
    -------
    float32 [3]
        RGB in [0, 1].
    """
    _check_rng(rng)
    names = list(PEN_COLOURS)
    weights = np.array([PEN_COLOURS[n][1] for n in names])
    name = names[int(rng.choice(len(names), p=weights / weights.sum()))]
    colour = np.asarray(PEN_COLOURS[name][0]) + rng.uniform(-0.04, 0.04, 3)
    return np.clip(colour, 0.0, 1.0).astype(np.float32)


def put_ink(paper_rgb, ink, colour, *, opacity: float = 1.0) -> np.ndarray:
    """Write ink onto paper: ``out = paper * (1 - opacity * ink * (1 - colour))``.

    Ink absorbs light: where ``ink = 0`` the paper is unchanged, where ``ink = 1`` (and
    ``opacity = 1``) it becomes ``paper * colour``, so a pen keeps its hue on tinted paper
    and in shadow.

    Parameters
    ----------
    paper_rgb : float array [H, W, 3]
        Paper colour in [0, 1] (e.g. ``Paper.rgb``).
    ink : float array [H, W]
        Ink coverage in [0, 1] (e.g. from :func:`img2dmp.data.render.render_paths`).
    colour : RGB triple in [0, 1]
        The pen's colour on white paper (:func:`random_pen_colour`).
    opacity : float in [0, 1]
        How much light fully inked paper absorbs; default 1.

    Returns
    -------
    float32 [H, W, 3]
        A new array; ``paper_rgb`` is left alone.
    """
    paper = np.asarray(paper_rgb)
    if paper.ndim != 3 or paper.shape[2] != 3 or not np.issubdtype(paper.dtype, np.floating):
        raise ValueError(
            f"paper_rgb must be a float array [H, W, 3], got {paper.dtype} {paper.shape}"
        )
    ink = np.asarray(ink)
    if ink.shape != paper.shape[:2] or not np.issubdtype(ink.dtype, np.floating):
        raise ValueError(
            f"ink must be a float array of shape {paper.shape[:2]}, got {ink.dtype} {ink.shape}"
        )
    colour = _check_rgb("colour", colour)
    opacity = _check_number("opacity", opacity, 0.0, 1.0)
    out = paper.astype(np.float32, copy=True)
    for r0, r1 in _bands(*ink.shape):
        band = ink[r0:r1].astype(np.float32, copy=False)
        if not np.all(np.isfinite(band)) or band.min(initial=0) < 0 or band.max(initial=0) > 1:
            raise ValueError("ink must hold finite values in [0, 1]")
        _absorb(out[r0:r1], band, colour, opacity)
    return out


def photo_finish(
    rng,
    rgb,
    *,
    jpeg_quality: int | None = None,
    blur_px: float | None = None,
    noise: float | None = None,
    sharpen: float | None = None,
) -> np.ndarray:
    """The camera's last steps: lens blur, the phone's sharpening, sensor noise, JPEG.

    Blur and sharpening make one point-spread function. Up to ``blur_px = 0.8`` it is a
    separable 3 x 3 kernel ``[c, 1 - 2c, c]`` per axis with ``c = blur_px^2 / 2 -
    sharpen / 4`` (variance ``2c``: the Gaussian's for sharpen 0; ``c < 0`` sharpens
    like an unsharp mask of radius 1 px), one pass of PIL's filter; a wider blur is PIL's
    Gaussian blur followed by the sharpening kernel (``c = -sharpen / 4``).

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws the defaults and the noise.
    rgb : float array [H, W, 3] in [0, 1] (or uint8)
        The scene (paper with ink); at most 24 MP.
    jpeg_quality : int in [1, 100], optional
        JPEG quality of the round trip (PIL, in memory); default drawn from 40-95.
    blur_px : float in [0, 20], optional
        Standard deviation of the lens blur, pixels; default 0 for a quarter of the
        photos, drawn from 0.3-0.8 for 60 % and from 0.8-1.6 for 15 %.
    noise : float in [0, 0.5], optional
        Standard deviation of the sensor noise (luminance: the same draw in all three
        channels), in units of full scale; default drawn from 0.002-0.02.
    sharpen : float in [0, 1.2], optional
        Strength of the phone's sharpening; default 0 for half of the photos, else drawn
        from 0.2-0.8.

    Returns
    -------
    uint8 [H, W, 3]
    """
    return _finish(rng, rgb, jpeg_quality, blur_px, noise, sharpen)[0]


def _finish(rng, rgb, jpeg_quality, blur_px, noise, sharpen) -> tuple[np.ndarray, dict]:
    """:func:`photo_finish`, also returning the parameters it used."""
    _check_rng(rng)
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must be an array [H, W, 3], got shape {rgb.shape}")
    _check_size("rgb's size", rgb.shape[:2])
    params = _finish_params(rng, jpeg_quality, blur_px, noise, sharpen)
    image = _point_spread(Image.fromarray(_to_uint8(rgb)), params["blur_px"], params["sharpen"])
    pixels = np.array(image)  # writable
    if params["noise"] > 0:
        _add_noise(rng, pixels, params["noise"])
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="JPEG", quality=params["jpeg_quality"])
    with Image.open(buffer) as decoded:
        return np.array(decoded.convert("RGB")), params


def _finish_params(rng, jpeg_quality, blur_px, noise, sharpen) -> dict:
    if jpeg_quality is None:
        jpeg_quality = int(rng.integers(40, 96))
    elif isinstance(jpeg_quality, bool) or not isinstance(jpeg_quality, (int, np.integer)):
        raise ValueError(f"jpeg_quality must be an integer in [1, 100], got {jpeg_quality!r}")
    if blur_px is None:  # mostly sharp photos: the wider blurs cost the most
        r = rng.random()
        blur_px = 0.0 if r < 0.25 else float(rng.uniform(*((0.3, 0.8) if r < 0.85 else (0.8, 1.6))))
    if noise is None:
        noise = float(rng.uniform(0.002, 0.02))
    if sharpen is None:
        sharpen = 0.0 if rng.random() < 0.5 else float(rng.uniform(0.2, 0.8))
    return {
        "jpeg_quality": int(_check_number("jpeg_quality", jpeg_quality, 1, 100)),
        "blur_px": _check_number("blur_px", blur_px, 0.0, 20.0),
        "noise": _check_number("noise", noise, 0.0, 0.5),
        "sharpen": _check_number("sharpen", sharpen, 0.0, 1.2),
    }


# The 3 x 3 point-spread kernel matches a Gaussian's variance up to this blur.
_KERNEL_MAX_BLUR_PX = 0.8


def _point_spread(image: Image.Image, blur_px: float, sharpen: float) -> Image.Image:
    if blur_px > _KERNEL_MAX_BLUR_PX:
        image = image.filter(ImageFilter.GaussianBlur(blur_px))
        c = -sharpen / 4
    else:
        c = blur_px**2 / 2 - sharpen / 4
    if c == 0:
        return image
    taps = np.array([c, 1.0 - 2.0 * c, c])
    return image.filter(ImageFilter.Kernel((3, 3), np.outer(taps, taps).ravel().tolist(), 1))


def _to_uint8(rgb: np.ndarray) -> np.ndarray:
    """Round to uint8, band by band (no full-size float temporaries)."""
    if rgb.dtype == np.uint8:
        return np.ascontiguousarray(rgb)
    if not np.issubdtype(rgb.dtype, np.floating):
        raise ValueError(f"rgb must be float in [0, 1] or uint8, got {rgb.dtype}")
    out = np.empty(rgb.shape, np.uint8)
    for r0, r1 in _bands(*rgb.shape[:2]):
        band = rgb[r0:r1].astype(np.float32) * np.float32(255.0)
        band += 0.5
        if not np.all(np.isfinite(band)):
            raise ValueError("rgb must hold finite values")
        np.copyto(out[r0:r1], np.clip(band, 0, 255, out=band), casting="unsafe")
    return out


# Bilinear upsampling by 2 averages four draws with weights (3/4, 1/4) x (3/4, 1/4): the
# standard deviation shrinks by (3/4)^2 + (1/4)^2 = 0.625, which is undone.
_NOISE_GAIN = 1.0 / 0.625


def _add_noise(rng, pixels: np.ndarray, sigma: float) -> None:
    """Sensor noise, in place: luminance only (the same in all three channels, since
    demosaicing and JPEG's chroma subsampling leave little independent colour noise),
    drawn on a grid of half the resolution and interpolated, as demosaicing spreads each
    sensor pixel's noise over its 2 x 2 neighbours; a quarter of the draws."""
    h, w = pixels.shape[:2]
    draws = rng.standard_normal((math.ceil(h / 2), math.ceil(w / 2)), np.float32)
    noise = _field(draws * np.float32(255.0 * sigma * _NOISE_GAIN))
    for r0, r1 in _bands(h, w):
        band = pixels[r0:r1].astype(np.float32)
        band += _field_rows(noise, (h, w), r0, r1)[..., None]
        band += 0.5
        np.copyto(pixels[r0:r1], np.clip(band, 0, 255, out=band), casting="unsafe")


# ---------------------------------------------------------------------------------------
# Pages


@dataclass(frozen=True, kw_only=True)
class CharacterSource:
    """One character to write: its pen path in its own frame, and what it is.

    Parameters
    ----------
    xy : float array [T, 2]
        Pen positions (x = column, y = row, y down) in any frame and unit, T >= 1.
    label : str
        What the character is ("7", "a").
    pen : array [T], optional
        Pen state per point, 1 down and 0 up (thresholded at 0.5); the segment from
        point i to i + 1 is written when both ends are down (docs/CONTRACTS.md). Default
        all down (one stroke). At least one point must be down.
    height : float, optional
        The character's nominal height in the source's unit: the page's character
        height maps to it. Default the larger of the pen-down points' height and width,
        so a short dash is not blown up to a full character.
    baseline : float, optional
        The source's y of the line the character sits on; default the lowest pen-down
        point.
    """

    xy: np.ndarray
    label: str
    pen: np.ndarray | None = None
    height: float | None = None
    baseline: float | None = None

    def __post_init__(self) -> None:
        xy = np.asarray(self.xy, dtype=np.float64)
        if xy.ndim != 2 or xy.shape[1] != 2 or xy.shape[0] < 1:
            raise ValueError(f"xy must have shape [T, 2] with T >= 1, got {xy.shape}")
        if not np.all(np.isfinite(xy)):
            raise ValueError("xy must hold finite numbers, got NaN or inf")
        pen = np.ones(len(xy)) if self.pen is None else np.asarray(self.pen, np.float64)
        if pen.shape != (len(xy),) or not np.all(np.isfinite(pen)):
            raise ValueError(f"pen must be {len(xy)} finite numbers, got shape {pen.shape}")
        if not np.any(pen >= 0.5):
            raise ValueError("pen must have at least one point down (>= 0.5), got none")
        if not isinstance(self.label, str):
            raise ValueError(f"label must be a str, got {self.label!r}")
        for name in ("height", "baseline"):
            v = getattr(self, name)
            if v is not None and (not np.isscalar(v) or not math.isfinite(float(v))):
                raise ValueError(f"{name} must be a finite number or None, got {v!r}")
        if self.height is not None and float(self.height) <= 0:
            raise ValueError(f"height must be > 0, got {self.height!r}")
        object.__setattr__(self, "xy", xy)
        object.__setattr__(self, "pen", (pen >= 0.5).astype(np.float64))

    def frame(self) -> tuple[float, float, float]:
        """``(x_left, y_baseline, height)`` of the character in its source frame."""
        down = self.xy[self.pen > 0]
        lo, hi = down.min(0), down.max(0)
        height = self.height if self.height is not None else float(max(hi - lo))
        baseline = self.baseline if self.baseline is not None else float(hi[1])
        return float(lo[0]), float(baseline), float(height) if height > 0 else 1.0


@dataclass(frozen=True)
class PageOptions:
    """Ranges that :func:`generate_page` draws a page's layout from (uniformly).

    Sizes ``*_rel`` are fractions of the page's character height ``h``.

    Parameters
    ----------
    n_lines : (low, high)
        Integers in [1, 100]: lines of writing (more when ``max_per_line`` requires);
        default (1, 4).
    max_per_line : int
        Most characters on one line, in [1, 1000]; default 30.
    char_height_px : (low, high)
        The page's character height h, pixels in [4, 1000]; default (30, 120). A page
        of a given size may lower it (never below the low end) to fit the writing.
    height_jitter : float
        Each character's height varies by up to this fraction of h, in [0, 0.5];
        default 0.08.
    char_angle_deg : float
        Each character leans by up to this many degrees, in [0, 30]; default 5.
    gap_rel : (low, high)
        Mean gap between the characters of a word on most pages, in [-0.5, 5]: from
        the inked edge of one character's rightmost stroke to the next one's leftmost
        (so the pen's width is added between their paths); default (0.12, 0.5).
    tight_probability : float
        Chance that a page is written tightly, with the mean gap drawn from
        ``tight_gap_rel`` (default (-0.03, 0.06): characters close together, now and
        then touching); default 0.3.
    gap_jitter_rel : float
        Each gap varies by up to this, in [0, 1]; default 0.06.
    word_length : (low, high)
        Integers in [1, 1000]: characters per word; default (1, 10).
    word_gap_rel : (low, high)
        Gap between words, in [0, 10]; default (0.7, 1.6).
    line_pitch_rel : (low, high)
        Distance between the baselines of lines, in [1.3, 20]; default (1.5, 2.4).
    line_angle_deg : float
        The writing's slope, degrees in [0, 10]: the page's in (-x, x); lines vary a
        little around it, never so much that they run into each other; default 4.
    baseline_jitter_rel : float
        Each character sits up to this far above or below the line, in [0, 0.3];
        default 0.05.
    pen_width_px : (low, high)
        The pen's width, pixels in [1, 30]; default (1.5, 6); at most
        ``pen_width_max_rel * h`` (default 0.12) so that small writing stays legible.
    opacity : (low, high)
        How much light a fully inked point absorbs, in [0.3, 1]; default (0.85, 1).
    margin_rel : (low, high)
        Blank border of the page as a fraction of its side, in [0, 0.45]; default
        (0.12, 0.22). Always wider than the paper's ``edge_depth_rel``.
    on_rules_probability : float
        Chance, on ruled and squared paper, that the writing sits on the rules (the
        spacing a whole fraction of the line pitch, the baselines on rules); default 0.7.
    spacing_rel : (low, high)
        Spacing of the rules, grid or dots, in [0.2, 5]; default (0.6, 1.4).
    """

    n_lines: tuple[int, int] = (1, 4)
    max_per_line: int = 30
    char_height_px: tuple[float, float] = (30.0, 120.0)
    height_jitter: float = 0.08
    char_angle_deg: float = 5.0
    gap_rel: tuple[float, float] = (0.12, 0.5)
    tight_probability: float = 0.3
    tight_gap_rel: tuple[float, float] = (-0.03, 0.06)
    gap_jitter_rel: float = 0.06
    word_length: tuple[int, int] = (1, 10)
    word_gap_rel: tuple[float, float] = (0.7, 1.6)
    line_pitch_rel: tuple[float, float] = (1.5, 2.4)
    line_angle_deg: float = 4.0
    baseline_jitter_rel: float = 0.05
    pen_width_px: tuple[float, float] = (1.5, 6.0)
    pen_width_max_rel: float = 0.12
    opacity: tuple[float, float] = (0.85, 1.0)
    margin_rel: tuple[float, float] = (0.12, 0.22)
    on_rules_probability: float = 0.7
    spacing_rel: tuple[float, float] = (0.6, 1.4)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name, hi in (("n_lines", 100), ("word_length", 1000)):
            v = getattr(self, name)
            a, b = _check_range(name, v, 1, hi)
            if a != int(a) or b != int(b):
                raise ValueError(f"{name} must be a pair of integers, got {v!r}")
            set_(self, name, (int(a), int(b)))
        v = self.max_per_line
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 1000:
            raise ValueError(f"max_per_line must be an integer in [1, 1000], got {v!r}")
        ranges = {
            "char_height_px": (4.0, 1000.0),
            "gap_rel": (-0.5, 5.0),
            "tight_gap_rel": (-0.5, 5.0),
            "word_gap_rel": (0.0, 10.0),
            "line_pitch_rel": (1.3, 20.0),
            "pen_width_px": (1.0, 30.0),
            "opacity": (0.3, 1.0),
            "margin_rel": (0.0, 0.45),
            "spacing_rel": (0.2, 5.0),
        }
        for name, (lo, hi) in ranges.items():
            set_(self, name, _check_range(name, getattr(self, name), lo, hi))
        numbers = {
            "height_jitter": 0.5,
            "char_angle_deg": 30.0,
            "tight_probability": 1.0,
            "gap_jitter_rel": 1.0,
            "line_angle_deg": 10.0,
            "baseline_jitter_rel": 0.3,
            "pen_width_max_rel": 1.0,
            "on_rules_probability": 1.0,
        }
        for name, hi in numbers.items():
            set_(self, name, _check_number(name, getattr(self, name), 0.0, hi))


@dataclass
class GeneratedPage:
    """A generated photo of a handwritten page, with the truth about every character.

    Characters are stored in reading order: line by line from the top, left to right.

    Attributes
    ----------
    image : uint8 [H, W, 3]
        The photo: the writing on cluttered paper, lit, blurred, noisy, JPEG.
    plain_image : uint8 [H, W, 3]
        The control: the same ink (same placement, pen and colour) on plain white
        paper, evenly lit, without noise or JPEG.
    ink : float32 [H, W]
        The true ink coverage in [0, 1] (the strongest of the characters' at a pixel).
    boxes : int64 [N, 4]
        ``[x0, y0, x1, y1]``: half-open pixel bounds (``x0 <= j < x1``, ``y0 <= i < y1``)
        of each character's own ink > 0.5.
    paths : list of float64 [T_i, 3]
        Each character's pen path ``(x, y, pen)`` in the page's pixels.
    labels : list of str
    lines : int64 [N]
        Line of each character, 0 for the top line.
    order : int64 [N]
        Place of each character in the reading order (``arange(N)``, as stored).
    words : int64 [N]
        Word of each character, counted over the page in reading order.
    pen_width_px : float
    pen_colour : float32 [3]
    kind : str
        The paper's kind.
    meta : dict
        ``paper`` (:attr:`Paper.meta`, with the sheet mask), ``finish`` (the photo's
        blur, noise, sharpening and JPEG quality), ``char_height_px``, ``gap_rel``,
        ``tight``, ``on_rules``, ``opacity``, ``line_angles_deg``.
    """

    image: np.ndarray
    plain_image: np.ndarray
    ink: np.ndarray
    boxes: np.ndarray
    paths: list[np.ndarray]
    labels: list[str]
    lines: np.ndarray
    order: np.ndarray
    words: np.ndarray
    pen_width_px: float
    pen_colour: np.ndarray
    kind: str
    meta: dict = field(default_factory=dict)


@dataclass
class _Layout:
    # The writing in units of the character height h, before it is placed on the page.
    paths: list[np.ndarray]  # [T_i, 3] (x, y, pen); line 0's baseline starts at (0, 0)
    lines: np.ndarray  # [N]
    words: np.ndarray  # [N]
    angles_deg: list[float]  # per line, the page's slope included
    pitch: float  # baseline to baseline
    spacing: float  # of the paper's pattern
    on_rules: bool
    tight: bool
    gap: float
    angle_deg: float  # the page's slope


def generate_page(
    rng,
    characters: Sequence[CharacterSource],
    *,
    kind: str | None = None,
    size_hw=None,
    options: PageOptions | None = None,
    paper_options: PaperOptions | None = None,
    pen_colour=None,
    pen_width_px: float | None = None,
) -> GeneratedPage:
    """A photo of a page with ``characters`` written on it in lines and words.

    Steps: lay the characters out in lines and words (in units of their height) ->
    choose the character height and the page's size -> draw the paper
    (:func:`random_paper`; on ruled and squared paper the writing often sits on the
    rules) -> render each character's path at page resolution
    (:func:`img2dmp.data.render.render_paths` on the character's neighbourhood only) ->
    :func:`put_ink` -> :func:`photo_finish`; and the same ink on white for the control.

    Parameters
    ----------
    rng : numpy.random.Generator
        The only source of randomness: the same state and arguments give the same page.
    characters : sequence of CharacterSource
        Written in this order (1 to 5000 of them): reading order is the given order.
    kind : {"plain", "ruled", "squared", "dotted"} or None
        The paper's kind; None draws one of ``paper_options.kinds``.
    size_hw : (H, W), optional
        The page's size (integers in [8, 8192], at most 24 MP); default sized to the
        writing and its margins (widened to at most 2 : 1). A given size lowers the
        character height if the writing would not fit, and refuses when even the lowest
        does not.
    options : PageOptions
        Layout, pen and margins; default ``PageOptions()``.
    paper_options : PaperOptions
        The paper; default ``PaperOptions()``. Its ``spacing_px`` (when None) and, when
        the writing sits on the rules, its ``angle_deg`` are set from the writing.
    pen_colour : RGB triple in [0, 1], optional
        Default :func:`random_pen_colour`.
    pen_width_px : float in [1, 30], optional
        Default drawn from ``options.pen_width_px`` (capped at
        ``options.pen_width_max_rel`` times the character height).

    Returns
    -------
    GeneratedPage
    """
    sources, options, paper_options, pen_colour, pen_width_px = _check_page_arguments(
        rng, characters, kind, options, paper_options, pen_colour, pen_width_px
    )
    kind = kind or paper_options.kinds[int(rng.integers(len(paper_options.kinds)))]
    h_px = _uniform(rng, options.char_height_px)
    drawn = min(_uniform(rng, options.pen_width_px), options.pen_width_max_rel * h_px)
    pen_rel = (pen_width_px or drawn) / h_px  # gaps are between the strokes' inked edges
    layout = _lay_out(rng, sources, kind, options, paper_options, pen_rel)
    h_px, size, margin = _fit_page(rng, layout, len(sources), h_px, size_hw, options, paper_options)
    pen_w = pen_width_px or max(pen_rel * h_px, 1.0)  # thinner if the writing had to shrink
    paper = random_paper(rng, size, kind, options=_page_paper_options(paper_options, layout, h_px))
    paths = _place(rng, layout, h_px, pen_w, size, margin, paper.meta)
    ink, boxes, region = _render_characters(paths, pen_w, size)
    colour = random_pen_colour(rng) if pen_colour is None else pen_colour
    opacity = _uniform(rng, options.opacity)
    scene, plain = _write_ink(paper.rgb, ink, colour, opacity, region)
    image, finish = _finish(rng, scene, None, None, None, None)
    return GeneratedPage(
        image=image,
        plain_image=plain,
        ink=ink,
        boxes=boxes,
        paths=paths,
        labels=[s.label for s in sources],
        lines=layout.lines,
        order=np.arange(len(sources), dtype=np.int64),
        words=layout.words,
        pen_width_px=float(pen_w),
        pen_colour=colour,
        kind=kind,
        meta=_page_meta(paper, finish, layout, h_px, opacity),
    )


def _page_meta(paper: Paper, finish: dict, layout: _Layout, h_px: float, opacity) -> dict:
    return {
        "paper": paper.meta,
        "finish": finish,
        "char_height_px": h_px,
        "gap_rel": layout.gap,
        "tight": layout.tight,
        "on_rules": layout.on_rules,
        "opacity": opacity,
        "line_angles_deg": layout.angles_deg,
    }


def _check_page_arguments(rng, characters, kind, options, paper_options, colour, width):
    _check_rng(rng)
    sources = _check_characters(characters)
    options = _check_options("options", options, PageOptions)
    paper_options = _check_options("paper_options", paper_options, PaperOptions)
    if kind is not None and kind not in KINDS:
        raise ValueError(f"kind must be one of {list(KINDS)} or None, got {kind!r}")
    if colour is not None:
        colour = _check_rgb("pen_colour", colour)
    if width is not None:
        width = _check_number("pen_width_px", width, 1.0, 30.0)
    return sources, options, paper_options, colour, width


#: Most characters on one page.
MAX_CHARACTERS = 5000


def _check_characters(characters) -> list[CharacterSource]:
    if isinstance(characters, (str, bytes, CharacterSource)) or not hasattr(characters, "__len__"):
        raise ValueError(
            f"characters must be a sequence of CharacterSource, got {type(characters).__name__}"
        )
    if not 1 <= len(characters) <= MAX_CHARACTERS:
        raise ValueError(
            f"characters must hold 1 to {MAX_CHARACTERS} CharacterSource, got {len(characters)}"
        )
    for i, c in enumerate(characters):
        if not isinstance(c, CharacterSource):
            raise ValueError(f"characters[{i}] must be a CharacterSource, got {type(c).__name__}")
    return list(characters)


# --- layout, in units of the character height ------------------------------------------


def _lay_out(rng, sources, kind: str, o: PageOptions, paper: PaperOptions, pen_rel) -> _Layout:
    n = len(sources)
    n_lines = int(rng.integers(o.n_lines[0], o.n_lines[1] + 1))
    n_lines = min(n, max(n_lines, math.ceil(n / o.max_per_line)))
    counts = _line_counts(rng, n, n_lines)
    tight = bool(rng.random() < o.tight_probability)
    gap = _uniform(rng, o.tight_gap_rel if tight else o.gap_rel)
    pitch = _uniform(rng, o.line_pitch_rel)
    spacing = _uniform(rng, o.spacing_rel)
    on_rules = (
        kind in ("ruled", "squared")
        and paper.spacing_px is None
        and bool(rng.random() < o.on_rules_probability)
    )
    if on_rules:  # baselines on rules: the pitch a whole number of spacings
        pitch = max(1, math.ceil(pitch / spacing - 1e-9)) * spacing
    page_angle = float(rng.uniform(-o.line_angle_deg, o.line_angle_deg))
    paths, lines, words, lengths = [], [], [], []
    start = 0
    for k, count in enumerate(counts):
        line_paths, line_words, length = _line(
            rng, sources[start : start + count], gap + pen_rel, o
        )
        paths += line_paths
        lines += [k] * count
        words += [w + (words[-1] + 1 if words else 0) for w in line_words]
        lengths.append(length)
        start += count
    # Neighbouring lines may converge by at most a quarter of the free space between them.
    free = max(pitch - 1.2, 0.05)
    spread = min(1.0, math.degrees(math.atan(0.25 * free / max(max(lengths), 1e-9))))
    spread = min(spread, 0.3) if on_rules else spread
    angles = [page_angle + float(rng.uniform(-spread, spread)) for _ in counts]
    _tilt_lines(paths, lines, angles, pitch, page_angle)
    return _Layout(
        paths=paths,
        lines=np.asarray(lines, np.int64),
        words=np.asarray(words, np.int64),
        angles_deg=angles,
        pitch=pitch,
        spacing=spacing,
        on_rules=on_rules,
        tight=tight,
        gap=gap,
        angle_deg=page_angle,
    )


def _line_counts(rng, n: int, n_lines: int) -> list[int]:
    # Nearly even lines, the remainder spread at random; every line holds a character.
    counts = np.full(n_lines, n // n_lines)
    counts[rng.permutation(n_lines)[: n % n_lines]] += 1
    return counts.tolist()


def _line(rng, sources, gap: float, o: PageOptions) -> tuple[list, list[int], float]:
    """One line's characters along a straight baseline (y = 0, x from 0), in units of h:
    their paths [T_i, 3], word numbers (from 0) and the line's length."""
    paths, words = [], []
    word, left_in_word = 0, int(rng.integers(o.word_length[0], o.word_length[1] + 1))
    cursor = 0.0
    for i, src in enumerate(sources):
        x_left, base, height = src.frame()
        scale = (1.0 + rng.uniform(-o.height_jitter, o.height_jitter)) / height
        a = math.radians(rng.uniform(-o.char_angle_deg, o.char_angle_deg))
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        xy = ((src.xy - (x_left, base)) * scale) @ rot.T
        down = xy[src.pen > 0]
        lo, hi = down[:, 0].min(), down[:, 0].max()
        xy[:, 0] += cursor - lo
        xy[:, 1] += rng.uniform(-o.baseline_jitter_rel, o.baseline_jitter_rel)
        paths.append(np.column_stack([xy, src.pen]))
        words.append(word)
        width = max(hi - lo, 0.12)  # a "1" still takes some room
        left_in_word -= 1
        if left_in_word == 0 and i + 1 < len(sources):
            step = _uniform(rng, o.word_gap_rel)
            word, left_in_word = word + 1, int(rng.integers(o.word_length[0], o.word_length[1] + 1))
        else:
            step = gap + rng.uniform(-o.gap_jitter_rel, o.gap_jitter_rel)
        # Touching is allowed, but the next character starts right of this one's middle.
        cursor += max(width + step, 0.55 * width + 0.05)
    return paths, words, cursor


def _tilt_lines(paths, lines, angles_deg, pitch: float, page_angle_deg: float) -> None:
    # In place: line k turned by its angle about its start, which lies k pitches down
    # the normal of the page's slope (lines of the same angle stay parallel and evenly
    # spaced, whatever their lengths).
    page = math.radians(page_angle_deg)
    for p, k in zip(paths, lines, strict=True):
        a = math.radians(angles_deg[k])
        c, s = math.cos(a), math.sin(a)
        x, y = p[:, 0].copy(), p[:, 1].copy()
        origin = (-k * pitch * math.sin(page), k * pitch * math.cos(page))
        p[:, 0] = origin[0] + c * x - s * y
        p[:, 1] = origin[1] + s * x + c * y


# --- the page's size, the paper, the placement ------------------------------------------


def _down_bounds(paths) -> tuple[float, float, float, float]:
    """``(x_lo, y_lo, x_hi, y_hi)`` of all pen-down points."""
    down = np.concatenate([p[p[:, 2] > 0, :2] for p in paths])
    lo, hi = down.min(0), down.max(0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _min_margin(o: PageOptions, paper: PaperOptions) -> float:
    # Characters stay clear of the band the sheet's edge may reach into.
    m = o.margin_rel[0]
    if paper.edge_probability > 0:
        m = max(m, paper.edge_depth_rel[1] + 0.02)
    if m >= 0.45:
        raise ValueError(
            f"paper_options.edge_depth_rel {paper.edge_depth_rel} leaves no room for writing "
            "inside the margins (its high end must be below 0.43)"
        )
    return m


#: Most elongated page that generate_page sizes itself (long side / short side).
_MAX_ASPECT = 2.0


def _fit_page(rng, layout: _Layout, n: int, h_px: float, size_hw, o: PageOptions, paper):
    """The character height (px: ``h_px``, lowered if the writing would not fit), the
    page's size (H, W) and its least margin (a share of the side)."""
    x_lo, y_lo, x_hi, y_hi = _down_bounds(layout.paths)
    slack = layout.spacing if layout.on_rules else 0.0  # room to move onto a rule
    extent = np.array([y_hi - y_lo + slack, x_hi - x_lo + slack])  # [2] (y, x), units of h
    pad_rel = o.pen_width_max_rel  # the pen's half width on either side, in units of h
    m_min = _min_margin(o, paper)
    lo = o.char_height_px[0]
    if size_hw is not None:
        size = np.array(_check_size("size_hw", size_hw))
        room = size * (1 - 2 * m_min) - 8.0  # 4 px more on either side
        h_px = min(h_px, float(np.min(room / (extent + pad_rel))))
        if h_px < lo:
            raise ValueError(
                f"size_hw {tuple(size_hw)} is too small for {n} characters at least "
                f"{lo:g} px high in {layout.lines.max() + 1} lines"
            )
        return h_px, (int(size[0]), int(size[1])), m_min
    wide = (max(o.margin_rel[0], m_min), max(o.margin_rel[1], m_min))
    margins = np.array([_uniform(rng, wide), _uniform(rng, wide)])  # [2] (y, x)
    for _ in range(8):  # shrink the writing until the page is small enough
        size = np.ceil(((extent + pad_rel) * h_px + 8.0) / (1 - 2 * margins)).astype(int)
        size = np.maximum(size, 32)
        # A photo of a page is not much more elongated than 2 : 1.
        size = np.maximum(size, np.ceil(size[::-1] / _MAX_ASPECT).astype(int))
        shrink = min(1.0, MAX_SIDE / size.max(), math.sqrt(MAX_PIXELS / (size[0] * size[1])))
        if shrink >= 1.0:
            break
        h_px *= 0.99 * shrink
    if h_px < lo or shrink < 1.0:
        raise ValueError(
            f"characters: {n} characters at least {lo:g} px high in "
            f"{layout.lines.max() + 1} lines do not fit a page of {MAX_PIXELS} pixels"
        )
    return h_px, (int(size[0]), int(size[1])), m_min


def _page_paper_options(paper: PaperOptions, layout: _Layout, h_px: float) -> PaperOptions:
    # The pattern's scale follows the writing's; writing on the rules shares their slope.
    changes = {}
    if paper.spacing_px is None:
        spacing = min(max(layout.spacing * h_px, 2.0), 4000.0)
        changes["spacing_px"] = (spacing, spacing)
    if layout.on_rules:
        changes["angle_deg"] = (layout.angle_deg, layout.angle_deg)
    return dataclasses.replace(paper, **changes)


def _place(rng, layout: _Layout, h_px: float, pen_w: float, size_hw, m_min, paper_meta) -> list:
    """The layout's paths in the page's pixels, at a random place inside the margins
    (on ruled and squared paper often with the baselines on the rules)."""
    paths = [np.column_stack([p[:, :2] * h_px, p[:, 2]]) for p in layout.paths]
    x_lo, y_lo, x_hi, y_hi = _down_bounds(paths)
    h, w = size_hw
    pad = 0.5 * pen_w + 4.0
    spacing = paper_meta["spacing_px"] if layout.on_rules else 0.0
    ox = _offset(rng, m_min * w + pad - x_lo, w - m_min * w - pad - x_hi)
    oy = _offset(rng, m_min * h + pad - y_lo, h - m_min * h - pad - y_hi - spacing)
    if layout.on_rules:
        # Move down onto a rule: the line-0 baseline at the page's (ox, oy) ends up a
        # little above the rule (the ink rests on it).
        sit = float(rng.uniform(-0.06, 0.0)) * h_px
        phase = float(pattern_phase(paper_meta, size_hw, ox, oy))
        oy += (sit - phase) % spacing / math.cos(math.radians(paper_meta["angle_deg"]))
    for p in paths:
        p[:, 0] += ox
        p[:, 1] += oy
    return paths


def _offset(rng, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi)) if hi > lo else 0.5 * (lo + hi)


# --- ink ------------------------------------------------------------------------------


def _render_characters(paths, pen_w: float, size_hw) -> tuple[np.ndarray, np.ndarray, tuple]:
    """The page's ink (float32 [H, W]), each character's box of ink > 0.5 (int64 [N, 4])
    and the rows and columns ``(y0, y1, x0, x1)`` that hold any ink.

    Each character is rendered on its own neighbourhood only (its pen-down points plus
    the reach of the pen's soft edge), so a big page costs what its characters do; the
    neighbourhoods go to :func:`render_paths` in batches (one batched call costs little
    more than one character, and far less than many small calls on a busy machine)."""
    h, w = size_hw
    ink = np.zeros((h, w), np.float32)
    boxes = np.zeros((len(paths), 4), np.int64)
    windows = [_window(p, pen_w, size_hw) for p in paths]  # (x0, y0, x1, y1) each
    for batch in _batches(windows):
        crops = _render_batch([paths[i] for i in batch], [windows[i] for i in batch], pen_w)
        for i, crop in zip(batch, crops, strict=True):
            x0, y0, x1, y1 = windows[i]
            np.maximum(ink[y0:y1, x0:x1], crop, out=ink[y0:y1, x0:x1])
            down = paths[i][paths[i][:, 2] > 0, :2]
            boxes[i] = _ink_box(crop, down - (x0, y0)) + (x0, y0, x0, y0)
    lo, hi = np.min(windows, 0), np.max(windows, 0)
    return ink, boxes, (int(lo[1]), int(hi[3]), int(lo[0]), int(hi[2]))


def _window(path: np.ndarray, pen_w: float, size_hw) -> tuple[int, int, int, int]:
    """``(x0, y0, x1, y1)``: the pixels a character's ink can reach, inside the page."""
    h, w = size_hw
    reach = math.ceil(pen_w) + 4  # beyond it render_paths leaves < 1e-3 of ink
    down = path[path[:, 2] > 0, :2]
    x0, y0 = (max(0, math.floor(v) - reach) for v in down.min(0))
    x1 = min(w, math.ceil(down[:, 0].max()) + reach + 1)
    y1 = min(h, math.ceil(down[:, 1].max()) + reach + 1)
    return x0, y0, x1, y1


# Most pixels of one batch of character neighbourhoods (all of the batch's largest size).
_RENDER_BATCH_PIXELS = 1 << 21


def _batches(windows) -> list[list[int]]:
    """Consecutive characters (of similar size, in reading order) grouped into batches."""
    batches, current, big = [], [], (0, 0)
    for i, (x0, y0, x1, y1) in enumerate(windows):
        size = (max(big[0], y1 - y0), max(big[1], x1 - x0))
        if current and (len(current) + 1) * size[0] * size[1] > _RENDER_BATCH_PIXELS:
            batches.append(current)
            current, size = [], (y1 - y0, x1 - x0)
        current.append(i)
        big = size
    return batches + [current]


def _render_batch(paths, windows, pen_w: float) -> list[np.ndarray]:
    # Paths shifted into their windows and padded to one length with pen-up copies of
    # their last point (pen-up segments are not drawn); each render cut to its window.
    n_points = max(len(p) for p in paths)
    hc = max(y1 - y0 for _, y0, _, y1 in windows)
    wc = max(x1 - x0 for x0, _, x1, _ in windows)
    points = np.zeros((len(paths), n_points, 3), np.float32)  # [B, T, 3]
    for b, (p, (x0, y0, _, _)) in enumerate(zip(paths, windows, strict=True)):
        points[b, : len(p)] = p - (x0, y0, 0)
        points[b, len(p) :, :2] = points[b, len(p) - 1, :2]
    images = render_paths(points, (hc, wc), pen_w).numpy()  # [B, hc, wc]
    return [im[: y1 - y0, : x1 - x0] for im, (x0, y0, x1, y1) in zip(images, windows, strict=True)]


def _ink_box(crop: np.ndarray, down: np.ndarray) -> np.ndarray:
    """``[x0, y0, x1, y1]`` of ``crop > 0.5``; for a character too faint to have any (a
    lone dot of a thin pen between pixel centres), the pixels of its pen-down points."""
    rows = np.flatnonzero((crop > 0.5).any(axis=1))
    cols = np.flatnonzero((crop > 0.5).any(axis=0))
    if rows.size:
        return np.array([cols[0], rows[0], cols[-1] + 1, rows[-1] + 1])
    px = np.round(down).astype(np.int64)
    lo, hi = px.min(0), px.max(0) + 1
    return np.array([lo[0], lo[1], hi[0], hi[1]])


def _write_ink(paper_rgb, ink, colour, opacity: float, region) -> tuple[np.ndarray, np.ndarray]:
    """The scene (the ink on ``paper_rgb``, in place) and the control (the same ink on
    white, uint8), both only worked on within ``region`` = (y0, y1, x0, x1)."""
    y0, y1, x0, x1 = region
    plain = np.full(paper_rgb.shape, 255, np.uint8)
    for r0, r1 in _bands(max(y1 - y0, 0), max(x1 - x0, 0)):
        rows = slice(y0 + r0, y0 + r1)
        cover = ink[rows, x0:x1]
        _absorb(paper_rgb[rows, x0:x1], cover, colour, opacity)
        white = np.ones((*cover.shape, 3), np.float32)
        _absorb(white, cover, colour, opacity)
        plain[rows, x0:x1] = _to_uint8(white)
    return paper_rgb, plain


# --- character sources ------------------------------------------------------------------


def page_sources_from_recorded(recorded_paths) -> list[CharacterSource]:
    """Characters from recorded pen paths over MNIST digits (:func:`img2dmp.data.recorded.
    load_recorded`): one stroke each, labelled with the digit.

    Parameters
    ----------
    recorded_paths : sequence of RecordedPath

    Returns
    -------
    list of CharacterSource
        In the given order; ``xy`` in the 28 x 28 frame, ``height`` the path's own.
    """
    out = []
    for i, r in enumerate(recorded_paths):
        if not isinstance(r, RecordedPath):
            raise ValueError(f"recorded_paths[{i}] must be a RecordedPath, got {type(r).__name__}")
        out.append(CharacterSource(xy=r.xy, label=str(r.label)))
    return out


def page_sources_from_synthetic(
    rng, n: int, *, digits=None, config: SyntheticConfig | None = None
) -> list[CharacterSource]:
    """``n`` synthetic digits (:mod:`img2dmp.data.synthetic`'s templates with their
    random variation and minimum-jerk timing), each drawn at random from ``digits``.

    Parameters
    ----------
    rng : numpy.random.Generator
    n : int in [1, 5000]
    digits : sequence of int 0-9, optional
        Default all ten.
    config : SyntheticConfig, optional
        Ranges of the templates' variation; default ``SyntheticConfig()``.

    Returns
    -------
    list of CharacterSource
        ``xy`` in the templates' unit frame (y in about [-1, 1]), one stroke each.
    """
    _check_rng(rng)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_CHARACTERS:
        raise ValueError(f"n must be an integer in [1, {MAX_CHARACTERS}], got {n!r}")
    digits = tuple(range(10)) if digits is None else tuple(digits)
    if not digits or any(d not in DIGIT_TEMPLATES for d in digits):
        raise ValueError(f"digits must be a non-empty choice of 0-9, got {digits!r}")
    config = config or SyntheticConfig()
    labels = [digits[int(k)] for k in rng.integers(len(digits), size=int(n))]
    return [
        CharacterSource(xy=sample_unit_paths(d, 1, config, rng)[0], label=str(d)) for d in labels
    ]


def page_sources_from_strokes(stroke_digits) -> list[CharacterSource]:
    """Multi-stroke characters from traced MNIST strokes (:func:`img2dmp.data.strokes.
    load_strokes`): between strokes one pen-up point halfway along the travel.

    Parameters
    ----------
    stroke_digits : sequence of StrokeDigit

    Returns
    -------
    list of CharacterSource
    """
    out = []
    for i, d in enumerate(stroke_digits):
        if not isinstance(d, StrokeDigit) or not d.strokes:
            raise ValueError(f"stroke_digits[{i}] must be a StrokeDigit with strokes, got {d!r}")
        xy, pen = [], []
        for k, stroke in enumerate(d.strokes):
            if k:
                xy.append(0.5 * (d.strokes[k - 1][-1] + stroke[0])[None])
                pen.append([0.0])
            xy.append(stroke)
            pen.append(np.ones(len(stroke)))
        out.append(
            CharacterSource(xy=np.concatenate(xy), pen=np.concatenate(pen), label=str(d.label))
        )
    return out
