"""The paper's gradient: sensitivity equations integrated alongside the DMP.

Section IV of Pahič et al. (eqs. 11-27) obtains the gradient of cost (10) by
differentiating the DMP's differential equations with respect to each parameter and
integrating the resulting *sensitivity* equations together with the DMP. In physical
time, with ``S = g - y0`` (or 1 for ``scaling="none"``), ``F = sum_k w_k phi_k(x)`` and
``f = alpha_z (beta_z (g - y) - z) + S F``::

    DMP             tau y' = z                 tau z' = f                       y(0)=y0, z(0)=0
    d/dw_kj         tau Yw' = Zw               tau Zw' = -a_z(b_z Yw + Zw) + S_j phi_k(x)
    d/dg            tau Yg' = Zg               tau Zg' =  a_z(b_z(1 - Yg) - Zg) + F   [F if scaled]
    d/dy0           tau Yy' = Zy               tau Zy' = -a_z(b_z Yy + Zy) - F        Yy(0)=1
    d/dtau          tau Yt' = Zt - z/tau       tau Zt' = -a_z(b_z Yt + Zt) + S F'(x) X - f/tau
                    X = dx/dtau = x alpha_x t / tau^2      (closed form of the phase's sensitivity)

All other initial values are 0. Each weight affects only its own dimension, so
``dy_j/dw_kj`` is stored as ``[N, d]`` per time stamp. The system is integrated with
classical RK4 with steps of at most ``max_step`` in normalised time ``t / tau`` (each
interval between consecutive time stamps is split evenly); the chain rule then
gives the gradient of any loss of the positions. This module is the paper's method, kept
as an independent check of :mod:`.rollout` (which is much faster) and for users who want
to see it.
"""

from __future__ import annotations

import torch

from .basis import basis_functions_and_derivative, kernel_centres, kernel_widths, negligible
from .config import DMPConfig
from .params import DMPParams, config_of
from .rollout import check_time_stamps


def sensitivity_rollout(
    params: DMPParams,
    t: torch.Tensor,
    config: DMPConfig | None = None,
    *,
    max_step: float = 0.005,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Integrate a batch of DMPs and their parameter sensitivities.

    The DMP (eqs. 3-7) and the sensitivity equations of the paper's eqs. 11-27 (the table
    in the module docstring) form one system of ODEs, integrated with RK4.

    Parameters
    ----------
    params : DMPParams
        Torch tensors with batch shape ``[B]``.
    t : tensor [B, T] or [T]
        Time stamps (s), strictly increasing, >= 0.
    max_step : float
        Longest RK4 step in normalised time ``t / tau``. The default (1/200 of the
        movement) keeps the error near 1e-6 px on a 40 px digit; smaller is more exact.

    Returns
    -------
    y : tensor [B, T, d]
    jac : dict
        ``"w"``: ``dy_j/dw_kj`` ``[B, T, N, d]``; ``"g"``, ``"y0"``: ``dy_j/dg_j``,
        ``dy_j/dy0_j`` ``[B, T, d]``; ``"tau"``: ``dy/dtau`` ``[B, T, d]``.
    """
    config = config_of(params, config)
    if not (isinstance(max_step, (int, float)) and 0 < max_step <= 1):
        raise ValueError(f"max_step must be in (0, 1], got {max_step!r}")
    w, tau, g, y0, t = _checked_inputs(params, t, config)
    deriv = _sensitivity_system(w, tau, g, y0, config)
    return _integrate(deriv, _initial_state(w, g, y0), t, tau, max_step)


def _checked_inputs(params: DMPParams, t, config: DMPConfig):
    """Detached ``w [B, N, d], tau [B], g [B, d], y0 [B, d]`` and time stamps ``[B, T]``."""
    params.validate(config)
    w, tau, g, y0 = (a.detach() for a in (params.w, params.tau, params.g, params.y0))
    if w.ndim != 3:
        raise ValueError(f"sensitivity_rollout takes a batch [B]; w has shape {tuple(w.shape)}")
    t = torch.as_tensor(t, dtype=w.dtype, device=w.device)
    check_time_stamps(t)
    if bool((t < 0).any()):
        raise ValueError("t must be >= 0 (seconds since the start of the movement)")
    b = w.shape[0]
    if t.ndim == 1:
        t = t.expand(b, t.shape[0])
    if t.shape[0] != b:
        raise ValueError(f"t has batch size {t.shape[0]}, the parameters have {b}")
    return w, tau, g, y0, t


def _sensitivity_system(w, tau, g, y0, config: DMPConfig):
    """Right-hand side ``deriv(t [B], state) -> d state / dt`` of the DMP and its
    sensitivities (eqs. 11-27); ``state`` is the list of :func:`_initial_state`."""
    az, bz, ax = config.alpha_z, config.beta, config.alpha_x
    scaled = config.scaling == "goal-start"
    c = kernel_centres(config)
    hw = kernel_widths(config)
    scale = (g - y0) if scaled else torch.ones_like(g)  # S, [B, d]
    tau_ = tau[:, None]  # [B, 1]
    tau_w = tau[:, None, None]  # [B, 1, 1]

    def deriv(tt, st):
        y, z, yw, zw, yg, zg, yy, zy, yt, zt = st
        x = torch.exp(-ax * tt / tau)  # phase, [B]
        phi, dphi = basis_functions_and_derivative(x, c, hw)  # [B, N]
        f_x = torch.einsum("bn,bnd->bd", phi, w)  # F(x), [B, d]
        df_x = torch.einsum("bn,bnd->bd", dphi, w)  # F'(x), [B, d]
        xt = (x * ax * tt / tau**2)[:, None]  # X = dx/dtau, [B, 1]
        f = az * (bz * (g - y) - z) + scale * f_x  # [B, d]
        f_g = f_x if scaled else 0.0  # d(S F)/dg = F = -d(S F)/dy0 for S = g - y0
        return (
            # DMP: tau y' = z, tau z' = f
            z / tau_,
            f / tau_,
            # d/dw_kj: tau Yw' = Zw, tau Zw' = -a_z(b_z Yw + Zw) + S_j phi_k(x)
            zw / tau_w,
            (-az * (bz * yw + zw) + scale[:, None, :] * phi[..., None]) / tau_w,
            # d/dg: tau Yg' = Zg, tau Zg' = a_z(b_z(1 - Yg) - Zg) + F  [F if scaled]
            zg / tau_,
            (az * (bz * (1 - yg) - zg) + f_g) / tau_,
            # d/dy0: tau Yy' = Zy, tau Zy' = -a_z(b_z Yy + Zy) - F  [F if scaled]
            zy / tau_,
            (-az * (bz * yy + zy) - f_g) / tau_,
            # d/dtau: tau Yt' = Zt - z/tau, tau Zt' = -a_z(b_z Yt + Zt) + S F'(x) X - f/tau
            (zt - z / tau_) / tau_,
            (-az * (bz * yt + zt) + scale * df_x * xt - f / tau_) / tau_,
        )

    return deriv


def _initial_state(w, g, y0) -> list[torch.Tensor]:
    """``[y, z, Yw, Zw, Yg, Zg, Yy, Zy, Yt, Zt]`` at t = 0: y = y0, Yy = dy/dy0 = 1, else 0."""
    zeros = torch.zeros_like(g)  # [B, d]
    wzeros = torch.zeros_like(w)  # [B, N, d]
    return [
        y0.clone(),
        zeros,
        wzeros,
        wzeros,
        zeros,
        zeros,
        torch.ones_like(g),
        zeros,
        zeros,
        zeros,
    ]


def _integrate(deriv, state, t, tau, max_step: float):
    """RK4 from t = 0 through the time stamps ``t [B, T]``; positions ``[B, T, d]`` and
    sensitivities (see :func:`sensitivity_rollout`) at every stamp."""
    w_like = state[2]  # [B, N, d]
    b, n, d = w_like.shape
    out_y = torch.empty(b, t.shape[1], d, dtype=w_like.dtype, device=w_like.device)
    out = {
        "w": torch.empty(b, t.shape[1], n, d, dtype=w_like.dtype, device=w_like.device),
        "g": torch.empty_like(out_y),
        "y0": torch.empty_like(out_y),
        "tau": torch.empty_like(out_y),
    }
    # RK4 steps per interval: enough for the sample that needs most, planned up front.
    dt = torch.diff(t, dim=1, prepend=torch.zeros_like(t[:, :1]))  # [B, T]
    n_steps = torch.ceil((dt / tau[:, None]).amax(0) / max_step).long().tolist()
    t_now = torch.zeros(b, dtype=w_like.dtype, device=w_like.device)
    for j in range(t.shape[1]):
        if n_steps[j] > 0:
            h = dt[:, j] / n_steps[j]  # [B]
            for _ in range(n_steps[j]):
                state = _rk4(deriv, t_now, state, h)
                t_now = t_now + h
        t_now = t[:, j].clone()  # no drift of the clock from summing steps
        out_y[:, j] = state[0]
        out["w"][:, j] = state[2]
        out["g"][:, j] = state[4]
        out["y0"][:, j] = state[6]
        out["tau"][:, j] = state[8]
    return out_y, out


def _rk4(deriv, t, state, h):
    """One classical Runge-Kutta step of size ``h [B]`` for a list of ``[B, ...]`` tensors."""
    hb = [h.reshape(-1, *([1] * (s.ndim - 1))) for s in state]  # h broadcast per tensor

    def shifted(k, a):
        return [s + a * hh * ki for s, hh, ki in zip(state, hb, k, strict=True)]

    k1 = deriv(t, state)
    k2 = deriv(t + h / 2, shifted(k1, 0.5))
    k3 = deriv(t + h / 2, shifted(k2, 0.5))
    k4 = deriv(t + h, shifted(k3, 1.0))
    # The states decay exponentially once their kernel has passed (e.g. dy/dy0 ~ e^-24s):
    # flushed to 0 below negligible() (1e-19 in float32), they never become subnormal
    # numbers, whose arithmetic is very slow on many x86 CPUs. One cheap op per tensor.
    flush = negligible(h.dtype)
    return [
        _shrink(s + hh / 6 * (a + 2 * bb + 2 * cc + dd), flush)
        for s, hh, a, bb, cc, dd in zip(state, hb, k1, k2, k3, k4, strict=True)
    ]


def _shrink(x: torch.Tensor, below: float) -> torch.Tensor:
    """``x`` with entries of magnitude at most ``below`` set to 0 (NaN stays NaN)."""
    return torch.nn.functional.hardshrink(x, below)


class _SensitivityRollout(torch.autograd.Function):
    @staticmethod
    def forward(ctx, w, tau, g, y0, t, config, max_step):
        y, jac = sensitivity_rollout(DMPParams(w, tau, g, y0), t, config, max_step=max_step)
        ctx.save_for_backward(jac["w"], jac["g"], jac["y0"], jac["tau"])
        return y

    @staticmethod
    def backward(ctx, gy):  # gy: [B, T, d]
        jw, jg, jy0, jtau = ctx.saved_tensors
        grad_w = torch.einsum("btd,btnd->bnd", gy, jw)
        grad_g = (gy * jg).sum(1)
        grad_y0 = (gy * jy0).sum(1)
        grad_tau = (gy * jtau).sum((1, 2))
        return grad_w, grad_tau, grad_g, grad_y0, None, None, None


def rollout_sensitivity(
    params: DMPParams,
    t: torch.Tensor,
    config: DMPConfig | None = None,
    *,
    max_step: float = 0.005,
) -> torch.Tensor:
    """Like :func:`img2dmp.dmp.rollout`, but differentiated by the sensitivity equations.

    Returns ``y [B, T, d]``; ``backward()`` through it uses the integrated sensitivities
    (the paper's eqs. 11-27) instead of autograd.
    """
    config = config_of(params, config)
    return _SensitivityRollout.apply(params.w, params.tau, params.g, params.y0, t, config, max_step)
