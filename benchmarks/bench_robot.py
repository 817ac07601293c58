"""Simulation speed of the writing robot: a 3 s digit "2" written by the simulated iiwa.

For each control rate it prints

- the speed of the control loop as a multiple of real time (simulated seconds of
  approach + writing + lift per wall-clock second, one physics step per control step),
  and per second of the process's CPU time in the same stages (less sensitive to other
  jobs on the machine than wall time),
- the wall time of the whole call (scene set-up, planning and the reachability check
  along the path, simulation; no pictures), and the digit's 3 s over that,
- where a control step's time goes (IK on the twin, inverse dynamics, physics step,
  the rest: state reads, contact query, DMP step, logging),
- the accuracy reached, so that speed is compared at equal quality.

Then, at 240 Hz, multi-stroke digits (DMPs with d = 3, a pen channel: a two-stroke "4", a
"5" with its top bar, a "7" with a cross bar, the "+" of the tests) with the DMP clock
held while the pen lands and lifts (the default) and without (as before), each with the
pen hovering low before a touch-down (the default) and without: per stroke the
share of its commanded pen-down length that left ink and the share of its pen-down time
with the force within ±20 % of the set point, the time the DMP was held, the speed.

Run: ``.venv/bin/python benchmarks/bench_robot.py [--rates 240 1000] [--repeats 3]
[--no-strokes]``
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import defaultdict

import numpy as np

import _machine
from img2dmp.dmp import DMPConfig, DMPIntegrator, fit_dmp
from img2dmp.robot import WritingOptions, WritingScene, write_dmp, write_with_options, writing
from img2dmp.robot.strokes import strokes_path

DURATION_S = 3.0


def digit_two(n: int = 300) -> np.ndarray:
    """A "2" in the pixels of a 28 x 28 image: arc over the top, diagonal, base line."""
    a = np.linspace(np.radians(160), np.radians(-40), 120)
    arc = np.stack([14 + 6 * np.cos(a), 11 - 6 * np.sin(a)], axis=-1)
    corner, end = np.array([8.0, 22.0]), np.array([21.0, 22.0])
    diag = arc[-1] + (corner - arc[-1]) * np.linspace(0, 1, 80)[1:, None]
    base = corner + (end - corner) * np.linspace(0, 1, 60)[1:, None]
    pts = np.concatenate([arc, diag, base])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    u = np.linspace(0.0, 1.0, n)
    u = (10 * u**3 - 15 * u**4 + 6 * u**5) * s[-1]
    return np.stack([np.interp(u, s, pts[:, 0]), np.interp(u, s, pts[:, 1])], axis=-1)


_A = np.radians(np.linspace(125, -150, 40))
MULTI_STROKE = {
    "4": [[(15, 5), (7, 17), (21, 17)], [(18, 9), (18, 24)]],
    "5": [np.concatenate([[(10, 5), (9, 13)],
                          np.stack([13.5 + 5 * np.cos(_A), 17.5 - 5 * np.sin(_A)], -1)]),
          [(10, 5), (20, 5)]],
    "7": [[(7, 6), (21, 6), (12, 24)], [(12, 15), (20, 15)]],
    "+": [[(14, 6), (14, 22)], [(7, 14), (21, 14)]],
}  # fmt: skip


def stroke_table() -> None:
    """Each multi-stroke digit at 240 Hz with and without the stroke gate."""
    print()
    print('multi-stroke digits at 240 Hz (3 s DMPs, d = 3, 40 kernels); per stroke: commanded '
          'length mm / ink % / force in band %')  # fmt: skip
    print(f"{'digit':>5} {'gate':>4} {'hover':>5} {'loop x real':>12} {'held s':>7} "
          f"{'F band %':>9} {'F band incl. held %':>20}  strokes")  # fmt: skip
    for name, strokes in MULTI_STROKE.items():
        y = strokes_path(strokes)
        config = DMPConfig(n_kernels=40, n_dims=3, scaling="none")
        params = fit_dmp(np.linspace(0, DURATION_S, len(y)), y, config).params
        for gate, hover in ((False, False), (False, True), (True, False), (True, True)):
            options = WritingOptions(render_size_px=None, stroke_dwell=gate, hover=hover)
            m = write_with_options(params, config, (28, 28), options).metrics
            per = "; ".join(
                f"{s['length_mm']:.1f} / {100 * s['ink_share']:.1f} / "
                f"{100 * s['force_in_band_share']:.1f}"
                for s in m["strokes"]
            )
            print(
                f"{name:>5} {'on' if gate else 'off':>4} {'on' if hover else 'off':>5} "
                f"{m['real_time_factor']:11.1f}x "
                f"{m['dwell_s']:7.3f} {100 * m['force_in_band_share']:9.1f} "
                f"{100 * m['force_in_band_share_with_dwell']:20.1f}  {per}"
            )
    print("(gate: the DMP waits for the pen at touch-down and lift-off; hover: the pen comes "
          "down to the approach clearance before a touch-down; F band: force within ±20 % of "
          "5 N over the pen-down time with the DMP running; incl. held: the time the DMP "
          "waited for the pen counted as pen-down time)")  # fmt: skip


def _timed(owner, name: str, totals: dict, clock=time.perf_counter):
    """Replace ``owner.name`` by a wrapper adding its time on ``clock`` (wall time by
    default) to ``totals["Owner.name"]``."""
    original = getattr(owner, name)
    key = f"{owner.__name__.rsplit('.', 1)[-1]}.{name}"

    def wrapper(*args, **kwargs):
        t0 = clock()
        try:
            return original(*args, **kwargs)
        finally:
            totals[key] += clock() - t0

    setattr(owner, name, wrapper)
    return original


# Timed parts of a control step: (owner, attribute, column title).
PARTS = (
    (DMPIntegrator, "step", "DMP %"),
    (WritingScene, "solve_ik", "IK %"),
    (WritingScene, "inverse_dynamics", "ID %"),
    (WritingScene, "step", "phys %"),
    (WritingScene, "contact_force_n", "contact %"),
)


def run_once(params, config, rate_hz: float):
    """One timed call of write_dmp; returns (metrics, call_s, shares of the loop [%]);
    ``metrics["cpu_time_factor"]``: simulated seconds per CPU second of the loop (the
    approach, write and lift stages)."""
    totals: dict = defaultdict(float)
    originals = [(owner, name, _timed(owner, name, totals)) for owner, name, _ in PARTS]
    # plan_path (DMP steps), check_path and slow_for_joint_limits (IK solves along the
    # plan) run before the loop: timed separately.
    names = ("plan_path", "check_path", "slow_for_joint_limits")
    pre = [(writing, n, _timed(writing, n, totals)) for n in names]
    cpu: dict = defaultdict(float)
    for stage in ("approach", "write", "lift"):
        original = _timed(writing.WritingRun, stage, cpu, time.process_time)
        pre.append((writing.WritingRun, stage, original))
    try:
        t0 = time.perf_counter()
        result = write_dmp(params, config, (28, 28), control_rate_hz=rate_hz, render_size_px=None)
        call_s = time.perf_counter() - t0
    finally:
        for owner, name, f in originals + pre:
            setattr(owner, name, f)
    m = result.metrics
    m["cpu_time_factor"] = m["simulated_s"] / sum(cpu.values())
    shares = []
    for owner, name, _ in PARTS:
        key = f"{owner.__name__}.{name}"
        spent = totals[key]  # the loop's share only:
        if key == "DMPIntegrator.step":
            spent -= totals["writing.plan_path"]  # which is made of DMP steps
        if key == "WritingScene.solve_ik":  # which these are made of
            spent -= totals["writing.check_path"] + totals["writing.slow_for_joint_limits"]
        shares.append(100.0 * spent / m["wall_s"])
    return m, call_s, shares


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", type=float, nargs="+", default=[240.0, 1000.0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-strokes", action="store_true", help="skip the multi-stroke digits")
    args = ap.parse_args()

    print(_machine.describe())
    config = DMPConfig(scaling="none")
    params = fit_dmp(np.linspace(0, DURATION_S, 300), digit_two(), config).params
    print(f'digit "2", tau = {float(params.tau):.1f} s, 28 x 28 px image written 40 mm tall')
    titles = [t for _, _, t in PARTS]
    print(
        f"{'rate Hz':>8} {'loop x real':>12} {'x CPU':>7} {'call s':>7} {'digit/call':>11} "
        + " ".join(f"{t:>9}" for t in titles)
        + f" {'err mean mm':>12} {'err max mm':>11} {'F mean N':>9} {'F std N':>8}"
    )
    for rate in args.rates:
        runs = [run_once(params, config, rate) for _ in range(args.repeats)]
        loop = statistics.median(r[0]["real_time_factor"] for r in runs)
        cpu = statistics.median(r[0]["cpu_time_factor"] for r in runs)
        call = statistics.median(r[1] for r in runs)
        shares = np.median(np.array([r[2] for r in runs]), axis=0)
        m = runs[-1][0]
        print(
            f"{rate:8.0f} {loop:11.1f}x {cpu:6.1f}x {call:7.2f} {DURATION_S / call:10.1f}x "
            + " ".join(f"{s:9.0f}" for s in shares)
            + f" {m['tracking_error_mean_mm']:12.3f} {m['tracking_error_max_mm']:11.3f}"
            f" {m['force_mean_n']:9.3f} {m['force_std_n']:8.4f}"
        )
    print(
        f"(medians of {args.repeats} runs; loop = simulated approach + writing + lift per "
        "wall second; x CPU = the same per CPU second of the loop; call = "
        "set-up, plan, reachability check and loop; shares are of the loop's wall time; "
        "headless pybullet p.DIRECT)"
    )
    if not args.no_strokes:
        stroke_table()


if __name__ == "__main__":
    main()
