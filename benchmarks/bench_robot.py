"""Simulation speed of the writing robot: a 3 s digit "2" written by the simulated iiwa.

For each control rate it prints

- the speed of the control loop as a multiple of real time (simulated seconds of
  approach + writing + lift per wall-clock second, one physics step per control step),
- the wall time of the whole call (scene set-up, planning and the reachability check
  along the path, simulation; no pictures), and the digit's 3 s over that,
- where a control step's time goes (IK on the twin, inverse dynamics, physics step,
  the rest: state reads, contact query, DMP step, logging),
- the accuracy reached, so that speed is compared at equal quality.

Run: ``.venv/bin/python benchmarks/bench_robot.py [--rates 240 1000] [--repeats 3]``
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import defaultdict

import numpy as np

from img2dmp.dmp import DMPConfig, DMPIntegrator, fit_dmp
from img2dmp.robot import WritingScene, write_dmp, writing

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


def _timed(owner, name: str, totals: dict):
    """Replace ``owner.name`` by a wrapper adding its wall time to ``totals["Owner.name"]``."""
    original = getattr(owner, name)
    key = f"{owner.__name__.rsplit('.', 1)[-1]}.{name}"

    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            totals[key] += time.perf_counter() - t0

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
    """One timed call of write_dmp; returns (metrics, call_s, shares of the loop [%])."""
    totals: dict = defaultdict(float)
    originals = [(owner, name, _timed(owner, name, totals)) for owner, name, _ in PARTS]
    # plan_path (DMP steps) and check_path (IK) run before the loop: timed separately.
    pre = [(writing, n, _timed(writing, n, totals)) for n in ("plan_path", "check_path")]
    try:
        t0 = time.perf_counter()
        result = write_dmp(params, config, (28, 28), control_rate_hz=rate_hz, render_size_px=None)
        call_s = time.perf_counter() - t0
    finally:
        for owner, name, f in originals + pre:
            setattr(owner, name, f)
    m = result.metrics
    shares = []
    for owner, name, _ in PARTS:
        key = f"{owner.__name__}.{name}"
        spent = totals[key]  # the loop's share only:
        if key == "DMPIntegrator.step":
            spent -= totals["writing.plan_path"]  # which is made of DMP steps
        if key == "WritingScene.solve_ik":
            spent -= totals["writing.check_path"]  # which is made of IK solves
        shares.append(100.0 * spent / m["wall_s"])
    return m, call_s, shares


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", type=float, nargs="+", default=[240.0, 1000.0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()

    config = DMPConfig(scaling="none")
    params = fit_dmp(np.linspace(0, DURATION_S, 300), digit_two(), config).params
    print(f'digit "2", tau = {float(params.tau):.1f} s, 28 x 28 px image written 40 mm tall')
    titles = [t for _, _, t in PARTS]
    print(
        f"{'rate Hz':>8} {'loop x real':>12} {'call s':>7} {'digit/call':>11} "
        + " ".join(f"{t:>9}" for t in titles)
        + f" {'err mean mm':>12} {'err max mm':>11} {'F mean N':>9} {'F std N':>8}"
    )
    for rate in args.rates:
        runs = [run_once(params, config, rate) for _ in range(args.repeats)]
        loop = statistics.median(r[0]["real_time_factor"] for r in runs)
        call = statistics.median(r[1] for r in runs)
        shares = np.median(np.array([r[2] for r in runs]), axis=0)
        m = runs[-1][0]
        print(
            f"{rate:8.0f} {loop:11.1f}x {call:7.2f} {DURATION_S / call:10.1f}x "
            + " ".join(f"{s:9.0f}" for s in shares)
            + f" {m['tracking_error_mean_mm']:12.3f} {m['tracking_error_max_mm']:11.3f}"
            f" {m['force_mean_n']:9.3f} {m['force_std_n']:8.4f}"
        )
    print(
        f"(medians of {args.repeats} runs; loop = simulated approach + writing + lift per "
        "wall second; call = set-up, plan, reachability check and loop; shares are of the "
        "loop's wall time; headless pybullet p.DIRECT)"
    )


if __name__ == "__main__":
    main()
