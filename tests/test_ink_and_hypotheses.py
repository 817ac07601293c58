"""Image-consistency cost terms and the winner-takes-all cost of several hypotheses."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from img2dmp.dmp import DMPConfig
from img2dmp.nn import Cost, ModelConfig, ParamNormaliser, build_model, split_hypotheses
from img2dmp.nn.costs import dmp_trajectory
from img2dmp.nn.ink import ink_attraction, ink_coverage, ink_distance_map, sample_map


def _line_image(h=28, w=28, row=14, c0=5, c1=22) -> torch.Tensor:
    img = torch.zeros(1, h, w)
    img[0, row, c0 : c1 + 1] = 1.0  # a one-pixel horizontal stroke
    return img


def _path_along(row: float, c0=5.0, c1=22.0, t=400) -> torch.Tensor:
    x = torch.linspace(c0, c1, t, dtype=torch.float64)
    return torch.stack([x, torch.full_like(x, row)], -1)[None]  # [1, T, 2]


def test_a_path_on_the_ink_costs_nothing_and_shifting_it_off_costs_the_square():
    img = _line_image()
    dist = ink_distance_map(img)
    assert float(ink_attraction(_path_along(14.0), dist)) == 0.0
    # (sampled points 0.04 px apart: an ink pixel's nearest point is at most 0.02 px away)
    assert float(ink_coverage(_path_along(14.0), img, tolerance_px=0.0)) < 1e-3
    for shift in (0.5, 2.0, 3.0):
        a = float(ink_attraction(_path_along(14.0 + shift), dist))
        assert a == pytest.approx(shift**2, rel=1e-6)  # distance map is exact across a line
        c = float(ink_coverage(_path_along(14.0 + shift), img, tolerance_px=0.0))
        assert c == pytest.approx(shift**2, rel=0.02)
    # coverage sees the ink a path leaves out: half the line untouched costs more
    half = _path_along(14.0, c0=5.0, c1=13.0)
    assert float(ink_coverage(half, img)) > 10 * float(ink_coverage(_path_along(14.0), img))
    # attraction does not: the half path lies on ink
    assert float(ink_attraction(half, dist)) == 0.0


def test_points_outside_the_image_are_pulled_back():
    img = _line_image()
    far = _path_along(14.0)
    far[..., 0] += 40.0  # every point 40+ px right of the image
    assert float(ink_attraction(far, ink_distance_map(img))) > 30.0**2


def test_ink_terms_pass_gradcheck():
    img = _line_image()
    img[0, 10:18, 9] = 0.8  # a second, fainter stroke
    dist = ink_distance_map(img).double()
    y = _path_along(13.3, t=40) + 0.17 * torch.randn(1, 40, 2, dtype=torch.float64)
    y.requires_grad_()
    # away from pixel centres and ties the terms are smooth in the path
    assert torch.autograd.gradcheck(lambda p: ink_attraction(p, dist), (y,), eps=1e-6, atol=1e-5)
    assert torch.autograd.gradcheck(
        lambda p: ink_coverage(p, img.double(), tolerance_px=0.5), (y,), eps=1e-6, atol=1e-5
    )
    v = sample_map(dist, torch.tensor([[[5.0, 14.0], [5.0, 16.0]]], dtype=torch.float64))
    assert v.tolist() == [[0.0, 2.0]]


def test_pen_up_points_are_not_pulled_and_do_not_cover():
    img = _line_image()
    y = torch.cat([_path_along(14.0, t=40), torch.ones(1, 40, 1, dtype=torch.float64)], -1)
    y[0, 20:, 2] = 0.0  # pen up over the second half, which is far off the ink
    y[0, 20:, 1] = 25.0
    assert float(ink_attraction(y, ink_distance_map(img))) == 0.0
    cov_up = float(ink_coverage(y, img, tolerance_px=0.0))
    y[0, 20:, 2] = 1.0
    assert float(ink_attraction(y, ink_distance_map(img))) > 10.0
    assert cov_up > 0.0  # the ink under the lifted half is not covered


def _setup(k: int, seed: int = 0):
    cfg = DMPConfig()
    rng = np.random.default_rng(seed)
    params = rng.normal(size=(64, cfg.n_params))
    params[:, cfg.n_kernels * 2] = 3.0 + rng.random(64)  # tau > 0
    norm = ParamNormaliser.fit(params, cfg)
    torch.manual_seed(seed)
    model = build_model(ModelConfig(image_size=[16, 16], encoder_layers=[32, 8], hypotheses=k))
    return cfg, norm, model


def test_one_hypothesis_is_the_single_head_cost_exactly():
    cfg, norm, model = _setup(1)
    x = torch.rand(6, 16, 16)
    z = model(x)
    t = torch.linspace(0, 3, 50).expand(6, 50)
    traj = 20 * torch.rand(6, 50, 2)
    zt = torch.randn(6, cfg.n_params)
    for name in ("trajectory", "parameter", "combined"):
        single = Cost(name, norm, cfg)
        general = Cost(name, norm, cfg)
        a, _ = single(z, zt, t, traj)
        b, _ = general._general(z, zt, t, traj, None)
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)


def test_winner_takes_all_learns_from_the_nearest_hypothesis_and_scores_it():
    cfg, norm, model = _setup(3)
    x = torch.rand(4, 16, 16)
    out = model(x).detach()
    z, logits = split_hypotheses(out, 3)
    t = torch.linspace(0, 3, 50).expand(4, 50)
    # the demonstration is hypothesis 2's own path for every sample
    target = dmp_trajectory(z[:, 2], t, norm, cfg).detach()
    cost = Cost("trajectory", norm, cfg, hypotheses=3, wta_relax=0.0, score_weight=1.0)
    out = out.clone().requires_grad_()
    loss, y_top = cost(out, torch.zeros(4, cfg.n_params), t, target)
    ce = torch.nn.functional.cross_entropy(logits, torch.full((4,), 2))
    assert float(loss.detach()) == pytest.approx(float(ce), rel=1e-5)  # the winner costs 0
    loss.backward()
    g = split_hypotheses(out.grad, 3)[0]  # [B, K, P]
    assert float(g[:, 2].abs().sum()) == 0.0  # an exact winner has nothing to learn
    assert float(g[:, :2].abs().sum()) == 0.0  # the losers get nothing without relaxation
    # the relaxed cost moves the losers a little, so that no head dies
    relaxed = Cost("trajectory", norm, cfg, hypotheses=3, wta_relax=0.1)
    out.grad = None
    relaxed(out, torch.zeros(4, cfg.n_params), t, target)[0].backward()
    assert float(split_hypotheses(out.grad, 3)[0][:, :2].abs().sum()) > 0.0
    assert y_top.shape == (4, 50, 2)
