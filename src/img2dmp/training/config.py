"""What a training run is told: model, data, optimiser, cost (one config mechanism).

Read from defaults, a YAML/TOML file and ``--set`` overrides by :func:`load_config`,
which builds through :mod:`img2dmp.config` (typed, unknown keys refused, errors naming
``section.field``). The resolved configuration is saved with every checkpoint, so a run
can be resumed or its model rebuilt from it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from .. import config as _config
from .._processes import machine_cores
from ..config import ConfigError, check_positive
from ..nn.architecture import ModelConfig

#: Learning-rate schedules, see :class:`OptimConfig`.
SCHEDULES = ("none", "cosine", "step", "plateau")
#: Most samples the generator draws at once (an epoch's, the validation set): all are held
#: in memory, 6.4 kB each at 40 x 40 pixels (50 times the paper's 20,000).
MAX_GENERATED_SAMPLES = 1_000_000


@dataclass
class DataConfig:
    """Where training examples come from.

    Parameters
    ----------
    path : str or None
        A stored data set (``img2dmp.data.store`` format). ``None``: use the generator.
    generator : dict
        Options passed to the on-the-fly synthetic generator (generator mode):
        :class:`~img2dmp.data.synthetic.SyntheticConfig` fields and ``dmp_config``.
    samples_per_epoch : int
        Generator mode: samples drawn for an epoch.
    refresh_epochs : int
        Generator mode: draw fresh samples every this many epochs and train on the same
        ones in between (their ``data.augment`` transforms are still new every epoch);
        0: draw them once, for epoch 0, and keep them. Drawing 20,000 samples takes
        about as long as an epoch of training on them, so a larger value trades sample
        variety for speed (``benchmarks/time_to_accuracy.py`` measures both). Default 1:
        fresh samples every epoch.
    val_samples : int
        Generator mode: size of the fixed validation set.
    val_fraction : float
        Stored mode: share of the training split held out for validation when the file
        has no validation split (split = 1).
    digits : list of int or None
        Keep only these labels (Table I's "digit 2 only" row), or all.
    classes : list of str or None
        Stored mode: keep only the classes of these names (a data set made by
        ``img2dmp import`` has its own, e.g. ``[L, T]``; for digits ``["2"]`` is the
        same as ``digits: [2]``), or all. Not together with ``digits``.
    augment : dict or None
        On-the-fly augmentation of the training batches: a fresh random affine transform
        of every image together with its trajectory (:mod:`img2dmp.data.affine`, the code
        that made the data), with the DMP targets of cost (9) refitted to the moved path.
        Keys are :class:`~img2dmp.data.affine.AffineRanges` fields, e.g.
        ``{rotation_deg: [-3, 3], scale: [0.97, 1.03], translation_rel: [-0.02, 0.02],
        shear_deg: [-3, 3]}``; a missing key means no change of that kind. The
        validation split is never augmented. None (default): off.
    unlabelled_mnist : str or None
        Folder of the MNIST IDX files: also train on MNIST images that have no recorded
        path, with the cost's ink terms alone (``cost.unlabelled_weight``), semi-supervised.
        Only t10k images and training images in the training part of the split rule
        (:func:`img2dmp.data.mnist.unlabelled_images`). None (default): off.
    train_on_validation : bool
        Stored mode: train on the validation split too, for a final model once the
        settings have been chosen on it. The validation error
        the run reports is then on samples it trained on, so it says only that training
        converged: every epoch's checkpoint is ``best`` (the last one is kept), and early
        stopping (``optim.patience``) and the ``plateau`` schedule, which would choose by
        it, are refused. The data set must have a validation split. Default False.
    unlabelled_count : int
        How many of those images (a fixed random choice).
    unlabelled_per_batch : int
        Unlabelled images beside each batch of examples with paths.
    """

    path: str | None = None
    generator: dict = field(default_factory=dict)
    samples_per_epoch: int = 20000
    refresh_epochs: int = 1
    val_samples: int = 1000
    val_fraction: float = 0.1
    digits: list[int] | None = None
    classes: list[str] | None = None
    augment: dict | None = None
    unlabelled_mnist: str | None = None
    unlabelled_count: int = 20000
    unlabelled_per_batch: int = 64
    train_on_validation: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.train_on_validation, bool):
            raise ConfigError(
                f"data.train_on_validation must be true or false, got {self.train_on_validation!r}"
            )
        if self.train_on_validation and self.path is None:
            raise ConfigError(
                "data.train_on_validation trains on a stored data set's validation split: set "
                "data.path (--data; the generator's validation set is drawn apart)"
            )
        for name in (
            "samples_per_epoch",
            "val_samples",
            "unlabelled_count",
            "unlabelled_per_batch",
        ):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"data.{name} must be >= 1, got {getattr(self, name)!r}")
        for name in ("samples_per_epoch", "val_samples"):
            if int(getattr(self, name)) > MAX_GENERATED_SAMPLES:
                raise ConfigError(
                    f"data.{name} must be at most {MAX_GENERATED_SAMPLES:,} (the generator "
                    f"holds them all in memory), got {getattr(self, name)!r}"
                )
        if int(self.refresh_epochs) < 0:
            raise ConfigError(f"data.refresh_epochs must be >= 0, got {self.refresh_epochs!r}")
        if not 0 <= self.val_fraction < 1:
            raise ConfigError(f"data.val_fraction must be in [0, 1), got {self.val_fraction!r}")
        if self.digits is not None and (
            not self.digits or any(not 0 <= int(d) <= 9 for d in self.digits)
        ):
            raise ConfigError(f"data.digits must be a non-empty list of 0-9, got {self.digits!r}")
        if self.classes is not None:
            names = self.classes
            if (
                not isinstance(names, list)
                or not names
                or not all(
                    isinstance(n, (str, int)) and not isinstance(n, bool) and str(n).strip()
                    for n in names
                )
            ):
                raise ConfigError(
                    f"data.classes must be a non-empty list of class names, got {names!r}"
                )
            self.classes = [str(n) for n in names]
            if self.digits is not None:
                raise ConfigError(
                    "data.digits and data.classes both select classes; give one of them"
                )
        self.augment_ranges()  # raises on a bad data.augment

    def augment_ranges(self):
        """The :class:`~img2dmp.data.affine.AffineRanges` of ``augment`` (None if off)."""
        from ..data.affine import AffineRanges

        if self.augment is None:
            return None
        if not isinstance(self.augment, dict):
            raise ConfigError(f"data.augment must be a mapping or null, got {self.augment!r}")
        ranges = AffineRanges.identity().to_dict()
        ranges.update(self.augment)
        try:
            return AffineRanges.from_dict(ranges)
        except (TypeError, ValueError) as e:
            raise ConfigError(f"data.augment: {e}") from e


@dataclass
class OptimConfig:
    """Adam and its learning-rate schedule.

    ``schedule``: ``"none"``; ``"cosine"`` (to ``min_lr`` over ``epochs``); ``"step"``
    (times ``gamma`` every ``step_size`` epochs); ``"plateau"`` (times ``gamma`` after
    ``step_size`` epochs without a better validation error). ``patience``: early stopping
    after that many epochs without a better validation trajectory error (0 = never).
    ``grad_clip``: largest gradient norm (None = no clipping). ``max_samples``: at most this
    many training samples in all (epochs times the samples of an epoch; 0 = no limit): a
    fresh run on more data takes fewer epochs, so a recipe's training time stays bounded
    whatever the data set's size; the epochs it takes are written to the run's
    configuration.
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
    max_samples: int = 0

    def __post_init__(self) -> None:
        numbers = {"lr": float, "weight_decay": float, "batch_size": int, "epochs": int}
        numbers |= {"patience": int, "step_size": int, "gamma": float, "min_lr": float}
        numbers |= {"max_samples": int}
        for name, kind in numbers.items():
            v = getattr(self, name)
            ok = isinstance(v, (int, float)) if kind is float else isinstance(v, int)
            if not ok or isinstance(v, bool):
                raise ConfigError(f"optim.{name} must be a number ({kind.__name__}), got {v!r}")
        check_positive("optim.lr", self.lr)
        check_positive("optim.weight_decay", self.weight_decay, allow_zero=True)
        check_positive("optim.min_lr", self.min_lr, allow_zero=True)
        check_positive("optim.gamma", self.gamma)
        if self.grad_clip is not None:
            check_positive("optim.grad_clip", self.grad_clip)
        bounds = ("batch_size", 1), ("epochs", 1), ("step_size", 1), ("patience", 0)
        for name, lo in (*bounds, ("max_samples", 0)):
            if getattr(self, name) < lo:
                raise ConfigError(f"optim.{name} must be >= {lo}, got {getattr(self, name)!r}")
        if self.schedule not in SCHEDULES:
            raise ConfigError(f"optim.schedule must be one of {SCHEDULES}, got {self.schedule!r}")


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

    ``ink_weight``, ``coverage_weight`` (px^-2 scale, 0 = off): image-consistency terms on
    every hypothesis, :func:`img2dmp.nn.ink.ink_attraction` (the path on the ink) and
    :func:`img2dmp.nn.ink.ink_coverage` (the ink reached by the path, beyond
    ``coverage_tolerance_px``). ``wta_relax`` and ``score_weight``: the winner-takes-all
    cost of a network with several hypotheses (``model.hypotheses``), see
    :class:`img2dmp.nn.Cost`. ``unlabelled_weight``: weight of those ink terms on images
    without a path (``data.unlabelled_mnist``). ``path_weight``: weight of the
    timing-free path cost (:func:`img2dmp.nn.costs.path_cost`, px^2) beside the cost.
    """

    name: str = "trajectory"
    parameter_weight: float = 1.0
    trajectory_weight: float = 1.0
    parameter_weighting: str = "none"
    parameter_weight_floor: float = 1e-3
    parameter_units: str = "weights"
    ink_weight: float = 0.0
    coverage_weight: float = 0.0
    coverage_tolerance_px: float = 1.0
    wta_relax: float = 0.05
    score_weight: float = 0.1
    unlabelled_weight: float = 1.0
    path_weight: float = 0.0

    def __post_init__(self) -> None:
        from ..nn.costs import PARAMETER_WEIGHTINGS, canonical_cost_name
        from ..nn.normalise import UNITS

        self.name = canonical_cost_name(self.name)
        check_positive("cost.parameter_weight", self.parameter_weight, allow_zero=True)
        check_positive("cost.trajectory_weight", self.trajectory_weight, allow_zero=True)
        for name in ("ink_weight", "coverage_weight", "coverage_tolerance_px", "score_weight",
                     "unlabelled_weight", "path_weight"):  # fmt: skip
            check_positive(f"cost.{name}", getattr(self, name), allow_zero=True)
        if not 0 <= self.wta_relax < 1:
            raise ConfigError(f"cost.wta_relax must be in [0, 1), got {self.wta_relax!r}")
        if self.parameter_weighting not in PARAMETER_WEIGHTINGS:
            raise ConfigError(
                f"cost.parameter_weighting must be one of {PARAMETER_WEIGHTINGS}, got "
                f"{self.parameter_weighting!r}"
            )
        if not 0 < float(self.parameter_weight_floor) <= 1:
            raise ConfigError(
                f"cost.parameter_weight_floor must be in (0, 1], got "
                f"{self.parameter_weight_floor!r}"
            )
        if self.parameter_units not in UNITS:
            raise ConfigError(
                f"cost.parameter_units must be one of {UNITS}, got {self.parameter_units!r}"
            )


@dataclass
class StrokesConfig:
    """A *stroke model* (:mod:`img2dmp.nn.strokes`): a character as up to ``slots``
    strokes, each its own 2-D DMP of ``n_kernels`` kernels per dimension, with a presence,
    an order key and a stroke count; 0 slots (the default) is the paper's one DMP per
    image.

    ``n_points``: instants per stroke at which the shapes are compared (cost 10 per
    stroke). ``matching``: predicted slots to true strokes by least cost (``"best"``) or
    slot i to the i-th stroke (``"order"``). ``presence_weight``, ``count_weight``,
    ``order_weight`` (``"best"`` only), ``tau_weight``: weights of the presence and count
    cross-entropies, the order key's and tau's squared errors beside the shapes' (px^2).
    ``count_class_weight`` (0 to 1): how much of the count's target is the distribution
    of the character's class's counts among the training drawings rather than the
    drawing's own count (:func:`img2dmp.training.data.count_targets`). The ink terms,
    hypotheses and winner-takes-all are those of ``cost`` and ``model``.
    """

    slots: int = 0
    n_kernels: int = 25
    n_points: int = 32
    matching: str = "best"
    presence_weight: float = 2.0
    count_weight: float = 1.0
    order_weight: float = 2.0
    tau_weight: float = 0.1
    count_class_weight: float = 0.0

    def __post_init__(self) -> None:
        for name in ("presence_weight", "count_weight", "order_weight", "tau_weight"):
            check_positive(f"strokes.{name}", getattr(self, name), allow_zero=True)
        w = check_positive("strokes.count_class_weight", self.count_class_weight, allow_zero=True)
        if w > 1:
            raise ConfigError(f"strokes.count_class_weight must be a number from 0 to 1, got {w!r}")
        from ..nn.strokes import MAX_SLOTS, StrokeLayout

        s = self.slots
        if isinstance(s, bool) or not isinstance(s, int) or not 0 <= s <= MAX_SLOTS:
            raise ConfigError(
                f"strokes.slots must be an integer from 1 to {MAX_SLOTS} (a stroke model: the "
                f"most strokes a drawing has), or 0 (one DMP per drawing), got {s!r}"
            )
        try:  # the other fields are checked also when the slots are off (0)
            StrokeLayout(1 if self.slots == 0 else self.slots, self.n_kernels, self.n_points,
                         self.matching)  # fmt: skip
        except ValueError as e:
            raise ConfigError(str(e)) from None

    def layout(self):
        """The :class:`~img2dmp.nn.strokes.StrokeLayout` (None for 0 slots)."""
        if not self.slots:
            return None
        from ..nn.strokes import StrokeLayout

        return StrokeLayout(self.slots, self.n_kernels, self.n_points, self.matching)


@dataclass
class ReadingConfig:
    """How the trained model's predictions are best read: the settings ``predict``,
    ``write``, ``evaluate`` and ``serve`` (and :func:`img2dmp.predict.load_model`) take
    for a run directory or checkpoint when their own flags do not say, as they take a
    shipped model's card's ``recommended``. Training does not use them; they travel in
    every checkpoint's record. A recipe sets those it chose on the validation part
    (``configs/real.yaml``, ``configs/omniglot.yaml``); the defaults recommend nothing.

    ``refine``: gradient steps that pull each prediction onto its image's ink
    (``--refine``; 0: the network's output). ``refine_unfamiliar``: the steps of images
    the model finds unfamiliar, below its familiarity line (``--refine-unfamiliar``;
    null: ``refine``'s; taken only where the run carries its familiarity).
    ``count_views``: the views a stroke model reads its stroke count from
    (``--count-views``; null: :data:`img2dmp.nn.strokes.COUNT_VIEWS`).
    """

    refine: int = 0
    refine_unfamiliar: int | None = None
    count_views: int | None = None

    def __post_init__(self) -> None:
        from ..nn._refine_options import MAX_REFINE_STEPS
        from ..nn._stroke_layout import MAX_COUNT_VIEWS

        for name, top in (("refine", MAX_REFINE_STEPS), ("refine_unfamiliar", MAX_REFINE_STEPS),
                          ("count_views", MAX_COUNT_VIEWS)):  # fmt: skip
            value = getattr(self, name)
            low = 1 if name == "count_views" else 0
            if value is not None and not low <= value <= top:
                null = "" if name == "refine" else " or null"
                raise ConfigError(f"reading.{name} must be a whole number from {low} to "
                                  f"{top:,}{null}, got {value!r}")  # fmt: skip

    def recommended(self) -> dict:
        """The settings it recommends, as a shipped model's card writes them (``refine``
        always; the others when set)."""
        from ..models import Reading

        return Reading(self.refine, self.refine_unfamiliar, self.count_views).recommended()


def _check_strokes(cfg) -> None:
    """Settings a stroke model cannot honour, refused by name."""
    if not cfg.strokes.slots:
        return
    if cfg.cost.name != "trajectory":
        raise ConfigError(
            f"a stroke model (strokes.slots = {cfg.strokes.slots}) trains with cost (10) per "
            f"stroke: cost.name must be 'trajectory', got {cfg.cost.name!r}"
        )
    if cfg.cost.path_weight:
        raise ConfigError("cost.path_weight is not used by a stroke model: set it to 0")
    if cfg.data.unlabelled_mnist is not None:
        raise ConfigError("data.unlabelled_mnist is not used by a stroke model: leave it out")


def _check_reading(cfg) -> None:
    """Reading settings the model cannot honour, refused by name."""
    if cfg.reading.count_views is not None and not cfg.strokes.slots:
        raise ConfigError(
            f"reading.count_views ({cfg.reading.count_views}) is read by a stroke model only; "
            "this one predicts one DMP per image (strokes.slots = 0): leave it out"
        )


def _check_train_on_validation(cfg) -> None:
    """Settings that choose by the validation error, refused when it is trained on."""
    if not cfg.data.train_on_validation:
        return
    if cfg.optim.patience:
        raise ConfigError(
            "data.train_on_validation trains on the validation split, so its error cannot "
            f"stop the run early: set optim.patience to 0 (got {cfg.optim.patience})"
        )
    if cfg.optim.schedule == "plateau":
        raise ConfigError(
            "data.train_on_validation trains on the validation split, so its error cannot "
            "drive the 'plateau' schedule: choose optim.schedule cosine, step or none"
        )


@dataclass
class TrainConfig:
    """Everything :func:`img2dmp.training.train` needs; read by :func:`load_config`.

    ``model.image_size`` left out (None) is taken from the data. ``threads``: torch's
    intra-op threads (None: torch's default). ``eval_batch_size``: images per validation
    batch. ``progress``: bars on a terminal, a line per epoch otherwise.

    ``init_from`` (CLI ``--init-from``): a run directory, checkpoint file or shipped model's
    name (``digits-real``, :mod:`img2dmp.models`) whose weights start this run instead of
    random ones (fine-tuning a pre-trained network). The architecture, the image size and
    the DMP configuration (N, d, scaling) must match. The checkpoint's output normalisation
    is **kept**, not refitted on the new data: the network's last layer speaks in those
    units, so keeping them makes the first fine-tuning step start from exactly the
    pre-trained network's predictions. Only the weights are taken; the optimiser, schedule and
    epoch count start afresh.
    """

    model: ModelConfig = field(default_factory=ModelConfig)
    data: DataConfig = field(default_factory=DataConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    cost: CostConfig = field(default_factory=CostConfig)
    strokes: StrokesConfig = field(default_factory=StrokesConfig)
    reading: ReadingConfig = field(default_factory=ReadingConfig)
    seed: int = 0
    threads: int | None = None
    eval_batch_size: int = 1024
    progress: bool = True
    init_from: str | None = None

    def __post_init__(self) -> None:
        if self.threads is not None and self.threads < 1:
            raise ConfigError(f"threads must be >= 1 or null, got {self.threads!r}")
        if self.threads is not None and self.threads > machine_cores():
            # torch starts one OpenMP thread per count: 100,000 of them crash the process
            raise ConfigError(
                f"threads must be at most this machine's {machine_cores()} cores, got "
                f"{self.threads!r}"
            )
        if self.eval_batch_size < 1:
            raise ConfigError(f"eval_batch_size must be >= 1, got {self.eval_batch_size!r}")
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed!r}")
        _check_strokes(self)
        _check_reading(self)
        _check_train_on_validation(self)

    def to_dict(self) -> dict:
        return _config.to_dict(self)

    @classmethod
    def from_dict(cls, d: dict | None) -> TrainConfig:
        return _config.from_mapping(cls, dict(d or {}))


def load_config(
    path: str | os.PathLike | None = None,
    overrides: list[str] | None = None,
    base: dict | None = None,
) -> TrainConfig:
    """Defaults, then ``base`` (a mapping of sections, e.g. :func:`run_sections`), then
    the file (if any), then the ``section.key=value`` overrides.

    ``path`` is a YAML, TOML or JSON file, or the name of a configuration shipped with
    img2dmp (``"paper"``, ``"conv-wide"``, ``"real"`` ...; :func:`img2dmp.config.shipped_configs`).
    """
    return _config.load(TrainConfig, path, overrides, base)


#: The sections of a run's configuration that ``img2dmp train --init-from RUN`` takes from
#: the run when no ``--config`` is given: what its network is (``model``; ``strokes``, the
#: layout of a stroke model's outputs), what it was trained to answer (``cost``) and how it
#: is read (``reading``). The data, the optimiser and the seed are the command line's.
RUN_SECTIONS = ("model", "cost", "strokes", "reading")


def run_sections(init_from: str | os.PathLike) -> dict:
    """The :data:`RUN_SECTIONS` of the configuration stored in the checkpoint ``init_from``
    (a run directory, a checkpoint file or a shipped model's name), as a mapping for
    :func:`load_config`'s ``base``; a section the checkpoint does not record is left out
    (the defaults'), but for a shipped model's ``reading``, which its card recommends
    (``digits-real``: 30 refinement steps, 60 for what it finds unfamiliar). The weights
    are not read."""
    from .. import models
    from ..checkpoint import read_checkpoint_meta, resolve_checkpoint

    path = resolve_checkpoint(init_from)
    stored = read_checkpoint_meta(path).get("train_config") or {}
    sections = {k: stored[k] for k in RUN_SECTIONS if isinstance(stored.get(k), dict)}
    shipped = models.resolve(init_from)
    if shipped is not None and "reading" not in sections:
        sections["reading"] = shipped.reading.recommended()
    try:  # a run of an older img2dmp may hold a setting this one no longer has
        _config.check_known(TrainConfig, sections)
    except ConfigError as e:
        raise ConfigError(f"the configuration stored in {path}: {e}") from None
    return sections


__all__ = [
    "SCHEDULES",
    "CostConfig",
    "DataConfig",
    "ModelConfig",
    "OptimConfig",
    "RUN_SECTIONS",
    "ReadingConfig",
    "StrokesConfig",
    "TrainConfig",
    "load_config",
    "machine_cores",
    "run_sections",
]
