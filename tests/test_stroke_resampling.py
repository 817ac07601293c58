"""Resampling a pen path so that every stroke keeps its own instants (issue 32, part 2).

The even time grid of ``resample_pen_path`` loses a dot (no duration) or a stroke shorter
than its step; ``resample_strokes`` allocates the instants per stroke and pen-up stretch
in proportion to their durations, with a floor for each. Checked on hand-made paths:
what each stroke gets, where the pen is, what a path of one stroke gets, and where the
floor gives way to a refusal that names the instants needed.
"""

from __future__ import annotations

import numpy as np
import pytest

from img2dmp.data.importer import (
    MIN_STROKE_INSTANTS,
    PenPath,
    resample,
    resample_pen_path,
    resample_strokes,
)
from img2dmp.data.store import pen_runs


def _path(strokes: list[tuple[float, float, int]], up: list[tuple[float, float]] = ()) -> PenPath:
    """A path of strokes ``(start s, end s, points)`` (a dot: one point, start = end) on
    a line x = t * 10, y = stroke; ``up`` adds pen-up points ``(t, x)``."""
    xy, t, stroke = [], [], []
    for k, (a, b, n) in enumerate(strokes):
        ts = np.linspace(a, b, n)
        t += list(ts)
        xy += [(10 * u, float(k)) for u in ts]
        stroke += [k] * n
    for u, x in up:
        t.append(u)
        xy.append((x, -1.0))
        stroke.append(-1)
    order = np.argsort(t)
    return PenPath(
        xy=np.array(xy)[order], t_s=np.array(t)[order], stroke=np.array(stroke)[order], name="p"
    )


def test_every_stroke_and_dot_gets_its_own_instants_in_proportion_to_time():
    # A 1 s stroke, a dot, a stroke of 3 points in 30 ms, a 2 s stroke.
    pen = _path([(0.0, 1.0, 50), (1.5, 1.5, 1), (2.0, 2.03, 3), (3.0, 5.0, 100)])
    pen.t_s[np.flatnonzero(pen.stroke == 2)[1]] = 2.005  # not midway: its own time counts
    with pytest.raises(ValueError, match="4 stroke.*become 2 on the grid of 60 instants"):
        resample_pen_path(pen, 60)  # the even grid misses the dot and the short stroke
    r = resample_strokes(pen, 60)
    assert len(r.times) == len(r.path) == 60 and (np.diff(r.times) > 0).all()
    assert r.times[0] == 0.0 and r.times[-1] == 5.0
    (a0, b0), dot, short, (a3, b3) = r.spans
    assert dot[0] == dot[1] and r.times[dot[0]] == 1.5  # the dot, at its time and place
    assert np.allclose(r.path[dot[0], :2], [15.0, 1.0])
    assert short[1] - short[0] + 1 == 3  # its own 3 points
    assert np.allclose(r.times[short[0] : short[1] + 1], [2.0, 2.005, 2.03])
    assert np.allclose(r.path[short[0] : short[1] + 1, 0], [20.0, 20.15, 20.3])  # its points
    # The rest follows time as on an even grid: the 2 s stroke gets twice the 1 s one.
    assert (b3 - a3 + 1) / (b0 - a0 + 1) == pytest.approx(2.0, abs=0.15)
    # The pen is down exactly on the spans; pen-up instants lie strictly between strokes.
    down = np.zeros(60, bool)
    for lo, hi in r.spans:
        down[lo : hi + 1] = True
    assert np.array_equal(r.path[:, 2] == 1.0, down) and set(r.path[:, 2]) == {0.0, 1.0}
    assert pen_runs(down) == r.spans
    pairs = zip(r.spans[:-1], r.spans[1:], strict=True)
    ends = [(r.times[hi], r.times[lo2]) for (_, hi), (lo2, _) in pairs]
    for k in np.flatnonzero(~down):
        assert any(e < r.times[k] < s for e, s in ends), k


def test_a_path_of_one_stroke_gets_the_even_grid():
    pen = _path([(0.2, 1.7, 37)])
    times, path = resample_pen_path(pen, 50)
    r = resample_strokes(pen, 50)
    assert np.array_equal(r.times, times) and np.array_equal(r.path, path)
    assert r.spans == [(0, 49)]
    assert resample(pen, 50, "uniform").spans == [(0, 49)]


def test_the_floor_gives_way_to_two_instants_then_to_a_refusal_naming_the_need():
    pen = _path([(k, k + 0.5, 5) for k in range(10)])  # 10 strokes of 5 points
    least = 10 * MIN_STROKE_INSTANTS + 9
    assert min(hi - lo + 1 for lo, hi in resample_strokes(pen, least).spans) == 3
    r = resample_strokes(pen, least - 1)  # too few for 3 each: 2 each at the least
    assert len(r.spans) == 10 and min(hi - lo + 1 for lo, hi in r.spans) == 2
    with pytest.raises(ValueError, match=r"10 strokes .* need at least 29 instants.*--n-times 29"):
        resample_strokes(pen, 28)
    assert len(resample_strokes(pen, 29).spans) == 10


def test_pen_up_before_the_first_stroke_and_after_the_last():
    pen = _path([(1.0, 2.0, 20), (3.0, 3.0, 1)], up=[(0.0, -5.0), (0.5, 0.0), (4.0, 40.0)])
    r = resample_strokes(pen, 30)
    assert r.times[0] == 0.0 and r.path[0, 2] == 0.0 and r.path[0, 0] == -5.0
    assert r.times[-1] == 4.0 and r.path[-1, 2] == 0.0 and r.path[-1, 0] == 40.0
    assert len(r.spans) == 2 and r.spans[1][0] == r.spans[1][1] < 29
