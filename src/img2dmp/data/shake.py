"""A shaken photo: the blur of a camera moved along a row or a column, found and undone.

A hand that moves the phone while the shutter is open smears every stroke along the
movement: a box blur of a few pixels to a dozen. Characters a little apart run together
along it, and the page's characters merge (``experiments/photo_conditions.py``, shake of
9 px along the rows: 21 of the yellow photo's 66 digits found alone). Such a blur leaves
its mark in the image's derivative along the movement: a pixel's change and its
neighbour's are alike (the edges are ramps as long as the blur), which they are not
across it nor in a photo in focus, and unlike a defocus, which blurs every way alike.

:func:`shake` reads it: the correlation of neighbouring derivatives along the rows
(``r_x``) and the columns (``r_y``). A blur along the rows when ``r_x`` is at least
``SHAKE_SMOOTH`` and exceeds ``r_y`` by ``SHAKE_ANISOTROPY`` (and along the columns the
other way round); its length is the lag, from 3 to ``SHAKE_MAX_PX`` pixels, at which the
derivative's correlation along it is the most negative (the far ends of each ramp).
:func:`steadied` then undoes it by a Wiener filter of that box (``SHAKE_WIENER``: the
share of noise to signal it assumes). Only along a row or a column: a shake at a slant
is left as it is.
"""

from __future__ import annotations

import numpy as np

#: An image under this many pixels on its shorter side is not read for a shake.
SHAKE_MIN_SIDE = 64
#: The correlation of neighbouring derivatives along the blur, at least (in focus: 0.0-0.4;
#: shaken 5-9 px: 0.5-0.9, read at a reduction too).
SHAKE_SMOOTH = 0.45
#: ... and above the one across it by this much (a defocus: under 0.05; a page of tall
#: strokes in focus: under 0.2).
SHAKE_ANISOTROPY = 0.25
#: The longest blur looked for (pixels of the image as read).
SHAKE_MAX_PX = 25
#: The Wiener filter's noise-to-signal ratio.
SHAKE_WIENER = 0.02


def _grey(levels: np.ndarray) -> np.ndarray:
    a = np.asarray(levels, np.float32)
    return a.mean(axis=2) if a.ndim == 3 else a


def _correlation(d: np.ndarray, axis: int, lag: int) -> float:
    """The correlation of ``d`` with itself ``lag`` pixels along ``axis``."""
    a, b = (d[:-lag], d[lag:]) if axis == 0 else (d[:, :-lag], d[:, lag:])  # views
    return float(np.mean(a * b, dtype=np.float64))


def shake(levels) -> tuple[int, int] | None:
    """The shake blurring ``levels`` (``[H, W]`` or ``[H, W, 3]``): ``(length_px, axis)``,
    axis 1 along the rows, 0 along the columns; None when there is none to read."""
    grey = _grey(levels)
    if min(grey.shape) < SHAKE_MIN_SIDE:
        return None
    derivs = [np.diff(grey, axis=axis) for axis in (0, 1)]
    derivs = [d - d.mean() for d in derivs]
    power = [float(np.mean(d * d, dtype=np.float64)) + 1e-12 for d in derivs]
    near = [
        _correlation(d, axis, 1) / p for axis, (d, p) in enumerate(zip(derivs, power, strict=True))
    ]
    axis = int(np.argmax(near))
    if near[axis] < SHAKE_SMOOTH or near[axis] - near[1 - axis] < SHAKE_ANISOTROPY:
        return None
    d, p = derivs[axis], power[axis]
    lags = range(3, min(SHAKE_MAX_PX, d.shape[axis] // 4) + 1)
    corr = [_correlation(d, axis, lag) / p for lag in lags]
    return (lags[int(np.argmin(corr))], axis) if corr else None


def steadied(levels, found: tuple[int, int] | None = None) -> np.ndarray:
    """``levels`` with the shake :func:`shake` finds (or ``found``) undone, ``float32``
    in [0, 1] and of the same shape; ``levels`` as they are when there is none."""
    found = shake(levels) if found is None else found
    if found is None:
        return levels
    length, axis = found
    a = np.asarray(levels, np.float32)
    planes = a[..., None] if a.ndim == 2 else a
    pad = 2 * length
    n = planes.shape[axis] + 2 * pad
    box = np.zeros(n)
    box[:length] = 1.0 / length
    otf = np.fft.rfft(np.roll(box, -(length // 2)))
    wiener = (np.conj(otf) / (np.abs(otf) ** 2 + SHAKE_WIENER)).astype(np.complex64)
    wiener = wiener.reshape((-1, 1) if axis == 0 else (1, -1))
    widths = [(pad, pad) if k == axis else (0, 0) for k in (0, 1)]
    keep = [slice(None), slice(None)]
    keep[axis] = slice(pad, pad + planes.shape[axis])
    out = np.empty(planes.shape, np.float32)
    for c in range(planes.shape[2]):  # a channel at a time: a third of the memory
        spectrum = np.fft.rfft(np.pad(planes[..., c], widths, mode="reflect"), axis=axis)
        spectrum *= wiener
        out[..., c] = np.fft.irfft(spectrum, n=n, axis=axis)[tuple(keep)]
    np.clip(out, 0.0, 1.0, out=out)
    return out[..., 0] if a.ndim == 2 else out


__all__ = ["shake", "steadied"]
