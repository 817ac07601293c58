"""Files written after a writing run: CSV log, the paper next to the commanded path and
the input image, camera renders and an animated GIF. Every file is written atomically
(:func:`img2dmp.checkpoint.atomic_write_bytes`: temporary file, then ``os.replace``)."""

from __future__ import annotations

import csv
import io

import numpy as np

from .._files import atomic_write_bytes, atomic_write_text
from .writing import PHASES, WritingResult


def save_log_csv(result: WritingResult, path) -> None:
    """One row per control step: time, phase, commanded and actual tip, force, torques.

    Columns: ``time_s, phase, dmp_time_s, pen_down, cmd_x_m, cmd_y_m, cmd_z_m, tip_x_m,
    tip_y_m, tip_z_m, force_n, torque_1_nm .. torque_7_nm`` (world frame, metres).
    """
    log = result.log
    header = [
        "time_s", "phase", "dmp_time_s", "pen_down",
        "cmd_x_m", "cmd_y_m", "cmd_z_m", "tip_x_m", "tip_y_m", "tip_z_m", "force_n",
        *[f"torque_{j}_nm" for j in range(1, 8)],
    ]  # fmt: skip
    f = io.StringIO(newline="")
    w = csv.writer(f)
    w.writerow(header)
    for i in range(len(log["time_s"])):
        w.writerow(
            [
                f"{log['time_s'][i]:.5f}",
                PHASES[log["phase"][i]],
                f"{log['dmp_time_s'][i]:.5f}",
                int(log["pen_down"][i]),
                *(f"{v:.6f}" for v in log["cmd_m"][i]),
                *(f"{v:.6f}" for v in log["tip_m"][i]),
                f"{log['force_n'][i]:.4f}",
                *(f"{v:.4f}" for v in log["torque_nm"][i]),
            ]
        )
    atomic_write_text(path, f.getvalue())


def _paper_mm(result: WritingResult, xy_m: np.ndarray) -> np.ndarray:
    """World metres to millimetres on the paper as the writer sees it (right, up)."""
    cx, cy = result.mapping.center_m
    return np.stack([-(xy_m[..., 1] - cy) * 1e3, (xy_m[..., 0] - cx) * 1e3], axis=-1)


def _png_bytes(save) -> bytes:
    buf = io.BytesIO()
    save(buf)
    return buf.getvalue()


def _save_figure(fig, path) -> None:
    atomic_write_bytes(path, _png_bytes(lambda b: fig.savefig(b, format="png", dpi=110)))


def plot_writing(result: WritingResult, path, image: np.ndarray | None = None, title=None):
    """PNG: input image | what the pen left on the paper with the commanded path | force
    and tracking error over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    log, m = result.log, result.metrics
    plan = result.plan
    fig, axes = plt.subplots(2, 2, figsize=(10, 8.4), gridspec_kw={"height_ratios": [3, 2]})
    ax = axes[0, 0]
    h, w = result.mapping.image_size
    if image is not None:
        ax.imshow(image, cmap="gray_r", vmin=0, vmax=1, extent=(-0.5, w - 0.5, h - 0.5, -0.5))
        ax.set_title("input image and the DMP (pixels)")
    else:
        ax.set_xlim(-0.5, w - 0.5)
        ax.set_ylim(h - 0.5, -0.5)
        ax.set_title("the DMP (pixels; no input image)")
    down = np.where(plan.pen_down, plan.xy_px[:, 0], np.nan)
    ax.plot(down, plan.xy_px[:, 1], color="tab:red", lw=1.2, label="DMP, pen down")
    ax.plot(plan.xy_px[~plan.pen_down, 0], plan.xy_px[~plan.pen_down, 1], ".",
            color="tab:orange", ms=2, label="pen up")  # fmt: skip
    ax.set_aspect("equal")
    ax.legend(loc="lower right", fontsize=8)

    ax = axes[0, 1]
    ink = log["force_n"] > 0.0
    tip = _paper_mm(result, log["tip_m"][:, :2])
    tip_ink = np.where(ink[:, None], tip, np.nan)
    ax.plot(tip_ink[:, 0], tip_ink[:, 1], color="#10104a", lw=2.5, solid_capstyle="round",
            label="ink (tip in contact)")  # fmt: skip
    cmd = _paper_mm(result, plan.xy_m)
    cmd_down = np.where(plan.pen_down[:, None], cmd, np.nan)
    ax.plot(cmd_down[:, 0], cmd_down[:, 1], "--", color="tab:red", lw=1.0,
            label="commanded path")  # fmt: skip
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
        f"on the paper: tracking error {m['tracking_error_mean_mm']:.3f} mm mean, "
        f"{m['tracking_error_max_mm']:.3f} mm max",
        fontsize=9,
    )
    ax.legend(loc="lower right", fontsize=8)

    t = log["time_s"]
    ax = axes[1, 0]
    f_set = m["force_set_n"]
    ax.axhspan(0.8 * f_set, 1.2 * f_set, color="tab:green", alpha=0.15, label="set point ±20 %")
    ax.plot(t, log["force_n"], lw=1.0, color="k", label="contact force")
    _shade_phases(ax, log)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("force along the pen (N)")
    ax.set_title(
        f"force {m['force_mean_n']:.2f} ± {m['force_std_n']:.2f} N while writing; "
        f"in contact {100 * m['contact_share']:.1f} %",
        fontsize=9,
    )
    ax.legend(loc="upper right", fontsize=8)

    ax = axes[1, 1]
    err = np.linalg.norm(log["cmd_m"][:, :2] - log["tip_m"][:, :2], axis=1) * 1e3
    ax.plot(t, err, lw=1.0, color="tab:blue")
    _shade_phases(ax, log)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("in-plane tracking error (mm)")
    ax.set_title("commanded vs actual tip", fontsize=9)
    fig.suptitle(title or "KUKA iiwa writing the DMP (pybullet)")
    fig.tight_layout()
    _save_figure(fig, path)
    plt.close(fig)


def _shade_phases(ax, log) -> None:
    write = log["phase"] == PHASES.index("write")
    if write.any():
        t = log["time_s"][write]
        ax.axvspan(t[0], t[-1], color="gray", alpha=0.08, lw=0)


def save_render(result: WritingResult, path) -> None:
    """The final camera picture (arm | paper close-up) as a PNG."""
    from PIL import Image

    if result.render is None:
        raise ValueError("this result has no render (write_dmp(render_size_px=None))")
    image = Image.fromarray(result.render)
    atomic_write_bytes(path, _png_bytes(lambda b: image.save(b, format="PNG")))


def save_video(result: WritingResult, path, frame_interval_s: float) -> None:
    """The camera frames as an animated GIF (pillow, no extra dependency)."""
    from PIL import Image

    if not result.frames:
        raise ValueError("this result has no frames (write_dmp(frame_interval_s=...))")
    images = [Image.fromarray(fr) for fr in result.frames]
    buf = io.BytesIO()
    images[0].save(
        buf,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        duration=int(round(frame_interval_s * 1000)),
        loop=0,
    )
    atomic_write_bytes(path, buf.getvalue())
