"""The one way to save and load a trained network: safetensors weights + JSON.

A checkpoint is one ``NAME.safetensors`` file. Its tensors are the model's weights
(``model.*``) and, for a resumable checkpoint, the optimiser's state (``optim.*``). Its
header's ``__metadata__`` holds one key ``"img2dmp"`` with a JSON object: format and
version, the architecture (:class:`~img2dmp.nn.ModelConfig`), the output normalisation,
the DMP constants, the training configuration, the data set's SHA-256, the epoch and
errors, and a SHA-256 of the weights. The same JSON is written beside it as
``NAME.json`` for people and tools; the copy inside the weights file is the one that is
read, so the pair can never disagree.

Both files are written to a temporary file in the same directory and moved into place
with ``os.replace``, so a process killed at any moment leaves either the old or the new
checkpoint, never half of one.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save

from . import __version__
from ._files import atomic_write_bytes, atomic_write_text, file_digest  # noqa: F401 (re-exported)

FORMAT = "img2dmp-checkpoint"
VERSION = 1
SUFFIX = ".safetensors"
# Where a run directory keeps its checkpoints, and which one a run directory stands for.
CHECKPOINT_DIR = "checkpoints"
DEFAULT_NAME = "best"


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
    model_state : dict[str, Tensor]
        ``state_dict`` of the network.
    extra : dict[str, Tensor]
        Other tensors, by their name without prefix (``optim.*`` -> optimiser state).
    """

    path: Path
    meta: dict
    model_state: dict = field(repr=False)
    extra: dict = field(default_factory=dict, repr=False)


def weights_digest(state: dict) -> str:
    """SHA-256 over the names, dtypes, shapes and bytes of a ``state_dict``, sorted by name."""
    h = hashlib.sha256()
    for k in sorted(state):
        t = state[k].detach().cpu().contiguous()
        h.update(f"{k}|{t.dtype}|{tuple(t.shape)}|".encode())
        flat = t.reshape(-1)  # a 0-dim tensor (BatchNorm's step count) cannot be viewed
        h.update(flat.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return h.hexdigest()


def _jsonable(obj):
    """Turn tensors and numpy scalars inside optimiser/scheduler records into JSON values."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, torch.Tensor):
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
        ``img2dmp_version`` and ``weights_sha256`` are added.
    extra : dict[str, Tensor], optional
        Further tensors (e.g. optimiser state), stored as ``optim.<name>``.
    """
    path = Path(path)
    if path.suffix != SUFFIX:
        raise ValueError(f"checkpoint path must end in {SUFFIX}, got {str(path)!r}")
    state = {k: v.detach().cpu().contiguous() for k, v in model_state.items()}
    record = dict(_jsonable(meta))
    record.update(
        format=FORMAT,
        version=VERSION,
        created=_dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        img2dmp_version=__version__,
        weights_sha256=weights_digest(state),
    )
    tensors = {f"model.{k}": v for k, v in state.items()}
    for k, v in (extra or {}).items():
        tensors[f"optim.{k}"] = v.detach().cpu().contiguous()
    text = json.dumps(record, indent=1, sort_keys=True)
    atomic_write_bytes(path, save(tensors, metadata={"img2dmp": text}))
    atomic_write_text(path.with_suffix(".json"), text + "\n")
    return path


def resolve_checkpoint(path: str | os.PathLike, name: str = DEFAULT_NAME) -> Path:
    """Find the weights file a user means: a ``.safetensors`` file, its ``.json`` sidecar,
    a run directory (its ``checkpoints/<name>.safetensors``) or a checkpoints directory."""
    p = Path(path)
    if p.is_dir():
        for cand in (p / CHECKPOINT_DIR / f"{name}{SUFFIX}", p / f"{name}{SUFFIX}"):
            if cand.is_file():
                return cand
        raise FileNotFoundError(
            f"{p} holds no checkpoint: expected {p / CHECKPOINT_DIR / (name + SUFFIX)}"
        )
    if p.suffix == ".json":
        p = p.with_suffix(SUFFIX)
    if not p.is_file():
        raise FileNotFoundError(f"checkpoint {p} does not exist")
    return p


def read_checkpoint_meta(path: str | os.PathLike) -> dict:
    """The JSON record inside a checkpoint, without reading the weights."""
    from safetensors import safe_open

    p = resolve_checkpoint(path)
    try:
        with safe_open(str(p), framework="pt") as f:
            raw = (f.metadata() or {}).get("img2dmp")
    except (SafetensorError, OSError, ValueError) as e:
        raise CheckpointError(f"checkpoint {p} is corrupt or truncated: {e}") from e
    return _parse_meta(p, raw)


def _parse_meta(p: Path, raw) -> dict:
    if raw is None:
        raise CheckpointError(
            f"{p} is a safetensors file but not an img2dmp checkpoint (no 'img2dmp' metadata)"
        )
    try:
        meta = json.loads(raw)
    except json.JSONDecodeError as e:
        raise CheckpointError(f"checkpoint {p}: metadata is not valid JSON ({e})") from e
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        fmt = meta.get("format") if isinstance(meta, dict) else None
        raise CheckpointError(f"{p}: metadata format is {fmt!r}, expected {FORMAT!r}")
    if meta.get("version") != VERSION:
        raise CheckpointError(
            f"{p}: checkpoint version {meta.get('version')!r} is not supported "
            f"(this img2dmp reads version {VERSION})"
        )
    return meta


def load_checkpoint(path: str | os.PathLike, name: str = DEFAULT_NAME) -> Checkpoint:
    """Read and verify a checkpoint written by :func:`save_checkpoint`.

    Raises
    ------
    FileNotFoundError
        Nothing at ``path``.
    CheckpointError
        The file is truncated or corrupt (unreadable header, or weights whose SHA-256 does
        not match the record), or not an img2dmp checkpoint.
    """
    p = resolve_checkpoint(path, name)
    try:
        tensors = load_file(str(p))
    except (SafetensorError, OSError, ValueError, RuntimeError) as e:
        raise CheckpointError(f"checkpoint {p} is corrupt or truncated: {e}") from e
    meta = read_checkpoint_meta(p)
    model_state = {k[6:]: v for k, v in tensors.items() if k.startswith("model.")}
    extra = {k[6:]: v for k, v in tensors.items() if k.startswith("optim.")}
    if not model_state:
        raise CheckpointError(f"checkpoint {p} holds no model weights")
    digest = weights_digest(model_state)
    if digest != meta.get("weights_sha256"):
        raise CheckpointError(
            f"checkpoint {p} is corrupt: its weights' SHA-256 {digest[:12]}... does not match "
            f"the recorded {str(meta.get('weights_sha256'))[:12]}..."
        )
    return Checkpoint(p, meta, model_state, extra)


def load_weights_into(model: torch.nn.Module, ckpt: Checkpoint) -> None:
    """``model.load_state_dict`` with a clear error when the architecture differs."""
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
    model.load_state_dict(ckpt.model_state)


def optimizer_to_tensors(opt: torch.optim.Optimizer) -> tuple[dict, dict]:
    """Split an optimiser's ``state_dict`` into tensors (for safetensors) and JSON."""
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
