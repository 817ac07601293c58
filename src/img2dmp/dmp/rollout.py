"""Fast, batched, differentiable DMP rollout (the core of cost (10)).

With tau fixed, the transformation system (eqs. 3-4) is linear and time-invariant in the
normalised time ``s = t / tau``::

    y'' = alpha_z * (beta_z * (g - y) - y') + S * F(x(s)),   x(s) = exp(-alpha_x s)

with ``y(0) = y0, y'(0) = 0`` and ``S = g - y0`` (or 1). Its solution is therefore an
affine function of ``y0``, ``g`` and the weights::

    y(s) = g + (y0 - g) * a(s) + S * sum_k w_k R_k(s)

where ``a`` is the free response to a unit initial offset and ``R_k`` the response to the
k-th normalised kernel ``phi_k(x(s))`` (see :func:`basis.basis_functions`). These N + 1
scalar functions depend only on the DMP constants, so they are solved once, to 1e-12
relative accuracy, on a fine grid and interpolated with cubic Hermite polynomials (values
and exact derivatives at the nodes). A batch rollout is then one small matrix product and
a gather, and its backward pass (written by hand, checked by gradcheck) gives the exact
derivatives of that interpolant for w, g, y0 and tau; tau enters only through
``s = t / tau``, so ``dy/dtau = -(t / tau^2) y'(s)``.

Two implementations of that one interpolant (``rollout(..., backend=...)``):

- ``"fused"`` (the default for float32/float64 CPU tensors): one compiled loop (numba,
  :mod:`img2dmp.dmp._kernels`) for the forward and one for the backward pass, over the
  samples in parallel on ``torch.get_num_threads()`` threads; nothing of the batch's size
  is materialised besides the output. Fastest on the CPU.
- ``"torch"``: torch operations (one GEMM of the coefficients with the pieces the batch
  reaches, a gather, a hand-written backward); any device and dtype.

They agree to rounding, and both are checked by gradcheck.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch
from scipy.integrate import solve_ivp

from . import _kernels
from .basis import basis_functions, kernel_centres, kernel_widths
from .config import DMPConfig
from .params import DMPParams, all_finite, as_host_array

# Nodes per shortest time scale of the responses: cubic Hermite error ~1e-7 relative
# (~2e-6 px on a 40 px digit), below float32 resolution, with few pieces to combine.
_NODES_PER_SCALE = 16
# The table ends where the phase and the free response have decayed below this.
_TAIL = 1e-10


@functools.lru_cache(maxsize=16)
def _response_table_f64(config: DMPConfig) -> tuple[float, float, np.ndarray]:
    """Solve the N + 1 unit responses on a uniform grid of s.

    Returns ``(h, s_max, table)`` where ``table`` is ``[G, 2, N + 1]``: values and
    s-derivatives of ``[a, R_1, ..., R_N]`` at ``s = 0, h, 2h, ...``.
    """
    n, az, bz, ax = config.n_kernels, config.alpha_z, config.beta, config.alpha_x
    c, hw = kernel_centres(config), kernel_widths(config)
    scale = min(1.0 / (n - 1), 1.0 / math.sqrt(az * bz), 2.0 / az)
    h = scale / _NODES_PER_SCALE
    # Slowest decay of the free response: the real part of the slower characteristic root.
    disc = az * az - 4 * az * bz
    slow = az / 2 - (math.sqrt(disc) / 2 if disc > 0 else 0.0)
    s_max = max(-math.log(_TAIL) / ax, (-math.log(_TAIL) + 5.0) / slow, 1.0)
    g = int(math.ceil(s_max / h)) + 1
    s_grid = np.arange(g) * h
    s_max = float(s_grid[-1])

    def rhs(s, u):
        y, yd = u[: n + 1], u[n + 1 :]
        drive = np.zeros(n + 1)
        drive[1:] = basis_functions(np.exp(np.array(-ax * s)), c, hw)
        return np.concatenate([yd, -az * bz * y - az * yd + drive])

    u0 = np.zeros(2 * (n + 1))
    u0[0] = 1.0  # a(0) = 1: unit initial offset; every R_k starts at rest
    sol = solve_ivp(rhs, (0.0, s_max), u0, method="DOP853", t_eval=s_grid, rtol=1e-12, atol=1e-16)
    if not sol.success:  # pragma: no cover - depends on scipy internals
        raise RuntimeError(f"could not tabulate DMP responses: {sol.message}")
    table = np.stack([sol.y[: n + 1].T, sol.y[n + 1 :].T], axis=1)  # [G, 2, N+1]
    return h, s_max, table


@functools.lru_cache(maxsize=32)
def _response_table(config: DMPConfig, dtype: torch.dtype, device: str):
    """Cubic Hermite pieces of the unit responses, as polynomial coefficients.

    Returns ``(h, s_max, poly)`` with ``poly`` of shape ``[C, G - 1, 4]`` (C = N + 1
    columns ``[a, R_1..R_N]``): on ``[s_i, s_i + h]`` column c is
    ``sum_k poly[c, i, k] * u**k`` with ``u = (s - s_i) / h``. The pieces match the
    tabulated values and derivatives at both ends, so the interpolant is C^1.
    """
    h, s_max, table = _response_table_f64(config)
    v, dv = table[:, 0], h * table[:, 1]  # [G, C]
    v0, v1, d0, d1 = v[:-1], v[1:], dv[:-1], dv[1:]
    poly = np.stack([v0, d0, 3 * (v1 - v0) - 2 * d0 - d1, 2 * (v0 - v1) + d0 + d1], -1)
    poly = torch.as_tensor(poly.transpose(1, 0, 2), dtype=dtype, device=device)
    return h, s_max, poly.contiguous()  # [C, G-1, 4]


def _locate(s: torch.Tensor, h: float, s_max: float, n_pieces: int):
    """Piece index ``i`` (no gradient) and local coordinate ``u`` in [0, 1] (differentiable)."""
    q = s.clamp(0.0, s_max) / h
    # A NaN s (e.g. a diverged network's tau with validate=False) must give NaN positions,
    # not an out-of-range index: look it up in piece 0 and let u carry the NaN.
    i = torch.nan_to_num(q.detach(), nan=0.0).floor().clamp(0, n_pieces - 1).long()
    return i, q - i


def _horner(c: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    # c: [..., 4] cubic coefficients, u: [...]. A product with the powers of u backpropagates
    # with two products, where indexing c[..., k] would allocate four zero-filled gradients.
    powers = torch.stack([torch.ones_like(u), u, u * u, u * u * u], dim=-1)
    return (c * powers).sum(-1)


def unit_responses(s: torch.Tensor, config: DMPConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """Free response ``a(s)`` and kernel responses ``R_k(s)`` at normalised times ``s``.

    Parameters
    ----------
    s : tensor [*batch, T]
        Normalised time ``t / tau`` (>= 0). Beyond the end of the table (where every
        response has settled to 1e-10) the last value is used.

    Returns
    -------
    a : tensor [*batch, T]
    R : tensor [*batch, T, N]
        Differentiable in ``s``.
    """
    h, s_max, poly = _response_table(config, s.dtype, str(s.device))
    i, u = _locate(s, h, s_max, poly.shape[1])
    val = _horner(poly[:, i].movedim(0, -2), u[..., None])  # [*batch, T, C]
    return val[..., 0], val[..., 1:]


def check_time_stamps(t, name: str = "t", *, non_negative: bool = False) -> None:
    """Raise ``ValueError`` unless ``t`` is finite, non-empty and strictly increasing.

    With ``non_negative`` also unless ``t >= 0``.
    """
    x = as_host_array(t) if torch.is_tensor(t) else np.asarray(t)
    if x is None:  # another device or a dtype NumPy lacks: check a float64 copy
        x = t.detach().to("cpu", torch.float64).numpy()
    if x.size == 0 or x.shape[-1] == 0:
        raise ValueError(f"{name} is empty: a trajectory needs at least one time stamp")
    if _kernels.available() and x.dtype in (np.float32, np.float64):
        faults = _kernels.time_stamp_faults(np.ascontiguousarray(x.reshape(-1, x.shape[-1])))
        if faults == 0 or (faults == 4 and not non_negative):
            return
    if not all_finite(x):
        raise ValueError(f"{name} contains NaN or inf")
    if x.shape[-1] > 1 and not bool((x[..., 1:] > x[..., :-1]).all()):
        raise ValueError(f"{name} must be strictly increasing along its last axis")
    if non_negative and bool((x[..., 0] < 0).any()):
        raise ValueError(f"{name} must be >= 0 (seconds since the start of the movement)")


def rollout(
    params: DMPParams,
    t: torch.Tensor,
    config: DMPConfig | None = None,
    *,
    validate: bool = True,
    backend: str = "auto",
) -> torch.Tensor:
    """Positions ``y(t)`` of a batch of DMPs at arbitrary per-sample time stamps.

    Exact solution of the DMP ODE (eqs. 3-7) up to ~1e-9 relative, differentiable by
    autograd in every field of ``params`` (w, tau, g, y0). Time runs from the start of
    the movement: ``t = 0`` is ``y0``.

    Parameters
    ----------
    params : DMPParams
        Torch tensors, batch shape ``[*batch]``.
    t : tensor [*batch, T] or [T]
        Time stamps in seconds, strictly increasing along the last axis.
    config : DMPConfig
        DMP constants; default ``DMPConfig()``.
    validate : bool
        Check inputs (costs a few host syncs; turn off in a hot training loop only once
        the inputs are known to be good).
    backend : {"auto", "fused", "torch"}
        ``"fused"``: one compiled loop (numba) for the forward and one for the backward
        pass, float32/float64 on CPU; ``"torch"``: the same maths in torch operations
        (any device and dtype). ``"auto"`` (default) takes the fused kernels where they
        apply. Both give the same numbers to rounding and the same gradients.

    Returns
    -------
    tensor [*batch, T, d]
    """
    config = config or DMPConfig()
    w, tau, g, y0 = params.w, params.tau, params.g, params.y0
    t = torch.as_tensor(t, dtype=w.dtype, device=w.device)
    if validate:
        params.validate(config)
        check_time_stamps(t, non_negative=True)
    batch = params.batch_shape
    if t.ndim == 1:
        t = t.expand(*batch, t.shape[0])
    elif tuple(t.shape[:-1]) != batch:
        raise ValueError(f"t has batch shape {tuple(t.shape[:-1])}, the parameters have {batch}")
    if _use_fused(backend, w, t):
        if len(batch) == 1:  # already flat: no reshapes (each would add an autograd node)
            return _FusedRollout.apply(t, tau, w, g, y0, config)
        flat = (t.reshape(-1, t.shape[-1]), tau.reshape(-1), w.reshape(-1, *w.shape[-2:]))
        flat += (g.reshape(-1, g.shape[-1]), y0.reshape(-1, y0.shape[-1]))
        y = _FusedRollout.apply(*flat, config)
        return y.reshape(*batch, *y.shape[-2:])
    s = (t / tau[..., None]).reshape(-1, t.shape[-1])  # [B, T]
    scale = (g - y0) if config.scaling == "goal-start" else torch.ones_like(g)
    # y = g + sum_c coef_c * column_c(s) with columns [a, R_1..R_N] of the response table.
    coef = torch.cat([(y0 - g)[..., None, :], scale[..., None, :] * w], dim=-2)
    coef = coef.reshape(-1, *coef.shape[-2:])  # [B, N+1, d]
    y = _combine_responses(s, coef, config) + g.reshape(-1, 1, g.shape[-1])
    return y.reshape(*batch, *y.shape[-2:])


def _combine_responses(s: torch.Tensor, coef: torch.Tensor, config: DMPConfig) -> torch.Tensor:
    """``sum_c coef[b, c, :] * column_c(s[b, t])`` over the response table's columns.

    Combining the columns' polynomial pieces with each sample's coefficients first (one
    GEMM over the pieces the batch reaches) and evaluating after touches 4 numbers per
    time stamp and dimension instead of 4 (N + 1): this is what makes the rollout and its
    backward pass cheap.

    s: [B, T], coef: [B, C, d] -> [B, T, d]
    """
    h, s_max, poly = _response_table(config, s.dtype, str(s.device))
    return _PiecewiseCombination.apply(s, coef, poly, h, s_max)


class _PiecewiseCombination(torch.autograd.Function):
    """Forward and hand-written backward of :func:`_combine_responses`.

    The four cubic coefficients are kept as the outermost axis, so that every step after
    the GEMM works on contiguous vectors of B*d*T numbers (reductions over a trailing axis
    of length 4 are slow on CPU).
    """

    @staticmethod
    def forward(ctx, s, coef, poly, h, s_max):
        b, c, d = coef.shape
        n_t = s.shape[-1]
        i, u = _locate(s, h, s_max, poly.shape[1])  # [B, T]
        pieces = int(i.max()) + 1
        table = poly[:, :pieces].permute(2, 0, 1)  # [4, C, G']
        coef_t = coef.transpose(1, 2).reshape(b * d, c)  # [B*d, C]
        traj = torch.matmul(coef_t, table).view(4, b * d * pieces)  # each sample's pieces
        # Column of sample b, dimension j, piece i: (b * d + j) * pieces + i.
        offset = torch.arange(b * d, device=s.device).view(b, d, 1) * pieces
        cols = (offset + i[:, None, :]).reshape(-1)  # [B*d*T]
        c0, c1, c2, c3 = traj.index_select(1, cols)  # 4 x [B*d*T]
        ub = u[:, None, :].expand(b, d, n_t).reshape(-1)  # [B*d*T]
        y = ((c3 * ub + c2) * ub + c1) * ub + c0
        inside = (s > 0) & (s < s_max)  # where the clamp passes the s-gradient on
        ctx.save_for_backward(cols, ub, c1, c2, c3, inside, table)
        ctx.h, ctx.shape = h, (b, c, d, pieces)
        return y.view(b, d, n_t).transpose(1, 2)  # [B, T, d]

    @staticmethod
    def backward(ctx, gy):  # gy: [B, T, d]
        cols, ub, c1, c2, c3, inside, table = ctx.saved_tensors
        b, c, d, pieces = ctx.shape
        g = gy.transpose(1, 2).reshape(-1)  # [B*d*T], same order as cols
        grad_s = grad_coef = None
        if ctx.needs_input_grad[0]:
            dy_du = (3 * c3 * ub + 2 * c2) * ub + c1
            grad_s = (g * dy_du).view(b, d, -1).sum(1) * inside / ctx.h  # [B, T]
        if ctx.needs_input_grad[1]:
            g1 = g * ub
            g2 = g1 * ub
            g_local = torch.stack([g, g1, g2, g2 * ub])  # [4, B*d*T]
            g_traj = torch.zeros(4, b * d * pieces, dtype=g.dtype, device=g.device)
            g_traj.index_add_(1, cols, g_local)
            per_k = torch.matmul(g_traj.view(4, b * d, pieces), table.transpose(1, 2))
            grad_coef = per_k.sum(0).view(b, d, c).transpose(1, 2)  # [B, C, d]
        return grad_s, grad_coef, None, None, None


BACKENDS = ("auto", "fused", "torch")


def _use_fused(backend: str, w: torch.Tensor, t: torch.Tensor) -> bool:
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "torch":
        return False
    ok = (
        _kernels.available()
        and w.device.type == "cpu"
        and w.dtype in (torch.float32, torch.float64)
        and not t.requires_grad
    )
    if backend == "fused" and not ok:
        raise ValueError(
            "backend='fused' needs numba and float32/float64 CPU tensors (and t without "
            f"gradient); got numba={'yes' if _kernels.available() else 'no'}, "
            f"device={w.device}, dtype={w.dtype}"
        )
    return ok


@functools.lru_cache(maxsize=16)
def _kernel_table(config: DMPConfig, dtype: torch.dtype):
    """``(1 / h, s_max, one, tab)``: scalars and cubic pieces (``[G, 4, C]``) of one dtype."""
    h, s_max, poly = _response_table(config, dtype, "cpu")
    tab = _kernels.piece_table(poly.numpy())
    one = tab.dtype.type(1.0)
    return one / tab.dtype.type(h), tab.dtype.type(s_max), one, tab


def _np(x: torch.Tensor, dtype: torch.dtype) -> np.ndarray:
    """A NumPy view of ``x`` in ``dtype`` (a converted copy only where needed)."""
    if x.dtype != dtype or not x.is_contiguous():
        x = x.to(dtype).contiguous()
    return x.detach().numpy()


def _fused_kernels(config_table, n_samples: int, n_dims: int):
    threads = torch.get_num_threads()
    if n_samples < 2 * _kernels.MIN_SAMPLES_PER_THREAD:
        threads = 1
    return _kernels.kernels(config_table.shape[2], n_dims, threads)


class _FusedRollout(torch.autograd.Function):
    """The whole rollout (forward and backward) in two compiled loops; see ``_kernels``.

    Large batches are spread over ``torch.get_num_threads()`` threads. Only the inputs
    are kept for the backward pass. The Python around the kernels is kept to a few
    microseconds: it is paid on every call.
    """

    @staticmethod
    def forward(ctx, t, tau, w, g, y0, config):
        dtype = w.dtype
        inv_h, s_max, one, tab = _kernel_table(config, dtype)
        y = torch.empty(*t.shape, w.shape[-1], dtype=dtype)
        forward = _fused_kernels(tab, t.shape[0], w.shape[-1])[0]
        arrays = [_np(x, dtype) for x in (t, tau, w, g, y0)]
        scaled = config.scaling == "goal-start"
        forward(*arrays, tab, inv_h, s_max, one, scaled, y.numpy())
        if any(ctx.needs_input_grad[1:5]):
            ctx.save_for_backward(t, tau, w, g, y0)
            ctx.config = config
        return y

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, gy):
        t, tau, w, g, y0 = ctx.saved_tensors
        dtype = w.dtype
        inv_h, s_max, one, tab = _kernel_table(ctx.config, dtype)
        need = ctx.needs_input_grad
        np_dtype = tab.dtype  # NumPy arrays: cheaper to make than tensors
        gw, gtau, gg, gy0 = (np.empty(tuple(x.shape), np_dtype) for x in (w, tau, g, y0))
        backward = _fused_kernels(tab, t.shape[0], w.shape[-1])[1]
        arrays = [_np(x, dtype) for x in (gy, t, tau, w, g, y0)]
        scaled = ctx.config.scaling == "goal-start"
        backward(*arrays, tab, inv_h, s_max, one, scaled, gw, gtau, gg, gy0, need[1])
        grads = [None] * 6
        for i, (grad, x) in enumerate(((gtau, tau), (gw, w), (gg, g), (gy0, y0)), start=1):
            if need[i]:
                grads[i] = torch.from_numpy(grad).to(x.dtype)  # .to: no copy when equal
        return tuple(grads)
