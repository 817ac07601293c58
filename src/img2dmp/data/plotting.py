"""Pictures of images with pen paths drawn over them (like Fig. 4 of Pahič et al.).

Used by ``img2dmp preview``, evaluation's ``examples.png`` and prediction's overlays:
the demonstrated path in blue, optionally a second path (e.g. the network's DMP) in red.
Each path has a dot at its start and an arrowhead partway along it that shows the
direction of writing; one legend at the top of the figure names the colours. Paths with
a pen channel (``d = 3``) are drawn only where the pen is down.

- :func:`plot_grid` - the matplotlib Figure
- :func:`save_grid`, :func:`overlay_figure` - the same written to a PNG file, atomically
  (:func:`img2dmp._files.save_figure`)
"""

from __future__ import annotations

import math
import numbers
import os
import re
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from .._files import new_figure, save_figure

DEFAULT_LABELS = ("demonstration", "DMP")
# The first path is drawn under the second; its start dot is larger so that it still
# shows when the second path starts at the same point.
_STYLES = (
    {"colour": "tab:blue", "start_size": 4.0, "arrow_at": 0.4},
    {"colour": "tab:red", "start_size": 2.5, "arrow_at": 0.6},
)
_MARKS = "0.35"  # grey of the "start" and "direction" legend entries
_FONT = 7  # points, titles and legend
#: Most images one grid draws (matplotlib takes ~55 ms a cell: about a minute).
MAX_GRID_CELLS = 1000
#: Largest figure drawn, in pixels (width x height); matplotlib's own limit is 2^16 a side.
MAX_FIGURE_PIXELS = 100_000_000
_MAX_FIGURE_SIDE_PX = (1 << 16) - 1


def check_grid_size(n_images: int, what: str = "images") -> int:
    """``n_images`` if one grid can draw that many, else ``ValueError`` naming ``what``,
    the number and the limit ``MAX_GRID_CELLS``. For callers to check before they make
    the images."""
    if isinstance(n_images, bool) or not isinstance(n_images, numbers.Integral):
        raise ValueError(f"{what} must be a whole number, got {n_images!r}")
    if not 0 <= n_images <= MAX_GRID_CELLS:
        raise ValueError(f"{what} = {n_images}: one grid draws 0 to {MAX_GRID_CELLS} images")
    return int(n_images)


def check_figure_size(width_in: float, height_in: float, dpi: float) -> None:
    """``ValueError`` unless a figure of ``width_in x height_in`` inches at ``dpi`` has
    positive finite sides, at most ``MAX_FIGURE_PIXELS`` pixels and under 2^16 a side."""
    for name, v in (
        ("dpi", dpi),
        ("figure width (in)", width_in),
        ("figure height (in)", height_in),
    ):
        if (
            isinstance(v, bool)
            or not isinstance(v, numbers.Real)
            or not (math.isfinite(v) and v > 0)
        ):
            raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
    w, h = width_in * dpi, height_in * dpi
    if w > _MAX_FIGURE_SIDE_PX or h > _MAX_FIGURE_SIDE_PX or w * h > MAX_FIGURE_PIXELS:
        raise ValueError(
            f"a figure of {w:.0f} x {h:.0f} px ({width_in:.3g} x {height_in:.3g} in at dpi "
            f"{dpi:g}) is too large: at most {MAX_FIGURE_PIXELS // 10**6} megapixels and "
            f"{_MAX_FIGURE_SIDE_PX} px a side; draw fewer or smaller cells, or lower the dpi"
        )


def _pen_down_xy(path: np.ndarray) -> np.ndarray:
    # [T, d] -> [T', 2] with NaN rows breaking the line where the pen is up.
    path = np.asarray(path, dtype=np.float64)
    xy = path[:, :2].copy()
    if path.shape[1] >= 3:
        xy[path[:, 2] < 0.5] = np.nan
    return xy


def _arrow_at(xy: np.ndarray, fraction: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Point at ``fraction`` of the drawn length of ``xy [T, 2]`` and the unit direction of
    the pen there; None for a path that does not move.

    Segments touching a NaN row (pen up) have no length, so the point is always on ink.
    """
    seg = np.diff(xy, axis=0)  # [T-1, 2]
    length = np.nan_to_num(np.linalg.norm(seg, axis=-1))  # [T-1]
    total = length.sum()
    if not total > 0:
        return None
    cum = np.cumsum(length)
    # For 0 < fraction < 1 the first segment to reach the point has length > 0.
    i = min(int(np.searchsorted(cum, fraction * total)), len(cum) - 1)
    u = seg[i] / length[i]
    into = fraction * total - (cum[i] - length[i])
    return xy[i] + np.clip(into, 0.0, length[i]) * u, u


def _draw_path(ax, xy: np.ndarray, style: dict, start_marker: bool, arrow_pt: float) -> None:
    """One path ``[T, 2]`` (NaN = pen up) with its start dot and, for ``arrow_pt > 0``, an
    arrowhead of about that size (points) in the direction of writing."""
    colour = style["colour"]
    ax.plot(xy[:, 0], xy[:, 1], color=colour, linewidth=style.get("linewidth", 1.0))
    finite = np.flatnonzero(np.isfinite(xy).all(axis=1))
    if start_marker and finite.size:
        x0, y0 = xy[finite[0]]
        ax.plot(x0, y0, "o", color=colour, ms=style["start_size"], mec="white", mew=0.4, zorder=3)
    where = _arrow_at(xy, style["arrow_at"]) if arrow_pt > 0 else None
    if where is not None:
        tip, u = where
        # The head's size is in points; the short shaft only sets its orientation. A white
        # rim keeps the head visible on dark ink.
        ax.annotate(
            "",
            xy=tip,
            xytext=tip - 0.5 * u,
            arrowprops={
                "arrowstyle": "-|>,head_length=0.7,head_width=0.35",
                "fc": colour,
                "ec": "white",
                "lw": 0.4,
                "shrinkA": 0,
                "shrinkB": 0,
                "mutation_scale": arrow_pt,
            },
            zorder=3,
        )


def _draw_cell(ax, image: np.ndarray, paths: list, start_marker: bool, arrow_pt: float):
    """One image ``[H, W]`` with its ``(xy [T, 2], style)`` paths over it."""
    h, w = image.shape
    # extent puts pixel [i, j]'s centre at (x=j, y=i), as in docs/CONTRACTS.md.
    ax.imshow(image, cmap="gray_r", vmin=0, vmax=1, extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    for xy, style in paths:
        _draw_path(ax, xy, style, start_marker, arrow_pt)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)


def _legend_handles(drawn: list[tuple[str, dict]], start_marker: bool, arrow: bool) -> list:
    handles = [Line2D([], [], color=s["colour"], linewidth=1.0, label=lab) for lab, s in drawn]
    if start_marker:
        handles.append(Line2D([], [], ls="none", marker="o", ms=3.5, color=_MARKS, label="start"))
    if arrow:
        handles.append(
            Line2D([], [], ls="none", marker=">", ms=4.0, color=_MARKS, label="direction")
        )
    return handles


def _add_legend(fig, handles: list) -> float:
    """A legend centred in a band added on top of the figure, as many entries per row as
    fit in the figure's width; returns the share of the new height below the band."""
    renderer = fig.canvas.get_renderer()
    width = fig.get_window_extent(renderer).width
    for ncol in range(len(handles), 0, -1):
        leg = fig.legend(
            handles=handles,
            loc="upper center",
            bbox_to_anchor=(0.5, 1.0),
            ncol=ncol,
            frameon=False,
            fontsize=_FONT,
            handlelength=1.8,
            columnspacing=1.2,
            borderaxespad=0.2,
        )
        box = leg.get_window_extent(renderer)
        if box.width <= width or ncol == 1:
            band = box.height / fig.dpi + 0.03  # inches; a little air above the titles
            # A band of its own, so that the cells keep their size.
            fig_w, fig_h = fig.get_size_inches()
            fig.set_size_inches(fig_w, fig_h + band)
            return fig_h / (fig_h + band)
        leg.remove()
    raise AssertionError("unreachable: one column is always accepted")


def _check_grid_inputs(images, paths, second_paths, titles, ncols, labels) -> np.ndarray:
    images = np.asarray(images)
    if images.ndim != 3:
        raise ValueError(f"images must have shape [M, H, W], got {images.shape}")
    m = images.shape[0]
    if m == 0:
        raise ValueError("images is empty: nothing to plot")
    check_grid_size(m)
    if not isinstance(ncols, int) or ncols < 1:
        raise ValueError(f"ncols must be an integer >= 1, got {ncols!r}")
    for name, p in (("paths", paths), ("second_paths", second_paths)):
        if p is not None and len(p) != m:
            raise ValueError(f"{name} has {len(p)} entries for {m} images")
    if titles is not None and len(titles) != m:
        raise ValueError(f"titles has {len(titles)} entries for {m} images")
    if isinstance(labels, str) or len(labels) != 2 or not all(isinstance(s, str) for s in labels):
        raise ValueError(f"labels must be two strings (first path, second path), got {labels!r}")
    return images


def plot_grid(
    images,
    paths=None,
    second_paths=None,
    *,
    titles=None,
    ncols: int = 10,
    cell_inches: float = 1.2,
    start_marker: bool = True,
    labels: tuple[str, str] = DEFAULT_LABELS,
    direction_arrow: bool = True,
    legend: bool = True,
    dpi: float | None = None,
):
    """A grid of grey images with paths over them; returns the matplotlib Figure.

    Parameters
    ----------
    images : array [M, H, W]
        Ink = 1 is drawn black on white.
    paths : array [M, T, d], optional
        Pixel coordinates (x = column, y = row), drawn in blue (e.g. the demonstration).
    second_paths : array [M, T', d], optional
        Drawn in red over the first (e.g. a DMP's rollout).
    titles : sequence of str, optional
        One per image.
    ncols : int
        Images per row (>= 1).
    cell_inches : float
        Side of one image.
    start_marker : bool
        A dot at the start of every path (the first path's dot is the larger).
    labels : (str, str)
        Legend names of the blue and the red path, e.g. ``("demonstration",
        "prediction")``.
    direction_arrow : bool
        An arrowhead on every path in the direction of writing, at 40 % of the blue
        path's length and 60 % of the red one's, so that both show where they coincide.
    legend : bool
        One legend for the whole figure, above the grid, naming the drawn paths (and the
        start dot and arrowhead); only drawn if there is a path.
    dpi : float, optional
        Resolution the figure will be saved at (default matplotlib's ``figure.dpi``): the
        figure's size in pixels is checked against ``MAX_FIGURE_PIXELS`` before drawing.

    At most ``MAX_GRID_CELLS`` images; ``ValueError`` otherwise.
    """
    images = _check_grid_inputs(images, paths, second_paths, titles, ncols, labels)
    m = images.shape[0]
    ncols = min(ncols, m)
    nrows = math.ceil(m / ncols)
    dpi = matplotlib.rcParams["figure.dpi"] if dpi is None else dpi
    # The legend band and titles add well under an inch.
    check_figure_size(cell_inches * ncols, cell_inches * nrows + 1.0, dpi)
    fig = new_figure(figsize=(cell_inches * ncols, cell_inches * nrows))
    axes = fig.subplots(nrows, ncols, squeeze=False)
    given = zip((paths, second_paths), labels, _STYLES, strict=True)
    sets = [(p, lab, style) for p, lab, style in given if p is not None]
    # Heads that stay visible in small cells without hiding a digit's strokes in large ones.
    arrow_pt = 4.5 + 1.5 * cell_inches if direction_arrow else 0.0
    for k, ax in enumerate(axes.flat):
        ax.set_axis_off()
        if k < m:
            cell_paths = [(_pen_down_xy(p[k]), style) for p, _, style in sets]
            _draw_cell(ax, images[k], cell_paths, start_marker, arrow_pt)
            if titles is not None:
                ax.set_title(wrap_title(str(titles[k]), cell_inches), fontsize=_FONT)
    top = 1.0
    if legend and sets:
        drawn = [(lab, style) for _, lab, style in sets]
        top = _add_legend(fig, _legend_handles(drawn, start_marker, direction_arrow))
    # tight_layout leaves figure legends alone, hence the explicit band. One pass leaves
    # the cell titles a few pixels too high (into the band, or cut at a one-row grid's
    # top edge); the second pass starts from the laid-out titles and fits them.
    for _ in range(2):
        fig.tight_layout(pad=0.2, rect=(0.0, 0.0, 1.0, top))
    return fig


def wrap_title(text: str, cell_inches: float, font_pt: float = _FONT) -> str:
    """``text`` broken into lines that fit a cell ``cell_inches`` wide at ``font_pt``
    points, after a space, a ``/`` or a ``_`` where it can (a class name such as
    ``Japanese_(hiragana)/character01`` stays readable), within a word where it must."""
    width = max(8, int(cell_inches * 72 / (0.62 * font_pt)))  # characters of a line
    lines, line = [], ""
    for token in re.findall(r"[^ /_]+[ /_]*|[ /_]+", text):
        if line and len(line) + len(token.rstrip()) > width:
            lines.append(line)
            line = ""
        line += token
        while len(line.rstrip()) > width:  # a word longer than a line
            lines.append(line[:width])
            line = line[width:]
    lines.append(line)
    return "\n".join(ln.rstrip() for ln in lines if ln.strip())


def save_grid(path: str | os.PathLike, *args, dpi: int = 100, **kwargs) -> Path:
    """:func:`plot_grid` written to a PNG file atomically (the figure is closed afterwards).

    The file is PNG whatever the suffix of ``path``.
    """
    return save_figure(plot_grid(*args, dpi=dpi, **kwargs), path, dpi=dpi)


def overlay_figure(
    path: str | os.PathLike,
    images: np.ndarray,  # [K, H, W]
    demo_paths: np.ndarray | None,  # [K, T, d] or None
    dmp_paths: np.ndarray | None,  # [K, T', d] or None
    titles: list[str] | None = None,
    ncols: int = 4,
    cell_inches: float = 1.8,
    *,
    labels: tuple[str, str] = DEFAULT_LABELS,
    dpi: int = 100,
) -> Path:
    """Fig.-4-style grid: each image with the demonstrated path (blue) and the DMP path
    (red) drawn over it (:func:`plot_grid`), written to a PNG file atomically.

    ``labels`` names the two paths in the legend, e.g. ``("demonstration",
    "prediction")``. Returns ``path``.
    """
    fig = plot_grid(
        images,
        demo_paths,
        dmp_paths,
        titles=titles,
        ncols=ncols,
        cell_inches=cell_inches,
        labels=labels,
        dpi=dpi,
    )
    return save_figure(fig, path, dpi=dpi)


__all__ = [
    "DEFAULT_LABELS",
    "MAX_FIGURE_PIXELS",
    "MAX_GRID_CELLS",
    "check_figure_size",
    "check_grid_size",
    "overlay_figure",
    "plot_grid",
    "save_grid",
]


#: Colours of ranked hypotheses (rank 1 first); more hypotheses cycle through them.
_HYPOTHESIS_COLOURS = ("tab:red", "tab:orange", "tab:green", "tab:purple", "tab:brown")


def hypotheses_figure(
    path: str | os.PathLike,
    image: np.ndarray,  # [H, W]
    paths: np.ndarray,  # [K, T, d], ranked: the top hypothesis first
    probs: np.ndarray,  # [K]
    title: str = "",
    cell_inches: float = 3.0,
    dpi: int = 100,
) -> Path:
    """One image with its K ranked predicted paths: the top one bold, the others thin, each
    with its start dot and direction arrow; the legend gives each rank's probability."""
    check_figure_size(cell_inches, cell_inches + 1.0, dpi)
    paths = np.asarray(paths)
    if paths.ndim != 3 or len(probs) != len(paths) or not 1 <= len(paths) <= MAX_GRID_CELLS:
        raise ValueError(
            f"paths must be [K, T, d] with 1 <= K <= {MAX_GRID_CELLS} and one probability "
            f"each, got shape {paths.shape} and {len(probs)} probabilities"
        )
    fig = new_figure(figsize=(cell_inches, cell_inches))
    ax = fig.subplots()
    ax.set_axis_off()
    _draw_cell(ax, np.asarray(image), [], True, 0.0)  # the image, framed as every cell
    arrow_pt = 4.5 + 1.5 * cell_inches
    handles = []
    for k in range(len(paths) - 1, -1, -1):  # the top hypothesis drawn last, on top
        colour = _HYPOTHESIS_COLOURS[k % len(_HYPOTHESIS_COLOURS)]
        width = 2.2 if k == 0 else 0.9
        style = {"colour": colour, "start_size": 4.0 if k == 0 else 2.5, "arrow_at": 0.5,
                 "linewidth": width}  # fmt: skip
        _draw_path(ax, _pen_down_xy(paths[k]), style, True, arrow_pt if k == 0 else 0.7 * arrow_pt)
        label = f"#{k + 1}: p = {float(probs[k]):.2f}" + (" (written)" if k == 0 else "")
        handles.insert(0, Line2D([], [], color=colour, linewidth=width, label=label))
    if title:
        ax.set_title(title, fontsize=_FONT + 1)
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.02), ncol=2,
              frameon=False, fontsize=_FONT)  # fmt: skip
    return save_figure(fig, path, dpi=dpi)


def _shown(a: np.ndarray) -> np.ndarray:
    """Channel planes ``[C, H, W]`` or levels ``[H, W(, 3)]`` as an image matplotlib shows."""
    a = np.asarray(a, dtype=np.float32)
    if a.ndim == 3 and a.shape[0] in (1, 3) and a.shape[2] not in (1, 3):
        a = np.moveaxis(a, 0, 2)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    return np.clip(a, 0.0, 1.0)


def _glare_note(found) -> str:
    """The darkness panel's note of a glare's contrast given back, if any."""
    gain = found.glare_gain
    return f"\n(a glare's contrast given back, up to {gain:.1f}x)" if gain > 1.0 else ""


def _shake_note(steps) -> str:
    """The image panel's note of a shake undone first, if any (its pixels as read)."""
    moved = steps.get("shake")
    if moved is None:
        return ""
    return f"\n(a shake of {moved.length:.1f} px at {moved.degrees:.0f} degrees undone)"


def paper_steps_figure(path: str | os.PathLike, found, boxes=None, title: str = "") -> Path:
    """The steps of :func:`img2dmp.data.paper.paper_ink` (kept with ``keep_steps``) as one
    PNG: the image, the paper's estimated colour, the ink's darkness against it, what
    was removed (rules red, off the sheet grey) over the kept strokes, and the ink the
    model reads, with the characters' boxes ``[[x0, y0, x1, y1], ...]`` when given."""
    s = found.steps
    dark, ink = s["darkness"], s["ink"]
    removed = np.ones((*dark.shape, 3), np.float32)
    removed[~s["sheet"]] = 0.8
    removed[s["candidates"] & ~found.mask] = (0.95, 0.6, 0.1)
    removed[found.mask] = 0.0
    removed[s["rules"]] = (0.85, 0.1, 0.1)
    shape = dark.shape
    bg = np.broadcast_to(s["background"], (len(s["background"]), *shape))
    panels = [("image" + _shake_note(s), _shown(s["input"])),
              ("paper (background estimate)", _shown(bg)),
              ("darkness against the paper" + _glare_note(found), 1.0 - dark),
              ("removed: rules red, faint marks, specks, edges orange, off the sheet grey",
               removed),
              (f"ink the model reads (pen {found.pen_width_px:.1f} px)", 1.0 - ink)]  # fmt: skip
    aspect = shape[0] / shape[1]
    fig = new_figure(figsize=(12, 8 * aspect + 0.8))
    axes = fig.subplots(2, 3, squeeze=False)
    for ax, (name, img) in zip(axes.ravel(), panels, strict=False):
        ax.imshow(img, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        ax.set_title(name, fontsize=_FONT + 1)
    for x0, y0, x1, y1 in boxes if boxes is not None else []:
        axes[1, 1].add_patch(Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0,
                                       fill=False, ec="tab:blue", lw=0.6))  # fmt: skip
    counts = "\n".join(f"{k}: {v}" for k, v in found.removed.items())
    axes[1, 2].text(0.02, 0.98, "removed\n" + counts, va="top", fontsize=_FONT + 1,
                    family="monospace", transform=axes[1, 2].transAxes)  # fmt: skip
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title, fontsize=_FONT + 2)
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)
