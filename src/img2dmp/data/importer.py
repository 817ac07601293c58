"""Your own images and pen paths to an img2dmp data set (``img2dmp import``).

A sample is an image of one written shape (a letter, symbol, digit, any class) and the
pen path that wrote it. :func:`import_dataset` reads them from

- a **folder** with one sub-folder per class, named after the class, each holding one
  image per sample (``.png``, ``.jpg``, ``.jpeg``, ``.bmp``, ``.gif``, ``.tif``, ``.tiff``,
  ``.webp``) and its trajectory file of the same stem (``.csv``, ``.json`` or ``.npy``)::

      letters/L/001.png  letters/L/001.csv  letters/T/001.png  letters/T/001.json ...

  Files and folders whose names start with ``.`` are ignored; so are files at the top
  that are not images (a manifest, a README, the data set written there). Every other
  file is part of a sample or refused.
- a **manifest**, a CSV file with the header ``image,trajectory,class`` and optionally
  ``split`` (``train``, ``validation`` or ``test``), or a JSON list of objects with those
  keys. Paths are relative to the manifest's folder (or absolute).
- a **folder of recordings** made on the Record page of ``img2dmp serve --images DIR``
  (``image_<n>.json``, each naming its ``"Image file"`` and digit), with ``images``, the
  folder of the images they trace.
- **Omniglot**: a folder holding ``images_NAME`` and ``strokes_NAME`` (folders, or the
  zip files as distributed), or ``strokes_NAME`` itself with its images beside it or
  given as ``images``; classes ``alphabet/character``, split by drawer (or ``split_by``
  character or alphabet). Its stroke files and their rules: :mod:`img2dmp.data.omniglot`.

**Trajectory files** (:func:`read_trajectory`), in pixels of the sample's own image:
x = column, y = row (y points down), the centre of pixel ``[i, j]`` at ``(x=j, y=i)``;
t in seconds (``time_unit="ms"``: milliseconds), strictly increasing.

- CSV with the header ``x,y,t`` or ``x,y,t,pen`` (any column order): ``pen`` is 1 where
  the pen touches the paper and 0 where it is lifted, so one file holds any number of
  strokes (each a run of pen-down points; the points between are pen-up travel);
- JSON: ``{"x": [...], "y": [...], "t": [...]}`` (optionally ``"pen": [...]``), or a list
  of strokes, each ``{"x": [...], "y": [...], "t": [...]}`` or a list of ``[x, y, t]``
  points (the pen is lifted between strokes), or ``{"strokes": [...]}``;
- NumPy ``.npy``: ``[T, 3]`` (x, y, t) or ``[T, 4]`` (x, y, t, pen);
- a recording in the recorded-path format (:mod:`img2dmp.data.recorded`: a JSON object
  with ``"Path"``, times in milliseconds, the image covering ``[0, W] x [0, H]``, and
  optionally ``"Strokes"``, the pen-down spans), read in its own units and frame.

**What happens to a sample** (:func:`import_samples`):

1. The trajectory is read and checked (numbers, finite, at least 2 points, t strictly
   increasing, pen 0 or 1, every stroke at least 2 points), and must lie within its
   image (no point beyond the border by more than ``OUTSIDE_TOLERANCE`` of the image's
   side).
2. The image is prepared as :func:`img2dmp.data.images.prepare_image` prepares an image
   for a model (polarity from the border, crop to the ink, square with ``margin`` on
   every border, optionally the strokes brought to ``stroke_width_px``, resized to
   ``image_size``): training and prediction then see the same framing.
   :func:`~img2dmp.data.images.prepare_image_framed` gives the map of that crop, pad and
   resize (an :class:`~img2dmp.data.images.ImageFrame`), which moves the path along
   (stored per row in the metadata). At least ``min_on_ink`` of the pen-down path must
   then lie on the prepared image's ink (:func:`img2dmp.metrics.on_ink_share`), which
   catches swapped axes, y pointing up and paths of another image.
3. The path is resampled to ``n_times`` instants (linear interpolation; with strokes,
   ``(x, y, pen)``, the pen 1 on a stroke and 0 on the pen-up travel between): allocated
   per stroke and pen-up stretch in proportion to their durations, at least
   ``min(points, MIN_STROKE_INSTANTS)`` per stroke (a dot: one) and one per stretch, so
   that every stroke keeps its own (:func:`resample_strokes`; ``resample="uniform"``:
   evenly over the path's duration, :func:`resample_pen_path`, which refuses a path whose
   short strokes or lifts fall between its instants); each stroke's first and last
   instant are kept (the data set's ``stroke_spans``). With ``duration_s`` the path is
   rescaled to last that long.

Then ``augment`` random affine copies of every training sample are added
(:func:`img2dmp.data.affine.sample_affine` / ``warp_images`` / ``warp_points``, as
``img2dmp prepare`` does, seeded) and a DMP is fitted to every path
(:func:`img2dmp.data.prepare.fit_paths`). Splits come from the manifest, or are drawn per
class with ``seed`` (``val_fraction``, ``test_fraction`` of each class).

**Classes** are any names: the classes found, sorted (or ``classes``, in its order; a
sample of another class is refused). The data set stores them as ``class_names`` in its
metadata and its ``labels`` index into them (:mod:`img2dmp.data.store`). Classes all named
``"0"`` .. ``"9"`` keep the digits as labels.

**Errors.** Every bad sample raises one ``ValueError`` (or ``FileNotFoundError``) naming
its file and the field, point or value at fault; nothing is skipped silently. With
``skip_bad=True`` bad samples are left out instead and listed, with their errors, in the
metadata (``source.skipped``) and the returned data's ``meta``.
"""

from __future__ import annotations

import csv
import math
import os
import re
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .._files import parse_json
from .._progress import bar as progress_bar
from ..dmp import DMPConfig
from ..metrics import on_ink_share
from .affine import AffineRanges, sample_affine, warp_images, warp_points
from .images import DEFAULT_MARGIN, OUTPUT_SIDE_PX, ImageFrame, prepare_image_framed
from .recorded import parse_recorded
from .store import (
    DIGIT_NAMES,
    MAX_CLASS_NAME_CHARS,
    MAX_CLASSES,
    SPLITS,
    STROKE_SPANS_KEY,
    DigitData,
    pen_runs,
)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".gif", ".tif", ".tiff", ".webp")
TRAJECTORY_SUFFIXES = (".csv", ".json", ".npy")
#: Seconds per unit of the files' ``t``.
TIME_UNITS = {"s": 1.0, "ms": 1e-3}
MANIFEST_COLUMNS = ("image", "trajectory", "class", "split")
#: A point may lie beyond the image's border by at most this share of the image's side.
OUTSIDE_TOLERANCE = 0.1
#: Most points of one trajectory file, and most bytes.
MAX_POINTS = 1_000_000
MAX_TRAJECTORY_BYTES = 256 << 20
#: Most affine copies per training sample.
MAX_AUGMENT = 1000
#: The ways of splitting Omniglot's drawings (img2dmp.data.omniglot.SPLIT_BY).
OMNIGLOT_SPLIT_BY = ("drawer", "character", "alphabet")
#: A recording's file name (``img2dmp serve``'s Record page, the shared recordings).
RECORDING_NAME = re.compile(r"image_(\d+)\.json")


@dataclass
class ImportOptions:
    """Everything that decides how samples become a data set (:func:`import_samples`).

    Attributes
    ----------
    image_size : int
        Side of the stored square images (the model's input), pixels.
    margin : float
        Share of the side left empty around the ink on every border
        (:func:`img2dmp.data.images.prepare_image`), in [0, 0.45].
    n_times : int
        Instants per trajectory (the DMP time grid).
    resample : {"strokes", "uniform"}
        How the instants are placed: ``"strokes"`` allocates them per stroke and pen-up
        stretch, so that every stroke and dot keeps its own (:func:`resample_strokes`);
        ``"uniform"`` spreads them evenly over the path's duration, refusing a path whose
        strokes or lifts that grid loses (:func:`resample_pen_path`, the only way before).
    duration_s : float or None
        Rescale every path to last this long (None: the recorded timing).
    time_unit : {"s", "ms"}
        Unit of the files' ``t``.
    n_dims : int or None
        2 (x, y) or 3 (x, y, pen); None: 3 if any sample has pen-up points or several
        strokes, else 2.
    scaling : str or None
        DMP forcing-term scaling; None: ``"goal-start"`` for d = 2, ``"none"`` for d = 3.
    n_kernels : int
        DMP kernels per dimension.
    ridge : float
        Relative Tikhonov term of the DMP fit.
    augment : int
        Random affine copies added per training sample.
    affine : AffineRanges
        Ranges of those copies' transforms.
    seed : int
        Seed of the augmentation and of the random split.
    val_fraction, test_fraction : float
        Share of each class put in validation / test when the source gives no split (of
        each alphabet's characters, or of the alphabets, with ``split_by``).
    split_by : {"drawer", "character", "alphabet"} or None
        How Omniglot's drawings are split (:mod:`img2dmp.data.omniglot`); None: by
        drawer. Other sources refuse it.
    classes : tuple of str or None
        The class names in label order; None: the classes found, sorted.
    min_on_ink : float
        Least share of a pen-down path on its prepared image's ink, in [0, 1] (0: off).
    stroke_width_px : float or None
        Bring every image's strokes to this pen width in stored pixels (as ``img2dmp
        predict`` does for a model's images), up to a quarter of ``image_size``; None keeps
        each image's own width (scaled with its framing).
    """

    image_size: int = 40
    margin: float = DEFAULT_MARGIN
    n_times: int = 100
    resample: str = "strokes"
    duration_s: float | None = None
    time_unit: str = "s"
    n_dims: int | None = None
    scaling: str | None = None
    n_kernels: int = 25
    ridge: float = 1e-9
    augment: int = 0
    affine: AffineRanges = field(default_factory=AffineRanges)
    seed: int = 0
    val_fraction: float = 0.1
    test_fraction: float = 0.2
    split_by: str | None = None
    classes: tuple[str, ...] | None = None
    min_on_ink: float = 0.5
    stroke_width_px: float | None = None

    def __post_init__(self) -> None:
        lo, hi = OUTPUT_SIDE_PX
        _check_int("image_size", self.image_size, max(8, lo), hi)
        _check_int("n_times", self.n_times, 2, 100_000)
        _check_int("n_kernels", self.n_kernels, 1, 10_000)
        _check_int("augment", self.augment, 0, MAX_AUGMENT)
        _check_int("seed", self.seed, 0, 2**63 - 1)
        _check_number("margin", self.margin, 0.0, 0.45)
        _check_number("min_on_ink", self.min_on_ink, 0.0, 1.0)
        _check_number("val_fraction", self.val_fraction, 0.0, 0.9)
        _check_number("test_fraction", self.test_fraction, 0.0, 0.9)
        if self.val_fraction + self.test_fraction >= 1.0:
            raise ValueError(
                f"val_fraction + test_fraction must be < 1 (some samples must train), got "
                f"{self.val_fraction} + {self.test_fraction}"
            )
        _check_number("ridge", self.ridge, 0.0, 1.0)
        if self.duration_s is not None:
            _check_number("duration_s", self.duration_s, 0.0, 1e6, open_low=True)
        if self.stroke_width_px is not None:
            widest = self.image_size / 4.0
            _check_number("stroke_width_px", self.stroke_width_px, 0.0, widest, open_low=True)
        if self.split_by not in (None, *OMNIGLOT_SPLIT_BY):
            raise ValueError(
                f"split_by must be one of {list(OMNIGLOT_SPLIT_BY)} or None, got {self.split_by!r}"
            )
        if self.resample not in RESAMPLING:
            raise ValueError(f"resample must be one of {list(RESAMPLING)}, got {self.resample!r}")
        if self.time_unit not in TIME_UNITS:
            raise ValueError(f"time_unit must be one of {list(TIME_UNITS)}, got {self.time_unit!r}")
        if self.n_dims not in (None, 2, 3):
            raise ValueError(f"n_dims must be 2 (x, y), 3 (x, y, pen) or None, got {self.n_dims!r}")
        if self.scaling not in (None, "goal-start", "none"):
            raise ValueError(f"scaling must be 'goal-start' or 'none', got {self.scaling!r}")
        if self.n_dims is not None:
            self.dmp_config(self.n_dims)  # a pen channel needs the scaling "none"
        if self.classes is not None:
            self.classes = tuple(self.classes)
            _check_class_list(self.classes)

    def dmp_config(self, n_dims: int) -> DMPConfig:
        """The DMP constants of a data set of ``n_dims`` dimensions."""
        scaling = self.scaling or ("goal-start" if n_dims == 2 else "none")
        if n_dims == 3 and scaling != "none":
            raise ValueError(
                "a pen channel (d = 3) needs scaling 'none': the pen starts and ends down, so "
                "g - y0 = 0 and the goal-start scaling would cancel its forcing term"
            )
        return DMPConfig(n_kernels=self.n_kernels, n_dims=n_dims, scaling=scaling)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["affine"] = self.affine.to_dict()
        d["classes"] = None if self.classes is None else list(self.classes)
        return d


def _check_int(name: str, value, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")


def _check_number(name: str, value, lo: float, hi: float, open_low: bool = False) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or value > hi or value < lo or (open_low and value == lo):
        bound = f"({lo}, {hi}]" if open_low else f"[{lo}, {hi}]"
        raise ValueError(f"{name} must be a number in {bound}, got {value!r}")


def check_class_name(name, where: str) -> str:
    """``name`` if it can name a class (non-empty printable text of at most
    ``MAX_CLASS_NAME_CHARS`` characters, no surrounding spaces), else ``ValueError``."""
    if not isinstance(name, str):
        raise ValueError(f"{where}: class {name!r} must be text")
    if not name or name != name.strip() or not name.isprintable():
        raise ValueError(
            f"{where}: class {name!r} is no class name (non-empty printable text without "
            "surrounding spaces)"
        )
    if len(name) > MAX_CLASS_NAME_CHARS:
        raise ValueError(
            f"{where}: class name {name[:20]!r}... has {len(name)} characters, more than "
            f"{MAX_CLASS_NAME_CHARS}"
        )
    return name


def _check_class_list(names: tuple) -> None:
    if not 1 <= len(names) <= MAX_CLASSES:
        raise ValueError(f"classes must name 1 to {MAX_CLASSES} classes, got {len(names)}")
    for i, name in enumerate(names):
        check_class_name(name, f"classes entry {i}")
        if names.index(name) != i:
            raise ValueError(f"classes entry {i} repeats {name!r}")


# --- trajectory files ----------------------------------------------------------------


@dataclass
class PenPath:
    """A pen path as read from a trajectory file.

    Attributes
    ----------
    xy : float64 [T, 2]
        Positions in pixels of the sample's image (x = column, y = row).
    t_s : float64 [T]
        Seconds, strictly increasing (as given, not shifted to 0).
    stroke : int64 [T]
        The stroke of every point (0, 1, ... in writing order), -1 while the pen is up.
    name : str
        The file it was read from.
    point_name : callable
        ``point_name(k)`` names point ``k`` in messages as the file does (``line 7`` of a
        CSV file, ``stroke 1 point 4`` of a JSON list of strokes, else ``point 7``).
    """

    xy: np.ndarray
    t_s: np.ndarray
    stroke: np.ndarray
    name: str
    point_name: Callable[[int], str] = field(default=lambda k: f"point {k}", repr=False)

    @property
    def n_strokes(self) -> int:
        return int(self.stroke.max()) + 1

    @property
    def needs_pen(self) -> bool:
        """Whether it needs a pen channel: several strokes or pen-up points."""
        return self.n_strokes > 1 or bool((self.stroke < 0).any())


def read_trajectory(path: str | os.PathLike, time_unit: str = "s") -> PenPath:
    """Read and check one trajectory file (CSV, JSON or ``.npy``; the module docstring).

    Raises ``FileNotFoundError`` for a missing file and ``ValueError`` naming the file and
    the row, field or value at fault.
    """
    path = Path(path)
    if time_unit not in TIME_UNITS:
        raise ValueError(f"time_unit must be one of {list(TIME_UNITS)}, got {time_unit!r}")
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
    return _pen_path(path, columns, point_name, unit_s)


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
            f"{path}: header is {','.join(rows[0])!r}; expected the columns x,y,t or x,y,t,pen"
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
                    f"{path}: line {lines[i + 1]}: field {header[j]!r} is {text.strip()!r}, "
                    "not a number"
                ) from None

    def point_name(k: int) -> str:
        return f"line {lines[k + 1]}"

    return {name: values[:, j] for j, name in enumerate(header)}, point_name


def _load_json(path: Path):
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
            raise ValueError(f"{path}: field {field!r} point {k} is {v!r}, not a number")
    return np.asarray(value, dtype=np.float64).reshape(-1)


def _xyt_object(path: Path, obj: dict, where: str, pen_allowed: bool) -> dict[str, np.ndarray]:
    keys = ("x", "y", "t", "pen") if pen_allowed else ("x", "y", "t")
    unknown = sorted(set(obj) - set(keys))
    missing = [k for k in ("x", "y", "t") if k not in obj]
    if unknown or missing:
        raise ValueError(
            f"{path}: {where or 'the object'} has keys {sorted(obj)}; expected {', '.join(keys)}"
            + (" (pen optional)" if pen_allowed else "")
        )
    cols = {k: _number_list(path, obj[k], f"{where}.{k}".lstrip(".")) for k in keys if k in obj}
    sizes = {k: len(v) for k, v in cols.items()}
    if len(set(sizes.values())) != 1:
        raise ValueError(f"{path}: {where or 'the lists'} differ in length: {sizes}")
    return cols


def _stroke_columns(path: Path, stroke, k: int) -> dict[str, np.ndarray]:
    """One stroke of a list of strokes: ``{"x", "y", "t"}`` or ``[[x, y, t], ...]``."""
    if isinstance(stroke, dict):
        return _xyt_object(path, stroke, f"stroke {k}", pen_allowed=False)
    if not isinstance(stroke, list) or not stroke:
        raise ValueError(
            f'{path}: stroke {k} must be {{"x": [...], "y": [...], "t": [...]}} or a '
            "non-empty list of [x, y, t] points"
        )
    for j, p in enumerate(stroke):
        if not isinstance(p, list) or len(p) != 3:
            raise ValueError(f"{path}: stroke {k} point {j} is {p!r}, expected [x, y, t]")
    cols = [
        _number_list(path, [p[i] for p in stroke], f"stroke {k}.{c}") for i, c in enumerate("xyt")
    ]
    return dict(zip("xyt", cols, strict=True))


def _read_json_trajectory(path: Path):
    """The columns of a JSON trajectory, and how to name a point (``point 4``, or in a list
    of strokes ``stroke 1 point 4``)."""
    doc = _load_json(path)
    if isinstance(doc, dict) and "Path" in doc:
        return _recording_columns(path, doc)
    if isinstance(doc, dict) and "strokes" in doc:
        if set(doc) != {"strokes"}:
            raise ValueError(f"{path}: has keys {sorted(doc)}; with 'strokes' no other key")
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
                f'{path}: "Strokes" entry {k} is {span!r}; expected [first, last] point '
                f"indices with {last} < first < last < {n}"
            )
        stroke[span[0] : span[1] + 1] = k
        last = span[1]
    cols = {"x": rec.xy[:, 0], "y": rec.xy[:, 1], "t": rec.t_s, "stroke": stroke}
    return cols, _point_k, 1.0  # t in seconds whatever --time-unit says


def _read_npy_trajectory(path: Path):
    try:
        a = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise ValueError(f"{path}: not a readable NumPy .npy array ({e})") from None
    if not isinstance(a, np.ndarray) or a.dtype.kind not in "iuf":
        raise ValueError(f"{path}: must hold numbers, got dtype {getattr(a, 'dtype', type(a))}")
    if a.ndim != 2 or a.shape[1] not in (3, 4):
        raise ValueError(
            f"{path}: has shape {list(a.shape)}; expected [T, 3] (x, y, t) or [T, 4] (x, y, t, pen)"
        )
    if len(a) > MAX_POINTS:
        raise ValueError(f"{path}: has {len(a)} points, more than {MAX_POINTS}")
    a = a.astype(np.float64)
    return {name: a[:, j] for j, name in enumerate(("x", "y", "t", "pen")[: a.shape[1]])}, _point_k


def _pen_path(path: Path, cols: dict, point, unit_s: float) -> PenPath:
    """Check the columns of a trajectory file and make its :class:`PenPath`; ``point(k)``
    names point ``k`` in messages."""
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
    steps = np.diff(t)
    if (steps <= 0).any():
        k = int(np.argmax(steps <= 0)) + 1
        before, at = float(t[k - 1]), float(t[k])
        raise ValueError(
            f"{path}: field 't' does not increase at {point(k)}: {before!r} then {at!r} "
            "(time stamps must be strictly increasing)"
        )
    if "stroke" in cols:
        stroke = cols["stroke"].astype(np.int64)
    else:
        stroke = _strokes_of_pen(path, cols.get("pen"), n, point)
    for s in range(int(stroke.max()) + 1):
        members = np.flatnonzero(stroke == s)
        if len(members) < 2:
            raise ValueError(
                f"{path}: stroke {s} has 1 point ({point(int(members[0]))}); a stroke needs "
                "at least 2"
            )
    xy = np.stack([cols["x"], cols["y"]], axis=-1)
    return PenPath(xy=xy, t_s=t * unit_s, stroke=stroke, name=str(path), point_name=point)


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


# --- where the samples are ------------------------------------------------------------


@dataclass(frozen=True)
class SampleSource:
    """One sample to import.

    Attributes
    ----------
    image, trajectory : Path or img2dmp.data.omniglot.ArchiveMember
        Its image file and its trajectory file (or a file in a zip).
    class_name : str
    split : {"train", "validation", "test"} or None
        None: drawn at random (:class:`ImportOptions` ``val_fraction``, ``test_fraction``).
    where : str
        Where it was listed, for messages (``manifest.csv: row 3``); empty for a folder.
    format : str
        How the trajectory is read: ``""`` by its suffix (:func:`read_trajectory`),
        ``"omniglot"`` as an Omniglot stroke file (:mod:`img2dmp.data.omniglot`).
    unit, stratum : str or None
        With ``unit``, the samples of one unit go to one split together, the units of
        each ``stratum`` drawn as a class's samples are (Omniglot by character: unit the
        character, stratum its alphabet); None: each sample is its own unit, drawn among
        its class.
    """

    image: Path
    trajectory: Path
    class_name: str
    split: str | None = None
    where: str = ""
    format: str = ""
    unit: str | None = None
    stratum: str | None = None

    @property
    def name(self) -> str:
        """How messages name it: its manifest row, else its trajectory file."""
        return self.where or str(self.trajectory)


def find_samples(
    source: str | os.PathLike,
    *,
    skip_bad: bool = False,
    images: str | os.PathLike | None = None,
    split_by: str | None = None,
) -> tuple[list[SampleSource], list[str]]:
    """The samples of a folder of class folders, of a manifest, of a folder of
    recordings with the folder of the images they trace (``images``), or of Omniglot's
    trees of images and strokes (module docstring; ``split_by``:
    :mod:`img2dmp.data.omniglot`).

    Returns the samples and, with ``skip_bad``, the one-line errors of the files that make
    no sample (an image without trajectory, a stray file, a bad manifest row); without it
    the first such error is raised. A source that is not a folder or manifest at all, a
    folder without class folders and a manifest with a bad header always raise.
    """
    from .omniglot import find_omniglot, omniglot_trees

    source = Path(source)
    if not source.exists():
        raise FileNotFoundError(f"import source {source} does not exist")
    trees = omniglot_trees(source, images)
    if trees is not None:
        samples, problems = find_omniglot(trees, split_by)
        if problems and not skip_bad:
            raise problems[0]
        return samples, [str(e) for e in problems]
    if split_by is not None:
        raise ValueError(
            f"{source}: split_by {split_by!r} (--split-by) is for Omniglot sources; the "
            "split of other sources comes from a manifest or is drawn per class"
        )
    recordings = _recordings_in(source)
    if images is not None and not recordings:
        raise ValueError(
            f"{source}: holds no recordings (image_<n>.json); --images goes with a folder of "
            "recordings made by img2dmp serve --images"
        )
    if recordings:
        samples, problems = _recording_samples(source, recordings, images)
    elif source.is_dir():
        samples, problems = _folder_samples(source)
    elif source.suffix.lower() in (".csv", ".json"):
        samples, problems = _manifest_samples(source)
    else:
        raise ValueError(
            f"{source}: the source must be a folder of class folders or a .csv or .json manifest"
        )
    if problems and not skip_bad:
        raise problems[0]
    return samples, [str(e) for e in problems]


def _recordings_in(source: Path) -> list[Path]:
    """The recordings (``image_<n>.json``) of a folder that holds no class folders."""
    if not source.is_dir():
        return []
    entries = [p for p in sorted(source.iterdir()) if not p.name.startswith(".")]
    if any(p.is_dir() for p in entries):
        return []
    return [p for p in entries if RECORDING_NAME.fullmatch(p.name)]


def _recording_samples(root: Path, files: list[Path], images) -> tuple[list, list]:
    """The samples of a folder of recordings of the images in ``images`` (the Record page
    of ``img2dmp serve --images DIR``): each names its image (``"Image file"``) and its
    digit (``"Image shape"``, the class)."""
    if images is None:
        raise ValueError(
            f"{root}: holds recordings (image_<n>.json); give the folder of the images they "
            "trace with --images DIR (the folder given to img2dmp serve --images)"
        )
    images = Path(images)
    if not images.is_dir():
        raise FileNotFoundError(f"images folder {images} does not exist")
    samples, problems = [], []
    for p in files:
        try:
            doc = _load_json(p)
            if not isinstance(doc, dict):
                raise ValueError(f"{p}: expected a recording (a JSON object)")
            name, label = doc.get("Image file"), doc.get("Image shape")
            if name is None:
                raise ValueError(
                    f'{p}: records MNIST image {doc.get("Image number")!r} (no "Image file"); '
                    f"make a data set of MNIST recordings with img2dmp prepare --recorded {root}"
                )
            if not isinstance(name, str) or not name or Path(name).name != name:
                raise ValueError(f'{p}: "Image file" must be a file name, got {name!r}')
            if not isinstance(label, int) or isinstance(label, bool) or not 0 <= label <= 9:
                raise ValueError(f'{p}: "Image shape" (the digit) must be 0-9, got {label!r}')
            samples.append(SampleSource(images / name, p, str(label)))
        except (ValueError, OSError) as e:
            problems.append(e)
    return samples, problems


def _folder_samples(root: Path) -> tuple[list[SampleSource], list[Exception]]:
    samples: list[SampleSource] = []
    problems: list[Exception] = []
    class_dirs = []
    for p in sorted(root.iterdir()):
        if p.name.startswith("."):
            continue
        if p.is_dir():
            class_dirs.append(p)
        elif p.suffix.lower() in IMAGE_SUFFIXES:
            problems.append(
                ValueError(
                    f"{p}: an image at the top of {root}; put every sample in the folder "
                    f"of its class ({root / 'CLASS' / p.name}), or give a manifest as the source"
                )
            )
    if not class_dirs:
        raise ValueError(
            f"{root}: holds no class folders; expected {root}/CLASS/NAME.png with "
            f"{root}/CLASS/NAME.csv (or .json, .npy), one folder per class"
        )
    for d in class_dirs:
        try:
            name = check_class_name(d.name, str(d))
        except ValueError as e:
            problems.append(e)
            continue
        found, bad = _class_folder(d, name)
        samples += found
        problems += bad
    return samples, problems


def _class_folder(d: Path, name: str) -> tuple[list[SampleSource], list[Exception]]:
    """The samples in the folder of class ``name``, and the files that make none."""
    images: dict[str, Path] = {}
    trajectories: dict[str, Path] = {}
    problems: list[Exception] = []
    for p in sorted(d.iterdir()):
        suffix = p.suffix.lower()
        if p.name.startswith("."):
            continue
        if p.is_dir():
            problems.append(ValueError(f"{p}: a folder in the class folder {d}; samples go in {d}"))
            continue
        group = images if suffix in IMAGE_SUFFIXES else trajectories
        if suffix not in IMAGE_SUFFIXES + TRAJECTORY_SUFFIXES:
            problems.append(
                ValueError(
                    f"{p}: neither an image ({', '.join(IMAGE_SUFFIXES)}) nor a trajectory "
                    f"({', '.join(TRAJECTORY_SUFFIXES)}) file"
                )
            )
        elif p.stem in group:
            problems.append(
                ValueError(f"{p}: {group[p.stem].name} has the same name; one file of each kind")
            )
        else:
            group[p.stem] = p
    samples = []
    for stem in sorted(set(images) | set(trajectories)):
        if stem not in trajectories:
            problems.append(
                FileNotFoundError(f"{images[stem]}: no trajectory file {stem}.csv, .json or .npy")
            )
        elif stem not in images:
            problems.append(
                FileNotFoundError(f"{trajectories[stem]}: no image {stem}.png (.jpg ...)")
            )
        else:
            samples.append(SampleSource(images[stem], trajectories[stem], name))
    if not images and not trajectories and not problems:
        problems.append(ValueError(f"{d}: the folder of class {name!r} holds no samples"))
    return samples, problems


def _manifest_rows(path: Path) -> tuple[list[str], list[dict], str]:
    """The columns and rows (dicts) of a manifest, and what a row is called in messages
    (``row`` n of a CSV file, counted from 1 after the header; ``entry`` n of a JSON list,
    counted from 0)."""
    if path.suffix.lower() == ".json":
        doc = _load_json(path)
        if not isinstance(doc, list) or not all(isinstance(r, dict) for r in doc):
            raise ValueError(
                f'{path}: a JSON manifest is a list of objects {{"image": ..., "trajectory": '
                '..., "class": ..., "split": ...}'
            )
        return sorted({k for r in doc for k in r}), doc, "entry"
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            rows = [r for r in csv.reader(f) if any(c.strip() for c in r)]
    except (UnicodeDecodeError, csv.Error) as e:
        raise ValueError(f"{path}: not a readable UTF-8 CSV manifest ({e})") from None
    if not rows:
        raise ValueError(f"{path}: is empty; expected the header image,trajectory,class[,split]")
    header = [c.strip().lower() for c in rows[0]]
    out = []
    for i, r in enumerate(rows[1:]):
        if len(r) != len(header):
            raise ValueError(f"{path}: row {i + 1} has {len(r)} fields, the header {len(header)}")
        out.append(dict(zip(header, (c.strip() for c in r), strict=True)))
    return header, out, "row"


def _manifest_samples(path: Path) -> tuple[list[SampleSource], list[Exception]]:
    columns, rows, word = _manifest_rows(path)
    unknown = [c for c in columns if c not in MANIFEST_COLUMNS]
    missing = [c for c in MANIFEST_COLUMNS[:3] if c not in columns]
    if unknown or missing or len(set(columns)) != len(columns):
        raise ValueError(
            f"{path}: has the columns {list(columns)}; expected image, trajectory, class and "
            "optionally split"
        )
    if not rows:
        raise ValueError(f"{path}: lists no samples")
    samples, problems, seen = [], [], {}
    for i, row in enumerate(rows):
        where = f"{path}: {word} {i + 1 if word == 'row' else i}"
        try:
            sample = _manifest_sample(path.parent, row, where)
            key = sample.trajectory.resolve()
            if key in seen:
                raise ValueError(f"{where}: repeats the trajectory of {seen[key]}")
            seen[key] = where.split(": ", 1)[1]
            samples.append(sample)
        except ValueError as e:
            problems.append(e)
    return samples, problems


def _manifest_sample(base: Path, row: dict, where: str) -> SampleSource:
    for key in ("image", "trajectory", "class"):
        if key not in row or not isinstance(row[key], str) or not row[key].strip():
            raise ValueError(
                f"{where}: field {key!r} is {row.get(key)!r}; it must be non-empty text"
            )
    split = row.get("split")
    if split in ("", None):
        split = None
    elif not isinstance(split, str) or split not in SPLITS:
        raise ValueError(f"{where}: field 'split' is {split!r}; expected one of {list(SPLITS)}")
    name = check_class_name(row["class"].strip(), where)
    return SampleSource(
        image=base / row["image"].strip(),
        trajectory=base / row["trajectory"].strip(),
        class_name=name,
        split=split,
        where=where,
    )


# --- one sample -----------------------------------------------------------------------


def check_within_image(pen: PenPath, size: tuple[int, int], image_name: str) -> None:
    """Every point within the image of ``size = (H, W)``, or beyond its border by at most
    ``OUTSIDE_TOLERANCE`` of its longer side; else ``ValueError`` naming the point."""
    h, w = size
    tol = OUTSIDE_TOLERANCE * max(w, h)
    x, y = pen.xy[:, 0], pen.xy[:, 1]
    bad = (x < -0.5 - tol) | (x > w - 0.5 + tol) | (y < -0.5 - tol) | (y > h - 0.5 + tol)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(
            f"{pen.name}: {pen.point_name(k)} (x={x[k]:g}, y={y[k]:g}) lies outside the "
            f"{w} x {h} image {image_name} by more than {OUTSIDE_TOLERANCE:.0%} of its side "
            "(x = column, y = row, in pixels of the image)"
        )


def resample_pen_path(pen: PenPath, n_times: int) -> tuple[np.ndarray, np.ndarray]:
    """A pen path at ``n_times`` instants evenly spaced over its duration.

    Positions are interpolated linearly between the recorded points; the pen is down
    (1) on every stretch between two points of one stroke and at the points of a
    stroke, up (0) strictly inside the travel between strokes.

    Returns
    -------
    times : float64 [n_times]
        Seconds since the first point.
    path : float64 [n_times, 3]
        ``(x, y, pen)``.

    Raises ``ValueError`` if a stroke or a pen-up gap is shorter than one step of the
    grid (the strokes would merge or vanish).
    """
    t, s = pen.t_s, pen.stroke
    grid = np.linspace(t[0], t[-1], n_times)  # [n]; its ends are t[0] and t[-1] exactly
    xy = np.stack([np.interp(grid, t, pen.xy[:, j]) for j in range(2)], axis=-1)  # [n, 2]
    k = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 2)  # [n]
    drawn = (s[:-1] == s[1:]) & (s[:-1] >= 0)  # [T-1] segments written
    down = np.where(grid == t[k], s[k] >= 0, drawn[k])
    down = np.where(grid == t[k + 1], s[k + 1] >= 0, down)
    runs = int(down[0]) + int(np.sum(down[1:] & ~down[:-1]))
    if runs != pen.n_strokes:
        step = (t[-1] - t[0]) / (n_times - 1)
        raise ValueError(
            f"{pen.name}: its {pen.n_strokes} stroke(s) become {runs} on the grid of "
            f"{n_times} instants {step:.3g} s apart: a stroke or a pen-up gap is shorter than "
            "a step; use more instants (--n-times)"
        )
    return grid - t[0], np.concatenate([xy, down[:, None].astype(np.float64)], axis=-1)


#: Fewest instants a stroke of this many points or more gets (its two ends and one
#: between); a stroke of fewer points gets one per point, a dot one. Where a drawing's
#: strokes cannot all have it, they get 2 (their ends).
MIN_STROKE_INSTANTS = 3
#: The ways of resampling a path (:class:`ImportOptions` ``resample``).
RESAMPLING = ("strokes", "uniform")


@dataclass
class Resampled:
    """A pen path at the instants of a data set's time grid.

    Attributes
    ----------
    times : float64 [n]
        Seconds since the first point, strictly increasing.
    path : float64 [n, 3]
        ``(x, y, pen)``, pen 1 down, 0 up.
    spans : list of (int, int)
        The first and last instant of every stroke, in writing order (the data set's
        ``stroke_spans``).
    """

    times: np.ndarray
    path: np.ndarray
    spans: list[tuple[int, int]]


def _pieces(pen: PenPath) -> list[tuple[str, float, float, int]]:
    """The strokes and pen-up stretches of a path in time order, as ``(kind, start, end,
    points)``: kind ``"stroke"``, ``"lead"`` (up before the first stroke), ``"up"``
    (between two strokes) or ``"trail"`` (up after the last); points of a stroke only."""
    t, s = pen.t_s, pen.stroke
    out = []
    for k in range(pen.n_strokes):
        members = np.flatnonzero(s == k)
        a, b = float(t[members[0]]), float(t[members[-1]])
        if out:
            out.append(("up", out[-1][2], a, 0))
        elif a > t[0]:
            out.append(("lead", float(t[0]), a, 0))
        out.append(("stroke", a, b, len(members)))
    if out[-1][2] < t[-1]:
        out.append(("trail", out[-1][2], float(t[-1]), 0))
    return out


def _allocate(durations: np.ndarray, least: np.ndarray, n: int) -> np.ndarray:
    """Instants per piece summing to ``n``: in proportion to the pieces' durations, as an
    even grid would give them, but at least ``least`` each (``least.sum() <= n``)."""
    free = np.ones(len(durations), bool)
    while True:  # pin the pieces whose share falls short of their least; share the rest
        budget = n - least[~free].sum()
        share = np.where(free, budget * durations / durations[free].sum(), least)
        short = free & (share < least)
        if not short.any():
            break
        free &= ~short
    counts = np.maximum(np.floor(share).astype(np.int64), least)
    rest = n - int(counts.sum())  # the largest remainders take the instants left
    order = np.argsort(-(share - np.floor(share)) * free, kind="stable")
    counts[order[:rest]] += 1
    return counts


def _piece_times(kind: str, a: float, b: float, k: int, t_own: np.ndarray) -> np.ndarray:
    """``k`` instants of one piece from ``a`` to ``b``: a stroke's both ends (or its own
    points when it has as few as it gets), strictly inside a pen-up stretch between
    strokes, from the start of the path before its first stroke, to its end after the
    last."""
    if kind == "stroke":
        if k == len(t_own) and k <= MIN_STROKE_INSTANTS:
            return t_own
        return np.linspace(a, b, k) if k > 1 else np.array([a])
    u = np.arange(k, dtype=np.float64)
    frac = {"up": (u + 1) / (k + 1), "lead": u / k, "trail": (u + 1) / k}[kind]
    return a + (b - a) * frac


def resample_strokes(pen: PenPath, n_times: int) -> Resampled:
    """A pen path at ``n_times`` instants allocated per stroke, so that none is lost.

    The even grid of :func:`resample_pen_path` loses a stroke or a pen lift shorter than
    its step (a dot has no duration at all). Here every stroke and every pen-up stretch
    gets its own instants, in proportion to its duration as on the even grid, but every
    stroke at least ``min(points, MIN_STROKE_INSTANTS)`` (a dot one, at its time) and
    every pen-up stretch at least one. A stroke's instants run evenly from its first to
    its last point (or are its own points, when it has no more than it gets), a pen-up
    stretch's strictly between the strokes. Positions are interpolated linearly between
    the recorded points; the pen is 1 at a stroke's instants, 0 at the others. A path of
    one stroke gets the even grid.

    Raises ``ValueError`` naming the file if the strokes need more instants than
    ``n_times`` (2 per stroke, 1 per dot and 1 per pen-up stretch at the least).
    """
    pieces = _pieces(pen)
    durations = np.array([b - a for _, a, b, _ in pieces])  # [P]
    for least_points in (MIN_STROKE_INSTANTS, 2):
        least = np.array(
            [min(p, least_points) if kind == "stroke" else 1 for kind, _, _, p in pieces]
        )
        if least.sum() <= n_times:
            break
    else:
        raise ValueError(
            f"{pen.name}: its {pen.n_strokes} strokes and the pen-up travel between them need "
            f"at least {least.sum()} instants, more than the {n_times} of the grid; use more "
            f"instants (--n-times {least.sum()})"
        )
    counts = _allocate(durations, least, n_times)  # [P]
    grid, spans, k, first = [], [], 0, 0
    t = pen.t_s
    for (kind, a, b, _), c in zip(pieces, counts, strict=True):
        own = t[pen.stroke == k] if kind == "stroke" else t[:0]
        grid.append(_piece_times(kind, a, b, int(c), own))
        if kind == "stroke":
            spans.append((first, first + int(c) - 1))
            k += 1
        first += int(c)
    times = np.concatenate(grid)  # [n]
    if not (np.diff(times.astype(np.float32)) > 0).all():
        raise ValueError(
            f"{pen.name}: two of its instants lie closer than a float32 time stamp can tell "
            f"apart ({times[-1] - t[0]:.6g} s long); give the path fewer instants (--n-times)"
        )
    xy = np.stack([np.interp(times, t, pen.xy[:, j]) for j in range(2)], axis=-1)  # [n, 2]
    down = np.zeros(n_times)
    for lo, hi in spans:
        down[lo : hi + 1] = 1.0
    return Resampled(times - t[0], np.concatenate([xy, down[:, None]], axis=-1), spans)


def resample(pen: PenPath, n_times: int, how: str = "strokes") -> Resampled:
    """:func:`resample_strokes` (``how="strokes"``) or :func:`resample_pen_path`
    (``"uniform"``) of a pen path, with the instants of every stroke."""
    if how == "strokes":
        return resample_strokes(pen, n_times)
    times, path = resample_pen_path(pen, n_times)
    return Resampled(times, path, pen_runs(path[:, 2] > 0.5))


@dataclass
class _Sample:
    image: np.ndarray  # [S, S] float32
    times: np.ndarray  # [n] s
    path: np.ndarray  # [n, 3] (x, y, pen) in the prepared image
    frame: ImageFrame  # the sample's image -> the prepared image
    needs_pen: bool
    n_strokes: int
    spans: list[tuple[int, int]]  # each stroke's first and last instant
    shift: tuple[float, float] | None = None  # Omniglot strokes moved onto the ink (px)


def _import_one(src: SampleSource, opt: ImportOptions) -> _Sample:
    """Read, check, prepare and map one sample (module docstring, steps 1-3)."""
    if opt.classes is not None and src.class_name not in opt.classes:
        raise ValueError(
            f"{src.name}: class {src.class_name!r} is not one of the classes {list(opt.classes)}"
        )
    from . import omniglot

    drawing = src.format == omniglot.FORMAT
    pen = (
        omniglot.read_strokes(src.trajectory)
        if drawing
        else read_trajectory(src.trajectory, opt.time_unit)
    )
    image, frame = prepare_image_framed(
        omniglot.image_of(src.image),
        (opt.image_size, opt.image_size),
        margin=opt.margin,
        stroke_width_px=opt.stroke_width_px,
        name=str(src.image),
        clean=not drawing,  # Omniglot's renderings: no paper (omniglot module docstring)
    )
    shift = None
    if drawing:
        pen, shift = omniglot.fit_to_image(pen, image, frame, str(src.image))
    else:
        check_within_image(pen, frame.image_size, str(src.image))
    res = resample(pen, opt.n_times, opt.resample)
    times, path = res.times, frame.to_model(res.path)
    share = float(on_ink_share(image[None], path[None])[0])
    if share < opt.min_on_ink:
        raise ValueError(
            f"{pen.name}: only {share:.0%} of its pen-down path lies on the ink of "
            f"{src.image} (at least {opt.min_on_ink:.0%} needed, --min-on-ink); is it that "
            "image's path, in its pixels, x = column and y = row (y down)?"
        )
    if opt.duration_s is not None:
        times = times * (opt.duration_s / times[-1])
    return _Sample(image, times, path, frame, pen.needs_pen, pen.n_strokes, res.spans, shift)


# --- the data set ---------------------------------------------------------------------


def _read_all(samples, opt: ImportOptions, progress: bool, skip_bad: bool, skipped: list):
    """``(source, _Sample)`` of every good sample; bad ones raise or join ``skipped``."""
    good = []
    for src in progress_bar(samples, desc="import", unit="sample", enabled=progress):
        try:
            good.append((src, _import_one(src, opt)))
        except (ValueError, OSError) as e:
            e = _in_row(e, src)
            if not skip_bad:
                raise e
            skipped.append(str(e))
    n_dims = opt.n_dims or (3 if any(s.needs_pen for _, s in good) else 2)
    if n_dims == 2:
        kept = []
        for src, s in good:
            if s.needs_pen:
                e = ValueError(
                    f"{src.trajectory}: lifts the pen ({s.n_strokes} stroke(s)), but a data "
                    "set of d = 2 holds one pen-down stroke per sample; import with --dims 3"
                )
                if not skip_bad:
                    raise e
                skipped.append(str(e))
            else:
                kept.append((src, s))
        good = kept
    if not good:
        raise ValueError(
            f"no sample could be imported ({len(skipped)} skipped"
            + (f"; the first: {skipped[0]}" if skipped else "")
            + ")"
        )
    return good, n_dims


def _in_row(e: Exception, src: SampleSource) -> Exception:
    """``e`` with the manifest row of ``src`` in front of its message (a folder's samples
    are named by their files, which every message holds already)."""
    if not src.where or str(e).startswith(src.where):
        return e
    try:
        out = type(e)(f"{src.where}: {e}")
    except TypeError:  # an exception class of other arguments
        out = ValueError(f"{src.where}: {e}")
    out.__cause__ = e
    return out


def _class_labels(names: list[str], classes) -> tuple[tuple[str, ...] | None, np.ndarray]:
    """The class names the labels index into (None: the digits themselves) and the labels."""
    if classes is None:
        found = sorted(set(names))
        if all(n in DIGIT_NAMES for n in found):
            return None, np.array([int(n) for n in names], np.int64)
        classes = tuple(found)
    index = {n: i for i, n in enumerate(classes)}
    return tuple(classes), np.array([index[n] for n in names], np.int64)


def _splits(sources: list[SampleSource], labels: np.ndarray, opt: ImportOptions, rng) -> np.ndarray:
    """The split of every sample: the manifest's, or drawn per class."""
    given = [s.split for s in sources]
    if all(g is not None for g in given):
        return np.array([SPLITS[g] for g in given], np.uint8)
    if any(g is not None for g in given):
        first = next(s for s in sources if s.split is None)
        raise ValueError(
            f"{first.name}: gives no split while other rows do; give every row a split or none"
        )
    if any(s.unit is not None for s in sources):
        return _unit_splits(sources, opt, rng)
    split = np.zeros(len(labels), np.uint8)
    for c in np.unique(labels):
        rows = rng.permutation(np.flatnonzero(labels == c))
        n_test, n_val = _split_counts(len(rows), opt)
        split[rows[:n_test]] = SPLITS["test"]
        split[rows[n_test : n_test + n_val]] = SPLITS["validation"]
    return split


def _split_counts(n: int, opt: ImportOptions) -> tuple[int, int]:
    """How many of ``n`` samples (or units) go to test and to validation: the options'
    fractions, rounded, at least one left to train on."""
    n_test = min(int(math.floor(opt.test_fraction * n + 0.5)), n - 1)
    n_val = int(math.floor(opt.val_fraction * n + 0.5))
    return n_test, min(n_val, n - n_test - 1)


def _unit_splits(sources: list[SampleSource], opt: ImportOptions, rng) -> np.ndarray:
    """The split of every sample when whole units go to one split (Omniglot by
    character or alphabet): the units of each stratum drawn with the fractions."""
    units = [(s.stratum or "", s.unit or s.name) for s in sources]
    unit_split = {}
    for stratum in sorted({st for st, _ in units}):
        names = sorted({u for st, u in units if st == stratum})
        order = [names[i] for i in rng.permutation(len(names))]
        n_test, n_val = _split_counts(len(names), opt)
        for i, name in enumerate(order):
            code = "test" if i < n_test else "validation" if i < n_test + n_val else "train"
            unit_split[(stratum, name)] = SPLITS[code]
    return np.array([unit_split[u] for u in units], np.uint8)


def _augment(images, paths, split, opt: ImportOptions, rng, progress: bool):
    """``opt.augment`` random affine copies of every training sample appended: images,
    paths, the source row of every sample and its copy number (0 = the original)."""
    rows = np.arange(len(paths))
    copy = np.zeros(len(paths), np.int64)
    train = np.flatnonzero(split == SPLITS["train"])
    if not opt.augment or not len(train):
        return images, paths, rows, copy
    src = np.repeat(train, opt.augment)  # [A]
    mats = sample_affine(rng, len(src), opt.image_size, opt.affine)  # [A, 2, 3]
    out = np.empty((len(src), opt.image_size, opt.image_size), np.float32)
    chunk = 4096  # bounds the memory of the warp
    for lo in progress_bar(
        range(0, len(src), chunk), desc="augment", unit="chunk", enabled=progress
    ):
        sl = slice(lo, lo + chunk)
        out[sl] = warp_images(images[src[sl]], mats[sl]).clamp(0.0, 1.0).numpy()
    return (
        np.concatenate([images, out]),
        np.concatenate([paths, warp_points(paths[src], mats)]),
        np.concatenate([rows, src]),
        np.concatenate([copy, np.tile(np.arange(1, opt.augment + 1), len(train))]),
    )


def _relative(path, root: Path | None) -> str:
    """A sample's file relative to the source (a file in a zip: ``ARCHIVE/MEMBER``, the
    archive relative to it)."""
    if not isinstance(path, Path):
        return f"{_relative(path.archive, root)}/{path.name}"
    try:
        return str(path.relative_to(root)) if root is not None else str(path)
    except ValueError:
        return str(path)


def import_samples(
    samples: list[SampleSource],
    options: ImportOptions | None = None,
    *,
    source: str | os.PathLike | None = None,
    progress: bool = False,
    skip_bad: bool = False,
    skipped: list[str] | None = None,
) -> DigitData:
    """Build a data set from listed samples (the steps of the module docstring).

    Parameters
    ----------
    samples : list of SampleSource
    options : ImportOptions
        Default ``ImportOptions()``.
    source : path, optional
        The folder or manifest they came from (recorded in the metadata; the rows' files
        are stored relative to it).
    progress : bool
        Progress bars (one line each when not on a terminal).
    skip_bad : bool
        Leave bad samples out, listed in ``meta["source"]["skipped"]``, instead of raising.
    skipped : list of str, optional
        Errors of files already left out while listing (:func:`find_samples`).

    Returns
    -------
    DigitData
        Not yet written (:func:`img2dmp.data.store.save_dataset`).
    """
    from .prepare import fit_paths

    opt = options or ImportOptions()
    skipped = list(skipped or [])
    good, n_dims = _read_all(samples, opt, progress, skip_bad, skipped)
    config = opt.dmp_config(n_dims)
    sources = [src for src, _ in good]
    class_names, labels = _class_labels([s.class_name for s in sources], opt.classes)
    split_rng, augment_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(opt.seed).spawn(2)
    )
    split = _splits(sources, labels, opt, split_rng)
    images = np.stack([s.image for _, s in good]).astype(np.float32)
    paths = np.stack([s.path[:, :n_dims] for _, s in good])
    images, paths, rows, copy = _augment(images, paths, split, opt, augment_rng, progress)
    times = np.stack([good[r][1].times for r in rows])
    fit = fit_paths(times, paths, config, ridge=opt.ridge, progress=progress)
    root = None if source is None else Path(source)
    root = root.parent if root is not None and not root.is_dir() else root
    meta = _meta(opt, config, good, (class_names, labels[rows], split[rows]), rows, copy, fit, root)
    meta["source"] = {
        "kind": "import",
        "path": None if source is None else str(source),
        "samples": len(good),
        "skipped": skipped,
    }
    if any(src.format == "omniglot" for src in sources):
        shifted = {_relative(src.trajectory, root): list(s.shift) for src, s in good if s.shift}
        meta["source"].update(format="omniglot", split_by=opt.split_by or "drawer", shifted=shifted)
    if class_names is not None:
        meta["class_names"] = list(class_names)
    meta[STROKE_SPANS_KEY] = [[list(span) for span in good[r][1].spans] for r in rows]
    return DigitData(
        images=np.ascontiguousarray(images, dtype=np.float32),
        trajectories=paths.astype(np.float32),
        times=times.astype(np.float32),
        labels=labels[rows].astype(np.int64),
        params=fit.params,
        fit_error_px=fit.error_px,
        split=split[rows].astype(np.uint8),
        meta=meta,
    )


def _meta(opt, config, good, classes, rows, copy, fit, root: Path | None) -> dict:
    """The data set's metadata but ``source`` and ``class_names``; ``classes`` is
    ``(class names or None, labels [M], split [M])`` of the stored rows."""
    class_names, labels, split = classes
    names = class_names or DIGIT_NAMES
    sources = [src for src, _ in good]
    return {
        "dmp_config": config.to_dict(),
        "seed": opt.seed,
        "import": {**opt.to_dict(), "n_dims": config.n_dims, "scaling": config.scaling},
        "counts_by_split": {name: int((split == code).sum()) for name, code in SPLITS.items()},
        "counts_by_class": {names[c]: int((labels == c).sum()) for c in np.unique(labels)},
        "units": "pixels of the stored images (x = column, y = row); a point (x, y) of a "
        "row's own image is at A @ (x, y) + b in the stored image before any augmentation, "
        "[A | b] = rows.image_to_model (img2dmp.data.images.ImageFrame)",
        "rows": {
            "image": [_relative(sources[r].image, root) for r in rows],
            "trajectory": [_relative(sources[r].trajectory, root) for r in rows],
            "image_size": [list(good[r][1].frame.image_size) for r in rows],
            "image_to_model": [good[r][1].frame.image_to_model.tolist() for r in rows],
            "augment_copy": copy.tolist(),
        },
        "fit": _fit_record(fit, labels, names, [sources[r].trajectory for r in rows], root),
    }


#: A DMP fit whose mean error exceeds this (px) is reported as poor (``fit.poor``).
POOR_FIT_PX = 1.0


def _fit_record(fit, labels, names, files, root: Path | None) -> dict:
    """The ``fit`` record: errors overall and per class, and the poor fits (the paper's
    goal-start scaling fails where start and goal nearly coincide: closed shapes)."""
    poor = np.flatnonzero(fit.error_px > POOR_FIT_PX)
    worst = int(np.argmax(fit.error_px))
    return {
        "mean_error_px": float(fit.error_px.mean()),
        "max_error_px": float(fit.max_error_px.max()),
        "mean_error_px_by_class": {
            names[c]: float(fit.error_px[labels == c].mean()) for c in np.unique(labels)
        },
        "poor": {
            "threshold_px": POOR_FIT_PX,
            "rows": int(len(poor)),
            "worst_row": worst,
            "worst_trajectory": _relative(files[worst], root),
            "worst_mean_error_px": float(fit.error_px[worst]),
        },
    }


def import_dataset(
    source: str | os.PathLike,
    options: ImportOptions | None = None,
    *,
    progress: bool = False,
    skip_bad: bool = False,
    images: str | os.PathLike | None = None,
) -> DigitData:
    """Your images and pen paths, from a folder of class folders, a manifest, or a folder
    of recordings and the folder of their ``images``, as a data set (see the module
    docstring for the layout, the formats and the checks).

    ``img2dmp import SOURCE --out FILE`` runs this and saves the result with
    :func:`img2dmp.data.store.save_dataset`. Raises ``ValueError`` or
    ``FileNotFoundError`` naming the file (and row, field or value) of the first bad
    sample, unless ``skip_bad``: then bad samples are left out and listed in
    ``meta["source"]["skipped"]``.
    """
    opt = options or ImportOptions()
    samples, skipped = find_samples(source, skip_bad=skip_bad, images=images, split_by=opt.split_by)
    return import_samples(
        samples, opt, source=source, progress=progress, skip_bad=skip_bad, skipped=skipped
    )
