"""Training the encoder-decoder network with cost (9) or cost (10) (Pahič et al., Sec. V).

One function does the job: :func:`train` takes a :class:`TrainConfig` and a run
directory and leaves there::

    config.yaml              the resolved configuration
    metrics.csv              one row per epoch (train/validation error in px, lr, cost)
    training_curve.png       the same, as a picture
    checkpoints/best.*       lowest validation trajectory error (weights only)
    checkpoints/last.*       end of the latest epoch, with optimiser state (for --resume)

Reproducibility: the initial weights, the per-epoch shuffling and (in generator mode) the
per-epoch samples are all drawn from generators seeded by ``(seed, epoch)``, never from
global state, so an uninterrupted run and one killed and resumed from ``last`` follow the
same numbers. ``last`` is written at the end of every epoch; a kill loses at most the
epoch under way.

Data-parallel: launched by ``torchrun`` (``WORLD_SIZE`` > 1) every process takes every
``world_size``-th sample of the same shuffled order, gradients are averaged by
``DistributedDataParallel`` over gloo, and rank 0 alone writes files.
"""

from __future__ import annotations

import copy
import csv
import io
import math
import os
import re
import sys
import time
import tomllib
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
import torch
import yaml
from tqdm.auto import tqdm

from .checkpoint import (
    CHECKPOINT_DIR,
    CheckpointError,
    atomic_write_text,
    file_digest,
    load_checkpoint,
    load_weights_into,
    optimizer_from_tensors,
    optimizer_to_tensors,
    save_checkpoint,
)
from .data.store import DigitData, load_dataset
from .dmp import DMPConfig
from .nn import Cost, ModelConfig, ParamNormaliser, build_model, trajectory_error_px
from .nn.costs import (
    PARAMETER_WEIGHTINGS,
    ParameterWeighting,
    canonical_cost_name,
    dmp_trajectory,
)
from .nn.normalise import UNITS
from .predict import ink_margin, typical_stroke_width

PLOT_EVERY_S = 20.0
_COST_EQ = {"parameter": "(9)", "trajectory": "(10)", "combined": "(9) + (10)"}
SCHEDULES = ("none", "cosine", "step", "plateau")
METRIC_FIELDS = (
    "epoch",
    "step",
    "lr",
    "train_cost",
    "train_error_px",
    "val_error_px",
    "best_val_error_px",
    "epoch_time_s",
)


# --------------------------------------------------------------------------- configuration
@dataclass
class DataConfig:
    """Where training examples come from.

    Parameters
    ----------
    path : str or None
        A stored data set (``img2dmp.data.store`` format). ``None``: use the generator.
    generator : dict
        Options passed to the on-the-fly synthetic generator (generator mode).
    samples_per_epoch : int
        Generator mode: fresh samples drawn for every epoch.
    val_samples : int
        Generator mode: size of the fixed validation set.
    val_fraction : float
        Stored mode: share of the training split held out for validation when the file
        has no validation split (split = 1).
    digits : list of int or None
        Keep only these labels (Table I's "digit 2 only" row), or all.
    augment : dict or None
        On-the-fly augmentation of the training batches: a fresh random affine transform
        of every image together with its trajectory (:mod:`img2dmp.data.affine`, the code
        that made the data), with the DMP targets of cost (9) refitted to the moved path.
        Keys are :class:`~img2dmp.data.affine.AffineRanges` fields, e.g.
        ``{rotation_deg: [-3, 3], scale: [0.97, 1.03], translation_rel: [-0.02, 0.02],
        shear_deg: [-3, 3]}``; a missing key means no change of that kind. The
        validation split is never augmented. None (default): off.
    """

    path: str | None = None
    generator: dict = field(default_factory=dict)
    samples_per_epoch: int = 20000
    val_samples: int = 1000
    val_fraction: float = 0.1
    digits: list[int] | None = None
    augment: dict | None = None

    def augment_ranges(self):
        """The :class:`~img2dmp.data.affine.AffineRanges` of ``augment`` (None if off)."""
        from .data.affine import AffineRanges

        if self.augment is None:
            return None
        if not isinstance(self.augment, dict):
            raise ValueError(f"data.augment must be a mapping or null, got {self.augment!r}")
        ranges = AffineRanges.identity().to_dict()
        ranges.update(self.augment)
        try:
            return AffineRanges.from_dict(ranges)
        except (TypeError, ValueError) as e:
            raise ValueError(f"data.augment: {e}") from e


@dataclass
class OptimConfig:
    """Adam and its learning-rate schedule.

    ``schedule``: ``"none"``; ``"cosine"`` (to ``min_lr`` over ``epochs``); ``"step"``
    (times ``gamma`` every ``step_size`` epochs); ``"plateau"`` (times ``gamma`` after
    ``step_size`` epochs without a better validation error). ``patience``: early stopping
    after that many epochs without a better validation trajectory error (0 = never).
    """

    lr: float = 1e-3
    weight_decay: float = 0.0
    batch_size: int = 128
    epochs: int = 100
    patience: int = 20
    schedule: str = "cosine"
    step_size: int = 10
    gamma: float = 0.5
    min_lr: float = 1e-6
    grad_clip: float | None = None


@dataclass
class CostConfig:
    """``name``: ``"parameter"`` (eq. 9), ``"trajectory"`` (eq. 10) or ``"combined"``.

    ``parameter_weighting``: per-unit weights of cost (9) (also inside ``combined``):
    ``"none"`` (every normalised unit alike, the paper), ``"trajectory"`` (each unit
    weighted by its mean squared trajectory sensitivity on the training set) or
    ``"trajectory-full"`` (the mean Gauss-Newton matrix of cost 10 as the metric); computed
    once before training and saved in the checkpoint, see
    :class:`img2dmp.nn.costs.ParameterWeighting`. ``parameter_weight_floor``: smallest
    weight (added to the diagonal for ``"trajectory-full"``), relative to their mean.

    ``parameter_units``: what the network's weight outputs (and so cost 9's weight units)
    are, before normalisation: ``"weights"`` (the w_k of eq. 8, the paper) or
    ``"amplitudes"`` (``(g - y0) w_k``, the same DMP without the ``1 / (g - y0)``
    singularity), see :mod:`img2dmp.nn.normalise`.
    """

    name: str = "trajectory"
    parameter_weight: float = 1.0
    trajectory_weight: float = 1.0
    parameter_weighting: str = "none"
    parameter_weight_floor: float = 1e-3
    parameter_units: str = "weights"


@dataclass
class TrainConfig:
    """Everything :func:`train` needs; read from YAML/TOML by :func:`load_config`.

    ``init_from`` (top-level key; CLI ``--init-from``): a run directory or checkpoint file
    whose weights start this run instead of random ones (fine-tuning a pre-trained
    network). The architecture, the image size and the DMP configuration (N, d, scaling)
    must match. The checkpoint's output normalisation is **kept**, not refitted on the new
    data: the network's last layer speaks in those units, so keeping them makes the first
    fine-tuning step start from exactly the pre-trained network's predictions. Only the
    weights are taken; the optimiser, schedule and epoch count start afresh.
    """

    model: ModelConfig = field(default_factory=ModelConfig)
    data: DataConfig = field(default_factory=DataConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    cost: CostConfig = field(default_factory=CostConfig)
    seed: int = 0
    threads: int | None = None
    eval_batch_size: int = 1024
    progress: bool = True
    init_from: str | None = None

    def __post_init__(self) -> None:
        o = self.optim
        numbers = {"lr": float, "weight_decay": float, "batch_size": int, "epochs": int}
        numbers |= {"patience": int, "step_size": int, "gamma": float, "min_lr": float}
        for name, kind in numbers.items():
            v = getattr(o, name)
            ok = isinstance(v, (int, float)) if kind is float else isinstance(v, int)
            if not ok or isinstance(v, bool):
                raise ValueError(f"optim.{name} must be a number ({kind.__name__}), got {v!r}")
        if not (o.lr > 0 and math.isfinite(o.lr)):
            raise ValueError(f"optim.lr must be > 0, got {o.lr!r}")
        if int(o.batch_size) < 1 or int(o.epochs) < 1 or int(o.patience) < 0:
            raise ValueError(
                f"optim.batch_size and optim.epochs must be >= 1 and optim.patience >= 0, "
                f"got {o.batch_size!r}, {o.epochs!r}, {o.patience!r}"
            )
        if o.schedule not in SCHEDULES:
            raise ValueError(f"optim.schedule must be one of {SCHEDULES}, got {o.schedule!r}")
        self.cost.name = canonical_cost_name(self.cost.name)
        if self.cost.parameter_weighting not in PARAMETER_WEIGHTINGS:
            raise ValueError(
                f"cost.parameter_weighting must be one of {PARAMETER_WEIGHTINGS}, got "
                f"{self.cost.parameter_weighting!r}"
            )
        if not 0 < float(self.cost.parameter_weight_floor) <= 1:
            raise ValueError(
                f"cost.parameter_weight_floor must be in (0, 1], got "
                f"{self.cost.parameter_weight_floor!r}"
            )
        if self.cost.parameter_units not in UNITS:
            raise ValueError(
                f"cost.parameter_units must be one of {UNITS}, got {self.cost.parameter_units!r}"
            )
        self.data.augment_ranges()  # raises on a bad data.augment
        if not 0 <= self.data.val_fraction < 1:
            raise ValueError(f"data.val_fraction must be in [0, 1), got {self.data.val_fraction!r}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        d = dict(d or {})
        sections = {
            "model": ModelConfig,
            "data": DataConfig,
            "optim": OptimConfig,
            "cost": CostConfig,
        }
        unknown = set(d) - {f.name for f in fields(cls)}
        if unknown:
            raise ValueError(f"unknown training config field(s): {sorted(unknown)}")
        kwargs = {}
        for name, value in d.items():
            if name in sections:
                sec = sections[name]
                if not isinstance(value, dict):
                    raise ValueError(f"config section {name!r} must be a mapping, got {value!r}")
                bad = set(value) - {f.name for f in fields(sec)}
                if bad:
                    raise ValueError(f"unknown field(s) in config section {name!r}: {sorted(bad)}")
                kwargs[name] = sec(**value)
            else:
                kwargs[name] = value
        return cls(**kwargs)


class _ConfigLoader(yaml.SafeLoader):
    """YAML's safe loader, reading ``3e-4`` and ``1E5`` as numbers.

    YAML 1.1 (PyYAML) takes a float without a dot for a string, so ``lr: 3e-4`` would
    reach the optimiser as text.
    """


_ConfigLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$""",
    ),
    list("-+0123456789"),
)


def _yaml_load(text: str):
    return yaml.load(text, Loader=_ConfigLoader)  # noqa: S506 - a SafeLoader subclass


def read_config_file(path: str | os.PathLike) -> dict:
    """A YAML (``.yaml``/``.yml``) or TOML (``.toml``) file as a dict."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"config file {p} does not exist")
    text = p.read_text(encoding="utf-8")
    try:
        if p.suffix == ".toml":
            d = tomllib.loads(text)
        elif p.suffix in (".yaml", ".yml"):
            d = _yaml_load(text) or {}
        else:
            raise ValueError(f"config file {p} must end in .yaml, .yml or .toml")
    except (yaml.YAMLError, tomllib.TOMLDecodeError) as e:
        raise ValueError(f"config file {p} cannot be parsed: {e}") from e
    if not isinstance(d, dict):
        raise ValueError(f"config file {p} must hold a mapping at the top level")
    return d


def apply_overrides(d: dict, overrides: list[str] | None) -> dict:
    """Apply ``section.key=value`` overrides (values parsed as YAML) to a config dict."""
    d = copy.deepcopy(d)
    for item in overrides or []:
        if "=" not in item:
            raise ValueError(f"override {item!r} must look like section.key=value")
        key, raw = item.split("=", 1)
        parts = key.strip().split(".")
        node = d
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ValueError(f"override {item!r}: {p!r} is not a config section")
        try:
            node[parts[-1]] = _yaml_load(raw)
        except yaml.YAMLError as e:
            raise ValueError(f"override {item!r}: value cannot be parsed ({e})") from e
    return d


def load_config(path: str | os.PathLike | None, overrides: list[str] | None = None) -> TrainConfig:
    """Defaults, then the file (if any), then the overrides."""
    base = read_config_file(path) if path else {}
    return TrainConfig.from_dict(apply_overrides(base, overrides))


# --------------------------------------------------------------------------- helpers
def _dist_info() -> tuple[int, int]:
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


def _maybe_init_distributed() -> bool:
    """Join the process group ``torchrun`` prepared; True if this call created it."""
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1 or not torch.distributed.is_available():
        return False
    if torch.distributed.is_initialized():
        return False
    torch.distributed.init_process_group(backend="gloo")
    return True


def _epoch_generator(seed: int, epoch: int, stream: int = 0) -> torch.Generator:
    # Independent, reproducible streams per (seed, epoch, purpose).
    return torch.Generator().manual_seed((seed * 1_000_003 + epoch * 7919 + stream) % (2**63))


def _make_scheduler(opt: torch.optim.Optimizer, o: OptimConfig):
    if o.schedule == "cosine":
        return torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=o.epochs, eta_min=o.min_lr)
    if o.schedule == "step":
        return torch.optim.lr_scheduler.StepLR(opt, step_size=o.step_size, gamma=o.gamma)
    if o.schedule == "plateau":
        return torch.optim.lr_scheduler.ReduceLROnPlateau(
            opt, factor=o.gamma, patience=o.step_size, min_lr=o.min_lr
        )
    return None


@torch.no_grad()
def trajectory_errors(
    model: torch.nn.Module,
    normaliser: ParamNormaliser,
    dmp_config: DMPConfig,
    images: torch.Tensor,  # [M, H, W]
    times: torch.Tensor,  # [M, T]
    trajectories: torch.Tensor,  # [M, T, d]
    batch_size: int = 1024,
) -> np.ndarray:
    """Per-sample mean Euclidean distance (px, on x and y) between the demonstration and
    the network's DMP rolled out at the demonstration's time stamps (Table I's metric)."""
    was_training = model.training
    model.eval()
    out = []
    for lo in range(0, images.shape[0], batch_size):
        z = model(images[lo : lo + batch_size])  # [b, P]
        y = dmp_trajectory(z, times[lo : lo + batch_size], normaliser, dmp_config)
        out.append(trajectory_error_px(y, trajectories[lo : lo + batch_size]))
    model.train(was_training)
    return torch.cat(out).double().numpy() if out else np.zeros(0)


def write_metrics_csv(path: Path, history: list[dict]) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=METRIC_FIELDS, lineterminator="\n")
    w.writeheader()
    for row in history:
        w.writerow({k: row.get(k, "") for k in METRIC_FIELDS})
    atomic_write_text(path, buf.getvalue())


def read_metrics_csv(path: str | os.PathLike) -> list[dict]:
    """Rows of a ``metrics.csv`` as dicts of floats (``epoch``/``step`` as int)."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    out = []
    for r in rows:
        out.append({k: (int(v) if k in ("epoch", "step") else float(v)) for k, v in r.items()})
    return out


def plot_training_curve(path: Path, history: list[dict], title: str = "") -> None:
    """Train and validation trajectory error (px, log scale) per epoch, saved atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    ep = [r["epoch"] for r in history]
    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    ax.plot(ep, [r["train_error_px"] for r in history], label="train", color="tab:blue")
    ax.plot(ep, [r["val_error_px"] for r in history], label="validation", color="tab:red")
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.yaxis.set_minor_formatter(matplotlib.ticker.FormatStrFormatter("%.2g"))
    ax.set_xlabel("epoch")
    ax.set_ylabel("mean trajectory error (px)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    from .checkpoint import atomic_write_bytes

    atomic_write_bytes(path, buf.getvalue())


# --------------------------------------------------------------------------- data
def generate_arrays(options: dict, n: int, seed: int, epoch: int = 0) -> DigitData:
    """``n`` fresh synthetic samples for one epoch from the on-the-fly generator
    (:class:`img2dmp.data.torch_data.SyntheticDigitStream`, seeded by ``(seed, epoch)``).

    ``options`` are :class:`~img2dmp.data.synthetic.SyntheticConfig` fields plus an
    optional ``dmp_config`` mapping.
    """
    from torch.utils.data import DataLoader

    from .data.synthetic import SyntheticConfig
    from .data.torch_data import SyntheticDigitStream

    opts = dict(options)
    dmp = DMPConfig.from_dict(opts.pop("dmp_config", {}) or {})
    config = SyntheticConfig.from_dict(opts)
    stream = SyntheticDigitStream(config, samples_per_epoch=int(n), seed=int(seed), dmp_config=dmp)
    stream.set_epoch(int(epoch))
    b = next(iter(DataLoader(stream, batch_size=int(n))))  # one batch = the whole epoch
    return DigitData(
        images=b["image"][:, 0].numpy(),  # [n, H, W]
        trajectories=b["trajectory"].numpy(),  # [n, T, d]
        times=b["times"].numpy(),  # [n, T]
        labels=b["label"].numpy(),
        params=b["params"].numpy(),  # [n, P]
        fit_error_px=b["fit_error_px"].numpy(),
        split=np.zeros(int(n), np.uint8),
        meta={"dmp_config": dmp.to_dict(), "source": {"kind": "synthetic"}, "seed": int(seed)},
    )


@dataclass
class _Split:
    images: torch.Tensor  # [M, H, W]
    times: torch.Tensor  # [M, T]
    trajectories: torch.Tensor  # [M, T, d]
    z_target: torch.Tensor  # [M, P]

    def __len__(self) -> int:
        return int(self.images.shape[0])


def _to_split(a: DigitData, idx: np.ndarray, norm: ParamNormaliser) -> _Split:
    params = torch.as_tensor(a.params[idx], dtype=torch.float64)
    return _Split(
        images=torch.as_tensor(a.images[idx], dtype=torch.float32),
        times=torch.as_tensor(a.times[idx], dtype=torch.float32),
        trajectories=torch.as_tensor(a.trajectories[idx], dtype=torch.float32),
        z_target=norm.normalise(params).to(torch.float32),
    )


def _select_labels(a: DigitData, digits) -> np.ndarray:
    keep = np.ones(len(a.labels), dtype=bool)
    if digits is not None:
        keep = np.isin(a.labels, np.asarray(digits))
    return keep


class _Data:
    """Training and validation splits, from a file or the generator.

    ``fit_arrays``: ``(params [M, P], times [M, T])`` of the training samples the output
    normalisation and the parameter weighting are fitted on (generator mode: epoch 0's).
    """

    def __init__(self, cfg: TrainConfig, normaliser: ParamNormaliser | None):
        d = cfg.data
        self.cfg = cfg
        self.dataset_sha256 = None
        if d.path is not None:
            a = load_dataset(d.path)
            self.dmp_config = a.dmp_config
            self.image_size = list(a.images.shape[1:])
            self.dataset_sha256 = file_digest(d.path)
            keep = _select_labels(a, d.digits)
            train_idx = np.flatnonzero(keep & (a.split == 0))
            val_idx = np.flatnonzero(keep & (a.split == 1))
            if len(val_idx) == 0:
                rng = np.random.default_rng(cfg.seed)
                perm = rng.permutation(train_idx)
                n_val = max(1, int(round(d.val_fraction * len(perm))))
                val_idx, train_idx = np.sort(perm[:n_val]), np.sort(perm[n_val:])
            if len(train_idx) < 2:
                raise ValueError(
                    f"data set {d.path} has {len(train_idx)} training samples"
                    + (f" with labels {d.digits}" if d.digits is not None else "")
                    + "; need at least 2"
                )
            self.normaliser = normaliser or ParamNormaliser.fit(
                a.params[train_idx], self.dmp_config, cfg.cost.parameter_units
            )
            self.fit_arrays = (a.params[train_idx], a.times[train_idx])
            self.train = _to_split(a, train_idx, self.normaliser)
            self.val = _to_split(a, val_idx, self.normaliser)
            self._arrays = None
        else:
            gen = dict(d.generator)
            if d.digits is not None:
                gen.setdefault("digits", list(d.digits))
            self.gen = gen
            # Validation: a fixed set from a stream no training epoch draws from.
            val = generate_arrays(gen, d.val_samples, seed=cfg.seed + 1_000_003)
            self.dmp_config = val.dmp_config
            self.image_size = list(val.images.shape[1:])
            first = self._generated(0)
            self.normaliser = normaliser or ParamNormaliser.fit(
                first.params, self.dmp_config, cfg.cost.parameter_units
            )
            self.fit_arrays = (first.params, first.times)
            self.val = _to_split(val, np.arange(len(val.labels)), self.normaliser)
            self._first = first
        # How the training images frame the ink, for preparing other images alike.
        self.ink_margin = ink_margin(self.val.images[:500].numpy())
        self.stroke_width_px = typical_stroke_width(self.val.images[:500].numpy())
        if self.image_size != list(cfg.model.image_size):
            raise ValueError(
                f"the data's images are {self.image_size} pixels but model.image_size is "
                f"{cfg.model.image_size}"
            )

    def _generated(self, epoch: int) -> DigitData:
        return generate_arrays(
            self.gen, self.cfg.data.samples_per_epoch, seed=self.cfg.seed, epoch=epoch
        )

    def train_for_epoch(self, epoch: int) -> _Split:
        if self.cfg.data.path is not None:
            return self.train
        a = self._first if epoch == 0 else self._generated(epoch)
        self._first = None
        return _to_split(a, np.arange(len(a.labels)), self.normaliser)


# --------------------------------------------------------------------------- training
@dataclass
class TrainResult:
    """Summary of a finished (or early-stopped) run."""

    run_dir: Path
    epochs_run: int
    best_epoch: int
    best_val_error_px: float
    last_val_error_px: float
    history: list[dict]
    wall_s: float


def _checkpoint_meta(cfg, data, epoch, history, best, extra=None) -> dict:
    meta = {
        "kind": "img2dmp-model",
        "model": cfg.model.to_dict(),
        "normaliser": data.normaliser.to_dict(),
        "parameter_weighting": data.weighting.to_dict() if data.weighting else None,
        "dmp_config": data.dmp_config.to_dict(),
        "train_config": cfg.to_dict(),
        "dataset": {"path": cfg.data.path, "sha256": data.dataset_sha256},
        "image_size": list(cfg.model.image_size),
        "ink_margin": data.ink_margin,
        "stroke_width_px": data.stroke_width_px,
        "epoch": epoch,
        "val_error_px": history[-1]["val_error_px"] if history else None,
        "best_val_error_px": best["error"],
        "best_epoch": best["epoch"],
        "torch_version": torch.__version__,
    }
    meta.update(extra or {})
    return meta


class _Augmenter:
    """Random affine transforms of a training batch (``data.augment``), image and path
    together; refits the cost-(9) targets to the moved paths when the cost uses them."""

    def __init__(self, ranges, normaliser, dmp_config, refit: bool):
        self.ranges = ranges
        self.normaliser = normaliser
        self.dmp_config = dmp_config
        self.refit = refit

    @classmethod
    def from_config(cls, cfg: TrainConfig, data) -> _Augmenter | None:
        ranges = cfg.data.augment_ranges()
        if ranges is None:
            return None
        return cls(ranges, data.normaliser, data.dmp_config, cfg.cost.name != "trajectory")

    def __call__(self, rng, images, times, trajectories, z_target):
        from .data.affine import sample_affine, warp_images, warp_points
        from .dmp import fit_dmp

        m = torch.as_tensor(sample_affine(rng, len(images), images.shape[-2:], self.ranges))
        images = warp_images(images, m)
        trajectories = warp_points(trajectories, m.to(trajectories.dtype))
        if self.refit:
            fit = fit_dmp(times, trajectories, self.dmp_config)
            z_target = self.normaliser.normalise(fit.params.to_vector()).to(torch.float32)
        return images, trajectories, z_target


def _parameter_weighting(cfg, data, state) -> ParameterWeighting | None:
    """Weights of cost (9): the resumed run's stored ones (a checkpoint without the record
    was trained unweighted), else fitted on the training samples (those the normaliser is
    fitted on) if the configuration asks for them and the cost has a parameter term."""
    if state is not None and "parameter_weighting" in state.meta:
        return ParameterWeighting.from_dict(state.meta["parameter_weighting"])
    if state is not None or cfg.cost.parameter_weighting == "none":
        return None
    if cfg.cost.name == "trajectory":  # cost (10) alone: no parameter cost to weight
        return None
    params, times = data.fit_arrays
    return ParameterWeighting.fit(
        params,
        times,
        data.normaliser,
        data.dmp_config,
        cfg.cost.parameter_weight_floor,
        kind=cfg.cost.parameter_weighting,
    )


def train(
    config: TrainConfig,
    run_dir: str | os.PathLike,
    *,
    resume: bool = False,
    overwrite: bool = False,
    epochs: int | None = None,
) -> TrainResult:
    """Train the encoder-decoder network (Sec. V) with cost (9) or (10).

    Parameters
    ----------
    config : TrainConfig
        Model, data, optimiser, cost. With ``resume`` the configuration stored in the run
        directory's last checkpoint is used instead (only ``progress`` is taken from
        ``config``).
    run_dir : path
        Output directory (see the module docstring).
    resume : bool
        Continue from ``run_dir/checkpoints/last.safetensors``.
    overwrite : bool
        Start afresh in a run directory that already holds a run.
    epochs : int, optional
        Overrides ``optim.epochs``; with ``resume`` this is the way to train a finished or
        interrupted run further (a cosine schedule is stretched to the new end).

    Returns
    -------
    TrainResult
    """
    t_start = time.perf_counter()
    created_pg = _maybe_init_distributed()
    rank, world = _dist_info()
    try:
        return _train(config, Path(run_dir), resume, overwrite, epochs, rank, world, t_start)
    finally:
        if created_pg:
            torch.distributed.destroy_process_group()


def _train(cfg, run_dir, resume, overwrite, epochs, rank, world, t_start) -> TrainResult:
    ckpt_dir = run_dir / CHECKPOINT_DIR
    last_path = ckpt_dir / "last.safetensors"
    best_path = ckpt_dir / "best.safetensors"
    state = None
    if resume:
        if not last_path.is_file():
            raise FileNotFoundError(f"cannot resume: {last_path} does not exist")
        state = load_checkpoint(last_path)
        stored = TrainConfig.from_dict(state.meta["train_config"])
        if epochs is not None:
            stored.optim.epochs = int(epochs)
        stored.progress = cfg.progress
        cfg = stored
        if cfg.optim.epochs <= state.meta["epoch"] + 1 and epochs is not None:
            raise ValueError(
                f"cannot resume to {epochs} epochs: the run in {run_dir} has already done "
                f"{state.meta['epoch'] + 1}"
            )
    else:
        if last_path.is_file() and not overwrite:
            raise FileExistsError(
                f"{run_dir} already holds a run; pass --resume to continue it or --overwrite"
            )
        if epochs is not None:
            cfg = copy.deepcopy(cfg)
            cfg.optim.epochs = int(epochs)
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))

    normaliser = ParamNormaliser.from_dict(state.meta["normaliser"]) if state else None
    init = None
    if state is None and cfg.init_from:
        init = load_checkpoint(cfg.init_from)  # a run directory means its best checkpoint
        normaliser = ParamNormaliser.from_dict(init.meta["normaliser"])
        if normaliser.units != cfg.cost.parameter_units:
            raise ValueError(
                f"cannot initialise from {init.path}: its network outputs weight units "
                f"{normaliser.units!r}, this run's cost.parameter_units is "
                f"{cfg.cost.parameter_units!r}"
            )
    data = _Data(cfg, normaliser)
    if init is not None and init.meta["dmp_config"] != data.dmp_config.to_dict():
        raise ValueError(
            f"cannot initialise from {init.path}: it was trained with DMP config "
            f"{init.meta['dmp_config']}, the data set {cfg.data.path} has "
            f"{data.dmp_config.to_dict()}"
        )
    if state and cfg.data.path and state.meta["dataset"]["sha256"] != data.dataset_sha256:
        raise ValueError(
            f"cannot resume: data set {cfg.data.path} has changed since the run started "
            f"(SHA-256 {data.dataset_sha256[:12]}... != {state.meta['dataset']['sha256'][:12]}...)"
        )
    data.weighting = _parameter_weighting(cfg, data, state)
    cfg.model.n_outputs = data.dmp_config.n_params
    model = build_model(cfg.model, seed=cfg.seed)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.optim.lr, weight_decay=cfg.optim.weight_decay)
    sched = _make_scheduler(opt, cfg.optim)
    history: list[dict] = []
    best = {"error": math.inf, "epoch": -1}
    bad_epochs, start_epoch, step = 0, 0, 0
    if init is not None:
        load_weights_into(model, init)
    if state:
        load_weights_into(model, state)
        opt.load_state_dict(optimizer_from_tensors(state.extra, state.meta["optimizer"]))
        if sched is not None and state.meta.get("scheduler"):
            sched.load_state_dict(state.meta["scheduler"])
            if isinstance(sched, torch.optim.lr_scheduler.CosineAnnealingLR):
                # Resumed with more epochs: the cosine now ends at the new last epoch.
                sched.T_max = cfg.optim.epochs
        history = state.meta["history"]
        best = {"error": state.meta["best_val_error_px"], "epoch": state.meta["best_epoch"]}
        bad_epochs = state.meta["bad_epochs"]
        start_epoch = state.meta["epoch"] + 1
        step = state.meta["step"]
        if best["error"] is None:
            best["error"] = math.inf

    cost = Cost(
        cfg.cost.name,
        data.normaliser,
        data.dmp_config,
        cfg.cost.parameter_weight,
        cfg.cost.trajectory_weight,
        data.weighting,
    )
    augment = _Augmenter.from_config(cfg, data)
    net = model
    if world > 1:
        net = torch.nn.parallel.DistributedDataParallel(model)
    if rank == 0:
        run_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_text(run_dir / "config.yaml", yaml.safe_dump(cfg.to_dict(), sort_keys=False))
        if history:
            write_metrics_csv(run_dir / "metrics.csv", history)

    per_rank = max(1, cfg.optim.batch_size // world)
    show = cfg.progress and rank == 0
    epochs = tqdm(
        range(start_epoch, cfg.optim.epochs),
        desc="epochs",
        disable=not show,
        initial=start_epoch,
        total=cfg.optim.epochs,
        file=sys.stderr,
        dynamic_ncols=True,
    )
    stopped_early = False
    last_plot = -math.inf
    for epoch in epochs:
        t_epoch = time.perf_counter()
        split = data.train_for_epoch(epoch)
        n = len(split) - len(split) % world
        order = torch.randperm(len(split), generator=_epoch_generator(cfg.seed, epoch))[:n]
        mine = order[rank::world]  # every process sees the same order, its own share
        model.train()
        rng = np.random.default_rng([cfg.seed, epoch, rank])  # augmentation, resumable
        sums = torch.zeros(3, dtype=torch.float64)  # cost * b, error_px sum, samples
        batches = tqdm(
            range(0, len(mine), per_rank),
            desc=f"epoch {epoch}",
            leave=False,
            disable=not show,
            file=sys.stderr,
            dynamic_ncols=True,
        )
        for lo in batches:
            idx = mine[lo : lo + per_rank]
            img, t = split.images[idx], split.times[idx]  # [b, H, W], [b, T]
            traj, zt = split.trajectories[idx], split.z_target[idx]  # [b, T, d], [b, P]
            if augment is not None:  # the input filter first: a warp hides impulse noise
                img, traj, zt = augment(rng, model.input_filter(img), t, traj, zt)
            z = net(img)  # [b, P]
            loss, y = cost(z, zt, t, traj)
            if not torch.isfinite(loss):
                raise FloatingPointError(
                    f"training cost is {float(loss)} at epoch {epoch}, step {step}: training "
                    f"diverged (lower optim.lr = {cfg.optim.lr} or set optim.grad_clip); the "
                    "last good epoch's checkpoint is kept"
                )
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if cfg.optim.grad_clip:
                torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.optim.grad_clip)
            opt.step()
            step += 1
            with torch.no_grad():
                if y is None:
                    y = dmp_trajectory(z.detach(), t, data.normaliser, data.dmp_config)
                err = trajectory_error_px(y, traj)  # [b]
            b = len(idx)
            sums += torch.tensor(
                [float(loss.detach()) * b, float(err.sum()), b], dtype=torch.float64
            )
            if show:
                batches.set_postfix(train_px=f"{sums[1] / sums[2]:.3f}")
        if world > 1:
            torch.distributed.all_reduce(sums)
        val_err = trajectory_errors(
            model,
            data.normaliser,
            data.dmp_config,
            data.val.images,
            data.val.times,
            data.val.trajectories,
            cfg.eval_batch_size,
        )
        val_mean = float(val_err.mean()) if len(val_err) else float(sums[1] / sums[2])
        if not math.isfinite(val_mean):
            raise FloatingPointError(
                f"validation error is {val_mean} at epoch {epoch}: training diverged "
                f"(lower optim.lr = {cfg.optim.lr})"
            )
        lr = opt.param_groups[0]["lr"]
        if sched is not None:
            sched.step(val_mean) if cfg.optim.schedule == "plateau" else sched.step()
        improved = val_mean < best["error"]
        if improved:
            best = {"error": val_mean, "epoch": epoch}
            bad_epochs = 0
        else:
            bad_epochs += 1
        history.append(
            {
                "epoch": epoch,
                "step": step,
                "lr": lr,
                "train_cost": float(sums[0] / sums[2]),
                "train_error_px": float(sums[1] / sums[2]),
                "val_error_px": val_mean,
                "best_val_error_px": best["error"],
                "epoch_time_s": time.perf_counter() - t_epoch,
            }
        )
        if show:
            epochs.set_postfix(
                train_px=f"{history[-1]['train_error_px']:.3f}",
                val_px=f"{val_mean:.3f}",
                best=f"{best['error']:.3f}",
            )
        if rank == 0:
            if improved:
                save_checkpoint(
                    best_path, model.state_dict(), _checkpoint_meta(cfg, data, epoch, history, best)
                )
            opt_tensors, opt_record = optimizer_to_tensors(opt)
            extra = {
                "optimizer": opt_record,
                "scheduler": sched.state_dict() if sched is not None else None,
                "history": history,
                "bad_epochs": bad_epochs,
                "step": step,
            }
            save_checkpoint(
                last_path,
                model.state_dict(),
                _checkpoint_meta(cfg, data, epoch, history, best, extra),
                opt_tensors,
            )
            write_metrics_csv(run_dir / "metrics.csv", history)
            final = epoch == cfg.optim.epochs - 1 or (
                cfg.optim.patience and bad_epochs >= cfg.optim.patience
            )
            # The picture costs ~0.3 s; redraw it at most every PLOT_EVERY_S seconds.
            if final or time.perf_counter() - last_plot >= PLOT_EVERY_S:
                plot_training_curve(
                    run_dir / "training_curve.png",
                    history,
                    f"{run_dir.name}: cost {_COST_EQ[cfg.cost.name]}, {cfg.model.encoder} encoder",
                )
                last_plot = time.perf_counter()
        if world > 1:
            torch.distributed.barrier()
        if cfg.optim.patience and bad_epochs >= cfg.optim.patience:
            stopped_early = True
            break
    epochs.close()
    if rank == 0 and stopped_early and show:
        tqdm.write(
            f"early stop: no better validation error for {cfg.optim.patience} epochs",
            file=sys.stderr,
        )
    return TrainResult(
        run_dir=run_dir,
        epochs_run=len(history),
        best_epoch=best["epoch"],
        best_val_error_px=best["error"],
        last_val_error_px=history[-1]["val_error_px"] if history else math.nan,
        history=history,
        wall_s=time.perf_counter() - t_start,
    )


__all__ = [
    "CheckpointError",
    "CostConfig",
    "DataConfig",
    "ModelConfig",
    "OptimConfig",
    "TrainConfig",
    "TrainResult",
    "apply_overrides",
    "load_config",
    "read_config_file",
    "read_metrics_csv",
    "train",
    "trajectory_errors",
]
