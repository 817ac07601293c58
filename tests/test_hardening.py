"""Issue 31 ("Hardening, third round") at the command line and in the library.

Links are never followed where img2dmp writes (lock files, temporaries); configurations,
JSON files and ``--set`` values are read bounded in depth and size (aliases counted, not
expanded) and strict (a key twice, a 5,000-digit number); the sizes that decide memory are
bounded by field; no output may be an input; DMP files whose movement is not finite are
refused when read; workers leave Ctrl-C to their parent; and the smaller ones (a 1 x 1
data set, NaN in a float image, a directory given as an image, tau = 1e300). Every
failure is exit status 2 and one line naming the input, and nothing else on disk changes.
The web server's cases are in ``test_web_api.py`` and ``test_web_browser.py``.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from img2dmp import _files, cli
from img2dmp._files import lock_directory, parse_json
from img2dmp.config import ConfigError, read_config_file
from img2dmp.data.store import load_dataset, save_dataset
from img2dmp.data.synthetic import SyntheticConfig, generate_dataset

SRC = str(Path(__file__).resolve().parents[1] / "src")
ENV = dict(os.environ, PYTHONPATH=SRC, OMP_NUM_THREADS="1")
#: A network and optimiser small enough that an epoch of 6 samples takes milliseconds.
TINY = [
    "threads=1",
    "optim.batch_size=4",
    "model.encoder_layers=[16, 8]",
    "model.decoder_layers=[8]",
]


def _fails(capsys, argv: list[str], *names: str) -> str:
    """Run a command that must fail: exit status 2, one line ``img2dmp COMMAND: error:``
    naming each of ``names``; the line."""
    capsys.readouterr()
    assert cli.main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"img2dmp {argv[0]}: error: "), err
    for name in names:
        assert str(name) in lines[0], (name, lines[0])
    return lines[0]


def _tree(root: Path) -> dict:
    """Everything under ``root``: file -> bytes, link -> its target, folder -> None, other
    kinds -> their mode (links are not followed, FIFOs not opened)."""
    out = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            p = Path(folder, name)
            rel = str(p.relative_to(root))
            if p.is_symlink():
                out[rel] = ("link", os.readlink(p))
            elif p.is_dir():
                out[rel] = None
            elif p.is_file():
                out[rel] = p.read_bytes()
            else:  # a FIFO: never opened
                out[rel] = ("special", p.lstat().st_mode)
    return out


def _train_argv(data, run_dir, *extra) -> list[str]:
    argv = ["train", "--data", str(data), "--run-dir", str(run_dir), "--no-progress"]
    for setting in TINY:
        argv += ["--set", setting]
    return [*argv, *extra]


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("hardening")


@pytest.fixture(scope="module")
def data(work) -> Path:
    """Six synthetic digits (2 and 3)."""
    path = work / "d.safetensors"
    save_dataset(path, generate_dataset(3, SyntheticConfig(digits=(2, 3)), seed=0, progress=False))
    return path


@pytest.fixture(scope="module")
def model(work, data) -> Path:
    """A run directory of a tiny network trained for one epoch."""
    run = work / "model"
    assert cli.main(_train_argv(data, run, "--epochs", "1")) == 0
    return run


@pytest.fixture
def inside(tmp_path, data) -> Path:
    """A folder holding a copy of the data set, for the tests that snapshot a folder."""
    (tmp_path / "d.safetensors").write_bytes(data.read_bytes())
    return tmp_path


def _dmp_doc(data: Path) -> dict:
    """The version-2 document of the data set's first DMP."""
    from img2dmp.data.dmpfile import dmp_document
    from img2dmp.dmp import DMPParams

    d = load_dataset(data)
    cfg = d.dmp_config
    params = DMPParams.from_vector(np.asarray(d.params[0], float), cfg.n_kernels, cfg.n_dims)
    return dmp_document(params, cfg, d.images.shape[1:])


# --- links: lock files and temporaries -----------------------------------------------------


@pytest.mark.parametrize("force", [[], ["--force"]])
def test_a_lock_file_link_is_never_followed(inside, capsys, force):
    """``train --run-dir R`` where ``R/.lock`` links to a file truncated it and wrote a pid
    into it, with or without --force."""
    victim = inside / "victim.txt"
    victim.write_text("precious\n")
    run = inside / "run"
    run.mkdir()
    (run / ".lock").symlink_to(victim)
    before = _tree(inside)
    line = _fails(capsys, _train_argv(inside / "d.safetensors", run, *force), run / ".lock")
    assert "symbolic link" in line
    assert _tree(inside) == before


def test_a_dangling_lock_link_creates_no_file_elsewhere(inside, capsys):
    outside = inside / "elsewhere" / "created.txt"
    outside.parent.mkdir()
    run = inside / "run"
    run.mkdir()
    (run / ".lock").symlink_to(outside)
    before = _tree(inside)
    _fails(capsys, _train_argv(inside / "d.safetensors", run), run / ".lock", "symbolic link")
    assert not outside.exists() and _tree(inside) == before


@pytest.mark.parametrize("kind", ["link", "dangling link", "hard link", "fifo", "directory"])
def test_the_lock_opener_takes_only_its_own_regular_file(tmp_path, kind):
    """:func:`img2dmp._files.lock_directory` (run directories) and the recordings' lock
    share one opener: whatever sits at ``.lock`` that is not a file of its own is refused,
    and what it points to is left as it was."""
    from img2dmp.web.recordings import Recordings

    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    folder = tmp_path / "folder"
    folder.mkdir()
    lock = folder / ".lock"
    if kind == "link":
        lock.symlink_to(victim)
    elif kind == "dangling link":
        lock.symlink_to(tmp_path / "created.txt")
    elif kind == "hard link":
        os.link(victim, lock)
    elif kind == "fifo":
        os.mkfifo(lock)
    else:
        lock.mkdir()
    before = _tree(tmp_path)
    why = {
        "link": "symbolic link",
        "dangling link": "symbolic link",
        "hard link": "hard link",
        "fifo": "not a regular file",
        "directory": "Is a directory",
    }[kind]
    with pytest.raises(OSError, match=why) as e, lock_directory(folder, "run directory"):
        pass
    assert str(lock) in str(e.value)
    with pytest.raises(OSError, match=why):
        Recordings(folder)
    assert _tree(tmp_path) == before


def test_writers_never_write_through_a_planted_temporary(tmp_path):
    """The IDX writer and the rollout's table cache wrote to predictable temporary names
    (``NAME.tmp``, ``NAME.PID.tmp``): a link planted there was followed."""
    from img2dmp.data.mnist import read_idx, write_idx
    from img2dmp.dmp import _table as table_module  # the rollout's table cache

    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    (tmp_path / "x.idx.tmp").symlink_to(victim)
    write_idx(tmp_path / "x.idx", np.arange(4, dtype=np.uint8).reshape(2, 2))
    assert np.array_equal(read_idx(tmp_path / "x.idx"), [[0, 1], [2, 3]])
    (tmp_path / "y.idx").symlink_to(victim)  # the output itself a link: replaced, not followed
    write_idx(tmp_path / "y.idx", np.zeros((2, 2), np.uint8))
    assert not (tmp_path / "y.idx").is_symlink()
    table = tmp_path / "dmp_responses_abc_def.npy"
    Path(f"{table}.{os.getpid()}.tmp").symlink_to(victim)
    table_module._save_table(str(table), np.ones(3))
    assert np.array_equal(np.load(table), np.ones(3))
    assert victim.read_text() == "precious\n"


# --- bounded parsing: depth, aliases, numbers, duplicate keys ------------------------------


def _nested(suffix: str, depth: int) -> str:
    value = "[" * depth + "]" * depth
    return {"toml": f"a = {value}\n", "json": f'{{"a": {value}}}\n'}.get(suffix, f"a: {value}\n")


@pytest.mark.parametrize("depth", [3000, 5000])
@pytest.mark.parametrize("suffix", ["yaml", "toml", "json"])
def test_deeply_nested_configurations_are_one_line(inside, capsys, suffix, depth):
    config = inside / f"deep.{suffix}"
    config.write_text(_nested(suffix, depth))
    before = _tree(inside)
    line = _fails(
        capsys, _train_argv(inside / "d.safetensors", inside / "run", "--config", config), config
    )
    assert "nested" in line
    line = _fails(capsys, ["generate", "--out", inside / "g.safetensors", "--config", config])
    assert "nested" in line and str(config) in line
    assert _tree(inside) == before


def test_a_deeply_nested_set_value_is_one_line(inside, capsys):
    before = _tree(inside)
    deep = "[" * 4000 + "]" * 4000
    argv = _train_argv(inside / "d.safetensors", inside / "run", "--set", f"model.x={deep}")
    line = _fails(capsys, argv, "model.x")
    assert "nested" in line and len(line) < 300
    assert _tree(inside) == before


def _alias_bomb(levels: int = 9, fan: int = 9) -> str:
    """A configuration whose ``data.generator`` holds ``levels`` anchors, each ``fan``
    aliases of the one before (``fan ** levels`` values once expanded, from a few hundred
    bytes), and whose ``seed`` is the last of them."""
    lines = ["data:", "  generator:", f"    a0: &a0 [{', '.join(['x'] * fan)}]"]
    for i in range(1, levels + 1):
        lines.append(f"    a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * fan)}]")
    return "\n".join(lines) + f"\nseed: *a{levels}\n"


@pytest.mark.parametrize("where", ["file", "set"])
def test_a_yaml_alias_bomb_is_refused_without_expanding_it(tmp_path, data, where):
    """Nine levels of nine aliases: the old reader ran for over a minute, growing, as the
    error message printed the expanded value. A process of its own, so that a regression
    fails by its time-out instead of filling the machine's memory."""
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(_alias_bomb())
    anchors = [f"&b0 [{', '.join(['1'] * 9)}]"]
    anchors += [f"&b{i} [{', '.join([f'*b{i - 1}'] * 9)}]" for i in range(1, 10)]
    flow = f"[{', '.join(anchors)}, *b9]"  # the same bomb as one --set value
    extra = ["--config", str(bomb)] if where == "file" else ["--set", f"seed={flow}"]
    argv = _train_argv(data, tmp_path / "run", *extra)
    proc = subprocess.run(
        [sys.executable, "-m", "img2dmp", *argv],
        env=ENV,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    line = proc.stderr.strip()
    assert line.startswith("img2dmp train: error: ") and "\n" not in line
    assert "100,000 values" in line and "aliases" in line
    assert (str(bomb) if where == "file" else "'seed'") in line
    assert not (tmp_path / "run").exists()


def test_an_error_never_prints_a_whole_value(inside, capsys):
    """A value within the bounds (four levels of nine aliases: 6,561 values), or a long
    text, is cut in the message and its size named."""
    config = inside / "aliases.yaml"
    config.write_text(_alias_bomb(levels=3))
    before = _tree(inside)
    line = _fails(
        capsys,
        _train_argv(inside / "d.safetensors", inside / "run", "--config", config),
        "seed",
        "list of 9 items",
    )
    assert len(line) < 300
    argv = _train_argv(inside / "d.safetensors", inside / "run", "--set", "seed=" + "x" * 100_000)
    line = _fails(capsys, argv, "seed", "100,000 characters")
    assert len(line) < 300
    assert _tree(inside) == before


def test_a_key_twice_is_refused_but_anchors_merges_and_json_still_read(tmp_path):
    """The bounds and the duplicate-key check leave ordinary configurations alone:
    anchors, merge keys (whose keys are given twice on purpose) and JSON."""
    (tmp_path / "a.yaml").write_text(
        "base: &base {lr: 0.01, batch_size: 8}\noptim:\n  <<: *base\n  lr: 0.02\nlayers: *base\n"
    )
    d = read_config_file(tmp_path / "a.yaml")
    assert d["optim"] == {"lr": 0.02, "batch_size": 8} and d["layers"]["batch_size"] == 8
    (tmp_path / "b.json").write_text('{"optim": {"lr": 1e-3, "epochs": 12345678901234567890}}')
    assert read_config_file(tmp_path / "b.json")["optim"]["epochs"] == 12345678901234567890
    (tmp_path / "c.yaml").write_text("a: 1\nb: 2\na: 3\n")
    with pytest.raises(ConfigError, match=r"c\.yaml cannot be parsed: key 'a' is given twice"):
        read_config_file(tmp_path / "c.yaml")


@pytest.mark.parametrize(
    "name, text",
    [
        ("dup.json", '{"seed": 1, "optim": {"lr": 0.1}, "seed": 2}'),
        ("dup.yaml", "seed: 1\noptim:\n  lr: 0.1\n  lr: 0.2\n"),
        ("big.json", '{"seed": ' + "9" * 5000 + "}"),
        ("big.yaml", "seed: " + "9" * 5000 + "\n"),
        ("big.toml", "seed = " + "9" * 5000 + "\n"),
    ],
)
def test_duplicate_keys_and_huge_numbers_in_a_configuration_are_named(inside, capsys, name, text):
    config = inside / name
    config.write_text(text)
    before = _tree(inside)
    line = _fails(
        capsys, _train_argv(inside / "d.safetensors", inside / "run", "--config", config), config
    )
    assert ("twice" in line) if name.startswith("dup") else ("5,000 digits" in line)
    assert _tree(inside) == before


@pytest.mark.parametrize("kind", ["a key twice in params", "a key twice on top", "5,000 digits"])
def test_dmp_files_with_duplicate_keys_or_huge_numbers_are_named(tmp_path, data, kind):
    """Python's json keeps the last of two keys silently; a 5,000-digit number raised
    Python's integer-conversion limit without naming the file."""
    from img2dmp.data.dmpfile import read_dmp_file

    doc = _dmp_doc(data)
    text = json.dumps(doc)
    tau = f'"tau": {json.dumps(doc["params"]["tau"])}'
    if kind == "a key twice in params":
        text, want = text.replace(tau, f'"tau": 2.5, {tau}'), "key 'tau' appears twice"
    elif kind == "a key twice on top":
        text, want = text[:-1] + ', "image_size": [1, 1]}', "key 'image_size' appears twice"
    else:
        text, want = text.replace(tau, '"tau": 1' + "0" * 4999), "5,000 digits"
    path = tmp_path / "x_dmp.json"
    path.write_text(text)
    with pytest.raises(ValueError, match=f"^{re.escape(str(path))}: .*{want}"):
        read_dmp_file(path)


def test_the_one_json_reader_names_where(tmp_path):
    with pytest.raises(ValueError, match=r"^f\.json: key 'a' appears twice"):
        parse_json('{"a": 1, "b": {"c": 2}, "a": 3}', "f.json")
    with pytest.raises(ValueError, match=r"^f\.json: .*5,000 digits"):
        parse_json("[" + "7" * 5000 + "]", "f.json")
    same_key_elsewhere = {"a": [1, 2.5, -3], "b": {"a": 1}}
    assert parse_json(json.dumps(same_key_elsewhere), "f") == same_key_elsewhere


# --- sizes that decide memory ---------------------------------------------------------------


@pytest.mark.parametrize(
    "setting, field",
    [
        ("model.encoder_layers=[100000000]", "model.encoder_layers"),
        ("model.decoder_layers=[100000, 100000]", "model.decoder_layers"),
        ("model.hypotheses=100000", "model.hypotheses"),
        ("model.encoder_layers=[" + ", ".join(["8"] * 1000) + "]", "model.encoder_layers"),
        ("model.conv_channels=[20000, 20000]", "model.conv_channels"),
        ("data.samples_per_epoch=1000000000", "data.samples_per_epoch"),
    ],
    ids=[
        "wide encoder",
        "wide decoder",
        "hypotheses",
        "a thousand layers",
        "wide conv",
        "generated samples",
    ],
)
def test_sizes_that_decide_memory_are_bounded_by_field(inside, capsys, setting, field):
    before = _tree(inside)
    extra = ["--set", "model.encoder=conv"] if "conv" in setting else []
    argv = _train_argv(inside / "d.safetensors", inside / "run", *extra, "--set", setting)
    t0 = time.monotonic()
    _fails(capsys, argv, field)
    assert time.monotonic() - t0 < 20  # refused, not allocated
    assert _tree(inside) == before


def test_the_python_api_bounds_them_too():
    from img2dmp.nn import build_model
    from img2dmp.nn.model import MAX_WEIGHTS, ModelConfig
    from img2dmp.training import TrainConfig
    from img2dmp.training.config import machine_cores

    with pytest.raises(ValueError, match=r"model\.encoder_layers .* at most 50,000,000"):
        ModelConfig(encoder_layers=[100_000_000])
    with pytest.raises(ValueError, match=r"model\.hypotheses must be an integer from 1 to 64"):
        ModelConfig(hypotheses=100_000)
    cores = machine_cores()
    with pytest.raises(ConfigError, match=rf"threads must be at most this machine's {cores}"):
        TrainConfig.from_dict({"threads": 100_000})
    cfg = ModelConfig(encoder_layers=[4000, 20], image_size=[40, 40])  # 6.5 M: allowed here
    cfg.image_size = [400, 400]  # ... and 640 M at the data's size: build_model checks again
    with pytest.raises(ValueError, match=f"at most {MAX_WEIGHTS:,}"):
        build_model(cfg)


def test_generate_starts_at_most_a_worker_per_core(tmp_path, capsys):
    """--workers 100000 started a process per chunk of the data, up to that many."""
    from img2dmp._processes import machine_cores

    argv = ["generate", "--out", tmp_path / "g.safetensors", "--per-digit", "2", "--workers",
            "100000"]  # fmt: skip
    line = _fails(capsys, argv, "--workers", f"from 1 to {machine_cores()}", "100000")
    assert line.endswith("(see 'img2dmp generate --help')") and not any(tmp_path.iterdir())


def test_a_hundred_thousand_threads_are_one_line(tmp_path, data):
    """torch.set_num_threads(100000) ended in a segmentation fault: a process of its own."""
    argv = _train_argv(data, tmp_path / "run", "--set", "threads=100000")
    proc = subprocess.run(
        [sys.executable, "-m", "img2dmp", *argv],
        env=ENV,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.startswith("img2dmp train: error: threads must be at most this machine")
    assert len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()


# --- no output may be an input -------------------------------------------------------------


def _png(path: Path, seed: int = 0) -> Path:
    from PIL import Image

    a = np.full((40, 40), 255, np.uint8)
    a[8:32, 17 + seed : 21 + seed] = 0
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(a).save(path)
    return path


def _letters(root: Path) -> Path:
    """An import source: classes L and T, two images each with their pen paths."""
    for c in "LT":
        for k in range(2):
            _png(root / c / f"00{k}.png", k)
            xy = np.c_[np.full(20, 19.0 + k), np.linspace(8, 31, 20), np.linspace(0, 1, 20)]
            np.savetxt(root / c / f"00{k}.csv", xy, delimiter=",", header="x,y,t", comments="")
    return root


def test_preview_never_turns_its_data_set_into_a_picture(inside, capsys):
    before = _tree(inside)
    d = inside / "d.safetensors"
    _fails(capsys, ["preview", "--data", d, "--out", d, "--force"], d, "data set", "reads")
    _fails(
        capsys,
        ["preview", "--data", d, "--out", inside / "." / "d.safetensors", "--force"],
        "data set",
    )
    assert _tree(inside) == before


@pytest.mark.parametrize("out", ["letters/L/000.png", "letters/new.safetensors", "letters"])
def test_import_never_writes_into_its_source(tmp_path, capsys, out):
    source = _letters(tmp_path / "letters")
    before = _tree(tmp_path)
    line = _fails(
        capsys,
        ["import", source, "--out", tmp_path / out, "--force", "--no-progress"],
        "source",
        source,
    )
    assert "lies inside the source" in line or "is the source itself" in line
    assert _tree(tmp_path) == before


def test_predict_never_replaces_an_input_with_an_output(tmp_path, capsys, model):
    """``predict x_overlay.png x.png --overlay`` wrote x.png's overlay over x_overlay.png."""
    first, second = _png(tmp_path / "x_overlay.png"), _png(tmp_path / "x.png", 1)
    before = _tree(tmp_path)
    argv = ["predict", "--model", model, first, second, "--overlay", "--out", tmp_path, "--force"]
    _fails(capsys, argv, f"output {first} is the image itself ({first})")
    assert _tree(tmp_path) == before


def test_more_commands_never_write_over_what_they_read(tmp_path, capsys, model, data):
    """export's description beside the checkpoint (its own record), train --init-from its
    run directory, generate --config, prepare --recorded."""
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    for f in (model / "checkpoints").iterdir():
        (run / "checkpoints" / f.name).write_bytes(f.read_bytes())
    config = tmp_path / "c.yaml"
    config.write_text("digits: [2]\n")
    recorded = tmp_path / "recordings"
    recorded.mkdir()
    before = _tree(tmp_path)
    best = run / "checkpoints" / "best.safetensors"
    _fails(
        capsys,
        ["export", "--model", best, "--onnx", best.with_suffix(".onnx"), "--force"],
        "is the model",
        best.with_suffix(".json"),
    )
    _fails(capsys, _train_argv(data, run, "--init-from", run, "--force"), "--init-from model")
    _fails(capsys, ["generate", "--config", config, "--out", config, "--force"], "config file")
    _fails(
        capsys,
        ["prepare", "--recorded", recorded, "--out", recorded / "x.safetensors"],
        "--recorded paths",
        recorded,
    )
    assert _tree(tmp_path) == before


def test_write_never_replaces_its_image(tmp_path, capsys, data):
    from img2dmp.robot import available

    if not available():
        pytest.skip("pybullet is not installed: img2dmp write stops before checking its files")
    dmp = tmp_path / "x.json"
    dmp.write_text(json.dumps(_dmp_doc(data)))
    image = _png(tmp_path / "x_paper.png")
    before = _tree(tmp_path)
    argv = ["write", "--dmp", dmp, "--image", image, "--out-dir", tmp_path, "--force"]
    _fails(capsys, argv, f"output {image} is the image itself ({image})")
    assert _tree(tmp_path) == before


# --- DMP files whose movement is not finite -------------------------------------------------


@pytest.mark.parametrize(
    "field, value",
    [("w", 1e308), ("g", -1e12), ("y0", 1e300), ("tau", 1e300)],
)
def test_a_dmp_of_absurd_magnitude_is_refused_when_read(tmp_path, capsys, data, field, value):
    """Weights of 1e308 reached the simulator and failed there as "the pen did not settle"
    (exit status 1)."""
    from img2dmp.data.dmpfile import read_dmp_file

    doc = _dmp_doc(data)
    if field == "w":
        doc["params"]["w"][3][1] = value
    elif field == "tau":
        doc["params"]["tau"] = value
    else:
        doc["params"][field][0] = value
    path = tmp_path / "x.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=rf"{re.escape(str(path))}: field 'params\.{field}' is "):
        read_dmp_file(path)
    from img2dmp.robot import available

    if available():
        before = _tree(tmp_path)
        argv = ["write", "--dmp", path, "--out-dir", tmp_path / "robot"]
        _fails(capsys, argv, path, f"params.{field}", f"{value:g}")
        assert _tree(tmp_path) == before


def test_finite_parameters_whose_movement_overflows_are_refused(tmp_path, data, monkeypatch):
    """Below the magnitude bound the rollout is finite; the check of the rollout itself
    stands behind it (here with the bound lifted)."""
    from img2dmp.data import dmpfile

    monkeypatch.setattr(dmpfile, "MAX_MAGNITUDE", float("inf"))
    doc = _dmp_doc(data)
    doc["params"]["w"] = [[1e308, -1e308]] * len(doc["params"]["w"])
    with pytest.raises(ValueError, match=r"field 'params' is invalid: its movement .* not finite"):
        dmpfile.check_dmp_document(doc, "x.json")


def test_a_step_count_of_300_digits_is_never_printed():
    """tau = 1e300 s at 240 Hz: the message named a 300-digit step count, cut at 500
    characters by the web server, instead of the limit."""
    from img2dmp.dmp import DMPConfig, DMPParams
    from img2dmp.robot import PaperMapping, plan_path

    p = DMPParams(np.zeros((25, 2)), 1e300, np.array([20.0, 20.0]), np.array([8.0, 8.0]))
    with pytest.raises(ValueError) as e:
        plan_path(p, DMPConfig(), PaperMapping((40, 40)), 1.0 / 240.0)
    msg = str(e.value)
    assert len(msg) < 250 and "2.4e+302 control steps" in msg and "250000" in msg


# --- Ctrl-C: workers exit quietly ------------------------------------------------------------


def _workers(pid: int) -> list[int]:
    """The multiprocessing workers whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
                command = Path(f"/proc/{entry}/cmdline").read_bytes()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid and b"spawn_main" in command:
                out.append(int(entry))
    return out


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to see the workers")
def test_ctrl_c_during_generate_is_one_line(tmp_path):
    """The terminal's Ctrl-C reaches the whole process group: the workers, still importing
    torch, printed 127 lines of KeyboardInterrupt tracebacks before "interrupted"."""
    out = tmp_path / "g.safetensors"
    argv = ["generate", "--out", str(out), "--per-digit", "1000", "--workers", "2", "--no-progress"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "img2dmp", *argv],
        env=ENV,
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
        # as from a terminal: a suite started in the background (a shell's `&` without job
        # control) runs with SIGINT ignored, which the command would inherit
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        deadline = time.monotonic() + 60
        while len(_workers(proc.pid)) < 2 and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.05)
        time.sleep(0.3)  # the workers are importing torch
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert err == "img2dmp generate: interrupted\n"
    assert not out.exists() and not list(tmp_path.glob(".*.tmp"))


# --- the smaller ones ------------------------------------------------------------------------


def _tiny_images_file(path: Path, data: Path) -> Path:
    """``data`` with 1 x 1 images, written with a valid checksum as an older img2dmp (or
    another program) could have written it."""
    from img2dmp.data import store

    d = load_dataset(data)
    arrays = {k: np.ascontiguousarray(v) for k, v in d.arrays().items()}
    arrays["images"] = np.ascontiguousarray(d.images[:, :1, :1])
    meta = dict(d.meta, image_size=[1, 1])
    header = json.dumps(meta, sort_keys=True)
    digest = store.content_digest(header, arrays)
    metadata = {store.META_KEY: header, store.CHECKSUM_KEY: digest}
    path.write_bytes(store._st_save(arrays, metadata=metadata))
    return path


def test_a_data_set_of_one_pixel_images_is_refused(tmp_path, capsys, data):
    from img2dmp.data.store import DigitData

    d = load_dataset(data)
    tiny = DigitData(
        **dict(d.arrays(), images=np.ascontiguousarray(d.images[:, :1, :1])), meta=d.meta
    )
    with pytest.raises(ValueError, match=r"'images' holds images of 1 x 1 pixels"):
        save_dataset(tmp_path / "never.safetensors", tiny)
    path = _tiny_images_file(tmp_path / "tiny.safetensors", data)
    before = _tree(tmp_path)
    _fails(capsys, _train_argv(path, tmp_path / "run"), path, "1 x 1 pixels")
    assert _tree(tmp_path) == before


def test_nan_in_a_float_image_is_named(tmp_path, capsys, model):
    from PIL import Image

    from img2dmp import load_model

    a = np.ones((40, 40), np.float32)
    a[8:32, 18:22] = 0.0
    a[0, 0] = np.nan
    with pytest.raises(ValueError, match="PIL image holds NaN"):
        load_model(model).predict(Image.fromarray(a, mode="F"))
    path = tmp_path / "nan.tif"
    Image.fromarray(a, mode="F").save(path)
    before = _tree(tmp_path)
    _fails(capsys, ["predict", "--model", model, path], f"image file {path} holds NaN")
    assert _tree(tmp_path) == before


def test_a_directory_given_as_an_image_is_called_a_directory(tmp_path, model):
    from img2dmp import load_model

    with pytest.raises(IsADirectoryError, match=f"image file {tmp_path} is a directory"):
        load_model(model).predict(tmp_path)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_model(model).predict(tmp_path / "missing.png")


def test_show_cuts_what_it_shows():
    from img2dmp.errors import show

    nested = [1] * 9
    for _ in range(9):
        nested = [nested] * 9  # 9**10 values, shared: never expanded
    assert show(nested).endswith("(list of 9 items)") and len(show(nested)) < 100
    assert show("x" * 10**6).endswith("(str of 1,000,000 characters)")
    assert show(10**5000) == "a whole number of 5,001 digits"
    assert show("ok") == "'ok'" and show([1, 2]) == "[1, 2]"
    assert _files.show is show
