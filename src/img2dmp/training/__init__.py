"""Training the encoder-decoder network with cost (9) or cost (10) (Pahič et al., Sec. V).

- :mod:`.config` - :class:`TrainConfig` (model, data, optim, cost) and :func:`load_config`
- :mod:`.data` - :class:`TrainingData` (splits, generator mode), :class:`Augmenter`
- :mod:`.state` - :class:`RunState`, :class:`EpochStats`, checkpoints
- :mod:`.setup` - :func:`open_run`: fresh, resumed or fine-tuning
- :mod:`.loop` - :func:`train` = :func:`open_run` + :func:`fit`; :func:`train_epoch`,
  :func:`train_step`, :func:`validate`
- :mod:`.records` - ``metrics.csv`` and ``training_curve.png``

Example::

    from img2dmp.training import load_config, train
    result = train(load_config("paper", ["data.path=digits.safetensors"]),
                   "runs/paper")
"""

from ..errors import TrainingDiverged
from .config import CostConfig, DataConfig, ModelConfig, OptimConfig, TrainConfig, load_config
from .data import Augmenter, Split, TrainingData, generate_arrays
from .loop import (
    StepResult,
    TrainResult,
    fit,
    train,
    train_epoch,
    train_step,
    trajectory_errors,
    validate,
)
from .records import METRIC_FIELDS, plot_training_curve, read_metrics_csv, write_metrics_csv
from .setup import Run, make_scheduler, open_run
from .state import EpochStats, RunState

__all__ = [
    "METRIC_FIELDS",
    "Augmenter",
    "CostConfig",
    "DataConfig",
    "EpochStats",
    "ModelConfig",
    "OptimConfig",
    "Run",
    "RunState",
    "Split",
    "StepResult",
    "TrainConfig",
    "TrainResult",
    "TrainingData",
    "TrainingDiverged",
    "fit",
    "generate_arrays",
    "load_config",
    "make_scheduler",
    "open_run",
    "plot_training_curve",
    "read_metrics_csv",
    "train",
    "train_epoch",
    "train_step",
    "trajectory_errors",
    "validate",
    "write_metrics_csv",
]
