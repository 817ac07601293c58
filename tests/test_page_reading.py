"""Reading a page (img2dmp.page, `predict --page`, `write --page`) on photos drawn here."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from drawn import glare, grainy_page, moved, on_paper, page, ruled
from img2dmp.cli import main
from img2dmp.data.dmpfile import check_dmp_document
from img2dmp.predict import load_model

LINES = [[("1", 40), ("7", 110), ("0", 190)], [("5", 60), ("0", 150)]]


@pytest.fixture(scope="module")
def runs(tmp_path_factory, train_tiny_runs):
    work = tmp_path_factory.mktemp("page_run")
    return train_tiny_runs(work, lambda k: work / f"run{k}")


@pytest.fixture(scope="module")
def run(runs):
    return runs[1]


def _photo(path, lines=LINES, size=(300, 520), orientation=None):
    """A photo of ``lines`` in blue ink on ruled paper, saved as PNG (upright raster, or
    stored turned with the EXIF ``orientation`` that turns it back); the true boxes."""
    ink, boxes = page(lines, size=size)
    rgb = on_paper(ink, ruled(size, 33.0, angle_deg=1.0), colour=(0.1, 0.15, 0.6))
    im = Image.fromarray((np.clip(rgb, 0, 1) * 255).astype(np.uint8))
    if orientation is None:
        im.save(path)
    else:  # 6: the viewer turns the stored raster 90 degrees clockwise
        exif = Image.Exif()
        exif[0x0112] = orientation
        im.transpose(Image.Transpose.ROTATE_90).save(path, exif=exif)
    return boxes


def _close(found, true, tol=5.0) -> bool:
    return all(abs(a - b) <= tol for a, b in zip(found, true, strict=True))


def test_a_page_is_read_character_by_character_in_reading_order(tmp_path, run):
    boxes = _photo(tmp_path / "p.png")
    result = load_model(run).predict_page(tmp_path / "p.png")
    assert [len(x) for x in result.lines] == [3, 2]
    doc = json.loads(result.to_json())
    assert (doc["format"], doc["version"], doc["image_size_px"]) == ("img2dmp-page", 1, [520, 300])
    chars = doc["characters"]
    assert [c["line"] for c in chars] == [0, 0, 0, 1, 1]
    assert [c["index"] for c in chars] == list(range(5))
    for c, box in zip(chars, boxes, strict=True):
        assert _close(c["box_image_px"], box), (c["box_image_px"], box)
        xy = np.array(c["path_image_px"])
        assert len(xy) == len(c["pen"]) == len(c["times_s"]) and set(c["pen"]) <= {0, 1}
        assert np.all(np.diff(c["times_s"]) > 0)
        # the path is near its own character: its centre within the character's box, grown
        x0, y0, x1, y1 = c["box_image_px"]
        cx, cy = xy.mean(axis=0)
        pad = 0.5 * max(x1 - x0, y1 - y0)
        assert x0 - pad < cx < x1 + pad and y0 - pad < cy < y1 + pad
        assert 0 <= c["confidence"] <= 1 and set(c["fit"]) == {"path_on_ink", "ink_written"}
        check_dmp_document(c["dmp"], "character dmp")  # the one DMP format, as write reads it


def test_the_page_document_and_picture_are_written_and_read_back_by_the_robot(tmp_path, run):
    from img2dmp.robot.pagefile import read_page

    _photo(tmp_path / "p.png")
    files = load_model(run).predict_page(tmp_path / "p.png").save(tmp_path / "out", "p")
    assert [f.name for f in files] == ["p_page.json", "p_page.png"]
    assert Image.open(files[1]).width >= 1000
    read = read_page(files[0])
    assert len(read.characters) == 5 and read.image_size_px == (520, 300)


def test_the_page_document_says_how_much_contrast_a_glare_was_given_back(tmp_path, run, capsys):
    img, _ = grainy_page()
    for photo, glared in ((img, False), (glare(img, 0.8), True)):
        doc = json.loads(load_model(run).predict_page((photo * 255).astype(np.uint8)).to_json())
        assert (doc["glare_gain"] > 2.0) if glared else (doc["glare_gain"] == 1.0)
        Image.fromarray((photo * 255).astype(np.uint8)).save(tmp_path / "g.png")
        capsys.readouterr()
        assert main(["predict", str(tmp_path / "g.png"), "--page", "--model", str(run),
                     "--out", str(tmp_path / "out"), "--force"]) == 0  # fmt: skip
        assert ("a glare's washed-out ink" in capsys.readouterr().out) == glared


def test_the_page_document_and_its_pictures_say_which_shake_was_undone(tmp_path, run, capsys):
    from img2dmp.data.images import paper_steps

    img, _ = grainy_page()
    for photo, shaken in ((img, False), (moved(img, 9, 30), True)):
        doc = json.loads(load_model(run).predict_page((photo * 255).astype(np.uint8)).to_json())
        if shaken:
            assert (
                abs(doc["shake"]["length_px"] - 9) < 1
                and abs(doc["shake"]["direction_deg"] - 30) < 3
            )
        else:
            assert doc["shake"] is None
        Image.fromarray((photo * 255).astype(np.uint8)).save(tmp_path / "s.png")
        steps = paper_steps(tmp_path / "s.png", steady=True)[0].steps
        assert (steps["shake"] is not None) == shaken  # what --explain's picture notes
        capsys.readouterr()
        assert main(["predict", str(tmp_path / "s.png"), "--page", "--model", str(run),
                     "--out", str(tmp_path / "out"), "--force", "--explain"]) == 0  # fmt: skip
        assert ("a shake of 9." in capsys.readouterr().out) == shaken
        assert (tmp_path / "out" / "s_explain.png").is_file()


def test_boxes_are_in_the_upright_photo_s_frame(tmp_path, run):
    boxes = _photo(tmp_path / "turned.png", orientation=6)
    result = load_model(run).predict_page(tmp_path / "turned.png")
    assert result.image_size == (300, 520)
    assert len(result.characters) == 5
    for c, box in zip(result.characters, boxes, strict=True):
        assert _close(c.box_image, box)


def test_an_empty_page_has_no_characters_and_says_so(tmp_path, run):
    Image.fromarray(np.full((200, 300, 3), 230, np.uint8)).save(tmp_path / "e.png")
    result = load_model(run).predict_page(tmp_path / "e.png")
    assert result.characters == [] and result.flags == ["no_ink"]
    assert json.loads(result.to_json())["characters"] == []


def test_a_single_prediction_of_several_characters_is_flagged(tmp_path, run):
    _photo(tmp_path / "p.png")
    assert not load_model(run).reads_letters  # a digit model: digits' rules
    pred = load_model(run).predict(tmp_path / "p.png")
    assert "several_characters" in pred.flags
    doc = pred.to_document()
    assert doc["flags"] == pred.flags and set(doc["fit"]) == {"path_on_ink", "ink_written"}
    one = _photo(tmp_path / "one.png", lines=[[("7", 200)]])
    assert one and "several_characters" not in load_model(run).predict(tmp_path / "one.png").flags


def test_write_warns_as_predict_does_before_the_arm_writes_a_flagged_image(tmp_path, run, capsys):
    """``write IMAGE`` of a page of characters says what ``predict`` says (one line on
    stderr, the same flags, "use --page"), then writes; an unflagged image says nothing."""
    pytest.importorskip("pybullet")
    _photo(tmp_path / "p.png")
    argv = ["--model", str(run), "--refine", "0", "--no-progress"]
    assert main(["predict", str(tmp_path / "p.png"), *argv[:4]]) == 0
    said = capsys.readouterr().err.split("warning: ", 1)[1]
    assert "several_characters" in said and "for a page of characters use --page" in said
    assert main(["write", str(tmp_path / "p.png"), "--out-dir", str(tmp_path / "W"), *argv]) == 0
    err = capsys.readouterr().err
    assert f"img2dmp write: warning: {said}" in err, err
    assert (tmp_path / "W" / "p_paper.png").exists()


def test_one_digit_is_one_character_and_touching_digits_two():
    """predict's count for a digit model: the page's waist cuts part some single digits
    (an open 0, a 4: one MNIST 4 in seven); a mark is cut into touching digits only when
    it is wider than tall (TOUCHING_WIDTH), so single digits stay one while most pairs
    written touching are still two (RESULTS 7.5)."""
    import sys

    from img2dmp.data.images import prepare_image_found
    from img2dmp.data.pages import find_characters
    from img2dmp.data.synthetic import SyntheticConfig, generate_dataset
    from img2dmp.predict import count_characters

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
    from several_characters import _pair

    d = generate_dataset(6, SyntheticConfig(), seed=3, progress=False)  # 60 digits
    masks = [prepare_image_found(np.pad(im, 12), (40, 40))[2] for im in d.images]
    assert sum(len(find_characters(m).characters) >= 2 for m in masks) >= 2  # the cuts' parts
    assert all(count_characters(m) == 1 for m in masks)
    pairs = [_pair(d.images[2 * j], d.images[2 * j + 1], 0) for j in range(len(d) // 2)]
    counts = [count_characters(prepare_image_found(np.pad(p, 12), (40, 40))[2]) for p in pairs]
    assert sum(c >= 2 for c in counts) >= 0.75 * len(pairs), counts  # flagged several


def test_the_warning_says_when_a_run_directory_s_path_is_unrefined(tmp_path, run, capsys):
    """A run directory recommends no refinement: a path flagged off the ink may be off
    it only for that, and the warning says so; with ``--refine`` it does not."""
    _photo(tmp_path / "p.png")
    assert main(["predict", "--model", str(run), str(tmp_path / "p.png")]) == 0
    err = capsys.readouterr().err
    assert "off_ink" in err or "unexplained_ink" in err, err
    assert "; the path is unrefined: --refine N pulls it onto the ink" in err
    assert main(["predict", "--model", str(run), str(tmp_path / "p.png"), "--refine", "2"]) == 0
    err = capsys.readouterr().err
    assert "warning:" in err and "unrefined" not in err


def test_predict_page_on_the_command_line(tmp_path, run, capsys):
    _photo(tmp_path / "p.png")
    out = tmp_path / "out"
    code = main(["predict", "--model", str(run), str(tmp_path / "p.png"), "--page",
                 "--out", str(out), "--explain"])  # fmt: skip
    assert code == 0
    assert {f.name for f in out.iterdir()} == {"p_page.json", "p_page.png", "p_explain.png"}
    assert "5 characters in 2 lines" in capsys.readouterr().out
    assert main(["predict", "--model", str(run), str(tmp_path / "p.png"), "--page",
                 "--overlay"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--overlay" in err[0]


def test_a_one_pixel_strip_is_one_line_of_error(tmp_path, run, capsys):
    Image.fromarray(np.full((1, 400), 200, np.uint8)).save(tmp_path / "strip.png")
    assert main(["predict", "--model", str(run), str(tmp_path / "strip.png"), "--page"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "strip.png" in err[0]


def test_the_robot_writes_a_three_character_page_read_from_a_photo(tmp_path, run):
    pytest.importorskip("pybullet")
    _photo(tmp_path / "p.png", lines=[[("1", 60), ("0", 160), ("7", 260)]])
    robot = tmp_path / "robot"
    code = main(["write", str(tmp_path / "p.png"), "--page", "--model", str(run),
                 "--width-mm", "80", "--out-dir", str(robot), "--no-progress"])  # fmt: skip
    assert code == 0
    with open(robot / "p_characters.csv") as f:
        rows = [r for r in csv.DictReader(f) if r["index"] != "page"]
    assert len(rows) == 3
    for r in rows:  # each character inked along what was commanded, and only there
        assert r["written"] == "1" and float(r["ink_share"]) > 0.95, r
        assert float(r["ink_on_path_share"]) > 0.95, r


def test_a_24_megapixel_photo_is_read_at_most_2_megapixels(tmp_path, run):
    from img2dmp.page import PAGE_WORK_PIXELS

    ink, boxes = page(LINES, size=(300, 520))
    big = np.asarray(Image.fromarray((255 * (1 - 0.9 * ink)).astype(np.uint8)).resize((6000, 4000)))
    Image.fromarray(big).save(tmp_path / "big.jpg", quality=85)
    result = load_model(run).predict_page(tmp_path / "big.jpg")
    assert result.image_size == (4000, 6000)
    h, w = result.layout.shape
    assert h * w <= PAGE_WORK_PIXELS and result.reduction >= 3
    assert len(result.characters) == len(boxes)
    sx, sy = 6000 / 520, 4000 / 300
    for c, box in zip(result.characters, boxes, strict=True):  # boxes in the photo's pixels
        true = [box[0] * sx, box[1] * sy, box[2] * sx, box[3] * sy]
        assert _close(c.box_image, true, tol=5 * sy)


def test_a_large_page_reads_the_same_as_an_array_a_pil_image_and_a_file(tmp_path):
    """Reduced to at most 2 MP, an 8-bit page gives the same levels (and characters)
    from an array as from its PNG file, which the command reads: before, an array was
    reduced in float and a file in 8 bits, and a generated ruled page (validation seed
    140) read from memory and from its PNG found different characters."""
    from img2dmp.page import segment_page

    ink, _ = page(LINES, size=(300, 520))
    rng = np.random.default_rng(0)
    big = np.asarray(Image.fromarray((255 * (1 - 0.9 * ink)).astype(np.uint8)).resize((2080, 1200)))
    big = np.clip(big[..., None] + rng.normal(0, 6, (1200, 2080, 3)), 0, 255).astype(np.uint8)
    Image.fromarray(big).save(tmp_path / "big.png")
    read = [segment_page(x) for x in (big, Image.fromarray(big), tmp_path / "big.png")]
    assert read[0].reduction == 2.0  # 2.5 MP: reduced 2 x 2
    for other in read[1:]:
        assert np.array_equal(other.levels, read[0].levels)
        boxes = [[r.box_in_image(c) for c in r.layout.characters] for r in (other, read[0])]
        assert boxes[0] == boxes[1] and len(boxes[0]) == len(LINES[0]) + len(LINES[1])


def test_a_sheet_of_2000_specks_is_read_as_no_writing_in_bounded_time(tmp_path, run):
    import time

    rng = np.random.default_rng(3)
    sheet = np.full((1500, 2000, 3), 235, np.uint8)
    ys, xs = rng.integers(0, 1499, 2000), rng.integers(0, 1999, 2000)
    for dy in (0, 1):  # specks of 1-4 pixels
        for dx in (0, 1):
            keep = rng.random(2000) < 0.6
            sheet[ys[keep] + dy, xs[keep] + dx] = 40
    Image.fromarray(sheet).save(tmp_path / "specks.png")
    model = load_model(run)
    start = time.perf_counter()
    result = model.predict_page(tmp_path / "specks.png")
    assert time.perf_counter() - start < 60  # bounded, not a timing target
    assert result.characters == [] and result.flags == ["no_ink"]


def test_a_character_cut_by_the_border_is_flagged(tmp_path, run):
    ink, _ = page([[("7", 40), ("0", 150)]], size=(200, 240))
    cut = ink[:, 50:]  # the 7 (x 40-64) cut through: its left part outside the photo
    rgb = on_paper(cut, np.full(cut.shape + (3,), 0.92, np.float32))
    Image.fromarray((np.clip(rgb, 0, 1) * 255).astype(np.uint8)).save(tmp_path / "cut.png")
    result = load_model(run).predict_page(tmp_path / "cut.png")
    assert len(result.characters) == 2
    first, second = result.characters
    assert "cut_by_border" in first.flags and "cut_by_border" not in second.flags
    assert first in result.flagged


def test_a_photo_of_something_that_is_not_writing_is_flagged_not_read(tmp_path, run):
    """A smooth blotchy picture (no pen strokes): no character, or every one flagged."""
    rng = np.random.default_rng(5)
    small = rng.random((6, 8, 3))
    im = Image.fromarray((small * 255).astype(np.uint8)).resize((800, 600), Image.BICUBIC)
    im.save(tmp_path / "photo.jpg")
    result = load_model(run).predict_page(tmp_path / "photo.jpg")
    assert result.flags in (["no_ink"], ["mostly_unreadable"]), result.flags
    assert json.loads(result.to_json())["flags"] == result.flags


def test_a_page_refines_each_character_s_top_hypothesis_only(runs):
    """``refine_top_only``: the top hypothesis as when every one is refined, the others as
    the network gave them."""
    rng = np.random.default_rng(0)
    x = (rng.random((3, 40, 40)) > 0.85).astype(np.float32)
    refined = load_model(runs[2], refine=5)  # two hypotheses
    plain = load_model(runs[2])
    all_, probs = refined.predict_hypotheses(x)
    top, probs_top = refined.predict_hypotheses(x, refine_top_only=True)
    raw, _ = plain.predict_hypotheses(x)
    np.testing.assert_array_equal(probs, probs_top)
    np.testing.assert_allclose(top[:, 0].to_vector(), all_[:, 0].to_vector(), atol=1e-4)
    np.testing.assert_array_equal(top[:, 1:].to_vector(), raw[:, 1:].to_vector())
    assert np.abs(top[:, 0].to_vector() - raw[:, 0].to_vector()).max() > 1e-3  # refined


def test_a_stroke_model_flags_a_page_read_as_one_character():
    """A stroke model reads up to 8 strokes, so the letters page (8 letters in 2 lines)
    was one character of 8 strokes, unflagged; lines of writing are several characters.
    One drawn character is not flagged (on Omniglot's 2,720 drawings the rule flags 4:
    RESULTS 8.22)."""
    from pathlib import Path

    from img2dmp import load_model

    samples = Path(__file__).resolve().parents[1] / "examples" / "samples"
    model = load_model("omniglot-strokes", refine=0)
    assert "several_characters" in model.predict(samples / "letters_page.png").flags
    assert "several_characters" not in model.predict(samples / "character_f.png").flags


TILT_LINES = [[("1", 30), ("7", 95), ("0", 160), ("5", 225)],
              [("7", 40), ("1", 110), ("0", 175)],
              [("5", 30), ("0", 100), ("7", 165), ("1", 230)]]  # fmt: skip


def _askew(angle_deg, lines=TILT_LINES, size=(340, 300), rules=False):
    """A page of ``lines`` photographed turned by ``angle_deg`` (counter-clockwise as
    seen), as ``uint8 [H, W, 3]``: plain paper on a grey desk (150), or (``rules``) ruled
    paper filling the frame; and the true characters' centres moved as the page was."""
    ink, boxes = page(lines, size=size)
    paper = ruled(size, 33.0) if rules else np.ones((*size, 3), np.float32) * 0.96
    rgb = on_paper(ink, paper, colour=(0.1, 0.15, 0.6))
    im = Image.fromarray((np.clip(rgb, 0, 1) * 255).astype(np.uint8)).convert("RGBA")
    turned = im.rotate(angle_deg, resample=Image.Resampling.BICUBIC, expand=not rules,
                       fillcolor=(245, 244, 237, 255))  # fmt: skip
    pad = 0 if rules else 30
    desk = Image.new("RGB", (turned.width + 2 * pad, turned.height + 2 * pad), (150, 150, 150))
    desk.paste(turned, (pad, pad), turned)
    a = np.radians(angle_deg)
    centres = []
    for x0, y0, x1, y1 in boxes:
        dx, dy = (x0 + x1) / 2 - size[1] / 2, (y0 + y1) / 2 - size[0] / 2
        centres.append((desk.width / 2 + np.cos(a) * dx + np.sin(a) * dy,
                        desk.height / 2 - np.sin(a) * dx + np.cos(a) * dy))  # fmt: skip
    return np.asarray(desk), centres


@pytest.mark.parametrize(("angle", "rules"), [(-14.0, False), (20.0, False), (-12.0, True)])
def test_a_page_photographed_askew_is_turned_level_and_read_line_by_line(angle, rules):
    """Taken 12-20 degrees askew, the page's lines were broken (its lines followed
    within 6 degrees only): it is now turned level (ruled paper's rules removed there),
    and every character found alone in its line, its box in the photo's pixels around it."""
    from img2dmp.page import segment_page

    photo, centres = _askew(angle, size=(420, 380), rules=True) if rules else _askew(angle)
    seg = segment_page(photo)
    assert abs(seg.turn_deg + angle) < 1.5, seg.turn_deg  # lines rising to the right: < 0
    assert [len(idx) for idx in seg.layout.lines] == [len(line) for line in TILT_LINES]
    boxes = [seg.box_in_image(c) for c in seg.layout.characters]
    for (x, y), (x0, y0, x1, y1) in zip(centres, boxes, strict=True):  # reading order
        assert x0 < x < x1 and y0 < y < y1, ((x, y), (x0, y0, x1, y1))


def test_a_page_nearly_level_or_of_few_characters_is_read_as_it_stands():
    from img2dmp.page import segment_page

    seg = segment_page(_askew(4.0)[0])
    assert seg.turn_deg == 0.0 and np.array_equal(seg.turn, np.eye(3))
    assert [len(idx) for idx in seg.layout.lines] == [len(line) for line in TILT_LINES]
    few = segment_page(_askew(20.0, lines=[[("1", 60), ("0", 150)]])[0])
    assert few.turn_deg == 0.0 and len(few.layout.characters) == 2


def test_a_page_turned_level_is_predicted_where_its_ink_stands(tmp_path, capsys):
    """The map from the model's input to the photo goes through the turn: each
    character's path lies on its own ink in the photo, and the document says the angle."""
    photo, centres = _askew(-14.0)
    Image.fromarray(photo).save(tmp_path / "askew.png")
    result = load_model("digits-real").predict_page(tmp_path / "askew.png")  # refined as shipped
    assert len(result.characters) == len(centres)
    for c, (x, y) in zip(result.characters, centres, strict=True):
        xy = c.prediction.path_image[0][:, :2]
        assert np.hypot(*(xy.mean(axis=0) - (x, y))) < 15.0
        assert c.prediction.fit["path_on_ink"] > 0.85, c.prediction.fit
    doc = json.loads(result.to_json())
    assert abs(doc["turned_deg"] - 14.0) < 1.5 and abs(doc["writing_angle_deg"] - 14.0) < 1.5
    # the command says so (the photo turned clockwise: its lines fall to the right)
    assert main(["predict", str(tmp_path / "askew.png"), "--page", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert re.search(r"in 3 lines \(turned 1[345]\.\d degrees counter-clockwise to level", out), out
    # the robot writes it level, turned as it was to be read (as it stands: falling 14 deg)
    assert abs(_slope_on_paper_deg(doc)) < 2.0, _slope_on_paper_deg(doc)
    assert abs(_slope_on_paper_deg({**doc, "turned_deg": 0.0}) + 14.0) < 2.0  # falling


def _slope_on_paper_deg(doc: dict) -> float:
    """The angle (degrees, rising to the writer's right) of a page document's lines as
    the robot would write them: a line through the centres of each line's planned paths
    on the paper, fitted with one slope for all lines (no simulation)."""
    from img2dmp.robot import check_page_document, plan_page

    plan = plan_page(check_page_document(doc, "askew_page.json"))
    centres = {cp.character.index: cp.plan.xy_m.mean(axis=0) for cp in plan.characters}
    xs, ys = [], []
    for line in plan.page.lines:  # world -y is the writer's right, +x away from the robot
        pts = np.array([centres[i] for i in line])
        xs.append(-pts[:, 1] - (-pts[:, 1]).mean())
        ys.append(pts[:, 0] - pts[:, 0].mean())
    xs, ys = np.concatenate(xs), np.concatenate(ys)
    return float(np.degrees(np.arctan2((xs * ys).sum(), (xs * xs).sum())))


def test_explain_draws_a_large_photo_s_boxes_around_its_characters(tmp_path, run, monkeypatch):
    """``--explain`` on a photo read reduced (over 2 MP) drew the boxes in the reduced
    pixels divided by the reduction once more: a 2 x 2 reduction put them at a quarter
    of the page. They are the photo's boxes brought to the pixels of the steps."""
    import img2dmp.data.plotting as plotting

    boxes = _photo(tmp_path / "small.png")
    Image.open(tmp_path / "small.png").resize((2080, 1200)).save(tmp_path / "p.png")
    drawn = {}

    def capture(path, found, boxes=None, title=""):
        drawn["shape"], drawn["boxes"] = found.mask.shape, boxes
        return Path(path)

    monkeypatch.setattr(plotting, "paper_steps_figure", capture)
    out = tmp_path / "out"
    assert main(["predict", "--model", str(run), str(tmp_path / "p.png"), "--page",
                 "--out", str(out), "--explain"]) == 0  # fmt: skip
    assert drawn["shape"] == (600, 1040)  # 2.5 MP read 2 x 2 reduced
    assert len(drawn["boxes"]) == len(boxes)
    for got, (x0, y0, x1, y1) in zip(drawn["boxes"], boxes, strict=True):  # small: 1/2 of it
        assert _close(got, (x0 * 2, y0 * 2, x1 * 2, y1 * 2), tol=6.0), (got, (x0, y0, x1, y1))


@pytest.mark.parametrize("quarters", [1, 3])
def test_a_page_photographed_sideways_is_read_upright(tmp_path, quarters):
    """A page stored sideways without an EXIF tag (a scan, a screenshot) was read as
    columns of broken characters, most flagged: its characters line up in columns, so
    it is read turned a quarter each way too, and the reading the model flags clearly
    least kept; the characters come back in the upright page's reading order, in the
    photo's pixels."""
    from img2dmp.page import segment_page

    upright, centres = _askew(0.0)
    h, w = upright.shape[:2]
    photo = np.ascontiguousarray(np.rot90(upright, quarters))  # counter-clockwise
    if quarters == 1:  # (x, y) -> (y, W - x)
        moved = [(y, w - x) for x, y in centres]
    else:  # (x, y) -> (H - y, x)
        moved = [(h - y, x) for x, y in centres]
    seg = segment_page(photo)  # as it stands, with the angle that would level its columns
    assert seg.turn_deg == 0.0 and 80.0 < abs(seg.sideways) < 100.0, seg.sideways
    turned = segment_page(photo, turn_deg=seg.sideways)
    assert sorted(len(idx) for idx in turned.layout.lines) == sorted(len(x) for x in TILT_LINES)
    if quarters == 3:  # the model's choice of way up read once, on the other quarter
        return
    Image.fromarray(photo).save(tmp_path / "sideways.png")
    result = load_model("digits-real").predict_page(tmp_path / "sideways.png")
    assert abs(result.turn_deg + 90.0) < 5.0, result.turn_deg  # turned back clockwise
    assert [len(x) for x in result.lines] == [len(x) for x in TILT_LINES]
    for c, (x, y) in zip(result.characters, moved, strict=True):  # upright reading order
        x0, y0, x1, y1 = c.box_image
        assert x0 < x < x1 and y0 < y < y1, ((x, y), c.box_image)
    assert len(result.flagged) <= 2, [c.flags for c in result.characters]


def test_a_page_upside_down_is_read_upright(tmp_path, capsys):
    """A page upside down was read as it stood: its paths on the ink but written from the
    wrong end, right to left, a 6 read as a 9. A page of which the model flags many
    characters (``PAGE_UPSIDE_DOWN_SHARE``) is read upside down too, and kept so when
    that reading flags clearly fewer."""
    upright, centres = _askew(0.0)
    h, w = upright.shape[:2]
    Image.fromarray(np.ascontiguousarray(upright[::-1, ::-1])).save(tmp_path / "down.png")
    moved = [(w - x, h - y) for x, y in centres]  # pixel edges: (x, y) -> (W - x, H - y)
    assert main(["predict", str(tmp_path / "down.png"), "--page", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert re.search(r"in 3 lines \(turned 180\.0 degrees [a-z-]+ to read it upright\)", out), out
    doc = json.loads((tmp_path / "down_page.json").read_text())
    assert abs(abs(doc["turned_deg"]) - 180.0) < 1e-6
    assert [len(line["characters"]) for line in doc["lines"]] == [len(x) for x in TILT_LINES]
    for c, (x, y) in zip(doc["characters"], moved, strict=True):  # upright reading order
        x0, y0, x1, y1 = c["box_image_px"]
        assert x0 < x < x1 and y0 < y < y1, ((x, y), c["box_image_px"])
    flags = [c["flags"] for c in doc["characters"]]
    assert sum(map(bool, flags)) <= 1, flags  # as it stood: 3 of 11


def test_a_page_upside_down_and_askew_is_read_upright_with_every_character(tmp_path, capsys):
    """A page upside down and 14 degrees askew is first turned level, and then read upside
    down from its ink as it stands. That second turn was made from the level page's ink,
    laid on the photo's pixels askew: most of the characters were lost, and the reading
    kept for the few it flagged."""
    upright, centres = _askew(14.0)
    h, w = upright.shape[:2]
    Image.fromarray(np.ascontiguousarray(upright[::-1, ::-1])).save(tmp_path / "down.png")
    moved = [(w - x, h - y) for x, y in centres]
    assert main(["predict", str(tmp_path / "down.png"), "--page", "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "down_page.json").read_text())
    assert abs(abs(doc["turned_deg"]) - 166.0) < 2.0, doc["turned_deg"]
    assert [len(line["characters"]) for line in doc["lines"]] == [len(x) for x in TILT_LINES]
    for c, (x, y) in zip(doc["characters"], moved, strict=True):  # upright reading order
        x0, y0, x1, y1 = c["box_image_px"]
        assert x0 < x < x1 and y0 < y < y1, ((x, y), c["box_image_px"])


def test_a_turned_reading_that_lost_characters_is_not_kept(monkeypatch):
    """A reading turned another way is kept when it flags clearly fewer characters, and
    not when it reads fewer characters unflagged: 1 character of 14, none flagged, is no
    better than 14 with 3 flagged (the upside-down reading of a page turned level once
    kept such a reading)."""
    from types import SimpleNamespace

    from img2dmp import page as page_module

    def reading(n, flagged):
        chars = [SimpleNamespace(flags=["unfamiliar"] if i < flagged else []) for i in range(n)]
        return SimpleNamespace(characters=chars, flagged=[c for c in chars if c.flags])

    as_it_stands = reading(14, 3)
    turn = lambda seg, angle, cut, join: SimpleNamespace(turn_deg=angle)  # noqa: E731
    monkeypatch.setattr(page_module, "_turned_segmentation", turn)
    for turned, kept in ((reading(1, 0), False), (reading(14, 0), True), (reading(14, 2), False)):
        monkeypatch.setattr(page_module, "_read_segmentation", lambda *a, t=turned: t)
        best = page_module._best_reading(None, None, None, (100, True, True, False),
                                         as_it_stands, [180.0])  # fmt: skip
        assert (best is turned) is kept, (len(turned.characters), len(turned.flagged))


def test_the_lines_angle_of_a_page_of_many_characters_counts_them_all():
    """Beyond 400 characters the pairs of centres are counted in bins, all of them. Every
    4th character, the sample before, lined up better in columns than in rows on a
    regular page of 1,360 on lines sloping 11.3 degrees (which would then be read twice
    more, turned a quarter), and its pairs cost 0.5 s."""
    from img2dmp.data.pages import PageCharacter, PageLayout
    from img2dmp.page import _lines_angle

    chars = [PageCharacter((x, y + x // 5, x + 20, y + x // 5 + 30), np.ones((30, 20), bool))
             for y in range(0, 2000, 60) for x in range(0, 1200, 30)]  # fmt: skip
    layout = PageLayout(characters=chars, height_px=30.0)
    (rows_deg, rows), (_, columns) = _lines_angle(layout, 30.0), _lines_angle(layout, 30.0, True)
    assert abs(rows_deg - np.degrees(np.arctan(0.2))) < 0.3 and rows > columns
