"""img2dmp DMPs to and from MP_PyTorch's ``DMP`` and ``ProDMP`` (ALR, tested with 0.1.4).

Both integrate, in normalised time ``s = (t - delay) / tau``, with ``v = tau y'``::

    v' = alpha (beta (g - y) - v) + f(x),   x = exp(-alpha_phase s)
    f(x) = x sum_i w_i b_i(x) / sum_i b_i(x),   b_i = exp(-h_i (x - c_i)^2 / 2)

``beta = alpha / 4`` (the DMP class keeps it as an attribute; ProDMP's closed form is
built on that critical damping). That is img2dmp's system for ``alpha = alpha_z``,
``alpha_phase = alpha_x``, ``w = S w_img2dmp`` and ``h_i = 2 h_i(img2dmp)``: the centres
are evenly spaced in time as img2dmp's, and ``basis_bandwidth_factor = 2 width_factor``
gives img2dmp's widths except the last (MP_PyTorch takes the spacing to a centre beyond
the end, img2dmp its neighbour's width: 18 % narrower at N = 25), which the export sets
(``basis_gn.bandwidth``). ``DMP`` integrates with explicit Euler steps at the given time
stamps (first order); ``ProDMP`` tabulates its basis by the trapezoidal rule on a grid of
``scaled_dt`` and interpolates linearly (second order). The parameters map exactly unless
img2dmp's ``beta_z`` is not ``alpha_z / 4`` and a ProDMP is asked for: then ProDMP's own
least squares (``learn_mp_params_from_trajs``) fits it to img2dmp's rollout.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..dmp import DMPConfig, DMPParams, fit_dmp, kernel_centres, kernel_widths, rollout
from ..dmp.params import config_of
from ._common import (
    PeerExport,
    PeerImport,
    as_numpy_params,
    check_dims,
    check_steps,
    forcing_amplitudes,
    import_config,
    max_distance,
    remember,
    require,
    weights_from_amplitudes,
)

KINDS = ("prodmp", "dmp")
#: How far (in units of tau) a ProDMP's basis table reaches: times beyond ``2 tau`` are
#: refused by MP_PyTorch. Its cost grows with the square of the table's length.
PRODMP_HORIZON = 2


def _mp_pytorch():
    require("mp_pytorch.mp", "mp-pytorch")
    import mp_pytorch.basis_gn as basis_gn
    import mp_pytorch.mp as mp
    import mp_pytorch.phase_gn as phase_gn

    return mp, basis_gn, phase_gn


def _build(kind: str, config: DMPConfig, steps: int, dtype: torch.dtype):
    """An MP_PyTorch DMP or ProDMP configured to img2dmp's constants (tau learnable, so
    that every DMP of a batch has its own)."""
    mp, basis_gn, phase_gn = _mp_pytorch()
    phase = phase_gn.ExpDecayPhaseGenerator(
        tau=1.0, alpha_phase=config.alpha_x, learn_tau=True, dtype=dtype
    )
    common = dict(
        num_basis=config.n_kernels,
        basis_bandwidth_factor=2.0 * config.width_factor,
        num_basis_outside=0,
        dtype=dtype,
    )
    widths = torch.as_tensor(2.0 * kernel_widths(config), dtype=dtype)
    if kind == "dmp":
        basis = basis_gn.NormalizedRBFBasisGenerator(phase, **common)
        basis.bandwidth = widths
        prim = mp.DMP(basis, config.n_dims, alpha=config.alpha_z, dtype=dtype)
        prim.beta = config.beta
        return prim
    # A coarse table first (building it is O(steps^2)), then the real one, once, with
    # img2dmp's last width.
    basis = basis_gn.ProDMPBasisGenerator(
        phase, dt=0.1, alpha=config.alpha_z, pre_compute_length_factor=PRODMP_HORIZON, **common
    )
    basis.bandwidth = widths
    basis.scaled_dt = torch.as_tensor(1.0 / steps, dtype=dtype)
    basis.pre_compute()
    return mp.ProDMP(basis, config.n_dims, dtype=dtype)


def to_mp_pytorch(
    params: DMPParams,
    config: DMPConfig | None = None,
    *,
    kind: str = "prodmp",
    steps: int | None = None,
    dtype: torch.dtype = torch.float64,
    check: bool = True,
) -> PeerExport:
    """One MP_PyTorch ``ProDMP`` or ``DMP`` holding img2dmp's DMP or batch.

    The object holds the parameters ``[*batch, 1 + d (N + 1)]`` (``tau``, then per
    dimension its N forcing amplitudes ``S w`` and its goal), the initial conditions
    (time 0, ``y0``, velocity 0) and time stamps ``steps + 1`` per DMP over ``[0, tau]``,
    so ``export.dmp.get_traj_pos()`` rolls it out.

    Parameters
    ----------
    params : DMPParams
        One DMP or a batch (NumPy or torch).
    config : DMPConfig
        img2dmp's constants; default: the ones
        ``params`` carries (a different one is refused), else ``DMPConfig()``.
    kind : {"prodmp", "dmp"}
        ``"prodmp"``: the closed-form ProDMP (differentiable, second-order basis table);
        ``"dmp"``: the Euler-integrated DMP.
    steps : int or None
        Time steps per tau: of the Euler integration (``"dmp"``, default 2000) or of
        ProDMP's basis table (default 500; building it costs O(steps^2), about 1 s at
        1000). Also the number of time stamps set on the object.
    dtype : torch dtype
        Of the peer's tensors; default float64 (MP_PyTorch's default is float32).
    check : bool
        Roll the object out (``get_traj_pos``) and return its largest distance from
        img2dmp's rollout per DMP (``error_px``).

    Returns
    -------
    PeerExport
        ``exact`` is False only for a ProDMP of a DMP whose ``beta_z`` is not
        ``alpha_z / 4``.
    """
    config = config_of(params, config)
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    steps = check_steps(steps, kind)
    p = as_numpy_params(params, config)
    batch = p.batch_shape
    if 0 in batch:  # MP_PyTorch holds a batch in one primitive: an empty one is none
        raise ValueError(f"params holds no DMP (batch shape {list(batch)}); give at least one")
    prim = _build(kind, config, steps, dtype)
    remember(prim, config)
    s = np.linspace(0.0, 1.0, steps + 1)
    times = p.tau[..., None] * s  # [*batch, T]
    tt = lambda a: torch.as_tensor(a, dtype=dtype)  # noqa: E731
    zeros = tt(np.zeros(batch))
    exact = kind == "dmp" or math.isclose(config.beta, config.alpha_z / 4, rel_tol=1e-12)
    amp = np.swapaxes(forcing_amplitudes(p, config), -1, -2)  # [*batch, d, N]
    wg = np.concatenate([amp, p.g[..., None]], axis=-1).reshape(*batch, -1)
    # tau first: MP_PyTorch reads a learnable tau once (later set_params keep it), and
    # ProDMP's set_times maps times to its table with it.
    prim.set_params(tt(np.concatenate([p.tau[..., None], wg], axis=-1)))
    if not exact:  # ProDMP cannot hold img2dmp's damping: its least squares on our path
        ours = rollout(p.to_torch(torch.float64), torch.as_tensor(times), config).numpy()
        prim.learn_mp_params_from_trajs(
            tt(times), tt(ours), init_time=zeros, init_pos=tt(p.y0), init_vel=tt(0 * p.y0)
        )
    prim.set_times(tt(times))
    prim.set_initial_conditions(zeros, tt(p.y0), tt(np.zeros_like(p.y0)))
    out = PeerExport(dmp=prim, batch_shape=batch, exact=exact)
    if check:
        y = prim.get_traj_pos().detach().to(torch.float64).numpy()
        out.times, out.error_px = times, max_distance(p, times, y, config)
    return out


def _numpy(a) -> np.ndarray:
    return torch.as_tensor(a).detach().to("cpu", torch.float64).numpy()


def _matches(prim, config: DMPConfig) -> bool:
    """True when ``prim``'s ODE is img2dmp's for ``config`` (then the import is exact)."""
    mp, _, phase_gn = _mp_pytorch()
    phase, basis = prim.phase_gn, prim.basis_gn
    rtol = 1e-9 if prim.dtype == torch.float64 else 1e-5
    close = lambda a, b: np.allclose(_numpy(a), b, rtol=rtol, atol=0)  # noqa: E731
    if not isinstance(phase, phase_gn.ExpDecayPhaseGenerator):
        return False
    if prim.num_basis != config.n_kernels or prim.num_dof != config.n_dims:
        return False
    if getattr(basis, "num_basis_outside", 0) != 0 or np.any(_numpy(phase.delay)):
        return False
    if isinstance(prim, mp.ProDMP):
        beta = prim.basis_gn.alpha / 4.0
        if prim.relative_goal or prim.auto_scale_basis or prim.disable_weights:
            return False
        if prim.disable_goal:
            return False
        alpha = prim.basis_gn.alpha
    else:
        alpha, beta = prim.alpha, prim.beta
    return (
        close(phase.alpha_phase, config.alpha_x)
        and close(alpha, config.alpha_z)
        and close(beta, config.beta)
        and close(basis.centers_p, kernel_centres(config))
        and close(basis.bandwidth, 2.0 * kernel_widths(config))
        and close(prim.weights_goal_scale, 1.0)
        and not np.any(_numpy(prim.init_time))
        and not np.any(_numpy(prim.init_vel))
    )


def from_mp_pytorch(prim, config: DMPConfig | None = None, *, check: bool = True) -> PeerImport:
    """img2dmp parameters of an MP_PyTorch ``DMP`` or ``ProDMP`` (one DMP or a batch).

    The object must hold parameters (``set_params``) and initial conditions. Exact (read
    off, ``w = amplitudes / S``) when its configuration is img2dmp's, as an export's is;
    otherwise img2dmp's DMP is fitted by :func:`img2dmp.dmp.fit_dmp` to the object's
    rollout at its time stamps (which must then be set), and ``error_px`` says how close
    it came.

    Parameters
    ----------
    prim : mp_pytorch.mp.DMP or mp_pytorch.mp.ProDMP
    config : DMPConfig
        img2dmp's constants for the result (which carries them); default ``DMPConfig()``.
    check : bool
        Compare img2dmp's rollout with the object's at its time stamps (``error_px``;
        skipped when it has none; a re-fit always measures it).

    Returns
    -------
    PeerImport
        Batch shape: the object's ``add_dim``.
    """
    mp, _, _ = _mp_pytorch()
    if not isinstance(prim, (mp.DMP, mp.ProDMP)):
        raise ValueError(f"expected an mp_pytorch DMP or ProDMP, got {type(prim).__name__}")
    config = import_config([prim], config)
    check_dims("prim", prim.num_dof, config)
    if prim.params is None or prim.init_pos is None:
        raise ValueError(
            "the MP_PyTorch object holds no parameters or initial conditions yet: call "
            "set_params and set_initial_conditions first"
        )
    batch, d, n = tuple(prim.add_dim), config.n_dims, config.n_kernels
    exact = _matches(prim, config)
    params = None
    if exact:
        wg = _numpy(prim.params).reshape(*batch, d, n + 1)
        g, y0 = wg[..., -1], _numpy(prim.init_pos)
        w = weights_from_amplitudes(np.swapaxes(wg[..., :-1], -1, -2), g, y0, config)
        if w is None:
            exact = False
        else:
            tau = np.broadcast_to(_numpy(prim.phase_gn.tau), batch).copy()
            params = DMPParams(w, tau, g, y0)
    has_times = prim.times is not None
    if not exact and not has_times:
        raise ValueError(
            "this MP_PyTorch object is not configured as img2dmp's DMP, so it is imported "
            "by fitting its rollout: set its time stamps first (set_times)"
        )
    times = y = None
    if has_times and (check or not exact):
        times, y = _rollout_with_start(prim, batch)
    if not exact:
        params = fit_dmp(times, y, config).params
        times = times - times[..., :1]
    out = PeerImport(params=params.with_config(config), exact=np.full(batch, exact))
    if times is not None:
        out.times, out.error_px = times, max_distance(params, times, y, config)
    return out


def _rollout_with_start(prim, batch: tuple) -> tuple[np.ndarray, np.ndarray]:
    """The object's time stamps ``[*batch, T]`` and positions ``[*batch, T, d]``, with
    its initial condition in front when its times start one step after it."""
    y = _numpy(prim.get_traj_pos())
    t = np.broadcast_to(_numpy(prim.times), (*batch, y.shape[-2])).copy()
    t0 = np.broadcast_to(_numpy(prim.init_time), batch)
    if not np.allclose(t[..., 0], t0):
        t = np.concatenate([t0[..., None], t], axis=-1)
        y = np.concatenate([_numpy(prim.init_pos)[..., None, :], y], axis=-2)
    return t, y
