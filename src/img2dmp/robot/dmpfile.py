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
``d = 3`` the third channel is the pen (1 = down, 0 = up, threshold 0.5). Other keys are
ignored, so a file may carry notes such as ``"label"`` or ``"source"``.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from .._files import atomic_write_text
from ..dmp import DMPConfig, DMPParams


def _bad(path, field: str, why: str) -> ValueError:
    return ValueError(f"{path}: field {field!r} {why}")


def load_dmp_json(path) -> tuple[DMPParams, DMPConfig, tuple[int, int]]:
    """Read one DMP from a JSON file (format in the module docstring).

    Returns
    -------
    params : DMPParams
        NumPy float64, no batch dimensions.
    config : DMPConfig
    image_size : tuple (H, W)

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If it is not valid JSON or a field is missing or wrong; the message names the
        file and the field.
    """
    path = os.fspath(path)
    with open(path, encoding="utf-8") as f:
        try:
            doc = json.load(f)
        except json.JSONDecodeError as e:
            raise ValueError(f"{path}: not a valid JSON file ({e})") from e
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: expected a JSON object at the top level")
    for key in ("dmp_config", "params", "image_size"):
        if key not in doc:
            raise _bad(path, key, "is missing")
    if not isinstance(doc["dmp_config"], dict):
        raise _bad(path, "dmp_config", "must be an object (DMPConfig.to_dict())")
    try:
        config = DMPConfig.from_dict(doc["dmp_config"])
    except (TypeError, ValueError) as e:
        raise _bad(path, "dmp_config", f"is invalid: {e}") from e

    if not isinstance(doc["params"], dict):
        raise _bad(path, "params", "must be an object with w, tau, g, y0")
    try:
        params = DMPParams.from_dict(doc["params"])
    except ValueError as e:
        raise _bad(path, "params", f"is invalid: {e}") from e
    if params.batch_shape != ():
        raise _bad(
            path,
            "params",
            f"must hold one DMP (w [N, d], scalar tau), got batch shape {params.batch_shape}",
        )
    try:
        params.validate(config)
    except ValueError as e:
        raise _bad(path, "params", f"does not match dmp_config: {e}") from e

    size = doc["image_size"]
    if (
        not isinstance(size, list)
        or len(size) != 2
        or not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in size)
    ):
        raise _bad(path, "image_size", f"must be [H, W], two positive integers, got {size!r}")
    return params, config, (size[0], size[1])


def save_dmp_json(path, params: DMPParams, config: DMPConfig, image_size, **extra) -> None:
    """Write one DMP in the format of :func:`load_dmp_json`, atomically.

    ``extra`` keys (JSON-serialisable, e.g. ``label=3``) are stored alongside.
    """
    p = params.to_numpy()
    if p.batch_shape != ():
        raise ValueError(f"params must hold one DMP, got batch shape {p.batch_shape}")
    p.validate(config)
    h, w = (int(s) for s in image_size)
    if h <= 0 or w <= 0:
        raise ValueError(f"image_size must be two positive integers, got {image_size!r}")
    doc = {"dmp_config": config.to_dict(), "params": p.to_dict(), "image_size": [h, w]}
    for k, v in extra.items():
        if k in doc:
            raise ValueError(f"extra key {k!r} would overwrite a format field")
        doc[k] = v
    if not all(math.isfinite(float(x)) for x in np.ravel(p.to_vector())):
        raise ValueError("params contain NaN or inf")
    atomic_write_text(path, json.dumps(doc, indent=1))
