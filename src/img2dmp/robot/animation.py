"""The video of a writing run: a paper panel that shows the ink appearing, and the frames
encoded as an animated GIF (pillow) or an MP4 (``imageio-ffmpeg``, if installed).

Each video frame is the arm (a camera picture of the simulation) next to
:class:`PaperInset`: the writing area seen from above as the writer sees it (image up =
away from the robot), drawn from the log - the commanded pen-down path in light red, the
ink (the tip's path while it touched the paper) in dark blue, the pen's place as a ring
(filled while it touches). A camera close-up of the pen could not show the ink: the pen
and the wrist stand over it. The last frame (the finished digit) is held for
``HOLD_LAST_S`` in both files.
"""

from __future__ import annotations

import io
import os
import tempfile

import numpy as np

from .strokes import stroke_spans

# The last frame (the finished digit) stays this long at the end of the video.
HOLD_LAST_S = 2.0
PAPER_RGB = (247, 247, 242)
INK_RGB = (16, 16, 74)
PATH_RGB = (240, 175, 175)
PEN_RGB = (200, 30, 30)
TEXT_RGB = (90, 90, 90)
# Drawn width of the ink line on the paper, metres (at least 2 px).
INK_WIDTH_M = 5e-4
MP4_HINT = "MP4 needs imageio-ffmpeg: pip install imageio-ffmpeg"


class PaperInset:
    """The writing area seen from above, with the ink drawn as it appears.

    The panel shows the commanded path's extent plus ``MARGIN_M`` around it (at least
    ``MIN_EXTENT_M`` across), with a 5 mm scale bar.

    Parameters
    ----------
    size_px : tuple (w, h)
        Size of the panel.
    path_xy_m : ndarray [T, 2]
        The commanded path on the paper (world metres).
    pen_down : ndarray [T] bool
        Its pen channel; the pen-down parts are drawn faintly under the ink.
    """

    MARGIN_M = 3e-3
    MIN_EXTENT_M = 1e-2

    def __init__(self, size_px, path_xy_m, pen_down):
        from PIL import Image, ImageDraw

        self.w, self.h = (int(v) for v in size_px)
        path = np.asarray(path_xy_m, dtype=float).reshape(-1, 2)
        lo, hi = path.min(axis=0), path.max(axis=0)
        self.center_m = (lo + hi) / 2
        extent = np.maximum(hi - lo + 2 * self.MARGIN_M, self.MIN_EXTENT_M)  # world x, y
        self.top_px = 14  # room for the caption
        # World y runs across the panel, world x up it.
        self.px_per_m = min(self.w / extent[1], (self.h - self.top_px) / extent[0])
        self.mid_px = np.array([self.w / 2, self.top_px + (self.h - self.top_px) / 2])
        self.paper = Image.new("RGB", (self.w, self.h), PAPER_RGB)
        self._draw = ImageDraw.Draw(self.paper)
        self.ink_width_px = max(2, int(round(INK_WIDTH_M * self.px_per_m)))
        self._scale_bar()
        path_px = self.to_px(path)
        for a, b in stroke_spans(pen_down):
            pts = [tuple(p) for p in path_px[a : b + 1]]
            if len(pts) > 1:
                self._draw.line(pts, fill=PATH_RGB, width=1)
        self._seen = 0  # log steps drawn so far
        self._last_px: tuple[float, float] | None = None  # last touching tip, if touching

    def _scale_bar(self) -> None:
        """A 5 mm bar in the lower left corner."""
        length = 5e-3 * self.px_per_m
        x0, y = 6.0, self.h - 8.0
        self._draw.line([(x0, y), (x0 + length, y)], fill=TEXT_RGB, width=2)
        self._draw.text((x0 + length + 4, y - 6), "5 mm", fill=TEXT_RGB)

    def to_px(self, xy_m) -> np.ndarray:
        """World ``[..., 2]`` (x, y) metres to panel pixels ``[..., 2]`` (column, row)."""
        d = np.asarray(xy_m, dtype=float)[..., :2] - self.center_m
        # Writer's right is world -y, up on the panel is world +x.
        return np.stack([-d[..., 1], -d[..., 0]], axis=-1) * self.px_per_m + self.mid_px

    def add(self, tip_m, force_n) -> None:
        """Draw the ink of the log steps not drawn yet: ``tip_m``, ``force_n`` are the whole
        log so far (sequences of ``[3]`` and floats); consecutive touching steps are
        joined by a line."""
        new_tips = np.asarray(tip_m[self._seen :], dtype=float).reshape(-1, 3)
        new_force = np.asarray(force_n[self._seen :], dtype=float)
        self._seen += len(new_force)
        r = self.ink_width_px / 2
        for p, touching in zip(self.to_px(new_tips), new_force > 0.0, strict=True):
            if not touching:
                self._last_px = None
                continue
            p = (float(p[0]), float(p[1]))
            if self._last_px is not None:
                self._draw.line([self._last_px, p], fill=INK_RGB, width=self.ink_width_px)
            self._draw.ellipse([p[0] - r, p[1] - r, p[0] + r, p[1] + r], fill=INK_RGB)
            self._last_px = p

    def draw(self, tip_m, time_s: float) -> np.ndarray:
        """The panel now: the paper with its ink, the pen at ``tip_m`` (a ring, filled while
        it touches; None: no pen) and a caption. ``uint8 [h, w, 3]``."""
        from PIL import ImageDraw

        im = self.paper.copy()
        d = ImageDraw.Draw(im)
        if tip_m is not None:
            x, y = self.to_px(np.asarray(tip_m, dtype=float)[:2])
            r = max(4.0, 1.5e-3 * self.px_per_m)
            d.ellipse([x - r, y - r, x + r, y + r], outline=PEN_RGB, width=2)
            if self._last_px is not None:  # touching
                d.ellipse([x - r / 2, y - r / 2, x + r / 2, y + r / 2], fill=PEN_RGB)
        d.text((4, 1), f"paper from above   t = {time_s:5.2f} s", fill=TEXT_RGB)
        return np.asarray(im, dtype=np.uint8).copy()


def _frame_list(frames) -> list[np.ndarray]:
    if not len(frames):
        raise ValueError("there are no frames to encode (write_dmp(frame_interval_s=...))")
    return [np.asarray(f, dtype=np.uint8) for f in frames]


def gif_bytes(frames, frame_interval_s: float, hold_last_s: float = HOLD_LAST_S) -> bytes:
    """Animated GIF of ``frames`` (each ``uint8 [h, w, 3]``), one every
    ``frame_interval_s``, the last one shown for ``hold_last_s`` (at least one interval)."""
    from PIL import Image

    images = [Image.fromarray(f) for f in _frame_list(frames)]
    step_ms = max(10, int(round(frame_interval_s * 1000)))
    durations = [step_ms] * len(images)
    durations[-1] = max(step_ms, int(round(hold_last_s * 1000)))
    buf = io.BytesIO()
    images[0].save(
        buf, format="GIF", save_all=True, append_images=images[1:], duration=durations, loop=0
    )
    return buf.getvalue()


def mp4_available() -> bool:
    """True if ``imageio_ffmpeg`` (which brings its own ffmpeg) can be imported."""
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        return False
    return True


def mp4_bytes(frames, frame_interval_s: float, hold_last_s: float = HOLD_LAST_S) -> bytes:
    """H.264 MP4 of ``frames`` at ``1 / frame_interval_s`` frames per second, the last
    frame repeated to last ``hold_last_s``; frames are padded (white) to even sides.
    ``ImportError`` naming the package without ``imageio-ffmpeg``."""
    try:
        import imageio_ffmpeg
    except ImportError as e:
        raise ImportError(f"{MP4_HINT} ({e})") from e
    frames = _frame_list(frames)
    h, w = frames[0].shape[:2]
    h2, w2 = h + h % 2, w + w % 2
    fps = 1.0 / frame_interval_s
    n_hold = max(1, int(round(hold_last_s / frame_interval_s)))
    with tempfile.TemporaryDirectory(prefix="img2dmp-video-") as tmp:
        path = os.path.join(tmp, "video.mp4")
        writer = imageio_ffmpeg.write_frames(
            path,
            (w2, h2),
            fps=fps,
            codec="libx264",
            pix_fmt_out="yuv420p",
            macro_block_size=1,
            quality=7,
            output_params=["-movflags", "+faststart"],
        )
        writer.send(None)
        for i, f in enumerate(frames):
            padded = np.full((h2, w2, 3), 255, dtype=np.uint8)
            padded[:h, :w] = f
            for _ in range(n_hold if i == len(frames) - 1 else 1):
                writer.send(np.ascontiguousarray(padded))
        writer.close()
        with open(path, "rb") as f:
            return f.read()
