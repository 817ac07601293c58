"""Executing a DMP with the simulated arm: map pixels to the paper, check, write, measure.

The sequence of :func:`write_dmp`:

1. **Plan and check** (before anything moves): check the DMP and the settings
   (:func:`checked_dmp`, :class:`WritingOptions`: finite numbers, a duration and a video
   of bounded size), sample its exact path (:func:`img2dmp.dmp.rollout`'s interpolant,
   in NumPy: writing never imports torch) at the control rate, map every point from
   image pixels to the paper (:class:`PaperMapping`), and raise ``ValueError`` if a
   point leaves the sheet or the arm cannot reach it with the pen vertical (inverse
   kinematics along the whole path, within joint limits).
2. **Approach** (:meth:`WritingRun.approach`): the arm starts at rest with the tip
   ``lift_height_m`` above the first point; the admittance law lowers the pen until it
   presses with the set force.
3. **Write** (:meth:`WritingRun.write`): the DMP runs online, one
   :meth:`DMPIntegrator.step` per control step; its x, y go through the mapping to the
   Cartesian target, its pen channel (d = 3) lifts and lowers the pen. Between strokes
   the DMP clock holds until the pen has landed with the set force, and until it has
   left the paper (:class:`img2dmp.robot.strokes.StrokeGate`).
4. **Lift** (:meth:`WritingRun.lift`) the pen off the paper at the end point.

Every control step is logged (:class:`WritingLog`, joint positions and velocities
included); metrics are taken over the commanded pen-down time of phase 3 (the DMP
running), the ink per stroke by :func:`img2dmp.robot.strokes.stroke_report`.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, fields

import numpy as np

from .._lazy import is_tensor
from ..config import check_positive
from ..dmp import DMPConfig, DMPIntegrator, DMPParams
from ..dmp._numpy_rollout import rollout_numpy
from ..dmp.params import config_of
from .animation import PaperInset
from .controller import ControllerConfig, WritingController, axis_move_s
from .scene import HOME_JOINTS_RAD, SceneConfig, WritingScene
from .strokes import CLOCK_RAMP_S, DMPClock, StrokeGate, clock_stops, stroke_report
from .tempo import (
    JOINT_ACCELERATION_SHARE,
    JOINT_SPEED_SHARE,
    Slowing,
    joint_acceleration_metrics,
    joint_speed_metrics,
    planned_joint_accelerations,
    planned_joint_velocities,
    settled_posture,
    slowed_dmp,
    slowing_for,
)

# The pen points straight down; the flange's x axis points back towards the robot.
PEN_DOWN_ROTATION = np.diag([-1.0, 1.0, -1.0])
# "travel": between the characters of a page (:mod:`img2dmp.robot.page`), pen up.
PHASES = ("approach", "write", "lift", "travel")
PEN_THRESHOLD = 0.5
IK_TOLERANCE_M = 1e-4
# Rounds of planning a slowed DMP again (slow_for_joint_limits).
MAX_SLOWING_ROUNDS = 6
#: Points farther than this from the arm's base are refused without solving the IK (the
#: iiwa reaches about 0.8 m; a point at 1e308 m overflowed the solver).
BEYOND_REACH_M = 2.0
# Writing starts once the force has stayed this close to the set point (relative).
SETTLE_BAND = 0.05
# A pen that goes down soon starts lowering to the approach clearance this much earlier
# than the descent strictly needs.
HOVER_MARGIN_S = 0.03
# Steps between two calls of the progress callback (0.1 s at 240 Hz).
PROGRESS_EVERY_STEPS = 24
# The longest write phase, in control steps (17 min at 240 Hz): the plan, the log and
# the simulation all grow with it.
MAX_WRITING_STEPS = 250_000
#: Narrowest and widest a page may be asked to be written, mm (whether it fits the
#: sheet, 148 mm wide, is checked after, naming the width that would).
PAGE_WIDTH_RANGE_MM = (5.0, 1e6)
# Bounds of the camera pictures: each side of a frame or render, and all video frames.
IMAGE_SIDE_PX = (16, 4096)
MAX_VIDEO_BYTES = 1 << 30
# The longest approach before giving up, seconds of simulated time.
MAX_APPROACH_TIMEOUT_S = 600.0
# The path stays this far inside the sheet's edges.
SHEET_MARGIN_M = 0.002


def _is_finite(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


def _image_size(size) -> tuple[int, int]:
    """``(H, W)`` as two positive integers, else ``ValueError`` naming the value."""
    try:
        h, w = size
        ok = all(_is_finite(v) and int(v) == v and v > 0 for v in (h, w))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"image_size must be two positive integers (H, W), got {size!r}")
    return int(h), int(w)


def _side_pair(name: str, size) -> tuple[int, int]:
    """A picture size ``(w, h)`` with both sides in ``IMAGE_SIDE_PX``."""
    lo, hi = IMAGE_SIDE_PX
    try:
        ok = len(size) == 2 and all(_is_finite(v) and int(v) == v and lo <= v <= hi for v in size)
    except TypeError:
        ok = False
    if not ok:
        raise ValueError(f"{name} must be two integers (w, h) in [{lo}, {hi}] px, got {size!r}")
    return int(size[0]), int(size[1])


@dataclass(frozen=True)
class PaperMapping:
    """Image pixels to metres on the paper, as a writer sitting at the robot sees it.

    The image's up direction (decreasing row) points away from the robot (world +x),
    its right direction (increasing column) points to the writer's right (world -y), and
    the centre of the written area (the whole image unless ``area_px`` says otherwise)
    lands on ``center_m``. ``writing_height_mm`` is the height of that area on paper, so
    a digit filling a 28-pixel MNIST image is about that tall.

    Parameters
    ----------
    image_size : tuple (H, W)
        Image size in pixels.
    writing_height_mm : float
        Height on paper of the written area (the full image height H by default).
    center_m : tuple (x, y)
        World position of the written area's centre, metres.
    area_px : tuple (x0, y0, x1, y1) or None
        The written area: half-open integer pixel bounds (columns ``x0 <= j < x1``,
        rows ``y0 <= i < y1``) inside the image, e.g. the characters of a page; None:
        the whole image. With ``turn_deg``, bounds in the image turned level (any
        finite numbers; None: around the whole image turned).
    turn_deg : float
        The image is turned by this angle, counter-clockwise as seen (negative:
        clockwise), about its centre before it is laid on the paper: a page photographed
        askew and read turned level (its document's ``turned_deg``) is written level.
        0 (default): as it stands.
    """

    image_size: tuple[int, int]
    writing_height_mm: float = 40.0
    center_m: tuple[float, float] = (0.55, 0.0)
    area_px: tuple[float, float, float, float] | None = None
    turn_deg: float = 0.0
    # the turn's map of pixel positions and its inverse, made once (to_table runs every
    # control step); None as it stands
    _level: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)
    _unlevel: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "image_size", _image_size(self.image_size))
        check_positive("writing_height_mm", self.writing_height_mm)
        if not (len(self.center_m) == 2 and all(_is_finite(v) for v in self.center_m)):
            raise ValueError(f"center_m must be two finite numbers (x, y), got {self.center_m!r}")
        if not (_is_finite(self.turn_deg) and -180.0 <= self.turn_deg <= 180.0):
            raise ValueError(f"turn_deg must be a number of degrees in [-180, 180], got "
                             f"{self.turn_deg!r}")  # fmt: skip
        object.__setattr__(self, "turn_deg", float(self.turn_deg))
        if self.turn_deg:
            level = level_map_px(self.image_size, self.turn_deg)
            object.__setattr__(self, "_level", level)
            object.__setattr__(self, "_unlevel", np.linalg.inv(level))
            object.__setattr__(self, "area_px", self._turned_area())
            return
        h, w = self.image_size
        area = (0, 0, w, h) if self.area_px is None else self.area_px
        try:
            ok = len(area) == 4 and all(_is_finite(v) and int(v) == v for v in area)
            x0, y0, x1, y1 = (int(v) for v in area)
            ok = ok and 0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise ValueError(
                f"area_px must be integers (x0, y0, x1, y1) with 0 <= x0 < x1 <= {w} and "
                f"0 <= y0 < y1 <= {h}, got {self.area_px!r}"
            )
        object.__setattr__(self, "area_px", (x0, y0, x1, y1))

    def _turned_area(self) -> tuple[float, float, float, float]:
        """The written area of a turned mapping, checked: its given bounds as floats, or
        the bounds around the whole image turned (pixel edges)."""
        if self.area_px is None:
            h, w = self.image_size
            return _box_around(_apply(self._level, _edge_corners((0, 0, w, h))))
        try:
            area = tuple(float(v) for v in self.area_px)
            ok = len(area) == 4 and all(_is_finite(v) for v in self.area_px)
            ok = ok and area[0] < area[2] and area[1] < area[3]
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise ValueError("area_px of a turned mapping must be four finite numbers (x0, y0, "
                             f"x1, y1) with x0 < x1 and y0 < y1, got {self.area_px!r}")  # fmt: skip
        return area  # type: ignore[return-value]

    @classmethod
    def for_width(cls, image_size, area_px, width_mm: float, center_m,
                  turn_deg: float = 0.0) -> PaperMapping:  # fmt: skip
        """The mapping that writes ``area_px`` ``width_mm`` wide (its aspect kept)."""
        x0, y0, x1, y1 = area_px
        width_mm = check_positive("width_mm", width_mm)
        lo, hi = PAGE_WIDTH_RANGE_MM
        if not lo <= width_mm <= hi:  # 1e-300 wrote a page 0.0 mm wide, 1e308 overflowed
            raise ValueError(f"width_mm {width_mm:g} must be from {lo:g} to {hi:g} mm (the "
                             "written area's width on the paper)")  # fmt: skip
        return cls(image_size, width_mm * (y1 - y0) / (x1 - x0), center_m, area_px, turn_deg)

    @property
    def metres_per_px(self) -> float:
        return self.writing_height_mm * 1e-3 / (self.area_px[3] - self.area_px[1])

    @property
    def area_size_mm(self) -> tuple[float, float]:
        """Width and height of the written area on paper, mm."""
        x0, y0, x1, y1 = self.area_px
        return (x1 - x0) * self.metres_per_px * 1e3, (y1 - y0) * self.metres_per_px * 1e3

    def _center_px(self) -> tuple[float, float]:
        # Pixel centres: the area's columns x0 .. x1 - 1 have their middle at (x0 + x1 - 1) / 2.
        x0, y0, x1, y1 = self.area_px
        return (x0 + x1 - 1) / 2, (y0 + y1 - 1) / 2

    def to_table(self, xy_px) -> np.ndarray:
        """``[..., 2]`` pixels (x = column, y = row) to world ``[..., 2]`` (x, y) metres."""
        xy = np.asarray(xy_px, dtype=float)
        if self._level is not None:
            xy = _apply(self._level, xy)
        cx, cy = self._center_px()
        s = self.metres_per_px
        wx = self.center_m[0] - (xy[..., 1] - cy) * s
        wy = self.center_m[1] - (xy[..., 0] - cx) * s
        return np.stack([wx, wy], axis=-1)

    def to_pixels(self, xy_m) -> np.ndarray:
        """Inverse of :meth:`to_table`."""
        xy = np.asarray(xy_m, dtype=float)
        cx, cy = self._center_px()
        s = self.metres_per_px
        col = cx - (xy[..., 1] - self.center_m[1]) / s
        row = cy - (xy[..., 0] - self.center_m[0]) / s
        out = np.stack([col, row], axis=-1)
        if self._unlevel is not None:
            out = _apply(self._unlevel, out)
        return out

    @property
    def image_area_px(self) -> tuple[int, int, int, int]:
        """The written area in the image's own pixels: ``area_px`` as it stands, or for a
        turned mapping the upright box around the area turned back, inside the image."""
        if not self.turn_deg:
            return self.area_px  # type: ignore[return-value]
        x0, y0, x1, y1 = _box_around(_apply(self._unlevel, _edge_corners(self.area_px)))
        h, w = self.image_size
        x0, y0 = max(0, math.floor(x0)), max(0, math.floor(y0))
        x1, y1 = min(w, max(x0 + 1, math.ceil(x1))), min(h, max(y0 + 1, math.ceil(y1)))
        return x0, y0, x1, y1


def level_map_px(image_size, turn_deg: float) -> np.ndarray:
    """The ``[3, 3]`` map of pixel positions (x = column, y = row) of an image ``(H, W)``
    to the same image turned by ``turn_deg`` (counter-clockwise as seen) about its
    centre, as :func:`img2dmp.page.read_page` turns a page taken askew to read it
    level."""
    h, w = image_size
    a = math.radians(turn_deg)
    c, s = math.cos(a), math.sin(a)
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    turn = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    shift = np.array([[1.0, 0.0, -cx], [0.0, 1.0, -cy], [0.0, 0.0, 1.0]])
    return np.linalg.inv(shift) @ turn @ shift


def level_box_px(box_px, image_size, turn_deg: float) -> tuple[float, float, float, float]:
    """The half-open box ``(x0, y0, x1, y1)`` (pixel bounds) around a box of the image
    turned by ``turn_deg`` about the image's centre (:func:`level_map_px`)."""
    return _box_around(_apply(level_map_px(image_size, turn_deg), _edge_corners(box_px)))


def _edge_corners(box) -> np.ndarray:
    """The four corners ``[4, 2]`` of a half-open pixel box, at the pixels' outer edges."""
    x0, y0, x1, y1 = (float(v) for v in box)
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]) - 0.5


def _box_around(corners: np.ndarray) -> tuple[float, float, float, float]:
    """The half-open box (pixel bounds) whose outer edges hold ``corners [n, 2]``."""
    lo, hi = corners.min(axis=0) + 0.5, corners.max(axis=0) + 0.5
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _apply(m: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The affine map ``m [3, 3]`` applied to points ``[..., 2]``."""
    return xy @ m[:2, :2].T + m[:2, 2]


@dataclass
class PlannedPath:
    """The DMP integrated at the control rate and mapped to the paper (checked)."""

    time_s: np.ndarray  # [T]
    xy_px: np.ndarray  # [T, 2]
    pen_down: np.ndarray  # [T] bool
    xy_m: np.ndarray  # [T, 2]


@dataclass(frozen=True)
class WritingOptions:
    """Settings of one writing run (the keyword arguments of :func:`write_dmp`).

    Parameters
    ----------
    writing_height_mm : float
        Height on paper of the whole image (see :class:`PaperMapping`).
    control_rate_hz : float
        Controller and physics rate, in [100, 10000]; one DMP step, one IK solve and one
        physics step per period.
    scene_config : SceneConfig
        Cell geometry; the writing area is centred on the paper.
    controller_config : ControllerConfig
        Controller gains and set points.
    approach_timeout_s : float
        Give up (``RuntimeError``) if the pen has not reached the set force by then.
    settle_s : float
        Time the force must stay within ``SETTLE_BAND`` (5 %) of the set point before
        writing starts.
    frame_interval_s : float or None
        If given, keep a camera frame every so many simulated seconds (for a video).
    frame_size_px, render_size_px : tuple (w, h)
        Size of each half of a video frame (arm | paper seen from above) and of the final
        render (arm | paper); ``render_size_px=None``: no final render.
    stroke_dwell : bool
        Hold the DMP clock at each touch-down until the force is in band and at each
        lift-off until the pen has left the paper (:mod:`img2dmp.robot.strokes`);
        ``False`` lets the DMP run on while the pen lands (the behaviour before).
    hover : bool
        Before each touch-down of the plan, lower the pen during the pen-up travel to
        ``approach_clearance_m`` above the paper (instead of ``lift_height_m``), timed so
        that it is there when the stroke starts: the touch-down then only has the slow
        final approach left.
    joint_speed_share : float or None
        Before anything moves, slow the DMP (a longer ``tau``: the same path) until the
        joint speeds planned along it stay within this share of the real iiwa's limits
        (:mod:`img2dmp.robot.tempo`); ``None``: write it at its own tempo, whatever the
        joints need (the simulated arm follows; a real iiwa may not).
    joint_acceleration_share : float or None
        The same for the joint accelerations planned along the DMP, against the 10
        rad/s^2 planning limit (``IIWA_ACCELERATION_LIMITS_RAD_S2``); default 0.6 (room
        for the simulated arm's own transients, as for the speed); ``None``: not slowed
        for them.
    """

    writing_height_mm: float = 40.0
    control_rate_hz: float = 240.0
    scene_config: SceneConfig = field(default_factory=SceneConfig)
    controller_config: ControllerConfig = field(default_factory=ControllerConfig)
    approach_timeout_s: float = 3.0
    settle_s: float = 0.2
    frame_interval_s: float | None = None
    frame_size_px: tuple[int, int] = (320, 240)
    render_size_px: tuple[int, int] | None = (640, 480)
    stroke_dwell: bool = True
    hover: bool = True
    joint_speed_share: float | None = JOINT_SPEED_SHARE
    joint_acceleration_share: float | None = JOINT_ACCELERATION_SHARE

    def __post_init__(self) -> None:
        for name in ("joint_speed_share", "joint_acceleration_share"):
            share = getattr(self, name)
            if share is not None and not (_is_finite(share) and 0.0 < share <= 1.0):
                raise ValueError(f"{name} must be in (0, 1] or None, got {share!r}")
        for name in ("stroke_dwell", "hover"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        rate = self.control_rate_hz
        if not (_is_finite(rate) and 100.0 <= rate <= 10000.0):
            raise ValueError(f"control_rate_hz must be in [100, 10000], got {rate!r}")
        check_positive("writing_height_mm", self.writing_height_mm)
        timeout = check_positive("approach_timeout_s", self.approach_timeout_s)
        if timeout > MAX_APPROACH_TIMEOUT_S:
            raise ValueError(
                f"approach_timeout_s must be in (0, {MAX_APPROACH_TIMEOUT_S:g}] s, got {timeout!r}"
            )
        if not check_positive("settle_s", self.settle_s) <= timeout:
            raise ValueError(
                f"settle_s must be in (0, approach_timeout_s = {timeout:g}] s, "
                f"got {self.settle_s!r}"
            )
        if self.frame_interval_s is not None:
            check_positive("frame_interval_s", self.frame_interval_s)
        for name in ("scene_config", "controller_config"):
            kind = SceneConfig if name == "scene_config" else ControllerConfig
            if not isinstance(getattr(self, name), kind):
                got = type(getattr(self, name)).__name__
                raise ValueError(f"{name} must be a {kind.__name__}, got {got}")
        object.__setattr__(self, "frame_size_px", _side_pair("frame_size_px", self.frame_size_px))
        if self.render_size_px is not None:
            size = _side_pair("render_size_px", self.render_size_px)
            object.__setattr__(self, "render_size_px", size)

    def check_video(self, tau_s: float) -> None:
        """``ValueError`` if the video frames of a DMP of ``tau_s`` seconds (kept every
        ``frame_interval_s`` over the approach, the writing and the lift) would take more
        than ``MAX_VIDEO_BYTES``."""
        if self.frame_interval_s is None:
            return
        cfg = self.controller_config
        lift_s = axis_move_s(cfg, cfg.lift_height_m) + 2 * CLOCK_RAMP_S  # and the clock's stop
        n = math.ceil((self.approach_timeout_s + tau_s + lift_s + 0.2) / self.frame_interval_s)
        w, h = self.frame_size_px
        size = n * 2 * w * h * 3
        if size > MAX_VIDEO_BYTES:
            raise ValueError(
                f"frame_interval_s = {self.frame_interval_s:g} s keeps up to {n} frames of "
                f"{2 * w} x {h} px for this DMP (tau = {tau_s:g} s), {size / 2**30:.1f} GiB; "
                f"at most {MAX_VIDEO_BYTES / 2**30:g} GiB: use a longer interval or smaller frames"
            )

    @property
    def dt_s(self) -> float:
        """Control period = physics time step."""
        return 1.0 / self.control_rate_hz


@dataclass(frozen=True, eq=False)
class WritingLog(Mapping):
    """One entry per control step of a writing run, ``S`` steps in all (world frame).

    Read the fields by name (``log.force_n``). ``log["force_n"]``, ``log.keys()`` and
    ``dict(log)`` work too, as for the dict this log used to be (so ``len(log)`` is the
    number of fields; the number of steps is :attr:`n_steps`).

    Attributes
    ----------
    time_s : ndarray [S]
        Simulated time at the end of the step.
    phase : ndarray [S] int
        Index into ``PHASES`` (approach, write, lift).
    dmp_time_s : ndarray [S]
        Time of the DMP (0 during the approach, ``tau`` during the lift).
    pen_down : ndarray [S] bool
        The commanded pen state.
    cmd_m : ndarray [S, 3]
        Commanded tip position: the DMP's point on the paper and the admittance height.
    tip_m : ndarray [S, 3]
        Actual tip position after the physics step.
    force_n : ndarray [S]
        Tip-paper normal force after the physics step (0 without contact).
    torque_nm : ndarray [S, 7]
        Joint torques applied during the step.
    joint_q_rad, joint_qd_rad_s : ndarray [S, 7]
        Joint positions and velocities after the step (NaN in a log made without them).
    dwell : ndarray [S] bool
        The DMP clock was held on this step (the pen landing at the start of a stroke or
        leaving the paper at its end); False in a log made without it.
    joint_q_ref_rad, joint_qd_ref_rad_s : ndarray [S, 7]
        The controller's reference on this step: ``q_d`` from its inverse kinematics and
        ``qd_d``, its finite difference (NaN in a log made without them).
    """

    time_s: np.ndarray  # [S]
    phase: np.ndarray  # [S] int
    dmp_time_s: np.ndarray  # [S]
    pen_down: np.ndarray  # [S] bool
    cmd_m: np.ndarray  # [S, 3]
    tip_m: np.ndarray  # [S, 3]
    force_n: np.ndarray  # [S]
    torque_nm: np.ndarray  # [S, 7]
    joint_q_rad: np.ndarray | None = None  # [S, 7]
    joint_qd_rad_s: np.ndarray | None = None  # [S, 7]
    dwell: np.ndarray | None = None  # [S] bool
    joint_q_ref_rad: np.ndarray | None = None  # [S, 7]
    joint_qd_ref_rad_s: np.ndarray | None = None  # [S, 7]

    def __post_init__(self) -> None:
        n_steps = len(self.time_s)
        for name in ("joint_q_rad", "joint_qd_rad_s", "joint_q_ref_rad", "joint_qd_ref_rad_s"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full((n_steps, 7), np.nan))
        if self.dwell is None:
            object.__setattr__(self, "dwell", np.zeros(n_steps, dtype=bool))
        for f in fields(self):
            shape = np.shape(getattr(self, f.name))
            width = {"cmd_m": 3, "tip_m": 3, "torque_nm": 7}.get(f.name)
            width = 7 if f.name.startswith("joint_") else width
            expected = (n_steps,) if width is None else (n_steps, width)
            if shape != expected:
                raise ValueError(f"WritingLog field '{f.name}' has shape {shape}, not {expected}")

    @property
    def n_steps(self) -> int:
        return len(self.time_s)

    def in_phase(self, name: str) -> np.ndarray:
        """``[S]`` bool: the steps of phase ``name`` (one of ``PHASES``)."""
        return self.phase == PHASES.index(name)

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._names():
            raise KeyError(name)
        return getattr(self, name)

    def __iter__(self) -> Iterator[str]:
        return iter(self._names())

    def __len__(self) -> int:
        return len(self._names())

    @classmethod
    def _names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))


@dataclass
class WritingResult:
    """Everything a writing run produced.

    Attributes
    ----------
    log : WritingLog
        One entry per control step (item access by name works as well).
    metrics : dict
        See :func:`writing_metrics`; also ``simulated_s``, ``wall_s``,
        ``real_time_factor``, ``control_rate_hz``, ``force_set_n``, ``approach_s``,
        and :func:`img2dmp.robot.strokes.stroke_report`'s ``strokes`` (ink and force per
        pen-down stroke), ``stroke_ink_share_min``, ``dwell_s`` (time the DMP clock was
        held between strokes) and ``force_in_band_share_with_dwell``.
    plan : PlannedPath
    mapping : PaperMapping
    scene_config : SceneConfig
    controller_config : ControllerConfig
    frames : list of ndarray
        Video frames ``uint8 [h, 2 w, 3]`` (arm | paper from above) if requested.
    render : ndarray or None
        Final camera picture ``uint8 [h, 2 w, 3]`` (arm | paper) if requested.
    start_joints_rad : ndarray [7] or None
        Joint positions at rest before the first step (the start posture).
    slowing : Slowing or None
        How much the DMP was slowed for the iiwa's joint speed limits
        (:mod:`img2dmp.robot.tempo`; factor 1: not); None for a page, whose characters
        each have theirs.
    """

    log: WritingLog
    metrics: dict
    plan: PlannedPath
    mapping: PaperMapping
    scene_config: SceneConfig
    controller_config: ControllerConfig
    frames: list = field(default_factory=list)
    render: np.ndarray | None = None
    start_joints_rad: np.ndarray | None = None
    slowing: Slowing | None = None

    def extra_log_columns(self) -> dict[str, np.ndarray]:
        """Columns the CSV log has after the log's fields, by name (``[S]`` each): none
        for one DMP (a page adds the character each step belongs to)."""
        return {}


def _pen_channel(y: np.ndarray, n_dims: int) -> np.ndarray:
    if n_dims == 2:
        return np.ones(y.shape[:-1], dtype=bool)
    return y[..., 2] >= PEN_THRESHOLD


def checked_dmp(params: DMPParams, config: DMPConfig) -> DMPParams:
    """One DMP to write, as float64 NumPy (torch tensors, integers and mixes of them are
    converted), checked: ``ValueError`` naming the field and its value for anything
    that is not a DMP of ``config`` with finite numbers and a duration ``tau > 0``."""
    if not isinstance(params, DMPParams):
        raise ValueError(f"params must be a DMPParams, got {type(params).__name__}")
    if not isinstance(config, DMPConfig):
        raise ValueError(f"config must be a DMPConfig, got {type(config).__name__}")
    fields_ = {}
    for name in ("w", "tau", "g", "y0"):
        a = getattr(params, name)
        if is_tensor(a):
            a = a.detach().cpu().numpy()
        a = np.asarray(a)
        if a.dtype.kind not in "iuf":
            raise ValueError(f"params.{name} must hold numbers, got dtype {a.dtype}")
        a = a.astype(np.float64)
        bad = np.flatnonzero(~np.isfinite(a.ravel()))
        if bad.size:
            where = [int(i) for i in np.unravel_index(bad[0], a.shape)] if a.ndim else ""
            value = a.ravel()[bad[0]]
            raise ValueError(f"params.{name}{where} is {value}: a DMP to write needs finite values")
        fields_[name] = a
    tau = fields_["tau"]
    if tau.shape != ():
        raise ValueError(f"params.tau must be one number (one DMP), got shape {tau.shape}")
    if not tau > 0:
        raise ValueError(f"params.tau is {float(tau)!r} s: the duration must be > 0")
    return DMPParams(**fields_, config=config_of(params, config))


def plan_path(
    params: DMPParams, config: DMPConfig, mapping: PaperMapping, dt_s: float
) -> PlannedPath:
    """The exact path of one DMP (:func:`img2dmp.dmp.rollout`, in NumPy) at steps of ``dt_s`` over
    ``[0, tau]``, mapped to the paper.

    ``ValueError`` (naming the value) for a DMP that :func:`checked_dmp` refuses or that
    takes more than ``MAX_WRITING_STEPS`` control steps.
    """
    if config.n_dims not in (2, 3):
        raise ValueError(
            f"a writing DMP has d = 2 (x, y) or d = 3 (x, y, pen), got d = {config.n_dims}"
        )
    params = checked_dmp(params, config)
    dt_s = check_positive("dt_s", dt_s)
    tau = float(params.tau)
    steps = tau / dt_s  # a float: tau = 1e300 s must not become a 300-digit integer
    if steps >= MAX_WRITING_STEPS + 0.5:  # round(steps) > MAX_WRITING_STEPS
        raise ValueError(
            f"params.tau is {tau:g} s: {steps:.3g} control steps at {1 / dt_s:g} Hz, more "
            f"than the {MAX_WRITING_STEPS} the arm writes (at most {MAX_WRITING_STEPS * dt_s:g} "
            "s at this rate)"
        )
    n = max(1, round(steps))
    t = np.arange(n + 1) * dt_s
    y = rollout_numpy(params, t, config)  # [T, d]
    if not np.isfinite(y).all():  # finite parameters can still overflow (w of 1e308)
        raise ValueError("params: the DMP's movement (its rollout) is not finite")
    return PlannedPath(
        time_s=t,
        xy_px=y[:, :2],
        pen_down=_pen_channel(y, config.n_dims),
        xy_m=mapping.to_table(y[:, :2]),
    )


def sheet_bounds_m(scene_config: SceneConfig) -> tuple[np.ndarray, np.ndarray]:
    """The lowest and highest world ``(x, y)`` a path may reach on the sheet: its edges
    less ``SHEET_MARGIN_M``."""
    center, size = np.array(scene_config.paper_center_m), np.array(scene_config.paper_size_m)
    return center - size / 2 + SHEET_MARGIN_M, center + size / 2 - SHEET_MARGIN_M


def check_path(scene: WritingScene, plan: PlannedPath, controller_config: ControllerConfig):
    """Raise ``ValueError`` if the path leaves the paper or the arm's reach.

    Every point must lie on the sheet (:func:`sheet_bounds_m`); the arm must reach the tip
    positions along the path (on the paper, and ``lift_height_m`` above it) with the
    pen vertical, to within 0.1 mm and inside the joint limits. Returns the joint
    angles that put the tip above the first point (the start posture).
    """
    cfg = scene.config
    lo, hi = sheet_bounds_m(cfg)
    outside = np.any((plan.xy_m < lo) | (plan.xy_m > hi), axis=1)
    if outside.any():
        i = int(np.argmax(outside))
        raise ValueError(
            f"the DMP path leaves the paper: at t = {plan.time_s[i]:.3f} s the point "
            f"({plan.xy_px[i, 0]:.1f}, {plan.xy_px[i, 1]:.1f}) px maps to world "
            f"({plan.xy_m[i, 0]:.3f}, {plan.xy_m[i, 1]:.3f}) m, outside the sheet "
            f"x in [{lo[0]:.3f}, {hi[0]:.3f}], y in [{lo[1]:.3f}, {hi[1]:.3f}] m; "
            "reduce the writing height or move the writing area"
        )
    surface = cfg.paper_top_z
    lift = surface + controller_config.lift_height_m
    far = np.hypot(plan.xy_m[:, 0], plan.xy_m[:, 1]) > BEYOND_REACH_M  # no IK out there
    if far.any():
        _unreachable(plan, int(np.argmax(far)), math.nan)
    # settled in the null space: the controller's first steps do not swing the arm there
    q, residual = settled_posture(scene, [*plan.xy_m[0], lift], PEN_DOWN_ROTATION,
                                  np.array(HOME_JOINTS_RAD))  # fmt: skip
    if not residual <= IK_TOLERANCE_M:  # NaN too (a point far off)
        _unreachable(plan, 0, residual)
    q_start = q
    # Every point along the path, at most 1 mm apart, on and above the paper.
    step = np.linalg.norm(np.diff(plan.xy_m, axis=0), axis=1)
    keep = [0]
    travelled = 0.0
    for i, s in enumerate(step, start=1):
        travelled += s
        if travelled >= 1e-3 or i == len(plan.xy_m) - 1:
            keep.append(i)
            travelled = 0.0
    for height in (lift, surface):
        for i in keep:
            q, residual = scene.solve_ik(
                [*plan.xy_m[i], height], PEN_DOWN_ROTATION, q, max_iterations=100
            )
            if not residual <= IK_TOLERANCE_M:  # NaN too (a point far off)
                _unreachable(plan, i, residual)
    return q_start


def _unreachable(plan: PlannedPath, i: int, residual_m: float):
    """``ValueError`` for point ``i`` of ``plan``: by how much the pen tip misses it, or
    (``residual_m`` NaN) that it lies beyond ``BEYOND_REACH_M``."""
    x, y = (f"{v:.3f}" if abs(v) < 1e6 else f"{v:.3g}" for v in plan.xy_m[i])
    why = (f"which the pen tip misses by {residual_m * 1e3:.1f} mm with the pen vertical"
           if math.isfinite(residual_m) else
           f"more than {BEYOND_REACH_M:g} m from the arm's base")  # fmt: skip
    raise ValueError(
        f"the arm cannot reach the DMP path: at t = {plan.time_s[i]:.3f} s the point "
        f"({plan.xy_px[i, 0]:.1f}, {plan.xy_px[i, 1]:.1f}) px maps to world ({x}, {y}) m, "
        f"{why}; {move_towards(plan.xy_m[i])}"
    )


def move_towards(xy_m) -> str:
    """Which way to move a writing area whose point ``xy_m`` the arm cannot reach:
    towards the base from beyond the default centre's distance, away from it inside."""
    r = float(np.hypot(*np.asarray(xy_m, dtype=float)[:2]))
    usual = float(np.hypot(*SceneConfig().paper_center_m))
    way = "closer to" if not r < usual else "farther from"  # NaN (far off): closer
    return (
        f"move the writing area {way} the arm's base (it is {r:.2f} m away there; "
        f"the default centre is {usual:.2f} m)"
    )


def slow_for_joint_limits(
    scene: WritingScene, params: DMPParams, config: DMPConfig, plan: PlannedPath,
    mapping: PaperMapping, options: WritingOptions,
) -> tuple[DMPParams, PlannedPath, Slowing]:  # fmt: skip
    """The DMP to write and its plan, slowed (if need be) so that the joint speeds
    planned along it stay within ``options.joint_speed_share`` of the iiwa's limits and
    its joint accelerations within ``options.joint_acceleration_share`` of theirs
    (:mod:`img2dmp.robot.tempo`), and the :class:`Slowing` that says by how much.

    Slowing multiplies ``tau``: the path is the same curve (checked already), sampled at
    the control rate over the longer time. ``ValueError`` (from :func:`plan_path`) if the
    slowed DMP takes more than ``MAX_WRITING_STEPS``.
    """
    qd, qdd = _planned(scene, plan)
    slowing = slowing_for(qd, float(params.tau), options.joint_speed_share, qdd,
                          options.joint_acceleration_share)  # fmt: skip
    if not slowing.slowed:
        return params, plan, slowing
    # Planned again at the slower tempo: sampled at the control rate, a DMP's fast start
    # is resolved better there than at its own tempo, and its accelerations need not
    # fall by the whole k^2; slower again until the plan is within (a few rounds).
    factor = slowing.factor
    for round_ in range(1, MAX_SLOWING_ROUNDS + 1):
        slowed = slowed_dmp(params, factor)
        plan = plan_path(slowed, config, mapping, options.dt_s)
        qd, qdd = _planned(scene, plan)
        again = slowing_for(qd, float(slowed.tau), options.joint_speed_share, qdd,
                            options.joint_acceleration_share)  # fmt: skip
        if not again.slowed or round_ == MAX_SLOWING_ROUNDS:
            break
        factor = math.ceil(factor * again.factor * 1000) / 1000
    written = (again.speed_ratio, again.acceleration_ratio)
    return slowed, plan, dataclasses.replace(slowing, factor=factor,
                                             written_shares_planned=written)  # fmt: skip


def _planned(scene: WritingScene, plan: PlannedPath) -> tuple[np.ndarray, np.ndarray]:
    """The joint velocities and accelerations planned along ``plan`` (:mod:`.tempo`)."""
    _, qd = planned_joint_velocities(scene, plan, np.array(HOME_JOINTS_RAD), PEN_DOWN_ROTATION)
    return qd, planned_joint_accelerations(qd, plan.time_s)


def writing_metrics(log: WritingLog, force_set_n: float, tolerance: float = 0.2) -> dict:
    """Tracking and force statistics over the commanded pen-down time of the write phase
    with the DMP running (steps on which its clock was held, ``log.dwell``, excluded).

    Parameters
    ----------
    log : WritingLog
        Or a dict with the same keys.
    force_set_n : float
        The contact force set point.
    tolerance : float
        Half-width of the force band, relative to ``force_set_n``.

    Returns
    -------
    dict with
        ``tracking_error_mean_mm``, ``tracking_error_max_mm`` - in-plane distance between
        commanded and actual tip; ``force_mean_n``, ``force_std_n``; ``contact_share`` -
        share of pen-down time with the tip touching the paper; ``force_in_band_share`` -
        share with the force within ``±tolerance`` of the set point; ``pen_down_s``.
    """
    if not isinstance(log, WritingLog):
        log = WritingLog(**log)
    sel = log.in_phase("write") & log.pen_down & ~log.dwell  # [S]
    if not sel.any():
        nan = float("nan")
        return {
            "tracking_error_mean_mm": nan,
            "tracking_error_max_mm": nan,
            "force_mean_n": nan,
            "force_std_n": nan,
            "contact_share": nan,
            "force_in_band_share": nan,
            "pen_down_s": 0.0,
        }
    err_mm = np.linalg.norm(log.cmd_m[sel, :2] - log.tip_m[sel, :2], axis=1) * 1e3
    force_n = log.force_n[sel]
    dt_s = float(np.median(np.diff(log.time_s))) if log.n_steps > 1 else 0.0
    in_band = np.abs(force_n - force_set_n) <= tolerance * force_set_n
    return {
        "tracking_error_mean_mm": float(err_mm.mean()),
        "tracking_error_max_mm": float(err_mm.max()),
        "force_mean_n": float(force_n.mean()),
        "force_std_n": float(force_n.std()),
        "contact_share": float(np.mean(force_n > 0.0)),
        "force_in_band_share": float(np.mean(in_band)),
        "pen_down_s": float(sel.sum() * dt_s),
    }


def write_dmp(
    params: DMPParams,
    config: DMPConfig,
    image_size,
    *,
    writing_height_mm: float = 40.0,
    control_rate_hz: float = 240.0,
    scene_config: SceneConfig | None = None,
    controller_config: ControllerConfig | None = None,
    approach_timeout_s: float = 3.0,
    settle_s: float = 0.2,
    frame_interval_s: float | None = None,
    frame_size_px: tuple[int, int] = (320, 240),
    render_size_px: tuple[int, int] | None = (640, 480),
    stroke_dwell: bool = True,
    joint_speed_share: float | None = JOINT_SPEED_SHARE,
    joint_acceleration_share: float | None = JOINT_ACCELERATION_SHARE,
    progress=None,
    on_tempo=None,
) -> WritingResult:
    """Write one DMP with the simulated KUKA iiwa; return the log and metrics.

    Builds a :class:`WritingOptions` from the keyword arguments and calls
    :func:`write_with_options`.

    Parameters
    ----------
    params : DMPParams
        One DMP in image pixels (x = column, y = row); d = 2, or d = 3 with a pen channel.
    config : DMPConfig
    image_size : tuple (H, W)
        Size of the image the DMP lives in.
    writing_height_mm : float
        Height on paper of the whole image (see :class:`PaperMapping`).
    control_rate_hz : float
        Controller and physics rate; one DMP step, one IK solve and one physics step
        per period.
    scene_config, controller_config
        Cell geometry and controller gains; the writing area is centred on the paper.
    approach_timeout_s : float
        Give up (``RuntimeError``) if the pen has not reached the set force by then.
    settle_s : float
        Time the force must stay within 5 % of the set point before writing starts.
    frame_interval_s : float or None
        If given, keep a video frame every so many simulated seconds, and one after the
        lift: the arm and the paper seen from above with the ink so far, side by side.
    frame_size_px, render_size_px : tuple (w, h)
        Size of each half of a video frame and of the final render (arm | paper);
        ``render_size_px=None``: no final render.
    stroke_dwell : bool
        Hold the DMP clock while the pen lands and lifts (:class:`WritingOptions`).
    joint_speed_share, joint_acceleration_share : float or None
        Slow the DMP until its planned joint speeds (accelerations) stay within this share
        of their limits (0.6 both; None: not for them; :class:`WritingOptions`).
    progress, on_tempo : callable or None
        ``progress(n_steps)`` after each batch of simulated steps; ``on_tempo(tau_s)``
        once before the first, with the ``tau`` the DMP will be written at (slowed or
        not: a progress estimate from its own ``tau`` can be set right).

    ``ValueError`` for bad arguments or a path that leaves the paper or the arm's reach
    (before the simulation starts); ``RuntimeError`` when the pen did not settle at the
    set force within ``approach_timeout_s``.
    """
    options = WritingOptions(
        writing_height_mm=writing_height_mm,
        control_rate_hz=control_rate_hz,
        scene_config=scene_config or SceneConfig(),
        controller_config=controller_config or ControllerConfig(),
        approach_timeout_s=approach_timeout_s,
        settle_s=settle_s,
        frame_interval_s=frame_interval_s,
        frame_size_px=frame_size_px,
        render_size_px=render_size_px,
        stroke_dwell=stroke_dwell,
        joint_speed_share=joint_speed_share,
        joint_acceleration_share=joint_acceleration_share,
    )
    return write_with_options(
        params, config, image_size, options, progress=progress, on_tempo=on_tempo
    )


def write_with_options(
    params: DMPParams,
    config: DMPConfig,
    image_size,
    options: WritingOptions,
    *,
    progress: Callable[[int], object] | None = None,
    on_tempo: Callable[[float], object] | None = None,
) -> WritingResult:
    """:func:`write_dmp` with its settings in one :class:`WritingOptions`."""
    if not isinstance(options, WritingOptions):
        raise ValueError(f"options must be a WritingOptions, got {type(options).__name__}")
    params = checked_dmp(params, config)
    scene_cfg, ctl_cfg, dt_s = options.scene_config, options.controller_config, options.dt_s
    mapping = PaperMapping(image_size, options.writing_height_mm, scene_cfg.paper_center_m)
    options.check_video(float(params.tau))
    plan = plan_path(params, config, mapping, dt_s)  # before the scene: fails fast
    scene = WritingScene(scene_cfg, time_step_s=dt_s)
    try:
        q_start = check_path(scene, plan, ctl_cfg)
        params, plan, slowing = slow_for_joint_limits(scene, params, config, plan, mapping,
                                                      options)  # fmt: skip
        options.check_video(float(params.tau))
        if on_tempo is not None:
            on_tempo(float(params.tau))
        scene.reset_joints(q_start)
        lift_z_m = scene_cfg.paper_top_z + ctl_cfg.lift_height_m
        controller = WritingController(scene, ctl_cfg, PEN_DOWN_ROTATION, q_start, lift_z_m)
        # One exact step per control period (stable for any tau); it agrees with the
        # checked plan to ~1e-6 px.
        dmp = DMPIntegrator(params, config)
        run = WritingRun(scene, plan, controller, options, dmp, mapping, progress=progress,
                         slowing=slowing)  # fmt: skip
        return run.execute()
    finally:
        scene.close()


class WritingRun:
    """One writing run on a checked plan: approach, write, lift, each step logged.

    The scene must hold the arm at rest in the start posture (tip ``lift_height_m`` above
    the first point). :meth:`execute` runs the stages in order and returns the result;
    they can also be called one by one (then :meth:`log` and :meth:`result`).

    Parameters
    ----------
    scene : WritingScene
    plan : PlannedPath
        From :func:`plan_path`, checked by :func:`check_path`.
    controller : WritingController
        Starting at the start posture.
    options : WritingOptions
    dmp : DMPIntegrator
        The plan's DMP at ``t = 0``; it is stepped online, one step per control period.
    mapping : PaperMapping
        The mapping the plan was made with.
    progress : callable or None
        Called as ``progress(n_steps)`` every ``PROGRESS_EVERY_STEPS`` steps and at the end.
    slowing : Slowing or None
        How much the plan's DMP was slowed (:func:`slow_for_joint_limits`), for the result.
    """

    def __init__(
        self,
        scene: WritingScene,
        plan: PlannedPath,
        controller: WritingController,
        options: WritingOptions,
        dmp: DMPIntegrator,
        mapping: PaperMapping,
        *,
        progress: Callable[[int], object] | None = None,
        slowing: Slowing | None = None,
    ):
        self.scene, self.plan, self.controller = scene, plan, controller
        self.slowing = slowing
        self.options, self.dmp, self.mapping = options, dmp, mapping
        self.progress = progress
        self.dt_s = scene.time_step_s
        self.surface_z_m = scene.config.paper_top_z
        self.time_s = 0.0  # simulated
        self.approach_s = 0.0
        self.frames: list[np.ndarray] = []  # each uint8 [h, 2 w, 3]
        self._columns: dict[str, list] = {f.name: [] for f in fields(WritingLog)}
        self._ink_pending: list[np.ndarray] = []  # each [3]
        self._next_frame_s = 0.0
        self._steps_unreported = 0
        self._inset: PaperInset | None = None  # the video's paper panel, made when needed
        self.start_joints_rad = scene.joint_state()[0]  # [7]

    def execute(self) -> WritingResult:
        """Approach, write and lift; return the log, metrics and pictures."""
        wall0 = time.perf_counter()
        self.approach()
        self.write()
        self.lift()
        self._report_progress()
        wall_s = time.perf_counter() - wall0
        return self.result(wall_s)

    def approach(self) -> None:
        """Lower the pen at the first point until the force has settled (unless the DMP
        starts with the pen up); ``RuntimeError`` after ``approach_timeout_s``."""
        opt, force_set_n = self.options, self.options.controller_config.force_set_n
        needed = max(1, int(round(opt.settle_s / self.dt_s)))
        settled = 0
        while self.plan.pen_down[0] and settled < needed:
            force_n = self.control_step("approach", self.plan.xy_m[0], True, 0.0)
            self.approach_s += self.dt_s
            ok = abs(force_n - force_set_n) <= SETTLE_BAND * force_set_n
            settled = settled + 1 if ok else 0
            if self.approach_s > opt.approach_timeout_s:
                raise RuntimeError(
                    f"the pen did not settle at {force_set_n} N within "
                    f"{opt.approach_timeout_s} s of approach (last force {force_n:.2f} N)"
                )

    def write(self) -> None:
        """Run the DMP online at the control rate, one step per control period; with
        ``options.stroke_dwell`` its clock holds while the pen lands at the start of a
        stroke and leaves the paper at its end (:class:`StrokeGate`). The clock comes to
        rest at each hold and at the path's end (:class:`DMPClock`), so the pen stops
        there instead of within one step; the pen's state is the plan's."""
        down = self.plan.pen_down  # [T]
        gate = StrokeGate(self, down) if self.options.stroke_dwell else None
        hover = self._hover_steps()  # [T] bool
        clock = DMPClock(self.dt_s, clock_stops(down, gate is not None))
        while not clock.done:
            step_s, stop = clock.advance()
            y = self.dmp.step(step_s)  # [d]
            k, pen_down = clock.sample(down)
            xy_m = self.mapping.to_table(y[:2])
            if gate is not None:
                gate.before_step(xy_m, pen_down, self.dmp.t)
            self.control_step("write", xy_m, pen_down, self.dmp.t, hover=bool(hover[k]))
            if gate is not None and stop is not None:
                gate.after_step(stop, xy_m, pen_down, self.dmp.t)

    def _hover_steps(self) -> np.ndarray:
        """``[T]`` bool: the pen-up samples of the plan after which the pen goes down within
        the time it takes to come from ``lift_height_m`` to ``approach_clearance_m`` (plus
        ``HOVER_MARGIN_S``); on them the pen hovers at the clearance (``options.hover``)."""
        down = np.asarray(self.plan.pen_down, dtype=bool)  # [T]
        hover = np.zeros(len(down), dtype=bool)
        if not self.options.hover:
            return hover
        cfg = self.options.controller_config
        lead_s = axis_move_s(cfg, cfg.lift_height_m - cfg.approach_clearance_m)
        lead = int(math.ceil((max(lead_s, 0.0) + HOVER_MARGIN_S) / self.dt_s))
        touch_downs = np.flatnonzero(down[1:] & ~down[:-1]) + 1
        for k in touch_downs:
            hover[max(0, k - lead) : k] = True
        return hover & ~down

    def lift(self, *, last: bool = True) -> None:
        """Lift the pen at the DMP's end point, and wait for it to get there; ``last``:
        nothing is written after it, so the video keeps a frame of the finished writing."""
        cfg = self.options.controller_config
        end_xy_m = self.mapping.to_table(self.dmp.y[:2])
        lift_s = axis_move_s(cfg, cfg.lift_height_m) + 0.2
        for _ in range(int(round(lift_s / self.dt_s))):
            self.control_step("lift", end_xy_m, False, self.dmp.t)
        if last and self.options.frame_interval_s is not None:
            self.record_frame()  # the video ends on the finished digit

    def control_step(
        self,
        phase: str,
        xy_m,
        pen_down: bool,
        dmp_time_s: float,
        *,
        dwell: bool = False,
        hover: bool = False,
        up_height_m: float | None = None,
    ) -> float:
        """One control period and physics step towards ``xy_m``; return the force after.
        ``dwell``: the DMP clock is held on this step (logged); ``hover``: a pen that is
        up waits at the approach clearance; ``up_height_m``: a pen that is up goes to
        this height above the paper instead of ``lift_height_m``
        (:meth:`WritingController.update_axis`)."""
        scene, ctl = self.scene, self.controller
        q, qd = scene.joint_state()
        ctl.update_axis(pen_down, scene.contact_force_n(), self.surface_z_m, hover, up_height_m)
        tau = ctl.torques(xy_m, q, qd)  # [7]
        scene.step(tau)
        self.time_s += self.dt_s
        q_after, qd_after = scene.joint_state()
        tip_m, _ = scene.tip_pose()
        force_n = scene.contact_force_n()
        row = {
            "time_s": self.time_s,
            "phase": PHASES.index(phase),
            "dmp_time_s": dmp_time_s,
            "pen_down": pen_down,
            "cmd_m": (xy_m[0], xy_m[1], ctl.z_c),
            "tip_m": tip_m,
            "force_n": force_n,
            "torque_nm": tau,
            "joint_q_rad": q_after,
            "joint_qd_rad_s": qd_after,
            "dwell": dwell,
            "joint_q_ref_rad": ctl.q_d.copy(),
            "joint_qd_ref_rad_s": ctl.qd_d.copy(),
        }
        for name, value in row.items():
            self._columns[name].append(value)
        if force_n > 0.0:
            # Ink dots 0.2 mm above the sheet, so the renderer draws them over it.
            self._ink_pending.append(np.array([tip_m[0], tip_m[1], self.surface_z_m + 0.0002]))
        interval_s = self.options.frame_interval_s
        if interval_s is not None and self.time_s >= self._next_frame_s:
            self.record_frame()
            self._next_frame_s += interval_s
        self._steps_unreported += 1
        if self._steps_unreported >= PROGRESS_EVERY_STEPS:
            self._report_progress()
        return force_n

    def record_frame(self) -> None:
        """Keep a video frame: the arm | the paper seen from above, with the ink so far and
        the pen's place (:class:`PaperInset`; the camera's close-up hid the ink under the
        pen)."""
        self.flush_ink()
        size = self.options.frame_size_px
        if self._inset is None:
            self._inset = PaperInset(size, self.plan.xy_m, self.plan.pen_down)
        c = self._columns
        self._inset.add(c["tip_m"], c["force_n"])
        arm = self.scene.render(*size, **_VIDEO_VIEW)
        paper = self._inset.draw(c["tip_m"][-1] if c["tip_m"] else None, self.time_s)
        self.frames.append(np.concatenate([arm, paper], axis=1))

    def flush_ink(self) -> None:
        """Draw the pending ink dots, about 0.3 mm apart (a picture, not a measurement)."""
        if not self._ink_pending:
            return
        pts = np.array(self._ink_pending)  # [n, 3]
        keep = [0]
        for i in range(1, len(pts)):
            if np.linalg.norm(pts[i, :2] - pts[keep[-1], :2]) >= 3e-4:
                keep.append(i)
        self.scene.add_ink(pts[keep])
        self._ink_pending.clear()

    def log(self) -> WritingLog:
        """The steps so far as a :class:`WritingLog`."""
        c = self._columns
        return WritingLog(
            time_s=np.array(c["time_s"], dtype=float),
            phase=np.array(c["phase"], dtype=int),
            dmp_time_s=np.array(c["dmp_time_s"], dtype=float),
            pen_down=np.array(c["pen_down"], dtype=bool),
            cmd_m=np.array(c["cmd_m"], dtype=float).reshape(-1, 3),
            tip_m=np.array(c["tip_m"], dtype=float).reshape(-1, 3),
            force_n=np.array(c["force_n"], dtype=float),
            torque_nm=np.array(c["torque_nm"], dtype=float).reshape(-1, 7),
            joint_q_rad=np.array(c["joint_q_rad"], dtype=float).reshape(-1, 7),
            joint_qd_rad_s=np.array(c["joint_qd_rad_s"], dtype=float).reshape(-1, 7),
            dwell=np.array(c["dwell"], dtype=bool),
            joint_q_ref_rad=np.array(c["joint_q_ref_rad"], dtype=float).reshape(-1, 7),
            joint_qd_ref_rad_s=np.array(c["joint_qd_ref_rad_s"], dtype=float).reshape(-1, 7),
        )

    def run_figures(self, wall_s: float, approach_s: float) -> dict:
        """The run's own figures beside its writing metrics: simulated and wall time, the
        real-time factor, the control rate, the force set point, the approach time."""
        return {
            "simulated_s": float(self.time_s),
            "wall_s": float(wall_s),
            "real_time_factor": float(self.time_s / wall_s) if wall_s > 0 else float("inf"),
            "control_rate_hz": 1.0 / self.dt_s,
            "force_set_n": self.options.controller_config.force_set_n,
            "approach_s": approach_s,
        }

    def result(self, wall_s: float) -> WritingResult:
        """Log, metrics (the loop took ``wall_s``), the remaining ink and the final render."""
        log = self.log()
        ctl_cfg = self.options.controller_config
        metrics = writing_metrics(log, ctl_cfg.force_set_n)
        metrics.update(self.run_figures(wall_s, float(self.approach_s)))
        metrics.update(stroke_report(self.plan, log, ctl_cfg.force_set_n))
        metrics.update(joint_speed_metrics(log))
        metrics.update(joint_acceleration_metrics(log))
        if self.slowing is not None:
            metrics.update(self.slowing.to_dict())
        self.flush_ink()
        return WritingResult(
            log=log,
            metrics=metrics,
            plan=self.plan,
            mapping=self.mapping,
            scene_config=self.scene.config,
            controller_config=ctl_cfg,
            frames=self.frames,
            render=self.final_render(),
            start_joints_rad=self.start_joints_rad,
            slowing=self.slowing,
        )

    def final_render(self) -> np.ndarray | None:
        """The arm at the end | a top-down close-up of the paper (None if not asked for)."""
        size = self.options.render_size_px
        if size is None:
            return None
        arm = self.scene.render(*size, **_ARM_VIEW)
        # For the close-up the arm is moved up out of the camera's view (after the
        # simulation: it is only a picture).
        self.scene.reset_joints(np.array(HOME_JOINTS_RAD))
        paper = self.scene.render(*size, shadow=False, **_paper_view(self.mapping, size))
        return np.concatenate([arm, paper], axis=1)

    def _report_progress(self) -> None:
        if self.progress is not None and self._steps_unreported:
            self.progress(self._steps_unreported)
        self._steps_unreported = 0


_ARM_VIEW = {"target_m": (0.35, 0.0, 0.25), "distance_m": 1.3, "yaw_deg": 55.0, "pitch_deg": -28.0}
_VIDEO_VIEW = {
    "target_m": (0.45, 0.0, 0.12),
    "distance_m": 0.75,
    "yaw_deg": 60.0,
    "pitch_deg": -35.0,
}


def _paper_view(mapping: PaperMapping, size_px: tuple[int, int]) -> dict:
    """Top-down close-up of the writing area, image-up pointing away from the robot, with
    room around it: the camera's 45 degree field of view is vertical, the area's width
    lies across a picture of ``size_px`` (w, h)."""
    width_mm, height_mm = mapping.area_size_mm
    extent_m = max(height_mm, width_mm * size_px[1] / size_px[0]) * 1e-3
    return {
        "target_m": (mapping.center_m[0], mapping.center_m[1], 0.0),
        "distance_m": max(0.05, 1.5 * extent_m / (2 * math.tan(math.radians(22.5)))),
        "yaw_deg": -90.0,
        "pitch_deg": -89.9,
    }
