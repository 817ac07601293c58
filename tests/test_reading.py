"""Reading settings that travel with a run (``reading`` in the training configuration):
``predict``, ``write``, ``evaluate``, ``serve`` and ``load_model`` take them for a run
directory where their own flags do not say, as they take a shipped model's card's."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import shutil

import pytest

from img2dmp import cli
from img2dmp.config import ConfigError
from img2dmp.familiar import RUN_FILE
from img2dmp.models import Reading, checkpoint_reading, find_shipped
from img2dmp.predict import reading_for
from img2dmp.training.config import load_config

#: What the run of :func:`reading_run` recommends (small: the tests refine fast).
SETTINGS = {"refine": 2, "refine_unfamiliar": 5, "count_views": 2}


@pytest.mark.parametrize(("recipe", "shipped"), [("real", "digits-real"),
                                                 ("omniglot", "omniglot-strokes")])  # fmt: skip
def test_a_recipe_recommends_what_its_shipped_models_card_does(recipe, shipped):
    assert load_config(recipe).reading.recommended() == find_shipped(shipped).recommended


def test_other_recipes_recommend_nothing():
    assert load_config("paper").reading.recommended() == {"refine": 0}
    assert load_config("mnist-conv").reading.recommended() == {"refine": 0}


@pytest.mark.parametrize(
    ("recipe", "setting", "said"),
    [
        ("omniglot", "reading.refine=-1", "reading.refine must be a whole number from 0"),
        ("omniglot", "reading.refine=null", "reading.refine must be a number"),
        ("omniglot", "reading.refine_unfamiliar=20000", "reading.refine_unfamiliar must be"),
        ("omniglot", "reading.count_views=0", "reading.count_views must be a whole number"),
        ("omniglot", "reading.count_views=two", "reading.count_views must be"),
        ("real", "reading.count_views=1", "reading.count_views (1) is read by a stroke model"),
        ("real", "reading.steps=3", "unknown field(s) reading.steps"),
    ],
)
def test_bad_reading_settings_are_refused_by_name(recipe, setting, said):
    with pytest.raises(ConfigError) as e:
        load_config(recipe, [setting])
    assert said in str(e.value)


@pytest.fixture(scope="module")
def reading_run(small_omniglot, tmp_path_factory):
    """A tiny stroke run (2 epochs) whose configuration recommends :data:`SETTINGS`, and
    what ``img2dmp train`` printed."""
    run = tmp_path_factory.mktemp("reading") / "run"
    args = ["train", "--config", "omniglot", "--data", str(small_omniglot), "--run-dir",
            str(run), "--epochs", "2", "--no-progress", "--set", "optim.batch_size=16"]  # fmt: skip
    for key, value in SETTINGS.items():
        args += ["--set", f"reading.{key}={value}"]
    log = run.parent / "train.txt"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert cli.main(args) == 0
    log.write_text(out.getvalue())
    return run


def test_train_says_how_its_run_will_be_read(reading_run):
    printed = (reading_run.parent / "train.txt").read_text()
    assert "read it with --refine 2 --refine-unfamiliar 5 --count-views 2" in printed
    assert (
        "reading:\n  refine: 2\n  refine_unfamiliar: 5\n  count_views: 2\n"
        in (reading_run / "config.yaml").read_text()
    )


def test_a_run_recommends_its_configurations_reading(reading_run):
    from img2dmp.predict import Predictor, load_model

    reading = reading_for(reading_run)
    assert (reading.refine, reading.refine_unfamiliar, reading.count_views) == (2, 5, 2)
    assert "training configuration" in reading.by
    loaded = Predictor.load(reading_run)  # the views are taken, no refinement set
    assert loaded.reading == reading and loaded.count_views == 2
    assert loaded.refine_options is None
    ready = load_model(reading_run)
    assert ready.refine_options.steps == 2 and ready.refine_unfamiliar == 5
    plain = load_model(reading_run, refine=0)
    assert plain.refine_options is None and plain.refine_unfamiliar is None
    assert load_model(reading_run, refine=7).refine_unfamiliar is None  # --refine alone


def test_predict_reads_a_run_as_it_recommends_unless_told(reading_run, omni_root, tmp_path,
                                                         capsys):  # fmt: skip
    image = omni_root / "images_test" / "Alpha" / "character02" / "0102_20.png"
    out = tmp_path / "out"
    assert cli.main(["predict", str(image), "--model", str(reading_run), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "with --refine 2 (--refine-unfamiliar 5: images it finds unfamiliar), as its " \
           "training configuration (reading) recommends" in err, err  # fmt: skip
    doc = json.loads((out / "0102_20_dmp.json").read_text())
    assert doc["refinement"]["steps"] in (2, 5) and doc["count"]["views"] == 2
    argv = ["predict", str(image), "--model", str(reading_run), "--out", str(out), "--force",
            "--refine", "0", "--count-views", "3"]  # fmt: skip
    assert cli.main(argv) == 0
    assert "note:" not in capsys.readouterr().err
    doc = json.loads((out / "0102_20_dmp.json").read_text())
    assert doc["refinement"]["steps"] == 0 and doc["count"]["views"] == 3


def test_evaluate_reads_a_run_as_it_recommends(reading_run, small_omniglot, tmp_path, capsys):
    out = tmp_path / "ev"
    argv = ["evaluate", "--model", str(reading_run), "--data", str(small_omniglot),
            "--figures", "0", "--out", str(out), "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    assert "as its training configuration (reading) recommends" in capsys.readouterr().err
    res = json.loads((out / "evaluation.json").read_text())
    assert res["refine_steps"] == 2 and res["refine_unfamiliar_steps"] == 5
    assert res["strokes"]["count_views"] == 2


def test_write_and_serve_read_a_run_as_it_recommends(reading_run, capsys):
    from img2dmp.commands import write as write_command
    from img2dmp.web.models import load_models

    parser = argparse.ArgumentParser()
    write_command.add_arguments(parser)
    predictor = write_command._predictor(parser.parse_args(["x.png", "--model", str(reading_run)]))
    assert predictor.refine_options.steps == 2 and predictor.refine_unfamiliar == 5
    assert predictor.count_views == 2
    assert "img2dmp write: note:" in capsys.readouterr().err
    (served,) = load_models([reading_run]).values()
    assert served.predictor.refine_options.steps == 2 and served.predictor.count_views == 2
    (told,) = load_models([reading_run], refine=0).values()
    assert told.predictor.refine_options is None


def test_a_run_without_its_familiarity_keeps_the_rest_of_its_reading(reading_run, tmp_path):
    from img2dmp.predict import load_model

    run = shutil.copytree(reading_run, tmp_path / "run")
    (run / RUN_FILE).unlink()
    reading = reading_for(run)
    assert (reading.refine, reading.refine_unfamiliar, reading.count_views) == (2, None, 2)
    predictor = load_model(run)  # no error for a setting it cannot honour
    assert predictor.refine_options.steps == 2 and predictor.refine_unfamiliar is None


def test_a_checkpoint_that_records_no_reading_recommends_nothing():
    from img2dmp.checkpoint import read_checkpoint_meta

    meta = read_checkpoint_meta("digits-real")  # trained before the section existed
    assert "reading" not in meta["train_config"]
    assert checkpoint_reading(meta) == Reading(by=checkpoint_reading(meta).by)
    assert checkpoint_reading({}).refine == 0
    with pytest.raises(ValueError, match=r"checkpoint X: reading setting 'refine' = -3"):
        checkpoint_reading({"train_config": {"reading": {"refine": -3}}}, "checkpoint X")
    with pytest.raises(ValueError, match="not a mapping"):
        checkpoint_reading({"train_config": {"reading": [1]}})


def test_a_checkpoint_with_a_bad_reading_is_refused_naming_the_file(reading_run, tmp_path):
    from img2dmp.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
    from img2dmp.predict import Predictor

    ckpt = load_checkpoint(reading_run)  # torch tensors, as save_checkpoint takes them
    meta = dict(ckpt.meta)
    meta["train_config"] = {**meta["train_config"], "reading": {"refine": "many"}}
    bad = tmp_path / "bad.safetensors"
    save_checkpoint(bad, ckpt.model_state, meta)  # its digests made anew: a whole file
    with pytest.raises(CheckpointError, match=r"bad\.safetensors: invalid record .*'refine'"):
        Predictor.load(bad)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("train_config", "x", "invalid record (train_config is 'x', not a mapping)"),
        ("ink_margin", "x", "invalid record (field 'ink_margin' must be a number, got 'x')"),
        ("ink_margin", None, "field 'ink_margin' must be a number, got None"),
        ("ink_margin", 5.0, "field 'ink_margin': margin must be in [0, 0.45], got 5.0"),
        ("stroke_width_px", -3.0, "field 'stroke_width_px': stroke_width_px must be a number"),
        ("dmp_config", "MISSING", "invalid record (field 'dmp_config' is missing)"),
    ],
)
def test_a_record_s_wrong_field_is_named_with_the_file(reading_run, tmp_path, field, value,
                                                        message):  # fmt: skip
    """Whole files (their digests made anew) whose record holds a wrong field: one
    CheckpointError naming the file and the field, at load, never a traceback later."""
    from img2dmp.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
    from img2dmp.predict import Predictor

    ckpt = load_checkpoint(reading_run)
    meta = {k: v for k, v in ckpt.meta.items() if k != field}
    if value != "MISSING":
        meta[field] = value
    bad = tmp_path / "bad.safetensors"
    save_checkpoint(bad, ckpt.model_state, meta)
    with pytest.raises(CheckpointError) as e:
        Predictor.load(bad)
    assert str(e.value).startswith(f"checkpoint {bad}: ") and message in str(e.value), e.value
