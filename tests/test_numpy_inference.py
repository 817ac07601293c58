"""The torch-free inference path against the torch one it replaces.

``rollout_numpy`` and its VJP against :func:`img2dmp.dmp.rollout` and autograd, the
NumPy de-normalisation and its VJP against :class:`ParamNormaliser`'s torch methods,
``refine_numpy`` against :func:`img2dmp.nn.refine.refine`, and a fresh interpreter that
runs the NumPy path without ever importing torch. Everything in float64.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from img2dmp.dmp import DMPConfig, DMPParams, _numpy_rollout, _table, rollout
from img2dmp.dmp._numpy_rollout import rollout_numpy, rollout_numpy_vjp
from img2dmp.nn import _refine_numpy, ink
from img2dmp.nn._refine_numpy import ink_distance_map_numpy, refine_numpy
from img2dmp.nn.normalise import ParamNormaliser
from img2dmp.nn.refine import RefineOptions, _Adam, refine

CONFIGS = {
    "default": DMPConfig(),
    "d3-none-N10": DMPConfig(n_kernels=10, n_dims=3, scaling="none"),
    "N6-underdamped": DMPConfig(n_kernels=6, alpha_z=20.0, beta_z=3.0, alpha_x=1.0),
    "d3-goal-N15-wf1": DMPConfig(n_kernels=15, n_dims=3, width_factor=1.0),
}
BATCHES = [(), (4,), (2, 3)]


def _random_params(rng, batch: tuple, config: DMPConfig, span: float = 40.0) -> DMPParams:
    n, d = config.n_kernels, config.n_dims
    w_scale = 5.0 if config.scaling == "goal-start" else 150.0  # forcing of ~100 px/s^2
    return DMPParams(
        w=rng.normal(0.0, w_scale, (*batch, n, d)),
        tau=rng.uniform(0.5, 2.0, batch),
        g=rng.uniform(0.0, span, (*batch, d)),
        y0=rng.uniform(0.0, span, (*batch, d)),
    )


def _time_stamps(rng, p: DMPParams, n_t: int = 60, s_end: float = 15.0) -> np.ndarray:
    """``[*batch, T]``: t = 0, the movement, and stamps past the table's end (s > s_max,
    about 11.5 for the default constants), where the rollout is clamped."""
    s = np.sort(rng.uniform(0.0, s_end, (*p.batch_shape, n_t)), axis=-1)
    s[..., 0] = 0.0
    return s * np.asarray(p.tau)[..., None]


def _torch_rollout_and_grads(p: DMPParams, t: np.ndarray, config: DMPConfig, gy: np.ndarray):
    leaves = [torch.tensor(a, dtype=torch.float64, requires_grad=True) for a in _fields(p)]
    y = rollout(DMPParams(*leaves), torch.as_tensor(t), config, backend="torch")
    (y * torch.as_tensor(gy)).sum().backward()
    return y.detach().numpy(), [leaf.grad.numpy() for leaf in leaves]


def _fields(p: DMPParams) -> tuple:
    return (p.w, p.tau, p.g, p.y0)


# --- the rollout -----------------------------------------------------------------------


@pytest.mark.parametrize("batch", BATCHES, ids=lambda b: f"batch{list(b)}")
@pytest.mark.parametrize("name", CONFIGS)
def test_rollout_numpy_is_the_torch_rollout_and_its_vjp_is_autograd(name, batch):
    config = CONFIGS[name]
    rng = np.random.default_rng([list(CONFIGS).index(name), len(batch)])
    p = _random_params(rng, batch, config)
    t = _time_stamps(rng, p)
    gy = rng.normal(size=(*batch, t.shape[-1], config.n_dims))
    y_torch, grads_torch = _torch_rollout_and_grads(p, t, config, gy)
    y = rollout_numpy(p, t, config)
    assert y.shape == (*batch, t.shape[-1], config.n_dims) and y.dtype == np.float64
    assert np.abs(y - y_torch).max() <= 1e-10  # px
    np.testing.assert_allclose(y[..., 0, :], p.y0, rtol=0, atol=1e-12)  # t = 0: the start
    grads = rollout_numpy_vjp(p, t, config, gy)
    for field, ours, theirs in zip(
        ("w", "tau", "g", "y0"), _fields(grads), grads_torch, strict=True
    ):
        assert ours.shape == theirs.shape, field
        scale = np.abs(theirs).max()
        assert scale > 0, field  # a gradient that is all zero would compare nothing
        assert np.abs(ours - theirs).max() <= 1e-8 * scale, field


def test_one_time_axis_is_shared_by_the_batch_and_the_clamp_stops_the_tau_gradient():
    config = CONFIGS["default"]
    rng = np.random.default_rng(1)
    p = _random_params(rng, (3,), config)
    t = np.linspace(0.0, 2.0, 41)  # [T]: broadcast over the batch
    np.testing.assert_array_equal(
        rollout_numpy(p, t, config), rollout_numpy(p, np.tile(t, (3, 1)), config)
    )
    # Every stamp past the table's end (s > s_max): a settled DMP, whose tau moves nothing.
    late = np.array([30.0, 40.0, 50.0]) * p.tau.max()
    y = rollout_numpy(p, late, config)
    np.testing.assert_allclose(y, np.broadcast_to(p.g[:, None, :], y.shape), atol=1e-6)
    grads = rollout_numpy_vjp(p, late, config, np.ones_like(y))
    assert np.all(grads.tau == 0.0)
    _, grads_torch = _torch_rollout_and_grads(p, np.tile(late, (3, 1)), config, np.ones_like(y))
    np.testing.assert_array_equal(grads_torch[1], 0.0)


def test_a_large_batch_goes_in_chunks_with_the_same_numbers(monkeypatch):
    config = CONFIGS["d3-none-N10"]
    rng = np.random.default_rng(12)
    p = _random_params(rng, (5, 2), config)
    t = _time_stamps(rng, p, n_t=9)
    gy = rng.normal(size=(5, 2, 9, 3))
    whole = rollout_numpy(p, t, config), rollout_numpy_vjp(p, t, config, gy)
    monkeypatch.setattr(_numpy_rollout, "_CHUNK_STAMPS", 20)  # 2 samples a chunk: 5 chunks
    assert len(_numpy_rollout._chunks((10, 9))) == 5
    np.testing.assert_allclose(rollout_numpy(p, t, config), whole[0], rtol=1e-15, atol=1e-13)
    chunked = rollout_numpy_vjp(p, t, config, gy)
    for ours, theirs in zip(_fields(chunked), _fields(whole[1]), strict=True):
        assert ours.shape == theirs.shape
        np.testing.assert_allclose(ours, theirs, rtol=1e-14, atol=1e-12)


def test_a_nan_duration_gives_nan_positions_without_validation_and_an_error_with_it():
    config = CONFIGS["default"]
    p = _random_params(np.random.default_rng(2), (3,), config)
    p.tau[1] = np.nan  # a field changed after construction, as a diverged output can be
    t = np.linspace(0.0, 1.0, 9)
    y = rollout_numpy(p, t, config, validate=False)
    pt = DMPParams.__new__(DMPParams)  # unvalidated, as a raw network output
    pt.w, pt.tau, pt.g, pt.y0 = (torch.as_tensor(a) for a in _fields(p))
    y_torch = rollout(pt, torch.as_tensor(t), config, validate=False, backend="torch")
    assert np.isnan(y[1]).all() and np.isnan(y_torch[1].numpy()).all()
    keep = [0, 2]
    assert np.abs(y[keep] - y_torch.numpy()[keep]).max() <= 1e-10
    grads = rollout_numpy_vjp(p, t, config, np.ones_like(y), validate=False)
    assert np.isnan(grads.tau[1]) and np.isfinite(grads.tau[keep]).all()
    with pytest.raises(ValueError, match="DMPParams.tau contains NaN"):
        rollout_numpy(p, t, config)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda p, t: (p.to_torch(), t), "DMPParams.w is a torch tensor"),
        (lambda p, t: (p, t[:, :0]), "at least one time stamp"),
        (lambda p, t: (p, t[:2]), r"t has batch shape \(2,\), the parameters have \(3,\)"),
        (lambda p, t: (p, t[:, ::-1]), "strictly increasing"),
        (lambda p, t: (p, t - 1.0), "must be >= 0"),
        (lambda p, t: (p, t.astype(complex)), "real time stamps"),
        (lambda p, t: ("params", t), "needs a DMPParams, got str"),
    ],
)
def test_rollout_numpy_refuses_bad_arguments_with_one_line(change, message):
    config = CONFIGS["default"]
    p = _random_params(np.random.default_rng(3), (3,), config)
    t = np.tile(np.linspace(0.0, 1.0, 5), (3, 1))
    p, t = change(p, t)
    with pytest.raises(ValueError, match=message):
        rollout_numpy(p, t, config)


def test_rollout_numpy_refuses_a_config_or_gradient_of_another_shape():
    config = CONFIGS["default"]
    p = _random_params(np.random.default_rng(3), (3,), config)
    t = np.linspace(0.0, 1.0, 5)
    with pytest.raises(ValueError, match="N=25 kernels and d=2 dims, the config expects N=5"):
        rollout_numpy(p, t, DMPConfig(n_kernels=5))
    with pytest.raises(ValueError, match="DMPParams.w has shape"):  # unvalidated: shapes still
        rollout_numpy(p, t, DMPConfig(n_kernels=5), validate=False)
    with pytest.raises(ValueError, match=r"grad_y has shape \(3, 5\), expected \(3, 5, 2\)"):
        rollout_numpy_vjp(p, t, config, np.ones((3, 5)))


def test_the_tables_cache_name_follows_the_code_that_computes_it(tmp_path, monkeypatch):
    """The table on disk is named by a hash of _table.py, basis.py and config.py (where
    it is solved and its grid chosen), not of rollout.py: a change to any of the three
    makes a new file."""
    here = Path(_table.__file__).parent
    computing = ("_table.py", "basis.py", "config.py")
    for name in (*computing, "rollout.py"):
        (tmp_path / name).write_bytes((here / name).read_bytes())
    monkeypatch.delenv("IMG2DMP_NO_TABLE_CACHE", raising=False)
    monkeypatch.setattr(_table, "__file__", str(tmp_path / "_table.py"))
    config = DMPConfig(n_kernels=7)
    names = [Path(_table._table_cache_file(config)).name]
    assert Path(_table._table_cache_file(config)).parent == tmp_path / "__pycache__"
    for name in ("rollout.py", *computing):
        with open(tmp_path / name, "a") as f:
            f.write("# changed\n")
        names.append(Path(_table._table_cache_file(config)).name)
    assert names[1] == names[0]  # rollout.py does not compute the table
    assert len(set(names[1:])) == 4  # each of the other three does
    assert names[0].split("_")[2] == names[4].split("_")[2]  # the constants' part is kept


def test_the_table_cache_keeps_the_most_recently_used_within_its_bounds(tmp_path, monkeypatch):
    """Any constants a file brings get a table on disk; the folder keeps the most recently
    used ones, at most _CACHE_FILES files and _CACHE_BYTES bytes."""
    here = Path(_table.__file__).parent
    for name in _table._TABLE_CODE:
        (tmp_path / name).write_bytes((here / name).read_bytes())
    monkeypatch.delenv("IMG2DMP_NO_TABLE_CACHE", raising=False)
    monkeypatch.setattr(_table, "__file__", str(tmp_path / "_table.py"))
    monkeypatch.setattr(_table, "_CACHE_FILES", 3)
    cache = tmp_path / "__pycache__"

    def use(alpha_z: float) -> str:
        config = DMPConfig(n_kernels=5, alpha_z=alpha_z)
        _table._response_table_f64.__wrapped__(config)  # past the in-memory cache
        time.sleep(0.02)  # distinct modification times
        return Path(_table._table_cache_file(config)).name

    first = use(40.0)
    others = [use(a) for a in (41.0, 42.0)]
    assert use(40.0) == first  # read from disk, and now the most recently used
    newest = use(43.0)
    kept = sorted(p.name for p in cache.glob("dmp_responses_*.npy"))
    assert kept == sorted([first, others[1], newest])  # 41 was the least recently used
    monkeypatch.setattr(_table, "_CACHE_BYTES", 1)  # only the one just written stays
    last = use(44.0)
    assert [p.name for p in cache.glob("dmp_responses_*.npy")] == [last]


# --- the normaliser --------------------------------------------------------------------


def _normaliser(units: str, config: DMPConfig, rng) -> ParamNormaliser:
    """A normaliser whose goal and start units are the raw positions (centre 0, scale 1),
    so that z can place |g - y0| on either side of the amplitudes' floor exactly."""
    p = config.n_params
    ti = config.n_kernels * config.n_dims
    centre, scale = rng.normal(0.0, 3.0, p), rng.uniform(0.5, 20.0, p)
    centre[ti], scale[ti] = 0.1, 0.3  # log tau
    centre[ti + 1 :], scale[ti + 1 :] = 0.0, 1.0
    return ParamNormaliser(centre, scale, config.n_kernels, config.n_dims, units)


@pytest.mark.parametrize("units", ["weights", "amplitudes"])
@pytest.mark.parametrize("batch", [(), (5,), (2, 4)], ids=lambda b: f"batch{list(b)}")
def test_denormalise_numpy_and_its_vjp_are_the_torch_ones(units, batch):
    config = DMPConfig(n_kernels=6, n_dims=3)
    rng = np.random.default_rng(4)
    norm = _normaliser(units, config, rng)
    ti, d = config.n_kernels * config.n_dims, config.n_dims
    z = rng.normal(size=(*batch, config.n_params))
    if batch == (5,):  # |g - y0| of dimension 0: 0, below, at and above the floor, negative
        z[:, ti + 1 + d] = 0.0
        z[:, ti + 1] = [0.0, 5e-10, 1e-9, 3e-9, -5e-10]
    gv = rng.normal(size=z.shape)
    zt = torch.tensor(z, requires_grad=True)
    v_torch = norm.denormalise_vector(zt)
    (v_torch * torch.as_tensor(gv)).sum().backward()
    v = norm.denormalise_numpy(z)
    assert v.shape == z.shape
    np.testing.assert_allclose(v, v_torch.detach().numpy(), rtol=1e-14, atol=0)
    gz = norm.denormalise_numpy_vjp(z, gv)
    scale = np.abs(zt.grad.numpy()).max()
    assert np.abs(gz - zt.grad.numpy()).max() <= 1e-12 * scale
    # and back: the torch normalise undoes the NumPy denormalise
    if units == "weights" or batch != (5,):  # (the floor is not invertible)
        back = norm.normalise(torch.as_tensor(v)).numpy()
        np.testing.assert_allclose(back, z, atol=1e-9)


def test_the_fit_is_the_same_in_numpy():
    config = DMPConfig(n_kernels=5)
    rng = np.random.default_rng(5)
    v = np.concatenate([rng.normal(0, 50, (30, 10)), rng.uniform(0.4, 2, (30, 1))], 1)
    v = np.concatenate([v, rng.uniform(0, 40, (30, 4))], 1)
    for units in ("weights", "amplitudes"):
        norm = ParamNormaliser.fit(v, config, units)
        z = norm.normalise(torch.as_tensor(v)).numpy()  # torch's units of the training set
        np.testing.assert_allclose(np.median(z, axis=0), 0.0, atol=1e-12)
        np.testing.assert_allclose(norm.denormalise_numpy(z), v, rtol=1e-12)


def test_denormalise_numpy_refuses_bad_vectors():
    norm = _normaliser("weights", DMPConfig(n_kernels=5), np.random.default_rng(6))
    with pytest.raises(ValueError, match=r"z has shape \(3, 14\), expected \[\*batch, 15\]"):
        norm.denormalise_numpy(np.zeros((3, 14)))
    with pytest.raises(ValueError, match="grad_v has shape"):
        norm.denormalise_numpy_vjp(np.zeros((3, 15)), np.zeros((2, 15)))
    with pytest.raises(ValueError, match="z must hold real numbers"):
        norm.denormalise_numpy(np.array(["a"] * 15))


# --- the refinement --------------------------------------------------------------------


def _drawn_case(config: DMPConfig, units: str, seed: int, batch: int = 4, size: int = 28):
    """Images drawn from random DMPs' own pen-down paths, the normaliser, the DMPs' z
    and the time stamps: ``(images [B, H, W], times [B, T], norm, z_true [B, P])``."""
    rng = np.random.default_rng(seed)
    n, d = config.n_kernels, config.n_dims
    g = rng.uniform(6.0, size - 6.0, (batch, d))
    y0 = rng.uniform(6.0, size - 6.0, (batch, d))
    if d == 3:  # the pen: down from the start, lifted before the end for half of them
        y0[:, 2], g[:, 2] = 1.0, np.where(np.arange(batch) % 2 == 0, 1.0, 0.0)
    w_scale = 3.0 if config.scaling == "goal-start" else 100.0
    p = DMPParams(rng.normal(0.0, w_scale, (batch, n, d)), rng.uniform(0.8, 1.2, batch), g, y0)
    fine = rollout_numpy(p, np.linspace(0.0, 1.0, 400)[None] * p.tau[:, None], config)
    rows, cols = np.mgrid[:size, :size]
    images = np.zeros((batch, size, size))
    for b in range(batch):  # a pen of ~2 px: intensity falls off with the distance
        down = fine[b, fine[b, :, 2] >= 0.5] if d == 3 else fine[b]
        d2 = (cols[None] - down[:, 0, None, None]) ** 2 + (rows[None] - down[:, 1, None, None]) ** 2
        images[b] = np.clip(1.3 * np.exp(-d2.min(0) / 2.0), 0.0, 1.0)
    v = p.to_vector()
    spread = v * (1.0 + rng.normal(0.0, 0.2, v.shape)) + rng.normal(0.0, 1.0, v.shape)
    spread[:, n * d] = np.abs(spread[:, n * d]) + 0.1  # tau > 0
    norm = ParamNormaliser.fit(np.concatenate([v, spread]), config, units)
    z_true = norm.normalise(torch.as_tensor(v)).numpy()
    times = np.linspace(0.0, 1.0, 100)[None] * p.tau[:, None] + 0.25  # shifted to 0 by both
    return images, times, norm, z_true


@pytest.mark.parametrize(
    ("config", "units"),
    [(DMPConfig(), "weights"), (DMPConfig(n_kernels=10, n_dims=3), "amplitudes")],
    ids=["d2-weights", "d3-pen-amplitudes"],
)
def test_refine_numpy_is_refine(config, units):
    images, times, norm, z_true = _drawn_case(config, units, seed=7)
    z0 = z_true + np.random.default_rng(8).normal(0.0, 0.3, z_true.shape)
    options = RefineOptions(steps=30, lr=0.02)
    z_torch = refine(
        torch.as_tensor(z0), torch.as_tensor(images), torch.as_tensor(times), norm, config, options
    ).numpy()
    z = refine_numpy(z0, images, times, norm, config, options)
    assert z.shape == z0.shape and z.dtype == np.float64
    assert np.abs(z_torch - z0).max() > 0.1  # the refinement moved: the comparison means something
    # The one place the two can part by more than rounding is the argmin of the coverage
    # term: both take squared distances in a matrix-product form that rounds them to
    # ~1e-13 px^2, each with its own product (NumPy's matmul, torch's cdist), so an ink
    # pixel that is equally near two path points to that precision may pull on different
    # points (and through them on different stamps' Jacobians). These paths are random
    # curves sampled at generic points, never on a grid, so such near-ties (a chance of
    # ~1e-12 per pixel and step) do not occur; a run that hit one would differ far above
    # rounding, not by ~1e-16.
    # (Exact ties, e.g. stamps past the table's end, which all give the same point, are
    # broken alike: both argmins take the first.)
    assert np.abs(z - z_torch).max() <= 1e-6
    # Without the image terms only the prior and Adam remain: z0 is a fixed point.
    still = RefineOptions(steps=5, ink_weight=0.0, coverage_weight=0.0)
    np.testing.assert_array_equal(refine_numpy(z0, images, times, norm, config, still), z0)
    np.testing.assert_array_equal(
        refine_numpy(z0, images, times, norm, config, RefineOptions(steps=0)), z0
    )


def test_the_ink_terms_and_their_gradients_are_the_torch_ones():
    """Each term on its own, at points on pixel lines, on the border and outside the
    image, where the bilinear read and the outside distance change their formula."""
    rng = np.random.default_rng(9)
    images = np.clip(rng.uniform(-1.0, 1.5, (3, 9, 12)), 0.0, 1.0)
    images[1] = 0.0  # no ink: a map of zeros, no coverage
    dist = ink_distance_map_numpy(images)
    np.testing.assert_array_equal(dist, ink.ink_distance_map(torch.as_tensor(images)).numpy())
    special = [[3.0, 4.0], [0.0, 2.5], [11.0, 3.0], [5.5, 8.0], [5.5, 0.0], [0.0, 0.0], [11.0, 8.0]]
    special += [[-1.0, 3.3], [13.0, 9.5], [2.0, 3.5], [7.25, 6.0], [-0.5, -2.0]]
    y = np.concatenate([np.tile(special, (3, 1, 1)), rng.uniform(-2.0, 14.0, (3, 30, 2))], 1)
    pen = np.where(np.arange(y.shape[1]) % 3 == 0, 0.2, 0.9)  # every third point pen-up
    pen = np.stack([pen, pen, np.full_like(pen, 0.4)])  # the third sample: the pen never down
    y = np.concatenate([y, pen[..., None]], -1)
    for dims in (2, 3):
        yt = torch.tensor(y[..., :dims], requires_grad=True)
        value, grad = _refine_numpy._ink_attraction(y[..., :dims], dist.astype(np.float64))
        a = ink.ink_attraction(yt, torch.as_tensor(dist).double())
        a.sum().backward()
        np.testing.assert_allclose(value, a.detach().numpy(), rtol=1e-13)
        assert np.abs(grad - yt.grad.numpy()[..., :2]).max() <= 1e-13
        yt.grad = None
        pixels = _refine_numpy._InkPixels(images, _refine_numpy.INK_THRESHOLD)
        value, grad = _refine_numpy._ink_coverage(y[..., :dims], pixels, 1.0)
        c = ink.ink_coverage(yt, torch.as_tensor(images), tolerance_px=1.0)
        c.sum().backward()
        np.testing.assert_allclose(value, c.detach().numpy(), rtol=1e-13)
        assert value[0] > 0 and value[1] == 0.0 and (value[2] == 0.0) == (dims == 3)
        assert np.abs(grad - yt.grad.numpy()[..., :2]).max() <= 1e-13
        assert (yt.grad[..., 2:] == 0).all()  # the pen gets no image gradient in torch either
    assert _refine_numpy.INK_THRESHOLD == ink.INK_THRESHOLD


def test_the_numpy_adam_is_refines_adam():
    rng = np.random.default_rng(10)
    z0 = rng.normal(size=(3, 7))
    ours, theirs = z0.copy(), torch.tensor(z0, requires_grad=True)
    adam_np, adam_torch = _refine_numpy._Adam(z0.shape, 0.05), _Adam(theirs, 0.05)
    for _ in range(20):
        grad = np.sin(3.0 * ours) + ours  # the same function of each one's own iterate
        ours = adam_np.step(ours, grad)
        theirs.grad = torch.sin(3.0 * theirs.detach()) + theirs.detach()
        adam_torch.step()
    assert np.abs(ours - z0).max() > 0.1
    assert np.abs(ours - theirs.detach().numpy()).max() <= 1e-13


def test_refine_numpy_refuses_bad_arguments():
    config = DMPConfig()
    images, times, norm, z = _drawn_case(config, "weights", seed=11, batch=2)
    cases = [
        ((z[:, :-1], images, times), r"z0 has shape \(2, 54\), expected \[B, 55\]"),
        ((z, images[:1], times), "one row per sample, got 2, 1 and 2"),
        ((z, images[0], times), r"images must have 3 axes, got shape \(28, 28\)"),
        ((z, images, times[:, :0]), "must not be empty"),
    ]
    for args, message in cases:
        with pytest.raises(ValueError, match=message):
            refine_numpy(*args, norm, config)
    with pytest.raises(ValueError, match="the normaliser is for N=25, d=2, the config for N=5"):
        refine_numpy(z, images, times, norm, DMPConfig(n_kernels=5))
    with pytest.raises(ValueError, match="options must be RefineOptions, got dict"):
        refine_numpy(z, images, times, norm, config, {"steps": 3})
    with pytest.raises(ValueError, match=r"images must be real numbers \[B, H, W\], got"):
        ink_distance_map_numpy(images[0])


# --- no torch --------------------------------------------------------------------------


def test_the_numpy_path_never_imports_torch():
    """A fresh interpreter imports the NumPy modules and runs a rollout, its VJP and a
    refinement: torch must never have been imported (its import costs 2-3 s)."""
    code = """
import sys
import img2dmp.dmp._numpy_rollout, img2dmp.nn._refine_numpy, img2dmp.nn.normalise
assert "torch" not in sys.modules, "imported torch"
import numpy as np
from img2dmp.dmp import DMPConfig, DMPParams
from img2dmp.dmp import _numpy_rollout
from img2dmp.dmp._numpy_rollout import rollout_numpy, rollout_numpy_vjp
from img2dmp.nn._refine_numpy import refine_numpy
from img2dmp.nn._refine_options import RefineOptions
from img2dmp.nn.normalise import ParamNormaliser

cfg = DMPConfig(n_kernels=5)
rng = np.random.default_rng(0)
p = DMPParams(rng.normal(size=(2, 5, 2)), np.ones(2), np.full((2, 2), 9.0), np.full((2, 2), 3.0))
t = np.linspace(0.0, 1.0, 20)
y = rollout_numpy(p, t, cfg)
rollout_numpy_vjp(p, t, cfg, np.ones_like(y))
v = np.concatenate([rng.normal(size=(6, 10)), np.ones((6, 1)), rng.uniform(0, 20, (6, 4))], 1)
norm = ParamNormaliser.fit(v, cfg)
img = np.zeros((2, 28, 28)); img[:, 10:14, 5:20] = 1.0
z = refine_numpy(np.zeros((2, 15)), img, np.tile(t, (2, 1)), norm, cfg, RefineOptions(steps=3))
assert np.isfinite(z).all()
assert "torch" not in sys.modules, "running the NumPy path imported torch"
"""
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
