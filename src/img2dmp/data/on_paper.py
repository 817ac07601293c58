"""Training characters on generated paper: the augmentation behind the paper's future work.

A training image (MNIST's 28 x 28 ink, say) is put where a camera would see it: enlarged
to a photo's resolution inside a random margin of paper (:func:`img2dmp.data.clutter.random_paper`:
ruled, squared, dotted or plain, tinted, lit unevenly, text from the back, maybe the
table's edge), written in a random pen colour (:func:`~img2dmp.data.clutter.put_ink`),
photographed (:func:`~img2dmp.data.clutter.photo_finish`: blur, noise, JPEG), and read back
the way every image is read (:func:`img2dmp.data.images.prepare_image_found`: the ink
separated from the paper, cropped, framed and resized). Its pen path goes through the same
frame, so image and path stay one sample. What the network learns from is what
prediction will show it: whatever the preparation leaves of the paper.

:func:`paper_copies` makes such copies of a set of samples (``img2dmp prepare
--paper SHARE``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .images import prepare_image_found

#: Photo pixels per image pixel of the enlarged character (drawn uniformly).
SCALE = (2.5, 6.0)
#: Paper around the character on each side, in image sides (drawn per side).
MARGIN = (0.1, 0.8)
#: A copy whose path lies less than this much on the prepared ink is not kept (the
#: preparation lost the character to the clutter: a few in a hundred).
MIN_ON_INK = 0.6


@dataclass
class PaperCopies:
    """The copies :func:`paper_copies` made.

    Attributes
    ----------
    images : float32 [M, S, S]
    paths : float [M, T, d]
        In the pixels of ``images``.
    failed : int
        Copies whose ink the preparation could not find, or whose path is not on it
        (left as they were).
    """

    images: np.ndarray
    paths: np.ndarray
    failed: int


def _enlarged(image: np.ndarray, scale: float, pads) -> np.ndarray:
    """``image [S, S]`` (ink = 1) enlarged ``scale`` times (bilinear) on a canvas with
    ``pads = (top, bottom, left, right)`` image pixels of paper around it."""
    from PIL import Image

    s = image.shape[0]
    top, bottom, left, right = pads
    h = round((s + top + bottom) * scale)
    w = round((s + left + right) * scale)
    big = Image.fromarray(np.asarray(image, np.float32), mode="F").resize(
        (round(s * scale), round(s * scale)), Image.Resampling.BILINEAR
    )
    canvas = np.zeros((h, w), np.float32)
    y0, x0 = round(top * scale), round(left * scale)
    b = np.asarray(big)[: h - y0, : w - x0]
    canvas[y0 : y0 + b.shape[0], x0 : x0 + b.shape[1]] = b
    return np.clip(canvas, 0.0, 1.0), y0, x0


def on_paper_copy(rng, image, path, *, margin: float, stroke_width_px: float | None):
    """One sample ``image [S, S]``, ``path [T, d]`` (its pixels) photographed on
    generated paper and read back (module docstring): the prepared image and the path in
    its pixels, or None when the preparation finds no ink or the path is not on what it
    found (``MIN_ON_INK``)."""
    from ..metrics import on_ink_share
    from .clutter import photo_finish, put_ink, random_paper, random_pen_colour

    s = image.shape[0]
    scale = float(rng.uniform(*SCALE))
    pads = [float(v) * s for v in rng.uniform(*MARGIN, size=4)]
    ink, y0, x0 = _enlarged(image, scale, pads)
    paper = random_paper(rng, ink.shape)
    rgb = put_ink(paper.rgb, ink, random_pen_colour(rng), opacity=float(rng.uniform(0.85, 1.0)))
    photo = photo_finish(rng, rgb)
    try:
        out, frame, _ = prepare_image_found(photo, image.shape, margin=margin,
                                            stroke_width_px=stroke_width_px)  # fmt: skip
    except ValueError as e:  # nothing left of the ink (a faint pen in deep shadow)
        if "no ink" in str(e) or "no pixel" in str(e):
            return None
        raise
    xy = np.array(path, dtype=np.float64)
    k = round(s * scale) / s  # the enlargement exactly (whole pixels)
    # pixel j spans [j, j + 1], so the centre of image pixel j is at (j + 0.5) k - 0.5
    xy[:, 0] = (xy[:, 0] + 0.5) * k - 0.5 + x0
    xy[:, 1] = (xy[:, 1] + 0.5) * k - 0.5 + y0
    moved = frame.to_model(xy)
    if on_ink_share(out[None], moved[None])[0] < MIN_ON_INK:
        return None  # the preparation kept something else (a shadow, a rule), not the ink
    return out, moved


#: Samples per job of :func:`paper_copies` (each job one random stream).
CHUNK = 256


def _copy_chunk(job):
    seed_seq, images, paths, margin, width = job
    rng = np.random.default_rng(seed_seq)
    out_images, out_paths, failed = images.copy(), paths.copy(), 0
    for i in range(len(images)):
        got = on_paper_copy(rng, images[i], paths[i], margin=margin, stroke_width_px=width)
        if got is None:
            failed += 1
            continue
        out_images[i], out_paths[i] = got
    return out_images, out_paths, failed


def paper_copies(rng, images, paths, *, margin: float, stroke_width_px: float | None,
                 workers: int = 1, progress: bool = False) -> PaperCopies:  # fmt: skip
    """Every sample ``images [M, S, S]``, ``paths [M, T, d]`` on generated paper
    (:func:`on_paper_copy`); a copy whose ink the preparation cannot find stays as it was
    (counted in ``failed``). Chunks of ``CHUNK`` samples, each with its own stream drawn
    from ``rng``, run in ``workers`` processes: the result does not depend on ``workers``."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from .._progress import bar

    images = np.asarray(images, dtype=np.float32)
    paths = np.asarray(paths, dtype=np.float64)
    n_chunks = -(-len(images) // CHUNK)
    seeds = np.random.SeedSequence(int(rng.integers(2**63))).spawn(n_chunks)
    jobs = [(seeds[k], images[k * CHUNK : (k + 1) * CHUNK], paths[k * CHUNK : (k + 1) * CHUNK],
             margin, stroke_width_px) for k in range(n_chunks)]  # fmt: skip
    pool = None
    if workers > 1 and n_chunks > 1:
        pool = ProcessPoolExecutor(min(workers, n_chunks), multiprocessing.get_context("spawn"))
    parts = []
    try:
        results = pool.map(_copy_chunk, jobs) if pool else map(_copy_chunk, jobs)
        with bar(total=len(images), desc="on paper", unit="image", enabled=progress) as b:
            for part in results:
                parts.append(part)
                b.update(len(part[0]))
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    if not parts:
        return PaperCopies(images.copy(), paths.copy(), 0)
    return PaperCopies(np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                       sum(p[2] for p in parts))  # fmt: skip


__all__ = ["CHUNK", "MARGIN", "SCALE", "PaperCopies", "on_paper_copy", "paper_copies"]
