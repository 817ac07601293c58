"""Trajectory files: one sample's pen path in CSV, JSON, ``.npy`` or the recorded-path
format, read and checked (:func:`read_trajectory`; the formats: :mod:`img2dmp.data.importer`).

In pixels of the sample's own image: x = column, y = row (y points down), the centre of
pixel ``[i, j]`` at ``(x=j, y=i)``; t in seconds (``time_unit="ms"``: milliseconds),
strictly increasing, or with ``spread_repeated`` non-decreasing, a run of equal stamps
spread as Omniglot's reader spreads them (:func:`spread_repeated_stamps`). Every bad file
raises one ``ValueError`` naming it and the line, field or value at fault.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np

from ..._files import parse_json
from ...errors import show
from ..recorded import parse_recorded
from ..resample import PenPath

TRAJECTORY_SUFFIXES = (".csv", ".json", ".npy")
#: Seconds per unit of the files' ``t``.
TIME_UNITS = {"s": 1.0, "ms": 1e-3}
#: Most points of one trajectory file, and most bytes.
MAX_POINTS = 1_000_000
MAX_TRAJECTORY_BYTES = 256 << 20
#: Largest time stamp, in seconds from 0 (a Unix time in seconds is 1.7e9), and longest
#: path, in seconds (as ``duration_s`` and a DMP file's tau): beyond them a time stamp is
#: no time of a pen path, and its arithmetic would overflow.
MAX_TIME_STAMP_S = 1e12
MAX_PATH_DURATION_S = 1e6


def read_trajectory(
    path: str | os.PathLike, time_unit: str = "s", spread_repeated: bool = False
) -> PenPath:
    """Read and check one trajectory file (CSV, JSON or ``.npy``; the module docstring).
    ``spread_repeated``: a time stamp equal to the one before is spread
    (:func:`spread_repeated_stamps`) instead of refused.

    Raises ``FileNotFoundError`` for a missing file and ``ValueError`` naming the file and
    the row, field or value at fault.
    """
    path = Path(path)
    if time_unit not in TIME_UNITS:
        raise ValueError(f"time_unit must be one of {list(TIME_UNITS)}, got {show(time_unit)}")
    if not path.is_file():
        raise FileNotFoundError(f"trajectory file {path} does not exist")
    size = path.stat().st_size
    if size > MAX_TRAJECTORY_BYTES:
        raise ValueError(
            f"{path}: has {size} bytes, more than the {MAX_TRAJECTORY_BYTES} a trajectory "
            "file may have"
        )
    readers = {
        ".csv": _read_csv_trajectory,
        ".json": _read_json_trajectory,
        ".npy": _read_npy_trajectory,
    }
    read = readers.get(path.suffix.lower())
    if read is None:
        raise ValueError(
            f"{path}: not a trajectory file (expected one of {', '.join(TRAJECTORY_SUFFIXES)})"
        )
    # A reader returns the columns and how to name a point, and the seconds per unit of
    # its t when its format fixes them (a recording: milliseconds, already converted).
    columns, point_name, *own_unit_s = read(path)
    unit_s = own_unit_s[0] if own_unit_s else TIME_UNITS[time_unit]
    return _pen_path(path, columns, point_name, unit_s, spread_repeated)


def _point_k(k: int) -> str:
    return f"point {k}"


def _csv_rows(path: Path) -> tuple[list[list[str]], list[int]]:
    """The non-blank rows of a CSV file and their line numbers (1 = the first line)."""
    rows, lines = [], []
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            for r in reader:
                if any(c.strip() for c in r):
                    rows.append(r)
                    lines.append(reader.line_num)
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not a text (UTF-8) CSV file ({e})") from None
    except csv.Error as e:
        raise ValueError(f"{path}: not a readable CSV file ({e})") from None
    return rows, lines


def _read_csv_trajectory(path: Path):
    """The columns of a CSV trajectory, and how to name a point (its line)."""
    rows, lines = _csv_rows(path)
    if not rows:
        raise ValueError(f"{path}: is empty; expected the header x,y,t or x,y,t,pen")
    header = [c.strip().lower() for c in rows[0]]
    if sorted(header) not in (["t", "x", "y"], ["pen", "t", "x", "y"]):
        raise ValueError(
            f"{path}: header is {show(','.join(rows[0]))}; expected the columns x,y,t or x,y,t,pen"
        )
    if len(rows) - 1 > MAX_POINTS:
        raise ValueError(f"{path}: has {len(rows) - 1} points, more than {MAX_POINTS}")
    values = np.empty((len(rows) - 1, len(header)))
    for i, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise ValueError(
                f"{path}: line {lines[i + 1]} has {len(row)} fields, the header {len(header)}"
            )
        for j, text in enumerate(row):
            try:
                values[i, j] = float(text)
            except ValueError:
                raise ValueError(
                    f"{path}: line {lines[i + 1]}: field {header[j]!r} is {show(text.strip())}, "
                    "not a number"
                ) from None

    def point_name(k: int) -> str:
        return f"line {lines[k + 1]}"

    return {name: values[:, j] for j, name in enumerate(header)}, point_name


def load_json(path: Path):
    with open(path, "rb") as f:
        return parse_json(f.read(), str(path))


def _number_list(path: Path, value, field: str) -> np.ndarray:
    """A JSON list of numbers as float64 ``[n]``, else ``ValueError`` naming the field."""
    if not isinstance(value, list):
        raise ValueError(f"{path}: field {field!r} must be a list of numbers")
    if len(value) > MAX_POINTS:
        raise ValueError(f"{path}: field {field!r} has {len(value)} points, more than {MAX_POINTS}")
    for k, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{path}: field {field!r} point {k} is {show(v)}, not a number")
    return np.asarray(value, dtype=np.float64).reshape(-1)


def _xyt_object(path: Path, obj: dict, where: str, pen_allowed: bool) -> dict[str, np.ndarray]:
    keys = ("x", "y", "t", "pen") if pen_allowed else ("x", "y", "t")
    unknown = sorted(set(obj) - set(keys))
    missing = [k for k in ("x", "y", "t") if k not in obj]
    if unknown or missing:
        raise ValueError(
            f"{path}: {where or 'the object'} has keys {show(sorted(obj))}; expected "
            f"{', '.join(keys)}" + (" (pen optional)" if pen_allowed else "")
        )
    cols = {k: _number_list(path, obj[k], f"{where}.{k}".lstrip(".")) for k in keys if k in obj}
    sizes = {k: len(v) for k, v in cols.items()}
    if len(set(sizes.values())) != 1:
        raise ValueError(f"{path}: {where or 'the lists'} differ in length: {sizes}")
    return cols


def _stroke_columns(path: Path, stroke, k: int) -> dict[str, np.ndarray]:
    """One stroke of a list of strokes: ``{"x", "y", "t"}`` or ``[[x, y, t], ...]``."""
    if isinstance(stroke, dict):
        cols = _xyt_object(path, stroke, f"stroke {k}", pen_allowed=False)
        if len(cols["x"]) == 0:
            raise ValueError(f"{path}: stroke {k} has no points; a stroke needs at least one")
        return cols
    if not isinstance(stroke, list) or not stroke:
        raise ValueError(
            f'{path}: stroke {k} must be {{"x": [...], "y": [...], "t": [...]}} or a '
            "non-empty list of [x, y, t] points"
        )
    for j, p in enumerate(stroke):
        if not isinstance(p, list) or len(p) != 3:
            raise ValueError(f"{path}: stroke {k} point {j} is {show(p)}, expected [x, y, t]")
    cols = [
        _number_list(path, [p[i] for p in stroke], f"stroke {k}.{c}") for i, c in enumerate("xyt")
    ]
    return dict(zip("xyt", cols, strict=True))


def _read_json_trajectory(path: Path):
    """The columns of a JSON trajectory, and how to name a point (``point 4``, or in a list
    of strokes ``stroke 1 point 4``)."""
    doc = load_json(path)
    if isinstance(doc, dict) and "Path" in doc:
        return _recording_columns(path, doc)
    if isinstance(doc, dict) and "strokes" in doc:
        if set(doc) != {"strokes"}:
            raise ValueError(f"{path}: has keys {show(sorted(doc))}; with 'strokes' no other key")
        doc = doc["strokes"]
    if isinstance(doc, dict):
        return _xyt_object(path, doc, "", pen_allowed=True), _point_k
    if not isinstance(doc, list) or not doc:
        raise ValueError(
            f'{path}: expected {{"x": [...], "y": [...], "t": [...]}} or a non-empty list of '
            "strokes"
        )
    strokes = [_stroke_columns(path, s, k) for k, s in enumerate(doc)]
    cols = {c: np.concatenate([s[c] for s in strokes]) for c in "xyt"}
    cols["stroke"] = np.concatenate([np.full(len(s["x"]), k) for k, s in enumerate(strokes)])
    starts = np.cumsum([0] + [len(s["x"]) for s in strokes])

    def point_name(k: int) -> str:
        s = int(np.searchsorted(starts, k, side="right") - 1)
        return f"stroke {s} point {k - int(starts[s])}"

    return cols, point_name


def _recording_columns(path: Path, doc: dict):
    """The columns of a recording in the recorded-path format (:mod:`.recorded`: the
    shared recordings, or ``img2dmp serve``'s Record page): its corner-convention points
    moved to pixel centres, its milliseconds to seconds, its ``"Strokes"`` (pen-down
    spans ``[first, last]`` of point indices; one stroke without them) to strokes."""
    rec = parse_recorded(doc, str(path))
    n = len(rec.xy)
    spans = doc.get("Strokes")
    stroke = np.zeros(n, np.int64) if spans is None else np.full(n, -1, np.int64)
    if spans is not None and (not isinstance(spans, list) or not spans):
        raise ValueError(f'{path}: "Strokes" must be a non-empty list of [first, last] points')
    last = -1
    for k, span in enumerate(spans or []):
        ok = isinstance(span, list) and len(span) == 2
        ok = ok and all(isinstance(v, int) and not isinstance(v, bool) for v in span)
        if not ok or not last < span[0] < span[1] < n:
            raise ValueError(
                f'{path}: "Strokes" entry {k} is {show(span)}; expected [first, last] point '
                f"indices with {last} < first < last < {n}"
            )
        stroke[span[0] : span[1] + 1] = k
        last = span[1]
    cols = {"x": rec.xy[:, 0], "y": rec.xy[:, 1], "t": rec.t_s, "stroke": stroke}
    return cols, _point_k, 1.0  # t in seconds whatever --time-unit says


def _npy_header(path: Path, f) -> tuple[tuple, np.dtype]:
    """The shape and dtype a ``.npy`` file's header declares, checked against the file:
    a NumPy file, of numbers, holding as many bytes as its shape needs (read before the
    array is, so a header that claims a huge array is refused without allocating it)."""
    from numpy.lib import format as npy

    start = f.read(len(npy.MAGIC_PREFIX))
    if not start:
        raise ValueError(f"{path}: is empty; expected a NumPy .npy array [T, 3] or [T, 4]")
    if start != npy.MAGIC_PREFIX:
        raise ValueError(
            f"{path}: not a NumPy .npy file (it does not begin with the .npy signature "
            "\\x93NUMPY); save the array with numpy.save"
        )
    f.seek(0)
    try:
        version = npy.read_magic(f)
    except (ValueError, OSError, EOFError) as e:
        raise ValueError(f"{path}: not a readable NumPy .npy array ({e})") from None
    read_header = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
    try:
        shape, _, dtype = read_header(f)
    except (ValueError, OSError, EOFError, TypeError) as e:
        raise ValueError(f"{path}: not a readable NumPy .npy array (bad header: {e})") from None
    if dtype.hasobject or dtype.kind not in "iuf":
        raise ValueError(f"{path}: must hold numbers, got dtype {dtype}")
    held = (path.stat().st_size - f.tell()) // dtype.itemsize
    if math.prod(shape) != held:
        said = " x ".join(str(n) for n in shape) or "1"
        raise ValueError(
            f"{path}: its header says {said} numbers but the file holds {held} (a truncated or "
            "damaged file)"
        )
    return shape, dtype


def _read_npy_trajectory(path: Path):
    with open(path, "rb") as f:
        shape, _ = _npy_header(path, f)
        if len(shape) != 2 or shape[1] not in (3, 4):
            raise ValueError(
                f"{path}: has shape {list(shape)}; expected [T, 3] (x, y, t) or [T, 4] "
                "(x, y, t, pen)"
            )
        if shape[0] > MAX_POINTS:
            raise ValueError(f"{path}: has {shape[0]} points, more than {MAX_POINTS}")
        f.seek(0)
        try:
            a = np.lib.format.read_array(f, allow_pickle=False)
        except (ValueError, OSError, EOFError) as e:
            raise ValueError(f"{path}: not a readable NumPy .npy array ({e})") from None
    a = a.astype(np.float64)
    return {name: a[:, j] for j, name in enumerate(("x", "y", "t", "pen")[: a.shape[1]])}, _point_k


def spread_repeated_stamps(t: np.ndarray) -> np.ndarray:
    """Non-decreasing time stamps ``t``, not all equal, with every run of equal stamps
    spread evenly up to the next stamp (the last run: back from the one before up to
    theirs): a tablet that logs two points in one clock tick. Omniglot's rule for the
    stamps of one stroke (:mod:`.omniglot`); ``img2dmp import --spread-repeated-times``
    applies it to a whole trajectory file."""
    out = t.copy()
    starts = np.flatnonzero(np.concatenate([[True], t[1:] != t[:-1]]))  # first of each run
    ends = np.concatenate([starts[1:], [len(t)]])  # one past the last
    for a, b in zip(starts, ends, strict=True):
        k = b - a
        if k == 1:
            continue
        if b < len(t):
            out[a:b] = t[a] + (t[b] - t[a]) * np.arange(k) / k
        else:
            out[a:b] = t[a] - (t[a] - t[a - 1]) * np.arange(k - 1, -1, -1) / k
    return out


def _pen_path(path: Path, cols: dict, point, unit_s: float, spread: bool = False) -> PenPath:
    """Check the columns of a trajectory file and make its :class:`PenPath`; ``point(k)``
    names point ``k`` in messages; ``spread``: repeated time stamps spread
    (:func:`spread_repeated_stamps`)."""
    n = len(cols["x"])
    if n < 2:
        raise ValueError(f"{path}: has {n} point(s); a path needs at least 2")
    for c in ("x", "y", "t", "pen"):
        if c in cols and not np.isfinite(cols[c]).all():
            k = int(np.argmin(np.isfinite(cols[c])))
            raise ValueError(
                f"{path}: {point(k)}: field {c!r} is {float(cols[c][k])!r}, not a finite number"
            )
    t = cols["t"]
    _check_time_limits(path, t, point, unit_s)
    steps = np.diff(t)
    if spread and (steps >= 0).all() and t[-1] > t[0]:
        t = spread_repeated_stamps(t)
        steps = np.diff(t)
    # Spread, a repeat is no error; a step back is, named before any repeat before it.
    bad = steps < 0 if spread and (steps < 0).any() else steps <= 0
    if bad.any():
        k = int(np.argmax(bad)) + 1
        before, at = float(t[k - 1]), float(t[k])
        hint = "" if spread or steps[k - 1] < 0 else "; --spread-repeated-times spreads a repeat"
        raise ValueError(
            f"{path}: field 't' does not increase at {point(k)}: {before!r} then {at!r} "
            f"(time stamps must be strictly increasing{hint})"
        )
    _check_time_limits(path, t, point, unit_s, since_first=True)
    if "stroke" in cols:
        stroke = cols["stroke"].astype(np.int64)
    else:
        stroke = _strokes_of_pen(path, cols.get("pen"), n, point)
    # A stroke of one point is a dot, kept as a stroke of its own (one instant of the grid).
    xy = np.stack([cols["x"], cols["y"]], axis=-1)
    return PenPath(xy=xy, t_s=t * unit_s, stroke=stroke, name=str(path), point_name=point)


def _check_time_limits(path: Path, t: np.ndarray, point, unit_s: float, since_first=False):
    """``ValueError`` naming the point if a time stamp lies beyond ``MAX_TIME_STAMP_S``
    from 0 (checked before any arithmetic on the time stamps, which such values would
    overflow), or with ``since_first`` (time stamps increasing) more than
    ``MAX_PATH_DURATION_S`` after the first point."""
    limit, reach = (MAX_PATH_DURATION_S, t - t[0]) if since_first else (MAX_TIME_STAMP_S, abs(t))
    beyond = reach > limit / unit_s
    if beyond.any():
        k = int(np.argmax(beyond))
        why = (f"more than {limit:g} s after the first point's {float(t[0])!r}; no pen path "
               "lasts that long" if since_first else
               f"beyond the {limit:g} s from 0 a time stamp may be")  # fmt: skip
        raise ValueError(f"{path}: {point(k)}: field 't' is {float(t[k])!r} "
                         f"{'s' if unit_s == 1.0 else 'ms'}, {why}")  # fmt: skip


def _strokes_of_pen(path: Path, pen: np.ndarray | None, n: int, point) -> np.ndarray:
    """Stroke index of every point from a pen column (runs of 1), -1 where it is 0; one
    stroke without a pen column."""
    if pen is None:
        return np.zeros(n, np.int64)
    bad = (pen != 0) & (pen != 1)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(
            f"{path}: {point(k)}: field 'pen' is {pen[k]:g}; pen is 1 (down) or 0 (up)"
        )
    down = pen == 1
    if not down.any():
        raise ValueError(f"{path}: field 'pen' is 0 at every point; the pen never writes")
    starts = down & ~np.concatenate([[False], down[:-1]])
    return np.where(down, np.cumsum(starts) - 1, -1).astype(np.int64)
