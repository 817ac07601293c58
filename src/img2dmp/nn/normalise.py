"""Per-unit scaling of the network's output, the flat DMP vector of eq. (8).

The raw parameters live on very different scales: weights of a few hundred (and, with the
paper's goal-start scaling, of thousands where ``g ~ y0`` in one dimension), a duration
of about one second, goal and start positions of tens of pixels. Cost (9) compares them
unit by unit, so every unit is mapped to a comparable scale first::

    u_j = log(tau)  if j is the tau unit,  v_j otherwise        (tau > 0 by construction)
    z_j = (u_j - centre_j) / scale_j

``centre`` is the per-unit median of the training set and ``scale`` the per-unit
interquartile range divided by 1.349 (the standard deviation of a Gaussian with that
IQR). Median and IQR are robust: the few huge goal-start weights of closed shapes do not
shrink every other sample's values to zero. ``scale`` is floored within each group of
units that share a physical unit (the weights; log tau; goal and start) at ``1e-3``
times the group's median scale (and at an absolute ``1e-2`` for log tau, ``1e-6`` for the
others), so a constant unit cannot divide by zero and no group's floor depends on the
size of another's numbers.

**Weight units.** With ``units="weights"`` (the paper) the weight units are the ``w_k``
themselves. With the paper's goal-start scaling they grow like ``1 / (g - y0)``, a
singular function of the image where a stroke ends near where it started in one
dimension. ``units="amplitudes"`` makes them the forcing amplitudes
``a_{k,i} = (g_i - y0_i) w_{k,i}`` instead: the same DMP (``diag(g - y0) F`` is the forcing
term either way), but the path is affine in ``a``, ``g`` and ``y0``, and an affine map of
the image moves them linearly. On the way back ``w = a / (g - y0)``, with ``|g - y0|``
kept at least ``1e-9`` (of its sign) so that it stays finite. Only for DMPs with the
goal-start scaling; without it the weights are already amplitudes.

The inverse (:meth:`ParamNormaliser.denormalise`) maps the network's output ``z`` back to a
:class:`~img2dmp.dmp.DMPParams`; tau comes out as ``exp(.)`` and is therefore always
positive, which is what the rollout of cost (10) needs. It is differentiable; its NumPy
twin :meth:`ParamNormaliser.denormalise_numpy` has a hand-written vector-Jacobian product
(:meth:`ParamNormaliser.denormalise_numpy_vjp`) for the refinement without torch.

torch is imported only by the methods that take tensors (a prediction that never
imports torch uses this module).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..dmp.config import DMPConfig
from ..dmp.params import DMPParams

if TYPE_CHECKING:
    import torch

_IQR_TO_STD = 1.3489795
UNITS = ("weights", "amplitudes")
_MIN_SPAN = 1e-9  # smallest |g - y0| divided by when amplitudes go back to weights


@dataclass
class ParamNormaliser:
    """Robust per-unit affine map between the flat DMP vector and the network's output.

    Attributes
    ----------
    centre : ndarray [P]
        Per-unit median of the (log-tau) parameter vector over the training set.
    scale : ndarray [P]
        Per-unit robust standard deviation (IQR / 1.349), floored.
    n_kernels, n_dims : int
        Shape of the DMP the vector encodes (``P = N*d + 1 + 2d``).
    units : {"weights", "amplitudes"}
        What the weight units hold: ``w`` (the paper) or ``(g - y0) * w``.
    """

    centre: np.ndarray
    scale: np.ndarray
    n_kernels: int
    n_dims: int
    units: str = "weights"

    def __post_init__(self) -> None:
        if self.units not in UNITS:
            raise ValueError(f"normalisation units must be one of {UNITS}, got {self.units!r}")
        self.centre = np.asarray(self.centre, dtype=np.float64)
        self.scale = np.asarray(self.scale, dtype=np.float64)
        p = self.n_kernels * self.n_dims + 1 + 2 * self.n_dims
        for name in ("centre", "scale"):
            a = getattr(self, name)
            if a.shape != (p,):
                raise ValueError(
                    f"ParamNormaliser.{name} has shape {a.shape}, expected ({p},) for "
                    f"N={self.n_kernels}, d={self.n_dims}"
                )
            if not np.isfinite(a).all():
                raise ValueError(f"ParamNormaliser.{name} contains NaN or inf")
        if not (self.scale > 0).all():
            raise ValueError("ParamNormaliser.scale must be > 0 in every unit")
        self._cache: dict = {}

    @property
    def n_params(self) -> int:
        return int(self.centre.shape[0])

    @property
    def tau_index(self) -> int:
        """Position of tau in the flat vector (right after the N*d weights)."""
        return self.n_kernels * self.n_dims

    @classmethod
    def fit(cls, params: np.ndarray, config: DMPConfig, units: str = "weights") -> ParamNormaliser:
        """Robust centre and scale of a training set's flat parameter vectors.

        Parameters
        ----------
        params : ndarray [M, P]
            Fitted DMPs (``DMPParams.to_vector``), tau > 0.
        config : DMPConfig
            Their constants.
        units : {"weights", "amplitudes"}
            See the module docstring; ``"amplitudes"`` needs ``config.scaling ==
            "goal-start"``.
        """
        if units == "amplitudes" and config.scaling != "goal-start":
            raise ValueError(
                f"weight units 'amplitudes' need DMPs with the goal-start scaling; with "
                f"scaling={config.scaling!r} the weights already are amplitudes (use 'weights')"
            )
        v = np.asarray(params, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != config.n_params or v.shape[0] < 2:
            raise ValueError(
                f"need at least 2 parameter vectors of length {config.n_params} to fit the "
                f"normalisation, got shape {v.shape}"
            )
        if not np.isfinite(v).all():
            raise ValueError("training parameter vectors contain NaN or inf")
        ti = config.n_kernels * config.n_dims
        if not (v[:, ti] > 0).all():
            raise ValueError("training parameter vectors have tau <= 0")
        u = _to_units_numpy(v, config.n_kernels, config.n_dims, units)
        q1, med, q3 = np.percentile(u, [25.0, 50.0, 75.0], axis=0)
        scale = (q3 - q1) / _IQR_TO_STD
        # A unit with (almost) no spread would otherwise blow up its normalised error;
        # floors are per group of units in the same physical unit.
        groups = ((slice(0, ti), 1e-6), (slice(ti, ti + 1), 1e-2), (slice(ti + 1, None), 1e-6))
        for group, absolute in groups:
            floor = max(1e-3 * float(np.median(scale[group])), absolute)
            scale[group] = np.maximum(scale[group], floor)
        return cls(med, scale, config.n_kernels, config.n_dims, units)

    def _tensors(self, like: torch.Tensor):
        key = (like.dtype, like.device)
        if key not in self._cache:
            import torch  # loaded already: ``like`` is a tensor

            c = torch.as_tensor(self.centre, dtype=like.dtype, device=like.device)
            s = torch.as_tensor(self.scale, dtype=like.dtype, device=like.device)
            self._cache[key] = (c, s)
        return self._cache[key]

    def normalise(self, v: torch.Tensor) -> torch.Tensor:
        """Flat parameter vectors ``[*batch, P]`` (tau > 0) to normalised units ``[*batch, P]``."""
        c, s = self._tensors(v)
        return (_to_units(v, self.n_kernels, self.n_dims, self.units) - c) / s

    def denormalise_vector(self, z: torch.Tensor) -> torch.Tensor:
        """Normalised units ``[*batch, P]`` to flat parameter vectors (tau = exp(.) > 0)."""
        c, s = self._tensors(z)
        return _from_units(z * s + c, self.n_kernels, self.n_dims, self.units)

    def denormalise(self, z: torch.Tensor) -> DMPParams:
        """Normalised network output ``[*batch, P]`` to :class:`DMPParams` (torch, differentiable).

        No validation is done (this sits in the training loop); tau is positive by
        construction, and finite as long as the output is.
        """
        v = self.denormalise_vector(z)
        n, d = self.n_kernels, self.n_dims
        batch = tuple(v.shape[:-1])
        w = v[..., : n * d].reshape(*batch, d, n).transpose(-1, -2)
        tau = v[..., n * d]
        g = v[..., n * d + 1 : n * d + 1 + d]
        y0 = v[..., n * d + 1 + d :]
        # object.__new__ skips DMPParams' validation (host syncs) in the hot loop.
        p = object.__new__(DMPParams)
        p.w, p.tau, p.g, p.y0 = w, tau, g, y0
        return p

    def _check_vector(self, what: str, a) -> np.ndarray:
        """``a`` as a float64 array ``[*batch, P]``, or a ``ValueError`` naming ``what``."""
        a = np.asarray(a)
        if a.dtype.kind not in "iuf":
            raise ValueError(f"{what} must hold real numbers, got dtype {a.dtype}")
        if a.ndim == 0 or a.shape[-1] != self.n_params:
            raise ValueError(
                f"{what} has shape {a.shape}, expected [*batch, {self.n_params}] "
                f"(N={self.n_kernels}, d={self.n_dims})"
            )
        return a.astype(np.float64, copy=False)

    def denormalise_numpy(self, z) -> np.ndarray:
        """:meth:`denormalise_vector` in NumPy float64: ``v = from_units(z * scale + centre)``.

        ``from_units`` takes tau = exp(u_tau) and, with ``units="amplitudes"``, the weights
        ``w = a / copysign(max(|g - y0|, 1e-9), g - y0)``.

        Parameters
        ----------
        z : array [*batch, P]
            Normalised units.

        Returns
        -------
        ndarray [*batch, P]
            Flat parameter vectors (the order of :meth:`DMPParams.to_vector`).
        """
        z = self._check_vector("z", z)
        u = z * self.scale + self.centre
        return _from_units_numpy(u, self.n_kernels, self.n_dims, self.units)

    def denormalise_numpy_vjp(self, z, grad_v) -> np.ndarray:
        """Vector-Jacobian product of :meth:`denormalise_numpy`: ``dL/dz`` from ``dL/dv``.

        With ``u = z * scale + centre`` and ``v = from_units(u)``::

            dL/du_tau = dL/dv_tau * exp(u_tau)
            dL/du_w   = dL/dv_w / D                              ("amplitudes", else dL/dv_w)
            dL/du_g  += sum_k -dL/dv_w_k * u_w_k / D^2 * [|g - y0| >= 1e-9]   (per dimension)
            dL/du_y0 -= the same
            dL/dz     = dL/du * scale

        where ``D = copysign(max(|g - y0|, 1e-9), g - y0)``; below the floor ``D`` is
        constant, as torch's autograd of :meth:`denormalise_vector` has it.

        Parameters
        ----------
        z : array [*batch, P]
        grad_v : array [*batch, P]
            Gradient with respect to the flat parameter vectors.

        Returns
        -------
        ndarray [*batch, P]
        """
        z = self._check_vector("z", z)
        gv = self._check_vector("grad_v", grad_v)
        if gv.shape != z.shape:
            raise ValueError(f"grad_v has shape {gv.shape}, z has {z.shape}: they must match")
        n, d = self.n_kernels, self.n_dims
        ti = n * d
        u = z * self.scale + self.centre  # [*batch, P]
        gu = gv.copy()
        gu[..., ti] = gv[..., ti] * np.exp(u[..., ti])
        if self.units == "amplitudes":
            span = _spans_numpy(u, n, d)  # [*batch, N*d]
            den = np.copysign(np.maximum(np.abs(span), _MIN_SPAN), span)
            gu[..., :ti] = gv[..., :ti] / den
            # d(a / D)/dspan = -a / D^2 where the floor is not active (|span| >= floor).
            g_span = -gv[..., :ti] * u[..., :ti] / (den * den) * (np.abs(span) >= _MIN_SPAN)
            g_span = g_span.reshape(*g_span.shape[:-1], d, n).sum(-1)  # [*batch, d]
            gu[..., ti + 1 : ti + 1 + d] += g_span
            gu[..., ti + 1 + d :] -= g_span
        return gu * self.scale

    def to_dict(self) -> dict:
        return {
            "kind": "robust-median-iqr-logtau",
            "centre": self.centre.tolist(),
            "scale": self.scale.tolist(),
            "n_kernels": self.n_kernels,
            "n_dims": self.n_dims,
            "units": self.units,
        }

    @classmethod
    def from_dict(cls, d: dict) -> ParamNormaliser:
        missing = [k for k in ("centre", "scale", "n_kernels", "n_dims") if k not in d]
        if missing:
            raise ValueError(f"normalisation record is missing field(s) {missing}")
        if d.get("kind", "robust-median-iqr-logtau") != "robust-median-iqr-logtau":
            raise ValueError(f"unknown normalisation kind {d.get('kind')!r}")
        return cls(
            np.asarray(d["centre"], dtype=np.float64),
            np.asarray(d["scale"], dtype=np.float64),
            int(d["n_kernels"]),
            int(d["n_dims"]),
            d.get("units", "weights"),  # records written before amplitudes existed
        )


def _spans(v: torch.Tensor, n: int, d: int) -> torch.Tensor:
    """``g - y0`` of flat vectors ``[*batch, P]``, repeated per weight: ``[*batch, N*d]``."""
    import torch  # loaded already: ``v`` is a tensor

    g = v[..., n * d + 1 : n * d + 1 + d]
    y0 = v[..., n * d + 1 + d :]
    return torch.repeat_interleave(g - y0, n, dim=-1)


def _to_units(v: torch.Tensor, n: int, d: int, units: str) -> torch.Tensor:
    """Flat DMP vectors to the units that are normalised: log tau, and w or (g - y0) w."""
    import torch  # loaded already: ``v`` is a tensor

    ti = n * d
    w = v[..., :ti] * _spans(v, n, d) if units == "amplitudes" else v[..., :ti]
    return torch.cat([w, torch.log(v[..., ti : ti + 1]), v[..., ti + 1 :]], dim=-1)


def _from_units(u: torch.Tensor, n: int, d: int, units: str) -> torch.Tensor:
    """Inverse of :func:`_to_units` (tau = exp(.) > 0; |g - y0| floored when dividing)."""
    import torch  # loaded already: ``u`` is a tensor

    ti = n * d
    w = u[..., :ti]
    if units == "amplitudes":
        span = _spans(u, n, d)
        w = w / torch.copysign(span.abs().clamp_min(_MIN_SPAN), span)
    return torch.cat([w, torch.exp(u[..., ti : ti + 1]), u[..., ti + 1 :]], dim=-1)


def _spans_numpy(v: np.ndarray, n: int, d: int) -> np.ndarray:
    """:func:`_spans` of NumPy vectors: ``g - y0`` repeated per weight, ``[*batch, N*d]``."""
    g = v[..., n * d + 1 : n * d + 1 + d]
    y0 = v[..., n * d + 1 + d :]
    return np.repeat(g - y0, n, axis=-1)


def _to_units_numpy(v: np.ndarray, n: int, d: int, units: str) -> np.ndarray:
    """:func:`_to_units` of NumPy vectors (log tau, and w or (g - y0) w)."""
    ti = n * d
    w = v[..., :ti] * _spans_numpy(v, n, d) if units == "amplitudes" else v[..., :ti]
    return np.concatenate([w, np.log(v[..., ti : ti + 1]), v[..., ti + 1 :]], axis=-1)


def _from_units_numpy(u: np.ndarray, n: int, d: int, units: str) -> np.ndarray:
    """:func:`_from_units` of NumPy vectors (tau = exp(.); |g - y0| floored when dividing)."""
    ti = n * d
    w = u[..., :ti]
    if units == "amplitudes":
        span = _spans_numpy(u, n, d)
        w = w / np.copysign(np.maximum(np.abs(span), _MIN_SPAN), span)
    return np.concatenate([w, np.exp(u[..., ti : ti + 1]), u[..., ti + 1 :]], axis=-1)
