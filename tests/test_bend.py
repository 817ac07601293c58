"""Bending a DMP (img2dmp.dmp.bend_dmp) against closed forms.

With ``s = t / tau`` a DMP's rollout is ``y = g + (y0 - g) a(s) + S P(s)``; with the
default constants ``a(s) = (1 + 24 s) exp(-24 s)`` (critical damping, alpha_z = 48). Each
test compares a bent DMP's rollout with what that closed form says the bent path is:
tempo, shift, scale and rotation exactly the transformed path; a new goal or start the
step response (no scaling) or the per-axis stretch (the paper's diag(g - y0) scaling).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from img2dmp.dmp import DMPConfig, DMPParams, affine_dmp, bend_dmp, fit_dmp, rollout

SCALINGS = ["none", "goal-start"]


def _free(s: np.ndarray) -> np.ndarray:
    """``a(s)``: the free response to a unit offset, alpha_z = 48, beta_z = 12 (closed form)."""
    return (1.0 + 24.0 * s) * np.exp(-24.0 * s)


def _movement(config: DMPConfig, n: int = 1) -> DMPParams:
    """``n`` fitted DMPs of curly paths whose start and goal differ in x and y."""
    t = np.linspace(0.0, 2.0, 160)
    out = []
    for i in range(n):
        y = np.stack([20 + 8 * np.cos(3 * t + i), 15 + 5 * np.sin(2 * t) + (3 + i) * t], -1)
        if config.n_dims == 3:
            y = np.concatenate([y, (t > 0.7 + 0.1 * i)[:, None] * 1.0], -1)
        out.append(fit_dmp(t, y, config).params)
    if n == 1:
        return out[0]
    return DMPParams(*(np.stack([getattr(p, f) for p in out]) for f in ("w", "tau", "g", "y0")))


def _roll(params: DMPParams, t, config: DMPConfig) -> np.ndarray:
    t = torch.as_tensor(np.asarray(t, dtype=np.float64))
    return rollout(params.to_torch(), t, config).numpy()


@pytest.mark.parametrize("scaling", SCALINGS)
@pytest.mark.parametrize("k", [0.5, 2.0, 3.7])
def test_tempo_k_replays_the_same_path_k_times_as_fast(scaling, k):
    config = DMPConfig(scaling=scaling)
    p = _movement(config)
    t = np.linspace(0.0, 1.3 * float(p.tau), 97)
    bent = bend_dmp(p, config, tempo=k)
    np.testing.assert_allclose(bent.tau, p.tau / k)
    # y_new(t) = y(k t): the bent DMP sampled at t / k is the original at t
    np.testing.assert_allclose(_roll(bent, t / k, config), _roll(p, t, config), atol=1e-9)
    # and it is not the original at the same times (the test can fail)
    assert np.abs(_roll(bent, t, config) - _roll(p, t, config)).max() > 0.1


@pytest.mark.parametrize("scaling", SCALINGS)
@pytest.mark.parametrize("d", [2, 3])
def test_scale_rotation_and_shift_about_the_start_are_exact(scaling, d):
    config = DMPConfig(scaling=scaling, n_dims=d)
    p = _movement(config)
    t = np.linspace(0.0, float(p.tau), 120)
    y, y0 = _roll(p, t, config), p.y0[:2]
    for s, deg, c in [(1.7, None, None), (None, 35.0, None), (0.6, -120.0, (4.0, -2.5))]:
        bent = bend_dmp(p, config, scale=s, rotate_deg=deg, shift=c)
        q = np.deg2rad(deg or 0.0)
        m = (s or 1.0) * np.array([[np.cos(q), -np.sin(q)], [np.sin(q), np.cos(q)]])
        want = y.copy()
        want[:, :2] = y0 + (y[:, :2] - y0) @ m.T + (c or 0.0)
        np.testing.assert_allclose(_roll(bent, t, config), want, atol=1e-9)
        np.testing.assert_allclose(bent.tau, p.tau)


def test_scale_under_the_papers_scaling_keeps_the_weights_and_none_scales_them():
    for scaling, factor in (("goal-start", 1.0), ("none", 2.5)):
        config = DMPConfig(scaling=scaling)
        p = _movement(config)
        np.testing.assert_allclose(bend_dmp(p, config, scale=2.5).w, factor * p.w, rtol=1e-12)


def test_moving_the_goal_alone_under_goal_start_scaling_stretches_it_does_not_rotate():
    config = DMPConfig(scaling="goal-start")
    p = _movement(config)
    q = np.deg2rad(40.0)
    r = np.array([[np.cos(q), -np.sin(q)], [np.sin(q), np.cos(q)]])
    t = np.linspace(0.0, float(p.tau), 100)
    y = _roll(p, t, config)
    rotated_goal = p.y0 + r @ (p.g - p.y0)
    moved = _roll(bend_dmp(p, config, goal=rotated_goal), t, config)
    stretch = (rotated_goal - p.y0) / (p.g - p.y0)
    np.testing.assert_allclose(moved, p.y0 + stretch * (y - p.y0), atol=1e-9)
    assert np.abs(moved - (p.y0 + (y - p.y0) @ r.T)).max() > 1.0  # not the rotated path


@pytest.mark.parametrize("scaling", SCALINGS)
def test_a_new_goal_without_forcing_is_the_closed_form_second_order_step(scaling):
    config = DMPConfig(scaling=scaling)
    p = DMPParams(np.zeros((25, 2)), 1.5, [30.0, 10.0], [5.0, 20.0])
    goal = np.array([12.0, -7.0])
    bent = bend_dmp(p, config, goal=goal)
    t = np.linspace(0.0, 2.0, 81)
    want = goal + (p.y0 - goal) * _free(t / 1.5)[:, None]
    np.testing.assert_allclose(_roll(bent, t, config), want, atol=1e-8)
    np.testing.assert_array_equal(bent.g, goal)
    np.testing.assert_array_equal(bent.y0, p.y0)


def test_a_new_goal_unscaled_adds_the_step_response_to_the_path():
    config = DMPConfig(scaling="none")
    p = _movement(config)
    goal = p.g + np.array([6.0, -9.0])
    t = np.linspace(0.0, float(p.tau), 90)
    bent = _roll(bend_dmp(p, config, goal=goal), t, config)
    step = (goal - p.g) * (1.0 - _free(t / float(p.tau)))[:, None]
    np.testing.assert_allclose(bent, _roll(p, t, config) + step, atol=1e-7)


def test_a_new_goal_under_goal_start_scaling_stretches_the_path_per_axis_about_the_start():
    config = DMPConfig(scaling="goal-start")
    p = _movement(config)
    goal = p.y0 + np.array([-0.5, 2.0]) * (p.g - p.y0)  # mirrored in x, doubled in y
    t = np.linspace(0.0, float(p.tau), 90)
    y = _roll(p, t, config)
    bent = _roll(bend_dmp(p, config, goal=goal), t, config)
    np.testing.assert_allclose(bent, p.y0 + np.array([-0.5, 2.0]) * (y - p.y0), atol=1e-9)


def test_a_new_start_unscaled_adds_a_decaying_offset():
    config = DMPConfig(scaling="none")
    p = _movement(config)
    start = p.y0 + np.array([-4.0, 3.0])
    t = np.linspace(0.0, float(p.tau), 90)
    bent = _roll(bend_dmp(p, config, start=start), t, config)
    offset = (start - p.y0) * _free(t / float(p.tau))[:, None]
    np.testing.assert_allclose(bent, _roll(p, t, config) + offset, atol=1e-7)
    np.testing.assert_allclose(bent[0], start, atol=1e-12)


def test_a_new_start_under_goal_start_scaling_stretches_the_path_about_the_goal():
    config = DMPConfig(scaling="goal-start")
    p = _movement(config)
    start = p.g - np.array([1.5, 0.25]) * (p.g - p.y0)
    t = np.linspace(0.0, float(p.tau), 90)
    y = _roll(p, t, config)
    bent = _roll(bend_dmp(p, config, start=start), t, config)
    np.testing.assert_allclose(bent, p.g + np.array([1.5, 0.25]) * (y - p.g), atol=1e-9)


@pytest.mark.parametrize("scaling", SCALINGS)
def test_the_given_start_and_goal_are_those_of_the_bent_dmp_whatever_else_changes(scaling):
    config = DMPConfig(scaling=scaling, n_dims=3)
    p = _movement(config)
    bent = bend_dmp(p, config, goal=[3.0, 4.0], start=[1.0, 2.0], scale=2.0, rotate_deg=90,
                    tempo=1.5)  # fmt: skip
    np.testing.assert_array_equal(bent.g[:2], [3.0, 4.0])
    np.testing.assert_array_equal(bent.y0[:2], [1.0, 2.0])
    assert bent.g[2] == p.g[2] and bent.y0[2] == p.y0[2]  # the pen channel is not a position
    np.testing.assert_allclose(bent.tau, p.tau / 1.5)
    same = bend_dmp(p, config)
    np.testing.assert_array_equal(same.to_vector(), p.to_vector())


@pytest.mark.parametrize("scaling", SCALINGS)
def test_a_batch_is_bent_item_by_item(scaling):
    config = DMPConfig(scaling=scaling)
    p = _movement(config, n=3)
    goals = np.array([[10.0, 5.0], [30.0, 40.0], [0.0, -3.0]])
    options = dict(scale=[1.0, 0.5, 2.0], rotate_deg=[0.0, 30.0, -75.0], tempo=[1.0, 2.0, 0.25])
    bent = bend_dmp(p, config, goal=goals, **options)
    for i in range(3):
        alone = bend_dmp(p[i], config, goal=goals[i], **{k: v[i] for k, v in options.items()})
        np.testing.assert_allclose(bent[i].to_vector(), alone.to_vector(), rtol=1e-12, atol=1e-12)
    shared = bend_dmp(p, config, goal=[7.0, 8.0], tempo=2.0)  # one value for every DMP
    np.testing.assert_array_equal(shared.g, np.tile([7.0, 8.0], (3, 1)))
    np.testing.assert_allclose(shared.tau, p.tau / 2.0)


def test_affine_dmp_takes_one_map_per_dmp():
    config = DMPConfig(scaling="goal-start")
    p = _movement(config, n=2)
    maps = np.array([[[0.8, -0.6, 3.0], [0.6, 0.8, 1.0]], [[2.0, 0.0, -5.0], [0.0, 0.5, 2.0]]])
    both = affine_dmp(p, config, maps)
    for i in range(2):
        alone = affine_dmp(p[i], config, maps[i])
        np.testing.assert_allclose(both[i].to_vector(), alone.to_vector(), rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match=r"batch shape \(3,\).*\(2,\)"):
        affine_dmp(p, config, np.stack([maps[0]] * 3))
    with pytest.raises(ValueError, match=r"not invertible.*batch index \[1\]"):
        affine_dmp(p, config, np.stack([maps[0], np.zeros((2, 3))]))


@pytest.mark.parametrize(
    "options, message",
    [
        (dict(goal=[np.nan, 3.0]), r"^goal must be finite, got NaN at index \[0\]$"),
        (dict(start=[1.0, np.inf]), r"^start must be finite, got Infinity at index \[1\]$"),
        (dict(shift=[1.0, -np.inf]), r"^shift must be finite, got -Infinity at index \[1\]$"),
        (dict(scale=np.nan), r"^scale must be finite, got NaN$"),
        (dict(scale=0.0), r"^scale must be a finite number > 0, got 0\.0$"),
        (dict(scale=-2.0), r"^scale must be a finite number > 0, got -2\.0$"),
        (dict(tempo=0.0), r"^tempo must be a finite number > 0, got 0\.0$"),
        (dict(tempo=-1.5), r"^tempo must be a finite number > 0, got -1\.5$"),
        (dict(tempo=np.inf), r"^tempo must be finite, got Infinity$"),
        (dict(rotate_deg=np.nan), r"^rotate_deg must be finite, got NaN$"),
        (
            dict(rotate_deg=1e308),
            r"^rotate_deg must be from -1e\+06 to 1e\+06 degrees, got 1e\+308$",
        ),
        (dict(rotate_deg=-1000001.0), r"^rotate_deg must be from -1e\+06 .* got -1000001\.0$"),
        (dict(tempo=True), r"^tempo must be a number or a list of numbers, got true$"),
        (dict(goal=[1.0, 2.0, 3.0]), r"^goal must be a point \(x, y\), got shape \[3\]$"),
        (dict(goal=5.0), r"^goal must be a point \(x, y\), got shape \[\]$"),
    ],
)
def test_bad_values_are_one_line_naming_the_value(options, message):
    config = DMPConfig()
    p = _movement(config)
    with pytest.raises(ValueError, match=message):
        bend_dmp(p, config, **options)


def test_bad_shapes_in_a_batch_and_impossible_bends_are_refused():
    config = DMPConfig()
    p = _movement(config, n=2)
    with pytest.raises(ValueError, match=r"^tempo at index \[1\] must be a finite number > 0"):
        bend_dmp(p, config, tempo=[1.0, -1.0])
    with pytest.raises(ValueError, match=r"^rotate_deg at index \[0\] must be from -1e\+06"):
        bend_dmp(p, config, rotate_deg=[-2e6, 30.0])
    turned = bend_dmp(p, config, rotate_deg=[1e6, -1e6])  # the bound itself: an exact angle
    np.testing.assert_allclose(
        turned.to_vector(), bend_dmp(p, config, rotate_deg=[280.0, -280.0]).to_vector(), atol=1e-9
    )
    with pytest.raises(
        ValueError, match=r"scale must be one number or one per DMP \(shape \[2\]\)"
    ):
        bend_dmp(p, config, scale=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"goal must be one point or one per DMP"):
        bend_dmp(p, config, goal=np.zeros((3, 2)))
    with pytest.raises(ValueError, match=r"needs d >= 2 dimensions.*d = 1"):
        one = DMPConfig(n_dims=1)
        bend_dmp(DMPParams(np.zeros((25, 1)), 1.0, [1.0], [0.0]), one, goal=[1.0, 2.0])
    # goal-start scaling: g - y0 = (10, 10) turned by 45 degrees has x = 0
    square = DMPParams(np.ones((25, 2)), 1.0, [20.0, 20.0], [10.0, 10.0])
    with pytest.raises(ValueError, match="g - y0 maps to 0 in coordinate 0"):
        bend_dmp(square, config, rotate_deg=45.0)
    with pytest.raises(ValueError, match="params must be a DMPParams, got dict"):
        bend_dmp({"w": 1}, config, tempo=2.0)


# -- img2dmp write --goal/--start/--shift/--scale/--rotate/--tempo -------------------------


def _dmp_file(tmp_path):
    from img2dmp.data.dmpfile import save_dmp_json

    t = np.linspace(0.0, 2.0, 200)
    y = np.stack([14 + 6 * np.cos(2 * t), 8 + 6 * t], -1)  # a curl down the 28-px frame
    config = DMPConfig(scaling="none")
    params = fit_dmp(t, y, config).params
    path = tmp_path / "curl.json"
    save_dmp_json(path, params, config, (28, 28))
    return path, params, config


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--goal", "3,nan"], "argument --goal: must be a finite number, got nan in '3,nan'"),
        (["--goal", "3"], "argument --goal: must be two numbers X,Y, got '3'"),
        (["--start", "a,2"], "argument --start: must be a number, got 'a' in 'a,2'"),
        (["--shift", "1,2,3"], "argument --shift: must be two numbers X,Y, got '1,2,3'"),
        (["--scale", "0"], "argument --scale: must be a finite number > 0, got 0"),
        (["--scale", "inf"], "argument --scale: must be a finite number > 0, got inf"),
        (["--scale", "1e300"], "scale must be from 1e-06 to 1e+06, got 1e+300"),
        (["--tempo", "1e-9"], "tempo must be from 1e-06 to 1e+06, got 1e-09"),
        (["--tempo", "-2"], "argument --tempo: must be a finite number > 0, got -2"),
        (["--tempo", "nan"], "argument --tempo: must be a finite number > 0, got nan"),
        (["--rotate=-inf"], "argument --rotate: must be a finite number, got -inf"),
    ],
)
def test_write_refuses_a_bad_bend_in_one_line_exit_2(tmp_path, capsys, flags, message):
    from img2dmp.cli import main

    path, _, _ = _dmp_file(tmp_path)
    assert main(["write", "--dmp", str(path), "--out-dir", str(tmp_path / "o"), *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "o").exists()


def _capture_write(monkeypatch) -> list:
    """Make ``img2dmp write`` stop where the arm would start, keeping what it was given."""
    import img2dmp.robot

    given = []

    def write_dmp(params, config, size, **kw):
        given.append((params, config, size))
        raise RuntimeError("stopped before the simulation (test)")

    monkeypatch.setattr(img2dmp.robot, "available", lambda: True)
    monkeypatch.setattr(img2dmp.robot, "write_dmp", write_dmp)
    return given


def test_write_hands_the_arm_the_bent_dmp(tmp_path, capsys, monkeypatch):
    from img2dmp.cli import main

    path, params, config = _dmp_file(tmp_path)
    given = _capture_write(monkeypatch)
    argv = ["write", "--dmp", str(path), "--out-dir", str(tmp_path / "o"), "--no-progress",
            "--goal", "20.5,22", "--scale", "0.8", "--rotate=-15", "--tempo", "1.5"]  # fmt: skip
    assert main(argv) == 1  # the stand-in arm fails on purpose
    [(bent, _, size)] = given
    want = bend_dmp(params, config, goal=(20.5, 22.0), scale=0.8, rotate_deg=-15.0, tempo=1.5)
    np.testing.assert_array_equal(bent.to_vector(), want.to_vector())
    assert size == (28, 28)
    out = capsys.readouterr().out
    assert "curl: bent (--goal 20.5,22 --scale 0.8 --rotate -15 --tempo 1.5)" in out
    assert "goal (20.50, 22.00) px" in out

    given.clear()
    assert main(argv[:6]) == 1  # no bending options: the file's DMP as it is
    np.testing.assert_array_equal(given[0][0].to_vector(), params.to_vector())


def test_a_negative_point_needs_no_equals_sign(tmp_path, capsys, monkeypatch):
    """``--shift -3,2`` is the point (-3, 2), as ``--shift=-3,2`` is; a word after a point
    option that is not a negative point, and words after ``--``, stay as they are."""
    from img2dmp.cli import main
    from img2dmp.commands._args import join_negative_points

    path, params, config = _dmp_file(tmp_path)
    given = _capture_write(monkeypatch)
    argv = ["write", "--dmp", str(path), "--out-dir", str(tmp_path / "o"), "--no-progress"]
    assert main([*argv, "--shift", "-3,2", "--goal", "-1.5e0,-4"]) == 1  # the stand-in fails
    want = bend_dmp(params, config, shift=(-3.0, 2.0), goal=(-1.5, -4.0))
    np.testing.assert_array_equal(given[0][0].to_vector(), want.to_vector())
    assert "bent (--goal -1.5,-4 --shift -3,2)" in capsys.readouterr().out
    assert join_negative_points(["--shift", "-3", "x", "--", "--goal", "-1,2", "--start"]) == [
        "--shift", "-3", "x", "--", "--goal", "-1,2", "--start"]  # fmt: skip
    assert main([*argv, "--shift", "-3"]) == 2
    assert "argument --shift: must be two numbers X,Y, got '-3'" in capsys.readouterr().err


def test_write_page_refuses_the_bending_options(tmp_path, capsys):
    from img2dmp.cli import main

    page = tmp_path / "p.json"
    page.write_text("{}")
    code = main(["write", str(page), "--page", "--tempo", "2", "--goal", "1,2"])
    assert code == 2
    assert "--goal, --tempo bend one DMP, not a page (--page)" in capsys.readouterr().err


def test_a_bend_the_dmp_cannot_take_is_one_line_exit_2(tmp_path, capsys, monkeypatch):
    from img2dmp.cli import main
    from img2dmp.data.dmpfile import save_dmp_json

    config = DMPConfig()  # goal-start: g - y0 = (10, 10) turned by 45 degrees has x = 0
    path = tmp_path / "diag.json"
    save_dmp_json(path, DMPParams(np.ones((25, 2)), 1.0, [20.0, 20.0], [10.0, 10.0]), config,
                  (28, 28))  # fmt: skip
    given = _capture_write(monkeypatch)
    code = main(["write", "--dmp", str(path), "--out-dir", str(tmp_path), "--rotate", "45"])
    assert code == 2 and not given
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "g - y0 maps to 0 in coordinate 0" in err


def test_the_arm_writes_a_bent_dmp_slower_to_its_new_goal(tmp_path):
    """``--tempo 0.5``: half as fast, twice the duration."""
    pytest.importorskip("pybullet", reason="the robot extra is not installed")
    import csv

    from img2dmp.cli import main
    from img2dmp.robot import PaperMapping

    path, params, config = _dmp_file(tmp_path)
    out = tmp_path / "o"
    argv = ["write", "--dmp", str(path), "--out-dir", str(out), "--no-progress",
            "--tempo", "0.5", "--goal", "8,20"]  # fmt: skip
    assert main(argv) == 0
    with open(out / "curl_log.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["phase"] == "write"]
    assert float(rows[-1]["dmp_time_s"]) == pytest.approx(2 * float(params.tau), abs=0.01)
    # where the commanded path ends on the paper is the bent DMP's end, not the file's
    t_end = float(rows[-1]["dmp_time_s"])
    bent = bend_dmp(params, config, tempo=0.5, goal=(8.0, 20.0))
    mapping = PaperMapping((28, 28), 40.0, (0.55, 0.0))
    got_px = mapping.to_pixels(np.array([float(rows[-1]["cmd_x_m"]), float(rows[-1]["cmd_y_m"])]))
    np.testing.assert_allclose(got_px, _roll(bent, [t_end], config)[0], atol=0.01)
    assert np.abs(got_px - _roll(params, [t_end / 2], config)[0]).max() > 2.0


@pytest.mark.parametrize("field", ["goal", "start", "shift"])
def test_a_position_beyond_any_image_is_refused_before_it_overflows(field):
    """A finite 1e308 became inf inside the bent DMP (the web API answered 500)."""
    params = DMPParams(np.zeros((25, 2)), 1.0, np.array([10.0, 12.0]), np.array([2.0, 3.0]))
    with pytest.raises(ValueError, match=rf"^{field} \[1e\+308, 0.0\] is beyond the 1e\+09 px"):
        bend_dmp(params, DMPConfig(), **{field: [1e308, 0.0]})
    bend_dmp(params, DMPConfig(), **{field: [1e9, 0.0]})  # the limit itself is a position


def test_an_image_frame_of_huge_or_no_numbers_is_one_line():
    from img2dmp.data.images import ImageFrame

    cases = [(np.diag([1e308, 1e308, 0])[:2], "entries up to 1e+308"),
             (np.full((2, 3), np.nan), "NaN or inf"), (np.eye(3), "shape [3, 3]")]  # fmt: skip
    for m, said in cases:
        with pytest.raises(ValueError) as e:
            ImageFrame(m, (280, 280), (28, 28))
        assert str(e.value).endswith(said) and "\n" not in str(e.value), e.value
