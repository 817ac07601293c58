"""Packaging: configurations shipped inside the package and named by --config NAME, the
package data and metadata (torch a range, extras, license, citation), and --device."""

from __future__ import annotations

import fnmatch
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from img2dmp import cli
from img2dmp.commands import _args
from img2dmp.config import ConfigError, parse_yaml, read_config_file, shipped_configs
from img2dmp.nn.device import place_model, resolve_device
from img2dmp.train import load_config

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "img2dmp"
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
NO_GPU = "no CUDA GPU on this machine"


def _one_error_line(err: str, command: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"img2dmp {command}: error: "), err
    return lines[0]


# --- configurations by name -----------------------------------------------------------


def test_every_configuration_ships_in_the_package_and_loads_by_name(tmp_path, monkeypatch):
    names = shipped_configs()
    expected = {"paper", "conv", "conv-wide", "generator", "mnist", "mnist-conv", "real", "demo"}
    assert expected <= set(names)
    assert not (ROOT / "configs").exists()  # one home: src/img2dmp/configs
    assert _args.shipped_config_names() == names  # the --help list, without YAML
    monkeypatch.chdir(tmp_path)  # a name works from any folder
    for name in names:
        path = Path(str(resources.files("img2dmp").joinpath("configs", f"{name}.yaml")))
        assert read_config_file(name) == parse_yaml(path.read_text()), name
        assert load_config(name).to_dict() == load_config(path).to_dict(), name
    assert load_config("paper").model.encoder_layers == [1500, 1300, 1000, 600, 200, 20]


def test_a_file_is_still_a_file_and_a_wrong_name_says_which_exist(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.yaml").write_text("optim: {epochs: 3}\n")
    assert load_config("mine.yaml").optim.epochs == 3
    with pytest.raises(ConfigError, match="no shipped configuration named 'papr'.*paper"):
        load_config("papr")
    with pytest.raises(FileNotFoundError, match="ships with img2dmp: --config paper"):
        load_config("configs/paper.yaml")  # where it used to be


def test_train_refuses_an_unknown_configuration_name_in_one_line(tmp_path, capsys):
    argv = ["train", "--config", "no-such", "--run-dir", str(tmp_path / "r"), "--epochs", "1"]
    assert cli.main(argv) == 2
    line = _one_error_line(capsys.readouterr().err, "train")
    assert "no shipped configuration named 'no-such'" in line and "conv-wide" in line


# --- package data and metadata --------------------------------------------------------


def test_package_data_covers_the_configurations_and_py_typed():
    globs = PYPROJECT["tool"]["setuptools"]["package-data"]["img2dmp"]
    assert "py.typed" in globs
    files = [p.relative_to(PACKAGE).as_posix() for p in (PACKAGE / "configs").iterdir()]
    assert files and all(any(fnmatch.fnmatch(f, g) for g in globs) for f in files), files


def test_torch_is_a_range_and_the_set_up_pins_the_cpu_build_first():
    deps = PYPROJECT["project"]["dependencies"]
    (torch_dep,) = [d for d in deps if d.replace(" ", "").startswith("torch")]
    assert "==" not in torch_dep and ">=" in torch_dep and "<3" in torch_dep
    extras = PYPROJECT["project"]["optional-dependencies"]
    assert {d.split(">")[0] for d in extras["export"]} == {"onnx", "onnxruntime", "onnxscript"}
    make = (ROOT / "Makefile").read_text()
    pin = make.index("pip install --quiet torch==$(TORCH)")
    assert "TORCH  ?= 2.13.0" in make
    assert pin < make.index("pip install --quiet -e '.[dev,robot,export,web,interop,bench]'")
    # The peers' extras are pinned to the versions the bridges are tested against, and
    # none of them brings a torch of its own.
    for extra in ("interop", "bench"):
        assert (
            "movement-primitives==0.9.1" in extras[extra] and "mp-pytorch==0.1.4" in extras[extra]
        )
        assert not any(d.startswith("torch") and "diffeq" not in d for d in extras[extra])


def test_license_and_citation():
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "the img2dmp authors" in text
    assert PYPROJECT["project"]["license"] == "MIT"
    assert PYPROJECT["project"]["license-files"] == ["LICENSE"]
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert cff["version"] == PYPROJECT["project"]["version"]
    paper = cff["preferred-citation"]
    assert paper["type"] == "conference-paper" and paper["year"] == 2018
    assert [a["family-names"] for a in paper["authors"]] == ["Pahič", "Gams", "Ude", "Morimoto"]
    changes = (ROOT / "CHANGELOG.md").read_text()
    assert f"## [{PYPROJECT['project']['version']}]" in changes


# --- --device -------------------------------------------------------------------------


def test_device_is_checked_when_read_and_cpu_is_the_default(capsys):
    for command in ("train", "evaluate", "predict"):
        assert cli.main([command, "--help"]) == 0
        assert "--device DEVICE" in capsys.readouterr().out
    assert cli.build_parser().parse_args(["train"]).device == "cpu"
    assert cli.main(["train", "--device", "tpu"]) == 2
    assert "must be cpu, cuda or cuda:N" in capsys.readouterr().err
    assert resolve_device("cpu") == torch.device("cpu")
    model = torch.nn.Linear(2, 2)
    assert place_model(model, "cpu") is model and not model._forward_hooks


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA GPU")
def test_a_missing_gpu_is_one_error_line(tmp_path, capsys):
    with pytest.raises(ValueError, match="no CUDA GPU"):
        resolve_device("cuda")
    image = tmp_path / "x.png"
    argv = ["predict", "--model", str(tmp_path), str(image), "--device", "cuda"]
    from PIL import Image

    Image.fromarray(np.zeros((8, 8), np.uint8)).save(image)
    assert cli.main(argv) == 2
    assert "no CUDA GPU" in _one_error_line(capsys.readouterr().err, "predict")
    assert cli.main(["train", "--run-dir", str(tmp_path / "r"), "--device", "cuda"]) == 2
    assert "no CUDA GPU" in _one_error_line(capsys.readouterr().err, "train")


@pytest.mark.skipif(not torch.cuda.is_available(), reason=NO_GPU)
def test_training_and_prediction_on_the_gpu_match_the_cpu(tmp_path):
    from img2dmp.data.store import save_dataset
    from img2dmp.data.synthetic import generate_dataset
    from img2dmp.predict import Predictor
    from img2dmp.train import TrainConfig, train

    data = tmp_path / "d.safetensors"
    save_dataset(data, generate_dataset(6, seed=1, progress=False))
    cfg = TrainConfig.from_dict(
        {
            "model": {"encoder_layers": [32, 20], "decoder_layers": [16]},
            "data": {"path": str(data)},
            "optim": {"epochs": 2, "batch_size": 16},
            "progress": False,
        }
    )
    res = train(cfg, tmp_path / "run", device="cuda")
    assert np.isfinite(res.best_val_error_px)
    images = np.random.default_rng(0).uniform(0, 1, (5, 40, 40)).astype(np.float32)
    on_gpu = Predictor.load(tmp_path / "run", device="cuda")
    assert next(on_gpu.model.parameters()).is_cuda
    gpu = on_gpu.predict_images(images).to_vector()
    cpu = Predictor.load(tmp_path / "run").predict_images(images).to_vector()
    assert np.allclose(gpu, cpu, rtol=1e-4, atol=1e-3)
    assert train(cfg, tmp_path / "run", resume=True, epochs=3, device="cpu").epochs_run == 3
