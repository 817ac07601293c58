"""A training's life cycle as a user lives it: the same run gives the same weights, it is
resumed from anywhere, and it is stopped by a signal in one line."""

from __future__ import annotations

import importlib
import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from img2dmp import cli
from img2dmp.data.store import save_dataset
from img2dmp.data.synthetic import generate_dataset
from img2dmp.train import TrainConfig, train

TINY = {"encoder_layers": [32, 20], "decoder_layers": [35]}
rollout_module = importlib.import_module("img2dmp.dmp.rollout")
SRC = str(Path(__file__).resolve().parents[1] / "src")


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("data") / "digits.safetensors"
    save_dataset(path, generate_dataset(12, seed=0, progress=False))
    return path


def config(data_path, epochs: int = 2) -> TrainConfig:
    """A tiny run whose batches (4 x 301 time stamps) are small calls of the rollout."""
    return TrainConfig.from_dict(
        {
            "model": dict(TINY),
            "data": {"path": str(data_path)},
            "optim": {"epochs": epochs, "batch_size": 4, "lr": 2e-3, "patience": 0},
            "cost": {"name": "trajectory"},
            "threads": 1,
            "progress": False,
        }
    )


def weights_digest(run: Path, name: str = "last") -> str:
    return json.loads((run / "checkpoints" / f"{name}.json").read_text())["weights_sha256"]


def test_a_run_s_weights_do_not_depend_on_what_its_process_ran_before(data, tmp_path, monkeypatch):
    """The rollout took torch's operations for small calls until its fused kernels had
    run once in the process: a run started in a fresh process and the same run started
    where they had run (or resumed, in a new process) took different paths and ended
    with different weights. A training now takes one path from its first step."""
    monkeypatch.setattr(rollout_module, "_fused_loaded", False)  # as a fresh process
    monkeypatch.setitem(rollout_module._unfused, "seconds", 0.0)
    train(config(data), tmp_path / "fresh")
    monkeypatch.setattr(rollout_module, "_fused_loaded", False)
    try:  # a process that has run the kernels before (when numba is there)
        rollout_module.rollout(*_one_dmp(), backend="fused")
    except ValueError:
        pass
    train(config(data), tmp_path / "warm")
    assert weights_digest(tmp_path / "fresh") == weights_digest(tmp_path / "warm")


def _one_dmp():
    import torch

    from img2dmp.dmp import DMPConfig, DMPParams

    c = DMPConfig()
    n, d = c.n_kernels, c.n_dims
    p = DMPParams(torch.zeros(1, n, d), torch.ones(1), torch.ones(1, d), torch.zeros(1, d))
    return p, torch.linspace(0.0, 1.0, 3), c


def test_a_run_resumes_from_another_directory_given_its_data_set_s_place(
    data, tmp_path, monkeypatch
):
    """A run started with a relative --data could not be resumed from anywhere else (its
    data set "does not exist"), nor after the file moved, and --resume refused --data.
    --data now gives the place of the same file (by SHA-256), and the resumed run's
    weights are those of the run left uninterrupted."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "d.safetensors").write_bytes(data.read_bytes())
    other = tmp_path / "other.safetensors"
    save_dataset(other, generate_dataset(12, seed=1, progress=False))
    run, ref = tmp_path / "run", tmp_path / "ref"
    tiny = ["--set", "threads=1", "optim.batch_size=4", "optim.patience=0", "optim.schedule=none"]
    tiny += [f"model.encoder_layers={TINY['encoder_layers']}", "--no-progress"]
    monkeypatch.chdir(tmp_path / "a")
    for where, epochs in ((run, "1"), (ref, "2")):
        argv = ["train", "--data", "d.safetensors", "--run-dir", str(where), "--epochs", epochs]
        assert cli.main([*argv, *tiny]) == 0
    monkeypatch.chdir(tmp_path / "b")
    resume = ["train", "--run-dir", str(run), "--resume", "--epochs", "2", "--no-progress"]
    assert cli.main(resume) == 2
    assert cli.main([*resume, "--data", str(other)]) == 2
    assert cli.main([*resume, "--data", "../a/d.safetensors"]) == 0
    assert weights_digest(run) == weights_digest(ref)
    stored = (run / "config.yaml").read_text()
    assert "../a/d.safetensors" in stored  # the next resume from here needs no --data


def test_the_lines_of_a_resume_that_cannot_find_its_data(data, tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    monkeypatch.chdir(data.parent)
    argv = ["train", "--data", data.name, "--run-dir", str(run), "--epochs", "1", "--no-progress"]
    assert cli.main([*argv, "--set", f"model.encoder_layers={TINY['encoder_layers']}"]) == 0
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    assert cli.main(["train", "--run-dir", str(run), "--resume", "--epochs", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--data PATH" in err and f"from {tmp_path}" in err, err
    wrong = tmp_path / "wrong.safetensors"
    save_dataset(wrong, generate_dataset(12, seed=2, progress=False))
    assert cli.main(["train", "--run-dir", str(run), "--resume", "--data", str(wrong)]) == 2
    err = capsys.readouterr().err
    assert "is not the one the run trained on" in err and err.count("\n") == 1, err
    # only --data: the configuration is still the stored one's
    assert cli.main(["train", "--run-dir", str(run), "--resume", "--seed", "3"]) == 2
    assert "--seed cannot be used" in capsys.readouterr().err


def test_sigterm_stops_a_training_in_one_line_that_says_how_to_resume(data, tmp_path):
    """SIGTERM (kill, a batch scheduler's time limit) ended a training on the spot without
    a word (exit status -15). It now stops it as Ctrl-C does: one line, exit status 143,
    no temporary left, the epochs kept and the command that resumes them."""
    run = tmp_path / "run"
    argv = [sys.executable, "-m", "img2dmp.cli", "train", "--data", str(data), "--run-dir"]
    argv += [str(run), "--epochs", "500", "--no-progress", "--set", "threads=1"]
    argv += [f"model.encoder_layers={TINY['encoder_layers']}"]
    env = dict(os.environ, PYTHONPATH=SRC)
    proc = subprocess.Popen(
        argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    metrics, deadline = run / "metrics.csv", time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if metrics.is_file() and len(metrics.read_text().splitlines()) >= 2:  # an epoch done
            proc.send_signal(signal.SIGTERM)
            break
        time.sleep(0.01)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    last = err.strip().splitlines()[-1]
    assert "Traceback" not in err
    saved = json.loads((run / "checkpoints" / "last.json").read_text())["epoch"] + 1
    assert last == (
        f"img2dmp train: terminated; {saved} of 500 epochs are saved in "
        f"{run / 'checkpoints' / 'last.safetensors'}; to continue: img2dmp train --run-dir "
        f"{shlex.quote(str(run))} --resume"
    )
    assert not [p for p in run.rglob("*") if p.name.endswith(".tmp")]
    assert cli.main(["train", "--run-dir", str(run), "--resume", "--epochs", str(saved + 1)]) == 0


def test_an_interrupt_before_the_first_epoch_says_nothing_is_saved(tmp_path):
    from argparse import Namespace

    from img2dmp.commands.train import saved_epochs

    args = Namespace(run_dir=str(tmp_path / "run"), resume=False)
    assert (
        saved_epochs(args, time.time())
        == "no epoch of this run finished, so nothing of it is saved"
    )


def test_the_summary_counts_what_this_command_trained_and_numbers_epochs_from_one(
    data, tmp_path, capsys
):
    """The summary said the best epoch counted from 0 ("epoch 5") under progress lines
    counted from 1 ("epoch 6/6"); a resumed run said "6 epochs" when it trained one or
    none; and it forgot the run's reading settings (those of the defaults instead)."""
    run = tmp_path / "run"
    argv = ["train", "--data", str(data), "--run-dir", str(run), "--epochs", "2"]
    argv += ["--set", f"model.encoder_layers={TINY['encoder_layers']}", "reading.refine=7"]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    rows = (run / "metrics.csv").read_text().splitlines()[1:]
    best = min(rows, key=lambda r: float(r.split(",")[5]))  # val_error_px
    assert out.startswith("2 epochs in ") and f"(epoch {int(best.split(',')[0]) + 1})" in out
    assert "--refine 7" in out
    resume = ["train", "--run-dir", str(run), "--resume", "--no-progress"]
    assert cli.main(resume) == 0
    out = capsys.readouterr().out
    assert out.startswith("no epoch to train: the run has done its 2 epochs"), out
    assert "--refine 7" in out
    assert cli.main([*resume, "--epochs", "4"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("epochs 3-4 in ") and " s (4 in all); " in out and "--refine 7" in out


def test_a_full_disk_in_mid_run_says_which_epochs_are_saved(data, tmp_path, monkeypatch, capsys):
    """A disk that fills during a run ended it with the file and "No space left on
    device" only; the line now adds the epochs kept and the command that resumes them."""
    import errno

    from img2dmp.training import state

    real, calls = state.save_checkpoint, {"last": 0}

    def save(path, *args, **kwargs):
        if path.name == "last.safetensors":
            calls["last"] += 1
            if calls["last"] == 3:
                raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, *args, **kwargs)

    monkeypatch.setattr(state, "save_checkpoint", save)
    run = tmp_path / "run"
    argv = ["train", "--data", str(data), "--run-dir", str(run), "--epochs", "5", "--no-progress"]
    assert cli.main([*argv, "--set", f"model.encoder_layers={TINY['encoder_layers']}"]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    last = run / "checkpoints" / "last.safetensors"
    assert line == (
        f"img2dmp train: error: {last}: No space left on device; 2 of 5 epochs are saved in "
        f"{last}; to continue: img2dmp train --run-dir {shlex.quote(str(run))} --resume"
    )
    monkeypatch.setattr(state, "save_checkpoint", real)  # room again
    assert cli.main(["train", "--run-dir", str(run), "--resume", "--no-progress"]) == 0


def test_an_early_stopped_run_counts_every_epoch_it_ran(data, tmp_path, monkeypatch, capsys):
    """The closing line of the epochs' bar left out the epoch at which training stopped
    early ("epochs: 4 epochs" after five), and said "1 epochs"."""
    from img2dmp.training import loop

    errors = iter([5.0, 4.0, 4.5, 4.6])  # patience 1: the third epoch is the last
    monkeypatch.setattr(loop, "validate", lambda run, epoch, fallback: next(errors))
    monkeypatch.setenv("IMG2DMP_PROGRESS", "lines")
    run = tmp_path / "run"
    argv = ["train", "--data", str(data), "--run-dir", str(run), "--epochs", "10"]
    argv += ["--set", "optim.patience=1", f"model.encoder_layers={TINY['encoder_layers']}"]
    assert cli.main(argv) == 0
    captured = capsys.readouterr()
    assert "early stop" in captured.err and "\nepochs: 3 epochs in " in captured.err
    assert captured.out.startswith("3 epochs in ") and "(epoch 2)" in captured.out
    errors = iter([4.7])
    assert cli.main(["train", "--run-dir", str(run), "--resume"]) == 0
    captured = capsys.readouterr()
    assert "\nepochs: 1 epoch in " in captured.err, captured.err
    assert captured.out.startswith("epoch 4 in ") and "(4 in all)" in captured.out


def test_the_command_to_continue_is_one_a_shell_takes(data, tmp_path):
    """A run directory with a space in its name: the command is quoted for a shell."""
    from argparse import Namespace

    from img2dmp.commands.train import saved_epochs

    run = tmp_path / "my runs" / "a"
    train(config(data, epochs=1), run)
    said = saved_epochs(Namespace(run_dir=str(run), resume=True), time.time())
    assert said.startswith(f"1 of 1 epochs are saved in {run}")
    command = said.split("; to continue: ")[1]
    assert shlex.split(command) == ["img2dmp", "train", "--run-dir", str(run), "--resume"]


def test_a_damaged_last_checkpoint_says_what_is_left(data, tmp_path, capsys):
    """A truncated last checkpoint ended a resume with the file's damage alone; the line
    now says the run cannot be resumed and how its best weights can start a new one."""
    run = tmp_path / "run"
    train(config(data, epochs=1), run)
    last = run / "checkpoints" / "last.safetensors"
    last.write_bytes(last.read_bytes()[:1000])
    capsys.readouterr()
    assert cli.main(["train", "--run-dir", str(run), "--resume", "--epochs", "2"]) == 2
    line = capsys.readouterr().err.strip()
    assert line.startswith(f"img2dmp train: error: cannot resume: checkpoint {last} is corrupt")
    assert f"--init-from {run / 'checkpoints' / 'best.safetensors'} --run-dir NEW" in line
    assert "--config" not in line  # the network comes with the weights (no --config)
    assert "\n" not in line
