"""Fused CPU kernels (numba) for the forward and backward pass of the fast rollout.

One loop over every (sample, time stamp) does the whole rollout of
:mod:`img2dmp.dmp.rollout`: locate the cubic piece of the response table, evaluate the
N + 1 unit responses there, and combine them with that sample's coefficients. The
backward loop evaluates the responses again and accumulates the gradients of w, g and
y0 from them, and that of tau from the table's derivative at the same place.

The maths is that of :class:`img2dmp.dmp.rollout._PiecewiseCombination` (the two paths
are tested against each other and by gradcheck). The table has the layout
``tab[piece, power, column]``, its columns padded with zeros to a multiple of 16, so
that the inner loops run over contiguous columns without a scalar remainder, and it
starts on a cache line (:func:`piece_table`), so that no vector load of it straddles
two. NaN in ``t`` or ``tau`` gives NaN positions, as in the torch path.

The kernels are compiled per (table width, number of dimensions, serial or parallel)
and dtype; the parallel ones spread the samples over numba's threads (OpenMP, the same
runtime torch uses). Compiled code is cached on disk (next to this file, or in numba's
user cache when that is not writable): the first call on a fresh machine compiles for
about 8 s per dtype, later processes load it in well under a second.

Numba is a dependency, but the package keeps working without it: :func:`available`
says whether it imported, and the rollout falls back to the torch path. It is imported
on the first call of :func:`available` (about 0.15 s), not with this module, so that a
process that never runs the kernels (a one-image prediction) does not pay for it.
"""

from __future__ import annotations

import functools
import importlib
import os
import threading

import numpy as np

numba = None  # the module, once available() has imported it
_numba_tried = False


# Reassociation lets LLVM vectorise the sums over the table's columns; no "nnan"/"ninf",
# so NaN inputs still propagate (through the comparisons in _locate_row).
_FASTMATH = {"reassoc", "contract"}


def _jit(fn, parallel: bool = False):
    if numba is None:  # pragma: no cover
        return fn
    opts = dict(fastmath=_FASTMATH, nogil=True, error_model="numpy", parallel=parallel)
    try:
        return numba.njit(cache=True, **opts)(fn)
    except RuntimeError:  # pragma: no cover - no writable cache location
        return numba.njit(cache=False, **opts)(fn)


def _locate_row(t, b, inv_tau, inv_h, s_max, one, pieces, coords):
    """Piece index and local coordinate in [0, 1] of every time stamp of sample ``b``.

    ``s = t / tau`` is clamped to [0, s_max]; past the last node the last piece is
    extended (its coordinate may then exceed 1 by rounding). A NaN ``s`` keeps a NaN
    coordinate, in a valid piece, so that it gives NaN positions. One branch-free pass
    over the row, which LLVM vectorises; the loops that use the result then start their
    table loads without waiting on a division, a rounding and a conversion per stamp
    (about a quarter of the forward pass's time when they were done in place).
    """
    zero = one - one
    # n_pieces - 1 in the table's dtype (s_max / h is a whole number of pieces).
    last = np.floor(s_max * inv_h + one / (one + one)) - one
    for i in range(t.shape[1]):
        q = t[b, i] * inv_tau
        q = zero if q < zero else q
        q = s_max if q > s_max else q
        q = q * inv_h
        fl = np.floor(q)
        fl = fl if fl < last else last  # NaN goes to the last piece
        coords[i] = q - fl
        pieces[i] = int(fl)


def _cubic(tab, p, c, u):
    """Column ``c`` of piece ``p`` at local coordinate ``u`` (Horner)."""
    return tab[p, 0, c] + u * (tab[p, 1, c] + u * (tab[p, 2, c] + u * tab[p, 3, c]))


def _cubic_and_slope(tab, p, c, u):
    """Column ``c`` of piece ``p`` at ``u`` and its derivative in ``u``, from one set of
    loads (the same arithmetic as :func:`_cubic` for the value)."""
    r1 = tab[p, 1, c]
    r2 = tab[p, 2, c]
    r3 = tab[p, 3, c]
    return tab[p, 0, c] + u * (r1 + u * (r2 + u * r3)), r1 + u * (r2 + r2 + u * (r3 + r3 + r3))


def _gy_pair(gy, b, i, jp, zero):
    """The output gradients of dimensions ``2 jp`` and ``2 jp + 1`` at stamp ``i``
    (``zero`` for a dimension past the last)."""
    return gy[b, i, 2 * jp], gy[b, i, 2 * jp + 1] if 2 * jp + 1 < gy.shape[2] else zero


def _inside(s, s_max, g_s, zero):
    """``g_s`` where ``0 < s < s_max``, else exactly 0: the clamp of ``s`` to the table
    has no time derivative (NaN ``s``: outside)."""
    return g_s if s > zero and s < s_max else zero


def _finish_gradients(b, gc, gy, w, g, y0, scaled, one, gw, gg, gy0):
    """The gradients of sample ``b``'s w, g and y0 from those of its coefficients ``gc``."""
    n_t, n_k, d = gy.shape[1], w.shape[1], w.shape[2]
    zero = one - one
    for j in range(d):
        sc = g[b, j] - y0[b, j] if scaled else one
        through_scale = zero
        g_sum = zero
        for i in range(n_t):
            g_sum += gy[b, i, j]
        for k in range(n_k):
            gw[b, k, j] = gc[j, k + 1] * sc
            if scaled:  # S = g - y0 passes the weights' gradient on to g and y0
                through_scale += gc[j, k + 1] * w[b, k, j]
        gg[b, j] = g_sum - gc[j, 0] + through_scale
        gy0[b, j] = gc[j, 0] - through_scale


def _coefficients(b, w, g, y0, scaled, coef, one):
    """This sample's coefficients of the table's columns: ``[y0 - g, S * w_1, ...]``.

    ``coef`` has an even number of rows (dimensions are processed in pairs); a padding
    row stays zero.
    """
    n_k, d = w.shape[1], w.shape[2]
    for j in range(d):
        sc = g[b, j] - y0[b, j] if scaled else one
        coef[j, 0] = y0[b, j] - g[b, j]
        for k in range(n_k):
            coef[j, k + 1] = sc * w[b, k, j]


def _build(n_columns: int, n_dims: int, parallel: bool):
    """Forward and backward kernels for tables of ``n_columns`` columns and ``n_dims`` dims.

    Both counts are compile-time constants of the closures: LLVM then vectorises the
    column loops without a scalar remainder, unrolls the loop over the pairs of
    dimensions and can tell the rows of the small work arrays apart, which together
    halve the time of the generic loops.

    Returns ``(forward, backward)``. Nothing of the batch's size passes from one to the
    other: the backward pass evaluates the unit responses again, in the loop that also
    needs their time derivative. (Keeping them from the forward pass, ``[B, T, 32]``,
    was no faster in float32 and 1.2x slower in float64, for 5-10 MB of memory traffic.)
    """
    n_c, d = n_columns, n_dims
    n_pairs = (d + 1) // 2
    # The loop over samples. Being a closure variable, it also keeps the on-disk cache
    # entries of the serial and the parallel kernels apart.
    samples = numba.prange if parallel else range

    def forward(t, tau, w, g, y0, tab, inv_h, s_max, one, scaled, out):
        """``out[b, i, j] = y_j(t[b, i])`` of DMP ``b``.

        t [B, T], tau [B], w [B, N, d], g / y0 [B, d], tab [G, 4, n_c] (columns past
        N + 1 are zero), out [B, T, d]. ``inv_h``, ``s_max`` and ``one`` are scalars of
        the table's dtype, so every float stays in that dtype (a Python literal would
        promote float32 code to float64). Dimensions go in pairs through one loop over
        the columns, vectorised with two accumulators per stamp; the stamps go in
        pairs too (an odd last one paired with itself), so that each coefficient
        loaded serves two of them.
        """
        n_b, n_t = t.shape
        zero = one - one
        coefs = np.zeros((n_b, 2 * n_pairs, n_c), dtype=tab.dtype)
        for b in samples(n_b):
            coef = coefs[b]
            _coefficients(b, w, g, y0, scaled, coef, one)
            # Small per-sample buffers: one [B, T] array would be large enough for
            # malloc to map fresh (page-faulting) memory on every call.
            pieces = np.empty(n_t, dtype=np.int64)
            coords = np.empty(n_t, dtype=tab.dtype)
            _locate_row(t, b, one / tau[b], inv_h, s_max, one, pieces, coords)
            for i in range(0, n_t, 2):
                i2 = min(i + 1, n_t - 1)
                p, u, p2, u2 = pieces[i], coords[i], pieces[i2], coords[i2]
                for jp in range(n_pairs):
                    acc_a, acc_b, acc_a2, acc_b2 = zero, zero, zero, zero
                    for c in range(n_c):
                        v = _cubic(tab, p, c, u)
                        v2 = _cubic(tab, p2, c, u2)
                        ca, cb = coef[2 * jp, c], coef[2 * jp + 1, c]
                        acc_a += ca * v
                        acc_b += cb * v
                        acc_a2 += ca * v2
                        acc_b2 += cb * v2
                    out[b, i, 2 * jp] = g[b, 2 * jp] + acc_a
                    out[b, i2, 2 * jp] = g[b, 2 * jp] + acc_a2
                    if 2 * jp + 1 < d:
                        out[b, i, 2 * jp + 1] = g[b, 2 * jp + 1] + acc_b
                        out[b, i2, 2 * jp + 1] = g[b, 2 * jp + 1] + acc_b2

    def backward(gy, t, tau, w, g, y0, tab, inv_h, s_max, one, scaled, gw, gtau, gg, gy0, want_s):
        """Gradients of ``sum(gy * y)`` for w, tau, g and y0, written into gw ... gy0.

        ``want_s`` skips the time derivative (and gtau) when tau needs no gradient.
        Stamps in pairs as in ``forward``: the second of a pair with itself has no
        weight.
        """
        n_b, n_t = t.shape
        zero = one - one
        coefs = np.zeros((n_b, 2 * n_pairs, n_c), dtype=tab.dtype)
        gcs = np.zeros((n_b, 2 * n_pairs, n_c), dtype=tab.dtype)  # gradient of coefs
        for b in samples(n_b):
            coef, gc = coefs[b], gcs[b]
            _coefficients(b, w, g, y0, scaled, coef, one)
            inv_tau = one / tau[b]
            pieces = np.empty(n_t, dtype=np.int64)
            coords = np.empty(n_t, dtype=tab.dtype)
            _locate_row(t, b, inv_tau, inv_h, s_max, one, pieces, coords)
            g_tau = zero
            for i in range(0, n_t, 2):
                i2 = min(i + 1, n_t - 1)
                p, u, p2, u2 = pieces[i], coords[i], pieces[i2], coords[i2]
                g_s, g_s2 = zero, zero
                for jp in range(n_pairs):
                    ga, gb = _gy_pair(gy, b, i, jp, zero)
                    ga2, gb2 = _gy_pair(gy, b, i2, jp, zero) if i2 > i else (zero, zero)
                    if want_s:  # responses and their derivatives from the same loads
                        acc, acc2 = zero, zero
                        for c in range(n_c):
                            v, dv = _cubic_and_slope(tab, p, c, u)
                            v2, dv2 = _cubic_and_slope(tab, p2, c, u2)
                            gc[2 * jp, c] += ga * v + ga2 * v2
                            gc[2 * jp + 1, c] += gb * v + gb2 * v2
                            ca, cb = coef[2 * jp, c], coef[2 * jp + 1, c]
                            acc += (ga * ca + gb * cb) * dv
                            acc2 += (ga2 * ca + gb2 * cb) * dv2
                        g_s += acc
                        g_s2 += acc2
                    else:
                        for c in range(n_c):
                            v = _cubic(tab, p, c, u)
                            v2 = _cubic(tab, p2, c, u2)
                            gc[2 * jp, c] += ga * v + ga2 * v2
                            gc[2 * jp + 1, c] += gb * v + gb2 * v2
                # dy/ds of the interpolant is (dy/du) / h, and s = t / tau; the clamp
                # at the ends of the table stops the time gradient outside.
                g_tau -= _inside(t[b, i] * inv_tau, s_max, g_s, zero) * t[b, i]
                if i2 > i:
                    g_tau -= _inside(t[b, i2] * inv_tau, s_max, g_s2, zero) * t[b, i2]
            gtau[b] = g_tau * inv_h * inv_tau * inv_tau
            _finish_gradients(b, gc, gy, w, g, y0, scaled, one, gw, gg, gy0)

    return _jit(forward, parallel), _jit(backward, parallel)


def time_stamp_faults(t):
    """One pass over time stamps ``[R, T]``: a bit mask of what is wrong with them.

    1: a NaN or inf; 2: a row not strictly increasing; 4: a row starting below 0.
    """
    faults = 0
    zero = t.dtype.type(0)
    for r in range(t.shape[0]):
        prev = t[r, 0]
        if not (prev - prev == zero):  # NaN or inf
            faults |= 1
        if prev < zero:
            faults |= 4
        for i in range(1, t.shape[1]):
            x = t[r, i]
            if not (x - x == zero):
                faults |= 1
            elif not (x > prev):
                faults |= 2
            prev = x
    return faults


def available() -> bool:
    """True when numba imports and the fused kernels can be used (imports it once)."""
    global numba, _numba_tried, _locate_row, time_stamp_faults, _cubic, _coefficients
    global _cubic_and_slope, _gy_pair, _inside, _finish_gradients
    if _numba_tried:
        return numba is not None
    with _import_lock:
        if _numba_tried:
            return numba is not None
        try:  # a dependency, but a broken or missing install must not break the package
            import numba as nb
        except Exception:  # pragma: no cover - exercised only on machines without numba
            nb = None
        if nb is not None:
            numba = nb
            # The helpers the kernels call, compiled (lazily, on their first call).
            _locate_row, time_stamp_faults = _jit(_locate_row), _jit(time_stamp_faults)
            _cubic, _coefficients = _jit(_cubic), _jit(_coefficients)
            _cubic_and_slope, _gy_pair = _jit(_cubic_and_slope), _jit(_gy_pair)
            _inside, _finish_gradients = _jit(_inside), _jit(_finish_gradients)
        _numba_tried = True
    return numba is not None


_import_lock = threading.Lock()


@functools.cache
def _kernel_pairs(n_columns: int, n_dims: int, parallel: bool):
    if not available():  # pragma: no cover - callers check first
        raise RuntimeError("the fused kernels need numba")
    return _build(n_columns, n_dims, parallel)


# The process that first ran a parallel kernel. GNU OpenMP cannot be used again in a
# child forked from it (numba aborts the child), so a forked child runs serial kernels.
_parallel_pid: int | None = None


def kernels(n_columns: int, n_dims: int, n_threads: int = 1):
    """``(forward, backward)`` for this table width and number of dims.

    With ``n_threads > 1`` the versions that spread the samples over numba's threads
    (``numba.set_num_threads`` is set to ``n_threads``, capped by numba's own limit).
    The serial versions are used instead when numba's only threading layer is
    "workqueue" (which must not be entered from two threads at once) and in a process
    forked from one that already ran a parallel kernel.
    """
    global _parallel_pid
    if n_threads <= 1 or not _parallel_safe():
        return _kernel_pairs(n_columns, n_dims, False)
    pid = os.getpid()
    if _parallel_pid is None:
        _parallel_pid = pid
    elif _parallel_pid != pid:
        return _kernel_pairs(n_columns, n_dims, False)
    numba.set_num_threads(min(n_threads, numba.config.NUMBA_NUM_THREADS))
    return _kernel_pairs(n_columns, n_dims, True)


# Below this many samples per thread, spreading the batch costs more than it saves.
MIN_SAMPLES_PER_THREAD = 16


@functools.lru_cache(maxsize=1)
def _parallel_safe() -> bool:
    """True when numba will run parallel kernels on OpenMP or TBB (thread-safe layers)."""
    if not available() or numba.config.THREADING_LAYER == "workqueue":
        return False
    for layer in ("omppool", "tbbpool"):
        try:
            importlib.import_module(f"numba.np.ufunc.{layer}")
            return True
        except Exception:
            continue
    return False


# Columns are padded with zeros to a multiple of this, so that the vectorised loops over
# them have no scalar remainder (16 float32 = one AVX-512 register).
_COLUMN_MULTIPLE = 16


def piece_table(poly: np.ndarray) -> np.ndarray:
    """The torch path's ``[C, G, 4]`` polynomial table in the kernels' ``[G, 4, C']`` layout.

    ``C'`` is ``C`` rounded up to a multiple of 16; the extra columns are zero. The
    table starts on a 64-byte boundary, so every row (a multiple of 64 bytes) does: the
    kernels load it in 64-byte vectors, and one that straddles two cache lines costs
    two loads. NumPy aligns to 16 bytes only, so the kernels' speed changed from one
    process to the next: at B = 128 float64 on an AMD EPYC (AVX-512), the table on a
    line or 16 bytes past one, about 30 or 43 cycles a stamp forward and 53 or 68
    backward (``benchmarks/bench_kernel.py``, experiments/RESULTS.md 5.6).
    """
    poly = np.asarray(poly)
    n_c = poly.shape[0]
    padded = -(-n_c // _COLUMN_MULTIPLE) * _COLUMN_MULTIPLE
    tab = _aligned_zeros((poly.shape[1], 4, padded), poly.dtype)
    tab[:, :, :n_c] = poly.transpose(1, 2, 0)
    return tab


def _aligned_zeros(shape: tuple, dtype, alignment: int = 64) -> np.ndarray:
    """Zeros whose first element starts a cache line (NumPy aligns to 16 bytes only), so
    that no vector load of a table row straddles two lines."""
    dtype = np.dtype(dtype)
    n = int(np.prod(shape))
    raw = np.zeros(n * dtype.itemsize + alignment, dtype=np.uint8)
    skip = -raw.ctypes.data % alignment
    return raw[skip : skip + n * dtype.itemsize].view(dtype).reshape(shape)
