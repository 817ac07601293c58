"""The ``img2dmp`` command line: one entry point, one module per subcommand.

Each module in :mod:`img2dmp.commands` defines ``HELP`` (one line), ``add_arguments(parser)``
and ``run(args) -> int``, and stays a thin call into the library. The command's name is
the module's (``_`` written ``-``), or the module's ``NAME`` if it sets one (``import`` is
a Python keyword, so ``img2dmp import`` lives in ``commands/import_data.py``). The command
modules import only the standard library (and the light :mod:`img2dmp.config`,
:mod:`img2dmp.errors`, :mod:`img2dmp.commands._args`) at module level, so that building
the parser (``img2dmp --help``) does not load torch; each ``run`` imports what it needs.

Exit status: 0 done; 2 a usage error or an anticipated failure (bad input, a missing,
unreadable, existing or unwritable file, a directory where a file belongs, a full disk, an
image too large to decode, a run directory in use by another run, a diverged training),
reported as one line ``img2dmp COMMAND: error: ...`` naming the file, field or value on
standard error; 1 a bug (traceback, then a request to report it); 130 interrupted (Ctrl-C,
SIGINT); 143 terminated (SIGTERM: ``kill``, a batch scheduler's time limit, a service
manager), which, like Ctrl-C, stops the command where it is with its clean-ups (no
temporary file is left, a lock is released) and one line ``img2dmp COMMAND: terminated``.

One rule for every command that writes (generate, prepare, import, train, predict,
evaluate, write, preview, demo, export): an existing output is never replaced without
``--force``, and this, like the inputs, is checked before any slow work starts
(:mod:`img2dmp.commands._args`).
Two inputs that would give one output file are refused, naming both. Files are written
atomically (:mod:`img2dmp._files`): a failure or a kill leaves the earlier file whole.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import pkgutil
import re
import shlex
import signal
import sys
import threading
import traceback
import warnings

from . import __version__, commands
from .commands import _args
from .errors import Img2dmpError

#: Failures that are the user's input or the machine's state, not bugs: one line, exit 2.
#: ``ValueError`` covers ``img2dmp.config.ConfigError`` and ``CheckpointError``;
#: ``OSError`` covers missing, existing and unreadable files, a full disk and a run
#: directory in use; PIL's decompression-bomb error (an ``Exception``) is one too.
ANTICIPATED = (ValueError, OSError, Img2dmpError)
#: The longest error line printed.
MAX_LINE_CHARS = 2000


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the command was, as Ctrl-C raises ``KeyboardInterrupt``, so
    that the same clean-ups run (:func:`_sigterm_as_interrupt`)."""


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """SIGTERM stops the command as Ctrl-C does, instead of ending the process on the
    spot without a word (no line, exit status -15, a half-written temporary left).

    A process forked from this one (a worker) that gets SIGTERM dies of it quietly, as
    it would have. Only the main thread may set a handler; elsewhere nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pid = os.getpid()

    def terminate(signum, frame):
        if os.getpid() != pid:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        raise Terminated

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def anticipated(e: BaseException) -> bool:
    """Whether ``e`` is an anticipated failure (:data:`ANTICIPATED`, or PIL's refusal of a
    decompression bomb, looked up only if PIL is loaded: the CLI does not import it)."""
    if isinstance(e, ANTICIPATED):
        return True
    pil = sys.modules.get("PIL.Image")
    bomb = getattr(pil, "DecompressionBombError", None)
    return bomb is not None and isinstance(e, bomb)


class _Parser(argparse.ArgumentParser):
    """A parser whose usage errors are one line (``prog: error: ...``), exit status 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


class _HelpFormatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """Descriptions as written; defaults shown, except for empty ones (None, off, [])."""

    def _get_help_string(self, action: argparse.Action) -> str:
        if action.default is None or action.default is False or action.default == []:
            return action.help or ""
        return super()._get_help_string(action)


def _command_modules():
    """``(command name, module)`` of every command, by module name: the module's ``NAME``
    if it sets one, else its name with ``-`` for ``_``."""
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if not info.name.startswith("_"):
            module = importlib.import_module(f"{commands.__name__}.{info.name}")
            yield getattr(module, "NAME", info.name.replace("_", "-")), module


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="img2dmp",
        description="From a raw image of handwriting to the DMP that wrote it (Pahič et al. "
        "2018).\nEvery command has its own --help.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"img2dmp {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module in _command_modules():
        p = sub.add_parser(
            name,
            help=module.HELP,
            description=module.__doc__,
            formatter_class=_HelpFormatter,
        )
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def describe(e: BaseException) -> str:
    """An anticipated failure as one line: the message, or for a system error the file
    and the reason (``out.safetensors: No space left on device``)."""
    if isinstance(e, OSError) and e.strerror and (e.errno is not None or e.filename):
        files = " -> ".join(str(f) for f in (e.filename, e.filename2) if f is not None)
        msg = f"{files}: {e.strerror}" if files else e.strerror
    else:
        msg = str(e)
    lines = [line.strip() for line in msg.splitlines() if line.strip()]
    line = " ".join(lines) or type(e).__name__
    if len(line) > MAX_LINE_CHARS:  # a message that holds a whole value is cut, its size said
        line = f"{line[: MAX_LINE_CHARS - 40]}... (a message of {len(line):,} characters)"
    return line


@contextlib.contextmanager
def _missing_glyphs_said(prog: str):
    """matplotlib's warnings of a glyph its font lacks (a class named in a script the
    figures' font does not cover; two per label, with source lines) said once, in one
    line, at the end of the command."""
    missing: dict[str, str] = {}
    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        m = re.match(r"Glyph (\d+) \(.+\) missing from font\(s\) (.+)\.$", str(message))
        if m is None:
            return shown(message, category, filename, lineno, file, line)
        missing.setdefault(chr(int(m.group(1))), m.group(2))

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = shown
        if missing:
            fonts = ", ".join(sorted(set(missing.values())))
            print(
                f"{prog}: note: the figures' font ({fonts}) has no glyph for "
                f"{', '.join(missing)}: those characters show as boxes",
                file=sys.stderr,
            )


def main(argv: list[str] | None = None) -> int:
    """Run one command; its exit status (see the module docstring)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        args = build_parser().parse_args(_args.join_negative_points(argv))
    except SystemExit as e:  # --help, --version, or a usage error already printed
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    prog = f"img2dmp {args.command}"
    try:
        with _sigterm_as_interrupt(), _missing_glyphs_said(prog):
            return int(args._run(args) or 0)
    except KeyboardInterrupt as e:
        said = "terminated" if isinstance(e, Terminated) else "interrupted"
        more = f"; {describe(e)}" if e.args else ""  # what a command adds (train: resume)
        print(f"{prog}: {said}{more}", file=sys.stderr)
        return 143 if isinstance(e, Terminated) else 130
    except Exception as e:
        if anticipated(e):
            print(f"{prog}: error: {describe(e)}", file=sys.stderr)
            return 2
        traceback.print_exc()
        print(
            f"{prog}: internal error, a bug in img2dmp; please report it with the traceback "
            f"above and the command line: {shlex.join(['img2dmp', *argv])}",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
