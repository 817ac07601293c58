"""The public entry point of training, kept for code written against earlier versions.

Everything lives in :mod:`img2dmp.training`; this module re-exports its public names
(and the configuration helpers that used to be defined here).
"""

from .checkpoint import CheckpointError
from .config import apply_overrides, read_config_file
from .training import *  # noqa: F403
from .training import __all__ as _training_all
from .training.data import Augmenter as _Augmenter  # noqa: F401 - the earlier private name

__all__ = [*_training_all, "CheckpointError", "apply_overrides", "read_config_file"]
