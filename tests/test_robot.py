"""The simulated KUKA writes DMPs: tracking, contact force, pen lifts, checks, files.

Needs pybullet (``pip install -e '/path/to/img2dmp[robot]'``); those tests are skipped without it.
DMPs are fitted to synthetic pen paths in the pixels of a 28 x 28 image.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from img2dmp.dmp import DMPConfig, fit_dmp
from img2dmp.robot import available, load_dmp_json, save_dmp_json

needs_pybullet = pytest.mark.skipif(
    not available(), reason="pybullet is not installed (pip install -e '/path/to/img2dmp[robot]')"
)

DURATION_S = 3.0
IMAGE_SIZE = (28, 28)


def _min_jerk(n: int) -> np.ndarray:
    u = np.linspace(0.0, 1.0, n)
    return 10 * u**3 - 15 * u**4 + 6 * u**5


def _resample(points: np.ndarray, n: int = 300) -> np.ndarray:
    """Points along a polyline at min-jerk arc-length spacing (starts and ends at rest)."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    u = _min_jerk(n) * s[-1]
    return np.stack([np.interp(u, s, points[:, 0]), np.interp(u, s, points[:, 1])], axis=-1)


def circle_path() -> np.ndarray:
    a = np.linspace(0.0, 1.9 * np.pi, 200)
    return _resample(np.stack([14 + 8 * np.cos(a), 14 + 8 * np.sin(a)], axis=-1))


def two_path() -> np.ndarray:
    """A "2": an arc over the top, a diagonal to the bottom left, a base line."""
    a = np.linspace(np.radians(160), np.radians(-40), 120)
    arc = np.stack([14 + 6 * np.cos(a), 11 - 6 * np.sin(a)], axis=-1)  # rows grow down
    corner, end = np.array([8.0, 22.0]), np.array([21.0, 22.0])
    diag = arc[-1] + (corner - arc[-1]) * np.linspace(0, 1, 80)[1:, None]
    base = corner + (end - corner) * np.linspace(0, 1, 60)[1:, None]
    return _resample(np.concatenate([arc, diag, base]))


def plus_path() -> np.ndarray:
    """Two strokes (down, then across) joined by a pen-up travel: [T, 3] with a pen channel."""
    segments = [((14, 6), (14, 22), 1.0), ((14, 22), (7, 14), 0.0), ((7, 14), (21, 14), 1.0)]
    parts = []
    for a, b, pen in segments:
        a, b = np.array(a, float), np.array(b, float)
        xy = a + (b - a) * _min_jerk(100)[:, None]
        parts.append(np.concatenate([xy, np.full((100, 1), pen)], axis=1))
    return np.concatenate(parts)


def fitted(y: np.ndarray, n_kernels: int = 25):
    config = DMPConfig(n_kernels=n_kernels, n_dims=y.shape[1], scaling="none")
    t = np.linspace(0.0, DURATION_S, len(y))
    fit = fit_dmp(t, y, config)
    assert float(fit.error_px) < 0.3
    return fit.params, config


# -- file format (no pybullet needed) ------------------------------------------------------


def test_dmp_json_round_trip(tmp_path):
    params, config = fitted(circle_path())
    path = tmp_path / "circle.json"
    save_dmp_json(path, params, config, IMAGE_SIZE, label="circle")
    p2, c2, size = load_dmp_json(path)
    assert c2 == config and size == IMAGE_SIZE
    np.testing.assert_allclose(p2.to_vector(), params.to_vector())
    assert json.loads(path.read_text())["label"] == "circle"


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda d: d.pop("image_size"), "image_size"),
        (lambda d: d.update(image_size=[28]), "image_size"),
        (lambda d: d["params"].pop("tau"), "params"),
        (lambda d: d["params"].update(tau=-1.0), "params"),
        (lambda d: d["params"].update(w=[[[0.0] * 2] * 25]), "params"),
        (lambda d: d["dmp_config"].update(n_kernels=1), "dmp_config"),
        (lambda d: d["dmp_config"].update(n_dims=3), "params"),
    ],
)
def test_dmp_json_errors_name_file_and_field(tmp_path, mutate, field):
    params, config = fitted(circle_path())
    path = tmp_path / "bad.json"
    save_dmp_json(path, params, config, IMAGE_SIZE)
    doc = json.loads(path.read_text())
    mutate(doc)
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=rf"bad\.json: field '{field}'"):
        load_dmp_json(path)


# -- pixels to paper ----------------------------------------------------------------------


@needs_pybullet
def test_paper_mapping_by_hand():
    from img2dmp.robot import PaperMapping

    m = PaperMapping((28, 28), writing_height_mm=28.0, center_m=(0.5, 0.1))
    # 1 mm per pixel; centre of a 28-pixel image is pixel 13.5.
    np.testing.assert_allclose(m.to_table([13.5, 13.5]), [0.5, 0.1])
    # One column right -> writer's right (-y); one row down -> towards the robot (-x).
    np.testing.assert_allclose(m.to_table([14.5, 13.5]), [0.5, 0.099])
    np.testing.assert_allclose(m.to_table([13.5, 14.5]), [0.499, 0.1])
    xy = np.array([[3.0, 7.0], [20.0, 1.0]])
    np.testing.assert_allclose(m.to_pixels(m.to_table(xy)), xy)
    with pytest.raises(ValueError, match="writing_height_mm"):
        PaperMapping((28, 28), writing_height_mm=0.0)


@needs_pybullet
def test_a_turned_paper_mapping_turns_the_image_about_its_centre_by_hand():
    """``turn_deg`` 90 (counter-clockwise as seen): the image's right (+column) becomes
    its up (away from the robot, world +x), its down becomes its right (world -y)."""
    from img2dmp.robot import PaperMapping

    m = PaperMapping((20, 40), writing_height_mm=40.0, center_m=(0.5, 0.1), turn_deg=90.0)
    # turned, the 40 x 20 image stands 40 px tall and 20 wide: 1 mm per pixel, its centre
    # (the pixel centre 19.5, 9.5) on the paper's
    np.testing.assert_allclose(m.area_px, (10.0, -10.0, 30.0, 30.0), atol=1e-9)  # pixel bounds
    np.testing.assert_allclose(m.area_size_mm, (20.0, 40.0), atol=1e-9)
    np.testing.assert_allclose(m.to_table([19.5, 9.5]), [0.5, 0.1], atol=1e-12)
    np.testing.assert_allclose(m.to_table([20.5, 9.5]), [0.501, 0.1], atol=1e-12)
    np.testing.assert_allclose(m.to_table([19.5, 10.5]), [0.5, 0.099], atol=1e-12)
    xy = np.array([[3.0, 7.0], [39.0, 1.0]])
    np.testing.assert_allclose(m.to_pixels(m.to_table(xy)), xy, atol=1e-9)
    assert m.image_area_px == (0, 0, 40, 20)
    with pytest.raises(ValueError, match="turn_deg must be a number of degrees"):
        PaperMapping((28, 28), turn_deg=float("nan"))
    with pytest.raises(ValueError, match="area_px of a turned mapping"):
        PaperMapping((28, 28), area_px=(5, 5, 5, 9), turn_deg=10.0)


@needs_pybullet
def test_ik_puts_the_tip_frame_at_the_pen_tip():
    from img2dmp.robot import WritingScene
    from img2dmp.robot.scene import HOME_JOINTS_RAD
    from img2dmp.robot.writing import PEN_DOWN_ROTATION

    with WritingScene() as scene:
        q = np.array(HOME_JOINTS_RAD)
        for target in ([0.55, 0.0, 0.001], [0.50, -0.04, 0.02], [0.60, 0.05, 0.001]):
            q, residual = scene.solve_ik(target, PEN_DOWN_ROTATION, q, max_iterations=200)
            assert residual < 1e-6
            # Independent check on the simulated robot, not the IK twin.
            scene.reset_joints(q)
            tip, axis = scene.tip_pose()
            np.testing.assert_allclose(tip, target, atol=1e-6)
            np.testing.assert_allclose(axis, [0, 0, -1], atol=1e-5)


# -- writing ------------------------------------------------------------------------------


def _assert_wrote_well(result, force_set_n=5.0):
    m = result.metrics
    assert m["tracking_error_mean_mm"] < 1.0, m
    assert m["force_in_band_share"] >= 0.95, m
    assert m["contact_share"] >= 0.95, m
    assert abs(m["force_mean_n"] - force_set_n) < 0.2 * force_set_n, m
    log = result.log
    write = (log["phase"] == 1) & log["pen_down"]
    # The force comes from physics: in contact the tip is pressed into the paper by about
    # F / contact stiffness, which the admittance loop must have found on its own.
    surface = result.scene_config.paper_top_z
    depth_m = surface - log["tip_m"][write, 2]
    expected_m = force_set_n / result.scene_config.contact_stiffness_n_per_m
    assert abs(float(np.median(depth_m)) - expected_m) < 0.3 * expected_m
    # The torques are the controller's, within the iiwa's limits and holding up the arm.
    tau = log["torque_nm"]
    assert np.all(np.abs(tau) <= 300.0)
    assert np.abs(tau[:, 1]).mean() > 1.0  # the shoulder carries the arm's weight


@needs_pybullet
@pytest.mark.parametrize("rate_hz", [240.0, 1000.0])
def test_circle_is_written(rate_hz):
    from img2dmp.robot import write_dmp

    params, config = fitted(circle_path())
    result = write_dmp(params, config, IMAGE_SIZE, control_rate_hz=rate_hz, render_size_px=None)
    _assert_wrote_well(result)
    # The ink lies on the circle of radius 8 px around (14, 14) and goes most of the way
    # round (1.9 pi of 2 pi).
    ink_px = result.mapping.to_pixels(result.log["tip_m"][result.log["force_n"] > 0, :2])
    rel = ink_px - [14.0, 14.0]
    np.testing.assert_allclose(np.linalg.norm(rel, axis=1), 8.0, atol=0.15)
    angles = np.unique(np.floor(np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) / 10))
    assert len(angles) >= 34


@needs_pybullet
def test_digit_two_is_written():
    from img2dmp.robot import write_dmp

    params, config = fitted(two_path())
    result = write_dmp(params, config, IMAGE_SIZE, render_size_px=None)
    _assert_wrote_well(result)
    # The ink follows the whole "2": every point of the DMP's path has ink within 0.1 px
    # (0.14 mm); the DMP itself is up to half a pixel off the drawn "2" at the corner.
    ink_px = result.mapping.to_pixels(result.log["tip_m"][result.log["force_n"] > 0, :2])
    path = result.plan.xy_px
    dist = np.linalg.norm(path[:, None, :] - ink_px[None, :, :], axis=2).min(axis=1)
    assert dist.max() < 0.1


@needs_pybullet
def test_pen_lifts_between_strokes():
    from img2dmp.robot import write_dmp

    params, config = fitted(plus_path(), n_kernels=40)
    result = write_dmp(params, config, IMAGE_SIZE, render_size_px=None)
    log, plan = result.log, result.plan
    write = log["phase"] == 1
    up = write & ~log["pen_down"]
    assert up.sum() * (1 / 240) > 0.5  # the DMP's pen channel asks for a lift
    surface = result.scene_config.paper_top_z
    # Mid-travel the pen is in the air, well clear of the paper, and leaves no ink (the
    # last 0.25 s of the travel: the pen lowers to hover, the clock slows to the landing).
    mid_up = up & (np.cumsum(up) > 30) & (np.cumsum(up) < up.sum() - 60)
    assert np.all(log["force_n"][mid_up] == 0.0)
    assert np.all(log["tip_m"][mid_up, 2] > surface + 0.004)
    # Both strokes are inked: contact near each stroke's midpoint.
    ink_px = result.mapping.to_pixels(log["tip_m"][log["force_n"] > 0, :2])
    for mid in ([14.0, 14.0 - 4.0], [17.5, 14.0]):
        assert np.min(np.linalg.norm(ink_px - mid, axis=1)) < 0.3
    # And nothing on the pen-up diagonal from (14, 22) to (7, 14).
    assert np.min(np.linalg.norm(ink_px - [10.5, 18.0], axis=1)) > 2.0
    assert plan.pen_down.any() and not plan.pen_down.all()
    assert result.metrics["tracking_error_mean_mm"] < 1.0
    # The DMP waits for the pen to land (issue 20): both strokes written whole, the force
    # in band for the pen-down time with the DMP running (was about 90 %).
    strokes = result.metrics["strokes"]
    assert len(strokes) == 2 and all(s["ink_share"] >= 0.98 for s in strokes), strokes
    assert result.metrics["force_in_band_share"] >= 0.95, result.metrics
    assert result.metrics["contact_share"] >= 0.95, result.metrics


@needs_pybullet
@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"writing_height_mm": 400.0}, "leaves the paper"),
        ({"scene_config": "far"}, "cannot reach"),
        # so far off that the IK overflowed: refused before it, a short number
        (
            {"scene_config": "very far"},
            r"maps to world \(1e\+308, [-\d.]+\) m, more than 2 m "
            r"from the arm's base; move",
        ),  # fmt: skip
    ],
)
def test_bad_path_fails_before_the_arm_moves(monkeypatch, kwargs, message):
    from img2dmp.robot import SceneConfig, WritingScene, write_dmp

    far = {"far": (1.3, 0.0), "very far": (1e308, 0.0)}.get(kwargs.get("scene_config"))
    if far:
        kwargs = {"scene_config": SceneConfig(paper_center_m=far)}
    steps = []
    monkeypatch.setattr(WritingScene, "step", lambda self, tau: steps.append(tau))
    params, config = fitted(two_path())
    with pytest.raises(ValueError, match=message):
        write_dmp(params, config, IMAGE_SIZE, render_size_px=None, **kwargs)
    assert steps == []


@needs_pybullet
def test_invalid_settings_are_named():
    from img2dmp.robot import ControllerConfig, SceneConfig, write_dmp

    with pytest.raises(ValueError, match="force_set_n"):
        ControllerConfig(force_set_n=-1.0)
    assert ControllerConfig(force_set_n=30.0).force_set_n == 30.0
    for force in (30.5, 1e308):  # 1e308 N started a simulation that never settled
        with pytest.raises(ValueError, match=r"force_set_n is .* N, more than 30 N"):
            ControllerConfig(force_set_n=force)
    with pytest.raises(ValueError, match="paper_size_m"):
        SceneConfig(paper_size_m=(0.1, 0.0))
    params, config = fitted(circle_path())
    with pytest.raises(ValueError, match="control_rate_hz"):
        write_dmp(params, config, IMAGE_SIZE, control_rate_hz=10.0)
    with pytest.raises(ValueError, match="joint_bandwidth_hz"):
        write_dmp(
            params,
            config,
            IMAGE_SIZE,
            controller_config=ControllerConfig(joint_bandwidth_hz=60.0),
            render_size_px=None,
        )


# -- the run object and its typed log -----------------------------------------------------

LOG_FIELDS = (
    "time_s", "phase", "dmp_time_s", "pen_down", "cmd_m", "tip_m", "force_n", "torque_nm",
    "joint_q_rad", "joint_qd_rad_s", "dwell", "joint_q_ref_rad", "joint_qd_ref_rad_s",
)  # fmt: skip
CSV_HEADER = [
    "time_s", "phase", "dmp_time_s", "pen_down",
    "cmd_x_m", "cmd_y_m", "cmd_z_m", "tip_x_m", "tip_y_m", "tip_z_m", "force_n",
    *[f"torque_{j}_nm" for j in range(1, 8)],
    "dwell", *[f"q_{j}_rad" for j in range(1, 8)], *[f"qd_{j}_rad_s" for j in range(1, 8)],
]  # fmt: skip


def _old_log_dict(log) -> dict:
    """The log as the former ``_simulate`` built it: one float row per step, read back by
    column index."""
    rows = np.column_stack(
        [log.time_s, log.phase, log.dmp_time_s, log.pen_down, log.cmd_m, log.tip_m,
         log.force_n, log.torque_nm, log.joint_q_rad, log.joint_qd_rad_s, log.dwell]
    )  # fmt: skip
    return {
        "time_s": rows[:, 0],
        "phase": rows[:, 1].astype(int),
        "dmp_time_s": rows[:, 2],
        "pen_down": rows[:, 3].astype(bool),
        "cmd_m": rows[:, 4:7],
        "tip_m": rows[:, 7:10],
        "force_n": rows[:, 10],
        "torque_nm": rows[:, 11:18],
        "joint_q_rad": rows[:, 18:25],
        "joint_qd_rad_s": rows[:, 25:32],
        "dwell": rows[:, 32].astype(bool),
    }


def test_writing_options_and_log_check_their_values():
    from img2dmp.robot import WritingLog, WritingOptions

    assert WritingOptions(control_rate_hz=1000.0).dt_s == pytest.approx(1e-3)
    with pytest.raises(ValueError, match="control_rate_hz"):
        WritingOptions(control_rate_hz=50.0)
    with pytest.raises(ValueError, match="frame_interval_s"):
        WritingOptions(frame_interval_s=0.0)
    n = 4
    good = {
        "time_s": np.arange(n) / 240, "phase": np.zeros(n, int), "dmp_time_s": np.zeros(n),
        "pen_down": np.ones(n, bool), "cmd_m": np.zeros((n, 3)), "tip_m": np.zeros((n, 3)),
        "force_n": np.zeros(n), "torque_nm": np.zeros((n, 7)),
    }  # fmt: skip
    log = WritingLog(**good)
    assert log.n_steps == n and tuple(log) == LOG_FIELDS and len(log) == len(LOG_FIELDS)
    assert log["force_n"] is log.force_n and "tip_m" in log and "nope" not in log
    with pytest.raises(KeyError):
        log["nope"]
    with pytest.raises(ValueError, match="'torque_nm'"):
        WritingLog(**{**good, "torque_nm": np.zeros((n, 6))})
    with pytest.raises(ValueError, match="'force_n'"):
        WritingLog(**{**good, "force_n": np.zeros(n + 1)})
    # A log made without joints and dwell (as before they were logged) gets NaN joints and
    # no dwell; given, they are checked like the rest.
    assert np.isnan(log.joint_q_rad).all() and log.joint_qd_rad_s.shape == (n, 7)
    assert log.dwell.dtype == bool and not log.dwell.any()
    with pytest.raises(ValueError, match="'joint_q_rad'"):
        WritingLog(**{**good, "joint_q_rad": np.zeros((n, 6))})
    with pytest.raises(ValueError, match="'dwell'"):
        WritingLog(**{**good, "dwell": np.zeros(n + 1, bool)})
    with pytest.raises(ValueError, match="stroke_dwell"):
        WritingOptions(stroke_dwell=1)


@needs_pybullet
def test_typed_log_is_consistent_and_gives_the_old_metrics(tmp_path):
    import matplotlib.pyplot as plt

    from img2dmp.robot import WritingLog, plot_writing, save_log_csv, write_dmp, writing_metrics

    params, config = fitted(plus_path(), n_kernels=40)
    result = write_dmp(params, config, IMAGE_SIZE, render_size_px=None)
    log = result.log
    assert isinstance(log, WritingLog) and tuple(log) == LOG_FIELDS
    s = log.n_steps
    for name in LOG_FIELDS:
        assert len(getattr(log, name)) == s, name
        assert log[name] is getattr(log, name)
    assert log.cmd_m.shape == (s, 3) and log.tip_m.shape == (s, 3)
    assert log.torque_nm.shape == (s, 7)
    assert log.joint_q_rad.shape == (s, 7) and log.joint_qd_rad_s.shape == (s, 7)
    assert log.phase.dtype.kind == "i" and log.pen_down.dtype == bool
    assert log.dwell.dtype == bool
    # Phases in order, one physics step per entry; the DMP's time rises on every write
    # step but the held ones, on which it stands still, up to the plan's end (its clock
    # slows to rest at the holds and the end: more steps than planned samples).
    assert np.all(np.diff(log.phase) >= 0) and set(log.phase) == {0, 1, 2}
    running = log.in_phase("write") & ~log.dwell
    assert np.all(np.diff(log.dmp_time_s[running]) > 0)
    assert log.dmp_time_s[running][-1] == pytest.approx(result.plan.time_s[-1], abs=1e-9)
    assert running.sum() > len(result.plan.time_s) - 1
    assert np.all(np.diff(log.dmp_time_s[log.dwell]) >= 0) and log.dwell.any()
    # A held step has the DMP time of the step it waits for (landing) or follows (lifting).
    held = np.flatnonzero(log.dwell)
    t = log.dmp_time_s
    assert np.all((t[held] == t[held - 1]) | (t[held] == t[held + 1]))
    np.testing.assert_allclose(np.diff(log.time_s), 1 / 240, rtol=1e-9)
    assert np.all(log.dmp_time_s[log.in_phase("approach")] == 0.0)
    # The metrics from the typed log equal those from the former column-indexed dict.
    old = writing_metrics(_old_log_dict(log), 5.0)
    assert writing_metrics(log, 5.0) == old == writing_metrics(dict(log), 5.0)
    assert {k: result.metrics[k] for k in old} == old
    # The CSV keeps its columns; the figure is written and closed.
    save_log_csv(result, tmp_path / "log.csv")
    with open(tmp_path / "log.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == CSV_HEADER and len(rows) == s + 1
    tip_z_m = float(rows[-1][CSV_HEADER.index("tip_z_m")])
    assert tip_z_m == pytest.approx(log.tip_m[-1, 2], abs=1e-6)
    q_4 = np.array([float(r[CSV_HEADER.index("q_4_rad")]) for r in rows[1:]])
    np.testing.assert_allclose(q_4, log.joint_q_rad[:, 3], atol=1e-8)
    assert sum(int(r[CSV_HEADER.index("dwell")]) for r in rows[1:]) == log.dwell.sum()
    plot_writing(result, tmp_path / "paper.png")
    assert (tmp_path / "paper.png").stat().st_size > 10_000 and not plt.get_fignums()


def test_planning_a_path_needs_no_torch_and_takes_tensors_alike():
    """The robot plans in NumPy: a fresh interpreter plans a DMP's path without importing
    torch (2-3 s of a write's start-up), and a DMP of torch tensors plans the same path."""
    code = """
import sys
import numpy as np
from img2dmp.dmp import DMPConfig, DMPParams
from img2dmp.robot import PaperMapping, plan_path
cfg = DMPConfig(n_kernels=5)
w = np.linspace(-50.0, 50.0, 10).reshape(5, 2)
p = DMPParams(w, np.array(1.0), np.array([20.0, 20.0]), np.array([8.0, 8.0]))
plan = plan_path(p, cfg, PaperMapping((28, 28), 40.0, (0.55, 0.0)), 1 / 240)
assert np.isfinite(plan.xy_m).all() and len(plan.time_s) == 241
assert "torch" not in sys.modules, "planning a path imported torch"
"""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            timeout=120)  # fmt: skip
    assert result.returncode == 0, result.stderr

    import torch

    from img2dmp.dmp import DMPParams, rollout
    from img2dmp.robot import PaperMapping, plan_path

    params, config = fitted(plus_path())
    mapping = PaperMapping(IMAGE_SIZE, 40.0, (0.55, 0.0))
    plan = plan_path(params, config, mapping, 1 / 240)
    fields = (params.w, params.tau, params.g, params.y0)
    tensors = DMPParams(*(torch.as_tensor(np.asarray(a)) for a in fields))
    np.testing.assert_array_equal(plan_path(tensors, config, mapping, 1 / 240).xy_px, plan.xy_px)
    # The NumPy path is torch's rollout, to rounding.
    y = rollout(params.to_torch(torch.float64), torch.from_numpy(plan.time_s), config).numpy()
    np.testing.assert_allclose(plan.xy_px, y[:, :2], rtol=0, atol=1e-9)


@needs_pybullet
def test_writing_run_stages_reproduce_write_dmp():
    from img2dmp.dmp import DMPIntegrator
    from img2dmp.robot import (
        PaperMapping,
        WritingController,
        WritingOptions,
        WritingRun,
        WritingScene,
        check_path,
        plan_path,
        write_with_options,
    )
    from img2dmp.robot.writing import PEN_DOWN_ROTATION, PHASES

    params, config = fitted(plus_path(), n_kernels=40)
    options = WritingOptions(render_size_px=None)
    expected = write_with_options(params, config, IMAGE_SIZE, options).log
    mapping = PaperMapping(IMAGE_SIZE, options.writing_height_mm, (0.55, 0.0))
    cfg = options.controller_config
    with WritingScene(options.scene_config, time_step_s=options.dt_s) as scene:
        plan = plan_path(params, config, mapping, options.dt_s)
        q_start = check_path(scene, plan, cfg)
        scene.reset_joints(q_start)
        z_m = scene.config.paper_top_z + cfg.lift_height_m
        ctl = WritingController(scene, cfg, PEN_DOWN_ROTATION, q_start, z_m)
        dmp = DMPIntegrator(params, config, max_step=options.dt_s)
        steps = []
        run = WritingRun(scene, plan, ctl, options, dmp, mapping, progress=steps.append)
        for stage in ("approach", "write", "lift"):
            getattr(run, stage)()
            assert PHASES[run.log().phase[-1]] == stage
        result = run.result(wall_s=1.0)
    # The simulation is deterministic: stage by stage equals the one call, step for step.
    for name in LOG_FIELDS:
        np.testing.assert_array_equal(result.log[name], expected[name])
    assert sum(steps) <= result.log.n_steps and set(steps) == {24}
    assert result.metrics["real_time_factor"] == pytest.approx(result.metrics["simulated_s"])


# -- command line -------------------------------------------------------------------------


@needs_pybullet
def test_write_command_with_dmp_file(tmp_path, capsys):
    from PIL import Image

    from img2dmp.cli import main

    params, config = fitted(two_path())
    dmp = tmp_path / "two.json"
    save_dmp_json(dmp, params, config, IMAGE_SIZE)
    out = tmp_path / "out"
    # Refused before anything runs, and no output folder left behind.
    for bad, said in ((["--force-n", "1e308"], "force_set_n is 1e+308 N, more than 30 N"),
                      (["--center-m", "3", "0"], "the arm cannot reach the DMP path"),
                      (["--center-m", "1.3", "0"], "move the writing area closer to the arm's"),
                      (["--center-m", "0.05", "0"], "move the writing area farther from the a"),
                      ):  # fmt: skip
        assert main(["write", "--dmp", str(dmp), "--out-dir", str(out), *bad]) == 2
        assert said in capsys.readouterr().err and not out.exists()
    code = main(["write", "--dmp", str(dmp), "--out-dir", str(out), "--no-progress"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "tracking error" in printed and "x real time" in printed
    with open(out / "two_log.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert {"time_s", "cmd_x_m", "tip_x_m", "force_n", "torque_7_nm"} <= set(rows[0])
    forces = np.array([float(r["force_n"]) for r in rows if r["phase"] == "write"])
    assert np.mean(np.abs(forces - 5.0) <= 1.0) >= 0.95
    for name in ("two_paper.png", "two_render.png"):
        with Image.open(out / name) as im:
            assert im.size[0] > 300 and im.size[1] > 200
    with Image.open(out / "two_render.png") as im:
        rgb = np.asarray(im.convert("RGB"), dtype=float)
    # The paper close-up (right half) shows dark ink on the light sheet.
    paper = rgb[:, rgb.shape[1] // 2 :]
    assert (paper.mean(axis=2) < 60).sum() > 200


def test_write_command_checks_an_image_without_model_before_the_shipped_model_reads_it(
    tmp_path, capsys
):
    # Without --model the shipped model reads the image (tests/test_models.py); a file that
    # is no image is still one line naming it, before any model is loaded.
    from img2dmp.cli import main

    image = tmp_path / "x.png"
    image.write_bytes(b"")
    code = main(["write", str(image), "--out-dir", str(tmp_path), "--no-progress"])
    assert code == 2
    err = capsys.readouterr().err
    assert f"{image} cannot be read as an image" in err or "pybullet" in err


def test_missing_pybullet_gives_install_hint(monkeypatch):
    import sys

    from img2dmp.robot import _pybullet

    monkeypatch.setitem(sys.modules, "pybullet", None)  # makes `import pybullet` fail
    assert not _pybullet.available()
    with pytest.raises(ImportError, match=r"pip install -e '/path/to/img2dmp\[robot\]'"):
        _pybullet.require()


def test_write_command_without_pybullet_says_how_to_install(monkeypatch, tmp_path, capsys):
    import sys

    from img2dmp.cli import main

    params, config = fitted(circle_path())
    dmp = tmp_path / "c.json"
    save_dmp_json(dmp, params, config, IMAGE_SIZE)
    monkeypatch.setitem(sys.modules, "pybullet", None)
    assert main(["write", "--dmp", str(dmp), "--out-dir", str(tmp_path), "--no-progress"]) == 2
    assert "pip install -e '/path/to/img2dmp[robot]'" in capsys.readouterr().err


def test_a_run_that_wrote_almost_nothing_is_warned_about():
    """A path of no length on the paper (goal-start scaling with g = y0, a huge frame) or
    a stroke mostly without ink (a tau the arm cannot follow) exit 0 with a warning."""
    from types import SimpleNamespace

    from img2dmp.robot.outputs import writing_warnings

    def run(*strokes):
        return SimpleNamespace(metrics={"strokes": [
            {"length_mm": n, "ink_share": s} for n, s in strokes]})  # fmt: skip

    assert writing_warnings(run((44.7, 1.0), (3.0, 0.9))) == []
    [line] = writing_warnings(run((0.1, 1.0), (0.2, 1.0)))
    assert line.startswith("its pen-down path is 0.30 mm long on the paper: almost nothing")
    [line] = writing_warnings(run((20.0, 0.8), (22.0, 0.011), (5.0, 0.3)))
    assert line.startswith("stroke 2 got ink along 1.1 % of its 22.0 mm")
    assert writing_warnings(run()) == []  # nothing planned pen-down: nothing to say
