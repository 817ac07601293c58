"""Files written after a writing run: CSV log, the paper next to the commanded path and
the input image, camera renders and the video (animated GIF; MP4 with imageio-ffmpeg,
:mod:`.animation`); for a page (:mod:`.page`) also its figure with the characters
numbered and the table of the characters' measures. Every file is written atomically
(:mod:`img2dmp._files`: temporary file, then ``os.replace``); figures go through the one
figure writer :func:`img2dmp._files.save_figure`."""

from __future__ import annotations

import csv
import io
import math

import numpy as np

from .._files import atomic_write_bytes, atomic_write_text, new_figure, save_figure
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
    qd_7_rad_s`` (joint positions and velocities after the step), then the result's
    :meth:`~img2dmp.robot.WritingResult.extra_log_columns` (a page: ``character``).
    """
    log = result.log
    extra = result.extra_log_columns()
    f = io.StringIO(newline="")
    w = csv.writer(f)
    w.writerow((*LOG_CSV_HEADER, *extra))
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
                *(column[i] for column in extra.values()),
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

    # Constrained layout makes room for the legends under the top panels and for titles.
    fig = new_figure(figsize=(10, 9.4), layout="constrained")
    axes = fig.subplots(2, 2, gridspec_kw={"height_ratios": [3, 2]})
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
    x0, y0, x1, y1 = result.mapping.image_area_px
    if image is not None:
        # An image of another size (a reduced view of a photo) still spans the pixels of
        # the frame the DMP is in.
        ax.imshow(image, cmap="gray_r", vmin=0, vmax=1, extent=(-0.5, w - 0.5, h - 0.5, -0.5))
        ax.set_title("input image and the DMP (pixels)", fontsize=10)
    else:
        ax.set_title("the DMP (pixels; no input image)", fontsize=10)
    ax.set_xlim(x0 - 0.5, x1 - 0.5)
    ax.set_ylim(y1 - 0.5, y0 - 0.5)
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
    from matplotlib.patches import Rectangle

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
    width_mm, height_mm = result.mapping.area_size_mm
    half_w, half_h = width_mm / 2, height_mm / 2
    ax.add_patch(
        Rectangle(
            (-half_w, -half_h),
            2 * half_w,
            2 * half_h,
            fill=False,
            ls=":",
            color="gray",
            label="writing area (image)" if _whole_image(result.mapping) else "writing area",
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


def _whole_image(mapping) -> bool:
    h, w = mapping.image_size
    return not mapping.turn_deg and tuple(mapping.area_px) == (0, 0, w, h)


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
    # Head room above the band for a two-row legend clear of the force trace (four
    # entries in one row are wider than the panel and cover its tick labels).
    ax.set_ylim(top=max(ax.get_ylim()[1], 2.0 * f_set))
    ax.legend(loc="upper center", ncol=2, fontsize=8)


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
    """Mark the first and the last point of the commanded path ``xy [T, 2]`` (where a
    goal given with ``--goal`` has moved it) and put an arrow on the path, 15 % of its
    length in, pointing the way it is written."""
    ax.plot(*xy[0], "o", ms=8, mfc="none", mec=COMMANDED_COLOR, mew=1.8, zorder=5,
            label="start")  # fmt: skip
    ax.plot(*xy[-1], "x", ms=8, color=COMMANDED_COLOR, mew=1.8, zorder=5, label="end")
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
    """Each run of write-phase steps (one per DMP: a page has one per character)."""
    for i, (a, b) in enumerate(stroke_spans(log.in_phase("write"))):
        ax.axvspan(log.time_s[a], log.time_s[b], color="gray", alpha=0.08, lw=0,
                   label="write phase" if i == 0 else None)  # fmt: skip


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


#: A run whose pen-down path is shorter on the paper (mm), or one of whose strokes got
#: less ink than this share, is worth a warning: it wrote (almost) nothing of the DMP.
WARN_LENGTH_MM = 0.5
WARN_INK_SHARE = 0.5


def writing_warnings(result: WritingResult) -> list[str]:
    """What a finished run wrote that its user would not want, in words (empty for a
    good run): a path of (almost) no length on the paper (a DMP whose goal-start scaling
    has g = y0, or a frame far larger than its movement), a stroke mostly without ink
    (a tau so short that the arm lags its path), a joint faster than a real iiwa's
    (:func:`joint_speed_warning`)."""
    warnings = []
    strokes = result.metrics.get("strokes", [])
    length = sum(s["length_mm"] for s in strokes)
    poor = [(i, s) for i, s in enumerate(strokes, start=1) if s["ink_share"] < WARN_INK_SHARE]
    if strokes and length < WARN_LENGTH_MM:
        warnings.append(f"its pen-down path is {length:.2f} mm long on the paper: almost "
                        "nothing was written (check the DMP's image_size, and g - y0 with "
                        "goal-start scaling)")  # fmt: skip
    elif poor:
        i, s = min(poor, key=lambda p: p[1]["ink_share"])
        warnings.append(f"stroke {i} got ink along {100 * s['ink_share']:.1f} % of its "
                        f"{s['length_mm']:.1f} mm (a DMP faster than the arm follows? a "
                        "longer tau, or --tempo below 1, slows it)")  # fmt: skip
    speed = joint_speed_warning(result.metrics)
    acceleration = joint_acceleration_warning(result.metrics)
    return warnings + [w for w in (speed, acceleration) if w]


def joint_speed_line(metrics: dict) -> str | None:
    """The run's peak joint speed against the real iiwa's limits in words (None for a
    run without joint speeds)."""
    share = metrics.get("joint_speed_peak_share", math.nan)
    if not math.isfinite(share):
        return None
    peaks = np.asarray(metrics["joint_speed_peak_rad_s"])
    limits = np.asarray(metrics["joint_speed_limit_rad_s"])
    j = int(np.argmax(peaks / limits))
    within = "within" if share <= 1.0 else "OVER"
    return (
        f"  joint speeds {within} the real iiwa's limits: peak {100 * share:.0f} % of its limit "
        f"({metrics['joint_speed_peak_joint']} {peaks[j]:.2f} of {limits[j]:.2f} rad/s at "
        f"t = {metrics['joint_speed_peak_time_s']:.2f} s); per joint "
        + " ".join(f"{p:.2f}" for p in peaks)
        + " rad/s"
    )


def _planned_acceleration_peak(metrics: dict) -> tuple:
    """``(share, joint, limit, where)`` of the peak acceleration planned along a run's
    DMPs: its share of the planning limit (NaN without a plan's accelerations), the
    joint's name and limit (rad/s^2), and on a page the entry whose (else None)."""
    share = metrics.get("planned_joint_acceleration_share", math.nan)
    if not math.isfinite(share):
        return share, None, math.nan, None
    joint = metrics["planned_joint_acceleration_joint"]
    limits = metrics["joint_acceleration_limit_rad_s2"]
    limit = float(limits[int(joint.rsplit("_", 1)[1]) - 1])
    return share, joint, limit, metrics.get("planned_joint_acceleration_character")


def joint_acceleration_line(metrics: dict, noun: str = "character") -> str | None:
    """The peak joint acceleration planned along the DMPs (at the tempo written) against
    the planning limit, and the simulated arm's own peak over the run, in words (None
    for a run without a plan's accelerations); on a page, naming the ``noun`` whose."""
    share, joint, limit, where = _planned_acceleration_peak(metrics)
    if not math.isfinite(share):
        return None
    limits = np.asarray(metrics["joint_acceleration_limit_rad_s2"])
    within = "within" if share <= 1.0 else "OVER"
    where = "" if where is None else f", {noun} {where}"
    line = (
        f"  joint accelerations planned along the DMPs {within} the planning limit: peak "
        f"{100 * share:.0f} % of it ({joint} {share * limit:.2f} of {limit:g} rad/s^2"
        f"{where})"
    )
    run = metrics.get("joint_acceleration_peak_share", math.nan)
    if math.isfinite(run):
        peaks = np.asarray(metrics["joint_acceleration_peak_rad_s2"])
        k = int(np.argmax(peaks / limits))
        line += (
            f"; the simulated arm's peak over the run {peaks[k]:.1f} rad/s^2, "
            f"{100 * run:.0f} % of it ({metrics['joint_acceleration_peak_joint']} at t = "
            f"{metrics['joint_acceleration_peak_time_s']:.2f} s, "
            f"{metrics['joint_acceleration_peak_phase']})"
        )
    return line


def joint_speed_warning(metrics: dict) -> str | None:
    """A warning (None if not needed) when the simulated arm moved a joint faster than a
    real iiwa can: the motion is not one a real arm can follow."""
    share = metrics.get("joint_speed_peak_share", math.nan)
    if not share > 1.0:
        return None
    peaks = np.asarray(metrics["joint_speed_peak_rad_s"])
    limits = np.asarray(metrics["joint_speed_limit_rad_s"])
    j = int(np.argmax(peaks / limits))
    return (
        f"{metrics['joint_speed_peak_joint']} moved at {peaks[j]:.2f} rad/s at t = "
        f"{metrics['joint_speed_peak_time_s']:.2f} s, {100 * share:.0f} % of the real "
        f"iiwa's limit of {limits[j]:.2f} rad/s: a real iiwa cannot follow this motion"
    )


def joint_acceleration_warning(metrics: dict, noun: str = "character") -> str | None:
    """A warning (None if not needed) when the joint accelerations planned along a DMP,
    at the tempo written (``--no-slowing``), pass the planning limit a real iiwa is
    driven within; on a page, naming the ``noun`` whose."""
    share, joint, limit, where = _planned_acceleration_peak(metrics)
    if not share > 1.0:
        return None
    where = "" if where is None else f" ({noun} {where})"
    return (
        f"{joint} would accelerate at {share * limit:.1f} rad/s^2 along a DMP{where}, "
        f"{100 * share:.0f} % of the planning limit of {limit:g} rad/s^2: a real iiwa "
        "would be driven slower (without --no-slowing it is)"
    )


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
        f"{m['simulated_s']:.2f} s simulated at {m['control_rate_hz']:g} Hz in "
        f"{m['wall_s']:.2f} s, {m['real_time_factor']:.1f}x real time"
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
    speeds = joint_speed_line(m)
    if speeds:
        lines.append(speeds)
    accelerations = joint_acceleration_line(m)
    if accelerations:
        lines.append(accelerations)
    return lines


# --- a page (img2dmp.robot.page) ----------------------------------------------------------

CHARACTERS_CSV_HEADER = (
    "index", "line", "written", "flags", "confidence", "start_s", "end_s", "strokes",
    "length_mm", "ink_share", "stroke_ink_share_min", "ink_on_path_share", "ink_length_mm",
    "placement_error_mm", "force_mean_n", "force_std_n", "force_in_band_share",
    "contact_share", "tracking_error_mean_mm", "tracking_error_max_mm", "dwell_s",
    "approach_s",
)  # fmt: skip
_PAGE_TOTALS = (
    "length_mm", "ink_share", "stroke_ink_share_min", "ink_on_path_share", "ink_length_mm",
    "force_mean_n", "force_std_n", "force_in_band_share", "contact_share",
    "tracking_error_mean_mm", "tracking_error_max_mm", "dwell_s", "approach_s",
)  # fmt: skip


def plot_page(result, path, image: np.ndarray | None = None, title=None,
              noun: str = "character") -> None:  # fmt: skip
    """PNG of a page (a ``PageResult``): the panels of :func:`plot_writing` over the whole
    page - the photo's written area with the DMPs in its pixels, the ink on the paper
    over the commanded paths (travels dotted), force and tracking error over time (one
    grey band per character) - with every character's number at its place and in time,
    and the characters left out (``skip_flagged``) drawn as dashed boxes.

    ``image``: the photo (ink = 1), of any resolution: it is stretched over the photo's
    pixel frame (e.g. a reduced view from :func:`img2dmp.data.images.ink_view`).
    ``noun``: what each entry is, for the titles (``"stroke"`` on a stroke model's page).
    """
    fig = new_figure(figsize=(11, 9.4), layout="constrained")
    axes = fig.subplots(2, 2, gridspec_kw={"height_ratios": [3, 2]})
    _plot_pixels(axes[0, 0], result, image)
    axes[0, 0].set_title(
        f"the photo's written area and the {noun}s' DMPs (pixels)"
        if image is not None
        else f"the {noun}s' DMPs (photo pixels; no photo)",
        fontsize=10,
    )
    _plot_paper(axes[0, 1], result)
    _plot_force(axes[1, 0], result)
    _plot_tracking_error(axes[1, 1], result)
    _number_characters(axes, result)
    n = len(result.characters)
    written = sum(r.written for r in result.characters)
    fig.suptitle(title or f"KUKA iiwa writes a page: {written} of {n} characters (pybullet)")
    save_figure(fig, path, dpi=FIGURE_DPI)


#: A page of more characters than this gets smaller numbers, "(skipped)" said by colour
#: (grey) and the dashed box alone, and over time only numbers that stand apart.
MANY_CHARACTERS = 20
#: ... at least this share of the time axis apart (at most 25 numbers across it).
TIME_LABEL_GAP = 0.04


def _number_characters(axes, result) -> None:
    """Each character's index at its box (pixels and paper) and over its time; dashed
    boxes (and grey numbers) for the characters not written. On a page of many, smaller
    numbers, and over time only those at least ``TIME_LABEL_GAP`` of the axis apart."""
    from matplotlib.patches import Polygon, Rectangle

    many = len(result.characters) > MANY_CHARACTERS
    text = {"fontsize": 6 if many else 8, "ha": "right", "va": "bottom"}
    span = float(result.log.time_s[-1] - result.log.time_s[0]) if len(result.log.time_s) else 0
    last_t = -math.inf
    for r in result.characters:
        x0, y0, x1, y1 = r.character.box_image_px
        corners_px = [[x0 - 0.5, y0 - 0.5], [x1 - 0.5, y0 - 0.5], [x1 - 0.5, y1 - 0.5],
                      [x0 - 0.5, y1 - 0.5]]  # fmt: skip
        corners_mm = _paper_mm(result, result.mapping.to_table(corners_px))
        label = str(r.character.index)
        if not r.written and not many:
            label += " (skipped)"
        color = "tab:blue" if r.written else "gray"
        axes[0, 0].text(x0 - 0.5, y0 - 0.5, label, color=color, **text)
        axes[0, 1].text(*corners_mm[0], label, color=color, **text)
        if not r.written:
            box = {"fill": False, "ls": "--", "color": "gray"}
            axes[0, 0].add_patch(Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, **box))
            axes[0, 1].add_patch(Polygon(corners_mm, closed=True, **box))
            continue
        a, b = r.steps
        t_mid = (result.log.time_s[a] + result.log.time_s[b - 1]) / 2
        if t_mid - last_t < TIME_LABEL_GAP * span:
            continue
        last_t = t_mid
        for ax in axes[1]:
            ax.annotate(
                str(r.character.index),
                (t_mid, 0.02),
                xycoords=("data", "axes fraction"),
                ha="center",
                fontsize=8,
                color="tab:blue",
            )


def _character_row(r) -> list:
    c, m = r.character, r.metrics
    head = [c.index, c.line, int(r.written), " ".join(c.flags), f"{c.confidence:.4f}"]
    if not r.written:
        return head + [""] * (len(CHARACTERS_CSV_HEADER) - len(head))
    return head + [
        f"{m['start_s']:.4f}", f"{m['end_s']:.4f}", len(m["strokes"]),
        *(f"{m[k]:.4f}" for k in CHARACTERS_CSV_HEADER[8:]),
    ]  # fmt: skip


def save_characters_csv(result, path, owners: dict | None = None) -> None:
    """One row per character of a page (a ``PageResult``), in reading order, then a row
    ``page`` of the totals. ``owners``: on a stroke model's page, each entry's
    ``(character, stroke, n_strokes)`` by index
    (:meth:`img2dmp.robot.page.PagePlan.entry_owners`), written as two more columns
    ``character, stroke`` (its stroke, from 1, of that character).

    Columns (``CHARACTERS_CSV_HEADER``): ``index, line, written`` (1/0), ``flags``
    (space-separated), ``confidence``, ``start_s, end_s`` (page time), ``strokes``,
    ``length_mm`` (commanded pen-down length), ``ink_share`` (the share of it with ink),
    ``stroke_ink_share_min``, ``ink_on_path_share`` (the share of the ink on the commanded
    path), ``ink_length_mm``, ``placement_error_mm`` (ink centre to commanded path centre),
    ``force_mean_n, force_std_n, force_in_band_share, contact_share,
    tracking_error_mean_mm, tracking_error_max_mm`` (the pen-down time with the DMP
    running), ``dwell_s, approach_s``; empty for a character not written
    (:func:`img2dmp.robot.page.character_metrics`, :func:`~img2dmp.robot.page.page_metrics`).
    """
    m = result.metrics
    f = io.StringIO(newline="")
    w = csv.writer(f)
    extra = ("character", "stroke") if owners else ()
    w.writerow(CHARACTERS_CSV_HEADER + extra)
    for r in result.characters:
        owner = owners.get(r.character.index) if owners else None
        w.writerow(_character_row(r) + (list(owner[:2]) if owner else [""] * len(extra)))
    total = {k: f"{m[k]:.4f}" for k in _PAGE_TOTALS}
    total.update(
        index="page",
        written=m["characters_written"],
        strokes=len(m["strokes"]),
        start_s="0.0000",
        end_s=f"{m['simulated_s']:.4f}",
        placement_error_mm=f"{m['placement_error_max_mm']:.4f}",  # the worst character's
    )
    w.writerow([total.get(k, "") for k in CHARACTERS_CSV_HEADER] + [""] * len(extra))
    atomic_write_text(path, f.getvalue())


def page_summary_lines(name: str, result, noun: str = "character", labels=None) -> list[str]:
    """A page's measures in words: the totals, then one line per character (``noun``:
    what its entries are called, e.g. a stroke model's ``"stroke"``; ``labels``: a
    name per entry index to add, :meth:`img2dmp.robot.page.PagePlan.entry_labels`)."""
    m = result.metrics
    between = (
        f"no ink between {noun}s"
        if m["travel_contact_s"] == 0
        else f"the pen touched the paper for {m['travel_contact_s']:.3f} s between {noun}s"
    )
    lines = [
        f"{name}: {m['characters_written']} of {m['characters']} {noun}s written on "
        f"{m['width_mm']:.1f} x {m['height_mm']:.1f} mm; commanded paths inked "
        f"{100 * m['ink_share']:.1f} %, ink on the commanded paths "
        f"{100 * m['ink_on_path_share']:.1f} %; {between}",
        f"  tracking error {m['tracking_error_mean_mm']:.3f} mm mean, "
        f"{m['tracking_error_max_mm']:.3f} mm max; contact force {m['force_mean_n']:.3f} ± "
        f"{m['force_std_n']:.3f} N (set {m['force_set_n']:g} N), within ±20 % "
        f"{100 * m['force_in_band_share']:.1f} % of the pen-down time; "
        f"{m['simulated_s']:.2f} s simulated at {m['control_rate_hz']:g} Hz in "
        f"{m['wall_s']:.2f} s, {m['real_time_factor']:.1f}x real time",
    ]
    speeds = joint_speed_line(m)
    if speeds:
        lines.append(speeds)
    accelerations = joint_acceleration_line(m, noun)
    if accelerations:
        lines.append(accelerations)
    for r in result.characters:
        c, cm = r.character, r.metrics
        label = (labels or {}).get(c.index)
        head = f"  {noun} {c.index}" + (f", {label}" if label else "") + f" (line {c.line}"
        head += f", flags {' '.join(c.flags)})" if c.flags else ")"
        if not r.written:
            lines.append(f"{head}: skipped")
            continue
        lines.append(
            f"{head}: path inked {100 * cm['ink_share']:.1f} %, ink on the path "
            f"{100 * cm['ink_on_path_share']:.1f} %, placed within "
            f"{cm['placement_error_mm']:.2f} mm; force {cm['force_mean_n']:.2f} ± "
            f"{cm['force_std_n']:.2f} N; tracking {cm['tracking_error_mean_mm']:.3f} mm mean, "
            f"{cm['tracking_error_max_mm']:.3f} mm max"
            + (f"; written {cm['slowdown']:.2f}x slower" if cm.get("slowdown", 1.0) > 1.0 else "")
        )
    return lines
