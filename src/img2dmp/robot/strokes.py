"""Pen-down strokes of a writing run: holding the DMP clock at touch-down and lift-off,
and how much of each stroke the pen really wrote.

**Stroke gate** (:class:`StrokeGate`). The DMP's pen channel lifts and lowers the pen
between strokes, but the pen needs about 0.15 s to come down 6 mm and press with the set
force; a DMP that keeps running meanwhile leaves the first millimetres of the next
stroke unwritten. The gate holds the DMP clock instead:

- at a **touch-down** (the DMP's pen goes down after being up) the arm stays at the
  stroke's first point with the pen commanded down until the force has stayed within
  ``LAND_BAND`` of the set point for ``LAND_SETTLE_S``; only then does the DMP go on;
- at a **lift-off** (the next sample of the planned path has the pen up, or the path
  ends) the arm stays at the stroke's last point with the pen commanded up until the tip
  has left the paper for ``LIFT_CLEAR_STEPS`` steps, so no ink is dragged along the
  pen-up travel.

The held steps are logged with ``dwell = True``; the DMP's time does not advance on them.

**The DMP's clock comes to rest** (:class:`DMPClock`) wherever it is held, and at the end
of the path: it slows down over ``CLOCK_RAMP_S`` (a constant deceleration of the clock's
rate, ``rate <= sqrt(2 (t_stop - t) / CLOCK_RAMP_S)``) so that it reaches the held sample
exactly and at rest; at the start and after a hold it speeds up over as long. The pen
follows the same path on the paper; only its timing near a stop changes. A DMP's last
planned sample still moves the pen (its joints at 0.04-0.47 rad/s on the samples of
``examples/samples``): a clock stopped within one control step asked the arm's joints
for up to 132 rad/s^2.
"""

from __future__ import annotations

import math

import numpy as np

# A point of a commanded stroke is inked if the ink passes within this distance: half
# the width of a 0.5 mm pen line.
INK_TOLERANCE_M = 2.5e-4
# Commanded strokes and ink traces are compared at points this far apart at most.
RESAMPLE_M = 2e-5
# A touch-down is over once the force has stayed this close to the set point (relative)
# for LAND_SETTLE_S.
LAND_BAND = 0.1
LAND_SETTLE_S = 0.03
# A lift-off is over once the tip has been off the paper for this many control steps.
LIFT_CLEAR_STEPS = 2
#: The DMP's clock slows to rest over this long before each hold and the path's end, and
#: speeds up over as long after a hold (:class:`DMPClock`): a joint moving at 0.47 rad/s
#: at the stop (the fastest end of a DMP on the samples) decelerates at about 5 rad/s^2.
CLOCK_RAMP_S = 0.1


def clock_stops(pen_down, gated: bool) -> np.ndarray:
    """The plan's sample indices ``[n]`` (increasing, > 0) where the DMP's clock comes
    to rest: the last sample, and with the stroke gate (``gated``) each touch-down's first
    pen-down sample and each lift-off's last one (:class:`StrokeGate` holds there)."""
    down = np.asarray(pen_down, dtype=bool)  # [T]
    stops = {len(down) - 1}
    if gated:
        stops.update((np.flatnonzero(down[1:] & ~down[:-1]) + 1).tolist())  # touch-downs
        stops.update(np.flatnonzero(down[:-1] & ~down[1:]).tolist())  # lift-offs
    return np.array(sorted(k for k in stops if k > 0), dtype=int)


class DMPClock:
    """The DMP's time during a writing run: one control period per step at full rate,
    slowed to rest at each of ``stops`` (sample indices of the plan, :func:`clock_stops`)
    and sped up again after it (module docstring).

    The rate ``r`` (DMP seconds per second) rises from 0 to 1 over ``ramp_s`` after the
    start and after each stop (smoothstep: ``3 u^2 - 2 u^3``, ``u`` the share of
    ``ramp_s`` gone; a DMP starts at rest but with its full acceleration at once) and
    stays within ``sqrt(2 (t_stop - t) / ramp_s)`` (a constant deceleration of the
    clock; as control steps: :func:`~img2dmp.robot.controller.axis_speed_towards`'s
    rule), so it falls to 0 exactly at the stop (the last step lands on it).

    Parameters
    ----------
    dt_s : float
        The plan's sample spacing = the control period.
    stops : ndarray [n] int
    ramp_s : float
    """

    def __init__(self, dt_s: float, stops, ramp_s: float = CLOCK_RAMP_S):
        self.dt_s, self.ramp_s = float(dt_s), float(ramp_s)
        self.stops = [int(k) for k in stops]
        self.t = 0.0
        self.rate = 0.0
        self._moving_s = 0.0  # since the start or the last stop
        self._next = 0

    @property
    def done(self) -> bool:
        """The last stop (the path's end) is reached."""
        return self._next >= len(self.stops)

    def advance(self) -> tuple[float, int | None]:
        """The DMP time to step this control period, and the stop reached by it (its
        sample index; None while between stops)."""
        stop = self.stops[self._next]
        remaining = stop * self.dt_s - self.t
        self._moving_s += self.dt_s
        u = min(1.0, self._moving_s / self.ramp_s)
        # smoothstep up: no step of the clock's acceleration where it reaches full rate;
        # down: the rate from which steps falling by dv = dt / ramp cover what remains
        dv = self.dt_s / self.ramp_s
        brake = dv * (math.sqrt(2.0 * max(remaining, 0.0) / (dv * self.dt_s) + 0.25) - 0.5)
        self.rate = min(u * u * (3.0 - 2.0 * u), brake)
        step = self.rate * self.dt_s
        if step < remaining - 1e-9 * self.dt_s:  # else it lands on the stop (rounding)
            self.t += step
            return step, None
        self.t, self.rate, self._moving_s = stop * self.dt_s, 0.0, 0.0
        self._next += 1
        return max(remaining, 0.0), stop

    def sample(self, pen_down) -> tuple[int, bool]:
        """The plan's sample at or before the clock's time, and the pen's state there: a
        sample's own, between two samples down only if both are (a pen switch happens at a
        sample, where the clock holds)."""
        j = self.t / self.dt_s
        k = int(round(j))
        if abs(j - k) > 1e-6:
            k = int(math.floor(j))
            return k, bool(pen_down[k] and pen_down[min(k + 1, len(pen_down) - 1)])
        return k, bool(pen_down[k])


def min_jerk_along(points, n: int) -> np.ndarray:
    """``n`` points ``[n, 2]`` along a polyline at minimum-jerk arc-length spacing (at rest
    at both ends): a pen's natural timing along one stroke."""
    points = np.asarray(points, dtype=float)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    u = np.linspace(0.0, 1.0, n)
    u = (10 * u**3 - 15 * u**4 + 6 * u**5) * s[-1]
    return np.stack([np.interp(u, s, points[:, 0]), np.interp(u, s, points[:, 1])], axis=-1)


def strokes_path(strokes, n_total: int = 400) -> np.ndarray:
    """A multi-stroke drawing as one pen path ``[T, 3]`` (x, y, pen) to fit a d = 3 DMP to.

    ``strokes`` is a list of polylines (``[n_i, 2]`` points each, pen down); consecutive
    strokes are joined by straight pen-up travels (pen 0). Every part is sampled at
    minimum-jerk spacing (:func:`min_jerk_along`) with points in proportion to its
    length (at least 40).
    """
    parts, prev = [], None
    for pts in strokes:
        pts = np.asarray(pts, dtype=float)
        if prev is not None:
            parts.append((np.array([prev, pts[0]]), 0.0))
        parts.append((pts, 1.0))
        prev = pts[-1]
    lengths = [np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p, _ in parts]
    out = []
    for (pts, pen), length in zip(parts, lengths, strict=True):
        n = max(40, int(n_total * length / sum(lengths)))
        out.append(np.concatenate([min_jerk_along(pts, n), np.full((n, 1), pen)], axis=1))
    return np.concatenate(out)


def stroke_spans(pen_down) -> list[tuple[int, int]]:
    """``(first, last)`` sample indices (inclusive) of each run of ``True`` in ``pen_down``."""
    down = np.asarray(pen_down, dtype=bool)
    edges = np.diff(np.concatenate([[0], down.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


def _densify(points: np.ndarray, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A polyline ``[n, 2]`` as points at most ``spacing_m`` apart, and the length each
    new point stands for (half of each neighbouring piece)."""
    if len(points) == 1:
        return points.copy(), np.zeros(1)
    seg = np.diff(points, axis=0)  # [n-1, 2]
    seg_len = np.linalg.norm(seg, axis=1)
    pieces = np.maximum(1, np.ceil(seg_len / spacing_m).astype(int))  # [n-1]
    # Point j of segment i at fraction j / pieces[i], plus the polyline's last point.
    seg_of = np.repeat(np.arange(len(seg)), pieces)
    frac = (np.arange(len(seg_of)) - np.repeat(np.cumsum(pieces) - pieces, pieces)) / np.repeat(
        pieces, pieces
    )
    dense = np.concatenate([points[seg_of] + frac[:, None] * seg[seg_of], points[-1:]])
    piece_len = np.repeat(seg_len / pieces, pieces)  # [m-1]
    weight = np.zeros(len(dense))
    weight[:-1] += piece_len / 2
    weight[1:] += piece_len / 2
    return dense, weight


def ink_trace(tip_xy_m: np.ndarray, touching: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ink_points` and the length (m) of ink each point stands for: half of each
    neighbouring piece of the tip's path, 0 for the steps on which the tip rested (a
    touch-down holds it at one point for a while)."""
    touching = np.asarray(touching, dtype=bool)
    points, weights = [], []
    for a, b in stroke_spans(touching):
        dense, weight = _densify(np.asarray(tip_xy_m[a : b + 1], dtype=float), RESAMPLE_M)
        points.append(dense)
        weights.append(weight)
    if not points:
        return np.zeros((0, 2)), np.zeros(0)
    return np.concatenate(points), np.concatenate(weights)


def ink_points(tip_xy_m: np.ndarray, touching: np.ndarray) -> np.ndarray:
    """The ink of a run as points ``[m, 2]`` at most ``RESAMPLE_M`` apart: the tip's path
    between consecutive steps that both touched the paper, and lone touching steps."""
    return ink_trace(tip_xy_m, touching)[0]


def coverage(path_xy_m: np.ndarray, ink_xy_m: np.ndarray, tolerance_m: float) -> float:
    """Share of the length of the polyline ``path_xy_m [n, 2]`` within ``tolerance_m`` of
    some point of ``ink_xy_m [m, 2]`` (a path of one point: 1.0 or 0.0)."""
    from scipy.spatial import cKDTree

    path = np.asarray(path_xy_m, dtype=float)
    if len(ink_xy_m) == 0:
        return 0.0
    dense, weight = _densify(path, RESAMPLE_M)
    dist, _ = cKDTree(ink_xy_m).query(dense, distance_upper_bound=tolerance_m)
    near = np.isfinite(dist)
    if weight.sum() <= 0.0:
        return float(near.all())
    return float(weight[near].sum() / weight.sum())


def ink_on_path_share(
    path_xy_m: np.ndarray,
    pen_down,
    ink_xy_m: np.ndarray,
    ink_weight=None,
    tolerance_m: float = INK_TOLERANCE_M,
) -> float:
    """Share of the ink ``ink_xy_m [m, 2]`` within ``tolerance_m`` of the pen-down parts
    of the commanded path ``path_xy_m [n, 2]`` (``pen_down [n]``): the converse of
    :func:`coverage`, which finds commanded path without ink; this finds ink off the
    path. ``ink_weight [m]``: the length each ink point stands for (:func:`ink_trace`);
    without it (or if it sums to 0) every point counts alike. NaN without ink."""
    from scipy.spatial import cKDTree

    ink = np.asarray(ink_xy_m, dtype=float).reshape(-1, 2)
    if len(ink) == 0:
        return float("nan")
    path = ink_points(np.asarray(path_xy_m, dtype=float), pen_down)  # the strokes, dense
    if len(path) == 0:
        return 0.0
    dist, _ = cKDTree(path).query(ink, distance_upper_bound=tolerance_m)
    near = np.isfinite(dist)
    w = np.ones(len(ink)) if ink_weight is None else np.asarray(ink_weight, dtype=float)
    if w.sum() <= 0.0:
        w = np.ones(len(ink))
    return float(w[near].sum() / w.sum())


def ink_distance_m(ink_a_m: np.ndarray, ink_b_m: np.ndarray) -> float:
    """Symmetric Hausdorff distance between two ink traces (points ``[n, 2]``, ``[m, 2]``):
    the farthest any ink of one lies from the ink of the other (inf if only one is empty)."""
    from scipy.spatial import cKDTree

    if len(ink_a_m) == 0 or len(ink_b_m) == 0:
        return 0.0 if len(ink_a_m) == len(ink_b_m) else float("inf")
    a_to_b = cKDTree(ink_b_m).query(ink_a_m)[0].max()
    b_to_a = cKDTree(ink_a_m).query(ink_b_m)[0].max()
    return float(max(a_to_b, b_to_a))


def stroke_table(
    plan, log, force_set_n: float, *, tolerance: float = 0.2, ink_tolerance_m=INK_TOLERANCE_M
) -> list[dict]:
    """One entry per pen-down stroke of ``plan`` (a ``PlannedPath``), measured on ``log``
    (a ``WritingLog``).

    Returns
    -------
    list of dict with
        ``start_s``, ``end_s`` - the stroke's DMP time; ``length_mm`` - its commanded
        length; ``ink_share`` - share of that length with ink (see the module
        docstring); ``force_in_band_share`` - share of its pen-down steps (DMP running)
        with the force within ``±tolerance`` of ``force_set_n`` (nan for none);
        ``dwell_s`` - time the DMP clock was held at its touch-down.
    """
    dt_s = float(np.median(np.diff(plan.time_s))) if len(plan.time_s) > 1 else 1.0
    tip_xy = log.tip_m[:, :2]
    writing = log.pen_down & (log.phase <= 1)  # approach or write, pen commanded down
    out = []
    for first, last in stroke_spans(plan.pen_down):
        t0, t1 = plan.time_s[first], plan.time_s[last]
        mine = writing & (log.dmp_time_s >= t0 - dt_s / 2) & (log.dmp_time_s <= t1 + dt_s / 2)
        ink = ink_points(tip_xy, mine & (log.force_n > 0.0))
        path = plan.xy_m[first : last + 1]
        running = mine & ~log.dwell & (log.phase == 1)
        in_band = np.abs(log.force_n[running] - force_set_n) <= tolerance * force_set_n
        out.append(
            {
                "start_s": float(t0),
                "end_s": float(t1),
                "length_mm": float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum() * 1e3),
                "ink_share": coverage(path, ink, ink_tolerance_m),
                "force_in_band_share": float(in_band.mean()) if in_band.size else float("nan"),
                "dwell_s": float((mine & log.dwell).sum() * dt_s),
            }
        )
    return out


def stroke_report(plan, log, force_set_n: float, *, tolerance: float = 0.2) -> dict:
    """The stroke measures of a run, for its metrics.

    Returns
    -------
    dict with
        ``strokes`` - :func:`stroke_table`; ``stroke_ink_share_min`` - the least-inked
        stroke's ink share (nan without strokes); ``dwell_s`` - time the DMP clock was
        held in all; ``force_in_band_share_with_dwell`` - share of the write phase's
        pen-down steps with the force in band, the held steps included.
    """
    strokes = stroke_table(plan, log, force_set_n, tolerance=tolerance)
    dt_s = float(np.median(np.diff(log.time_s))) if log.n_steps > 1 else 0.0
    down = (log.phase == 1) & log.pen_down
    in_band = np.abs(log.force_n[down] - force_set_n) <= tolerance * force_set_n
    return {
        "strokes": strokes,
        "stroke_ink_share_min": min((s["ink_share"] for s in strokes), default=float("nan")),
        "dwell_s": float(log.dwell.sum() * dt_s),
        "force_in_band_share_with_dwell": float(in_band.mean()) if in_band.size else float("nan"),
    }


class StrokeGate:
    """Holds the DMP clock of a writing run between strokes (see the module docstring).

    :meth:`WritingRun.write` calls :meth:`before_step` after stepping the DMP to sample
    ``k`` and before its control step, :meth:`after_step` after it. The held steps go
    through ``run.control_step(..., dwell=True)``.

    Parameters
    ----------
    run : WritingRun
        The run being written (its approach done).
    planned_pen_down : ndarray [T] bool
        The pen channel of the checked plan, to see a lift-off one sample ahead.
    """

    def __init__(self, run, planned_pen_down):
        self.run = run
        self.planned_pen_down = np.asarray(planned_pen_down, dtype=bool)
        self.force_set_n = run.options.controller_config.force_set_n
        self.timeout_s = run.options.approach_timeout_s
        self.settle_steps = max(1, int(round(LAND_SETTLE_S / run.dt_s)))
        self.max_steps = int(math.ceil(self.timeout_s / run.dt_s))
        # The approach has pressed the pen down at the first point if the plan starts so.
        self.pen_was_down = bool(self.planned_pen_down[0])

    def before_step(self, xy_m, pen_down: bool, dmp_time_s: float) -> None:
        """At a touch-down, hold at ``xy_m`` until the force has settled in band."""
        if pen_down and not self.pen_was_down:
            self._land(xy_m, dmp_time_s)
        self.pen_was_down = pen_down

    def after_step(self, k: int, xy_m, pen_down: bool, dmp_time_s: float) -> None:
        """If the plan lifts the pen after sample ``k`` (or ends there), hold at ``xy_m``
        until the tip has left the paper."""
        nxt = k + 1
        if pen_down and (nxt >= len(self.planned_pen_down) or not self.planned_pen_down[nxt]):
            self._lift(xy_m, dmp_time_s)
            self.pen_was_down = False

    def _land(self, xy_m, dmp_time_s: float) -> None:
        band = LAND_BAND * self.force_set_n
        settled = steps = 0
        force_n = 0.0
        while settled < self.settle_steps:
            force_n = self.run.control_step("write", xy_m, True, dmp_time_s, dwell=True)
            settled = settled + 1 if abs(force_n - self.force_set_n) <= band else 0
            steps += 1
            if steps > self.max_steps:
                raise RuntimeError(
                    f"the pen did not land at {self.force_set_n} N within {self.timeout_s} s "
                    f"at the stroke starting at t = {dmp_time_s:.3f} s of the DMP "
                    f"(last force {force_n:.2f} N)"
                )

    def _lift(self, xy_m, dmp_time_s: float) -> None:
        clear = steps = 0
        while clear < LIFT_CLEAR_STEPS:
            force_n = self.run.control_step("write", xy_m, False, dmp_time_s, dwell=True)
            clear = clear + 1 if force_n <= 0.0 else 0
            steps += 1
            if steps > self.max_steps:
                raise RuntimeError(
                    f"the pen did not leave the paper within {self.timeout_s} s at the "
                    f"stroke ending at t = {dmp_time_s:.3f} s of the DMP "
                    f"(last force {force_n:.2f} N)"
                )
