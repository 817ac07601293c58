"""How familiar an image is to a model: whether it looks like the drawings it learnt.

A stroke model reads the characters it was trained on well and those of an alphabet it
never saw much worse (experiments/RESULTS.md §8.9: the count right for 44 % instead of
79 %), and its count's own probability does not tell them apart (§8.8). The encoder
does (§8.11): an image's **familiarity** is the cosine similarity of its encoder
features (what the decoder reads) to those of the nearest training drawing. A model may
carry its training drawings' features and a **line**, the familiarity that all but
:data:`QUANTILE` of its validation drawings reach; a prediction below the line is
flagged ``"unfamiliar"``.

The features are stored as safetensors (``features``, float16 ``[N, F]``, unit rows) with
the line and how it was drawn in the file's JSON metadata: no code is stored. A shipped
model carries one (``familiar.safetensors`` beside its weights, its SHA-256 in
``model.json``); ``img2dmp train`` writes one into a run directory for its best
checkpoint (:func:`write_run_familiar`, read back by :func:`run_familiar` only for the
weights it was drawn for).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ._files import atomic_write_bytes, file_digest

#: The format name in a familiarity file's metadata.
FORMAT = "img2dmp-familiar"
VERSION = 1
#: The share of the validation drawings left below the line.
QUANTILE = 0.05
#: A familiarity within this of 1 is 1: a drawing whose features are a training
#: drawing's, its cosine rounded in float32 (1 - 6e-8 on an AVX-512 EPYC).
SAME_COSINE = 1e-6
#: At most this many training drawings' features are kept (a random choice of them,
#: seeded): 16,384 of 64 features are 2 MB, under the 3 MB a shipped file may take.
MAX_TRAIN = 16384
#: A run directory's familiarity file (beside ``checkpoints/``), as a shipped model's.
RUN_FILE = "familiar.safetensors"


def unit_rows(features) -> np.ndarray:
    """``features [N, F]`` as float64 rows of length 1 (a zero row stays zero)."""
    f = np.asarray(features, dtype=np.float64)
    return f / np.maximum(np.linalg.norm(f, axis=-1, keepdims=True), 1e-12)


@dataclass(frozen=True)
class Familiar:
    """A model's training drawings' encoder features ``[N, F]`` (unit rows; float16 as a
    file stores them, in :func:`fit_familiar` too) and the
    ``line`` below which an image is unfamiliar; ``quantile``, ``n_validation``: how the
    line was drawn (that share of that many validation drawings lie below it);
    ``weights_sha256``: the checkpoint file it was drawn for, when recorded (a run's)."""

    features: np.ndarray
    line: float
    quantile: float = QUANTILE
    n_validation: int = 0
    weights_sha256: str | None = None

    def __post_init__(self):
        f = np.asarray(self.features)
        if f.ndim != 2 or not len(f) or not np.isfinite(f).all():
            raise ValueError(f"familiar features must be a finite [N, F] array, got {f.shape}")
        if not np.isfinite(self.line) or not -1.0 <= self.line <= 1.0:
            raise ValueError(f"familiar line must be a cosine in [-1, 1], got {self.line!r}")
        # [N, F] float32, made once; each product with them is taken in float64.
        object.__setattr__(self, "_unit", unit_rows(f).astype(np.float32))

    @property
    def feature_size(self) -> int:
        return int(np.asarray(self.features).shape[1])

    def __repr__(self) -> str:  # the features themselves are thousands of rows
        n, f = np.asarray(self.features).shape
        drawn = f", for weights {self.weights_sha256[:12]}" if self.weights_sha256 else ""
        return (
            f"Familiar({n} training drawings x {f} features, line {self.line:.4f}: "
            f"{100 * self.quantile:g} % of {self.n_validation} validation drawings below it"
            f"{drawn})"
        )

    def familiarity(self, features) -> np.ndarray:
        """The familiarity ``[B]`` of images whose encoder features are ``[B, F]``: the
        largest cosine similarity to a training drawing's."""
        f = unit_rows(features)
        if f.ndim != 2 or f.shape[1] != self.feature_size:
            raise ValueError(
                f"features must be [B, {self.feature_size}] (the model's encoder), got {f.shape}"
            )
        ref, out = self._unit, np.full(len(f), -1.0)
        for b in range(0, len(f), 1024):  # [1024, 4096] products at a time (32 MB)
            for a in range(0, len(ref), 4096):
                best = (f[b : b + 1024] @ ref[a : a + 4096].T).max(1)
                np.maximum(out[b : b + 1024], best, out=out[b : b + 1024])
        # float32 unit rows can pass 1 by a rounding, or fall short of it: a drawing whose
        # features are a training drawing's is as familiar as can be, whichever way it
        # rounded (a line drawn at 1 would otherwise flag it, by 6e-8)
        out[out > 1.0 - SAME_COSINE] = 1.0
        return out

    def save(self, path: str | os.PathLike) -> Path:
        """Write the features (float16) and the line to ``path`` atomically."""
        from safetensors.numpy import save

        meta = {"format": FORMAT, "version": VERSION, "line": float(self.line),
                "quantile": float(self.quantile),
                "n_validation": int(self.n_validation)}  # fmt: skip
        if self.weights_sha256 is not None:
            meta["weights_sha256"] = str(self.weights_sha256)
        data = save({"features": unit_rows(self.features).astype(np.float16)},
                    metadata={"familiar": json.dumps(meta)})  # fmt: skip
        atomic_write_bytes(path, data)
        return Path(path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> Familiar:
        """Read a file :meth:`save` wrote; ``ValueError`` naming the file and what is wrong."""
        from safetensors import SafetensorError, safe_open

        p = Path(path)
        try:
            with safe_open(p, framework="numpy") as f:
                raw = (f.metadata() or {}).get("familiar")
                features = f.get_tensor("features") if "features" in f.keys() else None
        except (OSError, SafetensorError) as e:
            raise ValueError(f"familiarity file {p} cannot be read: {e}") from None
        try:
            meta = json.loads(raw) if raw is not None else None
        except ValueError:
            meta = None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT or features is None:
            raise ValueError(f"{p} is not a familiarity file (format {FORMAT!r}, 'features')")
        if meta.get("version") != VERSION:
            raise ValueError(f"{p}: familiarity file version {meta.get('version')!r} is not "
                             f"supported (this img2dmp reads version {VERSION})")  # fmt: skip
        try:
            quantile, n = float(meta.get("quantile", QUANTILE)), int(meta.get("n_validation", 0))
            weights = meta.get("weights_sha256")
            if weights is not None and not isinstance(weights, str):
                raise ValueError(f"weights_sha256 must be a string, got {weights!r}")
            return cls(features, float(meta["line"]), quantile, n, weights)  # as stored
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{p}: {e}") from None


def shipped_familiar(model) -> Familiar | None:
    """The :class:`Familiar` a shipped model (:class:`~img2dmp.models.ShippedModel`)
    carries, its file's SHA-256 checked (:func:`~img2dmp.models.verified_familiar`);
    None if it carries none."""
    from .errors import ShippedModelError
    from .models import verified_familiar

    path = verified_familiar(model)
    if path is None:
        return None
    try:
        return Familiar.load(path)
    except ValueError as e:
        raise ShippedModelError(f"shipped model {model.name}: {e}; reinstall img2dmp") from None


def run_familiar(checkpoint: str | os.PathLike) -> Familiar | None:
    """The familiarity ``img2dmp train`` wrote into the run directory of ``checkpoint``
    (a file in ``RUN/checkpoints/``; :data:`RUN_FILE` in ``RUN``), if it was drawn for
    that checkpoint's weights (its recorded SHA-256 is the file's); None otherwise (no
    file, another checkpoint, a checkpoint outside a run). ``ValueError`` naming a
    damaged file."""
    from .checkpoint import CHECKPOINT_DIR

    ckpt = Path(checkpoint)
    path = ckpt.parent.parent / RUN_FILE
    if ckpt.parent.name != CHECKPOINT_DIR or not path.is_file():
        return None
    try:
        familiar = Familiar.load(path)
    except ValueError as e:
        raise ValueError(f"{e}; remove it, or write it again with "
                         f"img2dmp.familiar.write_run_familiar({str(ckpt.parent.parent)!r}, "
                         "DATA)") from None  # fmt: skip
    if familiar.weights_sha256 is None or familiar.weights_sha256 != file_digest(ckpt):
        return None
    return familiar


class _Rows:
    """Images and a split of chosen rows (0: training, 1: validation, -1: neither), as
    :func:`fit_familiar` reads a data set."""

    def __init__(self, images, train_idx, val_idx):
        self.images = images
        self.split = np.full(len(images), -1, dtype=np.int64)
        self.split[np.asarray(train_idx, dtype=np.int64)] = 0
        self.split[np.asarray(val_idx, dtype=np.int64)] = 1


class _Encoder:
    """The encoder of a checkpoint file, in NumPy, as :func:`fit_familiar` reads a model."""

    def __init__(self, checkpoint: Path):
        from .checkpoint import load_checkpoint
        from .nn._numpy_net import NumpyNetwork
        from .nn.architecture import ModelConfig

        ckpt = load_checkpoint(checkpoint, framework="numpy")
        self.network = NumpyNetwork(ModelConfig.from_dict(ckpt.meta["model"]), ckpt.model_state)

    def encoder_features(self, images) -> np.ndarray:
        return self.network.features(np.asarray(images, dtype=np.float32))


def write_run_familiar(run_dir: str | os.PathLike, data, train_idx=None,
                       val_idx=None) -> Path | None:  # fmt: skip
    """Fit the familiarity of a run's best checkpoint (:func:`fit_familiar`) on the data
    set it trained on (a :class:`~img2dmp.data.store.DigitData` or its path; the rows
    ``train_idx`` and ``val_idx`` when given, else its splits) and write it to
    ``RUN/familiar.safetensors`` with the checkpoint's SHA-256; None (nothing written, an
    older file removed) when there are no validation rows to draw the line on."""
    from .checkpoint import resolve_checkpoint
    from .data.store import load_dataset

    run = Path(run_dir)
    ckpt = resolve_checkpoint(run)
    if isinstance(data, (str, os.PathLike)):
        data = load_dataset(data)
    if train_idx is not None and val_idx is not None:
        data = _Rows(data.images, train_idx, val_idx)
    if not (np.asarray(data.split) == 1).any():
        (run / RUN_FILE).unlink(missing_ok=True)  # drawn for other weights, if any
        return None
    familiar = fit_familiar(_Encoder(ckpt), data)
    familiar = replace(familiar, weights_sha256=file_digest(ckpt))
    return familiar.save(run / RUN_FILE)


def fit_familiar(
    predictor, data, quantile: float = QUANTILE, max_train: int = MAX_TRAIN
) -> Familiar:
    """The :class:`Familiar` of ``predictor``'s model from a data set (a
    :class:`~img2dmp.data.store.DigitData` or its path): its training split's features
    (at most ``max_train`` of its rows, chosen at random with seed 0), and the line that
    ``quantile`` of its validation split falls below. Choose it on the data set the model
    trained on; ``ValueError`` if a split is empty."""
    from .data.store import load_dataset

    if isinstance(data, (str, os.PathLike)):
        data = load_dataset(data)
    if not 0.0 < quantile < 0.5:
        raise ValueError(f"quantile must be in (0, 0.5), got {quantile!r}")
    if isinstance(max_train, bool) or not isinstance(max_train, int) or max_train < 1:
        raise ValueError(f"max_train must be a positive integer, got {max_train!r}")
    split = np.asarray(data.split)
    train, val = np.flatnonzero(split == 0), np.flatnonzero(split == 1)
    if len(train) > max_train:
        train = np.sort(np.random.default_rng(0).choice(train, max_train, replace=False))
    if not len(train) or not len(val):
        raise ValueError(f"the data set needs training and validation rows, has {len(train)} "
                         f"and {len(val)}")  # fmt: skip
    ref = unit_rows(predictor.encoder_features(data.images[train])).astype(np.float16)
    probe = Familiar(ref, 0.0)
    line = float(np.quantile(probe.familiarity(predictor.encoder_features(data.images[val])),
                             quantile))  # fmt: skip
    return Familiar(ref, line, quantile, len(val))


__all__ = [
    "FORMAT",
    "MAX_TRAIN",
    "QUANTILE",
    "Familiar",
    "RUN_FILE",
    "fit_familiar",
    "run_familiar",
    "shipped_familiar",
    "write_run_familiar",
    "unit_rows",
]
