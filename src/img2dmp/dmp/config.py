"""Constants of a dynamic movement primitive (Section III of Pahič et al., ICRA 2018).

The transformation system (eq. 3-4) and canonical system (eq. 5) are

    tau * dz/dt = alpha_z * (beta_z * (g - y) - z) + S * F(x)
    tau * dy/dt = z
    tau * dx/dt = -alpha_x * x,          x(0) = 1

with ``S = diag(g - y0)`` (the paper's scaling, ``scaling="goal-start"``) or ``S = I``
(``scaling="none"``). Everything here is a plain value object: no arrays, no I/O.
"""

from __future__ import annotations

import math
import sys
from dataclasses import asdict, dataclass, field

from ..config import check_positive

SCALINGS = ("goal-start", "none")
#: Most kernels a DMP may have (the paper: 25). The rollout's response table, built once
#: per configuration, grows with the square of it (about 30 MB and a second to solve at
#: N = 100, 17 s at N = 300 on a 2-core machine).
MAX_KERNELS = 200
#: Largest gain alpha_z, beta_z or alpha_x (the paper's: 48, 12 and 2).
MAX_GAIN = 1e4
#: Most entries (grid steps x responses) of the rollout's response table: memory and
#: time grow with it (the default constants at MAX_KERNELS make 7.4 million, 0.25 GB of
#: cubic pieces); a slow phase (small alpha_x), a slowly settling transformation system
#: (small alpha_z or beta_z) or a very fast one (large alpha_z) lengthen the table.
MAX_TABLE_ENTRIES = 8_000_000
# Nodes per shortest time scale of the responses: cubic Hermite error ~1e-7 relative
# (~2e-6 px on a 40 px digit), below float32 resolution, with few pieces to combine.
NODES_PER_SCALE = 16
# The table ends where the phase and the free response have decayed below this.
TABLE_TAIL = 1e-10


def response_grid(n_kernels: int, alpha_z: float, beta: float, alpha_x: float):
    """``(h, s_max, steps)`` of the rollout's response table (:mod:`img2dmp.dmp._table`):
    its step in normalised time ``s = t / tau``, where it ends, and its number of grid
    points (a float: ``inf`` for constants whose table has no end in floating point)."""
    try:
        az, bz, ax = float(alpha_z), float(beta), float(alpha_x)
        scale = min(1.0 / (n_kernels - 1), 1.0 / math.sqrt(az * bz), 2.0 / az)
        h = scale / NODES_PER_SCALE
        # Slowest decay of the free response: the real part of the slower characteristic root.
        disc = az * az - 4 * az * bz
        slow = az / 2 - (math.sqrt(disc) / 2 if disc > 0 else 0.0)
        s_max = max(-math.log(TABLE_TAIL) / ax, (-math.log(TABLE_TAIL) + 5.0) / slow, 1.0)
        steps = math.ceil(s_max / h) + 1.0
    except (ZeroDivisionError, OverflowError, ValueError):
        return 0.0, math.inf, math.inf
    return h, s_max, steps


@dataclass(frozen=True)
class DMPConfig:
    """Constants shared by every DMP of a model or data set.

    Parameters
    ----------
    n_kernels : int
        Number N of Gaussian kernels per dimension (eq. 7); at least 2. Default 25.
    n_dims : int
        Number d of movement dimensions (2 for a pen path in the image plane).
    alpha_z : float
        Stiffness gain of the transformation system; default 48.
    beta_z : float or None
        Damping ratio term; ``None`` gives ``alpha_z / 4`` (critical damping).
    alpha_x : float
        Decay rate of the canonical system (eq. 5); default 2, so x(tau) = e^-2.
    width_factor : float
        Kernel widths ``h_k = width_factor / (c_{k+1} - c_k)**2`` (eq. 7); neighbouring
        kernels cross at ``exp(-width_factor / 4)``. Default 2.
    scaling : {"goal-start", "none"}
        ``"goal-start"`` multiplies the forcing term by ``diag(g - y0)`` as in the paper
        (the shape then scales with the movement, but the weights blow up when a
        dimension starts and ends at the same place, as for the digits 0 and 8);
        ``"none"`` applies F(x) unscaled, which stays well-posed for closed shapes.
    """

    n_kernels: int = 25
    n_dims: int = 2
    alpha_z: float = 48.0
    beta_z: float | None = None
    alpha_x: float = 2.0
    width_factor: float = 2.0
    scaling: str = "goal-start"
    _beta: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if (
            isinstance(self.n_kernels, bool)
            or not isinstance(self.n_kernels, int)
            or not 2 <= self.n_kernels <= MAX_KERNELS
        ):
            raise ValueError(
                f"n_kernels must be an integer from 2 to {MAX_KERNELS}, got {self.n_kernels!r} "
                "(the rollout's response table grows with its square: 300 kernels took 17 s "
                "to build)"
            )
        if isinstance(self.n_dims, bool) or not isinstance(self.n_dims, int) or self.n_dims < 1:
            raise ValueError(f"n_dims must be an integer >= 1, got {self.n_dims!r}")
        for name in ("alpha_z", "alpha_x", "beta_z"):
            value = getattr(self, name)
            if (value is not None or name != "beta_z") and check_positive(name, value) > MAX_GAIN:
                raise ValueError(f"{name} must be at most {MAX_GAIN:g}, got {value!r}")
        check_positive("width_factor", self.width_factor)
        beta = self.alpha_z / 4.0 if self.beta_z is None else self.beta_z  # > 0: checked
        if self.scaling not in SCALINGS:
            raise ValueError(f"scaling must be one of {SCALINGS}, got {self.scaling!r}")
        object.__setattr__(self, "_beta", float(beta))
        self._check_table()
        self._check_kernels()

    def _check_kernels(self) -> None:
        """The narrowest kernel's width ``h = width_factor / (c_{N-1} - c_{N-2})**2`` is a
        float64 number: a phase that decays too fast (alpha_x above about 360 at 25
        kernels) puts the last centres closer than float64 tells apart, and the
        widths, the fit and the rollout become inf and NaN."""
        n, ax = self.n_kernels, float(self.alpha_x)
        step = ax / (n - 1)
        log_gap = -ax * (n - 2) / (n - 1) + math.log(-math.expm1(-step))  # log(c_N-2 - c_N-1)
        if math.log(self.width_factor) - 2 * log_gap >= math.log(sys.float_info.max):
            raise ValueError(
                f"alpha_x={self.alpha_x:g} with {n} kernels puts the last kernels' centres "
                f"(exp(-alpha_x k / {n - 1})) closer together than float64 can tell apart: "
                f"their widths overflow; a {'smaller' if ax > 1 else 'larger'} alpha_x "
                "(the paper's is 2)"
            )

    def _check_table(self) -> None:
        """The rollout's response table of these constants fits :data:`MAX_TABLE_ENTRIES`."""
        _, _, steps = response_grid(self.n_kernels, self.alpha_z, self._beta, self.alpha_x)
        entries = steps * (self.n_kernels + 1)
        if entries > MAX_TABLE_ENTRIES:
            size = "no end" if math.isinf(steps) else (
                f"{steps:,.0f} steps" if steps < 1e12 else f"{steps:.1e} steps")  # fmt: skip
            raise ValueError(
                f"alpha_z={self.alpha_z:g}, beta_z={self._beta:g}, alpha_x={self.alpha_x:g} "
                f"with {self.n_kernels} kernels give the rollout's response table {size} x "
                f"{self.n_kernels + 1} responses (at most {MAX_TABLE_ENTRIES:,} entries): a "
                "phase (alpha_x) or a transformation system (alpha_z, beta_z) that settles "
                "too slowly, or alpha_z too large; the paper's are 48, 12 and 2"
            )

    @property
    def beta(self) -> float:
        """The effective ``beta_z`` (``alpha_z / 4`` unless set)."""
        return self._beta

    @property
    def n_params(self) -> int:
        """Length of the flat parameter vector: ``N*d + 1 + 2*d`` (55 for N=25, d=2)."""
        return self.n_kernels * self.n_dims + 1 + 2 * self.n_dims

    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("_beta")
        return d

    @classmethod
    def from_dict(cls, d: dict) -> DMPConfig:
        known = {k: d[k] for k in cls.__dataclass_fields__ if k in d and not k.startswith("_")}
        unknown = set(d) - set(known)
        if unknown:
            raise ValueError(f"unknown DMP config field(s): {sorted(unknown)}")
        return cls(**known)


#: The default constants, made once: frozen, so one instance serves every call made
#: without a config (building one costs a few microseconds, a noticeable part of a
#: one-DMP rollout).
DEFAULT_CONFIG = DMPConfig()


def as_config(config, default: DMPConfig | None = None) -> DMPConfig:
    """``config`` if it is a :class:`DMPConfig`, ``default`` (the paper's constants when
    None) for None; a ``TypeError`` naming what was given otherwise (a dict or the name
    of a scaling failed later, on an attribute)."""
    if config is None:
        return DMPConfig() if default is None else default
    if not isinstance(config, DMPConfig):
        raise TypeError(
            f"config must be a DMPConfig (img2dmp.DMPConfig(...); DMPConfig.from_dict for "
            f"a dict), got {type(config).__name__}"
        )
    return config
