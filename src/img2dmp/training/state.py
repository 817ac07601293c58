"""A run's state as it goes on, its epoch statistics, and its checkpoints.

Everything that changes from epoch to epoch lives in one :class:`RunState`; what an
epoch measured is one :class:`EpochStats`. ``checkpoints/last`` holds the whole state
(with the optimiser's), so a killed run resumes where it stopped; ``checkpoints/best``
the weights of the epoch with the lowest validation error. Both are safetensors weights
with a JSON record beside (no pickled code), see :mod:`img2dmp.checkpoint`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from ..checkpoint import (
    CHECKPOINT_DIR,
    Checkpoint,
    load_weights_into,
    optimizer_from_tensors,
    optimizer_to_tensors,
    save_checkpoint,
)
from .config import TrainConfig
from .data import TrainingData
from .records import error_measure


@dataclass
class EpochStats:
    """What one epoch measured: a row of ``metrics.csv``."""

    epoch: int
    step: int  # optimiser steps so far
    lr: float  # learning rate during the epoch
    train_cost: float  # mean cost over the epoch's batches
    train_error_px: float  # mean Table-I error of the training batches (before each step)
    val_error_px: float
    best_val_error_px: float
    epoch_time_s: float

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class RunState:
    """The changing part of a run: network, optimiser, schedule, counters and history."""

    model: torch.nn.Module
    optimizer: torch.optim.Optimizer
    scheduler: object | None  # a torch LR scheduler
    history: list[EpochStats] = field(default_factory=list)
    next_epoch: int = 0
    step: int = 0
    best_error_px: float = math.inf
    best_epoch: int = -1
    bad_epochs: int = 0  # epochs since the best one (early stopping)

    def observe(self, val_error_px: float, epoch: int, last_is_best: bool = False) -> bool:
        """Take an epoch's validation error; True if it is the best so far (always, with
        ``last_is_best``: a run that trains on its validation split keeps its last epoch)."""
        improved = last_is_best or val_error_px < self.best_error_px
        if improved:
            self.best_error_px, self.best_epoch, self.bad_epochs = val_error_px, epoch, 0
        else:
            self.bad_epochs += 1
        return improved

    def history_dicts(self) -> list[dict]:
        return [s.as_dict() for s in self.history]

    def restore(self, ckpt: Checkpoint, epochs: int) -> None:
        """Continue from a ``last`` checkpoint; a cosine schedule now ends at ``epochs``."""
        meta = ckpt.meta
        load_weights_into(self.model, ckpt)
        self.optimizer.load_state_dict(optimizer_from_tensors(ckpt.extra, meta["optimizer"]))
        if self.scheduler is not None and meta.get("scheduler"):
            self.scheduler.load_state_dict(meta["scheduler"])
            if isinstance(self.scheduler, torch.optim.lr_scheduler.CosineAnnealingLR):
                self.scheduler.T_max = epochs
        self.history = [EpochStats(**row) for row in meta["history"]]
        best = meta["best_val_error_px"]
        self.best_error_px = math.inf if best is None else float(best)
        self.best_epoch = meta["best_epoch"]
        self.bad_epochs = meta["bad_epochs"]
        self.next_epoch = meta["epoch"] + 1
        self.step = meta["step"]


def checkpoint_meta(cfg: TrainConfig, data: TrainingData, state: RunState, weighting) -> dict:
    """The JSON record saved beside the weights: all a model needs to be rebuilt and used."""
    last = state.history[-1] if state.history else None
    return {
        "kind": "img2dmp-model",
        "model": cfg.model.to_dict(),
        "normaliser": data.normaliser.to_dict(),
        "parameter_weighting": weighting.to_dict() if weighting else None,
        "dmp_config": data.dmp_config.to_dict(),
        "strokes": layout.to_dict() if (layout := cfg.strokes.layout()) else None,
        "train_config": cfg.to_dict(),
        "dataset": {
            "path": cfg.data.path,
            "sha256": data.dataset_sha256,
            "class_names": list(data.class_names) if data.class_names else None,
        },
        "image_size": list(cfg.model.image_size),
        "ink_margin": data.ink_margin,
        "stroke_width_px": data.stroke_width_px,
        "epoch": last.epoch if last else -1,
        "val_error_px": last.val_error_px if last else None,
        "best_val_error_px": state.best_error_px,
        # what the two errors measure (records.ERROR_MEASURES; absent: "trajectory")
        "val_error_measure": error_measure(bool(cfg.strokes.slots)),
        "best_epoch": state.best_epoch,
        "torch_version": torch.__version__,
        "numerics": numerics(),
    }


#: The environment variables that choose how MKL and OpenMP sum (their threads, MKL's
#: instruction set): runs that differ in them train other weights, to rounding at first.
NUMERICS_ENV = ("MKL_ENABLE_INSTRUCTIONS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")


def numerics() -> dict:
    """What decides a run's last bits besides its configuration and data: the CPU, torch's
    threads and instruction set, the variables of :data:`NUMERICS_ENV` that are set (one
    recipe trained other weights on an AVX2 CPU than on an AVX-512 one, and MKL's thread
    count or instruction set moves a demo's test error in the third decimal)."""
    import os
    import platform

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f
                        if line.startswith("model name")), cpu)  # fmt: skip
    except OSError:  # not Linux
        pass
    return {
        "cpu": cpu,
        "torch_threads": torch.get_num_threads(),
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "env": {k: os.environ[k] for k in NUMERICS_ENV if k in os.environ},
    }


def save_state(run_dir: Path, meta: dict, state: RunState, improved: bool) -> None:
    """``best`` (if ``improved``) and ``last`` (always, with the optimiser) checkpoints."""
    ckpt_dir = run_dir / CHECKPOINT_DIR
    weights = state.model.state_dict()
    if improved:
        save_checkpoint(ckpt_dir / "best.safetensors", weights, meta)
    opt_tensors, opt_record = optimizer_to_tensors(state.optimizer)
    resume_record = {
        "optimizer": opt_record,
        "scheduler": state.scheduler.state_dict() if state.scheduler is not None else None,
        "history": state.history_dicts(),
        "bad_epochs": state.bad_epochs,
        "step": state.step,
    }
    save_checkpoint(ckpt_dir / "last.safetensors", weights, {**meta, **resume_record}, opt_tensors)


__all__ = ["EpochStats", "RunState", "checkpoint_meta", "save_state"]
