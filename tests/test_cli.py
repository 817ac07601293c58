"""The command line: entry points, shared options, configuration, errors and exit codes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from img2dmp import cli
from img2dmp.commands import _args, evaluate, generate, prepare, train
from img2dmp.errors import TrainingDiverged

SRC = str(Path(__file__).resolve().parents[1] / "src")


def _python(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=SRC)
    return subprocess.run(
        [sys.executable, *args], env=env, capture_output=True, text=True, timeout=120
    )


def _one_error_line(err: str, command: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"img2dmp {command}: error: "), err
    return lines[0]


# --- entry points and import weight ----------------------------------------------------


def test_python_m_img2dmp_shows_help():
    out = _python("-m", "img2dmp", "--help")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("usage: img2dmp") and "evaluate" in out.stdout
    out = _python("-m", "img2dmp", "evaluate", "--help")
    assert out.returncode == 0 and "--model" in out.stdout and "--digits" in out.stdout


def test_building_the_parser_imports_neither_torch_nor_numpy():
    code = (
        "import sys, img2dmp.cli; img2dmp.cli.build_parser(); "
        "heavy = [m for m in ('torch', 'numpy', 'matplotlib', 'scipy') if m in sys.modules]; "
        "assert not heavy, heavy"
    )
    out = _python("-c", code)
    assert out.returncode == 0, out.stderr


def test_help_and_usage_errors_return_their_exit_status(capsys):
    assert cli.main(["--help"]) == 0
    assert cli.main(["train", "--help"]) == 0
    assert cli.main(["no-such-command"]) == 2
    assert cli.main(["generate"]) == 2  # --out missing
    err = capsys.readouterr().err
    assert "--out" in err.splitlines()[-1]


# --- --digits ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "digits"),
    [
        ("2", (2,)),
        ("2,3", (2, 3)),
        ("1 4 7", (1, 4, 7)),
        ("0-9", tuple(range(10))),
        ("0-3,8", (0, 1, 2, 3, 8)),
        (" 3 , 5 ", (3, 5)),
        (["2", "3"], (2, 3)),
        ("2,2,1-3", (2, 1, 3)),
    ],
)
def test_digits_are_read_one_way(text, digits):
    assert _args.parse_digits(text) == digits


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("12", "0-9, got 12"),
        ("3-12", "0-9, got 12 in '3-12'"),
        ("2,x", "'x' is not a digit"),
        ("-1", "'-1' is not a digit"),
        ("5-2", "'5-2' runs backwards"),
        ("", "at least one digit"),
        (" , ", "at least one digit"),
    ],
)
def test_bad_digits_name_the_bad_part(text, message):
    with pytest.raises(ValueError, match=message):
        _args.parse_digits(text)


@pytest.mark.parametrize("command", ["generate", "preview", "prepare", "train", "evaluate"])
def test_every_command_takes_digits_the_same_way(command):
    parser = cli.build_parser()
    required = {"generate": ["--out", "x"], "preview": ["--out", "x"]}.get(command, [])
    for given, expected in (
        (["2,3"], (2, 3)),
        (["2", "3"], (2, 3)),
        (["0-3,8"], (0, 1, 2, 3, 8)),
    ):
        args = parser.parse_args([command, *required, "--digits", *given])
        assert args.digits == expected
    assert parser.parse_args([command, *required]).digits is None


def test_bad_digits_on_the_command_line_give_one_line(tmp_path, capsys):
    assert cli.main(["generate", "--out", str(tmp_path / "x"), "--digits", "2,x"]) == 2
    line = _one_error_line(capsys.readouterr().err, "generate")
    assert "argument --digits: 'x' is not a digit" in line


# --- numbers checked while reading the command line ------------------------------------


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["generate", "--out", "x", "--per-digit", "0"], "--per-digit"),
        (["generate", "--out", "x", "--image-size", "4"], "--image-size"),
        (["generate", "--out", "x", "--splits", "0.5,0.5"], "--splits"),
        (["train", "--epochs", "0"], "--epochs"),
        (["train", "--epochs", "-3"], "--epochs"),
        (["train", "--epochs", "two"], "--epochs"),
        (["predict", "--model", "m", "a.png", "--points", "1"], "--points"),
        (["preview", "--out", "x", "--per-digit", "0"], "--per-digit"),
        (["prepare", "--augment", "-1"], "--augment"),
        (["prepare", "--pen-speed", "0"], "--pen-speed"),
        (["evaluate", "m", "d", "--figures", "-1"], "--figures"),
        (["demo", "--epochs", "0"], "--epochs"),
    ],
)
def test_out_of_range_numbers_give_one_line(argv, option, capsys):
    assert cli.main(argv) == 2
    line = _one_error_line(capsys.readouterr().err, argv[0])
    assert f"argument {option}" in line


# --- evaluate: positional MODEL DATA or --model/--data ---------------------------------


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "d.st"],
        ["--model", "run", "--data", "d.st"],
        ["run", "--data", "d.st"],
        ["--data", "d.st", "--model", "run"],
        ["run", "d.st", "--model", "run/", "--data", "d.st"],  # both forms, agreeing
    ],
)
def test_evaluate_takes_model_and_data_either_way(argv):
    args = cli.build_parser().parse_args(["evaluate", *argv])
    model, data = evaluate.model_and_data(args)
    assert model.rstrip("/") == "run" and data == "d.st"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "no model given"),
        (["run"], "no data given"),
        (["--model", "run"], "no data given"),
        (["run", "d.st", "--model", "other"], "MODEL is given twice and differently"),
        (["run", "d.st", "--data", "e.st"], "DATA is given twice and differently"),
    ],
)
def test_evaluate_refuses_missing_or_contradicting_model_and_data(argv, message, capsys):
    args = cli.build_parser().parse_args(["evaluate", *argv])
    with pytest.raises(ValueError, match=message):
        evaluate.model_and_data(args)
    assert cli.main(["evaluate", *argv]) == 2
    assert message in _one_error_line(capsys.readouterr().err, "evaluate")


def test_evaluate_without_data_takes_the_data_set_the_run_recorded(monkeypatch, tmp_path):
    """``evaluate RUN`` refused without DATA although the run's checkpoint records the
    file it trained on: that file is taken when it is still there, unchanged."""
    import hashlib

    import img2dmp.checkpoint as checkpoint

    data = tmp_path / "d.safetensors"
    data.write_bytes(b"the data")
    record = {"path": str(data), "sha256": hashlib.sha256(b"the data").hexdigest()}
    monkeypatch.setattr(checkpoint, "read_checkpoint_meta", lambda model: {"dataset": record})
    args = cli.build_parser().parse_args(["evaluate", "runs/r"])
    assert evaluate.model_and_data(args) == ("runs/r", str(data))
    data.write_bytes(b"other data")
    with pytest.raises(ValueError, match=r"no data given, and the data set runs/r trained on, "
                                         r".*d\.safetensors, has changed since"):  # fmt: skip
        evaluate.model_and_data(args)
    data.unlink()
    with pytest.raises(ValueError, match=r"d\.safetensors, is not there"):
        evaluate.model_and_data(args)
    record.update(path=None)
    with pytest.raises(ValueError, match=r"runs/r records no data-set file \(it trained on gen"):
        evaluate.model_and_data(args)


def test_evaluate_passes_the_digits_to_the_library(monkeypatch, tmp_path, capsys):
    import img2dmp.evaluate as library

    calls = []

    def fake_evaluate(model, data, **kwargs):
        calls.append((model, data, kwargs))
        return {}

    monkeypatch.setattr(library, "evaluate", fake_evaluate)
    monkeypatch.setattr(library, "format_table", lambda res, title: title)
    out = str(tmp_path / "e")
    for argv in (
        ["--model", "runs/r", "--data", "d.st", "--digits", "2,3"],
        ["runs/r", "d.st", "--digits", "2", "3"],
    ):
        assert cli.main(["evaluate", *argv, "--out", out, "--split", "test"]) == 0
    assert [c[:2] for c in calls] == [("runs/r", "d.st")] * 2
    for _, _, kwargs in calls:
        assert kwargs == {
            "split": "test",
            "out_dir": out,
            "n_figures": 16,
            "digits": [2, 3],
            "classes": None,
            "refine": 0,
            "refine_unfamiliar": None,
            "count_views": None,
            "device": "cpu",
            "progress": True,
        }


# --- generate: --config through img2dmp.config, --set ---------------------------------


def test_generate_reads_its_config_file_and_overrides(tmp_path, capsys):
    from img2dmp.data.store import load_dataset

    cfg = tmp_path / "synth.yaml"
    cfg.write_text("ridge: 1e-6\nnoise_amount: 0.02\ndigits: [5]\naffine:\n  scale: [0.9, 1.0]\n")
    out = tmp_path / "d.safetensors"
    argv = ["generate", "--out", str(out), "--config", str(cfg), "--digits", "2"]
    argv += ["--per-digit", "2", "--workers", "1", "--no-progress"]
    argv += ["--set", "noise_amount=0.1", "--set", "affine.rotation_deg=[-5, 5]"]
    assert cli.main(argv) == 0, capsys.readouterr().err
    data = load_dataset(out)
    assert set(data.labels.tolist()) == {2}  # --digits overrides the file
    config = data.meta["source"]["config"]
    assert config["ridge"] == 1e-6 and isinstance(config["ridge"], float)
    assert config["noise_amount"] == 0.1  # --set overrides the file
    assert config["affine"]["scale"] == [0.9, 1.0]
    assert config["affine"]["rotation_deg"] == [-5.0, 5.0]


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("pen_size=3", "unknown field(s) pen_size; known: "),
        ("affine.foo=1", "affine.foo"),
        ("ridge=abc", "ridge must be a number, got 'abc'"),
        ("noise_amount=2", "noise_amount must lie in [0, 1]"),
    ],
)
def test_generate_refuses_bad_settings_in_one_line(tmp_path, setting, message, capsys):
    out = tmp_path / "x.safetensors"
    assert cli.main(["generate", "--out", str(out), "--set", setting]) == 2
    assert message in _one_error_line(capsys.readouterr().err, "generate")
    assert not out.exists()


def test_generate_config_file_problems_are_one_line(tmp_path, capsys):
    out = str(tmp_path / "x.safetensors")
    assert cli.main(["generate", "--out", out, "--config", str(tmp_path / "none.yaml")]) == 2
    assert "does not exist" in _one_error_line(capsys.readouterr().err, "generate")
    (tmp_path / "bad.yaml").write_text("noise_amount: [1, 2\n")
    assert cli.main(["generate", "--out", out, "--config", str(tmp_path / "bad.yaml")]) == 2
    assert "bad.yaml" in _one_error_line(capsys.readouterr().err, "generate")


def test_synthetic_config_from_dict_keeps_its_forms():
    from img2dmp.data.synthetic import SyntheticConfig

    assert SyntheticConfig.from_dict({"digits": 3, "image_size": 32}) == SyntheticConfig(
        digits=(3,), image_size=(32, 32)
    )
    with pytest.raises(ValueError, match="noise_amount must be a number"):
        SyntheticConfig.from_dict({"noise_amount": "lots"})


# --- prepare: --config / --set / flags -> PrepareOptions -------------------------------


def _prepare_options(*argv: str):
    return prepare.prepare_options(cli.build_parser().parse_args(["prepare", *argv]))


def test_prepare_without_settings_gives_the_library_defaults():
    from img2dmp.data.prepare import PrepareOptions

    assert _prepare_options() == PrepareOptions()


def test_prepare_flags_override_the_file_only_when_given(tmp_path):
    cfg = tmp_path / "prep.yaml"
    cfg.write_text(
        "n_times: 50\nseed: 7\naugment: 2\nimage_size: 40\nridge: 1e-8\n"
        "affine:\n  scale: [0.95, 1.05]\nspeed_profile:\n  pen_up_s: 0.3\n"
    )
    opt = _prepare_options(
        "--config",
        str(cfg),
        "--digits",
        "3,5",
        "--pen-speed",
        "40",
        "--augment",
        "1",
        "--set",
        "augment=4",
        "--set",
        "affine.rotation_deg=[-5, 5]",
    )
    assert opt.digits == (3, 5) and opt.n_times == 50 and opt.seed == 7  # file kept
    assert opt.image_size == 40 and opt.ridge == 1e-8
    assert opt.augment == 4  # --set after the flag
    assert opt.affine.scale == (0.95, 1.05) and opt.affine.rotation_deg == (-5.0, 5.0)
    sp = opt.speed_profile
    assert (sp.pen_speed_px_s, sp.pen_up_s, sp.min_stroke_s) == (40.0, 0.3, 0.1)
    assert _prepare_options("--config", str(cfg), "--seed", "1").seed == 1
    assert _prepare_options("--dims", "3").n_dims == 3


def test_prepare_refuses_unknown_or_mistyped_settings(tmp_path):
    with pytest.raises(ValueError, match="speed_profile.pen_speed"):
        _prepare_options("--set", "speed_profile.pen_speed=3")
    with pytest.raises(ValueError, match="n_times must be .*2.5"):
        _prepare_options("--set", "n_times=2.5")
    (tmp_path / "p.toml").write_text('sources = "recorded"\n')
    with pytest.raises(ValueError, match="sources"):
        _prepare_options("--config", str(tmp_path / "p.toml"))


def test_prepare_keeps_data_as_the_root_directory():
    args = cli.build_parser().parse_args(["prepare", "--data", "/data/root", "--out", "x"])
    assert args.data == "/data/root" and args.out == "x"
    assert cli.build_parser().parse_args(["prepare"]).data == prepare.DEFAULT_DATA_DIR


def test_literal_defaults_match_the_library():
    from img2dmp import pipeline
    from img2dmp.commands import demo
    from img2dmp.data.prepare import PrepareOptions

    opt = PrepareOptions()
    for key, value in prepare.DEFAULTS.items():
        obj = opt
        for part in key.split("."):
            obj = getattr(obj, part)
        assert obj == value, key
    assert set(prepare.FLAG_FIELDS.values()) <= {
        *PrepareOptions.__dataclass_fields__,
        "speed_profile.pen_speed_px_s",
        "speed_profile.pen_up_s",
    }
    assert demo.DEMO_SAMPLES_PER_DIGIT == pipeline.DEMO_SAMPLES_PER_DIGIT
    assert demo.DEMO_EPOCHS == pipeline.DEMO_EPOCHS


# --- train: repeated --set, shortcuts, --resume ----------------------------------------


def _train_args(*argv: str):
    return cli.build_parser().parse_args(["train", *argv])


def test_train_keeps_every_repeated_set():
    args = _train_args("--set", "optim.lr=0.01", "--set", "optim.batch_size=7", "threads=1")
    assert train.overrides(args) == ["optim.lr=0.01", "optim.batch_size=7", "threads=1"]
    from img2dmp.train import load_config

    cfg = load_config(None, train.overrides(args))
    assert (cfg.optim.lr, cfg.optim.batch_size, cfg.threads) == (0.01, 7, 1)


def test_train_shortcuts_become_overrides_before_set():
    args = _train_args(
        "--data",
        "data/2023.safetensors",
        "--cost",
        "parameter",
        "--digits",
        "2,3",
        "--seed",
        "4",
        "--init-from",
        "runs/pre",
        "--no-progress",
        "--set",
        "seed=5",
    )
    over = train.overrides(args)
    assert over[-1] == "seed=5"
    from img2dmp.train import load_config

    cfg = load_config(None, over)
    assert cfg.data.path == "data/2023.safetensors" and cfg.data.digits == [2, 3]
    assert (cfg.cost.name, cfg.seed, cfg.init_from, cfg.progress) == (
        "parameter",
        5,
        "runs/pre",
        False,
    )


@pytest.mark.parametrize(
    "extra",
    [
        ["--set", "optim.lr=0.1"],
        ["--config", "c.yaml"],
        # not --data: with --resume it names where the run's own data set is now
        # (tests/test_train_lifecycle.py)
        ["--cost", "parameter"],
        ["--seed", "0"],
        ["--digits", "2"],
        ["--init-from", "runs/pre"],
        ["--overwrite"],
    ],
)
def test_train_resume_refuses_configuration_options(tmp_path, extra, capsys):
    argv = ["train", "--run-dir", str(tmp_path / "run"), "--resume", *extra]
    assert cli.main(argv) == 2
    line = _one_error_line(capsys.readouterr().err, "train")
    assert "--resume" in line and extra[0] in line and "--epochs" in line


def test_train_resume_with_epochs_only_passes_the_check(tmp_path):
    args = _train_args("--run-dir", str(tmp_path), "--resume", "--epochs", "9", "--no-progress")
    train.check_resume(args)
    assert train.overrides(args) == ["progress=false"]


# --- errors: one line for anticipated failures, a traceback for bugs --------------------


@pytest.mark.parametrize(
    ("exc", "expected"),
    [
        (PermissionError(13, "Permission denied", "/x/out.safetensors"), "/x/out.safetensors"),
        (OSError(28, "No space left on device", "runs/a/metrics.csv"), "runs/a/metrics.csv"),
        (IsADirectoryError(21, "Is a directory", "out"), "out: Is a directory"),
        (FileExistsError("x exists; pass --force to overwrite it"), "pass --force"),
        (FileNotFoundError("no such image: a.png"), "no such image: a.png"),
        (ValueError("first line\n  second line"), "first line second line"),
        (TrainingDiverged("the training cost became NaN at epoch 3"), "NaN at epoch 3"),
    ],
)
def test_anticipated_failures_are_one_line_and_status_2(monkeypatch, capsys, exc, expected):
    def fail(args):
        raise exc

    monkeypatch.setattr(generate, "run", fail)
    assert cli.main(["generate", "--out", "x"]) == 2
    assert expected in _one_error_line(capsys.readouterr().err, "generate")


def test_a_real_os_error_is_one_line_naming_the_file(tmp_path, capsys):
    (tmp_path / "file").write_text("not a directory")
    out = tmp_path / "file" / "d.safetensors"
    argv = ["generate", "--out", str(out), "--per-digit", "1", "--digits", "2"]
    assert cli.main([*argv, "--workers", "1", "--no-progress"]) == 2
    line = _one_error_line(capsys.readouterr().err, "generate")
    assert str(tmp_path / "file") in line and "Traceback" not in line


def test_a_bug_keeps_its_traceback_and_asks_for_a_report(monkeypatch, capsys):
    def broken(args):
        return {}["missing"]

    monkeypatch.setattr(generate, "run", broken)
    assert cli.main(["generate", "--out", "x y"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "KeyError: 'missing'" in err
    last = err.strip().splitlines()[-1]
    assert "report" in last and "img2dmp generate --out 'x y'" in last


def test_interrupt_is_status_130(monkeypatch, capsys):
    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(generate, "run", interrupted)
    assert cli.main(["generate", "--out", "x"]) == 130
    assert capsys.readouterr().err.strip() == "img2dmp generate: interrupted"


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("optim.epochs=3", "optim.epochs cannot be changed in the demo; use --epochs"),
        ("seed=3", "use --seed"),
        ("optim.lrr=0.1", "optim.lrr"),
    ],
)
def test_demo_checks_its_settings_before_starting(tmp_path, setting, message, capsys):
    out = tmp_path / "demo"
    assert cli.main(["demo", "--out", str(out), "--set", setting]) == 2
    assert message in _one_error_line(capsys.readouterr().err, "demo")
    assert not out.exists()


@pytest.mark.parametrize("command", ["predict", "write"])
def test_the_one_image_commands_set_one_blas_thread_before_numpy_loads(command, tmp_path):
    """predict and write compute on one thread (_args.one_thread); OpenBLAS under NumPy
    takes that only from its environment before NumPy is imported, which predict's first
    import did (two BLAS threads: 60 % more CPU time for one image, and on a busy machine
    the products ten times slower)."""
    sample = Path(__file__).resolve().parents[1] / "examples" / "samples" / "digit_3.png"
    argv = [command, str(sample), "--refine", "0", "--no-progress"]
    argv += (
        ["--out", str(tmp_path / "p")]
        if command == "predict"
        else ["--out-dir", str(tmp_path / "w")]
    )
    script = (
        "import os, sys\n"
        "from img2dmp import cli\n"
        "from img2dmp.commands import _args\n"
        "calls = []\n"
        "real = _args.one_thread\n"
        "def spy():\n"
        "    calls.append('numpy' in sys.modules)\n"
        "    real()\n"
        "_args.one_thread = spy\n"
        f"code = cli.main({argv!r})\n"
        "print(code, calls[:1], os.environ.get('OPENBLAS_NUM_THREADS'))\n"
    )
    env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          env=env, timeout=300)  # fmt: skip
    if command == "write" and "pybullet" in done.stderr and "install" in done.stderr:
        pytest.skip("pybullet is not installed")
    assert done.stdout.split()[-3:] == ["0", "[False]", "1"], done.stdout + done.stderr


def test_a_glyph_the_figures_font_lacks_is_said_once_in_one_line(tmp_path, capsys):
    """matplotlib warns twice per label in a script its font lacks (with source lines);
    a command says it once, at its end; other warnings pass as they are."""
    import warnings

    from img2dmp._files import new_figure, save_figure
    from img2dmp.cli import _missing_glyphs_said

    with warnings.catch_warnings(record=True) as passed:
        warnings.simplefilter("always")
        with _missing_glyphs_said("img2dmp preview"):
            fig = new_figure(figsize=(2, 1))
            fig.suptitle("\u4e2d and \u05d0")
            fig.tight_layout()
            save_figure(fig, tmp_path / "f.png")
            warnings.warn("something else", UserWarning, stacklevel=1)
    assert [str(w.message) for w in passed] == ["something else"]
    err = capsys.readouterr().err
    notes = [line for line in err.splitlines() if "note:" in line]
    assert notes == [
        "img2dmp preview: note: the figures' font (DejaVu Sans) has no glyph for \u4e2d: those "
        "characters show as boxes"
    ]


def test_class_names_on_the_command_line_are_read_in_unicode_nfc():
    """import stores class names in NFC; --classes of train, evaluate, preview finds them
    however the accent was typed."""
    decomposed, composed = "cafe\u0301", "caf\u00e9"
    assert _args.parse_classes(f"{decomposed}, L") == [composed, "L"]
