"""The simulated arm's own joint accelerations: ramped pen-axis moves, a DMP clock that
comes to rest, a settled start posture, and the acceleration check of the exported joint
trajectory.

The pen-axis profile, the clock and the trajectory's check need no pybullet; one short
simulated run (a line whose DMP ends moving) checks the whole run against the 10 rad/s^2
planning limit, which it keeps at 6.7 rad/s^2: without the clock's stop it was 55.4
rad/s^2, without the settled start posture 21.1 (at t = 0), without the pen-axis ramp
82.4 (each measured by removing that one).
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import pytest

from img2dmp.dmp import DMPConfig, fit_dmp
from img2dmp.robot import ControllerConfig, available
from img2dmp.robot.controller import axis_move_s, axis_speed_towards
from img2dmp.robot.joints import IIWA_ACCELERATION_LIMITS_RAD_S2, JointTrajectory
from img2dmp.robot.strokes import CLOCK_RAMP_S, DMPClock, clock_stops

needs_pybullet = pytest.mark.skipif(
    not available(), reason="pybullet is not installed (pip install -e '/path/to/img2dmp[robot]')"
)
DT_S = 1.0 / 240.0


def _axis_move(distance_m: float, cfg: ControllerConfig, speed_m_s: float = 0.0,
               arrival_m_s: float = 0.0, steps: int = 400) -> np.ndarray:  # fmt: skip
    """``[steps]`` positions of a pen-axis move from 0 towards ``distance_m``."""
    z, v, out = 0.0, speed_m_s, []
    for _ in range(steps):
        v = axis_speed_towards(distance_m - z, v, cfg.travel_speed_m_s,
                               cfg.axis_acceleration_m_s2, DT_S, arrival_m_s)  # fmt: skip
        z += v * DT_S
        out.append(z)
    return np.array(out)


def test_pen_axis_moves_speed_up_and_slow_down_within_the_axis_acceleration():
    cfg = ControllerConfig()
    for distance_m in (0.006, -0.0055, 0.014, 0.0004):
        z = _axis_move(distance_m, cfg)
        v = np.diff(np.concatenate([[0.0], z])) / DT_S  # [steps] from rest
        dv = np.abs(np.diff(np.concatenate([[0.0], v])))
        assert dv.max() <= cfg.axis_acceleration_m_s2 * DT_S * (1 + 1e-9)
        assert np.abs(v).max() <= cfg.travel_speed_m_s * (1 + 1e-9)
        # at the target, at rest, and not past it by more than a micrometre
        assert z[-1] == pytest.approx(distance_m, abs=1e-12) and abs(v[-1]) < 1e-12
        assert np.max(np.sign(distance_m) * (z - distance_m)) < 1e-5
        # as long as the trapezoid takes, to the control step
        arrived = int(np.argmax(np.abs(z - distance_m) < 1e-9)) + 1
        assert abs(arrived * DT_S - axis_move_s(cfg, distance_m)) <= 3 * DT_S


def test_a_fast_descent_arrives_at_the_slow_approach_speed():
    cfg = ControllerConfig()
    z = _axis_move(-0.0055, cfg, speed_m_s=0.0, arrival_m_s=cfg.approach_speed_m_s)
    v = np.diff(z) / DT_S
    at = int(np.argmax(z <= -0.0055 + 1e-12))
    # slowed to about the approach speed as it gets there, not stopped from 0.1 m/s at once
    assert abs(v[at - 2]) < 2 * cfg.approach_speed_m_s + cfg.axis_acceleration_m_s2 * DT_S
    assert np.abs(np.diff(v)).max() <= cfg.axis_acceleration_m_s2 * DT_S * (1 + 1e-9)


def test_the_dmp_clock_comes_to_rest_exactly_at_its_stops_and_ramps():
    down = np.ones(300, dtype=bool)
    down[100:160] = False  # a lift-off after sample 99, a touch-down at 160
    stops = clock_stops(down, gated=True)
    assert stops.tolist() == [99, 160, 299]
    assert clock_stops(down, gated=False).tolist() == [299]
    clock = DMPClock(DT_S, stops)
    times, rates, reached = [], [], []
    while not clock.done:
        step_s, stop = clock.advance()
        assert step_s > 0.0
        times.append(clock.t)
        rates.append(step_s / DT_S)  # the DMP seconds of this control step, per second
        if stop is not None:
            rates.append(0.0)  # held
            reached.append(stop)
            assert clock.t == stop * DT_S and clock.rate == 0.0  # exactly there, at rest
    assert reached == stops.tolist()
    rates = np.array(rates)
    assert rates.max() == 1.0  # full tempo between stops far apart
    # the clock's own acceleration stays bounded (smoothstep up: 1.5 / ramp at most,
    # braking: 1 / ramp, to rest too)
    assert np.abs(np.diff(np.concatenate([[0.0], rates]))).max() / DT_S <= 1.5 / CLOCK_RAMP_S
    # the pen's state at a time between samples: down only inside a stroke
    assert clock.sample(down) == (299, True)
    clock.t = 99.5 * DT_S
    assert clock.sample(down) == (99, False)
    clock.t = 159.5 * DT_S
    assert clock.sample(down) == (159, False)
    # a stop takes about CLOCK_RAMP_S / 2 longer than the full tempo would
    assert len(times) * DT_S - 299 * DT_S == pytest.approx(3 * CLOCK_RAMP_S, abs=0.05)


def _trajectory(qdd_peak: float) -> JointTrajectory:
    """A rest-to-rest move of joint 3 in 0.25 s whose acceleration peaks at ``qdd_peak``
    (at t = 0.0625 s)."""
    t = np.arange(61) * DT_S
    qd = np.zeros((61, 7))
    qd[:, 2] = qdd_peak * 0.25 / (2 * math.pi) * (1 - np.cos(2 * math.pi * t / 0.25))
    q = np.cumsum(qd, axis=0) * DT_S
    return JointTrajectory(t, q, qd)


def test_an_exported_trajectory_over_the_acceleration_limit_is_named():
    over = _trajectory(12.0)
    peak = over.acceleration_peak()
    assert peak["joint"] == "lbr_iiwa_joint_3"
    assert peak["acceleration_rad_s2"] == pytest.approx(12.0, rel=5e-3)
    assert peak["time_s"] == pytest.approx(0.0625, abs=DT_S)
    assert peak["share"] == pytest.approx(12.0 / IIWA_ACCELERATION_LIMITS_RAD_S2[2], rel=5e-3)
    words = over.acceleration_violation()
    value = f"{peak['acceleration_rad_s2']:.2f} rad/s^2 at t = {peak['time_s']:.4f} s"
    assert words.startswith(f"lbr_iiwa_joint_3 acceleration {value}")
    assert "planning limit of ±10 rad/s^2 (120 % of it)" in words and "\n" not in words
    assert over.limit_violation() is None  # positions and speeds are within: still written
    assert _trajectory(8.0).acceleration_violation() is None
    import json

    doc = json.loads(over.to_json())
    assert doc["limits"]["acceleration_rad_s2"] == IIWA_ACCELERATION_LIMITS_RAD_S2.tolist()
    assert doc["acceleration_peak"] == peak


def test_the_write_command_warns_of_an_over_limit_export_and_writes_it(capsys, tmp_path):
    from img2dmp.commands import write as write_cmd

    args = argparse.Namespace(export_joints=str(tmp_path / "j"), no_slowing=False, out_dir=".")
    result = argparse.Namespace()
    trajectory = _trajectory(12.0)
    result_from = JointTrajectory.from_result
    try:
        JointTrajectory.from_result = classmethod(lambda cls, r, joints: trajectory)
        assert write_cmd._joint_trajectory(args, result, "line", 1) is trajectory
    finally:
        JointTrajectory.from_result = result_from
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("img2dmp write: warning: ")
    assert f"j.json: joint trajectory: {trajectory.acceleration_violation()}; written" in err


def _moving_end_line():
    """A line from rest whose DMP ends moving (about 70 mm/s at 40 mm per 28 px)."""
    u = np.linspace(0.0, 1.0, 200)
    y = np.stack([8 + 12 * u**2, 10 + 6 * u**2], axis=-1)
    config = DMPConfig(n_kernels=25, n_dims=2, scaling="none")
    fit = fit_dmp(np.linspace(0.0, 0.5, 200), y, config)
    return fit.params, config


@needs_pybullet
def test_a_whole_run_stays_within_the_acceleration_planning_limit():
    from img2dmp.robot import write_dmp

    params, config = _moving_end_line()
    result = write_dmp(params, config, (28, 28), render_size_px=None)
    m = result.metrics
    assert m["joint_acceleration_peak_share"] <= 1.0, (
        m["joint_acceleration_peak_rad_s2"], m["joint_acceleration_peak_time_s"],
        m["joint_acceleration_peak_phase"])  # fmt: skip
    # written as well as ever, to the path's end point
    assert m["stroke_ink_share_min"] >= 0.98 and m["tracking_error_mean_mm"] < 0.5
    log = result.log
    running = log.in_phase("write") & ~log.dwell
    assert log.dmp_time_s[running][-1] == pytest.approx(result.plan.time_s[-1], abs=1e-9)
    # the clock slowed to the end: its last steps are short ones
    steps = np.diff(log.dmp_time_s[running])
    assert steps[-1] < 0.2 * DT_S and steps[len(steps) // 2] == pytest.approx(DT_S)
    # the start posture is settled: the trajectory exported is within its limits
    assert JointTrajectory.from_result(result).acceleration_violation() is None


def _reference_along(xy_m: np.ndarray, rate_hz: float) -> np.ndarray:
    """``[T, 7]`` the controller's ``qdd_d`` while its target moves along ``xy_m [T, 2]``
    on the paper, one control step each (its IK alone: the arm held on the reference)."""
    from img2dmp.robot import WritingController, WritingScene
    from img2dmp.robot.tempo import settled_posture
    from img2dmp.robot.writing import PEN_DOWN_ROTATION

    with WritingScene(time_step_s=1.0 / rate_hz) as scene:
        z_m = scene.config.paper_top_z
        q0, _ = settled_posture(scene, [*xy_m[0], z_m], PEN_DOWN_ROTATION, scene.joint_state()[0])
        ctl = WritingController(scene, ControllerConfig(), PEN_DOWN_ROTATION, q0, z_m)
        qdd = []
        for xy in xy_m:
            ctl.torques(xy, ctl.q_d, ctl.qd_d)
            qdd.append(ctl.qdd_d.copy())
    return np.array(qdd)


@needs_pybullet
def test_the_controllers_reference_accelerations_carry_no_ik_jitter_at_1khz():
    """A 5 mm line from rest to rest in 0.4 s at 1 kHz: near its ends the target moves
    less than the IK's 1 um tolerance per step. An IK that then skipped a step (its
    warm start already within tolerance) left the joints standing for one step and
    caught up on the next: qdd_d jumped by up to 6.5 rad/s^2 off its smooth course (which
    peaks at 0.6 on this line); one iteration every step keeps it within 1 (what is left,
    0.33, is pybullet's single-precision forward kinematics: tip positions in steps of
    3e-8 m, which differences 1 ms apart read as tenths of a rad/s^2)."""
    rate_hz = 1000.0
    s = np.linspace(0.0, 1.0, 401)
    u = s**3 * (10 - 15 * s + 6 * s**2)  # minimum jerk
    xy = np.column_stack([0.55 + 0.005 * u, np.zeros_like(u)])
    qdd = _reference_along(xy, rate_hz)[2:]  # [T-2, 7]: from the first move on
    kernel = np.ones(25) / 25.0
    smooth = np.column_stack([np.convolve(qdd[:, j], kernel, mode="same") for j in range(7)])
    jitter = np.abs(qdd - smooth)[12:-12]  # the box mean is whole away from the ends
    assert jitter.max() < 1.0, jitter.max()


def test_the_depth_offset_is_the_measured_one_while_touching_smooth_and_0_in_the_air():
    from img2dmp.robot.joints import DEPTH_RAMP_S, depth_offset_m

    dt = DT_S
    n = 600
    t = np.arange(n) * dt
    touching = np.zeros(n, dtype=bool)
    touching[150:450] = True
    slow = 1.5e-4 + 1e-5 * np.sin(2 * np.pi * 0.5 * t)  # the depth, a slow course
    rng = np.random.default_rng(0)
    measured = slow + 2e-6 * rng.standard_normal(n)  # the contact's step noise
    # in the air: the arm's lag, a bump with a kink at each end (up to 0.4 mm)
    air = ~touching
    measured[air] = 4e-4 * np.maximum(0.0, 1 - np.abs(t[air] - t[500]) / 0.1)
    got = depth_offset_m(measured, touching, dt)
    ramp = round(DEPTH_RAMP_S / dt)
    # 0 well before the touch-down and after the lift-off's ramp (the bump dropped)
    assert np.abs(got[: 150 - ramp - 20]).max() < 1e-6  # < 1 % of the depth
    assert np.abs(got[450 + ramp + 20 :]).max() < 1e-6
    # the measured depth while touching, away from its ends, without the noise
    inner = slice(200, 400)
    off = got[inner] - slow[inner]
    assert np.sqrt(np.mean(off**2)) < 1e-6 and np.abs(off).max() < 2e-6  # the noise: 2 um RMS
    raw_jolt = np.abs(np.diff(measured[inner], 3)).max()
    assert np.abs(np.diff(got, 3)).max() < raw_jolt / 20, raw_jolt
    assert not depth_offset_m(measured, np.zeros(n, dtype=bool), dt).any()


def test_the_depth_low_pass_is_scipys_butterworth_forwards_and_backwards():
    """The reference's depth is low-passed by a hand-written 2nd-order Butterworth run
    both ways (importing ``scipy.signal`` cost a ``write`` 20 MiB): the same as
    ``sosfiltfilt`` of ``butter(2, ...)`` to rounding, short and long, at both rates."""
    signal = pytest.importorskip("scipy.signal")
    from img2dmp.robot.joints import _low_pass_both_ways

    rng = np.random.default_rng(3)
    for fs, n in ((240.0, 7), (240.0, 3000), (1000.0, 12), (1000.0, 20000)):
        x = np.cumsum(rng.normal(size=n)) * 1e-4
        sos = signal.butter(2, 10.0, fs=fs, output="sos")
        padlen = min(9, n - 1)
        want = signal.sosfiltfilt(sos, x, padlen=padlen)
        got = _low_pass_both_ways(x, 10.0 / fs, padlen)
        assert np.abs(got - want).max() <= 1e-12 * max(1e-9, np.abs(want).max())
