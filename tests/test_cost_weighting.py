"""Cost (9) with per-unit weights from the trajectory sensitivity (cost.parameter_weighting)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from img2dmp.checkpoint import load_checkpoint, save_checkpoint
from img2dmp.dmp import DMPConfig, fit_dmp
from img2dmp.nn import ParamNormaliser, parameter_cost
from img2dmp.nn.costs import (
    Cost,
    ParameterWeighting,
    dmp_trajectory,
    trajectory_gauss_newton,
    trajectory_sensitivity,
)
from img2dmp.train import TrainConfig, read_metrics_csv, train

TINY_MODEL = {"encoder_layers": [32, 12], "decoder_layers": [16], "image_size": [16, 16]}


def _fitted(n: int, config: DMPConfig, seed: int = 0):
    """Fitted DMP vectors [n, P] and their (uneven-length) time stamps [n, T]."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, 40)
    th = np.pi * (0.2 + 1.4 * s)[None] * rng.uniform(0.6, 1.2, (n, 1))
    paths = np.stack([np.cos(th), np.sin(th) * rng.uniform(0.5, 1.5, (n, 1))], -1) * 12 + 20
    t = s[None] * rng.uniform(0.7, 1.4, (n, 1))
    return fit_dmp(t, paths, config).params.to_vector(), t


def test_gauss_newton_matrix_and_sensitivity_equal_autograd():
    """H = mean_b 1/T sum_t J^T J and s = diag(H), against the Jacobian from autograd."""
    config = DMPConfig(n_kernels=6)
    v, t = _fitted(5, config)
    norm = ParamNormaliser.fit(v, config)
    h = trajectory_gauss_newton(v, t, norm, config, batch_size=2)  # several batches
    s = trajectory_sensitivity(v, t, norm, config)
    tt = torch.as_tensor(t)
    ref = np.zeros((norm.n_params, norm.n_params))
    for b in range(len(v)):
        z = norm.normalise(torch.as_tensor(v[b : b + 1]))

        def f(z_, b=b):
            return dmp_trajectory(z_, tt[b : b + 1], norm, config)[0]  # [T, d]

        jac = torch.autograd.functional.jacobian(f, z)[:, :, 0, :]  # [T, d, P]
        jac = jac.reshape(-1, norm.n_params).numpy()
        ref += jac.T @ jac / tt.shape[1] / len(v)
    assert h.shape == ref.shape and s.shape == (norm.n_params,)
    np.testing.assert_allclose(h, ref, rtol=1e-5, atol=1e-9 * np.abs(ref).max())
    np.testing.assert_allclose(s, np.diag(ref), rtol=1e-5, atol=1e-12)
    assert s[norm.tau_index] > 0  # tau moves the path too
    assert np.linalg.eigvalsh(h)[0] > -1e-9 * np.abs(h).max()


def test_weights_are_positive_normalised_and_floored():
    config = DMPConfig()
    v, t = _fitted(40, config)
    norm = ParamNormaliser.fit(v, config)
    w = ParameterWeighting.fit(v, t, norm, config, floor=1e-2)
    assert w.kind == "trajectory"
    assert w.weights.shape == w.sensitivity.shape == (config.n_params,)
    assert (w.weights >= 1e-2).all() and np.isfinite(w.weights).all()
    # above the floor, proportional to the sensitivity with mean(sensitivity) -> 1
    big = w.sensitivity / w.sensitivity.mean() > 1e-2
    np.testing.assert_allclose(w.weights[big], w.sensitivity[big] / w.sensitivity.mean())
    assert (w.weights == 1e-2).any()  # the first kernels barely move the path
    # the record round-trips; a missing record means unweighted
    back = ParameterWeighting.from_dict(w.to_dict())
    np.testing.assert_array_equal(back.weights, w.weights)
    assert ParameterWeighting.from_dict(None) is None
    with pytest.raises(ValueError, match="missing"):
        ParameterWeighting.from_dict({"kind": "trajectory"})
    with pytest.raises(ValueError, match="> 0"):
        ParameterWeighting("trajectory", np.zeros(3), np.zeros(3), 1e-3)
    with pytest.raises(ValueError, match="floor"):
        ParameterWeighting.from_sensitivity(w.sensitivity, floor=0.0)
    # the full matrix: H / mean(diag H) + floor * I, symmetric positive definite
    full = ParameterWeighting.fit(v, t, norm, config, floor=1e-2, kind="trajectory-full")
    h = trajectory_gauss_newton(v, t, norm, config)
    assert full.weights.shape == (config.n_params, config.n_params)
    np.testing.assert_allclose(full.sensitivity, w.sensitivity)
    np.testing.assert_allclose(
        full.weights, h / np.diag(h).mean() + 1e-2 * np.eye(config.n_params), rtol=1e-9, atol=1e-12
    )
    assert np.linalg.eigvalsh(full.weights)[0] >= 1e-2 * (1 - 1e-6)
    again = ParameterWeighting.from_dict(full.to_dict())
    assert again.kind == "trajectory-full"
    np.testing.assert_array_equal(again.weights, full.weights)
    with pytest.raises(ValueError, match="shape"):
        ParameterWeighting("trajectory-full", w.weights, w.sensitivity, 1e-3)
    with pytest.raises(ValueError, match="positive definite"):
        ParameterWeighting("trajectory-full", -full.weights, w.sensitivity, 1e-3)


def test_weighted_parameter_cost_by_hand():
    zp = torch.tensor([[1.0, 2.0], [0.0, 0.0]])
    zt = torch.tensor([[0.0, 0.0], [0.0, 3.0]])
    lam = torch.tensor([2.0, 0.5])
    # (2*1 + 0.5*4 + 0 + 0.5*9) / 4 entries
    assert float(parameter_cost(zp, zt, lam)) == pytest.approx(8.5 / 4)
    assert float(parameter_cost(zp, zt, torch.ones(2))) == pytest.approx(3.5)
    m = torch.tensor([[2.0, 1.0], [1.0, 0.5]])
    # e = [1, 2]: 2 + 2*1*2 + 0.5*4 = 8; e = [0, -3]: 0.5*9 = 4.5; / (B * P = 4)
    assert float(parameter_cost(zp, zt, m)) == pytest.approx(12.5 / 4)
    assert float(parameter_cost(zp, zt, torch.diag(lam))) == pytest.approx(8.5 / 4)
    # through Cost, also inside the combined cost
    config = DMPConfig(n_kernels=6)
    v, t = _fitted(8, config)
    norm = ParamNormaliser.fit(v, config)
    w = ParameterWeighting.fit(v, t, norm, config)
    z = norm.normalise(torch.as_tensor(v, dtype=torch.float32))
    zq = z + torch.linspace(-1, 1, norm.n_params)
    tt = torch.as_tensor(t, dtype=torch.float32)
    demo = dmp_trajectory(z, tt, norm, config)
    lam = torch.as_tensor(w.weights, dtype=torch.float32)
    expect = float((((zq - z) ** 2) * lam).mean())
    c9, _ = Cost("9", norm, config, weighting=w)(zq, z, tt, demo)
    assert float(c9) == pytest.approx(expect, rel=1e-6)
    assert float(Cost("9", norm, config)(zq, z, tt, demo)[0]) != pytest.approx(expect)
    c10, _ = Cost("10", norm, config)(zq, z, tt, demo)
    comb, _ = Cost("combined", norm, config, 2.0, 0.5, weighting=w)(zq, z, tt, demo)
    assert float(comb) == pytest.approx(2.0 * expect + 0.5 * float(c10), rel=1e-6)
    with pytest.raises(ValueError, match="units"):
        Cost(
            "9",
            ParamNormaliser.fit(_fitted(8, DMPConfig(n_kernels=5))[0], DMPConfig(5)),
            config,
            weighting=w,
        )


def test_weighted_second_order_model_predicts_cost_10():
    """A small error in one unit adds s_u dz^2 px^2 to cost (10) (the point of the weights)."""
    config = DMPConfig()
    v, t = _fitted(30, config)
    norm = ParamNormaliser.fit(v, config)
    s = trajectory_sensitivity(v, t, norm, config)
    z = norm.normalise(torch.as_tensor(v))
    tt = torch.as_tensor(t)
    y = dmp_trajectory(z, tt, norm, config)
    for u in (3, 12, 30, norm.tau_index, norm.tau_index + 1, norm.n_params - 1):
        dz = torch.zeros_like(z)
        dz[:, u] = 1e-2
        c10 = float(((dmp_trajectory(z + dz, tt, norm, config) - y) ** 2).sum(-1).mean())
        assert c10 == pytest.approx(s[u] * 1e-4, rel=1e-2)


def _cfg(data_path, **cost) -> TrainConfig:
    c = {"name": "parameter", "parameter_weighting": "trajectory"}
    c.update(cost)
    return TrainConfig.from_dict(
        {
            "model": dict(TINY_MODEL),
            "data": {"path": str(data_path)},
            "optim": {"epochs": 3, "batch_size": 32, "schedule": "none", "patience": 0},
            "cost": c,
            "threads": 1,
            "progress": False,
        }
    )


@pytest.fixture(scope="module")
def toy_data(tmp_path_factory):
    from test_nn import make_toy_dataset

    return make_toy_dataset(tmp_path_factory.mktemp("w") / "toy.safetensors", n=120)


def test_training_saves_the_weights_and_resume_keeps_them(toy_data, tmp_path):
    from img2dmp.data.store import load_dataset

    ref = train(_cfg(toy_data), tmp_path / "ref")
    best = load_checkpoint(tmp_path / "ref")
    last = load_checkpoint(tmp_path / "ref" / "checkpoints" / "last.safetensors")
    rec = best.meta["parameter_weighting"]
    assert rec is not None and rec == last.meta["parameter_weighting"]
    # the weights are those of the training split, with the saved normaliser
    a = load_dataset(toy_data)
    tr = a.split == 0
    norm = ParamNormaliser.from_dict(best.meta["normaliser"])
    again = ParameterWeighting.fit(a.params[tr], a.times[tr], norm, a.dmp_config)
    np.testing.assert_allclose(rec["weights"], again.weights, rtol=1e-12)
    assert best.meta["train_config"]["cost"]["parameter_weighting"] == "trajectory"

    # 2 epochs then resume to 3 = 3 epochs at once, with the stored weights
    part = tmp_path / "part"
    train(_cfg(toy_data), part, epochs=2)
    train(_cfg(toy_data), part, resume=True, epochs=3)
    got = read_metrics_csv(part / "metrics.csv")
    for x, y in zip(ref.history, got, strict=True):
        assert y["train_cost"] == pytest.approx(x["train_cost"], rel=1e-6)
        assert y["val_error_px"] == pytest.approx(x["val_error_px"], rel=1e-6)
    last_part = part / "checkpoints" / "last.safetensors"
    assert load_checkpoint(last_part).meta["parameter_weighting"] == rec
    # resume uses the stored weights, it does not refit them: change them, resume, compare
    ck = load_checkpoint(last_part)
    meta = dict(ck.meta)
    changed = ParameterWeighting.from_dict(rec)
    changed.weights = changed.weights * 3.0
    meta["parameter_weighting"] = changed.to_dict()
    save_checkpoint(last_part, ck.model_state, meta, ck.extra)
    more = train(_cfg(toy_data), part, resume=True, epochs=4)
    assert load_checkpoint(last_part).meta["parameter_weighting"] == changed.to_dict()
    assert more.history[-1]["train_cost"] > 1.5 * more.history[-2]["train_cost"]

    # unweighted runs record None; the weighting changes the training cost
    plain = train(_cfg(toy_data, parameter_weighting="none"), tmp_path / "plain", epochs=1)
    assert load_checkpoint(tmp_path / "plain").meta["parameter_weighting"] is None
    assert plain.history[0]["train_cost"] != pytest.approx(ref.history[0]["train_cost"])
    # the full matrix, in the combined cost
    train(
        _cfg(toy_data, name="combined", parameter_weighting="trajectory-full"),
        tmp_path / "f",
        epochs=1,
    )
    rec = load_checkpoint(tmp_path / "f").meta["parameter_weighting"]
    assert rec["kind"] == "trajectory-full" and np.asarray(rec["weights"]).shape == (55, 55)


def test_old_checkpoint_without_the_record_resumes_unweighted(toy_data, tmp_path):
    """A checkpoint written before the option existed: no record, no config keys."""
    run = tmp_path / "old"
    train(_cfg(toy_data, parameter_weighting="none"), run, epochs=1)
    path = run / "checkpoints" / "last.safetensors"
    ck = load_checkpoint(path)
    meta = dict(ck.meta)
    del meta["parameter_weighting"]
    for k in ("parameter_weighting", "parameter_weight_floor"):
        del meta["train_config"]["cost"][k]
    save_checkpoint(path, ck.model_state, meta, ck.extra)
    assert "parameter_weighting" not in load_checkpoint(path).meta
    res = train(_cfg(toy_data), run, resume=True, epochs=2)  # the stored config wins
    assert len(res.history) == 2
    assert load_checkpoint(path).meta["parameter_weighting"] is None


def test_bad_weighting_option_is_rejected(toy_data):
    with pytest.raises(ValueError, match="parameter_weighting"):
        _cfg(toy_data, parameter_weighting="pixels")
    with pytest.raises(ValueError, match="parameter_weight_floor"):
        _cfg(toy_data, parameter_weight_floor=0)
