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


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("steps", 2.5, "refine steps must be an integer from 0 to 10000, got 2.5"),
        ("steps", "30", "refine steps must be an integer from 0 to 10000, got '30'"),
        ("steps", 10**9, "from 0 to 10000, got 1000000000"),
        ("steps", True, "got True"),
        ("lr", -0.1, "refine lr must be"),
        ("coverage_tolerance_px", 0.0, "refine coverage_tolerance_px must be a finite number > 0"),
    ],
)
def test_refine_options_are_checked_where_they_are_made(field, value, message):
    from img2dmp.nn.refine import RefineOptions

    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        RefineOptions(**{field: value})
    assert RefineOptions(steps=np.int64(3)).steps == 3  # NumPy integers are integers


def test_refinement_pulls_a_dmp_onto_the_ink_and_the_prior_holds_it_back():
    from img2dmp.dmp import fit_dmp
    from img2dmp.nn.refine import RefineOptions, refine

    cfg = DMPConfig()
    img = _line_image()
    t = np.linspace(0.0, 1.0, 100)
    off = _path_along(16.0, t=100)[0].numpy()  # 2 px below the stroke
    fit = fit_dmp(t, off, cfg)
    params = np.stack([fit.params.to_vector()] * 4)
    spread = params + np.random.default_rng(0).normal(0, 1.0, params.shape)
    spread[:, cfg.n_kernels * cfg.n_dims] = params[0, cfg.n_kernels * cfg.n_dims]  # tau > 0
    norm = ParamNormaliser.fit(spread, cfg)
    z0 = norm.normalise(torch.as_tensor(params[:1]))
    times = torch.as_tensor(t)[None]
    dist = ink_distance_map(img).double()

    def attraction(z):
        return float(ink_attraction(dmp_trajectory(z, times, norm, cfg), dist))

    before = attraction(z0)
    assert before == pytest.approx(4.0, rel=0.05)
    z = refine(z0, img, times, norm, cfg, RefineOptions(steps=60, lr=0.1, prior_weight=0.01))
    assert attraction(z) < 0.25 * before
    held = refine(z0, img, times, norm, cfg, RefineOptions(steps=60, lr=0.1, prior_weight=1e4))
    assert attraction(held) > 0.8 * before
    assert torch.equal(refine(z0, img, times, norm, cfg, RefineOptions(steps=0)), z0.double())


def test_refinements_adam_is_torchs_adam_bit_for_bit():
    # refine's own Adam (written out: torch.optim imports torch._dynamo, seconds of a
    # one-image predict) against torch.optim.Adam on a non-convex function.
    from img2dmp.nn.refine import _Adam

    def cost(z):
        weights = torch.arange(z.numel(), dtype=z.dtype).reshape(z.shape)
        return ((z**3).sin() * weights).sum() + (z**2).sum()

    z0 = torch.randn(6, 55, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    ours, theirs = z0.clone().requires_grad_(), z0.clone().requires_grad_()
    adam, opt = _Adam(ours, 0.02), torch.optim.Adam([theirs], lr=0.02)
    for _ in range(30):
        ours.grad = None
        cost(ours).backward()
        adam.step()
        opt.zero_grad(set_to_none=True)
        cost(theirs).backward()
        opt.step()
    assert not torch.equal(ours.detach(), z0)
    assert torch.equal(ours.detach(), theirs.detach())


@pytest.fixture(scope="module")
def three_hypothesis_run(tmp_path_factory):
    from img2dmp.data.store import save_dataset
    from img2dmp.data.synthetic import generate_dataset
    from img2dmp.training import TrainConfig, train

    root = tmp_path_factory.mktemp("k3")
    save_dataset(root / "d.safetensors", generate_dataset(12, seed=2, progress=False))
    cfg = TrainConfig.from_dict(
        {
            "model": {"encoder_layers": [48, 20], "hypotheses": 3},
            "data": {"path": str(root / "d.safetensors")},
            "optim": {"epochs": 2, "batch_size": 16},
            "cost": {"ink_weight": 0.5, "coverage_weight": 0.5},
            "threads": 1,
            "progress": False,
        }
    )
    res = train(cfg, root / "run")
    return root, res


def test_a_three_hypothesis_network_trains_and_predict_ranks_its_hypotheses(three_hypothesis_run):
    import json

    from PIL import Image

    from img2dmp import cli
    from img2dmp.predict import Predictor

    root, res = three_hypothesis_run
    assert np.isfinite(res.best_val_error_px) and len(res.history) == 2
    pred = Predictor.load(root / "run")
    assert pred.n_hypotheses == 3
    img = np.zeros((80, 80), np.uint8) + 255
    img[20:60, 38:43] = 0  # a dark "1" on white
    Image.fromarray(img).save(root / "one.png")
    out = root / "pred"
    assert cli.main(["predict", "--model", str(root / "run"), str(root / "one.png"),
                     "--out", str(out), "--overlay", "--points", "20"]) == 0  # fmt: skip
    rec = json.loads((out / "one_dmp.json").read_text())
    probs = [h["probability"] for h in rec["hypotheses"]]
    assert [h["rank"] for h in rec["hypotheses"]] == [1, 2, 3]
    assert probs == sorted(probs, reverse=True) and sum(probs) == pytest.approx(1.0)
    assert rec["params"] == rec["hypotheses"][0]["params"]  # the top one is the one written
    rows = (out / "one_trajectory.csv").read_text().splitlines()
    assert rows[0].startswith("rank,probability,t_s,x_model_px,y_model_px,x_image_px")
    assert len(rows) == 1 + 3 * 20
    assert (out / "one_overlay.png").stat().st_size > 1000
    # the robot's input (predict_paths) is the top hypothesis
    from img2dmp.dmp import DMPParams

    [(top, _)] = pred.predict_paths([root / "one.png"])
    written = DMPParams.from_dict(rec["params"]).to_vector()
    np.testing.assert_allclose(top.to_vector(), written, rtol=1e-6)


def test_unlabelled_images_add_their_ink_terms_to_a_training_step():
    from img2dmp.training import train_step

    cfg, norm, model = _setup(2)
    cost = Cost("trajectory", norm, cfg, hypotheses=2, ink_weight=1.0, coverage_weight=1.0)
    x = torch.zeros(4, 16, 16)
    x[:, 8, 3:13] = 1.0  # a stroke on every image
    t = torch.linspace(0, 3, 30).expand(4, 30)
    traj = torch.stack([torch.linspace(3, 12, 30), torch.full((30,), 8.0)], -1).expand(4, 30, 2)
    zt = torch.zeros(4, cfg.n_params)
    extra = cost.image_terms(model(x).detach(), x, t)
    assert float(extra) > 0.0  # a random network does not write on the ink
    grads = []
    for unlabelled in (None, x.clone()):
        m = build_model(ModelConfig(image_size=[16, 16], encoder_layers=[32, 8], hypotheses=2))
        m.load_state_dict(model.state_dict())
        opt = torch.optim.SGD(m.parameters(), lr=0.0)  # measure, do not move
        train_step(m, opt, cost, x, t, traj, zt, unlabelled=unlabelled)
        grads.append(torch.cat([p.grad.flatten() for p in m.parameters()]))
    assert not torch.allclose(grads[0], grads[1])


def test_unlabelled_mnist_images_never_come_from_the_validation_or_test_part():
    from pathlib import Path

    from img2dmp.data.mnist import load_mnist, unlabelled_images
    from img2dmp.data.recorded import split_of_index

    mnist = Path(__file__).resolve().parents[2] / "shared" / "data" / "mnist"
    if not mnist.is_dir():
        pytest.skip(f"MNIST not found at {mnist} (../shared/data/mnist)")
    train, _ = load_mnist(mnist, "train")
    part = split_of_index(range(len(train)))
    images = unlabelled_images(mnist, seed=3)
    assert len(images) == int((part == 0).sum()) + 10_000
    seen = {a.tobytes() for a in images}
    held_out = np.flatnonzero(part != 0)[:300]
    assert not any(train[i].tobytes() in seen for i in held_out)
    assert sum(train[i].tobytes() in seen for i in np.flatnonzero(part == 0)[:300]) == 300


def test_the_path_cost_ignores_timing_and_passes_gradcheck():
    from img2dmp.metrics import path_error_px
    from img2dmp.metrics import resample_by_arc_length as resample_numpy
    from img2dmp.nn.costs import path_cost, resample_by_arc_length

    u = torch.linspace(0, 1, 120, dtype=torch.float64)

    def circle(s):
        return torch.stack([10 + 6 * torch.cos(6 * s), 10 + 6 * torch.sin(6 * s)], -1)

    even, uneven = circle(u)[None], circle(u**2)[None]  # one curve, two speeds
    assert float(path_cost(uneven, even)) < 1e-3
    assert float(((uneven - even) ** 2).sum(-1).mean()) > 1.0  # cost (10) sees the timing
    rng = torch.Generator().manual_seed(0)
    a = torch.randn(3, 50, 2, generator=rng, dtype=torch.float64).cumsum(1)
    b = torch.randn(3, 50, 2, generator=rng, dtype=torch.float64).cumsum(1)
    np.testing.assert_allclose(  # the metric's own resampling, in torch
        resample_by_arc_length(a, 64).numpy(), resample_numpy(a.numpy(), 64), atol=1e-9
    )
    assert (path_cost(a, b).sqrt() >= torch.as_tensor(path_error_px(a.numpy(), b.numpy()))).all()
    a.requires_grad_()
    assert torch.autograd.gradcheck(lambda p: path_cost(p, b), (a,), eps=1e-6, atol=1e-5)
