"""Bad and hostile input to the stored files and the DMP parameter API (issue 17).

Checkpoints, data-set files and DMP parameter files that are edited, corrupt, truncated,
foreign or wrongly typed are refused with one named exception whose one-line message
names the file, the field and the value; the checksums are verified on load; a refused
write leaves an earlier file as it was. Everything here is tiny: the whole file runs in
seconds.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from safetensors.numpy import save_file

from img2dmp import cli
from img2dmp.checkpoint import (
    RECORD_DIGEST,
    CheckpointError,
    load_checkpoint,
    optimizer_to_tensors,
    read_checkpoint_meta,
    record_digest,
    save_checkpoint,
)
from img2dmp.data.store import (
    CHECKSUM_KEY,
    META_KEY,
    DatasetError,
    DigitData,
    load_dataset,
    save_dataset,
)
from img2dmp.dmp import DMPConfig, DMPParams, fit_dmp, rollout
from img2dmp.nn import ModelConfig, ParamNormaliser, build_model
from img2dmp.predict import Predictor
from img2dmp.robot.dmpfile import MAX_FILE_BYTES, load_dmp_json, save_dmp_json

TINY_MODEL = {"encoder_layers": [64, 20], "decoder_layers": [35], "image_size": [40, 40]}


# -- helpers -----------------------------------------------------------------------------


def _header(path: Path) -> tuple[int, dict]:
    raw = path.read_bytes()
    n = int.from_bytes(raw[:8], "little")
    return n, json.loads(raw[8 : 8 + n])


def _rewrite_metadata(path: Path, edit) -> None:
    """Apply ``edit`` to the header's ``__metadata__`` dict of a safetensors file, keeping
    the tensors' bytes (what a hand edit of the file does)."""
    raw = path.read_bytes()
    n, header = _header(path)
    edit(header["__metadata__"])
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 8)
    path.write_bytes(len(text).to_bytes(8, "little") + text + raw[8 + n :])


def _edit_record(path: Path, edit) -> None:
    """Edit the img2dmp JSON record inside a safetensors file, nothing else."""

    def on_meta(meta: dict) -> None:
        record = json.loads(meta[META_KEY])
        edit(record)
        meta[META_KEY] = json.dumps(record, indent=1, sort_keys=True)

    _rewrite_metadata(path, on_meta)


def _flip(path: Path, offset: int) -> None:
    raw = bytearray(path.read_bytes())
    raw[offset] ^= 0x01
    path.write_bytes(bytes(raw))


def _tensor_offset(path: Path, name: str) -> int:
    """File offset of the first byte of tensor ``name``."""
    n, header = _header(path)
    return 8 + n + header[name]["data_offsets"][0]


def _valid_params(rng, m: int, config: DMPConfig) -> np.ndarray:
    v = rng.normal(size=(m, config.n_params))
    v[:, config.n_kernels * config.n_dims] = rng.uniform(0.5, 1.5, m)  # tau > 0
    return v


def _checkpoint(path: Path, *, resumable: bool = False) -> Path:
    """A real, loadable checkpoint of a tiny network (as training writes it)."""
    cfg, dmp = ModelConfig(**TINY_MODEL), DMPConfig()
    model = build_model(cfg, seed=0)
    norm = ParamNormaliser.fit(_valid_params(np.random.default_rng(0), 40, dmp), dmp)
    meta = {
        "kind": "img2dmp-model",
        "model": cfg.to_dict(),
        "normaliser": norm.to_dict(),
        "dmp_config": dmp.to_dict(),
        "image_size": [40, 40],
        "ink_margin": 0.15,
        "dataset": {"path": "d.safetensors", "sha256": "0" * 64},
    }
    extra = None
    if resumable:
        opt = torch.optim.Adam(model.parameters(), lr=1e-3)
        model(torch.rand(2, 40, 40)).sum().backward()
        opt.step()
        extra, record = optimizer_to_tensors(opt)
        meta["optimizer"] = record
    return save_checkpoint(path, model.state_dict(), meta, extra)


@pytest.fixture(scope="module")
def ckpt_bytes(tmp_path_factory) -> bytes:
    return _checkpoint(tmp_path_factory.mktemp("ckpt") / "best.safetensors").read_bytes()


@pytest.fixture
def ckpt(tmp_path, ckpt_bytes) -> Path:
    p = tmp_path / "best.safetensors"
    p.write_bytes(ckpt_bytes)
    return p


def _data(m: int = 6, t: int = 11, seed: int = 0) -> DigitData:
    rng = np.random.default_rng(seed)
    return DigitData(
        images=rng.random((m, 8, 9), dtype=np.float32),
        trajectories=rng.normal(size=(m, t, 2)).astype(np.float32),
        times=np.tile(np.arange(t, dtype=np.float32) * 0.01, (m, 1)),
        labels=rng.integers(0, 10, m).astype(np.int64),
        params=_valid_params(rng, m, DMPConfig()).astype(np.float32),
        fit_error_px=rng.random(m, dtype=np.float32),
        split=np.arange(m, dtype=np.uint8) % 3,
        meta={"dmp_config": DMPConfig().to_dict(), "source": {"kind": "test"}, "seed": 5},
    )


def _legacy_dataset(path: Path, data: DigitData) -> Path:
    """A data-set file as the previous img2dmp wrote it: no checksum key."""
    meta = dict(data.meta, format="img2dmp-dataset", version=1, image_size=[8, 9], created="x")
    save_file(data.arrays(), str(path), metadata={META_KEY: json.dumps(meta, sort_keys=True)})
    return path


def _one_line(e: pytest.ExceptionInfo) -> str:
    msg = str(e.value)
    assert "\n" not in msg
    return msg


# -- 1. checkpoints: the whole record is covered by a digest -------------------------------


def test_checkpoint_records_and_verifies_a_digest_of_the_whole_record(tmp_path):
    ckpt = _checkpoint(tmp_path / "best.safetensors")
    meta = read_checkpoint_meta(ckpt)
    assert meta["version"] == 2 and meta[RECORD_DIGEST] == record_digest(meta)
    assert json.loads(ckpt.with_suffix(".json").read_text()) == meta  # the sidecar agrees
    loaded = load_checkpoint(ckpt)
    assert loaded.meta == meta
    Predictor.load(ckpt).predict_images(np.zeros((1, 40, 40), np.float32))


def _times3(values):
    return [3 * v for v in values]


@pytest.mark.parametrize(
    "edit",
    [
        pytest.param(lambda r: r["normaliser"].update(centre=_times3(r["normaliser"]["centre"])),
                     id="normaliser-centre-x3"),
        pytest.param(lambda r: r["normaliser"]["scale"].__setitem__(50, 9.0), id="scale"),
        pytest.param(lambda r: r["model"].update(activation="tanh"), id="architecture"),
        pytest.param(lambda r: r["dmp_config"].update(alpha_z=12.0), id="dmp-constants"),
        pytest.param(lambda r: r.update(ink_margin=0.4), id="image-framing"),
        pytest.param(lambda r: r.update(weights_sha256="0" * 64), id="weights-digest"),
        pytest.param(lambda r: r.pop(RECORD_DIGEST), id="digest-removed"),
    ],
)  # fmt: skip
def test_an_edited_checkpoint_record_is_refused_by_name(ckpt, edit):
    _edit_record(ckpt, edit)
    for load in (load_checkpoint, read_checkpoint_meta, Predictor.load):
        with pytest.raises(CheckpointError, match="modified or is corrupt") as e:
            load(ckpt)
        assert str(ckpt) in _one_line(e)


def test_an_edited_checkpoint_is_refused_by_the_cli_with_exit_2(ckpt, tmp_path, capsys):
    _edit_record(ckpt, lambda r: r["normaliser"].update(centre=_times3(r["normaliser"]["centre"])))
    image = tmp_path / "one.png"
    Image.fromarray(np.full((40, 40), 255, np.uint8)).save(image)
    assert cli.main(["predict", "--model", str(ckpt), str(image), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "modified or is corrupt" in err and len(err.splitlines()) == 1
    assert not list(tmp_path.glob("*_dmp.json"))


def test_a_flipped_weight_bit_is_refused(ckpt):
    _flip(ckpt, _tensor_offset(ckpt, "model.decoder.0.weight") + 5)
    with pytest.raises(CheckpointError, match="modified or is corrupt.*weights"):
        load_checkpoint(ckpt)


def test_a_flipped_optimiser_bit_is_refused(tmp_path):
    p = _checkpoint(tmp_path / "last.safetensors", resumable=True)
    assert load_checkpoint(p).extra and "optim_sha256" in read_checkpoint_meta(p)
    _, header = _header(p)
    name = next(k for k in header if k.startswith("optim."))
    _flip(p, _tensor_offset(p, name))
    with pytest.raises(CheckpointError, match="optimiser state"):
        load_checkpoint(p)


def test_a_version_1_checkpoint_of_earlier_img2dmp_still_loads(ckpt):
    def as_v1(record):
        for key in (RECORD_DIGEST, "optim_sha256"):
            record.pop(key, None)
        record["version"] = 1

    _edit_record(ckpt, as_v1)
    assert load_checkpoint(ckpt).meta["version"] == 1
    Predictor.load(ckpt)
    _flip(ckpt, _tensor_offset(ckpt, "model.decoder.0.weight"))  # its weights still verified
    with pytest.raises(CheckpointError, match="SHA-256"):
        load_checkpoint(ckpt)


@pytest.mark.parametrize("version", [3, 0, "2", True, 2.5])
def test_other_checkpoint_versions_are_refused(ckpt, version):
    _edit_record(ckpt, lambda r: r.update(version=version))
    with pytest.raises(CheckpointError, match=f"version {version!r} is not supported"):
        load_checkpoint(ckpt)


def test_resaving_a_loaded_record_gives_fresh_digests(ckpt, tmp_path):
    # Resuming passes a loaded record (with its old digests) back to save_checkpoint.
    old = load_checkpoint(ckpt)
    state = {k: v + 1 for k, v in old.model_state.items()}
    out = save_checkpoint(tmp_path / "again.safetensors", state, old.meta)
    new = load_checkpoint(out)
    assert new.meta["weights_sha256"] != old.meta["weights_sha256"]
    assert new.meta[RECORD_DIGEST] == record_digest(new.meta)


@pytest.mark.parametrize("keep", [0, 7, 8, 60, -1])
def test_a_truncated_checkpoint_is_refused(ckpt, ckpt_bytes, keep):
    ckpt.write_bytes(ckpt_bytes[: keep if keep >= 0 else len(ckpt_bytes) + keep])
    with pytest.raises(CheckpointError, match="corrupt or truncated") as e:
        load_checkpoint(ckpt)
    assert str(ckpt) in _one_line(e)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda p: save_file({"w": np.zeros(3, np.float32)}, str(p)), "not an img2dmp checkpoint"),
        (lambda p: save_file({"w": np.zeros(3, np.float32)}, str(p), metadata={"img2dmp": "[1]"}),
         "metadata is a JSON list, expected an object"),
        (lambda p: save_file({"w": np.zeros(3, np.float32)}, str(p), metadata={"img2dmp": "{"}),
         "not valid JSON"),
        (lambda p: p.write_bytes((1 << 62).to_bytes(8, "little") + b"{}"), "corrupt or truncated"),
        (lambda p: p.write_bytes(b"\x80\x02pickled torch file, never unpickled"),
         "corrupt or truncated"),
    ],
    ids=["foreign-safetensors", "record-is-a-list", "record-not-json", "huge-header", "pickle"],
)  # fmt: skip
def test_foreign_and_malformed_checkpoint_files_are_refused(tmp_path, make, message):
    p = tmp_path / "x.safetensors"
    make(p)
    with pytest.raises(CheckpointError, match=message) as e:
        load_checkpoint(p)
    assert str(p) in _one_line(e)


def test_a_checkpoint_that_is_not_there_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="holds no checkpoint"):
        load_checkpoint(tmp_path)
    with pytest.raises(FileNotFoundError, match="nothing.safetensors"):
        load_checkpoint(tmp_path / "nothing.safetensors")


def test_a_refused_checkpoint_write_leaves_the_earlier_one(ckpt, ckpt_bytes, monkeypatch):
    state = load_checkpoint(ckpt).model_state
    with pytest.raises(ValueError, match="not JSON-serialisable"):
        save_checkpoint(ckpt, state, {"bad": object()})

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", full_disk)
    with pytest.raises(OSError, match="No space left"):
        save_checkpoint(ckpt, {k: v * 0 for k, v in state.items()}, {"kind": "x"})
    monkeypatch.undo()
    assert ckpt.read_bytes() == ckpt_bytes
    assert sorted(p.name for p in ckpt.parent.iterdir()) == ["best.safetensors"]
    load_checkpoint(ckpt)


# -- 2. data-set files: a checksum written with the file, verified on load ------------------


def test_a_data_set_carries_a_checksum_that_load_verifies(tmp_path):
    p = save_dataset(tmp_path / "d.safetensors", _data())
    _, header = _header(p)
    assert len(header["__metadata__"][CHECKSUM_KEY]) == 64
    back = load_dataset(p)
    assert back.origin == str(p)
    # Saving a loaded data set again (e.g. a subset) writes a fresh, valid checksum.
    load_dataset(save_dataset(tmp_path / "sub.safetensors", back.select_split("train")))


@pytest.mark.parametrize(
    ("field", "byte"), [("images", 3), ("labels", 0), ("params", 17), ("split", -1)]
)
def test_a_flipped_bit_in_a_data_set_is_refused(tmp_path, field, byte):
    p = save_dataset(tmp_path / "d.safetensors", _data())
    _, header = _header(p)
    lo, hi = header[field]["data_offsets"]
    _flip(p, _tensor_offset(p, field) + (byte if byte >= 0 else hi - lo + byte))
    with pytest.raises(DatasetError, match="modified or is corrupt") as e:
        load_dataset(p)
    assert str(p) in _one_line(e)


@pytest.mark.parametrize(
    "edit",
    [
        lambda m: m.update(seed=6),
        lambda m: m["dmp_config"].update(alpha_z=12.0),
        lambda m: m["source"].update(kind="edited"),
    ],
    ids=["seed", "dmp-constants", "source"],
)
def test_an_edited_data_set_field_is_refused(tmp_path, edit):
    p = save_dataset(tmp_path / "d.safetensors", _data())
    _edit_record(p, edit)
    with pytest.raises(DatasetError, match=f"{p.name} was modified or is corrupt"):
        load_dataset(p)


def test_a_data_set_of_the_previous_version_without_checksum_still_loads(tmp_path):
    p = _legacy_dataset(tmp_path / "old.safetensors", _data())
    data = load_dataset(p)
    assert len(data) == 6 and data.meta["version"] == 1


@pytest.mark.parametrize("keep", [0, 8, 100, -1])
def test_a_truncated_data_set_is_refused(tmp_path, keep):
    p = save_dataset(tmp_path / "d.safetensors", _data())
    raw = p.read_bytes()
    p.write_bytes(raw[: keep if keep >= 0 else len(raw) + keep])
    with pytest.raises(DatasetError, match="truncated") as e:
        load_dataset(p)
    assert str(p) in _one_line(e)


def test_a_huge_declared_header_or_a_list_record_is_refused(tmp_path):
    p = tmp_path / "huge.safetensors"
    p.write_bytes((1 << 62).to_bytes(8, "little") + b"{}")
    with pytest.raises(DatasetError, match="huge.safetensors"):
        load_dataset(p)
    q = save_dataset(tmp_path / "list.safetensors", _data())
    _rewrite_metadata(q, lambda m: (m.update({META_KEY: "[1, 2]"}), m.pop(CHECKSUM_KEY)))
    with pytest.raises(DatasetError, match="must be a JSON object"):
        load_dataset(q)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda m: m.update(image_size=40), "'image_size' is 40"),
        (lambda m: m.update(seed=True), "'seed' must be an integer or null"),
        (lambda m: m.update(version=True), "'version' is True"),
        (lambda m: m.update(format="img2dmp-checkpoint"), "'format' is 'img2dmp-checkpoint'"),
        (lambda m: m.pop("dmp_config"), "'dmp_config' is missing"),
        (lambda m: m["dmp_config"].update(n_kernels=24), "'params' has 55 numbers per sample"),
        (lambda m: m.update(source="synthetic"), "'source' must be a JSON object"),
    ],
    ids=["image-size", "seed", "version", "format", "no-config", "kernels", "source"],
)
def test_bad_metadata_is_named(tmp_path, edit, message):
    p = _legacy_dataset(tmp_path / "old.safetensors", _data())  # no checksum to stop at
    _edit_record(p, edit)
    with pytest.raises(DatasetError, match=message) as e:
        load_dataset(p)
    assert _one_line(e).startswith(str(p))


def test_a_directory_or_nothing_where_a_data_set_belongs_is_named(tmp_path):
    with pytest.raises(IsADirectoryError, match="is a directory"):
        load_dataset(tmp_path)
    with pytest.raises(FileNotFoundError, match="missing.safetensors"):
        load_dataset(tmp_path / "missing.safetensors")


def _set(field, row, value):
    def change(d: DigitData) -> None:
        getattr(d, field)[row] = value

    return change


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (_set("labels", 4, 11), "'labels' row 4 is 11: is not a digit 0-9"),
        (_set("labels", 2, -1), "'labels' row 2 is -1"),
        (_set("split", 5, 7), "'split' row 5 is 7"),
        (_set("fit_error_px", 1, -0.5), "'fit_error_px' row 1 is -0.5"),
        (_set("times", 3, np.linspace(1.0, 0.0, 11)), "not strictly increasing in row 3"),
        (_set("times", 2, np.arange(11) * 0.01 - 0.5), "'times' row 2 is -0.5: starts before 0"),
        (_set("images", 5, 2.0), "'images' row 5 has values outside"),
        (_set("trajectories", 3, np.nan), "'trajectories' row 3 contains NaN"),
        (lambda d: setattr(d, "split", d.split[:4]), "'split' has 4 rows but 'labels' has 6"),
        (lambda d: setattr(d, "times", d.times[:, :5]), "'times' has 5 time stamps"),
    ],
    ids=["label-11", "label-neg", "split", "fit-error", "times-order", "times-neg",
         "images", "nan", "rows", "stamps"],
)  # fmt: skip
def test_bad_rows_are_named_on_load_and_on_save(tmp_path, change, message):
    data = _data()
    change(data)
    # A file of the previous version (no checksum to stop at): the load names file and row.
    old = _legacy_dataset(tmp_path / "old.safetensors", data)
    with pytest.raises(DatasetError, match=message) as e:
        load_dataset(old)
    assert str(old) in _one_line(e)
    # Saving over an earlier file refuses before writing anything.
    target = save_dataset(tmp_path / "d.safetensors", _data(seed=1))
    before = target.read_bytes()
    with pytest.raises(DatasetError, match=message):
        save_dataset(target, data)
    assert target.read_bytes() == before


def test_a_non_json_record_is_refused_before_the_earlier_file_is_touched(tmp_path):
    target = save_dataset(tmp_path / "d.safetensors", _data())
    before = target.read_bytes()
    for meta in ({"note": float("nan")}, {"note": object()}):
        data = _data(seed=1)
        data.meta.update(meta)
        with pytest.raises(DatasetError, match="not JSON-serialisable"):
            save_dataset(target, data)
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.safetensors"]


@pytest.mark.parametrize(
    ("field", "index", "message"),
    [
        ("trajectories", (3, 5, 0), "field 'trajectories' row 3 holds a path position 1e+30 px"),
        ("trajectories", (4, 0, 1), "field 'trajectories' row 4 holds a path position -95 px"),
        ("params", (2, 52), "field 'params' row 2 holds a goal or start position 1e+30 px"),
    ],
)
def test_a_position_far_off_the_image_is_named_on_save_and_load(tmp_path, field, index, message):
    """A path, goal or start more than MAX_POSITION_SIDES image sides from the image is
    no position of it (1e30 was read as a path and evaluated into Infinity)."""
    from img2dmp.data.store import MAX_POSITION_SIDES

    data = _data(m=6)
    getattr(data, field)[index] = -95.0 if "-95" in message else 1e30
    assert 95 > MAX_POSITION_SIDES * 9  # an 8 x 9 image: 90 px from its centre at most
    with pytest.raises(DatasetError, match=re.escape(message)) as e:
        save_dataset(tmp_path / "d.safetensors", data)
    _one_line(e)
    assert not (tmp_path / "d.safetensors").exists()
    legacy = _legacy_dataset(tmp_path / "old.safetensors", data)  # written before the rule
    with pytest.raises(DatasetError, match=rf"old\.safetensors: {re.escape(message)}"):
        load_dataset(legacy)


def test_training_names_the_row_whose_duration_is_no_duration(tmp_path, capsys):
    from img2dmp.cli import main

    data = _data(m=9)
    data.params[4, DMPConfig().n_kernels * DMPConfig().n_dims] = -1.0
    p = save_dataset(tmp_path / "d.safetensors", data)  # the format stores any finite vector
    argv = ["train", "--config", "demo", "--data", str(p), "--run-dir", str(tmp_path / "r"),
            "--epochs", "1", "--no-progress"]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("d.safetensors: row 4: field 'params' has tau (column 50) = -1.0; "
                        "a DMP's duration must be > 0 s"), err  # fmt: skip


def test_a_duration_that_is_no_duration_is_named_by_file_and_row(tmp_path):
    data = _data(m=9)
    tau = DMPConfig().n_kernels * DMPConfig().n_dims
    data.params[7, tau] = -2.0
    p = save_dataset(tmp_path / "d.safetensors", data)
    loaded = load_dataset(p)
    assert loaded.dmp_params(slice(0, 7)).batch_shape == (7,)
    # row 7 of the file is row 2 of the validation split (rows 1, 4, 7)
    with pytest.raises(DatasetError, match=rf"d.safetensors: row 7: .*tau \(column {tau}\) = -2.0"):
        loaded.select_split("validation").dmp_params()


# -- 3. DMP parameter files ----------------------------------------------------------------


@pytest.fixture
def dmp_doc(tmp_path) -> tuple[Path, dict]:
    path = tmp_path / "dmp.json"
    config = DMPConfig()
    params = DMPParams(np.zeros((25, 2)), 1.5, np.array([30.0, 20.0]), np.array([5.0, 6.0]))
    save_dmp_json(path, params, config, (40, 40), label=3)
    return path, json.loads(path.read_text())


def _ragged(p):
    p["w"][3] = [1.0]


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["params"].update(tau=True), "field 'tau' must be a number .*got true"),
        (lambda d: d["params"].update(tau="2.0"), "field 'tau' must be a number .*got \"2.0\""),
        (lambda d: d["params"].update(g=["1", "2"]), "field 'g' must be .*got \"1\""),
        (lambda d: d["params"]["w"][0].__setitem__(1, False), "field 'w' must be .*got false"),
        (lambda d: d["params"].update(y0=[1.0, None]), "field 'y0' must be .*got null"),
        (lambda d: d["params"].update(tau=float("nan")), "field 'tau' must be finite, got NaN"),
        (lambda d: d["params"].update(g=[1.0, float("inf")]), "'g' must be finite, got Infinity"),
        (lambda d: d["params"].update(tau=0.0), "field 'tau' must be > 0 .*got 0.0"),
        (lambda d: d["params"].update(tau=[1.5]), r"'tau' has shape \[1\], expected \[\]"),
        (lambda d: d["params"].update(g=[1.0, 2.0, 3.0]), r"'g' has shape \[3\], expected \[2\]"),
        (lambda d: _ragged(d["params"]), "field 'w' is ragged"),
        (lambda d: d["params"].pop("y0"), r"missing field\(s\) \['y0'\]"),
        (lambda d: d["params"].update(tua=1.0), r"unknown field\(s\) \['tua'\]"),
        (lambda d: d.update(params=[1, 2]), "must be an object with fields"),
        (lambda d: d["dmp_config"].pop("alpha_z"), "'dmp_config' is missing alpha_z"),
        (lambda d: d["dmp_config"].update(n_dims=True), "n_dims must be a number, got true"),
        (lambda d: d["dmp_config"].update(alpha_z="48"), "alpha_z must be a number, got \"48\""),
        (lambda d: d["dmp_config"].update(speed=2), r"unknown DMP config field\(s\): \['speed'\]"),
        (lambda d: d["dmp_config"].update(n_kernels=100_000), "from 2 to 200, got 100000"),
        (lambda d: d["dmp_config"].update(n_dims=7), "n_dims must be 2 .* or 3"),
        (lambda d: d.update(image_size=[40, True]), r"'image_size' must be \[H, W\]"),
        (lambda d: d.update(image_size=[10**9, 10**9]),
         r"'image_size' is \[1000000000, 1000000000\]: a side of more than 100,000 px"),
    ],
    ids=["tau-bool", "tau-str", "g-str", "w-bool", "null", "nan", "inf", "tau-zero",
         "tau-list", "g-shape", "ragged", "missing", "unknown", "params-list", "config-missing",
         "config-bool", "config-str", "config-unknown", "kernels", "dims", "image-size",
         "image-size-huge"],
)  # fmt: skip
def test_dmp_file_fields_are_strict(dmp_doc, edit, message):
    path, doc = dmp_doc
    edit(doc)
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=message) as e:
        load_dmp_json(path)
    assert _one_line(e).startswith(f"{path}: field '")


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"[1, 2, 3]", "expected a JSON object at the top level, got a list"),
        (b'"params"', "got a string"),
        (b"", "not valid JSON"),
        (b'{"tau": 1', "not valid JSON"),
        (b"\xff\xfe{}", "not a UTF-8 text file"),
        (b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
        (b" " * (MAX_FILE_BYTES + 1), "larger than 16 MiB"),
    ],
    ids=["list", "string", "empty", "cut", "binary", "deep", "huge"],
)
def test_malformed_dmp_files_are_refused_by_name(tmp_path, content, message):
    path = tmp_path / "dmp.json"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=message) as e:
        load_dmp_json(path)
    assert _one_line(e).startswith(str(path))


def test_a_directory_or_nothing_where_a_dmp_file_belongs_is_named(tmp_path):
    with pytest.raises(IsADirectoryError, match=str(tmp_path)):
        load_dmp_json(tmp_path)
    with pytest.raises(FileNotFoundError, match="nothing.json"):
        load_dmp_json(tmp_path / "nothing.json")


def test_a_prediction_record_given_as_a_dmp_file_is_named(tmp_path):
    path = tmp_path / "x_dmp.json"
    path.write_text(json.dumps({"image": "x.png", "dmp": {}, "vector": [], "trajectory": {}}))
    with pytest.raises(ValueError, match="a prediction record of 'img2dmp predict'"):
        load_dmp_json(path)


def test_a_page_document_given_as_a_dmp_file_says_how_to_write_it(tmp_path):
    path = tmp_path / "p_page.json"
    path.write_text(json.dumps({"format": "img2dmp-page", "version": 1, "characters": []}))
    with pytest.raises(ValueError) as e:
        load_dmp_json(path)
    assert str(e.value) == (f"{path}: is a page document (format 'img2dmp-page'), not one "
                            f"DMP: img2dmp write {path} --page writes it")  # fmt: skip


def test_unknown_top_level_keys_are_notes(dmp_doc):
    path, doc = dmp_doc
    doc["source"] = {"image": "x.png"}
    path.write_text(json.dumps(doc))
    params, _, size = load_dmp_json(path)
    assert float(params.tau) == 1.5 and size == (40, 40)


def test_a_refused_dmp_write_leaves_the_earlier_file(dmp_doc):
    path, _ = dmp_doc
    before = path.read_bytes()
    good = load_dmp_json(path)[0]
    config = DMPConfig()
    with pytest.raises(ValueError, match="image_size"):
        save_dmp_json(path, good, config, (40, "40"))
    with pytest.raises(ValueError, match="not plain JSON"):
        save_dmp_json(path, good, config, (40, 40), note=float("nan"))
    with pytest.raises(ValueError, match="not plain JSON"):
        save_dmp_json(path, good, config, (40, 40), note=object())
    with pytest.raises(ValueError, match="n_dims must be 2 .* or 3"):
        save_dmp_json(path, DMPParams(np.zeros((25, 4)), 1.0, [1.0] * 4, [0.0] * 4),
                      DMPConfig(n_dims=4), (40, 40))  # fmt: skip
    assert path.read_bytes() == before
    assert [p.name for p in path.parent.iterdir()] == [path.name]


# -- 4. fit_dmp names the user's input ------------------------------------------------------


def _demo(n: int = 40) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0.0, 1.0, n)
    return t, np.stack([10 * np.sin(3 * t), 20 * t], axis=-1)


def test_fit_names_an_overflowing_trajectory_not_an_internal_field():
    t, y = _demo()
    with pytest.raises(ValueError, match=r"^y: its magnitude \(up to 2e\+201\) overflows") as e:
        fit_dmp(t, y * 1e200)
    assert "DMPParams" not in str(e.value)
    batch = np.stack([y, y * 1e200, y])
    with pytest.raises(ValueError, match=r"^y of demonstration \[1\]: its magnitude"):
        fit_dmp(t, batch)


def test_fit_names_where_a_trajectory_holds_nan():
    t, y = _demo()
    y = np.stack([y, y])
    y[1, 17, 0] = np.nan
    with pytest.raises(
        ValueError, match=r"y\[1, 17, 0\] is nan \(point 17, coordinate 0 of demonstration \[1\]\)"
    ):
        fit_dmp(t, y)


def test_fit_names_an_overflowing_duration():
    _, y = _demo(3)
    with pytest.raises(ValueError, match=r"^t: the duration .* overflows"):
        fit_dmp(np.array([-1e308, 0.0, 1e308]), y)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"y": np.array([["1", "2"], ["3", "4"]])}, "y must hold real numbers, .* dtype <U1"),
        ({"y": np.ones((2, 2), bool)}, "y must hold real numbers, got an array of dtype bool"),
        ({"t": torch.tensor([0.0, 1.0], dtype=torch.complex128)}, "t must hold real numbers"),
        ({"ridge": "1e-9"}, "ridge must be a finite number >= 0, got '1e-9'"),
        ({"ridge": -1.0}, "ridge must be a finite number >= 0"),
        ({"chunk_size": 0}, "chunk_size must be an integer >= 1, got 0"),
        ({"chunk_size": True}, "chunk_size must be an integer >= 1, got True"),
    ],
    ids=["y-text", "y-bool", "t-complex", "ridge-text", "ridge-negative", "chunk-0", "chunk-bool"],
)  # fmt: skip
def test_fit_refuses_arguments_that_are_not_numbers(kwargs, message):
    args = {"t": np.array([0.0, 1.0]), "y": np.array([[0.0, 0.0], [1.0, 2.0]]), **kwargs}
    with pytest.raises(ValueError, match=message):
        fit_dmp(**args)


# -- 5. DMPParams and rollout: kinds and dtypes ----------------------------------------------


def _torch_params(dtype=torch.float64) -> DMPParams:
    rng = np.random.default_rng(3)
    w = torch.as_tensor(rng.normal(size=(25, 2)), dtype=dtype)
    return DMPParams(w, torch.tensor(1.0, dtype=dtype), torch.tensor([30.0, 20.0], dtype=dtype),
                     torch.tensor([5.0, 6.0], dtype=dtype))  # fmt: skip


T = torch.linspace(0.0, 1.0, 20, dtype=torch.float64)


def test_dmp_params_refuse_a_mix_of_numpy_and_torch_by_field():
    p = _torch_params()
    with pytest.raises(ValueError, match="tau is a torch.Tensor, w is a numpy.ndarray"):
        DMPParams(p.w.numpy(), p.tau, p.g, p.y0)
    # A field swapped after construction: rollout names it, never a raw TypeError.
    p.g = p.g.numpy()
    with pytest.raises(ValueError, match=r"DMPParams.g is a NumPy array \(float64\).*to_torch"):
        rollout(p, T)


def test_rollout_refuses_numpy_params_with_a_hint():
    with pytest.raises(ValueError, match=r"DMPParams.w is a NumPy array.*params.to_torch\(\)"):
        rollout(_torch_params().to_numpy(), T)


def test_rollout_converts_integer_params_to_floating_point():
    ints = DMPParams(torch.zeros(25, 2, dtype=torch.int64), torch.tensor(1),
                     torch.tensor([30, 20]), torch.tensor([5, 6]))  # fmt: skip
    floats = ints.to_torch(torch.float64)
    y = rollout(ints, T)
    assert y.dtype == torch.float64
    torch.testing.assert_close(y, rollout(floats, T))
    # beside float32 fields, integers become float32
    mixed = _torch_params(torch.float32)
    mixed.g = torch.tensor([30, 20])
    assert rollout(mixed, T.float()).dtype == torch.float32


@pytest.mark.parametrize("dtype", [torch.bool, torch.complex64])
def test_rollout_and_params_refuse_booleans_and_complex_numbers(dtype):
    p = _torch_params()
    with pytest.raises(ValueError, match=f"DMPParams.g has dtype {dtype}"):
        DMPParams(p.w, p.tau, p.g.to(dtype), p.y0)
    p.g = p.g.to(dtype)
    with pytest.raises(ValueError, match=f"DMPParams.g has dtype {dtype}"):
        rollout(p, T, validate=False)


def test_rollout_refuses_time_stamps_that_are_not_numbers():
    with pytest.raises(ValueError, match="t must"):
        rollout(_torch_params(), ["0", "1"])
    with pytest.raises(ValueError, match="t must hold real time stamps"):
        rollout(_torch_params(), torch.tensor([False, True]))
    with pytest.raises(TypeError, match="rollout needs a DMPParams, got Tensor"):
        rollout(torch.zeros(55), T)


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"tau": True}, "DMPParams.tau must be a number, got the boolean True"),
        ({"tau": np.bool_(True)}, "DMPParams.tau must be a number, got the boolean"),
        ({"g": ["1", "2"]}, "DMPParams.g must be a number or a list of numbers, got \"1\""),
        ({"g": [1.0, True]}, "DMPParams.g must be .*got true"),
        ({"tau": np.array([1.0, -1.0, 2.0]), "w": np.zeros((3, 25, 2)), "g": np.zeros((3, 2)),
          "y0": np.zeros((3, 2))}, r"tau must be > 0 .*got -1.0 at index \[1\]"),
        ({"w": np.array([[np.inf, 0.0]] * 25)}, r"w contains NaN or inf, got inf at index \[0, 0"),
        ({"tau": "1.0"}, "DMPParams.tau must be an array or tensor, got str \"1.0\""),
    ],
    ids=["bool", "numpy-bool", "text-list", "bool-in-list", "tau-negative-row", "inf", "text"],
)  # fmt: skip
def test_dmp_params_name_the_field_and_the_value(fields, message):
    base = {"w": np.zeros((25, 2)), "tau": 1.0, "g": np.ones(2), "y0": np.zeros(2)}
    with pytest.raises(ValueError, match=message) as e:
        DMPParams(**{**base, **fields})
    _one_line(e)


def test_from_dict_is_strict_and_round_trips():
    p = DMPParams(np.zeros((25, 2)), 1.5, [1.0, 2.0], [0.0, 0.0])
    assert DMPParams.from_dict(p.to_dict()).to_dict() == p.to_dict()
    with pytest.raises(ValueError, match="field 'tau' must be a number .*got true"):
        DMPParams.from_dict({**p.to_dict(), "tau": True})
    with pytest.raises(ValueError, match=r"'w' has shape \[25, 2\], expected \[25, 3\]"):
        DMPParams.from_dict(p.to_dict(), config=DMPConfig(n_dims=3), batch_shape=())


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("n_dims", True, "n_dims must be an integer >= 1, got True"),
        ("n_kernels", False, "n_kernels must be an integer from 2 to 200, got False"),
        ("alpha_z", "48", "alpha_z must be a number > 0, got '48'"),
        ("alpha_x", b"2", "alpha_x must be a number > 0, got b'2'"),
        ("width_factor", True, "width_factor must be a number > 0, got True"),
    ],
)
def test_dmp_constants_refuse_booleans_and_text(field, value, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        DMPConfig(**{field: value})


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"alpha_z": 1e300}, "alpha_z must be at most 10000, got 1e+300"),
        ({"beta_z": 2e4}, "beta_z must be at most 10000, got 20000.0"),
        (
            {"alpha_z": 1e-300},
            "alpha_z=1e-300, beta_z=2.5e-301, alpha_x=2 with 25 kernels give "
            "the rollout's response table no end x 26",
        ),
        ({"beta_z": 1e-300}, "beta_z=1e-300"),
        (
            {"alpha_x": 1e-300},
            "alpha_x=1e-300 with 25 kernels give the rollout's response table 8.8e+303 steps x 26",
        ),
        ({"alpha_x": 0.01}, "table 884,194 steps x 26 responses (at most 8,000,000 entries)"),
        ({"alpha_z": 5000}, "alpha_z=5000, beta_z=1250"),
        ({"alpha_x": 0.5, "n_kernels": 200}, "146,630 steps x 201 responses"),
        ({"alpha_x": 370}, "alpha_x=370 with 25 kernels puts the last kernels' centres"),
    ],
)
def test_dmp_constants_whose_table_would_not_fit_are_refused_before_it_is_built(
    fields, message, monkeypatch
):
    """Gains that make the rollout's response table endless or gigabytes long (a DMP file,
    a checkpoint, a data set or a page may carry any) are one line naming them; the
    paper's constants at the most kernels, and everyday others, build theirs."""
    from img2dmp.dmp import _table
    from img2dmp.dmp.basis import kernel_widths

    monkeypatch.setattr(_table, "_solve_responses", None)  # never reached for these
    with pytest.raises(ValueError, match=re.escape(message)) as e:
        DMPConfig(**fields)
    _one_line(e)
    monkeypatch.undo()
    for fine in ({"n_kernels": 200}, {"alpha_z": 25.0, "alpha_x": 1.0}, {"alpha_z": 1000.0},
                 {"alpha_z": 1.0}, {"alpha_x": 0.1}, {"alpha_x": 368}):  # fmt: skip
        h, s_max, table = _table._response_table_f64(DMPConfig(**fine))
        assert table.shape[0] * table.shape[2] <= 8_000_000 and np.isfinite(table).all()
        assert np.isfinite(kernel_widths(DMPConfig(**fine))).all()


@pytest.mark.parametrize(
    "data, needle",
    [
        (b"\xff\xfe{}", "req: not a UTF-8 text file"),
        ('{"a": 1', "req: not valid JSON"),
        ("[" * 100_000 + "]" * 100_000, "req: JSON nested too deeply"),
        ('{"x": NaN}', "req: NaN is not a JSON number"),
        ('{"x": -Infinity}', "req: -Infinity is not a JSON number"),
    ],
)
def test_the_one_json_reader_names_what_it_reads(data, needle):
    from img2dmp._files import parse_json

    with pytest.raises(ValueError) as e:
        parse_json(data, "req", allow_nan=False)
    assert needle in str(e.value) and "\n" not in str(e.value)
    assert parse_json(b'\xef\xbb\xbf{"x": 1}', "req") == {"x": 1}  # a BOM is fine


def test_sizes_a_python_caller_gives_are_bounded_before_the_work(monkeypatch):
    """An audit's calls that ran for minutes or filled memory: a fit of 3 million points
    (6.2 GB), a rollout at 1e8 time stamps (77 GiB asked), an export checked on 1e9
    images; each is one ValueError naming the argument, at once."""
    import img2dmp
    from img2dmp.dmp import fit_dmp
    from img2dmp.export import default_check_images

    with pytest.raises(ValueError, match=r"a trajectory of 100,001 points is more than the "
                                         r"100,000 a fit takes"):  # fmt: skip
        fit_dmp(np.linspace(0, 1, 100_001), np.zeros((100_001, 2)))
    model = img2dmp.load_model(refine=0)
    params = model.predict_images(np.zeros((1, 28, 28), np.float32))
    with pytest.raises(ValueError, match=r"times holds 200,000 stamps, more than 100,000 per"):
        model.trajectories(params, times=np.linspace(0, 1, 200_000))
    for n in (2, 10**9, "5"):
        with pytest.raises(ValueError, match=r"n_check must be an integer from 3 to 4,096"):
            default_check_images(model, n)


def test_the_dmp_functions_name_a_config_that_is_no_dmpconfig_and_a_bare_time():
    """A dict or a scaling's name given as config failed on an attribute deep inside; a
    0-d time an IndexError; alpha_z None a TypeError; a reversed view torch's strides."""
    import torch

    from img2dmp import bend_dmp, interop, rollout
    from img2dmp.dmp import fit_dmp

    t = np.linspace(0.0, 1.0, 50)
    y = np.stack([10 + 5 * t, 12 - 3 * t**2], -1)
    p = fit_dmp(t, y).params
    said = "config must be a DMPConfig (img2dmp.DMPConfig(...); DMPConfig.from_dict for a dict)"
    calls = [
        lambda c: rollout(p.to_torch(), torch.as_tensor(t), c),
        lambda c: bend_dmp(p, c),
        lambda c: fit_dmp(t, y, c),
        lambda c: interop.to_movement_primitives(p, c),
    ]
    for call in calls:
        for config in ({"scaling": "none"}, "none"):
            with pytest.raises(TypeError, match=re.escape(said)):
                call(config)
    with pytest.raises(ValueError, match=r"t has shape \(\): give the time stamps as an array"):
        rollout(p.to_torch(), torch.tensor(0.5, dtype=torch.float64))
    with pytest.raises(ValueError, match="alpha_z must be a number > 0, got None"):
        DMPConfig(alpha_z=None)
    backwards = fit_dmp(t, y[::-1])  # a view with negative strides: fitted as it reads
    np.testing.assert_allclose(backwards.params.y0, y[-1], atol=1e-6)


def test_prepared_images_hold_ink_levels_in_0_1():
    """1e30 gave NaN weights, 0-255 weights of 1e6 and the familiarity of NaN images NaN:
    every call on prepared images refuses them alike."""
    import img2dmp

    model = img2dmp.load_model(refine=0)
    cases = [
        (np.full((1, 28, 28), 255, np.uint8), "got values from 255 to 255"),
        (np.full((1, 28, 28), 1e30, np.float32), "from 1e+30 to 1e+30"),
        (np.full((1, 28, 28), np.nan, np.float32), "images contain NaN or inf"),
    ]
    calls = (model.predict_images, model.predict_hypotheses, model.familiarity,
             model.encoder_features)  # fmt: skip
    for bad, said in cases:
        for call in calls:
            with pytest.raises(ValueError, match=re.escape(said)):
                call(bad)
    model.predict_images(np.ones((1, 28, 28), np.float32))  # all ink: a prepared image


def test_a_stem_with_a_folder_in_it_writes_nothing_outside(tmp_path):
    """PagePrediction.save(dir, "../x") wrote beside dir, and None as "None_page.json"."""
    import img2dmp
    from img2dmp.predict import write_prediction

    samples = Path(__file__).resolve().parents[1] / "examples" / "samples"
    model = img2dmp.load_model(refine=0)
    page = model.predict_page(samples / "page.jpg")
    pred = model.predict(samples / "digit_3.png")
    out = tmp_path / "out"
    for stem in ("../escaped", None, "", "..", "a/b"):
        with pytest.raises(ValueError, match="stem must be a file name without a folder"):
            page.save(out, stem, picture=False)
        with pytest.raises(ValueError, match="stem must be a file name without a folder"):
            write_prediction(out, stem, pred)
    assert not any(tmp_path.rglob("*.json"))


def test_a_list_of_images_and_a_dmp_to_save_are_named_when_they_are_not():
    import img2dmp
    from img2dmp.robot import save_dmp_json

    model = img2dmp.load_model(refine=0)
    for paths in ([], "x.png"):  # a path's characters were read as paths
        with pytest.raises(ValueError, match="paths must be a non-empty list of image paths"):
            model.prepare_paths(paths)
    with pytest.raises(TypeError, match="x.json: params must be a DMPParams, got NoneType"):
        save_dmp_json("x.json", None, DMPConfig(), (28, 28))
    params = DMPParams(np.zeros((25, 2)), 1.0, np.zeros(2), np.ones(2))
    with pytest.raises(TypeError, match="x.json: config must be a DMPConfig, got dict"):
        save_dmp_json("x.json", params, {}, (28, 28))


def test_a_model_that_is_no_path_is_named():
    import img2dmp

    said = "the model must be a run directory, a checkpoint file or a shipped model's name"
    for given, shown in ((5, "int 5"), (b"run", "bytes b'run'")):
        with pytest.raises(TypeError, match=re.escape(f"{said}, got {shown}")):
            img2dmp.load_model(given)


def test_the_api_audit_s_last_few_are_one_line():
    """An empty batch to MP_PyTorch (a reshape error), a seed of text (NumPy's words),
    refinement steps of no images (a TypeError) and a page's path at 1e308 (written)."""
    import json

    import img2dmp
    from img2dmp import interop
    from img2dmp.export import default_check_images
    from img2dmp.robot import check_page_document

    none = DMPParams(np.zeros((0, 25, 2)), np.ones(0), np.zeros((0, 2)), np.zeros((0, 2)))
    with pytest.raises(ValueError, match=r"params holds no DMP \(batch shape \[0\]\)"):
        interop.to_mp_pytorch(none, DMPConfig())
    model = img2dmp.load_model(refine=0)
    with pytest.raises(ValueError, match="seed must be an integer >= 0, got 'x'"):
        default_check_images(model, 8, "x")
    with pytest.raises(ValueError, match=r"images must be prepared images \[B, H, W\], got None"):
        model.refine_steps_for(None)
    samples = Path(__file__).resolve().parents[1] / "examples" / "samples"
    doc = json.loads(model.predict_page(samples / "page.jpg").to_json())
    doc["characters"][0]["path_image_px"][3] = [1e308, 0.0]
    with pytest.raises(ValueError, match=r"page: field 'characters\[0\].path_image_px' point 3 "
                                         r"is \[1e\+308, 0.0\], beyond the 1e\+09 px"):  # fmt: skip
        check_page_document(doc, "page")
