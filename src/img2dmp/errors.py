"""Failures that img2dmp anticipates, as classes the command line maps to one line.

Bad input raises ``ValueError`` (or a subclass such as
:class:`img2dmp.config.ConfigError` and :class:`img2dmp.checkpoint.CheckpointError`) or
``FileNotFoundError`` / ``FileExistsError``; the classes here cover what is neither.
Nothing here imports the rest of img2dmp (or torch), so the CLI can import it at once.
"""

from __future__ import annotations


class Img2dmpError(Exception):
    """Base of img2dmp's own anticipated failures."""


class TrainingDiverged(Img2dmpError, FloatingPointError):
    """The training cost or the validation error became NaN or infinite.

    A ``FloatingPointError`` too, so code written against earlier versions still catches it.
    """


__all__ = ["Img2dmpError", "TrainingDiverged"]
