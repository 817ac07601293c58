"""The fused kernels on their cache-line-aligned table, stamps in pairs (issue 33 part 4).

:func:`img2dmp.dmp._kernels.piece_table` now starts the table on a 64-byte boundary;
before, it started wherever NumPy put it (16-byte aligned), and the kernels now take
the time stamps two at a time. They must give the numbers they gave, to 1e-12 relative
in float64: the positions those of an independent NumPy evaluation of the same
piecewise cubic, the gradients those of the torch operations' hand-written backward
(itself checked by gradcheck in test_dmp.py), on any table placement, for odd and even
numbers of stamps.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from img2dmp.dmp import DMPConfig, DMPParams, _kernels, rollout
from img2dmp.dmp.rollout import _response_table

pytestmark = pytest.mark.skipif(not _kernels.available(), reason="needs numba")

DTYPES = {torch.float32: np.float32, torch.float64: np.float64}


def _batch(b, n_t, cfg, seed=0):
    rng = np.random.default_rng(seed)
    n, d = cfg.n_kernels, cfg.n_dims
    tau = rng.uniform(0.5, 4.0, b)
    p = DMPParams(
        w=rng.normal(0, 20, (b, n, d)),
        tau=tau,
        g=rng.uniform(0, 40, (b, d)),
        y0=rng.uniform(0, 40, (b, d)),
    )
    # Past the table's end too (s up to 1.3 s_max is clamped) and uneven stamps.
    t = np.sort(rng.uniform(0, 1.3, (b, n_t)), axis=1) * tau[:, None]
    t[:, 0] = 0.0
    return p, t


def _shifted(tab: np.ndarray, offset: int) -> np.ndarray:
    """A copy of ``tab`` starting ``offset`` bytes past a cache line."""
    raw = _kernels._aligned_zeros((tab.nbytes + 64,), np.uint8)
    out = raw[offset : offset + tab.nbytes].view(tab.dtype).reshape(tab.shape)
    out[...] = tab
    assert out.ctypes.data % 64 == offset
    return out


def _run(tab, cfg, p, t, gy, dtype, want_s=True):
    """Positions and the gradients (w, tau, g, y0) of ``sum(gy * y)`` from the kernels."""
    np_dtype = DTYPES[dtype]
    h, s_max, _ = _response_table(cfg, dtype, "cpu")
    one = np_dtype(1.0)
    consts = (tab, one / np_dtype(h), np_dtype(s_max), one, cfg.scaling == "goal-start")
    arrays = [np.ascontiguousarray(x, dtype=np_dtype) for x in (t, p.tau, p.w, p.g, p.y0)]
    forward, backward = _kernels.kernels(tab.shape[2], cfg.n_dims, 1)
    y = np.empty((*t.shape, cfg.n_dims), dtype=np_dtype)
    forward(*arrays, *consts, y)
    grads = [np.empty_like(arrays[i]) for i in (2, 1, 3, 4)]
    backward(gy.astype(np_dtype), *arrays, *consts, *grads, want_s)
    return [y, *grads]


def _reference_positions(cfg, p, t):
    """The piecewise cubic of ``_response_table`` evaluated by NumPy in float64."""
    h, s_max, poly = _response_table(cfg, torch.float64, "cpu")
    poly = poly.numpy()  # [C, G - 1, 4]
    q = np.clip(t / p.tau[:, None], 0.0, s_max) / h
    piece = np.minimum(np.floor(q), poly.shape[1] - 1).astype(int)
    u = q - piece
    r = sum(poly[:, piece, k] * u**k for k in range(4))  # [C, B, T]
    scale = (p.g - p.y0) if cfg.scaling == "goal-start" else np.ones_like(p.g)
    forced = np.einsum("kbt,bkd->btd", r[1:], p.w) * scale[:, None, :]
    return p.g[:, None, :] + (p.y0 - p.g)[:, None, :] * r[0][..., None] + forced


def _reference_gradients(cfg, p, t, gy):
    """Gradients (w, tau, g, y0) of ``sum(gy * y)`` through the torch operations."""
    leaves = [
        torch.tensor(a, dtype=torch.float64, requires_grad=True) for a in (p.w, p.tau, p.g, p.y0)
    ]
    y = rollout(DMPParams(*leaves), torch.tensor(t), cfg, backend="torch")
    (y * torch.tensor(gy)).sum().backward()
    return [a.grad.numpy() for a in leaves]


def test_piece_table_starts_on_a_cache_line_and_holds_the_pieces():
    for n in (6, 25, 40):
        cfg = DMPConfig(n_kernels=n)
        for dtype in DTYPES:
            poly = _response_table(cfg, dtype, "cpu")[2].numpy()
            tab = _kernels.piece_table(poly)
            assert tab.ctypes.data % 64 == 0 and tab.flags.c_contiguous
            assert tab.shape[2] % 16 == 0 and not tab[:, :, n + 1 :].any()
            np.testing.assert_array_equal(tab[:, :, : n + 1], poly.transpose(1, 2, 0))


CASES = [
    (1, 301, 25, 2, "goal-start"),
    (17, 7, 25, 2, "goal-start"),
    (40, 301, 25, 3, "none"),
    (5, 1, 6, 2, "none"),
    (33, 64, 6, 3, "goal-start"),
]


@pytest.mark.parametrize("dtype", list(DTYPES))
@pytest.mark.parametrize(("b", "n_t", "n", "d", "scaling"), CASES)
def test_kernels_give_the_reference_numbers_on_any_table_placement(dtype, b, n_t, n, d, scaling):
    cfg = DMPConfig(n_kernels=n, n_dims=d, scaling=scaling)
    p, t = _batch(b, n_t, cfg)
    gy = np.random.default_rng(1).normal(size=(b, n_t, d))
    tab = _kernels.piece_table(_response_table(cfg, dtype, "cpu")[2].numpy())
    new = _run(tab, cfg, p, t, gy, dtype)
    tol = 1e-12 if dtype == torch.float64 else 1e-6
    for offset in (16, 48):
        old = _run(_shifted(tab, offset), cfg, p, t, gy, dtype)
        for a, b_ in zip(new, old, strict=True):
            np.testing.assert_allclose(a, b_, rtol=0, atol=tol * np.abs(b_).max())
    if dtype == torch.float64:
        refs = [_reference_positions(cfg, p, t), *_reference_gradients(cfg, p, t, gy)]
        for a, ref in zip(new, refs, strict=True):
            np.testing.assert_allclose(a, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    # Without the time gradient: the same gradients for w, g and y0, and none for tau.
    other = _run(tab, cfg, p, t, gy, dtype, want_s=False)
    for k in (1, 3, 4):
        np.testing.assert_array_equal(other[k], new[k])
    assert not other[2].any()


@pytest.mark.parametrize("dtype", list(DTYPES))
def test_a_nan_tau_or_time_stamp_gives_nan_positions_of_its_sample_only(dtype):
    cfg = DMPConfig()
    p, t = _batch(4, 50, cfg)
    p.tau[1] = np.nan
    t[2, 10] = np.nan
    tab = _kernels.piece_table(_response_table(cfg, dtype, "cpu")[2].numpy())
    y = _run(tab, cfg, p, t, np.ones((4, 50, 2)), dtype)[0]
    assert np.isnan(y[1]).all() and np.isnan(y[2, 10]).all()
    assert np.isfinite(y[[0, 3]]).all() and np.isfinite(np.delete(y[2], 10, axis=0)).all()
