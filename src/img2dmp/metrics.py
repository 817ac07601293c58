"""Order- and timing-free measures of whether a path writes the digit in an image.

An image shows where the ink is, not how fast or in which order it was laid down. Table I
of Pahič et al. compares positions at the demonstration's own time stamps; the measures
here compare only *where* the pen went (NumPy only, no torch):

- :func:`resample_by_arc_length` - evenly spaced points along the pen-down path;
- :func:`path_error_px` - both paths resampled from start to end, point to point;
- :func:`chamfer_px` - symmetric Chamfer distance, free of order and direction;
- :func:`on_ink_share` - share of the path that lies on the image's ink;
- :func:`ink_written_share` - share of the image's ink that the path writes;
- :func:`enclosed_area_px2`, :func:`area_ratio` - the area a closed digit encloses
  (:func:`closed_labels`: which labels of a data set are closed digits);
- :func:`width_ratio`, :func:`start_error_px` - horizontal extent, where writing starts.

Conventions (``docs/CONTRACTS.md``): paths are ``[M, T, d]`` in image pixels, x = column,
y = row, the centre of pixel ``[i, j]`` at ``(x=j, y=i)``; only x and y are compared. With
``d >= 3`` the third channel is the pen, down where ``pen >= 0.5``: a segment is drawn
when the pen is down at both of its ends (as :func:`img2dmp.data.render.render_paths`
draws it), so pen-up travel is not part of the path. A path whose pen is never down is
taken whole (as if written), so that every measure stays finite.
"""

from __future__ import annotations

import numpy as np

#: Digits whose usual shape encloses an area (reported by :func:`area_ratio`).
CLOSED_DIGITS = (0, 6, 8, 9)


def closed_labels(label_names=None) -> tuple[int, ...]:
    """The labels whose class is a closed digit (:data:`CLOSED_DIGITS`).

    ``label_names`` is the name of every label (a data set's ``label_names``); None means
    the labels are the digits 0-9 themselves. A data set of other classes (letters,
    shapes) names no closed digit unless a class is called ``"0"``, ``"6"``, ``"8"`` or
    ``"9"``: its area ratio is not reported.
    """
    if label_names is None:
        return CLOSED_DIGITS
    closed = {str(d) for d in CLOSED_DIGITS}
    return tuple(i for i, name in enumerate(label_names) if name in closed)


# Elements per chunk of the batched [m, n, n] / [m, R, S] temporaries (~16 MB of float64).
_CHUNK_ELEMENTS = 1 << 21


def _paths(paths, name: str = "paths") -> np.ndarray:
    p = np.asarray(paths, dtype=np.float64)
    if p.ndim != 3 or p.shape[1] < 1 or p.shape[2] < 2:
        raise ValueError(f"{name} must have shape [M, T, d] with d >= 2, got {p.shape}")
    return p


def _pair(a, b) -> tuple[np.ndarray, np.ndarray]:
    pa, pb = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if pa.ndim != 3 or pb.ndim != 3 or len(pa) != len(pb) or min(pa.shape[2], pb.shape[2]) < 2:
        raise ValueError(f"paths must both have shape [M, T, 2+], got {pa.shape} and {pb.shape}")
    return pa, pb


def pen_down(paths) -> np.ndarray:
    """Pen-down mask ``[M, T]`` of paths ``[M, T, d]``.

    All points for ``d = 2``; ``pen >= 0.5`` for ``d >= 3``. A path whose pen is never
    down counts as down everywhere (taken whole).
    """
    p = _paths(paths)
    if p.shape[2] < 3:
        return np.ones(p.shape[:2], dtype=bool)
    down = p[..., 2] >= 0.5  # [M, T]
    return down | ~down.any(axis=1, keepdims=True)


def arc_fractions(paths) -> np.ndarray:
    """Share ``[M, T]`` of each path's length ``[M, T, 2]`` covered at each of its points.

    ``lambda_t = L_t / L_T`` with ``L_t = sum_{s < t} |p_{s+1} - p_s|`` (all columns of
    ``paths``; pass x, y only).
    """
    paths = np.asarray(paths, dtype=np.float64)
    seg = np.linalg.norm(np.diff(paths, axis=1), axis=-1)
    length = np.concatenate([np.zeros((len(paths), 1)), np.cumsum(seg, axis=1)], axis=1)
    return length / np.maximum(length[:, -1:], 1e-12)


def points_at_fractions(path, fractions_of_path, fractions) -> np.ndarray:
    """Points ``[K, 2]`` of one path ``[T, 2]`` (arc fractions ``[T]``) at ``fractions``.

    Linear interpolation along the path; points where the pen did not move are skipped.
    """
    keep = np.concatenate([[True], np.diff(fractions_of_path) > 0])  # np.interp: increasing
    f = fractions_of_path[keep]
    return np.stack([np.interp(fractions, f, path[keep, k]) for k in range(2)], axis=-1)


def _drawn_fractions(xy: np.ndarray, down: np.ndarray):
    """Arc fractions ``[M, T]`` along the drawn segments and the drawn mask ``[M, T-1]``."""
    drawn = down[:, :-1] & down[:, 1:]  # [M, T-1]: pen down at both ends
    seg = np.where(drawn, np.linalg.norm(np.diff(xy, axis=1), axis=-1), 0.0)  # [M, T-1]
    length = np.concatenate([np.zeros((len(xy), 1)), np.cumsum(seg, axis=1)], axis=1)
    return length / np.maximum(length[:, -1:], 1e-12), drawn


def _resample_one(xy, lam, drawn, down, grid) -> np.ndarray:
    """Points ``[n, 2]`` of one path ``xy [T, 2]`` at arc fractions ``grid [n]``.

    The formula of ``np.interp`` on the segments that advance the arc length, so that a
    single-stroke path gives exactly :func:`points_at_fractions`'s points.
    """
    moves = drawn & (lam[1:] > lam[:-1])  # [T-1] segments that advance the pen
    if not moves.any():  # a dot (or a pen that never moved): its first pen-down point
        return np.repeat(xy[np.argmax(down)][None], len(grid), axis=0)
    last = len(moves) - 1 - int(np.argmax(moves[::-1]))
    j = np.searchsorted(lam[1:], grid, side="right")  # [n] first segment ending beyond
    at_end = j > last
    j = np.minimum(j, last)
    f0, f1 = lam[j], lam[j + 1]  # [n]
    p0, p1 = xy[j], xy[j + 1]  # [n, 2]
    out = (p1 - p0) / (f1 - f0)[:, None] * (grid - f0)[:, None] + p0
    out = np.where((grid == f0)[:, None], p0, out)
    out[at_end] = xy[last + 1]
    return out


def resample_by_arc_length(paths, n_points: int = 128) -> np.ndarray:
    """Evenly spaced points ``[M, n, 2]`` along the pen-down path of ``paths [M, T, d]``.

    With ``L`` the total drawn length (pen-up segments count 0), point ``k`` lies at arc
    length ``s_k = L k / (n - 1)``, ``k = 0 .. n-1``, linearly interpolated on the drawn
    segment that contains it: the first point is where writing starts, the last where it
    ends. Several pen-down strokes share the ``n`` points by their lengths, and the
    pen-up jumps between them are not drawn. Points where the pen did not move are
    skipped; a path of length 0 gives its first pen-down point ``n`` times.
    """
    p = _paths(paths)
    if n_points < 2:
        raise ValueError(f"n_points must be >= 2, got {n_points}")
    xy, down = p[..., :2], pen_down(p)  # [M, T, 2], [M, T]
    lam, drawn = _drawn_fractions(xy, down)  # [M, T], [M, T-1]
    grid = np.linspace(0.0, 1.0, n_points)  # [n]
    out = np.empty((len(p), n_points, 2))
    for m in range(len(p)):
        out[m] = _resample_one(xy[m], lam[m], drawn[m], down[m], grid)
    return out


def path_error_px(y_a, y_b, n_points: int = 64) -> np.ndarray:
    """Timing-free distance ``[M]`` (px) between paths ``[M, T, d]`` (x, y used).

    Both paths are resampled at ``n`` evenly spaced arc lengths from their start to
    their end (:func:`resample_by_arc_length`) and compared point by point:

        e = 1/n sum_k |a(s_k) - b(s_k)|

    Two paths that trace the same curve at different speeds have path error 0 (up to the
    resampling), where Table I's error would not; the order and direction still count.
    """
    a, b = _pair(y_a, y_b)
    diff = resample_by_arc_length(a, n_points) - resample_by_arc_length(b, n_points)
    return np.linalg.norm(diff, axis=-1).mean(-1)  # [M]


def chamfer_px(a, b, n_points: int = 128) -> np.ndarray:
    """Symmetric Chamfer distance ``[M]`` (px) between paths ``[M, T, d]``.

    On ``n`` arc-length points ``A`` of ``a`` and ``B`` of ``b``
    (:func:`resample_by_arc_length`):

        C = 1/2 (1/n sum_{p in A} min_{q in B} |p - q| + 1/n sum_{q in B} min_{p in A} |p - q|)

    Free of order, direction and timing: 0 for a path and itself reversed; a line and
    its copy shifted by ``h`` across it give ``h``.
    """
    pa, pb = _pair(a, b)
    ra, rb = resample_by_arc_length(pa, n_points), resample_by_arc_length(pb, n_points)
    out = np.empty(len(ra))  # [M]
    step = max(1, _CHUNK_ELEMENTS // (n_points * n_points))
    for s in range(0, len(ra), step):
        a, b = ra[s : s + step, :, None], rb[s : s + step, None]  # [m, n, 1, 2], [m, 1, n, 2]
        d2 = (a[..., 0] - b[..., 0]) ** 2 + (a[..., 1] - b[..., 1]) ** 2  # [m, n, n]
        to_b, to_a = np.sqrt(d2.min(axis=2)), np.sqrt(d2.min(axis=1))  # [m, n] each
        out[s : s + step] = 0.5 * (to_b.mean(axis=1) + to_a.mean(axis=1))
    return out


def bilinear(images, points) -> np.ndarray:
    """Intensities ``[M, n]`` of ``images [M, H, W]`` at ``points [M, n, 2]`` (x, y).

    Bilinear between pixel centres (at integer coordinates); outside the image the
    intensity is 0, so it falls to 0 over the half pixel beyond the border.
    """
    img = np.asarray(images, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64)
    if img.ndim != 3 or pts.ndim != 3 or pts.shape[-1] != 2 or len(img) != len(pts):
        raise ValueError(
            f"need images [M, H, W] and points [M, n, 2], got {img.shape}, {pts.shape}"
        )
    h, w = img.shape[1:]
    padded = np.pad(img, ((0, 0), (1, 1), (1, 1)))  # [M, H+2, W+2], zero frame
    pts = np.where(np.isfinite(pts), pts, -2.0)  # NaN / inf: outside
    x = np.clip(pts[..., 0] + 1.0, 0.0, w + 1.0)  # [M, n] padded coordinates
    y = np.clip(pts[..., 1] + 1.0, 0.0, h + 1.0)
    j0 = np.minimum(np.floor(x).astype(np.intp), w)
    i0 = np.minimum(np.floor(y).astype(np.intp), h)
    fx, fy = x - j0, y - i0
    m = np.arange(len(img))[:, None]
    return (
        padded[m, i0, j0] * (1 - fx) * (1 - fy)
        + padded[m, i0, j0 + 1] * fx * (1 - fy)
        + padded[m, i0 + 1, j0] * (1 - fx) * fy
        + padded[m, i0 + 1, j0 + 1] * fx * fy
    )


def on_ink_share(images, paths, threshold: float = 0.5, n_points: int = 128) -> np.ndarray:
    """Share ``[M]`` in [0, 1] of each path that lies on its image's ink.

        s = 1/n #{k : I(p_k) > threshold}

    with ``p_k`` the ``n`` arc-length points of the pen-down path
    (:func:`resample_by_arc_length`) and ``I`` the bilinear intensity (:func:`bilinear`;
    ink = 1, outside the image 0). A path written along the strokes of the image has
    share 1; for a stroke rendered with pen width ``w`` the ink exceeds 0.5 within about
    ``w / 2`` of its centre line.
    """
    ink = bilinear(images, resample_by_arc_length(_paths(paths), n_points))  # [M, n]
    return (ink > threshold).mean(axis=1)


def ink_written_share(
    images, paths, radius_px: float = 1.5, threshold: float = 0.5, n_points: int = 256
) -> np.ndarray:
    """Share ``[M]`` in [0, 1] of each image's ink that its path writes.

        w = #{ink pixels within radius_px of the path} / #{ink pixels}

    with the ink pixels those above ``threshold`` (centres at integer coordinates) and the
    path its ``n`` arc-length points (:func:`resample_by_arc_length`). The converse of
    :func:`on_ink_share`: a path that writes only part of the image (one of two digits, a
    letter's bar left out) has a low share; an image without ink gives 1 (nothing left
    unwritten).
    """
    img = np.asarray(images, dtype=np.float64)
    pts = resample_by_arc_length(_paths(paths), n_points)  # [M, n, 2]
    if img.ndim != 3 or len(img) != len(pts):
        raise ValueError(f"need images [M, H, W] for paths [M, T, d], got {img.shape}")
    out = np.ones(len(img))
    for m in range(len(img)):
        rows, cols = np.nonzero(img[m] > threshold)
        if rows.size == 0:
            continue
        near = np.zeros(rows.size, bool)
        step = max(1, _CHUNK_ELEMENTS // n_points)
        for s in range(0, rows.size, step):
            dx = cols[s : s + step, None] - pts[m, None, :, 0]  # [k, n]
            dy = rows[s : s + step, None] - pts[m, None, :, 1]
            near[s : s + step] = (dx * dx + dy * dy).min(axis=1) <= radius_px**2
        out[m] = near.mean()
    return out


def _polygon(paths) -> np.ndarray:
    """Vertices ``[M, T, 2]``: pen-up points moved onto the pen-down point before them."""
    p = _paths(paths)
    down = pen_down(p)  # [M, T]
    t = np.arange(p.shape[1])
    idx = np.maximum.accumulate(np.where(down, t, -1), axis=1)  # last pen-down so far
    idx = np.where(idx < 0, np.argmax(down, axis=1)[:, None], idx)  # before the first
    return np.take_along_axis(p[..., :2], idx[..., None], axis=1)


def _shoelace(poly: np.ndarray) -> np.ndarray:
    v = poly - poly[:, :1]  # [M, T, 2], about the first point (rounding)
    x, y = v[..., 0], v[..., 1]
    return 0.5 * np.abs((x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y).sum(axis=1))


def _winding(poly: np.ndarray, n_rows: int) -> np.ndarray:
    """``int |w(x, y)| dx dy`` of closed polygons ``[M, S, 2]``: exact along x on
    ``n_rows`` scan lines, midpoint rule across them."""
    a, b = poly, np.roll(poly, -1, axis=1)  # edges a -> b, [M, S, 2]
    out = np.empty(len(poly))
    step = max(1, _CHUNK_ELEMENTS // (n_rows * poly.shape[1]))
    for s in range(0, len(poly), step):
        pa, pb = a[s : s + step, None], b[s : s + step, None]  # [m, 1, S, 2]
        lo, hi = poly[s : s + step, :, 1].min(1), poly[s : s + step, :, 1].max(1)  # [m]
        h = (hi - lo) / n_rows
        y = (lo[:, None] + (np.arange(n_rows) + 0.5) * h[:, None])[..., None]  # [m, R, 1]
        ay, by = pa[..., 1], pb[..., 1]  # [m, 1, S]
        up, down = (ay <= y) & (y < by), (by <= y) & (y < ay)  # [m, R, S] crossings
        cross = up | down
        u = (y - ay) / np.where(cross, by - ay, 1.0)
        far = poly[s : s + step, :, 0].max(1)[:, None, None]  # right of every crossing
        x = np.where(cross, pa[..., 0] + u * (pb[..., 0] - pa[..., 0]), far)  # [m, R, S]
        order = np.argsort(x, axis=-1)
        xs = np.take_along_axis(x, order, axis=-1)
        w = np.cumsum(np.take_along_axis(up.astype(int) - down, order, axis=-1), axis=-1)
        line = (np.abs(w[..., :-1]) * np.diff(xs, axis=-1)).sum(-1)  # [m, R]
        out[s : s + step] = line.sum(-1) * h
    return out


def enclosed_area_px2(paths, method: str = "winding", n_rows: int = 256) -> np.ndarray:
    """Area ``[M]`` (px^2) enclosed by the closed polygon of each pen-down path.

    The polygon joins the pen-down points in order (strokes joined end to start) and
    closes from the last back to the first.

    - ``"winding"`` (default): ``A = int |w(x, y)| dx dy`` with ``w`` the polygon's
      winding number, integrated exactly along x on ``n_rows`` scan lines and by the
      midpoint rule across them. Every loop counts, whichever way it turns: a one-stroke
      8, whose loops turn opposite ways, encloses both.
    - ``"shoelace"``: ``A = 1/2 |sum_t (x_t y_{t+1} - x_{t+1} y_t)|``, the absolute
      signed area; equal for a simple polygon, but loops turning opposite ways cancel
      (an 8 gives the difference of its loops).
    """
    poly = _polygon(paths)  # [M, T, 2]
    if method == "shoelace":
        return _shoelace(poly)
    if method == "winding":
        return _winding(poly, n_rows)
    raise ValueError(f"method must be 'winding' or 'shoelace', got {method!r}")


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)


def area_ratio(pred, ref, method: str = "winding") -> np.ndarray:
    """``A(pred) / A(ref)`` ``[M]`` of :func:`enclosed_area_px2`; NaN where ``A(ref) = 0``.

    1 when the predicted digit's loops enclose as much as the demonstration's; meant for
    :data:`CLOSED_DIGITS` (the median over samples is the headline number).
    """
    pa, pb = _pair(pred, ref)
    return _ratio(enclosed_area_px2(pa, method), enclosed_area_px2(pb, method))


def width_ratio(pred, ref) -> np.ndarray:
    """Horizontal extent ratio ``[M]``: ``(max x - min x)`` over the pen-down points of
    ``pred`` divided by that of ``ref``; NaN where ``ref`` has width 0."""
    pa, pb = _pair(pred, ref)

    def width(p):
        x, down = p[..., 0], pen_down(p)
        return np.where(down, x, -np.inf).max(1) - np.where(down, x, np.inf).min(1)

    return _ratio(width(pa), width(pb))


def start_error_px(a, b) -> np.ndarray:
    """Distance ``[M]`` (px) between the first pen-down points of ``a`` and ``b``:
    ``|a(t_a) - b(t_b)|``, ``t`` the first instant with the pen down."""
    pa, pb = _pair(a, b)
    m = np.arange(len(pa))
    first_a = pa[m, np.argmax(pen_down(pa), axis=1), :2]  # [M, 2]
    first_b = pb[m, np.argmax(pen_down(pb), axis=1), :2]
    return np.linalg.norm(first_a - first_b, axis=-1)


__all__ = [
    "CLOSED_DIGITS",
    "closed_labels",
    "arc_fractions",
    "area_ratio",
    "bilinear",
    "chamfer_px",
    "enclosed_area_px2",
    "ink_written_share",
    "on_ink_share",
    "path_error_px",
    "pen_down",
    "points_at_fractions",
    "resample_by_arc_length",
    "start_error_px",
    "width_ratio",
]
