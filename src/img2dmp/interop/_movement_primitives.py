"""img2dmp DMPs to and from ``movement_primitives.dmp.DMP`` (DFKI, tested with 0.9.1).

movement_primitives integrates (Ijspeert et al. 2013, eq. 2.1)::

    tau^2 y'' = alpha_y (beta_y (g - y) - tau y') + f(z),   z(t) = exp(-a t / tau)
    f(z) = z sum_i w_i psi_i(z) / sum_i psi_i(z),  psi_i = exp(-h_i (z - c_i)^2)

which is img2dmp's system (``tau z' = alpha_z (beta_z (g - y) - z) + S F(x)`` with
``z = tau y'``) for ``alpha_y = alpha_z``, ``beta_y = beta_z``, ``a = alpha_x`` and
``w = S w_img2dmp`` (it never scales by ``g - y0``). Its centres are evenly spaced in
time, as img2dmp's, and its widths ``h_i = -ln(overlap) / (c_{i+1} - c_i)^2`` (the last
one its neighbour's) are img2dmp's for ``overlap = exp(-width_factor)``. Its own DMP
class fixes ``a = -ln 0.01`` and ``overlap = 0.8``; the export therefore uses a subclass
(:class:`PhaseMatchedDMP`) whose forcing term keeps img2dmp's phase and widths, also
when ``execution_time_`` is changed. The parameters map exactly; what differs is the
integration (docs/INTEROP.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..config import check_positive
from ..dmp import DMPConfig, DMPParams, fit_dmp
from ..dmp.params import config_of
from ._common import (
    DEFAULT_STEPS,
    PeerExport,
    PeerImport,
    as_numpy_params,
    check_dims,
    check_dt,
    forcing_amplitudes,
    import_config,
    max_distance,
    remember,
    require,
    weights_from_amplitudes,
)

try:  # the optional peer (extra "interop"); without it the functions raise ImportError
    from movement_primitives.dmp import DMP as _DMP
    from movement_primitives.dmp._forcing_term import ForcingTerm as _ForcingTerm
except ImportError:  # pragma: no cover - exercised only without the extra
    _DMP = _ForcingTerm = None


if _DMP is not None:

    class PhaseMatchedDMP(_DMP):
        """A ``movement_primitives.dmp.DMP`` with a chosen phase decay and kernel overlap.

        Parameters
        ----------
        n_dims : int
        phase_decay : float
            ``a`` of the phase ``z(t) = exp(-a t / tau)`` (img2dmp's ``alpha_x``).
        overlap : float
            Value of a kernel at its neighbour's centre (``exp(-width_factor)``).
        **kwargs
            Passed on to ``movement_primitives.dmp.DMP``.
        """

        def __init__(self, n_dims, *, phase_decay: float, overlap: float, **kwargs):
            self.phase_decay = float(phase_decay)
            self.overlap = float(overlap)
            super().__init__(n_dims, **kwargs)

        def _init_forcing_term(self):
            # Called by DMP.__init__ and whenever execution_time_ is set.
            self.forcing_term = _ForcingTerm(
                self.n_dims,
                self.n_weights_per_dim,
                self.execution_time_,
                0.0,
                self.overlap,
                self.phase_decay,
            )

else:  # pragma: no cover
    PhaseMatchedDMP = None


def _peer():
    require("movement_primitives.dmp", "movement-primitives")
    return _DMP


def to_movement_primitives(
    params: DMPParams,
    config: DMPConfig | None = None,
    *,
    dt: float | None = None,
    check: bool = True,
) -> PeerExport:
    """movement_primitives DMP(s) with the same ODE as img2dmp's DMP(s).

    Parameters
    ----------
    params : DMPParams
        One DMP or a batch (NumPy or torch).
    config : DMPConfig
        img2dmp's constants; default: the ones
        ``params`` carries (a different one is refused), else ``DMPConfig()``.
    dt : float or None
        The peer's step (``dt_``, seconds); default ``tau / 4000`` per DMP. Its RK4 step
        evaluates the forcing term one step late (movement_primitives 0.9.1), so its
        error is first order in ``dt``: at most 0.92 px at ``tau / 100``, 0.046 px at
        ``tau / 2000`` and 0.023 px at ``tau / 4000`` on the ten digits of the 28-px
        frame (docs/INTEROP.md).
    check : bool
        Roll each exported DMP out with the peer's ``open_loop()`` and return its largest
        distance from img2dmp's rollout (``error_px``).

    Returns
    -------
    PeerExport
        ``dmp``: one :class:`PhaseMatchedDMP` (a ``movement_primitives.dmp.DMP``) for one
        DMP, else a list of them in C order of the batch; ``exact`` is True.
    """
    _peer()
    config = config_of(params, config)
    p = as_numpy_params(params, config)
    batch = p.batch_shape
    if dt is not None:
        dt = check_dt(dt)
    steps = DEFAULT_STEPS["movement_primitives"]
    n, d = config.n_kernels, config.n_dims
    flat = DMPParams(
        p.w.reshape(-1, n, d), p.tau.reshape(-1), p.g.reshape(-1, d), p.y0.reshape(-1, d)
    )
    amp = forcing_amplitudes(flat, config)  # [B, N, d]
    dmps, times, errors = [], [], []
    for i in range(flat.tau.shape[0]):
        tau = float(flat.tau[i])
        dmp = PhaseMatchedDMP(
            d,
            phase_decay=config.alpha_x,
            overlap=math.exp(-config.width_factor),
            execution_time=tau,
            dt=tau / steps if dt is None else check_dt(dt, tau),
            n_weights_per_dim=n,
            alpha_y=config.alpha_z,
            beta_y=config.beta,
        )
        dmp.forcing_term.weights_[:, :] = amp[i].T
        dmp.configure(start_y=flat.y0[i].copy(), goal_y=flat.g[i].copy())
        remember(dmp, config)
        dmps.append(dmp)
        if check:
            t, y = dmp.open_loop()
            errors.append(float(max_distance(flat[i], t, y, config)))
            times.append(t)
    out = PeerExport(dmp=dmps[0] if not batch else dmps, batch_shape=batch, exact=True)
    if check:
        out.error_px = np.asarray(errors).reshape(batch)
        out.times = times[0] if not batch else _stack(times, batch)
    return out


def _stack(times: list, batch: tuple):
    """Time stamps of several DMPs: one array when they have one length, else a list."""
    if len({len(t) for t in times}) == 1:
        return np.stack(times).reshape(*batch, -1)
    return times


def _matches(dmp, config: DMPConfig) -> bool:
    """True when ``dmp``'s ODE is img2dmp's for ``config`` (then the import is exact)."""
    ft = dmp.forcing_term
    overlap = math.exp(-ft.log_overlap)
    return (
        type(dmp) in (_DMP, PhaseMatchedDMP)
        and dmp.n_dims == config.n_dims
        and dmp.n_weights_per_dim == config.n_kernels
        and not dmp.smooth_scaling
        and float(dmp.p_gain) == 0.0
        and np.allclose(dmp.alpha_y, config.alpha_z, rtol=1e-12, atol=0)
        and np.allclose(dmp.beta_y, config.beta, rtol=1e-12, atol=0)
        and math.isclose(ft.alpha_z, config.alpha_x, rel_tol=1e-12)
        and math.isclose(overlap, math.exp(-config.width_factor), rel_tol=1e-9)
        and not np.any(dmp.start_yd)
        and not np.any(dmp.goal_yd)
        and not np.any(dmp.goal_ydd)
    )


def from_movement_primitives(
    dmps, config: DMPConfig | None = None, *, check: bool = True
) -> PeerImport:
    """img2dmp parameters of movement_primitives DMP(s).

    Exact (read off, ``w = weights / S``) when a DMP's configuration is img2dmp's (as an
    export's is); otherwise img2dmp's DMP is fitted by :func:`img2dmp.dmp.fit_dmp` to the
    peer's ``open_loop()`` rollout, and ``error_px`` says how close it came.

    Parameters
    ----------
    dmps : movement_primitives.dmp.DMP or sequence of them
        A sequence gives a batch of that length.
    config : DMPConfig
        img2dmp's constants for the result (which carries them); default ``DMPConfig()``.
    check : bool
        Compare img2dmp's rollout with the peer's at the peer's time stamps
        (``error_px``; a re-fit always measures it).

    Returns
    -------
    PeerImport
    """
    peer = _peer()
    one = isinstance(dmps, peer)
    items = [dmps] if one else list(dmps) if isinstance(dmps, Sequence) else None
    if not items or not all(isinstance(d, peer) for d in items):
        raise ValueError(
            "expected a movement_primitives.dmp.DMP or a non-empty sequence of them, "
            f"got {type(dmps).__name__}"
        )
    config = import_config(items, config)
    for k, dmp in enumerate(items):
        check_dims("dmps" if one else f"dmps[{k}]", dmp.n_dims, config)
    parts, exact, times, errors = [], [], [], []
    for k, dmp in enumerate(items):
        p, ok = _read(dmp, config)
        t = y = None
        if not ok or check:  # the peer integrates in steps of its dt_: bounded first
            tau = check_positive(f"dmps[{k}].execution_time_", float(dmp.execution_time_))
            check_dt(float(dmp.dt_), tau, f"dmps[{k}].dt_")
            t, y = dmp.open_loop()
        if not ok:
            p = fit_dmp(t, y, config).params
        parts.append(p)
        exact.append(ok)
        if t is not None and (check or not ok):
            times.append(t)
            errors.append(float(max_distance(p, t, y, config)))
    stack = lambda name: np.stack([getattr(q, name) for q in parts])  # noqa: E731
    params = DMPParams(stack("w"), stack("tau"), stack("g"), stack("y0"))
    if one:
        params = params[0]
    out = PeerImport(
        params=params.with_config(config), exact=np.asarray(exact[0] if one else exact)
    )
    if len(errors) == len(items):
        out.error_px = np.asarray(errors[0] if one else errors)
        out.times = times[0] if one else _stack(times, (len(items),))
    return out


def _read(dmp, config: DMPConfig) -> tuple[DMPParams, bool]:
    """The parameters read off ``dmp`` and whether that reading is exact."""
    tau = float(dmp.execution_time_)
    g = np.asarray(dmp.goal_y, np.float64).copy()
    y0 = np.asarray(dmp.start_y, np.float64).copy()
    if not _matches(dmp, config):
        return None, False
    w = weights_from_amplitudes(np.asarray(dmp.forcing_term.weights_, np.float64).T, g, y0, config)
    if w is None:  # goal-start scaling with g = y0 in a dimension: not determined
        return None, False
    return DMPParams(w, np.float64(tau), g, y0), True
