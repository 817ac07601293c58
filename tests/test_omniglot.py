"""Omniglot as a source of ``img2dmp import`` (issue 32, parts 1-3).

Small Omniglot trees are written here in Omniglot's layout and formats (a PNG per
drawing, black ink on white; a stroke file of lines ``x,y,t`` with y pointing up, t in
ms, ``START`` and ``BREAK``), as folders and as zips the way Omniglot's are packed (one
top folder, ``__MACOSX`` and ``.DS_Store`` beside the drawings). They are imported from
the command line and checked: classes ``alphabet/character``, the split by drawer,
character or alphabet, every stroke and dot kept with its span of instants, the same data
set from folders and zips; then the bad input of the issue, each imported by its rule or
refused in one line naming the file and the line. One test reads the real data when it is
there (``../shared/data/omniglot``).
"""

from __future__ import annotations

import shutil
import unicodedata
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageDraw

from img2dmp import cli
from img2dmp.data.importer import ImportOptions, find_samples, import_dataset, import_samples
from img2dmp.data.omniglot import DRAWER_SPLITS, parse_strokes
from img2dmp.data.store import SPLITS, load_dataset
from img2dmp.metrics import bilinear, on_ink_share

SIDE = 105  # Omniglot's images
REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "omniglot"
STEP_MS = 16  # the tablet's sampling, about 60 Hz


def _shape(character: int, drawer: int) -> list[np.ndarray]:
    """Strokes ``[K, 2]`` (x = column, y = row) of a character as a drawer draws it: even
    characters a bar, a dot and a second bar, odd ones a hook and a short tick of 3
    points."""
    rng = np.random.default_rng(100 * character + drawer)
    j = rng.uniform(-3, 3, 2)
    if character % 2 == 0:
        bar = np.linspace([25, 35], [80, 35 + 4 * character], 30) + j
        low = np.linspace([25, 60], [80, 60], 20) + j
        return [bar, np.array([[52.0, 80.0]]) + j, low]
    hook = np.concatenate(
        [np.linspace([30, 25], [30, 80], 25), np.linspace([30, 80], [75, 80], 20)]
    )
    return [hook + j, np.array([[60.0, 40.0], [63.0, 44.0], [66.0, 48.0]]) + j]


def _stroke_text(strokes: list[np.ndarray], *, repeat_every: int = 0) -> str:
    """An Omniglot stroke file: y up (-row), t in ms; with ``repeat_every`` every so many
    points a stamp repeats the one before (two points logged in one millisecond)."""
    lines, t = ["START"], 0
    for s in strokes:
        for k, (x, y) in enumerate(s):
            if not (repeat_every and k and k % repeat_every == 0):
                t += STEP_MS
            lines.append(f"{x:.6f},{-y:.6f},{t}")
        lines.append("BREAK")
        t += 300  # the pen lifts
    return "\n".join(lines) + "\n"


def _image(strokes: list[np.ndarray], shift=(0.0, 0.0)) -> Image.Image:
    im = Image.new("1", (SIDE, SIDE), 1)
    draw = ImageDraw.Draw(im)
    for s in strokes:
        s = s + shift
        if len(s) == 1:
            (x, y) = s[0]
            draw.ellipse([x - 2, y - 2, x + 2, y + 2], fill=0)
        else:
            draw.line([tuple(p) for p in s], fill=0, width=3, joint="curve")
    return im


def write_tree(root: Path, alphabets=("Alpha", "Beta"), characters=2, drawers=20) -> Path:
    """``root/images_test`` and ``root/strokes_test`` in Omniglot's layout."""
    for a, alphabet in enumerate(alphabets):
        for c in range(characters):
            number = 100 * (a + 1) + c + 1
            folder = Path(alphabet) / f"character{c + 1:02d}"
            for d in range(1, drawers + 1):
                strokes = _shape(c, d)
                write_drawing(root, folder / f"{number:04d}_{d:02d}", strokes)
    return root


def write_drawing(root: Path, stem: Path, strokes, text: str | None = None, shift=(0, 0)):
    """One drawing: its image and its stroke file (``text``, else written from it)."""
    image = root / "images_test" / stem.with_suffix(".png")
    image.parent.mkdir(parents=True, exist_ok=True)
    _image(strokes, shift).save(image)
    trajectory = root / "strokes_test" / stem.with_suffix(".txt")
    trajectory.parent.mkdir(parents=True, exist_ok=True)
    trajectory.write_text(text if text is not None else _stroke_text(strokes, repeat_every=7))
    return image, trajectory


def zip_tree(folder: Path, target: Path) -> Path:
    """``folder`` as Omniglot packs it: under a top folder of its name, with the macOS
    junk beside."""
    with zipfile.ZipFile(target, "w") as z:
        z.writestr(f"{folder.name}/.DS_Store", b"\0\0\0\1Bud1")
        z.writestr(f"__MACOSX/{folder.name}/._.DS_Store", b"\0\5\26\7")
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                z.write(p, f"{folder.name}/{p.relative_to(folder).as_posix()}")
    return target


@pytest.fixture(scope="module")
def tree(tmp_path_factory) -> Path:
    return write_tree(tmp_path_factory.mktemp("omniglot") / "omniglot")


def _import(source, out: Path, *extra) -> int:
    return cli.main(["import", str(source), "--out", str(out), "--no-progress", *extra])


@pytest.fixture(scope="module")
def imported(tree, tmp_path_factory):
    out = tmp_path_factory.mktemp("data") / "omniglot.safetensors"
    assert _import(tree, out) == 0
    return load_dataset(out)


# --- the source: classes, splits, every stroke ----------------------------------------


def test_a_folder_of_omniglot_trees_imports_with_classes_drawers_and_every_stroke(tree, imported):
    data = imported
    names = [f"{a}/character{c:02d}" for a in ("Alpha", "Beta") for c in (1, 2)]
    assert list(data.class_names) == names and len(data) == 80
    assert data.meta["counts_by_split"] == {"train": 60, "validation": 8, "test": 12}
    assert data.meta["source"]["format"] == "omniglot"
    assert data.meta["source"]["split_by"] == "drawer" and data.meta["source"]["shifted"] == {}
    for r, rel in enumerate(data.meta["rows"]["trajectory"]):
        drawer = int(Path(rel).stem.split("_")[1])
        assert data.split[r] == SPLITS[DRAWER_SPLITS[drawer]], rel
        assert rel.startswith("strokes_test/") and data.label_names[data.labels[r]] in rel
        pen = parse_strokes((tree / rel).read_text(), rel)
        spans = data.stroke_spans(r)
        assert len(spans) == pen.n_strokes == (3 if "character01" in rel else 2)
        m = np.array(data.meta["rows"]["image_to_model"][r])
        for k, (a, b) in enumerate(spans):
            own = pen.xy[pen.stroke == k]
            if len(own) == 1:  # a dot: one instant, where the dot is, and on the image
                dot = data.trajectories[r, a, :2]
                assert a == b and np.allclose(dot, own[0] @ m[:, :2].T + m[:, 2])
                # (the images are read without the paper cleaning for photos)
                assert bilinear(data.images[r][None], dot[None, None])[0, 0] > 0.5
            else:
                assert b - a + 1 >= 3
    # The pen is down exactly at the spans' instants; the paths write on the ink.
    assert on_ink_share(data.images, data.trajectories).min() > 0.9
    assert data.meta["fit"]["mean_error_px"] < 0.5


def _zipped(tree: Path, zips: Path) -> Path:
    """``zips`` made, holding ``tree``'s two folders as the zips Omniglot distributes."""
    zips.mkdir()
    for name in ("images_test", "strokes_test"):
        zip_tree(tree / name, zips / f"{name}.zip")
    return zips


def test_zips_as_distributed_import_the_same_as_their_folders(tree, imported, tmp_path):
    zips = _zipped(tree, tmp_path / "zips")
    out = tmp_path / "z.safetensors"
    assert _import(zips, out) == 0
    data = load_dataset(out)
    for name in ("images", "trajectories", "times", "labels", "split"):
        assert np.array_equal(getattr(data, name), getattr(imported, name)), name
    assert data.meta["stroke_spans"] == imported.meta["stroke_spans"]
    first = data.meta["rows"]["image"][0]
    assert first == "images_test.zip/images_test/Alpha/character01/0101_01.png"
    # A strokes zip given alone finds its images beside it; a strokes folder takes them
    # from --images.
    assert _import(zips / "strokes_test.zip", tmp_path / "a.safetensors") == 0
    assert np.array_equal(load_dataset(tmp_path / "a.safetensors").times, imported.times)
    elsewhere = tmp_path / "elsewhere"
    shutil.copytree(tree / "strokes_test", elsewhere / "strokes_test")
    argv = ["--images", str(zips / "images_test.zip")]
    assert _import(elsewhere / "strokes_test", tmp_path / "b.safetensors", *argv) == 0
    assert np.array_equal(load_dataset(tmp_path / "b.safetensors").images, imported.images)


def _rezip(source: Path, target: Path, rename) -> Path:
    """The zip ``source`` written again with every member's name passed through
    ``rename``."""
    with zipfile.ZipFile(source) as zi, zipfile.ZipFile(target, "w") as zo:
        for info in zi.infolist():
            zo.writestr(rename(info.filename), zi.read(info))
    return target


def test_zips_repacked_deeper_or_with_macos_names_import_the_same(tree, imported, tmp_path):
    """A user's own zips: the tree one folder deeper (GitHub's omniglot-master/python/),
    and a strokes zip re-packed on macOS (accents as combining characters, NFD) beside
    images named in NFC."""
    zips = _zipped(tree, tmp_path / "zips")
    deep, accents = tmp_path / "deep", tmp_path / "accents"
    deep.mkdir()
    accents.mkdir()
    for name in ("images_test", "strokes_test"):
        _rezip(zips / f"{name}.zip", deep / f"{name}.zip", lambda n: f"omniglot-master/python/{n}")
    for name, form in (("images_test", "NFC"), ("strokes_test", "NFD")):
        spelt = unicodedata.normalize(form, "Bêta")
        _rezip(
            zips / f"{name}.zip", accents / f"{name}.zip", lambda n, s=spelt: n.replace("Beta", s)
        )
    for source in (deep, accents):
        out = tmp_path / f"{source.name}.safetensors"
        assert _import(source, out) == 0, source
        data = load_dataset(out)
        for name in ("images", "trajectories", "labels", "split"):
            assert np.array_equal(getattr(data, name), getattr(imported, name)), (source, name)
    assert "Bêta/character01" in data.class_names  # NFC, as every class name is stored


def test_an_empty_character_folder_is_refused_by_name_once(tree, tmp_path, capsys):
    root = tmp_path / "o"
    shutil.copytree(tree, root)
    for name in ("images_test", "strokes_test"):
        (root / name / "Alpha" / "character09").mkdir()
    assert _import(root, tmp_path / "a.safetensors") == 2
    err = capsys.readouterr().err
    assert "strokes_test/Alpha/character09: a character folder without drawings" in err
    assert _import(root, tmp_path / "a.safetensors", "--skip-bad") == 0
    printed = capsys.readouterr().out
    assert printed.count("character09") == 1 and "skipped 1 file(s) or folder(s)" in printed
    # The same in zips (their folder entries), one of them only empty.
    zips = _zipped(root, tmp_path / "zips")
    with zipfile.ZipFile(zips / "strokes_test.zip", "a") as z:
        z.writestr("strokes_test/Beta/character07/", b"")
    assert _import(zips, tmp_path / "z.safetensors") == 2
    err = capsys.readouterr().err
    assert "strokes_test.zip/strokes_test/Beta/character07/: a character folder without" in err


def test_an_omniglot_path_off_its_ink_is_questioned_in_omniglots_frame(tmp_path, capsys):
    """A stroke file 30 px right of its image's ink (within the border's tolerance): the
    question names Omniglot's y pointing up, not the y down of other files."""
    root = tmp_path / "o"
    write_drawing(root, Path("A/character01/0101_01"), _shape(1, 1))
    moved = [s + (30.0, 0.0) for s in _shape(1, 1)]
    (root / "strokes_test/A/character01/0101_01.txt").write_text(_stroke_text(moved))
    assert _import(root, tmp_path / "a.safetensors") == 2
    err = capsys.readouterr().err
    assert "of its pen-down path lies on the ink of" in err
    assert "y = -row (y up, as Omniglot's stroke files have it)?" in err
    assert "y = row (y down)" not in err


def test_a_split_by_alphabet_with_nothing_held_out_says_which_fraction_would(tmp_path, capsys):
    root = write_tree(tmp_path / "o", alphabets=("A", "B", "C"), characters=1, drawers=2)
    assert _import(root, tmp_path / "a.safetensors", "--split-by", "alphabet") == 0
    out = capsys.readouterr().out
    assert "validation 0, test 2" in out  # 0.2 of 3 alphabets rounds to 1, 0.1 to none
    assert "note: no drawing in validation: --split-by alphabet draws --val-fraction 0.1" in out
    assert "of 3 alphabet(s)" in out and "--val-fraction 0.34 puts one there" in out
    argv = ["--split-by", "alphabet", "--val-fraction", "0.34"]
    assert _import(root, tmp_path / "b.safetensors", *argv) == 0
    out = capsys.readouterr().out
    assert "validation 2, test 2" in out and "no drawing in" not in out


def test_omniglots_images_or_other_zips_as_source_say_what_to_give(tree, tmp_path, capsys):
    zips = _zipped(tree, tmp_path / "zips")
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(zips / "images_test.zip", alone)
    with zipfile.ZipFile(tmp_path / "omniglot-master.zip", "w") as z:
        z.write(zips / "images_test.zip", "omniglot-master/python/images_test.zip")
    cases = [
        (zips / "images_test.zip", "images_test.zip: Omniglot's images; import its strokes, "),
        (tree / "images_test", "images_test: Omniglot's images; import its strokes, "),
        (alone, "holds Omniglot's images_test.zip but no strokes_test (folder or .zip)"),
        (alone / "images_test.zip", "images_test.zip: Omniglot's images without their strokes"),
        (tmp_path / "omniglot-master.zip", "a zip file is read only as Omniglot's strokes_NAME"),
    ]
    for source, expected in cases:
        assert _import(source, tmp_path / "x.safetensors") == 2, source
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and expected in err[0], (source, err)
    (alone / "images_test.zip").rename(alone / "omniglot-master.zip")
    assert _import(alone, tmp_path / "x.safetensors") == 2
    err = capsys.readouterr().err
    assert "zip files (omniglot-master.zip) are read only as Omniglot's images_NAME.zip" in err


def test_a_half_unzipped_folder_beside_its_zip_is_named_with_the_missing_file(tree, tmp_path):
    """The folder wins over the zip of its name: a file the folder lacks is named with
    where it was looked for, and that the zip beside it was not read."""
    root = tmp_path / "o"
    root.mkdir()
    for name in ("images_test", "strokes_test"):
        zip_tree(tree / name, root / f"{name}.zip")
    shutil.copytree(tree / "strokes_test" / "Alpha", root / "strokes_test" / "Alpha")
    with pytest.raises(FileNotFoundError) as e:
        find_samples(root)
    assert str(e.value).startswith(f"{root}/images_test.zip/images_test/Beta/character01/")
    assert str(e.value).endswith(
        f"no stroke file 0201_01.txt in {root}/strokes_test (the folder is read, not "
        "strokes_test.zip beside it)"
    )


def test_a_split_inside_another_as_omniglot_ships_them_is_refused_saying_what_to_do(
    tree, tmp_path, capsys
):
    """Omniglot's python/ folder holds background and its parts small1 and small2: the
    same characters in two pairs."""
    root = tmp_path / "python"
    root.mkdir()
    for name in ("images", "strokes"):
        zip_tree(tree / f"{name}_test", root / f"{name}_background.zip")
        shutil.copytree(
            tree / f"{name}_test" / "Alpha", root / f"{name}_background_small1" / "Alpha"
        )
    assert _import(root, tmp_path / "a.safetensors") == 2
    err = capsys.readouterr().err
    assert "strokes_background_small1: holds the character Alpha/character01 that" in err
    assert "are parts of background); import one of them (SOURCE strokes_NAME), or a" in err
    assert _import(root / "strokes_background_small1", tmp_path / "b.safetensors") == 0


def test_the_copies_experiment_writes_every_alphabet_again_from_folders_or_zips(
    tree, imported, tmp_path, experiment_script, capsys
):
    """``experiments/omniglot_copies.py`` (a larger source for timing a recipe): each
    alphabet three times under new names, the same drawings, from folders or zips."""
    mod = experiment_script("omniglot_copies")
    zips = _zipped(tree, tmp_path / "zips")
    for source in (tree, zips):
        out = tmp_path / f"x3_{source.name}"
        assert mod.main(["--omniglot", str(source), "--copies", "3", "--out", str(out)]) == 0
        assert not out.with_name(out.name + ".partial").exists()
        assert _import(out, tmp_path / "x3.safetensors", "--force") == 0
        data = load_dataset(tmp_path / "x3.safetensors")
        assert len(data) == 3 * len(imported)
        names = [f"{a}_copy{k}/character{c:02d}" for a in ("Alpha", "Beta") for k in (1, 2, 3)
                 for c in (1, 2)]  # fmt: skip
        assert sorted(data.class_names) == sorted(names)
        copy2 = np.isin(data.labels, [i for i, n in enumerate(data.class_names) if "_copy2/" in n])
        assert np.array_equal(data.trajectories[copy2], imported.trajectories)
        assert np.array_equal(data.split[copy2], imported.split)
    capsys.readouterr()
    assert mod.main(["--omniglot", str(tree), "--out", str(out)]) == 2  # OUT exists
    assert f"{out} exists (--force replaces it)" in capsys.readouterr().err
    assert mod.main(["--omniglot", str(zips), "--copies", "0",
                     "--out", str(tmp_path / "none")]) == 2  # fmt: skip
    assert "--copies must be >= 1, got 0" in capsys.readouterr().err
    assert not (tmp_path / "none").exists() and not (tmp_path / "none.partial").exists()
    (tmp_path / "empty").mkdir()
    assert mod.main(["--omniglot", str(tmp_path / "empty"), "--out", str(tmp_path / "none")]) == 2
    assert "no images_NAME / strokes_NAME folder or zip in it" in capsys.readouterr().err


def test_the_copies_experiment_with_transforms_writes_new_characters_on_their_ink(
    tree, imported, tmp_path, experiment_script
):
    """``--transforms``: copies 2, 3, 4 mirrored left-right, upside down, turned half
    round; each drawing keeps its strokes and their count, its path lies on its image's
    ink without the importer's shift, and the imported images are the original's
    mirrored."""
    mod = experiment_script("omniglot_copies")
    out = tmp_path / "x4t"
    argv = ["--omniglot", str(tree), "--copies", "4", "--transforms", "--out", str(out)]
    assert mod.main(argv) == 0
    png = Path("Alpha/character01/0101_03.png")
    original = np.array(Image.open(tree / "images_test" / png))
    flips = {1: original, 2: original[:, ::-1], 3: original[::-1], 4: original[::-1, ::-1]}
    for k, want in flips.items():
        got = np.array(
            Image.open(out / "images_test" / f"Alpha_copy{k}" / png.relative_to("Alpha"))
        )
        assert np.array_equal(got, want), k
    assert _import(out, tmp_path / "x4t.safetensors") == 0
    data = load_dataset(tmp_path / "x4t.safetensors")
    assert len(data) == 4 * len(imported) and data.meta["source"]["shifted"] == {}
    assert on_ink_share(data.images, data.trajectories).min() > 0.9
    spans = data.meta["stroke_spans"]
    counts = {rel.split("/", 1)[1]: len(spans[r]) for r, rel in
              enumerate(imported.meta["rows"]["trajectory"])}  # fmt: skip
    for r, rel in enumerate(data.meta["rows"]["trajectory"]):
        alphabet, rest = rel.split("/", 2)[1:]
        assert len(spans[r]) == counts[f"{alphabet.split('_copy')[0]}/{rest}"], rel
    copy2 = [i for i, n in enumerate(data.class_names) if n.startswith("Alpha_copy2/")]
    first = [i for i, n in enumerate(data.class_names) if n.startswith("Alpha_copy1/")]
    mirrored, plain = (data.images[np.isin(data.labels, c)] for c in (copy2, first))
    # (framed to within half a pixel of a mirror image)
    assert np.abs(mirrored - plain[..., ::-1]).mean() < 0.5 * np.abs(mirrored - plain).mean()


def test_a_split_by_drawer_without_validation_or_test_drawers_says_so(tree, tmp_path, capsys):
    few = write_tree(tmp_path / "few", characters=1, drawers=5)
    assert _import(few, tmp_path / "few.safetensors") == 0
    out = capsys.readouterr().out
    assert "(train 10, validation 0, test 0)" in out
    assert "note: no drawing in validation or test: the split by drawer puts" in out
    assert _import(tree, tmp_path / "all.safetensors") == 0
    assert "no drawing in" not in capsys.readouterr().out
    # One character per alphabet: a split by character cannot hold any out either.
    assert _import(few, tmp_path / "c.safetensors", "--split-by", "character") == 0
    out = capsys.readouterr().out
    assert "(train 10, validation 0, test 0)" in out
    assert "note: no drawing in validation or test: --split-by character keeps" in out
    assert "of an alphabet's 1 character(s) (at most)" in out and "--split-by drawer" in out


def test_a_character_without_test_drawers_is_named_in_a_note(tree, tmp_path, capsys):
    """A character drawn by fewer drawers (here without 18-20): the test figures leave it
    out, and the import says which."""
    root = tmp_path / "o"
    shutil.copytree(tree, root)
    for drawer in (18, 19, 20):
        for f in root.glob(f"*/Beta/character02/0202_{drawer}.*"):
            f.unlink()
    assert _import(root, tmp_path / "a.safetensors") == 0
    out = capsys.readouterr().out
    assert (
        "note: 1 character(s) without a drawing in test (drawers 18-20): Beta/character02;" in out
    )
    assert "without a drawing in validation" not in out
    assert _import(tree, tmp_path / "b.safetensors") == 0
    assert "without a drawing" not in capsys.readouterr().out


def test_omniglot_stroke_files_in_seconds_are_noted(tmp_path, capsys):
    """Omniglot's t are milliseconds; files of a user's own tablet written in seconds
    make drawings of a few milliseconds: imported, with a note."""
    root = write_tree(tmp_path / "o", alphabets=("A",), characters=1, drawers=3)
    for f in root.glob("strokes_test/*/*/*.txt"):
        lines = []
        for line in f.read_text().splitlines():
            x, y, t = line.split(",") if "," in line else (line, None, None)
            lines.append(f"{x},{y},{float(t) / 1000:g}" if t is not None else x)
        f.write_text("\n".join(lines) + "\n")
    assert _import(root, tmp_path / "a.safetensors") == 0
    out = capsys.readouterr().out
    assert "(t read in milliseconds), implausibly short for handwriting (less than 0.1 s" in out
    assert "Omniglot's stroke files give t in milliseconds: if these give seconds" in out
    assert _import(root, tmp_path / "b.safetensors", "--duration", "2") == 0
    assert "implausibly" not in capsys.readouterr().out


def test_split_by_character_or_alphabet_keeps_them_whole(tmp_path):
    root = write_tree(tmp_path / "o", alphabets=("A", "B", "C", "D", "E"), characters=5, drawers=2)
    samples, _ = find_samples(root, split_by="character")
    by_char = import_samples(samples, ImportOptions(split_by="character", seed=1))
    classes = np.array(by_char.label_names)[by_char.labels]
    for c in np.unique(classes):
        assert len(set(by_char.split[classes == c])) == 1, c  # 2 drawings, one split
    alphabet = np.array([c.split("/")[0] for c in classes])
    for a in "ABCDE":  # of 5 characters: 1 test, 1 validation (rounded), 3 train
        assert sorted(by_char.split[alphabet == a][::2]) == [0, 0, 0, 1, 2], a
    again = import_dataset(root, ImportOptions(split_by="character", seed=1))
    assert np.array_equal(again.split, by_char.split)
    by_alpha = import_dataset(root, ImportOptions(split_by="alphabet"))
    alphabet = np.array([c.split("/")[0] for c in np.array(by_alpha.label_names)[by_alpha.labels]])
    per = {a: set(by_alpha.split[alphabet == a]) for a in "ABCDE"}
    assert all(len(s) == 1 for s in per.values())
    assert sorted(s.pop() for s in per.values()) == [0, 0, 0, 1, 2]
    assert by_alpha.meta["source"]["split_by"] == "alphabet"
    # A split by drawer or character means nothing to a folder of class folders (here
    # the characters of one alphabet; Omniglot's images_test itself is refused by name).
    with pytest.raises(ValueError, match="split_by 'character' .* is for Omniglot sources"):
        find_samples(root / "images_test" / "A", split_by="character")


def test_stroke_resampling_keeps_the_dots_the_even_grid_refuses(tree, tmp_path, capsys):
    out = tmp_path / "u.safetensors"
    assert _import(tree, out, "--resample", "uniform") == 2
    err = capsys.readouterr().err
    assert "3 stroke(s) become 2 on the grid of 100 instants" in err and "0101_01.txt" in err
    assert _import(tree, out, "--n-times", "12", "--n-kernels", "2") == 0  # 3 strokes in 12
    printed = capsys.readouterr().out
    # Too few kernels for 3 strokes: the remedy is more of them, the scaling is none already.
    assert "DMP fit(s) are off" in printed and "try a larger --n-kernels" in printed
    assert "--scaling none" not in printed
    # ... for a model of one DMP per drawing: a stroke model's kernels are its own.
    assert "a stroke model (--config omniglot) does not learn this fit" in printed
    data = load_dataset(out)
    assert [len(data.stroke_spans(r)) for r in range(4)] == [3, 3, 3, 3]
    assert data.meta["import"]["resample"] == "strokes"


# --- the rules of a stroke file --------------------------------------------------------


def test_repeated_and_jittered_time_stamps_are_spread_in_order():
    text = "START\n1,-1,0\n2,-1,16\n3,-1,16\n4,-1,16\n5,-1,40\n6,-1,31\n7,-1,60\nBREAK\n"
    pen = parse_strokes(text, "f.txt")
    # 16 ms three times: spread up to 40; 31 after 40: jitter, taken as 40 and spread.
    assert np.allclose(pen.t_s * 1000, [0, 16, 24, 32, 40, 50, 60])
    assert np.allclose(pen.xy[:, 1], 1.0)  # y points up in the file: row = -y
    end = parse_strokes("START\n1,-1,0\n2,-1,10\n3,-1,20\n4,-1,20\nBREAK\n", "g.txt")
    assert np.allclose(end.t_s * 1000, [0, 10, 15, 20])  # at a stroke's end: back
    dots = parse_strokes("START\n5,-5,0\nBREAK\nBREAK\n9,-9,100\nBREAK\n", "h.txt")
    assert dots.n_strokes == 2 and list(dots.stroke) == [0, 1]  # an empty stroke left out


def _strokes(n: int) -> list[np.ndarray]:
    """``n`` short strokes of 3 points across the image."""
    return [
        np.array([[10 + 2 * k, 20.0], [10 + 2 * k, 30.0], [10 + 2 * k, 40.0]]) for k in range(n)
    ]


def _one(root: Path, text: str | None = None, strokes=None, shift=(0, 0)) -> Path:
    write_drawing(root, Path("A/character01/0101_01"), strokes or _shape(0, 1), text, shift)
    return root


def test_many_strokes_a_shifted_image_and_points_off_the_border_are_imported(tmp_path):
    root = _one(tmp_path / "many", strokes=_strokes(40))
    data = import_dataset(root, ImportOptions(n_times=200))
    assert len(data.stroke_spans(0)) == 40  # 40 strokes in 200 instants: every one kept
    # The image drawn 3 px left of and 2 px below its strokes: they are shifted onto it
    # (to about a pixel of the drawing's image, half a pixel of the stored one).
    root = _one(tmp_path / "shifted", strokes=_shape(1, 1), shift=(-3.0, 2.0))
    data = import_dataset(root)
    ((name, shift),) = data.meta["source"]["shifted"].items()
    assert name.endswith("0101_01.txt") and shift == pytest.approx([-3.0, 2.0], abs=1.1)
    assert on_ink_share(data.images, data.trajectories)[0] > 0.9
    # A bar drawn on past the right border (the tablet's canvas is larger): onto it.
    bar = [np.linspace([40, 50], [SIDE + 20, 50], 40)]
    root = _one(tmp_path / "off", strokes=bar)
    data = import_dataset(root)
    m = np.array(data.meta["rows"]["image_to_model"][0])
    border = np.array([SIDE - 0.5, 50.0]) @ m[:, :2].T + m[:, 2]
    assert data.trajectories[0, -1, 0] == pytest.approx(border[0], abs=1e-3)


def _text(*lines: str) -> str:
    return "\n".join(lines) + "\n"


#: (case, stroke-file text or an edit of the tree, extra options, what the one line holds)
BAD = [
    ("empty character", "", [], ["0101_01.txt: holds no point: an empty character"]),
    ("START and BREAK only", _text("START", "BREAK"), [], ["holds no point"]),
    (
        "a single point",
        _text("START", "50,-50,0", "BREAK"),
        [],
        ["0101_01.txt: line 2: the drawing is a single point"],
    ),
    (
        "malformed line",
        _text("START", "50,-50,0", "51,-50", "BREAK"),
        [],
        ["0101_01.txt: line 3 is '51,-50': expected x,y,t"],
    ),
    (
        "text for a number",
        _text("START", "50,-50,0", "51,abc,16", "BREAK"),
        [],
        ["0101_01.txt: line 3: field 'y' is 'abc', not a number"],
    ),
    (
        "NaN",
        _text("START", "50,-50,0", "nan,-50,16", "BREAK"),
        [],
        ["0101_01.txt: line 3: field 'x' is nan, not finite"],
    ),
    (
        "point before START",
        _text("50,-50,0", "START", "51,-50,16", "BREAK"),
        [],
        ["0101_01.txt: line 1 comes before START"],
    ),
    (
        "second START",
        _text("START", "50,-50,0", "51,-50,16", "BREAK", "START"),
        [],
        ["line 5: a second START"],
    ),
    (
        "no BREAK at the end",
        _text("START", "50,-50,0", "51,-50,16"),
        [],
        ["0101_01.txt: line 3: stroke 0 has no BREAK after it"],
    ),
    (
        "time far back",
        _text("START", "50,-50,500", "51,-50,516", "52,-50,300", "BREAK"),
        [],
        ["0101_01.txt: line 4: time stamp 300 ms lies 216 ms before"],
    ),
    (
        "a stroke in no time",
        _text("START", "50,-50,0", "60,-50,16", "BREAK", "50,-60,40", "60,-60,40", "BREAK"),
        [],
        ["0101_01.txt: lines 5-6: the 2 points of stroke 1 all have the time stamp 40 ms"],
    ),
    (
        "strokes out of order",
        _text("START", "50,-50,0", "60,-50,100", "BREAK", "50,-60,50", "60,-60,70", "BREAK"),
        [],
        ["0101_01.txt: line 5: stroke 1 begins at 50 ms, not after stroke 0 ended (100 ms)"],
    ),
    (
        "far off the image",
        _text("START", "50,-50,0", "50,-200,16", "BREAK"),
        [],
        ["0101_01.txt: line 3 (x=50, row=200) lies 95.5 px outside the 105 x 105 image"],
    ),
    (
        "40 strokes in 100 instants",
        "40 strokes",
        [],
        ["0101_01.txt: its 40 strokes", "need at least 119 instants", "--n-times 119"],
    ),
    ("missing image", "no image", [], ["0101_01.txt: no image 0101_01.png"]),
    ("stray file", "stray", [], ["notes.md: is no stroke file (.txt)"]),
    (
        "bad drawer",
        "drawer 0",
        [],
        ["0101_x.txt: the name '0101_x' is not <character id>_<drawer>"],
    ),
]


@pytest.mark.parametrize(
    ("edit", "options", "expected"), [c[1:] for c in BAD], ids=[c[0] for c in BAD]
)
def test_bad_input_is_one_line_naming_the_file_and_line(tmp_path, capsys, edit, options, expected):
    root = _one(tmp_path / "src")
    traj = root / "strokes_test/A/character01/0101_01.txt"
    if edit == "40 strokes":
        _one(root, strokes=_strokes(40))
    elif edit == "no image":
        (root / "images_test/A/character01/0101_01.png").unlink()
    elif edit == "stray":
        (traj.parent / "notes.md").write_text("drawn on a tablet\n")
    elif edit == "drawer 0":
        traj.rename(traj.with_name("0101_x.txt"))
        (root / "images_test/A/character01/0101_01.png").rename(
            root / "images_test/A/character01/0101_x.png"
        )
    else:
        traj.write_text(edit)
    out = tmp_path / "out.safetensors"
    out.write_bytes(b"an earlier data set")
    assert _import(root, out, "--force", *options) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("img2dmp import: error: "), err
    for text in expected:
        assert text in err[0], (text, err[0])
    assert out.read_bytes() == b"an earlier data set"


def test_skip_bad_lists_the_bad_drawings_and_imports_the_others(tmp_path, capsys):
    root = _one(tmp_path / "src")
    write_drawing(root, Path("A/character01/0101_02"), _shape(0, 2), _text("START", "1,-1,0"))
    out = tmp_path / "d.safetensors"
    assert _import(root, out, "--skip-bad") == 0
    printed = capsys.readouterr().out
    assert "1 samples" in printed and "skipped: " in printed and "0101_02.txt: line 2" in printed
    assert load_dataset(out).meta["source"]["skipped"][0].endswith("(a truncated file?)")


# --- the real data ---------------------------------------------------------------------


@pytest.mark.skipif(
    not (REAL / "strokes_background_small1.zip").is_file(),
    reason=f"Omniglot's zips are not in {REAL} (see ../shared/data/README.md)",
)
def test_the_real_first_character_keeps_every_stroke_the_even_grid_loses():
    samples, problems = find_samples(REAL)
    assert len(samples) == 2720 and not problems
    first = [s for s in samples if s.class_name == "Balinese/character01"]
    data = import_samples(first, ImportOptions(), source=REAL)
    assert len(data) == 20 and data.meta["source"]["skipped"] == []
    breaks = [s.trajectory.read_bytes(1 << 20).decode().count("BREAK") for s in first]
    assert [len(data.stroke_spans(r)) for r in range(20)] == breaks and max(breaks) > 1
    two = first[next(k for k, b in enumerate(breaks) if b > 1)]  # the first of 2 strokes
    with pytest.raises(ValueError, match="2 stroke.* become 1 on the grid of 100 instants"):
        import_samples([two], ImportOptions(resample="uniform"))
