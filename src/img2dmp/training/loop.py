"""The training loop, read top to bottom (Pahič et al., Sec. V).

:func:`train` = open the run (:func:`open_run`: configuration, data, network, optimiser,
cost; a fresh start, a resumed run or a fine-tuning) then :func:`fit`, which runs the
epochs. Each epoch: :func:`train_epoch` (batches through :func:`train_step`),
:func:`validate`, the learning-rate schedule, the checkpoints and records, early stopping.

The run directory receives::

    config.yaml              the resolved configuration
    metrics.csv              one row per epoch (train/validation error in px, lr, cost;
                             a stroke model's errors: its stroke shape error,
                             records.ERROR_MEASURES)
    training_curve.png       the same, as a picture
    checkpoints/best.*       lowest validation error (weights only)
    checkpoints/last.*       end of the latest epoch, with optimiser state (for resume)
    familiar.safetensors     at the end: how familiar an image is to the best checkpoint
                             (img2dmp.familiar; trained on a data-set file only)

A run that replaces another (``overwrite``) leaves the old one whole until its first
epoch is saved, then replaces all its files at once (:func:`.setup.replacing_old_run`).

Reproducibility: the initial weights, the per-epoch shuffling and (in generator mode) the
per-epoch samples are all drawn from generators seeded by ``(seed, epoch)``, never from
global state, so an uninterrupted run and one killed and resumed from ``last`` follow the
same numbers. ``last`` is written at the end of every epoch; a kill loses at most the
epoch under way.

Data-parallel: launched by ``torchrun`` (``WORLD_SIZE`` > 1) every process takes every
``world_size``-th sample of the same shuffled order, gradients are averaged by
``DistributedDataParallel`` over gloo, and rank 0 alone writes files.

One run at a time in a run directory: :func:`train` holds an advisory lock on
``run_dir/.lock`` (:func:`img2dmp._files.lock_directory`) from before it reads the
directory until it returns or fails; a second :func:`train` on that directory, in any
process, raises :class:`img2dmp._files.DirectoryBusy` at once.
"""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .._files import file_digest, lock_directory
from .._progress import bar, live, say
from ..errors import TrainingDiverged
from ..nn import Cost, trajectory_error_px
from ..nn.inference import dmp_trajectories
from .config import TrainConfig
from .data import Augmenter, Split, TrainingData
from .distributed import epoch_generator, on_rank0, process_group
from .records import ERROR_MEASURES, error_measure, plot_training_curve, write_metrics_csv
from .setup import Run, open_run, replacing_old_run
from .state import EpochStats, checkpoint_meta, save_state

#: The training curve costs ~0.3 s to draw; it is redrawn at most this often.
PLOT_EVERY_S = 20.0
_COST_EQ = {"parameter": "(9)", "trajectory": "(10)", "combined": "(9) + (10)"}


@dataclass
class TrainResult:
    """Summary of a finished (or early-stopped) run."""

    run_dir: Path
    epochs_run: int
    best_epoch: int
    best_val_error_px: float
    last_val_error_px: float
    history: list[dict]  # EpochStats.as_dict() per epoch, as in metrics.csv
    wall_s: float
    # What the errors measure: a key of records.ERROR_MEASURES ("trajectory": Table I's;
    # "stroke-shape": a stroke model's matched stroke shape error)
    error_measure: str = "trajectory"


@dataclass
class StepResult:
    """What one optimiser step measured on its batch."""

    cost: float
    error_px: torch.Tensor  # [b], Table I's error of the batch before the step


def train(
    config: TrainConfig,
    run_dir,
    *,
    resume: bool = False,
    overwrite: bool = False,
    epochs: int | None = None,
    device: str = "cpu",
    data=None,
) -> TrainResult:
    """Train the encoder-decoder network (Sec. V) with cost (9) or (10).

    Parameters
    ----------
    config : TrainConfig
        Model, data, optimiser, cost. It is not changed. With ``resume`` the configuration
        stored in the run's last checkpoint is used instead (only ``progress`` is taken
        from ``config``).
    run_dir : path
        Output directory (see the module docstring).
    resume : bool
        Continue from ``run_dir/checkpoints/last.safetensors``.
    overwrite : bool
        Start afresh in a run directory that already holds a run.
    epochs : int, optional
        Overrides ``optim.epochs``; with ``resume`` this is the way to train a finished or
        interrupted run further (a cosine schedule is stretched to the new end).
    device : str
        Where the network's weights live and its forward and backward passes run
        (``"cpu"``, ``"cuda"``); the costs and the DMP rollout stay on the CPU.
    data : path, optional
        With ``resume``: where the run's data set is now (moved, or the run resumed from
        another working directory than the one its relative ``data.path`` was given
        from). It must be the same file: its SHA-256 is checked against the run's.

    Returns
    -------
    TrainResult

    Raises
    ------
    TrainingDiverged
        The cost or the validation error became NaN or infinite.
    img2dmp._files.DirectoryBusy
        Another run holds ``run_dir`` (an ``OSError``).
    """
    t_start = time.perf_counter()
    run_dir = Path(run_dir)
    with (
        process_group() as (rank, world),
        on_rank0(lambda: lock_directory(run_dir, "run directory"), rank, world),
    ):
        run = open_run(config, run_dir, resume, overwrite, epochs, rank, world, device, data)
        return fit(run, t_start)


def fit(run: Run, t_start: float | None = None) -> TrainResult:
    """Run the epochs from ``run.state.next_epoch`` to ``optim.epochs`` (or early stop)."""
    t_start = time.perf_counter() if t_start is None else t_start
    cfg, state = run.cfg, run.state
    epochs = bar(
        range(state.next_epoch, cfg.optim.epochs),
        desc="epochs",
        total=cfg.optim.epochs,
        initial=state.next_epoch,
        unit="epoch",
        enabled=run.show_progress,
    )
    last_plot = -math.inf
    for epoch in epochs:
        t_epoch = time.perf_counter()
        lr = state.optimizer.param_groups[0]["lr"]
        train_cost, train_error = train_epoch(run, epoch)
        val_error = validate(run, epoch, fallback=train_error)
        improved = state.observe(val_error, epoch, run.cfg.data.train_on_validation)
        state.history.append(
            EpochStats(
                epoch,
                state.step,
                lr,
                train_cost,
                train_error,
                val_error,
                state.best_error_px,
                time.perf_counter() - t_epoch,
            )
        )
        _schedule(run, val_error)
        _report(run, epochs, state.history[-1])
        if run.rank == 0:
            with replacing_old_run(run.run_dir) if run.replaces else contextlib.nullcontext():
                if run.replaces:  # the old run's files go with this epoch's saved
                    run.write_config()
                save_state(run.run_dir, _meta(run), state, improved)
                write_metrics_csv(run.run_dir / "metrics.csv", state.history_dicts())
                if _stopping(run) or time.perf_counter() - last_plot >= PLOT_EVERY_S:
                    _plot(run)
                    last_plot = time.perf_counter()
            run.replaces = False
        if run.world > 1:
            torch.distributed.barrier()
        if _stopping(run) and epoch < cfg.optim.epochs - 1:
            if run.rank == 0 and run.show_progress:
                say(f"early stop: no better validation error for {cfg.optim.patience} epochs")
            epochs.update(1)  # a bar counts an epoch as the next begins: this one is done
            break
    epochs.close()
    if run.rank == 0:
        _write_familiar(run)
    return _result(run, time.perf_counter() - t_start)


def _write_familiar(run: Run) -> None:
    """``RUN/familiar.safetensors``: the best checkpoint's familiarity on the rows it
    trained and validated on (:func:`img2dmp.familiar.write_run_familiar`), when it
    trained on a data-set file that is still the one it read; a one-line note either
    way. A failure here costs the familiarity, never the training."""
    from ..familiar import RUN_FILE, write_run_familiar

    path, rows = run.cfg.data.path, run.data.rows
    if path is None or rows is None:
        return
    try:
        if file_digest(path) != run.data.dataset_sha256:
            (run.run_dir / RUN_FILE).unlink(missing_ok=True)
            say(f"note: {path} changed during training: no familiarity written")
            return
        written = write_run_familiar(run.run_dir, path, *rows)
    except (OSError, ValueError) as e:
        say(f"note: no familiarity written ({e})")
        return
    if written is None:
        say("note: no validation rows: no familiarity written (no 'unfamiliar' flag)")
    elif run.show_progress:
        say(f"familiarity of the best checkpoint (img2dmp.familiar): {written}")


def train_epoch(run: Run, epoch: int) -> tuple[float, float]:
    """One pass over the epoch's training split; mean cost and mean error (px)."""
    cfg, state = run.cfg, run.state
    split = run.data.train_for_epoch(epoch)
    n = len(split) - len(split) % run.world
    order = torch.randperm(len(split), generator=epoch_generator(cfg.seed, epoch))[:n]
    mine = order[run.rank :: run.world]  # every process sees the same order, its own share
    per_rank = max(1, cfg.optim.batch_size // run.world)
    rng = np.random.default_rng([cfg.seed, epoch, run.rank])  # augmentation, resumable
    rng_unlabelled = np.random.default_rng([cfg.seed, epoch, run.rank, 1])
    state.model.train()
    totals = torch.zeros(3, dtype=torch.float64)  # sum of cost * b, sum of error, samples
    batches = bar(
        range(0, len(mine), per_rank),
        desc=f"epoch {epoch}",
        leave=False,
        unit="batches",
        enabled=run.show_progress,
    )
    for lo in batches:
        images, times, paths, z_target = _batch(run, split, mine[lo : lo + per_rank], rng)
        try:
            out = train_step(
                run.net,
                state.optimizer,
                run.cost,
                images,
                times,
                paths,
                z_target,
                grad_clip=cfg.optim.grad_clip,
                unlabelled=run.data.unlabelled_batch(rng_unlabelled),
                unlabelled_weight=cfg.cost.unlabelled_weight,
            )
        except TrainingDiverged as e:
            raise _diverged(run, f"{e} at epoch {epoch}, step {state.step}") from None
        state.step += 1
        b = len(out.error_px)
        totals += torch.tensor([out.cost * b, float(out.error_px.sum()), b], dtype=torch.float64)
        batches.set_postfix(train_px=f"{totals[1] / totals[2]:.3f}")
    if run.world > 1:
        torch.distributed.all_reduce(totals)
    return float(totals[0] / totals[2]), float(totals[1] / totals[2])


def _batch(run: Run, split: Split, idx: torch.Tensor, rng: np.random.Generator):
    images, times = split.images[idx], split.times[idx]  # [b, H, W], [b, T]
    paths, z_target = split.trajectories[idx], split.z_target[idx]  # [b, T, d], [b, P]
    if run.augment is not None:  # the input filter first: a warp hides impulse noise
        filtered = run.state.model.input_filter(images)
        images, paths, z_target = run.augment(rng, filtered, times, paths, z_target)
    return images, times, paths, z_target


def train_step(
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    cost: Cost,
    images: torch.Tensor,  # [b, H, W]
    times: torch.Tensor,  # [b, T]
    trajectories: torch.Tensor,  # [b, T, d]
    z_target: torch.Tensor,  # [b, P], normalised DMP vector (cost 9's target)
    *,
    grad_clip: float | None = None,
    unlabelled: torch.Tensor | None = None,  # [u, H, W], images without a path
    unlabelled_weight: float = 1.0,
) -> StepResult:
    """One optimiser step on one batch: network, cost (9) or (10), backward, update.

    Also measures the batch's Table I error (the DMP rolled out at the demonstration's
    time stamps; for cost (10) the cost's own rollout, for cost (9) one more).
    ``unlabelled`` images (semi-supervised) add ``unlabelled_weight`` times the cost's
    ink terms (:meth:`img2dmp.nn.Cost.image_terms`), at the batch's first time stamps.

    Raises
    ------
    TrainingDiverged
        The cost is NaN or infinite; the weights are left as they were.
    """
    b = len(images)
    both = images if unlabelled is None else torch.cat([images, unlabelled])
    out = model(both)  # one forward pass for both: [b (+ u), P | K (P + 1)]
    z = out[:b]
    loss, y = cost(z, z_target, times, trajectories, images if cost.uses_images else None)
    if unlabelled is not None and cost.uses_images and unlabelled_weight > 0:
        t_u = times[:1].expand(len(unlabelled), -1)  # [u, T]
        loss = loss + unlabelled_weight * cost.image_terms(out[b:], unlabelled, t_u)
    if not torch.isfinite(loss):
        raise TrainingDiverged(f"training cost is {float(loss.detach())}")
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if grad_clip:
        torch.nn.utils.clip_grad_norm_(model.parameters(), grad_clip)
    optimizer.step()
    with torch.no_grad():
        error = cost.errors_px(z.detach(), y, times, trajectories)  # [b]
    return StepResult(float(loss.detach()), error)


@torch.no_grad()
def trajectory_errors(
    model, normaliser, dmp_config, images, times, trajectories, batch_size: int = 1024
) -> np.ndarray:
    """Per-sample mean Euclidean distance ``[M]`` (px, on x and y) between the
    demonstrations ``[M, T, d]`` and the network's DMPs for ``images [M, H, W]`` rolled out
    at the demonstrations' time stamps ``[M, T]`` (Table I's metric)."""
    y = dmp_trajectories(model, normaliser, dmp_config, images, times, batch_size)
    return trajectory_error_px(y, torch.as_tensor(trajectories)).double().numpy()


def validate(run: Run, epoch: int, fallback: float) -> float:
    """Mean validation error (px): Table I's trajectory error, or a stroke model's stroke
    shape error (:data:`~.records.ERROR_MEASURES`); ``fallback`` (the training error) with
    no validation."""
    val = run.data.val
    if not isinstance(run.cost, Cost):  # a stroke model: the mean shape error per stroke
        err = _stroke_errors(run, val)
    else:
        err = trajectory_errors(
            run.state.model,
            run.data.normaliser,
            run.data.dmp_config,
            val.images,
            val.times,
            val.trajectories,
            run.cfg.eval_batch_size,
        )
    mean = float(err.mean()) if len(err) else fallback
    if not math.isfinite(mean):
        raise _diverged(run, f"validation error is {mean} at epoch {epoch}")
    return mean


@torch.no_grad()
def _stroke_errors(run: Run, split) -> np.ndarray:
    """A stroke model's stroke shape error per sample (px) on ``split``, in batches: each
    true stroke against the predicted stroke matched to it (``StrokeCost``), not Table I's
    error of the whole path (:data:`~.records.ERROR_MEASURES`)."""
    model, out = run.state.model, []
    model.eval()
    try:
        for lo in range(0, len(split), run.cfg.eval_batch_size):
            sl = slice(lo, lo + run.cfg.eval_batch_size)
            z = model(split.images[sl])
            _, err = run.cost(z, split.z_target[sl], split.times[sl], split.trajectories[sl])
            out.append(err.double().cpu().numpy())
    finally:
        model.train()
    return np.concatenate(out) if out else np.zeros(0)


def _diverged(run: Run, what: str) -> TrainingDiverged:
    """The error of a diverged run, saying truly which checkpoints it leaves."""
    ckpt = run.run_dir / "checkpoints"
    best, last = ckpt / "best.safetensors", ckpt / "last.safetensors"
    state = run.state
    if state.history and best.is_file() and last.is_file():
        kept = (
            f"the checkpoints of the best epoch ({state.best_epoch}), {best}, and of the "
            f"last good epoch ({state.history[-1].epoch}), {last}, are kept"
        )
    elif best.is_file() or last.is_file():
        kept = f"no epoch of this run finished; the earlier checkpoints in {ckpt} are as they were"
    else:
        kept = "no epoch finished, so no checkpoint was written"
    return TrainingDiverged(
        f"{what}: training diverged (lower optim.lr = {run.cfg.optim.lr:g} or set "
        f"optim.grad_clip); {kept}"
    )


def _schedule(run: Run, val_error: float) -> None:
    sched = run.state.scheduler
    if sched is None:
        return
    if run.cfg.optim.schedule == "plateau":
        sched.step(val_error)
    else:
        sched.step()


def _stopping(run: Run) -> bool:
    patience, state = run.cfg.optim.patience, run.state
    last = state.history[-1].epoch if state.history else -1
    return last >= run.cfg.optim.epochs - 1 or bool(patience and state.bad_epochs >= patience)


def _report(run: Run, epochs, s: EpochStats) -> None:
    if not run.show_progress:
        return
    if live():
        epochs.set_postfix(
            train_px=f"{s.train_error_px:.3f}",
            val_px=f"{s.val_error_px:.3f}",
            best=f"{s.best_val_error_px:.3f}",
        )
    else:
        val = "validation (trained on)" if run.cfg.data.train_on_validation else "validation"
        measure = ERROR_MEASURES[error_measure(bool(run.cfg.strokes.slots))]
        say(
            f"epoch {s.epoch + 1}/{run.cfg.optim.epochs}: {measure} train "
            f"{s.train_error_px:.4f} px, "
            f"{val} {s.val_error_px:.4f} px (best {s.best_val_error_px:.4f}), "
            f"lr {s.lr:.2g}, {s.epoch_time_s:.1f} s"
        )


def _meta(run: Run) -> dict:
    return checkpoint_meta(run.cfg, run.data, run.state, run.weighting)


def _plot(run: Run) -> None:
    title = (
        f"{run.run_dir.name}: cost {_COST_EQ[run.cfg.cost.name]}, {run.cfg.model.encoder} encoder"
    )
    measure = error_measure(bool(run.cfg.strokes.slots))
    plot_training_curve(
        run.run_dir / "training_curve.png", run.state.history_dicts(), title, measure
    )


def _result(run: Run, wall_s: float) -> TrainResult:
    s = run.state
    return TrainResult(
        run_dir=run.run_dir,
        epochs_run=len(s.history),
        best_epoch=s.best_epoch,
        best_val_error_px=s.best_error_px,
        last_val_error_px=s.history[-1].val_error_px if s.history else math.nan,
        history=s.history_dicts(),
        wall_s=wall_s,
        error_measure=error_measure(bool(run.cfg.strokes.slots)),
    )


__all__ = [
    "Augmenter",
    "StepResult",
    "TrainResult",
    "TrainingData",
    "fit",
    "train",
    "train_epoch",
    "train_step",
    "trajectory_errors",
    "validate",
]
