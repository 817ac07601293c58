"""The one way to save and load a trained network: safetensors weights + JSON.

A checkpoint is one ``NAME.safetensors`` file. Its tensors are the model's weights
(``model.*``) and, for a resumable checkpoint, the optimiser's state (``optim.*``). Its
header's ``__metadata__`` holds one key ``"img2dmp"`` with a JSON object (the *record*):
format and version, the architecture (:class:`~img2dmp.nn.ModelConfig`), the output
normalisation, the DMP constants, the training configuration, the data set's SHA-256, the
epoch and errors, a SHA-256 of the weights (``weights_sha256``), one of the optimiser's
tensors (``optim_sha256``, resumable checkpoints only) and a SHA-256 of the whole record
(``record_sha256``). The same JSON is written beside it as ``NAME.json`` for people and
tools; the copy inside the weights file is the one that is read, so the pair can never
disagree. No code is ever stored or unpickled: tensors in safetensors, the rest JSON.

**Integrity.** ``record_sha256`` is the SHA-256 of the record without that one key, as
compact JSON with sorted keys (``json.dumps(r, sort_keys=True, separators=(",", ":"))``);
since the record holds ``weights_sha256`` and ``optim_sha256``, it covers every byte that
changes what the checkpoint does. :func:`read_checkpoint_meta` checks it and
:func:`load_checkpoint` checks it and the tensors' digests; an edited field (say the
normaliser's centre) or a flipped bit gives one :class:`CheckpointError` naming the file
and saying it was modified or is corrupt. These are checksums against accidents (an edit,
a bad disk, a truncated copy), not signatures: whoever edits a record on purpose can
recompute them.

**Versions.** Version 2 (this one) has the record digest and requires it. Version 1
checkpoints (img2dmp up to the introduction of ``record_sha256``) are still read: their
weights are verified against ``weights_sha256`` as before, but their record cannot be, and
their optimiser state is not verified; retraining or re-saving makes a version 2
checkpoint. Other versions are refused.

Both files are written to a temporary file in the same directory and moved into place
with ``os.replace``, so a process killed at any moment leaves either the old or the new
checkpoint, never half of one.

**Without torch.** This module imports torch only where a torch tensor is made or taken
(saving, :func:`load_weights_into`, the optimiser's state, and loading with
``framework="pt"``, the default). ``load_checkpoint(path, framework="numpy")`` reads the
weights as NumPy arrays, with the same checks: :func:`weights_digest` gives the same
digest for the arrays as for the tensors they were saved from.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from safetensors import SafetensorError

from . import __version__
from . import models as _shipped
from ._files import (  # noqa: F401 (file_digest re-exported)
    atomic_write_bytes,
    atomic_write_text,
    check_readable,
    file_digest,
    parse_json,
)
from ._lazy import is_tensor

if TYPE_CHECKING:
    import torch

FORMAT = "img2dmp-checkpoint"
VERSION = 2
READABLE_VERSIONS = (1, 2)  # see "Versions" in the module docstring
RECORD_DIGEST = "record_sha256"
SUFFIX = ".safetensors"
# Where a run directory keeps its checkpoints, and which one a run directory stands for.
CHECKPOINT_DIR = "checkpoints"
DEFAULT_NAME = "best"
#: What :func:`load_checkpoint` makes of the tensors: torch tensors or NumPy arrays.
FRAMEWORKS = ("pt", "numpy")
#: NumPy's dtypes that torch has too, by name: the digest spells them as torch does
#: (``torch.float32``), so that it is the same for a state dict's tensors and arrays.
_DIGEST_DTYPES = frozenset(
    ["bool", "float16", "float32", "float64", "complex64", "complex128"]
    + [f"{kind}{bits}" for kind in ("int", "uint") for bits in (8, 16, 32, 64)]
)


class CheckpointError(ValueError):
    """A checkpoint file is missing, corrupt, truncated or does not fit the model."""


@dataclass
class Checkpoint:
    """What :func:`load_checkpoint` returns.

    Attributes
    ----------
    path : Path
        The ``.safetensors`` file read.
    meta : dict
        The JSON record (see the module docstring).
    model_state : dict[str, Tensor] or dict[str, ndarray]
        ``state_dict`` of the network (NumPy arrays when loaded with ``framework="numpy"``).
    extra : dict[str, Tensor] or dict[str, ndarray]
        Other tensors, by their name without prefix (``optim.*`` -> optimiser state).
    """

    path: Path
    meta: dict
    model_state: dict = field(repr=False)
    extra: dict = field(default_factory=dict, repr=False)


def weights_digest(state: dict) -> str:
    """SHA-256 over the names, dtypes, shapes and bytes of a ``state_dict``, sorted by name.

    Each value is a torch tensor or a NumPy array; both give the same digest for the same
    values: the dtype is spelled as torch does (``torch.float32``), the bytes are
    little-endian in row-major order. ``ValueError`` naming an array whose dtype torch
    does not have.
    """
    h = hashlib.sha256()
    for k in sorted(state):
        v = state[k]
        if is_tensor(v):
            import torch

            t = v.detach().cpu().contiguous()
            dtype, shape = str(t.dtype), tuple(t.shape)
            flat = t.reshape(-1)  # a 0-dim tensor (BatchNorm's step count) cannot be viewed
            data = flat.view(torch.uint8).numpy().tobytes() if t.numel() else b""
        else:
            a = np.asarray(v)
            if a.dtype.name not in _DIGEST_DTYPES:
                raise ValueError(f"weights: {k!r} has dtype {a.dtype}, which torch has not")
            dtype, shape = f"torch.{a.dtype.name}", tuple(a.shape)
            data = a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes(order="C")
        h.update(f"{k}|{dtype}|{shape}|".encode())
        h.update(data)
    return h.hexdigest()


def record_digest(record: dict) -> str:
    """SHA-256 of a record without its ``record_sha256`` key (see the module docstring)."""
    body = {k: v for k, v in record.items() if k != RECORD_DIGEST}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode("ascii")).hexdigest()


def _jsonable(obj):
    """Turn tensors and numpy scalars inside optimiser/scheduler records into JSON values."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if is_tensor(obj):
        return obj.tolist()
    if hasattr(obj, "item") and callable(obj.item):
        return obj.item()
    return obj


def save_checkpoint(
    path: str | os.PathLike,
    model_state: dict,
    meta: dict,
    extra: dict | None = None,
) -> Path:
    """Write a checkpoint atomically (``path`` ends in ``.safetensors``; a ``.json`` beside it).

    Parameters
    ----------
    path : path
        Target file.
    model_state : dict[str, Tensor]
        The network's ``state_dict``.
    meta : dict
        JSON-serialisable record; ``format``, ``version``, ``created``,
        ``img2dmp_version``, ``weights_sha256``, ``optim_sha256`` (with ``extra``) and
        ``record_sha256`` are added (replacing any given).
    extra : dict[str, Tensor], optional
        Further tensors (e.g. optimiser state), stored as ``optim.<name>``.
    """
    from safetensors.torch import save

    path = Path(path)
    if path.suffix != SUFFIX:
        raise ValueError(f"checkpoint path must end in {SUFFIX}, got {str(path)!r}")
    state = {k: v.detach().cpu().contiguous() for k, v in model_state.items()}
    optim = {k: v.detach().cpu().contiguous() for k, v in (extra or {}).items()}
    record = dict(_jsonable(meta))
    for key in ("weights_sha256", "optim_sha256", RECORD_DIGEST):
        record.pop(key, None)  # a loaded record passed back in: its digests are stale
    record.update(
        format=FORMAT,
        version=VERSION,
        created=_dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        img2dmp_version=__version__,
        weights_sha256=weights_digest(state),
    )
    if optim:
        record["optim_sha256"] = weights_digest(optim)
    try:  # the digest is taken of the record as a reader will parse it
        record = json.loads(json.dumps(record))
    except (TypeError, ValueError) as e:
        raise ValueError(f"checkpoint {path}: the record is not JSON-serialisable: {e}") from e
    record[RECORD_DIGEST] = record_digest(record)
    tensors = {f"model.{k}": v for k, v in state.items()}
    tensors.update({f"optim.{k}": v for k, v in optim.items()})
    text = json.dumps(record, indent=1, sort_keys=True)
    atomic_write_bytes(path, save(tensors, metadata={"img2dmp": text}))
    atomic_write_text(path.with_suffix(".json"), text + "\n")
    return path


def resolve_checkpoint(path: str | os.PathLike, name: str = DEFAULT_NAME) -> Path:
    """Find the weights file a user means: a ``.safetensors`` file, its ``.json`` sidecar,
    a run directory (its ``checkpoints/<name>.safetensors``), a checkpoints directory, or
    the name of a model shipped with img2dmp (``digits-real``: its weights, their SHA-256
    checked, :func:`img2dmp.models.resolve`; an unknown name is refused listing the
    shipped ones)."""
    if not isinstance(path, (str, os.PathLike, _shipped.ShippedModel)):
        raise TypeError(f"the model must be a run directory, a checkpoint file or a shipped "
                        f"model's name, got {type(path).__name__} {path!r:.60}")  # fmt: skip
    shipped = _shipped.resolve(path)
    if shipped is not None:
        return _shipped.verified_weights(shipped)
    p = Path(path)
    if p.is_dir():
        for cand in (p / CHECKPOINT_DIR / f"{name}{SUFFIX}", p / f"{name}{SUFFIX}"):
            if cand.is_file():
                return check_readable(cand, "checkpoint")
        raise FileNotFoundError(
            f"{p} holds no checkpoint: expected {p / CHECKPOINT_DIR / (name + SUFFIX)}"
        )
    if p.suffix == ".json":
        p = p.with_suffix(SUFFIX)
    if not os.path.lexists(p):  # a path that is not there: a shipped name may be meant
        names = ", ".join(_shipped.shipped_model_names()) or "none"
        raise FileNotFoundError(
            f"checkpoint {p} does not exist (a run directory, a checkpoint file, or a "
            f"shipped model's name: {names})"
        )
    return check_readable(p, "checkpoint")


def read_checkpoint_meta(path: str | os.PathLike) -> dict:
    """The JSON record inside a checkpoint, verified, without reading the weights."""
    from safetensors import safe_open

    p = resolve_checkpoint(path)
    try:
        with safe_open(str(p), framework="np") as f:  # the header only: no torch needed
            raw = (f.metadata() or {}).get("img2dmp")
    except (SafetensorError, OSError, ValueError) as e:
        raise CheckpointError(
            f"checkpoint {p} is corrupt or truncated, or not a safetensors file: {e}"
        ) from e
    return _parse_meta(p, raw)


def _parse_meta(p: Path, raw) -> dict:
    if raw is None:
        raise CheckpointError(
            f"{p} is a safetensors file but not an img2dmp checkpoint (no 'img2dmp' metadata)"
        )
    try:
        meta = parse_json(raw, f"checkpoint {p}: metadata")
    except ValueError as e:  # not JSON, nested too deeply, a key twice, a huge number
        raise CheckpointError(str(e)) from None
    if not isinstance(meta, dict):
        raise CheckpointError(
            f"checkpoint {p}: metadata is a JSON {type(meta).__name__}, expected an object"
        )
    if meta.get("format") != FORMAT:
        raise CheckpointError(
            f"{p}: metadata format is {meta.get('format')!r}, expected {FORMAT!r}"
        )
    version = meta.get("version")
    if (
        not isinstance(version, int)
        or isinstance(version, bool)
        or version not in READABLE_VERSIONS
    ):
        raise CheckpointError(
            f"{p}: checkpoint version {version!r} is not supported "
            f"(this img2dmp reads versions {', '.join(map(str, READABLE_VERSIONS))})"
        )
    if version >= 2 and meta.get(RECORD_DIGEST) != record_digest(meta):
        raise CheckpointError(
            f"checkpoint {p} was modified or is corrupt: its record (architecture, "
            f"normaliser, configuration) does not match its {RECORD_DIGEST}"
        )
    return meta


def load_checkpoint(
    path: str | os.PathLike, name: str = DEFAULT_NAME, framework: str = "pt"
) -> Checkpoint:
    """Read and verify a checkpoint written by :func:`save_checkpoint`.

    Parameters
    ----------
    path : path or str
        What :func:`resolve_checkpoint` takes: a checkpoint, its sidecar, a run directory
        or the name of a shipped model.
    name : str
        Which checkpoint of a run directory (``"best"`` or ``"last"``).
    framework : {"pt", "numpy"}
        ``"pt"`` (default): the tensors as torch tensors; ``"numpy"``: as NumPy arrays,
        without importing torch (for :class:`~img2dmp.nn._numpy_net.NumpyNetwork`). The
        checks are the same.

    Raises
    ------
    FileNotFoundError
        Nothing at ``path``.
    CheckpointError
        The file is truncated, corrupt or modified (unreadable header, a record or tensors
        whose SHA-256 does not match the record), or not an img2dmp checkpoint.
    """
    if framework not in FRAMEWORKS:
        raise ValueError(f"framework must be one of {FRAMEWORKS}, got {framework!r}")
    p = resolve_checkpoint(path, name)
    meta = read_checkpoint_meta(p)  # before the tensors: a foreign file is not read whole
    if framework == "pt":
        from safetensors.torch import load_file
    else:
        from safetensors.numpy import load_file
    try:
        tensors = load_file(str(p))
    except (SafetensorError, OSError, ValueError, RuntimeError) as e:
        raise CheckpointError(f"checkpoint {p} is corrupt or truncated: {e}") from e
    except TypeError as e:  # NumPy has no bfloat16; img2dmp itself saves none
        raise CheckpointError(
            f"checkpoint {p} holds tensors NumPy cannot represent ({e}): load it with torch"
        ) from e
    model_state = {k[6:]: v for k, v in tensors.items() if k.startswith("model.")}
    extra = {k[6:]: v for k, v in tensors.items() if k.startswith("optim.")}
    if not model_state:
        raise CheckpointError(f"checkpoint {p} holds no model weights")
    _check_digest(p, "weights", weights_digest(model_state), meta.get("weights_sha256"))
    if meta["version"] >= 2 and (extra or "optim_sha256" in meta):
        _check_digest(p, "optimiser state", weights_digest(extra), meta.get("optim_sha256"))
    return Checkpoint(p, meta, model_state, extra)


def _check_digest(p: Path, what: str, digest: str, recorded) -> None:
    if digest != recorded:
        raise CheckpointError(
            f"checkpoint {p} was modified or is corrupt: the SHA-256 of its {what} "
            f"{digest[:12]}... does not match the recorded {str(recorded)[:12]}..."
        )


def load_weights_into(model: torch.nn.Module, ckpt: Checkpoint) -> None:
    """``model.load_state_dict`` with a clear error when the architecture differs (a
    checkpoint loaded as NumPy arrays is taken too)."""
    import torch

    own = model.state_dict()
    missing = sorted(set(own) - set(ckpt.model_state))
    unexpected = sorted(set(ckpt.model_state) - set(own))
    if missing or unexpected:
        raise CheckpointError(
            f"checkpoint {ckpt.path} was saved from another architecture: "
            f"missing {missing[:4]}, unexpected {unexpected[:4]}"
        )
    for k, v in own.items():
        if tuple(v.shape) != tuple(ckpt.model_state[k].shape):
            raise CheckpointError(
                f"checkpoint {ckpt.path} was saved from another architecture: layer {k!r} "
                f"has shape {tuple(ckpt.model_state[k].shape)}, the model has {tuple(v.shape)}"
            )
    state = {k: v if is_tensor(v) else torch.tensor(v) for k, v in ckpt.model_state.items()}
    model.load_state_dict(state)


def optimizer_to_tensors(opt: torch.optim.Optimizer) -> tuple[dict, dict]:
    """Split an optimiser's ``state_dict`` into tensors (for safetensors) and JSON."""
    import torch

    sd = opt.state_dict()
    tensors, scalars = {}, {}
    for idx, st in sd["state"].items():
        for k, v in st.items():
            if isinstance(v, torch.Tensor):
                tensors[f"state.{idx}.{k}"] = v
            else:
                scalars[f"{idx}.{k}"] = v
    return tensors, {"param_groups": _jsonable(sd["param_groups"]), "scalars": scalars}


def optimizer_from_tensors(tensors: dict, record: dict) -> dict:
    """Inverse of :func:`optimizer_to_tensors`: a ``state_dict`` for ``load_state_dict``."""
    state: dict = {}
    for name, v in tensors.items():
        _, idx, k = name.split(".", 2)
        state.setdefault(int(idx), {})[k] = v
    for name, v in record.get("scalars", {}).items():
        idx, k = name.split(".", 1)
        state.setdefault(int(idx), {})[k] = v
    return {"state": state, "param_groups": record["param_groups"]}
