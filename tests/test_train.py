"""Training: learning, checkpoints, resume after kill -9, configs, torchrun, the demo."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from img2dmp import cli
from img2dmp.checkpoint import (
    CheckpointError,
    load_checkpoint,
    load_weights_into,
    read_checkpoint_meta,
)
from img2dmp.data.store import load_dataset, save_dataset
from img2dmp.data.synthetic import generate_dataset
from img2dmp.evaluate import evaluate
from img2dmp.nn import ModelConfig, ParamNormaliser, build_model
from img2dmp.predict import Predictor
from img2dmp.train import (
    TrainConfig,
    load_config,
    read_metrics_csv,
    train,
    trajectory_errors,
)

TINY_MODEL = {"encoder_layers": [64, 20], "decoder_layers": [35], "image_size": [40, 40]}


def tiny_config(data_path, **optim) -> TrainConfig:
    o = {"epochs": 4, "batch_size": 16, "lr": 2e-3, "schedule": "none", "patience": 0}
    o.update(optim)
    return TrainConfig.from_dict(
        {
            "model": dict(TINY_MODEL),
            "data": {"path": str(data_path)},
            "optim": o,
            "cost": {"name": "trajectory"},
            "threads": 1,
            "progress": False,
        }
    )


@pytest.fixture(scope="module")
def small_data(tmp_path_factory) -> Path:
    """240 synthetic digits (200 train, 20 validation, 20 test) from the project's generator."""
    path = tmp_path_factory.mktemp("data") / "small.safetensors"
    save_dataset(path, generate_dataset(24, seed=0, progress=False))
    return path


@pytest.fixture(scope="module")
def trained(small_data, tmp_path_factory):
    run = tmp_path_factory.mktemp("runs") / "learn"
    cfg = tiny_config(small_data, epochs=25, schedule="cosine")
    return cfg, run, train(cfg, run)


def test_training_lowers_validation_error(small_data, trained):
    cfg, run, res = trained
    assert res.history[-1]["step"] >= 300  # "a few hundred steps"
    data = load_dataset(small_data).select_split("validation")
    norm = ParamNormaliser.fit(
        load_dataset(small_data).select_split("train").params, data.dmp_config
    )
    untrained = build_model(ModelConfig(**TINY_MODEL), seed=cfg.seed)
    before = trajectory_errors(
        untrained,
        norm,
        data.dmp_config,
        torch.as_tensor(data.images),
        torch.as_tensor(data.times),
        torch.as_tensor(data.trajectories),
    ).mean()
    assert res.best_val_error_px < 0.6 * before
    for name in (
        "config.yaml",
        "metrics.csv",
        "training_curve.png",
        "checkpoints/best.safetensors",
        "checkpoints/best.json",
        "checkpoints/last.safetensors",
        "checkpoints/last.json",
    ):
        assert (run / name).is_file(), name
    rows = read_metrics_csv(run / "metrics.csv")
    assert [r["epoch"] for r in rows] == list(range(25))
    assert min(r["val_error_px"] for r in rows) == pytest.approx(res.best_val_error_px)
    assert res.error_measure == "trajectory"  # Table I's, as evaluate reports it
    assert read_checkpoint_meta(run / "checkpoints" / "best.json")["val_error_measure"] == (
        "trajectory"
    )


def test_saved_model_predicts_the_same_numbers(small_data, trained):
    _, run, res = trained
    pred = Predictor.load(run, backend="torch")
    # The reloaded best model reproduces the validation error measured during training.
    ev = evaluate(run, small_data, split="validation")
    assert ev["overall"]["mean"] == pytest.approx(res.best_val_error_px, rel=1e-6)
    # Same weights in a fresh network give the same outputs; the JSON beside agrees.
    ckpt = load_checkpoint(run / "checkpoints" / "best.safetensors")
    fresh = build_model(ModelConfig.from_dict(ckpt.meta["model"]))
    load_weights_into(fresh, ckpt)
    x = torch.as_tensor(load_dataset(small_data).images[:8])
    with torch.no_grad():
        assert torch.equal(fresh.eval()(x), pred.predict_normalised(x))
    # the NumPy backend (what Predictor.load takes on the CPU) computes the same to rounding
    z = Predictor.load(run).predict_normalised(x)
    assert (z - pred.predict_normalised(x)).abs().max() <= 1e-5 * (1 + z.abs().max())
    side = json.loads((run / "checkpoints" / "best.json").read_text())
    assert side == ckpt.meta == read_checkpoint_meta(run)
    p = pred.predict_images(x.numpy())
    assert p.batch_shape == (8,) and isinstance(p.w, np.ndarray) and (p.tau > 0).all()
    assert pred.image_size == (40, 40) and pred.dmp_config.n_params == 55


def test_bad_checkpoints_give_clear_errors(trained, tmp_path):
    _, run, _ = trained
    good = (run / "checkpoints" / "best.safetensors").read_bytes()
    trunc = tmp_path / "truncated.safetensors"
    trunc.write_bytes(good[: len(good) // 2])
    with pytest.raises(CheckpointError, match="corrupt or truncated"):
        Predictor.load(trunc)
    flipped = bytearray(good)
    flipped[-100] ^= 0xFF  # a weight's byte, not the header
    bad = tmp_path / "flipped.safetensors"
    bad.write_bytes(bytes(flipped))
    with pytest.raises(CheckpointError, match="SHA-256"):
        Predictor.load(bad)
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"not a checkpoint at all")
    with pytest.raises(CheckpointError, match=str(junk.name)):
        Predictor.load(junk)
    with pytest.raises(FileNotFoundError):
        Predictor.load(tmp_path / "nothing.safetensors")
    other = build_model(ModelConfig(encoder_layers=[32, 20], decoder_layers=[35]))
    with pytest.raises(CheckpointError, match="another architecture"):
        load_weights_into(other, load_checkpoint(run))
    # and through the CLI: one line on stderr, exit code 2, no traceback
    assert cli.main(["predict", "--model", str(trunc), str(tmp_path / "x.png")]) == 2


def test_resume_after_kill_reproduces_history(small_data, tmp_path):
    """kill -9 in mid-epoch, --resume: the metrics equal those of an uninterrupted run."""
    args = [
        "--data",
        str(small_data),
        "--epochs",
        "8",
        "--no-progress",
        "--set",
        "threads=1",
        "optim.batch_size=4",
        "optim.schedule=cosine",
        "optim.patience=0",
        f"model.encoder_layers={TINY_MODEL['encoder_layers']}",
        f"model.decoder_layers={TINY_MODEL['decoder_layers']}",
    ]
    ref_dir, run_dir = tmp_path / "ref", tmp_path / "killed"
    assert cli.main(["train", "--run-dir", str(ref_dir), *args]) == 0
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1] / "src"))
    proc = subprocess.Popen(
        [sys.executable, "-m", "img2dmp.cli", "train", "--run-dir", str(run_dir), *args],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    metrics = run_dir / "metrics.csv"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if metrics.is_file() and len(metrics.read_text().splitlines()) >= 3:  # 2 epochs done
            time.sleep(0.05)  # into the third epoch
            proc.send_signal(signal.SIGKILL)
            break
        time.sleep(0.01)
    rc = proc.wait()
    if rc == 0:
        pytest.skip("the run finished before it could be killed")
    assert rc == -signal.SIGKILL
    done = len(read_metrics_csv(metrics))
    assert 2 <= done < 8
    resume = ["train", "--run-dir", str(run_dir), "--resume", "--no-progress"]
    # The resumed run takes its configuration from the checkpoint; changing it is refused.
    assert cli.main([*resume, *args]) == 2 and len(read_metrics_csv(metrics)) == done
    assert cli.main([*resume, "--epochs", "8"]) == 0
    ref, got = read_metrics_csv(ref_dir / "metrics.csv"), read_metrics_csv(metrics)
    assert len(got) == len(ref) == 8
    for a, b in zip(ref, got, strict=True):
        for k in a:
            if k != "epoch_time_s":
                assert b[k] == a[k], (a["epoch"], k)
    # bit for bit: every step of both runs took one rollout path (training.setup)
    for name in ("best", "last"):
        ours, theirs = (
            read_checkpoint_meta(d / "checkpoints" / f"{name}.safetensors")
            for d in (ref_dir, run_dir)
        )
        assert ours["weights_sha256"] == theirs["weights_sha256"], name
    # a finished run can be trained on, and a run directory is never silently overwritten
    assert (
        cli.main(
            [
                "train",
                "--run-dir",
                str(run_dir),
                "--resume",
                "--epochs",
                "9",
                "--no-progress",
            ]
        )
        == 0
    )
    assert [r["epoch"] for r in read_metrics_csv(metrics)] == list(range(9))
    with pytest.raises(FileExistsError, match="--resume"):
        train(load_config(None, [f"data.path={small_data}", "progress=false"]), run_dir)


def test_configs_from_yaml_and_toml(tmp_path, small_data):
    (tmp_path / "c.yaml").write_text("optim:\n  lr: 0.01\ncost:\n  name: '9'\n")
    (tmp_path / "c.toml").write_text('[optim]\nlr = 0.02\n[model]\nactivation = "tanh"\n')
    cfg = load_config(tmp_path / "c.yaml", ["optim.batch_size=7", "data.digits=[2, 3]"])
    assert (cfg.optim.lr, cfg.optim.batch_size, cfg.cost.name) == (0.01, 7, "parameter")
    assert cfg.data.digits == [2, 3]
    cfg = load_config(tmp_path / "c.toml", ["optim.lr=0.5"])
    assert (cfg.optim.lr, cfg.model.activation) == (0.5, "tanh")
    with pytest.raises(ValueError, match="optim"):
        load_config(tmp_path / "c.yaml", ["optim.learning_rate=1"])
    with pytest.raises(ValueError, match="schedule"):
        load_config(None, ["optim.schedule=sometimes"])
    # YAML 1.1 reads 3e-4 as text; the config reader takes it as a number, in files too.
    (tmp_path / "e.yaml").write_text("optim:\n  lr: 3e-4\n  min_lr: 1E-7\n")
    cfg = load_config(tmp_path / "e.yaml", ["optim.weight_decay=2e-5"])
    assert (cfg.optim.lr, cfg.optim.min_lr, cfg.optim.weight_decay) == (3e-4, 1e-7, 2e-5)
    with pytest.raises(ValueError, match=r"optim\.lr must be a number.*'fast'"):
        load_config(None, ["optim.lr=fast"])
    with pytest.raises(ValueError, match=r"optim\.epochs must be a number.*2\.5"):
        load_config(None, ["optim.epochs=2.5"])
    (tmp_path / "bad.yaml").write_text("optim: [1, 2\n")
    with pytest.raises(ValueError, match="bad.yaml"):
        load_config(tmp_path / "bad.yaml")
    with pytest.raises(ValueError, match="image"):  # model input does not fit the data
        cfg = load_config(
            None, [f"data.path={small_data}", "model.image_size=[28, 28]", "progress=false"]
        )
        train(cfg, tmp_path / "r")


def test_other_costs_encoders_and_generator_mode(small_data, tmp_path):
    for name, enc in (("parameter", "fc"), ("combined", "conv")):
        cfg = tiny_config(small_data, epochs=2)
        cfg.cost.name = name
        cfg.model.encoder = enc
        cfg.model.conv_channels = [4, 8]
        res = train(cfg, tmp_path / name)
        assert np.isfinite(res.best_val_error_px)
    # cost (9) in amplitude units, weighted by the full metric, on augmented batches
    cfg = tiny_config(small_data, epochs=2)
    cfg.cost.name = "parameter"
    cfg.cost.parameter_units = "amplitudes"
    cfg.cost.parameter_weighting = "trajectory-full"
    cfg.data.augment = {"rotation_deg": [-5, 5]}
    res = train(cfg, tmp_path / "amplitudes")
    assert np.isfinite(res.best_val_error_px)
    meta = json.loads((tmp_path / "amplitudes" / "checkpoints" / "best.json").read_text())
    assert meta["normaliser"]["units"] == "amplitudes"
    with pytest.raises(ValueError, match="cost.parameter_units"):
        TrainConfig.from_dict({"cost": {"parameter_units": "newtons"}})
    cfg = TrainConfig.from_dict(
        {
            "model": dict(TINY_MODEL),
            "data": {
                "generator": {"noise_amount": 0.0},
                "digits": [1, 7],
                "samples_per_epoch": 48,
                "val_samples": 16,
            },
            "optim": {"epochs": 2, "batch_size": 16},
            "threads": 1,
            "progress": False,
        }
    )
    res = train(cfg, tmp_path / "gen")
    assert len(res.history) == 2 and np.isfinite(res.best_val_error_px)


def test_torchrun_two_processes_match_one(small_data, tmp_path):
    """DistributedDataParallel on 2 gloo processes = one process with the same global batch."""
    over = [
        "threads=1",
        "optim.batch_size=20",
        "optim.schedule=none",
        "optim.patience=0",
        f"model.encoder_layers={TINY_MODEL['encoder_layers']}",
    ]
    args = ["train", "--data", str(small_data), "--epochs", "2", "--no-progress", "--set", *over]
    env = dict(
        os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1] / "src"), OMP_NUM_THREADS="1"
    )
    torchrun = [sys.executable, "-m", "torch.distributed.run", "--standalone"]
    torchrun += ["--nproc_per_node", "2", "--tee", "3", "-m", "img2dmp.cli", *args]
    run = [*torchrun, "--run-dir", str(tmp_path / "ddp")]
    out = subprocess.run(run, env=env, capture_output=True, text=True, timeout=120)
    if out.returncode != 0 and "(SIGABRT)" in out.stderr:
        # gloo aborted a rank with SIGABRT ("terminate called without an active exception")
        # when one rank tore the group down while the other still used it: 2 of 12 runs
        # beside a CPU burner; with a barrier before the teardown (training.distributed)
        # 0 of 32. A second try still tells such a flake of the transport from a failure
        # of ours, and the first attempt's output stays in the warning.
        warnings.warn(f"torchrun: a rank aborted, again:\n{out.stderr[-4000:]}", stacklevel=1)
        shutil.rmtree(tmp_path / "ddp", ignore_errors=True)
        out = subprocess.run(run, env=env, capture_output=True, text=True, timeout=120)
    ranks = "\n".join(ln for ln in out.stderr.splitlines() if ln.startswith(("[0]", "[1]")))
    assert out.returncode == 0, (ranks or out.stderr)[-4000:]
    assert cli.main([*args, "--run-dir", str(tmp_path / "one")]) == 0
    ddp = read_metrics_csv(tmp_path / "ddp" / "metrics.csv")
    one = read_metrics_csv(tmp_path / "one" / "metrics.csv")
    assert len(ddp) == len(one) == 2
    for a, b in zip(one, ddp, strict=True):
        assert a["step"] == b["step"]
        for k in ("train_cost", "train_error_px", "val_error_px"):
            assert b[k] == pytest.approx(a[k], rel=1e-4), k


def test_demo_runs_the_whole_chain(tmp_path):
    from img2dmp.pipeline import run_demo

    s = run_demo(
        tmp_path / "demo",
        samples_per_digit=10,
        epochs=2,
        progress=False,
        overrides={"model": {"encoder_layers": [64, 20]}},
    )
    for f in (
        "data.safetensors",
        "run/metrics.csv",
        "run/training_curve.png",
        "run/checkpoints/best.safetensors",
        "evaluation/evaluation.json",
        "evaluation/evaluation.txt",
        "evaluation/examples.png",
        "summary.json",
    ):
        assert (tmp_path / "demo" / f).is_file(), f
    assert s["epochs_run"] == 2 and np.isfinite(s["test_error_px"]["mean"])
    # what else decides the figures' last digits: as the run's checkpoints record it
    from img2dmp.checkpoint import read_checkpoint_meta

    meta = read_checkpoint_meta(tmp_path / "demo" / "run" / "checkpoints" / "best.safetensors")
    assert s["numerics"] == meta["numerics"] and s["numerics"]["torch_threads"] >= 1
    assert s["numerics"]["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()


def test_demo_config_is_shipped_once_and_is_what_the_demo_trains(tmp_path):
    # The demo's configuration exists once, as package data; the demo trains with it.
    from importlib import resources

    from img2dmp.pipeline import DEMO_CONFIG, DEMO_EPOCHS, run_demo

    root = Path(__file__).resolve().parents[1]
    assert not (root / "configs" / "demo.yaml").exists()
    shipped = resources.files("img2dmp").joinpath("configs", "demo.yaml")
    cfg = load_config(Path(str(shipped)))
    assert cfg.optim.epochs == DEMO_EPOCHS and cfg.model.encoder_layers == [512, 256, 64, 20]
    assert TrainConfig.from_dict(DEMO_CONFIG).to_dict() == cfg.to_dict()
    run_demo(tmp_path / "d", samples_per_digit=10, epochs=1, progress=False)
    import yaml

    used = yaml.safe_load((tmp_path / "d" / "run" / "config.yaml").read_text())
    for section in ("optim", "cost"):
        for key, value in DEMO_CONFIG[section].items():
            if key != "epochs":
                assert used[section][key] == value, (section, key)
    assert used["model"]["encoder_layers"] == DEMO_CONFIG["model"]["encoder_layers"]
    assert used["model"]["image_size"] == [40, 40]  # taken from the data


@pytest.mark.parametrize(
    "name",
    sorted(
        p.stem for p in (Path(__file__).resolve().parents[1] / "src/img2dmp/configs").glob("*.yaml")
    ),
)
def test_shipped_configs_load(name):
    # Every configuration in the package loads, by its name as --config NAME gives it.
    from img2dmp.train import load_config

    cfg = load_config(name)
    assert cfg.optim.epochs >= 1


def test_augmentation_moves_image_and_path_together_and_refits_targets(small_data):
    from img2dmp.dmp import DMPParams, rollout
    from img2dmp.train import _Augmenter

    a = load_dataset(small_data)
    cfg = tiny_config(small_data)
    cfg.data.augment = {"rotation_deg": [-8, 8], "translation_rel": [-0.05, 0.05]}
    cfg.cost.name = "parameter"
    norm = ParamNormaliser.fit(a.params, a.dmp_config)
    aug = _Augmenter(cfg.data.augment_ranges(), norm, a.dmp_config, refit=True)
    img = torch.as_tensor(a.images[:16])
    t = torch.as_tensor(a.times[:16])
    traj = torch.as_tensor(a.trajectories[:16])
    zt = norm.normalise(torch.as_tensor(a.params[:16], dtype=torch.float64)).float()
    img2, traj2, zt2 = aug(np.random.default_rng(0), img, t, traj, zt)
    assert (traj2 - traj).abs().amax(dim=(1, 2)).min() > 0.2  # every sample moved
    # the ink is still under the moved path: sample the moved images at the moved points
    h, w = img2.shape[-2:]
    xi = traj2[..., 0].round().long().clamp(0, w - 1)
    yi = traj2[..., 1].round().long().clamp(0, h - 1)
    on_ink = img2[torch.arange(16)[:, None], yi, xi] > 0.3
    assert on_ink.float().mean() > 0.9
    # the refitted targets roll out onto the moved paths, the old ones do not
    p2 = DMPParams.from_vector(norm.denormalise_vector(zt2.double()), 25, 2)
    err = (rollout(p2, t.double(), a.dmp_config) - traj2).norm(dim=-1).mean()
    p1 = DMPParams.from_vector(norm.denormalise_vector(zt.double()), 25, 2)
    err_old = (rollout(p1, t.double(), a.dmp_config) - traj2).norm(dim=-1).mean()
    assert err < 0.1 < err_old
    # reproducible from the generator's state
    again = aug(np.random.default_rng(0), img, t, traj, zt)
    torch.testing.assert_close(again[1], traj2)


def test_augmented_training_runs_and_bad_ranges_are_named(small_data, tmp_path, monkeypatch):
    cfg = tiny_config(small_data, epochs=2)
    cfg.data.augment = {"rotation_deg": [-3, 3], "scale": [0.97, 1.03]}
    res = train(cfg, tmp_path / "aug")
    assert len(res.history) == 2 and np.isfinite(res.best_val_error_px)
    meta = read_checkpoint_meta(tmp_path / "aug" / "checkpoints" / "best.json")
    assert meta["train_config"]["data"]["augment"]["rotation_deg"] == [-3, 3]
    assert 1.0 < meta["stroke_width_px"] < 6.0  # the training images' pen, in pixels
    # with the impulse filter, batches are filtered before they are warped (a warp would
    # smear the noise's exact 0 and 1 values past the filter's reach)
    from img2dmp.nn.model import ImpulseFilter
    from img2dmp.train import _Augmenter

    seen = []
    real_call = _Augmenter.__call__

    def spy(self, rng, images, *rest):
        seen.append(images.clone())
        return real_call(self, rng, images, *rest)

    monkeypatch.setattr(_Augmenter, "__call__", spy)
    cfg.model.input_filter = "impulse"
    train(cfg, tmp_path / "filtered", epochs=1)
    f, raw = ImpulseFilter(), torch.as_tensor(load_dataset(small_data).images[:64])
    assert float((f(raw) - raw).abs().max()) > 0.5  # the stored images carry impulses
    assert seen and all(float((f(b) - b).abs().max()) < 1e-3 for b in seen)
    for bad, match in (({"rotation": [0, 1]}, "unknown affine"), ({"scale": [-1, 1]}, "scale")):
        with pytest.raises(ValueError, match=f"data.augment.*{match}"):
            TrainConfig.from_dict({"data": {"augment": bad}})


def test_train_step_learns_its_batch_measures_it_and_refuses_a_nan_cost(small_data):
    from img2dmp.errors import TrainingDiverged
    from img2dmp.nn import Cost, trajectory_error_px
    from img2dmp.nn.costs import dmp_trajectory
    from img2dmp.training import train_step

    a = load_dataset(small_data).select_split("train")
    norm = ParamNormaliser.fit(a.params, a.dmp_config)
    images, times = torch.as_tensor(a.images[:32]), torch.as_tensor(a.times[:32])
    paths = torch.as_tensor(a.trajectories[:32])
    z_t = norm.normalise(torch.as_tensor(a.params[:32], dtype=torch.float64)).float()
    for name in ("parameter", "trajectory"):
        model = build_model(ModelConfig(**TINY_MODEL), seed=0)
        opt = torch.optim.Adam(model.parameters(), lr=2e-3)
        cost = Cost(name, norm, a.dmp_config)
        with torch.no_grad():  # the error it reports is that of the batch before the step
            expected = trajectory_error_px(
                dmp_trajectory(model(images), times, norm, a.dmp_config), paths
            )
        first = train_step(model, opt, cost, images, times, paths, z_t)
        torch.testing.assert_close(first.error_px, expected, rtol=1e-5, atol=1e-6)
        assert first.error_px.shape == (32,)
        for _ in range(60):
            last = train_step(model, opt, cost, images, times, paths, z_t, grad_clip=10.0)
        assert last.cost < 0.6 * first.cost, name
        assert float(last.error_px.mean()) < float(first.error_px.mean()), name
    before = {k: v.clone() for k, v in model.state_dict().items()}
    bad = images.clone()
    bad[0, 0, 0] = float("nan")
    with pytest.raises(TrainingDiverged, match="training cost is nan"):
        train_step(model, opt, cost, bad, times, paths, z_t)
    assert all(torch.equal(before[k], v) for k, v in model.state_dict().items())


def test_image_size_comes_from_the_data_and_the_config_is_not_changed(tmp_path, capsys):
    from img2dmp.data.synthetic import SyntheticConfig

    data = tmp_path / "d28.safetensors"
    gen = SyntheticConfig(image_size=(28, 28), digits=(1, 7))
    save_dataset(data, generate_dataset(20, gen, seed=1, progress=False))
    cfg = TrainConfig.from_dict(
        {
            "model": {"encoder_layers": [32, 20], "decoder_layers": [35]},
            "data": {"path": str(data)},
            "optim": {"epochs": 2, "batch_size": 8},
            "threads": 1,
        }
    )
    before = cfg.to_dict()
    res = train(cfg, tmp_path / "run")
    assert cfg.to_dict() == before and cfg.model.image_size is None  # the caller's config
    assert Predictor.load(tmp_path / "run").image_size == (28, 28)
    # Not a terminal: one plain line per epoch on stderr, no bar redrawn with "\r".
    err = capsys.readouterr().err
    epoch_lines = [ln for ln in err.splitlines() if ln.startswith("epoch ")]
    assert len(epoch_lines) == res.epochs_run == 2 and "\r" not in err
    cfg.model.image_size = [40, 40]
    with pytest.raises(ValueError, match=r"\[28, 28\] pixels but model.image_size is \[40, 40\]"):
        train(cfg, tmp_path / "run2")


def test_too_few_to_train_says_the_splits_the_hold_out_and_what_to_do(small_data, tmp_path):
    full = load_dataset(small_data)
    two = tmp_path / "two.safetensors"
    rows = np.flatnonzero(full.split == 0)[:2]
    save_dataset(two, full.subset(rows))  # train 2, validation 0, test 0
    with pytest.raises(ValueError) as e:
        train(tiny_config(two), tmp_path / "run")
    said = str(e.value)
    assert "has 1 sample(s) to train on (train 2, validation 0, test 0; with no " in said
    assert "1 of the training split is held out to validate on: data.val_fraction = 0.1" in said
    assert "--val-fraction" in said and "data.train_on_validation=true" in said
    one_each = full.subset(np.r_[rows[:1], np.flatnonzero(full.split == 1)[:1]])
    save_dataset(two, one_each)  # train 1, validation 1: nothing held out
    with pytest.raises(ValueError) as e:
        train(tiny_config(two), tmp_path / "run")
    said = str(e.value)
    assert "has 1 sample(s) to train on (train 1, validation 1, test 0); need at least 2" in said
    assert "held out" not in said and "train on the validation split too" in said
    cfg = tiny_config(two, patience=0, epochs=1)
    cfg.data.train_on_validation = True  # the remedy it names trains
    assert train(cfg, tmp_path / "run").epochs_run == 1


def test_a_diverging_run_ends_with_one_line_and_exit_2(small_data, tmp_path, capsys):
    args = ["train", "--data", str(small_data), "--run-dir", str(tmp_path / "run")]
    args += ["--epochs", "3", "--no-progress", "--set", "optim.lr=1e30", "threads=1"]
    args += ["optim.batch_size=16", f"model.encoder_layers={TINY_MODEL['encoder_layers']}"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "training diverged" in err[0] and "optim.lr" in err[0], err
    assert "Traceback" not in "\n".join(err)
    # it says truthfully whether an earlier epoch's checkpoint exists
    best = tmp_path / "run" / "checkpoints" / "best.safetensors"
    assert ("is kept" in err[0]) == best.is_file()


@pytest.mark.parametrize(
    ("every", "drawn"), [(1, [0, 1, 2, 3]), (2, [0, 0, 2, 2]), (0, [0, 0, 0, 0])]
)
def test_generator_refreshes_its_samples_every_k_epochs(every, drawn):
    from img2dmp.training.data import TrainingData

    data = {"samples_per_epoch": 12, "val_samples": 8, "refresh_epochs": every}
    cfg = TrainConfig.from_dict({"model": dict(TINY_MODEL), "data": data, "progress": False})
    td = TrainingData(cfg)
    epochs = [td.train_for_epoch(e).images for e in range(4)]
    # the same draw gives the same images, a new draw different ones; a fresh object
    # (a resumed run) sees for epoch 3 what the first one saw
    for e in range(1, 4):
        assert bool(torch.equal(epochs[e], epochs[e - 1])) == (drawn[e] == drawn[e - 1])
    assert torch.equal(TrainingData(cfg).train_for_epoch(3).images, epochs[3])
    with pytest.raises(ValueError, match="data.refresh_epochs must be >= 0, got -1"):
        TrainConfig.from_dict({"data": {"refresh_epochs": -1}})


def test_train_on_validation_trains_on_both_splits_and_keeps_the_last_epoch(
    small_data, tmp_path, capsys
):
    """The final model's option: the validation rows join the training rows, every epoch is
    ``best`` (the last is kept, whatever its validation error), evaluate says the figures
    on the validation split are not a test; the settings that would choose by the
    validation error are refused by name."""
    from img2dmp.config import ConfigError
    from img2dmp.training.data import _split_indices

    a = load_dataset(small_data)
    plain = tiny_config(small_data)
    both = tiny_config(small_data)
    both.data.train_on_validation = True
    train_idx, val_idx = _split_indices(a, plain)
    all_idx, val_again = _split_indices(a, both)
    assert np.array_equal(val_again, val_idx)
    assert np.array_equal(all_idx, np.union1d(train_idx, val_idx))
    assert len(all_idx) == len(train_idx) + len(val_idx) > len(train_idx)

    from types import SimpleNamespace

    from img2dmp.training.state import RunState

    s = SimpleNamespace(best_error_px=1.0, best_epoch=0, bad_epochs=0)
    assert RunState.observe(s, 2.0, 1, last_is_best=True) and s.best_epoch == 1
    assert not RunState.observe(s, 3.0, 2) and s.best_epoch == 1 and s.bad_epochs == 1

    run = tmp_path / "final"
    cfg = tiny_config(small_data, epochs=4, lr=2e-2)
    cfg.data.train_on_validation = True
    cfg.progress = True
    result = train(cfg, run)
    epochs = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("epoch ")]
    assert len(epochs) == 4 and all("validation (trained on)" in ln for ln in epochs), epochs
    assert result.best_epoch == 3 == result.epochs_run - 1
    best = read_checkpoint_meta(run / "checkpoints" / "best.safetensors")
    assert best["epoch"] == 3 and best["train_config"]["data"]["train_on_validation"] is True
    ev_val = evaluate(run, small_data, split="validation")
    ev_test = evaluate(run, small_data, split="test")
    assert ev_val["trained_on_split"] is True and ev_test["trained_on_split"] is False
    ev_plain = evaluate(run / "checkpoints" / "best.safetensors", small_data, split="train")
    assert ev_plain["trained_on_split"] is True

    out = tmp_path / "ev"
    code = cli.main(["evaluate", "--model", str(run), "--data", str(small_data),
                     "--split", "validation", "--out", str(out), "--figures", "0"])  # fmt: skip
    assert code == 0

    for bad, msg in (
        ({"optim": {"patience": 5}}, "set optim.patience to 0"),
        ({"optim": {"patience": 0, "schedule": "plateau"}}, "'plateau' schedule"),
        ({"data": {"path": None}}, "set data.path"),
        ({"data": {"train_on_validation": "yes"}}, "must be true or false, got 'yes'"),
    ):
        d = tiny_config(small_data).to_dict()
        d["data"]["train_on_validation"] = True
        for section, values in bad.items():
            d[section].update(values)
        with pytest.raises(ConfigError, match=msg):
            TrainConfig.from_dict(d)

    no_val = tmp_path / "no_val.safetensors"
    save_dataset(no_val, a.subset(a.split != 1))
    with pytest.raises(ConfigError, match=r"no_val.safetensors has no validation split"):
        cfg = tiny_config(no_val)
        cfg.data.train_on_validation = True
        _split_indices(load_dataset(no_val), cfg)


def test_evaluate_notes_a_split_the_model_trained_on(small_data, trained, capsys, tmp_path):
    _, run, _ = trained
    for split, seen in (("validation", False), ("train", True), ("test", False)):
        code = cli.main(["evaluate", "--model", str(run), "--data", str(small_data), "--split",
                         split, "--out", str(tmp_path / split), "--figures", "0"])  # fmt: skip
        assert code == 0
        assert ("not a test" in capsys.readouterr().out) is seen, split


def test_max_samples_takes_fewer_epochs_on_more_data_and_the_run_records_them(
    small_data, tmp_path, capsys
):
    """``optim.max_samples`` bounds epochs x training samples: a fresh run whose epochs
    would pass it takes fewer (said on stderr, written to config.yaml and the checkpoint,
    the cosine schedule ending there), one within it is untouched, and a resumed run
    keeps the epochs its start chose."""
    from img2dmp.config import ConfigError

    n = len(load_dataset(small_data).select_split("train").labels)
    cfg = tiny_config(small_data, epochs=6, schedule="cosine", max_samples=2 * n + n // 2)
    res = train(cfg, tmp_path / "few")
    err = capsys.readouterr().err
    assert f"6 epochs of {n} training samples would pass optim.max_samples" in err
    assert "training 2 epochs" in err
    assert res.epochs_run == 2
    stored = yaml.safe_load((tmp_path / "few" / "config.yaml").read_text())["optim"]
    assert stored["epochs"] == 2 and stored["max_samples"] == 2 * n + n // 2
    lr = [row["lr"] for row in read_metrics_csv(tmp_path / "few" / "metrics.csv")]
    assert lr[-1] < 0.6 * lr[0]  # half-way down a cosine of 2 epochs (of 6: 0.93)
    meta = read_checkpoint_meta(tmp_path / "few" / "checkpoints" / "last.safetensors")
    assert meta["train_config"]["optim"]["epochs"] == 2
    resumed = train(cfg, tmp_path / "few", resume=True)
    assert resumed.epochs_run == 2  # nothing left to do
    assert "would pass" not in capsys.readouterr().err

    roomy = tiny_config(small_data, epochs=3, max_samples=3 * n)
    assert train(roomy, tmp_path / "all").epochs_run == 3
    assert "would pass" not in capsys.readouterr().err
    one = tiny_config(small_data, epochs=3, max_samples=1)
    assert train(one, tmp_path / "one").epochs_run == 1
    for bad, msg in ((-1, "optim.max_samples must be >= 0, got -1"),
                     (2.5, "optim.max_samples must be a number")):  # fmt: skip
        with pytest.raises(ConfigError, match=msg):
            tiny_config(small_data, max_samples=bad)
