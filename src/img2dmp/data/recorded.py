"""Recorded human pen paths over MNIST digits (Jožef Stefan Institute; Pahič et al. 2018).

The data comes as ``trajectories.tar.gz`` holding ``trajectories/image_<n>.json``, one
file per traced MNIST **training** image ``n``, with the keys

- ``"Image number"``: ``n``, the index into ``train-images-idx3-ubyte``;
- ``"Image shape"``: despite its name, the digit's label 0-9;
- ``"Path"``: a *string* of comma-separated ``[x, y, t]`` triples, x = column and y = row
  in the 28 x 28 image, t in milliseconds from the first point.

:func:`load_recorded` reads the archive directly (or an unpacked folder), validates every
file and names the one at fault. Two conventions are fixed here (docs/MNIST.md):

Frame
    The recorded x, y put pixel ``[i, j]`` on the square ``[j, j+1) x [i, i+1)`` (corner
    convention): shifting every point by ``-0.5`` in x and y raises the share of points
    on ink (bilinear intensity > 0.5) from 0.795 to 0.887 over all 4,204 paths, the best
    of all half-pixel shifts from -1.5 to +0.5 (``img2dmp prepare --check-frames``).
    :data:`FRAME_OFFSET_PX` is that shift; the returned paths are in the project's
    centre convention (pixel ``[i, j]`` centred at ``(x=j, y=i)``).
Time glitches
    Two of the 4,204 files (``image_30508``, ``image_30740``) hold a time stamp that
    jumps backwards while the points move on smoothly (a clock reset). A step
    ``t[k+1] - t[k] <= 0`` is replaced by the path's median positive step, keeping the
    later steps; each repair is reported with :func:`warnings.warn` naming the file and
    counted in :attr:`RecordedPath.time_repairs`.

The fixed train / validation / test split of these paths is :func:`split_of_index`.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import tarfile
import warnings
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._files import parse_json
from .._progress import bar
from ..errors import show

#: Added to the recorded x and y to reach the centre convention of docs/CONTRACTS.md.
FRAME_OFFSET_PX = -0.5
#: Side of the frame the paths are recorded in (MNIST's 28 x 28 pixels).
FRAME_SIZE_PX = 28
#: Points may lie outside the image, but not further than this from its border.
_MARGIN_PX = 14.0
#: Largest time stamp (ms): beyond it a time stamp is no time of a pen path, and the
#: arithmetic on it would overflow.
MAX_TIME_STAMP_MS = 1e15
_NAME_RE = re.compile(r"(?:^|/)image_(\d+)\.json$")
_KEYS = ("Image number", "Image shape", "Path")

# Split of the recorded paths (docs/MNIST.md): by a hash of the MNIST training index, so
# that a path's part never depends on which other paths a copy of the data holds.
SPLIT_NAMES = ("train", "validation", "test")
SPLIT_FRACTIONS = (0.7, 0.1, 0.2)
_SPLIT_SALT = "img2dmp-mnist-split-v1"


@dataclass
class RecordedPath:
    """One recorded pen path over one MNIST training image.

    Attributes
    ----------
    image_index : int
        Index of the image in ``train-images-idx3-ubyte``.
    label : int
        The digit 0-9 (the file's ``"Image shape"`` key).
    xy : float64 [T, 2]
        Pen positions (x = column, y = row) in pixels of the 28 x 28 image, centre
        convention (pixel ``[i, j]`` centred at ``(j, i)``).
    t_s : float64 [T]
        Seconds since the first point, strictly increasing, ``t_s[0] == 0``.
    name : str
        The file (or archive member) it was read from.
    time_repairs : int
        Backward time steps replaced by the median step (see the module docstring).
    """

    image_index: int
    label: int
    xy: np.ndarray
    t_s: np.ndarray
    name: str
    time_repairs: int = 0

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1])


def split_of_index(image_index: int | Iterable[int]) -> np.ndarray:
    """The fixed data split of a recorded path, from its MNIST training index alone.

    ``u = int(sha256(f"img2dmp-mnist-split-v1:{n}")[:8], 16) / 2**32`` is uniform on
    [0, 1); ``u < 0.7`` is train (0), ``u < 0.8`` validation (1), else test (2). The part
    of an image never depends on which other paths are present, so a user's larger copy
    of the data keeps every test digit of ours in its test part.

    Parameters
    ----------
    image_index : int or iterable of int
        Index (or indices) into MNIST's training images.

    Returns
    -------
    uint8 array [n]
        0 train, 1 validation, 2 test (the codes of the data-set file format).
    """
    idx = np.atleast_1d(
        np.asarray(
            list(image_index) if not np.isscalar(image_index) else image_index, dtype=np.int64
        )
    )
    if idx.size and idx.min() < 0:
        raise ValueError(f"MNIST indices must be >= 0, got {int(idx.min())}")
    u = np.array(
        [
            int(hashlib.sha256(f"{_SPLIT_SALT}:{int(n)}".encode()).hexdigest()[:8], 16) / 2**32
            for n in idx
        ]
    )
    edges = np.cumsum(SPLIT_FRACTIONS)[:-1]  # [0.7, 0.8]
    return np.searchsorted(edges, u, side="right").astype(np.uint8)


def parse_path_string(text: str, name: str = "<string>") -> np.ndarray:
    """Parse the ``"Path"`` string ``"[x, y, t], [x, y, t], ..."`` into ``[T, 3]`` floats.

    Raises ``ValueError`` naming ``name`` if it is not a list of finite numeric triples.
    """
    if not isinstance(text, str):
        raise ValueError(f'{name}: "Path" must be a string, got {type(text).__name__}')
    try:
        triples = json.loads("[" + text + "]")
    except (ValueError, RecursionError) as e:  # not JSON, or past Python's number limit
        raise ValueError(f'{name}: "Path" is not a list of [x, y, t] triples ({e})') from None
    for k, p in enumerate(triples):
        if (
            not isinstance(p, list)
            or len(p) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in p)
        ):
            raise ValueError(f'{name}: "Path" point {k} is {show(p)}, expected [x, y, t] numbers')
    arr = np.asarray(triples, dtype=np.float64).reshape(-1, 3)  # [T, 3]
    if not np.isfinite(arr).all():
        k = int(np.flatnonzero(~np.isfinite(arr).all(axis=1))[0])
        raise ValueError(f'{name}: "Path" point {k} is not finite: {arr[k].tolist()}')
    return arr


def _repair_times(t_ms: np.ndarray, name: str) -> tuple[np.ndarray, int]:
    dt = np.diff(t_ms)  # [T-1]
    bad = dt <= 0
    if not bad.any():
        return t_ms, 0
    good = dt[~bad]
    if good.size == 0:
        raise ValueError(f"{name}: no time stamp after the first increases: {t_ms[:5].tolist()}")
    step = float(np.median(good))
    warnings.warn(
        f"{name}: {int(bad.sum())} time step(s) <= 0 (at point(s) "
        f"{(np.flatnonzero(bad) + 1).tolist()}) replaced by the median step {step:g} ms",
        stacklevel=3,
    )
    dt = np.where(bad, step, dt)
    return np.concatenate([[0.0], np.cumsum(dt)]), int(bad.sum())


def parse_recorded(data: bytes | str | dict, name: str) -> RecordedPath:
    """Validate and convert one ``image_<n>.json`` document.

    Parameters
    ----------
    data : bytes, str or dict
        The file's contents (or the already decoded JSON object).
    name : str
        File or archive-member name, used in every error message and checked against
        ``"Image number"`` when it has the form ``image_<n>.json``.

    Returns
    -------
    RecordedPath
        With positions shifted by :data:`FRAME_OFFSET_PX` and times in seconds.

    Raises
    ------
    ValueError
        Naming ``name`` and the key or value at fault.
    """
    if isinstance(data, (bytes, str)):
        doc = parse_json(data, name)
    else:
        doc = data
    if not isinstance(doc, dict):
        raise ValueError(f"{name}: expected a JSON object, got {type(doc).__name__}")
    missing = [k for k in _KEYS if k not in doc]
    if missing:
        raise ValueError(f"{name}: missing key(s) {missing}; expected {list(_KEYS)}")
    n, label = doc["Image number"], doc["Image shape"]
    if not isinstance(n, int) or isinstance(n, bool) or n < 0:
        raise ValueError(f'{name}: "Image number" must be an integer >= 0, got {show(n)}')
    if not isinstance(label, int) or isinstance(label, bool) or not 0 <= label <= 9:
        raise ValueError(f'{name}: "Image shape" (the label) must be 0-9, got {show(label)}')
    m = _NAME_RE.search(name)
    if m and int(m.group(1)) != n:
        raise ValueError(f'{name}: file name says image {m.group(1)}, "Image number" says {n}')
    arr = parse_path_string(doc["Path"], name)  # [T, 3]
    if len(arr) < 2:
        raise ValueError(f'{name}: "Path" has {len(arr)} point(s); a path needs at least 2')
    h, w = _frame_size(doc, name)
    margin = max(_MARGIN_PX, max(h, w) / 2)
    lo, hi = -margin, np.array([w, h]) + margin
    outside = (arr[:, :2] < lo) | (arr[:, :2] > hi)
    if outside.any():
        k = int(np.flatnonzero(outside.any(axis=1))[0])
        raise ValueError(
            f'{name}: "Path" point {k} = {arr[k, :2].tolist()} lies outside the '
            f"{h} x {w} frame by more than {margin:g} px"
        )
    far = np.abs(arr[:, 2]) > MAX_TIME_STAMP_MS
    if far.any():
        k = int(np.argmax(far))
        raise ValueError(
            f'{name}: "Path" point {k} has the time stamp {float(arr[k, 2])!r} ms, beyond the '
            f"{MAX_TIME_STAMP_MS:g} ms from 0 a time stamp may be"
        )
    t_ms = arr[:, 2] - arr[0, 2]  # [T]; "ms from the first point"
    t_ms, repairs = _repair_times(t_ms, name)
    return RecordedPath(
        image_index=n,
        label=label,
        xy=arr[:, :2] + FRAME_OFFSET_PX,
        t_s=t_ms / 1000.0,
        name=name,
        time_repairs=repairs,
    )


def _frame_size(doc: dict, name: str) -> tuple[int, int]:
    """``(H, W)`` of the image a recording traces: MNIST's 28 x 28, or its ``"Image
    size"`` (recordings of other images, e.g. made with ``img2dmp serve --images``)."""
    size = doc.get("Image size", [FRAME_SIZE_PX, FRAME_SIZE_PX])
    if (
        not isinstance(size, list)
        or len(size) != 2
        or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in size)
    ):
        raise ValueError(
            f'{name}: "Image size" must be [height, width] in pixels, got {show(size)}'
        )
    return size[0], size[1]


def check_recorded_path(path: str | os.PathLike) -> None:
    """``FileNotFoundError`` if ``path`` does not exist, ``ValueError`` if it is a file but
    no tar archive (:func:`load_recorded` reads the archive or a folder); quick, so a
    caller checks it before slower work."""
    path = Path(path)
    if path.is_dir():
        return
    if not path.is_file():
        raise FileNotFoundError(f"no recorded-path archive or folder at {path}")
    try:
        is_tar = tarfile.is_tarfile(path)
    except (OSError, EOFError, ValueError):
        is_tar = False
    if not is_tar:
        what = "is one recording" if path.suffix.lower() == ".json" else "is no tar archive"
        raise ValueError(
            f"{path}: {what}; --recorded (recorded_path) wants the recorded paths' archive "
            "trajectories.tar.gz or a folder of their image_<n>.json files (docs/MNIST.md)"
        )


def _iter_sources(path: Path):
    """Yield ``(name, bytes)`` of every ``image_<n>.json`` in a tar archive or folder."""
    if path.is_dir():
        root = path / "trajectories" if (path / "trajectories").is_dir() else path
        for p in sorted(root.glob("image_*.json")):
            yield str(p), p.read_bytes()
        return
    check_recorded_path(path)
    try:
        tar = tarfile.open(path, "r:*")
    except (tarfile.TarError, OSError, EOFError) as e:
        raise ValueError(f"{path}: not a readable tar archive ({e})") from e
    with tar:
        try:
            for member in tar:
                if not member.isfile() or not _NAME_RE.search(member.name):
                    continue
                f = tar.extractfile(member)
                yield f"{path}:{member.name}", f.read()
        except (tarfile.TarError, OSError, EOFError, ValueError) as e:
            raise ValueError(f"{path}: archive is truncated or corrupt ({e})") from e


def load_recorded(
    path: str | os.PathLike,
    *,
    digits: Iterable[int] | None = None,
    progress: bool = False,
) -> list[RecordedPath]:
    """Load and validate every recorded pen path.

    Parameters
    ----------
    path : path-like
        ``trajectories.tar.gz`` (read in place with :mod:`tarfile`), its unpacked
        ``trajectories/`` folder, or a folder holding that one.
    digits : iterable of int, optional
        Keep only these labels (every file is still validated).
    progress : bool
        Show progress (:func:`img2dmp._progress.bar`).

    Returns
    -------
    list of RecordedPath
        Sorted by MNIST image index.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        Naming the file (or archive member) at fault: broken archive, invalid JSON,
        missing keys, malformed ``"Path"``, duplicate image numbers, or no paths at all.
    """
    path = Path(path)
    keep = None if digits is None else {int(d) for d in digits}
    out: dict[int, RecordedPath] = {}
    for name, data in bar(
        _iter_sources(path), desc="recorded paths", unit="file", enabled=progress
    ):
        rec = parse_recorded(data, name)
        if rec.image_index in out:
            raise ValueError(
                f"{name}: image {rec.image_index} was already read from {out[rec.image_index].name}"
            )
        out[rec.image_index] = rec
    if not out:
        raise ValueError(f"{path}: holds no trajectories/image_<n>.json files")
    return [out[n] for n in sorted(out) if keep is None or out[n].label in keep]


def resample_path(xy: np.ndarray, t_s: np.ndarray, n_times: int) -> tuple[np.ndarray, np.ndarray]:
    """Resample a path to ``n_times`` evenly spaced instants from its own time stamps.

    Linear interpolation in time between the recorded samples (so gaps in the recording
    become straight, constant-speed pieces).

    Parameters
    ----------
    xy : array [T, d]
        Positions (any number of channels).
    t_s : array [T]
        Strictly increasing seconds.
    n_times : int
        Points of the output grid, >= 2.

    Returns
    -------
    grid_s : float64 [n_times]
        ``linspace(t_s[0], t_s[-1], n_times) - t_s[0]``.
    xy_grid : float64 [n_times, d]
    """
    if n_times < 2:
        raise ValueError(f"n_times must be >= 2, got {n_times}")
    t_s = np.asarray(t_s, dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64)
    grid = np.linspace(t_s[0], t_s[-1], n_times)  # [n_times]
    out = np.stack([np.interp(grid, t_s, xy[:, j]) for j in range(xy.shape[1])], axis=-1)
    return grid - t_s[0], out


def share_on_ink(image: np.ndarray, xy: np.ndarray, threshold: float = 0.5) -> float:
    """Share of path points where the image's bilinear intensity exceeds ``threshold``.

    ``image`` is ``[H, W]`` with ink = 1; ``xy`` is ``[T, 2]`` in the centre convention.
    Points outside the image count as off ink. The alignment measure of docs/MNIST.md.
    """
    from scipy.ndimage import map_coordinates

    xy = np.asarray(xy, dtype=np.float64)
    v = map_coordinates(
        np.asarray(image, dtype=np.float64), [xy[:, 1], xy[:, 0]], order=1, cval=0.0
    )
    return float(np.mean(v > threshold)) if len(v) else math.nan
