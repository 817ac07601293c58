"""Fit a DMP to a pen path sampled at uneven time stamps and roll it out again.

A figure-eight is sampled with gaps (as recorded pen paths are), fitted with
``fit_dmp`` (least squares on positions), and integrated with the step-by-step
reference integrator at 240 Hz, as a robot controller would.

Run: ``.venv/bin/python examples/plot_fit.py --out out/fit.png``
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from img2dmp.dmp import DMPConfig, DMPIntegrator, fit_dmp


def figure_eight(t: np.ndarray, duration_s: float) -> np.ndarray:
    u = t / duration_s
    a = 2 * np.pi * 0.97 * (10 * u**3 - 15 * u**4 + 6 * u**5)  # minimum-jerk progress
    return np.stack([20 + 10 * np.sin(2 * a), 22 - 18 * np.cos(a)], -1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/fit.png"))
    ap.add_argument("--scaling", default="none", choices=["goal-start", "none"])
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    duration_s = 2.0
    t = np.sort(np.concatenate([[0, duration_s], rng.uniform(0, duration_s, 120)]))
    y = figure_eight(t, duration_s)
    cfg = DMPConfig(scaling=args.scaling)
    fit = fit_dmp(t, y, cfg)
    dmp = DMPIntegrator(fit.params, cfg)
    rate_hz = 240
    robot = np.array([dmp.step(1 / rate_hz) for _ in range(int(1.2 * duration_s * rate_hz))])
    fig, ax = plt.subplots(figsize=(5, 5))
    ax.plot(y[:, 0], y[:, 1], "o", ms=3, color="tab:blue", label="demonstration (uneven)")
    ax.plot(robot[:, 0], robot[:, 1], "-", color="tab:red", label="DMP, 240 Hz integrator")
    ax.set_title(f"fit error {float(fit.error_px):.3f} px (mean), scaling={args.scaling}")
    ax.invert_yaxis()
    ax.set_aspect("equal")
    ax.legend(loc="center", fontsize=8, framealpha=0.9)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"mean fit error {float(fit.error_px):.4f} px; wrote {args.out}")


if __name__ == "__main__":
    main()
