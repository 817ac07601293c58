"""Bending a DMP: a new goal or start, another tempo, scaled, rotated or shifted.

This is what DMPs are used for in robotics: one movement replayed to a new goal, from a
new start, slower or faster, larger or smaller, turned. What each change does follows
from the rollout's closed form (:mod:`img2dmp.dmp.rollout`): with ``s = t / tau``,

    y(t) = g + (y0 - g) a(s) + S P(s),       P(s) = sum_k w_k R_k(s)

where ``a`` (the free response to a unit offset; with the default critical damping
``a(s) = (1 + omega s) exp(-omega s)``, ``omega = alpha_z / 2``) and the kernel responses ``R_k``
depend only on the constants, and ``S = diag(g - y0)`` (``scaling="goal-start"``) or
``I`` (``scaling="none"``). Hence, for a movement ``y(t)`` and ``d = g - y0``
(derivations and a figure: docs/DMP.md, "Bending a DMP"):

- tempo k (``tau' = tau / k``: k times as fast): exact in both, ``y'(t) = y(k t)``;
- shift c (``g`` and ``y0`` move by c): exact in both, ``y' = y + c``;
- scale s about the start: exact in both; ``"none"`` with ``w' = s w``, ``"goal-start"``
  with ``w`` unchanged;
- rotation R about the start: exact in both; ``"none"`` with ``w' = R w``,
  ``"goal-start"`` only with ``w' = L w``, ``L = diag(R d)^-1 R diag(d)`` (refused where
  ``(R d)_i = 0``);
- a new goal g' (weights kept) changes the shape: ``"none"``: ``y' = y + (g' - g)(1 -
  a(s))``, the path bends toward the goal, the forcing's shape unchanged;
  ``"goal-start"``: ``y' = y0 + diag((g' - y0) / d) (y - y0)``, stretched per axis about
  the start;
- a new start y0' (weights and goal kept) changes the shape: ``"none"``: ``y' = y +
  (y0' - y0) a(s)``, the offset dies away; ``"goal-start"``: ``y' = g + diag((g - y0') /
  d) (y - g)``, stretched per axis about the goal.

"Exact" means the rolled-out path is the transformed path to rounding (the affine rows
are :func:`img2dmp.dmp.affine.affine_dmp`'s). Under ``"goal-start"`` a coordinate with
``d_i = 0`` has no forcing; given a new goal or start there it moves along ``1 - a(s)``
(or ``a(s)``) only. A rotation of a ``"goal-start"`` DMP needs weights scaled by
``|d_i| / |(R d)_i|``, unbounded as ``(R d)_i`` nears 0 (moving the goal alone, weights
unchanged, stretches per axis instead: it does not rotate). Only positions (x, y) move:
a third channel (the pen) keeps its values. No I/O here: pure arithmetic on parameters.
"""

from __future__ import annotations

import numpy as np

from ..config import check_positive
from .affine import affine_dmp
from .config import DMPConfig
from .params import DMPParams, config_of, first_index, show_value, strict_numbers

#: Largest scale or tempo factor (and the inverse of the smallest).
MAX_FACTOR = 1e6
#: Largest rotation either way, degrees (2,777 turns; 1e308 % 360 keeps no digit of the
#: angle asked for).
MAX_ROTATE_DEG = 1e6
#: Largest coordinate of a goal, start or shift (as a DMP file's: its MAX_MAGNITUDE).
MAX_POINT = 1e9


def bend_dmp(
    params: DMPParams,
    config: DMPConfig | None = None,
    *,
    goal=None,
    start=None,
    shift=None,
    scale=None,
    rotate_deg=None,
    tempo=None,
) -> DMPParams:
    """The DMP of ``params`` bent: a new goal or start, scaled, rotated, shifted, retimed.

    The changes are applied in this order (see the module docstring for which are exact
    and what the others do to the path):

    1. ``scale`` and ``rotate_deg`` about the start and then ``shift``: the exact
       affine map ``y' = y0 + c + s R (y - y0)`` (:func:`img2dmp.dmp.affine.affine_dmp`),
       ``R = [[cos q, -sin q], [sin q, cos q]]``;
    2. ``start`` and ``goal`` replace ``y0`` and ``g`` (weights kept), so the bent DMP
       starts and ends where they say;
    3. ``tempo``: ``tau' = tau / tempo``, the same path ``tempo`` times as fast.

    Parameters
    ----------
    params : DMPParams
        One DMP (batch shape ``[]``) or a batch ``[*batch]``; NumPy or torch.
    config : DMPConfig, optional
        Its constants (default: the ones ``params`` carries; the result carries them);
        ``config.scaling`` decides what a new goal or start does to the shape.
    goal, start : array [2] or [*batch, 2], optional
        New goal ``g`` / start ``y0`` (x, y), in the DMP's own frame and units (pixels
        for img2dmp's DMPs); one for every DMP or one per DMP.
    shift : array [2] or [*batch, 2], optional
        Moves the whole movement by ``c`` (exact).
    scale : float or array [*batch], optional
        Factor ``s > 0`` about the start (exact).
    rotate_deg : float or array [*batch], optional
        Angle ``q`` in degrees about the start, from the x axis toward the y axis (exact;
        in image pixels, whose y axis points down, a positive angle turns clockwise as
        seen), ``|q| <=`` :data:`MAX_ROTATE_DEG`.
    tempo : float or array [*batch], optional
        Speed ``k > 0``, the duration divided by it: ``y'(t) = y(k t)`` (2: twice as fast).

    Returns
    -------
    DMPParams
        NumPy float64, the batch shape of ``params`` (not differentiable).

    Raises
    ------
    ValueError
        One line naming the value: a goal, start, shift, scale or angle not finite or
        out of bounds, a scale or tempo <= 0, shapes that do not fit the batch, positions asked
        of a DMP of fewer than 2 dimensions, or (``"goal-start"``) a rotation that maps a
        coordinate of ``g - y0`` to 0 (:func:`img2dmp.dmp.affine.affine_dmp`).
    """
    if not isinstance(params, DMPParams):
        raise ValueError(f"params must be a DMPParams, got {type(params).__name__}")
    config, p = config_of(params, config), params.to_numpy()
    p = DMPParams(*(np.asarray(a, dtype=np.float64) for a in (p.w, p.tau, p.g, p.y0)),
                  config=config)  # fmt: skip
    batch = p.batch_shape
    points = {k: _point(k, v, batch) for k, v in (("goal", goal), ("start", start),
                                                  ("shift", shift)) if v is not None}  # fmt: skip
    s = None if scale is None else _factor("scale", scale, batch)
    k = None if tempo is None else _factor("tempo", tempo, batch)
    q = None if rotate_deg is None else np.deg2rad(_angle("rotate_deg", rotate_deg, batch))
    if (points or s is not None or q is not None) and p.n_dims < 2:
        raise ValueError(f"moving positions needs d >= 2 dimensions (x, y), got d = {p.n_dims}")
    if s is not None or q is not None or "shift" in points:
        p = affine_dmp(p, config, _about_start(p.y0[..., :2], s, q, points.get("shift")))
    g, y0, tau = p.g.copy(), p.y0.copy(), p.tau.copy()
    if "start" in points:
        y0[..., :2] = points["start"]
    if "goal" in points:
        g[..., :2] = points["goal"]
    if k is not None:
        tau = tau / k
    return DMPParams(p.w.copy(), tau, g, y0, config=config)


def _about_start(y0, s, q, c) -> np.ndarray:
    """``[*batch, 2, 3]``: ``y -> y0 + c + s R(q) (y - y0)`` for starts ``y0 [*batch, 2]``."""
    s = 1.0 if s is None else s
    q = 0.0 if q is None else q
    cos, sin = np.cos(q) * s, np.sin(q) * s  # [*batch] or scalars
    a = np.stack([np.stack([cos, -sin], -1), np.stack([sin, cos], -1)], -2)  # [*b, 2, 2]
    a = np.broadcast_to(a, (*y0.shape[:-1], 2, 2))
    b = y0 - (a @ y0[..., None])[..., 0] + (0.0 if c is None else c)  # [*batch, 2]
    return np.concatenate([a, b[..., None]], axis=-1)


def _per_dmp(name: str, value, batch: tuple) -> np.ndarray:
    """A finite number, or one per DMP (``[*batch]``), as float64."""
    v = strict_numbers(name, value)
    try:
        return np.broadcast_to(v, batch).copy()
    except ValueError:
        raise ValueError(
            f"{name} must be one number or one per DMP (shape {list(batch)}), got shape "
            f"{list(v.shape)}"
        ) from None


def _factor(name: str, value, batch: tuple) -> np.ndarray:
    """:func:`_per_dmp`, each > 0 and within a factor :data:`MAX_FACTOR` of 1 (the first
    that is not is named: a scale of 1e300 overflowed the DMP into a singular matrix)."""
    v = _per_dmp(name, value, batch)
    bad = ~(v > 0)
    if bad.any():
        idx = first_index(bad)
        check_positive(name + (f" at index {list(idx)}" if idx else ""), float(v[idx]))
    far = (v > MAX_FACTOR) | (v < 1.0 / MAX_FACTOR)
    if far.any():
        idx = first_index(far)
        where = f"{name} at index {list(idx)}" if idx else name
        raise ValueError(
            f"{where} must be from {1 / MAX_FACTOR:g} to {MAX_FACTOR:g}, got {float(v[idx])!r}"
        )
    return v


def _angle(name: str, value, batch: tuple) -> np.ndarray:
    """:func:`_per_dmp`, each within :data:`MAX_ROTATE_DEG` of 0 (the first that is not
    is named: 1e308 degrees turned the DMP by an angle of no meaning)."""
    v = _per_dmp(name, value, batch)
    far = np.abs(v) > MAX_ROTATE_DEG
    if far.any():
        idx = first_index(far)
        where = f"{name} at index {list(idx)}" if idx else name
        raise ValueError(f"{where} must be from {-MAX_ROTATE_DEG:g} to {MAX_ROTATE_DEG:g} "
                         f"degrees, got {float(v[idx])!r}")  # fmt: skip
    return v


def _point(name: str, value, batch: tuple) -> np.ndarray:
    """Finite (x, y), one for every DMP or one per DMP (``[*batch, 2]``)."""
    v = strict_numbers(name, value)
    if v.ndim == 0 or v.shape[-1] != 2:
        raise ValueError(f"{name} must be a point (x, y), got shape {list(v.shape)}")
    if v.size and np.abs(v).max() > MAX_POINT:  # 1e308 overflowed into inf further on
        raise ValueError(f"{name} {show_value(v.tolist())} is beyond the {MAX_POINT:g} px "
                         "a DMP's position may be")  # fmt: skip
    try:
        return np.broadcast_to(v, (*batch, 2)).copy()
    except ValueError:
        raise ValueError(
            f"{name} must be one point or one per DMP (shape {[*batch, 2]}), got shape "
            f"{list(v.shape)}"
        ) from None


__all__ = ["bend_dmp"]
