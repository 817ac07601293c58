"""Files written so that a crash never leaves a half-written file that looks valid.

The one atomic writer of img2dmp (temporary file in the same directory, fsync,
``os.replace``), the cleaning of the temporaries a killed writer leaves, the check of an
input file before it is read, the advisory lock of a directory (its lock file opened
without following a link), the one JSON reader of what users give img2dmp, and the file
hash stored with models. No dependencies on the rest of the package but
:mod:`img2dmp.errors`, so every layer (data sets, checkpoints, robot logs) can use it.

A temporary is named ``.NAME.PID.XXXXXXXX.tmp`` beside ``NAME`` (PID: the writing process).
A kill between its creation and the final ``os.replace`` leaves it behind, never ``NAME``
half-written; the first write of a process into a directory removes the temporaries there
whose writer is gone (untouched for :data:`DEAD_WRITER_GRACE_S`) or that are older than
:data:`STALE_TEMPORARY_S`.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import stat
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

from .errors import show

#: A temporary untouched this long (seconds) is abandoned, whoever wrote it.
STALE_TEMPORARY_S = 3600.0
#: A temporary whose writing process is gone is abandoned once untouched this long.
DEAD_WRITER_GRACE_S = 60.0
#: The lock file :func:`lock_directory` holds inside the directory it locks.
LOCK_NAME = ".lock"

_cleaned_dirs: set[str] = set()


def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (the data set hash stored with a model)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _readable(tmp: str) -> None:
    # mkstemp makes 0600 files; give the result the permissions a plain open() would.
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)


# --- temporaries of killed writers ----------------------------------------------------


def _writer_pid(name: str, siblings: set[str]) -> int | None | bool:
    """The writer's pid in a temporary's name ``.NAME.PID.XXXXXXXX.tmp``; None for the
    name of earlier versions, ``.NAME.XXXXXXXX.tmp``, whose ``NAME`` is in ``siblings``;
    False for any other file (never touched)."""
    if not (name.startswith(".") and name.endswith(".tmp")):
        return False
    parts = name[1:-4].split(".")
    if len(parts) < 2 or len(parts[-1]) != 8 or not parts[-1].replace("_", "").isalnum():
        return False
    if len(parts) >= 3 and parts[-2].isdigit():
        return int(parts[-2])
    return None if ".".join(parts[:-1]) in siblings else False


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process (EPERM): alive
        return True
    return True


def clean_stale_temporaries(directory: str | os.PathLike, *, now: float | None = None) -> list:
    """Remove the temporaries in ``directory`` that a killed writer left (see the module
    docstring); the paths removed. Files that are not such temporaries are never touched,
    nor are those of a writer still at work."""
    now = time.time() if now is None else now
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    names = {e.name for e in entries}
    for entry in entries:
        pid = _writer_pid(entry.name, names)
        if pid is False:
            continue
        try:
            st = entry.stat(follow_symlinks=False)
        except OSError:
            continue
        if not stat.S_ISREG(st.st_mode):
            continue
        age = now - st.st_mtime
        dead = pid is not None and not _alive(pid) and age >= DEAD_WRITER_GRACE_S
        if dead or age >= STALE_TEMPORARY_S:
            try:
                os.unlink(entry.path)
            except OSError:
                continue
            removed.append(Path(entry.path))
    return removed


def _clean_once(directory: Path) -> None:
    # Once per process and directory: a directory of many outputs is not listed per file.
    key = os.path.abspath(directory)
    if key not in _cleaned_dirs:
        _cleaned_dirs.add(key)
        clean_stale_temporaries(directory)


# --- writing --------------------------------------------------------------------------


def _about(e: OSError, path: Path) -> OSError:
    """``e`` re-stated about the file being written (not its hidden temporary)."""
    if e.errno is None:
        return e
    return OSError(e.errno, e.strerror or os.strerror(e.errno), str(path))


def _make_parent(path: Path) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except FileExistsError as e:  # a file where the directory belongs
        raise NotADirectoryError(errno.ENOTDIR, "Not a directory", str(path.parent)) from e


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same directory + ``os.replace``.

    A failure (a full disk, no permission) leaves an earlier ``path`` as it was and raises
    an ``OSError`` naming ``path``; a directory at ``path`` is refused.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "Is a directory, not a file", str(path))
    _make_parent(path)
    _clean_once(path.parent)
    try:
        fd, tmp = tempfile.mkstemp(
            prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent
        )
    except OSError as e:
        raise _about(e, path) from e
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        _readable(tmp)
        os.replace(tmp, path)
    except BaseException as e:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(e, OSError):
            raise _about(e, path) from e
        raise


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def new_figure(**kwargs):
    """A matplotlib ``Figure(**kwargs)`` on an Agg canvas of its own, outside pyplot: the
    one way the package starts a figure, so that drawing never switches the caller's
    backend nor adds to pyplot's figures (a notebook shows one returned as a cell's
    value; :func:`save_figure` writes it)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(**kwargs)
    FigureCanvasAgg(fig)  # text sizes are measured on it (legend bands, tight layouts)
    return fig


def save_figure(fig, path: str | os.PathLike, *, dpi: int = 100) -> Path:
    """The one figure writer: a matplotlib figure to a PNG file, atomically, then closed.

    ``bbox_inches="tight"`` grows the canvas to whatever the figure draws, so titles,
    legends and labels are never cut at its edge. A pyplot figure given here is closed in
    pyplot after writing (the package's own come from :func:`new_figure`).
    """
    import io
    import sys

    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight", pad_inches=0.05)
    finally:
        pyplot = sys.modules.get("matplotlib.pyplot")  # imported by the caller, if at all
        if pyplot is not None:
            pyplot.close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return Path(path)


# --- reading --------------------------------------------------------------------------


def check_stem(stem, what: str = "stem") -> str:
    """``stem``, the start of the names of files written into a folder, if it is a plain
    file name (no folder in it: ``"../x"`` wrote outside the folder); else ``ValueError``."""
    if (not isinstance(stem, str) or not stem or stem in (".", "..") or "\0" in stem
            or os.sep in stem or (os.altsep and os.altsep in stem)):  # fmt: skip
        raise ValueError(f"{what} must be a file name without a folder, got {stem!r}")
    return stem


def check_readable(path: str | os.PathLike, what: str = "file") -> Path:
    """``path`` if it is a regular file this process can read; otherwise an ``OSError``
    whose message names ``what``, the file and the reason (no such file, a directory,
    not a regular file, permission denied), before any slow work starts."""
    p = Path(path)
    if "\0" in str(p):  # the system's calls refuse it with a bare "embedded null byte"
        raise ValueError(f"{what} {str(p)!r}: the name holds a NUL byte (\\x00)")
    try:
        st = p.stat()
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} {p} does not exist") from None
    except PermissionError:
        raise PermissionError(f"{what} {p} cannot be reached: permission denied") from None
    except OSError as e:
        raise OSError(f"{what} {p} cannot be read: {e.strerror or e}") from None
    if stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(f"{what} {p} is a directory, not a file")
    if not stat.S_ISREG(st.st_mode):
        raise OSError(f"{what} {p} is not a regular file")
    try:
        with open(p, "rb") as f:
            f.read(1)
    except PermissionError:
        raise PermissionError(f"{what} {p} cannot be read: permission denied") from None
    except OSError as e:
        raise OSError(f"{what} {p} cannot be read: {e.strerror or e}") from None
    return p


# --- locking --------------------------------------------------------------------------


def open_lock_file(directory: str | os.PathLike, what: str = "directory") -> int:
    """A descriptor (read and write) of ``directory/.lock``, created if missing.

    The one way img2dmp opens a lock file. It is written to (its holder's pid), so it
    must be the directory's own file: a symbolic link there (even a dangling one, which
    ``O_CREAT`` would follow to create a file elsewhere) is refused, and so is anything
    that is not a regular file or that has another name too (a hard link: truncating it
    would truncate the other file). ``OSError`` naming the lock file otherwise.
    """
    lock = Path(directory) / LOCK_NAME
    flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    # O_NONBLOCK: a FIFO planted at the name must not hang the open.
    flags |= getattr(os, "O_NONBLOCK", 0)
    try:
        dir_fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError as e:
        raise _about(e, Path(directory)) from e
    try:
        fd = os.open(LOCK_NAME, flags, 0o666, dir_fd=dir_fd)
    except OSError as e:
        if e.errno == errno.ELOOP or os.path.islink(lock):
            raise OSError(
                errno.ELOOP,
                f"lock file {lock} of {what} {directory} is a symbolic link; img2dmp never "
                "follows one there (remove it)",
            ) from None
        raise _about(e, lock) from e
    finally:
        os.close(dir_fd)
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
        os.close(fd)
        kind = "not a regular file" if not stat.S_ISREG(st.st_mode) else "a hard link"
        raise OSError(
            errno.EPERM,
            f"lock file {lock} of {what} {directory} is {kind}; img2dmp writes only its "
            "own lock file (remove it)",
        )
    return fd


class DirectoryBusy(OSError):
    """Another process holds the lock of a directory (:func:`lock_directory`)."""


@contextmanager
def lock_directory(directory: str | os.PathLike, what: str = "directory"):
    """Hold an advisory lock (``fcntl.flock`` on ``directory/.lock``) for the block.

    The lock file is opened by :func:`open_lock_file`: a link or anything but a regular
    file of its own at that name is refused, naming it.

    The directory is created if needed (and removed again if the block left nothing else
    in it). A second holder, in this process or another, gets :class:`DirectoryBusy` at
    once, naming the directory and the holder's pid; the lock goes with its holder (the
    end of the block, an exception, a kill). The lock file itself stays: removing it
    while others may have it open would let two processes lock two different files.
    Without ``fcntl`` (not a POSIX system) the block runs unlocked.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - POSIX only
        yield None
        return
    d = Path(directory)
    if d.exists() and not d.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, "Not a directory", str(d))
    created = not d.exists()
    d.mkdir(parents=True, exist_ok=True)
    lock = d / LOCK_NAME
    fd = open_lock_file(d, what)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode("ascii", "replace").strip()
            by = f" (process {holder})" if holder.isdigit() else ""
            raise DirectoryBusy(
                f"{what} {d} is in use by another img2dmp process{by}; wait for it to end "
                "or choose another directory"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
        try:
            yield lock
        finally:
            if created:
                _remove_if_only_lock(d, lock)
    finally:
        os.close(fd)  # releases the lock


def _remove_if_only_lock(d: Path, lock: Path) -> None:
    try:
        if os.listdir(d) == [LOCK_NAME]:
            lock.unlink()
            d.rmdir()
    except OSError:
        pass


__all__ = [
    "DEAD_WRITER_GRACE_S",
    "LOCK_NAME",
    "STALE_TEMPORARY_S",
    "DirectoryBusy",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_readable",
    "clean_stale_temporaries",
    "file_digest",
    "lock_directory",
    "open_lock_file",
    "parse_json",
    "check_stem",
    "new_figure",
    "save_figure",
]


#: The most digits of a whole number in a JSON text (Python refuses more than 4,300 when
#: converting; no number img2dmp reads needs more than a few dozen).
MAX_JSON_DIGITS = 100


def _refuse_duplicates(pairs: list) -> dict:
    out = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"key {show(key)} appears twice in one object; give each key once")
        out[key] = value
    return out


def _bounded_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > MAX_JSON_DIGITS:
        raise ValueError(
            f"a whole number of {digits:,} digits is too long (at most {MAX_JSON_DIGITS})"
        )
    return int(text)


def parse_json(data: bytes | str, where: str, *, allow_nan: bool = True):
    """The JSON value in ``data`` (bytes are read as UTF-8, with or without a BOM).

    The package's one JSON reader for what users give it (DMP files, data-set metadata,
    recordings, imported paths, web requests, checkpoint records): every failure is a
    ``ValueError`` of one line starting with ``where`` (a file, a field, a request part).
    A key given twice in one object is refused (Python's ``json`` would keep the last
    silently), and so is a whole number of more than :data:`MAX_JSON_DIGITS` digits.
    ``allow_nan=False`` also refuses the ``NaN`` and ``Infinity`` literals that Python's
    ``json`` accepts but JSON does not.
    """
    if isinstance(data, bytes):
        try:
            data = data.decode("utf-8-sig")
        except UnicodeDecodeError as e:
            raise ValueError(f"{where}: not a UTF-8 text file (byte {e.start})") from None

    def refuse(name: str):
        raise ValueError(f"{name} is not a JSON number; give a finite number")

    hooks = {"object_pairs_hook": _refuse_duplicates, "parse_int": _bounded_int}
    if not allow_nan:
        hooks["parse_constant"] = refuse
    try:
        return json.loads(data, **hooks)
    except json.JSONDecodeError as e:
        raise ValueError(f"{where}: not valid JSON ({e})") from None
    except RecursionError:
        raise ValueError(f"{where}: JSON nested too deeply") from None
    except ValueError as e:  # the hooks' refusals
        raise ValueError(f"{where}: {e}") from None
