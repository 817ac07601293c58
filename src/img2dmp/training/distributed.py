"""Data-parallel training under ``torchrun`` (gloo) and the run's random streams."""

from __future__ import annotations

import os
from contextlib import contextmanager

import torch


def _rank_and_world() -> tuple[int, int]:
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


@contextmanager
def process_group():
    """Join the process group ``torchrun`` prepared (``WORLD_SIZE`` > 1) for the block;
    yields ``(rank, world_size)``, ``(0, 1)`` in a single process."""
    created = False
    wanted = int(os.environ.get("WORLD_SIZE", "1")) > 1 and torch.distributed.is_available()
    if wanted and not torch.distributed.is_initialized():
        torch.distributed.init_process_group(backend="gloo")
        created = True
    try:
        yield _rank_and_world()
    finally:
        if created:
            torch.distributed.destroy_process_group()


def epoch_generator(seed: int, epoch: int, stream: int = 0) -> torch.Generator:
    """An independent, reproducible stream per ``(seed, epoch, purpose)``."""
    return torch.Generator().manual_seed((seed * 1_000_003 + epoch * 7919 + stream) % (2**63))


__all__ = ["epoch_generator", "process_group"]
