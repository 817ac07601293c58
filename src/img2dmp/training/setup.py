"""Opening a run: a fresh start, a resumed run or a fine-tuning, resolved once.

:func:`open_run` reads the configuration (the stored one when resuming), loads the data,
checks that a resumed or initialising checkpoint fits them, builds the network, the
optimiser, the schedule and the cost, and writes ``config.yaml`` (a run that replaces
another writes it with its first epoch: :func:`replacing_old_run`). What it returns,
:class:`Run`, is everything the loop needs; only ``run.state`` changes afterwards.
"""

from __future__ import annotations

import contextlib
import copy
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import torch
import yaml

from .._files import atomic_write_text, file_digest
from ..checkpoint import (
    CHECKPOINT_DIR,
    Checkpoint,
    CheckpointError,
    load_checkpoint,
    load_weights_into,
)
from ..nn import Cost, ParamNormaliser, build_model
from ..nn.costs import ParameterWeighting
from ..nn.device import place_model
from .config import OptimConfig, TrainConfig, machine_cores
from .data import Augmenter, TrainingData
from .records import write_metrics_csv
from .state import RunState


@dataclass
class Run:
    """A training run being carried out: its fixed parts and its :class:`RunState`."""

    cfg: TrainConfig  # resolved: image size and output count from the data
    run_dir: Path
    data: TrainingData
    weighting: ParameterWeighting | None  # cost (9)'s per-unit weights
    cost: Cost  # or a stroke model's StrokeCost (the same call)
    augment: Augmenter | None
    state: RunState
    net: torch.nn.Module  # state.model, or its DistributedDataParallel wrapper
    rank: int = 0
    world: int = 1
    # a fresh run (overwrite) in a directory that holds another: the old run stays whole
    # until this one's first epoch is saved (replacing_old_run)
    replaces: bool = False

    @property
    def show_progress(self) -> bool:
        return self.cfg.progress and self.rank == 0

    def write_config(self) -> None:
        """``config.yaml``: the resolved configuration."""
        text = yaml.safe_dump(self.cfg.to_dict(), sort_keys=False)
        atomic_write_text(self.run_dir / "config.yaml", text)


def open_run(
    config: TrainConfig,
    run_dir: Path,
    resume: bool = False,
    overwrite: bool = False,
    epochs: int | None = None,
    rank: int = 0,
    world: int = 1,
    device: str = "cpu",
    data=None,
) -> Run:
    """Everything :func:`~.loop.fit` needs, from a configuration and a run directory; the
    network's weights on ``device`` (:func:`img2dmp.nn.device.place_model`). With
    ``resume``, ``data`` is the run's data set at another place (:func:`~.loop.train`)."""
    cfg, last = _configuration(config, run_dir, resume, overwrite, epochs, data)
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    init = load_checkpoint(cfg.init_from) if last is None and cfg.init_from else None
    data = TrainingData(cfg, _kept_normaliser(cfg, last or init))
    _check_fits(cfg, data, last, init)
    cfg = _resolved(cfg, data)
    if init is not None:
        _check_same_network(cfg, init)
    if last is None:
        cfg = _within_sample_limit(cfg, data.samples_per_epoch, say=rank == 0)
    stored = last.meta.get("parameter_weighting") if last is not None else None
    weighting = data.parameter_weighting(stored, resumed=last is not None)
    model = place_model(build_model(cfg.model, seed=cfg.seed), device)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.optim.lr, weight_decay=cfg.optim.weight_decay)
    state = RunState(model, opt, make_scheduler(opt, cfg.optim))
    if init is not None:
        _load_init(model, init, cfg)
    if last is not None:
        state.restore(last, cfg.optim.epochs)
    cost = make_cost(cfg, data.normaliser, data.dmp_config, weighting)
    _one_rollout_path(cfg, data.dmp_config)
    net = torch.nn.parallel.DistributedDataParallel(model) if world > 1 else model
    augment = Augmenter.from_config(cfg, data)
    replaces = last is None and holds_run(run_dir)
    run = Run(cfg, run_dir, data, weighting, cost, augment, state, net, rank, world, replaces)
    if rank == 0 and not replaces:  # a replacing run writes it with its first epoch
        run_dir.mkdir(parents=True, exist_ok=True)
        run.write_config()
        if state.history:
            write_metrics_csv(run_dir / "metrics.csv", state.history_dicts())
    return run


def _one_rollout_path(cfg: TrainConfig, dmp_config) -> None:
    """Load the rollout's fused kernels before the first step, so that every rollout of
    the run goes through them (:func:`img2dmp.dmp.rollout.load_fused_kernels`).

    :func:`img2dmp.dmp.rollout` (``backend="auto"``) takes the torch operations for small
    calls until the kernels have run once in the process, or until such calls would have
    taken 0.5 s: a training switched paths at a step that depended on the machine's
    speed and load (then timed), and a resumed one (a new process) at another, so runs of
    one configuration differed after that step (to rounding, then growing). Loaded
    first, every step takes one path: the same weights, bit for bit, run after run and
    after a resume. Without numba every rollout takes torch's path.
    """
    from ..dmp.rollout import load_fused_kernels

    layout = cfg.strokes.layout()
    load_fused_kernels(dmp_config if layout is None else layout.config)


#: What a run writes into its directory (:mod:`.loop`), its checkpoints' folder first,
#: and ``img2dmp evaluate``'s default output for it (figures of the weights it replaces).
RUN_FILES = (CHECKPOINT_DIR, "config.yaml", "metrics.csv", "training_curve.png",
             "familiar.safetensors", "evaluation")  # fmt: skip
#: Where a run that replaces another puts the old one's files while it writes its own.
REPLACED = ".replaced-run"


def holds_run(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds a run's checkpoint (``best`` or ``last``)."""
    folder = run_dir / CHECKPOINT_DIR
    return any((folder / f"{n}.safetensors").is_file() for n in ("best", "last"))


@contextlib.contextmanager
def replacing_old_run(run_dir: Path):
    """Replace the run in ``run_dir`` by the files the block writes, all or nothing.

    The old run's files (:data:`RUN_FILES`; files of the user's own are left) are moved
    into ``run_dir/.replaced-run``, its checkpoints first (a rename each, no copy); when
    the block ends they are deleted, and when it fails (a full disk, Ctrl-C) the files it
    wrote are deleted and the old ones moved back, as they were. So a ``--force``
    restart leaves either the old run whole (stopped or failed before its first epoch is
    saved: ``--resume`` continues the old run, with its own configuration and weights)
    or its own first epoch, never the new ``config.yaml`` beside the old checkpoints.
    A ``kill -9`` inside the block (milliseconds) leaves the old run in
    ``.replaced-run``, which the next replacing run deletes."""
    aside = run_dir / REPLACED
    if aside.exists():  # the old run of a replacement killed in here
        shutil.rmtree(aside)
    aside.mkdir()
    moved = [name for name in RUN_FILES if os.path.lexists(run_dir / name)]
    for name in moved:
        (run_dir / name).rename(aside / name)
    try:
        yield
    except BaseException:
        for name in RUN_FILES:
            _remove(run_dir / name)
        for name in moved:
            (aside / name).rename(run_dir / name)
        aside.rmdir()
        raise
    shutil.rmtree(aside)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif os.path.lexists(path):
        path.unlink()


#: Settings of ``model`` that a network's weights leave free: how its weights would start
#: (``init``), its output count (the data's, whose DMP constants are checked against the
#: checkpoint's by :func:`_check_fits`) and ``dropout``, which changes no weight (where it
#: adds or removes dropout layers the weights' names do not fit: :func:`_load_init`).
FREE_OF_WEIGHTS = ("dropout", "init", "n_outputs")


def network_settings(train_config: dict) -> dict:
    """``"model.KEY"`` / ``"strokes.KEY"`` -> value: the settings of a stored configuration
    (:meth:`TrainConfig.to_dict`) that decide what its network's weights are and compute,
    each written one way (a convolutional encoder's default strides given, only its code's
    width of ``encoder_layers``; a fully connected encoder without the convolutions')."""
    model = {k: v for k, v in (train_config.get("model") or {}).items()
             if k not in FREE_OF_WEIGHTS}  # fmt: skip
    if model.get("encoder") == "conv":
        if model.get("conv_strides") is None and isinstance(model.get("conv_channels"), list):
            model["conv_strides"] = [2] * len(model["conv_channels"])
        if isinstance(model.get("encoder_layers"), list):
            model["encoder_layers"] = model["encoder_layers"][-1:]
    else:
        for k in ("conv_channels", "conv_strides", "conv_norm"):
            model.pop(k, None)
    out = {f"model.{k}": v for k, v in model.items()}
    strokes = train_config.get("strokes") or {}
    out["strokes.slots"] = strokes.get("slots") or 0
    if out["strokes.slots"]:
        out["strokes.n_kernels"] = strokes.get("n_kernels")
    return out


def _check_same_network(cfg: TrainConfig, init: Checkpoint) -> None:
    """Refuse to start from ``init`` a network that differs from its run's in a setting
    its weights do not fix (an activation, an input filter: weights of the same shapes
    that would compute something else), naming each such setting."""
    stored = init.meta.get("train_config")
    if not isinstance(stored, dict):
        return  # nothing recorded: the weights' shapes alone are checked
    theirs, ours = network_settings(stored), network_settings(cfg.to_dict())
    differ = [f"{k} {theirs[k]!r} (this run: {ours[k]!r})"
              for k in ours if k in theirs and theirs[k] != ours[k]]  # fmt: skip
    if differ:
        raise CheckpointError(
            f"cannot initialise from {init.path}: it was saved from another architecture; "
            f"the run it comes from differs in {', '.join(differ)}; without --config, train "
            "--init-from takes the run's network (its model and strokes sections)"
        )


def _load_init(model: torch.nn.Module, init: Checkpoint, cfg: TrainConfig) -> None:
    """``init``'s weights into ``model``; when they do not fit, the error names the
    ``model`` settings in which the checkpoint's run differs from this one."""
    try:
        load_weights_into(model, init)
    except CheckpointError as e:
        theirs = (init.meta.get("train_config") or {}).get("model") or {}
        ours = cfg.model.to_dict()
        differ = [
            f"model.{k} {theirs[k]!r} (this run: {ours[k]!r})"
            for k in ours
            if k in theirs and theirs[k] != ours[k] and k not in ("init", "n_outputs")
        ]
        if not differ:
            raise
        raise CheckpointError(
            f"{e}; the run it comes from differs in {', '.join(differ)}: give --init-from a "
            "run of this configuration's architecture"
        ) from None


def _configuration(config, run_dir, resume, overwrite, epochs, data=None):
    """The run's configuration (a copy; the stored one to resume, with ``data`` as its
    data set's place if given) and its last checkpoint."""
    last_path = run_dir / CHECKPOINT_DIR / "last.safetensors"
    if data is not None and not resume:
        raise ValueError("data= gives a resumed run's data set at another place: set data.path")
    if not resume:
        held = [p for p in (last_path, last_path.with_name("best.safetensors")) if p.is_file()]
        if held and not overwrite:
            raise FileExistsError(
                f"{run_dir} already holds a run ({held[0]}); pass --resume to continue it or "
                "--force (overwrite=True) to start afresh, replacing it"
            )
        cfg = copy.deepcopy(config)
        if epochs is not None:
            cfg.optim = _with_epochs(cfg.optim, epochs)
        return cfg, None
    if not last_path.is_file():
        started = " (no epoch of the run started there finished)" if (
            run_dir / "config.yaml").is_file() else ""  # fmt: skip
        raise FileNotFoundError(f"cannot resume: {last_path} does not exist{started}")
    try:
        last = load_checkpoint(last_path)
    except CheckpointError as e:  # damaged: say what is left to go on from
        best = last_path.with_name("best.safetensors")
        hint = (
            f"; its best weights can start a new run: --init-from {best} --run-dir NEW "
            "(the run's network and reading settings come with them; --data and --epochs "
            "are the new run's)"
            if best.is_file()
            else ""
        )
        raise CheckpointError(f"cannot resume: {e}{hint}") from None
    cfg = TrainConfig.from_dict(_on_this_machine(last.meta["train_config"]))
    cfg.progress = config.progress
    cfg.data.path = _resumed_data_path(cfg.data.path, data, run_dir)
    if cfg.data.path is not None:  # before the data are loaded, and said as they are read
        _check_same_data(cfg.data.path, file_digest(cfg.data.path), last)
    done = last.meta["epoch"] + 1
    if epochs is not None:
        if epochs <= done:
            raise ValueError(
                f"cannot resume to {epochs} epochs: the run in {run_dir} has already done {done}"
            )
        cfg.optim = _with_epochs(cfg.optim, epochs)
    return cfg, last


def _resumed_data_path(stored: str | None, data, run_dir: Path) -> str | None:
    """The data set a resumed run reads: ``data`` (the same file at another place, its
    SHA-256 checked against the run's by :func:`_check_fits`) or the stored path, which
    is relative to the directory the run was started from."""
    if data is not None:
        if stored is None:
            raise ValueError(
                f"cannot resume {run_dir} with a data set: it trained on the generator "
                "(data.path null); resume it without --data"
            )
        return str(data)
    if stored is not None and not Path(stored).exists():
        where = "" if Path(stored).is_absolute() else f" from {Path.cwd()}"
        raise FileNotFoundError(
            f"cannot resume: the run's data set {stored} (data.path, as given when the run "
            f"started) is not found{where}; give its place with --data PATH (data= in "
            "Python): the same file, checked by its SHA-256"
        )
    return stored


def _check_same_data(path, sha256: str, last: Checkpoint) -> None:
    """Refuse to resume ``last`` on a data set of another SHA-256 than its own."""
    theirs = last.meta["dataset"]["sha256"]
    if sha256 != theirs:
        raise ValueError(
            f"cannot resume: data set {path} is not the one the run trained on: it has "
            f"changed since the run started, or is another file (SHA-256 {sha256[:12]}... "
            f"!= {theirs[:12]}...)"
        )


def _on_this_machine(stored: dict) -> dict:
    """A stored configuration with its ``threads`` lowered to this machine's cores: a run
    started on a larger machine resumes here (threads set the speed, not the run)."""
    threads, cores = stored.get("threads"), machine_cores()
    if isinstance(threads, int) and not isinstance(threads, bool) and threads > cores:
        print(
            f"note: the run was set to {threads} threads; this machine has {cores} cores, "
            f"so it resumes on {cores}",
            file=sys.stderr,
        )
        return dict(stored, threads=cores)
    return stored


def _with_epochs(optim: OptimConfig, epochs: int) -> OptimConfig:
    if isinstance(epochs, bool) or not isinstance(epochs, int) or epochs < 1:
        raise ValueError(f"epochs must be an integer >= 1, got {epochs!r}")
    o = copy.deepcopy(optim)
    o.epochs = epochs
    return o


def _kept_normaliser(cfg: TrainConfig, ckpt: Checkpoint | None) -> ParamNormaliser | None:
    """A resumed run keeps its normaliser, a fine-tuning the pre-trained one (its last
    layer speaks those units); a fresh run fits its own (None)."""
    if ckpt is None:
        return None
    normaliser = ParamNormaliser.from_dict(ckpt.meta["normaliser"])
    if normaliser.units != cfg.cost.parameter_units:
        raise ValueError(
            f"cannot initialise from {ckpt.path}: its network outputs weight units "
            f"{normaliser.units!r}, this run's cost.parameter_units is "
            f"{cfg.cost.parameter_units!r}"
        )
    return normaliser


def _check_fits(cfg: TrainConfig, data: TrainingData, last, init) -> None:
    if init is not None and init.meta["dmp_config"] != data.dmp_config.to_dict():
        theirs, ours = init.meta["dmp_config"], data.dmp_config.to_dict()
        keys = [k for k in ours if theirs.get(k) != ours[k]]
        differ = ", ".join(f"{k} {theirs.get(k)!r} (the data: {ours[k]!r})" for k in keys)
        flags = " ".join(f"--{k.replace('_', '-')} {theirs[k]}" for k in keys
                         if k in ("scaling", "n_kernels", "n_dims") and k in theirs)  # fmt: skip
        remedy = (f": make the data with the network's ({flags.replace('--n-dims', '--dims')}"
                  " in generate, prepare or import)" if flags else "")  # fmt: skip
        where = f"data set {cfg.data.path}" if cfg.data.path else "generator (data.generator)"
        raise ValueError(
            f"cannot initialise from {init.path}: its DMP constants differ from those of the "
            f"{where} in {differ}{remedy}"
        )
    if last is not None and cfg.data.path:
        _check_same_data(cfg.data.path, data.dataset_sha256, last)
    size = cfg.model.image_size
    if init is not None and size is not None and list(size) != data.image_size:
        if list(size) == list(init.meta.get("image_size") or []):  # the run's own size
            raise ValueError(
                f"the data's images are {data.image_size} pixels but the network of "
                f"{init.path} reads {list(size)} (model.image_size): give it data of that size"
            )
    if size is not None and list(size) != data.image_size:
        raise ValueError(
            f"the data's images are {data.image_size} pixels but model.image_size is {size} "
            "(leave model.image_size out to take it from the data)"
        )


def _resolved(cfg: TrainConfig, data: TrainingData) -> TrainConfig:
    """``cfg`` with the image size and the output count taken from the data."""
    cfg = copy.deepcopy(cfg)
    cfg.model.image_size = list(data.image_size)
    layout = cfg.strokes.layout()
    cfg.model.n_outputs = data.dmp_config.n_params if layout is None else layout.n_outputs
    return cfg


def _within_sample_limit(cfg: TrainConfig, per_epoch: int, say: bool = True) -> TrainConfig:
    """``cfg`` with fewer epochs when its epochs of ``per_epoch`` training samples would
    pass ``optim.max_samples`` (said on stderr if ``say``); unchanged otherwise."""
    limit, wanted = cfg.optim.max_samples, cfg.optim.epochs
    epochs = max(1, limit // per_epoch) if limit else wanted
    if epochs >= wanted:
        return cfg
    if say:
        print(
            f"note: {wanted} epochs of {per_epoch} training samples would pass "
            f"optim.max_samples = {limit}; training {epochs} epochs ({epochs * per_epoch} "
            f"samples; --set optim.max_samples=0 for all {wanted})",
            file=sys.stderr,
        )
    cfg = copy.deepcopy(cfg)
    cfg.optim.epochs = epochs
    return cfg


def make_cost(cfg: TrainConfig, normaliser, dmp_config, weighting=None):
    """The run's :class:`~img2dmp.nn.Cost` from ``cfg.cost`` and ``model.hypotheses``, or
    for a stroke model (``strokes.slots`` > 0) its :class:`~img2dmp.nn.strokes.StrokeCost`."""
    c = cfg.cost
    layout = cfg.strokes.layout()
    if layout is not None:
        from ..nn.strokes import StrokeCost

        st = cfg.strokes
        return StrokeCost(
            layout, normaliser, cfg.model.hypotheses,
            presence_weight=st.presence_weight, count_weight=st.count_weight,
            tau_weight=st.tau_weight, order_weight=st.order_weight,
            ink_weight=c.ink_weight, coverage_weight=c.coverage_weight,
            coverage_tolerance_px=c.coverage_tolerance_px,
            score_weight=c.score_weight, wta_relax=c.wta_relax,
        )  # fmt: skip
    return Cost(
        c.name,
        normaliser,
        dmp_config,
        c.parameter_weight,
        c.trajectory_weight,
        weighting,
        hypotheses=cfg.model.hypotheses,
        wta_relax=c.wta_relax,
        score_weight=c.score_weight,
        ink_weight=c.ink_weight,
        coverage_weight=c.coverage_weight,
        coverage_tolerance_px=c.coverage_tolerance_px,
        path_weight=c.path_weight,
    )


def make_scheduler(opt: torch.optim.Optimizer, o: OptimConfig):
    """The learning-rate schedule ``o.schedule`` of ``opt`` (None for ``"none"``)."""
    if o.schedule == "cosine":
        return torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=o.epochs, eta_min=o.min_lr)
    if o.schedule == "step":
        return torch.optim.lr_scheduler.StepLR(opt, step_size=o.step_size, gamma=o.gamma)
    if o.schedule == "plateau":
        return torch.optim.lr_scheduler.ReduceLROnPlateau(
            opt, factor=o.gamma, patience=o.step_size, min_lr=o.min_lr
        )
    return None


__all__ = ["Run", "holds_run", "make_cost", "make_scheduler", "open_run", "replacing_old_run"]
