"""A pen path and its resampling to a data set's time grid (the build's resample step).

A :class:`PenPath` is what a reader of strokes with times yields (a trajectory file, a
recording, an Omniglot drawing): positions in pixels of the sample's own image, seconds,
the stroke of every point. :func:`resample` brings it to ``n_times`` instants:
:func:`resample_strokes` allocates them per stroke and pen-up stretch so that every
stroke and dot keeps its own; :func:`resample_pen_path` spreads them evenly over the
path's duration and refuses a path whose short strokes or lifts fall between them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .store import pen_runs

#: Fewest instants a stroke of this many points or more gets (its two ends and one
#: between); a stroke of fewer points gets one per point, a dot one. Where a drawing's
#: strokes cannot all have it, they get 2 (their ends).
MIN_STROKE_INSTANTS = 3
#: The ways of resampling a path (``ImportOptions.resample``).
RESAMPLING = ("strokes", "uniform")


@dataclass
class PenPath:
    """A pen path as read from a trajectory file.

    Attributes
    ----------
    xy : float64 [T, 2]
        Positions in pixels of the sample's image (x = column, y = row).
    t_s : float64 [T]
        Seconds, strictly increasing (as given, not shifted to 0).
    stroke : int64 [T]
        The stroke of every point (0, 1, ... in writing order), -1 while the pen is up.
    name : str
        The file it was read from.
    point_name : callable
        ``point_name(k)`` names point ``k`` in messages as the file does (``line 7`` of a
        CSV file, ``stroke 1 point 4`` of a JSON list of strokes, else ``point 7``).
    file_frame : str
        How the file gives positions, as a message asking whether they are right says
        it (an Omniglot stroke file has y pointing up; :attr:`xy` is read from it).
    """

    xy: np.ndarray
    t_s: np.ndarray
    stroke: np.ndarray
    name: str
    point_name: Callable[[int], str] = field(default=lambda k: f"point {k}", repr=False)
    file_frame: str = "x = column and y = row (y down)"

    @property
    def n_strokes(self) -> int:
        return int(self.stroke.max()) + 1

    @property
    def needs_pen(self) -> bool:
        """Whether it needs a pen channel: several strokes or pen-up points."""
        return self.n_strokes > 1 or bool((self.stroke < 0).any())


def resample_pen_path(pen: PenPath, n_times: int) -> tuple[np.ndarray, np.ndarray]:
    """A pen path at ``n_times`` instants evenly spaced over its duration.

    Positions are interpolated linearly between the recorded points; the pen is down
    (1) on every stretch between two points of one stroke and at the points of a
    stroke, up (0) strictly inside the travel between strokes.

    Returns
    -------
    times : float64 [n_times]
        Seconds since the first point.
    path : float64 [n_times, 3]
        ``(x, y, pen)``.

    Raises ``ValueError`` if a stroke or a pen-up gap is shorter than one step of the
    grid (the strokes would merge or vanish).
    """
    t, s = pen.t_s, pen.stroke
    grid = np.linspace(t[0], t[-1], n_times)  # [n]; its ends are t[0] and t[-1] exactly
    xy = np.stack([np.interp(grid, t, pen.xy[:, j]) for j in range(2)], axis=-1)  # [n, 2]
    k = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 2)  # [n]
    drawn = (s[:-1] == s[1:]) & (s[:-1] >= 0)  # [T-1] segments written
    down = np.where(grid == t[k], s[k] >= 0, drawn[k])
    down = np.where(grid == t[k + 1], s[k + 1] >= 0, down)
    runs = int(down[0]) + int(np.sum(down[1:] & ~down[:-1]))
    if runs != pen.n_strokes:
        step = (t[-1] - t[0]) / (n_times - 1)
        raise ValueError(
            f"{pen.name}: its {pen.n_strokes} stroke(s) become {runs} on the grid of "
            f"{n_times} instants {step:.3g} s apart: a stroke or a pen-up gap is shorter than "
            "a step; use more instants (--n-times)"
        )
    return grid - t[0], np.concatenate([xy, down[:, None].astype(np.float64)], axis=-1)


@dataclass
class Resampled:
    """A pen path at the instants of a data set's time grid.

    Attributes
    ----------
    times : float64 [n]
        Seconds since the first point, strictly increasing.
    path : float64 [n, 3]
        ``(x, y, pen)``, pen 1 down, 0 up.
    spans : list of (int, int)
        The first and last instant of every stroke, in writing order (the data set's
        ``stroke_spans``).
    """

    times: np.ndarray
    path: np.ndarray
    spans: list[tuple[int, int]]


def _pieces(pen: PenPath) -> list[tuple[str, float, float, int]]:
    """The strokes and pen-up stretches of a path in time order, as ``(kind, start, end,
    points)``: kind ``"stroke"``, ``"lead"`` (up before the first stroke), ``"up"``
    (between two strokes) or ``"trail"`` (up after the last); points of a stroke only."""
    t, s = pen.t_s, pen.stroke
    out = []
    for k in range(pen.n_strokes):
        members = np.flatnonzero(s == k)
        a, b = float(t[members[0]]), float(t[members[-1]])
        if out:
            out.append(("up", out[-1][2], a, 0))
        elif a > t[0]:
            out.append(("lead", float(t[0]), a, 0))
        out.append(("stroke", a, b, len(members)))
    if out[-1][2] < t[-1]:
        out.append(("trail", out[-1][2], float(t[-1]), 0))
    return out


def _allocate(durations: np.ndarray, least: np.ndarray, n: int) -> np.ndarray:
    """Instants per piece summing to ``n``: in proportion to the pieces' durations, as an
    even grid would give them, but at least ``least`` each (``least.sum() <= n``)."""
    free = np.ones(len(durations), bool)
    while True:  # pin the pieces whose share falls short of their least; share the rest
        budget = n - least[~free].sum()
        share = np.where(free, budget * durations / durations[free].sum(), least)
        short = free & (share < least)
        if not short.any():
            break
        free &= ~short
    counts = np.maximum(np.floor(share).astype(np.int64), least)
    rest = n - int(counts.sum())  # the largest remainders take the instants left
    order = np.argsort(-(share - np.floor(share)) * free, kind="stable")
    counts[order[:rest]] += 1
    return counts


def _piece_times(kind: str, a: float, b: float, k: int, t_own: np.ndarray) -> np.ndarray:
    """``k`` instants of one piece from ``a`` to ``b``: a stroke's both ends (or its own
    points when it has as few as it gets), strictly inside a pen-up stretch between
    strokes, from the start of the path before its first stroke, to its end after the
    last."""
    if kind == "stroke":
        if k == len(t_own) and k <= MIN_STROKE_INSTANTS:
            return t_own
        return np.linspace(a, b, k) if k > 1 else np.array([a])
    u = np.arange(k, dtype=np.float64)
    frac = {"up": (u + 1) / (k + 1), "lead": u / k, "trail": (u + 1) / k}[kind]
    return a + (b - a) * frac


def resample_strokes(pen: PenPath, n_times: int) -> Resampled:
    """A pen path at ``n_times`` instants allocated per stroke, so that none is lost.

    The even grid of :func:`resample_pen_path` loses a stroke or a pen lift shorter than
    its step (a dot has no duration at all). Here every stroke and every pen-up stretch
    gets its own instants, in proportion to its duration as on the even grid, but every
    stroke at least ``min(points, MIN_STROKE_INSTANTS)`` (a dot one, at its time) and
    every pen-up stretch at least one. A stroke's instants run evenly from its first to
    its last point (or are its own points, when it has no more than it gets), a pen-up
    stretch's strictly between the strokes. Positions are interpolated linearly between
    the recorded points; the pen is 1 at a stroke's instants, 0 at the others. A path of
    one stroke gets the even grid.

    Raises ``ValueError`` naming the file if the strokes need more instants than
    ``n_times`` (2 per stroke, 1 per dot and 1 per pen-up stretch at the least).
    """
    pieces = _pieces(pen)
    durations = np.array([b - a for _, a, b, _ in pieces])  # [P]
    for least_points in (MIN_STROKE_INSTANTS, 2):
        least = np.array(
            [min(p, least_points) if kind == "stroke" else 1 for kind, _, _, p in pieces]
        )
        if least.sum() <= n_times:
            break
    else:
        raise ValueError(
            f"{pen.name}: its {pen.n_strokes} strokes and the pen-up travel between them need "
            f"at least {least.sum()} instants, more than the {n_times} of the grid; use more "
            f"instants (--n-times {least.sum()})"
        )
    counts = _allocate(durations, least, n_times)  # [P]
    grid, spans, k, first = [], [], 0, 0
    t = pen.t_s
    for (kind, a, b, _), c in zip(pieces, counts, strict=True):
        own = t[pen.stroke == k] if kind == "stroke" else t[:0]
        grid.append(_piece_times(kind, a, b, int(c), own))
        if kind == "stroke":
            spans.append((first, first + int(c) - 1))
            k += 1
        first += int(c)
    times = np.concatenate(grid)  # [n]
    # As stored: float32 seconds since the first point (not the time stamps as given).
    if not (np.diff((times - t[0]).astype(np.float32)) > 0).all():
        raise ValueError(
            f"{pen.name}: two of its instants lie closer than a float32 time stamp can tell "
            f"apart ({times[-1] - t[0]:.6g} s long); give the path fewer instants (--n-times)"
        )
    xy = np.stack([np.interp(times, t, pen.xy[:, j]) for j in range(2)], axis=-1)  # [n, 2]
    down = np.zeros(n_times)
    for lo, hi in spans:
        down[lo : hi + 1] = 1.0
    return Resampled(times - t[0], np.concatenate([xy, down[:, None]], axis=-1), spans)


def resample(pen: PenPath, n_times: int, how: str = "strokes") -> Resampled:
    """:func:`resample_strokes` (``how="strokes"``) or :func:`resample_pen_path`
    (``"uniform"``) of a pen path, with the instants of every stroke."""
    if how == "strokes":
        return resample_strokes(pen, n_times)
    times, path = resample_pen_path(pen, n_times)
    return Resampled(times, path, pen_runs(path[:, 2] > 0.5))
