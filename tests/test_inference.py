"""The one batched inference path (img2dmp.nn.inference) and the import structure around it."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

import img2dmp.predict as predict_module
from img2dmp.data.synthetic import generate_dataset
from img2dmp.dmp import DMPParams, rollout
from img2dmp.nn import (
    ModelConfig,
    ParamNormaliser,
    build_model,
    dmp_trajectories,
    network_outputs,
    trajectory_error_px,
)
from img2dmp.predict import Predictor


@pytest.fixture(scope="module")
def setup():
    data = generate_dataset(1, seed=4, progress=False)  # 10 samples, 40 x 40
    cfg = data.dmp_config
    normaliser = ParamNormaliser.fit(data.params, cfg)
    mcfg = ModelConfig(encoder_layers=[32, 12], decoder_layers=[20], n_outputs=cfg.n_params)
    model = build_model(mcfg, seed=0)
    images = torch.as_tensor(data.images)  # [B, H, W]
    # Stamps that do not start at 0: the rollout must shift each row to start there.
    times = torch.as_tensor(data.times) + 0.25  # [B, T]
    return model, normaliser, cfg, images, times, data


def test_network_outputs_equal_the_model_batch_by_batch(setup):
    model, _, cfg, images, _, _ = setup
    model.eval()
    with torch.no_grad():
        whole = model(images)  # [B, P]
        by_three = torch.cat([model(images[lo : lo + 3]) for lo in range(0, len(images), 3)])
    z = network_outputs(model, images, batch_size=3)
    assert z.shape == (len(images), cfg.n_params) and not z.requires_grad
    assert torch.equal(z, by_three)  # the same computation, not just a close one
    torch.testing.assert_close(network_outputs(model, images), whole, rtol=0, atol=1e-6)


def test_dmp_trajectories_equal_a_direct_model_and_rollout(setup):
    model, normaliser, cfg, images, times, _ = setup
    y = dmp_trajectories(model, normaliser, cfg, images, times, batch_size=4)
    assert y.shape == (len(images), times.shape[1], cfg.n_dims) and not y.requires_grad
    with torch.no_grad():
        z = model.eval()(images)  # [B, P]
    # Independently, in float64: the network's vector un-normalised (eq. 8), rolled out
    # from t = 0 at the given stamps (eqs. 3-7).
    v = normaliser.denormalise_vector(z.double())  # [B, P]
    params = DMPParams.from_vector(v, cfg.n_kernels, cfg.n_dims)
    t = (times - times[:, :1]).double()  # [B, T]
    y_ref = rollout(params, t, cfg)  # [B, T, d]
    torch.testing.assert_close(y.double(), y_ref, rtol=0, atol=2e-3)
    err = trajectory_error_px(y.double(), y_ref)
    assert float(err.max()) < 1e-3  # px: float32 against float64, nothing more


def test_inference_leaves_the_model_in_its_mode():
    data = generate_dataset(1, seed=1, progress=False)
    cfg = data.dmp_config
    mcfg = ModelConfig(
        encoder="conv",
        conv_channels=[4, 8],
        conv_norm="batch",
        encoder_layers=[12],
        decoder_layers=[16],
        n_outputs=cfg.n_params,
    )
    model = build_model(mcfg, seed=0)
    images = torch.as_tensor(data.images)
    model.train()
    model(images)  # moves the batch norm's running averages away from their start
    z = network_outputs(model, images, batch_size=4)
    assert model.training  # given back in training mode
    with torch.no_grad():
        expected = model.eval()(images)  # batch norm with running averages, not batch stats
    torch.testing.assert_close(z, expected, rtol=0, atol=1e-5)
    assert not model.training  # and an eval-mode model stays so
    network_outputs(model.train(), images)
    assert model.training
    with pytest.raises(ValueError, match="pixels"):  # the model itself refuses the size
        network_outputs(model, torch.zeros(2, 28, 28))
    assert model.training  # restored even when the model raised


def test_inference_arguments_are_checked(setup):
    model, normaliser, cfg, images, times, _ = setup
    for bad in (0, -1, 2.5, None, True):
        with pytest.raises(ValueError, match="batch_size must be an integer >= 1"):
            network_outputs(model, images, batch_size=bad)
    assert network_outputs(model, images, batch_size=np.int64(4)).shape[0] == len(images)
    with pytest.raises(ValueError, match=r"images must be a tensor of shape \[B, H, W\]"):
        network_outputs(model, images[0])
    with pytest.raises(ValueError, match=r"times must have shape \[B, T\] with B = 10"):
        dmp_trajectories(model, normaliser, cfg, images, times[:3])
    assert network_outputs(model, images[:0]).shape == (0, cfg.n_params)
    empty = dmp_trajectories(model, normaliser, cfg, images[:0], times[:0])
    assert empty.shape == (0, times.shape[1], cfg.n_dims)


def test_predictor_goes_through_the_inference_path(setup, monkeypatch):
    model, normaliser, cfg, images, times, data = setup
    pred = Predictor(model, normaliser, cfg, meta={})
    calls = []

    def spy(fn):
        def wrapped(*args, **kwargs):
            calls.append(fn.__name__)
            return fn(*args, **kwargs)

        return wrapped

    import img2dmp.nn.inference as inference

    assert pred.backend == "torch"  # a Predictor made of a torch network computes in torch
    monkeypatch.setattr(inference, "network_outputs", spy(network_outputs))
    monkeypatch.setattr(inference, "rollout_outputs", spy(inference.rollout_outputs))
    z = pred.predict_normalised(data.images, batch_size=3)
    y = pred.trajectories_for_images(data.images, data.times + 0.25, batch_size=3)
    assert calls == ["network_outputs", "network_outputs", "rollout_outputs"]
    assert torch.equal(z, network_outputs(model, images, batch_size=3))
    assert isinstance(y, np.ndarray) and y.dtype == np.float32
    np.testing.assert_array_equal(y, dmp_trajectories(model, normaliser, cfg, images, times, 3))
    # predict_images is the same network output, un-normalised
    v = pred.predict_images(data.images, batch_size=3).to_vector()
    np.testing.assert_array_equal(v, normaliser.denormalise_vector(z.double()).numpy())


def _fresh_python(code: str) -> None:
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_predict_does_not_import_evaluate():
    _fresh_python(
        "import sys, img2dmp.predict\n"
        "assert 'img2dmp.evaluate' not in sys.modules, 'predict imports evaluate'\n"
        "assert 'matplotlib' not in sys.modules, 'predict starts matplotlib'\n"
    )


def test_old_import_paths_still_work():
    import img2dmp.data.images as images
    import img2dmp.data.plotting as plotting
    import img2dmp.evaluate as evaluate

    for name in (
        "DEFAULT_MARGIN",
        "INK_THRESHOLD",
        "ink_margin",
        "stroke_width",
        "typical_stroke_width",
        "prepare_image",
        "_match_stroke_width",
        "_decode",
    ):
        assert getattr(predict_module, name) is getattr(images, name), name
    from img2dmp.evaluate import overlay_figure

    assert overlay_figure is plotting.overlay_figure
    with pytest.raises(AttributeError, match="no_such_name"):
        evaluate.no_such_name  # noqa: B018
    # evaluate loads matplotlib only when it draws
    _fresh_python(
        "import sys, img2dmp.evaluate\nassert 'matplotlib' not in sys.modules, sorted(sys.modules)"
    )
