"""A shaken photo: the blur of a camera moved in a straight line, found and undone.

A hand that moves the phone while the shutter is open smears every stroke along the
movement: a line blur of a few pixels to a dozen, in any direction. Characters a little
apart run together along it, and the page's characters merge
(``experiments/photo_conditions.py``, shake of 9 px along the rows: 21 of the yellow
photo's 66 digits found alone; 15 degrees off them: 41).

:func:`shake` reads it in two ways that must agree:

- **the cepstrum** (the inverse transform of the log power spectrum, the image first
  faded to its edges by a Hann window). A blur of length L along a direction multiplies
  the spectrum by a sinc whose zeros repeat every 1/L along it, which leaves a deep,
  narrow trough in the cepstrum at L pixels along the movement: its deepest point between
  3 and ``SHAKE_MAX_PX`` pixels from the origin, ``SHAKE_CEPSTRUM_Z`` robust standard
  deviations (median absolute deviations times 1.4826) below the median of that ring at
  least, gives both length and direction (to a tenth of a pixel, by a parabola through
  its neighbours). In focus, out of focus or under a thick pen the trough is
  shallower, but a marker's square tip or a ruled page's rules make troughs too, so
- **the derivatives must agree**: along the movement the image's derivative is a
  difference of two copies of the page L apart, alike from one pixel to the next; across
  it, a derivative like a photo in focus. The correlation of the directional derivative
  two pixels along the movement exceeds that across it by ``SHAKE_ANISOTROPY``, or by
  ``SHAKE_SMOOTH_ANISOTROPY`` where it is ``SHAKE_SMOOTH`` at least (read from the 2-D
  correlations of the row and column derivatives; a defocus blurs every way alike).

Where they do not agree, a shake along the rows or the columns is still read as it was
first read (thin strokes, or a page read at a reduction, can keep the correlation two
pixels along a row low): the correlation of neighbouring derivatives along the rows (or
columns) is ``SHAKE_ROW_SMOOTH`` at least and exceeds the other direction's by
``SHAKE_ROW_ANISOTROPY``; its length is the lag, 3 to ``SHAKE_MAX_PX``, at which the
derivative's correlation along it is the most negative.

:func:`steadied` then undoes it by a Wiener filter (``SHAKE_WIENER``: the share of noise
to signal it assumes): along a row or a column (within ``SHAKE_AXIS_DEG``), of a box of
whole pixels, one dimension at a time; at a slant, of a line of that length and
direction drawn on the pixel grid (each pixel weighed by the length of the line inside
it), in two dimensions.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import scipy.fft

#: An image under this many pixels on its shorter side is not read for a shake.
SHAKE_MIN_SIDE = 64
#: The shortest blur looked for (pixels of the image as read).
SHAKE_MIN_PX = 3
#: The longest blur looked for (pixels of the image as read).
SHAKE_MAX_PX = 25
#: The cepstrum's trough, at least this many robust standard deviations below its ring's
#: median. This and the next three were chosen together on 792 validation images not
#: shaken (none passes) and 872 shaken 4-15 px in every direction (826 pass, with the
#: row and column reading; experiments/RESULTS.md 7.23).
SHAKE_CEPSTRUM_Z = 18.0
#: The directional derivative's correlation two pixels along the blur above the one
#: across it by this much ...
SHAKE_ANISOTROPY = 0.25
#: ... or by ``SHAKE_SMOOTH_ANISOTROPY`` where the one along it is ``SHAKE_SMOOTH`` at
#: least (at a slant the one across is read high: it is interpolated between lags).
SHAKE_SMOOTH = 0.4
SHAKE_SMOOTH_ANISOTROPY = 0.12
#: The row and column reading: the correlation of neighbouring derivatives along the rows
#: (or columns) at least this (in focus: 0.0-0.4; shaken 5-9 px: 0.5-0.9) ...
SHAKE_ROW_SMOOTH = 0.45
#: ... and above the one across them by this much (a defocus: under 0.05).
SHAKE_ROW_ANISOTROPY = 0.25
#: A blur this close to a row or a column (degrees) is undone along it.
SHAKE_AXIS_DEG = 2.0
#: The Wiener filter's noise-to-signal ratio.
SHAKE_WIENER = 0.02
#: Points per pixel of the line drawn on the pixel grid for a slanted blur.
_LINE_SAMPLES = 32


class Shake(NamedTuple):
    """A camera's straight movement: its length in pixels and its direction in degrees,
    0 along the rows (to the right), 90 along the columns (down the image), in
    ``[0, 180)``."""

    length: float
    degrees: float


def _grey(levels: np.ndarray) -> np.ndarray:
    a = np.asarray(levels, np.float32)
    return a.mean(axis=2) if a.ndim == 3 else a


def _lags(reach: int) -> tuple[np.ndarray, np.ndarray]:
    """The lags ``(dy [n, 1], dx [1, n])`` of a ``[2 reach + 1]``-square array whose
    centre is lag 0."""
    lag = np.arange(-reach, reach + 1)
    return lag[:, None], lag[None, :]


def _centred(spectrum: np.ndarray, shape, reach: int) -> np.ndarray:
    """The inverse transform of ``spectrum`` (of an image of ``shape``) at the lags
    within ``reach`` of 0, lag 0 at the centre."""
    full = scipy.fft.irfft2(spectrum, s=shape, workers=-1)
    return np.roll(full, (reach, reach), axis=(0, 1))[: 2 * reach + 1, : 2 * reach + 1]


def _trough(grey: np.ndarray, longest: int) -> tuple[float, float, float]:
    """The cepstrum's deepest point ``(dy, dx, z)`` between ``SHAKE_MIN_PX`` and
    ``longest`` pixels from the origin (half plane dy >= 0), to a tenth of a pixel, and
    how far below the ring's median it is (robust standard deviations, negative)."""
    h, w = grey.shape
    window = np.outer(np.hanning(h).astype(np.float32), np.hanning(w).astype(np.float32))
    power = np.abs(scipy.fft.rfft2((grey - grey.mean()) * window, workers=-1)) ** 2
    if not float(power.mean()) > 0.0:  # a flat image: nothing to read
        return 0.0, 0.0, 0.0
    reach = longest + 1
    cep = _centred(np.log(power + 1e-3 * float(power.mean())), grey.shape, reach)
    dy, dx = _lags(reach)
    radius = np.hypot(dy, dx)
    ring = (radius >= SHAKE_MIN_PX) & (radius <= longest) & ((dy > 0) | ((dy == 0) & (dx > 0)))
    values = cep[ring]
    median = float(np.median(values))
    spread = 1.4826 * float(np.median(np.abs(values - median))) + 1e-12
    iy, ix = np.unravel_index(int(np.argmin(np.where(ring, cep, np.inf))), cep.shape)

    def vertex(a: float, b: float, c: float) -> float:  # a parabola's through (-1, 0, 1)
        bend = a - 2.0 * b + c
        return float(np.clip(0.5 * (a - c) / bend, -0.5, 0.5)) if bend > 0 else 0.0

    fy = vertex(cep[iy - 1, ix], cep[iy, ix], cep[iy + 1, ix])
    fx = vertex(cep[iy, ix - 1], cep[iy, ix], cep[iy, ix + 1])
    return iy - reach + fy, ix - reach + fx, (float(cep[iy, ix]) - median) / spread


def _along_across(grey: np.ndarray, degrees: float) -> tuple[float, float]:
    """The correlation of the directional derivative two pixels along ``degrees``, and
    that of the derivative across it two pixels across."""
    gx = grey[:-1, 1:] - grey[:-1, :-1]
    gy = grey[1:, :-1] - grey[:-1, :-1]
    gx, gy = gx - gx.mean(), gy - gy.mean()
    reach = 3
    shape = (gx.shape[0] + reach, gx.shape[1] + reach)
    fx, fy = (scipy.fft.rfft2(g, s=shape, workers=-1) for g in (gx, gy))
    dy, dx = _lags(reach)
    overlap = (gx.shape[0] - np.abs(dy)) * (gx.shape[1] - np.abs(dx))
    rxx, ryy, rxy = (_centred(a * np.conj(b), shape, reach) / overlap
                     for a, b in ((fx, fx), (fy, fy), (fy, fx)))  # fmt: skip

    def at(r: np.ndarray, y: float, x: float) -> float:  # bilinear, lag (y, x)
        y, x = y + reach, x + reach
        y0, x0 = int(math.floor(y)), int(math.floor(x))
        ty, tx = y - y0, x - x0
        return float((1 - ty) * ((1 - tx) * r[y0, x0] + tx * r[y0, x0 + 1])
                     + ty * ((1 - tx) * r[y0 + 1, x0] + tx * r[y0 + 1, x0 + 1]))  # fmt: skip

    def correlation(theta: float) -> float:
        c, s = math.cos(theta), math.sin(theta)
        y, x = 2.0 * s, 2.0 * c
        lagged = c * c * at(rxx, y, x) + s * s * at(ryy, y, x)
        lagged += c * s * (at(rxy, y, x) + at(rxy, -y, -x))
        power = c * c * rxx[reach, reach] + s * s * ryy[reach, reach]
        power += 2.0 * c * s * rxy[reach, reach]
        return lagged / (power + 1e-12)

    theta = math.radians(degrees)
    return correlation(theta), correlation(theta + math.pi / 2)


def _from_cepstrum(grey: np.ndarray, longest: int) -> Shake | None:
    """The shake the cepstrum's trough and the derivatives agree on (module docstring)."""
    dy, dx, z = _trough(grey, longest)
    length = math.hypot(dy, dx)
    if z > -SHAKE_CEPSTRUM_Z or not SHAKE_MIN_PX <= length <= longest:
        return None
    degrees = math.degrees(math.atan2(dy, dx)) % 180.0
    along, across = _along_across(grey, degrees)
    smooth = along >= SHAKE_SMOOTH and along - across >= SHAKE_SMOOTH_ANISOTROPY
    if along - across < SHAKE_ANISOTROPY and not smooth:
        return None
    for axis in (0.0, 90.0, 180.0):
        if abs(degrees - axis) <= SHAKE_AXIS_DEG:
            return Shake(float(round(length)), axis % 180.0)
    return Shake(round(length, 1), round(degrees, 1))


def _correlation(d: np.ndarray, axis: int, lag: int) -> float:
    """The correlation of ``d`` with itself ``lag`` pixels along ``axis``."""
    a, b = (d[:-lag], d[lag:]) if axis == 0 else (d[:, :-lag], d[:, lag:])  # views
    return float(np.mean(a * b, dtype=np.float64))


def _along_row_or_column(grey: np.ndarray, longest: int) -> Shake | None:
    """A shake along the rows or the columns read from the correlation of neighbouring
    derivatives (module docstring); its length is the lag at which the derivative's
    correlation along it is the most negative (the far ends of each ramp)."""
    derivs = [np.diff(grey, axis=axis) for axis in (0, 1)]
    derivs = [d - d.mean() for d in derivs]
    power = [float(np.mean(d * d, dtype=np.float64)) + 1e-12 for d in derivs]
    near = [_correlation(d, k, 1) / p for k, (d, p) in enumerate(zip(derivs, power, strict=True))]
    axis = int(np.argmax(near))
    if near[axis] < SHAKE_ROW_SMOOTH or near[axis] - near[1 - axis] < SHAKE_ROW_ANISOTROPY:
        return None
    lags = range(SHAKE_MIN_PX, longest + 1)
    corr = [_correlation(derivs[axis], axis, lag) / power[axis] for lag in lags]
    return Shake(float(lags[int(np.argmin(corr))]), 0.0 if axis == 1 else 90.0) if corr else None


def shake(levels) -> Shake | None:
    """The shake blurring ``levels`` (``[H, W]`` or ``[H, W, 3]``, module docstring), or
    None when there is none to read."""
    grey = _grey(levels)
    if min(grey.shape) < SHAKE_MIN_SIDE:
        return None
    longest = min(SHAKE_MAX_PX, min(grey.shape) // 4)
    found = _from_cepstrum(grey, longest)
    return found if found is not None else _along_row_or_column(grey, longest)


def _checked(length, degrees, longest: float = math.inf) -> tuple[float, float]:
    """``(length, degrees)`` as floats; ``ValueError`` naming a length that is not a
    number from 1 to ``longest`` pixels, or a direction that is not a finite number."""
    try:
        length, degrees = float(length), float(degrees)
    except (TypeError, ValueError):
        raise ValueError(f"a shake is (length_px, degrees), got {(length, degrees)!r}") from None
    if not (math.isfinite(length) and 1.0 <= length <= longest):
        raise ValueError(f"a shake's length must be 1 to {longest:g} px, got {length!r}")
    if not math.isfinite(degrees):
        raise ValueError(f"a shake's direction must be a finite number of degrees, got {degrees!r}")
    return length, degrees


def line(length: float, degrees: float) -> np.ndarray:
    """A line of ``length`` pixels (at least 1) at ``degrees`` (:class:`Shake`) centred
    on the middle of an odd square array, each pixel weighed by the share of the line
    inside it; sums to 1."""
    length, degrees = _checked(length, degrees)
    theta = math.radians(degrees)
    reach = math.ceil(length / 2) + 1
    n = max(2, round(length * _LINE_SAMPLES))
    t = (np.arange(n) + 0.5) * (length / n) - length / 2  # the middles of n equal pieces
    ys = np.floor(reach + 0.5 + t * math.sin(theta)).astype(int)
    xs = np.floor(reach + 0.5 + t * math.cos(theta)).astype(int)
    out = np.zeros((2 * reach + 1, 2 * reach + 1))
    np.add.at(out, (ys, xs), 1.0)
    return out / out.sum()


def _wiener(otf: np.ndarray) -> np.ndarray:
    return (np.conj(otf) / (np.abs(otf) ** 2 + SHAKE_WIENER)).astype(np.complex64)


def _along_axis(planes: np.ndarray, length: int, axis: int) -> np.ndarray:
    """``planes`` (``[H, W, C]``) with a box of ``length`` pixels along ``axis`` undone."""
    pad = 2 * length
    n = planes.shape[axis] + 2 * pad
    box = np.zeros(n)
    box[:length] = 1.0 / length
    wiener = _wiener(np.fft.rfft(np.roll(box, -(length // 2))))
    wiener = wiener.reshape((-1, 1) if axis == 0 else (1, -1))
    widths = [(pad, pad) if k == axis else (0, 0) for k in (0, 1)]
    keep = [slice(None), slice(None)]
    keep[axis] = slice(pad, pad + planes.shape[axis])
    out = np.empty(planes.shape, np.float32)
    for c in range(planes.shape[2]):  # a channel at a time: a third of the memory
        spectrum = np.fft.rfft(np.pad(planes[..., c], widths, mode="reflect"), axis=axis)
        spectrum *= wiener
        out[..., c] = np.fft.irfft(spectrum, n=n, axis=axis)[tuple(keep)]
    return out


def _at_a_slant(planes: np.ndarray, length: float, degrees: float) -> np.ndarray:
    """``planes`` (``[H, W, C]``) with a line blur (:func:`line`) undone."""
    psf = line(length, degrees)
    reach = psf.shape[0] // 2
    pad = 2 * math.ceil(length)
    h, w = planes.shape[0] + 2 * pad, planes.shape[1] + 2 * pad
    kernel = np.zeros((h, w))
    kernel[: psf.shape[0], : psf.shape[1]] = psf
    otf = scipy.fft.rfft2(np.roll(kernel, (-reach, -reach), axis=(0, 1)), workers=-1)
    wiener = _wiener(otf)
    out = np.empty(planes.shape, np.float32)
    for c in range(planes.shape[2]):
        padded = np.pad(planes[..., c], pad, mode="reflect")
        spectrum = scipy.fft.rfft2(padded, workers=-1)
        spectrum *= wiener
        out[..., c] = scipy.fft.irfft2(spectrum, s=(h, w), workers=-1)[pad:-pad, pad:-pad]
    return out


def steadied(levels, found: Shake | None = None) -> np.ndarray:
    """``levels`` with the shake :func:`shake` finds (or ``found``, a :class:`Shake` or
    ``(length_px, degrees)``, its length at most half the image's shorter side) undone,
    ``float32`` in [0, 1] and of the same shape; ``levels`` as they are when there is
    none."""
    found = shake(levels) if found is None else found
    if found is None:
        return levels
    a = np.asarray(levels, np.float32)
    planes = a[..., None] if a.ndim == 2 else a
    try:
        length, degrees = found
    except (TypeError, ValueError):
        raise ValueError(f"a shake is (length_px, degrees), got {found!r}") from None
    length, degrees = _checked(length, degrees, min(planes.shape[:2]) / 2)
    degrees %= 180.0
    if degrees in (0.0, 90.0) and float(length).is_integer():
        out = _along_axis(planes, int(length), 1 if degrees == 0.0 else 0)
    else:
        out = _at_a_slant(planes, float(length), float(degrees))
    np.clip(out, 0.0, 1.0, out=out)
    return out[..., 0] if a.ndim == 2 else out


__all__ = ["Shake", "line", "shake", "steadied"]
