"""How familiar an image is to a model (``img2dmp.familiar``): the encoder's features in
NumPy and torch, the familiarity file, the line drawn on validation drawings, the
``"unfamiliar"`` flag of a stroke model's predictions and pages, and shipping it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import img2dmp
from img2dmp import cli, models
from img2dmp.data.store import load_dataset
from img2dmp.familiar import FORMAT, Familiar, fit_familiar, unit_rows
from img2dmp.predict import Predictor

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "examples" / "samples"


@pytest.mark.parametrize("source", ["omniglot-strokes", "digits-real"])
def test_the_numpy_encoder_gives_torch_s_features(source):
    import torch

    numpy = Predictor.load(source, backend="numpy")
    torch_ = Predictor.load(source, backend="torch")
    rng = np.random.default_rng(0)
    x = (rng.random((5, *numpy.image_size)) > 0.8).astype(np.float32)
    f = numpy.encoder_features(x)
    m = torch_.model
    with torch.no_grad():
        ref = m.encoder(m.input_filter(torch.as_tensor(x))).numpy()
    assert f.shape == ref.shape == (5, numpy.network.feature_size)
    np.testing.assert_allclose(f, ref, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(torch_.encoder_features(x), ref, rtol=1e-6, atol=1e-7)
    with pytest.raises(ValueError, match=r"images must be \[B, "):
        numpy.encoder_features(x[0])


def test_familiarity_is_the_cosine_to_the_nearest_training_drawing():
    ref = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    fam = Familiar(ref.astype(np.float32), line=0.5)
    got = fam.familiarity([[3.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    np.testing.assert_allclose(got, [1.0, 0.0, np.sqrt(0.5), 0.0], atol=1e-12)
    with pytest.raises(ValueError, match=r"features must be \[B, 3\]"):
        fam.familiarity(np.zeros((2, 4)))
    with pytest.raises(ValueError, match="cosine in"):
        Familiar(ref, line=1.5)
    with pytest.raises(ValueError, match="finite"):
        Familiar(np.full((2, 3), np.nan), line=0.5)


def test_a_training_drawing_itself_is_at_most_1_familiar():
    # The unit rows are held in float32: unclipped, a drawing's cosine to itself can come
    # out a rounding above 1.
    rows = np.random.default_rng(5).normal(size=(300, 64))
    got = Familiar(rows, line=0.5).familiarity(rows)
    assert (got <= 1.0).all() and np.allclose(got, 1.0, atol=1e-6)


def test_a_familiarity_file_round_trips_and_a_bad_one_is_named(tmp_path):
    rng = np.random.default_rng(1)
    fam = Familiar(unit_rows(rng.normal(size=(7, 4))).astype(np.float32), 0.8, 0.05, 12)
    path = fam.save(tmp_path / "f.safetensors")
    back = Familiar.load(path)
    assert (back.line, back.quantile, back.n_validation) == (0.8, 0.05, 12)
    np.testing.assert_allclose(back.features, fam.features, atol=1e-3)  # float16 stored
    (tmp_path / "junk.safetensors").write_bytes(b"not a safetensors file")
    with pytest.raises(ValueError, match=r"familiarity file .*junk.safetensors cannot be read"):
        Familiar.load(tmp_path / "junk.safetensors")
    from safetensors.numpy import save_file

    save_file({"features": np.zeros((2, 2), np.float16)}, tmp_path / "other.safetensors")
    with pytest.raises(
        ValueError, match=rf"other.safetensors is not a familiarity file .*{FORMAT}"
    ):
        Familiar.load(tmp_path / "other.safetensors")
    meta = {"familiar": json.dumps({"format": FORMAT, "version": 9, "line": 0.5})}
    save_file({"features": np.ones((2, 2), np.float16)}, tmp_path / "v9.safetensors", meta)
    with pytest.raises(ValueError, match="version 9 is not supported"):
        Familiar.load(tmp_path / "v9.safetensors")


class _Net:
    """What fit_familiar asks of a predictor: the encoder's features of images (here
    the images' own pixels)."""

    def encoder_features(self, images):
        return np.asarray(images, dtype=np.float64).reshape(len(images), -1)


class _Data:
    def __init__(self, images, split):
        self.images, self.split = images, np.asarray(split)


def test_the_line_is_the_validation_drawings_quantile():
    rng = np.random.default_rng(2)
    images = rng.normal(size=(60, 2, 3))
    split = np.r_[np.zeros(40, int), np.ones(20, int)]
    fam = fit_familiar(_Net(), _Data(images, split), quantile=0.1)
    ref = unit_rows(images[:40].reshape(40, -1)).astype(np.float16).astype(np.float64)
    val = unit_rows(images[40:].reshape(20, -1))
    expect = np.quantile((val @ unit_rows(ref).T).max(1), 0.1)
    assert fam.line == pytest.approx(expect, abs=1e-6)  # unit rows held in float32
    assert fam.n_validation == 20 and len(fam.features) == 40
    assert (fam.familiarity(images[40:].reshape(20, -1)) < fam.line).sum() == 2
    with pytest.raises(ValueError, match="needs training and validation rows, has 40 and 0"):
        fit_familiar(_Net(), _Data(images[:40], split[:40]))
    with pytest.raises(ValueError, match="quantile"):
        fit_familiar(_Net(), _Data(images, split), quantile=0.7)


@pytest.mark.parametrize(
    ("name", "sample"), [("omniglot-strokes", "character_f.png"), ("digits-real", "digit_3.png")]
)
def test_a_prediction_is_flagged_unfamiliar_below_the_line_only(name, sample):
    predictor = img2dmp.load_model(name, refine=0)
    image = SAMPLES / sample
    own = predictor.predict(image)
    assert own.familiarity is not None and own.familiar_line == predictor.familiar.line
    assert ("unfamiliar" in own.flags) == (own.familiarity < own.familiar_line)
    assert own.to_document()["familiarity"] == {
        "value": round(own.familiarity, 6),
        "line": round(predictor.familiar.line, 6),
    }
    # the image's own features as the only training drawing: familiarity 1, not flagged
    features = predictor.encoder_features(own.image[None])
    predictor.familiar = Familiar(features, line=0.999)
    same = predictor.predict(image)
    assert same.familiarity == pytest.approx(1.0, abs=1e-6) and "unfamiliar" not in same.flags
    predictor.familiar = Familiar(-features, line=0.0)  # pointing away: flagged, last
    away = predictor.predict(image)
    assert away.familiarity < 0 and away.flags[-1] == "unfamiliar"
    assert away.flags[:-1] == [f for f in own.flags if f != "unfamiliar"]
    if name == "digits-real":  # a digit page's entries too
        page = predictor.predict_page(SAMPLES / "page.jpg").to_document()
        assert page["characters"] and all(
            ("unfamiliar" in c["flags"]) == (c["familiarity"] < 0.0) for c in page["characters"]
        )
    predictor.familiar = None  # none carried: nothing recorded, nothing flagged
    none = predictor.predict(image)
    assert none.familiarity is None and "familiarity" not in none.to_document()
    assert "unfamiliar" not in none.flags


def test_the_digit_model_flags_a_letter_and_not_a_digit():
    """digits-real's familiarity (RESULTS 8.13): the drawn F of the samples is unlike
    every digit it learnt, the drawn 3 and the photographed 5 are not."""
    digits = img2dmp.load_model("digits-real")
    assert digits.familiar is not None and digits.familiar.feature_size == 64
    letter = digits.predict(SAMPLES / "character_f.png")
    assert "unfamiliar" in letter.flags and letter.familiarity < digits.familiar.line
    for name in ("digit_3.png", "digit_5_photo.jpg"):
        digit = digits.predict(SAMPLES / name)
        assert digit.familiarity >= digits.familiar.line and "unfamiliar" not in digit.flags


def test_a_page_notes_each_character_s_familiarity_and_flags_it():
    predictor = img2dmp.load_model("omniglot-strokes", refine=0)
    page = predictor.predict_page(SAMPLES / "letters_page.png")
    doc = page.to_document()
    line = predictor.familiar.line
    seen = set()
    assert doc["entries"] == "strokes"
    for entry in doc["characters"]:
        fam = entry["familiarity"]
        assert fam is not None and -1.0 <= fam <= 1.0
        assert ("unfamiliar" in entry["flags"]) == (fam < line)
        seen.add(entry["character"])
    assert len(seen) == len(page.characters) == 8
    one = page.characters[0].prediction
    assert one.familiarity == pytest.approx(predictor.familiarity(one.image[None])[0], abs=1e-6)


def test_a_run_of_one_s_own_gets_a_familiarity_and_ships_it(
    stroke_run, small_omniglot, tmp_path, monkeypatch, experiment_script
):
    predictor = Predictor.load(stroke_run)
    assert predictor.familiar is not None  # img2dmp train wrote it (the next test)
    data = load_dataset(small_omniglot)
    predictor.familiar = fit_familiar(predictor, small_omniglot)
    val = np.flatnonzero(data.split == 1)
    below = predictor.familiarity(data.images[val]) < predictor.familiar.line
    assert below.mean() <= 0.05 + 1.0 / len(val)
    # shipped: the file beside the weights, its digest in model.json, loaded with the model
    ship = experiment_script("ship_model")
    monkeypatch.setattr(ship, "MODELS", tmp_path / "models")
    ev = tmp_path / "ev"
    assert cli.main(["evaluate", "--model", str(stroke_run), "--data", str(small_omniglot),
                     "--split", "test", "--figures", "0", "--out", str(ev)]) == 0  # fmt: skip
    args = ["--run", str(stroke_run), "--evaluation", str(ev / "evaluation.json"),
            "--name", "mine", "--familiar", str(small_omniglot)]  # fmt: skip
    assert ship.main(args) == 0
    (shipped,) = models.shipped_models(tmp_path / "models")
    assert shipped.familiar is not None and models.verified_familiar(shipped)
    record = shipped.record["familiar"]
    assert record["line"] == pytest.approx(predictor.familiar.line, abs=1e-6)
    assert record["n_train"] == int((data.split == 0).sum())
    # shipped again without --familiar, same weights: kept
    assert ship.main(args[:-2]) == 0
    (again,) = models.shipped_models(tmp_path / "models")
    assert again.record["familiar"] == record and again.familiar.is_file()


def test_the_features_kept_from_the_network_s_pass_are_those_of_the_same_images():
    predictor = img2dmp.load_model("omniglot-strokes", refine=0)
    x = (np.random.default_rng(3).random((3, *predictor.image_size)) > 0.85).astype(np.float32)
    predictor.predict_strokes(x)  # the network's pass keeps the features
    fresh = predictor.familiar.familiarity(predictor.network.features(x))
    np.testing.assert_allclose(predictor.familiarity(x), fresh, atol=1e-6)
    x[0] = 0.0
    x[0, 10:30, 20] = 1.0  # the caller's array changed in place: not the kept images
    fresh = predictor.familiar.familiarity(predictor.network.features(x))
    np.testing.assert_allclose(predictor.familiarity(x), fresh, atol=1e-6)
    assert abs(predictor.familiarity(x)[0] - fresh[0]) < 1e-6


def test_one_prediction_computes_its_familiarity_once(monkeypatch):
    """The refinement's steps and the flag both need it: the second asks for the same
    kept features and gets the answer of the first (a product with every training
    drawing's features, ~3 ms of a 35 ms prediction)."""
    predictor = img2dmp.load_model("digits-real")
    calls = []
    real = Familiar.familiarity
    monkeypatch.setattr(Familiar, "familiarity", lambda self, f: calls.append(1) or real(self, f))
    pred = predictor.predict(SAMPLES / "digit_3.png")
    assert len(calls) == 1
    fresh = real(predictor.familiar, predictor.network.features(pred.image[None]))
    assert pred.familiarity == pytest.approx(float(fresh[0]), abs=1e-6)
    first = predictor.familiarity(pred.image[None])
    first[0] = -5.0  # the caller's copy: the kept answer is not changed through it
    assert predictor.familiarity(pred.image[None])[0] == pytest.approx(float(fresh[0]), abs=1e-6)
    features = predictor.encoder_features(pred.image[None])
    features[:] = 0.0  # nor the kept features through the caller's array
    np.testing.assert_array_equal(
        predictor.encoder_features(pred.image[None]), predictor.network.features(pred.image[None])
    )


def test_predict_warns_of_an_unfamiliar_character_with_its_familiarity(tmp_path, capsys):
    """The drawn digit 3 read by the stroke model: digits are in none of its alphabets."""
    image = SAMPLES / "digit_3.png"
    assert cli.main(["predict", str(image), "--model", "omniglot-strokes", "--out",
                     str(tmp_path)]) == 0  # fmt: skip
    doc = json.loads((tmp_path / "digit_3_dmp.json").read_text())
    fam = doc["familiarity"]
    assert fam["value"] < fam["line"] and "unfamiliar" in doc["flags"]
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if "warning" in x)
    assert f"unfamiliar (familiarity {fam['value']:.3f}, the model's line {fam['line']:.3f}; " in (
        line
    )


def test_familiarity_in_parts_is_the_whole_product_s_and_max_train_keeps_a_choice():
    rng = np.random.default_rng(4)
    ref, query = rng.normal(size=(5000, 8)), rng.normal(size=(1500, 8))
    fam = Familiar(ref.astype(np.float32), 0.5)
    whole = (unit_rows(query) @ unit_rows(ref.astype(np.float32)).T).max(1)
    np.testing.assert_allclose(fam.familiarity(query), whole, atol=1e-12)
    images = rng.normal(size=(60, 2, 3))
    split = np.r_[np.zeros(40, int), np.ones(20, int)]
    small = fit_familiar(_Net(), _Data(images, split), max_train=10)
    assert len(small.features) == 10
    rows = unit_rows(images[:40].reshape(40, -1)).astype(np.float16).astype(np.float32)
    assert all(any(np.allclose(f, r) for r in rows) for f in small.features)  # training rows
    with pytest.raises(ValueError, match="max_train"):
        fit_familiar(_Net(), _Data(images, split), max_train=0)


def test_the_familiarity_experiment_counts_what_it_flags(
    small_omniglot, experiment_script, tmp_path, capsys
):
    mod = experiment_script("familiarity")
    photos = tmp_path / "photos"
    photos.mkdir()
    (photos / "letters.png").write_bytes((SAMPLES / "letters_page.png").read_bytes())
    assert mod.main(["--data", str(small_omniglot), "--photos", str(photos)]) == 0
    out = capsys.readouterr().out
    n_val = int((load_dataset(small_omniglot).split == 1).sum())
    assert f"validation rows: {n_val} characters, below the line " in out
    page = img2dmp.load_model("omniglot-strokes").predict_page(photos / "letters.png")
    low = sum("unfamiliar" in c.flags for c in page.characters)
    assert f"letters.png: {len(page.characters)} characters, unfamiliar {low}, " in out
    r = {"familiarity": np.array([0.1, 0.9, 0.95]), "ink": np.array([0.5, 1.0, 0.9])}
    assert mod.describe("x", r, 0.5) == (
        "x: 3 characters, below the line 1 (33.3 %); below: on the ink 50.0 %; "
        "above: on the ink 95.0 %"
    )


@pytest.mark.parametrize(
    ("name", "familiar", "other"),
    [("omniglot-strokes", "character_f.png", "digit_3.png"),
     ("digits-real", "digit_3.png", "character_f.png")],
)  # fmt: skip
def test_unfamiliar_images_are_refined_with_their_own_steps(name, familiar, other):
    predictor = img2dmp.load_model(name, refine=0)
    x = np.stack([predictor.predict(SAMPLES / s).image for s in (familiar, other)])
    # the first image's own features as the only training drawing: it is familiar (1.0),
    # the other lies below the line
    predictor.familiar = Familiar(predictor.encoder_features(x[:1]), line=0.999)
    predictor.refine_with(4, unfamiliar=9)
    assert predictor.refine_unfamiliar == 9 and list(predictor.refine_steps_for(x)) == [4, 9]

    def read(images):
        if predictor.strokes is not None:
            return [v for v, _ in predictor.predict_strokes(images)]
        params, _ = predictor.predict_hypotheses(images)
        return list(np.concatenate([params.w.reshape(len(images), -1), params.g.reshape(
            len(images), -1), params.y0.reshape(len(images), -1)], axis=1))  # fmt: skip

    both = read(x)
    predictor.refine_with(4)
    assert predictor.refine_unfamiliar is None and list(predictor.refine_steps_for(x)) == [4, 4]
    four = read(x)
    np.testing.assert_array_equal(both[0], four[0])  # the familiar one: 4 steps
    assert not np.array_equal(both[1], four[1])
    predictor.refine_with(9)
    np.testing.assert_array_equal(both[1], read(x)[1])  # the unfamiliar one: 9 steps
    # a prediction records the steps its image had; a page both settings
    predictor.refine_with(4, unfamiliar=9)
    assert predictor.predict(SAMPLES / other).to_document()["refinement"] == {"steps": 9}
    assert predictor.predict(SAMPLES / familiar).to_document()["refinement"] == {"steps": 4}
    predictor.refine_with(0, unfamiliar=9)  # only the unfamiliar ones refined
    assert list(predictor.refine_steps_for(x)) == [0, 9]
    page = predictor.predict_page(SAMPLES / "letters_page.png").to_document()
    assert page["refinement"] == {"steps": 0, "unfamiliar_steps": 9}
    predictor.refine_with(5, unfamiliar=5)  # the same steps: nothing to tell apart
    assert predictor.refine_unfamiliar is None
    predictor.familiar = None
    with pytest.raises(ValueError, match="carries no familiarity"):
        predictor.refine_with(5, unfamiliar=9)
    with pytest.raises(ValueError, match=r"refine_unfamiliar .* \[0, "):
        img2dmp.load_model(name, refine_unfamiliar=-1)


@pytest.mark.parametrize("name", ["omniglot-strokes", "digits-real"])
def test_a_shipped_model_refines_unfamiliar_images_as_its_card_recommends(name):
    shipped = models.find_shipped(name)
    assert shipped.refine_unfamiliar is not None and shipped.refine_unfamiliar > shipped.refine
    assert img2dmp.load_model(name).refine_unfamiliar == shipped.refine_unfamiliar
    assert img2dmp.load_model(name, refine=7).refine_unfamiliar is None  # --refine alone: all
    assert img2dmp.load_model(name, refine=7, refine_unfamiliar=11).refine_unfamiliar == 11
    assert shipped.figures["refine_unfamiliar"] == shipped.refine_unfamiliar


def test_training_writes_the_run_s_familiarity_for_its_best_checkpoint_only(
    stroke_run, small_omniglot, tmp_path, capsys
):
    import shutil

    from img2dmp.familiar import RUN_FILE, run_familiar

    own = Predictor.load(stroke_run)
    assert own.familiar is not None and own.familiar.weights_sha256
    again = fit_familiar(own, small_omniglot)  # the data set's splits: the rows it trained on
    assert own.familiar.line == pytest.approx(again.line, abs=1e-6)
    np.testing.assert_array_equal(own.familiar.features, again.features)
    run = shutil.copytree(stroke_run, tmp_path / "run")
    best = run / "checkpoints" / "best.safetensors"
    assert run_familiar(best) is not None and run_familiar(tmp_path / "elsewhere.st") is None
    stale = Familiar(own.familiar.features, own.familiar.line, weights_sha256="0" * 64)
    stale.save(run / RUN_FILE)  # drawn for other weights: not used
    assert Predictor.load(run).familiar is None
    (run / RUN_FILE).write_bytes(b"not a familiarity file")
    with pytest.raises(ValueError, match="familiar.safetensors .*write_run_familiar"):
        Predictor.load(run)
    # an evaluation with it: the unfamiliar share and their steps recorded
    (run / RUN_FILE).unlink()
    shutil.copyfile(stroke_run / RUN_FILE, run / RUN_FILE)
    out = tmp_path / "ev"
    assert cli.main(["evaluate", "--model", str(run), "--data", str(small_omniglot), "--split",
                     "test", "--refine", "2", "--refine-unfamiliar", "3", "--figures", "0",
                     "--out", str(out), "--no-progress"]) == 0  # fmt: skip
    ev = json.loads((out / "evaluation.json").read_text())
    assert (ev["refine_steps"], ev["refine_unfamiliar_steps"]) == (2, 3)
    fam = np.asarray(ev["unfamiliar"]["familiarity"])
    assert ev["unfamiliar"]["share"] == pytest.approx(np.mean(fam < ev["unfamiliar"]["line"]))
    assert "unfamiliar to the model" in (out / "evaluation.txt").read_text()
    # --refine-unfamiliar alone: the others as a run's default, not refined
    image = str(SAMPLES / "character_f.png")
    assert cli.main(["predict", image, "--model", str(run), "--refine-unfamiliar", "3",
                     "--out", str(tmp_path / "p"), "--no-progress"]) == 0  # fmt: skip
    doc = json.loads((tmp_path / "p" / "character_f_dmp.json").read_text())
    below = doc["familiarity"]["value"] < doc["familiarity"]["line"]
    assert doc["refinement"] == {"steps": 3 if below else 0}
    (run / RUN_FILE).unlink()  # none: the option is refused in one line
    capsys.readouterr()
    for command in (["evaluate", "--data", str(small_omniglot), "--figures", "0", "--out",
                     str(tmp_path / "ev2")], ["predict", image]):  # fmt: skip
        code = cli.main(
            [*command, "--model", str(run), "--refine-unfamiliar", "3", "--no-progress"]
        )
        err = capsys.readouterr().err
        assert code == 2 and "carries no familiarity" in err and err.count("\n") == 1
