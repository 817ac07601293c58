"""Names of a package loaded from their modules on first use (PEP 562).

A package's ``__init__`` that imported all its modules would make every submodule's
import pay for the heaviest of them (torch, 1.5-3 s): ``img2dmp.dmp.params`` is
needed by a prediction without torch, ``img2dmp.dmp.rollout`` imports it.
:func:`exports` gives the ``__getattr__`` and ``__dir__`` of such a package: each name is
imported from its module when first asked for, then kept in the package's namespace.

A name that is also its module's (``img2dmp.dmp.rollout``, the function, in the module
``img2dmp.dmp.rollout``) stays the function, as an eager ``from .rollout import rollout``
left it: importing the module would otherwise bind the module to the package's name.

:func:`is_tensor` and :func:`is_dtype` serve modules that accept NumPy arrays or torch
tensors: they never import torch (while torch is not imported, nothing can be a tensor),
and code that runs only for tensors imports torch itself, already loaded, so free.
"""

from __future__ import annotations

import importlib
import sys
import types


def exports(package: str, names: dict[str, str], namespace: dict):
    """``(__getattr__, __dir__)`` for ``package``: ``names`` maps each exported name to
    its module (relative to the package, e.g. ``".rollout"``); ``namespace`` is the
    package's ``globals()``."""

    def __getattr__(name: str):
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module, package), name)
        namespace[name] = value  # later accesses skip this function
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *names})

    shadowed = {n for n, m in names.items() if m == "." + n}
    if shadowed:
        sys.modules[package].__class__ = _shadowing(package, frozenset(shadowed))
    return __getattr__, __dir__


def _shadowing(package: str, shadowed: frozenset) -> type:
    """A module class whose ``setattr(package, name, module)`` (what the import system
    does once a submodule has run) keeps the module's own ``name`` instead."""

    class Package(types.ModuleType):
        def __setattr__(self, name, value):
            if name in shadowed and getattr(value, "__name__", None) == f"{package}.{name}":
                value = getattr(value, name)
            super().__setattr__(name, value)

    return Package


def is_tensor(a) -> bool:
    """True for a ``torch.Tensor``; never imports torch."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(a, torch.Tensor)


def is_dtype(a) -> bool:
    """True for a ``torch.dtype``; never imports torch."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(a, torch.dtype)


__all__ = ["exports", "is_dtype", "is_tensor"]
