"""A DMP too fast for a real iiwa's joints is slowed before anything moves (the same path),
said in a note, and every run measures its joint speeds against the iiwa's limits;
``--export-joints`` of a motion over the limits writes nothing at all.

The fast DMP is a 28 mm stroke in 0.07 s (peaking near 0.75 m/s on the paper, as the
stroke of the letters page that drove joint 4 to 2.2 times its limit); its simulation
is about 100 control steps.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from img2dmp.dmp import DMPConfig, fit_dmp
from img2dmp.dmp._numpy_rollout import rollout_numpy
from img2dmp.robot import available

needs_pybullet = pytest.mark.skipif(
    not available(), reason="pybullet is not installed (pip install -e '/path/to/img2dmp[robot]')"
)

IMAGE_SIZE = (28, 28)
FAST_S = 0.07


def stroke_dmp(duration_s: float):
    """A straight min-jerk stroke from (4, 6) to (24, 20) px (28 mm at 40 mm per 28 px)."""
    u = np.linspace(0.0, 1.0, 200)
    s = 10 * u**3 - 15 * u**4 + 6 * u**5
    y = np.stack([4 + 20 * s, 6 + 14 * s], axis=-1)
    config = DMPConfig(n_kernels=20, n_dims=2, scaling="none")
    return fit_dmp(np.linspace(0.0, duration_s, len(y)), y, config).params, config


# -- no simulation ---------------------------------------------------------------------------


def test_slowing_keeps_the_fastest_joint_within_its_share_of_the_limit():
    from img2dmp.robot.joints import IIWA_VELOCITY_LIMITS_RAD_S as limits
    from img2dmp.robot.tempo import slowing_for

    qd = np.zeros((50, 7))
    qd[10, 1] = 0.5 * limits[1]  # within 60 %
    qd[20, 3] = -2.0 * limits[3]  # twice the limit of joint 4
    s = slowing_for(qd, 0.25, 0.6)
    assert s.slowed and s.joint_name == "lbr_iiwa_joint_4"
    assert s.factor == pytest.approx(2.0 / 0.6, abs=1e-3) and s.factor >= 2.0 / 0.6
    assert np.max(np.abs(qd) / s.factor / limits) <= 0.6
    assert "3.33x slower (0.250 s -> 0.834 s)" in s.words() and "200 %" in s.words()
    assert s.to_dict()["written_tau_s"] == pytest.approx(0.25 * s.factor)
    # Within the share: not slowed; None: measured only.
    assert slowing_for(qd * 0.25, 0.25, 0.6).factor == 1.0
    assert slowing_for(qd, 0.25, None).factor == 1.0


def test_slowing_keeps_the_planned_accelerations_within_their_share():
    """Slowing by k divides accelerations by k^2: a joint at 4 times its acceleration
    limit needs k = 2 for all of it, 4 for a quarter of it."""
    from img2dmp.robot.joints import IIWA_ACCELERATION_LIMITS_RAD_S2 as acc_limits
    from img2dmp.robot.tempo import slowing_for

    qd = np.zeros((50, 7))
    qdd = np.zeros((50, 7))
    qdd[30, 1] = -4.0 * acc_limits[1]
    s = slowing_for(qd, 0.5, 0.6, qdd, 1.0)
    assert s.slowed and s.by_acceleration and s.factor == pytest.approx(2.0)
    assert "lbr_iiwa_joint_2 would accelerate at 40 rad/s^2, 400 %" in s.words()
    assert s.to_dict()["slowdown_by"] == "acceleration"
    assert slowing_for(qd, 0.5, 0.6, qdd, 0.25).factor == pytest.approx(4.0)
    # Just over its share, a slowing of 1.01x names a share that is over it, not "60 %".
    qdd[30, 1] = -0.605 * acc_limits[1]
    s = slowing_for(qd, 0.5, 0.6, qdd, 0.6)
    assert np.sqrt(0.605 / 0.6) <= s.factor < 1.01  # rounded up to the next 0.001
    assert "would accelerate at 6.05 rad/s^2, 60.5 % of the planning limit" in s.words()
    qdd[30, 1] = -4.0 * acc_limits[1]
    # the larger of the two factors wins: joint 4 at twice its speed limit needs 3.33
    qd[20, 3] = 2.0 * np.radians(75)
    both = slowing_for(qd, 0.5, 0.6, qdd, 1.0)
    assert both.factor == pytest.approx(2.0 / 0.6, abs=1e-3) and not both.by_acceleration
    # acceleration share None: measured only
    assert slowing_for(qd * 0, 0.5, 0.6, qdd, None).factor == 1.0


def test_planned_accelerations_are_the_velocities_finite_differences():
    """A joint moving with constant acceleration a from rest: every planned acceleration
    after the first step is a (finite differences are exact for a parabola)."""
    from img2dmp.robot.tempo import planned_joint_accelerations

    t = np.arange(40) / 240.0
    q = 0.5 * 3.0 * t[:, None] ** 2 * np.arange(1, 8)  # [T, 7], a = 3, 6, ..., 21 rad/s^2
    qd = np.zeros_like(q)
    qd[1:] = np.diff(q, axis=0) / np.diff(t)[:, None]
    qdd = planned_joint_accelerations(qd, t)
    assert np.allclose(qdd[2:], 3.0 * np.arange(1, 8), rtol=1e-9)
    assert np.allclose(qdd[1], 1.5 * np.arange(1, 8)) and not qdd[0].any()


def test_planned_accelerations_do_not_depend_on_the_control_rate():
    """The same motion (from rest, peak 0.1 (2 pi)^2 = 3.95 rad/s^2) with a micro-radian
    of jitter a sample, as the warm-started IK leaves: at 1 kHz second differences 1 ms
    apart would read the jitter as several rad/s^2; read over 1/240 s they read the
    motion, as at 240 Hz (where the jitter is 17 times smaller)."""
    from img2dmp.robot.tempo import planned_joint_accelerations

    rng = np.random.default_rng(0)
    for rate in (240.0, 1000.0):
        t = np.arange(0.0, 2.0, 1.0 / rate)
        q = 0.1 * (1.0 - np.cos(2.0 * np.pi * t))[:, None] * np.ones(7)  # [T, 7]
        q += rng.normal(0.0, 1e-6, q.shape)
        qd = np.zeros_like(q)
        qd[1:] = np.diff(q, axis=0) * rate
        peak = np.abs(planned_joint_accelerations(qd, t)).max()
        assert peak == pytest.approx(0.1 * (2.0 * np.pi) ** 2, rel=0.15), rate


def test_joint_acceleration_metrics_name_the_joint_the_time_and_the_phase():
    from img2dmp.robot.tempo import joint_acceleration_metrics

    @dataclasses.dataclass
    class Log:
        time_s: np.ndarray
        joint_qd_rad_s: np.ndarray
        phase: np.ndarray

    t = np.arange(1, 6) * 0.01
    qd = np.zeros((5, 7))
    qd[:, 5] = [0.0, 0.0, 0.05, 0.05, 0.05]  # joint 6: 5 rad/s^2 over the third step
    qd[4, 2] = 0.2  # joint 3: 20 rad/s^2 over the fifth step
    m = joint_acceleration_metrics(Log(t, qd, np.array([0, 1, 1, 2, 2])))
    assert m["joint_acceleration_peak_joint"] == "lbr_iiwa_joint_3"
    assert m["joint_acceleration_peak_share"] == pytest.approx(2.0)
    assert m["joint_acceleration_peak_time_s"] == pytest.approx(0.05)
    assert m["joint_acceleration_peak_phase"] == "lift"
    assert m["joint_acceleration_peak_rad_s2"][5] == pytest.approx(5.0)
    empty = joint_acceleration_metrics(Log(t, np.full((5, 7), np.nan), np.zeros(5, int)))
    assert np.isnan(empty["joint_acceleration_peak_share"])


def test_a_slowed_dmp_draws_the_same_path_in_more_time():
    from img2dmp.robot.tempo import slowed_dmp

    params, config = stroke_dmp(FAST_S)
    slow = slowed_dmp(params, 3.0)
    assert float(slow.tau) == pytest.approx(3.0 * float(params.tau))
    t = np.linspace(0.0, float(params.tau), 57)
    assert (
        np.abs(rollout_numpy(slow, 3.0 * t, config) - rollout_numpy(params, t, config)).max() < 1e-9
    )
    assert slowed_dmp(params, 1.0) is params


def test_joint_speed_metrics_name_the_joint_nearest_its_limit():
    from img2dmp.robot.tempo import joint_speed_metrics

    @dataclasses.dataclass
    class Log:
        time_s: np.ndarray
        joint_qd_rad_s: np.ndarray

    qd = np.zeros((4, 7))
    qd[1, 0] = 1.4  # 94 % of 1.48 rad/s (85 deg/s)
    qd[2, 3] = -1.0  # 76 % of 1.31 rad/s
    m = joint_speed_metrics(Log(np.arange(1, 5) * 0.1, qd))
    assert m["joint_speed_peak_joint"] == "lbr_iiwa_joint_1"
    assert m["joint_speed_peak_share"] == pytest.approx(1.4 / np.radians(85))
    assert m["joint_speed_peak_time_s"] == pytest.approx(0.2)
    assert m["joint_speed_peak_rad_s"][3] == pytest.approx(1.0)
    empty = joint_speed_metrics(Log(np.arange(1, 5) * 0.1, np.full((4, 7), np.nan)))
    assert np.isnan(empty["joint_speed_peak_share"])


def test_joint_speed_share_is_checked():
    from img2dmp.robot import WritingOptions

    for bad in (0.0, -0.5, 1.5, float("nan"), True):
        with pytest.raises(ValueError, match="joint_speed_share must be in"):
            WritingOptions(joint_speed_share=bad)
        with pytest.raises(ValueError, match="joint_acceleration_share must be in"):
            WritingOptions(joint_acceleration_share=bad)
    assert WritingOptions(joint_speed_share=None).joint_speed_share is None


# -- the simulated arm ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fast_runs():
    """The fast stroke written as it is and slowed (the default)."""
    if not available():
        pytest.skip("pybullet is not installed")
    from img2dmp.robot import write_dmp

    params, config = stroke_dmp(FAST_S)
    own = write_dmp(params, config, IMAGE_SIZE, render_size_px=None, joint_speed_share=None,
                    joint_acceleration_share=None)  # fmt: skip
    slowed = write_dmp(params, config, IMAGE_SIZE, render_size_px=None)
    return params, own, slowed


@needs_pybullet
def test_a_dmp_too_fast_for_the_iiwa_is_slowed_until_its_joints_can_follow(fast_runs):
    params, own, slowed = fast_runs
    # At its own tempo the simulated arm follows, but joint 4 goes past the real limit.
    assert own.slowing.factor == 1.0 and own.metrics["joint_speed_peak_share"] > 1.0
    assert own.metrics["joint_speed_peak_joint"] == "lbr_iiwa_joint_4"
    # Slowed: the plan's tau is the slowed one and every joint stays within its limit.
    s = slowed.slowing
    assert s.slowed and s.joint_name == "lbr_iiwa_joint_4" and s.factor > 1.5
    assert s.planned_peak_rad_s > s.limit_rad_s  # the plan saw what the arm did
    assert slowed.plan.time_s[-1] == pytest.approx(float(params.tau) * s.factor, abs=1 / 240)
    assert slowed.metrics["joint_speed_peak_share"] < 0.9
    assert slowed.metrics["slowdown"] == s.factor
    assert np.all(np.abs(slowed.log.joint_qd_rad_s) <= np.radians([85, 85, 100, 75, 130, 135, 135]))
    # The same path: the slowed plan is the DMP's own rollout at t / factor.
    config = DMPConfig(n_kernels=20, n_dims=2, scaling="none")
    same = rollout_numpy(params, slowed.plan.time_s / s.factor, config)  # [T, 2]
    assert np.abs(slowed.plan.xy_px - same).max() < 1e-9
    assert slowed.metrics["stroke_ink_share_min"] >= 0.98


@needs_pybullet
def test_the_slowed_plan_keeps_its_joint_accelerations_within_the_limit(fast_runs):
    """Planned again, independently, along the slowed plan: every joint within its
    acceleration limit; at the DMP's own tempo they were far over it."""
    from img2dmp.robot import WritingScene
    from img2dmp.robot.joints import IIWA_ACCELERATION_LIMITS_RAD_S2 as acc_limits
    from img2dmp.robot.scene import HOME_JOINTS_RAD, SceneConfig
    from img2dmp.robot.tempo import planned_joint_accelerations, planned_joint_velocities
    from img2dmp.robot.writing import PEN_DOWN_ROTATION

    _, own, slowed = fast_runs
    with WritingScene(SceneConfig(), time_step_s=1 / 240) as scene:
        peaks = {}
        for name, run in (("own", own), ("slowed", slowed)):
            _, qd = planned_joint_velocities(scene, run.plan, np.array(HOME_JOINTS_RAD),
                                             PEN_DOWN_ROTATION)  # fmt: skip
            peaks[name] = np.abs(planned_joint_accelerations(qd, run.plan.time_s)).max(axis=0)
    assert np.max(peaks["own"] / acc_limits) > 2.0
    assert np.all(peaks["slowed"] <= acc_limits), peaks["slowed"]
    assert slowed.slowing.written_shares()[1] == pytest.approx(np.max(peaks["slowed"] / acc_limits))
    assert slowed.metrics["planned_joint_acceleration_share"] <= 1.0
    assert own.metrics["planned_joint_acceleration_share"] > 2.0


@needs_pybullet
def test_a_dmp_within_the_limits_is_written_exactly_as_before():
    from img2dmp.robot import write_dmp

    params, config = stroke_dmp(0.6)
    kw = {"render_size_px": None}
    slowed = write_dmp(params, config, IMAGE_SIZE, **kw)
    own = write_dmp(params, config, IMAGE_SIZE, joint_speed_share=None,
                    joint_acceleration_share=None, **kw)  # fmt: skip
    assert slowed.slowing.factor == 1.0 and not slowed.slowing.slowed
    for name in ("time_s", "cmd_m", "tip_m", "joint_q_rad", "joint_qd_rad_s"):
        assert np.array_equal(slowed.log[name], own.log[name]), name
    assert 0 < slowed.metrics["joint_speed_peak_share"] < 0.6


@needs_pybullet
def test_only_the_characters_of_a_page_that_need_it_are_slowed():
    from img2dmp.robot import WritingScene
    from img2dmp.robot.page import slow_page_plan
    from img2dmp.robot.tempo import JOINT_SPEED_SHARE
    from test_robot_page import page_with_a_fast_l

    plan, options, params = page_with_a_fast_l()
    with WritingScene(options.scene_config, time_step_s=options.dt_s) as scene:
        slowed = slow_page_plan(scene, plan)
    factors = [cp.slowing.factor for cp in slowed.characters]
    assert factors[0] == factors[2] == 1.0 and factors[1] > 1.0, factors
    assert slowed.characters[0] is not plan.characters[0]  # replaced, with its slowing
    assert slowed.characters[0].params is plan.characters[0].params
    l_char = slowed.characters[1]
    assert float(l_char.params.tau) == pytest.approx(float(params.tau) * factors[1])
    ratio = l_char.slowing.planned_peak_rad_s / factors[1] / l_char.slowing.limit_rad_s
    assert ratio <= JOINT_SPEED_SHARE


# -- the command line -------------------------------------------------------------------------


@needs_pybullet
def test_the_tempo_written_is_told_before_the_first_step(fast_runs):
    """``on_tempo`` gets the slowed tau before the run, so a progress estimate from the
    DMP's own tau (the command's bar, the web's write job) can be set right."""
    from img2dmp.robot import write_dmp

    params, _, slowed = fast_runs
    told, steps = [], []
    config = stroke_dmp(FAST_S)[1]
    result = write_dmp(params, config, IMAGE_SIZE, render_size_px=None, on_tempo=told.append,
                       progress=lambda n: steps.append((len(told), n)))  # fmt: skip
    assert told == [pytest.approx(float(params.tau) * slowed.slowing.factor)]
    assert told[0] > 1.5 * float(params.tau)  # the slowed tau, not the DMP's own
    assert steps and all(k == 1 for k, _ in steps)  # told before any step was reported
    assert result.slowing.factor == slowed.slowing.factor


@needs_pybullet
def test_a_run_over_the_acceleration_limit_is_warned_of_and_a_slowed_one_not(fast_runs):
    from img2dmp.robot.outputs import joint_acceleration_warning, writing_warnings

    _, own, slowed = fast_runs
    warning = joint_acceleration_warning(own.metrics)
    share = own.metrics["planned_joint_acceleration_share"]
    assert warning is not None and f"{100 * share:.0f} % of the planning limit" in warning
    assert own.metrics["planned_joint_acceleration_joint"] in warning
    assert warning in writing_warnings(own)
    assert joint_acceleration_warning(slowed.metrics) is None
    assert not any("accelerate" in w for w in writing_warnings(slowed))


@needs_pybullet
def test_write_command_slows_a_fast_dmp_and_says_so(tmp_path, capsys):
    from img2dmp.cli import main
    from img2dmp.robot import load_joint_trajectory, save_dmp_json

    params, config = stroke_dmp(FAST_S)
    save_dmp_json(tmp_path / "fast.json", params, config, IMAGE_SIZE, frame="image")
    out = tmp_path / "out"
    argv = ["write", "--dmp", str(tmp_path / "fast.json"), "--out-dir", str(out),
            "--export-joints", str(out / "joints"), "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    captured = capsys.readouterr()
    notes = [line for line in captured.err.splitlines() if "slower" in line]
    assert len(notes) == 1 and "fast: written" in notes[0] and "lbr_iiwa_joint_4" in notes[0]
    assert "joint speeds within the real iiwa's limits" in captured.out
    assert "joint accelerations planned along the DMPs within the planning limit" in captured.out
    assert "warning" not in captured.err
    traj = load_joint_trajectory(out / "joints.json")
    assert traj.limit_violation() is None


@needs_pybullet
def test_export_joints_of_a_motion_over_the_limits_writes_nothing(tmp_path, capsys):
    """At the DMP's own tempo (--no-slowing) the trajectory is refused before any file of
    the run is written, and the message says so; the metrics are printed all the same."""
    from img2dmp.cli import main
    from img2dmp.robot import save_dmp_json

    params, config = stroke_dmp(FAST_S)
    save_dmp_json(tmp_path / "fast.json", params, config, IMAGE_SIZE, frame="image")
    out = tmp_path / "out"
    argv = ["write", "--dmp", str(tmp_path / "fast.json"), "--out-dir", str(out), "--video",
            "--export-joints", str(tmp_path / "joints"), "--no-slowing",
            "--no-progress"]  # fmt: skip
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert "joint speeds OVER the real iiwa's limits" in captured.out
    err = captured.err.strip().splitlines()
    assert "a real iiwa cannot follow this motion" in err[-3]
    assert "would accelerate at" in err[-2] and "planning limit" in err[-2]
    assert err[-1].startswith(
        f"img2dmp write: error: {tmp_path / 'joints.json'}: joint trajectory: "
    )
    assert "nothing of fast written" in err[-1] and "without --no-slowing" in err[-1]
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["fast.json"]
    json.loads((tmp_path / "fast.json").read_text())  # the input untouched


def test_acceleration_share_is_checked_on_the_command_line(tmp_path, capsys):
    """A share outside (0, 1], or with --no-slowing, is a one-line error before anything
    is simulated."""
    from img2dmp.cli import main
    from img2dmp.robot import save_dmp_json

    params, config = stroke_dmp(0.6)
    save_dmp_json(tmp_path / "s.json", params, config, IMAGE_SIZE, frame="image")
    base = ["write", "--dmp", str(tmp_path / "s.json"), "--out-dir", str(tmp_path / "o"),
            "--no-progress"]  # fmt: skip
    for extra, says in (
        (["--acceleration-share", "0"], "--acceleration-share must be in (0, 1], got 0"),
        (["--acceleration-share", "1.5"], "--acceleration-share must be in (0, 1], got 1.5"),
        (["--acceleration-share", "nan"], "--acceleration-share must be in (0, 1], got nan"),
        (["--acceleration-share", "0.5", "--no-slowing"], "not with --no-slowing"),
    ):
        assert main(base + extra) == 2, extra
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0], err
    assert not (tmp_path / "o").exists()
