"""What a benchmark ran on: CPU model, cores, threads, load; and a busy neighbour process.

Shared by the scripts in ``benchmarks/``: timings on a shared machine mean little without
the load they were taken under.
"""

from __future__ import annotations

import contextlib
import os
import platform
import subprocess
import sys


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what :mod:`platform` knows."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def cpu_flags() -> str:
    """The widest vector extension the CPU reports (avx512f, avx2, ...), or ''."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    return next((v for v in ("avx512f", "avx2", "avx", "neon") if v in flags), "")
    except OSError:
        pass
    return ""


def cores() -> int:
    """CPUs this process may run on (its affinity set), else ``os.cpu_count()``."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def load_average() -> str:
    """``"1.23 1.10 0.95"``: the 1, 5 and 15-minute load averages ('n/a' if unknown)."""
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except (AttributeError, OSError):
        return "n/a"


def threads() -> str:
    """torch's intra-op threads and numba's thread limit, as one phrase."""
    parts, torch_threads = [], None
    try:
        import torch

        torch_threads = torch.get_num_threads()
        parts.append(f"torch threads {torch_threads}")
    except ImportError:
        pass
    try:
        import numba

        limit = numba.config.NUMBA_NUM_THREADS
        # Starting numba's pool can change the OpenMP thread count torch shares: keep it.
        parts.append(f"numba threads {numba.get_num_threads()} (of {limit})")
        if torch_threads is not None and torch.get_num_threads() != torch_threads:
            torch.set_num_threads(torch_threads)
    except ImportError:
        pass
    return ", ".join(parts) or "no torch, no numba"


def describe() -> str:
    """One line: CPU model, vector extension, cores, threads and the load averages."""
    flags = cpu_flags()
    return (
        f"CPU: {cpu_model()}{f' ({flags})' if flags else ''}, {cores()} cores; "
        f"{threads()}; load average {load_average()} (1/5/15 min)"
    )


_BUSY_LOOP = """
import os, sys, time
cpu = int(sys.argv[1])
if cpu >= 0 and hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {cpu})
end = time.monotonic() + float(sys.argv[2])
while time.monotonic() < end:
    pass
"""


@contextlib.contextmanager
def busy_neighbour(max_seconds: float = 600.0, enabled: bool = True):
    """A CPU-bound process on one core (the last one this process may use) while inside.

    It stops by itself after ``max_seconds`` and is killed on leaving the block, so a
    crashed benchmark cannot leave it running. Yields a short description (or None).
    """
    if not enabled:
        yield None
        return
    try:
        cpu = max(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpu = -1
    proc = subprocess.Popen([sys.executable, "-c", _BUSY_LOOP, str(cpu), str(max_seconds)])
    try:
        yield f"a busy-loop process (pid {proc.pid}) on CPU {cpu if cpu >= 0 else '?'}"
    finally:
        proc.kill()
        proc.wait()
