"""Options that several commands share, defined and parsed in one place.

``--model``, ``--data``, ``--digits``, ``--config``, ``--set``, ``--force``, ``--device``
and ``--no-progress`` mean the same in every command that takes them, and every number that
must lie in a range is checked while the command line is read, so that a bad value gives
one line and exit status 2 before anything slow starts. So are the files: the inputs
(:func:`check_inputs`: there, a file, readable) and the outputs (:func:`check_outputs`:
the overwrite rule, no directory where a file belongs, no two outputs with one name).

Standard library only (and :mod:`img2dmp._files`, which is too): building the parser
must not import torch, NumPy or matplotlib.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import warnings
from collections.abc import Iterable
from contextlib import contextmanager
from importlib import resources
from pathlib import Path

from .._files import check_readable

DIGITS_EXAMPLES = '2, 2,3, "1 4 7", 0-9 or 0-3,8'
#: The default shipped model and the refinement its card recommends, as the help words
#: them (img2dmp.models.default_model(); a test keeps them equal).
DEFAULT_MODEL_NAME = "digits-real"
DEFAULT_REFINE = 30
#: The views a stroke model reads its count from unless its card recommends others, and
#: the most it may (img2dmp.nn.strokes.COUNT_VIEWS and MAX_COUNT_VIEWS; a test keeps
#: them equal).
DEFAULT_COUNT_VIEWS, MAX_COUNT_VIEWS = 8, 64


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


def parse_classes(text: str) -> list[str]:
    """An argparse ``type``: class names separated by commas, in order (a name may hold
    spaces: ``"big circle,square"``), in Unicode NFC as ``img2dmp import`` stores them (an
    é typed as e and an accent names the same class)."""
    import unicodedata

    names = [unicodedata.normalize("NFC", n.strip()) for n in text.split(",")]
    if not all(names):
        raise argparse.ArgumentTypeError(f"must be class names separated by commas, got {text!r}")
    return names


def add_digits_or_classes(p: argparse.ArgumentParser, digits_help: str, classes_help: str):
    """``--digits`` (:func:`add_digits`) or ``--classes NAMES``, not both (argparse says
    so); ``args.classes`` is None or a tuple of names."""
    group = p.add_mutually_exclusive_group()
    add_digits(group, digits_help)
    group.add_argument(
        "--classes",
        nargs="+",
        type=parse_classes,
        action=_DigitsAction,
        metavar="NAMES",
        help=f"{classes_help}; written L,T or L T (the names of a data set made by "
        "img2dmp import, separated by commas; for digits the same as --digits)",
    )


# --- model, data, configuration -------------------------------------------------------


def add_model(
    p: argparse.ArgumentParser,
    *,
    required: bool = False,
    help: str = "",
    dest: str = "model",
    default_shipped: bool = False,
) -> None:
    """``--model RUN|NAME``: a trained network, its run directory or checkpoint file, or
    the name of a model shipped with img2dmp (:mod:`img2dmp.models`); with
    ``default_shipped`` the help says that none given means the default shipped model."""
    default = f" (default: the shipped model {DEFAULT_MODEL_NAME})" if default_shipped else ""
    p.add_argument(
        "--model",
        dest=dest,
        required=required,
        metavar="RUN|NAME",
        help=help
        or "trained network: run directory, checkpoint (.safetensors) or the name of a "
        f"model shipped with img2dmp (img2dmp models lists them){default}",
    )


def model_or_default(model):
    """``--model`` as given, or the default shipped model when none is (the
    :class:`~img2dmp.models.ShippedModel` itself, not its name: a folder of that name in
    the working directory is no model nobody asked for)."""
    if model is not None:
        return model
    from ..models import default_model

    return default_model()


def one_thread() -> None:
    """Compute on one thread, as ``serve`` does: a few images make arrays so small
    (refinement: [4, 100, 2] paths) that a second thread costs more in synchronisation
    than it computes; on the 2-core development machine refining one image took 0.29 s
    on one thread and 4-8 s on two while other jobs ran (docs/CLI.md), and the NumPy
    network's matrix products on a busy machine ten times longer on two BLAS threads.

    Called before the model is loaded: in a process that has not imported NumPy yet
    (a command's own), the thread counts of OpenBLAS under NumPy and OpenMP under torch
    are set through their environment variables, unless the user set them (a process
    that has, e.g. a test's, keeps its own); torch, if already imported, directly."""
    if "numpy" not in sys.modules and "torch" not in sys.modules:
        for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(name, "1")
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


def refine_steps(args, model, command: str, reading=None) -> tuple[int, int | None]:
    """``(--refine, --refine-unfamiliar)`` as given; else the steps the model recommends
    (``reading``, or :func:`img2dmp.predict.reading_for` ``model``: a shipped model's card,
    a run's training configuration), said in one note on standard error when they are not
    0. The second is None when unfamiliar images get the first's steps (neither given nor
    recommended, or ``--refine`` given alone)."""
    given = getattr(args, "refine_unfamiliar", None)
    if args.refine is not None:
        return args.refine, given
    if reading is None:
        from ..predict import reading_for

        try:
            reading = reading_for(model)
        except (OSError, ValueError):  # said by name where the model is loaded
            return 0, given
    card = reading.refine_unfamiliar if given is None else None  # the recommended, when taken
    if reading.refine or card:
        more = f" (--refine-unfamiliar {card}: images it finds unfamiliar)" if card else ""
        views = getattr(reading, "count_views", None)
        told = getattr(args, "count_views", None) is not None or not hasattr(args, "count_views")
        count = f"; the count from {views} view(s): --count-views {views}" if views else ""
        count = "" if told else count
        print(f"img2dmp {command}: note: model {model} with --refine {reading.refine}{more}, "
              f"as {reading.by} recommends (--refine 0: the network's output as it is){count}",
              file=sys.stderr)  # fmt: skip
    return reading.refine, given if given is not None else card


def set_refinement(args, model, predictor, command: str) -> None:
    """Refine ``predictor``'s predictions as ``--refine`` and ``--refine-unfamiliar`` say,
    or as the model recommends (its :attr:`~img2dmp.predict.Predictor.reading`,
    :func:`refine_steps`); nothing when neither asks for any
    (:meth:`~img2dmp.predict.Predictor.refine_with`: a ``ValueError`` for
    ``--refine-unfamiliar`` on a model without a familiarity)."""
    reading = predictor.reading if args.refine is None else None  # read only when taken
    refine, unfamiliar = refine_steps(args, model, command, reading)
    if refine or unfamiliar is not None:
        predictor.refine_with(refine, unfamiliar)


def add_data(p: argparse.ArgumentParser, *, help: str = "", dest: str = "data") -> None:
    """``--data FILE``: a data-set file (``img2dmp generate`` / ``prepare`` output)."""
    p.add_argument(
        "--data",
        dest=dest,
        metavar="FILE",
        help=help or "data-set file (.safetensors, from img2dmp generate or prepare)",
    )


def shipped_config_names() -> list[str]:
    """The configurations shipped inside the package, by name (``paper``, ``conv-wide``
    ...; :func:`img2dmp.config.shipped_configs`, listed here without importing YAML)."""
    folder = resources.files("img2dmp").joinpath("configs")
    return sorted(f.name[:-5] for f in folder.iterdir() if f.name.endswith(".yaml"))


def add_config(p: argparse.ArgumentParser, what: str) -> None:
    """``--config FILE|NAME``: a YAML, TOML or JSON file of ``what``'s fields, or the name
    of a configuration shipped with img2dmp."""
    p.add_argument(
        "--config",
        metavar="FILE|NAME",
        help=f"YAML, TOML or JSON file of {what} (unknown keys are refused), or the name of "
        f"a configuration shipped with img2dmp: {', '.join(shipped_config_names())}",
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


def _device_type(text: str) -> str:
    kind, sep, index = text.partition(":")
    if kind not in ("cpu", "cuda") or (sep and (kind != "cuda" or not index.isdecimal())):
        raise argparse.ArgumentTypeError(f"must be cpu, cuda or cuda:N, got {text!r}")
    return text


def add_device(p: argparse.ArgumentParser, what: str) -> None:
    """``--device cpu|cuda|cuda:N``: where ``what`` runs. The spelling is checked while
    the command line is read; whether the machine has that device by
    :func:`check_device` (which needs torch) when the command runs."""
    p.add_argument(
        "--device",
        default="cpu",
        type=_device_type,
        metavar="DEVICE",
        help=f"where {what} runs: cpu, or cuda (cuda:N) on a machine with a GPU; the DMP "
        "maths (rollout, costs) stays on the CPU",
    )


#: img2dmp.predict.BACKENDS (a literal: importing img2dmp.predict here would slow --help).
BACKENDS = ("auto", "numpy", "torch")


def add_backend(p: argparse.ArgumentParser) -> None:
    """``--backend auto|numpy|torch``: what computes a prediction (img2dmp.predict)."""
    p.add_argument(
        "--backend",
        default="auto",
        choices=BACKENDS,
        help="what computes the network, refinement and rollout: numpy (never imports "
        "torch, about 2 s faster to start), torch, or auto (default: numpy on the CPU, "
        "torch on a GPU); the two agree to rounding",
    )


def check_device(name: str) -> str:
    """``name`` if this machine has that device, else one ``ValueError`` line saying so
    (:func:`img2dmp.nn.device.resolve_device`; imports torch for a GPU only)."""
    if name == "cpu":
        return name
    from ..nn.device import resolve_device

    resolve_device(name)
    return name


def add_no_progress(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--no-progress",
        action="store_true",
        help="no progress bars (they show on a terminal; in a log, one line per step)",
    )


def add_force(p: argparse.ArgumentParser, what: str = "output files") -> None:
    """``--force``: the one way to replace an existing output (the rule of every command
    that writes, see :func:`check_outputs`)."""
    p.add_argument(
        "--force",
        action="store_true",
        help=f"replace existing {what}; without it an existing output is never replaced "
        "and the command stops before doing anything",
    )


def same_path(a, b) -> bool:
    """Whether two command-line paths name the same file (``runs/x/`` = ``runs/x``)."""
    return Path(a) == Path(b) or Path(a).resolve() == Path(b).resolve()


# --- files ----------------------------------------------------------------------------


def check_inputs(paths: Iterable, what: str) -> None:
    """Every path a regular file this process can read, else one clear ``OSError``
    (no such file, a directory, permission denied) naming ``what`` and the file."""
    for path in paths:
        check_readable(path, what)


@contextmanager
def reading_image(path):
    """Failures of reading the image file ``path`` in the block as one ``ValueError``
    naming it: a file that is no image, and PIL's refusal of a decompression bomb (an
    ``Exception`` that is neither ``OSError`` nor ``ValueError``)."""
    from PIL import Image

    try:
        yield
    except Image.DecompressionBombError as e:
        raise ValueError(f"image file {path} is refused as too large: {e}") from e
    except OSError as e:  # PIL's UnidentifiedImageError is one
        raise ValueError(f"image file {path} cannot be read as an image: {e}"
                         f"{_document_hint(path)}") from e  # fmt: skip


#: What a JSON file img2dmp wrote is, by its format, and the command that writes it.
_DOCUMENTS = {
    "img2dmp-page": "a page document: img2dmp write {path} --page writes it",
    "img2dmp-dmp": "a DMP file: img2dmp write --dmp {path} writes it",
    "img2dmp-strokes": "a stroke model's prediction: img2dmp write --dmp {path} writes it",
}


def _document_hint(path) -> str:
    """``"; it is a page document: ..."`` for a document of img2dmp's given where an image
    belongs (its ``"format"`` read from the file's first 64 KiB), else ``""``."""
    import re

    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16).decode("utf-8", errors="replace")
    except OSError:
        return ""
    m = re.search(r'"format"\s*:\s*"(img2dmp-[a-z]+)"', head)
    what = _DOCUMENTS.get(m.group(1)) if m else None
    return f"; it is {what.format(path=path)}" if what else ""


def _page_flag_words(flag: str) -> str:
    """A page's flag as :func:`warn_page` says it: the name, and what it means where the
    name alone does not say what to do."""
    if flag == "too_small":
        from img2dmp.page import PAGE_MIN_HEIGHT_PX

        return (f"too_small (its characters are under {PAGE_MIN_HEIGHT_PX:g} px tall in the "
                "photo, too small to read: none is given; photograph the page closer or at a "
                "higher resolution)")  # fmt: skip
    return flag


def warn_page(command: str, path, page, hint: str = "") -> None:
    """One warning line for a page read with flags (``PagePrediction``): the page's own
    and its flagged characters by index, ``hint`` after them."""
    flagged = page.flagged
    if not (page.flags or flagged):
        return
    which = ", ".join(f"#{c.character.index} ({'/'.join(c.flags)})" for c in flagged[:8])
    more = f" and {len(flagged) - 8} more" if len(flagged) > 8 else ""
    noun = "character" if len(flagged) == 1 else "characters"
    listed = [f"{len(flagged)} {noun} flagged (by index): {which}{more}"] if flagged else []
    what = "; ".join([_page_flag_words(f) for f in page.flags] + listed)
    print(f"img2dmp {command}: warning: {path}: {what}{hint if flagged else ''}",
          file=sys.stderr)  # fmt: skip


def warn_flags(command: str, path, pred) -> None:
    """One line on stderr for a prediction with flags (:attr:`Prediction.flags`: off the
    ink, ink unexplained, several characters, unfamiliar), with its fit and familiarity
    and what to do; nothing for one without."""
    flags = list(pred.flags)
    if not flags:
        return
    familiarity, line = pred.familiarity, pred.familiar_line
    digits = 3  # more where three would print the two alike
    while familiarity is not None and line is not None and digits < 8 and (
            f"{familiarity:.{digits}f}" == f"{line:.{digits}f}"):  # fmt: skip
        digits += 1
    known = "" if familiarity is None or line is None else (
        f"familiarity {familiarity:.{digits}f}, the model's line {line:.{digits}f}; ")  # fmt: skip
    # Unrefined (--refine 0, or a run whose reading recommends none): a path off the ink
    # may be off it only for that.
    unrefined = pred.refine_steps == 0 and bool({"off_ink", "unexplained_ink"} & set(flags))
    fit = pred.fit
    print(f"img2dmp {command}: warning: {path}: {', '.join(flags)} ({known}path on ink "
          f"{fit['path_on_ink']:.2f}, ink written {fit['ink_written']:.2f}): it may not "
          "show one character the model knows"
          + ("; for a page of characters use --page" if "several_characters" in flags else "")
          + ("; the path is unrefined: --refine N pulls it onto the ink" if unrefined else ""),
          file=sys.stderr)  # fmt: skip


def check_images(paths: Iterable) -> None:
    """Each path opens as an image (its header only, which is where PIL refuses a
    decompression bomb), else one ``ValueError`` naming it, before any slow work."""
    from PIL import Image

    for path in paths:
        with reading_image(path), warnings.catch_warnings():
            # PIL warns from 89 MP and refuses from 179 MP; the reading says the size
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path):
                pass


def _first_existing(path: Path) -> Path:
    for p in (path, *path.parents):
        if p.exists():
            return p
    return Path(".")


#: Suffixes of the files img2dmp reads and writes: a folder to be made of such a name
#: (``predict --out pred.json``) is taken for a file name and refused.
FILE_SUFFIXES = frozenset(
    ".json .csv .png .jpg .jpeg .safetensors .txt .onnx .npz .npy .mp4 .gif .yaml .pt".split()
)


def check_output_dir(path, what: str = "output directory") -> None:
    """``path`` is a directory or can become one: no file at it or above it, and not a
    new folder named like a file."""
    p = Path(path)
    there = _first_existing(p)
    if there != p and p.suffix.lower() in FILE_SUFFIXES:
        raise ValueError(
            f"{what} {p} names a folder to write into, not a {p.suffix} file: give a folder "
            f"(e.g. {what} {p.with_suffix('')})"
        )
    if there == p and not p.is_dir():
        raise NotADirectoryError(f"{what} {p} is a file, not a directory")
    if not there.is_dir():
        raise NotADirectoryError(f"{what} {p} cannot be made: {there} is a file")


def check_file_dir(path, what: str = "--out") -> None:
    """The folder a data-set file goes into exists (:func:`img2dmp.data.store.save_dataset`
    makes none), said before the data are made rather than after."""
    parent = Path(path).parent
    if not parent.is_dir():
        raise FileNotFoundError(f"{what} {path}: directory {str(parent)!r} does not exist")


def check_outputs(outputs: Iterable, force: bool, inputs: Iterable = ()) -> None:
    """The overwrite rule, checked before any work starts.

    ``outputs``: pairs (a file to write, the input it is made from or None). Two
    outputs of one name (``A/x.png`` and ``C/x.png`` both giving ``x_dmp.json``) are
    refused, naming both inputs; so is a directory where a file belongs or a file where
    its directory belongs; and an existing output is refused unless ``force``.

    ``inputs``: pairs (what, path) of everything the command reads (:func:`model_inputs`
    for a ``--model``). No output may be one of them, nor lie inside an input that is a
    folder, ``--force`` or not: ``preview --data X --out X`` would turn the data set
    into a picture, ``import DIR --out DIR/L/000.png`` replace one of its own images.
    """
    read = [(what, Path(path)) for what, path in inputs if path is not None]
    seen: dict[Path, object] = {}
    for out, source in outputs:
        p = Path(out)
        key = Path(os.path.abspath(p))
        if key in seen:
            first = seen[key]
            if first is not None and source is not None and same_path(first, source):
                raise ValueError(f"{source} is given twice; give each input once")
            raise ValueError(
                f"{first} and {source} would both be written to {p}; give inputs of "
                "different names, or run them with different output directories"
            )
        seen[key] = source
        _check_not_an_input(p, read)
        if p.is_dir():
            raise IsADirectoryError(f"output {p} is a directory, not a file")
        there = _first_existing(p.parent)
        if not there.is_dir():
            raise NotADirectoryError(f"output {p} cannot be written: {there} is a file")
        if p.exists() and not force:
            raise FileExistsError(f"{p} exists; pass --force to replace it")


def _check_not_an_input(out: Path, inputs: list[tuple[str, Path]]) -> None:
    """``ValueError`` if ``out`` is one of ``inputs`` or inside one that is a folder
    (links resolved: ``out`` through a link to an input is that input)."""
    real = out.resolve()
    for what, path in inputs:
        there = path.resolve()
        if real == there:
            raise ValueError(
                f"output {out} is the {what} itself ({path}), which this command reads; "
                "write the output elsewhere (--force replaces outputs, never inputs)"
            )
        if path.is_dir() and real.is_relative_to(there):
            raise ValueError(
                f"output {out} lies inside the {what} {path}, a folder this command reads; "
                "write it elsewhere"
            )


def config_inputs(args) -> list[tuple[str, Path]]:
    """``--config FILE`` as :func:`check_outputs` ``inputs`` (a shipped one by its name
    is no file of the user's)."""
    config = getattr(args, "config", None)
    # a file only: a folder given as --config is named as such by the config reader
    return [("config file", Path(config))] if config and Path(config).is_file() else []


def model_inputs(path, what: str = "model") -> list[tuple[str, Path]]:
    """What ``--model RUN`` reads, as :func:`check_outputs` ``inputs``: a checkpoint file
    and its ``.json`` record, or a run directory's ``checkpoints`` folder and the
    checkpoint files it may hold itself (not the whole run directory: ``evaluate`` writes
    into ``RUN/evaluation`` by default)."""
    if path is None:
        return []
    from ..models import RECORD_FILE, resolve

    shipped = resolve(path)
    if shipped is not None:  # the package's own files
        return [(what, shipped.weights), (what, shipped.folder / RECORD_FILE)]
    p = Path(path)
    if p.is_dir():
        return [(what, p / "checkpoints"), (what, p / "best.safetensors"), (what, p / "best.json")]
    stem = p.name[: -len(p.suffix)] if p.suffix in (".safetensors", ".json") else p.name
    return [(what, p.with_name(stem + ".safetensors")), (what, p.with_name(stem + ".json"))]


# --- numbers --------------------------------------------------------------------------


def int_at_least(lo: int, hi: int | None = None):
    """An argparse ``type``: an integer ``>= lo`` (and ``<= hi`` when given)."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
        if v < lo or (hi is not None and v > hi):
            bound = f">= {lo}" if hi is None else f"from {lo} to {hi}"
            raise argparse.ArgumentTypeError(f"must be an integer {bound}, got {v}")
        return v

    parse.__name__ = f"integer >= {lo}" if hi is None else f"integer in [{lo}, {hi}]"
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


def finite_float(text: str) -> float:
    """An argparse ``type``: a finite number (any sign)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return v


#: The options whose value is a point ``X,Y`` (:func:`point`).
POINT_OPTIONS = frozenset({"--goal", "--start", "--shift"})
_NEGATIVE_POINT = re.compile(r"-[0-9.][^,]*,[^,]*")


def join_negative_points(argv: list[str]) -> list[str]:
    """``--shift -3,2`` as ``--shift=-3,2``: argparse takes a word that starts with "-"
    (and is not a plain negative number) for an option, so a point option followed by a
    negative point is joined to it before parsing."""
    out, words = [], iter(argv)
    for word in words:
        if word == "--":  # what follows is positional as it stands
            out += [word, *words]
            break
        if word in POINT_OPTIONS:
            value = next(words, None)
            if value is not None and _NEGATIVE_POINT.fullmatch(value):
                out.append(f"{word}={value}")
                continue
            out += [word] if value is None else [word, value]
            continue
        out.append(word)
    return out


def point(text: str) -> tuple[float, float]:
    """An argparse ``type``: two finite numbers written ``X,Y`` (``--flag -5,3`` is read
    as ``--flag=-5,3``: :func:`join_negative_points`)."""
    parts = text.split(",")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"must be two numbers X,Y, got {text!r}")
    try:
        return finite_float(parts[0]), finite_float(parts[1])
    except argparse.ArgumentTypeError as e:
        raise argparse.ArgumentTypeError(f"{e} in {text!r}") from None


__all__ = [
    "finite_float",
    "point",
    "add_config",
    "add_device",
    "check_device",
    "check_file_dir",
    "add_force",
    "check_images",
    "check_inputs",
    "check_output_dir",
    "check_outputs",
    "config_inputs",
    "model_inputs",
    "add_data",
    "add_digits",
    "add_model",
    "model_or_default",
    "one_thread",
    "refine_steps",
    "set_refinement",
    "add_no_progress",
    "add_set",
    "int_at_least",
    "join_negative_points",
    "parse_digits",
    "positive_float",
    "reading_image",
    "same_path",
    "warn_flags",
]


def add_refine(p: argparse.ArgumentParser) -> None:
    """``--refine STEPS``: gradient steps that pull each predicted DMP onto the ink of its
    image near the network's output (:mod:`img2dmp.nn.refine`); 0 = the network's output;
    ``--refine-unfamiliar STEPS``: those of the images the model finds unfamiliar; not
    given (None): the model's recommendation, :func:`refine_steps`."""
    steps = {"metavar": "STEPS", "type": int_at_least(0), "default": None}
    p.add_argument(
        "--refine",
        **steps,
        help="refine each predicted DMP on its image with this many gradient steps that "
        "pull it onto the ink near the network's output (0 = the network's output as it "
        f"is); default: what the model recommends: a shipped model's card ({DEFAULT_REFINE} "
        f"for {DEFAULT_MODEL_NAME}), a run's training configuration (its reading section; "
        "0 where it says nothing)",
    )
    p.add_argument(
        "--refine-unfamiliar",
        **steps,
        help="refine the images the model finds unfamiliar (familiarity below its line, "
        "flagged 'unfamiliar') with this many steps instead; default: what the model "
        "recommends (a shipped model's card, img2dmp models shows it; a run's reading) "
        "when --refine is not given, else --refine's steps. Needs a model that carries a "
        "familiarity",
    )


def add_count_views(p: argparse.ArgumentParser) -> None:
    """``--count-views N``: how many views of each image a stroke model reads its stroke
    count from (:attr:`img2dmp.predict.Predictor.count_views`; :func:`set_count_views`)."""
    p.add_argument(
        "--count-views",
        metavar="N",
        type=int_at_least(1, MAX_COUNT_VIEWS),
        default=None,
        help="a stroke model reads each character's stroke count from N views of its image "
        "(the image and N-1 small affine copies, their count probabilities averaged; 1 = "
        "the image alone); default: what the model recommends (a shipped model's card, a "
        f"run's reading), else {DEFAULT_COUNT_VIEWS}",
    )


def set_count_views(args, predictor) -> None:
    """Read ``predictor``'s stroke counts from ``--count-views`` views when given
    (:meth:`~img2dmp.predict.Predictor.count_with`: a ``ValueError`` for a one-DMP model)."""
    if args.count_views is not None:
        predictor.count_with(args.count_views)


def add_dmp_fit_options(add, dims_default: str) -> None:
    """``--dims``, ``--scaling`` and ``--n-kernels`` of the commands that fit DMPs to pen
    paths (``prepare``, ``import``), through the command's own ``add(flag, text,
    shown_default, **kwargs)`` (which words the default and the config field)."""
    add("--dims", "2 = (x, y), 3 = (x, y, pen)", dims_default, type=int, choices=(2, 3))
    add(
        "--scaling",
        "DMP forcing-term scaling",
        "goal-start for d=2, none for d=3",
        choices=("goal-start", "none"),
    )
    add("--n-kernels", "DMP kernels per dimension", type=int_at_least(1), metavar="N")
