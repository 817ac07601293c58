"""What a browser sends as a digit: pen strokes to check and draw, or an image data URL.

Strokes are lists of ``[x, y, t_ms]`` points (x right, y down, in the drawing area's
pixels). :func:`render_strokes` draws them as the training images were drawn: dark ink
on white paper, a round pen ``max(W, H) / 14`` wide, a stroke of one point a dot. The
drawing's pixel ``[i, j]`` is PIL's point ``(j, i)``, so positions in the rendered image
(the centre convention of docs/CONTRACTS.md) are the positions as sent.
"""

from __future__ import annotations

import base64
import binascii
import io
import math
import re
import warnings

import numpy as np

from .errors import WebError, show

#: Most points of all strokes of one request together.
MAX_POINTS = 20_000
#: Most strokes of one request.
MAX_STROKES = 1_000
#: Largest side of a drawing area, pixels.
MAX_CANVAS_PX = 4096
#: Most pixels of an image sent as a data URL (larger ones are refused before decoding).
MAX_IMAGE_PIXELS = 25_000_000
#: The pen's width as a share of the drawing area's larger side.
PEN_SHARE = 1.0 / 14.0
_DATA_URL = re.compile(r"data:image/(png|jpeg|jpg);base64,", re.IGNORECASE)
_FORMATS = ("PNG", "JPEG")


def check_strokes(strokes, bounds: tuple[float, float, float, float], what: str) -> list:
    """The strokes as float64 arrays ``[n, 3]`` (x, y, t_ms), checked.

    Parameters
    ----------
    strokes : list of lists of [x, y, t] (numbers, already checked to be finite)
    bounds : (x_lo, x_hi, y_lo, y_hi)
        Where a point may lie.
    what : str
        Names the area in messages ("the canvas", "image 3").

    Raises
    ------
    WebError
        422 for no stroke, a stroke without points, too many strokes or points, or a
        point outside ``bounds`` (naming ``strokes[i][j]`` and the value).
    """
    if not strokes:
        raise WebError(422, "strokes: must hold at least one stroke, got []")
    if len(strokes) > MAX_STROKES:
        raise WebError(422, f"strokes: at most {MAX_STROKES} strokes, got {len(strokes)}")
    total = sum(len(s) for s in strokes)
    if total > MAX_POINTS:
        raise WebError(422, f"strokes: at most {MAX_POINTS} points in all, got {total}")
    x_lo, x_hi, y_lo, y_hi = bounds
    out = []
    for i, stroke in enumerate(strokes):
        if not stroke:
            raise WebError(422, f"strokes[{i}]: a stroke needs at least one point, got []")
        a = np.asarray(stroke, dtype=np.float64).reshape(-1, 3)
        outside = (a[:, 0] < x_lo) | (a[:, 0] > x_hi) | (a[:, 1] < y_lo) | (a[:, 1] > y_hi)
        if outside.any():
            j = int(np.flatnonzero(outside)[0])
            raise WebError(
                422,
                f"strokes[{i}][{j}]: point {show(stroke[j])} lies outside {what} "
                f"(x in [{x_lo:g}, {x_hi:g}], y in [{y_lo:g}, {y_hi:g}])",
            )
        out.append(a)
    return out


def canvas_size(canvas) -> tuple[int, int]:
    """``canvas = [width, height]`` (numbers in ``[1, MAX_CANVAS_PX]``) as whole pixels
    ``(W, H)``; 422 naming the value otherwise."""
    if canvas is None:
        raise WebError(422, "canvas: [width, height] is required with strokes")
    w, h = canvas
    if not (1 <= w <= MAX_CANVAS_PX and 1 <= h <= MAX_CANVAS_PX):
        raise WebError(
            422, f"canvas: width and height must be in [1, {MAX_CANVAS_PX}], got {show(canvas)}"
        )
    return math.ceil(w), math.ceil(h)


def canvas_bounds(size: tuple[int, int]) -> tuple[float, float, float, float]:
    """Where a drawn point may lie: the area and as much again on every side."""
    w, h = size
    return (-float(w), 2.0 * w, -float(h), 2.0 * h)


def render_strokes(strokes: list, size: tuple[int, int]) -> np.ndarray:
    """The strokes drawn as dark ink on white, ``uint8 [H, W]`` (``size = (W, H)``).

    Round joins and round ends, pen ``max(W, H) / 14`` wide; a stroke of one point is a
    dot of that diameter.
    """
    from PIL import Image, ImageDraw

    w, h = size
    im = Image.new("L", (w, h), 255)
    draw = ImageDraw.Draw(im)
    width = max(w, h) * PEN_SHARE
    r = width / 2.0
    for a in strokes:
        points = [(float(x), float(y)) for x, y in a[:, :2]]
        if len(points) > 1:
            draw.line(points, fill=0, width=max(1, round(width)), joint="curve")
        for x, y in {points[0], points[-1]}:
            draw.ellipse([x - r, y - r, x + r, y + r], fill=0)
    return np.asarray(im)


def grey_png(grey: np.ndarray) -> bytes:
    """A grey image ``[H, W]`` (values 0-255) as PNG bytes."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(grey, dtype=np.uint8), mode="L").save(buf, "PNG")
    return buf.getvalue()


def decode_data_url(text: str):
    """A ``data:image/png;base64,...`` (or JPEG) URL as a loaded PIL image.

    Raises
    ------
    WebError
        422 naming ``image`` for another kind of URL, bad base64, or bytes that
        :func:`decode_image_bytes` refuses.
    """
    m = _DATA_URL.match(text)
    if not m:
        raise WebError(
            422,
            f"image: must be a data:image/png;base64,... or data:image/jpeg;base64,... URL, "
            f"got {show(text[:40])}",
        )
    try:
        raw = base64.b64decode(text[m.end() :], validate=True)
    except (binascii.Error, ValueError) as e:
        raise WebError(422, f"image: the base64 data is not valid ({e})") from None
    return decode_image_bytes(raw, "image")


def decode_image_bytes(raw: bytes, what: str):
    """The bytes of a PNG or JPEG file as a loaded PIL image (its EXIF tag kept).

    Raises
    ------
    WebError
        422 naming ``what`` for bytes that are no PNG or JPEG, more than
        ``MAX_IMAGE_PIXELS`` pixels (checked from the header, before decoding) or data
        that do not decode.
    """
    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(io.BytesIO(raw))
        if im.format not in _FORMATS:
            raise WebError(422, f"{what}: must be a PNG or JPEG image, got {im.format}")
        w, h = im.size
        if w * h > MAX_IMAGE_PIXELS:
            raise WebError(
                422, f"{what}: {w} x {h} pixels is more than the {MAX_IMAGE_PIXELS:,} allowed"
            )
        im.load()
    except WebError:
        raise
    except UnidentifiedImageError:  # PIL's message names only the BytesIO object
        raise WebError(
            422, f"{what}: cannot be decoded as a PNG or JPEG image (it starts {show(raw[:8])})"
        ) from None
    except (Image.DecompressionBombError, OSError, SyntaxError, ValueError, EOFError) as e:
        raise WebError(422, f"{what}: cannot be decoded as a PNG or JPEG image ({e})") from None
    return im


__all__ = [
    "MAX_CANVAS_PX",
    "MAX_IMAGE_PIXELS",
    "MAX_POINTS",
    "MAX_STROKES",
    "canvas_bounds",
    "canvas_size",
    "check_strokes",
    "decode_data_url",
    "decode_image_bytes",
    "grey_png",
    "render_strokes",
]
