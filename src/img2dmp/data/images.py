"""Bringing an image of a handwritten digit to the network's input (NumPy, SciPy, PIL).

The training images frame the ink in a fixed way and draw it with a typical pen width;
an arbitrary photo or scan is brought to the same framing and width before the network
sees it.

- :func:`prepare_image` - an arbitrary PNG/JPEG (any size, dark ink on light paper or
  light on dark) or grey-level array to the model's input, the way the training images
  were made.
- :func:`ink_margin`, :func:`typical_stroke_width` - the framing and pen width of a set of
  prepared (training) images, stored with a model so :func:`prepare_image` can match them.
- :func:`stroke_width` - the pen width of one image.

Work and memory are linear in the image's size: a photo of more than
``MAX_WORK_PIXELS`` is reduced (area average) as it is read, and the ink's crop is
reduced to ``WORK_PER_OUTPUT_PX`` working pixels per output pixel before its pen width
is matched, so a 24-megapixel photo takes about a second and ~0.2 GB.

No torch here: training, prediction and data preparation all use this module.
"""

from __future__ import annotations

import math
import numbers
import os
import warnings
from pathlib import Path

import numpy as np

# How a prepared image frames the ink: the ink's bounding box, padded to a square, fills
# the image except for this share of the side on each border (see prepare_image). A model
# stores the median framing of its training images (ink_margin); this is the fallback,
# that of the synthetic digits at their default size.
DEFAULT_MARGIN = 0.175
# A pixel counts as ink for the bounding box when it is above this share of the range.
INK_THRESHOLD = 0.2
# Image preparation works on at most this many pixels: a larger image is reduced by an
# integer factor (area average) right after it is read.
MAX_WORK_PIXELS = 4_000_000
# The ink's crop is reduced to about this many pixels per output pixel (per side) before
# the pen width is matched and the image framed: the disc of a grey dilation is then at
# most a few pixels wide, whatever the photo's resolution.
WORK_PER_OUTPUT_PX = 4
# Sides of a prepared image, pixels.
OUTPUT_SIDE_PX = (2, 1024)
# stroke_width enlarges an image to at most this many pixels.
_MAX_UPSAMPLED_PIXELS = 4_000_000
# A grey dilation or erosion compares at most about this many pixel pairs (~0.5 s); a
# wider disc is applied at a coarser resolution.
_MAX_MORPHOLOGY_OPS = 2e8


def ink_margin(images: np.ndarray) -> float:
    """Median share of the side left empty around the ink (its bounding box's longer side)
    in prepared images ``[M, H, W]``; what :func:`prepare_image` reproduces."""
    margins = []
    for a in np.asarray(images):
        rows, cols = np.nonzero(a > INK_THRESHOLD)
        if rows.size == 0:
            continue
        side = max(
            (rows.max() - rows.min() + 1) / a.shape[0], (cols.max() - cols.min() + 1) / a.shape[1]
        )
        margins.append((1.0 - side) / 2.0)
    return float(np.clip(np.median(margins), 0.0, 0.45)) if margins else DEFAULT_MARGIN


def stroke_width(image: np.ndarray, upsample: int = 4) -> float:
    """Estimated pen width in pixels of the ink in a grey image ``[H, W]`` (ink high).

    The image is scaled to [0, 1], enlarged ``upsample`` times (bilinear) so that thin
    strokes span several pixels, and thresholded at half ink; for a stroke of width W the
    distance of its pixels to the background runs evenly from 0 to W / 2, so W is about
    four times their mean. Returns 0 for an image without ink.
    """
    from PIL import Image
    from scipy.ndimage import distance_transform_edt

    a = np.asarray(image, dtype=np.float32)
    top = float(a.max()) if a.size else 0.0
    if top <= 0:
        return 0.0
    # Enlarging a big image would only cost memory: its strokes span pixels already.
    upsample = max(1, min(int(upsample), math.isqrt(_MAX_UPSAMPLED_PIXELS // a.size)))
    big = Image.fromarray(a / top, mode="F").resize(
        (a.shape[1] * upsample, a.shape[0] * upsample), Image.Resampling.BILINEAR
    )
    mask = np.asarray(big) > 0.5
    if not mask.any():
        return 0.0
    return float(4.0 * distance_transform_edt(mask)[mask].mean() / upsample)


def typical_stroke_width(images: np.ndarray, limit: int = 500) -> float:
    """Median :func:`stroke_width` over (up to ``limit`` of) prepared images ``[M, H, W]``."""
    widths = [w for w in (stroke_width(a) for a in np.asarray(images)[:limit]) if w > 0]
    return float(np.median(widths)) if widths else 0.0


def _reduce(a: np.ndarray, factor: int, how: str = "mean") -> np.ndarray:
    """``a [H, W]`` reduced ``factor`` times on each side: the mean of every block of
    ``factor x factor`` pixels (area average; blocks cut by the border are averaged over
    their pixels) or, with ``how="max"``, its maximum (blocks padded with 0)."""
    from PIL import Image

    if factor <= 1:
        return a
    if how == "mean":
        return np.asarray(Image.fromarray(a.astype(np.float32), mode="F").reduce(factor), float)
    h, w = (-(-n // factor) * factor for n in a.shape)
    padded = np.zeros((h, w), dtype=a.dtype)
    padded[: a.shape[0], : a.shape[1]] = a
    return padded.reshape(h // factor, factor, w // factor, factor).max(axis=(1, 3))


def _work_factor(crop: np.ndarray, margin: float, out_side: int) -> int:
    """The integer reduction that leaves about ``WORK_PER_OUTPUT_PX`` crop pixels per
    output pixel (1: the crop is small enough)."""
    side = max(crop.shape) / (1.0 - 2.0 * margin)
    return max(1, math.ceil(side / (WORK_PER_OUTPUT_PX * out_side)))


def _match_stroke_width(
    crop: np.ndarray, scale: float, target_px: float, factor: int = 1
) -> np.ndarray:
    """Thicken or thin the ink of ``crop`` so that it is ``target_px`` wide after resizing.

    ``scale`` is output pixels per crop pixel. The crop is first reduced ``factor`` times
    (:func:`_work_factor`): by area average, or, when the strokes are to be thickened,
    by the maximum of each block, so that a hairline keeps its ink (the dilation would
    spread it anyway). Grey-level dilation (erosion) with a disc then widens (narrows)
    every stroke by twice the disc's radius and keeps its ink profile. Returns the crop
    at the reduced resolution.
    """
    from scipy.ndimage import grey_dilation, grey_erosion

    work, scale = _reduce(crop, factor), scale * factor
    # A crop is the ink's bounding box: a border of background lets the width measure see
    # the strokes' edges (a crisp bar filling its box would otherwise measure as huge).
    upsample = 1 if scale < 0.5 and factor == 1 else 4
    width_out = stroke_width(np.pad(work, 1), upsample=upsample) * scale
    if width_out <= 0 or abs(width_out - target_px) < 0.25:
        return work
    if width_out < target_px and factor > 1:
        work = _reduce(crop, factor, "max")
        width_out = stroke_width(np.pad(work, 1), upsample=upsample) * scale
    radius = abs(target_px - width_out) / 2.0 / scale  # in work pixels
    if width_out > target_px:  # never erode a stroke away: keep at least half its width
        radius = min(radius, width_out / scale / 4.0)
    ops = (work.shape[0] + 2 * radius) * (work.shape[1] + 2 * radius) * math.pi * radius**2
    coarser = math.ceil((ops / _MAX_MORPHOLOGY_OPS) ** 0.25)
    if coarser > 1:  # work and disc both shrink with its square
        work = _reduce(work, coarser, "max" if width_out < target_px else "mean")
        radius /= coarser
    r = int(np.ceil(radius))
    if r < 1:
        return work
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    disc = (xx**2 + yy**2) <= radius**2 + 1e-9
    op = grey_dilation if width_out < target_px else grey_erosion
    return op(np.pad(work, r), footprint=disc)


class ImageTooLargeError(ValueError):
    """An image file with more pixels than PIL's decompression-bomb limit."""


def _open_reduced(im, path: Path):
    """A loaded PIL image of at most ``MAX_WORK_PIXELS`` (JPEG: decoded at a reduced
    scale), and the further integer reduction it needs; ``ValueError`` for an image
    beyond PIL's decompression-bomb limit."""
    from PIL import Image

    w, h = im.size
    limit = Image.MAX_IMAGE_PIXELS
    if limit is not None and w * h > limit:
        raise ImageTooLargeError(
            f"image file {path} has {w} x {h} = {w * h} pixels, more than the {limit} "
            "an image may have (PIL.Image.MAX_IMAGE_PIXELS)"
        )
    factor = math.ceil(math.sqrt(w * h / MAX_WORK_PIXELS))
    if factor > 1:
        im.draft(None, (max(1, w // factor), max(1, h // factor)))  # JPEG only
    im.load()
    w, h = im.size
    return im, max(1, math.ceil(math.sqrt(w * h / MAX_WORK_PIXELS)))


def _decode(path: Path) -> np.ndarray:
    """Grey levels in [0, 1] of an image file; transparency is composited on white."""
    from PIL import Image, UnidentifiedImageError

    if not path.is_file():
        raise FileNotFoundError(f"image file {path} does not exist")
    try:
        with warnings.catch_warnings():  # the size is checked below, with a clear error
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(path)
        with im:
            im, factor = _open_reduced(im, path)
            if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
                rgba = im.convert("RGBA")
                bg = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
                im = Image.alpha_composite(bg, rgba)
            if factor > 1:  # 8-bit images reduce as 8 bits: a quarter of the memory
                wide = im.mode.startswith("I") or im.mode == "F"  # more than 8 bits
                im = im.convert("F" if wide else "L")
                im = im.reduce(factor)
            grey = np.asarray(im.convert("F"), dtype=np.float64)
    except ImageTooLargeError:
        raise
    except Image.DecompressionBombError as e:
        raise ImageTooLargeError(f"image file {path} is refused as too large: {e}") from e
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as e:
        raise ValueError(f"cannot decode image file {path}: {e}") from e
    if grey.ndim != 2 or min(grey.shape) < 2:
        raise ValueError(f"image file {path} has unusable size {grey.shape}")
    top = grey.max()
    return grey / (255.0 if top > 1.0 else 1.0)


def _grey_levels(source, name: str | None) -> tuple[np.ndarray, str]:
    """Grey levels ``[H, W]`` in [0, 1] of a file or array, and a label for messages."""
    if isinstance(source, (str, os.PathLike)):
        return _decode(Path(source)), str(source)
    label = name or "image array"
    grey = np.asarray(source)
    if grey.dtype.kind not in "buif":
        raise ValueError(f"{label} must hold numbers, got dtype {grey.dtype}")
    if grey.ndim != 2 or min(grey.shape) < 2:
        raise ValueError(f"{label} must be a 2-D grey-level array, got shape {grey.shape}")
    if not np.isfinite(grey).all():
        raise ValueError(f"{label} contains NaN or inf")
    factor = math.ceil(math.sqrt(grey.size / MAX_WORK_PIXELS))
    grey = _reduce(grey, factor) if factor > 1 else grey.astype(np.float64)
    if grey.max() > 1.0:
        grey = grey / 255.0
    return grey, label


def _ink_levels(grey: np.ndarray, label: str) -> np.ndarray:
    """Ink ``[H, W]`` from grey levels: light ink on zero background, darkest ink = 1.

    The polarity comes from the border: if the median of the outer ring (5 % of the
    shorter side) is brighter than the median of the whole image, or than mid grey, the
    ink is dark on light paper and the image is inverted. The background level (the
    ring's median) is subtracted and the ink scaled to 1.
    """
    ring = max(1, round(0.05 * min(grey.shape)))
    border = np.concatenate(
        [grey[:ring].ravel(), grey[-ring:].ravel(), grey[:, :ring].ravel(), grey[:, -ring:].ravel()]
    )
    if np.median(border) > np.median(grey) or np.median(border) > 0.5:
        grey = 1.0 - grey  # dark ink on light paper
        border = 1.0 - border
    ink = grey - np.median(border)
    top = ink.max()
    if top < 0.05:
        raise ValueError(f"{label} shows no ink (contrast {top:.3f} against the background)")
    return np.clip(ink / top, 0.0, 1.0)


def _crop_to_ink(ink: np.ndarray, label: str = "the image") -> np.ndarray:
    """The bounding box of the pixels above ``INK_THRESHOLD``."""
    rows, cols = np.nonzero(ink > INK_THRESHOLD)
    if rows.size == 0:
        raise ValueError(f"{label} has no pixel darker than half the ink's contrast")
    return ink[rows.min() : rows.max() + 1, cols.min() : cols.max() + 1]


def _frame(crop: np.ndarray, image_size: tuple[int, int], margin: float) -> np.ndarray:
    """The crop centred on a square with ``margin`` of its side free on every border,
    resized to ``image_size`` and scaled so the darkest ink is 1; float32 ``[H, W]``.

    Shrinking averages over boxes (anti-aliased, as the training strokes are); enlarging
    interpolates bilinearly.
    """
    from PIL import Image

    h_out, w_out = image_size
    inner = max(crop.shape) / (1.0 - 2.0 * margin)
    total = int(np.ceil(inner))
    canvas = np.zeros((total, total))
    top_off = (total - crop.shape[0]) // 2
    left_off = (total - crop.shape[1]) // 2
    canvas[top_off : top_off + crop.shape[0], left_off : left_off + crop.shape[1]] = crop
    im = Image.fromarray(canvas.astype(np.float32), mode="F")
    out = np.asarray(
        im.resize(
            (w_out, h_out),
            Image.Resampling.BOX if total >= max(h_out, w_out) else Image.Resampling.BILINEAR,
        ),
        dtype=np.float64,
    )
    out = np.clip(out / max(out.max(), 1e-12), 0.0, 1.0)
    return out.astype(np.float32)


def prepare_image(
    source,
    image_size=(40, 40),
    *,
    margin: float = DEFAULT_MARGIN,
    stroke_width_px: float | None = None,
    name: str | None = None,
) -> np.ndarray:
    """Bring an image of one handwritten digit to the network's input.

    Steps: grey levels in [0, 1]; polarity from the border (if the median of the outer
    ring of pixels is brighter than the median of the whole image, the ink is dark on
    light paper and the image is inverted); the background level (border median) is
    subtracted and the ink scaled to 1; crop to the bounding box of pixels above
    ``INK_THRESHOLD``; pad to a square around the box's centre; add ``margin`` of the
    side on every border; optionally thicken or thin the strokes to the training images'
    pen width (a thin pen photographed at high resolution would otherwise shrink to faint
    hairlines); resize with area averaging (anti-aliased, as the training strokes are);
    scale so the darkest ink is 1.

    Parameters
    ----------
    source : path or array [H, W]
        PNG/JPEG file (any size, RGB, grey or with transparency) or a grey-level array.
    image_size : (H, W)
        The model's input size.
    margin : float
        Share of the side left empty on each border, in [0, 0.45].
    stroke_width_px : float, optional
        Pen width, in output pixels, to bring the strokes to (a model's
        ``stroke_width_px``, see :func:`typical_stroke_width`); None keeps the width.
    name : str, optional
        Used in error messages for arrays.

    Returns
    -------
    ndarray float32 [H, W]
        Ink = 1, background = 0.
    """
    h_out, w_out = _output_size(image_size)
    if not (isinstance(margin, numbers.Real) and 0 <= margin <= 0.45):
        raise ValueError(f"margin must be in [0, 0.45], got {margin!r}")
    widest = max(h_out, w_out) / 4.0
    if stroke_width_px is not None and not (
        isinstance(stroke_width_px, numbers.Real)
        and np.isfinite(stroke_width_px)
        and 0 < stroke_width_px <= widest
    ):
        raise ValueError(
            f"stroke_width_px must be a number in (0, {widest:g}] (a quarter of the "
            f"image's side), got {stroke_width_px!r}"
        )
    grey, label = _grey_levels(source, name)
    crop = _crop_to_ink(_ink_levels(grey, label), label)
    factor = _work_factor(crop, margin, max(h_out, w_out))
    if stroke_width_px is not None:
        # The pen width is matched at the output's scale, which the framing fixes.
        side = max(crop.shape) / (1.0 - 2.0 * margin)
        scale = max(h_out, w_out) / side
        crop = _match_stroke_width(crop, scale, float(stroke_width_px), factor)
        crop = _crop_to_ink(crop, label)  # the widened ink may reach past the old box
    else:
        crop = _reduce(crop, factor)
    return _frame(crop, (h_out, w_out), margin)


def _output_size(image_size) -> tuple[int, int]:
    """``(H, W)`` of a prepared image, each in ``OUTPUT_SIDE_PX``, else ``ValueError``."""
    lo, hi = OUTPUT_SIDE_PX
    try:
        h, w = image_size
        ok = all(
            isinstance(v, numbers.Real)
            and not isinstance(v, bool)
            and lo <= v <= hi
            and int(v) == v
            for v in (h, w)
        )
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(
            f"image_size must be two integers (H, W) in [{lo}, {hi}], got {image_size!r}"
        )
    return int(h), int(w)


__all__ = [
    "DEFAULT_MARGIN",
    "INK_THRESHOLD",
    "ImageTooLargeError",
    "MAX_WORK_PIXELS",
    "OUTPUT_SIDE_PX",
    "WORK_PER_OUTPUT_PX",
    "ink_margin",
    "prepare_image",
    "stroke_width",
    "typical_stroke_width",
]
