"""Options that several commands share, defined and parsed in one place.

``--model``, ``--data``, ``--digits``, ``--config``, ``--set`` and ``--no-progress`` mean
the same in every command that takes them, and every number that must lie in a range is
checked while the command line is read, so that a bad value gives one line and exit
status 2 before anything slow starts.

Standard library only: building the parser must not import torch, NumPy or matplotlib.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from pathlib import Path

DIGITS_EXAMPLES = '2, 2,3, "1 4 7", 0-9 or 0-3,8'


# --- digits ---------------------------------------------------------------------------


def parse_digits(text: str | Iterable[str]) -> tuple[int, ...]:
    """Digits named as ``"2"``, ``"2,3"``, ``"1 4 7"``, ``"0-9"`` or ``"0-3,8"``.

    A list of such texts (``--digits 2 3`` gives ``["2", "3"]``) is read as one. Repeats
    are dropped, the first mention keeping its place. Raises ``ValueError`` naming the
    part that is not a digit 0-9 or a range of them.
    """
    texts = [text] if isinstance(text, str) else list(text)
    digits: list[int] = []
    for t in texts:
        for part in str(t).replace(",", " ").split():
            digits.extend(_digit_part(part))
    if not digits:
        raise ValueError(f"must name at least one digit, e.g. {DIGITS_EXAMPLES}")
    return tuple(dict.fromkeys(digits))


def _digit_part(part: str) -> range:
    lo, sep, hi = part.partition("-")
    if not (lo.isdecimal() and (hi.isdecimal() or not sep)):
        raise ValueError(f"{part!r} is not a digit 0-9 or a range like 0-3")
    a, b = int(lo), int(hi) if sep else int(lo)
    for v in (a, b):
        if v > 9:
            raise ValueError(f"digits must be 0-9, got {v}" + (f" in {part!r}" if sep else ""))
    if a > b:
        raise ValueError(f"range {part!r} runs backwards; write {b}-{a}")
    return range(a, b + 1)


def _digits_type(text: str) -> tuple[int, ...]:
    try:
        return parse_digits(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


class _DigitsAction(argparse.Action):
    """``--digits 2 3``, ``--digits 2,3`` and ``--digits "0-3 8"`` all give one tuple."""

    def __call__(self, parser, namespace, values, option_string=None):
        merged = [d for group in values for d in group]
        setattr(namespace, self.dest, tuple(dict.fromkeys(merged)))


def add_digits(p: argparse.ArgumentParser, help: str) -> None:
    """``--digits`` (default None: the command's own default, said in ``help``)."""
    p.add_argument(
        "--digits",
        nargs="+",
        type=_digits_type,
        action=_DigitsAction,
        metavar="DIGITS",
        help=f"{help}; written {DIGITS_EXAMPLES}",
    )


# --- model, data, configuration -------------------------------------------------------


def add_model(
    p: argparse.ArgumentParser, *, required: bool = False, help: str = "", dest: str = "model"
) -> None:
    """``--model RUN``: a trained network, its run directory or checkpoint file."""
    p.add_argument(
        "--model",
        dest=dest,
        required=required,
        metavar="RUN",
        help=help or "trained network: run directory or checkpoint (.safetensors)",
    )


def add_data(p: argparse.ArgumentParser, *, help: str = "", dest: str = "data") -> None:
    """``--data FILE``: a data-set file (``img2dmp generate`` / ``prepare`` output)."""
    p.add_argument(
        "--data",
        dest=dest,
        metavar="FILE",
        help=help or "data-set file (.safetensors, from img2dmp generate or prepare)",
    )


def add_config(p: argparse.ArgumentParser, what: str) -> None:
    """``--config FILE``: a YAML, TOML or JSON file of ``what``'s fields."""
    p.add_argument(
        "--config",
        metavar="FILE",
        help=f"YAML, TOML or JSON file of {what} (unknown keys are refused)",
    )


def add_set(p: argparse.ArgumentParser, example: str) -> None:
    """``--set KEY=VALUE ...``, repeatable; every occurrence's pairs are kept, in order."""
    p.add_argument(
        "--set",
        action="extend",
        nargs="+",
        default=[],
        metavar="KEY=VALUE",
        help="override one setting (value read as YAML; nested keys with dots), applied "
        f"after --config and the option shortcuts; may be repeated, e.g. {example}",
    )


def add_no_progress(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--no-progress",
        action="store_true",
        help="no progress bars (they show on a terminal; in a log, one line per step)",
    )


def same_path(a, b) -> bool:
    """Whether two command-line paths name the same file (``runs/x/`` = ``runs/x``)."""
    return Path(a) == Path(b) or Path(a).resolve() == Path(b).resolve()


# --- numbers --------------------------------------------------------------------------


def int_at_least(lo: int):
    """An argparse ``type``: an integer ``>= lo``."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"must be an integer >= {lo}, got {v}")
        return v

    parse.__name__ = f"integer >= {lo}"
    return parse


def positive_float(text: str) -> float:
    """An argparse ``type``: a finite number ``> 0``."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not (0 < v < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return v


__all__ = [
    "add_config",
    "add_data",
    "add_digits",
    "add_model",
    "add_no_progress",
    "add_set",
    "int_at_least",
    "parse_digits",
    "positive_float",
    "same_path",
]


def add_refine(p: argparse.ArgumentParser) -> None:
    """``--refine STEPS``: gradient steps that pull each predicted DMP onto the ink of its
    image near the network's output (:mod:`img2dmp.nn.refine`); 0 = the network's output."""
    p.add_argument(
        "--refine",
        metavar="STEPS",
        type=int_at_least(0),
        default=0,
        help="refine each predicted DMP on its image with this many gradient steps that "
        "pull it onto the ink near the network's output (0 = the network's output as it is)",
    )
