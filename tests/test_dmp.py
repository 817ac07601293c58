"""The DMP core against independent references: solve_ivp, finite differences, geometry."""

from __future__ import annotations

import collections
import importlib

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_flatten

from img2dmp.dmp import (
    DMPConfig,
    DMPIntegrator,
    DMPParams,
    fit_dmp,
    forcing_term,
    integrate,
    kernel_centres,
    kernel_widths,
    rollout,
    rollout_sensitivity,
    sensitivity_rollout,
)
from img2dmp.dmp import _table as table_module  # the response table (no torch)
from img2dmp.dmp import basis as basis_module

rollout_module = importlib.import_module("img2dmp.dmp.rollout")  # the module, not rollout()


def _random_params(rng, batch, config, span=40.0, tau_range=(0.5, 5.0), w_scale=None):
    n, d = config.n_kernels, config.n_dims
    y0 = rng.uniform(0, span, (batch, d))
    g = rng.uniform(0, span, (batch, d))
    if w_scale is None:
        w_scale = 1.0 if config.scaling == "goal-start" else 30.0
    w = rng.normal(0, w_scale, (batch, n, d)) * config.alpha_z * config.beta / 50
    tau = rng.uniform(*tau_range, batch)
    return DMPParams(w=w, tau=tau, g=g, y0=y0)


def _solve_ivp_reference(p: DMPParams, t: np.ndarray, config: DMPConfig) -> np.ndarray:
    """The continuous ODE of eqs. (3)-(5), state (y, z, x), by scipy at rtol 1e-9."""
    c, h = kernel_centres(config), kernel_widths(config)
    tau = float(p.tau)
    scale = (p.g - p.y0) if config.scaling == "goal-start" else 1.0
    d = p.g.shape[-1]

    def rhs(_, u):
        y, z, x = u[:d], u[d : 2 * d], u[2 * d]
        f = forcing_term(np.array(x), p.w, c, h)
        dz = config.alpha_z * (config.beta * (p.g - y) - z) + scale * f
        return np.concatenate([z / tau, dz / tau, [-config.alpha_x * x / tau]])

    u0 = np.concatenate([p.y0, np.zeros(d), [1.0]])
    sol = solve_ivp(rhs, (0, t[-1]), u0, t_eval=t, rtol=1e-9, atol=1e-10, method="DOP853")
    assert sol.success
    return sol.y[:d].T


BACKENDS = ["fused", "torch"]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("scaling", ["goal-start", "none"])
def test_fast_rollout_matches_solve_ivp(scaling, backend):
    cfg = DMPConfig(scaling=scaling)
    rng = np.random.default_rng(1)
    p = _random_params(rng, 6, cfg)
    worst = 0.0
    for b in range(6):
        pb = p[b]
        # uneven stamps, past the nominal duration, as a demonstration's would be
        t = np.sort(rng.uniform(0, 1.3 * pb.tau, 120))
        t[0] = 0.0
        ref = _solve_ivp_reference(pb, t, cfg)
        fast = rollout(pb.to_torch(), torch.tensor(t), cfg, backend=backend).numpy()
        assert np.ptp(ref) > 5  # a real movement, not a constant
        worst = max(worst, np.abs(fast - ref).max())
    assert worst < 0.01, f"fast rollout deviates from solve_ivp by {worst:.2e} px"


@pytest.mark.parametrize("backend", BACKENDS)
def test_fast_rollout_batched_equals_single_and_per_sample_times(backend):
    cfg = DMPConfig()
    rng = np.random.default_rng(2)
    p = _random_params(rng, 4, cfg).to_torch()
    t = torch.sort(torch.rand(4, 50, dtype=torch.float64) * 3, dim=-1).values
    batched = rollout(p, t, cfg, backend=backend)
    for b in range(4):
        single = rollout(p[b], t[b], cfg, backend=backend)
        torch.testing.assert_close(batched[b], single, rtol=0, atol=1e-12)
    # arbitrary leading batch dimensions
    p2 = DMPParams(
        p.w.reshape(2, 2, 25, 2), p.tau.reshape(2, 2), p.g.reshape(2, 2, 2), p.y0.reshape(2, 2, 2)
    )
    y2 = rollout(p2, t.reshape(2, 2, 50), cfg, backend=backend)
    torch.testing.assert_close(y2.reshape(4, 50, 2), batched)


def test_rollout_starts_at_y0_and_converges_to_goal():
    cfg = DMPConfig()
    p = _random_params(np.random.default_rng(3), 5, cfg).to_torch()
    t = torch.linspace(0, 1, 11, dtype=torch.float64)
    y = rollout(p, t[None].expand(5, -1) * p.tau[:, None] * 6, cfg)
    torch.testing.assert_close(y[:, 0], p.y0, rtol=0, atol=1e-12)
    torch.testing.assert_close(y[:, -1], p.g, rtol=0, atol=1e-3)


def test_reference_integrator_matches_ode_at_any_controller_rate():
    cfg = DMPConfig()
    p = _random_params(np.random.default_rng(4), 1, cfg)[0]
    t = np.linspace(0, float(p.tau) * 1.2, 200)
    ref = _solve_ivp_reference(p, t, cfg)
    assert np.abs(integrate(p, t, cfg) - ref).max() < 1e-6
    for rate_hz in (240.0, 1000.0):
        dmp = DMPIntegrator(p, cfg)
        n = int(round(t[-1] * rate_hz))
        ys = np.array([dmp.step(1.0 / rate_hz) for _ in range(n)])
        tt = np.arange(1, n + 1) / rate_hz
        ref_r = _solve_ivp_reference(p, np.concatenate([[0], tt]), cfg)[1:]
        assert np.abs(ys - ref_r).max() < 1e-6


def _small_batch(seed=5, b=3, t_count=25):
    cfg = DMPConfig(n_kernels=6)
    rng = np.random.default_rng(seed)
    p = _random_params(rng, b, cfg, tau_range=(0.6, 2.0), w_scale=2.0)
    t = torch.tensor(np.sort(rng.uniform(0.01, 2.0, (b, t_count)), axis=-1))
    return cfg, p.to_torch(), t


@pytest.mark.parametrize("backend", BACKENDS)
def test_gradcheck_fast_rollout(backend):
    cfg, p, t = _small_batch()
    leaves = [a.clone().requires_grad_(True) for a in (p.w, p.tau, p.g, p.y0)]

    def fn(w, tau, g, y0):
        return rollout(DMPParams(w, tau, g, y0), t, cfg, backend=backend)

    assert torch.autograd.gradcheck(fn, leaves, eps=1e-6, atol=1e-6, rtol=1e-5)


def _grads(fn, p, t, cfg, weights):
    leaves = [a.clone().requires_grad_(True) for a in (p.w, p.tau, p.g, p.y0)]
    y = fn(DMPParams(*leaves), t, cfg)
    (y * weights).sum().backward()
    return [leaf.grad for leaf in leaves]


def test_sensitivity_equations_agree_with_autograd_and_finite_differences():
    cfg, p, t = _small_batch(b=2, t_count=15)
    weights = torch.randn(2, 15, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    fast = _grads(rollout, p, t, cfg, weights)
    sens = _grads(lambda q, tt, c: rollout_sensitivity(q, tt, c, max_step=5e-4), p, t, cfg, weights)
    for name, a, b in zip(("w", "tau", "g", "y0"), fast, sens, strict=True):
        rel = (a - b).norm() / a.norm()
        assert rel < 1e-5, f"d/d{name}: sensitivity vs autograd relative error {rel:.2e}"

    # central finite differences of the exact ODE solution (solve_ivp), for tau and w[3, 1]
    def loss(q: DMPParams) -> float:
        tot = 0.0
        for b in range(2):
            y = _solve_ivp_reference(q.to_numpy()[b], np.concatenate([[0], t[b].numpy()]), cfg)
            tot += float((y[1:] * weights[b].numpy()).sum())
        return tot

    eps = 1e-5
    for name, idx in (("tau", (0,)), ("w", (1, 3, 1)), ("g", (0, 1)), ("y0", (1, 0))):
        plus, minus = (DMPParams(*(a.clone() for a in (p.w, p.tau, p.g, p.y0))) for _ in range(2))
        getattr(plus, name)[idx] += eps
        getattr(minus, name)[idx] -= eps
        fd = (loss(plus) - loss(minus)) / (2 * eps)
        got = float(sens[("w", "tau", "g", "y0").index(name)][idx])
        assert abs(got - fd) <= 1e-5 * max(1.0, abs(fd)), f"d/d{name}{idx}: {got} vs FD {fd}"


def test_sensitivity_forward_matches_fast_rollout():
    cfg, p, t = _small_batch()
    y_s, jac = sensitivity_rollout(p, t, cfg, max_step=2e-3)
    assert set(jac) == {"w", "g", "y0", "tau"}
    assert jac["w"].shape == (3, t.shape[1], 6, 2)
    torch.testing.assert_close(y_s, rollout(p, t, cfg), rtol=0, atol=1e-5)


def _arc(t, cx, cy, r, a0, a1):
    s = 10 * t**3 - 15 * t**4 + 6 * t**5  # minimum-jerk progress
    a = a0 + (a1 - a0) * s
    return np.stack([cx + r * np.cos(a), cy + r * np.sin(a)], -1)


@pytest.mark.parametrize(
    "shape",
    ["line", "arc", "figure8"],
)
def test_fit_then_rollout_reproduces_smooth_paths(shape):
    t = np.linspace(0, 3, 301)
    u = t / 3
    if shape == "line":
        s = 10 * u**3 - 15 * u**4 + 6 * u**5
        y = np.stack([5 + 30 * s, 35 - 28 * s], -1)
    elif shape == "arc":
        y = _arc(u, 20, 20, 15, -0.3, 3.6)
    else:  # figure eight, 40 px tall, ending 3 px from its start
        a = 2 * np.pi * (10 * u**3 - 15 * u**4 + 6 * u**5) * 0.97
        y = np.stack([20 + 10 * np.sin(2 * a), 20 - 18 * np.sin(a + np.pi / 2) + 2], -1)
        y[:, 1] += 0.0
    cfg = DMPConfig(scaling="none") if shape == "figure8" else DMPConfig()
    res = fit_dmp(t, y, cfg)
    assert res.params.w.shape == (25, 2)
    assert float(res.params.tau) == pytest.approx(3.0)
    y_fit = rollout(res.params.to_torch(), torch.tensor(t), cfg).numpy()
    err = np.linalg.norm(y_fit - y, axis=-1).mean()
    assert err < 0.05, f"{shape}: mean fit error {err:.3f} px"
    assert float(res.error_px) == pytest.approx(err, rel=1e-6)
    # After the demonstration ends, the DMP settles on its goal.
    late = integrate(res.params, np.array([3.0, 15.0]), cfg)
    np.testing.assert_allclose(late[-1], y[-1], atol=1e-3)


def test_fit_uneven_time_stamps_and_batches():
    rng = np.random.default_rng(7)
    t = np.sort(rng.uniform(0.2, 2.2, (4, 80)), axis=-1)
    u = (t - t[:, :1]) / (t[:, -1:] - t[:, :1])
    y = np.stack([_arc(ui, 20, 20, 12, 0.1 * i, 3 + 0.2 * i) for i, ui in enumerate(u)])
    res = fit_dmp(t, y)
    assert res.params.batch_shape == (4,)
    np.testing.assert_allclose(res.params.tau, t[:, -1] - t[:, 0])
    y_fit = rollout(res.params.to_torch(), torch.tensor(t - t[:, :1]), DMPConfig()).numpy()
    assert np.linalg.norm(y_fit - y, axis=-1).mean() < 0.05


@pytest.mark.parametrize("d", [1, 3])
def test_fit_without_a_config_takes_the_papers_constants_for_the_paths_dimensions(d):
    t = np.linspace(0.0, 1.5, 120)
    ease = (1 - np.cos(np.pi * t / t[-1])) / 2  # from rest to rest, as a DMP moves
    y = np.stack([5 * k + 10 * (k + 1) * ease * np.cos(k * ease) for k in range(d)], -1)
    res = fit_dmp(t, y)
    assert res.params.config == DMPConfig(n_dims=d) and res.params.n_dims == d
    explicit = fit_dmp(t, y, DMPConfig(n_dims=d))
    np.testing.assert_array_equal(res.params.to_vector(), explicit.params.to_vector())
    y_fit = rollout(res.params.to_torch(), torch.tensor(t)).numpy()  # its carried config
    assert np.abs(y_fit - y).mean() < 0.05
    # a path given as [d, T] is not read as T-dimensional: the message says the layout
    with pytest.raises(ValueError, match=r"y has d=120 dimensions, the config expects 2 \(y is"):
        fit_dmp(t[:2], np.stack([t, t]))


def test_flat_vector_order_and_round_trip():
    cfg = DMPConfig()
    assert cfg.n_params == 55
    p = _random_params(np.random.default_rng(8), 3, cfg)
    v = p.to_vector()
    assert v.shape == (3, 55)
    np.testing.assert_array_equal(v[:, :25], p.w[:, :, 0])
    np.testing.assert_array_equal(v[:, 25:50], p.w[:, :, 1])
    np.testing.assert_array_equal(v[:, 50], p.tau)
    np.testing.assert_array_equal(v[:, 51:53], p.g)
    np.testing.assert_array_equal(v[:, 53:55], p.y0)
    back = DMPParams.from_vector(torch.tensor(v), 25, 2)
    np.testing.assert_array_equal(back.w.numpy(), p.w)
    np.testing.assert_array_equal(DMPParams.from_dict(p.to_dict()).to_vector(), v)


def test_a_batch_of_dmps_has_a_length_and_iterates_over_its_first_dimension():
    p = _random_params(np.random.default_rng(3), 3, DMPConfig())  # batch [3]
    assert len(p) == 3 and bool(p)
    parts = list(p)
    assert [q.batch_shape for q in parts] == [()] * 3
    for i, q in enumerate(parts):
        np.testing.assert_array_equal(q.to_vector(), p[i].to_vector())
    assert len(p.to_torch()) == 3 and len(p[None]) == 1
    one = p[0]
    assert bool(one)  # a condition on parameters never asks their length
    with pytest.raises(TypeError, match=r"len\(\) of one DMP \(batch shape \(\)\)"):
        len(one)
    with pytest.raises(TypeError, match="not a batch"):
        list(one)  # was [] (its first index failed): silently nothing


def test_bad_input_raises_clear_errors():
    cfg = DMPConfig()
    p = _random_params(np.random.default_rng(9), 1, cfg)[0]
    t = np.linspace(0, 1, 10)
    with pytest.raises(ValueError, match="tau must be > 0"):
        DMPParams(p.w, np.array(-1.0), p.g, p.y0)
    with pytest.raises(ValueError, match="w contains NaN"):
        DMPParams(np.full_like(p.w, np.nan), p.tau, p.g, p.y0)
    with pytest.raises(ValueError, match="g has shape"):
        DMPParams(p.w, p.tau, np.zeros(3), p.y0)
    with pytest.raises(ValueError, match="n_kernels must be an integer from 2 to 200, got 1"):
        DMPConfig(n_kernels=1)
    with pytest.raises(ValueError, match="from 2 to 200, got 100000 .the rollout's response"):
        DMPConfig(n_kernels=100_000)  # refused before any table is built
    with pytest.raises(ValueError, match="strictly increasing"):
        rollout(p.to_torch(), torch.tensor([0.0, 0.5, 0.4]), cfg)
    with pytest.raises(ValueError, match="NaN or inf"):
        rollout(p.to_torch(), torch.tensor([0.0, np.inf]), cfg)
    with pytest.raises(ValueError, match="empty"):
        rollout(p.to_torch(), torch.zeros(0), cfg)
    with pytest.raises(ValueError, match="at least 2 points"):
        fit_dmp(np.zeros(0), np.zeros((0, 2)))
    with pytest.raises(ValueError, match="strictly increasing"):
        fit_dmp(np.array([0.0, 1.0, 1.0]), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="NaN or inf"):
        fit_dmp(t, np.full((10, 2), np.nan))
    with pytest.raises(ValueError, match="time stamps but y has"):
        fit_dmp(t[:5], np.zeros((10, 2)))
    with pytest.raises(ValueError, match="d=3 dimensions"):
        fit_dmp(t, np.zeros((10, 3)), cfg)  # without a config: DMPConfig(n_dims=3)
    with pytest.raises(ValueError, match="expected N\\*d"):
        DMPParams.from_vector(np.zeros(54), 25, 2)
    with pytest.raises(ValueError, match="dt must be"):
        DMPIntegrator(p, cfg).step(0.0)
    with pytest.raises(ValueError, match="config expects N=10"):
        rollout(p.to_torch(), torch.tensor(t), DMPConfig(n_kernels=10))


def test_unchanged_tensors_are_checked_once_and_changes_are_caught(monkeypatch):
    from img2dmp.dmp import params as params_module

    cfg = DMPConfig()
    p = _random_params(np.random.default_rng(4), 3, cfg).to_torch()
    t = torch.linspace(0.0, 1.0, 20)
    scans = []
    real = params_module.all_finite
    monkeypatch.setattr(params_module, "all_finite", lambda a: scans.append(1) or real(a))
    rollout(p, t, cfg)
    rollout(p, t, cfg)
    assert scans == []  # checked when made; unchanged since
    with torch.no_grad():
        p.tau[1] = -2.0  # an in-place change
    with pytest.raises(ValueError, match="tau must be > 0"):
        rollout(p, t, cfg)
    p.tau = torch.ones(3)
    p.g = torch.full((3, 2), float("nan"))  # a new tensor
    with pytest.raises(ValueError, match="g contains NaN"):
        rollout(p, t, cfg)
    assert len(scans) >= 2


@pytest.mark.parametrize("backend", BACKENDS)
def test_unvalidated_rollout_propagates_nan_instead_of_crashing(backend):
    # A diverged network can hand the hot loop (validate=False) a NaN duration: the
    # positions must come out NaN, for the training loop to report, not an IndexError.
    cfg = DMPConfig()
    p = _random_params(np.random.default_rng(10), 2, cfg).to_torch()
    tau = p.tau.clone()
    tau[1] = float("nan")
    bad = DMPParams.__new__(DMPParams)  # bypasses validation, as a raw network output would
    bad.w, bad.tau, bad.g, bad.y0 = p.w, tau, p.g, p.y0
    t = torch.linspace(0, 1, 7, dtype=torch.float64)
    y = rollout(bad, t, cfg, validate=False, backend=backend)
    assert torch.isfinite(y[0]).all()
    assert torch.isnan(y[1]).all()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize(("scaling", "n_kernels", "d"), [("goal-start", 25, 2), ("none", 10, 3)])
@pytest.mark.parametrize("batch", [3, 40])  # 40: the kernels that spread samples over threads
def test_fused_and_torch_rollouts_agree(dtype, scaling, n_kernels, d, batch):
    """Values and gradients of the two implementations, serial and parallel kernels."""
    cfg = DMPConfig(n_kernels=n_kernels, n_dims=d, scaling=scaling)
    rng = np.random.default_rng(11)
    p = _random_params(rng, batch, cfg).to_torch(dtype)
    t = torch.tensor(np.sort(rng.uniform(0, 6.0, (batch, 60)), axis=-1), dtype=dtype)
    weights = torch.tensor(rng.normal(size=(batch, 60, d)), dtype=dtype)
    tol = dict(rtol=2e-5, atol=2e-4) if dtype == torch.float32 else dict(rtol=1e-9, atol=1e-9)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    # Batch 40 on 2 threads, even when the machine is loaded (the default rule would
    # then run the kernels serially).
    rollout_module.fix_fused_threads(2 if batch >= 32 else None)
    try:
        out = {}
        for backend in BACKENDS:
            leaves = [a.clone().requires_grad_(True) for a in (p.w, p.tau, p.g, p.y0)]
            y = rollout(DMPParams(*leaves), t, cfg, backend=backend)
            (y * weights).sum().backward()
            out[backend] = [y.detach()] + [leaf.grad for leaf in leaves]
    finally:
        rollout_module.fix_fused_threads(None)
        torch.set_num_threads(threads)
    for name, a, b in zip(["y", "w", "tau", "g", "y0"], out["fused"], out["torch"], strict=True):
        assert a.dtype == dtype, name
        torch.testing.assert_close(a, b, **tol, msg=lambda m, name=name: f"{name}: {m}")


def test_fused_rollout_with_some_inputs_frozen_matches_torch():
    # Only w needs a gradient (tau fixed): the fused backward skips the time derivative.
    cfg, p, t = _small_batch(b=5)
    grads = {}
    for backend in BACKENDS:
        w = p.w.clone().requires_grad_(True)
        y = rollout(DMPParams(w, p.tau, p.g, p.y0), t, cfg, backend=backend)
        (y**2).sum().backward()
        grads[backend] = w.grad
    torch.testing.assert_close(grads["fused"], grads["torch"], rtol=1e-10, atol=1e-10)


def test_rollout_backend_choice_is_checked():
    cfg, p, t = _small_batch()
    with pytest.raises(ValueError, match="backend must be one of"):
        rollout(p, t, cfg, backend="cuda")
    with pytest.raises(ValueError, match="backend='fused' needs"):
        rollout(p.to_torch(torch.float16), t.half(), cfg, backend="fused")
    # "auto" takes what applies: float16 goes through the torch operations
    y = rollout(p.to_torch(torch.float16), t.half(), cfg)
    assert y.dtype == torch.float16 and torch.isfinite(y).all()


def test_rollout_without_numba_falls_back_to_torch_operations(monkeypatch):
    from img2dmp.dmp import _kernels

    cfg, p, t = _small_batch()
    expected = rollout(p, t, cfg, backend="torch")
    monkeypatch.setattr(_kernels, "available", lambda: False)
    torch.testing.assert_close(rollout(p, t, cfg), expected, rtol=0, atol=0)
    with pytest.raises(ValueError, match="numba=no"):
        rollout(p, t, cfg, backend="fused")


def test_forked_child_of_a_parallel_process_gets_serial_kernels(monkeypatch):
    # GNU OpenMP cannot run again in a child forked after it ran (numba aborts the child).
    from img2dmp.dmp import _kernels

    if not _kernels._parallel_safe():
        pytest.skip("numba has no OpenMP/TBB threading layer here: kernels are always serial")
    monkeypatch.setattr(_kernels, "_parallel_pid", -1)  # "the parent that ran them"
    serial = _kernels._kernel_pairs(32, 2, False)
    assert _kernels.kernels(32, 2, n_threads=2) is serial
    monkeypatch.setattr(_kernels, "_parallel_pid", None)
    assert _kernels.kernels(32, 2, n_threads=2) is _kernels._kernel_pairs(32, 2, True)
    assert _kernels.kernels(32, 2, n_threads=1) is serial


# --- Subnormal numbers --------------------------------------------------------------
# Arithmetic on subnormal numbers (below finfo.tiny) takes microcode assists on many x86
# CPUs: a float32 response table holding them made the fused rollout 5x slower.

SUBNORMAL_CONFIGS = [
    DMPConfig(),
    DMPConfig(n_kernels=10, alpha_x=1.0),
    DMPConfig(n_kernels=50, alpha_x=4.0, width_factor=1.0),
]


def _subnormals(x) -> int:
    x = x.detach().cpu().numpy() if torch.is_tensor(x) else np.asarray(x)
    return int(((np.abs(x) < np.finfo(x.dtype).tiny) & (x != 0)).sum())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("cfg", SUBNORMAL_CONFIGS, ids=["default", "N10-ax1", "N50-ax4-wf1"])
def test_response_tables_hold_no_subnormal_numbers(cfg, dtype):
    poly = rollout_module._response_table(cfg, dtype, "cpu")[2]  # the torch backend's
    tab = rollout_module._kernel_table(cfg, dtype)[3]  # the fused kernels'
    assert _subnormals(poly) == 0, f"{_subnormals(poly)} subnormal entries in the {dtype} table"
    assert _subnormals(tab) == 0, f"{_subnormals(tab)} subnormal entries in the kernels' table"
    # what is left is normal: flushed entries are 0, the others at least negligible(dtype)
    kept = np.abs(tab[tab != 0])
    assert kept.min() >= basis_module.negligible(dtype) and kept.max() <= 1.0


def test_negligible_threshold_keeps_products_normal_and_is_below_rounding():
    for dtype in (torch.float32, torch.float64, torch.bfloat16, np.float32, np.float64):
        fi = torch.finfo(dtype) if isinstance(dtype, torch.dtype) else np.finfo(dtype)
        thr = basis_module.negligible(dtype)
        assert thr * thr >= fi.tiny * 0.99  # a product of two kept numbers is normal
        assert thr <= fi.eps**2  # far below rounding of numbers near 1
    assert basis_module.negligible(torch.float16) == torch.finfo(torch.float16).tiny
    assert basis_module.negligible(torch.float32) == pytest.approx(1.0842e-19, rel=1e-4)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_kernels_never_return_subnormal_numbers(dtype):
    cfg = DMPConfig()
    x = torch.exp(-cfg.alpha_x * torch.linspace(0, 12, 2000, dtype=dtype))
    c, h = kernel_centres(cfg), kernel_widths(cfg)
    phi, dphi = basis_module.basis_functions_and_derivative(x, c, h)
    assert _subnormals(phi) == _subnormals(dphi) == 0
    assert _subnormals(basis_module.basis_functions(x, c, h)) == 0
    assert _subnormals(basis_module.basis_functions(x.numpy(), c, h)) == 0
    # far from its centre a kernel is exactly 0 (its true value is below rounding), but
    # every kernel is active somewhere and some kernel everywhere
    assert (phi == 0).any() and (phi > 0).any(0).all() and (phi > 0).any(1).all()


class _SubnormalWatch(TorchDispatchMode):
    """Counts subnormal values in the output of every torch operation run inside it.

    Views and uninitialised buffers (``empty``) are skipped: they compute nothing.
    """

    def __init__(self):
        super().__init__()
        self.found = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        returns = func._schema.returns
        is_view = bool(returns) and returns[0].alias_info is not None
        is_view = is_view and not returns[0].alias_info.is_write
        if "empty" in str(func) or is_view:
            return out
        for x in tree_flatten(out)[0]:
            if torch.is_tensor(x) and x.is_floating_point() and _subnormals(x):
                self.found[str(func)] += _subnormals(x)
        return out


def _typical_batch(dtype, b=12, span=1.3, t_count=120, seed=12):
    """A batch like a training step's: 40 px movements, times up to ``span`` * tau."""
    cfg = DMPConfig()
    rng = np.random.default_rng(seed)
    p = _random_params(rng, b, cfg, tau_range=(0.5, 3.5), w_scale=3.0)
    t = np.linspace(0, span, t_count)[None] * p.tau[:, None]
    return cfg, p.to_torch(dtype), torch.tensor(t, dtype=dtype)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_rollouts_compute_no_subnormal_intermediates(dtype):
    """Every intermediate of the torch backend and of the sensitivity equations (float32
    too, for 6 movement durations, where the sensitivities decay by e^-140), and the
    fused rollout's outputs and gradients."""
    for backend, fn, span in (
        ("torch", lambda q, t, c: rollout(q, t, c, backend="torch"), 1.3),
        ("fused", lambda q, t, c: rollout(q, t, c, backend="fused"), 1.3),
        ("sensitivity", lambda q, t, c: rollout_sensitivity(q, t, c, max_step=0.02), 6.0),
    ):
        cfg, p, t = _typical_batch(dtype, span=span)
        rollout(p, t, cfg, backend="torch")  # tables built outside the watch
        watch = _SubnormalWatch()
        with watch:
            leaves = [a.clone().requires_grad_(True) for a in (p.w, p.tau, p.g, p.y0)]
            y = fn(DMPParams(*leaves), t, cfg)
            (y**2).sum().backward()
        assert not watch.found, f"{backend}: subnormal results of {dict(watch.found)}"
        assert sum(_subnormals(a) for a in [y] + [leaf.grad for leaf in leaves]) == 0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_fused_kernel_products_stay_normal(dtype):
    """The products the fused kernels form (coefficient x table entry, and the Horner
    steps u x entry) on a typical batch: none is subnormal. The compiled loops cannot
    be watched from Python, so their arithmetic is redone here in NumPy."""
    cfg, p, t = _typical_batch(dtype)
    inv_h, s_max, _, tab = rollout_module._kernel_table(cfg, dtype)
    s = np.clip((t / p.tau[:, None]).numpy(), 0, s_max) * inv_h
    pieces = np.minimum(np.floor(s), tab.shape[0] - 1).astype(int)
    u = (s - pieces)[..., None, None]  # [B, T, 1, 1]
    entries = tab[pieces]  # [B, T, 4, C]
    w = p.w.numpy()
    scale = (p.g - p.y0).numpy()[:, None, :]
    coef = np.concatenate([(p.y0 - p.g).numpy()[:, None, :], scale * w], axis=1)  # [B, N+1, d]
    n_c = coef.shape[1]
    products = [
        entries[..., 3, :] * u[..., 0],
        (entries[..., 2, :] + entries[..., 3, :] * u[..., 0]) * u[..., 0],
    ]
    v = entries[..., 0, :] + u[..., 0] * (
        entries[..., 1, :] + u[..., 0] * (entries[..., 2, :] + u[..., 0] * entries[..., 3, :])
    )  # [B, T, C]
    products.append(v[..., :n_c, None] * coef[:, None])  # [B, T, C, d]
    for i, x in enumerate(products):
        assert _subnormals(x.astype(tab.dtype)) == 0, f"product {i}"


@pytest.mark.parametrize("backend", BACKENDS)
def test_flushing_the_tables_changes_no_result_beyond_rounding(backend, monkeypatch):
    """Rollout and gradients with the flushed tables and kernels against those without
    (as before the flush): equal to rounding, in both dtypes."""
    results = {}
    monkeypatch.setenv("IMG2DMP_NO_TABLE_CACHE", "1")  # never keep the unflushed tables
    for flush in (True, False):
        monkeypatch.setattr(table_module, "_FLUSH", flush)  # where _cubic_pieces reads it
        if not flush:
            monkeypatch.setattr(basis_module, "_kernel_exp", np.exp)
        for cache in (table_module._response_table_f64, rollout_module._response_table):
            cache.cache_clear()
        rollout_module._kernel_table.cache_clear()
        for dtype in (torch.float32, torch.float64):
            cfg, p, t = _typical_batch(dtype, span=3.0)
            leaves = [a.clone().requires_grad_(True) for a in (p.w, p.tau, p.g, p.y0)]
            y = rollout(DMPParams(*leaves), t, cfg, backend=backend)
            (y**2).sum().backward()
            results[flush, dtype] = [y.detach()] + [leaf.grad for leaf in leaves]
    monkeypatch.undo()
    for cache in (table_module._response_table_f64, rollout_module._response_table):
        cache.cache_clear()
    rollout_module._kernel_table.cache_clear()
    for dtype in (torch.float32, torch.float64):
        eps = torch.finfo(dtype).eps
        pairs = zip(results[True, dtype], results[False, dtype], strict=True)
        for name, (a, b) in zip("y w tau g y0".split(), pairs, strict=True):
            scale = b.abs().max()
            assert (a - b).abs().max() <= 8 * eps * scale, f"{dtype} {name}"


def test_fused_threads_follow_the_rule(monkeypatch):
    monkeypatch.setattr(torch, "get_num_threads", lambda: 4)
    monkeypatch.setattr(rollout_module, "idle_cores", lambda: 3)
    assert rollout_module.fused_threads(1) == 1
    assert rollout_module.fused_threads(31) == 1  # fewer than 16 samples per thread
    assert rollout_module.fused_threads(48) == 3
    assert rollout_module.fused_threads(1000) == 4  # torch's thread count caps it
    monkeypatch.setattr(rollout_module, "idle_cores", lambda: 0)
    assert rollout_module.fused_threads(1000) == 1  # a loaded machine: serial
    rollout_module.fix_fused_threads(2)
    try:
        assert rollout_module.fused_threads(1) == 2
    finally:
        rollout_module.fix_fused_threads(None)
    with pytest.raises(ValueError, match="threads must be"):
        rollout_module.fix_fused_threads(0)


def test_idle_cores_sees_a_busy_neighbour(monkeypatch):
    real_own_running = rollout_module._own_running
    monkeypatch.setattr(rollout_module.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    monkeypatch.setattr(rollout_module, "_load", {"at": -np.inf, "cpu": 0.0, "idle": 0})
    cases = [  # (running now incl. the caller, 1-min load average) -> idle cores
        ((1, 1.0), 1),  # only this process
        ((2, 1.0), 0),  # a neighbour that just started
        ((1, 2.0), 0),  # one that has run for a minute (and sleeps this instant)
    ]
    monkeypatch.setattr(rollout_module, "_own_running", lambda: 1)
    for (running, load), idle in cases:
        monkeypatch.setattr(rollout_module, "_running_now", lambda r=running: r)
        monkeypatch.setattr(rollout_module, "_load_average", lambda a=load: a)
        rollout_module._load["at"] = -np.inf  # look again now
        assert rollout_module.idle_cores() == idle, (running, load)
    # this process's own spinning threads are not a neighbour
    monkeypatch.setattr(rollout_module, "_running_now", lambda: 3)
    monkeypatch.setattr(rollout_module, "_own_running", lambda: 3)
    monkeypatch.setattr(rollout_module, "_load_average", lambda: 1.0)
    rollout_module._load["at"] = -np.inf
    assert rollout_module.idle_cores() == 1
    assert real_own_running() >= 1  # at least the caller
    # looked up at most every 0.5 s: a change within that time is not seen yet
    monkeypatch.setattr(rollout_module, "_running_now", lambda: 9)
    assert rollout_module.idle_cores() == 1


def test_response_table_is_kept_on_disk_and_a_bad_file_is_ignored(tmp_path, monkeypatch):
    cfg = DMPConfig(n_kernels=7)
    path = tmp_path / "table.npy"
    monkeypatch.setattr(table_module, "_table_cache_file", lambda config: str(path))
    solved = []
    real_solve = table_module._solve_responses
    monkeypatch.setattr(
        table_module, "_solve_responses", lambda *a: solved.append(1) or real_solve(*a)
    )
    tables = []
    for content in (None, "keep", b"not a table"):
        if isinstance(content, bytes):
            path.write_bytes(content)
        table_module._response_table_f64.cache_clear()
        tables.append(table_module._response_table_f64(cfg))
    table_module._response_table_f64.cache_clear()
    assert len(solved) == 2  # solved, then loaded, then solved again over the bad file
    for h, s_max, table in tables[1:]:
        assert (h, s_max) == tables[0][:2]
        np.testing.assert_array_equal(table, tables[0][2])
    assert table_module._load_table(str(path), tables[0][2].shape) is not None


def test_auto_backend_takes_torch_operations_for_small_calls_until_the_kernels_ran(monkeypatch):
    from img2dmp.dmp import _kernels

    if not _kernels.available():
        pytest.skip("numba missing: 'auto' always takes the torch operations")
    w = torch.zeros(2, 25, 2)
    small, big = torch.zeros(2, 100), torch.zeros(64, 100)
    monkeypatch.setattr(rollout_module, "_fused_loaded", False)
    monkeypatch.setitem(rollout_module._unfused, "seconds", 0.0)
    assert not rollout_module._use_fused("auto", w, small)  # ~0.3 s to load: not worth it
    assert rollout_module._use_fused("auto", w, big)
    assert rollout_module._use_fused("fused", w, small)  # asked for: always
    rollout(DMPParams(w, torch.ones(2), torch.zeros(2, 2), torch.zeros(2, 2)), torch.arange(100.0))
    # the torch operations' time counts, as an idle machine takes a call of 200 stamps:
    # counted, not timed, so that where a process switches does not follow its load
    idle_s = rollout_module._TORCH_CALL_S + 200 * rollout_module._TORCH_STAMP_S
    assert rollout_module._unfused["seconds"] == idle_s
    spent = rollout_module._KERNEL_LOAD_S
    monkeypatch.setitem(rollout_module._unfused, "seconds", spent)
    assert rollout_module._use_fused("auto", w, small)  # many small calls: worth loading
    monkeypatch.setattr(rollout_module, "_fused_loaded", True)
    assert rollout_module._use_fused("auto", w, small)  # loaded anyway


@pytest.mark.parametrize(
    "config",
    [
        DMPConfig(),
        DMPConfig(n_kernels=10, alpha_z=25.0),
        DMPConfig(n_kernels=6, alpha_z=12.0, beta_z=6.0),
    ],
    ids=["default", "n10-az25", "underdamped"],
)
def test_the_response_table_is_the_ode_s_solution(config):
    """The exact-step table (``_table._solve_responses``) against scipy's DOP853 at
    rtol 1e-13 on the system it solves, values and derivatives of every column."""
    from img2dmp.dmp import _table
    from img2dmp.dmp.basis import basis_functions, kernel_centres, kernel_widths

    n, az, bz, ax = config.n_kernels, config.alpha_z, config.beta, config.alpha_x
    c, hw = kernel_centres(config), kernel_widths(config)
    h, s_max, table = _table._response_table_f64(config)
    s = np.arange(len(table)) * h

    def rhs(si, u):
        drive = np.concatenate([[0.0], basis_functions(np.exp(np.array(-ax * si)), c, hw)])
        return np.concatenate([u[n + 1 :], -az * bz * u[: n + 1] - az * u[n + 1 :] + drive])

    u0 = np.zeros(2 * (n + 1))
    u0[0] = 1.0
    sol = solve_ivp(rhs, (0.0, s[-1]), u0, method="DOP853", t_eval=s, rtol=1e-13, atol=1e-17)
    ref = np.stack([sol.y[: n + 1].T, sol.y[n + 1 :].T], axis=1)  # [G, 2, N + 1]
    assert s[-1] == pytest.approx(s_max)
    assert np.abs(table[:, 0] - ref[:, 0]).max() <= 1e-12  # the responses peak near 1
    assert np.abs(table[:, 1] - ref[:, 1]).max() <= 1e-11 * max(1.0, np.abs(ref[:, 1]).max())
