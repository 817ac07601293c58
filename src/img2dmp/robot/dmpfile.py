"""A small JSON file holding one DMP to execute: ``img2dmp write --dmp params.json``.

Format (one JSON object)::

    {
      "dmp_config": {...},          # DMPConfig.to_dict()
      "params": {"w": [[...]], "tau": 3.0, "g": [x, y], "y0": [x, y]},
                                    # DMPParams.to_dict() of ONE DMP: w [N, d], scalar
                                    # tau (seconds), g [d], y0 [d]; no batch dimensions
      "image_size": [H, W]          # pixels of the image the DMP lives in
    }

Positions are image pixels (x = column, y = row, rows grow downward). With
``d = 3`` the third channel is the pen (1 = down, 0 = up, threshold 0.5).

Reading is strict, and every error is one line naming the file, the field and the value:

- every number must be a JSON number: ``"tau": true`` or ``"tau": "2.0"`` is refused,
  as are NaN and Infinity (which Python's JSON reader would accept), ragged lists and
  shapes other than ``w [N, d]``, scalar ``tau`` > 0, ``g [d]``, ``y0 [d]``;
- a field missing from ``params`` or ``dmp_config`` is refused, and so is an unknown
  one inside them (a misspelt field would otherwise be silently ignored);
- **unknown top-level keys are kept as notes** and ignored, so a file may carry
  ``"label"`` or ``"source"`` (:func:`save_dmp_json` writes such keys);
- a file larger than ``MAX_FILE_BYTES`` (16 MiB; a DMP file is a few kB), one that is not
  UTF-8 text, and a DMP of more than ``MAX_KERNELS`` kernels or of other than 2 or 3
  dimensions are refused before any work depends on them.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from .._files import atomic_write_text, check_readable
from ..dmp import DMPConfig, DMPParams
from ..dmp.params import show_value

MAX_FILE_BYTES = 16 << 20
# The rollout's response table grows with N^2 (about 30 MB and a second to solve at
# N = 100): far beyond the paper's N = 25, still cheap.
MAX_KERNELS = 200
_JSON_TYPES = {dict: "an object", list: "a list", str: "a string", bool: "a boolean"}


def _bad(path, field: str, why: str) -> ValueError:
    return ValueError(f"{path}: field {field!r} {why}")


def _read_document(path: str) -> dict:
    """The file's top-level JSON object; OSErrors (missing, a directory, no permission)
    pass through, naming the file."""
    check_readable(path, "DMP file")
    with open(path, "rb") as f:
        raw = f.read(MAX_FILE_BYTES + 1)
    if len(raw) > MAX_FILE_BYTES:
        raise ValueError(
            f"{path}: larger than {MAX_FILE_BYTES >> 20} MiB; a DMP file holds a few kB "
            "(is it the right file?)"
        )
    try:
        doc = json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not a UTF-8 text file (byte {e.start})") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not a valid JSON file ({e})") from None
    except RecursionError:
        raise ValueError(f"{path}: JSON nested too deeply to be a DMP file") from None
    if not isinstance(doc, dict):
        kind = _JSON_TYPES.get(type(doc), "a number" if doc is not None else "null")
        raise ValueError(f"{path}: expected a JSON object at the top level, got {kind}")
    return doc


def _read_config(path: str, raw) -> DMPConfig:
    if not isinstance(raw, dict):
        raise _bad(
            path, "dmp_config", f"must be an object (DMPConfig.to_dict()), got {show_value(raw)}"
        )
    missing = [k for k in DMPConfig().to_dict() if k not in raw]
    if missing:  # a default in their place would change the movement without a word
        raise _bad(path, "dmp_config", f"is missing {', '.join(missing)}")
    for k, v in raw.items():  # DMPConfig would read "48" as 48 in places, True as 1
        number = isinstance(v, (int, float)) and not isinstance(v, bool)
        if k != "scaling" and not number and not (k == "beta_z" and v is None):
            raise _bad(path, "dmp_config", f"is invalid: {k} must be a number, got {show_value(v)}")
    try:
        config = DMPConfig.from_dict(raw)
    except (TypeError, ValueError) as e:
        raise _bad(path, "dmp_config", f"is invalid: {e}") from e
    if config.n_kernels > MAX_KERNELS:
        raise _bad(
            path,
            "dmp_config",
            f"is invalid: n_kernels is {config.n_kernels}; a DMP file may have at most "
            f"{MAX_KERNELS} kernels",
        )
    if config.n_dims not in (2, 3):
        raise _bad(
            path,
            "dmp_config",
            f"is invalid: n_dims must be 2 (x, y) or 3 (x, y, pen) for a DMP to write, "
            f"got {config.n_dims}",
        )
    return config


def load_dmp_json(path) -> tuple[DMPParams, DMPConfig, tuple[int, int]]:
    """Read one DMP from a JSON file (format and checks in the module docstring).

    Returns
    -------
    params : DMPParams
        NumPy float64, no batch dimensions.
    config : DMPConfig
    image_size : tuple (H, W)

    Raises
    ------
    FileNotFoundError, IsADirectoryError, PermissionError
        If the file cannot be opened (the exception names it).
    ValueError
        If it is not a valid DMP file; the message names the file, the field and the value.
    """
    path = os.fspath(path)
    doc = _read_document(path)
    if "dmp_config" not in doc and "dmp" in doc and "trajectory" in doc:
        raise ValueError(
            f"{path}: a prediction record of 'img2dmp predict', not a DMP file (fields "
            "dmp_config, params, image_size); write from the image with --model instead"
        )
    for key in ("dmp_config", "params", "image_size"):
        if key not in doc:
            raise _bad(path, key, "is missing")
    config = _read_config(path, doc["dmp_config"])
    try:
        params = DMPParams.from_dict(doc["params"], config=config, batch_shape=())
    except ValueError as e:
        raise _bad(path, "params", f"is invalid: {e}") from e
    size = doc["image_size"]
    if (
        not isinstance(size, list)
        or len(size) != 2
        or not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in size)
    ):
        raise _bad(
            path, "image_size", f"must be [H, W], two positive integers, got {show_value(size)}"
        )
    return params, config, (size[0], size[1])


def save_dmp_json(path, params: DMPParams, config: DMPConfig, image_size, **extra) -> None:
    """Write one DMP in the format of :func:`load_dmp_json`, atomically.

    ``extra`` keys (JSON-serialisable, e.g. ``label=3``) are stored alongside. The
    document is checked as :func:`load_dmp_json` checks it before anything is written, so
    a refused DMP leaves an existing file at ``path`` untouched and a written file can
    always be read back.
    """
    path = os.fspath(path)
    p = params.to_numpy()
    if p.batch_shape != ():
        raise ValueError(f"{path}: params must hold one DMP, got batch shape {p.batch_shape}")
    p.validate(config)
    size = list(image_size) if isinstance(image_size, (list, tuple)) else image_size
    if not (
        isinstance(size, list)
        and len(size) == 2
        and all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) for s in size)
        and all(s > 0 for s in size)
    ):
        raise ValueError(f"{path}: image_size must be two positive integers, got {image_size!r}")
    if not all(math.isfinite(float(x)) for x in np.ravel(p.to_vector())):
        raise ValueError(f"{path}: params contain NaN or inf")
    doc = {
        "dmp_config": config.to_dict(),
        "params": p.to_dict(),
        "image_size": [int(s) for s in size],
    }
    for k, v in extra.items():
        if k in doc:
            raise ValueError(f"{path}: extra key {k!r} would overwrite a format field")
        doc[k] = v
    try:
        text = json.dumps(doc, indent=1, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{path}: extra keys are not plain JSON values: {e}") from e
    _read_config(path, doc["dmp_config"])  # the reader's limits (kernels, dimensions)
    atomic_write_text(path, text)
