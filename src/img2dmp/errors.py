"""Failures that img2dmp anticipates, as classes the command line maps to one line.

Bad input raises ``ValueError`` (or a subclass such as
:class:`img2dmp.config.ConfigError` and :class:`img2dmp.checkpoint.CheckpointError`) or
``FileNotFoundError`` / ``FileExistsError``; the classes here cover what is neither.
Nothing here imports the rest of img2dmp (or torch), so the CLI can import it at once.
"""

from __future__ import annotations

import reprlib


class Img2dmpError(Exception):
    """Base of img2dmp's own anticipated failures."""


class TrainingDiverged(Img2dmpError, FloatingPointError):
    """The training cost or the validation error became NaN or infinite.

    A ``FloatingPointError`` too, so code written against earlier versions still catches it.
    """


class UnknownModelError(Img2dmpError, FileNotFoundError):
    """A model given by name (``--model NAME``) that is neither a file nor a directory
    nor one of the models shipped with img2dmp; the message lists the shipped ones.

    A ``FileNotFoundError`` too, as a missing run directory is.
    """


class ShippedModelError(Img2dmpError, ValueError):
    """A model shipped with img2dmp is missing, unreadable or does not match the SHA-256
    recorded beside it (a damaged installation), or its record is malformed."""


def _bounded_repr(limit: int) -> reprlib.Repr:
    r = reprlib.Repr()
    r.maxlevel, r.maxlist, r.maxtuple, r.maxdict, r.maxset = 3, 8, 8, 8, 8
    r.maxstring = r.maxother = limit
    return r


def _digits(n: int) -> int:
    return len(str(n)) if n.bit_length() < 1000 else int(n.bit_length() * 0.30103) + 1


def show(value, limit: int = 60) -> str:
    """``value`` for an error message: its ``repr`` cut to ``limit`` characters, naming
    the size of what was cut. Never the whole value: a ``--set`` of a megabyte, or a YAML
    alias bomb whose expansion has a billion items, is shown as its first characters
    (``reprlib``: a few items of a few levels, so nothing large is ever turned into text).
    """
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 200:
        return f"a whole number of {_digits(abs(value)):,} digits"
    text = _bounded_repr(limit).repr(value)
    sized = isinstance(value, (str, bytes, list, tuple, dict, set))
    if len(text) <= limit and (not sized or "..." not in text):
        return text
    size = ""
    if sized:
        n = len(value)
        unit = {str: "character", bytes: "byte"}.get(type(value), "item")
        size = f" ({type(value).__name__} of {n:,} {unit}{'' if n == 1 else 's'})"
    return (text if len(text) <= limit else text[: limit - 3] + "...") + size


__all__ = ["Img2dmpError", "ShippedModelError", "TrainingDiverged", "UnknownModelError", "show"]
