"""The bridges to movement_primitives and MP_PyTorch, against the real packages.

Each export is checked by rolling it out in the peer and comparing with img2dmp's exact
rollout (not by trusting the error the bridge reports); imports are checked by round
trips and by rolling out the imported DMP. The peers are the extra ``interop``
(``make setup`` installs it); without them these tests skip with that reason.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from img2dmp.data.synthetic import SyntheticConfig, generate
from img2dmp.dmp import DMPConfig, DMPParams, rollout

mpp = pytest.importorskip(
    "movement_primitives.dmp",
    reason="movement_primitives absent (pip install -e '/path/to/img2dmp[interop]')",
)
mpt = pytest.importorskip(
    "mp_pytorch.mp", reason="mp-pytorch absent (pip install -e '/path/to/img2dmp[interop]')"
)

from img2dmp import interop  # noqa: E402


@pytest.fixture(scope="module", params=["none", "goal-start"])
def digits(request):
    """The ten synthetic digits in the 28-px frame, 1 s each, fitted with ``scaling``."""
    cfg = DMPConfig(scaling=request.param)
    syn = SyntheticConfig(image_size=(28, 28), duration_s=1.0)
    data = generate(np.arange(10), syn, np.random.default_rng(0), cfg)
    return cfg, DMPParams.from_vector(data.params.astype(np.float64), 25, 2)


def _ours(p: DMPParams, t, cfg) -> np.ndarray:
    return rollout(p.to_torch(), torch.as_tensor(np.asarray(t, np.float64)), cfg).numpy()


def _distance(a, b) -> np.ndarray:
    return np.linalg.norm(np.asarray(a, np.float64) - np.asarray(b, np.float64), axis=-1)


def test_movement_primitives_rollout_within_0_05_px_of_img2dmp(digits):
    cfg, p = digits
    out = interop.to_movement_primitives(p, cfg)
    assert out.exact and out.batch_shape == (10,) and len(out.dmp) == 10
    assert all(isinstance(dmp, mpp.DMP) for dmp in out.dmp)
    assert out.error_px.max() < 0.05  # the target, in the 28-px frame
    for i in (0, 8):  # the reported errors are the peer's own open loop's
        dmp = out.dmp[i]
        t, y = dmp.open_loop()
        # np.arange(0, tau + dt, dt) in open_loop may end one step past tau.
        assert t[0] == 0 and -1e-9 < t[-1] - p.tau[i] < 1.5 * dmp.dt_
        np.testing.assert_allclose(_distance(y, _ours(p[i], t, cfg)).max(), out.error_px[i])


def test_movement_primitives_odes_coincide_its_error_is_a_late_forcing_term(digits):
    """Its RK4 step takes the phase at the step's end, t, t + dt/2, t + dt (0.9.1): first
    order in dt. The same step given the step's own times is within 1e-4 px even at 100
    steps per movement, so what remains is integration, not a difference of the ODEs."""
    from movement_primitives.dmp._dmp import dmp_step_rk4

    cfg, p = digits
    one = p[4]
    dmp = interop.to_movement_primitives(one, cfg, dt=float(one.tau) / 100, check=False).dmp
    t, y_peer = dmp.open_loop(step_function="rk4")
    ref = _ours(one, t, cfg)
    y, yd, ys = dmp.start_y.copy(), np.zeros(2), [dmp.start_y.copy()]
    zero = np.zeros(2)
    for k in range(1, len(t)):
        dt = t[k] - t[k - 1]
        dmp_step_rk4(
            *(t[k - 1] - dt, t[k] - dt, y, yd, dmp.goal_y, zero, zero, dmp.start_y, zero, zero),
            *(dmp.execution_time_, 0.0, dmp.alpha_y, dmp.beta_y, dmp.forcing_term),
        )
        ys.append(y.copy())
    assert _distance(y_peer, ref).max() > 0.1
    assert _distance(ys, ref).max() < 1e-3


def test_movement_primitives_round_trip_gives_back_the_parameters(digits):
    cfg, p = digits
    out = interop.to_movement_primitives(p[:3], cfg, check=False)
    back = interop.from_movement_primitives(out.dmp, cfg)
    assert back.exact.tolist() == [True] * 3
    np.testing.assert_allclose(back.params.to_vector(), p[:3].to_vector(), rtol=1e-13, atol=1e-9)
    assert back.error_px.max() < 0.05
    one = interop.from_movement_primitives(out.dmp[0], cfg, check=False)
    assert one.params.batch_shape == () and one.error_px is None and bool(one.exact)


def test_the_bridges_take_the_constants_a_dmp_carries_and_refuse_others(digits):
    from dataclasses import replace

    cfg, p = digits
    own = p[:2].with_config(cfg)
    other = replace(cfg, scaling="goal-start" if cfg.scaling == "none" else "none")
    for export, back in ((interop.to_movement_primitives, interop.from_movement_primitives),
                         (interop.to_mp_pytorch, interop.from_mp_pytorch)):  # fmt: skip
        out = export(own)  # no config given: the carried one, not the paper's default
        assert out.exact and out.error_px.max() < 0.05
        imported = back(out.dmp, cfg).params
        assert imported.config == cfg
        np.testing.assert_allclose(imported.to_vector(), own.to_vector(), rtol=1e-13, atol=1e-9)
        with pytest.raises(ValueError, match="config differs from the constants these DMP"):
            export(own, other)
        remembered = back(out.dmp).params  # no config: the one the export was made with
        assert remembered.config == cfg and remembered == imported


def test_an_import_of_other_dimensions_names_them(digits):
    cfg, p = digits
    out = interop.to_movement_primitives(p[:2], cfg, check=False)
    with pytest.raises(ValueError, match=r"dmps\[0\] has 2 dimensions, the config 3"):
        interop.from_movement_primitives(out.dmp, DMPConfig(n_dims=3))
    prim = interop.to_mp_pytorch(p[:2], cfg, check=False).dmp
    with pytest.raises(ValueError, match="prim has 2 dimensions, the config 3"):
        interop.from_mp_pytorch(prim, DMPConfig(n_dims=3))


def test_movement_primitives_export_keeps_the_phase_when_its_duration_changes(digits):
    cfg, p = digits
    one = p[2]
    dmp = interop.to_movement_primitives(one, cfg, check=False).dmp
    dmp.execution_time_ = 2 * float(one.tau)
    dmp.dt_ = dmp.execution_time_ / 4000
    assert dmp.forcing_term.alpha_z == cfg.alpha_x
    t, y = dmp.open_loop()
    slower = DMPParams(one.w, 2 * one.tau, one.g, one.y0)
    assert _distance(y, _ours(slower, t, cfg)).max() < 0.05


def test_movement_primitives_of_another_configuration_is_imported_by_a_fit(digits):
    cfg, p = digits
    t = np.linspace(0, 1, 101)
    demo = _ours(p[3], t, cfg)
    peer = mpp.DMP(n_dims=2, execution_time=1.0, dt=0.01, n_weights_per_dim=10)  # its defaults
    peer.imitate(t, demo)
    back = interop.from_movement_primitives(peer, cfg)
    assert not bool(back.exact)
    t_peer, y_peer = peer.open_loop()
    measured = _distance(_ours(back.params, t_peer, cfg), y_peer).max()
    np.testing.assert_allclose(back.error_px, measured, rtol=1e-9)
    assert measured < 0.1


def test_goal_start_weights_of_a_closed_shape_are_refitted_not_divided_by_zero():
    cfg = DMPConfig(scaling="goal-start")
    peer = mpp.DMP(n_dims=2, execution_time=1.0, dt=0.001, n_weights_per_dim=25)
    peer.forcing_term.weights_[:] = np.random.default_rng(1).normal(0, 200, (2, 25))
    peer.configure(start_y=np.array([10.0, 10.0]), goal_y=np.array([10.0, 20.0]))
    back = interop.from_movement_primitives(peer, cfg)
    assert not bool(back.exact) and np.isfinite(back.params.w).all()


@pytest.mark.parametrize("kind", ["dmp", "prodmp"])
def test_mp_pytorch_rollout_within_0_05_px_and_round_trip(digits, kind):
    cfg, p = digits
    out = interop.to_mp_pytorch(p, cfg, kind=kind)
    prim = out.dmp
    assert out.exact and isinstance(prim, mpt.ProDMP if kind == "prodmp" else mpt.DMP)
    y = prim.get_traj_pos().detach().numpy()  # [10, T, 2]
    t = prim.times.numpy()
    measured = _distance(y, _ours(p, t, cfg)).max(-1)
    assert measured.max() < 0.05
    np.testing.assert_allclose(out.error_px, measured, rtol=1e-9)
    back = interop.from_mp_pytorch(prim, cfg)
    assert back.exact.all()
    np.testing.assert_allclose(back.params.to_vector(), p.to_vector(), rtol=1e-13, atol=1e-9)


def test_mp_pytorch_keeps_a_two_dimensional_batch(digits):
    cfg, p = digits
    grid = DMPParams.from_vector(p[:6].to_vector().reshape(2, 3, -1), 25, 2)
    out = interop.to_mp_pytorch(grid, cfg, kind="prodmp", steps=200)
    assert out.error_px.shape == (2, 3) and list(out.dmp.add_dim) == [2, 3]
    assert interop.from_mp_pytorch(out.dmp, cfg).params.batch_shape == (2, 3)
    mp_out = interop.to_movement_primitives(grid, cfg, dt=0.01)
    assert len(mp_out.dmp) == 6 and mp_out.error_px.shape == (2, 3)


def test_prodmp_of_another_damping_is_refitted_with_its_error_stated(digits):
    cfg0, p = digits
    cfg = DMPConfig(scaling=cfg0.scaling, beta_z=8.0)  # ProDMP is critically damped only
    out = interop.to_mp_pytorch(p[:3], cfg, kind="prodmp")
    assert not out.exact
    y = out.dmp.get_traj_pos().detach().numpy()
    measured = _distance(y, _ours(p[:3], out.dmp.times.numpy(), cfg)).max(-1)
    np.testing.assert_allclose(out.error_px, measured, rtol=1e-9)
    assert measured.max() < 0.5
    dmp = interop.to_mp_pytorch(p[:3], cfg, kind="dmp")  # the Euler DMP keeps beta
    assert dmp.exact and dmp.error_px.max() < 0.05


def test_mp_pytorch_of_another_configuration_is_imported_by_a_fit(digits):
    cfg, p = digits
    t = torch.linspace(0, 1, 101, dtype=torch.float64)
    demo = torch.as_tensor(_ours(p[5], t.numpy(), cfg))
    args = dict(num_basis=10, basis_bandwidth_factor=3, num_basis_outside=0, alpha=25)
    args.update(alpha_phase=3, dt=0.01)
    prim = mpt.MPFactory.init_mp("prodmp", args, num_dof=2, tau=1.0, dtype=torch.float64)
    prim.learn_mp_params_from_trajs(t[None], demo[None])
    back = interop.from_mp_pytorch(prim, cfg)
    assert not back.exact.any()
    y = prim.get_traj_pos().detach().numpy()[0]
    measured = _distance(_ours(back.params[0], t.numpy(), cfg), y).max()
    np.testing.assert_allclose(back.error_px[0], measured, rtol=1e-9)
    assert measured < 0.1


def test_bad_input_is_refused_with_one_line_errors(digits):
    cfg, p = digits
    with pytest.raises(ValueError, match="kind must be one of .* got 'promp'"):
        interop.to_mp_pytorch(p[0], cfg, kind="promp")
    with pytest.raises(ValueError, match="steps must be an integer from 2 to 2,000 .*got 1"):
        interop.to_mp_pytorch(p[0], cfg, steps=1)
    # bounded work: ProDMP's basis grows with steps squared, the DMP's loop with steps
    with pytest.raises(ValueError, match="from 2 to 2,000 .*for prodmp.*got 1000000"):
        interop.to_mp_pytorch(p[0], cfg, steps=10**6)
    with pytest.raises(ValueError, match="from 2 to 20,000 .*for dmp.*got 10000000"):
        interop.to_mp_pytorch(p[0], cfg, kind="dmp", steps=10**7)
    for dt in (-0.01, math.nan):
        with pytest.raises(ValueError, match="dt"):
            interop.to_movement_primitives(p[0], cfg, dt=dt)
    tau = float(p[0].tau)
    for dt in (1e-8, 2 * tau):  # 1e-8 s asked the peer for 8 GB; a step past the movement
        with pytest.raises(ValueError, match=r"dt .* s for a DMP of tau .*: give from tau / "):
            interop.to_movement_primitives(p[0], cfg, dt=dt)
    peer = interop.to_movement_primitives(p[0], cfg).dmp
    peer.dt_ = 0.0
    with pytest.raises(ValueError, match=r"dmps\[0\].dt_ must be a finite number > 0, got 0"):
        interop.from_movement_primitives(peer, cfg)
    with pytest.raises(ValueError, match="expected a movement_primitives.dmp.DMP.*got str"):
        interop.from_movement_primitives("dmp.json", cfg)
    with pytest.raises(ValueError, match="non-empty sequence"):
        interop.from_movement_primitives([], cfg)
    args = dict(num_basis=25, basis_bandwidth_factor=4, num_basis_outside=0, alpha=48)
    fresh = mpt.MPFactory.init_mp("dmp", {**args, "alpha_phase": 2}, num_dof=2)
    with pytest.raises(ValueError, match="holds no parameters"):
        interop.from_mp_pytorch(fresh, cfg)
    with pytest.raises(ValueError, match="expected an mp_pytorch DMP or ProDMP, got dict"):
        interop.from_mp_pytorch({}, cfg)
    for msg in (str(e) for e in _errors(p, cfg)):
        assert "\n" not in msg


def _errors(p, cfg):
    out = []
    for call in (
        lambda: interop.to_mp_pytorch(p[0], cfg, kind="x"),
        lambda: interop.to_movement_primitives(p[0], cfg, dt=0),
        lambda: interop.from_movement_primitives(3, cfg),
    ):
        try:
            call()
        except ValueError as e:
            out.append(e)
    assert len(out) == 3
    return out


def test_a_missing_peer_names_the_extra(monkeypatch):
    from img2dmp.interop import _common

    monkeypatch.setitem(__import__("sys").modules, "mp_pytorch.mp", None)
    with pytest.raises(ImportError, match=r"pip install -e '/path/to/img2dmp\[interop\]'"):
        _common.require("mp_pytorch.mp", "mp-pytorch")
