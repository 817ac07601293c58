"""The models shipped inside the package (img2dmp.models, ``img2dmp models``, ``--model
NAME``): their digests, their cards' figures, and the default model with its settings."""

from __future__ import annotations

import argparse
import json
import math
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

import img2dmp
from img2dmp import cli, models
from img2dmp.checkpoint import read_checkpoint_meta
from img2dmp.commands import _args
from img2dmp.errors import ShippedModelError, UnknownModelError
from img2dmp.nn.strokes import COUNT_VIEWS, MAX_COUNT_VIEWS

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data"
SAMPLE = ROOT / "examples" / "samples" / "digit_3.png"
MAX_BYTES = 3 * 1024 * 1024


def _one_error_line(err: str, command: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"img2dmp {command}: error: "), err
    return lines[0]


# --- what is shipped ------------------------------------------------------------------


def test_each_shipped_file_has_its_recorded_digest_and_size():
    shipped = models.shipped_models()
    assert shipped, "no model ships with img2dmp"
    for m in shipped:
        data = m.weights.read_bytes()
        assert len(data) == m.size_bytes <= MAX_BYTES, m.name
        assert models.file_digest(m.weights) == m.sha256, m.name
        assert models.verified_weights(m) == m.weights
        own = [models.WEIGHTS_FILE, models.RECORD_FILE, models.CARD_FILE]
        if m.familiar is not None:  # a familiarity, checked as the weights are
            own.append(models.FAMILIAR_FILE)
            assert models.verified_familiar(m) == m.familiar
            assert m.familiar.stat().st_size == m.record["familiar"]["bytes"]
        for f in m.folder.iterdir():  # nothing else in the folder grows the wheel
            assert f.name in own, f
            assert f.stat().st_size <= MAX_BYTES, f
        # the checkpoint inside is the one recorded (its own record digest verified)
        assert (
            read_checkpoint_meta(m.weights)["record_sha256"] == m.record["weights"]["record_sha256"]
        )


def test_every_shipped_file_is_in_the_repository():
    """A file of a shipped model that git ignores would be missing from every clone
    (``.gitignore`` ignores ``*.safetensors`` but the shipped models' own)."""
    import subprocess

    if not (ROOT / ".git").exists() or shutil.which("git") is None:
        pytest.skip("not a git checkout (an installed package): nothing to compare with")
    tracked = subprocess.run(["git", "ls-files", "src/img2dmp/models"], cwd=ROOT, check=True,
                             capture_output=True, text=True).stdout.split()  # fmt: skip
    for m in models.shipped_models():
        for f in m.folder.iterdir():
            assert f.relative_to(ROOT).as_posix() in tracked, f"{f} is not committed"


def test_the_wheel_takes_every_shipped_file():
    import fnmatch
    import tomllib

    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    globs = pyproject["tool"]["setuptools"]["package-data"]["img2dmp"]
    package = ROOT / "src" / "img2dmp"
    for m in models.shipped_models():
        for f in m.folder.iterdir():
            rel = f.relative_to(package).as_posix()
            assert any(fnmatch.fnmatch(rel, g) for g in globs), rel


def test_exactly_one_default_and_the_help_names_it():
    default = models.default_model()
    assert [m.name for m in models.shipped_models() if m.default] == [default.name]
    assert _args.DEFAULT_MODEL_NAME == default.name
    assert _args.DEFAULT_REFINE == default.refine
    assert (_args.DEFAULT_COUNT_VIEWS, _args.MAX_COUNT_VIEWS) == (COUNT_VIEWS, MAX_COUNT_VIEWS)


def test_each_card_states_its_records_figures_commands_and_limits():
    for m in models.shipped_models():
        card = m.card.read_text(encoding="utf-8")
        f = m.figures
        for value in (f"{f['chamfer_px']:.4f}", f"{100 * f['path_on_ink']:.1f} %",
                      f"{f['path_error_px']:.3f}", m.sha256, f"{m.size_bytes:,}"):  # fmt: skip
            assert value in card, (m.name, value)
        assert f"--refine {f['refine']}" in card and f"--refine {m.refine}" in card
        if m.refine_unfamiliar is not None:  # and the steps of images it finds unfamiliar
            assert f"--refine-unfamiliar {m.refine_unfamiliar}" in card, m.name
        if "count_views" in f:  # a stroke model: the views its figures' counts were read from
            assert f"--count-views {f['count_views']}" in card, m.name
            assert f"--count-views {m.count_views}" in card, m.name
        if f.get("count_mode_right"):  # and the count's ceiling, with the share of it read
            mode = f["count_mode_right"]
            for value in (f"{100 * mode:.1f} %", f"{100 * f['count_right'] / mode:.1f} %"):
                assert value in card, (m.name, value)
        for key in ("prepare_command", "train_command"):
            assert m.record["provenance"][key] in " ".join(card.split()).replace("\\ ", ""), key
        for revision in (m.record["provenance"]["prepare_revision"],
                         m.record["provenance"]["train_revision"]):  # fmt: skip
            assert revision in card
        assert "## What it is not for" in card


# --- names, damage, defaults ----------------------------------------------------------


def _copy_of_the_models(tmp_path, monkeypatch) -> Path:
    root = tmp_path / "shipped"
    shutil.copytree(models.models_root(), root, ignore=shutil.ignore_patterns("*.py", "__py*"))
    monkeypatch.setattr(models, "models_root", lambda: root)
    return root


def test_a_damaged_shipped_file_is_refused_naming_it(tmp_path, monkeypatch, capsys):
    root = _copy_of_the_models(tmp_path, monkeypatch)
    name = models.default_model().name
    weights = root / name / models.WEIGHTS_FILE
    data = bytearray(weights.read_bytes())
    data[len(data) // 2] ^= 0x01  # one bit in the weights
    weights.write_bytes(bytes(data))
    with pytest.raises(ShippedModelError, match=rf"shipped model {name}: .*{weights.name} is "
                       r"damaged: its SHA-256 .* is not the recorded"):  # fmt: skip
        img2dmp.load_model(name)
    with pytest.raises(ShippedModelError, match="damaged"):
        img2dmp.load_model()  # the default too
    assert cli.main(["predict", str(SAMPLE)]) == 2
    line = _one_error_line(capsys.readouterr().err, "predict")
    assert str(weights) in line and "reinstall img2dmp" in line
    weights.write_bytes(bytes(data[:1000]))  # truncated
    assert cli.main(["predict", "--model", name, str(SAMPLE)]) == 2
    assert "damaged" in _one_error_line(capsys.readouterr().err, "predict")
    assert cli.main(["models"]) == 0
    assert "DAMAGED" in capsys.readouterr().out


def test_a_damaged_familiarity_file_is_refused_naming_it(tmp_path, monkeypatch, capsys):
    root = _copy_of_the_models(tmp_path, monkeypatch)
    carriers = [m for m in models.shipped_models() if m.familiar is not None]
    assert carriers, "no shipped model carries a familiarity"
    name = carriers[0].name
    familiar = root / name / models.FAMILIAR_FILE
    data = bytearray(familiar.read_bytes())
    data[-3] ^= 0x01  # one bit in the features
    familiar.write_bytes(bytes(data))
    with pytest.raises(ShippedModelError, match=rf"shipped model {name}: .*{familiar.name} is "
                       r"damaged: its SHA-256 .* is not the recorded"):  # fmt: skip
        img2dmp.load_model(name)
    assert cli.main(["models"]) == 0
    assert f"DAMAGED: shipped model {name}" in capsys.readouterr().out


def test_an_unknown_name_lists_the_shipped_models(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    names = models.shipped_model_names()
    with pytest.raises(UnknownModelError, match="no run directory, checkpoint or shipped model "
                       r"named 'digits-rea'; the models shipped with img2dmp are: "
                       + re.escape(", ".join(names))):  # fmt: skip
        img2dmp.load_model("digits-rea")
    assert isinstance(UnknownModelError("x"), FileNotFoundError)
    for argv in (["predict", "--model", "nope", str(SAMPLE)],
                 ["evaluate", "--model", "nope", "--data", str(SAMPLE)],
                 ["export", "--model", "nope", "--onnx", "x.onnx"],
                 ["models", "nope"]):  # fmt: skip
        assert cli.main(argv) == 2, argv
        line = _one_error_line(capsys.readouterr().err, argv[0])
        assert "'nope'" in line and names[0] in line, line
    # a path stays a path: a missing one is named as a file, not looked up
    with pytest.raises(FileNotFoundError, match="checkpoint runs/nope does not exist") as e:
        img2dmp.load_model("runs/nope")
    assert str(e.value).endswith(f"or a shipped model's name: {', '.join(names)})")  # a hint


@pytest.mark.parametrize("value", [0, -1, 2.0, True, "8"])
def test_a_recommended_count_views_that_is_no_count_is_refused_naming_it(
    value, tmp_path, monkeypatch
):
    root = _copy_of_the_models(tmp_path, monkeypatch)
    record = root / "omniglot-strokes" / models.RECORD_FILE
    doc = json.loads(record.read_text(encoding="utf-8"))
    doc["recommended"]["count_views"] = value
    record.write_text(json.dumps(doc), encoding="utf-8")
    with pytest.raises(ShippedModelError, match=r"omniglot-strokes.*recommended setting "
                       r"'count_views' = "):  # fmt: skip
        models.find_shipped("omniglot-strokes")


def test_a_shipped_stroke_model_reads_its_count_as_its_card_recommends(monkeypatch):
    from img2dmp import predict

    m = models.find_shipped("omniglot-strokes")
    assert m.count_views is not None and m.count_views == m.figures["count_views"]
    predictor = img2dmp.load_model(m.name, refine=0)
    assert predictor.count_views == m.count_views
    calls = []
    real = predict.count_views
    monkeypatch.setattr(predict, "count_views", lambda x, n: calls.append(n) or real(x, n))
    predictor.predict(ROOT / "examples" / "samples" / "character_f.png")
    assert calls == [m.count_views]
    assert models.default_model().count_views is None  # a one-DMP model reads no count


def test_the_shipped_stroke_model_reads_the_letters_page_stroke_by_stroke():
    """examples/samples/letters_page.png (A H T X / L E K V, drawn stroke by stroke by
    make_samples.py): every letter found whole, on its line, read with its strokes on the
    ink; the stroke counts mostly right (measured: 6 of 8, the A and the E with fewer)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_samples", ROOT / "examples" /
                                                  "make_samples.py")  # fmt: skip
    samples = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(samples)
    page = img2dmp.load_model("omniglot-strokes").predict_page(
        ROOT / "examples" / "samples" / "letters_page.png"
    )
    assert [len(line) for line in page.lines] == [4, 4]
    letters = "".join(samples.LETTER_LINES)
    said = [c.prediction.n_strokes for c in page.characters]
    drawn = [len(samples.LETTER_STROKES[a]) for a in letters]
    assert sum(a == b for a, b in zip(said, drawn, strict=True)) >= 6, (said, drawn)
    assert all(c.prediction.fit["path_on_ink"] >= 0.85 for c in page.characters)
    assert not any(c.character.split for c in page.characters)  # a letter is never cut
    doc = page.to_document()
    assert len(doc["characters"]) == sum(said) and doc["n_characters"] == 8


def test_count_views_on_a_one_dmp_model_is_one_line_naming_it(capsys):
    assert cli.main(["predict", str(SAMPLE), "--count-views", "2"]) == 2
    line = _one_error_line(capsys.readouterr().err, "predict")
    assert "(--count-views) 2: model digits-real predicts one DMP per image" in line, line
    assert cli.main(["predict", str(SAMPLE), "--count-views", "0"]) == 2
    line = _one_error_line(capsys.readouterr().err, "predict")
    assert "--count-views: must be an integer from 1 to 64, got 0" in line, line


def test_a_folder_of_the_same_name_wins_over_the_shipped_model(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    name = models.default_model().name
    # A path of one word names the shipped model as the string does, until a folder has it.
    assert models.resolve(Path(name)) == models.resolve(name) == models.default_model()
    assert img2dmp.load_model(Path(name), refine=0).n_hypotheses >= 1
    (tmp_path / name).mkdir()
    assert models.resolve(name) is None and models.resolve(Path(name)) is None
    with pytest.raises(FileNotFoundError, match="holds no checkpoint"):
        img2dmp.load_model(name)


def test_the_default_model_is_read_when_none_is_given_whatever_folder_has_its_name(
    tmp_path, monkeypatch, capsys
):
    """Named, a folder ``digits-real`` here wins; not named at all, the default is the
    shipped model, never a folder (``predict --out digits-real`` makes one)."""
    from img2dmp.web.models import load_models

    monkeypatch.chdir(tmp_path)
    name = models.default_model().name
    (tmp_path / name).mkdir()
    assert img2dmp.load_model().shipped.name == name
    assert cli.main(["predict", str(SAMPLE), "--refine", "0"]) == 0
    assert '"flags"' in capsys.readouterr().out
    assert cli.main(["predict", str(SAMPLE), "--model", name]) == 2  # named: the folder
    assert "holds no checkpoint" in capsys.readouterr().err
    [(key, loaded)] = load_models([models.default_model()], refine=0).items()
    assert key == loaded.path == name and loaded.predictor.shipped.name == name


def test_the_default_model_comes_with_its_cards_settings_unless_told_otherwise():
    default = models.default_model()
    assert default.refine == 30
    m = img2dmp.load_model()
    assert m.shipped.name == default.name and m.refine_options.steps == default.refine
    assert img2dmp.load_model(default.name).refine_options.steps == default.refine
    assert img2dmp.load_model(refine=0).refine_options is None  # an explicit 0 wins
    assert img2dmp.load_model(refine=0).refine_steps == 0 and m.refine_steps == default.refine
    assert img2dmp.load_model(refine=5).refine_options.steps == 5
    with pytest.raises(ValueError, match="refine must be a whole number"):
        img2dmp.load_model(refine=-1)
    assert m.n_hypotheses == 4 and m.image_size == (28, 28)


def test_a_run_directory_keeps_no_refinement(train_tiny_runs, tmp_path):
    run = train_tiny_runs(tmp_path, lambda k: tmp_path / f"run{k}")[1]
    assert img2dmp.load_model(run).refine_options is None
    assert img2dmp.load_model(str(run)).shipped is None


def test_predict_without_a_model_writes_the_sample_digit(tmp_path, capsys):
    out = tmp_path / "pred"
    assert cli.main(["predict", str(SAMPLE), "--out", str(out), "--overlay"]) == 0
    captured = capsys.readouterr()
    assert (
        "model digits-real with --refine 30 (--refine-unfamiliar 60: images it finds "
        "unfamiliar), as its card recommends"
    ) in captured.err
    doc = json.loads((out / "digit_3_dmp.json").read_text())
    assert doc["refinement"] == {"steps": 30} and doc["flags"] == []
    assert doc["fit"]["path_on_ink"] > 0.95 and doc["fit"]["ink_written"] > 0.9, doc["fit"]
    assert (out / "digit_3_overlay_image.png").is_file()
    p, fit = doc["hypotheses"][0]["probability"], doc["fit"]  # the line says what it wrote
    assert (f"digit_3.png: tau = {doc['params']['tau']:.3f} s, top hypothesis of 4: p = "
            f"{p:.2f}; path on ink {fit['path_on_ink']:.2f}, ink written "
            f"{fit['ink_written']:.2f} -> {out / 'digit_3_dmp.json'}") in captured.out  # fmt: skip
    assert cli.main(["predict", str(SAMPLE), "--out", str(out), "--force", "--refine", "0"]) == 0
    assert "note" not in capsys.readouterr().err  # told otherwise: nothing to say
    assert json.loads((out / "digit_3_dmp.json").read_text())["refinement"] == {"steps": 0}


def test_predict_of_several_images_shows_a_bar_on_a_terminal_only(tmp_path, monkeypatch, capsys):
    from img2dmp import _progress

    photo = SAMPLE.with_name("digit_5_photo.jpg")
    argv = ["predict", str(SAMPLE), str(photo), "--out", str(tmp_path / "a"), "--refine", "0"]
    assert cli.main(argv) == 0
    assert "predict:" not in capsys.readouterr().err  # a log: nothing
    monkeypatch.setattr(_progress, "live", lambda: True)
    assert cli.main([*argv, "--force"]) == 0
    assert re.search(r"\rpredict: +0%.* 0/2 \[", capsys.readouterr().err)  # drawn, then cleared
    assert cli.main([*argv, "--force", "--no-progress"]) == 0
    assert "predict:" not in capsys.readouterr().err
    assert cli.main([*argv[:2], *argv[3:], "--force"]) == 0  # one image: no bar
    assert "predict:" not in capsys.readouterr().err
    from img2dmp.predict import Predictor

    def fails_on_the_photo(self, path, **kwargs):  # an error met inside the loop
        if str(path) == str(photo):
            raise ValueError(f"{path}: no ink found")
        return predict(self, path, **kwargs)

    predict = Predictor.predict
    monkeypatch.setattr(Predictor, "predict", fails_on_the_photo)
    assert cli.main([*argv, "--force"]) == 2
    err = capsys.readouterr().err
    assert re.search(r"\r +\rimg2dmp predict: error: .*no ink found", err), err  # bar cleared


def test_write_without_a_model_has_the_arm_write_the_sample(tmp_path, capsys):
    from img2dmp.robot import available

    if not available():
        pytest.skip("pybullet is not installed (the robot extra)")
    out = tmp_path / "robot"
    assert cli.main(["write", str(SAMPLE), "--out-dir", str(out), "--no-progress"]) == 0
    captured = capsys.readouterr()
    assert "model digits-real with --refine 30" in captured.err
    assert re.search(r"1: [\d.]+ mm, ink (9\d|100)\.\d %", captured.out), captured.out
    assert (out / "digit_3_paper.png").is_file() and (out / "digit_3_log.csv").is_file()


def test_write_serve_and_train_take_the_default_or_a_name():
    from img2dmp.commands import serve as serve_command
    from img2dmp.commands import write as write_command

    def parsed(module, argv):
        parser = argparse.ArgumentParser()
        module.add_arguments(parser)
        return parser.parse_args(argv)

    default = models.default_model()  # the shipped model itself: str() is its name
    name = default.name
    args = parsed(write_command, ["photo.png"])
    write_command._default_model(args)
    assert args.model == default and str(args.model) == name
    args = parsed(write_command, ["page.json", "--page"])  # a page document needs none
    write_command._default_model(args)
    assert args.model is None
    args = parsed(write_command, ["photo.jpg", "--page"])  # a photo of a page does
    write_command._default_model(args)
    assert args.model == default
    assert serve_command._models(parsed(serve_command, [])) == [default]
    assert serve_command._models(parsed(serve_command, ["--model", "a"])) == ["a"]
    expected = [("model", default.weights), ("model", default.folder / "model.json")]
    assert _args.model_inputs(name) == expected == _args.model_inputs(default)


def test_img2dmp_models_lists_each_with_its_figures_and_shows_a_card(capsys):
    assert cli.main(["models"]) == 0
    out = capsys.readouterr().out
    for m in models.shipped_models():
        assert f"{'*' if m.default else ' '} {m.name}  {m.size_bytes / 1e6:.2f} MB" in out
        assert f"Chamfer {m.figures['chamfer_px']:.4f} px" in out
        assert f"sha256 {m.sha256[:12]}... verified" in out
        for key, value in m.recommended.items():  # as the command line spells them
            assert f"--{key.replace('_', '-')} {value}" in out, (m.name, key)
    assert cli.main(["models", models.default_model().name]) == 0
    assert capsys.readouterr().out.startswith("# Model card: digits-real")


# --- the card's figures, on a sample of the test part ---------------------------------

#: Test digits evaluated: every fourth of the test part (211 of 841).
SAMPLE_EVERY = 4


def _sample_tolerance(values: np.ndarray, n_population: int) -> float:
    """Three standard errors of the mean of ``values``, a sample drawn from a population
    of ``n_population`` without replacement (finite-population correction): the card's
    mean over the whole test part lies within it unless the model or the measure changed."""
    n = len(values)
    correction = math.sqrt((n_population - n) / (n_population - 1))
    return 3.0 * float(np.std(values, ddof=1)) / math.sqrt(n) * correction


def _evaluate_the_cards_sample(m, data, tmp_path) -> dict:
    """``img2dmp evaluate`` of shipped model ``m`` on every ``SAMPLE_EVERY``-th sample of
    its card's test part ``data``, checked against the card's Chamfer distance, ink share
    and path error (:func:`_sample_tolerance`); the evaluation's result."""
    from img2dmp.data.store import save_dataset
    from img2dmp.evaluate import evaluate

    f = m.figures
    assert len(data) == f["n"]
    sample = data.subset(np.arange(0, len(data), SAMPLE_EVERY))
    path = save_dataset(tmp_path / "sample.safetensors", sample)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small tensors: one thread is twice as fast on 2 busy cores
    try:
        res = evaluate(m.name, path, split="test", n_figures=0, refine=f["refine"],
                       count_views=f.get("count_views"))  # fmt: skip
    finally:
        torch.set_num_threads(threads)
    for key, card in (("chamfer_px", f["chamfer_px"]), ("on_ink_shares", f["path_on_ink"]),
                      ("path_errors_px", f["path_error_px"])):  # fmt: skip
        values = np.asarray(res[key], dtype=np.float64)
        tolerance = _sample_tolerance(values, f["n"])
        assert abs(values.mean() - card) <= tolerance, (key, values.mean(), card, tolerance)
    return res


@pytest.mark.skipif(
    not (DATA / "mnist").is_dir() or not (DATA / "ijs-mnist-trajectories").is_dir(),
    reason=f"MNIST and the recorded pen paths are not at {DATA} (../shared/data)",
)
def test_the_default_model_reproduces_its_cards_figures_on_a_test_sample(tmp_path):
    from img2dmp.data.prepare import PrepareOptions, prepare_dataset

    m = models.default_model()
    # The test part as the card's data set holds it (never augmented: prepare's
    # augmentation and paper copies touch training digits only).
    options = PrepareOptions(scaling="none", duration_s=1.0)
    with warnings.catch_warnings():  # the recordings whose time steps prepare repairs
        warnings.simplefilter("ignore", UserWarning)
        data = prepare_dataset(options, data_dir=DATA, progress=False).select_split("test")
    _evaluate_the_cards_sample(m, data, tmp_path)


@pytest.mark.skipif(
    not (DATA / "omniglot").is_dir(), reason=f"Omniglot is not at {DATA} (../shared/data)"
)
def test_the_stroke_model_reproduces_its_cards_figures_on_a_sample_of_the_test_drawers(tmp_path):
    from img2dmp.data.importer import ImportOptions, import_dataset

    m = models.find_shipped("omniglot-strokes")
    f = m.figures
    whole = import_dataset(DATA / "omniglot", ImportOptions(n_times=300), progress=False)
    data = whole.select_split("test")
    res = _evaluate_the_cards_sample(m, data, tmp_path)
    right = np.equal(res["strokes"]["predicted_counts"], res["strokes"]["true_counts"])
    tolerance = _sample_tolerance(right.astype(np.float64), f["n"])
    assert abs(right.mean() - f["count_right"]) <= tolerance, (right.mean(), f["count_right"])
    # its ceiling: the test drawers' share whose count is their class's most common one
    # among the training drawers, from the stroke files alone (no model)
    from img2dmp.evaluate import count_ceiling

    ceiling = count_ceiling(whole, whole.select_split("test"))["count_mode_right"]
    assert f["count_mode_right"] == pytest.approx(ceiling, abs=1e-5)


def test_the_stroke_model_reads_the_sample_f_as_its_three_strokes(tmp_path, capsys):
    """examples/plot_strokes.py: the shipped stroke model reads the drawn "F" of
    examples/samples as three strokes, the bar down first, and draws them."""
    import importlib.util

    script = ROOT / "examples" / "plot_strokes.py"
    spec = importlib.util.spec_from_file_location("plot_strokes", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(["--out", str(tmp_path / "strokes.png")]) == 0
    assert capsys.readouterr().out.strip().endswith(": 3 strokes")
    assert (tmp_path / "strokes.png").stat().st_size > 10_000
    import matplotlib.pyplot as plt

    assert not plt.get_fignums()  # the figure is closed
    pred = img2dmp.load_model("omniglot-strokes").predict(module.SAMPLE)
    first = pred.path_image[0][pred.stroke_rows(0), :2]
    assert first[-1, 1] - first[0, 1] > 60  # the bar, top to bottom (image rows)
