"""Bend one DMP five ways: a new goal, a new start, scaled, rotated, another tempo.

A "2" (pixels of a 28 x 28 image, rows growing downward) is fitted twice, without
forcing-term scaling (``scaling="none"``, the recommended real-handwriting model's) and
with the paper's ``diag(g - y0)`` (``"goal-start"``), and bent with
:func:`img2dmp.dmp.bend_dmp`. Scale, rotation and tempo are exact in both (the bent path
is the transformed path); a new goal or start changes the shape, differently in each
(docs/DMP.md, "Bending a DMP"). The figure of docs/DMP.md is made by

    python examples/plot_bending.py --out docs/images/bending.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from img2dmp.dmp import DMPConfig, bend_dmp, fit_dmp, rollout  # noqa: E402

ORIGINAL = dict(color="0.6", lw=2.2, label="the movement")
NONE = dict(color="tab:red", lw=1.6)
GOAL_START = dict(color="tab:blue", lw=1.6, ls="--")


def two(t: np.ndarray) -> np.ndarray:
    """A "2": an arc over the top, a diagonal to the bottom left, a base line ``[T, 2]``."""
    u = t / t[-1]
    u = 10 * u**3 - 15 * u**4 + 6 * u**5  # minimum-jerk progress along the path
    a = np.linspace(np.radians(160), np.radians(-40), 120)
    arc = np.stack([14 + 6 * np.cos(a), 11 - 6 * np.sin(a)], -1)
    corner, end = np.array([8.0, 22.0]), np.array([21.0, 22.0])
    pts = np.concatenate([arc, arc[-1] + (corner - arc[-1]) * np.linspace(0, 1, 60)[1:, None],
                          corner + (end - corner) * np.linspace(0, 1, 50)[1:, None]])  # fmt: skip
    s = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return np.stack([np.interp(u * s[-1], s, pts[:, k]) for k in range(2)], -1)


def path(params, config, t) -> np.ndarray:
    return rollout(params.to_torch(), torch.as_tensor(t), config).numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/bending.png"))
    args = ap.parse_args()
    t = np.linspace(0.0, 2.0, 300)
    fits = {}
    for scaling in ("none", "goal-start"):
        config = DMPConfig(scaling=scaling)
        fits[scaling] = (fit_dmp(t, two(t), config).params, config)
    p, cfg = fits["none"]
    y = path(p, cfg, t)
    goal, start = np.array([26.0, 14.0]), np.array([4.0, 4.0])
    panels = [
        ("a new goal (26, 14): the weights kept", dict(goal=goal), True),
        ("a new start (4, 4): the weights kept", dict(start=start), True),
        ("scale 0.6 about the start: exact", dict(scale=0.6), False),
        ("rotated 35\u00b0 about the start: exact", dict(rotate_deg=35.0), False),
    ]
    fig, axes = plt.subplots(2, 3, figsize=(11, 7.6), layout="constrained")
    ax = axes[0, 0]
    ax.plot(y[:, 0], y[:, 1], **ORIGINAL)
    ax.set_title("the movement: a fitted \u201c2\u201d (2 s)", fontsize=10)
    for ax, (title, change, both) in zip(axes.flat[1:5], panels, strict=True):
        ax.plot(y[:, 0], y[:, 1], **ORIGINAL)
        for scaling, style in (("none", NONE), ("goal-start", GOAL_START)):
            q, c = fits[scaling]
            bent = path(bend_dmp(q, c, **change), c, t)
            label = f"scaling {scaling}" if both else "bent (both scalings)"
            ax.plot(bent[:, 0], bent[:, 1], label=label, **style)
            if not both:
                break
        for k, v in change.items():
            if k in ("goal", "start"):
                ax.plot(*v, "x" if k == "goal" else "o", color="k", ms=7, mfc="none")
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=7.5, loc="lower left")
    for ax in axes.flat[:5]:
        ax.plot(*y[0], "o", color="tab:green", ms=5)
        ax.set_xlim(0, 28)
        ax.set_ylim(28, 0)  # rows grow downward, as in the image
        ax.set_aspect("equal")
        ax.set_xlabel("x (px)", fontsize=8)
        ax.set_ylabel("y (px)", fontsize=8)
        ax.tick_params(labelsize=7)
    ax = axes[1, 2]  # tempo: the same path in another time
    for k, style in ((1.0, ORIGINAL), (2.0, NONE), (0.5, dict(color="tab:purple", lw=1.6))):
        tk = t / k
        yk = path(bend_dmp(p, cfg, tempo=k), cfg, tk)
        label = "the movement" if k == 1 else f"tempo {k:g}: tau / {k:g}"
        ax.plot(tk, yk[:, 1], **{**style, "label": label})
    ax.set_title("tempo k: y(t) = y_orig(k t), exact", fontsize=10)
    ax.set_xlabel("t (s)", fontsize=8)
    ax.set_ylabel("y (px)", fontsize=8)
    ax.invert_yaxis()
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7.5)
    fig.suptitle("Bending one DMP (img2dmp.dmp.bend_dmp); green dot: the start", fontsize=11)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=90)
    print(f"wrote {args.out} ({args.out.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main()
