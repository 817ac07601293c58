"""Real handwriting loaders, frames, split, multi-stroke DMPs and ``img2dmp prepare``.

Hand-made files (good and broken) are written to ``tmp_path``; tests on the real data in
``../shared/data`` skip with a reason when it is absent.
"""

from __future__ import annotations

import gzip
import io
import json
import struct
import tarfile
import warnings
from pathlib import Path

import numpy as np
import pytest

from img2dmp.data.mnist import load_mnist, read_idx, write_idx
from img2dmp.data.prepare import PrepareOptions, fit_paths, pen_rollout, prepare_dataset
from img2dmp.data.recorded import (
    FRAME_OFFSET_PX,
    load_recorded,
    parse_recorded,
    resample_path,
    share_on_ink,
    split_of_index,
)
from img2dmp.data.store import load_dataset
from img2dmp.data.strokes import (
    SpeedProfile,
    load_strokes,
    minimum_jerk,
    parse_sequence,
    pen_segments,
    read_npy,
    stroke_duration_s,
    time_strokes,
)
from img2dmp.dmp import DMPConfig

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
MNIST_DIR = DATA / "mnist"
RECORDED = DATA / "ijs-mnist-trajectories" / "trajectories.tar.gz"
STROKES_DIR = DATA / "mnist-stroke-sequences"


def _need(path: Path):
    return pytest.mark.skipif(
        not path.exists(), reason=f"real data not found at {path} (see docs/MNIST.md)"
    )


# --- hand-made data -------------------------------------------------------------------


def _draw(polyline: np.ndarray, size: int = 28, radius: float = 1.3) -> np.ndarray:
    """uint8 image with ink within ``radius`` px of a polyline (centre convention)."""
    ys, xs = np.mgrid[0:size, 0:size]
    pix = np.stack([xs, ys], -1).reshape(-1, 1, 2).astype(float)  # [P, 1, 2]
    a, b = polyline[None, :-1], polyline[None, 1:]  # [1, S, 2]
    ab = b - a
    u = np.clip(((pix - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0, 1)
    dist = np.linalg.norm(pix - (a + u[..., None] * ab), axis=-1).min(-1)
    return (255 * (dist < radius)).reshape(size, size).astype(np.uint8)


def _zigzag(k: int) -> np.ndarray:
    """A different smooth open path per k, inside the 28 x 28 frame, [40, 2]."""
    s = np.linspace(0, 1, 40)
    # Start and end differ in x and y: the paper's goal-start scaling needs g != y0.
    return np.stack([7 + 14 * s, 10 + 8 * s + (3 + k % 3) * np.sin(2 * np.pi * s + 0.6 * k)], -1)


def _recorded_doc(n: int, label: int, xy: np.ndarray, dt_ms: float = 16.7) -> dict:
    corner = xy - FRAME_OFFSET_PX  # the files use the pixel-corner convention
    t = np.arange(len(xy)) * dt_ms
    text = ", ".join(f"[{x:.5f}, {y:.5f}, {tt:.1f}]" for (x, y), tt in zip(corner, t, strict=True))
    return {"Image number": n, "Image shape": label, "Path": text}


def _tar_gz(path: Path, members: dict[str, bytes]) -> Path:
    with tarfile.open(path, "w:gz") as tar:
        for name, data in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return path


def _make_fake_data(root: Path, ink_radius: float = 1.3) -> Path:
    """A small data root: 12 MNIST-like images with ink on known paths + recorded JSONs."""
    (root / "mnist").mkdir(parents=True)
    (root / "ijs-mnist-trajectories").mkdir()
    paths = [_zigzag(k) for k in range(12)]
    images = np.stack([_draw(p, radius=ink_radius) for p in paths])
    labels = np.array([3, 5] * 6, np.uint8)
    write_idx(root / "mnist" / "train-images-idx3-ubyte.gz", images)
    write_idx(root / "mnist" / "train-labels-idx1-ubyte.gz", labels)
    members = {
        f"trajectories/image_{k}.json": json.dumps(_recorded_doc(k, int(labels[k]), p)).encode()
        for k, p in enumerate(paths)
    }
    _tar_gz(root / "ijs-mnist-trajectories" / "trajectories.tar.gz", members)
    return root


@pytest.fixture()
def fake_data(tmp_path) -> Path:
    return _make_fake_data(tmp_path / "data")


# --- MNIST IDX ------------------------------------------------------------------------


def test_idx_round_trip_gzip_and_raw(tmp_path):
    a = np.arange(2 * 3 * 4, dtype=np.uint8).reshape(2, 3, 4)
    for name in ("a.gz", "a"):
        write_idx(tmp_path / name, a)
        np.testing.assert_array_equal(read_idx(tmp_path / name, 2051), a)


def test_idx_truncated_gzip_is_named(tmp_path):
    p = tmp_path / "train-images-idx3-ubyte.gz"
    write_idx(p, np.zeros((5, 28, 28), np.uint8))
    p.write_bytes(p.read_bytes()[:-20])
    with pytest.raises(ValueError, match="train-images-idx3-ubyte.gz.*truncated"):
        read_idx(p)


def test_idx_bad_magic_is_named(tmp_path):
    p = tmp_path / "labels.idx"
    p.write_bytes(struct.pack(">ii", 1234, 1) + b"\x01")
    with pytest.raises(ValueError, match="labels.idx: bad IDX magic number 1234"):
        read_idx(p)
    write_idx(p, np.zeros(3, np.uint8))
    with pytest.raises(ValueError, match="magic number is 2049, expected 2051"):
        read_idx(p, expect_magic=2051)


def test_idx_wrong_length_is_named(tmp_path):
    p = tmp_path / "x.idx"
    header = struct.pack(">BBBBiii", 0, 0, 8, 3, 2, 28, 28)
    p.write_bytes(header + bytes(28 * 28))  # one image short
    with pytest.raises(ValueError, match=r"x.idx: IDX data truncated.*1568.*784"):
        read_idx(p)
    p.write_bytes(header + bytes(2 * 28 * 28 + 3))
    with pytest.raises(ValueError, match="trailing bytes"):
        read_idx(p)


def test_load_mnist_counts_must_match(tmp_path):
    write_idx(tmp_path / "train-images-idx3-ubyte.gz", np.zeros((3, 28, 28), np.uint8))
    write_idx(tmp_path / "train-labels-idx1-ubyte.gz", np.zeros(4, np.uint8))
    with pytest.raises(ValueError, match="3 images but .* 4 labels"):
        load_mnist(tmp_path, "train")
    with pytest.raises(FileNotFoundError, match="t10k-images"):
        load_mnist(tmp_path, "test")


@_need(MNIST_DIR)
def test_real_mnist():
    images, labels = load_mnist(MNIST_DIR, "test")
    assert images.shape == (10000, 28, 28) and images.dtype == np.float32
    assert images.min() == 0.0 and images.max() == 1.0
    assert labels.dtype == np.int64 and np.bincount(labels).min() > 800
    # Ink (1) sits in the middle, the border is background (0).
    assert images[:, 10:18, 10:18].mean() > 5 * images[:, :3].mean()


# --- recorded paths -------------------------------------------------------------------


def test_parse_recorded_converts_frame_and_units():
    xy = _zigzag(0)
    rec = parse_recorded(json.dumps(_recorded_doc(7, 3, xy, dt_ms=20.0)), "image_7.json")
    assert (rec.image_index, rec.label, rec.time_repairs) == (7, 3, 0)
    np.testing.assert_allclose(rec.xy, xy, atol=1e-4)
    np.testing.assert_allclose(rec.t_s, np.arange(40) * 0.02)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.pop("Path"), r"image_7.json: missing key\(s\) \['Path'\]"),
        (lambda d: d.pop("Image shape"), r"missing key\(s\) \['Image shape'\]"),
        (lambda d: d.update(Path="[1, 2, 0], [3, 4"), 'image_7.json: "Path" is not a list'),
        (lambda d: d.update(Path="[1, 2, 0], [3, 4]"), "point 1 is \\[3, 4\\]"),
        (lambda d: d.update(Path='[1, 2, 0], [3, "a", 5]'), "point 1"),
        (lambda d: d.update(Path="[1, 2, 0]"), "1 point"),
        (lambda d: d.update(Path="[1, 2, 0], [300, 2, 10]"), "outside"),
        (lambda d: d.update(Path=[[1, 2, 0]]), "must be a string"),
        (lambda d: d.update({"Image shape": 12}), "must be 0-9, got 12"),
        (lambda d: d.update({"Image number": 8}), "file name says image 7"),
        (lambda d: d.update({"Image number": "7"}), "integer >= 0"),
        (lambda d: d.update({"Image size": [28]}), r'"Image size" must be \[height, width\]'),
        (lambda d: d.update({"Image size": [0, 28]}), r'"Image size" must be'),
        # 300 px lies outside a 280 x 280 image too, by more than half its side.
        (
            lambda d: d.update({"Image size": [280, 280], "Path": "[1, 2, 0], [421, 2, 9]"}),
            "outside the 280 x 280 frame by more than 140 px",
        ),
    ],
)
def test_parse_recorded_rejects_broken_files(change, message):
    doc = _recorded_doc(7, 3, _zigzag(1))
    change(doc)
    with pytest.raises(ValueError, match=message):
        parse_recorded(json.dumps(doc), "trajectories/image_7.json")


def test_a_recording_of_a_larger_image_names_its_size():
    """Recordings of other images than MNIST's (img2dmp serve --images) carry their
    "Image size"; points anywhere on such an image are read."""
    doc = _recorded_doc(7, 3, _zigzag(1))
    doc.update({"Image size": [200, 300], "Path": "[250.5, 180.5, 0], [10.5, 20.5, 40]"})
    rec = parse_recorded(json.dumps(doc), "image_7.json")
    np.testing.assert_allclose(rec.xy, [[250.0, 180.0], [10.0, 20.0]])


def test_parse_recorded_rejects_invalid_json():
    with pytest.raises(ValueError, match="image_3.json: not valid JSON"):
        parse_recorded(b'{"Image number": 3, "Path": "[1, 2, 0]"', "image_3.json")


def test_backward_time_step_is_repaired_and_reported():
    doc = {"Image number": 1, "Image shape": 1, "Path": "[5, 5, 0], [6, 5, -400], [7, 5, -380]"}
    with pytest.warns(UserWarning, match="image_1.json: 1 time step"):
        rec = parse_recorded(json.dumps(doc), "image_1.json")
    # Steps 0 -> -400 (bad) and -400 -> -380 (20 ms): the bad one becomes the median, 20.
    np.testing.assert_allclose(rec.t_s, [0.0, 0.02, 0.04])
    assert rec.time_repairs == 1


def test_load_recorded_from_archive_and_folder(tmp_path):
    docs = {k: _recorded_doc(k, k % 10, _zigzag(k)) for k in (4, 2, 9)}
    members = {f"trajectories/image_{k}.json": json.dumps(d).encode() for k, d in docs.items()}
    archive = _tar_gz(tmp_path / "t.tar.gz", members)
    recs = load_recorded(archive)
    assert [r.image_index for r in recs] == [2, 4, 9]
    assert [r.image_index for r in load_recorded(archive, digits=[4])] == [4]
    folder = tmp_path / "unpacked" / "trajectories"
    folder.mkdir(parents=True)
    for name, data in members.items():
        (folder / Path(name).name).write_bytes(data)
    for where in (folder, folder.parent):
        again = load_recorded(where)
        assert [r.image_index for r in again] == [2, 4, 9]
        np.testing.assert_array_equal(again[1].xy, recs[1].xy)


def test_load_recorded_names_the_broken_member(tmp_path):
    members = {
        "trajectories/image_1.json": json.dumps(_recorded_doc(1, 1, _zigzag(1))).encode(),
        "trajectories/image_2.json": b'{"Image number": 2, "Image shape": 2}',
    }
    archive = _tar_gz(tmp_path / "t.tar.gz", members)
    with pytest.raises(ValueError, match=r"t.tar.gz:trajectories/image_2.json: missing key"):
        load_recorded(archive)


def test_load_recorded_truncated_archive(tmp_path):
    members = {
        f"trajectories/image_{k}.json": json.dumps(_recorded_doc(k, 1, _zigzag(k))).encode()
        for k in range(30)
    }
    archive = _tar_gz(tmp_path / "t.tar.gz", members)
    archive.write_bytes(archive.read_bytes()[: archive.stat().st_size // 2])
    with pytest.raises(ValueError, match="t.tar.gz"):
        load_recorded(archive)
    with pytest.raises(FileNotFoundError):
        load_recorded(tmp_path / "missing.tar.gz")


def test_split_is_fixed_and_hash_based():
    # Pinned: changing the rule would silently move test digits into training.
    assert split_of_index(range(10)).tolist() == [1, 0, 2, 0, 0, 1, 2, 0, 0, 2]
    assert split_of_index(30740).tolist() == [2]
    shares = np.bincount(split_of_index(range(20000)), minlength=3) / 20000
    np.testing.assert_allclose(shares, [0.7, 0.1, 0.2], atol=0.01)
    # A path's part does not depend on which others are present.
    assert split_of_index([5, 9]).tolist() == split_of_index(range(10))[[5, 9]].tolist()


def test_resample_path_uses_real_time_stamps():
    t = np.array([0.0, 0.1, 0.4])  # uneven: a gap after the second point
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 3.0]])
    grid, out = resample_path(xy, t, 5)
    np.testing.assert_allclose(grid, [0.0, 0.1, 0.2, 0.3, 0.4])
    np.testing.assert_allclose(out, [[0, 0], [1, 0], [1, 1], [1, 2], [1, 3]], atol=1e-12)


@pytest.fixture(scope="module")
def real_recorded():
    if not (RECORDED.exists() and MNIST_DIR.exists()):
        pytest.skip(f"real data not found at {RECORDED} / {MNIST_DIR} (see docs/MNIST.md)")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the two known clock glitches
        recs = load_recorded(RECORDED)
    images, labels = load_mnist(MNIST_DIR, "train")
    return recs, images, labels


def test_real_recorded_paths_lie_on_their_images(real_recorded):
    recs, images, labels = real_recorded
    assert len(recs) == 4204
    assert sorted({r.label for r in recs}) == list(range(10))
    assert all(r.label == labels[r.image_index] for r in recs)
    assert sum(r.time_repairs for r in recs) == 2
    assert all(np.all(np.diff(r.t_s) > 0) for r in recs)
    sample = recs[::7]
    share = np.mean([share_on_ink(images[r.image_index], r.xy) for r in sample])
    unshifted = np.mean(
        [share_on_ink(images[r.image_index], r.xy - FRAME_OFFSET_PX) for r in sample]
    )
    transposed = np.mean([share_on_ink(images[r.image_index], r.xy[:, ::-1]) for r in sample])
    assert share > 0.86, share
    assert share > unshifted + 0.02 > transposed, (share, unshifted, transposed)
    # Paths belong to their own image, not to any image of the same digit.
    other = np.mean([share_on_ink(images[(r.image_index + 1) % 60000], r.xy) for r in sample])
    assert other < 0.5 * share


# --- traced stroke sequences ----------------------------------------------------------


def _sequence(rows, length=12, leading=False) -> np.ndarray:
    rows = np.asarray(rows, float)
    pad = np.zeros((length - len(rows), 4))
    return np.concatenate([pad, rows] if leading else [rows, pad])


# Two strokes: (5,5) -> (7,5) pen up, then a one-point spur, then (3,8) -> (3,10).
_ROWS = [
    [5, 5, 0, 0], [1, 0, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0],
    [4, 4, 0, 0], [0, 0, 1, 0],
    [-8, -1, 0, 0], [0, 1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1],
]  # fmt: skip


@pytest.mark.parametrize("leading", [False, True])
def test_parse_sequence_strokes_and_padding(leading):
    s = parse_sequence(_sequence(_ROWS, leading=leading), "seq#0")
    assert s.n_strokes == 2 and s.dropped_strokes == 1
    np.testing.assert_array_equal(s.strokes[0], [[4, 4], [5, 4], [6, 4]])  # frame shift -1
    np.testing.assert_array_equal(s.strokes[1], [[2, 7], [2, 8], [2, 9]])


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        (np.zeros((5, 4)), "all padding"),
        (_sequence([[5, 5, 0, 0], [1, 0, 1, 0]]), "no end-of-digit"),
        (_sequence([[5, 5, 0, 0], [1, 0, 1, 1], [1, 1, 0, 0]]), "row 2 holds data after"),
        (_sequence([[5, 5, 0, 0], [1, 0, 0.5, 1]]), "row 1 has eos/eod"),
        (_sequence([[5, 5, 0, 0], [np.nan, 0, 1, 1]]), "row 1 is not finite"),
        (_sequence([[5, 5, 0, 1]]), "no stroke with two distinct points"),
        (np.zeros((5, 3)), r"\[L, 4\]"),
    ],
)
def test_parse_sequence_rejects_broken(rows, message):
    with pytest.raises(ValueError, match="seq#3: .*" + message):
        parse_sequence(rows, "seq#3")


def _npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def _stroke_dir(tmp_path: Path, seqs: np.ndarray, labels: np.ndarray) -> Path:
    d = tmp_path / "strokes"
    d.mkdir()
    _tar_gz(d / "train-padded-trailing.tar.gz", {"train-padded-trailing.npy": _npy_bytes(seqs)})
    _tar_gz(d / "train-labels.tar.gz", {"train-labels.npy": _npy_bytes(labels)})
    return d


def test_load_strokes_from_archives(tmp_path):
    seqs = np.stack([_sequence(_ROWS)] * 3)
    seqs[1, 0, :2] = [6, 6]  # a different start for row 1
    d = _stroke_dir(tmp_path, seqs, np.array([4, 7, 4], np.int32))
    out = load_strokes(d, "train")
    assert [(s.index, s.label) for s in out] == [(0, 4), (1, 7), (2, 4)]
    np.testing.assert_array_equal(out[1].strokes[0][0], [5, 5])
    assert [s.index for s in load_strokes(d, "train", indices=[1])] == [1]
    assert [s.index for s in load_strokes(d, "train", digits=[4])] == [0, 2]
    # The unpacked .npy files work the same.
    u = tmp_path / "unpacked"
    u.mkdir()
    np.save(u / "train-padded-trailing.npy", seqs)
    np.save(u / "train-labels.npy", np.array([4, 7, 4], np.int32))
    assert [s.label for s in load_strokes(u, "train")] == [4, 7, 4]


def test_load_strokes_broken_files_are_named(tmp_path):
    seqs = np.stack([_sequence(_ROWS)] * 3)
    d = _stroke_dir(tmp_path, seqs, np.array([4, 7], np.int32))
    with pytest.raises(ValueError, match=r"train-labels.tar.gz:train-labels.npy: \(2,\) labels"):
        load_strokes(d, "train")
    # A truncated array inside an intact archive.
    blob = _npy_bytes(seqs)[:-100]
    _tar_gz(d / "train-padded-trailing.tar.gz", {"train-padded-trailing.npy": blob})
    with pytest.raises(ValueError, match="train-padded-trailing.npy: data truncated"):
        read_npy(d / "train-padded-trailing.tar.gz")
    # A truncated gzip stream.
    p = d / "train-padded-trailing.tar.gz"
    _tar_gz(
        p, {"train-padded-trailing.npy": _npy_bytes(np.random.default_rng(0).random((50, 117, 4)))}
    )
    p.write_bytes(p.read_bytes()[:-5000])
    with pytest.raises(ValueError, match="train-padded-trailing.tar.gz"):
        read_npy(p)
    # Not an .npy at all.
    _tar_gz(p, {"train-padded-trailing.npy": b"hello, this is no array"})
    with pytest.raises(ValueError, match="not a valid .npy header"):
        read_npy(p)


@_need(STROKES_DIR)
@_need(MNIST_DIR)
@pytest.mark.parametrize("split", ["train", "test"])
def test_real_strokes_lie_on_their_images(split):
    digits = load_strokes(STROKES_DIR, split, indices=range(300))
    images, labels = load_mnist(MNIST_DIR, split)
    assert len(digits) == 300
    assert all(s.label == labels[s.index] for s in digits)
    share = np.mean([share_on_ink(images[s.index], s.points()) for s in digits])
    unshifted = np.mean([share_on_ink(images[s.index], s.points() + 1.0) for s in digits])
    assert share > 0.97, share
    assert unshifted < share - 0.1
    assert max(s.n_strokes for s in digits) >= 3


# --- timing and multi-stroke DMPs -----------------------------------------------------


def test_minimum_jerk_profile():
    u = np.linspace(0, 1, 101)
    s = minimum_jerk(u)
    assert s[0] == 0 and s[-1] == 1 and np.all(np.diff(s) >= 0)
    np.testing.assert_allclose(minimum_jerk(np.array([0.5])), [0.5])
    # Zero velocity at both ends (finite differences).
    assert abs(s[1] - s[0]) < 1e-4 and abs(s[-1] - s[-2]) < 1e-4


_TWO_STROKES = [
    np.array([[6.0, 6.0], [6.0, 16.0], [18.0, 16.0]]),  # "L" of a 4
    np.array([[16.0, 6.0], [16.0, 24.0]]),  # its stem
]


def test_time_strokes_pen_states_and_duration():
    prof = SpeedProfile(pen_speed_px_s=40.0, min_stroke_s=0.1, pen_up_s=0.2)
    t, xyp = time_strokes(_TWO_STROKES, 301, prof)
    total = 22 / 40 + 0.2 + 18 / 40
    assert stroke_duration_s(_TWO_STROKES, prof) == pytest.approx(total)
    assert t[-1] == pytest.approx(total)
    np.testing.assert_allclose(xyp[0], [6, 6, 1])
    np.testing.assert_allclose(xyp[-1], [16, 24, 1])
    up = xyp[:, 2] == 0
    assert pen_segments(xyp[:, 2]) == 2
    # The pen is up exactly during the travel (up to one grid step at each end).
    assert abs(up.mean() * total - 0.2) <= 2 * t[1]
    # The travel is a straight line from the end of stroke 1 to the start of stroke 2.
    travel = xyp[up, :2]
    rel, direction = travel - [18, 16], np.array([16 - 18, 6 - 16])
    d = rel[:, 0] * direction[1] - rel[:, 1] * direction[0]
    np.testing.assert_allclose(d, 0, atol=1e-9)


def test_multi_stroke_round_trip_fit_rollout_pen():
    config = DMPConfig(n_dims=3, scaling="none")
    t, xyp = time_strokes(_TWO_STROKES, 100)
    fit = fit_paths(t[None], xyp[None], config)
    assert fit.params.shape == (1, config.n_params)
    assert fit.error_px[0] < 0.3, fit.error_px
    assert fit.pen_agreement[0] >= 0.97
    from img2dmp.dmp import DMPParams

    params = DMPParams.from_vector(fit.params.astype(np.float64), 25, 3)
    xy, down = pen_rollout(params, t, config)
    assert pen_segments(down[0].astype(float)) == 2
    np.testing.assert_allclose(xy[0, down[0]], xyp[down[0], :2], atol=1.0)
    # The paper's goal-start scaling cannot lift the pen: g - y0 = 0 on that channel.
    flat = fit_paths(t[None], xyp[None], DMPConfig(n_dims=3, scaling="goal-start"))
    assert flat.pen_agreement[0] < fit.pen_agreement[0]
    with pytest.raises(ValueError, match="scaling='none'"):
        PrepareOptions(source="strokes", scaling="goal-start")


# --- prepare --------------------------------------------------------------------------


def test_prepare_on_hand_made_data_keeps_augmented_paths_on_ink(fake_data):
    opt = PrepareOptions(source="recorded", augment=4, n_times=60, seed=3)
    data = prepare_dataset(opt, data_dir=fake_data, progress=False)
    rows = data.meta["rows"]
    copy = np.array(rows["augment_copy"])
    n_train = int((split_of_index(range(12)) == 0).sum())
    assert len(data) == 12 + 4 * n_train
    assert (data.split[copy > 0] == 0).all()
    np.testing.assert_array_equal(data.split[:12], split_of_index(range(12)))
    share = np.array(
        [share_on_ink(i, p) for i, p in zip(data.images, data.trajectories, strict=True)]
    )
    assert share[copy == 0].min() > 0.95
    assert share[copy > 0].mean() > 0.9, share[copy > 0]
    # The copies really moved: paths differ from their originals.
    src = np.array(rows["mnist_index"])
    moved = np.abs(data.trajectories[copy > 0] - data.trajectories[src[copy > 0]]).max()
    assert moved > 0.5
    assert data.fit_error_px.max() < 0.1
    # Same seed, same data; another seed, other transforms.
    again = prepare_dataset(opt, data_dir=fake_data, progress=False)
    np.testing.assert_array_equal(again.trajectories, data.trajectories)


@pytest.mark.parametrize(("size", "mode"), [(40, "scale"), (40, "pad"), (20, "scale")])
def test_prepare_image_size_keeps_paths_on_ink(fake_data, size, mode):
    opt = PrepareOptions(source="recorded", image_size=size, resize_mode=mode, n_times=40)
    data = prepare_dataset(opt, data_dir=fake_data, progress=False)
    assert data.images.shape[1:] == (size, size)
    share = np.mean(
        [share_on_ink(i, p) for i, p in zip(data.images, data.trajectories, strict=True)]
    )
    assert share > 0.9, share
    s, o = data.meta["pixel_scale"], data.meta["pixel_offset"]
    np.testing.assert_allclose(data.trajectories[0, 0], s * _zigzag(0)[0] + o, atol=1e-3)


def test_cli_prepare_writes_a_valid_file_and_reports_bad_input(fake_data, tmp_path, capsys):
    from img2dmp.cli import main

    out = tmp_path / "out" / "rec.safetensors"
    argv = ["prepare", "--data", str(fake_data), "--out", str(out), "--no-progress"]
    assert main([*argv, "--digits", "3", "--dims", "3"]) == 0
    data = load_dataset(out)
    assert set(data.labels.tolist()) == {3} and data.trajectories.shape[-1] == 3
    assert (data.trajectories[..., 2] == 1).all()
    assert data.meta["source"]["kind"] == "mnist-recorded"
    assert "wrote" in capsys.readouterr().out
    bad = fake_data / "mnist" / "train-labels-idx1-ubyte.gz"
    bad.write_bytes(bad.read_bytes()[:-6])
    assert main([*argv, "--force"]) == 2
    assert "train-labels-idx1-ubyte.gz" in capsys.readouterr().err


@_need(RECORDED)
@_need(MNIST_DIR)
def test_prepare_real_recorded_digits_3_and_5():
    opt = PrepareOptions(source="recorded", digits=(3, 5), limit_per_digit=40, augment=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = prepare_dataset(opt, data_dir=DATA, progress=False)
    copy = np.array(data.meta["rows"]["augment_copy"])
    assert set(data.labels.tolist()) == {3, 5} and (copy == 0).sum() == 80
    assert data.fit_error_px[copy == 0].mean() < 0.1
    share = [share_on_ink(i, p) for i, p in zip(data.images, data.trajectories, strict=True)]
    assert np.mean(share) > 0.8


@_need(RECORDED)
@_need(MNIST_DIR)
def test_prepare_duration_normalises_time_and_keeps_paths():
    base = dict(source="recorded", digits=(3,), limit_per_digit=10)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        real = prepare_dataset(PrepareOptions(**base), data_dir=DATA, progress=False)
        norm = prepare_dataset(
            PrepareOptions(**base, duration_s=1.5), data_dir=DATA, progress=False
        )
    durations = real.times[:, -1] - real.times[:, 0]
    assert np.ptp(durations) > 0.1  # people write at different speeds
    np.testing.assert_allclose(norm.times[:, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(norm.times[:, -1], 1.5, rtol=1e-6)
    np.testing.assert_array_equal(norm.trajectories, real.trajectories)
    tau = norm.params[:, 25 * 2]  # the flat vector's tau
    np.testing.assert_allclose(tau, 1.5, rtol=1e-5)
    assert norm.fit_error_px.mean() < 0.1
    with pytest.raises(ValueError, match="duration_s"):
        PrepareOptions(**base, duration_s=0.0)


@_need(STROKES_DIR)
@_need(MNIST_DIR)
def test_prepare_real_strokes_multi_stroke():
    opt = PrepareOptions(source="strokes", limit_per_digit=15, n_times=100)
    data = prepare_dataset(opt, data_dir=DATA, progress=False)
    assert data.trajectories.shape[1:] == (100, 3)
    assert (data.trajectories[..., 2] == 0).any(axis=1).mean() > 0.2  # some pen lifts
    assert data.fit_error_px.mean() < 0.2
    assert data.meta["fit"]["pen_agreement_mean"] > 0.99
    idx = np.array(data.meta["rows"]["mnist_index"])
    np.testing.assert_array_equal(data.split, split_of_index(idx))


def test_idx_gzip_detected_by_content(tmp_path):
    # A raw IDX file named .gz is read as raw; a gzip file without .gz is gunzipped.
    raw = struct.pack(">BBBBi", 0, 0, 8, 1, 2) + b"\x01\x02"
    (tmp_path / "raw.gz").write_bytes(raw)
    (tmp_path / "zipped").write_bytes(gzip.compress(raw))
    for name in ("raw.gz", "zipped"):
        assert read_idx(tmp_path / name, 2049).tolist() == [1, 2]


def test_check_frames_finds_the_corner_convention(tmp_path, capsys):
    from img2dmp.cli import main
    from img2dmp.data.prepare import frame_alignment

    # Thin ink, so that only the right shift puts every point on it.
    fake_data = _make_fake_data(tmp_path / "data", ink_radius=0.75)
    r = frame_alignment(fake_data)["recorded"]
    assert r["best_shift"] == "-0.5,-0.5"
    assert r["share_chosen"] == r["best_share"] > 0.95
    assert max(v for k, v in r["grid"].items() if k != "-0.5,-0.5") < 0.96
    assert r["share_raw"] < r["share_chosen"] - 0.1
    assert main(["prepare", "--check-frames", "--data", str(fake_data), "--no-progress"]) == 0
    assert "recorded" in capsys.readouterr().out


def test_cli_choices_match_the_library():
    from img2dmp.commands import prepare as command
    from img2dmp.data import prepare as library

    assert command.SOURCES == library.SOURCES
    assert command.RESIZE_MODES == library.RESIZE_MODES
    assert Path(command.DEFAULT_DATA_DIR) == library.DEFAULT_DATA_DIR
