"""The img2dmp data-set file: one ``.safetensors`` file per data set.

The layout is fixed by ``docs/CONTRACTS.md`` and described for users in
``docs/DATASET.md``. Tensors (M samples, T time stamps, d dimensions, P = N*d + 1 + 2d)::

    images        float32 [M, H, W]   ink = 1, background = 0
    trajectories  float32 [M, T, d]   pen path in image pixels (x = column, y = row)
    times         float32 [M, T]      seconds since the start of the movement
    labels        int64   [M]         digit 0-9, or an index into ``class_names``
    params        float32 [M, P]      fitted DMP, flat vector (DMPParams.to_vector)
    fit_error_px  float32 [M]         mean error of that fit in pixels
    split         uint8   [M]         0 train, 1 validation, 2 test

The safetensors header's ``__metadata__`` holds one key ``"img2dmp"`` whose value is a
JSON object with at least ``format``, ``version``, ``dmp_config``, ``source``, ``seed``,
``image_size`` and ``created``. Files are written atomically: to a temporary file in the
target's directory, flushed to disk, then moved over the target with :func:`os.replace`,
so a reader never sees half a file.

**Checksum.** A second metadata key, ``"img2dmp_sha256"``, holds the SHA-256 of the
``"img2dmp"`` JSON text exactly as stored and of the seven tensors (name, dtype, shape and
little-endian bytes, in the order above): :func:`content_digest`. :func:`load_dataset`
verifies it before anything else, so a flipped bit in the arrays or an edited metadata
field gives one :class:`DatasetError` naming the file and saying it was modified or is
corrupt. It is a checksum against accidents, not a signature. Files written before the
checksum was introduced (same format version 1, no ``"img2dmp_sha256"`` key) are still
read, unverified beyond the checks of :meth:`DigitData.validate`; saving such a data set
again adds the checksum.

**Class names.** A data set of other classes than the digits (letters, symbols, shapes:
``img2dmp import``) holds their names in the metadata key ``class_names``: a JSON list of
distinct, non-empty strings, and its ``labels`` index into it (``0 .. len - 1``). Without
the key, labels are the digits 0-9, as in every file written before the key existed, which
load unchanged (the format version stays 1). :attr:`DigitData.label_names` gives the name of
every label either way, :meth:`DigitData.labels_of_digits` maps digits to labels.

**Stroke spans.** A data set whose paths are made of strokes (``img2dmp import``) may
hold in the metadata key ``stroke_spans`` which instants belong to which stroke: one entry
per row, a list of ``[first, last]`` instant indices (inclusive) per stroke in writing
order, each stroke after the one before (``0 <= first <= last < T``); the instants of no
span are pen-up travel. With a pen channel (d = 3) the pen is down (> 0.5) at exactly the
spans' instants. Files without the key load as before (format version 1);
:meth:`DigitData.stroke_spans` then reads the strokes off the pen channel.

Every value check names the file, the field and the first row at fault.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from safetensors import SafetensorError, safe_open
from safetensors.numpy import save as _st_save

from .._files import atomic_write_bytes, check_readable, parse_json
from ..dmp import DMPConfig, DMPParams

FORMAT = "img2dmp-dataset"
VERSION = 1
META_KEY = "img2dmp"
CHECKSUM_KEY = "img2dmp_sha256"
SPLITS = {"train": 0, "validation": 1, "test": 2}

# name -> (dtype, rank); the shapes' consistency is checked in DigitData.validate.
_FIELDS: dict[str, tuple[np.dtype, int]] = {
    "images": (np.dtype(np.float32), 3),
    "trajectories": (np.dtype(np.float32), 3),
    "times": (np.dtype(np.float32), 2),
    "labels": (np.dtype(np.int64), 1),
    "params": (np.dtype(np.float32), 2),
    "fit_error_px": (np.dtype(np.float32), 1),
    "split": (np.dtype(np.uint8), 1),
}
_REQUIRED_META = ("format", "version", "dmp_config", "source", "seed", "image_size", "created")
#: The metadata key of the class names, and its bounds.
CLASS_NAMES_KEY = "class_names"
MAX_CLASSES = 10_000
#: Smallest side of a data set's images: what generate, import and prepare make at the
#: least. A 1 x 1 "image" holds no shape to learn a movement from.
MIN_IMAGE_SIDE = 8
#: Pen positions (a path's, a DMP's goal and start) lie within this many image sides of
#: the image's centre: farther, a value is not a position of this image (1e30 was read
#: as a path, and an evaluation wrote Infinity).
MAX_POSITION_SIDES = 10
MAX_CLASS_NAME_CHARS = 100
#: The metadata key of the stroke spans (module docstring).
STROKE_SPANS_KEY = "stroke_spans"
#: The names of the labels of a data set without ``class_names``.
DIGIT_NAMES = tuple(str(d) for d in range(10))


class DatasetError(ValueError):
    """A data set (file or arrays) that is corrupt, modified, truncated or invalid."""


def content_digest(meta_text: str, arrays: dict) -> str:
    """SHA-256 of a data set's metadata JSON text and its seven tensors (module docstring)."""
    h = hashlib.sha256(meta_text.encode("utf-8") + b"\0")
    for name in _FIELDS:
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.name}|{list(a.shape)}|".encode())
        h.update(a.astype(a.dtype.newbyteorder("<"), copy=False).reshape(-1).view(np.uint8))
    return h.hexdigest()


def digits_named(names, what: str) -> tuple[int, ...]:
    """The digits that class names ``"0"`` .. ``"9"`` stand for (classes where only digits
    exist, e.g. of the synthetic generator); ``ValueError`` naming ``what`` otherwise."""
    bad = [str(n) for n in names if str(n) not in DIGIT_NAMES]
    if bad:
        raise ValueError(f"{what}: the synthetic generator draws digits 0-9, not {bad}")
    return tuple(int(n) for n in names)


def check_class_names(names, where: str = "data set") -> tuple[str, ...]:
    """``names`` as a tuple if it is a list of 1 to ``MAX_CLASSES`` distinct class names,
    each a non-empty string of at most ``MAX_CLASS_NAME_CHARS`` printable characters
    without surrounding white space; else :class:`DatasetError` naming the entry."""
    what = f"{where}: metadata field {CLASS_NAMES_KEY!r}"
    if not isinstance(names, (list, tuple)):
        raise DatasetError(f"{what} must be a list of strings, got {type(names).__name__}")
    if not 1 <= len(names) <= MAX_CLASSES:
        raise DatasetError(f"{what} must hold 1 to {MAX_CLASSES} names, got {len(names)}")
    seen: dict[str, int] = {}
    for i, name in enumerate(names):
        if not isinstance(name, str):
            raise DatasetError(f"{what} entry {i} is {name!r}, not a string")
        if not name or name != name.strip() or not name.isprintable():
            raise DatasetError(
                f"{what} entry {i} is {name!r}: a class name must be non-empty printable "
                "text without surrounding spaces"
            )
        if len(name) > MAX_CLASS_NAME_CHARS:
            raise DatasetError(
                f"{what} entry {i} has {len(name)} characters, more than {MAX_CLASS_NAME_CHARS}"
            )
        if name in seen:
            raise DatasetError(f"{what} entry {i} repeats {name!r} (entry {seen[name]})")
        seen[name] = i
    return tuple(names)


def _is_span(span) -> bool:
    """Whether ``span`` is a ``[first, last]`` pair of integers (JSON numbers, not
    booleans)."""
    return (
        isinstance(span, (list, tuple))
        and len(span) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) for v in span)
    )


def pen_runs(down: np.ndarray) -> list[tuple[int, int]]:
    """``(first, last)`` of every run of True in ``down`` (bool ``[T]``)."""
    d = np.concatenate([[False], np.asarray(down, bool), [False]])
    edges = np.flatnonzero(d[1:] != d[:-1])  # starts and ends + 1, alternating
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _first_row(bad: np.ndarray) -> int:
    """The first row (index along the first axis) where ``bad`` holds a True."""
    return int(np.argmax(bad.reshape(bad.shape[0], -1).any(axis=1)))


@dataclass
class DigitData:
    """The arrays of one data set plus its metadata (one row per sample).

    Attributes
    ----------
    images : float32 [M, H, W]
    trajectories : float32 [M, T, d]
    times : float32 [M, T]
    labels : int64 [M]
    params : float32 [M, P]
        Flat DMP vectors in the order of :class:`img2dmp.dmp.DMPParams`.
    fit_error_px : float32 [M]
    split : uint8 [M]
        0 train, 1 validation, 2 test (see ``SPLITS``).
    meta : dict
        JSON-ready metadata; must hold ``dmp_config`` (a ``DMPConfig.to_dict()``),
        ``source`` (a dict saying where the samples came from, e.g. the generator config)
        and ``seed`` (int or None); may hold ``class_names`` (the labels then index into
        it, see the module docstring) and ``stroke_spans`` (each row's strokes: the
        module docstring). ``format``, ``version``, ``image_size`` and ``created`` are
        filled in by :func:`save_dataset`.
    """

    images: np.ndarray
    trajectories: np.ndarray
    times: np.ndarray
    labels: np.ndarray
    params: np.ndarray
    fit_error_px: np.ndarray
    split: np.ndarray
    meta: dict = field(default_factory=dict)
    # Where the rows came from, for error messages: the file (set by load_dataset) and
    # each row's number in it (None: the rows are the file's, in order).
    origin: str | None = field(default=None, repr=False, compare=False)
    file_rows: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __len__(self) -> int:
        return int(self.labels.shape[0])

    @property
    def dmp_config(self) -> DMPConfig:
        """The :class:`DMPConfig` the stored parameters were fitted with."""
        return DMPConfig.from_dict(self.meta["dmp_config"])

    @property
    def image_size(self) -> tuple[int, int]:
        return int(self.images.shape[1]), int(self.images.shape[2])

    @property
    def class_names(self) -> tuple[str, ...] | None:
        """The names the labels index into, or None for a data set of digits 0-9."""
        names = self.meta.get(CLASS_NAMES_KEY) if isinstance(self.meta, dict) else None
        return None if names is None else tuple(names)

    @property
    def label_names(self) -> tuple[str, ...]:
        """The name of every label: ``class_names``, or ``"0"`` .. ``"9"`` for digits."""
        return self.class_names if self.class_names is not None else DIGIT_NAMES

    def labels_of_digits(self, digits) -> np.ndarray:
        """The labels of the classes named by ``digits`` (int64 ``[n]``).

        For a data set of digits they are the digits themselves; with ``class_names``
        the labels of the classes named ``"2"``, ``"3"`` ...; a digit that names no class
        raises :class:`DatasetError` listing the data set's classes.
        """
        hint = "digits select classes by their names; "
        return self._labels_named([str(d) for d in digits], hint)

    def labels_of_classes(self, names) -> np.ndarray:
        """The labels (int64 ``[n]``) of the classes named ``names`` (e.g. ``["L", "T"]``,
        or ``["2"]`` for a data set of digits); a name that is no class of the data set
        raises :class:`DatasetError` listing its classes."""
        return self._labels_named([str(n) for n in names], "")

    def labels_selected(self, digits=None, classes=None) -> np.ndarray | None:
        """The labels ``digits`` (:meth:`labels_of_digits`) or ``classes``
        (:meth:`labels_of_classes`) select, or None when neither is given; both at once
        raise ``ValueError``."""
        if digits is not None and classes is not None:
            raise ValueError("digits and classes both select classes; give one of them")
        if digits is not None:
            return self.labels_of_digits(digits)
        return None if classes is None else self.labels_of_classes(classes)

    def _labels_named(self, names: list[str], hint: str) -> np.ndarray:
        known = self.label_names
        out = []
        for name in names:
            if name not in known:
                where = self.origin or "the data set"
                shown = ", ".join(known[:20]) + (", ..." if len(known) > 20 else "")
                raise DatasetError(
                    f"{where} has no class named {name!r} ({hint}its classes are {shown})"
                )
            out.append(known.index(name))
        return np.asarray(out, dtype=np.int64)

    def arrays(self) -> dict[str, np.ndarray]:
        """The seven tensors by their file names."""
        return {name: getattr(self, name) for name in _FIELDS}

    def subset(self, index) -> DigitData:
        """Rows selected by an index, slice or boolean mask; the metadata is shared but
        for ``stroke_spans``, which is selected with the rows."""
        rows = self._file_rows()[index] if self.origin is not None else None
        meta = self.meta
        spans = meta.get(STROKE_SPANS_KEY) if isinstance(meta, dict) else None
        if spans is not None:
            meta = {**meta, STROKE_SPANS_KEY: [spans[i] for i in np.arange(len(self))[index]]}
        return DigitData(
            **{k: v[index] for k, v in self.arrays().items()},
            meta=meta,
            origin=self.origin,
            file_rows=rows,
        )

    def stroke_spans(self, row: int) -> list[tuple[int, int]]:
        """``(first, last)`` instant of every stroke of ``row``, in writing order.

        From the metadata's ``stroke_spans`` when the data set has them (module
        docstring); else, for a data set of an earlier img2dmp or another source, the runs
        of the pen channel (d = 3: pen > 0.5), or one stroke over all instants (d = 2).
        """
        spans = self.meta.get(STROKE_SPANS_KEY) if isinstance(self.meta, dict) else None
        if spans is not None:
            return [(int(a), int(b)) for a, b in spans[row]]
        if self.trajectories.shape[-1] >= 3:
            return pen_runs(self.trajectories[row, :, 2] > 0.5)
        return [(0, int(self.trajectories.shape[1]) - 1)]

    def _file_rows(self) -> np.ndarray:
        return self.file_rows if self.file_rows is not None else np.arange(len(self))

    def _row_name(self, row: int) -> str:
        """``"data.safetensors: row 17"``: a row as the file numbers it."""
        if self.origin is None:
            return f"data set: row {row}"
        return f"{self.origin}: row {int(self._file_rows()[row])}"

    def dmp_params(self, index=slice(None)) -> DMPParams:
        """The fitted DMPs of the selected rows, checked (tau > 0, finite).

        :meth:`validate` does not require tau > 0 (the file format stores any finite
        vectors), this does: a row that is no DMP raises a :class:`DatasetError` naming
        the file and its row (``data.safetensors: row 17: field 'params' ...``).
        """
        config = self.dmp_config
        rows = np.arange(len(self))[index]
        v = self.params[rows]
        tau_col = config.n_kernels * config.n_dims
        bad = ~(np.isfinite(v).all(axis=-1) & (v[..., tau_col] > 0))
        if bad.any():
            row = int(np.atleast_1d(rows)[_first_row(np.atleast_1d(bad))])
            raise DatasetError(
                f"{self._row_name(row)}: field 'params' has tau (column {tau_col}) = "
                f"{self.params[row, tau_col].item()!r}; a DMP's duration must be > 0 s"
            )
        return DMPParams.from_vector(v, config.n_kernels, config.n_dims, config=config)

    def select_split(self, split: str | int) -> DigitData:
        """Only the samples of one split (``"train"``, ``"validation"``, ``"test"`` or 0-2)."""
        code = SPLITS.get(split, split) if isinstance(split, str) else split
        if code not in SPLITS.values():
            raise ValueError(f"split must be one of {sorted(SPLITS)} or 0-2, got {split!r}")
        return self.subset(self.split == code)

    def validate(self, where: str = "data set") -> DigitData:
        """Check dtypes, shapes, value ranges and metadata.

        Raises :class:`DatasetError` (a ``ValueError``) whose message starts with
        ``where`` (e.g. the file name) and names the field and the first row at fault.
        """
        arrays = self.arrays()
        for name, (dtype, rank) in _FIELDS.items():
            a = arrays[name]
            if not isinstance(a, np.ndarray):
                raise DatasetError(
                    f"{where}: field {name!r} must be a NumPy array, got {type(a).__name__}"
                )
            if a.dtype != dtype:
                raise DatasetError(f"{where}: field {name!r} has dtype {a.dtype}, expected {dtype}")
            if a.ndim != rank:
                raise DatasetError(
                    f"{where}: field {name!r} has shape {a.shape}, expected {rank} dimensions"
                )
        h, w = self.images.shape[1:]
        if min(h, w) < MIN_IMAGE_SIDE:
            raise DatasetError(
                f"{where}: field 'images' holds images of {h} x {w} pixels; a data set's "
                f"images have at least {MIN_IMAGE_SIDE} x {MIN_IMAGE_SIDE}"
            )
        m = self.labels.shape[0]
        for name, a in arrays.items():
            if a.shape[0] != m:
                raise DatasetError(
                    f"{where}: field {name!r} has {a.shape[0]} rows but 'labels' has {m}"
                )
        t = self.trajectories.shape[1]
        if self.times.shape[1] != t:
            raise DatasetError(
                f"{where}: field 'times' has {self.times.shape[1]} time stamps per sample "
                f"but 'trajectories' has {t}"
            )
        if isinstance(self.meta, dict) and self.meta.get(CLASS_NAMES_KEY) is not None:
            check_class_names(self.meta[CLASS_NAMES_KEY], where)
        if isinstance(self.meta, dict) and self.meta.get(STROKE_SPANS_KEY) is not None:
            self._validate_spans(where)
        if m:
            self._validate_values(where)
        self._validate_meta(where)
        return self

    def _validate_values(self, where: str) -> None:
        for name in ("images", "trajectories", "times", "params", "fit_error_px"):
            a = getattr(self, name)
            if not np.isfinite(a).all():
                row = _first_row(~np.isfinite(a))
                raise DatasetError(f"{where}: field {name!r} row {row} contains NaN or inf")
        if self.images.min() < 0 or self.images.max() > 1:
            row = _first_row((self.images < 0) | (self.images > 1))
            raise DatasetError(f"{where}: field 'images' row {row} has values outside [0, 1]")
        names = self.meta.get(CLASS_NAMES_KEY) if isinstance(self.meta, dict) else None
        n_classes = len(names) if isinstance(names, (list, tuple)) else 10
        label_rule = (
            "is not a digit 0-9"
            if names is None
            else f"is not a class index 0-{n_classes - 1} (metadata field 'class_names')"
        )
        checks = (
            ("labels", (self.labels < 0) | (self.labels >= n_classes), label_rule),
            ("split", self.split > 2, "is not 0 (train), 1 (validation) or 2 (test)"),
            ("fit_error_px", self.fit_error_px < 0, "is negative (an error in pixels)"),
            ("times", self.times[:, 0] < 0, "starts before 0 (seconds since the start)"),
        )
        for name, bad, why in checks:
            if bad.any():
                row = _first_row(bad)
                value = getattr(self, name)[row].reshape(-1)[0].item()
                raise DatasetError(f"{where}: field {name!r} row {row} is {value!r}: {why}")
        if self.times.shape[1] > 1 and not (np.diff(self.times, axis=1) > 0).all():
            row = _first_row(np.diff(self.times, axis=1) <= 0)
            raise DatasetError(f"{where}: field 'times' is not strictly increasing in row {row}")

    def _validate_positions(self, where: str, config: DMPConfig) -> None:
        """Paths, goals and starts near the image (:data:`MAX_POSITION_SIDES`; a tau <= 0
        is named where the DMPs are read, :meth:`dmp_params`)."""
        h, w = self.images.shape[1:]
        centre, reach = np.array([w - 1, h - 1]) / 2.0, MAX_POSITION_SIDES * max(h, w)
        ti, d = config.n_kernels * config.n_dims, config.n_dims
        where_xy = (
            ("trajectories", self.trajectories[:, :, :2]),
            ("params", self.params[:, ti + 1 : ti + 1 + 2 * d].reshape(-1, 2, d)[:, :, :2]),
        )
        for name, xy in where_xy:  # [M, n, 2]
            far = np.abs(xy - centre).max(axis=(1, 2)) > reach  # [M]
            if far.any():
                row = _first_row(far)
                value = xy[row].reshape(-1)[np.abs(xy[row] - centre).argmax()].item()
                what = "a path" if name == "trajectories" else "a goal or start"
                raise DatasetError(
                    f"{where}: field {name!r} row {row} holds {what} position {value:g} px, "
                    f"more than {MAX_POSITION_SIDES} sides of the {w} x {h} image from it"
                )

    def _validate_spans(self, where: str) -> None:
        """The metadata's ``stroke_spans``: one entry per row, increasing spans within the
        time grid, and with a pen channel the pen down at exactly their instants."""
        spans, (m, t) = self.meta[STROKE_SPANS_KEY], self.times.shape
        what = f"{where}: metadata field {STROKE_SPANS_KEY!r}"
        if not isinstance(spans, list) or len(spans) != m:
            got = f"{len(spans)} entries" if isinstance(spans, list) else type(spans).__name__
            raise DatasetError(f"{what} must be a list of one entry per row ({m}), got {got}")
        down = np.zeros((m, t), bool)  # [M, T] the instants of the spans
        for row, entry in enumerate(spans):
            last = -1
            ok = isinstance(entry, list) and bool(entry)
            for span in entry if ok else ():
                ok = _is_span(span) and last < span[0] <= span[1] < t
                if not ok:
                    break
                down[row, span[0] : span[1] + 1] = True
                last = span[1]
            if not ok:
                shown = json.dumps(entry)[:60]
                raise DatasetError(
                    f"{what} row {row} is {shown}: expected a non-empty list of [first, last] "
                    f"instants, each after the one before, within 0-{t - 1}"
                )
        if self.trajectories.shape[-1] >= 3 and m:
            bad = down != (self.trajectories[..., 2] > 0.5)  # [M, T]
            if bad.any():
                row = _first_row(bad)
                k = int(np.argmax(bad[row]))
                raise DatasetError(
                    f"{what} row {row} does not match the pen channel: instant {k} is "
                    f"{'in' if down[row, k] else 'outside'} a stroke but the pen is "
                    f"{self.trajectories[row, k, 2]:g}"
                )

    def _validate_meta(self, where: str) -> None:
        if not isinstance(self.meta, dict):
            raise DatasetError(f"{where}: metadata must be a dict, got {type(self.meta).__name__}")
        for key in ("dmp_config", "source", "seed"):
            if key not in self.meta:
                raise DatasetError(f"{where}: metadata field {key!r} is missing")
        try:
            config = DMPConfig.from_dict(self.meta["dmp_config"])
        except (TypeError, ValueError) as e:
            raise DatasetError(f"{where}: metadata field 'dmp_config' is invalid: {e}") from e
        if not isinstance(self.meta["source"], dict):
            raise DatasetError(f"{where}: metadata field 'source' must be a JSON object")
        seed = self.meta["seed"]
        if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool)):
            raise DatasetError(f"{where}: metadata field 'seed' must be an integer or null")
        if self.params.shape[1] != config.n_params:
            raise DatasetError(
                f"{where}: field 'params' has {self.params.shape[1]} numbers per sample, "
                f"dmp_config expects {config.n_params}"
            )
        if self.trajectories.shape[2] != config.n_dims:
            raise DatasetError(
                f"{where}: field 'trajectories' has d={self.trajectories.shape[2]}, "
                f"dmp_config expects n_dims={config.n_dims}"
            )
        if self.labels.shape[0]:
            self._validate_positions(where, config)
        size = self.meta.get("image_size")
        if size is not None and size != list(self.images.shape[1:]):
            raise DatasetError(
                f"{where}: metadata field 'image_size' is {size} but 'images' are "
                f"{list(self.images.shape[1:])}"
            )


def save_dataset(path: str | os.PathLike, data: DigitData, *, overwrite: bool = True) -> Path:
    """Validate ``data`` and write it atomically to ``path`` (a ``.safetensors`` file).

    The metadata's ``format``, ``version``, ``image_size`` and ``created`` are set here;
    everything else in ``data.meta`` is stored as given (it must be JSON-serialisable).

    Parameters
    ----------
    path : path
        Target file; its directory must exist.
    data : DigitData
    overwrite : bool
        If False, raise ``FileExistsError`` when ``path`` exists.

    Returns
    -------
    Path
        The written file.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"{path}: directory {str(path.parent)!r} does not exist")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists (pass overwrite=True to replace it)")
    meta = dict(data.meta)
    meta.update(
        format=FORMAT,
        version=VERSION,
        image_size=[int(s) for s in data.images.shape[1:]],
        created=meta.get("created") or _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    )
    data = DigitData(**data.arrays(), meta=meta).validate(str(path))
    try:
        header = json.dumps(meta, sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise DatasetError(f"{path}: metadata is not JSON-serialisable: {e}") from e
    arrays = {k: np.ascontiguousarray(v) for k, v in data.arrays().items()}
    digest = content_digest(header, arrays)
    blob = _st_save(arrays, metadata={META_KEY: header, CHECKSUM_KEY: digest})
    atomic_write_bytes(path, blob)
    return path


def _read_file(path: Path) -> tuple[dict, dict]:
    """The header's metadata strings and the seven arrays of a data-set file."""
    check_readable(path, "data-set file")  # missing, a directory, no permission: OSError
    try:
        with safe_open(str(path), framework="np") as f:
            header = f.metadata() or {}
            keys = set(f.keys())
            missing = [k for k in _FIELDS if k not in keys]
            if missing:
                raise DatasetError(f"{path}: tensor field(s) {missing} are missing")
            arrays = {k: f.get_tensor(k) for k in _FIELDS}
    except (SafetensorError, OSError) as e:
        raise DatasetError(
            f"{path}: not a safetensors data-set file, or truncated or corrupt ({e})"
        ) from e
    return header, arrays


def _parse_header(path: Path, header: dict) -> dict:
    if META_KEY not in header:
        raise DatasetError(f"{path}: header metadata has no {META_KEY!r} entry")
    try:
        meta = parse_json(header[META_KEY], f"{path}: metadata field {META_KEY!r}")
    except ValueError as e:
        raise DatasetError(str(e)) from None
    if not isinstance(meta, dict):
        raise DatasetError(f"{path}: metadata field {META_KEY!r} must be a JSON object")
    for key in _REQUIRED_META:
        if key not in meta:
            raise DatasetError(f"{path}: metadata field {key!r} is missing")
    if meta["format"] != FORMAT:
        raise DatasetError(f"{path}: metadata field 'format' is {meta['format']!r}, not {FORMAT!r}")
    if meta["version"] != VERSION or isinstance(meta["version"], bool):
        raise DatasetError(
            f"{path}: metadata field 'version' is {meta['version']!r}; this img2dmp reads "
            f"version {VERSION}"
        )
    return meta


def load_dataset(path: str | os.PathLike) -> DigitData:
    """Read, verify and validate a data-set file written by :func:`save_dataset`.

    Raises
    ------
    FileNotFoundError, IsADirectoryError, PermissionError
        If ``path`` does not exist, is a directory or cannot be read.
    DatasetError
        A ``ValueError``: the file is not a valid img2dmp data set, is truncated, or
        does not match its checksum (modified or corrupt); the message names the file
        and the field (and row) at fault.
    """
    path = Path(path)
    header, arrays = _read_file(path)
    if CHECKSUM_KEY in header:
        digest = content_digest(header.get(META_KEY, ""), arrays)
        if header[CHECKSUM_KEY] != digest:
            raise DatasetError(
                f"{path} was modified or is corrupt: its arrays and metadata do not match "
                f"its SHA-256 checksum ({digest[:12]}... against the recorded "
                f"{str(header[CHECKSUM_KEY])[:12]}...)"
            )
    meta = _parse_header(path, header)
    return DigitData(**arrays, meta=meta, origin=str(path)).validate(str(path))
