"""The rollout of :mod:`img2dmp.dmp.rollout` in NumPy (float64), with its hand-written VJP.

For a prediction that never imports torch (its import takes longer than the whole
prediction). The interpolant is the torch rollout's, from the same table
(:mod:`img2dmp.dmp._table`):

    s = clip(t / tau, 0, s_max),   q = s / h,   i = clip(floor(q), 0, G - 2),   u = q - i
    y(t) = g + (y0 - g) p_0(i, u) + S * sum_k w_k p_k(i, u)

with ``p_c(i, u) = sum_m P[i, c, m] u^m`` the cubic Hermite piece ``i`` of column ``c``
(``[a, R_1..R_N]``) and ``S = g - y0`` (``scaling="goal-start"``) or 1 (``"none"``).
Past the table's end the last piece is extended (``u`` may exceed 1 by rounding); a
NaN ``t / tau`` is looked up in piece 0 and its NaN ``u`` gives NaN positions.
A third dimension (the pen) is rolled out like the other two.

The VJP is that of the torch path's backward (``_PiecewiseCombination``): exact
derivatives of the interpolant in w, g, y0, and for tau through ``s = t / tau``
only where ``0 < s < s_max`` (the clamp passes nothing on outside):

    dL/dtau = -sum_t (t / tau^2) [0 < s < s_max] sum_j gy_tj dy_j/ds,
    dy_j/ds = (1 / h) sum_c coef_cj dp_c/du.
"""

from __future__ import annotations

import functools

import numpy as np

from .._lazy import is_tensor
from ._table import _cubic_pieces
from .config import DEFAULT_CONFIG, DMPConfig
from .params import DMPParams, config_of

_FIELDS = ("w", "tau", "g", "y0")
# Stamps rolled out at once: each holds its piece of the table (4 (N + 1) numbers, 832
# bytes for N = 25), so a large batch goes in chunks of ~27 MB instead of one copy of
# its whole size.
_CHUNK_STAMPS = 1 << 15


@functools.lru_cache(maxsize=16)
def _pieces(config: DMPConfig) -> tuple[float, float, np.ndarray]:
    """``(h, s_max, poly)`` with ``poly`` ``[G - 1, 4, C]``: one piece's four powers of
    every column are one contiguous row, gathered per stamp in one copy."""
    h, s_max, poly = _cubic_pieces(config, np.float64)  # [G-1, C, 4], as the torch path's
    poly = np.ascontiguousarray(poly.transpose(0, 2, 1))
    poly.flags.writeable = False  # shared by every call
    return h, s_max, poly


def _locate(s: np.ndarray, h: float, s_max: float, n_pieces: int):
    """Piece index ``i`` ``[B, T]`` and local coordinate ``u`` ``[B, T]`` of ``s``."""
    q = np.minimum(np.maximum(s, 0.0), s_max) / h  # NaN stays NaN
    # fmax/fmin drop a NaN: a NaN s is looked up in piece 0 and its u stays NaN.
    i = np.fmin(np.fmax(np.floor(q), 0.0), n_pieces - 1).astype(np.intp)
    return i, q - i


class _Rollout:
    """One forward pass on flat arrays, kept for its VJP (:meth:`vjp`).

    Arrays: ``w`` [B, N, d], ``tau`` [B], ``g`` and ``y0`` [B, d], ``t`` [B, T], float64.
    As in the torch path, each stamp's piece is combined with the sample's coefficients
    first (one batched product) and the resulting cubic of ``y - g`` evaluated after:
    the per-stamp work is then 4 d numbers, not 4 (N + 1).
    """

    def __init__(self, w, tau, g, y0, t, config: DMPConfig):
        h, s_max, poly = _pieces(config)
        self.h, self.s_max = h, s_max
        self.w, self.tau, self.t = w, tau, t
        self.scaled = config.scaling == "goal-start"
        with np.errstate(invalid="ignore", divide="ignore"):
            self.s = t / tau[:, None]  # [B, T]
        i, self.u = _locate(self.s, h, s_max, poly.shape[0])
        self.scale = g - y0 if self.scaled else np.ones_like(g)  # [B, d]
        # Columns [a, R_1..R_N] combine with [y0 - g, S w_1, .., S w_N].
        coef = np.concatenate([(y0 - g)[:, None, :], self.scale[:, None, :] * w], 1)
        b, n_t = t.shape
        self.pieces = np.take(poly, i, axis=0).reshape(b, n_t * 4, -1)  # [B, T*4, C]
        cubic = np.matmul(self.pieces, coef).reshape(b, n_t, 4, -1)  # [B, T, 4, d]
        self.cubic = cubic
        u = self.u[..., None]  # [B, T, 1]
        y = ((cubic[:, :, 3] * u + cubic[:, :, 2]) * u + cubic[:, :, 1]) * u + cubic[:, :, 0]
        self.y = y + g[:, None, :]  # [B, T, d]

    def vjp(self, gy: np.ndarray) -> tuple[np.ndarray, ...]:
        """``(gw, gtau, gg, gy0)``: gradients of ``sum(gy * y)``, ``gy`` ``[B, T, d]``."""
        cubic, u = self.cubic, self.u[..., None]
        dy_du = (3.0 * cubic[:, :, 3] * u + 2.0 * cubic[:, :, 2]) * u + cubic[:, :, 1]
        inside = (self.s > 0) & (self.s < self.s_max)  # [B, T]
        # A product, not np.where: a NaN s (NaN tau) must give a NaN gradient, as in torch.
        grad_s = (gy * dy_du).sum(-1) * inside / self.h  # [B, T]
        gtau = -(grad_s * self.t).sum(-1) / (self.tau * self.tau)  # [B]
        g1 = gy * u
        g2 = g1 * u
        local = np.stack([gy, g1, g2, g2 * u], axis=2)  # [B, T, 4, d]: gy times u^m
        b, n_t, _, d = local.shape
        gcoef = np.matmul(self.pieces.transpose(0, 2, 1), local.reshape(b, n_t * 4, d))
        g_free, g_forced = gcoef[:, 0], gcoef[:, 1:]  # [B, d], [B, N, d]
        gw = self.scale[:, None, :] * g_forced
        gg = gy.sum(1) - g_free
        gy0 = g_free.copy()
        if self.scaled:  # S = g - y0 passes the weights' gradient on to g and y0
            through = (g_forced * self.w).sum(1)  # [B, d]
            gg += through
            gy0 -= through
        return gw, gtau, gg, gy0


def _flat_inputs(params: DMPParams, t, config: DMPConfig, validate: bool):
    """Checked float64 arrays, flattened to one batch axis, and the batch shape."""
    if not isinstance(params, DMPParams):
        raise ValueError(f"rollout_numpy needs a DMPParams, got {type(params).__name__}")
    fields = {}
    for name in _FIELDS:
        a = getattr(params, name)
        if is_tensor(a):
            raise ValueError(
                f"rollout_numpy needs NumPy arrays, but DMPParams.{name} is a torch tensor; "
                "convert the parameters with params.to_numpy()"
            )
        a = np.asarray(a)
        if a.dtype.kind not in "iuf":
            raise ValueError(f"rollout_numpy needs real numbers, DMPParams.{name} is {a.dtype}")
        fields[name] = a.astype(np.float64, copy=False)
    p = object.__new__(DMPParams)  # its values are checked below only with validate
    p.w, p.tau, p.g, p.y0 = (fields[k] for k in _FIELDS)
    if validate:
        p.validate(config)
    else:  # the shapes at least: a wrong one would broadcast silently
        _check_shapes(p, config)
    t = np.asarray(t)
    if t.dtype.kind not in "iuf":
        raise ValueError(f"t must hold real time stamps in seconds, got dtype {t.dtype}")
    t = t.astype(np.float64, copy=False)
    batch = p.batch_shape
    if t.ndim == 0 or t.shape[-1] == 0:
        raise ValueError(f"t has shape {t.shape}: a trajectory needs at least one time stamp")
    if t.ndim == 1:
        t = np.broadcast_to(t, (*batch, t.shape[0]))
    elif t.shape[:-1] != batch:
        raise ValueError(f"t has batch shape {t.shape[:-1]}, the parameters have {batch}")
    if validate:
        _check_time_stamps(t)
    n, d = p.w.shape[-2:]
    flat = (p.w.reshape(-1, n, d), p.tau.reshape(-1), p.g.reshape(-1, d), p.y0.reshape(-1, d))
    return flat, t.reshape(-1, t.shape[-1]), batch


def _check_shapes(p: DMPParams, config: DMPConfig) -> None:
    """The shape checks of :meth:`DMPParams.validate`, without its value checks."""
    n, d = config.n_kernels, config.n_dims
    if p.w.ndim < 2 or p.w.shape[-2:] != (n, d):
        raise ValueError(
            f"DMPParams.w has shape {p.w.shape}, expected [*batch, {n}, {d}] for this config"
        )
    batch = p.w.shape[:-2]
    for name, shape in (("tau", batch), ("g", (*batch, d)), ("y0", (*batch, d))):
        if getattr(p, name).shape != shape:
            raise ValueError(
                f"DMPParams.{name} has shape {getattr(p, name).shape}, expected {shape}"
            )


def _check_time_stamps(t: np.ndarray) -> None:
    """``ValueError`` unless ``t`` is finite, >= 0 and strictly increasing (last axis)."""
    if not np.isfinite(t).all():
        raise ValueError("t contains NaN or inf")
    if t.shape[-1] > 1 and not (t[..., 1:] > t[..., :-1]).all():
        raise ValueError("t must be strictly increasing along its last axis")
    if (t[..., 0] < 0).any():
        raise ValueError("t must be >= 0 (seconds since the start of the movement)")


def rollout_numpy(
    params: DMPParams, t, config: DMPConfig | None = None, *, validate: bool = True
) -> np.ndarray:
    """Positions ``y(t)`` of a batch of DMPs, in NumPy float64; no torch involved.

    ``y(t) = g + (y0 - g) p_0(s) + S sum_k w_k p_k(s)`` at ``s = clip(t / tau, 0, s_max)``
    with the cubic Hermite pieces ``p_c`` of the unit responses (module docstring): the
    same interpolant as :func:`img2dmp.dmp.rollout`, equal to its float64 result to
    rounding (~1e-13 px).

    Parameters
    ----------
    params : DMPParams
        NumPy fields (real dtype, converted to float64), batch shape ``[*batch]``.
    t : array [*batch, T] or [T]
        Time stamps in seconds, from the start of the movement (``t = 0`` is ``y0``).
    config : DMPConfig
        DMP constants; default: the ones ``params`` carries (a different one is
        refused), else ``DMPConfig()``.
    validate : bool
        Check the values (finite, tau > 0, t >= 0 and strictly increasing); shapes are
        always checked. Without it a NaN tau gives NaN positions.

    Returns
    -------
    ndarray [*batch, T, d]
    """
    config = config_of(params, config, DEFAULT_CONFIG)
    (w, tau, g, y0), t, batch = _flat_inputs(params, t, config, validate)
    parts = [_Rollout(w[c], tau[c], g[c], y0[c], t[c], config).y for c in _chunks(t.shape)]
    y = parts[0] if len(parts) == 1 else np.concatenate(parts)  # [B, T, d]
    return y.reshape(*batch, *y.shape[-2:])


def _chunks(shape: tuple) -> list[slice]:
    """Slices of the flat batch ``[B, T]`` of at most ``_CHUNK_STAMPS`` stamps (or one
    sample) each."""
    step = max(1, _CHUNK_STAMPS // shape[1])
    return [slice(a, a + step) for a in range(0, shape[0], step)]


def rollout_numpy_vjp(
    params: DMPParams, t, config: DMPConfig | None, grad_y, *, validate: bool = True
) -> DMPParams:
    """Gradients of ``L = sum(grad_y * y)``, ``y = rollout_numpy(params, t, config)``.

    The vector-Jacobian product of the interpolant, as the torch rollout's backward
    defines it (module docstring): ``dL/dw_kj = S_j sum_t gy_tj p_k(s_t)``;
    ``dL/dy0_j = c_j - [goal-start] sum_k w_kj dL/d(S w)_kj`` and
    ``dL/dg_j = sum_t gy_tj - c_j + [goal-start] sum_k w_kj dL/d(S w)_kj`` with
    ``c_j = sum_t gy_tj p_0(s_t)``; and ``dL/dtau`` through ``s = t / tau`` from the
    interpolant's own derivative, zero where the clamp of s is active.

    Parameters
    ----------
    params, t, config, validate
        As for :func:`rollout_numpy`.
    grad_y : array [*batch, T, d]
        The output's gradient.

    Returns
    -------
    DMPParams
        NumPy float64 gradients of the shapes of ``params``' fields (not validated: a
        gradient may be negative or NaN).
    """
    config = config_of(params, config, DEFAULT_CONFIG)
    (w, tau, g, y0), t, batch = _flat_inputs(params, t, config, validate)
    gy = np.asarray(grad_y, dtype=np.float64)
    expected = (*batch, t.shape[-1], config.n_dims)
    if gy.shape != expected:
        raise ValueError(f"grad_y has shape {gy.shape}, expected {expected} (that of y)")
    gy = gy.reshape(-1, *expected[-2:])  # [B, T, d]
    parts = [_Rollout(w[c], tau[c], g[c], y0[c], t[c], config).vjp(gy[c]) for c in _chunks(t.shape)]
    grads = parts[0] if len(parts) == 1 else [np.concatenate(a) for a in zip(*parts, strict=True)]
    gw, gtau, gg, gy0 = (a.reshape((*batch, *a.shape[1:])) for a in grads)
    out = object.__new__(DMPParams)  # gradients: tau's may be <= 0
    out.w, out.tau, out.g, out.y0 = gw, gtau, gg, gy0
    return out


__all__ = ["rollout_numpy", "rollout_numpy_vjp"]
