"""Traced pen-stroke sequences for all 70,000 MNIST digits (Edwin de Jong, CC BY-SA 3.0).

The numpy encoding comes as ``train-padded-trailing.npy`` (float64 ``[60000, 117, 4]``)
and ``test-padded-leading.npy`` (``[10000, 117, 4]``), each inside a ``.tar.gz`` of the
same stem, with ``train-labels.npy`` / ``test-labels.npy`` beside them. Row i pairs
with MNIST image i of the same split. Columns are ``dx, dy, eos, eod``:

- all-zero rows pad the sequence at the end (train) or the start (test);
- the first row's ``(dx, dy)`` is the start pixel, positions are the cumulative sum;
- ``eos = 1`` marks the last point of a stroke (the pen lifts after it); the marker row
  itself has ``dx = dy = 0``, so it repeats that point;
- ``eod = 1`` marks the last point of the digit.

Frame
    The cumulative positions are one pixel too far right and down: ``(x - 1, y - 1)``
    lies on ink (bilinear MNIST intensity > 0.5) for 99.4 % of the points of every 20th
    training digit, against 71 % without the shift; it is the best of all half-pixel
    shifts from -1.5 to +0.5 (``img2dmp prepare --check-frames``). :data:`FRAME_OFFSET_PX`
    is that shift; the returned strokes are in the centre convention of
    docs/CONTRACTS.md.
Single-point strokes
    0.7 % of the training digits hold a "stroke" that is one point (a skeleton spur the
    tracer visited and left). It carries no movement; :func:`parse_sequence` drops it and
    counts it in :attr:`StrokeDigit.dropped_strokes`.

The traces have no timing; :class:`SpeedProfile` and :func:`time_strokes` give them one
(constant mean pen speed, minimum-jerk along each stroke, fixed pen-up travel time).
"""

from __future__ import annotations

import os
import tarfile
from collections.abc import Iterable
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .._progress import bar
from ..config import check_positive

#: Added to the cumulative x and y to reach the centre convention (see module docstring).
FRAME_OFFSET_PX = -1.0

#: File stems of the two splits (``<stem>.tar.gz`` or ``<stem>.npy``).
STROKE_FILES = {
    "train": ("train-padded-trailing", "train-labels"),
    "test": ("test-padded-leading", "test-labels"),
}


@dataclass
class StrokeDigit:
    """One traced digit: its strokes as polylines.

    Attributes
    ----------
    index : int
        Row in the file = index of the MNIST image of the same split.
    label : int
        Digit 0-9 (-1 when no labels were read).
    strokes : list of float64 [K_i, 2]
        Pen-down polylines (x = column, y = row, centre convention), each with at least
        two distinct points, consecutive repeats removed; the pen lifts between strokes.
    name : str
        ``file[:member]#row`` it was read from.
    dropped_strokes : int
        Single-point strokes removed (see the module docstring).
    """

    index: int
    label: int
    strokes: list[np.ndarray]
    name: str
    dropped_strokes: int = 0

    @property
    def n_strokes(self) -> int:
        return len(self.strokes)

    def points(self) -> np.ndarray:
        """All stroke points, ``[sum K_i, 2]``."""
        return np.concatenate(self.strokes, axis=0)


@dataclass(frozen=True)
class SpeedProfile:
    """The timing given to traced strokes, which have none (docs/MNIST.md).

    Each stroke of arc length L takes ``max(L / pen_speed_px_s, min_stroke_s)`` seconds
    and follows it with the minimum-jerk profile ``s(u) = L (10u^3 - 15u^4 + 6u^5)``
    (Flash & Hogan 1985), which starts and stops at rest. Between strokes the pen travels
    up in a straight line, also minimum-jerk, in ``pen_up_s`` seconds.

    Attributes
    ----------
    pen_speed_px_s : float
        Mean pen speed while writing, in pixels of the 28 x 28 frame per second. The
        default 51 is the median over the 4,204 recorded human paths (path length /
        duration), so traced and recorded digits take similar times.
    min_stroke_s : float
        Shortest stroke duration.
    pen_up_s : float
        Duration of each pen-up travel.
    """

    pen_speed_px_s: float = 51.0
    min_stroke_s: float = 0.1
    pen_up_s: float = 0.2

    def __post_init__(self) -> None:
        for name, v in asdict(self).items():
            check_positive(f"SpeedProfile.{name}", v)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class _Segment:
    polyline: np.ndarray  # [K, 2]
    duration_s: float
    pen: float
    arc: np.ndarray = field(init=False)  # [K], cumulative arc length

    def __post_init__(self) -> None:
        steps = np.linalg.norm(np.diff(self.polyline, axis=0), axis=1)
        self.arc = np.concatenate([[0.0], np.cumsum(steps)])


def minimum_jerk(u):
    """Minimum-jerk progress ``10u^3 - 15u^4 + 6u^5`` on u in [0, 1] (clipped outside)."""
    u = np.clip(u, 0.0, 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u**2)


def _segments(strokes: list[np.ndarray], profile: SpeedProfile) -> list[_Segment]:
    segs: list[_Segment] = []
    for k, s in enumerate(strokes):
        s = np.asarray(s, dtype=np.float64).reshape(-1, 2)
        if k > 0:
            segs.append(_Segment(np.stack([segs[-1].polyline[-1], s[0]]), profile.pen_up_s, 0.0))
        seg = _Segment(s, 0.0, 1.0)
        seg.duration_s = max(seg.arc[-1] / profile.pen_speed_px_s, profile.min_stroke_s)
        segs.append(seg)
    return segs


def stroke_duration_s(strokes: list[np.ndarray], profile: SpeedProfile | None = None) -> float:
    """Total duration the profile gives a digit (strokes plus pen-up travels)."""
    return float(sum(s.duration_s for s in _segments(strokes, profile or SpeedProfile())))


def time_strokes(
    strokes: list[np.ndarray],
    n_times: int,
    profile: SpeedProfile | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Sample a multi-stroke digit at ``n_times`` evenly spaced instants as ``(x, y, pen)``.

    Parameters
    ----------
    strokes : list of array [K_i, 2]
        Pen-down polylines in writing order (a single point is a dot held for
        ``min_stroke_s``).
    n_times : int
        Number of output instants (>= 2), from 0 to the total duration.
    profile : SpeedProfile
        Timing; default :class:`SpeedProfile()`.

    Returns
    -------
    t_s : float64 [n_times]
        Seconds since the start.
    xyp : float64 [n_times, 3]
        Position (x, y) and pen state: 1 while a stroke is written (its first and last
        instants included), 0 strictly inside a pen-up travel (docs/CONTRACTS.md, d = 3).
    """
    if n_times < 2:
        raise ValueError(f"n_times must be >= 2, got {n_times}")
    if len(strokes) == 0:
        raise ValueError("a digit needs at least one stroke")
    segs = _segments(strokes, profile or SpeedProfile())
    dur = np.array([s.duration_s for s in segs])  # [S]
    starts = np.concatenate([[0.0], np.cumsum(dur)])  # [S + 1]
    t = np.linspace(0.0, starts[-1], n_times)  # [n_times]
    # Instants on a boundary belong to the pen-down side, so every stroke keeps its ends.
    seg_of = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(segs) - 1)
    on_edge = np.isclose(t, starts[seg_of], rtol=0, atol=1e-12)
    prev_down = (seg_of > 0) & on_edge & (np.array([s.pen for s in segs])[seg_of] == 0)
    seg_of = np.where(prev_down, seg_of - 1, seg_of)
    out = np.empty((n_times, 3))
    for k, seg in enumerate(segs):
        m = seg_of == k
        if not m.any():
            continue
        u = (t[m] - starts[k]) / seg.duration_s
        s = minimum_jerk(u) * seg.arc[-1]
        if seg.arc[-1] > 0:
            out[m, 0] = np.interp(s, seg.arc, seg.polyline[:, 0])
            out[m, 1] = np.interp(s, seg.arc, seg.polyline[:, 1])
        else:
            out[m, :2] = seg.polyline[0]
        out[m, 2] = seg.pen
    return t, out


def pen_segments(pen: np.ndarray, threshold: float = 0.5) -> int:
    """Number of pen-down runs in a pen channel ``[T]`` thresholded at ``threshold``."""
    down = np.asarray(pen) > threshold
    return int(down[0]) + int(np.sum(down[1:] & ~down[:-1]))


# --- reading the numpy encoding ------------------------------------------------------


@contextmanager
def _open_npy(path: Path):
    """Yield ``(name, binary file)`` of the one ``.npy`` in ``path`` (.npy or tar archive)."""
    if not path.is_file():
        raise FileNotFoundError(f"no stroke-sequence file at {path}")
    if path.suffix == ".npy":
        with open(path, "rb") as f:
            yield str(path), f
        return
    try:
        tar = tarfile.open(path, "r:*")
    except (tarfile.TarError, OSError, EOFError) as e:
        raise ValueError(f"{path}: not a readable tar archive ({e})") from e
    with tar:
        try:
            member = next((m for m in tar if m.isfile() and m.name.endswith(".npy")), None)
        except (tarfile.TarError, OSError, EOFError) as e:
            raise ValueError(f"{path}: archive is truncated or corrupt ({e})") from e
        if member is None:
            raise ValueError(f"{path}: holds no .npy file")
        yield f"{path}:{member.name}", tar.extractfile(member)


def read_npy(path: str | os.PathLike, n_rows: int | None = None) -> tuple[np.ndarray, str]:
    """Read a ``.npy`` array, or only its first ``n_rows`` rows, from a file or tar archive.

    The archive is streamed: reading the first rows of ``train-padded-trailing.tar.gz``
    does not decompress the rest.

    Returns
    -------
    array, name
        The array and ``file[:member]`` for messages.

    Raises
    ------
    ValueError
        Naming the file, if the header is not a ``.npy`` header, the dtype is an object
        dtype, or the data is shorter than the header says.
    """
    path = Path(path)
    with _open_npy(path) as (name, f):
        try:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
            else:
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
        except (ValueError, OSError, EOFError, tarfile.TarError) as e:
            raise ValueError(f"{name}: not a valid .npy header ({e})") from e
        if dtype.hasobject:
            raise ValueError(f"{name}: object arrays are not accepted")
        if len(shape) == 0:
            raise ValueError(f"{name}: expected an array with rows, got a scalar")
        rows = shape[0] if n_rows is None or fortran else min(int(n_rows), shape[0])
        row_items = int(np.prod(shape[1:], dtype=np.int64))
        want = rows * row_items * dtype.itemsize
        try:
            buf = f.read(want)
        except (OSError, EOFError, tarfile.TarError) as e:
            raise ValueError(f"{name}: data is truncated or corrupt ({e})") from e
        if len(buf) != want:
            raise ValueError(
                f"{name}: data truncated: header says shape {shape} ({want} bytes for "
                f"{rows} row(s)), read {len(buf)}"
            )
    order = "F" if fortran else "C"
    arr = np.frombuffer(buf, dtype=dtype).reshape((rows, *shape[1:]), order=order)
    return (arr[:n_rows] if n_rows is not None else arr), name


def parse_sequence(rows: np.ndarray, name: str, index: int = -1, label: int = -1) -> StrokeDigit:
    """Turn one padded ``[L, 4]`` (dx, dy, eos, eod) sequence into strokes.

    Leading all-zero rows are stripped, the sequence is cut at its ``eod`` row, positions
    are the cumulative sum shifted by :data:`FRAME_OFFSET_PX`, and strokes end at ``eos``
    rows.

    Raises
    ------
    ValueError
        Naming ``name`` and the row, if values are not finite, eos/eod are not 0/1, the
        sequence has no ``eod`` row, non-zero rows follow it, or no stroke has two points.
    """
    rows = np.asarray(rows, dtype=np.float64)
    if rows.ndim != 2 or rows.shape[1] != 4:
        raise ValueError(f"{name}: a sequence must be [L, 4] (dx, dy, eos, eod), got {rows.shape}")
    if not np.isfinite(rows).all():
        raise ValueError(
            f"{name}: row {int(np.flatnonzero(~np.isfinite(rows).all(1))[0])} is not finite"
        )
    flags = rows[:, 2:]
    if not np.isin(flags, (0.0, 1.0)).all():
        k = int(np.flatnonzero(~np.isin(flags, (0.0, 1.0)).all(1))[0])
        raise ValueError(f"{name}: row {k} has eos/eod {flags[k].tolist()}, expected 0 or 1")
    nonzero = np.flatnonzero(np.abs(rows).sum(axis=1) > 0)
    if nonzero.size == 0:
        raise ValueError(f"{name}: sequence is all padding (no points)")
    first = int(nonzero[0])
    ends = np.flatnonzero(rows[first:, 3] == 1) + first
    if ends.size == 0:
        raise ValueError(f"{name}: no end-of-digit (eod = 1) row")
    last = int(ends[0])
    if np.abs(rows[last + 1 :]).sum() > 0:
        k = last + 1 + int(np.flatnonzero(np.abs(rows[last + 1 :]).sum(1) > 0)[0])
        raise ValueError(f"{name}: row {k} holds data after the end-of-digit row {last}")
    seq = rows[first : last + 1]  # [L', 4]
    pos = np.cumsum(seq[:, :2], axis=0) + FRAME_OFFSET_PX  # [L', 2]
    stroke_ends = np.flatnonzero((seq[:, 2] == 1) | (np.arange(len(seq)) == len(seq) - 1))
    strokes, dropped, lo = [], 0, 0
    for hi in stroke_ends:
        p = pos[lo : hi + 1]
        keep = np.concatenate([[True], np.any(np.diff(p, axis=0) != 0, axis=1)])
        p = p[keep]
        if len(p) >= 2:
            strokes.append(p)
        else:
            dropped += 1
        lo = hi + 1
    if not strokes:
        raise ValueError(f"{name}: no stroke with two distinct points")
    return StrokeDigit(
        index=index, label=label, strokes=strokes, name=name, dropped_strokes=dropped
    )


def _find(directory: Path, stem: str) -> Path:
    for suffix in (".tar.gz", ".npy", ".tgz", ".tar"):
        p = directory / f"{stem}{suffix}"
        if p.is_file():
            return p
    raise FileNotFoundError(f"no {stem}.tar.gz or {stem}.npy in {directory}")


def load_strokes(
    directory: str | os.PathLike,
    split: str = "train",
    *,
    indices: Iterable[int] | None = None,
    digits: Iterable[int] | None = None,
    progress: bool = False,
) -> list[StrokeDigit]:
    """Load, validate and parse the traced stroke sequences of one MNIST split.

    Parameters
    ----------
    directory : path-like
        Folder with ``<split>-padded-*.tar.gz`` (or ``.npy``) and ``<split>-labels``.
    split : {"train", "test"}
        MNIST split; row i pairs with MNIST image i of that split.
    indices : iterable of int, optional
        Rows to keep (default: all). Only the rows up to the largest one are read.
    digits : iterable of int, optional
        Keep only these labels.
    progress : bool
        Show progress while parsing (:func:`img2dmp._progress.bar`).

    Returns
    -------
    list of StrokeDigit
        In row order.

    Raises
    ------
    ValueError
        Naming the file (and row) at fault: wrong shape, truncated data, counts of
        sequences and labels that differ, malformed sequences, indices out of range.
    """
    if split not in STROKE_FILES:
        raise ValueError(f"stroke split must be one of {sorted(STROKE_FILES)}, got {split!r}")
    directory = Path(directory)
    seq_path = _find(directory, STROKE_FILES[split][0])
    lab_path = _find(directory, STROKE_FILES[split][1])
    idx = None if indices is None else np.unique(np.asarray(list(indices), dtype=np.int64))
    n_rows = None if idx is None or idx.size == 0 else int(idx.max()) + 1
    seqs, seq_name = read_npy(seq_path, n_rows)
    labels, lab_name = read_npy(lab_path, n_rows)
    if seqs.ndim != 3 or seqs.shape[2] != 4:
        raise ValueError(f"{seq_name}: expected shape [n, L, 4], got {seqs.shape}")
    if labels.ndim != 1 or len(labels) != len(seqs):
        raise ValueError(
            f"{lab_name}: {labels.shape} labels for {len(seqs)} sequences in {seq_name}"
        )
    if len(labels) and (labels.min() < 0 or labels.max() > 9):
        raise ValueError(f"{lab_name}: labels must be 0-9, found {labels.min()}..{labels.max()}")
    if idx is None:
        idx = np.arange(len(seqs))
    elif idx.size and (idx.min() < 0 or idx.max() >= len(seqs)):
        raise ValueError(f"{seq_name}: row indices must lie in 0..{len(seqs) - 1}")
    keep = None if digits is None else {int(d) for d in digits}
    out = []
    for i in bar(idx, desc=f"strokes ({split})", unit="digit", enabled=progress):
        if keep is not None and int(labels[i]) not in keep:
            continue
        out.append(parse_sequence(seqs[i], f"{seq_name}#{int(i)}", int(i), int(labels[i])))
    return out
