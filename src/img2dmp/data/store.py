"""The img2dmp data-set file: one ``.safetensors`` file per data set.

The layout is fixed by ``docs/CONTRACTS.md`` and described for users in
``docs/DATASET.md``. Tensors (M samples, T time stamps, d dimensions, P = N*d + 1 + 2d)::

    images        float32 [M, H, W]   ink = 1, background = 0
    trajectories  float32 [M, T, d]   pen path in image pixels (x = column, y = row)
    times         float32 [M, T]      seconds since the start of the movement
    labels        int64   [M]         digit 0-9
    params        float32 [M, P]      fitted DMP, flat vector (DMPParams.to_vector)
    fit_error_px  float32 [M]         mean error of that fit in pixels
    split         uint8   [M]         0 train, 1 validation, 2 test

The safetensors header's ``__metadata__`` holds one key ``"img2dmp"`` whose value is a
JSON object with at least ``format``, ``version``, ``dmp_config``, ``source``, ``seed``,
``image_size`` and ``created``. Files are written atomically: to a temporary file in the
target's directory, flushed to disk, then moved over the target with :func:`os.replace`,
so a reader never sees half a file.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from safetensors import SafetensorError, safe_open
from safetensors.numpy import save as _st_save

from .._files import atomic_write_bytes
from ..dmp import DMPConfig

FORMAT = "img2dmp-dataset"
VERSION = 1
META_KEY = "img2dmp"
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
        and ``seed`` (int or None). ``format``, ``version``, ``image_size`` and
        ``created`` are filled in by :func:`save_dataset`.
    """

    images: np.ndarray
    trajectories: np.ndarray
    times: np.ndarray
    labels: np.ndarray
    params: np.ndarray
    fit_error_px: np.ndarray
    split: np.ndarray
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.labels.shape[0])

    @property
    def dmp_config(self) -> DMPConfig:
        """The :class:`DMPConfig` the stored parameters were fitted with."""
        return DMPConfig.from_dict(self.meta["dmp_config"])

    @property
    def image_size(self) -> tuple[int, int]:
        return int(self.images.shape[1]), int(self.images.shape[2])

    def arrays(self) -> dict[str, np.ndarray]:
        """The seven tensors by their file names."""
        return {name: getattr(self, name) for name in _FIELDS}

    def subset(self, index) -> DigitData:
        """Rows selected by an index, slice or boolean mask; the metadata is shared."""
        return DigitData(**{k: v[index] for k, v in self.arrays().items()}, meta=self.meta)

    def select_split(self, split: str | int) -> DigitData:
        """Only the samples of one split (``"train"``, ``"validation"``, ``"test"`` or 0-2)."""
        code = SPLITS.get(split, split) if isinstance(split, str) else split
        if code not in SPLITS.values():
            raise ValueError(f"split must be one of {sorted(SPLITS)} or 0-2, got {split!r}")
        return self.subset(self.split == code)

    def validate(self, where: str = "data set") -> DigitData:
        """Check dtypes, shapes, value ranges and metadata.

        Raises ``ValueError`` whose message starts with ``where`` (e.g. the file name)
        and names the field at fault.
        """
        arrays = self.arrays()
        for name, (dtype, rank) in _FIELDS.items():
            a = arrays[name]
            if not isinstance(a, np.ndarray):
                raise ValueError(f"{where}: field {name!r} must be a NumPy array, got {type(a)}")
            if a.dtype != dtype:
                raise ValueError(f"{where}: field {name!r} has dtype {a.dtype}, expected {dtype}")
            if a.ndim != rank:
                raise ValueError(
                    f"{where}: field {name!r} has shape {a.shape}, expected {rank} dimensions"
                )
        m = self.labels.shape[0]
        for name, a in arrays.items():
            if a.shape[0] != m:
                raise ValueError(
                    f"{where}: field {name!r} has {a.shape[0]} rows but 'labels' has {m}"
                )
        t = self.trajectories.shape[1]
        if self.times.shape[1] != t:
            raise ValueError(
                f"{where}: field 'times' has {self.times.shape[1]} time stamps per sample "
                f"but 'trajectories' has {t}"
            )
        for name in ("images", "trajectories", "times", "params", "fit_error_px"):
            if not np.isfinite(arrays[name]).all():
                raise ValueError(f"{where}: field {name!r} contains NaN or inf")
        if m and (self.images.min() < 0 or self.images.max() > 1):
            raise ValueError(f"{where}: field 'images' has values outside [0, 1]")
        if m and ((self.labels < 0).any() or (self.labels > 9).any()):
            raise ValueError(f"{where}: field 'labels' has values outside the digits 0-9")
        if m and (self.split > 2).any():
            raise ValueError(f"{where}: field 'split' has values other than 0, 1, 2")
        if m and t > 1 and not (np.diff(self.times, axis=1) > 0).all():
            raise ValueError(f"{where}: field 'times' is not strictly increasing in every row")
        self._validate_meta(where)
        return self

    def _validate_meta(self, where: str) -> None:
        if not isinstance(self.meta, dict):
            raise ValueError(f"{where}: metadata must be a dict, got {type(self.meta)}")
        for key in ("dmp_config", "source", "seed"):
            if key not in self.meta:
                raise ValueError(f"{where}: metadata field {key!r} is missing")
        try:
            config = DMPConfig.from_dict(self.meta["dmp_config"])
        except (TypeError, ValueError) as e:
            raise ValueError(f"{where}: metadata field 'dmp_config' is invalid: {e}") from e
        if not isinstance(self.meta["source"], dict):
            raise ValueError(f"{where}: metadata field 'source' must be a JSON object")
        seed = self.meta["seed"]
        if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool)):
            raise ValueError(f"{where}: metadata field 'seed' must be an integer or null")
        if self.params.shape[1] != config.n_params:
            raise ValueError(
                f"{where}: field 'params' has {self.params.shape[1]} numbers per sample, "
                f"dmp_config expects {config.n_params}"
            )
        if self.trajectories.shape[2] != config.n_dims:
            raise ValueError(
                f"{where}: field 'trajectories' has d={self.trajectories.shape[2]}, "
                f"dmp_config expects n_dims={config.n_dims}"
            )
        size = self.meta.get("image_size")
        if size is not None and list(size) != list(self.images.shape[1:]):
            raise ValueError(
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
        header = json.dumps(meta, sort_keys=True)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{path}: metadata is not JSON-serialisable: {e}") from e
    blob = _st_save(
        {k: np.ascontiguousarray(v) for k, v in data.arrays().items()},
        metadata={META_KEY: header},
    )
    atomic_write_bytes(path, blob)
    return path


def load_dataset(path: str | os.PathLike) -> DigitData:
    """Read and validate a data-set file written by :func:`save_dataset`.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If the file is not a valid img2dmp data set; the message names the file and the
        field at fault.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such data-set file")
    try:
        with safe_open(str(path), framework="np") as f:
            header = f.metadata() or {}
            keys = set(f.keys())
            missing = [k for k in _FIELDS if k not in keys]
            if missing:
                raise ValueError(f"{path}: tensor field(s) {missing} are missing")
            arrays = {k: f.get_tensor(k) for k in _FIELDS}
    except (SafetensorError, OSError) as e:
        raise ValueError(f"{path}: not a readable safetensors file ({e})") from e
    if META_KEY not in header:
        raise ValueError(f"{path}: header metadata has no {META_KEY!r} entry")
    try:
        meta = json.loads(header[META_KEY])
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: metadata field {META_KEY!r} is not valid JSON ({e})") from e
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: metadata field {META_KEY!r} must be a JSON object")
    for key in _REQUIRED_META:
        if key not in meta:
            raise ValueError(f"{path}: metadata field {key!r} is missing")
    if meta["format"] != FORMAT:
        raise ValueError(f"{path}: metadata field 'format' is {meta['format']!r}, not {FORMAT!r}")
    if meta["version"] != VERSION:
        raise ValueError(
            f"{path}: metadata field 'version' is {meta['version']!r}; this img2dmp reads "
            f"version {VERSION}"
        )
    return DigitData(**arrays, meta=meta).validate(str(path))
