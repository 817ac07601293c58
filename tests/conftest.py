"""Shared test helpers."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "experiments"


@pytest.fixture
def experiment_script(monkeypatch):
    """``load(name)``: the module ``experiments/<name>.py``, imported from its file.

    The experiments directory goes on ``sys.path`` first, as it does when Python runs the
    script, so that its helpers (``_provenance``) import.
    """
    monkeypatch.syspath_prepend(str(EXPERIMENTS))

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, EXPERIMENTS / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod  # dataclasses look their module up there
        spec.loader.exec_module(mod)
        return mod

    return load
