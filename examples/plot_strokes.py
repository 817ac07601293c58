"""Read a character of several strokes from an image, one DMP per stroke.

The shipped stroke model ``omniglot-strokes`` reads ``examples/samples/character_f.png``
(an "F" drawn by ``make_samples.py``: the bar down, the top bar, the middle bar) as its
strokes in writing order, each its own 2-D DMP, and the figure shows them over the image: each
stroke in its own colour, numbered where it starts, an arrow where it ends, the pen-up
travel between strokes dashed. The figure of docs/TRAINING.md ("Stroke models") is made by

    python examples/plot_strokes.py --out docs/images/strokes.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

import img2dmp  # noqa: E402

HERE = Path(__file__).resolve().parent
SAMPLE = HERE / "samples" / "character_f.png"
COLOURS = ("tab:red", "tab:blue", "tab:green", "tab:orange", "tab:purple", "tab:brown")


def draw_strokes(ax, pred) -> None:
    """The prediction's strokes over its image (image pixels), in writing order."""
    xy, pen = pred.path_image[0][:, :2], pred.path_image[0][:, 2]
    for j in range(pred.n_strokes):
        rows = pred.stroke_rows(j)
        s = xy[rows]
        colour = COLOURS[j % len(COLOURS)]
        ax.plot(s[:, 0], s[:, 1], color=colour, lw=2.4)
        ax.annotate("", xy=s[-1], xytext=s[-4], arrowprops=dict(arrowstyle="-|>", color=colour))
        back = s[0] - s[min(3, len(s) - 1)]  # the number stands behind the stroke's start
        back = 14 * back / max(float(np.linalg.norm(back)), 1e-9)
        ax.annotate(f"{j + 1}", xy=s[0], xytext=back * [1, -1], textcoords="offset points",
                    color=colour, fontsize=13, weight="bold", ha="center", va="center")  # fmt: skip
    up = pen < 0.5
    travel = np.where(up[:, None], xy, np.nan)
    ax.plot(travel[:, 0], travel[:, 1], color="0.35", lw=1.2, ls=(0, (3, 3)), label="pen up")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--image", type=Path, default=SAMPLE)
    ap.add_argument("--out", type=Path, default=Path("out/strokes.png"))
    args = ap.parse_args(argv)
    model = img2dmp.load_model("omniglot-strokes")  # refined 60 steps, as its card says
    pred = model.predict(args.image)
    fig, ax = plt.subplots(figsize=(4.2, 4.4))
    ax.imshow(np.asarray(Image.open(args.image).convert("L")), cmap="gray", vmin=0, vmax=255)
    draw_strokes(ax, pred)
    taus = ", ".join(f"{t:.2f}" for t in np.asarray(pred.strokes.tau))
    ax.set_title(f"{pred.n_strokes} strokes read, each its own DMP\n(tau {taus} s)", fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_axis_off()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110, bbox_inches="tight")
    plt.close(fig)
    print(f"{args.out}: {pred.n_strokes} strokes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
