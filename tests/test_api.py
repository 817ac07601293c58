"""The one call from Python, the one DMP file and the user's image frame (issue 18).

- ``img2dmp.load_model(run).predict(image)`` for a path, a PIL image and arrays of either
  polarity gives one DMP; ``import img2dmp`` loads no torch;
- what ``Prediction.save`` and ``img2dmp predict --out`` write is what
  ``load_dmp_json`` and ``img2dmp write --dmp`` read (hypotheses selectable); the files
  of before (version 1, the old predict record) are still read and converted;
- the frame: a digit drawn at a known place in a large image maps onto the prepared
  image's ink and back; a prediction's DMP in the image frame is exact;
- bad input: one-line errors naming the file, the field and the value.

Everything runs on two tiny networks trained here for one epoch (a few seconds).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from scipy.ndimage import distance_transform_edt, map_coordinates

import img2dmp
from img2dmp import cli
from img2dmp.data.dmpfile import read_dmp_file, write_dmp_document
from img2dmp.data.images import prepare_image_framed
from img2dmp.data.render import render_paths
from img2dmp.dmp import DMPConfig, DMPParams, fit_dmp, rollout
from img2dmp.dmp.affine import affine_dmp
from img2dmp.robot import available, load_dmp_json, save_dmp_json

#: Corners of a "7" drawn in a 600 x 900 image (x = column, y = row), pen 18 px wide.
SEVEN = np.array([[250.0, 120.0], [520.0, 120.0], [360.0, 470.0]])
BIG = (600, 900)


def _seven_path(n: int = 200) -> np.ndarray:
    return np.concatenate([np.linspace(SEVEN[i], SEVEN[i + 1], n) for i in range(2)])


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("api")


@pytest.fixture(scope="module")
def runs(work, train_tiny_runs) -> dict[int, Path]:
    """Run directories of networks with one and with two hypotheses (one epoch each)."""
    return train_tiny_runs(work, lambda k: work / f"run{k}")


@pytest.fixture(scope="module")
def seven(work) -> dict:
    """The "7" as ink (light on dark, float) and as a dark-on-light PNG."""
    ink = render_paths(_seven_path(), BIG, 18.0).numpy().astype(np.float64)
    png = work / "seven.png"
    Image.fromarray(np.round(255 * (1.0 - ink)).astype(np.uint8)).save(png)
    return {"ink": ink, "png": png}


def _vector(p: DMPParams) -> np.ndarray:
    return np.asarray(p.to_numpy().to_vector())


# -- 1. one call from Python ---------------------------------------------------------------


def test_load_model_predicts_from_a_path_pil_images_and_arrays_of_either_polarity(runs, seven):
    model = img2dmp.load_model(runs[2])
    by_path = model.predict(seven["png"])
    grey = np.asarray(Image.open(seven["png"]))  # uint8, dark ink on light paper
    inputs = {
        "PIL grey": Image.open(seven["png"]),
        "PIL RGB": Image.open(seven["png"]).convert("RGB"),
        "uint8 dark on light": grey,
        "float light on dark": 1.0 - grey / 255.0,
        "RGB array": np.repeat(grey[..., None], 3, axis=-1),
    }
    for what, image in inputs.items():
        pred = model.predict(image)
        np.testing.assert_allclose(
            _vector(pred.params), _vector(by_path.params), rtol=1e-5, atol=1e-4, err_msg=what
        )
        np.testing.assert_allclose(pred.probabilities, by_path.probabilities, atol=1e-6)
        np.testing.assert_allclose(pred.frame.image_to_model, by_path.frame.image_to_model)
        assert pred.source is None
    k, t = 2, 100
    assert by_path.source == str(seven["png"]) and by_path.n_hypotheses == k
    assert by_path.params.batch_shape == (k,) and by_path.dmp.batch_shape == ()
    assert by_path.times.shape == (k, t) and by_path.path_model.shape == (k, t, 2)
    assert by_path.path_image.shape == (k, t, 2) and by_path.image.shape == (40, 40)
    assert by_path.probabilities[0] >= by_path.probabilities[1]
    assert by_path.probabilities.sum() == pytest.approx(1.0)
    assert by_path.frame.image_size == BIG and by_path.frame.model_size == (40, 40)
    # the one call does what the four calls did
    [(top, image)] = model.predict_paths([seven["png"]])
    np.testing.assert_allclose(_vector(top), _vector(by_path.dmp), rtol=1e-6)
    np.testing.assert_array_equal(image, by_path.image)


def test_import_img2dmp_loads_no_torch_and_exports_a_small_documented_set():
    code = (
        "import json, sys, img2dmp\n"
        "heavy = [m for m in ('torch', 'numpy', 'PIL', 'matplotlib') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
        "names = set(img2dmp.__all__) - {'__version__'}\n"
        "assert names <= set(dir(img2dmp)), names - set(dir(img2dmp))\n"
        "for n in sorted(names):\n"
        "    assert getattr(img2dmp, n).__doc__, n\n"
        "assert 'torch' in sys.modules\n"
        "print(json.dumps(sorted(names)))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert {"load_model", "Prediction", "DMPParams", "DMPConfig", "rollout"} <= set(
        json.loads(out.stdout)
    )
    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        img2dmp.no_such_name  # noqa: B018
    assert img2dmp.DMPParams is DMPParams and img2dmp.affine_dmp is affine_dmp
    assert (Path(img2dmp.__file__).parent / "py.typed").is_file()


# -- 2. the frames ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "source, stroke",
    [("png", None), ("png", 2.0), ("jpeg", 2.0), ("array", 2.5), ("huge array", 2.0)],
)
def test_a_digit_at_a_known_place_maps_onto_the_ink_and_back(seven, work, source, stroke):
    ink, path = seven["ink"], _seven_path()
    if source == "jpeg":  # > 4 MP: decoded at a reduced scale (PIL's draft)
        ink = render_paths(path * 3, (1800, 2700), 54.0).numpy().astype(np.float64)
        path = path * 3 + 1.0  # pixel centres: 3 (x + 0.5) - 0.5
        src = work / "seven.jpg"
        Image.fromarray(np.round(255 * (1 - ink)).astype(np.uint8)).save(src, quality=95)
    elif source == "huge array":  # > 4 MP: reduced by area average as it is read
        ink = render_paths(path * 3, (1800, 2700), 54.0).numpy().astype(np.float64)
        path, src = path * 3 + 1.0, ink
    else:
        src = seven["png"] if source == "png" else ink
    prepared, frame = prepare_image_framed(src, (40, 40), stroke_width_px=stroke)
    assert frame.image_size == ink.shape
    # the drawn path, mapped into the model frame, runs along the prepared image's ink
    xy = frame.to_model(path)
    along = map_coordinates(prepared, [xy[:, 1], xy[:, 0]], order=1)
    assert along.min() > 0.3 and np.median(along) > 0.6
    rows, cols = np.nonzero(prepared > 0.5)
    assert abs(xy[:, 0].min() - cols.min()) < 1.5 and abs(xy[:, 0].max() - cols.max()) < 1.5
    assert abs(xy[:, 1].min() - rows.min()) < 1.5 and abs(xy[:, 1].max() - rows.max()) < 1.5
    # and back: the inverse gives the drawn path again, and the prepared image's ink
    # lands on the ink of the user's image (within the pen-width filter's widening)
    np.testing.assert_allclose(frame.to_image(xy), path, atol=1e-9)
    a = frame.image_to_model
    inked = frame.to_image(np.stack([cols, rows], -1).astype(float))
    off_ink = distance_transform_edt(ink < 0.5)  # user pixels to the user's ink
    gap = map_coordinates(off_ink, [inked[:, 1], inked[:, 0]], order=1)
    assert gap.max() < ((stroke or 0.5) / 2 + 1.0) / a[0, 0]  # a pixel and the widening
    assert np.median(gap) < 1.0 / a[0, 0]
    # an axis-aligned scaling and shift, and the pen channel passes through
    assert a[0, 1] == a[1, 0] == 0 and a[0, 0] == pytest.approx(a[1, 1]) and a[0, 0] > 0
    np.testing.assert_array_equal(frame.to_image(np.c_[xy, np.ones(len(xy))])[:, 2], 1.0)


def _blobs(h: int, w: int) -> np.ndarray:
    """Two smooth blobs of ink, off centre, light on dark, darkest ink 1."""
    r, c = np.mgrid[:h, :w]
    s = h / 10

    def blob(cx, cy, sx, sy):
        return np.exp(-((c - cx) ** 2 / (2 * sx**2) + (r - cy) ** 2 / (2 * sy**2)))

    ink = blob(0.37 * w, 0.61 * h, 1.3 * s, 0.8 * s) + 0.7 * blob(
        0.45 * w, 0.4 * h, 0.6 * s, 0.9 * s
    )
    return ink / ink.max()


@pytest.mark.parametrize("shape, size, tolerance", [((60, 45), (64, 48), 1e-4),
                                                    ((600, 900), (40, 40), 0.03)])  # fmt: skip
def test_the_prepared_image_is_the_users_image_seen_through_the_frame(shape, size, tolerance):
    ink = _blobs(*shape)
    # The plain reading keeps the blobs' grey levels linear, so the picture seen through
    # the frame is the prepared image up to a gain (the paper-aware one thresholds them).
    prepared, frame = prepare_image_framed(ink, size, margin=0.1, clean=False)
    r, c = np.mgrid[: size[0], : size[1]]
    xy = frame.to_image(np.stack([c.ravel(), r.ravel()], -1).astype(float))
    seen = map_coordinates(ink, [xy[:, 1], xy[:, 0]], order=1).reshape(size)
    # inside the ink's box (outside it the preparation cut the faint tails away)
    rows, cols = np.nonzero(ink > 0.2)
    pad = 2.0 / frame.image_to_model[0, 0]  # two model pixels
    inside = (
        (xy[:, 0] > cols.min() + pad) & (xy[:, 0] < cols.max() - pad)
        & (xy[:, 1] > rows.min() + pad) & (xy[:, 1] < rows.max() - pad)
    ).reshape(size)  # fmt: skip
    gain = (prepared[inside] @ seen[inside]) / (seen[inside] @ seen[inside])  # ink scaled to 1
    # enlarging interpolates at exactly these points (to float32 and the subtracted
    # background, 1e-5); shrinking averages around them; half a pixel off is 0.06
    assert np.abs(prepared[inside] - gain * seen[inside]).max() < tolerance
    assert inside.sum() > 200


def test_a_prediction_in_the_image_frame_is_an_exact_dmp(runs, seven):
    pred = img2dmp.load_model(runs[2]).predict(seven["png"], n_points=60)
    np.testing.assert_allclose(pred.path_image, pred.frame.to_image(pred.path_model))
    y = rollout(pred.params_image.to_torch(), torch.as_tensor(pred.times), pred.dmp_config)
    np.testing.assert_allclose(y.numpy(), pred.path_image, atol=1e-6 * BIG[1])
    # the paper's diag(g - y0) scaling absorbs an axis-aligned map: same weights
    np.testing.assert_allclose(pred.params_image.w, pred.params.w, rtol=1e-12)
    np.testing.assert_allclose(pred.params_image.tau, pred.params.tau)
    # the path stays in the part of the user's image the model saw
    corners = pred.frame.to_image(np.array([[-0.5, -0.5], [39.5, 39.5]]))
    slack = 40 * pred.frame.model_to_image[0, 0]  # a model-frame image width of slack
    assert (pred.path_image >= corners[0] - slack).all()
    assert (pred.path_image <= corners[1] + slack).all()


def test_a_predicted_dmp_carries_its_constants_and_refuses_others(runs, seven):
    from dataclasses import replace

    from img2dmp.dmp import DMPIntegrator
    from img2dmp.dmp._numpy_rollout import rollout_numpy

    pred = img2dmp.load_model(runs[2]).predict(seven["png"], n_points=60)
    own = pred.dmp_config
    for p in (pred.dmp, pred.params, pred.params_image, pred.params[1], pred.dmp.to_torch()):
        assert p.config == own
    t = torch.as_tensor(pred.times[0])
    top = pred.params[0].to_torch()
    np.testing.assert_array_equal(rollout(top, t).numpy(), rollout(top, t, own).numpy())
    np.testing.assert_allclose(rollout(top, t).numpy(), pred.path_model[0], atol=1e-4)
    other = replace(own, scaling="goal-start" if own.scaling == "none" else "none")
    message = f"scaling '{other.scaling}' \\(carried '{own.scaling}'\\)"
    calls = (
        lambda c: rollout(top, t, c),
        lambda c: rollout_numpy(pred.params[0], pred.times[0], c),
        lambda c: img2dmp.bend_dmp(pred.dmp, c, tempo=2.0),
        lambda c: affine_dmp(pred.dmp, c, [[1, 0, 0], [0, 1, 0]]),
        lambda c: DMPIntegrator(pred.dmp, c),
    )
    for call in calls:
        with pytest.raises(ValueError, match=message):
            call(other)
        call(own)  # the same constants given again are fine
    bent = img2dmp.bend_dmp(pred.dmp, tempo=2.0)  # the carried constants, carried on
    assert bent.config == own and affine_dmp(bent, None, np.eye(2, 3)).config == own
    relabelled = pred.params[0].with_config(other)  # on purpose: another movement
    assert relabelled.config == other and np.shares_memory(relabelled.w, pred.params.w)
    moved = rollout_numpy(relabelled, pred.times[0])
    assert np.abs(moved - rollout_numpy(pred.params[0], pred.times[0])).max() > 1e-3


def test_dmp_parameters_keep_their_constants_through_every_conversion():
    import pickle

    config = DMPConfig(n_kernels=6, scaling="none")
    t = np.linspace(0.0, 1.0, 80)
    y = np.stack([5 + 3 * np.sin(3 * t), 2 * t], -1)
    fitted = fit_dmp(np.stack([t, t]), np.stack([y, y + 1.0]), config).params
    assert fitted.config == config
    for p in (fitted[0], fitted[:1], fitted.to_torch(), fitted.to_torch().to_numpy(),
              pickle.loads(pickle.dumps(fitted)),
              DMPParams.from_vector(fitted.to_vector(), 6, 2, config=config),
              DMPParams.from_dict(fitted[0].to_dict(), config=config, batch_shape=())):  # fmt: skip
        assert p.config == config
    assert DMPParams(fitted.w, fitted.tau, fitted.g, fitted.y0).config is None
    # unlabelled numbers take what they are given, or the paper's constants
    bare = fitted[0].with_config(None)
    np.testing.assert_array_equal(
        rollout(bare.to_torch(), torch.as_tensor(t), config).numpy(),
        rollout(fitted[0].to_torch(), torch.as_tensor(t)).numpy(),
    )
    with pytest.raises(ValueError, match="N=6 kernels.*expects N=25"):
        fitted.with_config(DMPConfig())
    with pytest.raises(TypeError, match="config must be a DMPConfig or None, got dict"):
        DMPParams(fitted.w, fitted.tau, fitted.g, fitted.y0, config={"scaling": "none"})


def test_constants_are_compared_by_the_movement_they_make_and_files_keep_them(tmp_path):
    from dataclasses import replace

    config = DMPConfig(n_kernels=6, scaling="none")
    t = np.linspace(0.0, 1.0, 60)
    p = fit_dmp(t, np.stack([4 * np.sin(3 * t), 2 * t], -1), config).params
    spelled = replace(config, beta_z=config.alpha_z / 4)  # the same damping, written out
    tt = torch.as_tensor(t)
    np.testing.assert_array_equal(rollout(p.to_torch(), tt, spelled).numpy(),
                                  rollout(p.to_torch(), tt).numpy())  # fmt: skip
    with pytest.raises(ValueError, match=r"beta 11.0 \(carried 12.0\)"):
        rollout(p.to_torch(), tt, replace(config, beta_z=11.0))
    # equality: values and the movement's constants
    copy = DMPParams(p.w.copy(), p.tau.copy(), p.g.copy(), p.y0.copy(), config=spelled)
    assert p == copy and p != copy.with_config(None) and p != p.to_torch()
    assert p != p.with_config(replace(config, scaling="goal-start"))
    moved = copy.w.copy()
    moved[0, 0] += 1e-9
    assert p != DMPParams(moved, p.tau, p.g, p.y0, config=config)
    # a DMP file stores the carried constants, and refuses others
    img2dmp.save_dmp_json(tmp_path / "a.json", p, None, (28, 28), label=np.int64(3))
    back, stored, _ = load_dmp_json(tmp_path / "a.json")
    assert stored == config and back.config == config
    assert json.loads((tmp_path / "a.json").read_text())["label"] == 3
    with pytest.raises(ValueError, match="b.json: config differs .* scaling 'goal-start'"):
        img2dmp.save_dmp_json(tmp_path / "b.json", p, DMPConfig(n_kernels=6), (28, 28))
    assert not (tmp_path / "b.json").exists()
    with pytest.raises(
        TypeError, match="c.json: config must be a DMPConfig, got NoneType .*carry none"
    ):
        img2dmp.save_dmp_json(tmp_path / "c.json", p.with_config(None), None, (28, 28))
    # affine_dmp(params, matrix) with the carried constants
    shifted = affine_dmp(p, [[1, 0, 5], [0, 1, 0]])
    assert shifted.config == config
    np.testing.assert_allclose(shifted.g, p.g + [5, 0])
    with pytest.raises(ValueError, match="affine_dmp needs a matrix"):
        affine_dmp(p)


def test_time_stamps_at_fault_are_named_with_their_index():
    y = np.random.default_rng(0).normal(size=(3, 8, 2))
    t = np.linspace(0.0, 1.0, 8)
    assert fit_dmp(t[None], y).params.batch_shape == (3,)  # [1, T]: shared stamps
    repeated = np.r_[t[:4], t[3], t[5:]]
    with pytest.raises(ValueError, match=r"t\[4\] = 0.428\d* repeats t\[3\] = 0.428"):
        fit_dmp(repeated, y)
    with pytest.raises(ValueError, match=r"t\[2\] is nan"):
        fit_dmp(np.r_[t[:2], np.nan, t[3:]], y)
    with pytest.raises(ValueError, match=r"t\[1, 0\] is -1.0"):
        rollout(fit_dmp(t, y[:2]).params.to_torch(), torch.tensor([[0.0, 1.0], [-1.0, 0.5]]))


@pytest.mark.parametrize("scaling", ["goal-start", "none"])
@pytest.mark.parametrize("d", [2, 3])
def test_an_affinely_mapped_dmp_rolls_out_to_the_mapped_path(scaling, d):
    t = np.linspace(0.0, 2.0, 150)
    y = np.stack([20 + 8 * np.cos(3 * t), 15 + 5 * np.sin(2 * t) + 3 * t, (t > 1) * 1.0], -1)
    config = DMPConfig(n_dims=d, scaling=scaling)
    params = fit_dmp(t, y[:, :d], config).params
    before = rollout(params.to_torch(), torch.as_tensor(t), config).numpy()
    for m in (
        [[0.3, 0, 5], [0, 0.7, -2]],
        [[0.8, -0.6, 3], [0.6, 0.8, 1]],
        [[-2, 0.5, 0], [0.1, 1.5, 7]],
    ):
        m = np.array(m, dtype=float)
        mapped = affine_dmp(params, config, m)
        after = rollout(mapped.to_torch(), torch.as_tensor(t), config).numpy()
        want = before.copy()
        want[:, :2] = before[:, :2] @ m[:, :2].T + m[:, 2]
        np.testing.assert_allclose(after, want, atol=1e-9)
        np.testing.assert_allclose(mapped.tau, params.tau)


def test_a_map_the_papers_scaling_cannot_follow_is_refused():
    config = DMPConfig()  # goal-start: g - y0 = (10, 10); a 45 degree rotation zeroes x
    params = DMPParams(np.ones((25, 2)), 1.0, [20.0, 20.0], [10.0, 10.0])
    c = np.sqrt(0.5)
    with pytest.raises(ValueError, match="g - y0 maps to 0 in coordinate 0.*scaling 'none'"):
        affine_dmp(params, config, [[c, -c, 0], [c, c, 0]])
    with pytest.raises(ValueError, match="not invertible"):
        affine_dmp(params, config, [[1, 2, 0], [2, 4, 0]])


# -- 3. one DMP file: predict -> write ---------------------------------------------------------


def test_a_saved_prediction_is_the_dmp_file_write_reads(runs, seven, work):
    pred = img2dmp.load_model(runs[2]).predict(seven["png"])
    path = pred.save(work / "seven_dmp.json")
    params, config, size = load_dmp_json(path)
    assert config == pred.dmp_config and size == (40, 40)
    np.testing.assert_array_equal(_vector(params), _vector(pred.dmp))
    second, _, _ = load_dmp_json(path, hypothesis=2)
    np.testing.assert_array_equal(_vector(second), _vector(pred.params[1]))
    f = read_dmp_file(path)
    assert f.converted_from is None and f.frame == "model"
    assert f.probabilities == pred.probabilities.tolist()
    np.testing.assert_array_equal(f.image_frame.image_to_model, pred.frame.image_to_model)
    for k in range(2):
        np.testing.assert_array_equal(_vector(f.hypotheses_image[k]), _vector(pred.params_image[k]))
    doc = json.loads(path.read_text())
    assert (doc["format"], doc["version"], doc["image_frame"]["image"]) == (
        "img2dmp-dmp",
        2,
        str(seven["png"]),
    )
    traj = doc["hypotheses"][0]["trajectory"]
    assert set(traj) == {"t_s", "xy_model_px", "xy_image_px"}
    np.testing.assert_allclose(traj["xy_image_px"], pred.path_image[0], atol=1e-6)
    # a DMP made by hand is the same format
    save_dmp_json(work / "hand.json", params, config, (40, 40), frame="image", label="7")
    assert load_dmp_json(work / "hand.json")[2] == (40, 40)
    assert json.loads((work / "hand.json").read_text())["version"] == 2


def test_predict_then_write_on_the_command_line(runs, seven, work, capsys):
    out = work / "P"
    argv = ["predict", "--model", str(runs[2]), str(seven["png"]), "--out", str(out), "--overlay"]
    assert cli.main(argv) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == [f"seven{s}" for s in ("_dmp.json", "_overlay.png", "_overlay_image.png",
                                              "_trajectory.csv")]  # fmt: skip
    csv = (out / "seven_trajectory.csv").read_text().splitlines()
    assert csv[0] == "rank,probability,t_s,x_model_px,y_model_px,x_image_px,y_image_px"
    assert len(csv) == 1 + 2 * 100
    capsys.readouterr()
    assert cli.main(["predict", "--model", str(runs[1]), str(seven["png"]), "--points", "7"]) == 0
    printed = json.loads(capsys.readouterr().out)  # without --out: the same file, printed
    assert printed["version"] == 2 and len(printed["hypotheses"]) == 1
    assert len(printed["hypotheses"][0]["trajectory"]["t_s"]) == 7
    bad = ["write", "--dmp", str(out / "seven_dmp.json"), "--hypothesis", "3", "--no-progress"]
    assert cli.main(bad + ["--out-dir", str(work / "W")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "field 'hypotheses': the file has 2 hypotheses" in err
    if not available():
        pytest.skip("pybullet is not installed: img2dmp write cannot run")
    argv = ["write", "--dmp", str(out / "seven_dmp.json"), "--out-dir", str(work / "W")]
    assert cli.main([*argv, "--hypothesis", "2", "--no-progress"]) == 0
    assert "tracking error" in capsys.readouterr().out
    assert (work / "W" / "seven_dmp_log.csv").is_file()


# -- 4. the files of before ------------------------------------------------------------------


def _old_record(config: DMPConfig, n_hyps: int = 1) -> tuple[dict, list[DMPParams]]:
    """A record as ``img2dmp predict`` wrote it before version 2."""
    t = np.linspace(0.0, 2.0, 50)
    ps, hyps = [], []
    for k in range(n_hyps):
        y = np.stack([10 + 8 * np.cos(2 * t + k), 12 + 6 * np.sin(3 * t) + 2 * t], -1)
        p = fit_dmp(t, y, config).params
        yy = rollout(p.to_torch(), torch.as_tensor(t), config).numpy()
        traj = {"t": t.tolist(), "y": yy.tolist()}
        ps.append(p)
        hyps.append({"rank": k + 1, "probability": 1.0 / (k + 2) if n_hyps > 1 else 1.0,
                     "dmp": p.to_dict(), "trajectory": traj})  # fmt: skip
    rec = {"image": "x.png", "dmp": ps[0].to_dict(), "vector": _vector(ps[0]).tolist(),
           "trajectory": hyps[0]["trajectory"]}  # fmt: skip
    if n_hyps > 1:
        hyps[0]["probability"] = 0.6
        rec["hypotheses"] = hyps
    return rec, ps


@pytest.mark.parametrize("scaling", ["goal-start", "none"])
def test_an_old_predict_record_is_converted(tmp_path, scaling):
    rec, ps = _old_record(DMPConfig(scaling=scaling), n_hyps=2)
    path = tmp_path / "x_dmp.json"
    path.write_text(json.dumps(rec))
    with pytest.raises(
        ValueError, match=r"field 'image_size' is missing: a prediction record"
    ) as e:
        load_dmp_json(path)
    assert str(e.value).startswith(f"{path}: ") and "\n" not in str(e.value)
    params, config, size = load_dmp_json(path, image_size=(40, 40))
    assert config == DMPConfig(scaling=scaling) and size == (40, 40)  # constants recovered
    np.testing.assert_array_equal(_vector(params), _vector(ps[0]))
    np.testing.assert_array_equal(
        _vector(load_dmp_json(path, hypothesis=2, image_size=(40, 40))[0]), _vector(ps[1])
    )
    f = read_dmp_file(path, image_size=(40, 40))
    assert f.converted_from == "predict record" and f.frame == "model"
    assert f.document["image"] == "x.png" and "vector" not in f.document  # a note stays
    # a model with other constants: its trajectory gives it away
    rec, _ = _old_record(DMPConfig(alpha_z=30.0, scaling=scaling))
    path.write_text(json.dumps(rec))
    with pytest.raises(ValueError, match="field 'trajectory' cannot be reproduced"):
        load_dmp_json(path, image_size=(40, 40))
    rec["trajectory"]["t"][7] = rec["trajectory"]["t"][6]  # a time stamp repeated
    path.write_text(json.dumps(rec))
    with pytest.raises(ValueError) as e:
        load_dmp_json(path, image_size=(40, 40))
    t6 = rec["trajectory"]["t"][6]
    assert str(e.value) == (f"{path}: field 'trajectory.t' must increase strictly, but "
                            f"t[7] = {t6!r} follows t[6] = {t6!r}")  # fmt: skip


def test_a_version_1_file_still_reads_and_the_cli_asks_for_an_old_records_size(tmp_path, capsys):
    config = DMPConfig(scaling="none")
    t = np.linspace(0, 1, 30)
    params = fit_dmp(t, np.stack([5 + 10 * t, 8 + 3 * t**2], -1), config).params
    v1 = {"dmp_config": config.to_dict(), "params": params.to_dict(), "image_size": [28, 28],
          "label": 3}  # fmt: skip
    path = tmp_path / "v1.json"
    path.write_text(json.dumps(v1))
    p, c, size = load_dmp_json(path)
    assert c == config and size == (28, 28)
    np.testing.assert_array_equal(_vector(p), _vector(params))
    f = read_dmp_file(path)
    assert f.converted_from == "version 1" and f.document["label"] == 3
    with pytest.raises(ValueError, match=r"field 'image_size' is \[28, 28\]; the image size given"):
        load_dmp_json(path, image_size=(40, 40))
    rec, _ = _old_record(DMPConfig())
    (tmp_path / "old.json").write_text(json.dumps(rec))
    argv = ["write", "--dmp", str(tmp_path / "old.json"), "--out-dir", str(tmp_path / "W")]
    if not available():
        pytest.skip("pybullet is not installed: img2dmp write stops before reading the file")
    assert cli.main([*argv, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "field 'image_size' is missing" in err and "--image-size H W" in err


# -- 5. bad input --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "image, message",
    [
        (np.zeros(5), r"image array must be a grey-level \[H, W\], RGB .* got shape \(5,\)"),
        (np.full((20, 20), np.nan), "image array contains NaN or inf"),
        (np.array([["a", "b"], ["c", "d"]]), "image array must hold numbers, got dtype <U1"),
        (np.full((20, 20), 0.5), "image array shows no ink"),
        (np.zeros((20, 20, 2)), r"got shape \(20, 20, 2\)"),
        (42, "image must be a file path, a PIL image or a NumPy array, got int"),
    ],
    ids=["1-d", "nan", "text", "blank", "two-channels", "int"],
)
def test_bad_images_are_named(runs, image, message):
    model = img2dmp.load_model(runs[1])
    with pytest.raises(ValueError, match=message) as e:
        model.predict(image)
    assert "\n" not in str(e.value)


def test_bad_arguments_of_the_one_call_are_named(runs, seven, tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing"):
        img2dmp.load_model(tmp_path / "nothing")
    with pytest.raises(ValueError, match="refine must be a whole number in .*got -1"):
        img2dmp.load_model(runs[1], refine=-1)
    model = img2dmp.load_model(runs[1])
    with pytest.raises(ValueError, match=r"n_points \(--points\) must be .*got 1"):
        model.predict(seven["png"], n_points=1)
    with pytest.raises(ValueError, match="my scan shows no ink"):
        model.predict(np.ones((30, 30)), name="my scan")
    with pytest.raises(FileNotFoundError, match="image file .*missing.png does not exist"):
        model.predict(tmp_path / "missing.png")


def _set(d: dict, dotted: str, value) -> None:
    keys = dotted.split(".")
    for k in keys[:-1]:
        d = d[int(k)] if isinstance(d, list) else d[k]
    d[keys[-1]] = value


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("format", "other", "field 'format' must be 'img2dmp-dmp', got \"other\""),
        ("version", 3, "field 'version' is 3: written by a newer img2dmp"),
        ("version", "2", "field 'version' must be a whole number >= 1, got \"2\""),
        ("frame", "paper", "field 'frame' must be one of model, image, got \"paper\""),
        ("hypotheses", [], "field 'hypotheses' must be a non-empty list"),
        ("hypotheses.1.probability", 1.5, r"'hypotheses\[1\].probability' must be a number in"),
        ("hypotheses.1.probability", 0.99, r"'hypotheses\[1\].probability' is 0.99, above"),
        ("hypotheses.1.rank", 1, r"'hypotheses\[1\].rank' must be 2 \(ranked from 1\), got 1"),
        ("hypotheses.0.params.tau", 9.0, r"'hypotheses\[0\].params' differs from 'params'"),
        ("hypotheses.0.params_image.tau", 9.0, r"'hypotheses\[0\].params_image' is not params"),
        ("hypotheses.0.params_image.tau", True, r"'hypotheses\[0\].params_image' is invalid"),
        ("hypotheses.0.colour", "red", r"'hypotheses\[0\]' has unknown field\(s\) \['colour'\]"),
        ("hypotheses.0.trajectory.t_s", [0.0], r"'hypotheses\[0\].trajectory.xy_model_px' has"),
        ("hypotheses.0.trajectory.pen", [1.0], r"'hypotheses\[0\].trajectory.pen' must be given"),
        ("image_frame.model_to_image", [[1, 0, 0], [0, 1, 0]], "is not the inverse of"),
        ("image_frame.image_to_model", [[1, 2, 0], [2, 4, 0]], "'image_frame.image_to_model' is"),
        ("image_frame.model_size", [28, 28], r"'image_frame.model_size' is \[28, 28\], but"),
        ("image_frame.image", 7, "'image_frame.image' must be a file name or null, got 7"),
        ("refinement.steps", -1, "'refinement.steps' must be a whole number >= 0, got -1"),
        ("frame", "image", "'image_frame' needs \"frame\": \"model\""),
    ],
)  # fmt: skip
def test_a_dmp_file_is_strict_in_its_new_fields(runs, seven, tmp_path, field, value, message):
    path = tmp_path / "x_dmp.json"
    pred = img2dmp.load_model(runs[2]).predict(seven["png"], n_points=5)
    doc = pred.to_document()
    _set(doc, field, value)
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=message) as e:
        load_dmp_json(path)
    assert str(e.value).startswith(f"{path}: ") and "\n" not in str(e.value)
    with pytest.raises(ValueError, match=message):  # the writers refuse what the reader does
        write_dmp_document(tmp_path / "again.json", doc)
    assert not (tmp_path / "again.json").exists()


def test_a_rank_the_file_does_not_have_is_named(runs, seven, tmp_path):
    path = img2dmp.load_model(runs[1]).predict(seven["png"]).save(tmp_path / "one.json")
    with pytest.raises(
        ValueError, match=r"field 'hypotheses': the file has one DMP; .*1\.\.1, got 2"
    ):
        load_dmp_json(path, hypothesis=2)
    with pytest.raises(ValueError, match="got True"):
        load_dmp_json(path, hypothesis=True)


def test_write_from_an_image_takes_the_hypothesis_of_the_rank_asked_for(runs, seven, tmp_path):
    from img2dmp.commands import write as write_command

    def inputs(*extra):
        parser = argparse.ArgumentParser()
        write_command.add_arguments(parser)
        args = parser.parse_args([str(seven["png"]), "--model", str(runs[2]), *extra])
        return write_command._inputs(args)

    pred = img2dmp.load_model(runs[2]).predict(seven["png"])
    for rank in (1, 2):
        [(name, params, config, size, image)] = inputs("--hypothesis", str(rank))
        assert (name, size, config) == ("seven", (40, 40), pred.dmp_config)
        np.testing.assert_allclose(_vector(params), _vector(pred.params[rank - 1]), rtol=1e-6)
    with pytest.raises(
        ValueError, match=r"--hypothesis 3: the model proposes 2 .*\(ranks 1\.\.2\)"
    ):
        inputs("--hypothesis", "3")
    parser = argparse.ArgumentParser()
    write_command.add_arguments(parser)
    args = parser.parse_args([str(seven["png"]), "--model", "m", "--image-size", "40", "40"])
    with pytest.raises(ValueError, match="--image-size is for --dmp files"):
        write_command.check_files(args)
