"""Image-consistency terms: a predicted path should lie on the ink and cover it.

The image itself says where the pen went, so these terms need no recorded path (they can
train on images that have none, and refine a prediction at inference time):

- :func:`ink_attraction` pulls every pen-down point of the path onto the ink: the
  squared distance to the nearest ink pixel, read bilinearly from a distance map
  (:func:`ink_distance_map`), plus the distance outside the image.
- :func:`ink_coverage` asks the path to reach all the ink: for every ink pixel, weighted
  by its intensity, the squared distance to the nearest path point beyond a tolerance
  (half a pen width: the edge of a stroke is that far from its centre line).

Both are in px^2 per sample, like cost (10), and differentiable in the path.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ._refine_numpy import INK_THRESHOLD, ink_distance_map_numpy


@torch.no_grad()
def ink_distance_map(images: torch.Tensor, threshold: float = INK_THRESHOLD) -> torch.Tensor:
    """Distance (px) from every pixel to the nearest ink pixel, ``[B, H, W]``.

    0 on ink (intensity > ``threshold``); an image without ink gets a map of zeros, so
    it pulls nowhere. Exact Euclidean distance transform
    (:func:`img2dmp.nn._refine_numpy.ink_distance_map_numpy`, the one computation).
    """
    x = images.detach().to("cpu", torch.float32).numpy()  # [B, H, W]
    return torch.from_numpy(ink_distance_map_numpy(x, threshold)).to(images.device)


def _pen_down(y: torch.Tensor) -> torch.Tensor:
    """Weights ``[B, T]``: 1 where the pen is down (always for d = 2; pen >= 0.5 for d = 3)."""
    if y.shape[-1] < 3:
        return y.new_ones(y.shape[:-1])
    return (y[..., 2].detach() >= 0.5).to(y.dtype)


def sample_map(maps: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Bilinear values ``[B, T]`` of maps ``[B, H, W]`` at points ``[B, T, 2]`` (x, y in
    pixels, pixel ``[i, j]``'s centre at ``(j, i)``); the border value outside."""
    h, w = maps.shape[-2:]
    gx = points[..., 0] * (2.0 / max(w - 1, 1)) - 1.0
    gy = points[..., 1] * (2.0 / max(h - 1, 1)) - 1.0
    grid = torch.stack([gx, gy], dim=-1)[:, :, None, :]  # [B, T, 1, 2]
    v = F.grid_sample(
        maps[:, None].to(points.dtype), grid, align_corners=True, padding_mode="border"
    )
    return v[:, 0, :, 0]  # [B, T]


def _outside_px(points: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """How far (px, per axis summed) points ``[B, T, 2]`` lie outside the image."""
    x, y = points[..., 0], points[..., 1]
    return F.relu(-x) + F.relu(x - (w - 1)) + F.relu(-y) + F.relu(y - (h - 1))


def ink_attraction(y: torch.Tensor, distance_map: torch.Tensor) -> torch.Tensor:
    """Mean squared distance (px^2) of the pen-down points to the ink, per sample.

    ``A_b = sum_t m_t (D_b(y_t) + o(y_t))^2 / sum_t m_t`` with ``D_b`` the distance map
    read bilinearly, ``o`` the distance outside the image and ``m_t`` the pen-down mask.

    Parameters
    ----------
    y : tensor [B, T, d]
        Paths in pixels (d = 2, or 3 with the pen channel).
    distance_map : tensor [B, H, W]
        :func:`ink_distance_map` of the images.

    Returns
    -------
    tensor [B]
    """
    h, w = distance_map.shape[-2:]
    pts = y[..., :2]
    d = sample_map(distance_map, pts) + _outside_px(pts, h, w)  # [B, T]
    m = _pen_down(y)
    return (m * d**2).sum(-1) / m.sum(-1).clamp_min(1.0)


def _ink_pixels(images: torch.Tensor, threshold: float):
    """Coordinates ``[B, M, 2]`` and weights ``[B, M]`` of each image's ink pixels (the
    M = most inked pixels of any image in the batch; padding has weight 0)."""
    b, h, w = images.shape
    flat = images.detach().reshape(b, h * w)
    weight = torch.where(flat > threshold, flat, torch.zeros_like(flat))
    m = int((weight > 0).sum(-1).max().item()) if b else 0
    m = max(m, 1)
    weight, idx = torch.topk(weight, m, dim=-1)  # [B, M]
    xy = torch.stack([idx % w, idx // w], dim=-1)  # [B, M, 2], x = column, y = row
    return xy, weight


def ink_coverage(
    y: torch.Tensor,
    images: torch.Tensor,
    threshold: float = INK_THRESHOLD,
    tolerance_px: float = 1.0,
) -> torch.Tensor:
    """How much ink the path leaves unvisited (px^2), per sample.

    ``C_b = sum_i a_i relu(min_t |p_i - y_t| - r)^2 / sum_i a_i`` over ink pixels ``p_i``
    (intensity ``a_i > threshold``) and pen-down points ``y_t``; ``r`` = ``tolerance_px``.

    Parameters
    ----------
    y : tensor [B, T, d]
    images : tensor [B, H, W]
        In [0, 1], ink = 1 (what the network saw).

    Returns
    -------
    tensor [B]; 0 for an image without ink.
    """
    xy, a = _ink_pixels(images, threshold)  # [B, M, 2], [B, M]
    xy = xy.to(y.dtype)
    a = a.to(y.dtype)
    up = _pen_down(y) < 0.5  # [B, T]
    pts = y[..., :2]
    with torch.no_grad():  # which path point is nearest each ink pixel (no gradient needed)
        dist = torch.cdist(xy, pts.detach().contiguous())  # [B, M, T], matrix-product form
        if bool(up.any()):  # a 2-D path is all pen-down: no copy of the [B, M, T] table
            dist = dist.masked_fill(up[:, None, :], float("inf"))
        idx = dist.argmin(dim=-1)  # [B, M]
        none_down = up.all(dim=-1)  # [B]: no pen-down point, nothing covers
    near = torch.gather(pts, 1, idx[..., None].expand(-1, -1, 2))  # [B, M, 2], differentiable
    nearest = torch.sqrt(((xy - near) ** 2).sum(-1) + 1e-12)  # [B, M]
    nearest = nearest.masked_fill(none_down[:, None], 0.0)
    gap = F.relu(nearest - tolerance_px)
    return (a * gap**2).sum(-1) / a.sum(-1).clamp_min(1e-12)


__all__ = [
    "INK_THRESHOLD",
    "ink_attraction",
    "ink_coverage",
    "ink_distance_map",
    "sample_map",
]
