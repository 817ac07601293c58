"""The rollout's direct path for calls without a gradient (issue 33, "small calls cheap").

Once the fused kernels are loaded, :func:`img2dmp.dmp.rollout` calls the forward kernel on
NumPy views of the inputs without an autograd node. It must give the numbers of the
general path (the same kernel through ``torch.autograd.Function``) and of the torch
operations, and refuse exactly what the general path refuses, with the same message.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest
import torch

from img2dmp.dmp import DMPConfig, DMPParams, rollout

rollout_module = importlib.import_module("img2dmp.dmp.rollout")


@pytest.fixture(autouse=True)
def kernels_loaded():
    from img2dmp.dmp import _kernels

    if not _kernels.available():
        pytest.skip("numba missing: there is no direct path")
    cfg, p, t = _one(torch.float64)
    rollout(p, t, cfg, backend="fused")  # loads the kernels: "auto" now takes them
    assert rollout_module._fused_loaded


def _one(dtype, batch=(1,), config=None, n_t=301, seed=0):
    cfg = config or DMPConfig()
    rng = np.random.default_rng(seed)
    n, d = cfg.n_kernels, cfg.n_dims
    tau = rng.uniform(0.5, 4.0, batch)
    p = DMPParams(
        w=rng.normal(0, 20, (*batch, n, d)),
        tau=tau,
        g=rng.uniform(0, 40, (*batch, d)),
        y0=rng.uniform(0, 40, (*batch, d)),
    ).to_torch(dtype)
    t = torch.as_tensor(np.linspace(0, 1.2, n_t) * tau[..., None], dtype=dtype)
    return cfg, p, t


def _general(p, t, cfg, monkeypatch, **kw):
    """The rollout with the direct path switched off."""
    with monkeypatch.context() as m:
        m.setattr(rollout_module, "_direct_rollout", lambda *a: None)
        return rollout(p, t, cfg, **kw)


def _taken(p, t, cfg, **kw) -> bool:
    return rollout_module._direct_rollout(p, t, cfg, kw.get("validate", True), "auto") is not None


CASES = {
    "B=1": dict(batch=(1,)),
    "one DMP, no batch axis": dict(batch=()),
    "B=5": dict(batch=(5,)),
    "batch 2x3": dict(batch=(2, 3)),
    "no scaling, N=10, d=3": dict(batch=(2,), config=DMPConfig(10, 3, scaling="none")),
    "one time stamp": dict(batch=(1,), n_t=1),
}


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["f64", "f32"])
@pytest.mark.parametrize("case", CASES.values(), ids=CASES.keys())
@pytest.mark.parametrize("t_kind", ["batched", "1-D", "numpy"])
def test_direct_path_gives_the_general_path_s_numbers(case, dtype, t_kind, monkeypatch):
    cfg, p, t = _one(dtype, **case)
    if t_kind != "batched":
        t = t.reshape(-1, t.shape[-1])[0]  # one row for every DMP
    if t_kind == "numpy":
        t = t.numpy()
    assert _taken(p, t, cfg)
    y = rollout(p, t, cfg)
    reference = _general(p, t, cfg, monkeypatch)
    assert y.shape == reference.shape and y.dtype == reference.dtype
    torch.testing.assert_close(y, reference, rtol=0, atol=0)  # the same kernel, bit for bit
    ops = rollout(p, torch.as_tensor(t), cfg, backend="torch")
    scale = float(ops.abs().max())
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    assert float((y - ops).abs().max()) <= tol * scale


def test_non_contiguous_inputs_are_copied_not_compiled_for(monkeypatch):
    cfg, p, t = _one(torch.float64, batch=(4,))
    wide = torch.stack([t, t], -1)[..., 0]  # a strided view
    w_t = p.w.transpose(-1, -2).contiguous().transpose(-1, -2)  # same values, other strides
    q = DMPParams(w_t, p.tau, p.g, p.y0)
    assert not wide.is_contiguous() and not w_t.is_contiguous()
    assert _taken(q, wide, cfg)
    torch.testing.assert_close(rollout(q, wide, cfg), _general(p, t, cfg, monkeypatch))


def test_a_gradient_takes_the_autograd_path_and_matches_the_torch_operations():
    cfg, p, t = _one(torch.float64, batch=(1,))
    leaves = [a.clone().requires_grad_(True) for a in (p.w, p.tau, p.g, p.y0)]
    q = DMPParams(*leaves)
    assert not _taken(q, t, cfg)  # something to record: the general path
    (rollout(q, t, cfg) ** 2).sum().backward()
    grads = [a.grad.clone() for a in leaves]
    for a in leaves:
        a.grad = None
    (rollout(q, t, cfg, backend="torch") ** 2).sum().backward()
    for got, want in zip(grads, (a.grad for a in leaves), strict=True):
        torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-10)
    assert not _taken(p, t.clone().requires_grad_(True), cfg)


def test_without_validation_a_nan_tau_gives_nan_positions_on_both_paths(monkeypatch):
    cfg, p, t = _one(torch.float64, batch=(2,))
    tau = p.tau.clone()
    tau[1] = float("nan")
    q = DMPParams.__new__(DMPParams)  # unchecked, as a diverged network's output
    q.w, q.tau, q.g, q.y0 = p.w, tau, p.g, p.y0
    assert _taken(q, t, cfg, validate=False)
    y = rollout(q, t, cfg, validate=False)
    torch.testing.assert_close(y, _general(q, t, cfg, monkeypatch, validate=False), equal_nan=True)
    assert torch.isfinite(y[0]).all() and torch.isnan(y[1]).all()


def _bad_calls():
    """``name -> (params, t, config, kwargs)`` for calls the rollout refuses."""
    cfg, p, t = _one(torch.float64, batch=(2,))
    nan_w = p.w.clone()
    nan_w[1, 3, 0] = float("nan")
    neg_tau = p.tau.clone()
    neg_tau[0] = -1.0
    inf_g = p.g.clone()
    inf_g[0, 1] = float("inf")

    def raw(w=p.w, tau=p.tau, g=p.g, y0=p.y0):  # unchecked parameters
        q = DMPParams.__new__(DMPParams)
        q.w, q.tau, q.g, q.y0 = w, tau, g, y0
        return q

    t_nan, t_down, t_neg = t.clone(), t.clone(), t - 0.1
    t_nan[1, 5] = float("nan")
    t_down[0, 7] = t_down[0, 6]
    return {
        "NaN weight": (raw(w=nan_w), t, cfg, {}),
        "tau <= 0": (raw(tau=neg_tau), t, cfg, {}),
        "inf goal": (raw(g=inf_g), t, cfg, {}),
        "g's shape": (raw(g=p.g[:, :1]), t, cfg, {}),
        "tau's shape": (raw(tau=p.tau[:1]), t, cfg, {}),
        "config's kernels": (p, t, DMPConfig(n_kernels=10), {}),
        "NaN time stamp": (p, t_nan, cfg, {}),
        "repeated time stamp": (p, t_down, cfg, {}),
        "negative time stamp": (p, t_neg, cfg, {}),
        "no time stamps": (p, t[:, :0], cfg, {}),
        "t's batch shape": (p, t[:1], cfg, {}),
        "t's batch shape, unvalidated": (p, t[:1], cfg, {"validate": False}),
        "boolean t": (p, t > 1, cfg, {}),
        "NumPy parameters": (p.to_numpy(), t, cfg, {}),
        "unknown backend": (p, t, cfg, {"backend": "fast"}),
    }


def test_a_zero_dimensional_t_fails_as_on_the_general_path(monkeypatch):
    cfg, p, t = _one(torch.float64, batch=())
    for validate in (True, False):
        errors = []
        for call in (rollout, lambda *a, **k: _general(*a, monkeypatch, **k)):
            try:
                call(p, t[3], cfg, validate=validate)
                errors.append(None)
            except Exception as e:  # whatever the general path does, the same
                errors.append((type(e), str(e)))
        assert errors[0] == errors[1]


@pytest.mark.parametrize("name", list(_bad_calls()))
def test_bad_input_gets_the_general_path_s_message(name, monkeypatch):
    params, t, cfg, kw = _bad_calls()[name]
    with pytest.raises(ValueError) as direct:
        rollout(params, t, cfg, **kw)
    with pytest.raises(ValueError) as general:
        _general(params, t, cfg, monkeypatch, **kw)
    assert str(direct.value) == str(general.value)
    assert "\n" not in str(direct.value)
