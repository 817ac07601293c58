"""Issue 17 at the command line: never a traceback, never a lost result.

Concurrent training runs on one run directory, two inputs of one output name, the
overwrite rule of every command that writes, repeated and bad ``--set``, a diverged
training, permissions, directories where files belong, a full disk, files that are no
images, decompression bombs, and the temporaries of killed writers. Every failure is exit
status 2 and one line ``img2dmp COMMAND: error: ...`` naming the file, field or value, and
where an earlier result exists the test shows it undamaged.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from img2dmp import _files, cli
from img2dmp._files import DirectoryBusy, clean_stale_temporaries, lock_directory
from img2dmp.checkpoint import read_checkpoint_meta
from img2dmp.commands import _args, demo, generate, prepare, train
from img2dmp.data.store import load_dataset, save_dataset
from img2dmp.data.synthetic import SyntheticConfig, generate_dataset
from img2dmp.errors import TrainingDiverged
from img2dmp.predict import Predictor
from img2dmp.train import load_config
from img2dmp.training import loop
from img2dmp.training.records import read_metrics_csv

SRC = str(Path(__file__).resolve().parents[1] / "src")
ENV = dict(os.environ, PYTHONPATH=SRC, OMP_NUM_THREADS="1")
#: A network and optimiser small enough that an epoch of 6 samples takes milliseconds.
TINY = [
    "threads=1",
    "optim.batch_size=4",
    "optim.schedule=none",
    "optim.patience=0",
    "model.encoder_layers=[16, 8]",
    "model.decoder_layers=[8]",
]
ROOT_SKIP = "running as root: the kernel lets root read and write any file, so a real "
ROOT_SKIP += "permission-denied file cannot be made (the simulated tests below still run)"


def _one_error_line(err: str, command: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"img2dmp {command}: error: "), err
    assert "Traceback" not in err
    return lines[0]


def _fails(capsys, argv: list[str]) -> str:
    """Run a command that must fail: exit status 2 and one error line, which is returned."""
    capsys.readouterr()
    assert cli.main(argv) == 2
    return _one_error_line(capsys.readouterr().err, argv[0])


def _train_argv(data, run_dir, *extra: str) -> list[str]:
    argv = ["train", "--data", str(data), "--run-dir", str(run_dir), "--no-progress"]
    for setting in TINY:  # one --set per setting: every one must be kept
        argv += ["--set", setting]
    return [*argv, *extra]


def _snapshot(path: Path) -> dict:
    """Every file under ``path`` (or the file itself) -> its bytes."""
    if path.is_file():
        return {path.name: path.read_bytes()}
    files = [p for p in sorted(path.rglob("*")) if p.is_file() and p.name != ".lock"]
    return {str(p.relative_to(path)): p.read_bytes() for p in files}


def _temporaries(directory: Path) -> list[Path]:
    return [p for p in directory.rglob(".*.tmp")]


def _python(code: str, *args: str, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", code, *args], env=ENV, text=True, **kwargs)


# --- shared inputs ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("bad_input")


@pytest.fixture(scope="module")
def data(work) -> Path:
    """Six synthetic digits (2 and 3), all in the training split."""
    path = work / "d.safetensors"
    config = SyntheticConfig(digits=(2, 3))
    save_dataset(path, generate_dataset(3, config, seed=0, progress=False))
    return path


@pytest.fixture(scope="module")
def model(work, data) -> Path:
    """A run directory with a model trained for two epochs."""
    run = work / "model"
    assert cli.main(_train_argv(data, run, "--epochs", "2")) == 0
    return run


@pytest.fixture(scope="module")
def images(work, data) -> tuple[Path, Path]:
    """Two different images of one name, A/x.png and C/x.png."""
    from PIL import Image

    d = load_dataset(data)
    out = []
    for i, folder in enumerate(("A", "C")):
        path = work / folder / "x.png"
        path.parent.mkdir()
        Image.fromarray((255 * (1 - d.images[i])).astype(np.uint8)).save(path)
        out.append(path)
    return out[0], out[1]


@pytest.fixture(scope="module")
def dmp_file(work, data) -> Path:
    """One DMP of the data set in the format of ``img2dmp write --dmp``."""
    from img2dmp.dmp import DMPParams
    from img2dmp.robot import save_dmp_json

    d = load_dataset(data)
    cfg = d.dmp_config
    params = DMPParams.from_vector(np.asarray(d.params[0], float), cfg.n_kernels, cfg.n_dims)
    path = work / "two.json"
    save_dmp_json(path, params, cfg, d.images.shape[1:])
    return path


def _needs_robot():
    from img2dmp.robot import available

    if not available():
        pytest.skip("pybullet is not installed: img2dmp write stops before checking its files")


# --- 1. two training runs on one run directory -----------------------------------------


def _wait_for_epochs(run: Path, proc: subprocess.Popen, n: int) -> None:
    metrics, deadline = run / "metrics.csv", time.monotonic() + 120
    while time.monotonic() < deadline:
        if metrics.is_file() and len(metrics.read_text().splitlines()) > n:
            return
        assert proc.poll() is None, proc.stderr.read()
        time.sleep(0.02)
    pytest.fail("the first run did not finish an epoch in 120 s")


def test_a_second_run_on_a_busy_run_dir_stops_at_once(data, tmp_path, capsys):
    run = tmp_path / "run"
    argv = _train_argv(data, run, "--epochs", "100000")
    first = subprocess.Popen(
        [sys.executable, "-m", "img2dmp.cli", *argv],
        env=ENV,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        _wait_for_epochs(run, first, 1)
        t0 = time.monotonic()
        # Not even --force takes a run directory from a run that is training in it.
        line = _fails(capsys, _train_argv(data, run, "--epochs", "2", "--seed", "7", "--force"))
        assert time.monotonic() - t0 < 5
        assert f"run directory {run} is in use" in line and f"process {first.pid}" in line
        assert first.poll() is None  # the first run goes on
    finally:
        first.kill()
        first.wait()
    # The first run's model is whole, its own, and the kill released the lock: it resumes.
    assert read_checkpoint_meta(run)["train_config"]["seed"] == 0
    Predictor.load(run)
    done = read_checkpoint_meta(run / "checkpoints" / "last.safetensors")["epoch"] + 1
    resume = ["train", "--run-dir", str(run), "--resume", "--no-progress"]
    assert cli.main([*resume, "--epochs", str(done + 1)]) == 0
    assert len(read_metrics_csv(run / "metrics.csv")) == done + 1


def test_two_runs_started_together_leave_one_whole_model(data, tmp_path):
    """Long enough (40 epochs) that the two overlap: before the lock both exited 0."""
    run = tmp_path / "run"
    procs = {
        seed: subprocess.Popen(
            [sys.executable, "-m", "img2dmp.cli"]
            + _train_argv(data, run, "--epochs", "40", "--seed", str(seed)),
            env=ENV,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        for seed in (1, 2)
    }
    errs = {seed: p.communicate(timeout=300)[1] for seed, p in procs.items()}
    codes = {seed: p.returncode for seed, p in procs.items()}
    assert sorted(codes.values()) == [0, 2], errs
    winner = next(s for s, c in codes.items() if c == 0)
    loser = next(s for s, c in codes.items() if c == 2)
    line = _one_error_line(errs[loser], "train")
    assert str(run) in line  # "in use" or, had the winner already finished, "holds a run"
    assert read_checkpoint_meta(run)["train_config"]["seed"] == winner
    assert [r["epoch"] for r in read_metrics_csv(run / "metrics.csv")] == list(range(40))


def test_the_python_api_refuses_a_busy_run_dir_too(data, tmp_path):
    from img2dmp.train import train as train_api

    run = tmp_path / "run"
    cfg = load_config(None, [f"data.path={data}", "progress=false", *TINY])
    with lock_directory(run, "run directory"):
        with pytest.raises(DirectoryBusy, match=f"run directory {run} is in use"):
            train_api(cfg, run, epochs=1)
    assert train_api(cfg, run, epochs=1).epochs_run == 1  # free again


def test_the_lock_refuses_a_second_holder_and_goes_with_the_first(tmp_path):
    d = tmp_path / "run"
    with lock_directory(d, "run directory") as lock:
        assert lock == d / ".lock" and lock.read_text().strip() == str(os.getpid())
        with pytest.raises(DirectoryBusy, match=f"process {os.getpid()}"):
            with lock_directory(d, "run directory"):
                pass
    with lock_directory(d):
        pass
    assert not d.exists()  # made for a block that left nothing in it: removed again


def test_a_killed_holder_releases_the_lock(tmp_path):
    d = tmp_path / "run"
    code = (
        "import sys, time\nfrom img2dmp._files import lock_directory\n"
        "with lock_directory(sys.argv[1]):\n    print('locked', flush=True)\n    time.sleep(120)"
    )
    holder = _python(code, str(d), stdout=subprocess.PIPE)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(DirectoryBusy, match=f"process {holder.pid}"):
            with lock_directory(d):
                pass
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    with lock_directory(d):
        pass


# --- 2. two inputs, one output name ------------------------------------------------------


@pytest.mark.parametrize("same", [False, True], ids=["A/x.png and C/x.png", "one image twice"])
def test_predict_refuses_two_inputs_of_one_output_name(model, images, tmp_path, capsys, same):
    a, c = images
    second = a if same else c
    out = tmp_path / "P"
    line = _fails(
        capsys, ["predict", "--model", str(model), str(a), str(second), "--out", str(out)]
    )
    assert str(a) in line
    if same:
        assert "given twice" in line
    else:
        assert str(c) in line and str(out / "x_dmp.json") in line
    assert not out.exists()  # refused before anything was written


def test_a_document_given_as_an_image_is_named_with_the_command_that_takes_it(
    model, dmp_file, tmp_path, capsys
):
    page = tmp_path / "note_page.json"
    page.write_text(json.dumps({"format": "img2dmp-page", "version": 1}))
    for command, path, said in (
        ("predict", page, f"; it is a page document: img2dmp write {page} --page writes it"),
        ("write", dmp_file, f"; it is a DMP file: img2dmp write --dmp {dmp_file} writes it"),
    ):
        line = _fails(capsys, [command, str(path), "--model", str(model)])
        assert line.endswith(said), line
    other = tmp_path / "other.json"
    other.write_text('{"format": "something-else"}')
    assert _fails(capsys, ["predict", str(other), "--model", str(model)]).endswith(
        "cannot identify image file " + repr(str(other))
    )


def test_a_warning_prints_the_familiarity_and_its_line_apart(capsys):
    from types import SimpleNamespace

    from img2dmp.commands._args import warn_flags

    fit = {"path_on_ink": 1.0, "ink_written": 1.0}
    pred = SimpleNamespace(
        flags=["unfamiliar"], familiarity=0.99654, familiar_line=0.99687, refine_steps=30, fit=fit
    )
    warn_flags("predict", "x.png", pred)
    assert "familiarity 0.9965, the model's line 0.9969;" in capsys.readouterr().err


def test_predict_help_says_how_names_are_made(capsys):
    assert cli.main(["predict", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "two images of one name from different folders" in text and "refused" in text


# --- 3. one overwrite rule ---------------------------------------------------------------

WRITERS = ["generate", "prepare", "preview", "predict", "evaluate", "train", "write", "demo"]


def _existing_output(command, tmp_path, data, model, images, dmp_file):
    """(argv, the existing output it would replace, the name the error must give)."""
    earlier = b"an earlier result"
    if command in ("generate", "prepare", "preview"):
        out = tmp_path / ("p.png" if command == "preview" else "d.safetensors")
        shutil.copy(data, out)
        argv = {
            "generate": ["generate", "--out", str(out), "--per-digit", "1", "--digits", "2"]
            + ["--workers", "1", "--no-progress"],
            "prepare": ["prepare", "--out", str(out), "--data", str(tmp_path / "no-data")],
            "preview": ["preview", "--out", str(out), "--data", str(data)],
        }[command]
        return argv, out, out
    if command == "train":
        run = tmp_path / "run"
        shutil.copytree(model, run)
        return _train_argv(data, run, "--epochs", "1"), run, run
    outputs = {
        "predict": ("P", "x_dmp.json", ["predict", "--model", str(model), str(images[0])]),
        "evaluate": ("E", "evaluation.json", ["evaluate", str(model), str(data)]),
        "write": ("W", "two_log.csv", ["write", "--dmp", str(dmp_file), "--no-progress"]),
        "demo": ("D", "summary.json", ["demo", "--samples-per-digit", "10", "--no-progress"]),
    }
    folder, name, argv = outputs[command]
    flag = "--out-dir" if command == "write" else "--out"
    (tmp_path / folder).mkdir()
    (tmp_path / folder / name).write_bytes(earlier)
    return [*argv, flag, str(tmp_path / folder)], tmp_path / folder, tmp_path / folder / name


@pytest.mark.parametrize("command", WRITERS)
def test_no_command_replaces_an_existing_output_without_force(
    command, tmp_path, data, model, images, dmp_file, capsys
):
    if command == "write":
        _needs_robot()
    argv, existing, named = _existing_output(command, tmp_path, data, model, images, dmp_file)
    before = _snapshot(existing)
    line = _fails(capsys, argv)
    assert "--force" in line and str(named) in line
    assert _snapshot(existing) == before  # byte-identical
    if command == "train":
        Predictor.load(existing)


@pytest.mark.parametrize("command", ["generate", "preview", "predict", "evaluate"])
def test_force_replaces_the_output(command, tmp_path, data, model, images, dmp_file, capsys):
    argv, existing, named = _existing_output(command, tmp_path, data, model, images, dmp_file)
    before = named.read_bytes()
    assert cli.main([*argv, "--force"]) == 0, capsys.readouterr().err
    assert named.read_bytes() != before
    assert not _temporaries(tmp_path)


def test_evaluate_never_replaces_its_worst_figure_without_force(tmp_path, data, model, capsys):
    """evaluate checked evaluation.json, .txt and examples.png, then also wrote worst.png:
    an earlier worst.png was replaced without --force, and the line "written:" left it out
    (and named examples.png with --figures 0, which writes none)."""
    out = tmp_path / "E"
    out.mkdir()
    (out / "worst.png").write_bytes(b"an earlier figure")
    argv = ["evaluate", str(model), str(data), "--out", str(out), "--no-progress"]
    line = _fails(capsys, argv)
    assert "--force" in line and str(out / "worst.png") in line
    assert (out / "worst.png").read_bytes() == b"an earlier figure"
    assert cli.main([*argv, "--force"]) == 0
    written = capsys.readouterr().out.strip().splitlines()[-1]
    assert written == f"written: {out / 'evaluation.json'}, evaluation.txt, examples.png, worst.png"
    assert cli.main([*argv[:-3], "--out", str(tmp_path / "F"), "--figures", "0"]) == 0
    written = capsys.readouterr().out.strip().splitlines()[-1]
    assert written == f"written: {tmp_path / 'F' / 'evaluation.json'}, evaluation.txt"
    assert sorted(p.name for p in (tmp_path / "F").iterdir()) == [
        "evaluation.json",
        "evaluation.txt",
    ]


@pytest.mark.parametrize("command", WRITERS)
def test_every_writing_command_documents_the_rule(command, capsys):
    assert cli.main([command, "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--force" in text and "never replaced" in text
    assert "never replaced without ``--force``" in " ".join(cli.__doc__.split())


# --- 4. --set and --epochs --------------------------------------------------------------


GEN_SETS = ["noise_amount=0.1", "ridge=1e-6", "affine.scale=[0.9, 1.0]"]


def _sets(settings: list[str]) -> list[str]:
    return [a for s in settings for a in ("--set", s)]


@pytest.mark.parametrize("command", ["generate", "prepare", "train", "demo"])
def test_every_repeated_set_is_kept(command):
    parse = cli.build_parser().parse_args
    out = ["--out", "x"] if command == "generate" else []
    sets = ["--set", "a=1", "--set", "b=2", "c=3", "--set", "d=4"]
    assert parse([command, *out, *sets]).set == ["a=1", "b=2", "c=3", "d=4"]
    if command == "generate":
        gen = generate.synthetic_config(parse(["generate", *out, *_sets(GEN_SETS)]))
        assert (gen.noise_amount, gen.ridge, gen.affine.scale) == (0.1, 1e-6, (0.9, 1.0))
    elif command == "prepare":
        prep = prepare.prepare_options(parse(["prepare", *_sets(["augment=4", "seed=3"])]))
        assert (prep.augment, prep.seed) == (4, 3)
    elif command == "train":
        args = parse(["train", *_sets(["optim.lr=0.01", "threads=1", "optim.batch_size=7"])])
        cfg = load_config(None, train.overrides(args))
        assert (cfg.optim.lr, cfg.threads, cfg.optim.batch_size) == (0.01, 1, 7)
    else:
        args = parse(["demo", *_sets(["optim.lr=0.01", "model.activation=tanh"])])
        assert demo.demo_overrides(args) == {"optim": {"lr": 0.01}, "model": {"activation": "tanh"}}


def test_a_trained_run_keeps_every_repeated_set(model):
    cfg = read_checkpoint_meta(model)["train_config"]
    assert cfg["threads"] == 1 and cfg["optim"]["batch_size"] == 4
    assert cfg["optim"]["schedule"] == "none" and cfg["model"]["encoder_layers"] == [16, 8]
    assert cfg["model"]["decoder_layers"] == [8]


@pytest.mark.parametrize(
    ("command", "value"), [("train", "0"), ("train", "-3"), ("demo", "0"), ("demo", "-3")]
)
def test_epochs_below_one_are_refused(command, value, data, tmp_path, capsys):
    out = tmp_path / "out"
    where = (
        ["--run-dir", str(out), "--data", str(data)] if command == "train" else ["--out", str(out)]
    )
    line = _fails(capsys, [command, *where, f"--epochs={value}"])
    assert "argument --epochs" in line and f"got {value}" in line
    assert not out.exists()


@pytest.mark.parametrize(
    ("setting", "named"),
    [
        ("optim.min_lr=-1", "optim.min_lr must be a finite number >= 0, got -1"),
        ("data.val_fraction=x", "data.val_fraction must be a number, got 'x'"),
        ("data.val_fraction=1.5", "data.val_fraction must be in [0, 1), got 1.5"),
        ("threads=-1", "threads must be >= 1 or null, got -1"),
        ("threads=1.5", "threads must be a number (int), got 1.5"),
        ("optim.epochs=0", "optim.epochs must be >= 1, got 0"),
        ("optim.batch_size=0", "optim.batch_size must be >= 1, got 0"),
        ("optim.patience=-2", "optim.patience must be >= 0, got -2"),
        ("optim.lr=-1", "optim.lr must be a finite number > 0, got -1"),
        ("optim.lr=.inf", "optim.lr must be a finite number, got inf"),
        ("seed=-1", "seed must be >= 0, got -1"),
        # 0 is a setting too (one DMP per drawing, the default): it said "from 1 to 32"
        ("strokes.slots=-1", "or 0 (one DMP per drawing), got -1"),
    ],
)
def test_a_bad_setting_is_one_line_naming_field_and_value(setting, named, data, tmp_path, capsys):
    run = tmp_path / "run"
    line = _fails(capsys, ["train", "--data", str(data), "--run-dir", str(run), "--set", setting])
    assert named in line
    assert not run.exists()  # refused before the run directory is made


# --- 5. a diverged training --------------------------------------------------------------


def test_a_configuration_that_does_not_parse_says_what_and_where(data, tmp_path, capsys):
    """YAML's errors were cut to their first line, "while parsing a flow sequence",
    which says neither what is wrong nor where; a folder given as --config was "a folder
    this command reads" that the run directory lay in."""
    bad = tmp_path / "mine.yaml"
    bad.write_text("optim:\n  lr: [1\n")
    run = tmp_path / "run"
    line = _fails(
        capsys, ["train", "--config", str(bad), "--data", str(data), "--run-dir", str(run)]
    )
    assert line.endswith(
        f"config file {bad} cannot be parsed: while parsing a flow sequence (line 2, column 7): "
        "expected ',' or ']', but got '<stream end>' (line 3, column 1)"
    )
    bad.write_text("optim:\n  lr: 0.1\n  epochs 3\n")
    line = _fails(
        capsys, ["train", "--config", str(bad), "--data", str(data), "--run-dir", str(run)]
    )
    assert "(line 3, column 3): could not find expected ':'" in line
    line = _fails(capsys, ["train", "--data", str(data), "--run-dir", str(run), "--set", "x.y=[1"])
    assert "override 'x.y': value cannot be parsed: while parsing a flow sequence" in line
    assert "(line 1, column 1)" in line
    line = _fails(
        capsys, ["train", "--config", str(tmp_path), "--data", str(data), "--run-dir", str(run)]
    )
    assert line.endswith(f"config file {tmp_path} is a directory")
    assert not run.exists()


def _diverge_at(monkeypatch, epoch: int) -> None:
    """Make the training cost NaN from ``epoch`` on (through the real loop's handling)."""
    real_epoch, real_step, now = loop.train_epoch, loop.train_step, {"epoch": 0}

    def train_epoch(run, e):
        now["epoch"] = e
        return real_epoch(run, e)

    def train_step(*args, **kwargs):
        if now["epoch"] >= epoch:
            raise TrainingDiverged("training cost is nan")
        return real_step(*args, **kwargs)

    monkeypatch.setattr(loop, "train_epoch", train_epoch)
    monkeypatch.setattr(loop, "train_step", train_step)


def test_divergence_before_any_epoch_claims_no_checkpoint(data, tmp_path, monkeypatch, capsys):
    _diverge_at(monkeypatch, 0)
    run = tmp_path / "run"
    line = _fails(capsys, _train_argv(data, run, "--epochs", "3"))
    assert "training diverged" in line and "at epoch 0" in line
    assert "no epoch finished, so no checkpoint was written" in line and "kept" not in line
    assert not (run / "checkpoints").exists()


def test_divergence_later_names_the_checkpoints_it_keeps(data, tmp_path, monkeypatch, capsys):
    _diverge_at(monkeypatch, 2)
    run = tmp_path / "run"
    line = _fails(capsys, _train_argv(data, run, "--epochs", "5"))
    best, last = run / "checkpoints" / "best.safetensors", run / "checkpoints" / "last.safetensors"
    assert "at epoch 2" in line and str(best) in line and str(last) in line
    assert "last good epoch (1)" in line and "are kept" in line
    assert read_checkpoint_meta(last)["epoch"] == 1
    Predictor.load(run)  # what the message promises is there and loads


def test_divergence_of_a_forced_run_leaves_the_earlier_model(
    data, model, tmp_path, monkeypatch, capsys
):
    run = tmp_path / "run"
    shutil.copytree(model, run)
    before = _snapshot(run / "checkpoints")
    _diverge_at(monkeypatch, 0)
    line = _fails(capsys, _train_argv(data, run, "--epochs", "3", "--force"))
    assert "no epoch of this run finished" in line and str(run / "checkpoints") in line
    assert _snapshot(run / "checkpoints") == before
    Predictor.load(run)


# --- 6. permissions, directories, full disks, foreign files -----------------------------


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason=ROOT_SKIP)
@pytest.mark.parametrize("what", ["data set", "image", "output directory", "run directory"])
def test_real_permission_denied_is_one_line(what, data, model, images, tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    if what == "data set":
        d = shutil.copy(data, locked / "d.safetensors")
        os.chmod(d, 0)
        argv, named = ["preview", "--out", str(tmp_path / "p.png"), "--data", str(d)], d
    elif what == "image":
        im = shutil.copy(images[0], locked / "x.png")
        os.chmod(im, 0)
        argv, named = ["predict", "--model", str(model), str(im)], im
    else:
        os.chmod(locked, 0o555)
        argv = ["generate", "--out", str(locked / "d.safetensors"), "--per-digit", "1"]
        argv += ["--digits", "2", "--workers", "1", "--no-progress"]
        if what == "run directory":
            argv = _train_argv(data, locked / "run", "--epochs", "1")
        named = locked
    line = _fails(capsys, argv)
    assert str(named) in line and "ermission denied" in line
    assert "No such file" not in line


@pytest.mark.parametrize("command", ["train", "preview", "predict", "evaluate"])
def test_an_unreadable_input_says_permission_denied(
    command, data, model, images, tmp_path, monkeypatch, capsys
):
    """Simulated (runs as root too): reading the file fails with EACCES, as it does for a
    file of mode 000; safetensors would call that "No such file or directory"."""
    victim = images[0] if command == "predict" else data
    real_open = open

    def refusing_open(path, *args, **kwargs):
        if Path(path) == Path(victim):
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(_files, "open", refusing_open, raising=False)
    argv = {
        "train": _train_argv(data, tmp_path / "run", "--epochs", "1"),
        "preview": ["preview", "--out", str(tmp_path / "p.png"), "--data", str(data)],
        "predict": ["predict", "--model", str(model), str(victim)],
        "evaluate": ["evaluate", str(model), str(data), "--out", str(tmp_path / "E")],
    }[command]
    line = _fails(capsys, argv)
    assert f"{victim} cannot be read: permission denied" in line
    assert "No such file" not in line and "does not exist" not in line


def test_an_unwritable_output_names_the_file_not_its_temporary(data, tmp_path, monkeypatch, capsys):
    def refusing_mkstemp(prefix, suffix, dir):
        raise PermissionError(errno.EACCES, "Permission denied", f"{dir}/{prefix}abcdefgh{suffix}")

    monkeypatch.setattr(_files.tempfile, "mkstemp", refusing_mkstemp)
    out = tmp_path / "p.png"
    line = _fails(capsys, ["preview", "--out", str(out), "--data", str(data)])
    assert line.endswith(f"{out}: Permission denied") and ".tmp" not in line


@pytest.mark.parametrize(
    "case",
    [
        "generate --out DIR",
        "preview --out DIR",
        "predict DIR",
        "predict output DIR",
        "train --data DIR",
        "train --config DIR",
        "evaluate DATA=DIR",
        "write --dmp DIR",
    ],
)
def test_a_directory_where_a_file_belongs(case, data, model, images, tmp_path, capsys):
    if case.startswith("write"):
        _needs_robot()
    d = tmp_path / "DIR"
    (d / "x_dmp.json").mkdir(parents=True)
    argv = {
        "generate --out DIR": ["generate", "--out", str(d), "--force", "--per-digit", "1"],
        "preview --out DIR": ["preview", "--out", str(d), "--force", "--data", str(data)],
        "predict DIR": ["predict", "--model", str(model), str(d)],
        "predict output DIR": ["predict", "--model", str(model), str(images[0])]
        + ["--out", str(d), "--force"],
        "train --data DIR": _train_argv(d, tmp_path / "run"),
        "train --config DIR": ["train", "--config", str(d), "--run-dir", str(tmp_path / "r")],
        "evaluate DATA=DIR": ["evaluate", str(model), str(d), "--out", str(tmp_path / "E")],
        "write --dmp DIR": ["write", "--dmp", str(d), "--out-dir", str(tmp_path / "W")],
    }[case]
    line = _fails(capsys, argv)
    named = d / "x_dmp.json" if case == "predict output DIR" else d
    assert f"{named} is a directory" in line


@pytest.mark.parametrize(
    "case", ["predict --out", "evaluate --out", "train --run-dir", "generate --out", "demo --out"]
)
def test_a_file_where_a_directory_belongs(case, data, model, images, tmp_path, capsys):
    f = tmp_path / "FILE"
    f.write_text("a file")
    argv = {
        "predict --out": ["predict", "--model", str(model), str(images[0]), "--out", str(f)],
        "evaluate --out": ["evaluate", str(model), str(data), "--out", str(f)],
        "train --run-dir": _train_argv(data, f),
        "generate --out": ["generate", "--out", str(f / "d.safetensors"), "--per-digit", "1"],
        "demo --out": ["demo", "--out", str(f / "demo")],
    }[case]
    line = _fails(capsys, argv)
    assert str(f) in line and "is a file" in line
    assert f.read_text() == "a file"


@pytest.mark.parametrize("case", ["predict --out", "evaluate --out", "train --run-dir"])
def test_a_new_folder_named_like_a_file_is_taken_for_a_file_name(
    case, data, model, images, tmp_path, capsys
):
    named = tmp_path / {"predict --out": "pred.json", "evaluate --out": "e.csv"}.get(
        case, "model.safetensors"
    )
    argv = {
        "predict --out": ["predict", "--model", str(model), str(images[0]), "--out", str(named)],
        "evaluate --out": ["evaluate", str(model), str(data), "--out", str(named)],
        "train --run-dir": _train_argv(data, named),
    }[case]
    line = _fails(capsys, argv)
    assert str(named) in line and f"not a {named.suffix} file" in line
    assert not named.exists()  # nothing made
    named.mkdir()  # a folder that is already there is taken whatever its name
    if case == "predict --out":
        assert cli.main(argv) == 0 and (named / f"{Path(images[0]).stem}_dmp.json").is_file()


def _disk_full(monkeypatch) -> None:
    def no_space(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(_files.os, "fsync", no_space)


@pytest.mark.parametrize("command", ["generate", "preview", "predict", "train"])
def test_a_full_disk_is_one_line_and_keeps_the_earlier_file(
    command, tmp_path, data, model, images, dmp_file, monkeypatch, capsys
):
    if command == "train":
        run = tmp_path / "run"
        shutil.copytree(model, run)
        argv, existing, named = _train_argv(data, run, "--epochs", "1", "--force"), run, run
    else:
        argv, existing, named = _existing_output(command, tmp_path, data, model, images, dmp_file)
        argv = [*argv, "--force"]
    before = _snapshot(existing)
    _disk_full(monkeypatch)
    line = _fails(capsys, argv)
    assert "No space left on device" in line and str(named) in line and ".tmp" not in line
    assert _snapshot(existing) == before
    assert not _temporaries(tmp_path)


def test_a_file_size_limit_is_one_line_and_keeps_the_earlier_file(data, tmp_path):
    out = tmp_path / "d.safetensors"
    shutil.copy(data, out)
    before = out.read_bytes()
    code = (
        "import resource, sys\nfrom img2dmp import cli\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000))\n"
        "sys.exit(cli.main(sys.argv[1:]))"
    )
    argv = ["generate", "--out", str(out), "--force", "--per-digit", "3", "--digits", "2,3"]
    proc = _python(code, *argv, "--workers", "1", "--no-progress", stderr=subprocess.PIPE)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err
    assert _one_error_line(err, "generate").endswith(f"{out}: File too large")
    assert out.read_bytes() == before and not _temporaries(tmp_path)


@pytest.mark.parametrize("command", ["predict", "write"])
def test_a_text_file_given_as_an_image(command, model, dmp_file, tmp_path, capsys):
    if command == "write":
        _needs_robot()
    text = tmp_path / "notes.png"
    text.write_text("not an image\n")
    argv = {
        "predict": ["predict", "--model", str(model), str(text)],
        "write": ["write", "--dmp", str(dmp_file), "--image", str(text)]
        + ["--out-dir", str(tmp_path / "W")],
    }[command]
    line = _fails(capsys, argv)
    assert f"image file {text} cannot be read as an image" in line


@pytest.mark.parametrize("command", ["predict", "write"])
def test_a_decompression_bomb_is_refused_by_name(
    command, model, images, dmp_file, tmp_path, monkeypatch, capsys
):
    if command == "write":
        _needs_robot()
    from PIL import Image

    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)  # a 40 x 40 image is then a bomb
    argv = {
        "predict": ["predict", "--model", str(model), str(images[0])],
        "write": ["write", "--dmp", str(dmp_file), "--image", str(images[0])]
        + ["--out-dir", str(tmp_path / "W")],
    }[command]
    line = _fails(capsys, argv)
    assert f"image file {images[0]} is refused as too large" in line
    assert "decompression bomb" in line


def test_an_image_pil_only_warns_about_is_checked_without_its_warning(tmp_path, monkeypatch):
    import warnings

    from PIL import Image

    from img2dmp.commands._args import check_images

    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)  # 12 x 12: warned of, not refused
    path = tmp_path / "big.png"
    Image.new("L", (12, 12), 255).save(path)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        check_images([path])
    assert not [w for w in seen if issubclass(w.category, Image.DecompressionBombWarning)]


def test_an_image_of_one_row_is_named_with_its_size(tmp_path):
    from PIL import Image

    from img2dmp.data.images import prepare_image_framed

    Image.new("L", (5, 1), 0).save(tmp_path / "tiny.png")
    with pytest.raises(ValueError, match=r"tiny.png is 5 x 1 pixels \(width x height\)"):
        prepare_image_framed(tmp_path / "tiny.png")


def test_a_decompression_bomb_anywhere_is_still_one_line(monkeypatch, capsys):
    from PIL import Image

    def bomb(args):
        raise Image.DecompressionBombError("Image size (10 pixels) exceeds limit of 2 pixels")

    monkeypatch.setattr(generate, "run", bomb)
    assert "exceeds limit" in _fails(capsys, ["generate", "--out", "x"])


def test_inputs_are_checked_before_the_model_is_loaded(tmp_path, capsys):
    missing = tmp_path / "nothing.png"
    line = _fails(capsys, ["predict", "--model", str(tmp_path / "no-model"), str(missing)])
    assert f"image {missing} does not exist" in line


# --- 7. temporaries of killed writers ----------------------------------------------------


def test_a_kill_during_the_final_write_leaves_a_temporary_the_next_write_removes(
    tmp_path, monkeypatch
):
    target = tmp_path / "d.safetensors"
    target.write_bytes(b"earlier")
    code = (
        "import os, signal, sys\nfrom img2dmp import _files\n"
        "_files.os.replace = lambda a, b: os.kill(os.getpid(), signal.SIGKILL)\n"
        "_files.atomic_write_bytes(sys.argv[1], b'x' * 100000)"
    )
    writer = _python(code, str(target))
    assert writer.wait(timeout=60) == -signal.SIGKILL
    (tmp,) = _temporaries(tmp_path)
    assert tmp.name.startswith(f".d.safetensors.{writer.pid}.") and tmp.stat().st_size == 100000
    assert target.read_bytes() == b"earlier"  # the kill never leaves a half-written target
    old = time.time() - 2 * _files.DEAD_WRITER_GRACE_S
    os.utime(tmp, (old, old))
    monkeypatch.setattr(_files, "_cleaned_dirs", set())  # as in a new process
    _files.atomic_write_bytes(target, b"newer")
    assert target.read_bytes() == b"newer" and not _temporaries(tmp_path)


def _dead_pid() -> int:
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


@pytest.mark.parametrize(
    ("name", "age_s", "removed"),
    [
        (".d.safetensors.{dead}.abcd_123.tmp", 120, True),  # writer gone
        (".d.safetensors.{dead}.abcd_123.tmp", 10, False),  # writer gone a moment ago
        (".d.safetensors.{me}.abcd_123.tmp", 120, False),  # writer at work
        (".d.safetensors.{me}.abcd_123.tmp", 7200, True),  # untouched for two hours
        (".d.safetensors.abcd_123.tmp", 7200, True),  # an earlier version's name
        (".gone.safetensors.abcd_123.tmp", 7200, False),  # ... of a file that is not there
        (".notes.tmp", 7200, False),  # not ours
        (".d.safetensors.tmp", 7200, False),
        ("d.safetensors.{dead}.abcd_123.tmp", 7200, False),  # not hidden
        (".d.safetensors.{dead}.toolongname.tmp", 7200, False),
    ],
)
def test_only_abandoned_temporaries_are_removed(name, age_s, removed, tmp_path):
    (tmp_path / "d.safetensors").write_bytes(b"data")
    f = tmp_path / name.format(dead=_dead_pid(), me=os.getpid())
    f.write_bytes(b"partial")
    now = time.time()
    os.utime(f, (now - age_s, now - age_s))
    assert clean_stale_temporaries(tmp_path, now=now) == ([f] if removed else [])
    assert f.exists() is not removed
    assert (tmp_path / "d.safetensors").read_bytes() == b"data"


def test_a_collision_is_refused_even_with_force():
    pairs = [(Path("P/x_dmp.json"), "A/x.png"), (Path("P/x_dmp.json"), "C/x.png")]
    with pytest.raises(ValueError, match="A/x.png and C/x.png would both be written"):
        _args.check_outputs(pairs, force=True)


def test_the_command_line_bounds_predict_points_like_the_library():
    from img2dmp import predict
    from img2dmp.commands import predict as predict_command

    assert predict_command.MAX_POINTS == predict.MAX_POINTS


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["predict", "--model", "m", "x.png", "--points", "100000000"], "--points"),
        (["preview", "--per-digit", "100000", "--out", "p.png"], "--per-digit x digits"),
    ],
)
def test_sizes_a_user_controls_are_refused_before_any_work(argv, named, tmp_path, capsys):
    import resource

    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    argv = [str(tmp_path / a) if a.endswith(".png") else a for a in argv]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and named in err[0], err
    # refused before anything large was allocated (the peak grew by less than 200 MB)
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000


def test_write_errors_are_one_line_even_when_pybullet_loads(tmp_path):
    # pybullet prints a build-time banner from C when it is first imported; the error
    # line of `write` must still be the only line on standard error (a fresh process).
    from img2dmp.robot import available

    if not available():
        pytest.skip("pybullet is not installed (the robot extra)")
    bad = tmp_path / "bad.json"
    bad.write_text('{"dmp_config": {}, "params": {"tau": true}, "image_size": [40, 40]}')
    cmd = [sys.executable, "-m", "img2dmp", "write", "--dmp", str(bad), "--out-dir", "o"]
    r = subprocess.run(cmd, capture_output=True, text=True, env=ENV, cwd=tmp_path, timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [r.stderr.strip()], r.stderr
    assert "bad.json" in r.stderr and r.stdout == ""


def test_generate_refuses_what_it_could_not_finish_before_drawing_a_sample(
    tmp_path, capsys, monkeypatch
):
    """A data set too large to hold, or a file whose folder is missing: one line, before
    any sample is drawn (100 million per digit once filled 15 GB of memory in 30 s)."""
    import img2dmp.data.synthetic as synthetic

    def never(*a, **k):
        raise AssertionError("a sample was drawn")

    monkeypatch.setattr(synthetic, "_generate_chunks", never)
    argv = ["generate", "--out", str(tmp_path / "g.safetensors"), "--no-progress"]
    assert cli.main([*argv, "--per-digit", "100000000"]) == 2
    err = capsys.readouterr().err.strip()
    assert "samples_per_digit (--per-digit) 100000000: 1,000,000,000 samples of 40 x 40" in err
    assert "at most" in err and len(err.splitlines()) == 1, err
    missing = tmp_path / "nodir" / "x.safetensors"
    assert cli.main(["generate", "--out", str(missing), "--per-digit", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(f"--out {missing}: directory '{missing.parent}' does not exist"), err
    with pytest.raises(ValueError, match="at most 41,9"):  # the library says the same
        generate_dataset(10**6, SyntheticConfig(), progress=False)


@pytest.mark.parametrize(("given", "what"), [("J/", "'J/', a directory"), ("", "an empty name")])
def test_export_joints_needs_a_file_name(tmp_path, dmp_file, capsys, monkeypatch, given, what):
    """``--export-joints DIR/`` wrote the hidden files DIR/.csv and DIR/.json, and an empty
    name was ignored: both are one line, before the arm moves."""
    pytest.importorskip("pybullet")
    monkeypatch.chdir(tmp_path)
    argv = ["write", "--dmp", str(dmp_file), "--out-dir", "W", "--export-joints", given]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(f"--export-joints needs a file name (FILE: FILE.csv and FILE.json are "
                        f"written), got {what}"), err  # fmt: skip
    assert not (tmp_path / "W").exists()


def test_a_nul_byte_in_a_file_name_is_named(capsys):
    """The system refuses such a name with a bare "embedded null byte"; the commands say
    which argument and what."""
    assert cli.main(["predict", "a\x00b.png"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "img2dmp predict: error: image 'a\\x00b.png': the name holds a NUL byte (\\x00)"
    with pytest.raises(ValueError, match="the name holds a NUL byte"):
        _files.check_readable("x\x00", "data set")


def test_evaluate_names_the_classes_a_model_never_trained_on(tmp_path, data, capsys):
    """A model trained on digit 2 alone, evaluated on 2 and 3: the 3s' figures were
    mixed into the table without a word."""
    run = tmp_path / "run"
    assert cli.main(_train_argv(data, run, "--epochs", "1", "--digits", "2")) == 0
    argv = ["evaluate", str(run), str(data), "--out", str(tmp_path / "E"), "--split", "all"]
    capsys.readouterr()
    assert cli.main([*argv, "--no-progress", "--figures", "0"]) == 0
    out = capsys.readouterr().out
    assert f"note: the model never trained on the class 3 of {data}" in out
    assert json.loads((tmp_path / "E" / "evaluation.json").read_text())["untrained_classes"] == [
        "3"
    ]
    assert cli.main([*argv, "--no-progress", "--figures", "0", "--digits", "2", "--force"]) == 0
    assert "never trained" not in capsys.readouterr().out


def test_a_misspelt_key_of_a_config_file_names_the_file(data, tmp_path, capsys):
    """An unknown key was named, but not the file it came from (a --set's as well)."""
    mine = tmp_path / "mine.yaml"
    mine.write_text("model:\n  encoder: conv\n  conv_chanels: [8]\n")
    run = tmp_path / "run"
    line = _fails(
        capsys, ["train", "--config", str(mine), "--data", str(data), "--run-dir", str(run)]
    )
    assert f"error: config file {mine}: unknown field(s) model.conv_chanels; known: " in line
    mine.write_text("model:\n  encoder: conv\n")
    argv = ["train", "--config", str(mine), "--data", str(data), "--run-dir", str(run)]
    line = _fails(capsys, [*argv, "--set", "model.conv_chanels=[8]"])
    assert "error: unknown field(s) model.conv_chanels" in line and "config file" not in line
