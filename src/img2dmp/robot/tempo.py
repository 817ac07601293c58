"""Slowing a DMP so that a real iiwa's joints can follow it, and the joint speeds of a run.

The simulated arm is driven by joint torques (up to 300 N m) and follows a DMP at any
speed it is asked to; a real LBR iiwa does not: its axes have speed limits
(:data:`img2dmp.robot.joints.IIWA_VELOCITY_LIMITS_RAD_S`, 75 to 135 deg/s). A DMP that is
short for its length (e.g. a stroke model's stroke of 36 mm in 0.22 s, peaking at
0.76 m/s on the paper) asks joint 4 for twice its limit. Before anything moves:

1. **Plan the joints** (:func:`planned_joint_velocities`): the controller's own inverse
   kinematics (:meth:`WritingScene.solve_ik`, warm-started, with its step towards the
   home posture in the null space) at every sample of the planned path, the pen on the
   paper where it is down and at the lift height where it is up; the joint velocities
   are their finite differences at the control rate, as the controller's ``qd_d``.
2. **Slow the DMP** (:func:`slowing_for`, :func:`slowed_dmp`): if a planned joint speed
   exceeds ``share`` (``JOINT_SPEED_SHARE``, 60 %) of its limit, the DMP's duration is
   multiplied by the smallest factor that brings every joint within it. Scaling ``tau``
   is exact: the DMP's path is ``y(t / k)``, the same curve on the paper, every
   Cartesian and joint velocity divided by ``k``. The share leaves room for what the
   plan does not see: the tracking transients of the torque controller (measured on the
   letters page: the simulated arm's peak about 1.25 times the planned one on a jerky
   stroke) and the pen's landing.
3. **Measure** (:func:`joint_speed_metrics`): the peak speed of every joint over the
   whole run, against its limit.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..dmp import DMPParams
from .joints import IIWA_JOINT_NAMES, IIWA_VELOCITY_LIMITS_RAD_S

#: Planned joint speeds are kept within this share of the iiwa's limits.
JOINT_SPEED_SHARE = 0.6
# The controller's IK iterations per control step (WritingController.torques).
_CONTROLLER_IK_ITERATIONS = 10


def planned_joint_velocities(scene, plan, q_seed_rad, rotation) -> tuple[np.ndarray, np.ndarray]:
    """The joint positions ``[T, 7]`` and velocities ``[T, 7]`` the controller will
    command along ``plan`` (a :class:`~img2dmp.robot.writing.PlannedPath`).

    The tip on the paper (``scene.config.paper_top_z``) at every sample, with orientation
    ``rotation``: the DMP sets the pen's motion in the plane; its landings and lifts are
    the controller's own, at most ``travel_speed_m_s`` (0.1 m/s) along the pen, and not
    part of the plan. The first sample is solved from ``q_seed_rad`` (the arm waits
    there at rest: its velocity is 0), every later one as the controller solves it
    (:meth:`WritingController.torques`: warm-started from the sample before, with the
    null-space step towards the home posture); the velocities are the finite
    differences at the plan's time steps, the controller's ``qd_d``.
    """
    z_m = scene.config.paper_top_z
    q, _ = scene.solve_ik([*plan.xy_m[0], z_m], rotation, q_seed_rad, max_iterations=200)
    qs = np.empty((len(plan.time_s), 7))  # [T, 7]
    qs[0] = q
    for i in range(1, len(qs)):
        q, _ = scene.solve_ik([*plan.xy_m[i], z_m], rotation, q,
                              max_iterations=_CONTROLLER_IK_ITERATIONS)  # fmt: skip
        qs[i] = q
    qd = np.zeros_like(qs)  # [T, 7]
    qd[1:] = np.diff(qs, axis=0) / np.diff(plan.time_s)[:, None]
    return qs, qd


@dataclass(frozen=True)
class Slowing:
    """How much one DMP is slowed for the iiwa's joint speed limits.

    Attributes
    ----------
    factor : float
        The DMP's duration is multiplied by it (1: not slowed).
    joint : int
        The joint (0-based) that asked for the most, relative to its limit.
    planned_peak_rad_s : float
        That joint's planned peak speed at the DMP's own tempo.
    limit_rad_s : float
        That joint's limit.
    share : float
        The share of the limits the planned speeds are kept within.
    tau_s : float
        The DMP's duration before slowing.
    """

    factor: float
    joint: int
    planned_peak_rad_s: float
    limit_rad_s: float
    share: float
    tau_s: float

    @property
    def slowed(self) -> bool:
        return self.factor > 1.0

    @property
    def joint_name(self) -> str:
        return IIWA_JOINT_NAMES[self.joint]

    def words(self) -> str:
        """``"2.97x slower (0.221 s -> 0.656 s): at its own tempo lbr_iiwa_joint_4 would
        reach 2.33 rad/s, 178 % of the iiwa's limit of 1.31 rad/s"``."""
        return (
            f"{self.factor:.2f}x slower ({self.tau_s:.3f} s -> {self.tau_s * self.factor:.3f} "
            f"s): at its own tempo {self.joint_name} would reach "
            f"{self.planned_peak_rad_s:.2f} rad/s, "
            f"{100 * self.planned_peak_rad_s / self.limit_rad_s:.0f} % of the iiwa's limit "
            f"of {self.limit_rad_s:.2f} rad/s"
        )

    def to_dict(self) -> dict:
        return {
            "slowdown": self.factor,
            "slowdown_joint": self.joint_name,
            "planned_joint_speed_peak_rad_s": self.planned_peak_rad_s,
            "tau_s": self.tau_s,
            "written_tau_s": self.tau_s * self.factor,
        }


def slowing_for(qd_rad_s: np.ndarray, tau_s: float, share: float | None) -> Slowing:
    """The :class:`Slowing` that keeps planned joint velocities ``qd_rad_s [T, 7]`` of a
    DMP of ``tau_s`` seconds within ``share`` of the iiwa's limits (``share`` None:
    factor 1, only measured)."""
    peaks = np.abs(np.asarray(qd_rad_s, dtype=float)).max(axis=0)  # [7]
    ratio = peaks / IIWA_VELOCITY_LIMITS_RAD_S
    j = int(np.argmax(ratio))
    factor = 1.0 if share is None else max(1.0, float(ratio[j]) / share)
    if factor > 1.0:  # round up a little, so the slowed plan lands inside, not on, the share
        factor = math.ceil(factor * 1000) / 1000
    return Slowing(factor, j, float(peaks[j]), float(IIWA_VELOCITY_LIMITS_RAD_S[j]),
                   1.0 if share is None else float(share), float(tau_s))  # fmt: skip


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
    ratio = np.abs(qd) / limits  # [S, 7]
    i, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    return {
        "joint_speed_peak_rad_s": np.abs(qd).max(axis=0).tolist(),
        "joint_speed_limit_rad_s": limits.tolist(),
        "joint_speed_peak_share": float(ratio[i, j]),
        "joint_speed_peak_joint": IIWA_JOINT_NAMES[j],
        "joint_speed_peak_time_s": float(log.time_s[i]),
    }
