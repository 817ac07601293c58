"""Bringing your own data: ``img2dmp import`` of images and pen paths of any classes.

A small set of letters (L, T, V, O) is drawn here from lines and an elliptic arc, as
images of several sizes and both polarities with their pen paths, written as PNG + CSV
(with and without a pen column), JSON (lists and strokes) and NumPy files, in class
folders and in manifests. It is imported, checked (class names, paths on the ink of the
prepared images), trained on for two epochs, evaluated (the tables name the classes) and
predicted from; then bad inputs, each refused in one line naming the file and the value,
exit status 2, the existing output untouched.
"""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageDraw

from img2dmp import cli
from img2dmp.data.images import prepare_image
from img2dmp.data.importer import (
    ImportOptions,
    find_samples,
    import_dataset,
    read_trajectory,
    resample_pen_path,
)
from img2dmp.data.store import DatasetError, DigitData, load_dataset, save_dataset
from img2dmp.metrics import on_ink_share
from img2dmp.predict import load_model

CLASSES = ("L", "O", "T", "V")  # sorted: the labels' order
SIZES = [(96, 80), (150, 150), (64, 120), (200, 160)]  # (W, H) of the images
SPEED_PX_S = 120.0  # pen speed of the drawn letters
PEN_UP_S = 0.15  # pen-up travel between strokes


def _letter(name: str, rng: np.random.Generator) -> list[np.ndarray]:
    """Strokes ``[K, 2]`` of a letter in the unit square (x right, y down), jittered."""
    j = lambda: rng.uniform(-0.03, 0.03, 2)  # noqa: E731
    if name == "L":
        strokes = [np.array([[0.3, 0.15], [0.3, 0.85], [0.72, 0.85]])]
    elif name == "T":
        strokes = [np.array([[0.15, 0.18], [0.85, 0.18]]), np.array([[0.5, 0.18], [0.5, 0.85]])]
    elif name == "V":
        strokes = [np.array([[0.2, 0.15], [0.5, 0.85], [0.8, 0.15]])]
    else:  # O: an elliptic arc with a gap, so that its ends show
        a = np.deg2rad(np.linspace(-70, 250, 40))
        strokes = [np.stack([0.5 + 0.3 * np.cos(a), 0.5 - 0.36 * np.sin(a)], -1)]
    return [s + np.stack([j() for _ in s]) for s in strokes]


def _dense(poly: np.ndarray, step_px: float = 1.5) -> np.ndarray:
    """Points about every ``step_px`` along a polyline (its corners kept)."""
    out = [poly[:1]]
    for a, b in zip(poly[:-1], poly[1:], strict=True):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step_px)))
        out.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    return np.concatenate(out)


def _draw(name: str, k: int, rng) -> tuple[Image.Image, list[np.ndarray]]:
    """A letter as an image of size ``SIZES[k]`` (dark on light, every third light on
    dark) and its strokes ``[K, 2]`` in pixels of that image."""
    w, h = SIZES[k % len(SIZES)]
    strokes = [_dense(s * [w - 1, h - 1]) for s in _letter(name, rng)]
    dark_on_light = k % 3 != 2
    im = Image.new("L", (w, h), 255 if dark_on_light else 0)
    draw = ImageDraw.Draw(im)
    pen = max(3, round(0.07 * min(w, h)))
    for s in strokes:
        draw.line([tuple(p) for p in s], fill=0 if dark_on_light else 255, width=pen, joint="curve")
    return im, strokes


def _timed(strokes: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(xy, t)`` per stroke: the pen moves at ``SPEED_PX_S`` and lifts for ``PEN_UP_S``."""
    out, t0 = [], 0.1
    for s in strokes:
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(s, axis=0), axis=1))])
        t = t0 + arc / SPEED_PX_S
        out.append((s, t))
        t0 = t[-1] + PEN_UP_S
    return out


#: How each letter's trajectory is written (T alternates: CSV with a pen column, JSON strokes).
FORMATS = {"L": "csv", "V": "json", "O": "npy"}


def write_sample(folder: Path, name: str, k: int, fmt: str | None = None) -> tuple[Path, Path]:
    """Letter ``name`` number ``k`` as ``folder/NNN.png`` and its trajectory file."""
    im, strokes = _draw(name, k, np.random.default_rng(1000 * k + ord(name)))
    folder.mkdir(parents=True, exist_ok=True)
    image = folder / f"{k:03d}.png"
    im.save(image)
    fmt = fmt or FORMATS.get(name, "csv-pen" if k % 2 else "json-strokes")
    return image, _write_trajectory(folder / f"{k:03d}", _timed(strokes), fmt)


def _write_trajectory(stem: Path, strokes, fmt: str) -> Path:
    xy = np.concatenate([s for s, _ in strokes])
    t = np.concatenate([t for _, t in strokes])
    if fmt == "csv":
        assert len(strokes) == 1
        path = stem.with_suffix(".csv")
        rows = ["x,y,t"] + [f"{x:.4f},{y:.4f},{tt:.5f}" for (x, y), tt in zip(xy, t, strict=True)]
        path.write_text("\n".join(rows) + "\n")
    elif fmt == "csv-pen":  # pen-up travel recorded as points with pen 0 between strokes
        path = stem.with_suffix(".csv")
        rows = ["t,x,y,pen"]  # any column order
        for i, (s, ts) in enumerate(strokes):
            if i:
                (a, ta), b = (strokes[i - 1][0][-1], strokes[i - 1][1][-1]), s[0]
                for u in (0.25, 0.5, 0.75):
                    p = a + u * (b - a)
                    rows.append(f"{ta + u * (ts[0] - ta):.5f},{p[0]:.4f},{p[1]:.4f},0")
            rows += [f"{tt:.5f},{x:.4f},{y:.4f},1" for (x, y), tt in zip(s, ts, strict=True)]
        path.write_text("\n".join(rows) + "\n")
    elif fmt == "json":
        path = stem.with_suffix(".json")
        path.write_text(
            json.dumps({"x": xy[:, 0].tolist(), "y": xy[:, 1].tolist(), "t": t.tolist()})
        )
    elif fmt == "json-strokes":
        path = stem.with_suffix(".json")
        doc = [
            [[float(x), float(y), float(tt)] for (x, y), tt in zip(s, ts, strict=True)]
            for s, ts in strokes
        ]
        path.write_text(json.dumps(doc))
    else:
        path = stem.with_suffix(".npy")
        np.save(path, np.column_stack([xy, t]))
    return path


def write_letters(root: Path, per_class: int) -> Path:
    """``root/CLASS/NNN.png`` + trajectory for every letter, ``per_class`` of each."""
    for name in CLASSES:
        for k in range(per_class):
            write_sample(root / name, name, k)
    return root


@pytest.fixture(scope="module")
def letters(tmp_path_factory) -> Path:
    return write_letters(tmp_path_factory.mktemp("letters") / "letters", 6)


@pytest.fixture(scope="module")
def imported(letters, tmp_path_factory) -> tuple[Path, DigitData]:
    out = tmp_path_factory.mktemp("data") / "letters.safetensors"
    save_dataset(out, import_dataset(letters, ImportOptions(seed=3)))
    return out, load_dataset(out)


# --- what an import stores ------------------------------------------------------------


def test_import_stores_the_class_names_and_the_paths_on_the_ink(letters, imported):
    path, data = imported
    assert data.class_names == CLASSES and data.meta["class_names"] == list(CLASSES)
    assert len(data) == 24 and data.images.shape == (24, 40, 40)
    rows = data.meta["rows"]
    names = [Path(p).parts[0] for p in rows["image"]]  # stored relative to the folder
    assert [data.label_names[c] for c in data.labels] == names
    assert data.meta["counts_by_class"] == {c: 6 for c in CLASSES}
    # T has two strokes: the data set gets a pen channel, and T keeps two pen-down runs.
    assert data.trajectories.shape[-1] == 3 and data.dmp_config.scaling == "none"
    down = data.trajectories[..., 2] > 0.5
    runs = (down[:, 1:] & ~down[:, :-1]).sum(1) + down[:, 0]
    assert (runs == np.where(np.array(names) == "T", 2, 1)).all()
    # The mapped paths write on the ink of the stored images, measured independently.
    assert on_ink_share(data.images, data.trajectories).min() > 0.9
    # Each image is what predict would make of the file, and the stored map moves the
    # file's points onto the stored path.
    for r in (0, 7, 13, 22):
        image = letters / rows["image"][r]
        assert np.array_equal(data.images[r], prepare_image(image, (40, 40)))
        pen = read_trajectory(letters / rows["trajectory"][r])
        m = np.array(rows["image_to_model"][r])
        first = pen.xy[0] @ m[:, :2].T + m[:, 2]
        assert np.allclose(first, data.trajectories[r, 0, :2], atol=1e-4)
        assert data.times[r, -1] == pytest.approx(pen.t_s[-1] - pen.t_s[0], rel=1e-5)
    assert data.meta["fit"]["mean_error_px"] < 0.5
    counts = data.meta["counts_by_split"]  # per class of 6: 1 test, 1 validation, 4 train
    assert counts == {"train": 16, "validation": 4, "test": 4}
    assert data.meta["source"] == {
        "kind": "import",
        "path": str(letters),
        "samples": 24,
        "skipped": [],
        "skipped_entries": 0,
        "median_duration_s": pytest.approx(np.median(data.times[:, -1]), rel=1e-5),
    }


def test_strokes_resample_with_the_pen_up_between_them(tmp_path):
    image, traj = write_sample(tmp_path, "T", 1)  # CSV with pen-up travel points
    pen = read_trajectory(traj)
    assert pen.n_strokes == 2 and pen.needs_pen and (pen.stroke == -1).sum() == 3
    times, path = resample_pen_path(pen, 200)
    assert times[0] == 0 and times[-1] == pytest.approx(pen.t_s[-1] - pen.t_s[0])
    down = path[:, 2] > 0.5
    assert down[0] and down[-1] and (down[1:] != down[:-1]).sum() == 2  # down, up, down
    # The pen is up strictly inside the travel between the strokes, down elsewhere.
    gap = (times > pen.t_s[pen.stroke == 0][-1] - pen.t_s[0] + 1e-9) & (
        times < pen.t_s[pen.stroke == 1][0] - pen.t_s[0] - 1e-9
    )
    assert not down[gap].any() and down[~gap].all()
    json_pen = read_trajectory(write_sample(tmp_path / "j", "T", 0)[1])  # list of strokes
    assert json_pen.n_strokes == 2 and (json_pen.stroke >= 0).all()
    with pytest.raises(ValueError, match="2 stroke.*become 1 on the grid of 2 instants"):
        resample_pen_path(pen, 2)  # both instants on a stroke: the lift is lost


def test_a_stroke_of_one_point_is_a_dot_of_its_own(tmp_path):
    """A tap of the pen (an i's dot, a diacritic) in any trajectory format: a stroke of
    one point, kept as a stroke of its own and given one instant of the grid."""
    image, _ = write_sample(tmp_path / "T", "T", 0, "json-strokes")
    strokes = json.loads((tmp_path / "T/000.json").read_text())
    x, y, t = strokes[0][len(strokes[0]) // 2]  # on the bar's ink, after the stem
    dot = [[x, y + 1.0, strokes[-1][-1][2] + 0.3]]
    (tmp_path / "T/000.json").write_text(json.dumps([*strokes, dot]))
    as_dict = [{"x": [p[0] for p in s], "y": [p[1] for p in s], "t": [p[2] for p in s]}
               for s in [*strokes, dot]]  # fmt: skip
    (tmp_path / "D").mkdir()
    (tmp_path / "D/000.json").write_text(json.dumps({"strokes": as_dict}))
    (tmp_path / "D/000.png").write_bytes(image.read_bytes())
    for traj in (tmp_path / "T/000.json", tmp_path / "D/000.json"):
        pen = read_trajectory(traj)
        assert pen.n_strokes == 3 and (pen.stroke == 2).sum() == 1
        times, path = resample_pen_path(pen, 60)
        down = path[:, 2] > 0.5
        starts = np.flatnonzero(down & ~np.r_[False, down[:-1]])
        assert len(starts) == 3 and down[starts[-1] :].sum() == 1  # the dot: one instant
        assert path[starts[-1], :2] == pytest.approx([x, y + 1.0])
    data = import_dataset(tmp_path, ImportOptions(n_times=60, val_fraction=0, test_fraction=0))
    assert [len(s) for s in data.meta["stroke_spans"][0]] == [2, 2, 2]  # [first, last] each
    first, last = data.meta["stroke_spans"][0][2]
    assert first == last  # the dot's one instant


def test_manifests_give_classes_splits_and_paths(letters, tmp_path):
    rows = [
        ("L/000.png", "L/000.csv", "L", "train"),
        ("L/001.png", "L/001.csv", "L", "test"),
        ("V/000.png", "V/000.json", "V", "train"),
        ("V/001.png", "V/001.json", "V", "validation"),
        ("O/000.png", "O/000.npy", "O", "train"),
    ]
    manifest = letters / "manifest.csv"  # beside the class folders: paths relative to it
    try:
        with open(manifest, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["image", "trajectory", "class", "split"])
            w.writerows(rows)
        data = import_dataset(manifest, ImportOptions(classes=("V", "L", "O")))
        # a folder import is not disturbed by the manifest beside the class folders
        assert len(find_samples(letters)[0]) == 24
    finally:
        manifest.unlink()
    assert data.class_names == ("V", "L", "O")  # the given order
    assert data.labels.tolist() == [1, 1, 0, 0, 2]
    assert data.split.tolist() == [0, 2, 0, 1, 0] and data.trajectories.shape[-1] == 2
    as_json = tmp_path / "m.json"
    as_json.write_text(
        json.dumps(
            [
                {"image": str(letters / r[0]), "trajectory": str(letters / r[1]), "class": r[2]}
                for r in rows
            ]
        )
    )
    again = import_dataset(as_json, ImportOptions(seed=1, test_fraction=0.0, val_fraction=0.0))
    assert again.class_names == ("L", "O", "V") and (again.split == 0).all()
    assert np.allclose(again.trajectories[0], data.trajectories[0])


def test_augmented_copies_are_seeded_and_training_only(letters, tmp_path):
    manifest = tmp_path / "m.csv"
    manifest.write_text(
        "image,trajectory,class,split\n"
        + "".join(
            f"{letters}/{c}/00{k}.png,{letters}/{c}/00{k}.{f},{c},{s}\n"
            for c, f in (("L", "csv"), ("V", "json"))
            for k, s in ((0, "train"), (1, "test"))
        )
    )
    opt = ImportOptions(augment=3, seed=5)
    a, b = import_dataset(manifest, opt), import_dataset(manifest, opt)
    assert len(a) == 4 + 2 * 3 and np.array_equal(a.images, b.images)
    assert a.meta["rows"]["augment_copy"] == [0, 0, 0, 0, 1, 2, 3, 1, 2, 3]
    assert (a.split[4:] == 0).all() and a.labels[4:].tolist() == [0, 0, 0, 1, 1, 1]
    assert on_ink_share(a.images, a.trajectories).min() > 0.8  # image and path moved together
    c = import_dataset(manifest, ImportOptions(augment=3, seed=6))
    assert not np.array_equal(a.images[4:], c.images[4:])


def test_classes_named_as_digits_make_a_digit_data_set(tmp_path):
    for digit, letter in (("1", "L"), ("7", "V")):
        for k in range(2):
            write_sample(tmp_path / "src" / digit, letter, k)
    data = import_dataset(tmp_path / "src", ImportOptions(test_fraction=0.0, val_fraction=0.0))
    assert data.class_names is None and "class_names" not in data.meta
    assert sorted(data.labels.tolist()) == [1, 1, 7, 7]
    assert data.labels_of_digits([7]).tolist() == [7]


def test_the_file_format_stores_class_names_and_checks_them(imported, tmp_path):
    path, data = imported
    assert data.labels.max() == 3
    meta = dict(data.meta)
    bad = [
        ({"class_names": ["L", "L", "T", "V"]}, "entry 1 repeats 'L'"),
        ({"class_names": ["L", " O", "T", "V"]}, "entry 1 is ' O'"),
        ({"class_names": ["L", 3, "T", "V"]}, "entry 1 is 3, not a string"),
        ({"class_names": "LOTV"}, "must be a list of strings"),
        ({"class_names": ["L", "O", "T"]}, "'labels' row .* is 3: is not a class index 0-2"),
    ]
    for change, message in bad:
        broken = DigitData(**data.arrays(), meta={**meta, **change})
        with pytest.raises(DatasetError, match=message):
            broken.validate("x.safetensors")
    # Without class names the labels are digits, as in every older file.
    digits = DigitData(**data.arrays(), meta={k: v for k, v in meta.items() if k != "class_names"})
    assert digits.validate().label_names[3] == "3"
    digits.labels[0] = 10
    with pytest.raises(DatasetError, match="is 10: is not a digit 0-9"):
        digits.validate()
    with pytest.raises(DatasetError, match="has no class named '2'.*L, O, T, V"):
        data.labels_of_digits([2])


def test_digit_filters_select_classes_by_name_or_refuse(imported, tmp_path):
    from img2dmp.data.synthetic import generate_dataset
    from img2dmp.training import TrainConfig
    from img2dmp.training.data import TrainingData

    path, _ = imported
    cfg = TrainConfig.from_dict({"data": {"path": str(path), "digits": [2]}, "progress": False})
    with pytest.raises(DatasetError, match=r"has no class named '2' .*its classes are L, O, T, V"):
        TrainingData(cfg)
    # A data set of digits filters as before.
    digits = tmp_path / "digits.safetensors"
    data = generate_dataset(4, seed=0, progress=False)
    save_dataset(digits, data)
    cfg = TrainConfig.from_dict(
        {"data": {"path": str(digits), "digits": [2, 3]}, "progress": False}
    )
    feed = TrainingData(cfg)
    expected = np.isin(data.labels, [2, 3]) & (data.split < 2)
    assert len(feed.train_for_epoch(0)) + len(feed.val) == expected.sum()


def test_classes_select_classes_by_name_or_refuse(imported):
    from img2dmp.config import ConfigError
    from img2dmp.training import TrainConfig
    from img2dmp.training.data import TrainingData

    path, _ = imported
    data = load_dataset(path)  # (the fixture's copy is shared with tests that edit it)
    cfg = TrainConfig.from_dict(
        {"data": {"path": str(path), "classes": ["T", "L"]}, "progress": False}
    )
    feed = TrainingData(cfg)
    wanted = np.isin(data.labels, [CLASSES.index("L"), CLASSES.index("T")]) & (data.split < 2)
    assert len(feed.train_for_epoch(0)) + len(feed.val) == wanted.sum() > 0
    cfg = TrainConfig.from_dict({"data": {"path": str(path), "classes": ["X"]}, "progress": False})
    with pytest.raises(DatasetError, match=r"has no class named 'X' \(its classes are L, O, T, V"):
        TrainingData(cfg)
    with pytest.raises(ConfigError, match="data.digits and data.classes both select classes"):
        TrainConfig.from_dict({"data": {"path": str(path), "digits": [2], "classes": ["L"]}})
    with pytest.raises(ConfigError, match="data.classes must be a non-empty list"):
        TrainConfig.from_dict({"data": {"path": str(path), "classes": []}})
    generator = TrainConfig.from_dict({"data": {"classes": ["L"]}, "progress": False})
    with pytest.raises(ConfigError, match=r"generator draws digits 0-9, not \['L'\]"):
        TrainingData(generator)


def _recordings(root: Path, n: int = 6) -> tuple[Path, Path, Path]:
    """``n`` L and T images in ``root/photos``, recorded as the Record page of ``img2dmp
    serve --images`` writes (``root/rec/image_<k>.json``: corner convention, milliseconds,
    ``"Strokes"``, digit 1 for L and 7 for T), and the same samples as a manifest of
    JSON strokes (pixel centres, seconds)."""
    photos, rec = root / "photos", root / "rec"
    photos.mkdir(parents=True)
    rec.mkdir()
    rows = ["image,trajectory,class"]
    for k in range(n):
        name, digit = ("L", 1) if k % 2 == 0 else ("T", 7)
        im, strokes = _draw(name, k, np.random.default_rng(k))
        im.save(photos / f"{name}{k}.png")
        timed = _timed(strokes)
        _write_trajectory(photos / f"{name}{k}", timed, "json-strokes")
        rows.append(f"photos/{name}{k}.png,photos/{name}{k}.json,{digit}")
        points = [(x + 0.5, y + 0.5, 1000 * (t - timed[0][1][0])) for s, ts in timed
                  for (x, y), t in zip(s, ts, strict=True)]  # fmt: skip
        ends = np.cumsum([len(s) for s, _ in timed])
        doc = {
            "Image number": k,
            "Image shape": digit,
            "Path": ", ".join(f"[{float(x)!r}, {float(y)!r}, {float(t)!r}]" for x, y, t in points),
            "Strokes": [
                [int(e - len(s)), int(e - 1)] for e, (s, _) in zip(ends, timed, strict=True)
            ],
            "Image file": f"{name}{k}.png",
            "Image size": [im.height, im.width],
        }
        (rec / f"image_{k}.json").write_text(json.dumps(doc))
    (root / "manifest.csv").write_text("\n".join(rows) + "\n")
    return rec, photos, root / "manifest.csv"


def test_recordings_of_your_own_images_import_like_the_same_paths_in_seconds(tmp_path):
    rec, photos, manifest = _recordings(tmp_path)
    options = ImportOptions(seed=5, augment=1)
    recorded = import_dataset(rec, options, images=photos)
    listed = import_dataset(manifest, options)
    assert recorded.class_names is None and sorted(set(recorded.labels.tolist())) == [1, 7]
    assert recorded.trajectories.shape[-1] == 3  # the T's two strokes need the pen channel
    np.testing.assert_array_equal(recorded.labels, listed.labels)
    np.testing.assert_array_equal(recorded.split, listed.split)
    np.testing.assert_array_equal(recorded.images, listed.images)
    np.testing.assert_allclose(recorded.trajectories, listed.trajectories, atol=1e-4)
    np.testing.assert_allclose(recorded.times, listed.times, atol=1e-6)


def test_recordings_need_their_images_and_say_what_is_wrong(tmp_path, capsys):
    rec, photos, _ = _recordings(tmp_path, n=2)
    with pytest.raises(ValueError, match=r"holds recordings .* --images DIR"):
        import_dataset(rec)
    with pytest.raises(ValueError, match="holds no recordings"):
        import_dataset(tmp_path / "photos", images=photos)
    doc = json.loads((rec / "image_1.json").read_text())
    doc["Strokes"] = [[0, 5], [3, 9]]  # overlapping strokes
    (rec / "image_1.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"image_1.json: \"Strokes\" entry 1 is \[3, 9\]"):
        import_dataset(rec, images=photos)
    del doc["Image file"], doc["Strokes"]  # a recording of an MNIST image
    (rec / "image_1.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="records MNIST image 1 .*img2dmp prepare --recorded"):
        import_dataset(rec, images=photos)
    out = tmp_path / "mine.safetensors"
    argv = ["import", str(rec), "--images", str(photos), "--out", str(out), "--no-progress"]
    assert cli.main([*argv, "--skip-bad"]) == 0
    assert "skipped: " in capsys.readouterr().out and len(load_dataset(out)) == 1


# --- the whole chain on the command line ----------------------------------------------


def test_import_train_evaluate_predict_on_the_command_line(letters, tmp_path, capsys):
    data, run = tmp_path / "letters.safetensors", tmp_path / "run"
    assert cli.main(["import", str(letters), "--out", str(data), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert f"wrote {data}: 24 samples" in out and "classes: L 6, O 6, T 6, V 6" in out
    assert "note:" not in out and "skipped" not in out
    train = ["train", "--data", str(data), "--run-dir", str(run), "--epochs", "2"]
    train += ["--classes", "V,T,O,L"]  # every class, by name (in any order)
    train += ["--no-progress", "--set", "threads=1", "optim.batch_size=8"]
    train += ["model.encoder_layers=[64, 20]", "model.decoder_layers=[35]"]
    assert cli.main(train) == 0, capsys.readouterr().err
    note = capsys.readouterr().err  # the T's two strokes: a stroke model is made for them
    assert "training drawings" in note and "have several strokes (up to 2)" in note
    assert "a stroke model learns one DMP per stroke: --config omniglot" in note
    evaluation = tmp_path / "eval"
    argv = ["evaluate", "--model", str(run), "--data", str(data), "--out", str(evaluation)]
    assert cli.main([*argv, "--figures", "4"]) == 0, capsys.readouterr().err
    table = capsys.readouterr().out.splitlines()
    heads = [ln.split() for ln in table if ln.strip().startswith("class")]
    assert len(heads) == 2 and heads[0][:2] == ["class", "n"]  # both tables, by class
    firsts = [ln.split()[0] for ln in table if ln.split()]
    for name in CLASSES:  # one row per class in each table (the test split has them all)
        assert firsts.count(name) == 2, table
    saved = json.loads((evaluation / "evaluation.json").read_text())
    assert saved["class_names"] == list(CLASSES) and set(saved["per_class"]) == set(CLASSES)
    assert "per_digit" not in saved and set(saved["chamfer"]["per_class"]) == set(CLASSES)
    assert (evaluation / "examples.png").is_file()
    assert cli.main([*argv, "--force", "--digits", "3", "--figures", "0"]) == 2
    assert "has no class named '3'" in capsys.readouterr().err
    assert cli.main([*argv, "--force", "--classes", "O,V", "--figures", "0"]) == 0
    table = capsys.readouterr().out.splitlines()
    firsts = [ln.split()[0] for ln in table if ln.split()]
    assert [firsts.count(n) for n in CLASSES] == [0, 2, 0, 2]  # L O T V: only O and V
    assert cli.main([*argv, "--force", "--classes", "O", "--digits", "3"]) == 2
    assert "not allowed with" in capsys.readouterr().err
    grid = tmp_path / "grid.png"
    preview = ["preview", "--data", str(data), "--out", str(grid), "--per-digit", "2"]
    assert cli.main([*preview, "--classes", "T", "L"]) == 0 and grid.is_file()
    assert cli.main([*preview, "--force", "--digits", "2"]) == 2  # no class is named 2
    assert "has no class named '2'" in capsys.readouterr().err
    model = load_model(run)  # it learnt letters: a V is not cut at its waist into two
    assert model.class_names == CLASSES and model.reads_letters
    for name in ("V", "O"):  # both are two characters by the rules for digits
        assert "several_characters" not in model.predict(letters / name / "001.png").flags
    image = letters / "T" / "001.png"  # any image, of any size
    pred = tmp_path / "pred"
    assert cli.main(["predict", "--model", str(run), str(image), "--out", str(pred)]) == 0
    text = (pred / "001_dmp.json").read_text()  # the DMP file's layout is predict's own
    assert json.loads(text) and "NaN" not in text and "Infinity" not in text


# --- bad input: one line naming the file and the value, exit 2, the output untouched ---


@pytest.fixture(scope="module")
def small_source(tmp_path_factory) -> Path:
    """Two letters of two classes: L (CSV x,y,t) and T (JSON strokes, CSV with pen)."""
    root = tmp_path_factory.mktemp("small") / "src"
    for name in ("L", "T"):
        for k in range(2):
            write_sample(root / name, name, k)
    return root


def _edit_csv(path: Path, line: int, column: str, value: str) -> None:
    """Set ``column`` on ``line`` (1 = the header) of a CSV file."""
    rows = [r.split(",") for r in path.read_text().splitlines()]
    rows[line - 1][rows[0].index(column)] = value
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")


def _move_x(path: Path, by: float) -> None:
    rows = path.read_text().splitlines()
    moved = [f"{float(x) + by},{y},{t}" for x, y, t in (r.split(",") for r in rows[1:])]
    path.write_text("\n".join([rows[0], *moved]) + "\n")


def _manifest(root: Path, text: str) -> Path:
    path = root / "m.csv"
    path.write_text(text)
    return path


M_HEAD = "image,trajectory,class,split\n"
M_ROW = "L/000.png,L/000.csv,L,train\n"

#: (case, edit of the source returning the SOURCE argument or None, extra options,
#:  text the error line must hold: the file, the field and the value).
BAD = [
    (
        "missing trajectory",
        lambda r: (r / "L/001.csv").unlink(),
        [],
        ["L/001.png", "no trajectory file 001.csv"],
    ),
    ("missing image", lambda r: (r / "L/001.png").unlink(), [], ["L/001.csv", "no image 001.png"]),
    (
        "unreadable image",
        lambda r: (r / "L/000.png").write_bytes(b"\x89PNG not really"),
        [],
        ["L/000.png", "cannot decode image file"],
    ),
    (
        "blank image",
        lambda r: Image.new("L", (60, 50), 255).save(r / "L/000.png"),
        [],
        ["L/000.png", "shows no ink"],
    ),
    (
        "NaN",
        lambda r: _edit_csv(r / "L/000.csv", 4, "x", "nan"),
        [],
        ["L/000.csv", "line 4: field 'x' is nan"],
    ),
    (
        "not a number",
        lambda r: _edit_csv(r / "L/000.csv", 5, "y", "1,5"),
        [],
        ["L/000.csv", "line 5 has 4 fields"],
    ),
    (
        "text for a number",
        lambda r: _edit_csv(r / "L/000.csv", 5, "y", "abc"),
        [],
        ["L/000.csv", "line 5: field 'y' is 'abc', not a number"],
    ),
    (
        "time going back",
        lambda r: _edit_csv(r / "L/000.csv", 6, "t", "0.0"),
        [],
        ["L/000.csv", "field 't' does not increase at line 6", "then 0.0"],
    ),
    (
        "too few points",
        lambda r: (r / "L/000.csv").write_text("x,y,t\n3,4,0\n"),
        [],
        ["L/000.csv", "has 1 point(s)"],
    ),
    (
        "bad header",
        lambda r: (r / "L/000.csv").write_text("x,y,time\n1,2,0\n2,3,1\n"),
        [],
        ["L/000.csv", "header is 'x,y,time'"],
    ),
    (
        "pen value",
        lambda r: _edit_csv(r / "T/001.csv", 3, "pen", "2"),
        [],
        ["T/001.csv", "line 3: field 'pen' is 2"],
    ),
    (
        "empty stroke of lists",
        lambda r: (r / "T/000.json").write_text(
            '[[[5, 5, 0], [30, 5, 0.2]], {"x": [], "y": [], "t": []}]'
        ),  # fmt: skip
        [],
        ["T/000.json", "stroke 1 has no points; a stroke needs at least one"],
    ),
    (
        "path off the image",
        lambda r: _move_x(r / "L/000.csv", 400.0),
        [],
        ["L/000.csv", "line 2 (x=", "lies outside the 96 x 80 image", "L/000.png"],
    ),
    (
        "path off the ink",
        lambda r: _move_x(r / "L/000.csv", 28.0),
        [],
        ["L/000.csv", "of its pen-down path lies on the ink of", "L/000.png"],
    ),
    (
        "unknown class",
        None,
        ["--classes", "L"],
        ["T/000.json", "class 'T' is not one of the classes ['L']"],
    ),
    (
        "strokes in d = 2",
        None,
        ["--dims", "2"],
        ["T/000.json", "lifts the pen (2 stroke(s))", "--dims 3"],
    ),
    (
        "stray file",
        lambda r: (r / "L/notes.txt").write_text("x"),
        [],
        ["L/notes.txt", "neither an image"],
    ),
    (
        "npy of 2 columns",
        lambda r: ((r / "L/000.csv").unlink(), np.save(r / "L/000.npy", np.zeros((5, 2)))),
        [],
        ["L/000.npy", "has shape [5, 2]"],
    ),
    (
        "invalid JSON",
        lambda r: (r / "T/000.json").write_text("[[1, 2,"),
        [],
        ["T/000.json", "not valid JSON"],
    ),
    (
        "JSON lists of two lengths",
        lambda r: (r / "T/000.json").write_text('{"x": [1, 2, 3], "y": [1, 2], "t": [0, 1, 2]}'),
        [],
        ["T/000.json", "differ in length", "'y': 2"],
    ),
    (
        "JSON text for a number",
        lambda r: (r / "T/000.json").write_text('{"x": [1, "2"], "y": [1, 2], "t": [0, 1]}'),
        [],
        ["T/000.json", "field 'x' point 1 is '2', not a number"],
    ),
    ("no class folders", lambda r: r / "L", [], ["/L: holds no class folders"]),
    (
        "manifest split",
        lambda r: _manifest(r, M_HEAD + "L/000.png,L/000.csv,L,dev\n"),
        [],
        ["m.csv: row 1: field 'split' is 'dev'"],
    ),
    (
        "manifest columns",
        lambda r: _manifest(r, "image,trajectory,label\n" + "L/000.png,L/000.csv,L\n"),
        [],
        ["m.csv: has the columns ['image', 'trajectory', 'label']"],
    ),
    (
        "manifest image missing",
        lambda r: _manifest(r, M_HEAD + "L/009.png,L/000.csv,L,train\n"),
        [],
        ["m.csv: row 1: image file", "L/009.png does not exist"],
    ),
    (
        "manifest repeats",
        lambda r: _manifest(r, M_HEAD + M_ROW + M_ROW),
        [],
        ["m.csv: row 2: repeats the trajectory of row 1"],
    ),
    (
        "manifest splits mixed",
        lambda r: _manifest(r, M_HEAD + M_ROW + "T/000.png,T/000.json,T,\n"),
        [],
        ["m.csv: row 2: gives no split while other rows do"],
    ),
    (
        "manifest class",
        lambda r: _manifest(r, M_HEAD + "L/000.png,L/000.csv,,train\n"),
        [],
        ["m.csv: row 1: field 'class' is ''"],
    ),
]


@pytest.mark.parametrize(
    ("edit", "options", "expected"), [c[1:] for c in BAD], ids=[c[0] for c in BAD]
)
def test_bad_input_is_one_line_naming_it_exit_2_output_untouched(
    small_source, tmp_path, capsys, edit, options, expected
):
    root = tmp_path / "src"
    shutil.copytree(small_source, root)
    source = (edit(root) if edit is not None else None) or root
    source = source if isinstance(source, Path) else root
    out = tmp_path / "out.safetensors"
    out.write_bytes(b"an earlier data set")
    argv = ["import", str(source), "--out", str(out), "--force", "--no-progress", *options]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("img2dmp import: error: "), err
    for text in expected:
        assert text in err[0], (text, err[0])
    assert out.read_bytes() == b"an earlier data set"
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "out.safetensors",
        "src",
    ]  # no temporaries


def test_skip_bad_leaves_bad_samples_out_and_lists_them(small_source, tmp_path, capsys):
    root = tmp_path / "src"
    shutil.copytree(small_source, root)
    _edit_csv(root / "L/000.csv", 4, "x", "nan")
    (root / "T/000.png").unlink()
    out = tmp_path / "d.safetensors"
    argv = ["import", str(root), "--out", str(out), "--no-progress", "--skip-bad"]
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "wrote" in printed and "2 samples" in printed
    skipped = [ln for ln in printed.splitlines() if ln.startswith("skipped: ")]
    assert len(skipped) == 2 and "T/000.json: no image 000.png" in skipped[0]
    assert "L/000.csv: line 4: field 'x' is nan" in skipped[1]
    data = load_dataset(out)
    assert data.meta["source"]["skipped"] == [s.removeprefix("skipped: ") for s in skipped]
    # The image-less path makes no sample (found with the files); the NaN one failed to read.
    assert data.meta["source"]["skipped_entries"] == 1
    assert (
        "skipped 1 bad sample(s) and 1 file(s) or folder(s) of the source that make no "
        "sample, listed above"
    ) in printed
    assert sorted(data.meta["rows"]["trajectory"]) == ["L/001.csv", "T/001.csv"]
    # An existing output is refused without --force, before anything is read.
    assert cli.main(argv) == 2
    assert "exists; pass --force" in capsys.readouterr().err
    assert cli.main(["import", str(out), "--out", str(out), "--force"]) == 2
    assert "the source itself" in capsys.readouterr().err


def _in_ms(image: Path, traj: Path, folder: Path) -> None:
    """A copy of a sample (CSV ``x,y,t``) in ``folder``, its t in milliseconds."""
    rows = traj.read_text().splitlines()
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(image, folder / image.name)
    (folder / traj.name).write_text(
        "\n".join(
            [rows[0]]
            + [f"{x},{y},{float(t) * 1000:.2f}" for x, y, t in (r.split(",") for r in rows[1:])]
        )
        + "\n"
    )


def test_time_units_and_durations(tmp_path):
    _in_ms(*write_sample(tmp_path / "s" / "L", "L", 0), tmp_path / "ms" / "L")
    opt = {"test_fraction": 0.0, "val_fraction": 0.0}
    seconds = import_dataset(tmp_path / "s", ImportOptions(**opt))
    millis = import_dataset(tmp_path / "ms", ImportOptions(time_unit="ms", **opt))
    assert np.allclose(seconds.times, millis.times, atol=1e-5)
    fixed = import_dataset(tmp_path / "s", ImportOptions(duration_s=2.0, **opt))
    assert fixed.times[0, -1] == pytest.approx(2.0) and np.allclose(
        fixed.trajectories, seconds.trajectories
    )
    with pytest.raises(ValueError, match="time_unit must be one of"):
        ImportOptions(time_unit="min")
    with pytest.raises(ValueError, match=r"val_fraction \+ test_fraction must be < 1"):
        ImportOptions(val_fraction=0.5, test_fraction=0.5)


def test_a_class_given_that_no_sample_has_is_kept_and_noted(small_source, tmp_path, capsys):
    out = tmp_path / "c.safetensors"
    argv = ["import", str(small_source), "--out", str(out), "--no-progress"]
    assert cli.main([*argv, "--classes", "T,ghost,L"]) == 0  # the label order is kept
    printed = capsys.readouterr().out
    assert "classes: T 2, ghost 0, L 2" in printed
    assert "note: no sample has the class(es) 'ghost' given (--classes)" in printed
    data = load_dataset(out)
    assert data.class_names == ("T", "ghost", "L") and set(data.labels) == {0, 2}
    assert data.meta["counts_by_class"] == {"T": 2, "ghost": 0, "L": 2}
    assert cli.main([*argv, "--force", "--classes", "T,L"]) == 0
    assert "note:" not in capsys.readouterr().out


def test_seconds_read_as_milliseconds_are_noted_not_refused(tmp_path, capsys):
    for k in range(2):
        write_sample(tmp_path / "s" / "L", "L", k)
    out = tmp_path / "s.safetensors"
    argv = ["import", str(tmp_path / "s"), "--out", str(out), "--no-progress", "--force"]
    argv += ["--val-fraction", "0", "--test-fraction", "0"]
    assert cli.main(argv) == 0
    assert "note:" not in capsys.readouterr().out  # seconds read as seconds
    assert cli.main([*argv, "--time-unit", "ms"]) == 0
    printed = capsys.readouterr().out
    assert "(t read in milliseconds), implausibly short for handwriting (less than 0.1 s" in printed
    assert "if the files' t are seconds, import again without --time-unit ms" in printed
    assert load_dataset(out).meta["source"]["median_duration_s"] < 0.1


def test_milliseconds_read_as_seconds_are_noted_not_refused(tmp_path, capsys):
    for k in range(2):
        _in_ms(*write_sample(tmp_path / "s" / "L", "L", k), tmp_path / "ms" / "L")
    out = tmp_path / "ms.safetensors"
    argv = ["import", str(tmp_path / "ms"), "--out", str(out), "--no-progress", "--force"]
    argv += ["--val-fraction", "0", "--test-fraction", "0"]
    assert cli.main(argv) == 0  # a note, not a refusal: the unit is the user's to say
    printed = capsys.readouterr().out
    assert "implausibly long for handwriting (more than 60 s" in printed
    assert "--time-unit ms" in printed
    assert load_dataset(out).meta["source"]["median_duration_s"] > 60
    for more in (["--time-unit", "ms"], ["--duration", "2"]):  # said, or made irrelevant
        assert cli.main([*argv, *more]) == 0
        assert "note:" not in capsys.readouterr().out
    assert cli.main([*argv[:1], str(tmp_path / "s"), *argv[2:]]) == 0  # seconds: no note
    assert "note:" not in capsys.readouterr().out


def test_poor_dmp_fits_are_reported_with_their_remedy(tmp_path, capsys):
    folder = tmp_path / "src" / "circle"
    folder.mkdir(parents=True)
    for k in range(2):  # closed circles: start = goal, where goal-start scaling fails
        a = np.linspace(0.0, 2 * np.pi, 120)
        x, y = 60 + 40 * np.cos(a + k), 60 + 40 * np.sin(a + k)
        im = Image.new("L", (120, 120), 255)
        ImageDraw.Draw(im).line(list(zip(x, y, strict=True)), fill=0, width=8, joint="curve")
        im.save(folder / f"{k}.png")
        np.save(folder / f"{k}.npy", np.column_stack([x, y, np.linspace(0, 1.5, 120)]))
    out = tmp_path / "c.safetensors"
    argv = ["import", str(tmp_path / "src"), "--out", str(out), "--no-progress", "--force"]
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "note: 2 DMP fit(s) are off by more than 1 px" in printed and "--scaling none" in printed
    assert "stroke model" not in printed  # one stroke each: nothing to say of stroke models
    assert load_dataset(out).meta["fit"]["poor"]["rows"] == 2
    assert cli.main([*argv, "--scaling", "none"]) == 0
    assert "note:" not in capsys.readouterr().out
    assert load_dataset(out).meta["fit"]["max_error_px"] < 0.5
