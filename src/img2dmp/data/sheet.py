"""Finding the sheet of paper in a photo: the desk around it is no ink (NumPy, SciPy, PIL).

The usual photo of a page shows the sheet lying on a desk, with a margin of desk around
it: darker or lighter than the paper, plain or a little textured. :func:`find_sheet`
finds the sheet so that :func:`img2dmp.data.paper.paper_ink` reads only what is on it.
On the photo reduced to about ``SHEET_SIDE`` pixels on its shorter side and smoothed:

1. **edges**: the pixels where the colour changes faster than ``STEP_NOISE`` times the
   image's usual change (and ``STEP_MIN``): the sheet's edge, the strokes; not the
   lines of ruled or squared paper (:func:`_rules`: thin, with the paper on both sides,
   straight and in parallel sets, ``RULE_*``), which, closed, would fill the sheet (a
   sheet's own thin dark border on a desk of its shade, with a plain desk beyond it, is
   an edge).
   The long straight ones (the sheet's border) are drawn on through their faint
   stretches (where the paper's shade nears the desk's level, ``LINE_*``) and on to the
   corner where two of them meet (``CORNER_GAP``); all grown by a pixel, gaps of up to
   about ``2 EDGE_GAP`` pixels closed;
2. **regions**: the connected areas between them; the paper is the one that holds most
   of the image's middle. When it reaches the border, the desk may have come in through
   a longer gap (where the paper's shade meets the desk's level): its part of the
   border's colour (``DESK_TOLERANCE``) connected to the border is a region of its own;
3. **desk**: the regions that lie along ``DESK_BORDER`` of the image's border, cover at
   least ``DESK_MIN_SHARE`` of it, are bounded by edges (``DESK_EDGED`` of their
   outline), differ in colour by ``DESK_CONTRAST`` from what lies just beyond their edge
   and from the paper's median colour (or, bounded by a step of twice that, from a
   quarter, ``DESK_DIFFERS``, of the paper read in cells: a sheet shaded from lighter to
   darker than the desk; a shade on the paper, a rule's band or the paper beyond a
   margin line do not), have no lines between them (``DESK_LINED``: a
   shade on ruled paper) and hold no writing (marks enclosed by them and the straight
   edges along them under ``DESK_HOLES`` of their area: a shadow's edge across the page
   is a region too, with characters in it or at its edge; and, darker than the paper,
   no writing read in the photo itself, ``written``: a shadow across the page);
4. **sheet**: the desk grown over the edges beside it (``EDGE_BAND``, those reaching no
   farther than ``EDGE_REACH``: the sheet's edge, a shadow along it), the rest grown
   away from it by ``EDGE_MARGIN`` pixels (the edge's blur), the part that holds the
   paper, its convex hull (a sheet is a quadrilateral, in perspective too; the notch a
   gap let in is back), drawn straight at the photo's
   pixels; at least ``SHEET_MIN_SHARE`` of the image. Its sides' angle is where its
   rules run (:attr:`Sheet.angle_deg`). Off the sheet the photo is
   painted with the nearest paper's colour, from ``EDGE_GAP + 2`` pixels inside.

The sheet is None when no desk is found (a photo of the sheet alone, a scan), when the
desk's regions hold the middle of the image, when the rest is too small, or when the desk
is darker than ``DESK_DARK`` of the paper (a dark table: :func:`img2dmp.data.paper.sheet_mask`
takes it, as before).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: A desk darker than this share of the paper's brightness is left to
#: :func:`img2dmp.data.paper.sheet_mask` (a dark table beside the sheet, as the generated
#: pages' are: painted over, the pen's level there was read lower and grid remnants
#: stayed, validation seed 92 lost 5 of 18 characters; TABLE_LEVEL's share).
DESK_DARK = 0.45
#: ITU-R 601-2 luma weights.
_LUMA = (0.299, 0.587, 0.114)
#: The search runs on the photo reduced to about this many pixels on its shorter side.
SHEET_SIDE = 200
#: An edge pixel: the colour changes by at least this many times the image's median change
#: per pixel, ...
STEP_NOISE = 6.0
#: ... and at least this much per pixel (levels in [0, 1]).
STEP_MIN = 0.01
#: Gaps of up to about twice this many reduced pixels in the edges are closed.
EDGE_GAP = 4
#: A straight edge (the sheet's border) is drawn through its faint stretches where pixels
#: that change by this share of an edge pixel's change lie along it ...
LINE_WEAK = 0.34
#: ... for this share of the shorter side (gaps of up to ``LINE_GAP`` of it), ...
LINE_MIN = 0.2
LINE_GAP = 0.1
#: ... covering this share of it, and edge pixels this share, ...
LINE_COVER = 0.7
LINE_STRONG = 0.2
#: ... changing across it within this angle (radians); at most ``LINE_MAX`` lines.
LINE_ANGLE = 0.35
LINE_MAX = 12
#: Two straight edges that would meet within this share of the shorter side beyond their
#: ends are drawn on to the corner.
CORNER_GAP = 0.15
#: A desk region covers at least this share of the image,
DESK_MIN_SHARE = 0.01
#: ... differs by this much in some channel (its median colour) from the median of the
#: pixels just beyond its boundary and from the paper's (or, beside a step of twice this,
#: from ``DESK_DIFFERS`` of the paper's cells: a sheet shaded from lighter to darker than
#: it), ...
DESK_CONTRAST = 0.025
DESK_DIFFERS = 0.25
#: ... and encloses marks of at most this share of its area (a desk holds no writing).
DESK_HOLES = 0.01
#: A desk region lies along at least this share of the image's border.
DESK_BORDER = 0.08
#: A group of desk regions with more edge pixels between them than this share of their
#: area is a shade on lined paper.
DESK_LINED = 0.02
#: A desk region's outline lies on edges for at least this share (the rest: gaps),
DESK_EDGED = 0.6
#: ... and the desk that came in through a gap in the edge is of the border's colour
#: within this much (or four times its spread).
DESK_TOLERANCE = 0.03
#: The edge pixels within this many reduced pixels of the desk, joined to it and reaching no
#: farther than ``EDGE_REACH`` from it, are the desk's (the sheet's edge, a shadow along it,
#: a strip of another desk; not a character touching it), ...
EDGE_BAND = 6
EDGE_REACH = 12
#: ... and the sheet keeps this many reduced pixels clear of them (the edge's blur).
EDGE_MARGIN = 3
#: A thin line on the paper (a rule): an edge pixel that differs more from the two pixels
#: this many reduced pixels away across it than they differ from each other, ...
RULE_SIDE = 3
#: ... with such pixels along it for this share of this share of the shorter side one way
#: or the other, ...
RULE_COVER = 0.7
RULE_RUN = 0.12
#: ... and more of them on one side, beyond its own band (this many pixels), within this
#: share of the shorter side (ruled and squared paper's pitch); grown across it over the
#: changing pixels within this many pixels (its blurred sides, a stroke's pixels on it).
RULE_OWN = 4
RULE_PITCH = 0.15
RULE_BAND = 3
#: A line with the set's other lines on one side only, and nothing changing on the other
#: for this many times the distance to the nearest of them, is where the set ends (a
#: sheet's own thin border on a plain desk of its shade), no rule.
RULE_END = 1.5
#: Groups of edge pixels this small that touch the rules go with them.
RULE_SPECK = 12
#: The band beside the desk: this share of the photo's shorter side.
BAND_SHARE = 0.03
#: The sheet covers at least this share of the image.
SHEET_MIN_SHARE = 0.2


@dataclass
class Sheet:
    """The sheet found in a photo.

    Attributes
    ----------
    mask : bool [H, W]
        The sheet, its edge's band left out.
    fill : float32 [C, H, W]
        The photo with the desk painted over by the nearest paper's colour (what the
        background estimate and the polarity read: the desk's level is not the paper's).
    band : bool [H, W]
        Within ``BAND_SHARE`` of the shorter side of the desk (where the sheet's edge
        may leave a line: :func:`img2dmp.data.paper.paper_ink` drops long ones).
    desk_px : int
        Pixels of the photo off the sheet.
    angle_deg : float
        The angle of the sheet's sides from the photo's rows and columns (degrees in
        [-45, 45), the rows' convention of :func:`img2dmp.data.paper.dominant_angle`):
        where the rules of ruled paper lying askew run.
    """

    mask: np.ndarray
    fill: np.ndarray
    band: np.ndarray
    desk_px: int
    angle_deg: float = 0.0


def _reduce(planes: np.ndarray, factor: int) -> np.ndarray:
    """``planes [C, H, W]`` area-averaged ``factor`` times per side (PIL's reduce)."""
    from PIL import Image

    if factor == 1:
        return planes.astype(np.float32)
    return np.stack([
        np.asarray(Image.fromarray(np.ascontiguousarray(p, np.float32), mode="F").reduce(factor))
        for p in planes
    ])  # fmt: skip


def _upsample(mask: np.ndarray, factor: int, shape: tuple[int, int]) -> np.ndarray:
    """A reduced ``mask`` (or plane) at the photo's pixels (nearest; the rows and columns
    that the reduction left out take the last ones')."""
    full = np.repeat(np.repeat(mask, factor, axis=0), factor, axis=1)[: shape[0], : shape[1]]
    return np.pad(full, ((0, shape[0] - full.shape[0]), (0, shape[1] - full.shape[1])), mode="edge")


def _grown(mask: np.ndarray, n: int) -> np.ndarray:
    """``mask`` grown by ``n`` pixels every way (a 3 x 3 square's dilation ``n`` times,
    outside the image nothing), in one pass: a maximum over a square of ``2 n + 1``."""
    from scipy.ndimage import maximum_filter

    return maximum_filter(mask, 2 * n + 1, mode="constant", cval=False)


def _shrunk(mask: np.ndarray, n: int) -> np.ndarray:
    """``mask`` eroded by ``n`` pixels every way (outside the image nothing), in one pass."""
    from scipy.ndimage import minimum_filter

    return minimum_filter(mask, 2 * n + 1, mode="constant", cval=False)


def _change(small: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The largest change per pixel over the channels of ``small [C, h, w]`` and the
    direction it changes in (radians in [0, pi): a line's normal), both ``[h, w]``."""
    change = np.zeros(small.shape[1:], np.float32)
    normal = np.zeros(small.shape[1:], np.float32)
    for p in small:
        gy, gx = np.gradient(p)
        c = np.maximum(np.abs(gx), np.abs(gy))
        more = c > change
        change[more] = c[more]
        normal[more] = np.mod(np.arctan2(gy[more], gx[more]), np.pi)
    return change, normal


def _segments(
    strong: np.ndarray, weak: np.ndarray, normal: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray, float, float]]:
    """The long straight edges of an image, as ``(centre, direction, start, end)`` (the
    points ``centre + s direction``, x and y, for ``s`` from start to end): lines of a
    Hough transform of the ``weak`` pixels (each voting only for the lines across its own
    change's direction, ``normal``), strongest first; a line's band (its pixels within
    ``EDGE_GAP``, changing across it within ``LINE_ANGLE``) cut where more than
    ``LINE_GAP`` of the shorter side apart. A stretch at least ``LINE_MIN`` of the side
    long, its positions covered for ``LINE_COVER`` of its length and for ``LINE_STRONG``
    by ``strong`` pixels, is fitted by least squares and runs from its first strong pixel
    to its last."""
    h, w = weak.shape
    ys, xs = np.nonzero(weak)
    least = LINE_MIN * min(h, w)
    if xs.size < least:
        return []
    n_theta = 180
    step = np.pi / n_theta
    theta = normal[ys, xs]
    firm = strong[ys, xs]
    reach = int(np.ceil(np.hypot(h, w)))
    bins = np.round(theta / step).astype(np.int64)
    cos, sin = np.cos(np.arange(n_theta) * step), np.sin(np.arange(n_theta) * step)
    votes = []
    for d in (-2, -1, 0, 1, 2):  # each pixel votes near its own direction only
        t = np.mod(bins + d, n_theta)
        rho = np.round(xs * cos[t] + ys * sin[t]).astype(np.int64) + reach
        votes.append(t * (2 * reach + 1) + rho)
    votes = np.stack(votes)  # [5, pixels]
    size = n_theta * (2 * reach + 1)
    acc = np.bincount(votes.ravel(), minlength=size)
    out = []
    for _ in range(LINE_MAX):
        peak = int(np.argmax(acc))
        if acc[peak] < least:
            break
        t, r = np.unravel_index(peak, (n_theta, 2 * reach + 1))
        c, s = np.cos(t * step), np.sin(t * step)
        turn = np.abs(np.mod(theta - t * step + np.pi / 2, np.pi) - np.pi / 2)
        # the edge's band (a blurred step, a shadow's line, a strip of another desk): its
        # pixels' votes taken back, its middle fitted
        on = (np.abs(xs * c + ys * s - (r - reach)) <= EDGE_GAP) & (turn <= LINE_ANGLE)
        acc -= np.bincount(votes[:, on].ravel(), minlength=size)
        acc[peak] = 0
        pts = np.stack([xs[on], ys[on]], 1).astype(np.float64)
        along = pts @ np.array([-s, c])
        order = np.argsort(along)
        pts, along, sure = pts[order], along[order], firm[on][order]
        cuts = np.flatnonzero(np.diff(along) > LINE_GAP * min(h, w)) + 1
        for part, pos, hard in zip(np.split(pts, cuts), np.split(along, cuts),
                                   np.split(sure, cuts), strict=True):  # fmt: skip
            length = pos[-1] - pos[0] + 1
            if length < least:
                continue
            covered = np.unique(np.round(pos)).size
            firmly = np.unique(np.round(pos[hard])).size
            if covered < LINE_COVER * length or firmly < LINE_STRONG * length:
                continue  # a row of marks, a shade's ripples
            centre = part.mean(0)
            _, _, vt = np.linalg.svd(part - centre, full_matrices=False)
            proj = (part - centre)[hard] @ vt[0]  # from edge pixel to edge pixel, not
            out.append((centre, vt[0], float(proj.min()), float(proj.max())))  # on into grain
    return out


def _straight(strong: np.ndarray, weak: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The sheet's straight border drawn through its faint stretches (``bool`` like
    ``strong``): each long straight edge of :func:`_segments` from its first pixel to
    its last, and on to where it meets another (a corner) when that is within
    ``CORNER_GAP`` of the shorter side of both ends."""
    h, w = strong.shape
    segs = _segments(strong, weak, normal)
    ends = [[a, b] for _, _, a, b in segs]
    reach = CORNER_GAP * min(h, w)
    for i, (ci, ui, _, _) in enumerate(segs):
        for j in range(i + 1, len(segs)):
            cj, uj, _, _ = segs[j]
            det = ui[0] * -uj[1] + uj[0] * ui[1]
            if abs(det) < np.sin(np.pi / 6):
                continue  # nearly parallel: no corner
            d = cj - ci
            si = (d[0] * -uj[1] + uj[0] * d[1]) / det  # ci + si ui = cj + sj uj
            sj = (ui[0] * d[1] - ui[1] * d[0]) / det
            gi = max(ends[i][0] - si, si - ends[i][1], 0.0)
            gj = max(ends[j][0] - sj, sj - ends[j][1], 0.0)
            corner = ci + si * ui
            inside = -2 <= corner[0] <= w + 1 and -2 <= corner[1] <= h + 1
            if inside and gi <= reach and gj <= reach:
                ends[i] = [min(ends[i][0], si), max(ends[i][1], si)]
                ends[j] = [min(ends[j][0], sj), max(ends[j][1], sj)]
    out = np.zeros_like(strong)
    for (c, u, _, _), (a, b) in zip(segs, ends, strict=True):
        s = np.arange(a, b + 0.5, 0.5)
        x = np.clip(np.round(c[0] + s * u[0]).astype(int), 0, w - 1)
        y = np.clip(np.round(c[1] + s * u[1]).astype(int), 0, h - 1)
        out[y, x] = True
    return out


def _along(mask: np.ndarray, ys, xs, dy, dx, offsets) -> np.ndarray:
    """``mask`` read at the points ``(ys, xs) + d (dy, dx)`` for every ``d`` of
    ``offsets`` (rounded, outside the image False): ``bool [len(offsets), n]``."""
    h, w = mask.shape
    d = np.asarray(offsets, np.float64)[:, None]
    y, x = np.round(ys + d * dy).astype(np.int64), np.round(xs + d * dx).astype(np.int64)
    inside = (y >= 0) & (y < h) & (x >= 0) & (x < w)
    return mask[np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)] & inside


def _orientation(small: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """The direction (radians in [0, pi)) across which ``small [C, h, w]`` changes at the
    pixels ``(ys, xs)``, read over ``RULE_SIDE`` pixels (the structure tensor summed over
    the channels, smoothed): steady along a faint rule, where a pixel's own change turns
    with the grain."""
    from scipy.ndimage import gaussian_filter

    jxx = np.zeros(small.shape[1:], np.float32)
    jxy, jyy = np.zeros_like(jxx), np.zeros_like(jxx)
    for p in small:
        gy, gx = np.gradient(p)
        jxx += gx * gx
        jxy += gx * gy
        jyy += gy * gy
    jxx, jxy, jyy = (gaussian_filter(j, RULE_SIDE / 2, mode="nearest")[ys, xs]
                     for j in (jxx, jxy, jyy))  # fmt: skip
    return np.mod(0.5 * np.arctan2(2 * jxy, jxx - jyy), np.pi)


def _rules(small: np.ndarray, weak: np.ndarray) -> np.ndarray:
    """The pixels of ``weak`` (changing by a share of an edge's change) on ruled or squared
    paper's lines (``bool``, the same shape): thin lines, a pixel differing more from the
    two sides ``RULE_SIDE`` pixels away across it than they differ from each other, and
    those by less than ``DESK_CONTRAST``, as they are or once the paper's own slope is
    taken out (read twice as far away: the paper on both sides, if shaded; a step, the
    sheet's border, a thin line between the desk and the paper of nearly one shade, or a
    shadow's edge, is no rule), straight (such pixels along it for ``RULE_COVER`` of
    ``RULE_RUN`` of the shorter side one way or the other: on to the sheet's edge) and
    with another such line on one side within ``RULE_PITCH`` of it (rules come in
    parallel sets: a margin line, a fold, a long stroke stay edges), not where the set
    ends (:func:`_set_ends`: its outermost line with nothing changing beyond it for
    ``RULE_END`` times the pitch, a sheet's own thin dark border on a plain desk of its
    shade); grown across the line over the pixels of ``weak`` within ``RULE_BAND``
    (the line's blurred sides, a stroke's pixels on it; not on past its end into the
    sheet's border). Across and along:
    :func:`_orientation`'s direction; the pixels tested: ``weak`` and those beside them
    (a sharp line's middle changes little)."""
    from scipy.ndimage import binary_dilation

    h, w = weak.shape
    ys, xs = np.nonzero(binary_dilation(weak, np.ones((3, 3), bool)))
    if ys.size == 0:
        return np.zeros_like(weak)
    normal = _orientation(small, ys, xs)
    ny, nx = np.sin(normal), np.cos(normal)

    def sides(d):  # small at the pixels d across them
        y = np.clip(np.round(ys + d * ny).astype(np.int64), 0, h - 1)
        x = np.clip(np.round(xs + d * nx).astype(np.int64), 0, w - 1)
        return small[:, y, x]

    ahead, behind = sides(RULE_SIDE), sides(-RULE_SIDE)
    across = ahead - behind
    step = np.max(np.abs(across), axis=0)
    dev = np.max(np.abs(small[:, ys, xs] - 0.5 * (ahead + behind)), axis=0)
    ok = dev > step
    ys, xs, ny, nx, step, across = ys[ok], xs[ok], ny[ok], nx[ok], step[ok], across[:, ok]
    # a step between its sides, the paper's own slope taken out (twice as far away, the
    # sides differ twice as much on a slope, as much across a step)
    sheer = np.max(np.abs(2 * across - (sides(2 * RULE_SIDE) - sides(-2 * RULE_SIDE))), axis=0)
    ok = np.minimum(step, sheer) < DESK_CONTRAST
    thin = np.zeros_like(weak)
    thin[ys[ok], xs[ok]] = True
    ys, xs, ny, nx = ys[ok], xs[ok], ny[ok], nx[ok]
    run = max(4, round(RULE_RUN * min(h, w)))
    near = binary_dilation(thin, np.ones((3, 3), bool))  # a pixel either way: rounding
    ahead = _along(near, ys, xs, nx, -ny, range(run + 1)).mean(axis=0)
    behind = _along(near, ys, xs, -nx, ny, range(run + 1)).mean(axis=0)
    ok = np.maximum(ahead, behind) >= RULE_COVER
    ys, xs, ny, nx = ys[ok], xs[ok], ny[ok], nx[ok]
    straight = np.zeros_like(weak)
    straight[ys, xs] = True
    reach = range(RULE_OWN + 1, max(RULE_OWN + 2, round(RULE_PITCH * min(h, w)) + 1))
    ahead = _along(straight, ys, xs, ny, nx, reach)  # [len(reach), n]
    behind = _along(straight, ys, xs, -ny, -nx, reach)
    ok = ahead.any(axis=0) | behind.any(axis=0)
    ok &= ~_set_ends(weak, ys, xs, ny, nx, ahead, behind, reach.start)
    out = np.zeros_like(weak)
    ys, xs, ny, nx = ys[ok], xs[ok], ny[ok], nx[ok]
    for d in range(-RULE_BAND, RULE_BAND + 1):  # across the line, not on past its end
        y = np.clip(np.round(ys + d * ny).astype(np.int64), 0, h - 1)
        x = np.clip(np.round(xs + d * nx).astype(np.int64), 0, w - 1)
        out[y, x] = True
    return weak & out


def _set_ends(weak, ys, xs, ny, nx, ahead, behind, start: int) -> np.ndarray:
    """Whether each line pixel ``(ys, xs)`` (across it ``(ny, nx)``), with the set's
    other lines on one side only (``ahead`` / ``behind``: :func:`_along`'s answers from
    ``start`` pixels on), has nothing of ``weak`` on its other side for ``RULE_END``
    times the distance to the nearest of them, all inside the image: where the set ends
    (``bool [n]``). A sheet's own thin dark border on a plain desk of its shade: beyond
    it nothing changes; beyond a page's last rule, the image's border within a pitch
    and a half (a margin narrower than that) leaves it a rule."""
    h, w = weak.shape
    ahead_any, behind_any = ahead.any(axis=0), behind.any(axis=0)
    lone = np.flatnonzero(ahead_any ^ behind_any)
    out = np.zeros(ys.size, bool)
    if lone.size == 0:
        return out
    fwd = ahead_any[lone]
    pitch = np.where(fwd, ahead[:, lone].argmax(axis=0), behind[:, lone].argmax(axis=0)) + start
    far = np.ceil(RULE_END * pitch).astype(np.int64)
    sign = np.where(fwd, -1.0, 1.0)  # towards the side without lines
    y, x, dy, dx = ys[lone], xs[lone], sign * ny[lone], sign * nx[lone]
    end_y, end_x = np.round(y + far * dy), np.round(x + far * dx)
    inside = (end_y >= 0) & (end_y < h) & (end_x >= 0) & (end_x < w)
    beyond = _along(weak, y, x, dy, dx, range(RULE_OWN + 1, int(far.max()) + 1))
    beyond &= np.arange(RULE_OWN + 1, int(far.max()) + 1)[:, None] <= far[None, :]
    out[lone] = inside & ~beyond.any(axis=0)
    return out


def _specks_on(edges: np.ndarray, rules: np.ndarray) -> np.ndarray:
    """The groups of ``edges`` (``bool``) of at most ``RULE_SPECK`` pixels that touch
    ``rules``: what the rules' removal left where squared paper's lines cross, which the
    closing of the edges' gaps would join into a net over the sheet."""
    from scipy.ndimage import binary_dilation, label

    groups, n = label(edges, np.ones((3, 3), bool))
    size = np.bincount(groups.ravel(), minlength=n + 1)
    touch = np.zeros(n + 1, bool)
    touch[np.unique(groups[binary_dilation(rules, np.ones((3, 3), bool)) & edges])] = True
    small = touch & (size <= RULE_SPECK)
    small[0] = False
    return small[groups]


def _edges(small: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edge pixels (step 1) of the reduced, smoothed ``small [C, h, w]``, the straight
    lines drawn among them and the rules of ruled or squared paper (:func:`_rules`,
    left out of the edges: closed, they would fill the sheet): ``bool [h, w]`` each."""
    from scipy.ndimage import binary_dilation

    change, normal = _change(small)
    level = max(STEP_MIN, STEP_NOISE * float(np.median(change)))
    strong = change > level
    weak = change > LINE_WEAK * level
    rules = _rules(small, weak)
    if rules.any():  # and the specks its removal left on them (where lines cross)
        rules |= _specks_on(strong & ~rules, rules)
    lines = _straight(strong & ~rules, weak & ~rules, normal)
    edges = binary_dilation((strong & ~rules) | lines, np.ones((3, 3), bool))
    # gaps in the sheet's edge closed (where the paper's shade meets the desk's level)
    g = EDGE_GAP
    padded = np.pad(edges, g, mode="edge")
    return _shrunk(_grown(padded, g), g)[g:-g, g:-g], lines, rules


def _hull(mask: np.ndarray) -> np.ndarray | None:
    """The corners ``[k, 2]`` (x, y; pixel edges at whole numbers) of the convex hull of
    ``mask``'s pixels (whole pixels), or None for too few."""
    from scipy.ndimage import binary_erosion
    from scipy.spatial import ConvexHull, QhullError

    rows, cols = np.nonzero(mask & ~binary_erosion(mask))  # the outline is enough
    pts = np.concatenate([np.stack([cols + dx, rows + dy], 1) for dx in (0, 1) for dy in (0, 1)])
    try:
        return pts[ConvexHull(pts).vertices].astype(np.float64)
    except (QhullError, ValueError):
        return None


def _sides_angle(corners: np.ndarray) -> float:
    """The angle (degrees in [-45, 45)) of a polygon's sides (``corners [k, 2]``, x, y)
    from the rows and columns: their directions modulo 90 degrees averaged, each
    weighted by its length (a quadrilateral's four sides, its hull's short steps aside)."""
    d = np.diff(np.vstack([corners, corners[:1]]), axis=0)
    length = np.hypot(d[:, 0], d[:, 1])
    four = 4.0 * np.arctan2(d[:, 1], d[:, 0])  # a quarter turn is a whole turn
    mean = np.arctan2((length * np.sin(four)).sum(), (length * np.cos(four)).sum()) / 4.0
    return float(np.mod(np.degrees(mean) + 45.0, 90.0) - 45.0)


def _polygon(corners: np.ndarray, scale: int, shape: tuple[int, int]) -> np.ndarray:
    """The pixels (``bool`` of ``shape``) whose centres lie inside the polygon
    ``corners`` scaled by ``scale`` (straight at the photo's own pixels)."""
    from PIL import Image, ImageDraw

    im = Image.new("1", (shape[1], shape[0]), 0)
    ImageDraw.Draw(im).polygon([tuple(p) for p in corners * scale - 0.5], fill=1)
    return np.asarray(im, bool)


def _middle_counts(labels: np.ndarray, n: int) -> np.ndarray:
    """Per label (0: none): its pixels in the middle third of the image both ways."""
    h, w = labels.shape
    counts = np.bincount(labels[h // 3 : h - h // 3, w // 3 : w - w // 3].ravel(), minlength=n + 1)
    counts[0] = 0
    return counts


def _ring(labels: np.ndarray) -> np.ndarray:
    return np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])


def _leak(small: np.ndarray, region: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """The part of the paper's ``region`` that is the desk come in through a gap in the
    sheet's edge (where the paper's shade meets the desk's level): the pixels of the
    colour of the region's part on the image's border (``ring``, ``bool``: where it
    touches it) within ``DESK_TOLERANCE`` (or four times that part's spread, at most
    half the way to the paper's colour in the middle), connected to the border."""
    from scipy.ndimage import label

    h, w = region.shape
    middle = np.zeros_like(region)
    middle[h // 3 : h - h // 3, w // 3 : w - w // 3] = True
    edge, inner = small[:, ring & region], small[:, middle & region]
    if edge.shape[1] < 8 or inner.shape[1] < 8:
        return np.zeros_like(region)
    desk, paper = np.median(edge, axis=1), np.median(inner, axis=1)
    contrast = float(np.max(np.abs(desk - paper)))
    if contrast < 2 * DESK_CONTRAST:
        return np.zeros_like(region)  # the sheet reaches the border there
    spread = float(np.max(1.4826 * np.median(np.abs(edge - desk[:, None]), axis=1)))
    tol = min(max(DESK_TOLERANCE, 4 * spread), 0.5 * contrast)
    like = region & (np.max(np.abs(small - desk[:, None, None]), axis=0) <= tol)
    parts, _ = label(like)
    touching = np.unique(parts[ring & like])
    return np.isin(parts, touching[touching > 0])


def _lined(desk: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """The desk regions of ``desk`` with lines between them (``bool``, the same shape):
    each group of regions closed over ``EDGE_GAP + 2`` pixels, its edges that are not
    on its outline more than ``DESK_LINED`` of its area (the rules, grid or writing that
    run on through a shade on the paper; a desk is plain)."""
    from scipy.ndimage import label

    g = EDGE_GAP + 2
    closed = _shrunk(_grown(np.pad(desk, g, mode="edge"), g), g)[g:-g, g:-g]
    closed |= desk
    groups, n = label(closed)
    outline = _grown(~closed, g)  # the edge along the sheet
    inner = edges & closed & ~desk & ~outline
    lines = np.bincount(groups[inner], minlength=n + 1)
    area = np.bincount(groups[desk], minlength=n + 1)
    bad = lines > DESK_LINED * np.maximum(area, 1)
    bad[0] = False
    return desk & bad[groups]


def _differs(colour: np.ndarray, image: np.ndarray, where: np.ndarray) -> bool:
    """Whether ``DESK_DIFFERS`` of the pixels ``where`` (``bool [h, w]``) of ``image [C, h,
    w]`` differ from ``colour [C]`` by ``DESK_CONTRAST`` in some channel, each read as the
    median of its cell of ``2 EDGE_GAP`` pixels (the paper's grain is no difference)."""
    ys, xs = np.nonzero(where)
    if ys.size == 0:
        return False
    cell = 2 * EDGE_GAP
    key = (ys // cell) * (where.shape[1] // cell + 1) + xs // cell
    order = np.argsort(key, kind="stable")
    key, px = key[order], image[:, ys[order], xs[order]]
    starts = np.flatnonzero(np.diff(key, prepend=-1))
    sizes = np.diff(np.append(starts, key.size))
    medians = np.stack(
        [np.median(px[:, a : a + n], axis=1) for a, n in zip(starts, sizes, strict=True)]
    )
    differ = np.max(np.abs(medians - colour[None, :]), axis=1)  # [cells]
    return bool(np.quantile(np.repeat(differ, sizes), 1.0 - DESK_DIFFERS) >= DESK_CONTRAST)


def _is_desk(small, labels, lab: int, edges, lines, area: int, paper: np.ndarray) -> bool:
    """Whether region ``lab`` of ``labels`` passes step 3's tests (module docstring);
    ``paper``: the paper's region (``bool``)."""
    from scipy.ndimage import binary_dilation, binary_fill_holes, find_objects, label

    h, w = labels.shape
    pad = 2 * EDGE_GAP + 8
    sl = tuple(
        slice(max(0, s.start - pad), s.stop + pad)
        for s in find_objects((labels == lab).astype(np.int8))[0]
    )
    region = labels[sl] == lab
    grid = np.ones((3, 3), bool)
    outline = binary_dilation(region, grid) & ~region
    if np.count_nonzero(edges[sl] & outline) < DESK_EDGED * np.count_nonzero(outline):
        return False  # bounded by a shade's level, not by an edge
    # what lies just beyond the edge's band (the edges grown and closed are wide)
    near = _grown(region, EDGE_GAP + 2)
    beyond = _grown(near, 4) & ~near & ~edges[sl]
    if not beyond.any():
        return False
    inside = np.median(small[(slice(None), *sl)][:, region], axis=1)
    outside = np.median(small[(slice(None), *sl)][:, beyond], axis=1)
    if np.max(np.abs(inside - outside)) < DESK_CONTRAST:
        return False  # a shade on the paper, a band between rules
    if np.max(np.abs(inside - np.median(small[:, paper], axis=1))) < DESK_CONTRAST:
        # the paper's colour (the sheet beyond a margin line, a band above a rule), unless
        # a step of twice that bounds it and a quarter of the paper differs from it (a
        # sheet shaded from lighter to darker than the desk)
        step = np.max(np.abs(inside - np.median(small[(slice(None), *sl)][:, beyond], axis=1)))
        if step < 2 * DESK_CONTRAST or not _differs(inside, small, paper):
            return False
    # the marks it encloses, with the straight lines along it (writing that touches a
    # shadow's edge drawn straight), not the sheet that a desk all around encloses
    solid = region | (_grown(lines[sl], EDGE_GAP + 1) & edges[sl])
    holes, k = label(binary_fill_holes(solid) & ~solid)
    sizes = np.bincount(holes.ravel(), minlength=k + 1)[1:]
    return sizes[sizes < DESK_MIN_SHARE * h * w].sum() <= DESK_HOLES * area


def _level(small: np.ndarray, region: np.ndarray, paper: np.ndarray) -> float:
    """The brightness of ``region``'s median colour as a share of the ``paper``'s."""
    luma = np.asarray(_LUMA[: len(small)] if len(small) == 3 else (1.0,), np.float32)
    return float(luma @ np.median(small[:, region], axis=1)) / max(float(luma @ paper), 1e-3)


def _shaded(small: np.ndarray, region: np.ndarray, paper: np.ndarray) -> bool:
    """Whether ``region`` could be the paper in a shadow: darker than the ``paper``'s
    colour, but not so dark that it is left to the table's test (``DESK_DARK``)."""
    return DESK_DARK <= _level(small, region, paper) < 1.0


def _desk(small: np.ndarray, edges: np.ndarray, lines: np.ndarray, rules: np.ndarray,
          written=None) -> np.ndarray | None:  # fmt: skip
    """The desk regions of step 3 (``bool [h, w]``), or None; ``rules``: the paper's lines
    left out of ``edges`` (a shade on ruled paper has them between its regions);
    ``written``: ``region -> bool``, whether a region holds writing, read in the photo."""
    from scipy.ndimage import label

    labels, n = label(~edges)
    counts = _middle_counts(labels, n)
    if counts.max() == 0:
        return None
    paper = int(np.argmax(counts))
    border = np.zeros(labels.shape, bool)
    border[[0, -1], :] = border[:, [0, -1]] = True
    if np.any(_ring(labels) == paper):  # the desk may have come in through a gap
        leak = _leak(small, labels == paper, border)
        if leak.any():
            labels[leak] = n + 1
            n += 1
            counts = _middle_counts(labels, n)
            paper = int(np.argmax(counts))
    ring = np.unique(_ring(labels))
    area = np.bincount(labels.ravel(), minlength=n + 1)
    h, w = labels.shape
    desk = np.zeros((h, w), bool)
    colour = np.median(small[:, labels == paper], axis=1)
    edge_ring = _ring(labels)
    for lab in ring[ring > 0]:
        if lab == paper or area[lab] < DESK_MIN_SHARE * h * w:
            continue
        if counts[lab] > 0.5 * counts[paper]:
            continue  # the middle of the image is the sheet's
        if np.count_nonzero(edge_ring == lab) < DESK_BORDER * edge_ring.size:
            continue  # a band of the paper, between rules, that reaches the border
        if _is_desk(small, labels, lab, edges, lines, area[lab], labels == paper) and not (
            written is not None and _shaded(small, labels == lab, colour) and written(labels == lab)
        ):
            desk |= labels == lab
    desk &= ~_lined(desk, edges | rules)
    if not desk.any():
        return None
    if _level(small, desk, colour) < DESK_DARK:
        return None  # a dark table: paper.sheet_mask's, as it always was
    return desk


def _edge_band(desk: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """The edges beside the ``desk`` that go with it (``bool``, the same shape): the sheet's
    edge, a shadow along it, a strip of another desk. The pixels within ``EDGE_BAND`` of
    the desk of each group of edge pixels joined to it that reaches no farther than
    ``EDGE_REACH`` (a character touching a margin line taken for the desk reaches into the
    sheet)."""
    from scipy.ndimage import distance_transform_edt, label, maximum, minimum

    groups, n = label(edges & ~desk, np.ones((3, 3), bool))
    if n == 0:
        return np.zeros_like(desk)
    far = distance_transform_edt(~desk)
    index = np.arange(n + 1)
    reach, near = np.asarray(maximum(far, groups, index)), np.asarray(minimum(far, groups, index))
    keep = (near <= 1.5) & (reach <= EDGE_REACH)
    keep[0] = False
    return keep[groups] & (far <= EDGE_BAND)


def sheet_factor(shape) -> int:
    """How many times :func:`find_sheet` reduces a photo of ``shape`` (H, W, ...)."""
    return max(1, min(shape[0], shape[1]) // SHEET_SIDE)


def find_sheet(planes: np.ndarray, factor: int | None = None, written=None) -> Sheet | None:
    """The sheet of paper in a photo (module docstring), or None when no desk shows.

    Parameters
    ----------
    planes : float32 [C, H, W]
        The photo's channels (1 or 3), levels in [0, 1], either polarity.
    factor : int, optional
        Look at the photo reduced this many times (default: to about ``SHEET_SIDE``
        pixels on its shorter side). A photo turned onto a larger canvas keeps the
        reduction of the photo as it stands, so that its rules lie as far apart.
    written : callable, optional
        ``region -> bool`` for a region of the photo (``bool [H, W]``) that passes the
        desk's tests: True when it holds writing, the paper in a shadow across the page
        (:func:`img2dmp.data.paper.shade_test`), which then is no desk.
    """
    from scipy.ndimage import distance_transform_edt, gaussian_filter, label

    height, width = planes.shape[1:]
    if min(height, width) < 2 * SHEET_SIDE // 3:
        return None  # a character's crop, not a photo of a sheet
    if factor is None:
        factor = sheet_factor((height, width))
    small = _reduce(planes, factor)
    small = np.stack([gaussian_filter(p, 1.0, mode="nearest") for p in small])
    edges, lines, rules = _edges(small)
    test = (
        None
        if written is None
        else (lambda region: written(_upsample(region, factor, (height, width))))
    )
    found = _desk(small, edges, lines, rules, test)
    if found is None:
        return None
    desk = found | _edge_band(found, edges)
    grown = _grown(desk, EDGE_MARGIN)
    parts, _ = label(~grown)
    h, w = desk.shape
    middle = parts[h // 3 : h - h // 3, w // 3 : w - w // 3]
    counts = np.bincount(middle.ravel(), minlength=parts.max() + 1)
    counts[0] = 0
    if counts.max() == 0:
        return None
    corners = _hull(parts == int(np.argmax(counts)))  # the notch of a leak, back
    if corners is None:
        return None
    sheet = _polygon(corners, 1, (h, w))
    if np.count_nonzero(sheet) < SHEET_MIN_SHARE * h * w:
        return None
    # the desk painted over with the nearest paper's colour: the paper's level, not the
    # desk's, for the cells of the background estimate beside the edge
    inner = _shrunk(sheet, EDGE_GAP + 2)
    inner = inner if inner.any() else sheet  # paper clear of the edge's band and blur
    near = distance_transform_edt(~inner, return_distances=False, return_indices=True)
    paper = small[:, near[0], near[1]]
    full = _polygon(corners, factor, (height, width))
    reach = max(1, round(BAND_SHARE * min(height, width) / factor))
    band = _upsample(_grown(~sheet, reach), factor, (height, width))
    fill = planes.astype(np.float32, copy=True)
    off = ~full
    # each pixel off the sheet takes its reduced pixel's paper (the last row and column
    # of them for the rows and columns the reduction left out)
    np.copyto(fill, np.stack([_upsample(p, factor, (height, width)) for p in paper]),
              where=off[None])  # fmt: skip
    return Sheet(full, fill, band, int(off.sum()), _sides_angle(corners))


__all__ = ["Sheet", "find_sheet"]
