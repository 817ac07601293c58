"""Evaluation statistics (Table I), Fig.-4 pictures, prediction from image files."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from img2dmp import cli
from img2dmp.data.render import render_paths
from img2dmp.data.store import load_dataset, save_dataset
from img2dmp.data.synthetic import generate_dataset
from img2dmp.dmp import DMPParams, rollout
from img2dmp.evaluate import error_statistics, evaluate, format_table, summarise
from img2dmp.predict import (
    DEFAULT_MARGIN,
    Predictor,
    ink_margin,
    prepare_image,
    stroke_width,
)
from img2dmp.train import TrainConfig, train


@pytest.fixture(scope="module")
def model_and_data(tmp_path_factory):
    root = tmp_path_factory.mktemp("evp")
    data = root / "d.safetensors"
    save_dataset(data, generate_dataset(12, seed=5, progress=False))
    cfg = TrainConfig.from_dict(
        {
            "model": {"encoder_layers": [48, 20], "decoder_layers": [35]},
            "data": {"path": str(data)},
            "optim": {"epochs": 3, "batch_size": 16},
            "threads": 1,
            "progress": False,
        }
    )
    train(cfg, root / "run")
    return root / "run", data


def test_statistics_by_hand():
    e = np.array([1.0, 2.0, 3.0, 4.0, 10.0])
    s = error_statistics(e)
    assert (s["n"], s["mean"], s["median"], s["max"]) == (5, 4.0, 3.0, 10.0)
    assert s["std"] == pytest.approx(np.sqrt((9 + 4 + 1 + 0 + 36) / 5))  # ddof 0
    assert s["p95"] == pytest.approx(4.0 + 0.8 * 6.0)  # linear interpolation, rank 3.8
    summ = summarise(e, np.array([1, 1, 2, 2, 2]))
    assert summ["per_digit"]["1"]["mean"] == 1.5 and summ["per_digit"]["2"]["n"] == 3
    assert "all" in format_table(summ) and error_statistics([])["n"] == 0


def test_evaluate_matches_an_independent_rollout(model_and_data, tmp_path):
    run, data_path = model_and_data
    res = evaluate(run, data_path, split="test", out_dir=tmp_path, n_figures=6)
    data = load_dataset(data_path).select_split("test")
    pred = Predictor.load(run)
    params = pred.predict_images(data.images).to_torch()
    y = rollout(params, data.times.astype(np.float64), pred.dmp_config).numpy()  # [M, T, 2]
    err = np.linalg.norm(y - data.trajectories, axis=-1).mean(-1)  # [M]
    assert np.allclose(res["errors_px"], err, rtol=1e-4, atol=1e-4)
    assert res["overall"]["mean"] == pytest.approx(err.mean(), rel=1e-4)
    assert res["overall"]["n"] == len(data)
    saved = json.loads((tmp_path / "evaluation.json").read_text())
    assert saved["overall"] == res["overall"] and set(saved["per_digit"]) == set(
        str(d) for d in np.unique(data.labels)
    )
    assert (tmp_path / "evaluation.txt").read_text().startswith("trajectory error")
    with Image.open(tmp_path / "examples.png") as im:
        assert im.size[0] > 200
    res2 = evaluate(run, data_path, split="all", digits=[3])
    assert set(res2["per_digit"]) == {"3"}
    with pytest.raises(ValueError, match="split"):
        evaluate(run, data_path, split="dev")


def _save(path: Path, grey: np.ndarray) -> Path:
    Image.fromarray(np.clip(grey * 255, 0, 255).astype(np.uint8)).save(path)
    return path


def test_prepare_image_polarity_size_and_framing(tmp_path):
    # A '7'-like stroke drawn small, off-centre, in a large non-square canvas.
    pts = np.array([[30.0, 40.0], [90.0, 40.0], [55.0, 140.0]])
    dense = np.concatenate([np.linspace(pts[i], pts[i + 1], 40) for i in range(2)])
    ink = render_paths(dense, (200, 300), 6.0).numpy()
    light_on_dark = prepare_image(_save(tmp_path / "a.png", ink), (40, 40))
    dark_on_light = prepare_image(_save(tmp_path / "b.jpg", 1.0 - ink), (40, 40))
    assert light_on_dark.shape == (40, 40) and light_on_dark.dtype == np.float32
    assert light_on_dark.max() == pytest.approx(1.0) and light_on_dark.min() >= 0
    assert np.abs(light_on_dark - dark_on_light).mean() < 0.02  # JPEG artefacts only
    rows, cols = np.nonzero(light_on_dark > 0.2)
    # the ink's taller side fills the image but for the margins, centred
    assert abs(rows.max() - rows.min() + 1 - 40 * (1 - 2 * DEFAULT_MARGIN)) <= 2.5
    assert abs((rows.max() + rows.min()) / 2 - 19.5) <= 1.5
    assert abs((cols.max() + cols.min()) / 2 - 19.5) <= 1.5
    # prepared like the training images: the framing measured on them is reproduced
    data = generate_dataset(3, seed=1, progress=False)
    m = ink_margin(data.images)
    again = np.stack([prepare_image(a, (40, 40), margin=m) for a in data.images])
    assert ink_margin(again) == pytest.approx(m, abs=0.02)
    rgba = np.zeros((60, 50, 4), np.uint8)
    rgba[10:50, 20:26, 3] = 255  # black ink on a transparent background
    Image.fromarray(rgba, "RGBA").save(tmp_path / "t.png")
    assert prepare_image(tmp_path / "t.png", (40, 40)).max() == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("background", "ink"),
    [
        (1000, 60000),  # 16-bit, light ink on near-black (was read as dark ink: "no ink")
        (60000, 3000),  # 16-bit, dark ink on light paper
        (100, 4000),  # a 12-bit scan in a 16-bit file, light on dark
        (4000, 200),  # the same, dark on light (scaled by 65535 its paper is 6 % grey)
    ],
)
def test_16_bit_images_read_like_8_bit_ones(tmp_path, background, ink):
    yy, xx = np.mgrid[0:120, 0:120]
    ring = np.abs(np.hypot(xx - 60, yy - 60) - 35) < 4  # a "0"
    want = prepare_image(ring.astype(float), (40, 40))
    levels = np.where(ring, ink, background).astype(np.uint16)
    Image.fromarray(levels).save(tmp_path / "scan.png")  # mode I;16
    assert Image.open(tmp_path / "scan.png").mode.startswith("I")
    for source in (tmp_path / "scan.png", levels, np.stack([levels] * 3, -1)):
        assert np.abs(prepare_image(source, (40, 40)) - want).max() < 1e-3


# What a viewer shows for each EXIF orientation, as the raster to store for an upright
# image u (the tag's meaning: 3 = turn 180 degrees, 6 = turn 90 degrees clockwise to show,
# 8 = 90 counter-clockwise, 2 = mirror, 5 = transpose).
_RASTER_OF_UPRIGHT = {
    2: lambda u: u[:, ::-1],
    3: lambda u: u[::-1, ::-1],
    5: lambda u: u.T,
    6: lambda u: np.rot90(u, 1),
    8: lambda u: np.rot90(u, -1),
}


@pytest.mark.parametrize("orientation", sorted(_RASTER_OF_UPRIGHT))
@pytest.mark.parametrize("suffix", [".png", ".jpg"])
def test_phone_photos_are_read_upright_as_their_exif_tag_says(tmp_path, orientation, suffix):
    from img2dmp.data.images import ink_view, prepare_image_framed
    from img2dmp.web.recordings import FolderImages

    upright = np.full((90, 60), 255, np.uint8)  # an "L" in a portrait image
    upright[15:75, 15:24] = 0
    upright[66:75, 15:48] = 0
    exif = Image.Exif()
    exif[0x0112] = orientation
    path = tmp_path / f"photo{suffix}"
    raster = np.ascontiguousarray(_RASTER_OF_UPRIGHT[orientation](upright))
    Image.fromarray(raster).save(path, exif=exif, quality=95)
    want, want_frame = prepare_image_framed(upright.astype(float) / 255, (40, 40))
    corner = np.array([[15.0, 74.0]])  # the L's corner, in the image as it is shown
    for source in (path, Image.open(path)):
        got, frame = prepare_image_framed(source, (40, 40))
        assert frame.image_size == (90, 60)
        assert np.abs(got - want).max() < 0.05
        assert np.abs(frame.to_model(corner) - want_frame.to_model(corner)).max() < 1e-9
    assert ink_view(path)[0].shape == (90, 60)
    folder = FolderImages(tmp_path)  # the Record page shows and sizes it the same way
    assert folder.size(0) == (90, 60)
    shown = np.asarray(Image.open(io.BytesIO(folder.png(0))).convert("L"))
    assert np.abs(shown.astype(int) - upright).max() < 60


def test_an_orientation_tag_out_of_range_leaves_the_image_as_stored(tmp_path):
    from img2dmp.data.images import shown_size, upright

    exif = Image.Exif()
    exif[0x0112] = 9  # not an orientation: viewers show the raster as it is
    Image.new("L", (60, 30), 255).save(tmp_path / "odd.png", exif=exif)
    with Image.open(tmp_path / "odd.png") as im:
        assert shown_size(im) == (30, 60)
        assert upright(im).size == (60, 30)


def test_the_scale_of_white_follows_the_bits_an_image_uses():
    from img2dmp.data.images import full_scale

    assert [full_scale(v) for v in (0.0, 1.0, 2.0, 255, 256, 4000, 4095, 4096, 65535)] == [
        1.0,
        1.0,
        255.0,
        255.0,
        511.0,
        4095.0,
        4095.0,
        8191.0,
        65535.0,
    ]


def test_float_levels_a_little_above_1_are_an_overshoot_and_below_0_refused():
    """Bicubic resampling rings past 1: such levels are [0, 1], clipped (they were read as
    [0, 255], a black image with "no ink"); normalised values are named for what they
    are."""
    img = np.zeros((28, 28))
    img[5:23, 12:16] = 1.0
    plain = prepare_image(img)
    for top in (1.0 + 1e-6, 1.02, 1.5):
        np.testing.assert_array_equal(prepare_image(np.where(img > 0, top, 0.0)), plain)
    assert prepare_image(np.where(img > 0, 255.0, 0.0)).max() == pytest.approx(plain.max())
    with pytest.raises(ValueError, match=r"has levels below 0 \(down to -0\.4194\).*\(x - mean\)"):
        prepare_image((img - 0.13) / 0.31)


def test_plausible_misuse_of_the_python_api_is_named_or_taken(model_and_data):
    """What a researcher's pipeline plausibly hands over: a torch tensor that requires
    grad or is bfloat16 (read as its values), prepare()'s (image, frame), a list of paths
    given to predict, a Predictor to pickle (one line each, not numpy's or torch's)."""
    import copy
    import pickle

    import torch

    run, _ = model_and_data
    model = Predictor.load(run)
    img = np.zeros((28, 28))
    img[5:23, 12:16] = 1.0
    ref = model.predict(img).params
    for tensor in (torch.tensor(img, requires_grad=True), torch.tensor(img).to(torch.bfloat16)):
        np.testing.assert_array_equal(model.predict(tensor).params.w, ref.w)
    prepared = model.prepare(img)
    with pytest.raises(ValueError, match=r"prepare\(\) returns \(image, frame\)"):
        model.predict_images(prepared)
    grad = torch.tensor(prepared[0][None], requires_grad=True)
    np.testing.assert_allclose(
        model.predict_images(grad).w, model.predict_images(prepared[0][None]).w
    )
    with pytest.raises(
        ValueError, match="must be one image .* got a list of 2; several: prepare_paths"
    ):
        model.predict(["a.png", "b.png"])
    for copier in (pickle.dumps, copy.deepcopy, copy.copy):
        with pytest.raises(TypeError, match="a Predictor is not pickled or copied .* initializer"):
            copier(model)
    assert pickle.loads(pickle.dumps(model.predict(img))).params.w.shape == ref.w.shape


def test_bad_images_give_clear_errors(tmp_path, model_and_data):
    (tmp_path / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not a PNG")
    with pytest.raises(ValueError, match="cannot decode image file .*broken.png"):
        prepare_image(tmp_path / "broken.png")
    with pytest.raises(ValueError, match="no ink"):
        prepare_image(_save(tmp_path / "blank.png", np.full((30, 30), 0.8)))
    with pytest.raises(FileNotFoundError):
        prepare_image(tmp_path / "missing.png")
    run, _ = model_and_data
    pred = Predictor.load(run)
    with pytest.raises(ValueError, match="shape"):
        pred.predict_images(np.zeros((2, 28, 28), np.float32))
    assert cli.main(["predict", "--model", str(run), str(tmp_path / "broken.png")]) == 2


def test_predict_paths_and_cli(model_and_data, tmp_path, capsys):
    run, data_path = model_and_data
    data = load_dataset(data_path)
    files = [_save(tmp_path / f"d{i}.png", 1.0 - data.images[i]) for i in range(2)]
    pred = Predictor.load(run)
    out = pred.predict_paths(files)
    assert len(out) == 2 and out[0][1].shape == (40, 40)
    assert out[0][0].batch_shape == () and float(out[0][0].tau) > 0
    assert cli.main(["predict", "--model", str(run), str(files[0]), "--points", "50"]) == 0
    rec = json.loads(capsys.readouterr().out)  # the one DMP file (docs/ROBOT.md)
    assert (rec["format"], rec["version"], rec["frame"]) == ("img2dmp-dmp", 2, "model")
    assert len(rec["hypotheses"][0]["trajectory"]["t_s"]) == 50
    vector = DMPParams.from_dict(rec["params"]).to_vector()
    assert len(vector) == 55 and np.allclose(vector, out[0][0].to_vector())
    assert (
        cli.main(
            [
                "predict",
                "--model",
                str(run),
                *map(str, files),
                "--out",
                str(tmp_path / "o"),
                "--overlay",
            ]
        )
        == 0
    )
    for stem in ("d0", "d1"):
        for suffix in ("_dmp.json", "_trajectory.csv", "_overlay.png", "_overlay_image.png"):
            assert (tmp_path / "o" / f"{stem}{suffix}").is_file()
    csv = (tmp_path / "o" / "d0_trajectory.csv").read_text().splitlines()
    header = "rank,probability,t_s,x_model_px,y_model_px,x_image_px,y_image_px"
    assert csv[0] == header and len(csv) == 101
    assert cli.main(["evaluate", str(run), str(data_path), "--out", str(tmp_path / "e")]) == 0
    assert (tmp_path / "e" / "examples.png").is_file()


def test_stroke_width_estimate_tracks_the_pen():
    path = generate_dataset(4, seed=0, progress=False).trajectories[1][None] * 10  # 400 px
    widths = [
        stroke_width(render_paths(path, 400, pen_width_px=w)[0].numpy(), upsample=1)
        for w in (4.0, 12.0, 30.0)
    ]
    assert widths[0] < widths[1] < widths[2]
    assert widths[2] - widths[0] > 20  # 26 px apart, biased by the soft edges only
    assert stroke_width(np.zeros((10, 10))) == 0.0


def test_prepare_image_brings_thin_and_thick_pens_to_the_training_width():
    path = generate_dataset(4, seed=0, progress=False).trajectories[1][None] * 10
    target = 2.6
    kept, matched = [], []
    for pen in (4.0, 12.0, 30.0):
        scan = 1.0 - render_paths(path, 400, pen_width_px=pen)[0].numpy()  # dark on light
        kept.append(stroke_width(prepare_image(scan, (40, 40))))
        matched.append(stroke_width(prepare_image(scan, (40, 40), stroke_width_px=target)))
    assert max(kept) - min(kept) > 2.0  # unnormalised: from hairline to marker
    assert max(matched) - min(matched) < 0.8
    assert all(abs(w - target) < 0.6 for w in matched), matched
    with pytest.raises(ValueError, match="stroke_width_px"):
        prepare_image(scan, (40, 40), stroke_width_px=-1.0)


def test_path_error_ignores_timing_but_not_shape():
    from img2dmp.evaluate import path_error_px

    u = np.linspace(0, 1, 120)
    circle = lambda s: np.stack([20 + 8 * np.cos(5 * s), 20 + 8 * np.sin(5 * s)], -1)  # noqa: E731
    even, uneven = circle(u), circle(u**2)  # one curve, two speeds
    timed = np.linalg.norm(even - uneven, axis=-1).mean()
    assert timed > 3  # Table I's error sees the speed
    both = path_error_px(np.stack([even, even + [1.0, 0.0]]), np.stack([uneven, uneven]))
    assert both[0] < 0.05  # the path error does not
    assert abs(both[1] - 1.0) < 0.05  # but it sees a 1 px shift
    with pytest.raises(ValueError, match="shape"):
        path_error_px(even, uneven)


PATH_MEASURES = ("chamfer", "on_ink", "on_ink_human", "start_error", "area_ratio", "width_ratio")
PER_SAMPLE = (
    "chamfer_px",
    "on_ink_shares",
    "on_ink_human_shares",
    "start_errors_px",
    "area_ratios",
    "width_ratios",
)


def test_evaluate_reports_the_timing_free_path_measures(model_and_data, tmp_path):
    run, data_path = model_and_data
    res = evaluate(run, data_path, split="test", out_dir=tmp_path, n_figures=0)
    labels = load_dataset(data_path).select_split("test").labels
    n = res["overall"]["n"]
    for key in PATH_MEASURES:
        assert set(res[key]) == {"overall", "per_digit"}, key
    for key in PER_SAMPLE:
        assert len(res[key]) == n, key
    human = np.array(res["on_ink_human_shares"])
    model = np.array(res["on_ink_shares"])
    assert np.all((human >= 0) & (human <= 1)) and np.all((model >= 0) & (model <= 1))
    assert res["on_ink_human"]["overall"]["mean"] > 0.9  # the images were drawn from them
    assert np.all(np.array(res["chamfer_px"]) >= 0) and np.all(
        np.array(res["start_errors_px"]) >= 0
    )
    assert res["on_ink"]["overall"]["mean"] == pytest.approx(model.mean())
    closed = np.isin(labels, (0, 6, 8, 9))
    assert set(res["area_ratio"]["per_digit"]) == {str(d) for d in np.unique(labels[closed])}
    assert all(r is None for r, c in zip(res["area_ratios"], closed, strict=True) if not c)
    assert all(r > 0 for r, c in zip(res["area_ratios"], closed, strict=True) if c)
    assert res["area_ratio"]["overall"]["n"] == closed.sum()
    assert res["hypotheses"] == 1 and "best_of_k" not in res and res["pen_never_down"] == 0
    saved = json.loads((tmp_path / "evaluation.json").read_text())
    assert saved["chamfer"] == res["chamfer"] and saved["area_ratios"] == res["area_ratios"]
    text = (tmp_path / "evaluation.txt").read_text()
    assert text.startswith("trajectory error") and "path measures" in text
    assert len([ln for ln in text.splitlines() if ln.split()[:1] == ["all"]]) == 2


class _ThreeGuesses:
    """A stand-in predictor with K = 3 hypotheses: the most probable is the demonstration
    shifted 2 px to the right, then the demonstration itself, then it backwards."""

    def __init__(self, data):
        self.data = data
        self.image_size = tuple(data.image_size)
        self.dmp_config = data.dmp_config
        self.meta = {}

    def hypothesis_trajectories(self, images, times, batch_size):
        assert np.array_equal(images, self.data.images) and batch_size > 0
        demo = self.data.trajectories.astype(np.float64)  # [M, T, 2]
        shifted = demo + [2.0, 0.0]
        y = np.stack([shifted, demo, demo[:, ::-1]], axis=1)  # [M, 3, T, 2]
        return y, np.tile([0.5, 0.2, 0.3], (len(demo), 1))


def test_best_of_k_hypotheses_finds_the_demonstration(model_and_data, tmp_path):
    _, data_path = model_and_data
    stand_in = _ThreeGuesses(load_dataset(data_path).select_split("test"))
    res = evaluate(stand_in, data_path, split="test", out_dir=tmp_path, n_figures=2)
    assert res["hypotheses"] == 3
    # the table reports the most probable hypothesis: 2 px off everywhere
    assert res["overall"]["mean"] == pytest.approx(2.0, abs=1e-5)
    assert 0.1 < res["chamfer"]["overall"]["mean"] <= 2.0 + 1e-9  # each point has one 2 px off
    best = res["best_of_k"]
    assert best["k"] == 3 and best["top_is_best"] == 0.0
    assert set(best["top_hypothesis"]) == {0} and set(best["best_hypothesis"]) == {1}
    assert best["trajectory_error"]["overall"]["max"] == pytest.approx(0.0, abs=1e-6)
    assert best["path_error"]["overall"]["max"] == pytest.approx(0.0, abs=1e-6)
    assert best["chamfer"]["overall"]["max"] == pytest.approx(0.0, abs=1e-6)
    assert len(best["errors_px"]) == res["overall"]["n"]
    assert "best of K = 3" in format_table(res)
    assert json.loads((tmp_path / "evaluation.json").read_text())["best_of_k"] == best


def test_hypothesis_metrics_checks_its_shapes():
    from img2dmp.evaluate import hypothesis_metrics

    y = np.zeros((4, 2, 10, 2))
    with pytest.raises(ValueError, match="probs"):
        hypothesis_metrics(y, np.ones((4, 3)), y[:, 0], np.zeros((4, 8, 8)), np.arange(4))


def test_a_crisp_bar_filling_its_box_is_prepared_not_eroded_away():
    # A clean "1": its crop is all ink, with no background inside the bounding box.
    img = np.full((200, 200), 255, np.uint8)
    img[40:160, 95:105] = 0
    for width in (None, 2.5, 1.2):
        out = prepare_image(img.astype(np.float32) / 255.0, (28, 28), stroke_width_px=width)
        cols = np.flatnonzero((out > 0.5).any(axis=0))
        assert 1 <= cols.size <= 4 and (out > 0.5).sum(axis=0).max() >= 18, width


def test_data_framed_unlike_the_models_training_images_is_noted(model_and_data, tmp_path, capsys):
    run, data_path = model_and_data
    res = evaluate(run, data_path, split="test")
    assert res["framing"]["same"]  # its own test split: framed as it learnt
    data = load_dataset(data_path)
    side = data.images.shape[-1]
    small = side // 2  # the same images at half their size, in the middle of the frame
    at = (side - small) // 2
    images = np.zeros_like(data.images)
    for i, a in enumerate(data.images):
        shrunk = Image.fromarray(a.astype(np.float32)).resize((small, small), Image.BILINEAR)
        images[i, at : at + small, at : at + small] = np.asarray(shrunk)
    data.images = images
    framed = tmp_path / "framed.safetensors"
    save_dataset(framed, data)
    res = evaluate(run, framed, split="test")
    assert not res["framing"]["same"]
    assert res["framing"]["data_ink_margin"] > res["framing"]["model_ink_margin"] + 0.1
    assert cli.main(["evaluate", str(run), str(framed), "--out", str(tmp_path / "e")]) == 0
    note = [ln for ln in capsys.readouterr().out.splitlines() if "framed unlike" in ln]
    assert len(note) == 1 and str(framed) in note[0] and "--margin" in note[0]
