"""The one place that imports pybullet, with a clear message when it is missing."""

from __future__ import annotations

import contextlib
import os
import sys

INSTALL_HINT = (
    "img2dmp.robot needs pybullet, an optional dependency: install it with "
    "`pip install -e '/path/to/img2dmp[robot]'` (or `pip install pybullet==3.2.7`)"
)


def available() -> bool:
    """True if pybullet and pybullet_data can be imported."""
    try:
        require()
    except ImportError:
        return False
    return True


@contextlib.contextmanager
def _c_output_silenced():
    """Standard output and error closed to C code for a moment: pybullet's module
    initialisation prints a build-time banner that would otherwise come before every
    command's own lines (a one-line error would be two lines)."""
    if "pybullet" in sys.modules:
        yield
        return
    saved = []
    try:
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        devnull = os.open(os.devnull, os.O_WRONLY)
        for fd in (1, 2):
            saved.append((fd, os.dup(fd)))
            os.dup2(devnull, fd)
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # no real file descriptors: leave them
        pass
    try:
        yield
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)


def require():
    """Return the modules ``(pybullet, pybullet_data)``; raise ``ImportError`` if missing."""
    try:
        with _c_output_silenced():
            import pybullet
            import pybullet_data
    except ImportError as e:
        raise ImportError(f"{INSTALL_HINT} ({e})") from e
    return pybullet, pybullet_data
