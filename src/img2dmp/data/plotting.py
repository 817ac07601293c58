"""Pictures of images with pen paths drawn over them (like Fig. 4 of Pahič et al.).

Used by ``img2dmp preview`` and by evaluation pictures: the demonstrated path in blue,
optionally a second path (e.g. the network's DMP) in red. Paths with a pen channel
(``d = 3``) are drawn only where the pen is down.
"""

from __future__ import annotations

import math
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _pen_down_xy(path: np.ndarray) -> np.ndarray:
    # [T, d] -> [T', 2] with NaN rows breaking the line where the pen is up.
    path = np.asarray(path, dtype=np.float64)
    xy = path[:, :2].copy()
    if path.shape[1] >= 3:
        xy[path[:, 2] < 0.5] = np.nan
    return xy


def plot_grid(
    images,
    paths=None,
    second_paths=None,
    *,
    titles=None,
    ncols: int = 10,
    cell_inches: float = 1.2,
    start_marker: bool = True,
):
    """A grid of grey images with paths over them; returns the matplotlib Figure.

    Parameters
    ----------
    images : array [M, H, W]
        Ink = 1 is drawn black on white.
    paths : array [M, T, d], optional
        Pixel coordinates (x = column, y = row), drawn in blue; a dot marks the start.
    second_paths : array [M, T, d], optional
        Drawn in red (e.g. a predicted DMP's rollout).
    titles : sequence of str, optional
        One per image.
    ncols : int
        Images per row (>= 1).
    """
    images = np.asarray(images)
    if images.ndim != 3:
        raise ValueError(f"images must have shape [M, H, W], got {images.shape}")
    m = images.shape[0]
    if m == 0:
        raise ValueError("images is empty: nothing to plot")
    if not isinstance(ncols, int) or ncols < 1:
        raise ValueError(f"ncols must be an integer >= 1, got {ncols!r}")
    for name, p in (("paths", paths), ("second_paths", second_paths)):
        if p is not None and len(p) != m:
            raise ValueError(f"{name} has {len(p)} entries for {m} images")
    if titles is not None and len(titles) != m:
        raise ValueError(f"titles has {len(titles)} entries for {m} images")
    ncols = min(ncols, m)
    nrows = math.ceil(m / ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(cell_inches * ncols, cell_inches * nrows), squeeze=False
    )
    h, w = images.shape[1:]
    for k, ax in enumerate(axes.flat):
        ax.set_axis_off()
        if k >= m:
            continue
        # extent puts pixel [i, j]'s centre at (x=j, y=i), as in docs/CONTRACTS.md.
        ax.imshow(images[k], cmap="gray_r", vmin=0, vmax=1, extent=(-0.5, w - 0.5, h - 0.5, -0.5))
        for p, colour in ((paths, "tab:blue"), (second_paths, "tab:red")):
            if p is None:
                continue
            xy = _pen_down_xy(p[k])
            ax.plot(xy[:, 0], xy[:, 1], color=colour, linewidth=1.0)
            if start_marker and p is paths:
                ax.plot(xy[0, 0], xy[0, 1], "o", color=colour, markersize=2.5)
        ax.set_xlim(-0.5, w - 0.5)
        ax.set_ylim(h - 0.5, -0.5)
        if titles is not None:
            ax.set_title(str(titles[k]), fontsize=7)
    fig.tight_layout(pad=0.2)
    return fig


def save_grid(path: str | os.PathLike, *args, dpi: int = 100, **kwargs) -> None:
    """:func:`plot_grid` written to a PNG file (the figure is closed afterwards)."""
    fig = plot_grid(*args, **kwargs)
    try:
        fig.savefig(path, dpi=dpi)
    finally:
        plt.close(fig)
