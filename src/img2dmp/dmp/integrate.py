"""Step-by-step reference integrator of one DMP, in float64 NumPy.

Made for a controller that advances the movement at its own rate (``step(dt)`` at 240 Hz
or 1 kHz) and for tests. The transformation system (eqs. 3-4) is advanced with the
classical fourth-order Runge-Kutta method; the phase of eq. (5) is evaluated in closed
form, ``x(t) = exp(-alpha_x t / tau)``, so it carries no integration error.
"""

from __future__ import annotations

import math

import numpy as np

from .basis import forcing_term, kernel_centres, kernel_widths
from .config import DMPConfig
from .params import DMPParams


class DMPIntegrator:
    """Integrate one DMP forward in time, one ``step(dt)`` at a time.

    Parameters
    ----------
    params : DMPParams
        One DMP (no batch dimensions): ``w [N, d]``, scalar ``tau``, ``g [d]``, ``y0 [d]``.
    config : DMPConfig
        DMP constants.
    max_step : float
        Longest internal Runge-Kutta step in seconds; a longer ``step(dt)`` is split.

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
        self, params: DMPParams, config: DMPConfig | None = None, *, max_step: float = 1e-3
    ):
        self.config = config or DMPConfig()
        p = params.to_numpy()
        if p.batch_shape != ():
            raise ValueError(
                f"DMPIntegrator runs one DMP; got parameters with batch shape {p.batch_shape}"
            )
        p.validate(self.config)
        if not (math.isfinite(max_step) and max_step > 0):
            raise ValueError(f"max_step must be > 0, got {max_step!r}")
        self.w = np.asarray(p.w, dtype=np.float64)
        self.tau = float(p.tau)
        self.g = np.asarray(p.g, dtype=np.float64).copy()
        self.y0 = np.asarray(p.y0, dtype=np.float64).copy()
        self.max_step = float(max_step)
        self._c = kernel_centres(self.config)
        self._h = kernel_widths(self.config)
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

    def _deriv(self, t: float, y: np.ndarray, z: np.ndarray):
        cfg = self.config
        x = math.exp(-cfg.alpha_x * t / self.tau)
        f = forcing_term(np.array(x), self.w, self._c, self._h)
        scale = (self.g - self.y0) if cfg.scaling == "goal-start" else 1.0
        dz = (cfg.alpha_z * (cfg.beta * (self.g - y) - z) + scale * f) / self.tau
        return z / self.tau, dz

    def step(self, dt: float) -> np.ndarray:
        """Advance by ``dt`` seconds (RK4, split into steps of at most ``max_step``).

        Returns the new position (a copy).
        """
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a finite number > 0, got {dt!r}")
        n = max(1, math.ceil(dt / self.max_step - 1e-9))
        h = dt / n
        for _ in range(n):
            t, y, z = self.t, self.y, self.z
            k1y, k1z = self._deriv(t, y, z)
            k2y, k2z = self._deriv(t + h / 2, y + h / 2 * k1y, z + h / 2 * k1z)
            k3y, k3z = self._deriv(t + h / 2, y + h / 2 * k2y, z + h / 2 * k2z)
            k4y, k4z = self._deriv(t + h, y + h * k3y, z + h * k3z)
            self.y = y + h / 6 * (k1y + 2 * k2y + 2 * k3y + k4y)
            self.z = z + h / 6 * (k1z + 2 * k2z + 2 * k3z + k4z)
            self.t = t + h
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
    params: DMPParams, t, config: DMPConfig | None = None, *, max_step: float = 1e-3
) -> np.ndarray:
    """Positions ``[T, d]`` of one DMP at time stamps ``t`` by :class:`DMPIntegrator`."""
    return DMPIntegrator(params, config, max_step=max_step).run(t)
