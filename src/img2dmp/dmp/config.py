"""Constants of a dynamic movement primitive (Section III of Pahič et al., ICRA 2018).

The transformation system (eq. 3-4) and canonical system (eq. 5) are

    tau * dz/dt = alpha_z * (beta_z * (g - y) - z) + S * F(x)
    tau * dy/dt = z
    tau * dx/dt = -alpha_x * x,          x(0) = 1

with ``S = diag(g - y0)`` (the paper's scaling, ``scaling="goal-start"``) or ``S = I``
(``scaling="none"``). Everything here is a plain value object: no arrays, no I/O.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from ..config import check_positive

SCALINGS = ("goal-start", "none")
#: Most kernels a DMP may have (the paper: 25). The rollout's response table, built once
#: per configuration, grows with the square of it (about 30 MB and a second to solve at
#: N = 100, 17 s at N = 300 on a 2-core machine).
MAX_KERNELS = 200


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
        check_positive("alpha_z", self.alpha_z)
        check_positive("alpha_x", self.alpha_x)
        check_positive("width_factor", self.width_factor)
        beta = self.alpha_z / 4.0 if self.beta_z is None else self.beta_z
        check_positive("beta_z", beta)
        if self.scaling not in SCALINGS:
            raise ValueError(f"scaling must be one of {SCALINGS}, got {self.scaling!r}")
        object.__setattr__(self, "_beta", float(beta))

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
