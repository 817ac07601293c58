"""Bringing an image of a handwritten digit to the network's input (NumPy, SciPy, PIL).

The training images frame the ink in a fixed way and draw it with a typical pen width;
an arbitrary photo or scan is brought to the same framing and width before the network
sees it.

- :func:`prepare_image` - an arbitrary PNG/JPEG (any size, dark ink on light paper or
  light on dark), PIL image or array to the model's input, the way the training images
  were made; :func:`prepare_image_framed` - the same and the :class:`ImageFrame` that
  maps positions between the user's image and the model's input.
- :func:`ink_margin`, :func:`typical_stroke_width` - the framing and pen width of a set of
  prepared (training) images, stored with a model so :func:`prepare_image` can match them.
- :func:`stroke_width` - the pen width of one image.
- :func:`ink_view` - a whole image as ink levels, small enough for a picture.
- :func:`upright`, :func:`shown_size` - an image file as viewers show it: phones store a
  portrait photo as a landscape raster and an EXIF tag that says how to turn it; every
  reader here turns it, so the user's image frame is the one they see.

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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._files import check_readable
from .._lazy import is_tensor

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
# The EXIF tag of the orientation (1 = upright, 2-8 = mirrored and/or turned), and the
# values that swap the raster's width and height.
_ORIENTATION_TAG = 0x0112
_TURNED = (5, 6, 7, 8)
# Sides of a prepared image, pixels.
OUTPUT_SIDE_PX = (2, 1024)
# stroke_width enlarges an image to at most this many pixels.
_MAX_UPSAMPLED_PIXELS = 4_000_000
# A grey image of more than 8 bits is converted to float and reduced about this many of
# its pixels at a time (_reduced_wide).
_STRIP_PIXELS = 1 << 20
# A grey dilation or erosion compares at most about this many pixel pairs (~0.5 s); a
# wider disc is applied at a coarser resolution.
_MAX_MORPHOLOGY_OPS = 2e8


def _size_pair(what: str, value) -> tuple[int, int]:
    try:
        h, w = value
        ok = all(
            isinstance(v, numbers.Integral) and not isinstance(v, bool) and v > 0 for v in (h, w)
        )
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"{what} must be (H, W), two positive integers, got {value!r}")
    return int(h), int(w)


#: Largest entry of an image frame's affine map (a scale of 1e6 maps a pixel to a
#: millionth of one; 1e308 overflowed its determinant).
MAX_FRAME_ENTRY = 1e9


class ImageFrame:
    """Where the model's input sits in the user's own image: an affine map of positions.

    Both frames follow docs/CONTRACTS.md: ``(x, y)`` = (column, row) in pixels, the centre
    of pixel ``[i, j]`` at ``(x=j, y=i)``. The **image frame** is the user's image as
    given (the file's own pixels, before any reduction); the **model frame** is the
    prepared image the network reads (``model_size``, e.g. 40 x 40).

    Attributes
    ----------
    image_to_model : float64 [2, 3]
        ``[x_m, y_m] = A @ [x, y] + b`` with ``A = image_to_model[:, :2]``,
        ``b = image_to_model[:, 2]`` (the convention of :mod:`img2dmp.data.affine`).
        :func:`prepare_image_framed` makes an axis-aligned scaling and shift (``A``
        diagonal and positive); any invertible ``A`` is accepted.
    model_to_image : float64 [2, 3]
        The inverse map.
    image_size, model_size : (H, W)
        The user's image and the model's input, pixels.
    """

    def __init__(self, image_to_model, image_size, model_size):
        m = np.array(image_to_model, dtype=np.float64)
        if m.shape != (2, 3) or not np.isfinite(m).all() or np.abs(m).max() > MAX_FRAME_ENTRY:
            got = f"shape {list(m.shape)}" if m.shape != (2, 3) else (
                "NaN or inf" if not np.isfinite(m).all()
                else f"entries up to {float(np.abs(m).max()):g}")  # fmt: skip
            raise ValueError(
                f"image_to_model must be a 2 x 3 matrix of finite numbers of at most "
                f"{MAX_FRAME_ENTRY:g}, got {got}"
            )
        det = float(np.linalg.det(m[:, :2]))
        if not abs(det) > 1e-12 * max(1.0, float(np.abs(m[:, :2]).max()) ** 2):
            raise ValueError(f"image_to_model is not invertible: det(A) = {det!r}")
        inv = np.empty((2, 3))
        inv[:, :2] = np.linalg.inv(m[:, :2])
        inv[:, 2] = -inv[:, :2] @ m[:, 2]
        m.setflags(write=False)
        inv.setflags(write=False)
        self.image_to_model, self.model_to_image = m, inv
        self.image_size = _size_pair("image_size", image_size)
        self.model_size = _size_pair("model_size", model_size)

    @staticmethod
    def _apply(matrix: np.ndarray, points) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64)
        if p.ndim < 1 or p.shape[-1] < 2:
            raise ValueError(f"points must have shape [..., d >= 2] (x, y first), got {p.shape}")
        out = p.copy()
        out[..., :2] = p[..., :2] @ matrix[:, :2].T + matrix[:, 2]
        return out

    def to_model(self, points) -> np.ndarray:
        """Points ``[..., d]`` (x, y first; further columns such as the pen pass through)
        from the user's image to the model's input."""
        return self._apply(self.image_to_model, points)

    def to_image(self, points) -> np.ndarray:
        """Points ``[..., d]`` from the model's input to the user's image."""
        return self._apply(self.model_to_image, points)

    def to_dict(self) -> dict:
        """JSON-ready: both matrices and both sizes."""
        return {
            "image_size": list(self.image_size),
            "model_size": list(self.model_size),
            "image_to_model": self.image_to_model.tolist(),
            "model_to_image": self.model_to_image.tolist(),
        }

    def __repr__(self) -> str:
        a = self.image_to_model

        def row(r) -> str:  # "0.5 x + 0 y - 3": each term's sign once
            return f"{r[0]:.6g} x {_signed(r[1])} y {_signed(r[2])}"

        return (
            f"ImageFrame(image {self.image_size[0]} x {self.image_size[1]} -> model "
            f"{self.model_size[0]} x {self.model_size[1]} (H x W): x_m = {row(a[0])}, "
            f"y_m = {row(a[1])})"
        )


def _signed(v: float) -> str:
    """``"+ 3"`` or ``"- 3"``: a term of a sum as one writes it."""
    return f"- {-v:.6g}" if v < 0 else f"+ {v:.6g}"


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
    rows = factor * max(1, _STRIP_PIXELS // (a.shape[1] * factor))
    if how == "mean" and a.shape[0] > rows:  # a strip of whole blocks at a time: no
        # full-size float32 copy of a large array (the same levels)
        return np.concatenate([_reduce(a[top : top + rows], factor)
                               for top in range(0, a.shape[0], rows)])  # fmt: skip
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
    """Thicken or thin the ink of ``crop`` so that it is ``target_px`` wide after resizing
    (:func:`_match_stroke_width_framed` without the change of frame)."""
    return _match_stroke_width_framed(crop, scale, target_px, factor)[0]


def _match_stroke_width_framed(
    crop: np.ndarray, scale: float, target_px: float, factor: int = 1
) -> tuple[np.ndarray, int, int]:
    """Thicken or thin the ink of ``crop`` so that it is ``target_px`` wide after resizing.

    ``scale`` is output pixels per crop pixel. The crop is first reduced ``factor`` times
    (:func:`_work_factor`): by area average, or, when the strokes are to be thickened,
    by the maximum of each block, so that a hairline keeps its ink (the dilation would
    spread it anyway). Grey-level dilation (erosion) with a disc then widens (narrows)
    every stroke by twice the disc's radius and keeps its ink profile. Returns the crop
    at the reduced resolution, the reduction (crop pixels per returned pixel) and the
    border added on every side (returned pixels): a position ``u`` of the crop (pixel
    edges) is at ``u / reduction + border`` in the result.
    """
    from scipy.ndimage import grey_dilation, grey_erosion

    work, scale = _reduce(crop, factor), scale * factor
    # A crop is the ink's bounding box: a border of background lets the width measure see
    # the strokes' edges (a crisp bar filling its box would otherwise measure as huge).
    upsample = 1 if scale < 0.5 and factor == 1 else 4
    width_out = stroke_width(np.pad(work, 1), upsample=upsample) * scale
    if width_out <= 0 or abs(width_out - target_px) < 0.25:
        return work, factor, 0
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
    reduction = factor * max(coarser, 1)
    r = int(np.ceil(radius))
    if r < 1:
        return work, reduction, 0
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    disc = (xx**2 + yy**2) <= radius**2 + 1e-9
    op = grey_dilation if width_out < target_px else grey_erosion
    return op(np.pad(work, r), footprint=disc), reduction, r


class ImageTooLargeError(ValueError):
    """An image file with more pixels than PIL's decompression-bomb limit."""


def _open_reduced(im, label: str, max_pixels: int = MAX_WORK_PIXELS, pixels: int | None = None):
    """A loaded PIL image of at most ``max_pixels`` (JPEG: decoded at a reduced
    scale), the further integer reduction it needs and the scale the decoder applied
    (1 unless a JPEG was decoded at 1/2, 1/4 or 1/8); ``ValueError`` for an image beyond
    PIL's decompression-bomb limit. ``pixels``: the part of the image to be read (a
    region's), which the decoder's scale is chosen for (default: all of it)."""
    from PIL import Image

    w, h = im.size
    limit = Image.MAX_IMAGE_PIXELS
    if limit is not None and w * h > limit:
        raise ImageTooLargeError(
            f"{label} has {w} x {h} = {w * h} pixels, more than the {limit} "
            "an image may have (PIL.Image.MAX_IMAGE_PIXELS)"
        )
    factor = math.ceil(math.sqrt((w * h if pixels is None else pixels) / max_pixels))
    draft = None
    if factor > 1:
        draft = im.draft(None, (max(1, w // factor), max(1, h // factor)))  # JPEG only
    im.load()
    # The decoder's scale, exactly: PIL's box is the image in the drafted pixels.
    scale = w / draft[1][2] if draft else 1.0
    w, h = im.size
    return im, max(1, math.ceil(math.sqrt(w * h / max_pixels))), scale


def full_scale(top: float) -> float:
    """The grey level of white for an image whose brightest pixel is ``top``.

    1 for levels in [0, 1]; else the largest value of the fewest bits (at least 8) that
    hold ``top``: 255 for 8-bit images, 4095 for a 12-bit scan stored in 16 bits,
    65535 for a full 16-bit one. Files do not say how many of their 16 bits a scanner
    used, and scaling a 12-bit scan by 65535 would leave its paper at 6 % grey.
    """
    if top <= 1.0:
        return 1.0
    return float(2 ** max(8, math.ceil(math.log2(float(top) + 1.0))) - 1)


def _orientation(im) -> int:
    """The EXIF orientation of a PIL image, 1 (upright) when it has none or a damaged one
    (image viewers then show the raster as it is, and so does img2dmp)."""
    try:
        value = im.getexif().get(_ORIENTATION_TAG, 1)
    except Exception:  # noqa: BLE001 - any defect of the EXIF block: no orientation
        return 1
    return value if isinstance(value, int) and 1 <= value <= 8 else 1


def upright(im):
    """A PIL image as image viewers and browsers show it: mirrored and turned as its EXIF
    orientation tag says (a phone stores a portrait photo as a landscape raster and a
    tag), without the tag; ``im`` itself when it is already upright."""
    if _orientation(im) == 1:
        return im
    from PIL import ImageOps

    return ImageOps.exif_transpose(im)


def shown_size(im) -> tuple[int, int]:
    """``(H, W)`` of a PIL image as :func:`upright` shows it, from its header only."""
    w, h = im.size
    return (w, h) if _orientation(im) in _TURNED else (h, w)


def _pil_levels(im, label: str, max_pixels: int = MAX_WORK_PIXELS, box=None,
                white: float | None = None):  # fmt: skip
    """Levels in [0, 1] of a PIL image: RGB ``float32 [h, w, 3]`` for a colour image,
    grey ``[h, w]`` otherwise; upright (:func:`upright`), transparency composited on
    white, reduced to at most ``max_pixels``; the reduction (its pixels per level
    pixel), the corner ``(x, y)`` of the levels in its pixels (pixel edges) and the grey
    level of white the levels were divided by (:func:`full_scale`).

    ``box``: only the region ``(x0, y0, x1, y1)`` (half-open, the upright image's pixels;
    JPEG: widened to whole pixels of the decoder's scale) is read, reduced as its own
    size needs; ``white``: divide grey levels by it (the whole image's, as a first
    reading found it) instead of the region's own :func:`full_scale`."""
    from PIL import Image

    pixels = None if box is None else (box[2] - box[0]) * (box[3] - box[1])
    im, factor, scale = _open_reduced(im, label, max_pixels, pixels)
    im = upright(im)
    origin = (0.0, 0.0)
    if box is not None:  # in the decoded pixels (a JPEG's: 1 / scale of the file's)
        x0, y0 = math.floor(box[0] / scale), math.floor(box[1] / scale)
        x1 = min(im.width, math.ceil(box[2] / scale))
        y1 = min(im.height, math.ceil(box[3] / scale))
        im, origin = im.crop((x0, y0, x1, y1)), (x0 * scale, y0 * scale)
        factor = max(1, math.ceil(math.sqrt(im.width * im.height / max_pixels)))
    if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
        rgba = im.convert("RGBA")
        bg = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        im = Image.alpha_composite(bg, rgba).convert("RGB" if im.mode != "LA" else "L")
    wide = im.mode.startswith("I") or im.mode == "F"  # more than 8 bits: grey
    colour = not wide and im.mode not in ("1", "L")
    if colour:
        im = im.convert("RGB")
    if factor > 1 and not wide:  # 8-bit images reduce as 8 bits: a quarter of the memory
        im = (im if colour else im.convert("L")).reduce(factor)
    if colour:
        levels, white = np.asarray(im, dtype=np.float32) / np.float32(255.0), 255.0
    else:
        if factor > 1 and wide:  # 8-bit grey was reduced above, as 8 bits
            levels = _reduced_wide(im, factor)
        else:
            levels = np.array(im.convert("F"), dtype=np.float32)  # a copy: divided in place
        if not np.isfinite(levels).all():  # a floating-point ("F") image may hold NaN
            raise ValueError(f"{label} holds NaN or infinite grey levels")
        if white is None:
            white = full_scale(float(levels.max()) if levels.size else 0.0)
        levels /= np.float32(white)
    if min(levels.shape[:2]) < 2:
        h, w = levels.shape[:2]
        raise ValueError(f"{label} is {w} x {h} pixels (width x height): an image needs at "
                         "least 2 x 2")  # fmt: skip
    return levels, scale * factor, origin, float(white)


def _reduced_wide(im, factor: int) -> np.ndarray:
    """A grey image of more than 8 bits (PIL modes "I;16", "I", "F") as float32 levels
    ``[h, w]`` reduced ``factor`` times (area average), converted and reduced a strip of
    whole blocks at a time: the same levels as converting it whole, without a full-size
    float copy (140 MB for a 600-dpi A4 scan in 16 bits)."""
    w, h = im.size
    rows = factor * max(1, _STRIP_PIXELS // (w * factor))
    out = np.empty((-(-h // factor), -(-w // factor)), np.float32)
    for top in range(0, h, rows):
        strip = im.crop((0, top, w, min(h, top + rows))).convert("F").reduce(factor)
        out[top // factor : top // factor + strip.height] = np.asarray(strip, np.float32)
    return out


def _decode_framed(path: Path, max_pixels: int = MAX_WORK_PIXELS, box=None,
                   white: float | None = None):  # fmt: skip
    """Levels in [0, 1] of an image file (:func:`_pil_levels`, ``box`` and ``white`` as
    there), the reduction (file pixels per level pixel), the file's own size ``(H, W)``,
    the levels' corner ``(x, y)`` in the file's pixels and the level of white."""
    from PIL import Image, UnidentifiedImageError

    check_readable(path, "image file")  # missing, a directory, unreadable: said as such
    try:
        with warnings.catch_warnings():  # the size is checked below, with a clear error
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(path)
        with im:
            size = shown_size(im)
            levels, reduction, origin, white = _pil_levels(
                im, f"image file {path}", max_pixels, _clipped(box, size), white
            )
    except ImageTooLargeError:
        raise
    except Image.DecompressionBombError as e:
        raise ImageTooLargeError(f"image file {path} is refused as too large: {e}") from e
    except (UnidentifiedImageError, OSError, SyntaxError) as e:
        raise ValueError(f"cannot decode image file {path}: {e}") from e
    except ValueError as e:
        if str(e).startswith(f"image file {path}"):
            raise
        raise ValueError(f"cannot decode image file {path}: {e}") from e
    return levels, reduction, size, origin, white


def _clipped(box, size) -> tuple[int, int, int, int] | None:
    """A region ``(x0, y0, x1, y1)`` in whole pixels within an image of ``size`` (H, W);
    None for None."""
    if box is None:
        return None
    h, w = size
    x0, y0 = max(0, math.floor(box[0])), max(0, math.floor(box[1]))
    x1, y1 = min(w, math.ceil(box[2])), min(h, math.ceil(box[3]))
    if x1 - x0 < 2 or y1 - y0 < 2:
        raise ValueError(f"region {tuple(box)} holds less than 2 x 2 pixels of an image of "
                         f"{w} x {h}")  # fmt: skip
    return x0, y0, x1, y1


def grey_of(levels: np.ndarray) -> np.ndarray:
    """Grey levels ``[h, w]`` (float64) of levels ``[h, w]`` or RGB ``[h, w, 3]``: the
    ITU-R 601-2 luma, as PIL's ``"L"``."""
    if levels.ndim == 2:
        return levels.astype(np.float64)
    return levels.astype(np.float64) @ np.array([0.299, 0.587, 0.114])


def _decode(path: Path) -> np.ndarray:
    """Grey levels in [0, 1] of an image file; transparency is composited on white."""
    return grey_of(_decode_framed(path)[0])


#: Float levels up to this are levels in [0, 1] with a resampling's overshoot (bicubic
#: interpolation rings past 1), clipped to 1; above it, [0, 255] or more
#: (:func:`full_scale`). In [0, 255] a brightest pixel of 1.5 would be a black image.
MAX_OVERSHOOT = 1.5


def _array_levels(source, label: str) -> tuple[np.ndarray, float]:
    """A NumPy array ``[H, W]`` (grey), ``[H, W, 3]`` (RGB) or ``[H, W, 4]`` (RGBA,
    composited on white) as levels at full size (grey ``[H, W]`` or RGB ``[H, W, 3]``),
    checked (``ValueError`` naming ``label``), and the level of white
    (:func:`full_scale`) to divide them by once the image is reduced (a full-size float
    copy of a large photo is what reducing first avoids)."""
    a = np.asarray(source)
    if a.dtype.kind not in "buif":
        raise ValueError(f"{label} must hold numbers, got dtype {a.dtype}")
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] in (3, 4))) or min(a.shape[:2]) < 2:
        hint = ""
        if a.ndim == 3 and a.shape[0] in (1, 3, 4):
            hint = " (channels first? give [H, W, C]; several images: predict_batch)"
        elif a.ndim == 4 or (a.ndim == 3 and a.shape[0] < min(a.shape[1:])):
            hint = " (several images: predict_batch)"
        raise ValueError(
            f"{label} must be a grey-level [H, W], RGB [H, W, 3] or RGBA [H, W, 4] array "
            f"(or [H, W, 1] grey) of at least 2 x 2 pixels, got shape {a.shape}{hint}"
        )
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise ValueError(f"{label} contains NaN or inf")
    if a.dtype.kind in "if" and a.min() < 0:
        raise ValueError(
            f"{label} has levels below 0 (down to {float(a.min()):.4g}): an image array holds "
            "grey levels, in [0, 1] or [0, 255], not normalised values such as (x - mean) / std"
        )
    top = float(a.max())
    if a.dtype.kind == "f" and 1.0 < top <= MAX_OVERSHOOT:  # a resampling's overshoot
        a, top = np.minimum(a, np.asarray(1.0, a.dtype)), 1.0
    full = full_scale(top)
    if a.ndim == 2 or a.shape[2] == 3:
        return a, full
    alpha = a[..., 3:].astype(np.float32) / np.float32(full)  # composite on white
    return a[..., :3] * alpha + np.float32(full) * (1.0 - alpha), full


def _channels_last(a: np.ndarray) -> np.ndarray:
    """A tensor's values ``[C, H, W]`` (torch's and torchvision's order, C = 1, 3 or 4)
    as ``[H, W, C]``; any other array as it is (``[H, W, C]`` is kept where both read)."""
    if a.ndim == 3 and a.shape[0] in (1, 3, 4) and a.shape[2] not in (1, 3, 4):
        return a.transpose(1, 2, 0)
    return a


def _reduce_levels(levels: np.ndarray, factor: int) -> np.ndarray:
    """:func:`_reduce` (area average) of grey ``[H, W]`` or RGB ``[H, W, 3]`` levels."""
    if levels.ndim == 2:
        return _reduce(levels, factor)
    return np.stack([_reduce(levels[..., c], factor) for c in range(3)], axis=-1)


@dataclass(frozen=True)
class _Reading:
    """What :func:`_read_levels` read: ``levels`` in [0, 1] (grey ``[h, w]`` or RGB
    ``[h, w, 3]``, float32), ``reduction`` (the source's pixels per level pixel), the
    source's ``size`` ``(H, W)``, a ``label`` for messages, the levels' corner
    ``origin`` ``(x, y)`` in the source's pixels (pixel edges; not 0 for a region) and
    the grey level of ``white`` the source's values were divided by."""

    levels: np.ndarray
    reduction: float
    size: tuple[int, int]
    label: str
    origin: tuple[float, float] = (0.0, 0.0)
    white: float = 1.0


def _levels_framed(source, name: str | None, max_pixels: int = MAX_WORK_PIXELS):
    """Levels in [0, 1] (grey ``[h, w]`` or RGB ``[h, w, 3]``, float32) of a file, PIL
    image or array, the reduction (the source's pixels per level pixel), the source's
    size ``(H, W)`` and a label for messages."""
    r = _read_levels(source, name, max_pixels)
    return r.levels, r.reduction, r.size, r.label


def _read_levels(source, name: str | None, max_pixels: int = MAX_WORK_PIXELS, box=None,
                 white: float | None = None) -> _Reading:  # fmt: skip
    """A file, PIL image or array read as levels (:class:`_Reading`), at most
    ``max_pixels``; ``box`` ``(x0, y0, x1, y1)``: only that region of it (the source's
    own pixels, upright; half-open), reduced as its own size needs; ``white``: grey
    levels divided by it (a first reading's) instead of what the values read show."""
    from PIL import Image

    if isinstance(source, (str, os.PathLike)):
        levels, reduction, size, origin, white = _decode_framed(Path(source), max_pixels, box,
                                                                white)  # fmt: skip
        return _Reading(levels, reduction, size, str(source), origin, white)
    if isinstance(source, Image.Image):
        label = name or "PIL image"
        size = shown_size(source)
        levels, reduction, origin, white = _pil_levels(source.copy(), label, max_pixels,
                                                       _clipped(box, size), white)  # fmt: skip
        return _Reading(levels, reduction, size, label, origin, white)
    if not (isinstance(source, (np.ndarray, list, tuple)) or hasattr(source, "__array__")):
        raise ValueError(
            f"{name or 'image'} must be a file path, a PIL image or a NumPy array, got "
            f"{type(source).__name__}"
        )
    if isinstance(source, (list, tuple)) and any(isinstance(v, (str, os.PathLike, Image.Image))
                                                 for v in source):  # fmt: skip
        raise ValueError(
            f"{name or 'image'} must be one image (a file path, a PIL image or an array), got "
            f"a {type(source).__name__} of {len(source)}; several: prepare_paths, then "
            "predict_images (their DMPs), or predict_batch (their predictions)"
        )
    if is_tensor(source):  # a torch tensor: its values, whatever its dtype or grad
        source = _channels_last(source.detach().cpu().float().numpy())
    source = np.asarray(source)
    if source.ndim == 3 and source.shape[2] == 1:  # [H, W, 1]: grey
        source = source[..., 0]
    label = name or "image array"
    levels, full = _array_levels(source, label)
    size = (int(levels.shape[0]), int(levels.shape[1]))
    a, origin = source, (0.0, 0.0)
    if box is not None:
        x0, y0, x1, y1 = _clipped(box, size)
        a, levels, origin = a[y0:y1, x0:x1], levels[y0:y1, x0:x1], (float(x0), float(y0))
        full = full if white is None else white
    factor = math.ceil(math.sqrt(levels.shape[0] * levels.shape[1] / max_pixels))
    if factor > 1 and a.dtype == np.uint8:  # reduced as its file is read: in 8 bits
        levels, reduction, _, white = _pil_levels(Image.fromarray(np.ascontiguousarray(a)),
                                                  label, max_pixels, None,
                                                  None if box is None else full)  # fmt: skip
        return _Reading(levels, reduction, size, label, origin, white)
    levels = _reduce_levels(levels, factor) if factor > 1 else levels
    levels = (levels / np.float32(full)).astype(np.float32)
    return _Reading(levels, float(factor), size, label, origin, float(full))


def _grey_levels(source, name: str | None) -> tuple[np.ndarray, str]:
    """Grey levels ``[H, W]`` in [0, 1] of a file, PIL image or array, and a label for
    messages."""
    levels, _, _, label = _levels_framed(source, name)
    return grey_of(levels), label


def _ink_levels(levels: np.ndarray, label: str, clean: bool = True) -> np.ndarray:
    """Ink ``[H, W]`` from levels (grey or RGB): light ink on zero background, ink = 1.

    ``clean`` (the default): the handwriting separated from its paper by
    :func:`img2dmp.data.paper.paper_ink` (lighting flattened, ink of any colour, ruled,
    squared and dotted lines, text from the back, specks and the sheet's edge removed),
    typical ink = 1. Otherwise the plain reading: the polarity from the border (if the
    median of the outer ring, 5 % of the shorter side, is brighter than the median of the
    whole image, or than mid grey, the ink is dark on light paper and the image is
    inverted), the background level (the ring's median) subtracted and the darkest ink
    scaled to 1.
    """
    if clean:
        from .paper import paper_ink

        found = paper_ink(levels)
        if found is None:
            raise ValueError(f"{label} shows no ink (nothing stands out from the paper)")
        return found.ink.astype(np.float64)
    grey = grey_of(levels)
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


def _crop_box(ink: np.ndarray, label: str = "the image") -> tuple[np.ndarray, int, int]:
    """The bounding box of the pixels above ``INK_THRESHOLD``, and its first row and
    column in ``ink``."""
    rows, cols = np.nonzero(ink > INK_THRESHOLD)
    if rows.size == 0:
        raise ValueError(f"{label} has no pixel darker than half the ink's contrast")
    r0, c0 = int(rows.min()), int(cols.min())
    return ink[r0 : rows.max() + 1, c0 : cols.max() + 1], r0, c0


def _crop_to_ink(ink: np.ndarray, label: str = "the image") -> np.ndarray:
    """The bounding box of the pixels above ``INK_THRESHOLD``."""
    return _crop_box(ink, label)[0]


def _frame(crop: np.ndarray, image_size: tuple[int, int], margin: float) -> np.ndarray:
    """The crop centred on a square with ``margin`` of its side free on every border,
    resized to ``image_size`` and scaled so the darkest ink is 1; float32 ``[H, W]``
    (:func:`_frame_placed` without the placement)."""
    return _frame_placed(crop, image_size, margin)[0]


def _frame_placed(crop: np.ndarray, image_size: tuple[int, int], margin: float):
    """The crop centred on a square with ``margin`` of its side free on every border,
    resized to ``image_size`` and scaled so the darkest ink is 1; float32 ``[H, W]``, and
    the placement ``(side, top, left)``: the square's side and the crop's offset in it, in
    crop pixels (the square fills the output, corner to corner).

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
    return out.astype(np.float32), (total, top_off, left_off)


def _scaling(sx: float, sy: float | None = None) -> np.ndarray:
    return np.diag([float(sx), float(sx if sy is None else sy), 1.0])


def _shift(dx: float, dy: float) -> np.ndarray:
    m = np.eye(3)
    m[:2, 2] = dx, dy
    return m


def prepare_image(
    source,
    image_size=(40, 40),
    *,
    margin: float = DEFAULT_MARGIN,
    stroke_width_px: float | None = None,
    name: str | None = None,
    clean: bool = True,
) -> np.ndarray:
    """Bring an image of one handwritten digit to the network's input.

    Steps: levels in [0, 1] (colour kept); the ink separated from its paper
    (:func:`img2dmp.data.paper.paper_ink`: polarity from the border, lighting flattened,
    ink of any colour on paper of any tint, ruled, squared and dotted lines, text showing
    through from the back, specks and the sheet's edge removed; typical ink = 1; with
    ``clean=False`` only the polarity and the border's level, the earlier reading); crop to
    the bounding box of pixels above
    ``INK_THRESHOLD``; pad to a square around the box's centre; add ``margin`` of the
    side on every border; optionally thicken or thin the strokes to the training images'
    pen width (a thin pen photographed at high resolution would otherwise shrink to faint
    hairlines); resize with area averaging (anti-aliased, as the training strokes are);
    scale so the darkest ink is 1. :func:`prepare_image_framed` also gives where the
    result sits in ``source`` (an :class:`ImageFrame`).

    Parameters
    ----------
    source : path, PIL image or array
        PNG/JPEG file (any size, RGB, grey or with transparency), a ``PIL.Image.Image``
        (both turned upright as an EXIF orientation tag says, :func:`upright`), or an
        array: grey levels ``[H, W]`` (or ``[H, W, 1]``), RGB ``[H, W, 3]`` or RGBA
        ``[H, W, 4]``, a torch tensor also channels first ``[C, H, W]`` as torchvision
        gives it (values in [0, 1], floats up to 1.5 clipped to 1 as a resampling's overshoot;
        when any is above that, in [0, 255] or, above 255, in the range of the fewest
        bits that hold them, as for 16-bit files: :func:`full_scale`; none below 0).
    image_size : (H, W)
        The model's input size.
    margin : float
        Share of the side left empty on each border, in [0, 0.45].
    stroke_width_px : float, optional
        Pen width, in output pixels, to bring the strokes to (a model's
        ``stroke_width_px``, see :func:`typical_stroke_width`); None keeps the width.
    name : str, optional
        Used in error messages for arrays and PIL images.
    clean : bool
        Separate the ink from the paper (default); False reads the image as plain paper
        (for images known to be clean, and for comparisons).

    Returns
    -------
    ndarray float32 [H, W]
        Ink = 1, background = 0.
    """
    return prepare_image_framed(
        source, image_size, margin=margin, stroke_width_px=stroke_width_px, name=name,
        clean=clean,
    )[0]  # fmt: skip


def _check_preparation(image_size, margin, stroke_width_px) -> tuple[int, int]:
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
    return h_out, w_out


def prepare_image_framed(
    source,
    image_size=(40, 40),
    *,
    margin: float = DEFAULT_MARGIN,
    stroke_width_px: float | None = None,
    name: str | None = None,
    clean: bool = True,
) -> tuple[np.ndarray, ImageFrame]:
    """:func:`prepare_image` (same arguments), and the :class:`ImageFrame` that maps
    positions in ``source`` to positions in the prepared image and back.

    Every step that moves pixels is a shift or a scaling (the reduction of a large image,
    the crop, the pen-width filter's border, the square's padding, the resize), so the
    map is affine: ``frame.to_model(xy)`` puts a point of the user's image where it is in
    the returned image, ``frame.to_image(xy)`` the reverse.
    """
    out, frame, _ = prepare_image_found(
        source, image_size, margin=margin, stroke_width_px=stroke_width_px, name=name,
        clean=clean,
    )  # fmt: skip
    return out, frame


def prepare_image_found(
    source,
    image_size=(40, 40),
    *,
    margin: float = DEFAULT_MARGIN,
    stroke_width_px: float | None = None,
    name: str | None = None,
    clean: bool = True,
):
    """:func:`prepare_image_framed`, and the mask of the pen strokes found in ``source``
    (``bool [h, w]`` at the resolution the image was read at; with ``clean=False`` the
    plain ink above half): what tells whether the image holds one character or several.
    ``clean=False`` reads a clean image (a drawing rendered on a blank canvas) without
    the paper cleaning meant for photos, which costs tens of milliseconds."""
    h_out, w_out = _check_preparation(image_size, margin, stroke_width_px)
    levels, reduction, size, label = _levels_framed(source, name)
    mask = None
    if clean:
        from .paper import paper_ink

        found = paper_ink(levels)
        if found is None:
            raise ValueError(f"{label} shows no ink (nothing stands out from the paper)")
        ink, mask = found.ink.astype(np.float64), found.mask
    else:
        ink = _ink_levels(levels, label, clean=False)
        mask = ink > 0.5
    out, edge = frame_ink(ink, (h_out, w_out), margin, stroke_width_px, label)
    # Positions are tracked on pixel edges (pixel j spans [j, j + 1]), where a reduction
    # or a resize is a pure scaling; CONTRACTS.md's centres are half a pixel less.
    frame = ImageFrame(_centred(edge @ _scaling(1.0 / reduction)), size, (h_out, w_out))
    return out, frame, mask


def _centred(edge: np.ndarray) -> np.ndarray:
    """A map of pixel-edge positions ``[3, 3]`` as the ``[2, 3]`` map of pixel centres."""
    return (_shift(-0.5, -0.5) @ edge @ _shift(0.5, 0.5))[:2]


def frame_ink(
    ink: np.ndarray,
    image_size: tuple[int, int],
    margin: float = DEFAULT_MARGIN,
    stroke_width_px: float | None = None,
    label: str = "the image",
) -> tuple[np.ndarray, np.ndarray]:
    """An ink map ``[h, w]`` (ink = 1) as the model's input: cropped to the ink, the pen
    width matched, framed and resized as :func:`prepare_image` does; ``float32 [H, W]``
    and the ``[3, 3]`` affine map from pixel-edge positions of ``ink`` (pixel ``j``
    spans ``[j, j + 1]``) to those of the result (sizes and margin as checked by
    :func:`prepare_image`)."""
    h_out, w_out = image_size
    crop, r0, c0 = _crop_box(ink, label)
    edge = _shift(-c0, -r0)
    factor = _work_factor(crop, margin, max(h_out, w_out))
    if stroke_width_px is not None:
        # The pen width is matched at the output's scale, which the framing fixes.
        side = max(crop.shape) / (1.0 - 2.0 * margin)
        scale = max(h_out, w_out) / side
        crop, red, pad = _match_stroke_width_framed(crop, scale, float(stroke_width_px), factor)
        edge = _shift(pad, pad) @ _scaling(1.0 / red) @ edge
        crop, r0, c0 = _crop_box(crop, label)  # the widened ink may reach past the old box
        edge = _shift(-c0, -r0) @ edge
    else:
        crop = _reduce(crop, factor)
        edge = _scaling(1.0 / factor) @ edge
    out, (total, top, left) = _frame_placed(crop, (h_out, w_out), margin)
    return out, _scaling(w_out / total, h_out / total) @ _shift(left, top) @ edge


def ink_view(source, max_side: int = 600, *, name: str | None = None, clean: bool = True):
    """The whole of ``source`` (a path, PIL image or array, as for :func:`prepare_image`)
    as ink levels for a picture: the ink separated from the paper as
    :func:`prepare_image` separates it (``clean``), background 0, ink 1, reduced (area
    average) so that its longer side is at most ``max_side`` pixels.

    Returns
    -------
    view : ndarray float32 [h, w]
    scale : float
        View pixels per pixel of ``source``: a point ``(x, y)`` of the user's image frame
        is at ``((x + 0.5) * scale - 0.5, (y + 0.5) * scale - 0.5)`` in the view.
    """
    if isinstance(max_side, bool) or not isinstance(max_side, int) or max_side < 2:
        raise ValueError(f"max_side must be a whole number >= 2, got {max_side!r}")
    levels, reduction, _, label = _levels_framed(source, name)
    factor = max(1, math.ceil(max(levels.shape[:2]) / max_side))
    view = _reduce(_ink_levels(levels, label, clean), factor)
    return view.astype(np.float32), 1.0 / (reduction * factor)


def paper_steps(source, *, name: str | None = None, max_pixels: int = MAX_WORK_PIXELS,
                steady: bool = False):  # fmt: skip
    """Every step of the ink's separation from the paper for ``source`` (a path, PIL
    image or array, read as :func:`prepare_image` reads it, at most ``max_pixels``):
    :func:`img2dmp.data.paper.paper_ink` with ``keep_steps`` (None when nothing stands
    out from the paper), and the reduction (the source's pixels per pixel of the steps).
    ``steady``: a shake's blur undone first, as a page's is
    (:func:`img2dmp.data.shake.steadied`); its steps then hold ``shake``, the
    :class:`img2dmp.data.shake.Shake` undone (None: none read)."""
    from .paper import paper_ink
    from .shake import shake, steadied

    levels, reduction, _, _ = _levels_framed(source, name, max_pixels)
    moved = shake(levels) if steady else None
    found = paper_ink(levels if moved is None else steadied(levels, moved), keep_steps=True)
    if found is not None and steady:
        found.steps["shake"] = moved
    return found, reduction


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
    "ImageFrame",
    "ImageTooLargeError",
    "MAX_WORK_PIXELS",
    "OUTPUT_SIDE_PX",
    "WORK_PER_OUTPUT_PX",
    "ink_margin",
    "frame_ink",
    "grey_of",
    "ink_view",
    "paper_steps",
    "prepare_image",
    "prepare_image_found",
    "prepare_image_framed",
    "shown_size",
    "stroke_width",
    "typical_stroke_width",
    "upright",
]
