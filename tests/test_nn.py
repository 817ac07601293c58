"""The network, the output normalisation and the two costs (eqs. 9 and 10)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from img2dmp.data.render import render_paths
from img2dmp.data.store import DigitData, save_dataset
from img2dmp.dmp import DMPConfig, DMPParams, fit_dmp, integrate, rollout
from img2dmp.nn import (
    Cost,
    ModelConfig,
    ParamNormaliser,
    build_model,
    parameter_cost,
    trajectory_cost,
    trajectory_error_px,
)

TINY = {"encoder_layers": [64, 16], "decoder_layers": [16], "image_size": [16, 16]}


def toy_paths(n: int, seed: int = 0, n_points: int = 60):
    """Simple pen paths (a few smooth families, one per label) with random size/offset."""
    rng = np.random.default_rng(seed)
    labels = rng.integers(0, 3, n)
    s = np.linspace(0.0, 1.0, n_points)
    paths = np.empty((n, n_points, 2))
    for i, lab in enumerate(labels):
        a = rng.uniform(0.7, 1.0)
        if lab == 0:  # arc
            th = np.pi * (0.2 + 1.4 * s)
            p = np.stack([np.cos(th), np.sin(th)], -1)
        elif lab == 1:  # diagonal stroke with a bend
            p = np.stack([-0.8 + 1.6 * s, -0.8 + 1.6 * s**1.5], -1)
        else:  # zig
            p = np.stack([-0.8 + 1.6 * s, 0.6 * np.sin(2 * np.pi * s)], -1)
        paths[i] = a * p + rng.normal(0, 0.05, 2)
    return paths, labels


def make_toy_dataset(path, n: int = 300, size: int = 16, seed: int = 0, config=None):
    """A small data set in the store format, made without the synthetic generator."""
    config = config or DMPConfig()
    paths, labels = toy_paths(n, seed)
    px = (paths * 0.4 + 0.5) * (size - 1)  # [M, T, 2] in pixels
    t = np.linspace(0, 1.0, px.shape[1])[None].repeat(n, 0) * np.random.default_rng(seed).uniform(
        0.8, 1.2, (n, 1)
    )
    fit = fit_dmp(t, px, config)
    split = np.zeros(n, np.uint8)
    split[int(0.8 * n) : int(0.9 * n)] = 1
    split[int(0.9 * n) :] = 2
    data = DigitData(
        images=render_paths(px, size, 1.5).numpy(),
        trajectories=px.astype(np.float32),
        times=t.astype(np.float32),
        labels=labels.astype(np.int64),
        params=fit.params.to_vector().astype(np.float32),
        fit_error_px=fit.error_px.astype(np.float32),
        split=split,
        meta={"dmp_config": config.to_dict(), "source": {"kind": "toy"}, "seed": seed},
    )
    return save_dataset(path, data)


def _random_params(n: int, config: DMPConfig, seed: int = 0) -> np.ndarray:
    paths, _ = toy_paths(n, seed)
    t = np.linspace(0, 1.0, paths.shape[1])
    return fit_dmp(t, paths * 15 + 20, config).params.to_vector()  # [n, P]


def test_normaliser_round_trip_and_positive_tau():
    config = DMPConfig()
    v = _random_params(200, config)
    norm = ParamNormaliser.fit(v, config)
    vt = torch.as_tensor(v)
    z = norm.normalise(vt)
    assert torch.allclose(norm.denormalise_vector(z), vt, rtol=1e-10, atol=1e-9)
    # Gaussian units with wildly different scales (and a log-normal tau) come out as
    # standard normal: about half of every unit lies within +-0.6745, whatever outliers.
    rng = np.random.default_rng(1)
    g = rng.normal(0, 1, (4000, config.n_params)) * np.logspace(-2, 3, config.n_params) + 7
    g[:, norm.tau_index] = np.exp(rng.normal(0.5, 0.2, 4000))
    g[:40, 3] = 1e6  # a few huge outliers in one unit
    zg = ParamNormaliser.fit(g, config).normalise(torch.as_tensor(g))
    inside = (zg.abs() < 0.6745).double().mean(0)
    assert float(inside.min()) > 0.45 and float(inside.max()) < 0.55
    # any output, however wild, gives a positive tau
    p = norm.denormalise(torch.randn(7, config.n_params) * 30)
    assert bool((p.tau > 0).all())
    p.validate(config)
    # the unflattening agrees with DMPParams.from_vector
    ref = DMPParams.from_vector(vt[:3], config.n_kernels, config.n_dims)
    got = norm.denormalise(z[:3])
    for k in ("w", "tau", "g", "y0"):
        assert torch.allclose(getattr(got, k), getattr(ref, k), atol=1e-9)
    back = ParamNormaliser.from_dict(norm.to_dict())
    assert np.array_equal(back.scale, norm.scale)


def test_amplitude_units_are_the_same_dmp_and_move_linearly():
    config = DMPConfig()
    v = _random_params(200, config)
    vt = torch.as_tensor(v)
    norm = ParamNormaliser.fit(v, config, units="amplitudes")
    assert norm.units == "amplitudes"
    z = norm.normalise(vt)
    n, d = config.n_kernels, config.n_dims
    span = (vt[:, n * d + 1 : n * d + 1 + d] - vt[:, n * d + 1 + d :]).abs().min(-1).values
    assert float(span.min()) == 0.0  # the zigzags end at their start's height: w is lost
    ok = span > 1e-3  # elsewhere the vector comes back
    assert torch.allclose(norm.denormalise_vector(z)[ok], vt[ok], rtol=1e-9, atol=1e-9)
    # the weight units hold (g - y0) * w, unit by unit, in the flat order of eq. (8)
    p = DMPParams.from_vector(vt, n, d)
    amp = ((p.g - p.y0)[:, None, :] * p.w).transpose(1, 2).reshape(len(v), -1)
    raw = z * torch.as_tensor(norm.scale) + torch.as_tensor(norm.centre)
    assert torch.allclose(raw[:, : n * d], amp, rtol=1e-12, atol=1e-9)
    # the same DMP (also where g = y0): rolled out from either normalisation, paths agree
    t = torch.linspace(0, 1, 50, dtype=torch.float64)
    by_weights = ParamNormaliser.fit(v, config)
    y_a = rollout(norm.denormalise(z), t, config)
    y_w = rollout(by_weights.denormalise(by_weights.normalise(vt)), t, config)
    assert torch.allclose(y_a, y_w, atol=1e-9)
    # the path is affine in the amplitude units: the midpoint of two outputs rolls out to
    # the midpoint of their paths (in weight units it does not, w being scaled by g - y0)
    za, zb = z[:4], z[4:8]
    mid = rollout(norm.denormalise((za + zb) / 2), t, config)
    ends = rollout(norm.denormalise(za), t, config) + rollout(norm.denormalise(zb), t, config)
    assert torch.allclose(mid, ends / 2, atol=1e-8)
    zw_a, zw_b = by_weights.normalise(vt[:4]), by_weights.normalise(vt[4:8])
    mid_w = rollout(by_weights.denormalise((zw_a + zw_b) / 2), t, config)
    assert not torch.allclose(mid_w, ends / 2, atol=1e-3)
    # g == y0 in a dimension: finite weights, and the record keeps the units
    zero_span = vt[:1].clone()
    zero_span[0, n * d + 1] = zero_span[0, n * d + 1 + d]
    assert torch.isfinite(norm.denormalise_vector(norm.normalise(zero_span))).all()
    assert ParamNormaliser.from_dict(norm.to_dict()).units == "amplitudes"
    old = by_weights.to_dict()
    del old["units"]  # records written before the units existed hold weights
    assert ParamNormaliser.from_dict(old).units == "weights"
    with pytest.raises(ValueError, match="goal-start"):
        ParamNormaliser.fit(v, DMPConfig(scaling="none"), units="amplitudes")
    with pytest.raises(ValueError, match="units"):
        ParamNormaliser.fit(v, config, units="forces")


def test_normaliser_floors_each_group_on_its_own_scale():
    # huge weights and a constant tau: tau's floor must not follow the weights' size
    config = DMPConfig()
    v = _random_params(100, config)
    n_w = config.n_kernels * config.n_dims
    v[:, :n_w] *= 1e4
    v[:, n_w] = 2.0
    norm = ParamNormaliser.fit(v, config)
    assert norm.scale[n_w] == pytest.approx(1e-2)
    assert norm.scale[n_w + 1 :].min() < 10  # positions keep their own pixel scale
    v[:, n_w + 1] = 5.0  # a constant goal unit: floored at 1e-3 of the positions' scale
    norm = ParamNormaliser.fit(v, config)
    assert norm.scale[n_w + 1] == pytest.approx(1e-3 * np.median(norm.scale[n_w + 1 :]), rel=0.5)


def test_normaliser_rejects_bad_input():
    config = DMPConfig()
    v = _random_params(10, config)
    v[3, config.n_kernels * 2] = -1.0  # tau <= 0
    with pytest.raises(ValueError, match="tau"):
        ParamNormaliser.fit(v, config)
    with pytest.raises(ValueError, match="length 55"):
        ParamNormaliser.fit(v[:, :10], config)


def test_paper_architecture_and_conv_encoder():
    model = build_model(ModelConfig())
    sizes = [m.out_features for m in model.modules() if isinstance(m, torch.nn.Linear)]
    first = next(m for m in model.modules() if isinstance(m, torch.nn.Linear))
    assert first.in_features == 1600
    assert sizes == [1500, 1300, 1000, 600, 200, 20, 35, 55]
    x = torch.rand(3, 40, 40)
    assert model(x).shape == (3, 55)
    conv = build_model(ModelConfig(encoder="conv", encoder_layers=[32], decoder_layers=[16]))
    assert conv(x).shape == (3, 55)
    assert conv.encoder.head[0].in_features == 64 * 5 * 5  # 40 -> 20 -> 10 -> 5
    # a stride-1 first layer keeps the full resolution: 40 -> 40 -> 20 -> 10
    cfg = ModelConfig(encoder="conv", conv_channels=[4, 8, 8], conv_strides=[1, 2, 2])
    fine = build_model(ModelConfig.from_dict(cfg.to_dict()))
    assert fine.encoder.head[0].in_features == 8 * 10 * 10
    assert fine(x).shape == (3, 55)
    assert ModelConfig.from_dict({"encoder": "conv"}).conv_strides is None  # old records
    with pytest.raises(ValueError, match="conv_strides"):
        ModelConfig(encoder="conv", conv_channels=[4, 8], conv_strides=[1])
    with pytest.raises(ValueError, match="conv_strides"):
        ModelConfig(encoder="conv", conv_channels=[4, 8], conv_strides=[0, 2])
    with pytest.raises(ValueError, match="expects"):
        model(torch.rand(2, 28, 28))
    with pytest.raises(ValueError, match="activation"):
        ModelConfig(activation="swishy")
    # seeded initialisation is reproducible
    a, b = build_model(ModelConfig(**TINY), seed=3), build_model(ModelConfig(**TINY), seed=3)
    assert all(torch.equal(p, q) for p, q in zip(a.parameters(), b.parameters(), strict=True))


def test_he_initialisation_keeps_the_images_variation_through_the_papers_network():
    from img2dmp.nn.model import ModelConfig, build_model

    rng = np.random.default_rng(0)
    images = torch.as_tensor(rng.random((256, 40, 40)) < 0.1, dtype=torch.float32)

    def code_variation(init):
        net = build_model(ModelConfig(init=init), seed=0)
        with torch.no_grad():
            code = net.encoder(images)  # [B, 20], after the code layer's ReLU
        return float(code.std(0).mean()), net

    torch_std, _ = code_variation("torch")
    he_std, net = code_variation("he")
    assert he_std > 30 * torch_std  # PyTorch's default: ~1/7 of the variance per layer
    layers = [m for m in net.modules() if isinstance(m, torch.nn.Linear)]
    for layer in layers:
        assert float(layer.bias.detach().abs().max()) == 0.0
    first, last = layers[0], layers[-1]  # followed by a ReLU; the output layer: by nothing
    assert abs(float(first.weight.detach().std()) * 1600**0.5 - 2**0.5) < 0.02
    assert abs(float(last.weight.detach().std()) * 35**0.5 - 1.0) < 0.15
    conv = build_model(ModelConfig(encoder="conv", conv_norm="batch", init="he"), seed=0)
    c = next(m for m in conv.modules() if isinstance(m, torch.nn.Conv2d))  # BN, then ReLU
    assert abs(float(c.weight.detach().std()) * 9**0.5 - 2**0.5) < 0.25
    with pytest.raises(ValueError, match="model.init must be one of"):
        ModelConfig(init="xavier")


def test_dropout_acts_in_training_only_after_the_hidden_layers_of_the_fc_encoder():
    from img2dmp.nn.model import ModelConfig, build_model

    net = build_model(ModelConfig(encoder_layers=[64, 32, 8], dropout=0.5), seed=0)
    kinds = [type(m).__name__ for m in net.encoder.net]
    assert kinds == ["Linear", "ReLU", "Dropout", "Linear", "ReLU", "Dropout", "Linear", "ReLU"]
    x = torch.rand(4, 40, 40)
    with torch.no_grad():
        net.train()
        assert not torch.equal(net(x), net(x))  # units dropped at random
        net.eval()
        assert torch.equal(net(x), net(x))
        plain = build_model(ModelConfig(encoder_layers=[64, 32, 8]), seed=0).eval()
        assert torch.allclose(net(x), plain(x))  # the same weights, nothing dropped
    for bad in (1.0, -0.1, "0.2", True):
        with pytest.raises(ValueError, match="model.dropout must be a number in"):
            ModelConfig(dropout=bad)


def test_dropout_of_the_conv_encoder_drops_the_code_in_training_only_and_adds_no_weights():
    from img2dmp.nn.model import ModelConfig, build_model

    cfg = {"encoder": "conv", "conv_channels": [4, 8], "encoder_layers": [16]}
    net = build_model(ModelConfig(**cfg, dropout=0.5), seed=0)
    assert [type(m).__name__ for m in net.encoder.head] == ["Linear", "ReLU", "Dropout"]
    plain = build_model(ModelConfig(**cfg), seed=0).eval()
    assert net.state_dict().keys() == plain.state_dict().keys()  # checkpoints unchanged
    x = torch.rand(4, 40, 40)
    with torch.no_grad():
        net.train()
        assert not torch.equal(net(x), net(x))
        net.eval()
        assert torch.equal(net(x), net(x))
        assert torch.allclose(net(x), plain(x))


def test_conv_batch_norm_trains_saves_and_reloads(tmp_path):
    """``conv_norm: batch``: running statistics move in training, are saved and reloaded,
    and an evaluated image's output does not depend on the rest of its batch."""
    from img2dmp.checkpoint import load_checkpoint, load_weights_into, save_checkpoint

    cfg = ModelConfig(
        encoder="conv", conv_channels=[4, 8], encoder_layers=[16], decoder_layers=[8],
        conv_norm="batch",
    )  # fmt: skip
    model = build_model(cfg, seed=0)
    norms = [m for m in model.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert len(norms) == 2
    assert all(m.bias is None for m in model.modules() if isinstance(m, torch.nn.Conv2d))
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    x = torch.rand(16, 40, 40) * 3.0 + 1.0  # far from the initial running mean 0, var 1
    for _ in range(5):
        loss = model(x).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(norms[0].running_mean.abs().max()) > 0.01
    model.eval()
    with torch.no_grad():
        ref = model(x)
        assert torch.allclose(model(x[:3]), ref[:3], atol=1e-6)  # no batch statistics
    save_checkpoint(tmp_path / "bn.safetensors", model.state_dict(), {"model": cfg.to_dict()})
    ck = load_checkpoint(tmp_path / "bn.safetensors")
    back = build_model(ModelConfig.from_dict(ck.meta["model"])).eval()
    load_weights_into(back, ck)
    with torch.no_grad():
        assert torch.equal(back(x), ref)
    assert ModelConfig.from_dict({"encoder": "conv"}).conv_norm == "none"  # old records
    with pytest.raises(ValueError, match="conv_norm"):
        ModelConfig(encoder="conv", conv_norm="layer")


def test_impulse_filter_undoes_most_salt_and_pepper_noise():
    """``input_filter: impulse`` against the generator's own noise: the same samples drawn
    with and without it (the noise is the last draw from the generator's stream)."""
    from dataclasses import replace

    from img2dmp.data import synthetic
    from img2dmp.nn.model import ImpulseFilter

    labels = np.arange(60) % 10
    cfg = synthetic.SyntheticConfig()
    noisy = torch.as_tensor(synthetic.generate(labels, cfg, np.random.default_rng(4)).images)
    clean = synthetic.generate(labels, replace(cfg, noise_amount=0.0), np.random.default_rng(4))
    clean = torch.as_tensor(clean.images)
    f = ImpulseFilter()
    before = float((noisy - clean).square().mean().sqrt())
    after = float((f(noisy) - clean).square().mean().sqrt())
    assert after < before / 3, (before, after)
    torch.testing.assert_close(f(clean), clean, rtol=0, atol=1e-4)  # no noise: ~unchanged
    # only pixels at exactly 0 or 1 change, each to the median of its 8 neighbours
    x = torch.full((1, 5, 5), 0.5)
    x[0, 2, 2], x[0, 0, 0], x[0, 1, 3] = 0.0, 1.0, 0.7
    y = f(x)
    assert y[0, 2, 2] == pytest.approx(0.5) and y[0, 0, 0] == pytest.approx(0.5)
    inside = (x > 0) & (x < 1)
    assert torch.equal(y[inside], x[inside])
    model = build_model(ModelConfig(encoder="conv", conv_channels=[4], input_filter="impulse"))
    plain = build_model(ModelConfig(encoder="conv", conv_channels=[4]))
    plain.load_state_dict(model.state_dict())  # the filter has no weights
    with torch.no_grad():
        torch.testing.assert_close(model(noisy[:4]), plain(f(noisy[:4])))
    assert ModelConfig.from_dict({"encoder": "conv"}).input_filter == "none"  # old records
    with pytest.raises(ValueError, match="input_filter"):
        ModelConfig(input_filter="gaussian")


def test_parameter_cost_by_hand():
    zp = torch.tensor([[1.0, 2.0], [0.0, 0.0]])
    zt = torch.tensor([[0.0, 0.0], [0.0, 3.0]])
    # (1 + 4 + 0 + 9) / 4 entries
    assert float(parameter_cost(zp, zt)) == pytest.approx(3.5)


def test_trajectory_cost_matches_reference_integrator():
    """Cost (10) against a step-by-step integration of the DMP ODE (independent code)."""
    config = DMPConfig()
    v = _random_params(50, config)
    norm = ParamNormaliser.fit(v, config)
    z = norm.normalise(torch.as_tensor(v[:3]))
    t = torch.linspace(0.0, 1.0, 40, dtype=torch.float64).expand(3, 40)
    demo = torch.zeros(3, 40, 2, dtype=torch.float64) + 5.0
    got = trajectory_cost(z, t, demo, norm, config)
    ref = []
    for b in range(3):
        p = DMPParams.from_vector(v[b], config.n_kernels, config.n_dims)
        y = integrate(p, t[b].numpy(), config, max_step=1e-4)
        ref.append(((y - 5.0) ** 2).sum(-1).mean())
    assert float(got) == pytest.approx(float(np.mean(ref)), rel=1e-5)


def test_trajectory_cost_gradient_matches_finite_differences():
    config = DMPConfig(n_kernels=6)
    v = _random_params(30, config)
    norm = ParamNormaliser.fit(v, config)
    z = norm.normalise(torch.as_tensor(v[:2])) + 0.1
    t = torch.linspace(0.0, 0.9, 25, dtype=torch.float64).expand(2, 25)
    demo = rollout(DMPParams.from_vector(torch.as_tensor(v[2:4]), 6, 2), t, config)
    z.requires_grad_(True)
    c = trajectory_cost(z, t, demo, norm, config)
    (g,) = torch.autograd.grad(c, z)
    eps = 1e-6
    for j in (0, 7, 12, 13, 15):  # a weight of each dim, tau, goal, start
        dz = torch.zeros_like(z)
        dz[1, j] = eps
        with torch.no_grad():
            fd = (
                trajectory_cost(z + dz, t, demo, norm, config)
                - trajectory_cost(z - dz, t, demo, norm, config)
            ) / (2 * eps)
        assert float(g[1, j]) == pytest.approx(float(fd), rel=1e-4, abs=1e-7)
    assert float(g[1, 12].abs()) > 0  # tau receives a gradient


def test_cost_selection_and_zero_at_the_fit():
    config = DMPConfig()
    v = _random_params(20, config)
    norm = ParamNormaliser.fit(v, config)
    z = norm.normalise(torch.as_tensor(v))
    t = torch.linspace(0.0, 1.0, 30, dtype=torch.float64).expand(20, 30)
    demo = rollout(DMPParams.from_vector(torch.as_tensor(v), 25, 2), t, config)
    for name in ("9", "10", "parameter", "trajectory", "combined"):
        c, y = Cost(name, norm, config)(z, z, t, demo)
        assert float(c) == pytest.approx(0.0, abs=1e-12)
    _, y = Cost("10", norm, config)(z, z, t, demo)
    assert float(trajectory_error_px(y, demo).max()) < 1e-9
    assert Cost("parameter", norm, config)(z, z, t, demo)[1] is None
    with pytest.raises(ValueError, match="cost.name"):
        Cost("11", norm, config)
