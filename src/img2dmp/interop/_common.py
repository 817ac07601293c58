"""What both bridges share: the result records, the forcing amplitudes, the distance."""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..config import check_positive
from ..dmp import DMPConfig, DMPParams, rollout
from ..dmp.config import as_config
from ..dmp.params import same_movement

#: Time steps per movement (per ``tau``) of a peer's rollout unless the caller says.
#: Measured on the ten synthetic digits in the 28-px frame (docs/INTEROP.md): the largest
#: distance from img2dmp's rollout is then 0.023 px for movement_primitives (first order,
#: 0.046 px at 2000), 0.023 px for MP_PyTorch's Euler DMP and 0.004 px for ProDMP, whose
#: second-order basis table needs far fewer steps (and costs O(steps^2) to build).
DEFAULT_STEPS = {"movement_primitives": 4000, "dmp": 2000, "prodmp": 500}
#: Most time steps per tau a peer is asked to integrate: ten times the defaults
#: (movement_primitives' Python loop and MP_PyTorch's DMP integrate step by step, the
#: ProDMP's basis grows with the square of its steps: 5,000 took 21 s; dt = 1e-8 s asked
#: movement_primitives for 8 GB).
MAX_STEPS = {"movement_primitives": 40_000, "dmp": 20_000, "prodmp": 2_000}


@dataclass
class PeerExport:
    """An img2dmp DMP (or batch) handed to another library.

    Attributes
    ----------
    dmp : object
        The peer's object: a ``movement_primitives.dmp.DMP`` (or, for a batch, a list of
        them in C order of the batch), or one MP_PyTorch ``DMP`` / ``ProDMP`` holding the
        whole batch.
    batch_shape : tuple
        The batch shape of the exported parameters (``()`` for one DMP).
    exact : bool
        True when the parameters were mapped analytically (the two ODEs are the same);
        False when they were re-fitted to img2dmp's rollout because the peer's ODE
        differs (then ``error_px`` is the re-fit's error plus the peer's integration).
    times : array [*batch, T] or None
        The time stamps (seconds) the peer rolled out at for the check.
    error_px : array [*batch] or None
        Largest distance between the peer's own rollout and img2dmp's exact rollout at
        ``times`` (units of the DMP, px in the image frame); None when not checked.
    """

    dmp: Any  # the peer's own class (its library's types are not img2dmp's to declare)
    batch_shape: tuple
    exact: bool
    times: np.ndarray | None = None
    error_px: np.ndarray | None = None


@dataclass
class PeerImport:
    """A peer's DMP (or batch) read back into img2dmp.

    Attributes
    ----------
    params : DMPParams
        NumPy float64 fields, batch shape ``[*batch]``.
    exact : array of bool [*batch]
        True where the peer's configuration is img2dmp's and the parameters were read
        off analytically; False where img2dmp's DMP was fitted (``fit_dmp``) to the
        peer's rollout.
    times : array [*batch, T] or None
        The peer's time stamps used for the comparison.
    error_px : array [*batch] or None
        Largest distance between img2dmp's rollout of ``params`` and the peer's own
        rollout at ``times``; None when not checked.
    """

    params: DMPParams
    exact: np.ndarray
    times: np.ndarray | None = None
    error_px: np.ndarray | None = None


CONFIG_ATTRIBUTE = "img2dmp_config"  # an export's constants, on the peer's object


def remember(peer_object, config: DMPConfig) -> None:
    """Keep the constants an export was made with on the peer's object, so that its
    import gives back parameters of the same constants when given no ``config``."""
    setattr(peer_object, CONFIG_ATTRIBUTE, config)


def import_config(peer_objects: list, config) -> DMPConfig:
    """``config``; without one, the constants the objects were exported with (all the
    same), else the paper's."""
    if config is not None:
        return as_config(config)
    kept = [getattr(o, CONFIG_ATTRIBUTE, None) for o in peer_objects]
    first = kept[0]
    if isinstance(first, DMPConfig) and all(
        isinstance(k, DMPConfig) and same_movement(k, first) for k in kept
    ):
        return first
    return DMPConfig()


def check_dims(what: str, n_dims: int, config: DMPConfig) -> None:
    """A peer object of ``n_dims`` dimensions against ``config``: one line naming both."""
    if int(n_dims) != config.n_dims:
        raise ValueError(
            f"{what} has {int(n_dims)} dimensions, the config {config.n_dims}; give "
            f"config=DMPConfig(n_dims={int(n_dims)}, ...) with the DMP's other constants"
        )


def require(module: str, package: str):
    """Import ``module`` or raise ``ImportError`` naming the pip package and the extra."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise ImportError(
            f"{module} is not installed ({e}); install {package} or img2dmp's extra: "
            "pip install -e '/path/to/img2dmp[interop]'"
        ) from None


def as_numpy_params(params: DMPParams, config: DMPConfig) -> DMPParams:
    """``params`` as float64 NumPy arrays, checked against ``config``."""
    if not isinstance(params, DMPParams):
        raise TypeError(f"expected a DMPParams, got {type(params).__name__}")
    p = params.to_numpy()
    return DMPParams(*(np.asarray(a, np.float64) for a in (p.w, p.tau, p.g, p.y0)), config=config)


def scale(p: DMPParams, config: DMPConfig) -> np.ndarray:
    """``S`` of the forcing term, ``[*batch, d]``: ``g - y0`` (goal-start) or ones."""
    if config.scaling == "goal-start":
        return np.asarray(p.g - p.y0, np.float64)
    return np.ones_like(np.asarray(p.g, np.float64))


def forcing_amplitudes(p: DMPParams, config: DMPConfig) -> np.ndarray:
    """``S w``, ``[*batch, N, d]``: the weights of a DMP whose forcing term is unscaled.

    Neither peer scales its forcing term by ``g - y0``; with the same start and goal the
    two ODEs are then the same (a new goal in the peer no longer stretches the shape).
    """
    return np.asarray(p.w, np.float64) * scale(p, config)[..., None, :]


def weights_from_amplitudes(amp, g, y0, config: DMPConfig):
    """Inverse of :func:`forcing_amplitudes`; None where ``g - y0`` is (nearly) 0 in a
    dimension under goal-start scaling (the weights are then not determined)."""
    amp = np.asarray(amp, np.float64)
    if config.scaling != "goal-start":
        return amp
    s = np.asarray(g, np.float64) - np.asarray(y0, np.float64)
    ref = max(1.0, float(np.abs(g).max(initial=0.0)), float(np.abs(y0).max(initial=0.0)))
    if np.any(np.abs(s) <= 1e-9 * ref):
        return None
    return amp / s[..., None, :]


def check_steps(steps, kind: str) -> int:
    """``steps`` (time steps per tau), the default of ``kind`` when None."""
    if steps is None:
        return DEFAULT_STEPS[kind]
    most = MAX_STEPS[kind]
    if (isinstance(steps, bool) or not isinstance(steps, (int, np.integer))
            or not 2 <= steps <= most):  # fmt: skip
        raise ValueError(
            f"steps must be an integer from 2 to {most:,} (time steps per tau for {kind}), "
            f"got {steps!r}"
        )
    return int(steps)


def check_dt(dt, tau: float | None = None, what: str = "dt") -> float:
    """``dt`` > 0, and with ``tau`` at least ``tau / MAX_STEPS["movement_primitives"]``
    and at most ``tau`` (a step longer than the movement integrates nothing of it)."""
    dt = check_positive(what, dt)
    if tau is not None:
        most = MAX_STEPS["movement_primitives"]
        if not tau / most <= dt <= tau:
            raise ValueError(
                f"{what} {dt:g} s for a DMP of tau {tau:g} s: give from tau / {most:,} to "
                f"tau ({tau / most:.3g} to {tau:g} s)"
            )
    return dt


def max_distance(p: DMPParams, t, y, config: DMPConfig) -> np.ndarray:
    """Largest distance ``[*batch]`` between img2dmp's rollout of ``p`` at ``t`` and ``y``.

    ``p`` has batch shape ``[*batch]``, ``t`` ``[*batch, T]`` and ``y`` ``[*batch, T, d]``.
    """
    t = torch.as_tensor(np.asarray(t, np.float64))
    ours = rollout(p.to_torch(torch.float64), t, config).numpy()
    dist = np.linalg.norm(ours - np.asarray(y, np.float64), axis=-1)
    return dist.max(axis=-1)
