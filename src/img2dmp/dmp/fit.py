"""Fitting DMP parameters to demonstrated trajectories.

``tau``, ``g`` and ``y0`` are read off the demonstration (its duration, last and first
point). Because the DMP's solution is affine in the weights (see :mod:`.rollout`), the
weights are then found by linear least squares **on the positions themselves**::

    min_w  mean_t || y_demo(t) - y_dmp(t; w) ||^2  +  ridge * mean_eig * ||w||^2

This needs no numerical differentiation of the demonstration (the classical regression
on ``tau^2 y''`` amplifies sampling noise and gaps), works at arbitrary, uneven time
stamps, and minimises exactly the error that evaluation and cost (10) measure.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..config import check_positive
from .config import DMPConfig, as_config
from .params import DMPParams, first_index
from .rollout import check_time_stamps, unit_responses


@dataclass
class FitResult:
    """Outcome of :func:`fit_dmp`.

    Attributes
    ----------
    params : DMPParams
        Fitted parameters, batch shape ``[*batch]``, same array kind as the input;
        they carry the ``config`` they were fitted under.
    error_px : array [*batch]
        Mean Euclidean distance between the demonstration and the fitted DMP's rollout at
        the demonstration's time stamps (units of the input, e.g. pixels).
    max_error_px : array [*batch]
        Largest such distance.
    """

    params: DMPParams
    error_px: Any  # NumPy or torch, as the input
    max_error_px: Any


#: Most points of one trajectory fitted (memory grows by about 2 KB a point).
MAX_FIT_POINTS = 100_000


def fit_dmp(
    t,
    y,
    config: DMPConfig | None = None,
    *,
    ridge: float = 1e-9,
    chunk_size: int = 4096,
) -> FitResult:
    """Fit DMPs to a batch of demonstrations by least squares in trajectory space.

    Parameters
    ----------
    t : array [*batch, T] or [T] (also [1, T]: shared)
        Time stamps in seconds, strictly increasing; need not be evenly spaced and need
        not start at 0 (the movement is taken to start at ``t[..., 0]``).
    y : array [*batch, T, d]
        Demonstrated positions.
    config : DMPConfig or None
        Constants; its ``n_dims`` must equal d. None: the paper's constants for d
        dimensions (``DMPConfig(n_dims=d)``), the fitted parameters carry them.
    ridge : float
        Tikhonov regularisation, relative to the mean eigenvalue of the normal
        equations (scale-free). The small default only guards against singular systems;
        raise it (e.g. 1e-4) to keep weights small where ``g - y0`` is near zero.
    chunk_size : int
        Demonstrations solved at once when every sample has its own time stamps.

    Returns
    -------
    FitResult
        NumPy in, NumPy out; torch in, torch out (float64 inside).
    """
    config = as_config(config if config is not None else _config_for(y))
    as_numpy = not isinstance(y, torch.Tensor)
    t, y, ridge = _check_inputs(t, y, config, ridge, chunk_size)
    batch = tuple(y.shape[:-2])

    yf = y.reshape(-1, *y.shape[-2:])  # [B, T, d]
    shared = t.ndim == 1
    tf = t[None] if shared else t.reshape(-1, t.shape[-1])  # [1 or B, T]
    outs = []
    step = yf.shape[0] if shared else chunk_size
    for lo in range(0, yf.shape[0], max(step, 1)):
        tc = tf if shared else tf[lo : lo + step]
        outs.append(_fit_chunk(tc, yf[lo : lo + step], config, ridge))
    w, tau, g, y0, err, emax = (torch.cat(parts) for parts in zip(*outs, strict=True))
    _check_fit(w, tau, yf, shared, batch)
    params = DMPParams(
        w=w.reshape(*batch, *w.shape[1:]),
        tau=tau.reshape(batch),
        g=g.reshape(*batch, -1),
        y0=y0.reshape(*batch, -1),
        config=config,
    )
    err, emax = err.reshape(batch), emax.reshape(batch)
    if as_numpy:
        return FitResult(params.to_numpy(), err.numpy(), emax.numpy())
    return FitResult(params, err, emax)


def _fit_chunk(t: torch.Tensor, y: torch.Tensor, config: DMPConfig, ridge: float):
    # t: [1 or B, T], y: [B, T, d]
    rel = t - t[:, :1]
    tau = rel[:, -1]  # [1 or B]
    s = rel / tau[:, None]
    a, r = unit_responses(s, config)  # [1|B, T], [1|B, T, N]
    n_t = y.shape[1]
    y0, g = y[:, 0], y[:, -1]  # [B, d]
    resid = y - g[:, None] - (y0 - g)[:, None] * a[..., None]  # [B, T, d]
    scale = (g - y0) if config.scaling == "goal-start" else torch.ones_like(g)  # [B, d]
    gram = r.transpose(1, 2) @ r / n_t  # [1|B, N, N]
    rhs = r.transpose(1, 2) @ resid / n_t  # [B, N, d]
    n = config.n_kernels
    eye = torch.eye(n, dtype=y.dtype)
    lam = ridge * torch.diagonal(gram, dim1=1, dim2=2).mean(-1)  # [1|B]
    w = torch.empty_like(rhs)
    for j in range(y.shape[-1]):
        sj = scale[:, j]
        lhs = sj[:, None, None] ** 2 * gram + (lam[:, None, None] + 1e-300) * eye
        w[..., j] = torch.linalg.solve(lhs, sj[:, None] * rhs[..., j])
    fitted = g[:, None] + (y0 - g)[:, None] * a[..., None] + scale[:, None] * (r @ w)
    dist = torch.linalg.vector_norm(fitted - y, dim=-1)  # [B, T]
    tau_b = tau.expand(y.shape[0])
    return w, tau_b, g, y0, dist.mean(-1), dist.amax(-1)


def _as_real_tensor(name: str, a) -> torch.Tensor:
    """``a`` as a float64 tensor; refuse booleans, complex numbers, text and objects."""
    if not isinstance(a, torch.Tensor):
        try:
            a = np.asarray(a)
        except (TypeError, ValueError) as e:  # ragged nested lists
            raise ValueError(f"{name} must be an array of numbers: {e}") from None
        if a.dtype.kind not in "iuf":
            raise ValueError(f"{name} must hold real numbers, got an array of dtype {a.dtype}")
        a = torch.from_numpy(np.ascontiguousarray(a))  # a reversed view has negative strides
    elif a.is_complex() or a.dtype == torch.bool:
        raise ValueError(f"{name} must hold real numbers, got a tensor of dtype {a.dtype}")
    return a.to(torch.float64)


def _check_inputs(t, y, config: DMPConfig, ridge, chunk_size) -> tuple:
    """``(t, y, ridge)``: float64 tensors and a float, every argument of :func:`fit_dmp`
    checked."""
    if isinstance(ridge, (str, bytes)):
        raise ValueError(f"ridge must be a finite number >= 0, got {ridge!r}")
    ridge = check_positive("ridge", ridge, allow_zero=True)
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
        raise ValueError(f"chunk_size must be an integer >= 1, got {chunk_size!r}")
    y = _as_real_tensor("y", y)
    t = _as_real_tensor("t", t)
    if y.ndim < 2:
        raise ValueError(f"y must have shape [*batch, T, d], got {tuple(y.shape)}")
    if y.shape[-2] < 2:
        raise ValueError(
            f"a trajectory needs at least 2 points to fit a DMP, got {y.shape[-2]} (empty?)"
        )
    if y.shape[-2] > MAX_FIT_POINTS:  # about 2 KB a point: 3 million took 6.2 GB
        raise ValueError(
            f"a trajectory of {y.shape[-2]:,} points is more than the {MAX_FIT_POINTS:,} a "
            "fit takes; resample it (a DMP of 25 kernels needs a few hundred)"
        )
    if y.shape[-1] != config.n_dims:
        raise ValueError(
            f"y has d={y.shape[-1]} dimensions, the config expects {config.n_dims} (y is "
            f"[*batch, T, d]: {y.shape[-2]} points of {y.shape[-1]} coordinates here)"
        )
    if not bool(torch.isfinite(y).all()):
        idx = first_index(~torch.isfinite(y))
        raise ValueError(
            f"y contains NaN or inf: y[{', '.join(map(str, idx))}] is {float(y[idx])} "
            f"(point {idx[-2]}, coordinate {idx[-1]}{_of_demo(idx[:-2])})"
        )
    check_time_stamps(t)
    if t.shape[-1] != y.shape[-2]:
        raise ValueError(f"t has {t.shape[-1]} time stamps but y has {y.shape[-2]} points")
    batch = tuple(y.shape[:-2])
    if t.ndim > 1 and all(n == 1 for n in t.shape[:-1]):
        t = t.reshape(-1)  # [1, T] or [1, 1, T]: one set of stamps for every demonstration
    if t.ndim > 1 and tuple(t.shape[:-1]) != batch:
        raise ValueError(f"t has batch shape {tuple(t.shape[:-1])}, y has {batch}")
    return t, y, ridge


def _config_for(y) -> DMPConfig:
    """The paper's constants for the dimensions of demonstrations ``y [..., T, d]``:
    the default's d = 2 where the shape says nothing usable, or has no more points than
    dimensions (a path given as ``[d, T]``), which the checks then name."""
    try:
        shape = tuple(y.shape) if hasattr(y, "shape") else np.shape(y)
    except ValueError:  # ragged lists: refused by the checks
        return DMPConfig()
    if len(shape) < 2 or not 1 <= int(shape[-1]) < int(shape[-2]):
        return DMPConfig()
    return DMPConfig(n_dims=int(shape[-1]))


def _of_demo(batch_index: tuple) -> str:
    return f" of demonstration {list(batch_index)}" if batch_index else ""


def _check_fit(w, tau, y, shared: bool, batch: tuple) -> None:
    """Name the demonstration (and the input at fault) whose fit left float64's range."""
    ok_tau = torch.isfinite(tau)
    ok = torch.isfinite(w).flatten(1).all(1) & ok_tau
    if bool(ok.all()):
        return
    b = int(torch.nonzero(~ok)[0, 0])
    where = _of_demo(tuple(int(i) for i in np.unravel_index(b, batch)) if batch else ())
    if not bool(ok_tau[b]):
        which = "t" if shared else f"t{where}"
        raise ValueError(
            f"{which}: the duration t[-1] - t[0] overflows float64; give times in seconds"
        )
    big = float(y[b].abs().max())
    raise ValueError(
        f"y{where}: its magnitude (up to {big:.3g}) overflows float64 in the fit; "
        "scale the trajectory down (e.g. to pixels or metres)"
    )
