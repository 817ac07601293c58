"""Data-parallel training under ``torchrun`` (gloo) and the run's random streams."""

from __future__ import annotations

import os
from contextlib import ExitStack, contextmanager

import torch

from ..errors import Img2dmpError


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
        if created:  # every rank done with the group before any tears it down
            torch.distributed.barrier()
    finally:
        if created:
            torch.distributed.destroy_process_group()


@contextmanager
def on_rank0(make, rank: int, world: int):
    """Enter the context ``make()`` (a lock of the run directory) on rank 0 alone, for the
    block; if rank 0 fails to enter it, every rank raises (rank 0 its own error), so that
    no rank waits for the others in vain."""
    failure = None
    with ExitStack() as stack:
        if rank == 0:
            try:
                stack.enter_context(make())
            except Exception as e:  # noqa: BLE001 - told to every rank, then re-raised
                failure = e
        if world > 1:
            flag = torch.tensor([0 if failure is None else 1])
            torch.distributed.broadcast(flag, src=0)
            if failure is None and int(flag.item()):
                failure = Img2dmpError(f"rank 0 could not start the run (rank {rank} stops too)")
        if failure is not None:
            raise failure
        yield


def epoch_generator(seed: int, epoch: int, stream: int = 0) -> torch.Generator:
    """An independent, reproducible stream per ``(seed, epoch, purpose)``."""
    return torch.Generator().manual_seed((seed * 1_000_003 + epoch * 7919 + stream) % (2**63))


__all__ = ["epoch_generator", "on_rank0", "process_group"]
