"""Executing a DMP with the simulated arm: map pixels to the paper, check, write, measure.

The sequence of :func:`write_dmp`:

1. **Plan and check** (before anything moves): integrate the DMP at the control rate,
   map every point from image pixels to the paper (:class:`PaperMapping`), and raise
   ``ValueError`` if a point leaves the sheet or the arm cannot reach it with the pen
   vertical (inverse kinematics along the whole path, within joint limits).
2. **Approach**: the arm starts at rest with the tip ``lift_height_m`` above the first
   point; the admittance law lowers the pen until it presses with the set force.
3. **Write**: the DMP runs online, one :meth:`DMPIntegrator.step` per control step; its
   x, y go through the mapping to the Cartesian target, its pen channel (d = 3) lifts
   and lowers the pen.
4. **Lift** the pen off the paper at the end point.

Metrics are taken over the commanded pen-down time of phase 3.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..dmp import DMPConfig, DMPIntegrator, DMPParams
from .controller import ControllerConfig, WritingController
from .scene import HOME_JOINTS_RAD, SceneConfig, WritingScene

# The pen points straight down; the flange's x axis points back towards the robot.
PEN_DOWN_ROTATION = np.diag([-1.0, 1.0, -1.0])
PHASES = ("approach", "write", "lift")
PEN_THRESHOLD = 0.5
IK_TOLERANCE_M = 1e-4


@dataclass(frozen=True)
class PaperMapping:
    """Image pixels to metres on the paper, as a writer sitting at the robot sees it.

    The image's up direction (decreasing row) points away from the robot (world +x),
    its right direction (increasing column) points to the writer's right (world -y), and
    the image centre lands on ``center_m``. ``writing_height_mm`` is the height of the
    whole image on paper, so a digit filling a 28-pixel MNIST image is about that tall.

    Parameters
    ----------
    image_size : tuple (H, W)
        Image size in pixels.
    writing_height_mm : float
        Height on paper of the full image height H.
    center_m : tuple (x, y)
        World position of the image centre, metres.
    """

    image_size: tuple[int, int]
    writing_height_mm: float = 40.0
    center_m: tuple[float, float] = (0.55, 0.0)

    def __post_init__(self) -> None:
        h, w = self.image_size
        if not (int(h) == h and int(w) == w and h > 0 and w > 0):
            raise ValueError(f"image_size must be two positive integers, got {self.image_size}")
        if not (math.isfinite(self.writing_height_mm) and self.writing_height_mm > 0):
            raise ValueError(f"writing_height_mm must be > 0, got {self.writing_height_mm!r}")

    @property
    def metres_per_px(self) -> float:
        return self.writing_height_mm * 1e-3 / self.image_size[0]

    def to_table(self, xy_px) -> np.ndarray:
        """``[..., 2]`` pixels (x = column, y = row) to world ``[..., 2]`` (x, y) metres."""
        xy = np.asarray(xy_px, dtype=float)
        h, w = self.image_size
        s = self.metres_per_px
        wx = self.center_m[0] - (xy[..., 1] - (h - 1) / 2) * s
        wy = self.center_m[1] - (xy[..., 0] - (w - 1) / 2) * s
        return np.stack([wx, wy], axis=-1)

    def to_pixels(self, xy_m) -> np.ndarray:
        """Inverse of :meth:`to_table`."""
        xy = np.asarray(xy_m, dtype=float)
        h, w = self.image_size
        s = self.metres_per_px
        col = (w - 1) / 2 - (xy[..., 1] - self.center_m[1]) / s
        row = (h - 1) / 2 - (xy[..., 0] - self.center_m[0]) / s
        return np.stack([col, row], axis=-1)


@dataclass
class PlannedPath:
    """The DMP integrated at the control rate and mapped to the paper (checked)."""

    time_s: np.ndarray  # [T]
    xy_px: np.ndarray  # [T, 2]
    pen_down: np.ndarray  # [T] bool
    xy_m: np.ndarray  # [T, 2]


@dataclass
class WritingResult:
    """Everything a writing run produced.

    Attributes
    ----------
    log : dict of str -> ndarray [S, ...]
        One row per control step: ``time_s``, ``phase`` (index into ``PHASES``),
        ``dmp_time_s``, ``pen_down``, ``cmd_m [S, 3]``, ``tip_m [S, 3]``, ``force_n``,
        ``torque_nm [S, 7]``.
    metrics : dict
        See :func:`writing_metrics`.
    plan : PlannedPath
    mapping : PaperMapping
    frames : list of ndarray
        Camera frames ``uint8 [h, w, 3]`` if requested.
    """

    log: dict
    metrics: dict
    plan: PlannedPath
    mapping: PaperMapping
    scene_config: SceneConfig
    controller_config: ControllerConfig
    frames: list = field(default_factory=list)
    render: np.ndarray | None = None


def _pen_channel(y: np.ndarray, n_dims: int) -> np.ndarray:
    if n_dims == 2:
        return np.ones(y.shape[:-1], dtype=bool)
    return y[..., 2] >= PEN_THRESHOLD


def plan_path(
    params: DMPParams, config: DMPConfig, mapping: PaperMapping, dt_s: float
) -> PlannedPath:
    """Integrate one DMP at steps of ``dt_s`` over ``[0, tau]`` and map it to the paper."""
    if config.n_dims not in (2, 3):
        raise ValueError(
            f"a writing DMP has d = 2 (x, y) or d = 3 (x, y, pen), got d = {config.n_dims}"
        )
    integ = DMPIntegrator(params, config, max_step=dt_s)
    n = max(1, int(round(integ.tau / dt_s)))
    ys = [integ.y.copy()]
    for _ in range(n):
        ys.append(integ.step(dt_s))
    y = np.array(ys)  # [T, d]
    t = np.arange(n + 1) * dt_s
    return PlannedPath(
        time_s=t,
        xy_px=y[:, :2],
        pen_down=_pen_channel(y, config.n_dims),
        xy_m=mapping.to_table(y[:, :2]),
    )


def check_path(scene: WritingScene, plan: PlannedPath, controller_config: ControllerConfig):
    """Raise ``ValueError`` if the path leaves the paper or the arm's reach.

    Every point must lie on the sheet (with a 2 mm margin); the arm must reach the tip
    positions along the path (on the paper, and ``lift_height_m`` above it) with the
    pen vertical, to within 0.1 mm and inside the joint limits. Returns the joint
    angles that put the tip above the first point (the start posture).
    """
    cfg = scene.config
    margin = 0.002
    lo = np.array(cfg.paper_center_m) - np.array(cfg.paper_size_m) / 2 + margin
    hi = np.array(cfg.paper_center_m) + np.array(cfg.paper_size_m) / 2 - margin
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
    q, residual = scene.solve_ik(
        [*plan.xy_m[0], lift], PEN_DOWN_ROTATION, np.array(HOME_JOINTS_RAD), max_iterations=200
    )
    if residual > IK_TOLERANCE_M:
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
            if residual > IK_TOLERANCE_M:
                _unreachable(plan, i, residual)
    return q_start


def _unreachable(plan: PlannedPath, i: int, residual_m: float):
    raise ValueError(
        f"the arm cannot reach the DMP path: at t = {plan.time_s[i]:.3f} s the point "
        f"({plan.xy_px[i, 0]:.1f}, {plan.xy_px[i, 1]:.1f}) px maps to world "
        f"({plan.xy_m[i, 0]:.3f}, {plan.xy_m[i, 1]:.3f}) m, which the pen tip misses by "
        f"{residual_m * 1e3:.1f} mm with the pen vertical; move the writing area closer"
    )


def writing_metrics(log: dict, force_set_n: float, tolerance: float = 0.2) -> dict:
    """Tracking and force statistics over the commanded pen-down time of the write phase.

    Returns
    -------
    dict with
        ``tracking_error_mean_mm``, ``tracking_error_max_mm`` - in-plane distance between
        commanded and actual tip; ``force_mean_n``, ``force_std_n``; ``contact_share`` -
        share of pen-down time with the tip touching the paper; ``force_in_band_share`` -
        share with the force within ``±tolerance`` of the set point; ``pen_down_s``.
    """
    sel = (log["phase"] == PHASES.index("write")) & log["pen_down"]
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
    err_mm = np.linalg.norm(log["cmd_m"][sel, :2] - log["tip_m"][sel, :2], axis=1) * 1e3
    f = log["force_n"][sel]
    dt = float(np.median(np.diff(log["time_s"]))) if len(log["time_s"]) > 1 else 0.0
    return {
        "tracking_error_mean_mm": float(err_mm.mean()),
        "tracking_error_max_mm": float(err_mm.max()),
        "force_mean_n": float(f.mean()),
        "force_std_n": float(f.std()),
        "contact_share": float(np.mean(f > 0.0)),
        "force_in_band_share": float(np.mean(np.abs(f - force_set_n) <= tolerance * force_set_n)),
        "pen_down_s": float(sel.sum() * dt),
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
    progress=None,
) -> WritingResult:
    """Write one DMP with the simulated KUKA iiwa; return the log and metrics.

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
        If given, keep a camera frame every so many simulated seconds (for a video):
        the arm and a close-up of the pen on the paper, side by side.
    frame_size_px, render_size_px : tuple (w, h)
        Size of each half of a video frame and of the final render (arm | paper);
        ``render_size_px=None``: no final render.
    progress : callable or None
        Called as ``progress(n_steps)`` after each batch of simulated steps.

    Raises
    ------
    ValueError
        Bad arguments, or a path that leaves the paper or the arm's reach (raised before
        the simulation starts).
    """
    if not (math.isfinite(control_rate_hz) and 100.0 <= control_rate_hz <= 10000.0):
        raise ValueError(f"control_rate_hz must be in [100, 10000], got {control_rate_hz!r}")
    if frame_interval_s is not None and not (frame_interval_s > 0):
        raise ValueError(f"frame_interval_s must be > 0, got {frame_interval_s!r}")
    scene_config = scene_config or SceneConfig()
    ctl_cfg = controller_config or ControllerConfig()
    params = params.to_numpy()
    if params.batch_shape != ():
        raise ValueError(f"write_dmp runs one DMP, got batch shape {params.batch_shape}")
    params.validate(config)
    mapping = PaperMapping(tuple(image_size), writing_height_mm, scene_config.paper_center_m)
    dt = 1.0 / control_rate_hz

    scene = WritingScene(scene_config, time_step_s=dt)
    try:
        plan = plan_path(params, config, mapping, dt)
        q_start = check_path(scene, plan, ctl_cfg)
        return _simulate(
            scene,
            params,
            config,
            mapping,
            plan,
            ctl_cfg,
            q_start,
            approach_timeout_s=approach_timeout_s,
            settle_s=settle_s,
            frame_interval_s=frame_interval_s,
            frame_size_px=frame_size_px,
            render_size_px=render_size_px,
            progress=progress,
        )
    finally:
        scene.close()


def _simulate(
    scene: WritingScene,
    params,
    config,
    mapping,
    plan,
    ctl_cfg,
    q_start,
    *,
    approach_timeout_s,
    settle_s,
    frame_interval_s,
    frame_size_px,
    render_size_px,
    progress,
) -> WritingResult:
    dt = scene.time_step_s
    surface = scene.config.paper_top_z
    scene.reset_joints(q_start)
    ctl = WritingController(
        scene, ctl_cfg, PEN_DOWN_ROTATION, q_start, surface + ctl_cfg.lift_height_m
    )
    # One RK4 step per control period: at 240 Hz it differs from 1 ms sub-steps by
    # about 2e-7 px (DMP time constants are tens of milliseconds and longer).
    integ = DMPIntegrator(params, config, max_step=dt)
    rows: list[tuple] = []
    frames: list[np.ndarray] = []
    ink_pending: list[np.ndarray] = []
    next_frame_s = 0.0
    t_sim = 0.0
    wall0 = time.perf_counter()
    n_since_progress = 0

    def control_step(phase: int, xy_m, pen_down: bool, dmp_t: float) -> float:
        nonlocal t_sim, next_frame_s, n_since_progress
        q, qd = scene.joint_state()
        force = scene.contact_force_n()
        ctl.update_axis(pen_down, force, surface)
        tau = ctl.torques(xy_m, q, qd)
        scene.step(tau)
        t_sim += dt
        tip, _ = scene.tip_pose()
        force_after = scene.contact_force_n()
        rows.append(
            (t_sim, phase, dmp_t, pen_down, xy_m[0], xy_m[1], ctl.z_c, *tip, force_after, *tau)
        )
        if force_after > 0.0:
            ink_pending.append(np.array([tip[0], tip[1], surface + 0.0002]))
        if frame_interval_s is not None and t_sim >= next_frame_s:
            _flush_ink(scene, ink_pending)
            frames.append(
                np.concatenate(
                    [
                        scene.render(*frame_size_px, **_VIDEO_VIEW),
                        scene.render(*frame_size_px, shadow=False, **_pen_view(mapping)),
                    ],
                    axis=1,
                )
            )
            next_frame_s += frame_interval_s
        n_since_progress += 1
        if progress is not None and n_since_progress >= 24:
            progress(n_since_progress)
            n_since_progress = 0
        return force_after

    # Approach: lower the pen at the first point until the force has settled (unless
    # the DMP starts with the pen up).
    start_xy = plan.xy_m[0]
    settled_steps, needed = 0, max(1, int(round(settle_s / dt)))
    t_approach = 0.0
    while plan.pen_down[0] and settled_steps < needed:
        force = control_step(0, start_xy, True, 0.0)
        t_approach += dt
        ok = abs(force - ctl_cfg.force_set_n) <= 0.05 * ctl_cfg.force_set_n
        settled_steps = settled_steps + 1 if ok else 0
        if t_approach > approach_timeout_s:
            raise RuntimeError(
                f"the pen did not settle at {ctl_cfg.force_set_n} N within "
                f"{approach_timeout_s} s of approach (last force {force:.2f} N)"
            )
    # Write: the DMP runs online at the control rate.
    n_write = len(plan.time_s) - 1
    for _ in range(n_write):
        y = integ.step(dt)
        xy_m = mapping.to_table(y[:2])
        pen = bool(_pen_channel(y, config.n_dims))
        control_step(1, xy_m, pen, integ.t)

    # Lift at the end point.
    end_xy = mapping.to_table(integ.y[:2])
    lift_s = ctl_cfg.lift_height_m / ctl_cfg.travel_speed_m_s + 0.2
    for _ in range(int(round(lift_s / dt))):
        control_step(2, end_xy, False, integ.t)
    if progress is not None and n_since_progress:
        progress(n_since_progress)
    wall_s = time.perf_counter() - wall0

    arr = np.array(rows, dtype=float)
    log = {
        "time_s": arr[:, 0],
        "phase": arr[:, 1].astype(int),
        "dmp_time_s": arr[:, 2],
        "pen_down": arr[:, 3].astype(bool),
        "cmd_m": arr[:, 4:7],
        "tip_m": arr[:, 7:10],
        "force_n": arr[:, 10],
        "torque_nm": arr[:, 11:18],
    }
    metrics = writing_metrics(log, ctl_cfg.force_set_n)
    metrics.update(
        {
            "simulated_s": float(t_sim),
            "wall_s": float(wall_s),
            "real_time_factor": float(t_sim / wall_s) if wall_s > 0 else float("inf"),
            "control_rate_hz": 1.0 / dt,
            "force_set_n": ctl_cfg.force_set_n,
            "approach_s": float(t_approach),
        }
    )
    _flush_ink(scene, ink_pending)
    render = None
    if render_size_px is not None:
        arm = scene.render(*render_size_px, **_ARM_VIEW)
        # For the close-up the arm is moved up out of the camera's view (after the
        # simulation: it is only a picture).
        scene.reset_joints(np.array(HOME_JOINTS_RAD))
        paper = scene.render(*render_size_px, shadow=False, **_paper_view(mapping))
        render = np.concatenate([arm, paper], axis=1)
    return WritingResult(
        log=log,
        metrics=metrics,
        plan=plan,
        mapping=mapping,
        scene_config=scene.config,
        controller_config=ctl_cfg,
        frames=frames,
        render=render,
    )


_ARM_VIEW = {"target_m": (0.35, 0.0, 0.25), "distance_m": 1.3, "yaw_deg": 55.0, "pitch_deg": -28.0}
_VIDEO_VIEW = {
    "target_m": (0.45, 0.0, 0.12),
    "distance_m": 0.75,
    "yaw_deg": 60.0,
    "pitch_deg": -35.0,
}


def _paper_view(mapping: PaperMapping) -> dict:
    """Top-down close-up of the writing area, image-up pointing away from the robot."""
    height_m = mapping.writing_height_mm * 1e-3
    return {
        "target_m": (mapping.center_m[0], mapping.center_m[1], 0.0),
        "distance_m": max(0.05, 1.5 * height_m / (2 * math.tan(math.radians(22.5)))),
        "yaw_deg": -90.0,
        "pitch_deg": -89.9,
    }


def _pen_view(mapping: PaperMapping) -> dict:
    """Close-up of the writing area from behind the pen (robot side), digit upright."""
    return {
        "target_m": (mapping.center_m[0], mapping.center_m[1], 0.0),
        "distance_m": max(0.05, 3.0 * mapping.writing_height_mm * 1e-3),
        "yaw_deg": -90.0,
        "pitch_deg": -50.0,
    }


def _flush_ink(scene: WritingScene, pending: list) -> None:
    if pending:
        pts = np.array(pending)
        # Keep dots about 0.3 mm apart; the ink is a picture, not a measurement.
        keep = [0]
        for i in range(1, len(pts)):
            if np.linalg.norm(pts[i, :2] - pts[keep[-1], :2]) >= 3e-4:
                keep.append(i)
        scene.add_ink(pts[keep])
        pending.clear()
