"""Slowing a DMP so that a real iiwa's joints can follow it, and the joint speeds and
accelerations of a run.

The simulated arm is driven by joint torques (up to 300 N m) and follows a DMP at any
speed it is asked to; a real LBR iiwa does not: its axes have speed limits
(:data:`img2dmp.robot.joints.IIWA_VELOCITY_LIMITS_RAD_S`, 75 to 135 deg/s) and cannot
accelerate without bound (:data:`~img2dmp.robot.joints.IIWA_ACCELERATION_LIMITS_RAD_S2`:
10 rad/s^2, a widely used planning limit; KUKA publishes none). A DMP that is short for
its length (e.g. a stroke model's stroke of 36 mm in 0.22 s, peaking at 0.76 m/s on the
paper) asks joint 4 for twice its speed limit and 24 times that acceleration. Before
anything moves:

1. **Plan the joints** (:func:`planned_joint_velocities`,
   :func:`planned_joint_accelerations`): the controller's own inverse kinematics
   (:meth:`WritingScene.solve_ik`, warm-started, with its step towards the home posture
   in the null space) at every sample of the planned path, the pen on the paper; the
   joint velocities and accelerations are their finite differences at the control rate,
   as the controller's ``qd_d`` and ``qdd_d``, from rest at the first point.
2. **Slow the DMP** (:func:`slowing_for`, :func:`slowed_dmp`): if a planned joint speed
   exceeds ``share`` (``JOINT_SPEED_SHARE``, 60 %) of its limit, or a planned joint
   acceleration ``acceleration_share`` (``JOINT_ACCELERATION_SHARE``, 60 %) of its
   limit, the DMP's duration is multiplied by the smallest factor ``k`` that brings every
   joint within both. Scaling ``tau`` is exact: the DMP's path is ``y(t / k)``, the same
   curve on the paper, every Cartesian and joint velocity divided by ``k`` and every
   acceleration by ``k**2``. The speed share leaves room for what the plan does not see:
   the tracking transients of the torque controller (measured on the letters page: the
   simulated arm's peak about 1.25 times the planned one on a jerky stroke) and the
   pen's landing; the acceleration share leaves room for the same transients and for
   the pen's friction on the paper (``JOINT_ACCELERATION_SHARE``).
3. **Measure** (:func:`joint_speed_metrics`, :func:`joint_acceleration_metrics`): the
   peak speed and acceleration of every joint over the whole run, against its limits.
   The run's accelerations also hold what the plan does not: the controller's own
   landings and lifts (:func:`~img2dmp.robot.controller.axis_speed_towards`, ramped),
   the DMP clock's stops and starts (:class:`~img2dmp.robot.strokes.DMPClock`, ramped)
   and the start from rest (a start posture settled in the null space).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..dmp import DMPParams
from .joints import IIWA_ACCELERATION_LIMITS_RAD_S2, IIWA_JOINT_NAMES, IIWA_VELOCITY_LIMITS_RAD_S

#: Planned joint speeds are kept within this share of the iiwa's limits.
JOINT_SPEED_SHARE = 0.6
#: Planned joint accelerations are kept within this share of their limits. The simulated
#: arm's own peaks while it writes are up to 1.2 times the planned ones on the heavy joints
#: (its tracking) and up to 2.3 times on the light wrist (the pen's friction on the paper
#: at a stroke's sharp turn); at 0.6 its peak over a whole run stays within the limit on
#: the samples of ``examples/samples`` (1.0: 12.5 rad/s^2 on the letters page; 0.75: 11.5).
JOINT_ACCELERATION_SHARE = 0.6
#: Planned accelerations are read over this window at least (the default control
#: period): see :func:`planned_joint_accelerations`.
ACCELERATION_WINDOW_S = 1.0 / 240.0
# The null-space steps that settle the start posture (the arm waits at the first point
# for the approach and the settling, far longer, before the DMP starts).
_SETTLE_ITERATIONS = 100
# The controller's IK iterations per control step (WritingController.torques).
_CONTROLLER_IK_ITERATIONS = 10


def planned_joint_velocities(scene, plan, q_seed_rad, rotation) -> tuple[np.ndarray, np.ndarray]:
    """The joint positions ``[T, 7]`` and velocities ``[T, 7]`` the controller will
    command along ``plan`` (a :class:`~img2dmp.robot.writing.PlannedPath`).

    The tip on the paper (``scene.config.paper_top_z``) at every sample, with orientation
    ``rotation``: the DMP sets the pen's motion in the plane; its landings and lifts are
    the controller's own, at most ``travel_speed_m_s`` (0.1 m/s) along the pen, and not
    part of the plan. The first sample is solved from ``q_seed_rad`` and settled in the
    null space towards the home posture, as the controller's posture is by the time the
    DMP starts (the arm waits there at rest: its velocity is 0); every later one as the
    controller solves it (:meth:`WritingController.torques`: warm-started from the sample
    before, with the null-space step towards the home posture); the velocities are the
    finite differences at the plan's time steps, the controller's ``qd_d``.
    """
    z_m = scene.config.paper_top_z
    q, _ = settled_posture(scene, [*plan.xy_m[0], z_m], rotation, q_seed_rad)
    qs = np.empty((len(plan.time_s), 7))  # [T, 7]
    qs[0] = q
    for i in range(1, len(qs)):
        q, _ = scene.solve_ik([*plan.xy_m[i], z_m], rotation, q,
                              max_iterations=_CONTROLLER_IK_ITERATIONS,
                              min_iterations=1)  # fmt: skip
        qs[i] = q
    qd = np.zeros_like(qs)  # [T, 7]
    qd[1:] = np.diff(qs, axis=0) / np.diff(plan.time_s)[:, None]
    return qs, qd


def settled_posture(scene, position_m, rotation, q_seed_rad) -> tuple[np.ndarray, float]:
    """The joint angles that put the tip at ``position_m`` with ``rotation``, settled in
    the null space towards the home posture (:meth:`WritingScene.solve_ik` from
    ``q_seed_rad``, then its null-space step until it stands still), and the residual.

    The controller's IK takes that step whenever it is not yet within its tolerance: from
    a posture not settled, its first solves swung joints 1, 3, 5 and 7 along the null
    space (joint 5 at 120-155 rad/s^2 on the first control step of a page)."""
    q, _ = scene.solve_ik(position_m, rotation, q_seed_rad, max_iterations=200)
    # tol 0: every iteration takes its null-space step (a converged solve stops before it)
    return scene.solve_ik(position_m, rotation, q, max_iterations=_SETTLE_ITERATIONS, tol_m=0.0)


def _figure(value: float) -> str:
    """A peak or a share in words: three figures below 100 (``60.5``: a DMP slowed 1.01x
    for a share of 60 % is not said to be at ``60``), whole numbers above (``2404``)."""
    return f"{value:.3g}" if abs(value) < 100 else f"{value:.0f}"


def planned_joint_accelerations(qd_rad_s, time_s) -> np.ndarray:
    """``[T, 7]`` joint accelerations of planned velocities ``qd_rad_s [T, 7]`` at times
    ``time_s [T]`` (evenly spaced; :func:`planned_joint_velocities`): at the default
    control rate their finite differences, the controller's ``qdd_d``; the first 0 (the
    arm at rest before the DMP starts, whose first velocity sample ``qd[0]`` is 0, so
    ``qdd[1]`` is the start from rest).

    At a faster control rate they are read over ``ACCELERATION_WINDOW_S``: the second
    difference of the positions ``s`` samples apart (``s`` samples to the window, the arm
    at rest before the first; ``s = 1`` is the above), so that what is planned does not
    depend on the rate. An IK that skipped the control steps on which its warm start was
    already within tolerance moved the joints by about a micro-radian here and there,
    which differences 1 ms apart read as several rad/s^2 (a 3 s digit at 1 kHz: 6.55
    rad/s^2 planned, 1.28 at 240 Hz) and which no slowing removes; the IK now takes a
    step every control period (``min_iterations=1``), and the digit's 1 ms differences
    read 1.29 rad/s^2, its window 1.28."""
    qd = np.asarray(qd_rad_s, dtype=float)
    qdd = np.zeros_like(qd)  # [T, 7]
    if len(qd) < 2:
        return qdd
    dt = np.diff(np.asarray(time_s, dtype=float))  # [T-1]
    h = float(np.median(dt))
    s = max(1, int(round(ACCELERATION_WINDOW_S / h)))
    if s == 1:
        qdd[1:] = np.diff(qd, axis=0) / dt[:, None]
        return qdd
    moved = np.cumsum(qd[1:] * dt[:, None], axis=0)  # [T-1, 7]: q[k] - q[0], k >= 1
    p = np.concatenate([np.zeros((2 * s + 1, qd.shape[1])), moved])  # [T + 2s, 7]
    return (p[2 * s :] - 2.0 * p[s:-s] + p[: -2 * s]) / (s * h) ** 2


@dataclass(frozen=True)
class Slowing:
    """How much one DMP is slowed for the iiwa's joint speed and acceleration limits.

    Attributes
    ----------
    factor : float
        The DMP's duration is multiplied by it (1: not slowed).
    joint : int
        The joint (0-based) that asked for the most speed, relative to its limit.
    planned_peak_rad_s : float
        That joint's planned peak speed at the DMP's own tempo.
    limit_rad_s : float
        That joint's limit.
    share : float
        The share of the speed limits the planned speeds are kept within.
    tau_s : float
        The DMP's duration before slowing.
    acceleration_joint : int
        The joint that asked for the most acceleration, relative to its limit.
    planned_acceleration_peak_rad_s2 : float
        Its planned peak acceleration at the DMP's own tempo (NaN: not planned).
    acceleration_limit_rad_s2 : float
    acceleration_share : float
        The share of the acceleration limits the planned accelerations are kept within.
    written_shares_planned : (float, float) or None
        The peak speed and acceleration over their limits planned again at the tempo
        written (:func:`~img2dmp.robot.writing.slow_for_joint_limits`); None: not
        planned again (not slowed).
    """

    factor: float
    joint: int
    planned_peak_rad_s: float
    limit_rad_s: float
    share: float
    tau_s: float
    acceleration_joint: int = 0
    planned_acceleration_peak_rad_s2: float = math.nan
    acceleration_limit_rad_s2: float = float(IIWA_ACCELERATION_LIMITS_RAD_S2[0])
    acceleration_share: float = 1.0
    written_shares_planned: tuple[float, float] | None = None

    @property
    def slowed(self) -> bool:
        return self.factor > 1.0

    @property
    def joint_name(self) -> str:
        return IIWA_JOINT_NAMES[self.joint]

    @property
    def speed_ratio(self) -> float:
        """The planned peak speed over its limit at the DMP's own tempo."""
        return self.planned_peak_rad_s / self.limit_rad_s

    @property
    def acceleration_ratio(self) -> float:
        """The planned peak acceleration over its limit at the DMP's own tempo."""
        return self.planned_acceleration_peak_rad_s2 / self.acceleration_limit_rad_s2

    @property
    def by_acceleration(self) -> bool:
        """The acceleration, not the speed, set the factor."""
        return bool(self.acceleration_ratio / self.acceleration_share
                    > (self.speed_ratio / self.share) ** 2)  # fmt: skip

    def written_shares(self) -> tuple[float, float]:
        """The planned peak speed and acceleration over their limits at the tempo
        written: planned again when slowed (``written_shares_planned``), else those at
        its own tempo."""
        if self.written_shares_planned is not None:
            return self.written_shares_planned
        return self.speed_ratio, self.acceleration_ratio

    def words(self) -> str:
        """``"2.97x slower (0.221 s -> 0.656 s): at its own tempo lbr_iiwa_joint_4 would
        reach 2.33 rad/s, 178 % of the iiwa's limit of 1.31 rad/s"``, or for a factor
        the acceleration set, ``"... would accelerate at 240 rad/s^2, 2404 % of the
        planning limit of 10 rad/s^2"``."""
        head = (f"{self.factor:.2f}x slower ({self.tau_s:.3f} s -> "
                f"{self.tau_s * self.factor:.3f} s): at its own tempo ")  # fmt: skip
        if self.by_acceleration:
            return head + (
                f"{IIWA_JOINT_NAMES[self.acceleration_joint]} would accelerate at "
                f"{_figure(self.planned_acceleration_peak_rad_s2)} rad/s^2, "
                f"{_figure(100 * self.acceleration_ratio)} % of the planning limit of "
                f"{self.acceleration_limit_rad_s2:g} rad/s^2"
            )
        return head + (
            f"{self.joint_name} would reach {self.planned_peak_rad_s:.2f} rad/s, "
            f"{_figure(100 * self.speed_ratio)} % of the iiwa's limit of "
            f"{self.limit_rad_s:.2f} rad/s"
        )

    def to_dict(self) -> dict:
        speed, acceleration = self.written_shares()
        return {
            "slowdown": self.factor,
            "slowdown_joint": self.joint_name,
            "slowdown_by": "acceleration" if self.by_acceleration else "speed",
            "planned_joint_speed_peak_rad_s": self.planned_peak_rad_s,
            "planned_joint_acceleration_peak_rad_s2": self.planned_acceleration_peak_rad_s2,
            "planned_joint_acceleration_joint": IIWA_JOINT_NAMES[self.acceleration_joint],
            "planned_joint_speed_share": speed,
            "planned_joint_acceleration_share": acceleration,
            "tau_s": self.tau_s,
            "written_tau_s": self.tau_s * self.factor,
        }


def slowing_for(qd_rad_s: np.ndarray, tau_s: float, share: float | None,
                qdd_rad_s2: np.ndarray | None = None,
                acceleration_share: float | None = None) -> Slowing:  # fmt: skip
    """The :class:`Slowing` that keeps planned joint velocities ``qd_rad_s [T, 7]`` of a
    DMP of ``tau_s`` seconds within ``share`` of the iiwa's speed limits and its planned
    accelerations ``qdd_rad_s2 [T, 7]`` within ``acceleration_share`` of theirs: ``k =
    max(1, v / share, sqrt(a / acceleration_share))`` for the peak ratios ``v`` and ``a``
    (a share None: that limit only measured, not slowed for)."""
    peaks = np.abs(np.asarray(qd_rad_s, dtype=float)).max(axis=0)  # [7]
    ratio = peaks / IIWA_VELOCITY_LIMITS_RAD_S
    j = int(np.argmax(ratio))
    factors = [1.0]
    if share is not None:
        factors.append(float(ratio[j]) / share)
    ja, acc_peak = 0, math.nan
    if qdd_rad_s2 is not None:
        acc = np.abs(np.asarray(qdd_rad_s2, dtype=float)).max(axis=0)  # [7]
        acc_ratio = acc / IIWA_ACCELERATION_LIMITS_RAD_S2
        ja, acc_peak = int(np.argmax(acc_ratio)), float(acc[int(np.argmax(acc_ratio))])
        if acceleration_share is not None:
            factors.append(math.sqrt(float(acc_ratio[ja]) / acceleration_share))
    factor = max(factors)
    if factor > 1.0:  # round up a little, so the slowed plan lands inside, not on, the share
        factor = math.ceil(factor * 1000) / 1000
    return Slowing(factor, j, float(peaks[j]), float(IIWA_VELOCITY_LIMITS_RAD_S[j]),
                   1.0 if share is None else float(share), float(tau_s), ja, acc_peak,
                   float(IIWA_ACCELERATION_LIMITS_RAD_S2[ja]),
                   1.0 if acceleration_share is None else float(acceleration_share))  # fmt: skip


def slowed_dmp(params: DMPParams, factor: float) -> DMPParams:
    """``params`` with its duration ``tau`` multiplied by ``factor``: the same path
    ``factor`` times slower (exact: the DMP's movement becomes ``y(t / factor)``)."""
    if factor == 1.0:
        return params
    return dataclasses.replace(params, tau=np.asarray(params.tau, dtype=float) * factor)


def joint_speed_metrics(log) -> dict:
    """The peak speed of every joint over a run's log, against the iiwa's limits.

    Returns
    -------
    dict with
        ``joint_speed_peak_rad_s`` - ``[7]`` peak ``|qd|`` per joint;
        ``joint_speed_limit_rad_s`` - ``[7]`` the limits; ``joint_speed_peak_share`` -
        the largest peak relative to its limit (< 1: a real iiwa can follow);
        ``joint_speed_peak_joint`` - that joint's name; ``joint_speed_peak_time_s`` -
        when; all NaN (and the joint None) for a log without joint states.
    """
    qd = np.asarray(log.joint_qd_rad_s, dtype=float)  # [S, 7]
    limits = IIWA_VELOCITY_LIMITS_RAD_S
    if qd.size == 0 or not np.isfinite(qd).all():
        nan = [math.nan] * 7
        return {"joint_speed_peak_rad_s": nan, "joint_speed_limit_rad_s": limits.tolist(),
                "joint_speed_peak_share": math.nan, "joint_speed_peak_joint": None,
                "joint_speed_peak_time_s": math.nan}  # fmt: skip
    peaks, share, i, j = _peak(qd, limits)
    return {
        "joint_speed_peak_rad_s": peaks,
        "joint_speed_limit_rad_s": limits.tolist(),
        "joint_speed_peak_share": share,
        "joint_speed_peak_joint": IIWA_JOINT_NAMES[j],
        "joint_speed_peak_time_s": float(log.time_s[i]),
    }


def _peak(values: np.ndarray, limits: np.ndarray) -> tuple[list, float, int, int]:
    """Of ``values [S, 7]`` against per-joint ``limits [7]``: each joint's peak ``|v|``,
    the largest ``|v| / limit``, and the sample and joint where it is."""
    ratio = np.abs(values) / limits  # [S, 7]
    i, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    return np.abs(values).max(axis=0).tolist(), float(ratio[i, j]), int(i), int(j)


def joint_acceleration_metrics(log) -> dict:
    """The peak acceleration of every joint over a run's log, against the limits
    (:data:`~img2dmp.robot.joints.IIWA_ACCELERATION_LIMITS_RAD_S2`): the finite
    differences of the logged joint velocities, the first from rest.

    Returns
    -------
    dict with
        ``joint_acceleration_peak_rad_s2`` - ``[7]`` peak ``|qdd|`` per joint;
        ``joint_acceleration_limit_rad_s2`` - ``[7]``; ``joint_acceleration_peak_share``
        - the largest peak relative to its limit; ``joint_acceleration_peak_joint``,
        ``joint_acceleration_peak_time_s``, ``joint_acceleration_peak_phase`` - which
        joint, when and in which phase (``PHASES``); NaN (None) for a log without
        joint states.
    """
    from .writing import PHASES  # the log's phases; writing imports this module

    qd = np.asarray(log.joint_qd_rad_s, dtype=float)  # [S, 7]
    limits = IIWA_ACCELERATION_LIMITS_RAD_S2
    if qd.size == 0 or not np.isfinite(qd).all():
        return {"joint_acceleration_peak_rad_s2": [math.nan] * 7,
                "joint_acceleration_limit_rad_s2": limits.tolist(),
                "joint_acceleration_peak_share": math.nan,
                "joint_acceleration_peak_joint": None,
                "joint_acceleration_peak_time_s": math.nan,
                "joint_acceleration_peak_phase": None}  # fmt: skip
    t = np.asarray(log.time_s, dtype=float)
    dt = np.diff(np.concatenate([[0.0], t]))  # [S] the first step from rest at t = 0
    qdd = np.diff(np.vstack([np.zeros(7), qd]), axis=0) / dt[:, None]  # [S, 7]
    peaks, share, i, j = _peak(qdd, limits)
    return {
        "joint_acceleration_peak_rad_s2": peaks,
        "joint_acceleration_limit_rad_s2": limits.tolist(),
        "joint_acceleration_peak_share": share,
        "joint_acceleration_peak_joint": IIWA_JOINT_NAMES[j],
        "joint_acceleration_peak_time_s": float(t[i]),
        "joint_acceleration_peak_phase": PHASES[int(log.phase[i])],
    }
