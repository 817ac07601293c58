"""DMP parameters (eq. 8 of Pahič et al.) and their flat-vector form.

The network of the paper outputs one flat vector per image. Its order is fixed here and
nowhere else::

    [ w[0, 0] .. w[N-1, 0],  w[0, 1] .. w[N-1, 1], ...,   # N weights of dim 0, dim 1, ...
      tau,                                                # 1 number, seconds
      g[0] .. g[d-1],                                     # goal
      y0[0] .. y0[d-1] ]                                  # start

which for N = 25 kernels and d = 2 dimensions is 50 + 1 + 2 + 2 = 55 numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .config import DMPConfig


def _is_torch(a) -> bool:
    return isinstance(a, torch.Tensor)


def as_host_array(a) -> np.ndarray | None:
    """A zero-copy NumPy view of a CPU tensor or array (None for other devices/dtypes)."""
    if _is_torch(a):
        if not a.is_cpu or a.dtype in (torch.bfloat16,) or a.is_complex():
            return None
        return a.detach().numpy()
    return np.asarray(a)


def all_finite(a) -> bool:
    """True when no element is NaN or inf.

    On the CPU one sum decides (any NaN or inf makes it non-finite); only a non-finite
    sum, which an overflow can also cause, is checked element by element. That keeps
    input validation a small fraction of a fast rollout.
    """
    x = as_host_array(a)
    if x is None:
        return bool(torch.isfinite(a).all())
    if x.dtype.kind not in "fc":
        return True
    with np.errstate(all="ignore"):
        if np.isfinite(x.sum()):
            return True
    return bool(np.isfinite(x).all())


def _cat(parts, like):
    return torch.cat(parts, dim=-1) if _is_torch(like) else np.concatenate(parts, axis=-1)


def _swap_last(a):
    return a.transpose(-1, -2) if _is_torch(a) else np.swapaxes(a, -1, -2)


@dataclass
class DMPParams:
    """The parameters of a batch of DMPs: weights, duration, goal and start.

    Attributes
    ----------
    w : array [*batch, N, d]
        Kernel weights ``w_k`` of the forcing term (eq. 6), one column per dimension.
    tau : array [*batch]
        Temporal scaling in seconds (> 0); with the default constants it is the
        movement's duration.
    g : array [*batch, d]
        Goal position.
    y0 : array [*batch, d]
        Start position.

    The arrays may be NumPy arrays or torch tensors (all of one kind).
    """

    w: object
    tau: object
    g: object
    y0: object

    def __post_init__(self) -> None:
        # NumPy scalars and Python numbers (e.g. from indexing one sample) become 0-d arrays.
        if not any(_is_torch(getattr(self, k)) for k in ("w", "tau", "g", "y0")):
            for k in ("w", "tau", "g", "y0"):
                v = getattr(self, k)
                if isinstance(v, (np.generic, int, float, list, tuple)):
                    setattr(self, k, np.asarray(v, dtype=np.float64))
        self.validate()

    def _values_stamp(self) -> tuple | None:
        # Which tensors, in which state, the values were last checked on: torch bumps a
        # tensor's _version at every in-place change (a write through a NumPy view of its
        # memory is the one change it cannot see).
        fields = (self.w, self.tau, self.g, self.y0)
        if not all(_is_torch(a) for a in fields):
            return None
        return tuple((id(a), a._version) for a in fields)

    def validate(self, config: DMPConfig | None = None) -> DMPParams:
        """Check shapes and values; raise ``ValueError`` naming the field at fault.

        The values of torch tensors are checked once: validating the same, unchanged
        tensors again (as :func:`img2dmp.dmp.rollout` does with parameters that were
        checked when they were made) only checks the shapes.
        """
        stamp = self._values_stamp()
        if stamp is None or stamp != self.__dict__.get("_checked"):
            self._check_values()
            if stamp is not None:
                self.__dict__["_checked"] = stamp
        w, tau, g, y0 = self.w, self.tau, self.g, self.y0
        if w.ndim < 2:
            raise ValueError(f"DMPParams.w must have shape [*batch, N, d], got {tuple(w.shape)}")
        batch, n, d = tuple(w.shape[:-2]), w.shape[-2], w.shape[-1]
        if tuple(g.shape) != batch + (d,):
            raise ValueError(f"DMPParams.g has shape {tuple(g.shape)}, expected {batch + (d,)}")
        if tuple(y0.shape) != batch + (d,):
            raise ValueError(f"DMPParams.y0 has shape {tuple(y0.shape)}, expected {batch + (d,)}")
        if tuple(tau.shape) != batch:
            raise ValueError(f"DMPParams.tau has shape {tuple(tau.shape)}, expected {batch}")
        if config is not None and (n, d) != (config.n_kernels, config.n_dims):
            raise ValueError(
                f"DMPParams.w has N={n} kernels and d={d} dims, "
                f"the config expects N={config.n_kernels}, d={config.n_dims}"
            )
        return self

    def _check_values(self) -> None:
        names = ("w", "tau", "g", "y0")
        for name in names:
            a = getattr(self, name)
            if not (_is_torch(a) or isinstance(a, np.ndarray)):
                raise ValueError(f"DMPParams.{name} must be an array or tensor, got {type(a)}")
        # One finite total decides for all four fields at once (a few microseconds: this
        # runs for every batch a network makes); only a non-finite one, which an
        # overflow can also cause, is looked into field by field to name the culprit.
        hosts = [as_host_array(getattr(self, name)) for name in names]
        finite = False
        if all(h is not None and h.dtype.kind == "f" for h in hosts):
            with np.errstate(all="ignore"):
                finite = bool(np.isfinite(sum(float(h.sum()) for h in hosts)))
        if not finite:
            for name in names:
                if not all_finite(getattr(self, name)):
                    raise ValueError(f"DMPParams.{name} contains NaN or inf")
        tau_host = hosts[1]
        if not bool(((tau_host if tau_host is not None else self.tau) > 0).all()):
            raise ValueError("DMPParams.tau must be > 0 (it is a duration in seconds)")

    @property
    def batch_shape(self) -> tuple:
        return tuple(self.w.shape[:-2])

    @property
    def n_kernels(self) -> int:
        return int(self.w.shape[-2])

    @property
    def n_dims(self) -> int:
        return int(self.w.shape[-1])

    def to_vector(self):
        """Flat vector ``[*batch, N*d + 1 + 2d]`` in the order given in the module docstring."""
        w_flat = _swap_last(self.w).reshape(*self.batch_shape, -1)
        return _cat([w_flat, self.tau[..., None], self.g, self.y0], self.w)

    @classmethod
    def from_vector(cls, v, n_kernels: int, n_dims: int) -> DMPParams:
        """Inverse of :meth:`to_vector`; ``v`` has shape ``[*batch, N*d + 1 + 2d]``."""
        n, d = n_kernels, n_dims
        expected = n * d + 1 + 2 * d
        if v.shape[-1] != expected:
            raise ValueError(
                f"parameter vector has length {v.shape[-1]}, expected N*d + 1 + 2d = {expected} "
                f"for N={n}, d={d}"
            )
        batch = tuple(v.shape[:-1])
        w = _swap_last(v[..., : n * d].reshape(*batch, d, n))
        tau = v[..., n * d]
        g = v[..., n * d + 1 : n * d + 1 + d]
        y0 = v[..., n * d + 1 + d :]
        return cls(w=w, tau=tau, g=g, y0=y0)

    def to_torch(self, dtype=torch.float64, device=None) -> DMPParams:
        conv = lambda a: torch.as_tensor(a, dtype=dtype, device=device)  # noqa: E731
        return DMPParams(conv(self.w), conv(self.tau), conv(self.g), conv(self.y0))

    def to_numpy(self) -> DMPParams:
        conv = lambda a: a.detach().cpu().numpy() if _is_torch(a) else np.asarray(a)  # noqa: E731
        return DMPParams(conv(self.w), conv(self.tau), conv(self.g), conv(self.y0))

    def __getitem__(self, idx) -> DMPParams:
        """Index the batch dimensions: ``params[3]``, ``params[:10]``."""
        return DMPParams(self.w[idx], self.tau[idx], self.g[idx], self.y0[idx])

    def to_dict(self) -> dict:
        """JSON-ready nested lists (NumPy view)."""
        p = self.to_numpy()
        return {"w": p.w.tolist(), "tau": p.tau.tolist(), "g": p.g.tolist(), "y0": p.y0.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> DMPParams:
        missing = [k for k in ("w", "tau", "g", "y0") if k not in d]
        if missing:
            raise ValueError(f"DMP parameters are missing field(s) {missing}")
        try:
            arrs = {k: np.asarray(d[k], dtype=np.float64) for k in ("w", "tau", "g", "y0")}
        except (TypeError, ValueError) as e:
            raise ValueError(f"DMP parameters are not numeric: {e}") from e
        return cls(**arrs)
