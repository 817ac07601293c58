"""Phone photos as people take them (experiments/photo_conditions.py), and the page
photographed from far away (img2dmp.page: read enlarged, or said to be too small)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from drawn import on_paper, page

FAR_LINES = [[("1", 40), ("7", 110), ("0", 190), ("5", 270), ("1", 350), ("0", 430)],
             [("7", 40), ("5", 120), ("0", 200), ("1", 280), ("7", 360)]]  # fmt: skip


def _far_page(scale: float):
    """A page of ``FAR_LINES`` (characters 40 px tall, a 3-px pen) on light paper with
    the desk beyond the sheet's top edge in the frame (14 rows, dark), photographed from
    far away: scaled by ``scale`` (Lanczos); and the true boxes scaled with it."""
    ink, boxes = page(FAR_LINES, size=(300, 520))
    rgb = on_paper(ink, np.full((300, 520, 3), 0.93, np.float32), colour=(0.1, 0.1, 0.2))
    rgb[:14] = 0.25
    im = Image.fromarray((np.clip(rgb, 0, 1) * 255).astype(np.uint8))
    small = im.resize((round(520 * scale), round(300 * scale)), Image.Resampling.LANCZOS)
    return small, [tuple(v * scale for v in b) for b in boxes]


def _shared_photos() -> Path:
    photos = Path(__file__).resolve().parents[2] / "shared" / "data" / "photos"
    if not (photos / "photos.json").is_file():
        pytest.skip(f"the shared phone photos are not at {photos} (../shared/data/photos)")
    return photos


@pytest.fixture(scope="module")
def run(tmp_path_factory, train_tiny_runs):
    work = tmp_path_factory.mktemp("far_run")
    return train_tiny_runs(work, lambda k: work / f"run{k}")[1]


def test_a_page_photographed_from_far_away_is_read_character_by_character():
    """Characters 8 px tall, strokes under a pixel wide and faint beside the dark desk at
    the border: the desk's edge alone was taken for ink and cut into 42 characters a few
    pixels tall; the page is now read enlarged, each character alone in its box."""
    from img2dmp.page import segment_page

    photo, boxes = _far_page(0.2)  # 104 x 60 px
    seg = segment_page(photo)
    assert [len(line) for line in seg.layout.lines] == [len(line) for line in FAR_LINES]
    assert not seg.too_small
    found = [seg.box_in_image(c) for c in seg.layout.characters]  # in reading order
    for (x0, y0, x1, y1), (a0, b0, a1, b1) in zip(boxes, found, strict=True):
        x, y = (x0 + x1) / 2, (y0 + y1) / 2
        assert a0 <= x <= a1 and b0 <= y <= b1, ((x, y), (a0, b0, a1, b1))
    assert seg.reduction < 1.0  # read enlarged: the boxes still in the photo's pixels


def test_characters_too_small_to_read_are_said_to_be_so_not_invented(run, experiment_script,
                                                                     capsys):  # fmt: skip
    """Characters 2 px tall: no character is given, and the page is flagged (and counted
    so by the experiment); ``predict --page`` says what the flag means in its line."""
    from img2dmp.commands._args import warn_page
    from img2dmp.page import PAGE_MIN_HEIGHT_PX, segment_page
    from img2dmp.predict import load_model

    photo, _ = _far_page(0.05)  # 26 x 15 px
    seg = segment_page(photo)
    assert seg.too_small and not seg.layout.characters
    assert experiment_script("photo_conditions")._read(None, photo)[5]
    result = load_model(run).predict_page(photo)
    assert result.flags == ["too_small"] and not result.characters
    assert result.to_document(dmps=False)["flags"] == ["too_small"]
    warn_page("predict", "far.png", result)
    line = capsys.readouterr().err
    assert line.count("\n") == 1 and "far.png: too_small (" in line
    assert f"under {PAGE_MIN_HEIGHT_PX:g} px" in line and "closer" in line
    small, _ = _far_page(0.25)  # characters 10 px tall: read
    assert not segment_page(small).too_small


def test_the_shared_white_photo_from_far_away_reads_its_fourteen_digits():
    """The white photo scaled to 0.25 (digits about 10 px tall) gave 78 boxes."""
    from img2dmp.page import segment_page

    photo = Image.open(_shared_photos() / "page_white_black_ink.png").convert("RGB")
    small = photo.resize(
        (round(photo.width * 0.25), round(photo.height * 0.25)), Image.Resampling.LANCZOS
    )
    seg = segment_page(small)
    assert [len(line) for line in seg.layout.lines] == [7, 7]


def test_every_condition_is_deterministic_and_changes_the_photo(experiment_script):
    pc = experiment_script("photo_conditions")
    photo, _ = _far_page(0.5)
    rgb = np.asarray(photo)
    for cond in pc.CONDITIONS:
        once = pc.apply(cond, rgb, 0, 3)
        assert once.dtype == np.uint8 and once.ndim == 3 and once.shape[2] == 3, cond.name
        assert np.array_equal(once, pc.apply(cond, rgb, 0, 3)), cond.name
        if cond.name == "as-is":
            assert np.array_equal(once, rgb)
        elif cond.family != "far":
            assert once.shape == rgb.shape and not np.array_equal(once, rgb), cond.name
    noisy = [c for c in pc.CONDITIONS if c.name in ("pencil", "warm-dim-noisy")]
    for cond in noisy:  # the seed is the noise's
        assert not np.array_equal(pc.apply(cond, rgb, 0, 3), pc.apply(cond, rgb, 1, 3))
    far = {c.name: c for c in pc.CONDITIONS}["far-0.25"]
    assert pc.apply(far, rgb, 0, 3).shape[:2] == (
        round(rgb.shape[0] * 0.25),
        round(rgb.shape[1] * 0.25),
    )
    shadow = {c.name: c for c in pc.CONDITIONS}["shadow-0.5-hard-straight"]
    dim = pc.apply(shadow, np.full((40, 80, 3), 200, np.uint8), 0, 0)
    assert dim[:, :5].mean() == pytest.approx(200, abs=1)  # the lit half
    assert dim[:, -5:].mean() == pytest.approx(100, abs=1)  # 0.5 of the light


def test_conditions_are_chosen_by_name_or_family(experiment_script):
    pc = experiment_script("photo_conditions")
    assert [c.name for c in pc.select("far")] == ["far-0.5", "far-0.35", "far-0.25", "far-0.18"]
    assert [c.name for c in pc.select("jpeg-20,pencil")] == ["jpeg-20", "pencil"]
    assert len(pc.select(None)) == len(pc.CONDITIONS)
    with pytest.raises(ValueError, match="unknown fog"):
        pc.select("far,fog")


def test_the_experiment_scores_the_shared_photos_and_writes_its_tables(
    experiment_script, tmp_path, capsys
):
    photos = _shared_photos()
    pc = experiment_script("photo_conditions")
    assert pc.main(["--photos", str(photos), "--pages", "0", "--conditions", "as-is,far-0.25",
                    "--out", str(tmp_path)]) == 0  # fmt: skip
    report = json.loads((tmp_path / "photo_conditions.json").read_text())
    rows = {(r["photo"], r["condition"]): r for r in report["photos"]["rows"]}
    white = rows[("page_white_black_ink.png", "as-is")]
    assert (white["reference"], white["matched"], white["extra"]) == (14, 14, 0)
    far = rows[("page_white_black_ink.png", "far-0.25")]
    assert far["size"] == [148, 102] and far["extra"] <= 2  # was 78 boxes, none matched
    families = [e["family"] for e in report["photos"]["families"]]
    assert families == ["as is", "far"]
    assert not white["too_small"] and not far["too_small"]
    text = (tmp_path / "photo_conditions.md").read_text()
    assert "| family |" in text and "CPU:" in text
    assert "far-0.25" in capsys.readouterr().out


@pytest.mark.parametrize("light", [0.7, 0.6])
def test_a_page_half_in_a_hard_shadow_beside_a_dark_desk_is_dark_ink_on_light_paper(light):
    """The white photo on a dark desk (right and below), the right half of the frame at 0.7
    or 0.6 of the light: the cells across the shadow's hard edge voted for light ink (the
    median interpolated across the step), the votes came out even, and the dark desk along
    the border then read the page as light ink on dark paper. Cells at a step to a
    neighbour (``POLARITY_STEP``) vote no more; at 0.6 the shaded half held the median
    cell, and the lit half, far from it, voted no more either: cells near the lightest
    common level vote too."""
    from img2dmp.data.paper import dark_on_light, paper_ink

    rgb = np.asarray(Image.open(_shared_photos() / "page_white_black_ink.png").convert("RGB"),
                     np.float32) / 255.0  # fmt: skip
    h, w = rgb.shape[:2]
    img = np.empty((int(h * 1.15), int(w * 1.15), 3), np.float32)
    img[:] = 0.16 * np.array([1.0, 0.7, 0.45], np.float32)  # a dark wooden desk
    img[:h, :w] = rgb
    cols = np.mgrid[: img.shape[0], : img.shape[1]][1]
    img *= np.where(cols > 0.5 * img.shape[1], light, 1.0)[..., None].astype(np.float32)
    assert dark_on_light(np.ascontiguousarray(np.moveaxis(img, 2, 0)))
    found = paper_ink(img)
    assert found is not None and found.dark_on_light


def test_a_shaken_photo_s_ink_level_is_the_pen_s_not_the_sheet_s_edge():
    """The white photo blurred 5 px sideways (a shaken phone): its dark edge strips at the
    border stayed as dark while the pen's upright strokes grew faint, set the page's ink
    level, and the strokes fell apart under it (43 boxes in 6 lines). The marks along the
    border within its band set no level of the pen's: its 14 digits in two lines."""
    from scipy.ndimage import convolve

    from img2dmp.page import segment_page

    rgb = np.asarray(Image.open(_shared_photos() / "page_white_black_ink.png").convert("RGB"),
                     np.float64)  # fmt: skip
    kernel = np.zeros((5, 5))
    kernel[2, :] = 0.2
    shaken = np.stack([convolve(rgb[..., c], kernel) for c in range(3)], -1)
    seg = segment_page(Image.fromarray(np.clip(shaken + 0.5, 0, 255).astype(np.uint8)))
    assert [len(line) for line in seg.layout.lines] == [7, 7]


def test_a_photo_point_is_placed_on_a_page_read_finer_from_its_origin(experiment_script):
    """The experiments score boxes against the photo's points moved into the page as read
    (``tilted_pages._as_read``): a large photo read again finer holds only the part with
    the writing, from ``origin``; the point lands where the segmentation's own map puts
    it (it ignored the origin before)."""
    from types import SimpleNamespace

    from img2dmp.page import PageSegmentation

    c, s = np.cos(0.2), np.sin(0.2)
    turn = np.array([[c, -s, 5.0], [s, c, -3.0], [0.0, 0.0, 1.0]])
    seg = SimpleNamespace(reduction=1.5, origin=(300.0, 120.0), turn=turn)
    to_levels = PageSegmentation.photo_to_levels(seg)
    want = turn @ to_levels @ np.array([700.0, 410.0, 1.0])
    got = experiment_script("tilted_pages")._as_read(seg, 700.0, 410.0)
    np.testing.assert_allclose(got, want[:2], atol=1e-9)
