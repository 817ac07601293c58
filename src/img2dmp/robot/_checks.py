"""Argument checks shared by the robot's settings objects."""

from __future__ import annotations

import math


def check_positive(obj, names) -> None:
    """Raise ``ValueError`` naming the first attribute of ``obj`` in ``names`` that is not
    a finite number > 0."""
    for name in names:
        v = getattr(obj, name)
        ok = isinstance(v, (int, float)) and not isinstance(v, bool)
        if not (ok and math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
