"""The refinement of :func:`img2dmp.nn.refine.refine` in NumPy, with hand-derived gradients
(and a stroke model's, :func:`refine_strokes_numpy`).

For a one-image prediction that never imports torch. The same computation in float64:
Adam steps on the normalised DMP vectors ``z`` ``[B, P]`` that minimise, per sample,

    J(z) = lambda |z - z0|^2 / P + a A(y) + c C(y),   y = rollout(denormalise(z), t - t_0)

with the ink terms of :mod:`img2dmp.nn.ink`:

    A = sum_t m_t (D(y_t) + o(y_t))^2 / max(sum_t m_t, 1)
    C = sum_i a_i relu(|p_i - y_n(i)| - r)^2 / max(sum_i a_i, 1e-12)

``D`` the ink distance map read bilinearly as ``F.grid_sample(align_corners=True,
padding_mode="border")`` reads it, ``o`` the distance outside the image, ``m_t`` the
pen-down mask (pen >= 0.5 when d = 3), ``p_i`` the ink pixels of intensity ``a_i``,
``n(i)`` the pen-down path point nearest pixel i (an argmin: no gradient through it) and
``|.|`` the distance ``sqrt(|p - y|^2 + 1e-12)``. The gradient is assembled backwards:
``dJ/dy`` here, then :meth:`~img2dmp.dmp._numpy_rollout._Rollout.vjp` (w, tau, g, y0),
then :meth:`~img2dmp.nn.normalise.ParamNormaliser.denormalise_numpy_vjp`, plus the
prior's ``2 lambda (z - z0) / P``. The mask ``m`` and the argmin are constants, as in the
torch version, whose ``detach()`` they mirror; the pen channel gets no image gradient.
"""

from __future__ import annotations

import numpy as np

from ..dmp._numpy_rollout import _Rollout
from ..dmp.config import DMPConfig
from ._refine_options import MAX_REFINE_STEPS, RefineOptions  # re-exported here
from .normalise import ParamNormaliser

#: A pixel counts as ink above this intensity (images in [0, 1], ink = 1); the ink terms
#: of training (:mod:`img2dmp.nn.ink`) read it from here.
INK_THRESHOLD = 0.5


def ink_distance_map_numpy(images, threshold: float = INK_THRESHOLD) -> np.ndarray:
    """Distance (px) from every pixel to the nearest ink pixel, float32 ``[B, H, W]``.

    :func:`img2dmp.nn.ink.ink_distance_map` in NumPy: ``D(p) = min_{q: x_q > threshold}
    |p - q|`` (exact Euclidean distance transform, ``scipy.ndimage``), 0 on ink; an image
    without ink gets a map of zeros. Like the torch version, the intensities are compared
    and the distances kept in float32.
    """
    from scipy.ndimage import distance_transform_edt  # ~0.3 s to import: only when used

    x = np.asarray(images)
    if x.ndim != 3 or x.dtype.kind not in "iuf":
        raise ValueError(f"images must be real numbers [B, H, W], got {x.dtype} {x.shape}")
    x = x.astype(np.float32)  # [B, H, W]
    out = np.zeros_like(x)
    for b in range(x.shape[0]):  # one transform per image: scipy's is 2-D
        ink = x[b] > threshold
        if ink.any():
            out[b] = distance_transform_edt(~ink)
    return out


def _sample_map(maps: np.ndarray, points: np.ndarray):
    """Bilinear values of ``maps`` ``[B, H, W]`` at ``points`` ``[B, T, 2]`` (x, y in px)
    and their gradient ``[B, T, 2]``, as ``F.grid_sample(align_corners=True,
    padding_mode="border")`` and its backward define them.

    A coordinate is clipped to ``[0, size - 1]``; its gradient is zero where the clip
    holds it at either border (torch counts the border itself as outside). Inside,
    ``v = sum of the four corner values weighted by (1 - tx or tx)(1 - ty or ty)`` with
    ``tx = ix - floor(ix)``, and the derivative is the bilinear one of the cell
    ``[floor(ix), floor(ix) + 1]``: on a pixel line, that of the cell right of (below)
    it. A corner past the last row or column (weight 0) reads 0, as torch's does.
    """
    b, h, w = maps.shape
    x, y = points[..., 0], points[..., 1]  # [B, T]
    # Normalised to [-1, 1] and back, in torch's arithmetic (align_corners=True).
    sx, sy = 2.0 / max(w - 1, 1), 2.0 / max(h - 1, 1)
    ux, uy = (w - 1) / 2.0, (h - 1) / 2.0
    ix = (x * sx - 1.0 + 1.0) * ux
    iy = (y * sy - 1.0 + 1.0) * uy
    cx = np.minimum(np.maximum(ix, 0.0), w - 1.0)  # a NaN stays NaN
    cy = np.minimum(np.maximum(iy, 0.0), h - 1.0)
    in_x = (cx > 0) & (cx < w - 1)  # where the clip passes the gradient on
    in_y = (cy > 0) & (cy < h - 1)
    # fmax/fmin: a NaN coordinate reads a valid pixel; its NaN weight makes v NaN.
    x0 = np.fmin(np.fmax(np.floor(cx), 0.0), w - 1.0).astype(np.intp)
    y0 = np.fmin(np.fmax(np.floor(cy), 0.0), h - 1.0).astype(np.intp)
    tx, ty = cx - x0, cy - y0
    padded = np.zeros((b, h + 1, w + 1))  # the zero row and column past the image
    padded[:, :h, :w] = maps
    flat = padded.reshape(b, -1)
    at = y0 * (w + 1) + x0  # [B, T]
    v_nw = np.take_along_axis(flat, at, 1)
    v_ne = np.take_along_axis(flat, at + 1, 1)
    v_sw = np.take_along_axis(flat, at + w + 1, 1)
    v_se = np.take_along_axis(flat, at + w + 2, 1)
    rx, ry = 1.0 - tx, 1.0 - ty
    value = v_nw * rx * ry + v_ne * tx * ry + v_sw * rx * ty + v_se * tx * ty
    d_ix = ((v_ne - v_nw) * ry + (v_se - v_sw) * ty) * in_x
    d_iy = ((v_sw - v_nw) * rx + (v_se - v_ne) * tx) * in_y
    grad = np.stack([d_ix * ux * sx, d_iy * uy * sy], axis=-1)  # [B, T, 2]
    return value, grad


def _pen_down(y: np.ndarray) -> np.ndarray:
    """``[B, T]`` 1.0 where the pen is down (always for d = 2; pen >= 0.5 for d >= 3)."""
    if y.shape[-1] < 3:
        return np.ones(y.shape[:-1])
    return (y[..., 2] >= 0.5).astype(np.float64)


def _ink_attraction(y: np.ndarray, dist: np.ndarray):
    """``A`` ``[B]`` (module docstring) and ``dA/dy`` ``[B, T, 2]`` (x, y only).

    ``dA/dy_t = 2 m_t (D + o) (grad D + grad o) / max(sum m, 1)``, with
    ``o = relu(-x) + relu(x - (W - 1)) + relu(-y) + relu(y - (H - 1))`` whose gradient is
    -1 / +1 strictly outside and 0 on the border (relu'(0) = 0, as in torch).
    """
    h, w = dist.shape[-2:]
    pts = y[..., :2]  # [B, T, 2]
    d_map, g_map = _sample_map(dist, pts)
    size = np.array([w - 1.0, h - 1.0])
    below, above = pts < 0, pts > size  # [B, T, 2]
    outside = (np.maximum(-pts, 0.0) + np.maximum(pts - size, 0.0)).sum(-1)  # [B, T]
    g_out = above.astype(np.float64) - below
    m = _pen_down(y)
    total = np.maximum(m.sum(-1), 1.0)  # [B]
    d = d_map + outside
    value = (m * d * d).sum(-1) / total
    grad = (2.0 * m * d / total[:, None])[..., None] * (g_map + g_out)
    return value, grad


class _InkPixels:
    """The ink pixels of each image, padded to the batch's largest count with weight 0.

    ``xy`` ``[B, M, 2]`` (x = column, y = row), ``a`` ``[B, M]`` their intensities
    (``> threshold``), ``total`` ``[B]`` = ``max(sum a, 1e-12)``. Constant over the steps.
    """

    def __init__(self, images: np.ndarray, threshold: float):
        b, h, w = images.shape
        flat = images.reshape(b, h * w)
        weight = np.where(flat > threshold, flat, 0.0)
        m = max(int((weight > 0).sum(-1).max()) if b else 0, 1)
        # The M largest weights of each row: every ink pixel, then padding of weight 0.
        idx = np.argsort(-weight, axis=-1, kind="stable")[:, :m]  # [B, M]
        self.a = np.take_along_axis(weight, idx, 1)
        self.xy = np.stack([idx % w, idx // w], axis=-1).astype(np.float64)
        self.total = np.maximum(self.a.sum(-1), 1e-12)
        # Constant over the steps, for the squared distances of _ink_coverage: -2 p (a
        # power of two: -2 (p.y) is (-2 p).y exactly, one pass fewer per step) and |p|^2.
        self.xy_m2 = -2.0 * self.xy  # [B, M, 2]
        self.xy_sq = (self.xy * self.xy).sum(-1)[:, :, None]  # [B, M, 1]


def _ink_coverage(y: np.ndarray, ink: _InkPixels, tolerance_px: float):
    """``C`` ``[B]`` (module docstring) and ``dC/dy`` ``[B, T, 2]`` (x, y only).

    ``dC/dy_n(i) += 2 a_i relu(r_i - tol) (y_n(i) - p_i) / (r_i sum a)`` with ``r_i`` the
    smoothed distance to the nearest pen-down point ``n(i)``; nothing where no point is
    pen-down. The nearest point is found from squared distances in the matrix-product
    form ``|p|^2 + |y|^2 - 2 p.y`` (one batched product: three times faster than the
    exact differences, RESULTS 8.6), as torch's ``cdist`` finds it; the two may still
    round a product differently and so pick different points where two are equally near
    to ~1e-13 px^2 (see tests/test_numpy_inference.py). The distance itself is then taken
    exactly, from the point's offset.
    """
    b, n_t = y.shape[:2]
    pts = y[..., :2]  # [B, T, 2]
    up = _pen_down(y) < 0.5  # [B, T]
    d2 = np.matmul(ink.xy_m2, pts.transpose(0, 2, 1))  # [B, M, T], as torch's cdist: one product
    d2 += ink.xy_sq
    d2 += np.where(up, np.inf, (pts * pts).sum(-1))[:, None, :]  # pen-up points never nearest
    idx = np.argmin(d2, axis=-1)  # [B, M]; the first of equal ones, as torch's argmin
    none_down = up.all(-1)  # [B]
    near = np.take_along_axis(pts, idx[..., None], 1)  # [B, M, 2]
    offset = near - ink.xy  # [B, M, 2]
    smooth = np.sqrt((offset * offset).sum(-1) + 1e-12)  # [B, M], >= 1e-6
    nearest = np.where(none_down[:, None], 0.0, smooth)  # nothing pen-down: nothing covers
    gap = np.maximum(nearest - tolerance_px, 0.0)  # 0 where relu passes no gradient
    value = (ink.a * gap * gap).sum(-1) / ink.total
    g_near = (2.0 * ink.a * gap / (ink.total[:, None] * smooth))[..., None] * offset
    # Scatter each pixel's pull onto its nearest path point (bincount sums repeats).
    slot = (idx + n_t * np.arange(b)[:, None]).reshape(-1)  # [B*M]
    grad = np.stack(
        [np.bincount(slot, g_near[..., k].reshape(-1), minlength=b * n_t) for k in (0, 1)],
        axis=-1,
    ).reshape(b, n_t, 2)
    return value, grad


class _Adam:
    """Adam on one array, the arithmetic of :class:`img2dmp.nn.refine._Adam` (betas 0.9,
    0.999, eps 1e-8): ``m += (1 - b1)(g - m)``, ``v = b2 v + (1 - b2) g^2``,
    ``z -= lr / (1 - b1^n) * m / (sqrt(v) / sqrt(1 - b2^n) + eps)``. torch's fused
    ``lerp``/``addcmul`` round once where this rounds twice: the results agree to
    rounding, not bit for bit."""

    def __init__(self, shape, lr: float, betas=(0.9, 0.999), eps: float = 1e-8):
        self.lr, self.betas, self.eps = float(lr), betas, eps
        self.m = np.zeros(shape)  # first moment
        self.v = np.zeros(shape)  # second moment
        self.n = 0

    def step(self, z: np.ndarray, grad: np.ndarray) -> np.ndarray:
        (b1, b2), g = self.betas, grad
        self.n += 1
        self.m += (1 - b1) * (g - self.m)
        self.v = self.v * b2 + (1 - b2) * (g * g)
        bias1, bias2 = 1 - b1**self.n, 1 - b2**self.n
        denom = np.sqrt(self.v) / bias2**0.5 + self.eps
        return z + (-self.lr / bias1) * (self.m / denom)


def _check_inputs(z0, images, times, normaliser, config, options):
    """Float64 arrays of the checked inputs, or a ``ValueError`` naming the one at fault."""
    if not isinstance(normaliser, ParamNormaliser):
        raise ValueError(f"normaliser must be a ParamNormaliser, got {type(normaliser).__name__}")
    if not isinstance(config, DMPConfig):
        raise ValueError(f"config must be a DMPConfig, got {type(config).__name__}")
    if (normaliser.n_kernels, normaliser.n_dims) != (config.n_kernels, config.n_dims):
        raise ValueError(
            f"the normaliser is for N={normaliser.n_kernels}, d={normaliser.n_dims}, the "
            f"config for N={config.n_kernels}, d={config.n_dims}"
        )
    if config.n_dims < 2:
        raise ValueError(f"refinement needs paths in the image plane: d >= 2, got {config.n_dims}")
    if options is not None and not isinstance(options, RefineOptions):
        raise ValueError(f"options must be RefineOptions, got {type(options).__name__}")
    arrays = []
    for name, a, ndim in (("z0", z0, 2), ("images", images, 3), ("times", times, 2)):
        a = np.asarray(a)
        if a.dtype.kind not in "iuf":
            raise ValueError(f"{name} must hold real numbers, got dtype {a.dtype}")
        if a.ndim != ndim:
            raise ValueError(f"{name} must have {ndim} axes, got shape {a.shape}")
        arrays.append(a.astype(np.float64))  # a copy: nothing of the caller's is written
    z0, images, times = arrays
    b = z0.shape[0]
    if z0.shape[1] != normaliser.n_params:
        raise ValueError(f"z0 has shape {z0.shape}, expected [B, {normaliser.n_params}]")
    if images.shape[0] != b or times.shape[0] != b:
        raise ValueError(
            f"z0, images and times must have one row per sample, got {b}, "
            f"{images.shape[0]} and {times.shape[0]}"
        )
    if times.shape[1] == 0 or min(images.shape[1:]) == 0:
        raise ValueError(f"times {times.shape} and images {images.shape} must not be empty")
    return z0, images, times


def refine_numpy(
    z0,
    images,
    times,
    normaliser: ParamNormaliser,
    config: DMPConfig,
    options: RefineOptions | None = None,
) -> np.ndarray:
    """Normalised DMP vectors ``[B, P]`` refined on their images, in NumPy float64.

    :func:`img2dmp.nn.refine.refine` without torch: ``options.steps`` Adam steps on
    ``J(z) = lambda |z - z0|^2 / P + a A(y(z)) + c C(y(z))`` (module docstring), with
    the gradient derived by hand. Agrees with the torch version to rounding, except
    where an ink pixel is equally near two path points to rounding (the argmin of ``C``).

    Parameters
    ----------
    z0 : array [B, P]
        The network's output (one hypothesis per image), normalised units.
    images : array [B, H, W]
        The prepared images (ink = 1) the network saw.
    times : array [B, T]
        Time stamps at which the path is compared with the ink; each row is shifted to
        start at 0, as in :func:`img2dmp.nn.costs.dmp_trajectory`.
    normaliser : ParamNormaliser
        Maps ``z`` to the DMP's parameters.
    config : DMPConfig
        The DMP constants (``d >= 2``: x, y and optionally the pen).
    options : RefineOptions
        Steps, learning rate and weights; default ``RefineOptions()``.

    Returns
    -------
    ndarray [B, P]
        ``z0`` after the steps (float64, a new array).
    """
    z0, imgs, t = _check_inputs(z0, images, times, normaliser, config, options)
    o = options or RefineOptions()
    if o.steps == 0 or z0.shape[0] == 0:
        return z0
    t = t - t[:, :1]  # [B, T]
    n, d, b = config.n_kernels, config.n_dims, z0.shape[0]
    ti = n * d
    dist = ink_distance_map_numpy(imgs).astype(np.float64) if o.ink_weight else None
    ink = _InkPixels(imgs, INK_THRESHOLD) if o.coverage_weight else None
    z = z0.copy()
    adam = _Adam(z.shape, o.lr)
    prior = 2.0 * o.prior_weight / z.shape[1]
    for _ in range(int(o.steps)):
        v = normaliser.denormalise_numpy(z)  # [B, P]
        w = v[:, :ti].reshape(b, d, n).transpose(0, 2, 1)  # [B, N, d]
        roll = _Rollout(w, v[:, ti], v[:, ti + 1 : ti + 1 + d], v[:, ti + 1 + d :], t, config)
        grad_y = np.zeros_like(roll.y)  # [B, T, d]; the pen channel gets none
        if o.ink_weight:
            grad_y[..., :2] += o.ink_weight * _ink_attraction(roll.y, dist)[1]
        if o.coverage_weight:
            grad_y[..., :2] += (
                o.coverage_weight * _ink_coverage(roll.y, ink, o.coverage_tolerance_px)[1]
            )
        gw, gtau, gg, gy0 = roll.vjp(grad_y)
        grad_v = np.concatenate([gw.transpose(0, 2, 1).reshape(b, ti), gtau[:, None], gg, gy0], 1)
        grad_z = normaliser.denormalise_numpy_vjp(z, grad_v) + prior * (z - z0)
        z = adam.step(z, grad_z)
    return z


def refine_strokes_numpy(strokes: list, images, normaliser: ParamNormaliser, layout,
                         options: RefineOptions | None = None) -> list:  # fmt: skip
    """:func:`img2dmp.nn.strokes.refine_strokes` without torch, in NumPy float64.

    Per character, Adam steps on all of its stroke vectors at once (padded to the
    batch's most strokes, ``z [B, S, P]``) that minimise

        J = lambda mean_s |z_s - z0_s|^2 / P + a A(y) + c C(y),

    the prior averaged over the character's strokes and the ink terms (module
    docstring) on the union of its strokes: each stroke rolled out at
    ``layout.n_points`` instants over its own tau (``t = u tau``), pen down on its
    strokes, up on the padding. A stroke's shape does not depend on its tau (the DMP
    runs on ``t / tau``), so tau gets no gradient, as torch's (to rounding) gets none.

    Parameters
    ----------
    strokes : list of (vectors [c_i, P], presence [c_i])
        :func:`~img2dmp.nn._stroke_layout.read_strokes`' characters.
    images : array [B, H, W]
        Their prepared images (ink = 1).
    normaliser : ParamNormaliser
        Maps a stroke vector to its DMP's parameters.
    layout : StrokeLayout
        The stroke model's layout (``n_points``, its 2-D DMP constants).
    options : RefineOptions
        Default ``RefineOptions()``.

    Returns
    -------
    list
        The same shape, each character's vectors replaced (float64).
    """
    o = options or RefineOptions()
    if o.steps == 0 or not strokes:
        return strokes
    p, n, cfg = layout.n_params, layout.n_points, layout.config
    s_max = max(len(v) for v, _ in strokes)
    imgs = np.asarray(images, dtype=np.float64)
    if imgs.ndim != 3 or len(imgs) != len(strokes):
        raise ValueError(f"images must be [B, H, W] with B = {len(strokes)} characters, "
                         f"got shape {imgs.shape}")  # fmt: skip
    if s_max == 0:
        return strokes
    b, k, d = len(strokes), cfg.n_kernels, cfg.n_dims
    ti = k * d
    z0, mask = np.zeros((b, s_max, p)), np.zeros((b, s_max))
    for i, (v, _) in enumerate(strokes):
        z0[i, : len(v)] = np.asarray(v, dtype=np.float64)
        mask[i, : len(v)] = 1.0
    pen = np.repeat(mask, n, axis=1)[..., None]  # [B, S n, 1]: up on the padding
    prior = 2.0 * o.prior_weight / p * (mask / np.maximum(mask.sum(-1, keepdims=True), 1.0))
    dist = ink_distance_map_numpy(imgs).astype(np.float64) if o.ink_weight else None
    ink = _InkPixels(imgs, INK_THRESHOLD) if o.coverage_weight else None
    u = np.linspace(0.0, 1.0, n)
    z = z0.copy()
    adam = _Adam(z.shape, o.lr)
    for _ in range(int(o.steps)):
        flat = z.reshape(b * s_max, p)
        v = normaliser.denormalise_numpy(flat)  # [B S, P]
        w = v[:, :ti].reshape(-1, d, k).transpose(0, 2, 1)  # [B S, N, d]
        tau = v[:, ti]
        roll = _Rollout(w, tau, v[:, ti + 1 : ti + 1 + d], v[:, ti + 1 + d :],
                        u[None] * tau[:, None], cfg)  # fmt: skip
        y = np.concatenate([roll.y.reshape(b, s_max * n, d), pen], -1)  # [B, S n, 3]
        grad_y = np.zeros((b, s_max * n, d))
        if o.ink_weight:
            grad_y[..., :2] += o.ink_weight * _ink_attraction(y, dist)[1]
        if o.coverage_weight:
            grad_y[..., :2] += o.coverage_weight * _ink_coverage(y, ink, o.coverage_tolerance_px)[1]
        gw, _, gg, gy0 = roll.vjp(grad_y.reshape(b * s_max, n, d))
        grad_v = np.concatenate(
            [gw.transpose(0, 2, 1).reshape(-1, ti), np.zeros((len(v), 1)), gg, gy0], 1
        )
        grad_z = normaliser.denormalise_numpy_vjp(flat, grad_v).reshape(b, s_max, p)
        z = adam.step(z, grad_z + prior[..., None] * (z - z0))
    return [(z[i, : len(v)], pr) for i, (v, pr) in enumerate(strokes)]


__all__ = [
    "INK_THRESHOLD",
    "MAX_REFINE_STEPS",
    "RefineOptions",
    "ink_distance_map_numpy",
    "refine_numpy",
    "refine_strokes_numpy",
]
