"""Bad input to ``img2dmp import`` and ``img2dmp prepare`` found by the bad-input audit.

Each case is refused by the reader of the file at fault, so the Python API and the
command line say the same: one line (exit 2) naming the file and the field, line or
value, with a short form of a large value; never a traceback, a RuntimeWarning or a
misleading hint; a check that can fail up front fails before any slow work. The inputs
are built here, tiny: the whole file runs in seconds.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageDraw

from img2dmp import cli
from img2dmp.data.importer import ImportOptions, import_dataset
from img2dmp.data.omniglot import parse_strokes
from img2dmp.data.prepare import PrepareOptions, prepare_dataset
from img2dmp.data.recorded import load_recorded, parse_recorded
from img2dmp.data.sources.trajectory import read_trajectory
from img2dmp.data.store import load_dataset

SIDE = 64  # of the images drawn here
N_POINTS = 20


def _line(name: str) -> np.ndarray:
    """The points ``[N, 2]`` (x = column, y = row) of letter ``name``'s one stroke: L a
    vertical bar, T a horizontal one."""
    u = np.linspace(10.0, 50.0, N_POINTS)
    fixed = np.full(N_POINTS, 15.0)
    return np.stack([fixed, u] if name == "L" else [u, fixed], axis=-1)


def _image(path: Path, name: str) -> None:
    im = Image.new("L", (SIDE, SIDE), 255)
    xy = _line(name)
    ImageDraw.Draw(im).line([tuple(xy[0]), tuple(xy[-1])], fill=0, width=5)
    path.parent.mkdir(parents=True, exist_ok=True)
    im.save(path)


def _csv(path: Path, xy: np.ndarray, t) -> Path:
    rows = ["x,y,t"] + [f"{x!r},{y!r},{tt!r}" for (x, y), tt in zip(xy.tolist(), t, strict=True)]
    path.write_text("\n".join(rows) + "\n")
    return path


def _source(root: Path, t0: float = 0.0) -> Path:
    """Two classes L and T of two samples each: ``root/CLASS/00k.png`` and ``.csv``, the
    time stamps from ``t0`` every 10 ms."""
    for name in ("L", "T"):
        for k in range(2):
            _image(root / name / f"{k:03d}.png", name)
            t = [t0 + 0.01 * i for i in range(N_POINTS)]
            _csv(root / name / f"{k:03d}.csv", _line(name), t)
    return root


def _run(argv: list[str], capsys) -> str:
    """The one error line of a command that must fail with exit 2."""
    assert cli.main([*argv, "--no-progress"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1, err
    assert "Traceback" not in captured.err and "Warning" not in captured.err
    return err[0]


def _import(source: Path, tmp_path: Path, capsys, *extra: str) -> str:
    out = tmp_path / "out.safetensors"
    line = _run(["import", str(source), "--out", str(out), *extra], capsys)
    assert line.startswith("img2dmp import: error: ")
    assert not out.exists()
    return line


# --- 1, 2: .npy files that are none, or whose header lies ---------------------------


def _npy_with_header(path: Path, shape: tuple, numbers: int) -> Path:
    """A .npy file whose header says ``shape`` (float64) but which holds ``numbers``."""
    with open(path, "wb") as f:
        np.lib.format.write_array_header_1_0(
            f, {"descr": "<f8", "fortran_order": False, "shape": shape}
        )
        f.write(np.arange(numbers, dtype="<f8").tobytes())
    return path


def test_an_npy_header_claiming_a_huge_array_is_refused_before_loading(tmp_path, capsys):
    path = _npy_with_header(tmp_path / "a.npy", (100_000_000_000, 3), 60)
    said = "its header says 100000000000 x 3 numbers but the file holds 60"
    with pytest.raises(ValueError, match=rf"a\.npy: {said}"):
        read_trajectory(path)
    root = _source(tmp_path / "src")
    (root / "L/000.csv").unlink()
    _npy_with_header(root / "L/000.npy", (100_000_000_000, 3), 60)
    line = _import(root, tmp_path, capsys)
    assert f"L/000.npy: {said}" in line


def test_a_text_file_named_npy_is_no_numpy_file_and_no_pickle_is_suggested(tmp_path, capsys):
    path = tmp_path / "a.npy"
    path.write_text("hello\n")
    with pytest.raises(ValueError, match=r"a\.npy: not a NumPy \.npy file") as e:
        read_trajectory(path)
    assert "pickle" not in str(e.value)
    (tmp_path / "empty.npy").write_bytes(b"")
    with pytest.raises(ValueError, match=r"empty\.npy: is empty"):
        read_trajectory(tmp_path / "empty.npy")
    root = _source(tmp_path / "src")
    (root / "L/000.csv").unlink()
    (root / "L/000.npy").write_text("hello\n")
    line = _import(root, tmp_path, capsys)
    assert "L/000.npy: not a NumPy .npy file" in line and "pickle" not in line


# --- 3: time stamps no pen path has ---------------------------------------------------


def test_time_stamps_beyond_a_sane_bound_are_named_before_any_arithmetic(tmp_path, capsys):
    t = [0.0, 1e298] + [2e298 + i * 1e283 for i in range(N_POINTS - 2)]
    path = _csv(tmp_path / "a.csv", _line("L"), t)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a RuntimeWarning fails the test
        with pytest.raises(ValueError, match=r"a\.csv: line 3: field 't' is 1e\+298 s, beyond"):
            read_trajectory(path)
    far = _csv(tmp_path / "b.csv", _line("L"), [1e6 * i for i in range(N_POINTS)])
    with pytest.raises(ValueError, match=r"b\.csv: line 4: field 't' is 2000000\.0 s, more "):
        read_trajectory(far)  # a path of 19e6 s
    root = _source(tmp_path / "src")
    _csv(root / "L/001.csv", _line("L"), t)
    line = _import(root, tmp_path, capsys)
    assert "L/001.csv: line 3: field 't' is 1e+298 s" in line and "float32" not in line


def test_omniglot_and_recorded_time_stamps_are_bounded_too():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"s\.txt: line 3: field 't' is 1e\+299 ms"):
            parse_strokes("START\n1,2,0\n3,4,1e299\n5,6,2e299\nBREAK\n", "s.txt")
        doc = {"Image number": 1, "Image shape": 1, "Path": "[1, 2, -1.7e308], [3, 4, 1.7e308]"}
        with pytest.raises(ValueError, match=r'r\.json: "Path" point 0 has the time stamp'):
            parse_recorded(doc, "r.json")


def test_time_stamps_of_a_clock_far_from_0_import_as_any(tmp_path):
    """Unix times (1.7e9 s): the instants are checked as stored, from the first point."""
    data = import_dataset(_source(tmp_path / "src", t0=1.7e9), ImportOptions(), progress=False)
    assert len(data) == 4
    np.testing.assert_allclose(data.times[:, -1], 0.19, rtol=1e-5)


# --- 4: --duration --------------------------------------------------------------------


@pytest.mark.parametrize("options", [ImportOptions, PrepareOptions])
def test_a_duration_too_short_for_a_pen_path_is_refused_up_front(options):
    said = r"duration_s \(--duration\) must be at least 0\.001 s, got 1e-300"
    with pytest.raises(ValueError, match=said):
        options(duration_s=1e-300)
    assert options(duration_s=1e-3).duration_s == 1e-3


def test_the_duration_flag_is_checked_before_anything_is_read(tmp_path, capsys):
    missing = tmp_path / "nothing"
    missing.mkdir()  # an empty folder: reading it would fail with another message
    line = _import(missing, tmp_path, capsys, "--duration", "1e-300")
    assert "duration_s (--duration) must be at least 0.001 s, got 1e-300" in line


# --- 5: a folder of recordings named strokes_* ----------------------------------------


def _recording(folder: Path, k: int, name: str, digit: int) -> None:
    """A recording of ``images/NAME.png`` as serve's Record page writes it (corner
    convention, milliseconds)."""
    xy = _line(name) + 0.5
    path = ", ".join(f"[{x!r}, {y!r}, {10.0 * i!r}]" for i, (x, y) in enumerate(xy.tolist()))
    doc = {
        "Image number": k,
        "Image shape": digit,
        "Path": path,
        "Image file": f"{name}.png",
        "Image size": [SIDE, SIDE],
    }
    (folder / f"image_{k}.json").write_text(json.dumps(doc))


def test_a_folder_of_recordings_named_strokes_is_read_as_recordings(tmp_path, capsys):
    images, rec = tmp_path / "images", tmp_path / "strokes_mine"
    rec.mkdir()
    for k, (name, digit) in enumerate([("L", 1), ("T", 7), ("L", 1), ("T", 7)]):
        _image(images / f"{name}.png", name)
        _recording(rec, k, name, digit)
    data = import_dataset(rec, ImportOptions(), images=images, progress=False)
    assert sorted(set(data.labels.tolist())) == [1, 7]
    flat = tmp_path / "strokes_flat"
    flat.mkdir()
    (flat / "notes.txt").write_text("not a drawing")
    said = r"strokes_\* is read as Omniglot's strokes .*ALPHABET/CHARACTER.*holds no folders"
    with pytest.raises(ValueError, match=rf"strokes_flat: a folder named {said}"):
        import_dataset(flat)
    line = _import(flat, tmp_path, capsys)
    assert "a folder named strokes_* is read as Omniglot's strokes" in line


# --- 6: large values are shown short ----------------------------------------------------


def test_large_values_are_shown_in_a_short_form(tmp_path, capsys):
    big = list(range(5000))
    root = _source(tmp_path / "src")
    (root / "L/000.csv").unlink()
    (root / "L/000.json").write_text(json.dumps({"x": [big] * 3, "y": [1, 2, 3], "t": [0, 1, 2]}))
    with pytest.raises(ValueError, match=r"field 'x' point 0 is \[0, 1, 2, .*list of 5,000"):
        read_trajectory(root / "L/000.json")
    line = _import(root, tmp_path, capsys)
    assert "L/000.json: field 'x' point 0 is" in line and len(line) - len(str(root)) < 200
    text = _csv(tmp_path / "a.csv", _line("L"), [0.01 * i for i in range(N_POINTS)])
    text.write_text(text.read_text().replace("0.01\n", "0.01" + "z" * 100_000 + "\n", 1))
    with pytest.raises(ValueError, match="line 3: field 't' is '0.01zzz") as e:
        read_trajectory(text)
    assert len(str(e.value)) - len(str(text)) < 200
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps([{"image": big, "trajectory": "a.csv", "class": "L"}]))
    with pytest.raises(ValueError, match=r"entry 0: field 'image' is .*list of 5,000") as e:
        import_dataset(manifest)
    assert len(str(e.value)) - len(str(manifest)) < 200


# --- 7, 8: prepare's --recorded and --data ----------------------------------------------


def test_recorded_must_be_the_archive_or_a_folder_not_one_recording(tmp_path, capsys):
    one = tmp_path / "image_140.json"
    _recording(tmp_path, 140, "L", 1)
    wanted = "--recorded (recorded_path) wants the recorded paths' archive trajectories.tar.gz"
    with pytest.raises(ValueError, match=r"image_140\.json: is one recording; --recorded"):
        load_recorded(one)
    # Refused before MNIST is read: here there is none.
    argv = ["prepare", "--mnist", str(tmp_path / "no-mnist"), "--recorded", str(one)]
    line = _run([*argv, "--out", str(tmp_path / "p.safetensors")], capsys)
    assert f"{one}: is one recording; {wanted}" in line
    other = tmp_path / "data.safetensors"
    other.write_bytes(b"not an archive")
    with pytest.raises(ValueError, match=r"data\.safetensors: is no tar archive; --recorded"):
        load_recorded(other)


def test_data_must_be_the_data_root_folder_not_a_data_set_file(tmp_path, capsys):
    file = tmp_path / "tiny.safetensors"
    file.write_bytes(b"a data set")
    said = r"--data \(data_dir\) must be the root folder of the real data"
    with pytest.raises(NotADirectoryError, match=rf"tiny\.safetensors: {said}"):
        prepare_dataset(PrepareOptions(), data_dir=file, progress=False)
    line = _run(["prepare", "--data", str(file), "--out", str(tmp_path / "p.safetensors")], capsys)
    assert f"{file}: --data (data_dir) must be the root folder" in line and "not a file" in line


# --- 9: a NUL byte in a manifest -----------------------------------------------------


def test_a_nul_byte_in_a_manifest_names_the_file_row_and_field(tmp_path, capsys):
    root = _source(tmp_path / "src")
    manifest = root / "m.csv"
    manifest.write_text("image,trajectory,class\nL/000.png\0,L/000.csv,L\n")
    said = r"field 'image' is 'L/000\.png\\x00', which holds a NUL byte"
    with pytest.raises(ValueError, match=rf"m\.csv: row 1: {said}"):
        import_dataset(manifest, progress=False)
    line = _import(manifest, tmp_path, capsys)
    assert f"{manifest}: row 1: field 'image' is 'L/000.png\\x00'" in line


def test_a_class_named_with_a_comma_is_refused_naming_it(tmp_path, capsys):
    root = _source(tmp_path / "src")
    manifest = root / "m.csv"
    manifest.write_text('image,trajectory,class\nL/000.png,L/000.csv,"a,b"\n')
    line = _import(manifest, tmp_path, capsys)
    assert f"{manifest}: row 1: class 'a,b' holds a comma, which --classes reads" in line
    (root / "L").rename(root / "L,l")  # a class folder too
    line = _import(root, tmp_path, capsys)
    assert f"{root / 'L,l'}: class 'L,l' holds a comma" in line
    with pytest.raises(ValueError, match="classes entry 1: class 'a,b' holds a comma"):
        ImportOptions(classes=("T", "a,b"))  # in a --config file or --set


def test_class_names_are_unicode_nfc_so_e_acute_is_one_class_however_written(tmp_path):
    nfc, nfd = "\u00e9", "e\u0301"  # the same "é", one code point or e + accent
    root = _source(tmp_path / "src")
    (root / "L").rename(root / nfc)
    (root / "T").rename(root / nfd)  # as macOS names a folder
    data = import_dataset(root, ImportOptions(val_fraction=0, test_fraction=0))
    assert data.class_names == (nfc,)
    assert data.meta["counts_by_class"] == {nfc: 4}
    (root / nfd).rename(root / "T")
    data = import_dataset(root, ImportOptions(classes=("T", nfd)))  # --classes in NFD
    assert data.class_names == ("T", nfc) and sorted(data.meta["counts_by_class"].values()) == [
        2,
        2,
    ]


def test_repeated_time_stamps_are_refused_or_spread_as_omniglot_s(tmp_path, capsys):
    root = _source(tmp_path / "src")
    path = root / "L" / "000.csv"
    t = [0.01 * i for i in range(N_POINTS)]
    t[3] = t[4] = t[5] = t[2]  # a tablet logging 4 points in one 10 ms tick
    t[-1] = t[-2]  # and 2 at the very end
    _csv(path, _line("L"), t)
    line = _import(root, tmp_path, capsys)
    assert "field 't' does not increase at line 5: 0.02 then 0.02" in line
    assert "--spread-repeated-times spreads a repeat" in line
    spread = read_trajectory(path, spread_repeated=True).t_s
    assert spread[2:6] == pytest.approx([0.02, 0.03, 0.04, 0.05])  # up to the next, 0.06
    assert spread[-2:] == pytest.approx([0.175, 0.18])  # the last run: back from the one before
    out = tmp_path / "spread.safetensors"
    argv = ["import", str(root), "--out", str(out), "--no-progress"]
    assert cli.main([*argv, "--spread-repeated-times"]) == 0 and out.is_file()
    assert load_dataset(out).meta["import"]["spread_repeated_times"] is True
    t[8] = t[7] - 0.001  # a step back is no repeat: refused, named before the repeats' place
    _csv(path, _line("L"), t)
    line = _import(root, tmp_path, capsys, "--spread-repeated-times")
    assert "does not increase at line 10:" in line and "spreads" not in line
    _csv(path, _line("L"), [0.5] * N_POINTS)  # one stamp for every point: nothing to spread
    line = _import(root, tmp_path, capsys, "--spread-repeated-times")
    assert "does not increase at line 3: 0.5 then 0.5" in line
