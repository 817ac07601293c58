"""The tabulated unit responses of the DMP transformation system, without torch.

With tau fixed, the transformation system (eqs. 3-4) is linear and time-invariant in the
normalised time ``s = t / tau``, so its solution is

    y(s) = g + (y0 - g) * a(s) + S * sum_k w_k R_k(s)

with ``a`` the free response to a unit initial offset (``a(0) = 1, a'(0) = 0``) and
``R_k`` the response to the k-th kernel ``phi_k(x(s))`` from rest, each solving
``r'' = -alpha_z beta_z r - alpha_z r' + drive(s)``. This module solves those N + 1
functions once per configuration on a uniform grid of s (values and s-derivatives),
keeps the table on disk, and turns it into the cubic Hermite pieces that both
rollouts interpolate: :mod:`img2dmp.dmp.rollout` (torch) and
:mod:`img2dmp.dmp._numpy_rollout` (NumPy, for a prediction that never imports torch).
Neither torch nor scipy is imported here.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import math
import os
import tempfile

import numpy as np

from .basis import basis_functions, kernel_centres, kernel_widths, negligible
from .config import NODES_PER_SCALE, TABLE_TAIL, DMPConfig, response_grid

# Grid steps whose forcing is integrated at once (bounds the drive's memory).
_CHUNK = 8192
# Flush negligible table entries to 0 (see _cubic_pieces). Only a test turns it off,
# to show what the flush prevents.
_FLUSH = True


@functools.lru_cache(maxsize=16)
def _response_table_f64(config: DMPConfig) -> tuple[float, float, np.ndarray]:
    """Solve the N + 1 unit responses on a uniform grid of s.

    Returns ``(h, s_max, table)`` where ``table`` is ``[G, 2, N + 1]``: values and
    s-derivatives of ``[a, R_1, ..., R_N]`` at ``s = 0, h, 2h, ...``. Solved once per
    configuration (:func:`_solve_responses`, a few milliseconds) and kept on disk
    (:func:`_table_cache_file`).
    """
    n = config.n_kernels
    h, _, steps = response_grid(n, config.alpha_z, config.beta, config.alpha_x)
    g = int(steps)  # bounded by DMPConfig (MAX_TABLE_ENTRIES)
    s_grid = np.arange(g) * h
    cache = _table_cache_file(config)
    table = _load_table(cache, (g, 2, n + 1))
    if table is None:
        table = _solve_responses(config, s_grid)
        _save_table(cache, table)
    return h, float(s_grid[-1]), table


def _cubic_pieces(config: DMPConfig, dtype) -> tuple[float, float, np.ndarray]:
    """Cubic Hermite pieces of the unit responses, as float64 polynomial coefficients.

    Returns ``(h, s_max, poly)`` with ``poly`` of shape ``[G - 1, C, 4]`` (C = N + 1
    columns ``[a, R_1..R_N]``): on ``[s_i, s_i + h]`` column c is
    ``sum_k poly[i, c, k] * u**k`` with ``u = (s - s_i) / h``, i.e. with values ``v``
    and scaled derivatives ``d = h v'`` at the two nodes

        p(u) = v0 + d0 u + (3 (v1 - v0) - 2 d0 - d1) u^2 + (2 (v0 - v1) + d0 + d1) u^3,

    which matches both ends' values and derivatives (the interpolant is C^1).

    Entries below ``negligible(dtype)`` (a torch or NumPy dtype: 1.1e-19 in float32,
    1.5e-154 in float64) are exactly 0: the responses of far-away kernels and the
    decayed tails reach 1e-300 and below, which a cast to float32 would turn into
    subnormal numbers, and arithmetic on those is very slow on many x86 CPUs. The
    flushed entries are far below the solution's own rounding (1e-16), so no accuracy is
    lost. A new array on every call (the callers cache their own form).
    """
    h, s_max, table = _response_table_f64(config)
    v, dv = table[:, 0], h * table[:, 1]  # [G, C]
    v0, v1, d0, d1 = v[:-1], v[1:], dv[:-1], dv[1:]
    poly = np.stack([v0, d0, 3 * (v1 - v0) - 2 * d0 - d1, 2 * (v0 - v1) + d0 + d1], -1)
    if _FLUSH:
        poly[np.abs(poly) < negligible(dtype)] = 0.0
    return h, s_max, poly  # [G-1, C, 4]


#: Gauss-Legendre nodes per grid step for the forcing's integral (exact for polynomials
#: of degree 2 m - 1; the kernels vary over 16 steps, so the error is far below 1e-16).
_QUADRATURE_NODES = 8


def _expm2(m: np.ndarray) -> np.ndarray:
    """``exp(m)`` of 2 x 2 matrices ``[..., 2, 2]``: scaling and squaring of a Taylor series
    (to machine precision for the norms of a DMP's steps; no scipy.linalg import)."""
    norm = float(np.abs(m).sum(axis=-1).max()) if m.size else 0.0
    k = max(0, int(math.ceil(math.log2(norm))) + 1) if norm > 0.5 else 0
    a = m / 2.0**k
    out = term = np.broadcast_to(np.eye(2), m.shape).copy()
    for j in range(1, 20):
        term = term @ a / j
        out = out + term
    for _ in range(k):
        out = out @ out
    return out


def _solve_responses(config: DMPConfig, s_grid: np.ndarray) -> np.ndarray:
    """``[G, 2, N + 1]`` values and derivatives of the unit responses on the uniform grid
    ``s_grid`` (``s_i = i h``), by the exact step of the linear system.

    Every response solves ``u' = A u + (0, f(s))`` with ``u = (r, r')`` and
    ``A = [[0, 1], [-alpha_z beta_z, -alpha_z]]`` (f = 0 for the free response, which
    starts at ``u = (1, 0)``; f = the k-th kernel ``phi_k(x(s))`` for ``R_k``, from rest), so

        u(s + h) = e^{A h} u(s) + int_0^h e^{A (h - r)} (0, f(s + r)) dr

    exactly; the integral is taken by Gauss-Legendre quadrature on each step. The result
    agrees with scipy's DOP853 at ``rtol = 1e-12`` to about 1e-13 (tests/test_dmp.py) and
    takes a few milliseconds instead of about a second and a half (with its import).
    """
    n, az, bz, ax = config.n_kernels, config.alpha_z, config.beta, config.alpha_x
    c, hw = kernel_centres(config), kernel_widths(config)
    g = len(s_grid)
    h = float(s_grid[1] - s_grid[0]) if g > 1 else 1.0
    a = np.array([[0.0, 1.0], [-az * bz, -az]])
    nodes, weights = np.polynomial.legendre.leggauss(_QUADRATURE_NODES)
    r = 0.5 * h * (nodes + 1.0)  # [m], in [0, h]
    step = _expm2(a * h)  # [2, 2]
    kernel = _expm2(a * (h - r)[:, None, None])[:, :, 1] * (0.5 * h * weights)[:, None]  # [m, 2]
    push = np.empty((max(g - 1, 0), 2, n))  # [G - 1, 2, N]: each step's forcing
    for i in range(0, g - 1, _CHUNK):  # in pieces: the drive is m times the table's size
        s = s_grid[i : min(i + _CHUNK, g - 1), None] + r  # [<=CHUNK, m]: quadrature points
        drive = basis_functions(np.exp(-ax * s), c, hw)  # [<=CHUNK, m, N]
        push[i : i + len(s)] = np.einsum("jr,ijk->irk", kernel, drive)
    out = np.zeros((g, 2, n + 1))
    out[0, 0, 0] = 1.0  # a(0) = 1: unit initial offset; every R_k starts at rest
    u = out[0].copy()  # [2, N + 1]
    for i in range(g - 1):  # a stable linear recurrence: rounding does not grow
        u = step @ u
        u[:, 1:] += push[i]
        out[i + 1] = u
    return out  # [G, 2, N + 1]


# The files whose code decides the table's numbers: a change to any makes a new cache.
_TABLE_CODE = ("_table.py", "basis.py", "config.py")
# The cache folder keeps at most this many tables and bytes, the least recently used
# going first: DMP files, data sets and the web API may bring any constants, each set its
# own table (up to 128 MB: MAX_TABLE_ENTRIES).
_CACHE_FILES = 64
_CACHE_BYTES = 512 * 2**20


def _table_cache_file(config: DMPConfig) -> str | None:
    """Where the table of ``config`` is kept: named by a hash of the constants and of
    the code that computes it (this file, basis.py and config.py), so that a change of any
    makes a new one. In ``__pycache__`` next to this file (as numba's cache), else in
    ``$XDG_CACHE_HOME/img2dmp`` (``~/.cache/img2dmp``); None when neither is writable
    or ``IMG2DMP_NO_TABLE_CACHE`` is set."""
    if os.environ.get("IMG2DMP_NO_TABLE_CACHE"):
        return None
    here = os.path.dirname(os.path.abspath(__file__))
    constants = (config.n_kernels, config.alpha_z, config.beta, config.alpha_x)
    constants += (config.width_factor, NODES_PER_SCALE, TABLE_TAIL)
    code = hashlib.sha1()
    try:
        for name in _TABLE_CODE:
            with open(os.path.join(here, name), "rb") as f:
                code.update(f.read())
    except OSError:  # pragma: no cover - installed without sources
        return None
    name = f"dmp_responses_{hashlib.sha1(repr(constants).encode()).hexdigest()[:12]}"
    name += f"_{code.hexdigest()[:12]}.npy"  # the other code's files go when this is saved
    user = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    for folder in (os.path.join(here, "__pycache__"), os.path.join(user, "img2dmp")):
        try:
            os.makedirs(folder, exist_ok=True)
        except OSError:
            continue
        if os.access(folder, os.W_OK):
            return os.path.join(folder, name)
    return None


def _load_table(path: str | None, shape: tuple) -> np.ndarray | None:
    """The cached table, or None if absent, unreadable or not what was expected."""
    if path is None:
        return None
    try:
        table = np.load(path, allow_pickle=False)
    except (OSError, ValueError):
        return None
    ok = table.shape == shape and table.dtype == np.float64 and np.isfinite(table).all()
    if ok:
        with contextlib.suppress(OSError):
            os.utime(path)  # used: the last to go when the cache is trimmed
    return table if ok else None


def _save_table(path: str | None, table: np.ndarray) -> None:
    """Write atomically (a temporary file renamed), so that readers never see half of it."""
    if path is None:
        return
    folder, name = os.path.split(path)
    tmp = None
    try:
        # mkstemp creates a new file (O_EXCL): a link planted at a predictable temporary
        # name in a shared cache folder is never followed.
        fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=folder or ".")
        with os.fdopen(fd, "wb") as f:
            np.save(f, table, allow_pickle=False)
        os.replace(tmp, path)
    except OSError:  # a read-only or full disk: solve again next time
        with contextlib.suppress(OSError, TypeError):
            os.remove(tmp)
        return
    # Tables of these constants made by an earlier version of the code are stale.
    stale, sep, _ = name.rpartition("_")  # "dmp_responses_<constants>" "_" "<code>.npy"
    for other in os.listdir(folder) if sep else ():
        if other.startswith(stale + sep) and other.endswith(".npy") and other != name:
            with contextlib.suppress(OSError):
                os.remove(os.path.join(folder, other))
    _trim_cache(folder, keep=name)


def _trim_cache(folder: str, keep: str) -> None:
    """Remove the least recently used tables of ``folder`` beyond :data:`_CACHE_FILES`
    files or :data:`_CACHE_BYTES` bytes (never ``keep``, the one just written)."""
    tables = []
    with contextlib.suppress(OSError):
        for entry in os.scandir(folder):
            if entry.name.startswith("dmp_responses_") and entry.name.endswith(".npy"):
                with contextlib.suppress(OSError):
                    st = entry.stat()
                    tables.append((entry.name == keep, st.st_mtime, st.st_size, entry.path))
    tables.sort(reverse=True)  # the one just written, then the most recently used
    total = 0
    for k, (_, _, size, path) in enumerate(tables):
        total += size
        if k >= 1 and (k >= _CACHE_FILES or total > _CACHE_BYTES):
            with contextlib.suppress(OSError):
                os.remove(path)
