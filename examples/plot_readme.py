"""The picture at the top of the README: a photo of a digit, the DMP the shipped model
reads in it, and the simulated arm that has just written it.

Left, the sample photo ``examples/samples/digit_5_photo.jpg`` (made by
``examples/make_samples.py``) with the four predicted movements of the default shipped
model, ranked (the top one bold); right, the camera picture of the simulated KUKA iiwa at
the end of writing the top one (``img2dmp.robot.write_dmp``), the arm and the paper.
Needs the robot extra (pybullet). Run from the repository's root:

    python examples/plot_readme.py                           # docs/images/readme.png
    python examples/plot_readme.py --out out/readme.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import img2dmp  # noqa: E402
from img2dmp._files import save_figure  # noqa: E402
from img2dmp.robot import write_dmp  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "samples" / "digit_5_photo.jpg"
COLOURS = ("#d62728", "#ff7f0e", "#2ca02c", "#9467bd")


def draw_prediction(ax, photo: np.ndarray, pred) -> None:
    ax.imshow(photo)
    for k in reversed(range(pred.n_hypotheses)):  # the top one drawn last, on top
        xy = pred.path_image[k]
        ax.plot(xy[:, 0], xy[:, 1], color=COLOURS[k % 4], lw=3.0 if k == 0 else 1.2,
                label=f"#{k + 1}: p = {pred.probabilities[k]:.2f}")  # fmt: skip
    ax.plot(*pred.path_image[0, 0, :2], "o", color=COLOURS[0], ms=7)  # the pen starts here
    handles, labels = ax.get_legend_handles_labels()
    ax.legend(handles[::-1], labels[::-1], loc="lower right", fontsize=7)  # ranked, #1 first
    ax.set_title("a photo and the DMPs the model reads in it", fontsize=9)
    ax.set_axis_off()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "readme.png")
    args = p.parse_args(argv)
    from PIL import Image

    model = img2dmp.load_model()  # the default shipped model, refined as its card says
    pred = model.predict(SAMPLE)
    result = write_dmp(pred.dmp, pred.dmp_config, pred.frame.model_size)
    photo = np.asarray(Image.open(SAMPLE).convert("RGB"))
    fig, axes = plt.subplots(1, 2, figsize=(8.0, 3.0), width_ratios=(1.0, 1.78))
    draw_prediction(axes[0], photo, pred)
    axes[1].imshow(result.render)
    axes[1].set_title("the simulated KUKA iiwa has written the top one", fontsize=9)
    axes[1].set_axis_off()
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, args.out, dpi=90)  # closes the figure
    print(f"{args.out}: {args.out.stat().st_size / 1e3:.0f} KB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
