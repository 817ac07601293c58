"""Synthetic digits: alignment, timing, ranges, determinism, DMP fits, data sets, CLI."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from img2dmp.cli import main
from img2dmp.data import load_dataset, save_dataset
from img2dmp.data import synthetic as syn
from img2dmp.data.affine import AffineRanges
from img2dmp.data.synthetic import SyntheticConfig, generate, generate_dataset
from img2dmp.data.torch_data import StoredDigits, SyntheticDigitStream
from img2dmp.dmp import DMPConfig, DMPParams, rollout

ALL = np.repeat(np.arange(10), 8)  # 8 of each digit


def _on_ink_share(images: np.ndarray, paths: np.ndarray, threshold: float = 0.5) -> float:
    # Share of path points whose nearest pixel holds ink.
    h, w = images.shape[1:]
    ij = np.rint(paths).astype(int)
    inside = (ij[..., 0] >= 0) & (ij[..., 0] < w) & (ij[..., 1] >= 0) & (ij[..., 1] < h)
    rows = np.arange(len(images))[:, None]
    vals = images[rows, ij[..., 1].clip(0, h - 1), ij[..., 0].clip(0, w - 1)]
    return float(((vals > threshold) & inside).mean())


@pytest.mark.parametrize("affine", [AffineRanges.identity(), AffineRanges()])
def test_paths_lie_on_the_ink_before_noise(affine):
    cfg = SyntheticConfig(noise_amount=0.0, affine=affine)
    data = generate(ALL, cfg, np.random.default_rng(0))
    assert _on_ink_share(data.images, data.trajectories) >= 0.95
    # ... and not by accident: a path of another sample mostly misses the ink.
    shuffled = np.roll(data.trajectories, 1, axis=0)
    assert _on_ink_share(data.images, shuffled) < 0.6


def test_shapes_dtypes_times_and_labels():
    data = generate(ALL, SyntheticConfig(), np.random.default_rng(1))
    m = ALL.size
    p = DMPConfig().n_params
    assert data.images.shape == (m, 40, 40) and data.images.dtype == np.float32
    assert data.trajectories.shape == (m, 301, 2) and data.trajectories.dtype == np.float32
    assert data.times.shape == (m, 301) and data.times.dtype == np.float32
    np.testing.assert_allclose(data.times[0], np.arange(301) * 0.01, atol=1e-6)
    assert data.params.shape == (m, p) and data.params.dtype == np.float32
    assert data.labels.dtype == np.int64 and np.array_equal(data.labels, ALL)
    assert data.images.min() >= 0 and data.images.max() <= 1
    data.validate()
    # Every digit fits in its image with a margin for the pen (2.4 px wide).
    assert data.trajectories.min() >= 1.7 and data.trajectories.max() <= 39 - 1.7


def test_timing_is_minimum_jerk_along_the_path():
    cfg = SyntheticConfig(duration_s=2.0, dt_s=0.005, affine=AffineRanges.identity())
    data = generate(np.array([7, 1, 4]), cfg, np.random.default_rng(2))  # straight lines
    assert data.trajectories.shape[1] == 401
    y = data.trajectories.astype(np.float64)
    arc = np.concatenate(
        [np.zeros((3, 1)), np.cumsum(np.linalg.norm(np.diff(y, axis=1), axis=-1), 1)], 1
    )
    u = np.arange(401) / 400.0
    expect = (10 * u**3 - 15 * u**4 + 6 * u**5) * arc[:, -1:]
    # Chords cut corners only where lines meet: the arc length follows s(t) closely.
    assert np.abs(arc - expect).max() < 0.02 * arc[:, -1].min()
    step = np.linalg.norm(np.diff(y, axis=1), axis=-1)
    assert step[:, 0].max() < 1e-3 and step[:, -1].max() < 1e-3  # at rest at both ends
    assert (step[:, 195:205].mean(1) > 10 * step[:, :5].mean(1)).all()


def test_element_ranges_are_respected():
    cfg = SyntheticConfig(line_length_rel=0.1, line_angle_deg=3.0, start_shift=0.02)
    template = syn.DIGIT_TEMPLATES[7]
    anchor, elements = syn.sample_element_params(template, 2000, cfg, np.random.default_rng(3))
    dense = syn.build_paths(template, anchor, elements)
    k = syn._LINE_POINTS
    first = dense[:, k - 1] - dense[:, 0]  # the first line, measured on the path
    nominal = template.elements[0]
    angle = np.degrees(np.arctan2(first[:, 1], first[:, 0]))
    length = np.linalg.norm(first, axis=-1)
    assert np.abs(angle - nominal.angle_deg).max() <= 3.0 + 1e-9
    assert np.abs(angle - nominal.angle_deg).max() > 2.8  # the whole range is used
    assert length.min() >= 0.9 * nominal.length - 1e-9
    assert length.max() <= 1.1 * nominal.length + 1e-9
    assert np.abs(dense[:, 0] - template.start).max() <= 0.02 + 1e-12
    # An arc's parameters stay in their ranges too.
    cfg = SyntheticConfig(arc_axis_rel=0.05, arc_tilt_deg=2.0, arc_angle_deg=4.0)
    arc = syn.DIGIT_TEMPLATES[0].elements[0]
    _, (p,) = syn.sample_element_params(syn.DIGIT_TEMPLATES[0], 500, cfg, np.random.default_rng(4))
    assert np.abs(p["a"] / arc.a - 1).max() <= 0.05 + 1e-12
    assert np.abs(p["start_deg"] - arc.start_deg).max() <= 4.0 + 1e-12
    assert np.abs(p["tilt_deg"] - arc.tilt_deg).max() <= 2.0 + 1e-12


def test_zero_ranges_give_one_fixed_path_per_digit():
    still = dict(line_length_rel=0, line_angle_deg=0, arc_axis_rel=0, arc_tilt_deg=0)
    cfg = SyntheticConfig(
        **still, arc_angle_deg=0, start_shift=0, affine=AffineRanges.identity(), noise_amount=0
    )
    data = generate(np.array([3, 3, 3]), cfg, np.random.default_rng(5))
    np.testing.assert_array_equal(data.trajectories[0], data.trajectories[2])
    np.testing.assert_array_equal(data.images[0], data.images[1])
    # The nominal 0 is the ellipse of its template: every point at its scaled radius.
    data = generate(np.array([0]), cfg, np.random.default_rng(5))
    arc = syn.DIGIT_TEMPLATES[0].elements[0]
    rel = (data.trajectories[0] - 19.5) / cfg.unit_px
    tilt = np.radians(arc.tilt_deg)
    u = rel @ np.array([[np.cos(tilt), -np.sin(tilt)], [np.sin(tilt), np.cos(tilt)]])
    np.testing.assert_allclose((u[:, 0] / arc.a) ** 2 + (u[:, 1] / arc.b) ** 2, 1.0, atol=3e-3)


def test_other_image_sizes_scale_the_digit():
    cfg = SyntheticConfig(image_size=64, affine=AffineRanges.identity())
    small = generate(
        ALL[:20], SyntheticConfig(affine=AffineRanges.identity()), np.random.default_rng(6)
    )
    big = generate(ALL[:20], cfg, np.random.default_rng(6))
    assert big.images.shape == (20, 64, 64)
    np.testing.assert_allclose(
        (big.trajectories - 31.5) / 64, (small.trajectories - 19.5) / 40, atol=1e-4
    )
    assert _on_ink_share(big.images, big.trajectories) > 0.9


def test_stored_dmp_reproduces_each_path():
    data = generate(ALL, SyntheticConfig(), np.random.default_rng(7))
    cfg = data.dmp_config
    params = DMPParams.from_vector(torch.from_numpy(data.params).double(), cfg.n_kernels, 2)
    y = rollout(params, torch.from_numpy(data.times).double(), cfg).numpy()
    err = np.linalg.norm(y - data.trajectories, axis=-1).mean(-1)  # [M] px
    assert err.mean() < 0.1
    np.testing.assert_allclose(err, data.fit_error_px, atol=5e-3)
    # tau, g, y0 are the duration, last and first points (eq. 8).
    np.testing.assert_allclose(params.tau.numpy(), 3.0, rtol=1e-6)
    np.testing.assert_allclose(params.y0.numpy(), data.trajectories[:, 0], atol=1e-4)
    np.testing.assert_allclose(params.g.numpy(), data.trajectories[:, -1], atol=1e-4)


def test_start_and_goal_differ_in_both_coordinates():
    cfg = SyntheticConfig(min_start_goal_rel=0.05)
    data = generate(np.repeat(np.arange(10), 30), cfg, np.random.default_rng(8))
    gap = np.abs(data.trajectories[:, -1] - data.trajectories[:, 0]).min(-1)
    assert gap.min() >= 0.05 * 40 - 1e-4


def test_end_clearance_of_simple_strokes():
    theta = np.linspace(0.0, 2.0 * np.pi, 721)
    ring = 10.0 * np.stack([np.cos(theta), np.sin(theta)], -1)  # closed: both ends covered
    open_ring = ring[: 721 - 60]  # 30 degrees left open
    line = np.stack([np.linspace(0, 30, 50), np.zeros(50)], -1)
    clear = [syn.end_clearance(p[None], exclusion=8.0) for p in (ring, open_ring)]
    clear.append(syn.end_clearance(line[None], exclusion=5.0))
    (start, end), (start_open, end_open), (start_line, end_line) = clear
    assert start[0] < 1e-9 and end[0] < 1e-9
    gap = 2 * 10.0 * np.sin(np.deg2rad(15.0))  # chord of the 30-degree gap
    np.testing.assert_allclose([start_open[0], end_open[0]], gap, rtol=1e-3)
    # A straight stroke: the nearest segment left is the one past the exclusion.
    np.testing.assert_allclose([start_line[0], end_line[0]], 5.0, atol=30 / 49)
    assert np.isinf(syn.end_clearance(line[None, :3], exclusion=50.0)[0]).all()
    with pytest.raises(ValueError, match="paths"):
        syn.end_clearance(line, exclusion=1.0)


def test_both_ends_of_every_stroke_show_in_the_image(monkeypatch):
    cfg = SyntheticConfig()
    data = generate(np.repeat(np.arange(10), 20), cfg, np.random.default_rng(3))
    clear = cfg.min_end_clearance_rel * 40
    start, end = syn.end_clearance(data.trajectories, 2 * clear)
    assert min(start.min(), end.min()) >= clear - 1e-3
    # A 0 closed over its own start, as in the first templates: no draw can pass.
    closed = syn.DigitTemplate(centre=(0.0, 0.0), elements=(syn.Arc(0.6, 0.95, 8, -100, -520),))
    monkeypatch.setitem(syn.DIGIT_TEMPLATES, 0, closed)
    with pytest.raises(ValueError, match="min_end_clearance_rel"):
        generate(np.zeros(4, int), cfg, np.random.default_rng(0))
    unchecked = SyntheticConfig(min_end_clearance_rel=0)
    data = generate(np.zeros(4, int), unchecked, np.random.default_rng(0))
    assert syn.end_clearance(data.trajectories, 2 * clear)[0].max() < 1.0


def test_data_set_is_deterministic_and_split_per_digit():
    cfg = SyntheticConfig(digits=(2, 5))
    a = generate_dataset(10, cfg, seed=11, splits=(0.6, 0.2, 0.2), progress=False)
    b = generate_dataset(10, cfg, seed=11, splits=(0.6, 0.2, 0.2), progress=False)
    c = generate_dataset(10, cfg, seed=12, splits=(0.6, 0.2, 0.2), progress=False)
    for k, v in a.arrays().items():
        np.testing.assert_array_equal(v, getattr(b, k))
    assert not np.array_equal(a.images, c.images)
    assert a.meta["seed"] == 11 and a.meta["source"]["config"]["digits"] == [2, 5]
    for d in (2, 5):
        s = a.split[a.labels == d]
        assert (s == 0).sum() == 6 and (s == 1).sum() == 2 and (s == 2).sum() == 2
    assert sorted(set(a.labels.tolist())) == [2, 5]


def test_data_set_does_not_depend_on_the_number_of_workers(monkeypatch):
    monkeypatch.setattr(syn, "CHUNK", 10)  # several chunks from a small data set
    cfg = SyntheticConfig(digits=(1, 8))
    one = generate_dataset(25, cfg, seed=3, progress=False, workers=1)
    two = generate_dataset(25, cfg, seed=3, progress=False, workers=2)
    for k, v in one.arrays().items():
        np.testing.assert_array_equal(v, getattr(two, k))


def test_saved_data_set_round_trips_and_feeds_a_dataloader(tmp_path):
    data = generate_dataset(3, SyntheticConfig(), seed=1, progress=False)
    path = save_dataset(tmp_path / "syn.safetensors", data)
    back = load_dataset(path)
    assert SyntheticConfig.from_dict(back.meta["source"]["config"]) == SyntheticConfig()
    ds = StoredDigits(path, split="train")
    assert len(ds) == int((data.split == 0).sum())
    batch = next(iter(DataLoader(ds, batch_size=4)))
    assert batch["image"].shape == (4, 1, 40, 40) and batch["trajectory"].shape == (4, 301, 2)
    assert batch["params"].shape == (4, 55) and batch["label"].dtype == torch.int64


def test_stream_gives_distinct_samples_across_workers_and_epochs():
    cfg = SyntheticConfig(digits=(3,))
    stream = SyntheticDigitStream(cfg, samples_per_epoch=24, seed=5, chunk_size=8)
    loader = DataLoader(stream, batch_size=6, num_workers=2)

    def epoch():
        return torch.cat([b["trajectory"] for b in loader])  # [24, T, 2]

    first = epoch()
    assert first.shape[0] == 24
    starts = first[:, 0].numpy()
    assert len(np.unique(starts.round(5), axis=0)) == 24  # no sample twice
    np.testing.assert_array_equal(epoch().numpy(), first.numpy())  # same seed, same epoch
    stream.set_epoch(1)
    second = epoch().numpy()
    assert not np.isin(second[:, 0, 0], starts[:, 0]).any()
    single = torch.cat([b["trajectory"] for b in DataLoader(stream, batch_size=6)])
    assert single.shape[0] == 24


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"digits": ()}, "digits"),
        ({"digits": (3, 10)}, "digits must be integers 0-9, got 10"),
        ({"image_size": (-40, 40)}, "image_size"),
        ({"pen_width_rel": -0.1}, "pen_width_rel"),
        ({"duration_s": 0.0}, "duration_s"),
        ({"noise_amount": 1.5}, "noise_amount"),
        ({"line_length_rel": 1.2}, "line_length_rel"),
        ({"arc_angle_deg": -1.0}, "arc_angle_deg"),
    ],
)
def test_bad_configuration_is_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SyntheticConfig(**kwargs)


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="not among the configured digits"):
        generate(np.array([4]), SyntheticConfig(digits=(2,)))
    with pytest.raises(ValueError, match="samples_per_digit"):
        generate_dataset(0, progress=False)
    with pytest.raises(ValueError, match="splits"):
        generate_dataset(2, splits=(0.5, 0.5, 0.5), progress=False)
    with pytest.raises(ValueError, match=r"unknown field\(s\) pen_size; known: digits, "):
        SyntheticConfig.from_dict({"pen_size": 3})
    with pytest.raises(ValueError, match=r"unknown field\(s\) affine\.shaer; known: "):
        SyntheticConfig.from_dict({"affine": {"shaer": 0.1}})


def test_cli_generate_and_preview(tmp_path, capsys):
    out = tmp_path / "two.safetensors"
    code = main(
        [
            "generate",
            "--out",
            str(out),
            "--digits",
            "2",
            "--per-digit",
            "5",
            "--image-size",
            "32",
            "--seed",
            "4",
            "--no-progress",
            "--workers",
            "1",
        ]
    )
    assert code == 0
    data = load_dataset(out)
    assert set(data.labels.tolist()) == {2} and data.images.shape == (5, 32, 32)
    png = tmp_path / "p.png"
    assert main(["preview", "--data", str(out), "--out", str(png), "--digits", "2", "--dmp"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["generate", "--out", str(out), "--digits", "2", "--no-progress"]) == 2  # exists
    assert main(["generate", "--out", str(tmp_path / "x.st"), "--digits", "12"]) == 2
    assert main(["generate", "--out", str(tmp_path / "x.st"), "--digits", ""]) == 2
    err = capsys.readouterr().err
    assert "exists" in err and "0-9, got 12" in err and "at least one digit" in err
