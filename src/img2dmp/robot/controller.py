"""The writing controller: joint-torque tracking of an IK reference plus an admittance
loop along the pen axis.

Per control step (one physics step of ``dt``):

1. **Admittance along the pen** (the z axis of the world; the pen is held vertical). The
   commanded tip height ``z_c`` obeys the first-order admittance law

       d_a * dz_c/dt = -(F_set - F_meas)          (pen down)

   i.e. the pen sinks while it presses less than ``F_set`` and rises while it presses
   more, at a speed limited to ``max_axis_speed_m_s``. ``F_meas`` is the tip-paper
   normal force, low-pass filtered. Without contact the pen is lowered: at
   ``travel_speed_m_s`` down to ``approach_clearance_m`` above the paper (its height
   is known), then at ``approach_speed_m_s`` until it touches, so the admittance law
   only ever acts in contact. When the pen is up, ``z_c`` moves at ``travel_speed_m_s``
   to ``lift_height_m`` above the paper. Every move of ``z_c`` outside the contact
   speeds up and slows down at ``axis_acceleration_m_s2`` (a trapezoidal speed
   profile, :func:`axis_speed_towards`): a pen that started or stopped at 0.1 m/s
   within one control step asked the arm's joints for 65-110 rad/s^2.

   The loop is a first-order one with time constant ``d_a / k`` for a contact
   stiffness ``k`` (pen, paper and arm in series); sampled at ``dt`` it needs
   ``k dt / d_a`` well below 1 (the defaults give 0.2). A stiffer surface or a slower
   controller needs a larger ``d_a``.
2. **Inverse kinematics**: the tip target ``(x_c, y_c, z_c)`` with the pen vertical is
   turned into joint angles ``q_d`` by damped least squares on a kinematic twin
   (:meth:`WritingScene.solve_ik`), warm-started from the previous ``q_d``, at least one
   iteration every step: a solve that stopped at once where the warm start was within
   its 1 um tolerance (a target moving less than that per step, as near a stroke's ends
   or while the pen sinks into the paper at 1 kHz) left ``q_d`` standing for a step and
   caught up on the next, a jolt of up to 6.5 rad/s^2 in ``qdd_d``.
3. **Joint-torque control** (computed torque): with ``qd_d`` and ``qdd_d`` from finite
   differences of ``q_d``,

       tau = M(q) (qdd_d + K_p (q_d - q) + K_d (qd_d - qd)) + C(q, qd) qd + g(q)

   evaluated by pybullet's recursive Newton-Euler inverse dynamics, with
   ``K_p = omega^2``, ``K_d = 2 zeta omega`` and ``omega = 2 pi joint_bandwidth_hz``, so
   every joint error decays like a critically damped second-order system. pybullet's
   position servo is not used; the torques go to ``TORQUE_CONTROL``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import check_positive_fields

#: The largest contact force the controller is asked to hold (N). Writing a "5" at 240 Hz
#: (2026-12-07): 20, 25, 30, 35 N held within 0.1 N; at 40 N and above the pen bounces
#: off the paper and never settles.
MAX_FORCE_SET_N = 30.0
#: How fast the pen-axis speed may change outside the contact (m/s^2). The joints move
#: about 2 rad/s per m/s of pen-axis speed here (joint 2 at 0.196 rad/s for 0.1 m/s), so
#: 2 m/s^2 asks them for about 4 rad/s^2, well within the 10 rad/s^2 planning limit.
AXIS_ACCELERATION_M_S2 = 1.5


def axis_speed_towards(distance_m: float, speed_m_s: float, max_speed_m_s: float,
                       acceleration_m_s2: float, dt_s: float,
                       arrival_speed_m_s: float = 0.0) -> float:  # fmt: skip
    """The pen-axis speed for the next control step of a move ``distance_m`` (signed)
    away from its target, from ``speed_m_s`` now: a trapezoidal profile, at most
    ``max_speed_m_s``, changed by at most ``acceleration_m_s2 * dt_s`` per step, and slow
    enough to stop (or arrive at ``arrival_speed_m_s``) at the target with that
    deceleration: ``v <= sqrt(v_arrive^2 + 2 a |d|)``, as control steps (each moves
    ``v dt`` after its speed is set): ``a dt (sqrt(2 |d| / (a dt^2) + (v_arrive / (a
    dt))^2 + 1/4) - 1/2)``, which stops on the target instead of past it. The last step
    lands on the target."""
    dv = acceleration_m_s2 * dt_s
    reach = dv * (math.sqrt(2.0 * abs(distance_m) / (dv * dt_s) + (arrival_speed_m_s / dv) ** 2
                            + 0.25) - 0.5)  # fmt: skip
    wanted = math.copysign(min(max_speed_m_s, reach, abs(distance_m) / dt_s), distance_m)
    return min(max(wanted, speed_m_s - dv), speed_m_s + dv)


def axis_move_s(config: ControllerConfig, distance_m: float) -> float:
    """Seconds a pen-axis move of ``distance_m`` from rest to rest takes
    (:func:`axis_speed_towards` at ``travel_speed_m_s`` and ``axis_acceleration_m_s2``)."""
    v, a, d = config.travel_speed_m_s, config.axis_acceleration_m_s2, abs(distance_m)
    return d / v + v / a if d >= v * v / a else 2.0 * math.sqrt(d / a)


@dataclass(frozen=True)
class ControllerConfig:
    """Gains and set points of :class:`WritingController`.

    Parameters
    ----------
    force_set_n : float
        Contact force along the pen held while writing, newtons; at most
        ``MAX_FORCE_SET_N``.
    admittance_damping_n_s_per_m : float
        ``d_a`` of the admittance law: newtons of force error per m/s of pen-axis speed.
    max_axis_speed_m_s : float
        Cap on the pen-axis speed under the admittance law (final approach, force
        correction).
    travel_speed_m_s : float
        Pen-axis speed when lifting and when lowering down to ``approach_clearance_m``.
    approach_speed_m_s : float
        Pen-axis speed below ``approach_clearance_m`` until the tip touches.
    approach_clearance_m : float
        Height above the paper below which the admittance law takes over the descent.
    force_filter_hz : float
        Cut-off of the first-order low-pass filter on the measured force.
    joint_bandwidth_hz : float
        Natural frequency of the joint-space error dynamics.
    damping_ratio : float
        Damping ratio of the joint-space error dynamics.
    lift_height_m : float
        Height of the tip above the paper when the pen is up.
    axis_acceleration_m_s2 : float
        The largest change of the pen-axis speed per second outside the contact (starts
        and stops of the lowering and the lifting; the admittance law in contact has its
        own speed cap).
    """

    force_set_n: float = 5.0
    admittance_damping_n_s_per_m: float = 400.0
    max_axis_speed_m_s: float = 0.03
    travel_speed_m_s: float = 0.1
    approach_speed_m_s: float = 0.01
    approach_clearance_m: float = 0.0005
    force_filter_hz: float = 40.0
    joint_bandwidth_hz: float = 12.0
    damping_ratio: float = 1.0
    lift_height_m: float = 0.006
    axis_acceleration_m_s2: float = AXIS_ACCELERATION_M_S2

    def __post_init__(self) -> None:
        check_positive_fields(
            self,
            (
                "force_set_n",
                "admittance_damping_n_s_per_m",
                "max_axis_speed_m_s",
                "travel_speed_m_s",
                "approach_speed_m_s",
                "approach_clearance_m",
                "force_filter_hz",
                "joint_bandwidth_hz",
                "damping_ratio",
                "lift_height_m",
                "axis_acceleration_m_s2",
            ),
        )
        if self.force_set_n > MAX_FORCE_SET_N:
            raise ValueError(
                f"force_set_n is {self.force_set_n:g} N, more than {MAX_FORCE_SET_N:g} N: a pen "
                "writes with a few newtons, and the simulated arm's pen does not settle on the "
                "paper much above that (--force-n)"
            )


class WritingController:
    """Admittance along the pen + IK + computed-torque joint control (see module docstring).

    Parameters
    ----------
    scene : WritingScene
        The simulated cell; the controller reads its state and applies torques.
    config : ControllerConfig
    rotation : ndarray [3, 3]
        Desired orientation of the tip frame (pen axis = its z column, pointing down).
    q_start_rad : ndarray [7]
        Joint angles at the start (the first IK seed and the first ``q_d``).
    z_start_m : float
        Commanded tip height at the start.
    """

    def __init__(self, scene, config: ControllerConfig, rotation, q_start_rad, z_start_m: float):
        self.scene = scene
        self.config = config
        self.rotation = np.asarray(rotation, dtype=float)
        self.dt = scene.time_step_s
        omega = 2.0 * math.pi * config.joint_bandwidth_hz
        if omega * self.dt > 0.5:
            raise ValueError(
                f"joint_bandwidth_hz={config.joint_bandwidth_hz} is too high for a control "
                f"step of {self.dt:.4g} s (needs 2 pi f dt <= 0.5)"
            )
        self.kp = omega**2
        self.kd = 2.0 * config.damping_ratio * omega
        self.q_d = np.asarray(q_start_rad, dtype=float).copy()
        self.qd_d = np.zeros(7)
        self.qdd_d = np.zeros(7)
        self.z_c = float(z_start_m)
        self.z_speed_m_s = 0.0  # of z_c
        self.force_filtered_n = 0.0
        self._alpha = 1.0 - math.exp(-2.0 * math.pi * config.force_filter_hz * self.dt)
        self.last_ik_residual_m = 0.0

    def update_axis(
        self,
        pen_down: bool,
        force_n: float,
        surface_z_m: float,
        hover: bool = False,
        up_height_m: float | None = None,
    ) -> float:
        """Advance the pen-axis admittance by one step; return the commanded tip height.

        Pen up only: ``hover`` goes to ``approach_clearance_m`` above the paper instead of
        ``lift_height_m``, so that a touch-down that is due soon starts from there;
        ``up_height_m`` goes to that height instead (a page's travel between characters)."""
        cfg = self.config
        self.force_filtered_n += self._alpha * (force_n - self.force_filtered_n)
        above = surface_z_m + cfg.approach_clearance_m
        if pen_down and force_n > 0.0:
            speed = -(cfg.force_set_n - self.force_filtered_n) / cfg.admittance_damping_n_s_per_m
            limit = cfg.max_axis_speed_m_s
            self.z_speed_m_s = float(np.clip(speed, -limit, limit))
        else:
            if pen_down and self.z_c > above:  # lowered fast, arriving at the slow approach
                target, speed, arrive = above, cfg.travel_speed_m_s, cfg.approach_speed_m_s
            elif pen_down:  # the last of the clearance slowly, until it touches
                target, speed, arrive = -math.inf, cfg.approach_speed_m_s, cfg.approach_speed_m_s
            else:
                height = cfg.lift_height_m if up_height_m is None else up_height_m
                height = cfg.approach_clearance_m if hover else height
                target, speed, arrive = surface_z_m + height, cfg.travel_speed_m_s, 0.0
            distance = max(target - self.z_c, -1.0)  # -inf: keep going down
            self.z_speed_m_s = axis_speed_towards(
                distance, self.z_speed_m_s, speed, cfg.axis_acceleration_m_s2, self.dt, arrive
            )
        self.z_c += self.z_speed_m_s * self.dt
        return self.z_c

    def torques(self, xy_m, q, qd) -> np.ndarray:
        """Joint torques (N m) that track the tip target ``(xy_m, z_c)``; updates ``q_d``."""
        target = np.array([xy_m[0], xy_m[1], self.z_c])
        q_new, self.last_ik_residual_m = self.scene.solve_ik(
            target, self.rotation, self.q_d, max_iterations=10, min_iterations=1
        )
        qd_new = (q_new - self.q_d) / self.dt
        self.qdd_d = (qd_new - self.qd_d) / self.dt
        self.q_d, self.qd_d = q_new, qd_new
        acc = self.qdd_d + self.kp * (self.q_d - q) + self.kd * (self.qd_d - qd)
        tau = self.scene.inverse_dynamics(q, qd, acc)
        limit = self.scene.max_torque_nm
        return np.clip(tau, -limit, limit)
