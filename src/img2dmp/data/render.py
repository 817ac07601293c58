"""Drawing pen paths into images: the one rendering function, blur and noise.

Coordinates follow ``docs/CONTRACTS.md``: a point ``(x, y)`` is column x, row y, and the
centre of pixel ``[i, j]`` is ``(x=j, y=i)``. Images are float32, ink = 1.

:func:`render_paths` models the pen as a stroke with a soft (anti-aliased) edge. Along
the polyline, points carry Gaussian footprints of standard deviation ``sigma`` weighted by
the arc length they stand for, so their sum approximates the line integral

    I(p) = int exp(-|p - c(s)|^2 / (2 sigma^2)) ds / (sqrt(2 pi) sigma)

which, across a straight stroke, is ``exp(-r^2 / (2 sigma^2))`` at distance ``r`` from the
centre line, whatever the writing speed. The ink is ``clip(A I, 0, 1)`` with ``A`` chosen
so that the stroke is half-inked at ``r = w / 2``: the pen width ``w`` is the full width
at half ink, and the ink per unit length of stroke comes to about ``w``. Gaussians are
separable, so each image is one small matrix product (GEMM)::

    I = Gy^T diag(weights) Gx,   Gx[t, j] = exp(-(x_t - j)^2 / (2 sigma^2))   # [T, W]
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..config import check_positive

# Floats per rendering chunk (bounds the [chunk, T, H + W] footprint tensors).
_MAX_ELEMENTS = 1 << 20
# Points along a segment are at most this many sigmas apart (ripple of the sum ~1e-8).
_MAX_SPACING_SIGMAS = 1.0
# Largest side of a rendered image, pixels.
MAX_IMAGE_SIDE = 4096
# Most footprints along one path (the points and the sub-points of its segments): a
# segment far outside the image would otherwise be cut into millions of sub-points.
MAX_FOOTPRINTS_PER_PATH = 1_000_000


def _size2(size) -> tuple[int, int]:
    bad = ValueError(
        f"image size must be positive integers (H, W) of at most {MAX_IMAGE_SIDE} px, got {size!r}"
    )
    if isinstance(size, (int, np.integer)):
        size = (int(size), int(size))
    try:
        h, w = (int(s) for s in size)
    except (TypeError, ValueError):
        raise bad from None
    if not (1 <= h <= MAX_IMAGE_SIDE and 1 <= w <= MAX_IMAGE_SIDE) or tuple(size) != (h, w):
        raise bad
    return h, w


def _tensor(a) -> torch.Tensor:
    """A tensor view of ``a`` (read-only arrays, e.g. broadcasts, are copied)."""
    if torch.is_tensor(a):
        return a
    a = np.asarray(a)
    return torch.from_numpy(a if a.flags.writeable else a.copy())


def render_paths(
    points,
    image_size: int | tuple[int, int] = 40,
    pen_width_px: float = 2.4,
    pen_down=None,
    *,
    edge_sigma_px: float = 0.7,
) -> torch.Tensor:
    """Render a batch of pen paths as anti-aliased strokes (see the module docstring).

    Parameters
    ----------
    points : array or tensor [*batch, T, 2] (or [*batch, T, 3] with a pen channel)
        Pen positions in pixels. With 3 columns the third is the pen state (1 down,
        0 up, thresholded at 0.5) and ``pen_down`` must be None.
    image_size : int or (H, W)
        Size of the output images; ink outside them is cut off.
    pen_width_px : float
        Stroke width in pixels (full width at half ink), > 0.
    pen_down : bool array [*batch, T], optional
        Pen state per point. The segment from point i to i+1 is drawn when the pen is
        down at both ends; a pen-down point with no drawn segment is drawn as a dot.
        Default: all down.
    edge_sigma_px : float
        Softness of the stroke's edge (standard deviation of the footprint), > 0; raised
        to ``pen_width_px / 8`` for wide pens so the gain ``A`` stays bounded.

    Returns
    -------
    tensor float32 [*batch, H, W]
        Ink = 1, background = 0.
    """
    h, w = _size2(image_size)
    check_positive("pen_width_px", pen_width_px)
    check_positive("edge_sigma_px", edge_sigma_px)
    pts, pen, batch = _points_and_pen(points, pen_down)
    sigma = max(float(edge_sigma_px), pen_width_px / 8.0)
    gain = 0.5 * math.exp(pen_width_px**2 / (8.0 * sigma**2))  # A: half ink at r = w / 2
    seg_len = torch.linalg.vector_norm(pts[:, 1:] - pts[:, :-1], dim=-1)  # [B, T-1]
    drawn = pen[:, 1:] & pen[:, :-1] & (seg_len > 0)  # [B, T-1] segments on paper
    longest = float(seg_len[drawn].max()) if bool(drawn.any()) else 0.0
    # Beyond this distance A * exp(-r^2 / (2 sigma^2)) < 1e-3: footprints are cut there.
    reach = sigma * math.sqrt(2.0 * math.log(1000.0 * max(gain, 1.0)))
    n_sub = max(1, math.ceil(longest / (_MAX_SPACING_SIGMAS * sigma)))
    footprints = (pts.shape[1] - 1) * n_sub + 1
    if footprints > MAX_FOOTPRINTS_PER_PATH:
        raise ValueError(
            f"points: paths of {pts.shape[1]} points with a drawn segment {longest:.4g} px "
            f"long need {footprints} footprints each, more than {MAX_FOOTPRINTS_PER_PATH}; "
            f"are points far outside the {h} x {w} image?"
        )
    out = torch.empty(pts.shape[0], h, w, dtype=torch.float32)
    per_sample = footprints * (h + w)
    chunk = max(1, _MAX_ELEMENTS // per_sample)
    for lo in range(0, pts.shape[0], chunk):
        sl = slice(lo, lo + chunk)
        q, wt = _footprints(pts[sl], pen[sl], drawn[sl], seg_len[sl], n_sub, sigma)
        gx = _footprint_1d(q[..., 0], w, sigma, reach)  # [b, T', W]
        gy = _footprint_1d(q[..., 1], h, sigma, reach)  # [b, T', H]
        img = torch.bmm(gy.transpose(1, 2), wt[..., None] * gx)  # [b, H, W]
        out[sl] = (img * (gain / (math.sqrt(2.0 * math.pi) * sigma))).clamp_(0.0, 1.0)
    return out.reshape(*batch, h, w)


def _points_and_pen(points, pen_down) -> tuple[torch.Tensor, torch.Tensor, tuple]:
    """Checked points ``[B, T, 2]``, pen states ``[B, T]`` and the batch shape."""
    pts = _tensor(points).to(torch.float32)
    if pts.ndim < 2 or pts.shape[-1] not in (2, 3):
        raise ValueError(f"points must have shape [*batch, T, 2 or 3], got {tuple(pts.shape)}")
    if pts.shape[-2] < 1:
        raise ValueError("points must hold at least one point per path")
    batch = tuple(pts.shape[:-2])
    if pts.shape[-1] == 3:
        if pen_down is not None:
            raise ValueError("give the pen state either as a third column or as pen_down")
        pen = pts[..., 2] >= 0.5
        pts = pts[..., :2]
    elif pen_down is None:
        pen = torch.ones(pts.shape[:-1], dtype=torch.bool)
    else:
        pen = _tensor(pen_down).to(torch.bool)
        if tuple(pen.shape) != tuple(pts.shape[:-1]):
            raise ValueError(
                f"pen_down has shape {tuple(pen.shape)}, expected {tuple(pts.shape[:-1])}"
            )
    if not bool(torch.isfinite(pts).all()):
        raise ValueError("points contain NaN or inf")
    return pts.reshape(-1, *pts.shape[-2:]), pen.reshape(-1, pen.shape[-1]), batch


def _footprint_1d(c: torch.Tensor, n: int, sigma: float, reach: float) -> torch.Tensor:
    """``exp(-(c - k)^2 / (2 sigma^2))`` for k = 0..n-1, zero beyond ``reach``: [*c, n].

    Only the few pixels within reach of each coordinate are evaluated, then scattered
    into the dense rows the matrix product wants.
    """
    r = math.ceil(reach)
    k = 2 * r + 2
    if k >= n:
        grid = torch.arange(n, dtype=torch.float32)
        g = (c[..., None] - grid).square_().mul_(-0.5 / sigma**2).exp_()
        return g.masked_fill_((c[..., None] - grid).abs() > reach, 0.0)
    idx = torch.floor(c)[..., None] - r + torch.arange(k, dtype=torch.float32)  # [*c, k]
    d = c[..., None] - idx
    g = d.square().mul_(-0.5 / sigma**2).exp_()
    g.masked_fill_((d.abs() > reach) | (idx < 0) | (idx >= n), 0.0)
    out = torch.zeros(*c.shape, n, dtype=torch.float32)
    # Window cells outside the image carry 0 and land, clamped, on an edge pixel.
    out.scatter_add_(-1, idx.clamp_(0, n - 1).long(), g)
    return out


def _footprints(pts, pen, drawn, seg_len, n_sub, sigma):
    # Points [b, T', 2] at which footprints sit and their weights [b, T'] (arc length).
    b, t = pen.shape
    if n_sub > 1:
        f = torch.arange(n_sub, dtype=torch.float32) / n_sub  # [n_sub]
        seg = pts[:, :-1, None] + f[:, None] * (pts[:, 1:] - pts[:, :-1])[:, :, None]
        q = torch.cat([seg.reshape(b, -1, 2), pts[:, -1:]], 1)  # [b, (T-1) n_sub + 1, 2]
        sub_len = (seg_len * drawn / n_sub).repeat_interleave(n_sub, dim=1)  # [b, (T-1) n_sub]
    else:
        q = pts
        sub_len = seg_len * drawn  # [b, T-1]
    zero = torch.zeros(b, 1)
    wt = 0.5 * (torch.cat([zero, sub_len], 1) + torch.cat([sub_len, zero], 1))  # [b, T']
    # A pen-down point touching no drawn segment is a dot: one footprint of full weight.
    has_seg = torch.zeros_like(pen)
    has_seg[:, 1:] |= drawn
    has_seg[:, :-1] |= drawn
    # Repeats of a pen-down point (zero-length segments) make one dot, not several.
    repeat = torch.zeros_like(pen)
    repeat[:, 1:] = pen[:, 1:] & pen[:, :-1] & (seg_len == 0)
    dot = (pen & ~has_seg & ~repeat).to(torch.float32) * (math.sqrt(2.0 * math.pi) * sigma)
    wt[:, ::n_sub] += dot
    return q, wt


def _gaussian_matrix(n: int, sigma_px: float) -> torch.Tensor:
    # [n, n] band matrix: row i holds the truncated, normalised kernel centred on i.
    r = max(1, int(math.ceil(3 * sigma_px)))
    g = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=torch.float32) / sigma_px) ** 2)
    g = g / g.sum()
    i = torch.arange(n)
    off = i[None, :] - i[:, None]  # [n, n] column minus row
    return torch.where(off.abs() <= r, g[(off + r).clamp(0, 2 * r)], torch.zeros(()))


def gaussian_filter(images, sigma_px: float) -> torch.Tensor:
    """Blur images with an isotropic Gaussian of standard deviation ``sigma_px``.

    Separable: ``Ky @ X @ Kx^T`` with band matrices ``K`` (kernel truncated at 3 sigma
    and normalised to sum 1), so the border behaves as if padded with background (0).
    ``sigma_px = 0`` returns a copy.

    Parameters
    ----------
    images : array or tensor [*batch, H, W]

    Returns
    -------
    tensor float32 [*batch, H, W]
    """
    if not (isinstance(sigma_px, (int, float)) and math.isfinite(sigma_px)) or sigma_px < 0:
        raise ValueError(f"sigma_px must be a finite number >= 0, got {sigma_px!r}")
    x = _tensor(images).to(torch.float32)
    if x.ndim < 2:
        raise ValueError(f"images must have shape [*batch, H, W], got {tuple(x.shape)}")
    widest = 4 * max(x.shape[-2:])
    if sigma_px > widest:  # the kernel's length grows with it
        raise ValueError(
            f"sigma_px must be in [0, {widest}] (4 times the image's side), got {sigma_px!r}"
        )
    if sigma_px == 0:
        return x.clone()
    ky = _gaussian_matrix(x.shape[-2], sigma_px)  # [H, H]
    kx = _gaussian_matrix(x.shape[-1], sigma_px)  # [W, W]
    return ky @ x @ kx.T


def salt_and_pepper(
    images,
    amount: float,
    rng: np.random.Generator,
    *,
    salt_fraction: float = 0.5,
    foreground_threshold: float = 0.1,
) -> torch.Tensor:
    """Salt-and-pepper noise on the foreground: ink pixels set at random to 1 or 0.

    Each pixel whose value exceeds ``foreground_threshold`` is hit with probability
    ``amount``; a hit pixel becomes 1 (salt) with probability ``salt_fraction``, else 0
    (pepper). Background pixels are left alone, so the noise stays on the writing.

    Parameters
    ----------
    images : array or tensor [*batch, H, W] in [0, 1]
    amount : float in [0, 1]
    rng : numpy Generator
        Source of randomness (reproducible given its seed).

    Returns
    -------
    tensor float32 [*batch, H, W]
    """
    for name, v in (
        ("amount", amount),
        ("salt_fraction", salt_fraction),
        ("foreground_threshold", foreground_threshold),
    ):
        if not (isinstance(v, (int, float)) and 0 <= v <= 1):
            raise ValueError(f"{name} must be a number in [0, 1], got {v!r}")
    x = _tensor(images).to(torch.float32).clone()
    if amount == 0:
        return x
    draw = torch.from_numpy(rng.random((2, *x.shape), dtype=np.float32))  # [2, *batch, H, W]
    hit = (x > foreground_threshold) & (draw[0] < amount)
    x[hit] = (draw[1][hit] < salt_fraction).to(torch.float32)
    return x
