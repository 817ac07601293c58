"""Step-by-step reference integrator of one DMP, in float64 NumPy.

Made for a controller that advances the movement at its own rate (``step(dt)`` at 240 Hz
or 1 kHz) and for tests. It is independent of :func:`img2dmp.dmp.rollout` (no response
table), so the two check each other.

With tau fixed, the transformation system (eqs. 3-4) is linear with constant
coefficients in the normalised time ``s = t / tau``. With ``e = y - g`` and ``z = de/ds``
(the scaled velocity, ``tau dy/dt``) the state ``u = (e, z)`` obeys::

    u' = A u + b(s),   A = [[0, 1], [-alpha_z beta_z, -alpha_z]],   b = (0, S F(x(s)))

so a step of any length ``D`` from ``s0`` is, exactly (variation of constants),

    u(s0 + D) = Phi(D) u(s0) + int_{s0}^{s0 + D} Phi(s0 + D - r) b(r) dr,   Phi = exp(A D).

``Phi`` is the 2 x 2 matrix exponential in closed form, so the stiff part (time constant
``tau / 24`` with the defaults) is solved exactly: no step is too long for any tau, and
nothing can diverge. The integral is taken by 5-point Gauss-Legendre quadrature on pieces
of at most 1/4 of the system's shortest time scale in ``s`` (the one the rollout's table
is built on): ~1e-12 px from scipy's DOP853 at rtol 1e-13 on a 30 px movement. ``F``
carries the factor ``x = exp(-alpha_x s)``: once ``x < 1e-16`` (``s > 18.4`` with
``alpha_x = 2``) it is below float64 rounding of the position and no quadrature is done,
so one step takes at most ~1800 pieces with the default constants, whatever ``tau``
and however long the step (a step within the forced part takes at least one). A step
that would take more than ``MAX_PIECES_PER_STEP`` (only a tiny ``max_step`` or absurd
constants get there) is refused with a ``ValueError`` before any work. The phase is
evaluated in closed form, ``x(t) = exp(-alpha_x t / tau)``.
"""

from __future__ import annotations

import math

import numpy as np

from .basis import forcing_term, kernel_centres, kernel_widths
from .config import DMPConfig
from .params import DMPParams, config_of

# Gauss-Legendre nodes per quadrature piece: exact for polynomials of degree 9.
_GAUSS = np.polynomial.legendre.leggauss(5)
# Quadrature pieces per shortest time scale of the system (in s = t / tau).
_PIECES_PER_SCALE = 4
# Below this phase the forcing term is under float64 rounding of the position.
_X_NEGLIGIBLE = 1e-16
# One step(dt) may take at most this many quadrature pieces (about 2 s of work); only a
# tiny max_step (or absurd DMP constants) comes near it.
MAX_PIECES_PER_STEP = 200_000
# Kernel values per NumPy call (bounds the [nodes, N] temporaries to a few MB).
_CHUNK_ELEMENTS = 1 << 17


def _real(name: str, value) -> float:
    """``value`` as a float; ``ValueError`` naming ``name`` unless a finite real number
    (a Python or NumPy number, or a 0-d array or tensor)."""
    if isinstance(value, (bool, np.bool_, str, bytes)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


class _Propagator:
    """``Phi(t) = exp(A t)`` of the homogeneous system, for arrays of ``t >= 0``.

    ``Phi = [[p - mu q, q], [-k q, p + mu q]]`` with ``mu = -alpha_z / 2``,
    ``k = alpha_z beta_z``, ``p = e^{mu t} C(t)`` and ``q = e^{mu t} S(t)``, where
    ``(C, S) = (cosh dt, sinh(dt) / d)``, ``(cos wt, sin(wt) / w)`` or ``(1, t)`` for
    ``d^2 = mu^2 - k`` positive (over-damped), negative or zero (critically damped).
    """

    def __init__(self, config: DMPConfig):
        self.k = config.alpha_z * config.beta
        self.mu = -config.alpha_z / 2.0
        self.d2 = self.mu * self.mu - self.k

    def pq(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=np.float64)
        mu, d2 = self.mu, self.d2
        if d2 == 0.0:
            e = np.exp(mu * t)
            return e, t * e
        if d2 < 0.0:
            w = math.sqrt(-d2)
            e = np.exp(mu * t)
            return e * np.cos(w * t), e * np.sin(w * t) / w
        d = math.sqrt(d2)  # 0 < d < -mu: both roots mu +- d are negative
        short = d * t <= 1.0
        ts = np.where(short, t, 0.0)  # cosh and sinh stay small here
        e = np.exp(mu * ts)
        p_short, q_short = e * np.cosh(d * ts), e * np.sinh(d * ts) / d
        tl = np.where(short, 1.0 / d, t)  # no cancellation when d t > 1
        e1, e2 = np.exp((mu + d) * tl), np.exp((mu - d) * tl)
        p_long, q_long = (e1 + e2) / 2.0, (e1 - e2) / (2.0 * d)
        return np.where(short, p_short, p_long), np.where(short, q_short, q_long)

    def apply(self, t: float, e: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``Phi(t) (e, z)``."""
        p, q = (float(v) for v in self.pq(np.array(t)))
        return (p - self.mu * q) * e + q * z, -self.k * q * e + (p + self.mu * q) * z


class DMPIntegrator:
    """Integrate one DMP forward in time, one ``step(dt)`` at a time (module docstring).

    Parameters
    ----------
    params : DMPParams
        One DMP (no batch dimensions): ``w [N, d]``, scalar ``tau``, ``g [d]``, ``y0 [d]``.
    config : DMPConfig
        DMP constants; default: the ones ``params`` carries (a different one is
        refused), else ``DMPConfig()``.
    max_step : float or None
        Longest quadrature piece in seconds, on top of the automatic one (a fraction of
        the system's shortest time scale, ``tau / 96`` with the default constants); a
        smaller value only makes the quadrature finer. None (default): automatic.

    Attributes
    ----------
    t : float
        Time since the start, seconds.
    y : ndarray [d]
        Position. ``z`` is the scaled velocity (``dy/dt = z / tau``).
    g : ndarray [d]
        Goal; may be changed while running (the movement then adapts smoothly).
    """

    def __init__(
        self, params: DMPParams, config: DMPConfig | None = None, *, max_step: float | None = None
    ):
        if not isinstance(params, DMPParams):
            raise ValueError(f"params must be a DMPParams, got {type(params).__name__}")
        self.config = config_of(params, config)
        p = params.to_numpy()
        if p.batch_shape != ():
            raise ValueError(
                f"DMPIntegrator runs one DMP; got parameters with batch shape {p.batch_shape}"
            )
        p.validate(self.config)
        if max_step is not None and not _real("max_step", max_step) > 0:
            raise ValueError(f"max_step must be > 0 seconds (or None), got {max_step!r}")
        self.w = np.asarray(p.w, dtype=np.float64)
        self.tau = float(p.tau)
        self.g = np.asarray(p.g, dtype=np.float64).copy()
        self.y0 = np.asarray(p.y0, dtype=np.float64).copy()
        self.max_step = None if max_step is None else float(max_step)
        cfg = self.config
        self._c = kernel_centres(cfg)
        self._h = kernel_widths(cfg)
        self._phi = _Propagator(cfg)
        scale = min(1.0 / (cfg.n_kernels - 1), 1.0 / math.sqrt(self._phi.k), 2.0 / cfg.alpha_z)
        piece = scale / _PIECES_PER_SCALE
        if self.max_step is not None:
            piece = min(piece, self.max_step / self.tau)
        self._piece_s = piece  # longest quadrature piece, in s = t / tau
        self._s_forced = -math.log(_X_NEGLIGIBLE) / cfg.alpha_x  # F is negligible beyond
        self.reset()

    def reset(self) -> None:
        """Back to the start: ``t = 0``, ``y = y0``, ``z = 0``."""
        self.t = 0.0
        self.y = self.y0.copy()
        self.z = np.zeros_like(self.y0)

    @property
    def x(self) -> float:
        """Phase at the current time (eq. 5)."""
        return math.exp(-self.config.alpha_x * self.t / self.tau)

    @property
    def velocity(self) -> np.ndarray:
        """``dy/dt`` in units per second."""
        return self.z / self.tau

    def _pieces(self, s0: float, s1: float) -> int:
        """Quadrature pieces of the forced part of ``[s0, s1]``; ``ValueError`` if too many."""
        end = min(s1, self._s_forced)
        if end <= s0:
            return 0
        n = math.ceil((end - s0) / self._piece_s * (1.0 - 1e-12))
        if n > MAX_PIECES_PER_STEP:
            raise ValueError(
                f"DMPIntegrator.step: {n} quadrature pieces needed (at most "
                f"{MAX_PIECES_PER_STEP}) for {(end - s0) * self.tau:.3g} s of forcing with "
                f"max_step = {self.max_step!r} s, tau = {self.tau:.3g} s and alpha_z = "
                f"{self.config.alpha_z:g}: use a larger max_step (or None)"
            )
        return max(n, 1)

    def _forced(self, s0: float, s1: float) -> tuple[np.ndarray, np.ndarray]:
        """``int_{s0}^{s1} Phi(s1 - r) (0, F(x(r))) dr`` as ``(e, z)`` parts ``[d]`` each."""
        d = self.y0.shape[0]
        n = self._pieces(s0, s1)
        fe, fz = np.zeros(d), np.zeros(d)
        if n == 0:
            return fe, fz
        end = min(s1, self._s_forced)
        h = (end - s0) / n
        nodes, weights = _GAUSS
        per = len(nodes)
        chunk = max(1, _CHUNK_ELEMENTS // (per * self.config.n_kernels))  # pieces per call
        for lo in range(0, n, chunk):
            k = np.arange(lo, min(n, lo + chunk), dtype=np.float64)
            r = (s0 + h * (k[:, None] + (nodes + 1.0) / 2.0)).ravel()  # [M] in s
            wq = np.tile(weights * (h / 2.0), k.size)  # [M]
            x = np.exp(-self.config.alpha_x * r)
            f = forcing_term(x, self.w, self._c, self._h)  # [M, d]
            p, q = self._phi.pq(s1 - r)
            fe += (wq * q) @ f
            fz += (wq * (p + self._phi.mu * q)) @ f
        return fe, fz

    def step(self, dt: float) -> np.ndarray:
        """Advance by ``dt`` seconds (exactly, up to the quadrature of the forcing term).

        Any ``dt > 0`` is stable and costs at most a bounded amount of work (see the
        module docstring). Returns the new position (a copy).
        """
        dt = _real("dt", dt)
        if not dt > 0:
            raise ValueError(f"dt must be a finite number > 0, got {dt!r}")
        g = np.asarray(self.g, dtype=np.float64)
        if g.shape != self.y0.shape or not np.isfinite(g).all():
            raise ValueError(f"DMPIntegrator.g must be {self.y0.size} finite numbers, got {g}")
        self.g = g
        s0, s1 = self.t / self.tau, (self.t + dt) / self.tau
        scale = (g - self.y0) if self.config.scaling == "goal-start" else 1.0
        e, z = self._phi.apply(s1 - s0, self.y - g, self.z)
        fe, fz = self._forced(s0, s1)
        self.y = g + e + scale * fe
        self.z = z + scale * fz
        self.t += dt
        return self.y.copy()

    def run(self, t: np.ndarray) -> np.ndarray:
        """Reset, then return positions ``[T, d]`` at the increasing time stamps ``t >= 0``."""
        t = np.asarray(t, dtype=np.float64)
        if t.ndim != 1 or t.size == 0:
            raise ValueError(f"t must be a non-empty 1-D array, got shape {t.shape}")
        if not np.isfinite(t).all() or (t < 0).any() or (np.diff(t) <= 0).any():
            raise ValueError("t must be finite, >= 0 and strictly increasing")
        self.reset()
        out = np.empty((t.size, self.y.size))
        for i, ti in enumerate(t):
            if ti > self.t:
                self.step(ti - self.t)
            out[i] = self.y
        return out


def integrate(
    params: DMPParams, t, config: DMPConfig | None = None, *, max_step: float | None = None
) -> np.ndarray:
    """Positions ``[T, d]`` of one DMP at time stamps ``t`` by :class:`DMPIntegrator`."""
    return DMPIntegrator(params, config, max_step=max_step).run(t)
