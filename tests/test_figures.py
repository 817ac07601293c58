"""Figures of images with paths (data.plotting): legend, start and direction marks, titles
that fit, and the one atomic figure writer."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.text import Annotation
from PIL import Image

import img2dmp._files as files
from img2dmp.data import plotting
from img2dmp.data.plotting import overlay_figure, plot_grid, save_grid
from img2dmp.data.synthetic import generate_dataset

SRC = Path(__file__).resolve().parents[1] / "src" / "img2dmp"


@pytest.fixture(scope="module")
def digits():
    data = generate_dataset(1, seed=3, progress=False)  # 10 digits, 40 x 40
    dmp = data.trajectories.copy()
    dmp[..., :2] += 0.8  # a second path that differs visibly
    return data, dmp


def _legend_texts(fig) -> list[str]:
    assert len(fig.legends) == 1, "one legend per figure"
    return [t.get_text() for t in fig.legends[0].get_texts()]


def _marks(ax) -> tuple[list, list]:
    starts = [ln for ln in ax.get_lines() if ln.get_marker() == "o"]
    arrows = [t for t in ax.texts if isinstance(t, Annotation)]
    return starts, arrows


def test_legend_names_the_paths_once_per_figure(digits):
    data, dmp = digits
    fig = plot_grid(data.images[:6], data.trajectories[:6], dmp[:6], ncols=3)
    assert _legend_texts(fig) == ["demonstration", "DMP", "start", "direction"]
    colours = [h.get_color() for h in fig.legends[0].legend_handles[:2]]
    assert colours == ["tab:blue", "tab:red"]
    assert all(ax.get_legend() is None for ax in fig.axes)  # not per cell
    plt.close(fig)
    fig = plot_grid(data.images[:2], None, dmp[:2], labels=("demonstration", "prediction"))
    assert _legend_texts(fig) == ["prediction", "start", "direction"]
    plt.close(fig)
    fig = plot_grid(data.images[:2], data.trajectories[:2], start_marker=False)
    assert _legend_texts(fig) == ["demonstration", "direction"]
    plt.close(fig)
    fig = plot_grid(data.images[:2])  # no path, nothing to name
    assert fig.legends == []
    plt.close(fig)
    with pytest.raises(ValueError, match="labels must be two strings"):
        plot_grid(data.images[:2], data.trajectories[:2], labels="DMP")


def test_both_paths_have_a_start_dot_and_a_direction_arrow(digits):
    data, dmp = digits
    fig = plot_grid(data.images[:4], data.trajectories[:4], dmp[:4], ncols=2)
    for k, ax in enumerate(fig.axes):
        starts, arrows = _marks(ax)
        assert [s.get_color() for s in starts] == ["tab:blue", "tab:red"]
        # each dot sits on its path's first point
        np.testing.assert_allclose(starts[0].get_xydata()[0], data.trajectories[k, 0, :2])
        np.testing.assert_allclose(starts[1].get_xydata()[0], dmp[k, 0, :2])
        assert len(arrows) == 2
        for arrow, path in zip(arrows, (data.trajectories[k], dmp[k]), strict=True):
            tip, tail = np.asarray(arrow.xy), np.asarray(arrow.xyann)
            # on the path, pointing the way it is written
            assert np.linalg.norm(path[:, :2] - tip, axis=1).min() < 0.6
            i = np.linalg.norm(path[:, :2] - tip, axis=1).argmin()
            ahead = path[min(i + 3, len(path) - 1), :2] - path[max(i - 3, 0), :2]
            assert np.dot(tip - tail, ahead) > 0
    plt.close(fig)
    fig = plot_grid(data.images[:1], data.trajectories[:1], start_marker=False, legend=False)
    assert _marks(fig.axes[0])[0] == [] and fig.legends == []
    plt.close(fig)


def test_arrow_stays_on_ink_when_the_pen_lifts():
    # Pen down along x = 5, pen up to x = 30, down again: the long invisible jump must not
    # carry the arrow, though it is most of the distance travelled.
    s = np.linspace(0, 1, 20)[:, None]
    down1 = np.hstack([5 + 0 * s, 5 + 10 * s, np.ones_like(s)])
    up = np.hstack([5 + 25 * s, 15 - 10 * s, np.zeros_like(s)])
    down2 = np.hstack([30 + 0 * s, 5 + 10 * s, np.ones_like(s)])
    xy = plotting._pen_down_xy(np.vstack([down1, up, down2]))
    for fraction in (0.2, 0.4, 0.6, 0.9):
        tip, u = plotting._arrow_at(xy, fraction)
        assert tip[0] in (5.0, 30.0) and np.allclose(u, [0.0, 1.0])
    assert plotting._arrow_at(np.full((5, 2), 3.0), 0.4) is None  # a dot has no direction


@pytest.mark.parametrize("m, ncols", [(1, 10), (4, 10), (7, 3)])
def test_titles_fit_in_the_figure_below_the_legend(digits, m, ncols):
    data, dmp = digits
    titles = [f"{int(d)}: {0.123 * k:.3f} px" for k, d in enumerate(data.labels[:m])]
    fig = plot_grid(data.images[:m], data.trajectories[:m], dmp[:m], titles=titles, ncols=ncols)
    fig.canvas.draw()
    box = fig.bbox
    legend = fig.legends[0].get_window_extent()
    assert legend.y1 <= box.y1 + 0.5 and legend.x0 >= -0.5 and legend.x1 <= box.x1 + 0.5
    for ax in fig.axes[:m]:
        t = ax.title.get_window_extent()
        assert ax.title.get_text() in titles
        assert t.y1 <= legend.y0 + 0.5, "title runs into the legend"
        assert t.x0 >= -0.5 and t.x1 <= box.x1 + 0.5 and t.y0 >= 0
    plt.close(fig)


@pytest.mark.parametrize("cell_inches", [1.2, 1.8])
def test_long_class_names_in_titles_are_wrapped_not_run_into_each_other(digits, cell_inches):
    data, dmp = digits
    names = ["Japanese_(hiragana)/character01", "Alphabet_of_the_Magi/character12"]
    titles = [f"{names[k % 2]}: path {0.5 + k:.2f} px" for k in range(4)]
    fig = plot_grid(data.images[:4], data.trajectories[:4], dmp[:4], titles=titles, ncols=4,
                    cell_inches=cell_inches)  # fmt: skip
    fig.canvas.draw()
    boxes = [ax.title.get_window_extent() for ax in fig.axes[:4]]
    for left, right in zip(boxes, boxes[1:], strict=False):
        assert left.x1 <= right.x0 + 0.5, "two cells' titles overlap"
    for ax, title in zip(fig.axes[:4], titles, strict=True):
        shown = ax.title.get_text()
        assert "\n" in shown and shown.replace("\n", "").replace(" ", "") == title.replace(" ", "")
    plt.close(fig)
    assert plotting.wrap_title("3: 0.123 px", 1.2) == "3: 0.123 px"  # short: as it is
    long = plotting.wrap_title("x" * 70, 1.2)  # a word longer than a line is cut
    assert long.replace("\n", "") == "x" * 70 and len(long.splitlines()) > 2


def test_save_grid_writes_atomically_through_the_one_figure_writer(digits, tmp_path, monkeypatch):
    data, dmp = digits
    written = []
    real = files.atomic_write_bytes

    def spy(path, blob):
        written.append((Path(path), blob[:8]))
        real(path, blob)

    monkeypatch.setattr(files, "atomic_write_bytes", spy)
    before = set(plt.get_fignums())
    out = save_grid(tmp_path / "g.png", data.images[:3], data.trajectories[:3], dmp[:3], dpi=50)
    assert written == [(tmp_path / "g.png", b"\x89PNG\r\n\x1a\n")] and out == tmp_path / "g.png"
    assert set(plt.get_fignums()) == before  # the figure was closed
    with Image.open(out) as im:
        assert im.format == "PNG" and im.size[0] > 100
    assert [p.name for p in tmp_path.iterdir()] == ["g.png"]  # no temporary file left
    # A figure that fails to render leaves neither a file nor an open figure behind.
    monkeypatch.setattr(Figure, "savefig", lambda *a, **k: (_ for _ in ()).throw(OSError("x")))
    with pytest.raises(OSError):
        save_grid(tmp_path / "bad.png", data.images[:1], data.trajectories[:1])
    assert not (tmp_path / "bad.png").exists() and set(plt.get_fignums()) == before


def test_overlay_figure_keeps_its_arguments_and_names_the_prediction(digits, tmp_path):
    data, dmp = digits
    p = overlay_figure(tmp_path / "o.png", data.images[:1], None, dmp[:1], ["mine"], 4, 3.0)
    with Image.open(p) as im:
        assert im.size[0] >= 280  # 3-inch cell at 100 dpi
    from img2dmp.evaluate import overlay_figure as old_home

    old_home(tmp_path / "e.png", data.images[:5], data.trajectories[:5], dmp[:5])
    assert (tmp_path / "e.png").stat().st_size > 0


def test_no_other_figure_writer_in_plotting_evaluate_predict():
    for rel in ("data/plotting.py", "evaluate.py", "predict.py"):
        assert ".savefig(" not in (SRC / rel).read_text(), rel


def test_drawing_leaves_the_callers_backend_and_pyplot_figures_alone(tmp_path):
    """A notebook user's backend survives every figure the package draws (a training
    curve, a grid, a paper's steps); no module switches it or draws through pyplot."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(
        f"""
        import matplotlib
        matplotlib.use("svg")  # any backend but Agg stands for the caller's own
        import matplotlib.pyplot as plt
        import numpy as np
        mine = plt.figure()
        from img2dmp.data import plotting
        from img2dmp.training.records import plot_training_curve
        import img2dmp.robot.outputs
        out = {str(tmp_path)!r}
        rows = [{{"epoch": e, "train_error_px": 1.0 / e, "val_error_px": 2.0 / e}}
                for e in (1, 2, 3)]
        plot_training_curve(out + "/curve.png", rows)
        plotting.save_grid(out + "/grid.png", np.zeros((2, 8, 8)))
        fig = plotting.plot_grid(np.zeros((2, 8, 8)))
        print(matplotlib.get_backend(), plt.get_fignums() == [mine.number], type(fig).__name__)
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["svg", "True", "Figure"], done.stdout
    assert (tmp_path / "curve.png").stat().st_size and (tmp_path / "grid.png").stat().st_size
    for path in SRC.rglob("*.py"):  # the modules this script did not draw with, too
        text = path.read_text()
        for habit in ("matplotlib.use(", "import matplotlib.pyplot", "import pyplot", "plt."):
            assert habit not in text, f"{path}: {habit}"
