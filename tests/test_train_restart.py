"""Starting a run from another: ``train --init-from RUN`` takes the run's network when no
``--config`` says otherwise and refuses one that does not fit by name; ``train --force``
replaces an old run so that nothing of it is left to resume, even when the new run is
stopped before its first epoch ends."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from img2dmp import cli
from img2dmp.data.store import save_dataset
from img2dmp.data.synthetic import SyntheticConfig, generate_dataset
from img2dmp.training import loop, setup

SRC = str(Path(__file__).resolve().parents[1] / "src")
#: A network and optimiser small enough that an epoch of 8 samples takes milliseconds.
TINY = [
    "threads=1",
    "optim.batch_size=4",
    "optim.schedule=none",
    "optim.patience=0",
]
#: The pre-trained run's own network: not the defaults, in every way that could be lost.
PRE = [
    "model.encoder_layers=[16, 8]",
    "model.decoder_layers=[8]",
    "model.activation=tanh",
    "model.hypotheses=2",
    "cost.score_weight=0.2",
    "reading.refine=7",
]


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """Eight synthetic digits (2 and 3), in the training and validation splits."""
    path = tmp_path_factory.mktemp("restart") / "d.safetensors"
    save_dataset(
        path,
        generate_dataset(4, SyntheticConfig(digits=(2, 3)), seed=0, splits=(0.5, 0.5, 0.0),
                         progress=False),
    )  # fmt: skip
    return path


def _argv(data: Path, run: Path, *extra: str, settings=TINY) -> list[str]:
    argv = ["train", "--data", str(data), "--run-dir", str(run), "--no-progress"]
    for s in settings:
        argv += ["--set", s]
    return [*argv, *extra]


@pytest.fixture(scope="module")
def pre(data, tmp_path_factory) -> Path:
    """A run of two epochs of its own network, cost and reading settings."""
    run = tmp_path_factory.mktemp("pre") / "run"
    assert cli.main(_argv(data, run, "--epochs", "2", settings=TINY + PRE)) == 0
    return run


def _stored(run: Path) -> dict:
    return yaml.safe_load((run / "config.yaml").read_text())


def _digest(run: Path, name: str = "last") -> str:
    return json.loads((run / "checkpoints" / f"{name}.json").read_text())["weights_sha256"]


def _error_line(capsys, argv: list[str], status: int = 2) -> str:
    capsys.readouterr()
    assert cli.main(argv) == status
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


# --- --init-from ------------------------------------------------------------------------


def test_init_from_without_config_takes_the_run_s_network_cost_and_reading(
    data, pre, tmp_path, capsys
):
    """Without --config the defaults' network (fully connected, 1500 ... 20) was built
    and the run's weights refused: a user had to repeat the run's --config."""
    tuned = tmp_path / "tuned"
    argv = _argv(data, tuned, "--init-from", str(pre), "--epochs", "1")
    assert cli.main([*argv, "--set", "optim.lr=1e-4"]) == 0, capsys.readouterr().err
    theirs, ours = _stored(pre), _stored(tuned)
    for section in ("model", "cost", "strokes", "reading"):
        assert ours[section] == theirs[section], section
    assert ours["optim"]["lr"] == 1e-4 and ours["optim"]["epochs"] == 1  # the command line's
    assert ours["init_from"] == str(pre)
    assert "--refine 7" in capsys.readouterr().out  # the reading it recommends is the run's


def test_init_from_with_a_config_of_another_network_names_the_field(data, pre, tmp_path, capsys):
    """A --config whose network has the run's shapes but another activation loaded the
    weights into a network that computes something else, without a word."""
    mine = tmp_path / "mine.yaml"
    mine.write_text(
        "model:\n  encoder_layers: [16, 8]\n  decoder_layers: [8]\n  hypotheses: 2\n"
        "  activation: relu\n"
    )
    argv = _argv(data, tmp_path / "tuned", "--init-from", str(pre), "--config", str(mine))
    line = _error_line(capsys, argv)
    assert f"cannot initialise from {pre / 'checkpoints' / 'best.safetensors'}" in line
    assert "model.activation 'tanh' (this run: 'relu')" in line
    assert "without --config" in line
    assert not (tmp_path / "tuned" / "checkpoints").exists()
    # the initialisation the weights replace may differ
    mine.write_text(mine.read_text().replace("relu", "tanh") + "  init: he\n")
    assert cli.main([*argv, "--epochs", "1"]) == 0, capsys.readouterr().err
    assert _stored(tmp_path / "tuned")["model"]["init"] == "he"


def test_init_from_refuses_a_set_that_changes_the_run_s_network(data, pre, tmp_path, capsys):
    argv = _argv(data, tmp_path / "tuned", "--init-from", str(pre))
    line = _error_line(capsys, [*argv, "--set", "model.hypotheses=1", "--set", "model.init=he"])
    assert "model.hypotheses 2 (this run: 1)" in line and "model.init" not in line


def test_init_from_a_network_of_other_images_says_which_size_it_reads(data, pre, tmp_path, capsys):
    """The hint was to leave model.image_size out, which the run's weights cannot."""
    other = tmp_path / "other.safetensors"
    config = SyntheticConfig(digits=(2,), image_size=(32, 32))
    save_dataset(other, generate_dataset(4, config, seed=0, progress=False))
    line = _error_line(capsys, _argv(other, tmp_path / "tuned", "--init-from", str(pre)))
    assert "the data's images are [32, 32] pixels" in line
    assert f"the network of {pre / 'checkpoints' / 'best.safetensors'} reads [40, 40]" in line


# --- --force ----------------------------------------------------------------------------


def test_a_force_restart_stopped_before_its_first_epoch_leaves_the_old_run_whole(
    data, pre, tmp_path, monkeypatch, capsys
):
    """The new config.yaml was written as the restart began, beside the old run's
    checkpoints, records and familiarity, which a stop before the first epoch ended
    left: a run directory of two runs."""
    run = tmp_path / "run"
    shutil.copytree(pre, run)
    before = _snapshot(run)
    monkeypatch.setattr(loop, "train_epoch", _interrupted)
    line = _error_line(capsys, _argv(data, run, "--force", "--seed", "3", "--epochs", "3"), 130)
    said = f"no epoch of this run finished, so nothing of it is saved; the earlier run in {run} "
    assert said + "is as it was" in line
    monkeypatch.undo()
    assert _snapshot(run) == before
    # --resume continues the old run, with its own configuration
    capsys.readouterr()
    assert cli.main(["train", "--run-dir", str(run), "--resume", "--epochs", "3"]) == 0
    assert _stored(run)["seed"] == 0 and _stored(run)["model"] == _stored(pre)["model"]
    assert "epoch 3 in" in capsys.readouterr().out


@pytest.mark.parametrize("at", ["config", "checkpoint", "metrics"])
def test_a_force_restart_stopped_as_it_replaces_the_old_run_puts_it_back(
    at, data, pre, tmp_path, monkeypatch, capsys
):
    """Stopped while it writes its first epoch's files (after some are written), the
    restart deletes them and the old run is back, as it was."""
    run = tmp_path / "run"
    shutil.copytree(pre, run)
    (run / "notes.txt").write_text("mine")  # a file of the user's own is left where it is
    (run / "evaluation").mkdir()
    (run / "evaluation" / "evaluation.txt").write_text("the old run's")
    before = _snapshot(run)
    target = {"config": (setup.Run, "write_config"), "checkpoint": (loop, "save_state"),
              "metrics": (loop, "write_metrics_csv")}[at]  # fmt: skip
    real = getattr(*target)

    def written_then_stopped(*args, **kwargs):
        real(*args, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(*target, written_then_stopped)
    _error_line(capsys, _argv(data, run, "--force", "--seed", "3", "--epochs", "3"), 130)
    assert _snapshot(run) == before
    assert not (run / setup.REPLACED).exists()


def test_a_force_restart_replaces_the_whole_run_with_its_first_epoch(
    data, pre, tmp_path, monkeypatch, capsys
):
    run = tmp_path / "run"
    shutil.copytree(pre, run)
    (run / "notes.txt").write_text("mine")
    (run / "evaluation").mkdir()  # evaluate's default --out: the old weights' figures
    (run / "evaluation" / "evaluation.txt").write_text("the old run's")
    old = _digest(run)
    seen = {}
    real = loop.save_state

    def save_state(run_dir, *args):  # what the directory holds as the first epoch is saved
        seen.setdefault("names", sorted(p.name for p in run_dir.iterdir()))
        seen.setdefault("config", _stored(run_dir))
        return real(run_dir, *args)

    monkeypatch.setattr(loop, "save_state", save_state)
    assert cli.main(_argv(data, run, "--force", "--seed", "3", "--epochs", "2")) == 0
    assert seen["names"] == [".lock", setup.REPLACED, "config.yaml", "notes.txt"]
    assert seen["config"]["seed"] == 3
    assert _digest(run) != old and _stored(run)["seed"] == 3
    assert len((run / "metrics.csv").read_text().splitlines()) == 3  # its header, its epochs
    assert not (run / setup.REPLACED).exists() and (run / "notes.txt").read_text() == "mine"
    assert not (run / "evaluation").exists()


def _interrupted(run, epoch):
    raise KeyboardInterrupt


def _snapshot(path: Path) -> dict:
    """Every file under ``path`` -> its bytes (but the lock's, which holds its holder's pid)."""
    files = [p for p in path.rglob("*") if p.is_file() and p.name != ".lock"]
    return {str(p.relative_to(path)): p.read_bytes() for p in files}


def test_a_force_restart_that_fails_its_checks_keeps_the_old_run(data, pre, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(pre, run)
    before = _snapshot(run)
    line = _error_line(capsys, _argv(data, run, "--force", "--set", "model.image_size=[30, 30]"))
    assert "model.image_size" in line
    assert _snapshot(run) == before


def test_a_force_restart_replaces_the_old_run_s_records(data, pre, tmp_path, capsys):
    """A new run on the generator writes no familiarity: the old run's stayed beside it."""
    run = tmp_path / "run"
    shutil.copytree(pre, run)
    assert (run / "familiar.safetensors").is_file()
    old = _digest(run)
    argv = ["train", "--run-dir", str(run), "--no-progress", "--force", "--epochs", "1"]
    for s in [*TINY, "data.samples_per_epoch=8", "data.val_samples=4",
              "model.encoder_layers=[16, 8]"]:  # fmt: skip
        argv += ["--set", s]
    assert cli.main(argv) == 0, capsys.readouterr().err
    assert _digest(run) != old
    assert not (run / "familiar.safetensors").exists()
    assert len((run / "metrics.csv").read_text().splitlines()) == 2  # its header, its epoch


def test_init_from_a_run_of_other_dmp_constants_names_them_and_the_remedy(
    data, pre, tmp_path, capsys
):
    """The line gave both whole DMP configurations, for the reader to compare."""
    other = tmp_path / "none.safetensors"
    assert cli.main(["generate", "--out", str(other), "--per-digit", "4", "--digits", "2",
                     "--scaling", "none", "--workers", "1", "--no-progress"]) == 0  # fmt: skip
    line = _error_line(capsys, _argv(other, tmp_path / "tuned", "--init-from", str(pre)))
    assert f"cannot initialise from {pre / 'checkpoints' / 'best.safetensors'}" in line
    assert (
        f"differ from those of the data set {other} in scaling 'goal-start' (the data: 'none')"
        in line
    )
    assert "--scaling goal-start" in line and "alpha_z" not in line


def test_init_from_a_shipped_model_takes_its_network_and_its_card_s_reading(tmp_path, capsys):
    """Fine-tuning digits-real without --config: its network, and the reading its card
    recommends (the record has no reading section; the fine-tuned run recommended none)."""
    from img2dmp import models
    from img2dmp.checkpoint import read_checkpoint_meta, resolve_checkpoint

    record = read_checkpoint_meta(resolve_checkpoint("digits-real"))
    size = record["train_config"]["model"]["image_size"]
    scaling = record["dmp_config"]["scaling"]
    data = tmp_path / "d.safetensors"
    argv = ["generate", "--out", str(data), "--per-digit", "4", "--digits", "3", "--no-progress",
            "--image-size", str(size[0]), "--scaling", scaling, "--workers", "1"]  # fmt: skip
    assert cli.main(argv) == 0
    run = tmp_path / "tuned"
    assert cli.main(_argv(data, run, "--init-from", "digits-real", "--epochs", "1")) == 0
    stored = _stored(run)
    assert stored["model"] == record["train_config"]["model"]
    card = models.resolve("digits-real").reading.recommended()
    assert card["refine"] > 0
    assert {k: v for k, v in stored["reading"].items() if v is not None} == card


def test_a_force_restart_killed_in_its_first_epoch_leaves_the_old_run_whole(data, pre, tmp_path):
    """kill -9, which no clean-up follows, in the restart's first epoch."""
    run = tmp_path / "run"
    shutil.copytree(pre, run)
    before = _snapshot(run)
    started = tmp_path / "in-epoch"
    code = (
        "import sys, time\nfrom pathlib import Path\nfrom img2dmp import cli\n"
        "from img2dmp.training import loop\n"
        "def stays(run, epoch):\n"
        f"    Path({str(started)!r}).touch()\n"
        "    time.sleep(600)\n"
        "loop.train_epoch = stays\n"
        "sys.exit(cli.main(sys.argv[1:]))\n"
    )
    env = dict(os.environ, PYTHONPATH=SRC, OMP_NUM_THREADS="1")
    argv = _argv(data, run, "--force", "--seed", "3")
    proc = subprocess.Popen([sys.executable, "-c", code, *argv], env=env)
    try:
        deadline = time.monotonic() + 120
        while not started.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert started.exists(), "the restart never reached its first epoch"
    finally:
        proc.kill()
        proc.wait()
    assert _snapshot(run) == before
