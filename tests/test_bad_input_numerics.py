"""Numerics and resources under bad or extreme input (issue 17, "Numerics and resources").

- the robot's online DMP integrator is stable for any tau and step, agrees with the exact
  rollout from tau = 1e-6 s to 1e3 s, and bounds its work;
- the arm's plan is the exact rollout (a short-tau DMP on the paper is written, not
  refused), and malformed DMPs and settings give one-line errors naming the field;
- image preparation is linear in the image's size (a crisp bar, a 12-megapixel noisy
  photo) and refuses absurd sizes;
- every size a user controls (trajectory points, figures, grids, refine steps, batch
  sizes, rendered images) is bounded with an error naming the value and the range.

Every error is a ``ValueError`` (or a subclass) with a one-line message. No test asserts a
duration; the slow-in-the-past cases print theirs.
"""

from __future__ import annotations

import importlib
import math
import time
import tracemalloc

import numpy as np
import pytest
import torch
from PIL import Image

from img2dmp.data import images as images_module
from img2dmp.data.images import prepare_image, stroke_width
from img2dmp.dmp import DMPConfig, DMPIntegrator, DMPParams, integrate, rollout
from img2dmp.robot import available

# The module, not the function of that name that img2dmp.dmp exports.
integrate_module = importlib.import_module("img2dmp.dmp.integrate")
needs_pybullet = pytest.mark.skipif(not available(), reason="pybullet is not installed")


def _one_line(excinfo, *needles: str) -> str:
    """The error's message: one line, a ValueError, containing every needle."""
    assert isinstance(excinfo.value, ValueError), type(excinfo.value)
    msg = str(excinfo.value)
    assert "\n" not in msg and msg, msg
    for needle in needles:
        assert needle in msg, (needle, msg)
    return msg


def _dmp(tau: float, seed: int = 0, config: DMPConfig | None = None) -> DMPParams:
    """A DMP on a 28 x 28 image with strong weights (a curly path)."""
    config = config or DMPConfig()
    w = np.random.default_rng(seed).normal(0.0, 1.0, (config.n_kernels, 2))
    w *= config.alpha_z * config.beta / 50.0
    return DMPParams(w=w, tau=np.float64(tau), g=np.array([18.0, 20.0]), y0=np.array([8.0, 7.0]))


def _exact(p: DMPParams, t: np.ndarray, config: DMPConfig) -> np.ndarray:
    return rollout(p.to_torch(), torch.from_numpy(np.asarray(t, np.float64)), config).numpy()


# -- the online integrator ------------------------------------------------------------


@pytest.mark.parametrize("tau", [1e-6, 1e-3, 1e-2, 1.0, 1e3])
def test_integrator_agrees_with_the_exact_rollout_for_any_tau(tau):
    """At a controller's 240 Hz and at steps of tau / 7: before, tau = 1e-3 s gave 1e20
    px after one 1/240 s step and tau = 1e-6 s overflowed."""
    config = DMPConfig()
    p = _dmp(tau)
    for dt in (1.0 / 240.0, tau / 7.0):
        dmp = DMPIntegrator(p, config)
        y = np.array([dmp.step(dt) for _ in range(40)])
        ref = _exact(p, np.arange(1, 41) * dt, config)
        assert np.isfinite(y).all()
        assert np.abs(y - ref).max() < 1e-4, (tau, dt, np.abs(y - ref).max())
    assert np.abs(dmp.y - p.g).max() < 1e-3  # 40 steps of tau / 7: near the goal


@pytest.mark.parametrize("beta_z", [5.0, 30.0])
def test_integrator_exact_for_over_and_under_damped_systems(beta_z):
    config = DMPConfig(beta_z=beta_z, scaling="none")
    p = _dmp(0.8, seed=1, config=config)
    t = np.linspace(0.0, 2.0, 97)
    assert np.abs(integrate(p, t, config) - _exact(p, t, config)).max() < 1e-4


def test_one_huge_step_is_exact_and_its_work_is_bounded(monkeypatch):
    """step(1e5) used to take 1e8 RK4 steps (hours); now the forcing term is integrated
    only while it matters (x > 1e-16) and the rest is the closed-form solution."""
    nodes = []
    real = integrate_module.forcing_term
    monkeypatch.setattr(
        integrate_module, "forcing_term", lambda x, *a: nodes.append(np.size(x)) or real(x, *a)
    )
    for tau in (1e-6, 1.0):
        nodes.clear()
        p = _dmp(tau)
        dmp = DMPIntegrator(p)
        t0 = time.perf_counter()
        y = dmp.step(1e5)
        print(f"tau {tau:g} s: step(1e5) in {time.perf_counter() - t0:.4f} s, {sum(nodes)} nodes")
        np.testing.assert_allclose(y, p.g, rtol=0, atol=1e-9)
        assert sum(nodes) < 20_000  # a whole movement: ~1800 pieces of 5 nodes
        assert dmp.t == 1e5 and math.isclose(dmp.x, 0.0, abs_tol=1e-300)


def test_goal_changed_while_running_is_followed():
    config = DMPConfig()
    p = _dmp(0.5)
    dmp = DMPIntegrator(p, config)
    for _ in range(60):
        dmp.step(1.0 / 240.0)
    dmp.g = np.array([2.0, 25.0])
    for _ in range(2400):
        y = dmp.step(1.0 / 240.0)
    assert np.isfinite(y).all() and np.abs(y - dmp.g).max() < 1e-6
    dmp.g = np.array([np.nan, 1.0])
    with pytest.raises(ValueError) as e:
        dmp.step(0.01)
    _one_line(e, "DMPIntegrator.g", "nan")


def test_tiny_max_step_is_refused_before_any_work(monkeypatch):
    # a small but sane max_step only refines the quadrature
    p = _dmp(1.0)
    t = np.linspace(0.0, 1.0, 11)
    fine = integrate(p, t, max_step=1e-4)
    assert np.abs(fine - _exact(p, t, DMPConfig())).max() < 1e-4
    calls = []
    monkeypatch.setattr(integrate_module, "forcing_term", lambda *a: calls.append(1))
    with pytest.raises(ValueError) as e:
        DMPIntegrator(p, max_step=1e-12).step(1.0)
    _one_line(
        e, "max_step", "1e-12", "quadrature pieces", str(integrate_module.MAX_PIECES_PER_STEP)
    )
    assert calls == []


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        ({"dt": 0.0}, "dt"),
        ({"dt": -1.0}, "dt"),
        ({"dt": float("nan")}, "dt"),
        ({"dt": float("inf")}, "dt"),
        ({"dt": "0.1"}, "dt"),
        ({"dt": True}, "dt"),
        ({"max_step": 0.0}, "max_step"),
        ({"max_step": float("nan")}, "max_step"),
        ({"params": {"tau": 1.0}}, "params must be a DMPParams"),
    ],
)
def test_integrator_arguments_are_checked(kwargs, needle):
    with pytest.raises(ValueError) as e:
        if "dt" in kwargs:
            DMPIntegrator(_dmp(1.0)).step(kwargs["dt"])
        elif "max_step" in kwargs:
            DMPIntegrator(_dmp(1.0), max_step=kwargs["max_step"])
        else:
            DMPIntegrator(kwargs["params"])
    _one_line(e, needle)


# -- the robot layer -------------------------------------------------------------------


def test_plan_is_the_exact_rollout_for_a_short_tau():
    from img2dmp.robot import PaperMapping, plan_path

    config = DMPConfig()
    p = _dmp(1e-3)
    plan = plan_path(p, config, PaperMapping((28, 28)), 1.0 / 240.0)
    assert plan.xy_px.shape == (2, 2) and np.isfinite(plan.xy_px).all()
    np.testing.assert_allclose(plan.xy_px, _exact(p, plan.time_s, config), atol=1e-9)
    np.testing.assert_allclose(plan.xy_px[-1], p.g, atol=1e-3)  # tau << 1/240 s


@needs_pybullet
def test_write_accepts_a_short_tau_dmp_that_stays_on_the_paper():
    """Before: "the DMP path leaves the paper ... (1e8, 1e8) px" from the diverged integrator."""
    from img2dmp.robot import write_dmp

    result = write_dmp(_dmp(1e-3), DMPConfig(), (28, 28), render_size_px=None)
    cmd_px = result.plan.xy_px
    assert np.isfinite(result.log.cmd_m).all() and np.abs(cmd_px - 14).max() < 14


@needs_pybullet
def test_write_a_zero_length_path_a_dot(tmp_path):
    import matplotlib.pyplot as plt

    from img2dmp.robot import plot_writing, write_dmp

    config = DMPConfig(scaling="none")
    dot = DMPParams(
        w=np.zeros((25, 2)), tau=np.float64(0.1), g=np.full(2, 14.0), y0=np.full(2, 14.0)
    )
    result = write_dmp(dot, config, (28, 28), render_size_px=None)
    assert np.ptp(result.plan.xy_px, axis=0).max() == 0.0
    assert result.metrics["pen_down_s"] > 0 and np.isfinite(result.metrics["force_mean_n"])
    plot_writing(result, tmp_path / "dot.png")
    assert (tmp_path / "dot.png").stat().st_size > 1000 and not plt.get_fignums()


def _bad_params(kind: str):
    p = _dmp(1.0)
    w, tau, g, y0 = p.w.copy(), p.tau.copy(), p.g.copy(), p.y0.copy()
    if kind == "nan w":
        w[3, 1] = np.nan
    elif kind == "inf g":
        g[0] = np.inf
    elif kind == "negative tau":
        tau = np.float64(-1.0)
    elif kind == "zero tau":
        tau = np.float64(0.0)
    elif kind == "long tau":
        tau = np.float64(1e7)
    elif kind == "two taus":
        tau = np.array([1.0, 2.0])
    elif kind == "strings":
        g = np.array(["1", "2"])
    else:
        return {"w": w}  # not a DMPParams at all
    obj = object.__new__(DMPParams)  # skip DMPParams' own checks: the robot's are tested
    obj.w, obj.tau, obj.g, obj.y0 = w, tau, g, y0
    return obj


@pytest.mark.parametrize(
    "kind, needles",
    [
        ("nan w", ("params.w[3, 1]", "nan")),
        ("inf g", ("params.g[0]", "inf")),
        ("negative tau", ("params.tau", "-1.0")),
        ("zero tau", ("params.tau", "0.0", "> 0")),
        ("long tau", ("params.tau", "1e+07", "250000")),
        ("two taus", ("params.tau", "one number")),
        ("strings", ("params.g", "numbers")),
        ("dict", ("params must be a DMPParams", "dict")),
    ],
)
def test_write_refuses_a_malformed_dmp_by_name_before_the_arm_moves(kind, needles, monkeypatch):
    from img2dmp.robot import WritingScene, write_dmp

    monkeypatch.setattr(WritingScene, "__init__", lambda *a, **k: pytest.fail("scene built"))
    with pytest.raises(ValueError) as e:
        write_dmp(_bad_params(kind), DMPConfig(), (28, 28), render_size_px=None)
    _one_line(e, *needles)


def test_write_takes_mixed_torch_numpy_and_integer_params():
    from img2dmp.robot import PaperMapping, plan_path

    config = DMPConfig()
    mapping = PaperMapping((28, 28))
    ref = plan_path(_dmp(2.0), config, mapping, 1.0 / 240.0)
    mixed = _dmp(2.0)  # DMPParams refuses a mix when made; fields can still be replaced
    mixed.w, mixed.y0 = torch.from_numpy(mixed.w), torch.from_numpy(mixed.y0)
    got = plan_path(mixed, config, mapping, 1.0 / 240.0)
    np.testing.assert_allclose(got.xy_px, ref.xy_px, rtol=0, atol=1e-12)
    ints = DMPParams(
        w=np.zeros((25, 2), int), tau=np.array(1), g=np.array([20, 9]), y0=np.array([5, 5])
    )
    plan = plan_path(ints, config, mapping, 1.0 / 240.0)
    assert plan.xy_px.dtype == np.float64 and np.allclose(plan.xy_px[0], [5, 5])


@pytest.mark.parametrize(
    "kwargs, needles",
    [
        ({"frame_size_px": (0, 240)}, ("frame_size_px", "(0, 240)", "[16, 4096]")),
        ({"frame_size_px": (10**6, 240)}, ("frame_size_px", "1000000")),
        ({"render_size_px": "big"}, ("render_size_px", "'big'")),
        ({"approach_timeout_s": 1e9}, ("approach_timeout_s", "600")),
        ({"settle_s": 5.0}, ("settle_s", "approach_timeout_s")),
        ({"control_rate_hz": "240"}, ("control_rate_hz", "'240'")),
        ({"scene_config": None}, ("scene_config", "SceneConfig")),
    ],
)
def test_writing_options_bound_every_size(kwargs, needles):
    from img2dmp.robot import WritingOptions

    with pytest.raises(ValueError) as e:
        WritingOptions(**kwargs)
    _one_line(e, *needles)


def test_video_size_is_bounded_before_the_simulation():
    from img2dmp.robot import WritingOptions

    options = WritingOptions(frame_interval_s=1e-4)
    with pytest.raises(ValueError) as e:
        options.check_video(2.0)
    _one_line(e, "frame_interval_s", "0.0001", "GiB")
    WritingOptions(frame_interval_s=0.1).check_video(2.0)  # the write command's default


@pytest.mark.parametrize("size", [(0, 28), (28, 2.5), "ab", (1, 2, 3), (float("nan"), 5)])
def test_paper_mapping_names_a_bad_image_size(size):
    from img2dmp.robot import PaperMapping

    with pytest.raises(ValueError) as e:
        PaperMapping(size)
    _one_line(e, "image_size", repr(size))


# -- image preparation: linear in the image's size -------------------------------------


@pytest.mark.parametrize("side", [200, 1000])
def test_a_crisp_bar_is_prepared_at_any_size(side, tmp_path):
    """A clean "1" as a PNG: before, 200 px failed with "zero-size array" (4.8 GB) and
    1000 px ran out of memory."""
    img = np.full((side, side), 255, np.uint8)
    img[side // 5 : 4 * side // 5, side // 2 - side // 40 : side // 2 + side // 40] = 0
    Image.fromarray(img).save(tmp_path / "bar.png")
    for width in (None, 3.0, 1.2):
        out = prepare_image(tmp_path / "bar.png", (28, 28), stroke_width_px=width)
        cols = np.flatnonzero((out > 0.5).any(axis=0))
        assert 1 <= cols.size <= 4 and (out > 0.5).sum(axis=0).max() >= 17, (width, cols)
        if width == 3.0:  # thickened (1.2 px is below what the width estimate resolves)
            assert abs(stroke_width(out) - width) < 0.5, stroke_width(out)


def _photo(h: int, w: int) -> np.ndarray:
    """A grey "photo": paper at 0.85 with sensor noise, a dark ring (a "0") drawn with a
    pen 1/30 of the image tall."""
    rng = np.random.default_rng(0)
    a = 0.85 + 0.05 * rng.standard_normal((h, w), dtype=np.float32)
    yy, xx = np.ogrid[0:h, 0:w]
    a[np.abs(np.hypot(xx - w / 2, yy - h / 2) - h / 4) < h / 60] = 0.15
    return (np.clip(a, 0.0, 1.0) * 255).astype(np.uint8)


def _check_ring(out: np.ndarray) -> None:
    ink = out > 0.5
    assert out.shape == (28, 28) and ink.sum() > 40
    assert not ink[12:16, 12:16].any()  # a ring: empty in the middle
    assert abs(stroke_width(out) - 3.0) < 1.0


@pytest.mark.parametrize("suffix", [".jpg", ".png"])
def test_a_twelve_megapixel_photo_is_prepared_in_linear_time_and_memory(suffix, tmp_path):
    """Before: a 6000 x 4000 photo took 84 s and 5.1 GB (the stroke-width step)."""
    path = tmp_path / f"photo{suffix}"
    Image.fromarray(_photo(3000, 4000)).convert("RGB").save(path)
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        out = prepare_image(path, (28, 28), stroke_width_px=3.0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    print(f"12 MP {suffix}: {time.perf_counter() - t0:.2f} s, NumPy peak {peak / 2**20:.0f} MiB")
    _check_ring(out)
    assert peak < 400 * 2**20  # NumPy's arrays (PIL's decoded image is not traced)


def test_a_twelve_megapixel_array_is_reduced_as_it_is_read():
    grey = _photo(3000, 4000)
    tracemalloc.start()
    try:
        out = prepare_image(grey, (28, 28), stroke_width_px=3.0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    _check_ring(out)
    assert peak < 400 * 2**20


def test_stroke_width_of_a_large_image_does_not_enlarge_it():
    a = np.zeros((3000, 3000), np.float32)
    a[:, 1490:1510] = 1.0  # a bar 20 px wide
    tracemalloc.start()
    try:
        w = stroke_width(a)  # upsample=4 would be a 144-megapixel image (576 MB)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert 19 < w < 24 and peak < 300 * 2**20


@pytest.mark.parametrize(
    "kwargs, needles",
    [
        ({"image_size": (100_000, 40)}, ("image_size", "100000", "[2, 1024]")),
        ({"image_size": (0, 40)}, ("image_size", "(0, 40)")),
        ({"image_size": (40.5, 40)}, ("image_size", "40.5")),
        ({"image_size": "40"}, ("image_size", "'40'")),
        ({"stroke_width_px": 1e9}, ("stroke_width_px", "1000000000.0", "(0, 10]")),
        ({"stroke_width_px": float("nan")}, ("stroke_width_px", "nan")),
        ({"margin": 0.6}, ("margin", "0.6")),
    ],
)
def test_prepare_image_bounds_its_sizes(kwargs, needles):
    bar = np.zeros((60, 60))
    bar[10:50, 28:32] = 1.0
    with pytest.raises(ValueError) as e:
        prepare_image(bar, **{"image_size": (40, 40), **kwargs})
    _one_line(e, *needles)


@pytest.mark.parametrize("limit", [5000, 1000])
def test_an_image_over_the_pixel_limit_is_a_value_error(limit, tmp_path, monkeypatch):
    """Up to twice PIL's limit PIL only warns (prepare_image refuses); beyond, PIL raises
    DecompressionBombError, which is not a ValueError."""
    Image.fromarray(np.zeros((100, 100), np.uint8)).save(tmp_path / "big.png")
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", limit)
    with pytest.raises(images_module.ImageTooLargeError) as e:
        prepare_image(tmp_path / "big.png")
    _one_line(e, "big.png", "too large" if limit == 1000 else "10000 pixels")


def test_an_array_of_text_is_refused():
    with pytest.raises(ValueError) as e:
        prepare_image(np.full((30, 30), "a"))
    _one_line(e, "image array", "numbers")


# -- bounded sizes of prediction, evaluation, figures and rendering ---------------------


@pytest.mark.parametrize("n_points", [100_000_000, 1, 2.5, True])
def test_trajectory_points_are_bounded(n_points):
    """``predict --points 100000000`` allocated 24 GB before the kernel killed it."""
    from img2dmp.predict import MAX_POINTS, Predictor

    predictor = object.__new__(Predictor)
    predictor.dmp_config = DMPConfig()
    with pytest.raises(ValueError) as e:
        predictor.trajectories(_dmp(1.0), n_points=n_points)
    _one_line(e, "n_points (--points)", repr(n_points), f"[2, {MAX_POINTS}]")
    t, y = predictor.trajectories(_dmp(1.0), n_points=MAX_POINTS)
    assert y.shape == (MAX_POINTS, 2) and t[-1] == pytest.approx(1.0)


@pytest.mark.parametrize(
    "kwargs, needles",
    [
        ({"n_figures": 10**6}, ("n_figures (--figures)", "1000000", "[0, 1000]")),
        ({"n_figures": -1}, ("n_figures", "-1")),
        ({"batch_size": 0}, ("batch_size", "0")),
        ({"refine": 10**9}, ("refine (--refine)", "1000000000", "[0, 10000]")),
    ],
)
def test_evaluate_checks_its_sizes_before_loading_anything(kwargs, needles, tmp_path):
    from img2dmp.evaluate import evaluate

    with pytest.raises(ValueError) as e:  # the model and data do not exist: checked first
        evaluate(tmp_path / "no_model", tmp_path / "no_data.safetensors", **kwargs)
    _one_line(e, *needles)


def test_grids_are_bounded_before_matplotlib_draws():
    """``preview --per-digit 100000`` tried to allocate 2.6 GB."""
    import matplotlib.pyplot as plt

    from img2dmp.data import plotting
    from img2dmp.evaluate import MAX_FIGURES

    assert MAX_FIGURES == plotting.MAX_GRID_CELLS
    with pytest.raises(ValueError) as e:
        plotting.check_grid_size(100_000 * 10, "--per-digit x digits")
    _one_line(e, "--per-digit x digits", "1000000", "1000")
    with pytest.raises(ValueError) as e:
        plotting.plot_grid(np.zeros((1001, 8, 8)))
    _one_line(e, "1001")
    with pytest.raises(ValueError) as e:
        plotting.save_grid("unused.png", np.zeros((2, 8, 8)), cell_inches=1e4)
    _one_line(e, "px", "megapixels")
    with pytest.raises(ValueError) as e:
        plotting.hypotheses_figure(
            "unused.png", np.zeros((8, 8)), np.zeros((1, 5, 2)), [1.0], dpi=1e6
        )
    _one_line(e, "dpi 1e+06")
    assert not plt.get_fignums()


def test_rendering_bounds_image_size_and_footprints():
    from img2dmp.data.render import MAX_IMAGE_SIDE, gaussian_filter, render_paths

    pts = np.array([[[5.0, 5.0], [20.0, 20.0]]])
    with pytest.raises(ValueError) as e:
        render_paths(pts, 100_000)
    _one_line(e, "image size", str(MAX_IMAGE_SIDE), "100000")
    with pytest.raises(ValueError) as e:
        render_paths(np.array([[[5.0, 5.0], [1e12, 5.0]]]), 40)
    _one_line(e, "points", "footprints")
    with pytest.raises(ValueError) as e:
        gaussian_filter(np.zeros((1, 40, 40)), 1e9)
    _one_line(e, "sigma_px", "1000000000.0", "[0, 160]")
    assert render_paths(pts, 40).shape == (1, 40, 40)
