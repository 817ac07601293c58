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


# --- stroke spans (issue 32): which instants belong to which stroke ---------------------


def _strokes(m: int = 4, t: int = 12) -> DigitData:
    """A d = 3 data set whose rows hold 1 to 3 strokes, the pen channel down on them."""
    config = DMPConfig(n_dims=3, scaling="none")
    spans = [[[0, t - 1]], [[0, 4], [7, 7]], [[1, 3], [5, 6], [9, 11]], [[2, 9]]][:m]
    pen = np.zeros((m, t), np.float32)
    for r, row in enumerate(spans):
        for a, b in row:
            pen[r, a : b + 1] = 1.0
    rng = np.random.default_rng(0)
    xy = rng.normal(size=(m, t, 2)).astype(np.float32)
    data = _data(m=m, t=t)
    data.trajectories = np.concatenate([xy, pen[..., None]], axis=-1)
    data.params = rng.normal(size=(m, config.n_params)).astype(np.float32)
    data.meta = dict(data.meta, dmp_config=config.to_dict(), stroke_spans=spans)
    return data


def test_stroke_spans_round_trip_and_follow_subsets(tmp_path):
    data = _strokes()
    back = load_dataset(save_dataset(tmp_path / "s.safetensors", data))
    assert [back.stroke_spans(r) for r in range(4)] == [
        [(0, 11)],
        [(0, 4), (7, 7)],
        [(1, 3), (5, 6), (9, 11)],
        [(2, 9)],
    ]
    part = back.subset(np.array([False, True, False, True]))
    assert part.stroke_spans(0) == [(0, 4), (7, 7)] and part.stroke_spans(1) == [(2, 9)]
    again = load_dataset(save_dataset(tmp_path / "part.safetensors", part))
    assert again.meta["stroke_spans"] == [[[0, 4], [7, 7]], [[2, 9]]]
    assert back.meta["stroke_spans"][0] == [[0, 11]]  # the subset left the whole alone


def test_files_without_stroke_spans_load_and_read_the_strokes_off_the_pen(tmp_path):
    data = _strokes()
    del data.meta["stroke_spans"]
    back = load_dataset(save_dataset(tmp_path / "old.safetensors", data))
    assert "stroke_spans" not in back.meta
    assert back.stroke_spans(2) == [(1, 3), (5, 6), (9, 11)]  # from the pen channel
    assert load_dataset(save_dataset(tmp_path / "d2.safetensors", _data())).stroke_spans(1) == [
        (0, 10)
    ]


@pytest.mark.parametrize(
    ("spans", "message"),
    [
        ("all", "'stroke_spans' must be a list of one entry per row \\(4\\), got str"),
        ([[[0, 11]]] * 3, "one entry per row \\(4\\), got 3 entries"),
        (3, "got int"),
        ("row 1 empty", "'stroke_spans' row 1 is \\[\\]: expected a non-empty list"),
        ("row 2 overlaps", "row 2 is \\[\\[1, 3\\], \\[3, 6\\], \\[9, 11\\]\\]"),
        ("row 3 beyond", "row 3 is \\[\\[2, 12\\]\\].*within 0-11"),
        ("row 3 true", "row 3 is \\[\\[true, 9\\]\\]"),
        ("row 1 not the pen", "row 1 does not match the pen channel: instant 7 is outside"),
    ],
)
def test_bad_stroke_spans_are_named(tmp_path, spans, message):
    data = _strokes()
    rows = data.meta["stroke_spans"]
    edits = {
        "row 1 empty": (1, []),
        "row 2 overlaps": (2, [[1, 3], [3, 6], [9, 11]]),
        "row 3 beyond": (3, [[2, 12]]),
        "row 3 true": (3, [[True, 9]]),
        "row 1 not the pen": (1, [[0, 4]]),
    }
    if isinstance(spans, str) and spans in edits:
        row, value = edits[spans]
        rows[row] = value
    else:
        data.meta["stroke_spans"] = spans
    with pytest.raises(ValueError, match=message):
        save_dataset(tmp_path / "bad.safetensors", data)
    assert not any(tmp_path.iterdir())
