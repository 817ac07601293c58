"""experiments/bottleneck_floor.py: the floor of a k-unit code, and a code's live units."""

from __future__ import annotations

import numpy as np
import torch

from img2dmp.data.synthetic import generate_dataset
from img2dmp.nn import ModelConfig, build_model


def test_the_floor_falls_with_the_code_s_width_to_zero(experiment_script):
    mod = experiment_script("bottleneck_floor")
    data = generate_dataset(4, seed=3, progress=False)  # 40 samples of ten digits
    floor = mod.principal_floor(data, data, ks=(2, 10, 30, 55))
    errors = [floor[k][0].mean() for k in (2, 10, 30, 55)]
    assert errors[0] > 1.0  # two components cannot hold ten digits
    assert all(a >= b - 1e-9 for a, b in zip(errors, errors[1:], strict=False))
    assert errors[-1] < 1e-6 and floor[55][1] < 1e-20  # every component: exact
    # One digit's parameters vary less: fewer components hold them.
    twos = data.subset(np.flatnonzero(data.labels == 2))
    assert mod.principal_floor(twos, twos, ks=(2,))[2][0].mean() < errors[0]


def test_dead_units_are_counted(experiment_script):
    mod = experiment_script("bottleneck_floor")
    cfg = ModelConfig(encoder_layers=[16, 6], decoder_layers=[5], n_outputs=55, image_size=[8, 8])
    model = build_model(cfg, seed=0)
    images = np.random.default_rng(0).uniform(0, 1, (40, 8, 8)).astype(np.float32)
    last = [m for m in model.encoder.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():
        last.weight[:2] = 0.0
        last.bias[:2] = -1.0  # two units below zero for every image: dead after the ReLU
        last.bias[2:] = 100.0  # the others always on
    live, width, per_image = mod.live_units(model, images, batch=16)
    assert (live, width) == (4, 6) and per_image == 4.0


def test_the_perfect_encoder_network_holds_more_with_a_wider_code(experiment_script):
    mod = experiment_script("bottleneck_floor")
    data = generate_dataset(2, seed=5, progress=False)  # 20 samples
    narrow = mod.perfect_encoder_floor(data, data, epochs=200, code=1, hidden=35)
    wide = mod.perfect_encoder_floor(data, data, epochs=200, code=55, hidden=110)
    assert narrow.shape == wide.shape == (20,)
    assert wide.mean() < 0.5 * narrow.mean()
