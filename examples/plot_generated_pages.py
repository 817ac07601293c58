"""Generated photos of handwritten pages, one per kind of paper, with their true boxes and paths.

Each page is written by ``generate_page`` with characters whose pen paths are known
(synthetic digits, or with ``--recorded`` the recorded human paths over MNIST digits) on
plain, ruled, squared and dotted paper; the boxes of each character's ink and its
pen-down path are drawn over the photo, coloured by line.

Run: ``.venv/bin/python examples/plot_generated_pages.py --out out/generated_pages.png``
(add ``--recorded ../shared/data/ijs-mnist-trajectories/trajectories.tar.gz``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Rectangle

from img2dmp.data.clutter import (
    KINDS,
    generate_page,
    page_sources_from_recorded,
    page_sources_from_synthetic,
)


def sources(rng: np.random.Generator, n: int, recorded: Path | None):
    if recorded is None:
        return page_sources_from_synthetic(rng, n)
    from img2dmp.data.recorded import load_recorded

    paths = load_recorded(recorded)
    return page_sources_from_recorded([paths[i] for i in rng.choice(len(paths), n)])


def draw_page(ax, page) -> None:
    ax.imshow(page.image)
    colours = plt.cm.tab10(np.arange(10))
    for box, path, line in zip(page.boxes, page.paths, page.lines, strict=True):
        c = colours[line % 10]
        x0, y0, x1, y1 = box
        # Box edges sit on pixel borders: half a pixel outside the pixel centres.
        ax.add_patch(Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, fill=False, ec=c, lw=0.7))
        xy = np.where(path[:, 2:] > 0.5, path[:, :2], np.nan)  # pen-up points break the line
        ax.plot(xy[:, 0], xy[:, 1], "-", color=c, lw=0.5, alpha=0.8)
    m = page.meta
    extras = [k for k in ("bleed", "margin") if m["paper"][k]]
    extras += [f"shadow: {m['paper']['shadow']}"] if m["paper"]["shadow"] else []
    extras += [f"edge: {'+'.join(m['paper']['edge'])}"] if m["paper"]["edge"] else []
    ax.set_title(
        f"{page.kind}, {m['paper']['tint']}: {len(page.labels)} characters of "
        f"{m['char_height_px']:.0f} px, pen {page.pen_width_px:.1f} px"
        + ("\n" + ", ".join(extras) if extras else "\n "),
        fontsize=8,
    )
    ax.set_axis_off()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("generated_pages.png"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--characters", type=int, default=24, help="per page")
    ap.add_argument("--recorded", type=Path, default=None, help="trajectories.tar.gz")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    for ax, kind in zip(axes.ravel(), KINDS, strict=True):
        chars = sources(rng, args.characters, args.recorded)
        draw_page(ax, generate_page(rng, chars, kind=kind, size_hw=(900, 1200)))
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=130)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
