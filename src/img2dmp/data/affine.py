"""Joint affine transforms of images and pen paths, so that both stay aligned.

One helper for the synthetic and the MNIST pipelines. A transform is a ``[2, 3]`` matrix
``M = [A | b]`` acting on pixel coordinates ``p = (x, y)`` (x = column, y = row, pixel
``[i, j]`` centred at ``(j, i)``, as in ``docs/CONTRACTS.md``)::

    p' = A p + b

Points are mapped forwards by :func:`warp_points`. :func:`warp_images` fills each output
pixel ``p'`` with the input sampled at ``A^-1 (p' - b)`` (bilinear, background outside),
which is the same map: ink at ``p`` in the input appears at ``p'`` in the output;
:func:`warp_images_numpy` does the same in NumPy. The module imports torch only when a
torch function runs, so that prediction without torch can warp images too.

:func:`sample_affine` draws the paper's data-augmentation transform: translation,
rotation, scaling and shearing, each uniform in a configurable range, composed about the
image centre ``c``::

    p' = c + t + R(rotation) @ Sh(shear) @ (scale * (p - c))

with ``Sh = [[1, tan(shear)], [0, 1]]`` (a horizontal shear, like slanted writing).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch


def _check_range(name: str, r, lo_limit: float = -math.inf, hi_limit: float = math.inf):
    try:
        lo, hi = (float(v) for v in r)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (low, high), got {r!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
        raise ValueError(f"{name} must be a finite range with low <= high, got {r!r}")
    if lo < lo_limit or hi > hi_limit:
        raise ValueError(f"{name} must lie within [{lo_limit}, {hi_limit}], got {r!r}")
    return lo, hi


@dataclass(frozen=True)
class AffineRanges:
    """Uniform ranges of the random affine transform (each a ``(low, high)`` pair).

    Parameters
    ----------
    translation_rel : (float, float)
        Shift in x and in y (drawn independently) as a fraction of the image width and
        height; default +-0.05 (+-2 px at 40 x 40).
    rotation_deg : (float, float)
        Rotation about the image centre in degrees (positive turns x towards y, i.e.
        clockwise on screen); default +-10.
    scale : (float, float)
        Isotropic scale factor (> 0); default 0.9-1.1.
    shear_deg : (float, float)
        Horizontal shear angle in degrees, within (-80, 80); default +-10.
    """

    translation_rel: tuple[float, float] = (-0.05, 0.05)
    rotation_deg: tuple[float, float] = (-10.0, 10.0)
    scale: tuple[float, float] = (0.9, 1.1)
    shear_deg: tuple[float, float] = (-10.0, 10.0)

    def __post_init__(self) -> None:
        for name in ("translation_rel", "rotation_deg", "scale", "shear_deg"):
            object.__setattr__(self, name, _check_range(name, getattr(self, name)))
        _check_range("translation_rel", self.translation_rel, -1.0, 1.0)
        if self.scale[0] <= 0:
            raise ValueError(f"scale must be > 0, got {self.scale!r}")
        _check_range("shear_deg", self.shear_deg, -80.0, 80.0)

    @classmethod
    def identity(cls) -> AffineRanges:
        """Ranges that always give the identity transform."""
        return cls((0.0, 0.0), (0.0, 0.0), (1.0, 1.0), (0.0, 0.0))

    def to_dict(self) -> dict:
        return {k: list(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> AffineRanges:
        unknown = set(d) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"unknown affine range field(s): {sorted(unknown)}")
        return cls(**{k: tuple(v) for k, v in d.items()})


def affine_matrix(image_size, translation_px, rotation_deg, scale, shear_deg) -> np.ndarray:
    """Matrices ``[*batch, 2, 3]`` of the composition in the module docstring.

    Parameters
    ----------
    image_size : (H, W)
    translation_px : array [*batch, 2]
        ``t = (tx, ty)`` in pixels.
    rotation_deg, scale, shear_deg : arrays [*batch]
    """
    h, w = image_size
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    rot, shear = np.deg2rad(rotation_deg), np.deg2rad(shear_deg)
    cr, sr, ts = np.cos(rot), np.sin(rot), np.tan(shear)
    s = np.asarray(scale, dtype=np.float64)
    # A = R @ Sh @ (s I); R = [[cr, -sr], [sr, cr]], Sh = [[1, ts], [0, 1]].
    a = np.stack(
        [np.stack([cr * s, (cr * ts - sr) * s], -1), np.stack([sr * s, (sr * ts + cr) * s], -1)],
        -2,
    )  # [*batch, 2, 2]
    b = c + np.asarray(translation_px, dtype=np.float64) - a @ c  # [*batch, 2]
    return np.concatenate([a, b[..., None]], -1)


def sample_affine(
    rng: np.random.Generator, n: int, image_size, ranges: AffineRanges | None = None
) -> np.ndarray:
    """Draw ``n`` random transforms with every parameter uniform in its range.

    Parameters
    ----------
    rng : numpy Generator
    n : int
        Number of transforms (>= 0).
    image_size : int or (H, W)
        Size of the images they will be applied to (sets the centre and the pixel
        translation).
    ranges : AffineRanges
        Default ``AffineRanges()``.

    Returns
    -------
    float64 array [n, 2, 3]
    """
    if not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n must be an integer >= 0, got {n!r}")
    h, w = (image_size, image_size) if isinstance(image_size, int) else image_size
    r = ranges or AffineRanges()
    u = rng.random((n, 5))  # [n, 5]; one fixed draw order keeps streams reproducible

    def pick(col, lohi):
        return lohi[0] + (lohi[1] - lohi[0]) * u[:, col]

    t = np.stack([pick(0, r.translation_rel) * w, pick(1, r.translation_rel) * h], -1)
    return affine_matrix((h, w), t, pick(2, r.rotation_deg), pick(3, r.scale), pick(4, r.shear_deg))


def _as_matrices(matrix, batch: tuple, dtype) -> torch.Tensor:
    from .render import _tensor

    m = _tensor(matrix).to(dtype)
    if m.shape[-2:] != (2, 3):
        raise ValueError(f"affine matrix must have shape [*batch, 2, 3], got {tuple(m.shape)}")
    if m.ndim == 2:
        m = m.expand(*batch, 2, 3)
    elif tuple(m.shape[:-2]) != batch:
        raise ValueError(
            f"affine matrices have batch shape {tuple(m.shape[:-2])}, the data has {batch}"
        )
    return m


def warp_points(points, matrix):
    """Map points forwards: ``p' = A p + b`` on the first two columns (x, y).

    Further columns (e.g. the pen state of ``d = 3`` paths) are passed through.

    Parameters
    ----------
    points : array or tensor [*batch, T, d], d >= 2
    matrix : array or tensor [*batch, 2, 3] or [2, 3]

    Returns
    -------
    Same kind as ``points`` (NumPy in, NumPy out), same dtype and shape.
    """
    import torch

    from .render import _tensor

    as_numpy = not torch.is_tensor(points)
    p = _tensor(points)
    if p.ndim < 2 or p.shape[-1] < 2:
        raise ValueError(f"points must have shape [*batch, T, d >= 2], got {tuple(p.shape)}")
    m = _as_matrices(matrix, tuple(p.shape[:-2]), torch.float64)
    xy = p[..., :2].to(torch.float64)  # [*batch, T, 2]
    out_xy = xy @ m[..., :2].transpose(-1, -2) + m[..., None, :, 2]
    out = torch.cat([out_xy.to(p.dtype), p[..., 2:]], -1)
    return out.numpy() if as_numpy else out


def warp_images(images, matrix) -> torch.Tensor:
    """Warp images by the forward map ``p' = A p + b`` (bilinear, background outside).

    Parameters
    ----------
    images : array or tensor [*batch, H, W]
    matrix : array or tensor [*batch, 2, 3] or [2, 3]

    Returns
    -------
    tensor float32 [*batch, H, W]
    """
    import torch
    import torch.nn.functional as F

    from .render import _tensor

    x = _tensor(images).to(torch.float32)
    if x.ndim < 2:
        raise ValueError(f"images must have shape [*batch, H, W], got {tuple(x.shape)}")
    shape = x.shape
    h, w = shape[-2:]
    m = _as_matrices(matrix, tuple(shape[:-2]), torch.float64).reshape(-1, 2, 3)  # [B, 2, 3]
    a_inv = torch.linalg.inv(m[:, :, :2])  # [B, 2, 2]
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij"
    )
    dst = torch.stack([xs, ys], -1).reshape(1, -1, 2)  # [1, H*W, 2]
    src = (dst - m[:, None, :, 2]) @ a_inv.transpose(-1, -2)  # [B, H*W, 2]
    # align_corners=True puts -1 and +1 on the centres of the first and last pixels.
    scale = torch.tensor([2.0 / max(w - 1, 1), 2.0 / max(h - 1, 1)], dtype=torch.float64)
    grid = (src * scale - 1.0).to(torch.float32).reshape(-1, h, w, 2)  # [B, H, W, 2]
    out = F.grid_sample(
        x.reshape(-1, 1, h, w), grid, mode="bilinear", padding_mode="zeros", align_corners=True
    )
    return out.reshape(shape)


def warp_images_numpy(images, matrix) -> np.ndarray:
    """:func:`warp_images` in NumPy (bilinear, zero outside; the same numbers to float32
    rounding), for prediction without torch.

    Parameters
    ----------
    images : array [*batch, H, W]
    matrix : array [*batch, 2, 3] or [2, 3]

    Returns
    -------
    float32 array [*batch, H, W]
    """
    x = np.asarray(images, dtype=np.float32)
    if x.ndim < 2:
        raise ValueError(f"images must have shape [*batch, H, W], got {x.shape}")
    h, w = x.shape[-2:]
    flat = x.reshape(-1, h, w)  # [B, H, W]
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape[-2:] != (2, 3):
        raise ValueError(f"affine matrix must have shape [*batch, 2, 3], got {m.shape}")
    m = np.broadcast_to(m, (*x.shape[:-2], 2, 3)).reshape(-1, 2, 3)  # [B, 2, 3]
    a_inv = np.linalg.inv(m[:, :, :2])  # [B, 2, 2]
    ys, xs = np.meshgrid(np.arange(h, dtype=np.float64), np.arange(w, dtype=np.float64),
                         indexing="ij")  # fmt: skip
    dst = np.stack([xs, ys], -1).reshape(1, -1, 2)  # [1, H*W, 2]
    src = (dst - m[:, None, :, 2]) @ a_inv.transpose(0, 2, 1)  # [B, H*W, 2]
    x0, y0 = np.floor(src[..., 0]), np.floor(src[..., 1])
    fx, fy = src[..., 0] - x0, src[..., 1] - y0
    b = np.arange(len(flat))[:, None]
    out = np.zeros(src.shape[:2])
    for dy, dx, wgt in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)),
                        (1, 0, (1 - fx) * fy), (1, 1, fx * fy)):  # fmt: skip
        xi, yi = (x0 + dx).astype(np.int64), (y0 + dy).astype(np.int64)
        inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
        out += np.where(inside, wgt * flat[b, yi.clip(0, h - 1), xi.clip(0, w - 1)], 0.0)
    return out.astype(np.float32).reshape(x.shape)
