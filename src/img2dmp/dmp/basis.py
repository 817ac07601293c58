"""Canonical system and Gaussian kernels (eqs. 5-7 of Pahič et al., ICRA 2018).

Every function accepts NumPy arrays or torch tensors and returns the same kind, with any
number of leading batch dimensions.
"""

from __future__ import annotations

import math

import numpy as np

from .._lazy import is_dtype, is_tensor
from .config import DMPConfig


def _exp(a):
    return a.exp() if is_tensor(a) else np.exp(a)


def negligible(dtype) -> float:
    """Magnitude below which a DMP table entry or kernel value is replaced by exactly 0.

    ``sqrt(tiny)`` of the dtype (1.1e-19 for float32 and bfloat16, 1.5e-154 for float64),
    for two reasons. A product of two numbers above it is a normal number, never a
    subnormal one (arithmetic on subnormals takes microcode assists, up to ~100x slower
    per instruction, on many x86 CPUs). And it is far below rounding: below
    ``eps ** 2`` of the dtype, where the unit responses and kernels it is applied to
    peak near 1e-3 to 1. float16, whose exponent range is too narrow for both, flushes
    only its subnormal numbers (``max(tiny, ...)``).

    ``dtype``: a torch or NumPy floating dtype.
    """
    if is_dtype(dtype):
        import torch

        fi = torch.finfo(dtype)
    else:
        fi = np.finfo(dtype)
    return max(float(fi.tiny), min(math.sqrt(float(fi.tiny)), float(fi.eps) ** 2))


def _kernel_exp(e):
    """``exp(e)`` for ``e <= 0``, exactly 0 where it would be below :func:`negligible`.

    The argument is masked to -inf first, so that no subnormal result is ever made (an
    exponent down to -745 in float64, -103 in float32, would give one).
    """
    lo = math.log(negligible(e.dtype))
    if is_tensor(e):
        return e.masked_fill(e < lo, -math.inf).exp()
    return np.exp(np.where(e < lo, -np.inf, e))


def phase(t, tau, alpha_x: float = 2.0):
    """Phase of the canonical system, eq. (5): ``x(t) = exp(-alpha_x * t / tau)``.

    Solves ``tau * dx/dt = -alpha_x * x`` with ``x(0) = 1``.

    Parameters
    ----------
    t : array [*batch, T]
        Time stamps in seconds.
    tau : array [*batch, 1] or scalar
        Temporal scaling (duration) in seconds; broadcast against ``t``.
    """
    return _exp(-alpha_x * t / tau)


def kernel_centres(config: DMPConfig) -> np.ndarray:
    """Kernel centres ``c_k = exp(-alpha_x * k / (N - 1))``, k = 0..N-1.

    They are spaced evenly in normalised time ``s = t / tau`` on [0, 1], i.e. along the
    phase of eq. (5). Returns a float64 array ``[N]``.
    """
    k = np.arange(config.n_kernels, dtype=np.float64)
    return np.exp(-config.alpha_x * k / (config.n_kernels - 1))


def kernel_widths(config: DMPConfig) -> np.ndarray:
    """Kernel widths ``h_k`` of eq. (7), from the spacing of the centres.

    ``h_k = width_factor / (c_{k+1} - c_k)**2`` and the last kernel takes its neighbour's
    width, so two neighbours cross at ``exp(-width_factor / 4)`` of their peak.
    Returns a float64 array ``[N]``.
    """
    c = kernel_centres(config)
    dc = np.diff(c)
    dc = np.append(dc, dc[-1])
    return config.width_factor / dc**2


def basis_functions(x, centres, widths):
    """Normalised, phase-weighted kernels ``phi_k(x) = psi_k(x) x / sum_j psi_j(x)``.

    With ``psi_k(x) = exp(-h_k (x - c_k)^2)`` (eq. 7), the forcing term of eq. (6) is
    ``F(x) = sum_k w_k phi_k(x)``.

    Parameters
    ----------
    x : array [*batch]
        Phase values.
    centres, widths : array [N]
        From :func:`kernel_centres` and :func:`kernel_widths`.

    Returns
    -------
    array [*batch, N]
    """
    if is_tensor(x):
        import torch

        centres = torch.as_tensor(centres, dtype=x.dtype, device=x.device)
        widths = torch.as_tensor(widths, dtype=x.dtype, device=x.device)
    d = x[..., None] - centres
    # Subtracting the largest exponent keeps the ratio exact far from every centre; the
    # kernels below negligible() of the largest (which is 1) are exactly 0.
    e = -widths * d * d
    if is_tensor(e):
        psi = _kernel_exp(e - e.amax(dim=-1, keepdim=True))
        return psi * x[..., None] / psi.sum(dim=-1, keepdim=True)
    psi = _kernel_exp(e - e.max(axis=-1, keepdims=True))
    return psi * x[..., None] / psi.sum(axis=-1, keepdims=True)


def forcing_term(x, w, centres, widths):
    """Forcing term of eq. (6): ``F(x) = sum_k w_k psi_k(x) x / sum_k psi_k(x)``.

    Parameters
    ----------
    x : array [*batch]
        Phase values.
    w : array [*batch, N, d]
        Kernel weights.

    Returns
    -------
    array [*batch, d]
    """
    phi = basis_functions(x, centres, widths)  # [*batch, N]
    return (phi[..., :, None] * w).sum(-2)


def basis_functions_and_derivative(x, centres, widths):
    """``phi_k(x)`` of :func:`basis_functions` and its derivative ``d phi_k / dx``.

    With ``p_k = psi_k / sum_j psi_j`` and ``q_k = -2 h_k (x - c_k)`` (so that
    ``psi_k' = q_k psi_k``), ``phi_k = x p_k`` and
    ``phi_k' = p_k + x p_k (q_k - sum_j p_j q_j)``. Needed by the tau-sensitivity.

    Parameters
    ----------
    x : tensor [*batch]

    Returns
    -------
    phi, dphi : tensors [*batch, N]
    """
    import torch

    centres = torch.as_tensor(centres, dtype=x.dtype, device=x.device)
    widths = torch.as_tensor(widths, dtype=x.dtype, device=x.device)
    d = x[..., None] - centres
    e = -widths * d * d
    psi = _kernel_exp(e - e.amax(dim=-1, keepdim=True))  # no subnormal kernel values
    p = psi / psi.sum(dim=-1, keepdim=True)
    q = -2.0 * widths * d
    qbar = (p * q).sum(dim=-1, keepdim=True)
    phi = x[..., None] * p
    dphi = p + x[..., None] * p * (q - qbar)
    return phi, dphi
