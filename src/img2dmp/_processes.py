"""Worker processes: how many are worth starting, and leaving Ctrl-C to their parent.

A terminal sends Ctrl-C (SIGINT) to every process of its foreground group. Workers that
are still importing torch (``generate``'s pool, ``serve``'s robot runs) would each print a
``KeyboardInterrupt`` traceback of dozens of lines before the command's one line
"interrupted"; their parent handles the interrupt and ends them, so they ignore it.
Standard library only, like :mod:`img2dmp._files`.
"""

from __future__ import annotations

import os
import signal
import threading
from contextlib import contextmanager


def machine_cores() -> int:
    """The cores this process may run on (its CPU affinity): the most threads or worker
    processes worth starting (torch starts one thread per count asked for: 100,000 of
    them crash the process)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        return os.cpu_count() or 1


@contextmanager
def children_ignore_interrupts():
    """Processes started in the block ignore SIGINT for their whole life.

    An ignored signal stays ignored across ``fork`` and ``exec``, and a Python started
    with SIGINT ignored installs no ``KeyboardInterrupt`` handler, so this works for
    "spawn" children too, from their first instruction. SIGINT is blocked meanwhile: a
    Ctrl-C in the block reaches this process when the block ends (Linux keeps a blocked
    signal pending even while it is ignored). Only the main thread may change a signal's
    handler; in another thread the block changes nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


__all__ = ["children_ignore_interrupts", "machine_cores"]
