"""Files written after a writing run: CSV log, the paper next to the commanded path and
the input image, camera renders and the video (animated GIF; MP4 with imageio-ffmpeg,
:mod:`.animation`). Every file is written atomically
(:mod:`img2dmp._files`: temporary file, then ``os.replace``); figures go through the one
figure writer :func:`img2dmp._files.save_figure`."""

from __future__ import annotations

import csv
import io

import numpy as np

from .._files import atomic_write_bytes, atomic_write_text, save_figure
from .animation import MP4_HINT, gif_bytes, mp4_available, mp4_bytes
from .strokes import stroke_spans
from .writing import PHASES, WritingResult

LOG_CSV_HEADER = (
    "time_s", "phase", "dmp_time_s", "pen_down",
    "cmd_x_m", "cmd_y_m", "cmd_z_m", "tip_x_m", "tip_y_m", "tip_z_m", "force_n",
    *[f"torque_{j}_nm" for j in range(1, 8)],
    "dwell",
    *[f"q_{j}_rad" for j in range(1, 8)],
    *[f"qd_{j}_rad_s" for j in range(1, 8)],
)  # fmt: skip
COMMANDED_COLOR = "tab:red"
INK_COLOR = "#10104a"
FIGURE_DPI = 110


def save_log_csv(result: WritingResult, path) -> None:
    """One row per control step: time, phase, commanded and actual tip, force, torques.

    Columns: ``time_s, phase, dmp_time_s, pen_down, cmd_x_m, cmd_y_m, cmd_z_m, tip_x_m,
    tip_y_m, tip_z_m, force_n, torque_1_nm .. torque_7_nm`` (world frame, metres), then
    ``dwell`` (1: the DMP clock held), ``q_1_rad .. q_7_rad`` and ``qd_1_rad_s ..
    qd_7_rad_s`` (joint positions and velocities after the step).
    """
    log = result.log
    f = io.StringIO(newline="")
    w = csv.writer(f)
    w.writerow(LOG_CSV_HEADER)
    for i in range(log.n_steps):
        w.writerow(
            [
                f"{log.time_s[i]:.5f}",
                PHASES[log.phase[i]],
                f"{log.dmp_time_s[i]:.5f}",
                int(log.pen_down[i]),
                *(f"{v:.6f}" for v in log.cmd_m[i]),
                *(f"{v:.6f}" for v in log.tip_m[i]),
                f"{log.force_n[i]:.4f}",
                *(f"{v:.4f}" for v in log.torque_nm[i]),
                int(log.dwell[i]),
                *(f"{v:.8f}" for v in log.joint_q_rad[i]),
                *(f"{v:.6f}" for v in log.joint_qd_rad_s[i]),
            ]
        )
    atomic_write_text(path, f.getvalue())


def _paper_mm(result: WritingResult, xy_m: np.ndarray) -> np.ndarray:
    """World metres to millimetres on the paper as the writer sees it (right, up)."""
    cx, cy = result.mapping.center_m
    return np.stack([-(xy_m[..., 1] - cy) * 1e3, (xy_m[..., 0] - cx) * 1e3], axis=-1)


def plot_writing(result: WritingResult, path, image: np.ndarray | None = None, title=None):
    """PNG: input image | what the pen left on the paper with the commanded path | force
    and tracking error over time.

    The commanded path (red) carries a start marker and an arrow in the direction of
    writing; the ink (dark blue) is the tip's path while it touched the paper; the grey
    band in the time plots is the writing phase.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # Constrained layout makes room for the legends under the top panels and for titles.
    fig, axes = plt.subplots(
        2, 2, figsize=(10, 9.4), gridspec_kw={"height_ratios": [3, 2]}, layout="constrained"
    )
    _plot_pixels(axes[0, 0], result, image)
    _plot_paper(axes[0, 1], result)
    _plot_force(axes[1, 0], result)
    _plot_tracking_error(axes[1, 1], result)
    fig.suptitle(title or "KUKA iiwa writing the DMP (pybullet)")
    save_figure(fig, path, dpi=FIGURE_DPI)


def _plot_pixels(ax, result: WritingResult, image: np.ndarray | None) -> None:
    """The input image (if any) under the DMP's path in pixels, pen down and pen up."""
    plan = result.plan
    h, w = result.mapping.image_size
    if image is not None:
        ax.imshow(image, cmap="gray_r", vmin=0, vmax=1, extent=(-0.5, w - 0.5, h - 0.5, -0.5))
        ax.set_title("input image and the DMP (pixels)", fontsize=10)
    else:
        ax.set_xlim(-0.5, w - 0.5)
        ax.set_ylim(h - 0.5, -0.5)
        ax.set_title("the DMP (pixels; no input image)", fontsize=10)
    down = np.where(plan.pen_down, plan.xy_px[:, 0], np.nan)  # [T]
    ax.plot(down, plan.xy_px[:, 1], color=COMMANDED_COLOR, lw=1.2, label="DMP, pen down")
    up = ~plan.pen_down
    if up.any():
        ax.plot(plan.xy_px[up, 0], plan.xy_px[up, 1], ".", color="tab:orange", ms=2,
                label="DMP, pen up")  # fmt: skip
    _mark_start_and_direction(ax, plan.xy_px)
    ax.set_aspect("equal")
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    _legend_below(ax)


def _plot_paper(ax, result: WritingResult) -> None:
    """The ink (tip positions in contact) over the commanded path, mm on the paper."""
    import matplotlib.pyplot as plt

    log, plan, m = result.log, result.plan, result.metrics
    tip = _paper_mm(result, log.tip_m[:, :2])  # [S, 2]
    tip_ink = np.where((log.force_n > 0.0)[:, None], tip, np.nan)
    ax.plot(tip_ink[:, 0], tip_ink[:, 1], color=INK_COLOR, lw=2.5, solid_capstyle="round",
            label="ink (actual tip in contact)")  # fmt: skip
    cmd = _paper_mm(result, plan.xy_m)  # [T, 2]
    cmd_down = np.where(plan.pen_down[:, None], cmd, np.nan)
    ax.plot(cmd_down[:, 0], cmd_down[:, 1], "--", color=COMMANDED_COLOR, lw=1.0,
            label="commanded path, pen down")  # fmt: skip
    if not plan.pen_down.all():
        cmd_up = np.where(plan.pen_down[:, None], np.nan, cmd)
        ax.plot(cmd_up[:, 0], cmd_up[:, 1], ":", color="tab:orange", lw=1.0,
                label="commanded path, pen up")  # fmt: skip
    _mark_start_and_direction(ax, cmd)
    h, w = result.mapping.image_size
    half_w = w * result.mapping.metres_per_px * 1e3 / 2
    half_h = h * result.mapping.metres_per_px * 1e3 / 2
    ax.add_patch(
        plt.Rectangle(
            (-half_w, -half_h),
            2 * half_w,
            2 * half_h,
            fill=False,
            ls=":",
            color="gray",
            label="writing area (image)",
        )  # fmt: skip
    )
    ax.set_xlim(-half_w * 1.1, half_w * 1.1)
    ax.set_ylim(-half_h * 1.1, half_h * 1.1)
    ax.set_aspect("equal")
    ax.set_xlabel("mm (writer's right)")
    ax.set_ylabel("mm (away from the robot)")
    ax.set_title(
        "on the paper: tracking error\n"
        f"{m['tracking_error_mean_mm']:.3f} mm mean, {m['tracking_error_max_mm']:.3f} mm max",
        fontsize=10,
    )
    _legend_below(ax)


def _plot_force(ax, result: WritingResult) -> None:
    """Contact force over time against the set point's ±20 % band."""
    log, m = result.log, result.metrics
    f_set = m["force_set_n"]
    ax.axhspan(0.8 * f_set, 1.2 * f_set, color="tab:green", alpha=0.15, label="set point ±20 %")
    ax.plot(log.time_s, log.force_n, lw=1.0, color="k", label="contact force")
    _shade_write_phase(ax, log)
    _shade_dwell(ax, log)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("force along the pen (N)")
    ax.set_title(
        f"force {m['force_mean_n']:.2f} ± {m['force_std_n']:.2f} N while writing;\n"
        f"in contact {100 * m['contact_share']:.1f} % of the pen-down time",
        fontsize=10,
    )
    # Head room above the band for a one-row legend clear of the force trace.
    ax.set_ylim(top=max(ax.get_ylim()[1], 1.7 * f_set))
    ax.legend(loc="upper center", ncol=4, fontsize=8)


def _plot_tracking_error(ax, result: WritingResult) -> None:
    """In-plane distance between commanded and actual tip over time."""
    log = result.log
    err_mm = np.linalg.norm(log.cmd_m[:, :2] - log.tip_m[:, :2], axis=1) * 1e3  # [S]
    ax.plot(log.time_s, err_mm, lw=1.0, color="tab:blue", label="in-plane error")
    _shade_write_phase(ax, log)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("in-plane tracking error (mm)")
    ax.set_title("commanded vs actual tip", fontsize=10)
    # Head room above the curve for a one-row legend.
    ax.set_ylim(top=max(ax.get_ylim()[1], 1.3 * float(err_mm.max())))
    ax.legend(loc="upper center", ncol=2, fontsize=8)


def _mark_start_and_direction(ax, xy: np.ndarray) -> None:
    """Mark the first point of the commanded path ``xy [T, 2]`` and put an arrow on the
    path, 15 % of its length in, pointing the way it is written."""
    ax.plot(*xy[0], "o", ms=8, mfc="none", mec=COMMANDED_COLOR, mew=1.8, zorder=5,
            label="start")  # fmt: skip
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])  # [T]
    if s[-1] <= 0.0:
        return
    # A short chord (6 % of the length) so the arrow follows curved strokes closely.
    i = int(np.searchsorted(s, 0.15 * s[-1]))
    j = min(int(np.searchsorted(s, s[i] + 0.06 * s[-1])), len(xy) - 1)
    if j <= i:
        return
    arrow = {"arrowstyle": "-|>", "color": COMMANDED_COLOR, "lw": 1.8, "mutation_scale": 16}
    ax.annotate("", xy=xy[j], xytext=xy[i], arrowprops=arrow, zorder=5)
    # Annotations have no legend entry; a stand-in marker gives the arrow one.
    ax.plot([], [], ">", color=COMMANDED_COLOR, ms=7, label="direction of writing")


def _legend_below(ax) -> None:
    """Legend under the axes, so that it never hides the drawing."""
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, fontsize=8,
              frameon=False)  # fmt: skip


def _shade_write_phase(ax, log) -> None:
    write = log.in_phase("write")  # [S]
    if write.any():
        t = log.time_s[write]
        ax.axvspan(t[0], t[-1], color="gray", alpha=0.08, lw=0, label="write phase")


def _shade_dwell(ax, log) -> None:
    """The steps on which the DMP clock was held (pen landing or lifting between strokes)."""
    spans = [s for s in stroke_spans(log.dwell) if s[1] > s[0]]
    for i, (a, b) in enumerate(spans):
        ax.axvspan(log.time_s[a], log.time_s[b], color="tab:orange", alpha=0.15, lw=0,
                   label="DMP held" if i == 0 else None)  # fmt: skip


def save_render(result: WritingResult, path) -> None:
    """The final camera picture (arm | paper close-up) as a PNG."""
    from PIL import Image

    if result.render is None:
        raise ValueError("this result has no render (write_dmp(render_size_px=None))")
    buf = io.BytesIO()
    Image.fromarray(result.render).save(buf, format="PNG")
    atomic_write_bytes(path, buf.getvalue())


def save_video(result: WritingResult, path, frame_interval_s: float) -> None:
    """The video frames as an animated GIF (pillow, no extra dependency), the last frame
    (the finished digit) held for ``animation.HOLD_LAST_S``."""
    if not result.frames:
        raise ValueError("this result has no frames (write_dmp(frame_interval_s=...))")
    atomic_write_bytes(path, gif_bytes(result.frames, frame_interval_s))


def save_mp4(result: WritingResult, path, frame_interval_s: float) -> None:
    """The video frames as an H.264 MP4 (needs ``imageio-ffmpeg``: ``ImportError`` saying
    so), the last frame held for ``animation.HOLD_LAST_S``."""
    if not result.frames:
        raise ValueError("this result has no frames (write_dmp(frame_interval_s=...))")
    atomic_write_bytes(path, mp4_bytes(result.frames, frame_interval_s))


def save_videos(result: WritingResult, base, frame_interval_s: float) -> list[str]:
    """``base.gif`` always and ``base.mp4`` where imageio-ffmpeg is installed; returns the
    files written, followed by a note when the MP4 was left out (and why)."""
    written = [f"{base}.gif"]
    save_video(result, written[0], frame_interval_s)
    if mp4_available():
        save_mp4(result, f"{base}.mp4", frame_interval_s)
        written.append(f"{base}.mp4")
    else:
        written.append(f"no MP4 ({MP4_HINT})")
    return written


def summary_lines(name: str, result: WritingResult) -> list[str]:
    """The metrics of a run in words: tracking and force over the pen-down time (DMP
    running), then each stroke's ink share and force share and the time the DMP clock
    was held."""
    m = result.metrics
    lines = [
        f"{name}: tracking error {m['tracking_error_mean_mm']:.3f} mm mean, "
        f"{m['tracking_error_max_mm']:.3f} mm max; contact force "
        f"{m['force_mean_n']:.3f} ± {m['force_std_n']:.3f} N (set {m['force_set_n']:g} N), "
        f"within ±20 % {100 * m['force_in_band_share']:.1f} % and in contact "
        f"{100 * m['contact_share']:.1f} % of the pen-down time; "
        f"{m['simulated_s']:.2f} s simulated at {m['control_rate_hz']:g} Hz, "
        f"{m['real_time_factor']:.1f}x real time"
    ]
    strokes = m.get("strokes", [])
    parts = [
        f"{i}: {s['length_mm']:.1f} mm, ink {100 * s['ink_share']:.1f} %, force in band "
        f"{100 * s['force_in_band_share']:.1f} %"
        for i, s in enumerate(strokes, start=1)
    ]
    if parts:
        lines.append(
            f"  strokes (share of each commanded pen-down stroke with ink) {'; '.join(parts)}; "
            f"DMP held {m['dwell_s']:.2f} s for the pen to land and lift (force in band "
            f"{100 * m['force_in_band_share_with_dwell']:.1f} % counting that time)"
        )
    return lines
