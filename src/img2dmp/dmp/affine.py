"""A DMP seen in another frame: the exact DMP of an affinely mapped movement.

If a DMP writes ``y(t)`` (eqs. 3-5), the movement ``y'(t) = M y(t) + c`` (``M``
invertible) is written by the DMP with the same ``tau`` and constants and

    g' = M g + c,     y0' = M y0 + c,     w'_k = L w_k  (every kernel k),

because the transformation system is linear in ``y``, ``g`` and the forcing term
``S f(x)``, and ``f`` is linear in the weights. ``L`` absorbs the forcing's scaling
``S``:

- ``scaling="none"`` (``S = I``): ``L = M``; exact for every invertible ``M``.
- ``scaling="goal-start"`` (the paper's ``S = diag(g - y0)``): ``S' = diag(M (g - y0))``,
  so ``L = diag(M d)^-1 M diag(d)`` with ``d = g - y0``. For an axis-aligned ``M``
  (scaling and shift, what :func:`img2dmp.data.images.prepare_image_framed` makes)
  ``L = I``: the weights do not change, which is what the paper's scaling is for. For a
  rotation or shear it is exact too, as long as no coordinate of ``M d`` is 0 where the
  mapped forcing is not (then ``S'`` has a zero row that no weights can undo, and
  :func:`affine_dmp` refuses). A coordinate with ``d = 0`` has no forcing before and
  none after.

Only positions move: with ``d = 3`` the pen channel (the third) keeps its values
(``M`` acts on x, y; the pen's row of ``M`` is the identity).
"""

from __future__ import annotations

import numpy as np

from .config import DMPConfig
from .params import DMPParams, config_of


def _full_map(matrix, d: int, batch: tuple) -> tuple[np.ndarray, np.ndarray]:
    """``M [*b, d, d]`` and ``c [*b, d]`` of ``[*b, 2, 3]`` maps of x, y (other channels
    unchanged); ``b`` is ``[]`` (one map for every DMP) or broadcasts to ``batch``."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.ndim < 2 or m.shape[-2:] != (2, 3) or not np.isfinite(m).all():
        raise ValueError(f"matrix must be a finite 2 x 3 affine map, got shape {m.shape}")
    where = m.shape[:-2]
    try:
        fits = np.broadcast_shapes(where, batch) == batch
    except ValueError:
        fits = False
    if not fits:
        raise ValueError(
            f"matrix has batch shape {where}, which does not broadcast to the DMPs' {batch}"
        )
    a = m[..., :2]  # [*b, 2, 2]
    size = np.maximum(1.0, np.abs(a).max(axis=(-2, -1))) ** 2
    singular = np.abs(np.linalg.det(a)) <= 1e-12 * size
    if singular.any():
        at = f" (batch index {[int(i) for i in np.argwhere(singular)[0]]})" if where else ""
        raise ValueError(f"matrix is not invertible: its 2 x 2 part has determinant 0{at}")
    full = np.broadcast_to(np.eye(d), (*where, d, d)).copy()
    shift = np.zeros((*where, d))
    full[..., :2, :2], shift[..., :2] = a, m[..., 2]
    return full, shift


def affine_dmp(params: DMPParams, config: DMPConfig | None = None, matrix=None) -> DMPParams:
    """The DMP whose movement is ``matrix`` applied to ``params``'s movement, exactly.

    Parameters
    ----------
    params : DMPParams
        Batch shape ``[*batch]``, ``d >= 2`` (x, y first), NumPy or torch.
    config : DMPConfig or None
        Its constants (the result carries them); None: the ones ``params`` carries (a
        different one is refused), else the paper's. ``affine_dmp(params, matrix)``
        takes the carried ones.
    matrix : array [2, 3] or [*batch, 2, 3]
        ``[x', y'] = A @ [x, y] + b`` (the convention of :mod:`img2dmp.data.affine`): one
        map for every DMP, or one per DMP (any batch shape that broadcasts to ``[*batch]``).

    Returns
    -------
    DMPParams
        NumPy float64, the batch shape of ``params``; ``rollout(result, t)`` equals the
        mapped ``rollout(params, t)`` to rounding (see the module docstring for why).

    Raises
    ------
    ValueError
        For a matrix that is not an invertible ``2 x 3`` map, parameters that do not fit
        ``config``, or (``scaling="goal-start"`` with a rotation or shear only) a
        movement whose mapped ``g - y0`` has a zero coordinate.
    """
    if not isinstance(params, DMPParams):
        raise ValueError(f"params must be a DMPParams, got {type(params).__name__}")
    if matrix is None and config is not None and not isinstance(config, DMPConfig):
        config, matrix = None, config  # affine_dmp(params, matrix)
    if matrix is None:
        raise ValueError("affine_dmp needs a matrix: the 2 x 3 map [x', y'] = A [x, y] + b")
    config, p = config_of(params, config), params.to_numpy()
    p = DMPParams(*(np.asarray(a, dtype=np.float64) for a in (p.w, p.tau, p.g, p.y0)),
                  config=config)  # fmt: skip
    if p.n_dims < 2:
        raise ValueError(f"an affine map of x, y needs d >= 2 dimensions, got d = {p.n_dims}")
    m, c = _full_map(matrix, p.n_dims, p.batch_shape)  # [*b, D, D], [*b, D]
    g, y0 = _apply(m, p.g) + c, _apply(m, p.y0) + c  # [*batch, D]
    if config.scaling == "none":
        lin = np.broadcast_to(m, (*p.batch_shape, p.n_dims, p.n_dims))
    else:
        d = p.g - p.y0  # [*batch, D]
        d_new = _apply(m, d)  # M d (not g' - y0', which rounds differently)
        mixed = m * d[..., None, :]  # M diag(d)
        size = np.abs(mixed).sum(axis=-1)  # [*batch, D]
        forced = size > 0  # rows of M diag(d) that are not zero
        # M d cancelling to rounding is a zero: dividing by it would blow the weights up
        vanished = np.abs(d_new) <= 1e-12 * size
        zero = forced & vanished
        if zero.any():
            idx = tuple(int(i) for i in np.argwhere(zero)[0])
            raise ValueError(
                f"with scaling 'goal-start' this map is not a DMP: g - y0 maps to 0 in "
                f"coordinate {idx[-1]} (batch index {list(idx[:-1])}), so the mapped "
                "movement's forcing term there cannot be scaled; use scaling 'none'"
            )
        safe = np.where(d_new == 0, 1.0, d_new)
        lin = mixed / safe[..., :, None]
        # A row of M diag(d) that is zero has (M d)_i = 0: no forcing before or after
        # (d = 0 on an axis-aligned map); its weights are kept, acting on nothing.
        lin = np.where(forced[..., None], lin, np.eye(p.n_dims))
    w = p.w @ np.swapaxes(lin, -1, -2)  # w'_k = L w_k for every kernel (rows of w)
    return DMPParams(w, p.tau.copy(), g, y0, config=config)


def _apply(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``M v`` for ``m [*b, D, D]`` and ``v [*batch, D]`` (``b`` broadcasting)."""
    return (m @ v[..., None])[..., 0]


__all__ = ["affine_dmp"]
