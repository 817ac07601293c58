"""The settings of the refinement at prediction time, without torch.

:class:`RefineOptions` and :data:`MAX_REFINE_STEPS` are shared by the torch refinement
(:func:`img2dmp.nn.refine.refine`, which re-exports them) and the NumPy one
(:func:`img2dmp.nn._refine_numpy.refine_numpy`); importing them must not import torch.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

from ..config import check_positive

#: Most refinement steps per prediction (``--refine``; 30 is the default).
MAX_REFINE_STEPS = 10_000


@dataclass(frozen=True)
class RefineOptions:
    """Settings of :func:`~img2dmp.nn.refine.refine`.

    ``steps`` Adam steps of size ``lr`` (normalised units); ``prior_weight`` = lambda;
    ``ink_weight`` = a, ``coverage_weight`` = c (px^-2 scale); ``coverage_tolerance_px``
    as in :func:`~img2dmp.nn.ink.ink_coverage`.
    """

    steps: int = 30
    lr: float = 0.02
    prior_weight: float = 5.0
    ink_weight: float = 1.0
    coverage_weight: float = 1.0
    coverage_tolerance_px: float = 1.0

    def __post_init__(self) -> None:
        steps = self.steps
        integer = isinstance(steps, numbers.Integral) and not isinstance(steps, bool)
        if not integer or not 0 <= steps <= MAX_REFINE_STEPS:
            raise ValueError(
                f"refine steps must be an integer from 0 to {MAX_REFINE_STEPS}, got {steps!r}"
            )
        for name in ("lr", "prior_weight", "ink_weight", "coverage_weight"):
            check_positive(f"refine {name}", getattr(self, name), allow_zero=True)
        check_positive("refine coverage_tolerance_px", self.coverage_tolerance_px)


__all__ = ["MAX_REFINE_STEPS", "RefineOptions"]
