"""Torch data sets: stored samples (map-style) and fresh synthetic samples (iterable).

Both yield the same dict per sample::

    image         float32 [1, H, W]   ink = 1 (a channel axis for the encoder)
    trajectory    float32 [T, d]      demonstrated path, pixels
    times         float32 [T]         seconds
    label         int64   []          digit
    params        float32 [P]         fitted DMP, flat vector
    fit_error_px  float32 []          error of that fit

so the default collate function stacks them into batches.
"""

from __future__ import annotations

import os

import numpy as np
import torch
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from ..dmp import DMPConfig
from .store import DigitData, load_dataset


def _sample_dict(data: DigitData, i: int) -> dict[str, torch.Tensor]:
    return {
        "image": torch.from_numpy(data.images[i]).unsqueeze(0),  # [1, H, W]
        "trajectory": torch.from_numpy(data.trajectories[i]),  # [T, d]
        "times": torch.from_numpy(data.times[i]),  # [T]
        "label": torch.tensor(int(data.labels[i])),
        "params": torch.from_numpy(data.params[i]),  # [P]
        "fit_error_px": torch.tensor(float(data.fit_error_px[i])),
    }


class StoredDigits(Dataset):
    """Map-style data set over a stored data-set file (or a :class:`DigitData`).

    Parameters
    ----------
    source : path or DigitData
        A file written by :func:`img2dmp.data.save_dataset`, or arrays in memory.
    split : {"train", "validation", "test"} or None
        Keep only this split; None keeps all.
    """

    def __init__(self, source: str | os.PathLike | DigitData, split: str | None = None):
        data = source if isinstance(source, DigitData) else load_dataset(source)
        self.data = data if split is None else data.select_split(split)

    def __len__(self) -> int:
        return len(self.data)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        if not -len(self) <= i < len(self):
            raise IndexError(f"index {i} out of range for {len(self)} samples")
        return _sample_dict(self.data, int(i) % len(self))

    @property
    def dmp_config(self) -> DMPConfig:
        return self.data.dmp_config


class SyntheticDigitStream(IterableDataset):
    """Fresh synthetic digits, generated on the fly, never the same sample twice.

    Each iterator draws chunks of ``chunk_size`` samples with
    :func:`img2dmp.data.synthetic.generate`. Its random stream is seeded from
    ``(seed, epoch, worker id, number of workers)``, so under a ``DataLoader`` with
    several workers every worker produces a different stream, and each epoch (see
    :meth:`set_epoch`) a new one. With ``seed=None`` the streams come from torch's
    per-worker seed (``DataLoader`` draws a fresh one each epoch; set ``torch.manual_seed``
    for reproducibility).

    Parameters
    ----------
    config : SyntheticConfig
        Generator settings (digits, sizes, ranges); default ``SyntheticConfig()``.
    samples_per_epoch : int or None
        Samples per pass, shared out among the workers; None streams forever.
    seed : int or None
    chunk_size : int
        Samples generated at once (vectorised) inside each worker.
    dmp_config : DMPConfig
    """

    def __init__(
        self,
        config=None,
        samples_per_epoch: int | None = None,
        seed: int | None = 0,
        chunk_size: int = 256,
        dmp_config: DMPConfig | None = None,
    ):
        from .synthetic import SyntheticConfig

        super().__init__()
        self.config = config or SyntheticConfig()
        if samples_per_epoch is not None and (
            not isinstance(samples_per_epoch, int) or samples_per_epoch < 1
        ):
            raise ValueError(
                f"samples_per_epoch must be an integer >= 1 or None, got {samples_per_epoch!r}"
            )
        if seed is not None and (not isinstance(seed, int) or seed < 0):
            raise ValueError(f"seed must be an integer >= 0 or None, got {seed!r}")
        if not isinstance(chunk_size, int) or chunk_size < 1:
            raise ValueError(f"chunk_size must be an integer >= 1, got {chunk_size!r}")
        self.samples_per_epoch = samples_per_epoch
        self.seed = seed
        self.chunk_size = chunk_size
        self.dmp_config = dmp_config or DMPConfig()
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch; each epoch draws samples no other epoch draws."""
        if not isinstance(epoch, int) or epoch < 0:
            raise ValueError(f"epoch must be an integer >= 0, got {epoch!r}")
        self.epoch = epoch

    def __len__(self) -> int:
        if self.samples_per_epoch is None:
            raise TypeError("an endless SyntheticDigitStream has no length")
        return self.samples_per_epoch

    def _rng(self) -> tuple[np.random.Generator, int, int]:
        info = get_worker_info()
        wid, nw = (0, 1) if info is None else (info.id, info.num_workers)
        if self.seed is None:
            base = torch.initial_seed() if info is None else info.seed
            seq = np.random.SeedSequence([base % (1 << 63), wid])
        else:
            seq = np.random.SeedSequence([self.seed, self.epoch, wid, nw])
        return np.random.default_rng(seq), wid, nw

    def __iter__(self):
        from .synthetic import generate

        rng, wid, nw = self._rng()
        if self.samples_per_epoch is None:
            remaining = None
        else:  # worker k gets every nw-th sample of the epoch, rounded up for the first ones
            remaining = len(range(wid, self.samples_per_epoch, nw))
        digits = np.array(self.config.digits, dtype=np.int64)
        while remaining is None or remaining > 0:
            n = self.chunk_size if remaining is None else min(self.chunk_size, remaining)
            labels = rng.choice(digits, size=n)
            data = generate(labels, self.config, rng, self.dmp_config)
            for i in range(n):
                yield _sample_dict(data, i)
            if remaining is not None:
                remaining -= n
