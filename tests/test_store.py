"""The data-set file format of docs/CONTRACTS.md: round trip, atomic write, validation."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from safetensors.numpy import save_file

from img2dmp.data import DigitData, load_dataset, save_dataset
from img2dmp.data.store import META_KEY
from img2dmp.dmp import DMPConfig


def _data(m: int = 6, t: int = 11, h: int = 8, w: int = 9, seed: int = 0) -> DigitData:
    rng = np.random.default_rng(seed)
    return DigitData(
        images=rng.random((m, h, w), dtype=np.float32),
        trajectories=rng.normal(size=(m, t, 2)).astype(np.float32),
        times=np.tile(np.arange(t, dtype=np.float32) * 0.01, (m, 1)),
        labels=rng.integers(0, 10, m).astype(np.int64),
        params=rng.normal(size=(m, DMPConfig().n_params)).astype(np.float32),
        fit_error_px=rng.random(m, dtype=np.float32),
        split=rng.integers(0, 3, m).astype(np.uint8),
        meta={"dmp_config": DMPConfig().to_dict(), "source": {"kind": "test"}, "seed": 5},
    )


def test_round_trip_is_bit_exact(tmp_path):
    data = _data()
    path = save_dataset(tmp_path / "d.safetensors", data)
    back = load_dataset(path)
    for name, a in data.arrays().items():
        b = getattr(back, name)
        assert b.dtype == a.dtype and b.shape == a.shape
        np.testing.assert_array_equal(b, a)
    assert back.meta["format"] == "img2dmp-dataset" and back.meta["version"] == 1
    assert back.meta["image_size"] == [8, 9] and back.meta["seed"] == 5
    assert back.meta["source"] == {"kind": "test"}
    assert back.dmp_config == DMPConfig()
    # The header is plain safetensors: the JSON sits under one metadata key.
    header_len = int.from_bytes(path.read_bytes()[:8], "little")
    header = json.loads(path.read_bytes()[8 : 8 + header_len])
    assert json.loads(header["__metadata__"][META_KEY])["format"] == "img2dmp-dataset"


def test_select_split_and_subset():
    data = _data(m=30)
    for code, name in enumerate(("train", "validation", "test")):
        part = data.select_split(name)
        assert len(part) == int((data.split == code).sum())
        assert (part.split == code).all()
    with pytest.raises(ValueError, match="split"):
        data.select_split("dev")


def test_write_is_atomic_and_leaves_no_temp_files(tmp_path, monkeypatch):
    target = tmp_path / "d.safetensors"
    save_dataset(target, _data(seed=1))
    before = target.read_bytes()

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        save_dataset(target, _data(seed=2))
    assert target.read_bytes() == before  # the old file is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.safetensors"]
    # Written like any file: readable by others as the umask allows, not 0600.
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask


def test_overwrite_false_refuses(tmp_path):
    target = save_dataset(tmp_path / "d.safetensors", _data())
    with pytest.raises(FileExistsError):
        save_dataset(target, _data(), overwrite=False)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("labels", np.full(6, 10, np.int64), "'labels'"),
        ("labels", np.zeros(6, np.int32), "'labels' has dtype int32"),
        ("images", np.full((6, 8, 9), 1.5, np.float32), "'images'"),
        ("split", np.full(6, 3, np.uint8), "'split'"),
        ("params", np.zeros((6, 54), np.float32), "'params'"),
        ("fit_error_px", np.zeros(5, np.float32), "'fit_error_px' has 5 rows"),
        ("times", np.zeros((6, 11), np.float32), "'times' is not strictly increasing"),
        ("trajectories", np.full((6, 11, 2), np.nan, np.float32), "'trajectories'"),
    ],
)
def test_validation_names_the_field(tmp_path, field, value, message):
    data = _data()
    setattr(data, field, value)
    with pytest.raises(ValueError, match=message):
        save_dataset(tmp_path / "bad.safetensors", data)
    assert not any(tmp_path.iterdir())


def _write_raw(path, arrays, meta):
    save_file(arrays, str(path), metadata=None if meta is None else {META_KEY: meta})


def test_load_rejects_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_dataset(tmp_path / "missing.safetensors")

    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"not a safetensors file at all")
    with pytest.raises(ValueError, match="junk.safetensors"):
        load_dataset(junk)

    good = _data()
    arrays = good.arrays()
    meta = dict(good.meta, format="img2dmp-dataset", version=1, image_size=[8, 9], created="x")

    no_meta = tmp_path / "nometa.safetensors"
    _write_raw(no_meta, arrays, None)
    with pytest.raises(ValueError, match="nometa.safetensors.*'img2dmp'"):
        load_dataset(no_meta)

    future = tmp_path / "future.safetensors"
    _write_raw(future, arrays, json.dumps(dict(meta, version=99)))
    with pytest.raises(ValueError, match="'version'"):
        load_dataset(future)

    missing = tmp_path / "missing_field.safetensors"
    _write_raw(missing, {k: v for k, v in arrays.items() if k != "split"}, json.dumps(meta))
    with pytest.raises(ValueError, match=r"missing_field.safetensors.*\['split'\]"):
        load_dataset(missing)

    wrong_size = tmp_path / "size.safetensors"
    _write_raw(wrong_size, arrays, json.dumps(dict(meta, image_size=[40, 40])))
    with pytest.raises(ValueError, match="'image_size'"):
        load_dataset(wrong_size)
