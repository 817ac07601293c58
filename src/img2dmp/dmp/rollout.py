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
relative accuracy, on a fine grid (and kept on disk) and interpolated with cubic Hermite
polynomials (values and exact derivatives at the nodes); entries below ``negligible``
are exactly 0, never subnormal numbers. A batch rollout is then one small matrix product and
a gather, and its backward pass (written by hand, checked by gradcheck) gives the exact
derivatives of that interpolant for w, g, y0 and tau; tau enters only through
``s = t / tau``, so ``dy/dtau = -(t / tau^2) y'(s)``.

Two implementations of that one interpolant (``rollout(..., backend=...)``):

- ``"fused"`` (the default for float32/float64 CPU tensors, but for the first calls of
  fewer than 4096 time stamps, see :func:`_use_fused`): one compiled loop (numba,
  :mod:`img2dmp.dmp._kernels`) for the forward and one for the backward pass, over the
  samples, on as many threads as :func:`fused_threads` allows (no more than the idle
  cores); nothing of the batch's size is materialised besides the output. Fastest on
  the CPU.
- ``"torch"``: torch operations (one GEMM of the coefficients with the pieces the batch
  reaches, a gather, a hand-written backward); any device and dtype.

They agree to rounding, and both are checked by gradcheck.
"""

from __future__ import annotations

import functools
import math
import os
import time

import numpy as np
import torch

from . import _kernels
from ._table import _cubic_pieces
from .config import DEFAULT_CONFIG, DMPConfig
from .params import DMPParams, all_finite, as_host_array, config_of, first_index

# The table is solved, kept on disk and flushed in ._table, which imports no torch: the
# NumPy rollout (._numpy_rollout) interpolates the very same pieces.


@functools.lru_cache(maxsize=32)
def _response_table(config: DMPConfig, dtype: torch.dtype, device: str):
    """Cubic Hermite pieces of the unit responses, as polynomial coefficients.

    Returns ``(h, s_max, poly)`` with ``poly`` of shape ``[C, G - 1, 4]`` (C = N + 1
    columns ``[a, R_1..R_N]``): on ``[s_i, s_i + h]`` column c is
    ``sum_k poly[c, i, k] * u**k`` with ``u = (s - s_i) / h``. The pieces match the
    tabulated values and derivatives at both ends, so the interpolant is C^1.

    Entries below ``negligible(dtype)`` (1.1e-19 in float32, 1.5e-154 in float64) are
    exactly 0: the responses of far-away kernels and the decayed tails reach 1e-300
    and below, which the cast would turn into subnormal numbers (tens of thousands in
    float32), and arithmetic on those is very slow on many x86 CPUs (the float32 fused
    rollout was 5x slower). Both backends share this table. The flushed entries are far
    below the ODE solver's own absolute tolerance (1e-16), so no accuracy is lost.
    """
    h, s_max, poly = _cubic_pieces(config, dtype)  # [G-1, C, 4] float64, flushed
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
    if x.ndim == 0:
        raise ValueError(f"{name} has shape (): give the time stamps as an array [T]")
    if x.size == 0 or x.shape[-1] == 0:
        raise ValueError(f"{name} is empty: a trajectory needs at least one time stamp")
    # NumPy below that size until the kernels are loaded: loading compiled code costs ~0.3 s
    big = x.size >= _FUSED_MIN_STAMPS or _fused_loaded
    if big and _kernels.available() and x.dtype in (np.float32, np.float64):
        faults = _kernels.time_stamp_faults(np.ascontiguousarray(x.reshape(-1, x.shape[-1])))
        if faults == 0 or (faults == 4 and not non_negative):
            return
    if not all_finite(x):
        idx = first_index(~np.isfinite(x))
        raise ValueError(f"{name} contains NaN or inf: {name}{list(idx)} is {float(x[idx])}")
    if x.shape[-1] > 1 and not bool((x[..., 1:] > x[..., :-1]).all()):
        idx = first_index(~(x[..., 1:] > x[..., :-1]))
        at = (*idx[:-1], idx[-1] + 1)
        what = "repeats" if x[at] == x[idx] else "is before"
        raise ValueError(
            f"{name} must be strictly increasing along its last axis: {name}{list(at)} = "
            f"{float(x[at])!r} {what} {name}{list(idx)} = {float(x[idx])!r}"
        )
    if non_negative and bool((x[..., 0] < 0).any()):
        idx = (*first_index(x[..., 0] < 0), 0)
        raise ValueError(
            f"{name} must be >= 0 (seconds since the start of the movement): "
            f"{name}{list(idx)} is {float(x[idx])!r}"
        )


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
        Torch tensors on one device, batch shape ``[*batch]``. Integer fields are
        converted to the fields' floating dtype (float64 if none is floating); NumPy
        fields, boolean or complex tensors and tensors on different devices are refused
        with a ``ValueError`` naming the field (``params.to_torch()`` converts NumPy).
    t : tensor [*batch, T] or [T]
        Time stamps in seconds, strictly increasing along the last axis.
    config : DMPConfig
        DMP constants; default: the ones ``params`` carries, else ``DMPConfig()``. One
        that differs from the carried ones is refused (``ValueError``).
    validate : bool
        Check inputs (costs a few host syncs; turn off in a hot training loop only once
        the inputs are known to be good).
    backend : {"auto", "fused", "torch"}
        ``"fused"``: one compiled loop (numba) for the forward and one for the backward
        pass, float32/float64 on CPU; ``"torch"``: the same maths in torch operations
        (any device and dtype). ``"auto"`` (default) takes the fused kernels where they
        apply, except for calls of fewer than 4096 time stamps (over the batch) until
        the kernels have run once in the process (:func:`load_fused_kernels`) or such
        calls would have taken the torch operations 0.5 s on an idle machine (counted
        from their sizes, not timed: where a process switches does not depend on the
        machine's load; loading the kernels takes 0.3-0.7 s). Both give the same
        numbers to rounding and the same gradients. Once the kernels are loaded, a call
        that records no gradient runs the compiled forward loop without autograd.

    Returns
    -------
    tensor [*batch, T, d]
    """
    config = config_of(params, config, DEFAULT_CONFIG)
    y = _direct_rollout(params, t, config, validate, backend)
    if y is not None:  # a call that records no gradient, once the kernels are loaded
        return y
    params = _torch_params(params)
    w, tau, g, y0 = params.w, params.tau, params.g, params.y0
    t = _time_tensor(t, w)
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
    y = _torch_rollout(t, params, config)
    if not _fused_loaded:
        _unfused["seconds"] += _TORCH_CALL_S + _TORCH_STAMP_S * t.numel()
    return y


def _torch_rollout(t: torch.Tensor, params: DMPParams, config: DMPConfig) -> torch.Tensor:
    """The rollout in torch operations; ``t`` of the parameters' batch shape."""
    w, tau, g, y0 = params.w, params.tau, params.g, params.y0
    s = (t / tau[..., None]).reshape(-1, t.shape[-1])  # [B, T]
    scale = (g - y0) if config.scaling == "goal-start" else torch.ones_like(g)
    # y = g + sum_c coef_c * column_c(s) with columns [a, R_1..R_N] of the response table.
    coef = torch.cat([(y0 - g)[..., None, :], scale[..., None, :] * w], dim=-2)
    coef = coef.reshape(-1, *coef.shape[-2:])  # [B, N+1, d]
    y = _combine_responses(s, coef, config) + g.reshape(-1, 1, g.shape[-1])
    return y.reshape(*params.batch_shape, *y.shape[-2:])


def _direct_rollout(params, t, config: DMPConfig, validate: bool, backend: str):
    """The fused forward kernel on NumPy views of the inputs, without autograd, or None.

    For calls that record no gradient, once the kernels are loaded: a small batch then
    pays for its checks and the kernel only (a B = 1 call spent 5 us of its ~50 us in
    the kernel; the rest went to building an autograd node, converting tensors and
    checks done as many small NumPy operations). None sends the call down the general
    path, which gives the same numbers (the same kernel) and raises its own messages:
    a gradient to record, another device or dtype, a shape that does not fit, or
    anything the checks would refuse.
    """
    if not (_fused_loaded and backend in ("auto", "fused") and _kernels.available()):
        return None
    arrays = _host_arrays(params, t)
    if arrays is None or not _shapes_fit(*arrays, config):
        return None
    t, tau, w, g, y0 = arrays
    batch, n_t, d = tau.shape, t.shape[-1], w.shape[-1]
    t = _stamp_rows(t, batch)  # [B, T]
    if validate:
        params.validate(config)  # the same checks (and messages) as the general path
        if _kernels.time_stamp_faults(t):  # NaN or inf, not increasing, below 0
            return None  # the general path names what is wrong with t
    flat = (tau.reshape(-1), w.reshape(-1, *w.shape[-2:]), g.reshape(-1, d), y0.reshape(-1, d))
    y = torch.from_numpy(_forward_kernel(t, *(np.ascontiguousarray(a) for a in flat), config))
    return y if len(batch) == 1 else y.reshape(*batch, n_t, d)


def _host_arrays(params, t) -> tuple | None:
    """``(t, tau, w, g, y0)`` as NumPy views, when the four fields are CPU tensors of one
    float dtype the kernels take and nothing needs a gradient (``t`` a tensor or NumPy
    array of that dtype); else None."""
    if type(params) is not DMPParams:
        return None
    fields = (params.tau, params.w, params.g, params.y0)
    dtype = getattr(params.w, "dtype", None)
    if dtype not in _NP_DTYPES:
        return None
    if type(t) is np.ndarray and t.dtype == _NP_DTYPES[dtype]:
        t = torch.from_numpy(t)  # a view: checked below as the tensors are
    for a in (t, *fields):
        if type(a) is not torch.Tensor or a.dtype is not dtype or a.requires_grad or not a.is_cpu:
            return None
    return tuple(a.numpy() for a in (t, *fields))


def _stamp_rows(t: np.ndarray, batch: tuple) -> np.ndarray:
    """``t`` (``[*batch, T]`` or ``[T]``) as C-contiguous rows ``[B, T]``, a view where
    it can be (a kernel given another layout would be compiled again for it)."""
    n_t = t.shape[-1]
    if t.ndim == 2 and t.flags.c_contiguous and len(batch) == 1:
        return t
    if t.ndim == 1 and math.prod(batch) == 1:
        return np.ascontiguousarray(t).reshape(1, n_t)
    return np.ascontiguousarray(np.broadcast_to(t, (*batch, n_t)).reshape(-1, n_t))


_NP_DTYPES = {torch.float32: np.dtype(np.float32), torch.float64: np.dtype(np.float64)}


def _shapes_fit(t, tau, w, g, y0, config: DMPConfig) -> bool:
    """Shapes the kernels take: those :meth:`DMPParams.validate` accepts for ``config``,
    ``t`` of the parameters' batch shape or 1-D, at least one time stamp."""
    batch = w.shape[:-2]
    fields_fit = (
        w.ndim >= 2
        and w.shape[-2:] == (config.n_kernels, config.n_dims)
        and tau.shape == batch
        and g.shape == y0.shape == (*batch, config.n_dims)
    )
    t_fits = t.ndim >= 1 and t.shape[-1] > 0 and (t.ndim == 1 or t.shape[:-1] == batch)
    return fields_fit and t_fits


def _forward_kernel(t, tau, w, g, y0, config: DMPConfig) -> np.ndarray:
    """Positions ``[B, T, d]`` from the fused forward kernel; C-contiguous NumPy inputs
    ``t [B, T]``, ``tau [B]``, ``w [B, N, d]``, ``g``, ``y0 [B, d]`` of one float dtype."""
    global _fused_loaded
    _fused_loaded = True
    inv_h, s_max, one, tab = _kernel_table(config, _TORCH_DTYPES[t.dtype.type])
    y = np.empty((*t.shape, w.shape[-1]), dtype=tab.dtype)
    forward = _fused_kernels(tab, t.shape[0], w.shape[-1])[0]
    forward(t, tau, w, g, y0, tab, inv_h, s_max, one, config.scaling == "goal-start", y)
    return y


_TORCH_DTYPES = {np.float32: torch.float32, np.float64: torch.float64}


def _torch_params(params: DMPParams) -> DMPParams:
    """``params`` if its fields are floating tensors on one device (the fast path),
    else with integer tensors converted, or a ``ValueError`` naming the field at fault."""
    if not isinstance(params, DMPParams):
        raise TypeError(f"rollout needs a DMPParams, got {type(params).__name__}")
    fields = (params.w, params.tau, params.g, params.y0)
    if all(isinstance(a, torch.Tensor) for a in fields):
        dev = params.w.device
        if all(a.dtype.is_floating_point and a.device == dev for a in fields):
            return params
    named = dict(zip(("w", "tau", "g", "y0"), fields, strict=True))
    for name, a in named.items():
        if not isinstance(a, torch.Tensor):
            kind = f"a NumPy array ({a.dtype})" if isinstance(a, np.ndarray) else type(a).__name__
            raise ValueError(
                f"rollout needs torch tensors, but DMPParams.{name} is {kind}; "
                "convert the parameters with params.to_torch()"
            )
        if a.is_complex() or a.dtype == torch.bool:
            raise ValueError(
                f"rollout needs real numbers, but DMPParams.{name} has dtype {a.dtype}"
            )
        if a.device != params.w.device:
            raise ValueError(
                f"DMPParams.{name} is on {a.device} but DMPParams.w is on {params.w.device}; "
                "put all four on one device"
            )
    floats = [a.dtype for a in fields if a.dtype.is_floating_point]
    dtype = functools.reduce(torch.promote_types, floats) if floats else torch.float64
    conv = (a if a.dtype.is_floating_point else a.to(dtype) for a in fields)
    return DMPParams(*conv, config=params.config)


def _time_tensor(t, w: torch.Tensor) -> torch.Tensor:
    """Time stamps as a tensor of ``w``'s dtype and device; refuse what is not numbers."""
    dtype = getattr(t, "dtype", None)
    if dtype is not None and (
        dtype in (torch.bool, torch.complex64, torch.complex128)
        or (isinstance(dtype, np.dtype) and dtype.kind not in "iuf")
    ):
        raise ValueError(f"t must hold real time stamps in seconds, got dtype {dtype}")
    try:
        return torch.as_tensor(t, dtype=w.dtype, device=w.device)
    except (TypeError, ValueError, RuntimeError) as e:
        raise ValueError(f"t must be time stamps in seconds (numbers): {e}") from None


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
    if (
        backend == "auto"
        and not _fused_loaded
        and t.numel() < _FUSED_MIN_STAMPS
        and _unfused["seconds"] < _KERNEL_LOAD_S
    ):
        return False  # a small call before any large one: not worth loading the kernels
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


# "auto" takes the torch operations for calls of fewer time stamps than this (over the
# whole batch) until the fused kernels have run once in the process: loading numba's
# compiled code from its disk cache takes ~0.3 s once per process, which a one-image
# prediction would feel, while the torch operations roll out a few thousand stamps in
# about a millisecond. The time-stamp check takes NumPy below this size for that reason.
# A process that makes many small calls (a controller, a server rolling out one DMP per
# request) loads the kernels once the torch operations have spent about as long on them
# as the loading takes (0.3-0.7 s on a 2-core AMD EPYC): it then pays at most about
# twice what knowing its future would have cost, and ~20 us per B = 1 call after, where
# the torch operations take 0.3 ms on an idle machine and up to 25 ms on a loaded one
# (each of their parallel regions waits for a busy core; see fused_threads).
# That time is counted from the calls' sizes, as an idle machine takes them, not timed:
# timed, the call at which a process switched (and so the last bits of every result
# after it) followed the machine's load. The sizes' cost: one thread of a 2-core Intel
# Xeon, the fastest of 200 calls, float64, d = 2, 25 kernels: 0.21 ms at 100 stamps,
# 0.23 at 1,000, 0.43-0.51 at 4,000 (B = 1 to 16).
_FUSED_MIN_STAMPS = 4096
_KERNEL_LOAD_S = 0.5
_TORCH_CALL_S = 2e-4
_TORCH_STAMP_S = 7e-8
_fused_loaded = False  # set by the first fused rollout
_unfused = {"seconds": 0.0}  # idle time of the torch operations' rollouts before that


def load_fused_kernels(config: DMPConfig | None = None) -> bool:
    """Load the rollout's fused kernels now (numba's compiled code, 0.3-0.7 s once per
    process; those for ``config``'s kernels and dimensions, default ``DMPConfig()``), so
    that every later :func:`rollout` with ``backend="auto"`` of float CPU tensors takes
    them: the results of a long-running process (a server, a controller, a training)
    then do not depend on the calls made before. False without numba (the torch
    operations throughout)."""
    config = DEFAULT_CONFIG if config is None else config
    n, d = config.n_kernels, config.n_dims
    params = DMPParams(torch.zeros(1, n, d), torch.ones(1), torch.ones(1, d), torch.zeros(1, d))
    try:
        rollout(params, torch.linspace(0.0, 1.0, 2), config, backend="fused")
    except ValueError:  # no numba
        return False
    return True


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
    threads = fused_threads(n_samples)
    if threads == 1:
        return _kernels.kernels(config_table.shape[2], n_dims, 1)
    # numba's first start of its thread pool can set the OpenMP thread count that torch
    # shares with it (when torch read it before) to numba's own limit: keep torch's.
    torch_threads = torch.get_num_threads()
    pair = _kernels.kernels(config_table.shape[2], n_dims, threads)
    if torch.get_num_threads() != torch_threads:
        torch.set_num_threads(torch_threads)
    return pair


# How many threads the fused kernels use. A parallel region with a thread on a core that
# another process keeps busy waits for the scheduler: 15-30 ms per region on a 2-core
# machine with one busy neighbour, against ~1 ms for the whole rollout on one thread
# (benchmarks/bench_rollout.py --load). Idle cores halve the time at best, so threads
# are only added for cores that look idle.
_fixed_threads: int | None = None  # set by fix_fused_threads
_LOOK_EVERY = 0.5  # seconds between two looks at the machine's load
_load = {"at": -math.inf, "cpu": 0.0, "idle": 0}


def fix_fused_threads(n: int | None) -> None:
    """Make the fused kernels use ``n`` threads for every batch (``None``: the rule).

    For benchmarks and tests; numba's own limit still caps ``n``.
    """
    global _fixed_threads
    if n is not None and (not isinstance(n, int) or n < 1):
        raise ValueError(f"threads must be an integer >= 1 or None, got {n!r}")
    _fixed_threads = n


def fused_threads(n_samples: int) -> int:
    """Threads the fused kernels spread a batch of ``n_samples`` over.

    ``min(torch.get_num_threads(), n_samples // 16, 1 + idle_cores())``, at least 1:
    one thread per 16 samples at most (fewer samples per thread cost more to hand out
    than they save), and one more than the cores no other process seems to be using
    (:func:`idle_cores`), so that a loaded machine runs the kernels serially instead of
    waiting for a busy core.
    """
    if _fixed_threads is not None:
        return _fixed_threads
    n = min(torch.get_num_threads(), n_samples // _kernels.MIN_SAMPLES_PER_THREAD)
    return 1 if n <= 1 else max(1, min(n, 1 + idle_cores()))


def idle_cores() -> int:
    """Cores available to this process, besides the calling thread's, that look idle.

    ``cores - 1 - others`` rounded, where ``cores`` is the CPU affinity set and
    ``others`` the larger of two estimates of the cores other processes keep busy: the
    tasks running right now (``/proc/loadavg``) less this process's running threads
    (its own thread pools may still be spinning after a parallel region), which sees a
    neighbour start at once, and the one-minute load average less this process's own
    CPU use since the last look, which remembers a neighbour that is only sometimes
    running. Looked up at most every 0.5 s (a few tens of us); 0 when unknown.
    """
    now = time.monotonic()
    if now - _load["at"] < _LOOK_EVERY:
        return _load["idle"]
    cpu = time.process_time()  # all threads of this process
    own = (cpu - _load["cpu"]) / (now - _load["at"]) if math.isfinite(_load["at"]) else 1.0
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        cores = os.cpu_count() or 1
    others = max(_running_now() - _own_running(), _load_average() - own)
    _load.update(at=now, cpu=cpu, idle=max(0, int(cores - 1 - others + 0.5)))
    return _load["idle"]


def _running_now() -> int:
    """Tasks running or runnable this instant, system-wide, this one included (0: unknown)."""
    try:
        with open("/proc/loadavg") as f:  # "0.52 0.58 0.59 2/345 12345"
            return int(f.read().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):  # pragma: no cover - not Linux
        return 0


def _own_running() -> int:
    """Threads of this process running or runnable this instant (at least this one)."""
    n = 0
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:  # pragma: no cover - not Linux
        return 1
    for tid in tids:
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:  # "pid (name) R ..."
                stat = f.read()
        except OSError:  # the thread has ended
            continue
        n += stat[stat.rindex(")") + 2] == "R"
    return max(n, 1)


def _load_average() -> float:
    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):  # pragma: no cover - not Unix
        return 0.0


class _FusedRollout(torch.autograd.Function):
    """The whole rollout (forward and backward) in two compiled loops; see ``_kernels``.

    Large batches are spread over :func:`fused_threads` threads. Only the inputs are kept
    for the backward pass. The Python around the kernels is kept to a few
    microseconds: it is paid on every call.
    """

    @staticmethod
    def forward(ctx, t, tau, w, g, y0, config):
        arrays = [_np(x, w.dtype) for x in (t, tau, w, g, y0)]
        y = torch.from_numpy(_forward_kernel(*arrays, config))
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
