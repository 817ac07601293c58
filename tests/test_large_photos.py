"""Large photos read at the detail they hold (img2dmp.page, img2dmp.data.images): a photo
reduced to ``PAGE_WORK_PIXELS`` whose characters come out small is read again from the
file, the part that holds its writing, at a finer reduction; every coordinate stays in
the file's own pixels. ``PAGE_WORK_PIXELS`` is lowered here so the images stay small."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from drawn import on_paper, page

LINES = [[("1", 40), ("7", 110), ("0", 190), ("5", 270), ("1", 350), ("0", 430)],
         [("7", 40), ("5", 120), ("0", 200), ("1", 280), ("7", 360)]]  # fmt: skip
CANVAS = (900, 1200)  # (H, W): 1.08 MP, reduced 3 x 3 at a work size of 120,000 pixels
AT = (500, 400)  # the page's top-left corner on the canvas (x, y)
WORK_PIXELS = 120_000


def _far_sheet(scale: float, angle_deg: float = 0.0):
    """``LINES`` (characters 40 px tall, written at ``angle_deg``) on light paper, scaled
    by ``scale`` (Lanczos) and pasted at ``AT`` on a large canvas of the paper's colour,
    as a large photo of a sheet seen from far; and the true boxes in the canvas's pixels."""
    ink, boxes = page(LINES, angle_deg=angle_deg, size=(300, 520))
    rgb = on_paper(ink, np.full((300, 520, 3), 0.93, np.float32), colour=(0.1, 0.1, 0.2))
    im = Image.fromarray((np.clip(rgb, 0, 1) * 255).astype(np.uint8))
    small = im.resize((round(520 * scale), round(300 * scale)), Image.Resampling.LANCZOS)
    canvas = Image.new("RGB", CANVAS[::-1], (237, 237, 237))
    canvas.paste(small, AT)
    true = [(AT[0] + x0 * scale, AT[1] + y0 * scale, AT[0] + x1 * scale, AT[1] + y1 * scale)
            for x0, y0, x1, y1 in boxes]  # fmt: skip
    return canvas, true


@pytest.fixture
def small_work(monkeypatch):
    import img2dmp.page as P

    monkeypatch.setattr(P, "PAGE_WORK_PIXELS", WORK_PIXELS)
    return P


def _centres_inside(found, true) -> int:
    """True characters whose centre lies in exactly one found box."""
    n = 0
    for x0, y0, x1, y1 in true:
        x, y = (x0 + x1) / 2, (y0 + y1) / 2
        n += sum(a0 <= x <= a1 and b0 <= y <= b1 for a0, b0, a1, b1 in found) == 1
    return n


@pytest.mark.parametrize("scale", [0.6, 0.3])
def test_a_reduced_photo_of_small_characters_is_read_again_at_a_finer_reduction(small_work, scale):
    """Characters 24 (12) px tall in the file come out 8 (4) px tall reduced 3 x 3: the
    coarse reading found 8 (6) of 11 in lines of [4, 4] ([4, 2]); read again from the
    file, the part that holds the writing, every one is found in its line, and its box
    is in the file's own pixels."""
    canvas, true = _far_sheet(scale)
    seg = small_work.segment_page(canvas)
    assert seg.reduction < 3.0 and seg.origin != (0.0, 0.0)
    assert [len(line) for line in seg.layout.lines] == [len(line) for line in LINES]
    found = [seg.box_in_image(c) for c in seg.layout.characters]
    assert _centres_inside(found, true) == len(true)
    assert seg.whole().shape[:2] == (CANVAS[0] // 3, CANVAS[1] // 3)  # the picture: all of it


def test_a_page_written_askew_is_read_finer_and_turned_level(small_work):
    """Lines at 12 degrees: the part read again is turned level too, and the boxes,
    through the turn, the reduction and the part's corner, hold every character."""
    canvas, true = _far_sheet(0.6, angle_deg=12.0)
    seg = small_work.segment_page(canvas)
    assert seg.reduction < 3.0 and seg.origin != (0.0, 0.0) and seg.turn_deg
    assert [len(line) for line in seg.layout.lines] == [len(line) for line in LINES]
    found = [seg.box_in_image(c) for c in seg.layout.characters]
    assert _centres_inside(found, true) == len(true)


def test_the_boxes_of_a_part_read_again_are_those_of_the_part_read_alone(small_work):
    """The same characters read from the part alone (cut out of the canvas, small enough
    to be read as it is): the boxes in the file's pixels agree within the finer
    reading's pixel, shifted by where the part lies."""
    canvas, _ = _far_sheet(0.6)
    seg = small_work.segment_page(canvas)
    x0, y0 = (int(v) for v in seg.origin)
    h, w = seg.levels.shape[:2]
    r = seg.reduction
    part = canvas.crop((x0, y0, x0 + round(w * r), y0 + round(h * r)))
    alone = small_work.segment_page(part)
    assert alone.reduction == r == 1.0 and alone.origin == (0.0, 0.0)
    got = [seg.box_in_image(c) for c in seg.layout.characters]
    want = [tuple(np.add(alone.box_in_image(c), (x0, y0, x0, y0))) for c in alone.layout.characters]
    assert len(got) == len(want) == 11
    assert np.abs(np.subtract(got, want)).max() <= 1
    for c in seg.layout.characters:  # levels_box -> box_in_image: origin + reduction
        bx = seg.levels_box(c)
        assert seg.box_in_image(c) == (bx[0] + x0, bx[1] + y0, bx[2] + x0, bx[3] + y0)
    edge = seg.photo_to_ink() @ np.array([x0 + 10.0, y0 + 20.0, 1.0])
    assert np.allclose(edge[:2], [10.0, 20.0])


def test_a_photo_whose_characters_are_large_enough_is_read_once(small_work, monkeypatch):
    """Characters 40 px tall reduced 3 x 3 (13 px): no finer reading, no file read again."""
    from img2dmp.data import images

    canvas, true = _far_sheet(1.0)
    calls = []
    read = images._read_levels
    monkeypatch.setattr(images, "_read_levels", lambda *a, **k: calls.append(a) or read(*a, **k))
    seg = small_work.segment_page(canvas)
    assert len(calls) == 1 and seg.reduction == 3.0 and seg.origin == (0.0, 0.0)
    assert seg.overview is None
    assert _centres_inside([seg.box_in_image(c) for c in seg.layout.characters], true) == 11


def test_the_characters_frames_and_the_picture_stay_in_the_files_pixels(
    small_work, tmp_path, train_tiny_runs
):
    """Read by a model from the file: each character's frame maps its model input's ink
    back into its box (photo pixels), the JSON gives the same boxes, and the page
    picture shows the whole photo."""
    import json

    from img2dmp.predict import load_model

    work = tmp_path / "runs"
    work.mkdir()
    run = train_tiny_runs(work, lambda k: work / f"run{k}")[1]
    canvas, true = _far_sheet(0.6)
    canvas.save(tmp_path / "far.png")
    result = load_model(run).predict_page(tmp_path / "far.png")
    assert result.reduction < 3.0 and result.origin != (0.0, 0.0)
    assert result.image_size == CANVAS
    boxes = [c.box_image for c in result.characters]
    assert _centres_inside(boxes, true) == len(true)
    for c in result.characters:
        x0, y0, x1, y1 = c.box_image
        ys, xs = np.nonzero(c.prediction.image > 0.5)  # the model input's ink
        back = c.prediction.frame.to_image(np.stack([xs, ys], 1).astype(float))
        assert (back[:, 0] > x0 - 2).all() and (back[:, 0] < x1 + 2).all()
        assert (back[:, 1] > y0 - 2).all() and (back[:, 1] < y1 + 2).all()
    ph, pw = result.preview.shape[:2]
    assert abs(pw / ph - CANVAS[1] / CANVAS[0]) < 0.01  # the whole photo, not the part
    files = result.save(tmp_path / "out", "far")
    doc = json.loads(files[0].read_text())
    assert [e["box_image_px"] for e in doc["characters"]] == [list(b) for b in boxes]
    assert doc["image_size_px"] == [CANVAS[1], CANVAS[0]]


def test_a_region_is_read_from_a_file_as_the_upright_image_shows_it(tmp_path):
    """A region of a file stored turned (EXIF orientation 6) is the region of the image
    as viewers show it; reduced as its own size needs; its corner said; a JPEG's
    region widened to whole pixels of its decoder's scale."""
    from PIL import ImageOps

    from img2dmp.data.images import _read_levels

    rng = np.random.default_rng(0)
    raster = rng.integers(0, 256, (60, 90, 3), dtype=np.uint8)
    im = Image.fromarray(raster)
    exif = im.getexif()
    exif[0x0112] = 6
    im.save(tmp_path / "turned.png", exif=exif.tobytes())
    shown = np.asarray(ImageOps.exif_transpose(Image.open(tmp_path / "turned.png")), np.float32)
    assert shown.shape[:2] == (90, 60)
    r = _read_levels(tmp_path / "turned.png", None, 10_000, box=(7, 11, 47, 71))
    assert r.size == (90, 60) and r.origin == (7.0, 11.0) and r.reduction == 1.0
    assert np.array_equal(r.levels, shown[11:71, 7:47] / np.float32(255.0))
    coarse = _read_levels(tmp_path / "turned.png", None, 600, box=(7, 11, 47, 71))
    assert coarse.reduction == 2.0 and coarse.levels.shape == (30, 20, 3)
    for source in (Image.fromarray(shown.astype(np.uint8)), shown.astype(np.uint8)):
        same = _read_levels(source, None, 10_000, box=(7, 11, 47, 71))
        assert same.origin == (7.0, 11.0) and np.array_equal(same.levels, r.levels)
    big = Image.fromarray(rng.integers(0, 256, (400, 640, 3), dtype=np.uint8))
    big.save(tmp_path / "big.jpg", quality=95)
    j = _read_levels(tmp_path / "big.jpg", None, 4_000, box=(101, 51, 301, 251))
    assert j.reduction > 1 and j.origin[0] <= 101 and j.origin[1] <= 51
    assert j.origin[0] % j.reduction == 0 and j.origin[1] % j.reduction == 0
    assert j.levels.shape[0] * j.levels.shape[1] <= 4_000


def test_a_region_of_a_16_bit_scan_keeps_the_whole_scans_white(tmp_path):
    """A 12-bit scan stored in 16 bits whose region holds no level above 255 is divided
    by the first reading's white (4095), not read as 8 bits."""
    from img2dmp.data.images import _read_levels

    a = np.full((40, 60), 200, np.uint16)
    a[:, 40:] = 4000  # bright paper beyond the region
    Image.fromarray(a).save(tmp_path / "scan.png")
    whole = _read_levels(tmp_path / "scan.png", None)
    assert whole.white == 4095.0
    part = _read_levels(tmp_path / "scan.png", None, box=(0, 0, 30, 40), white=whole.white)
    assert np.allclose(part.levels, 200 / 4095.0)
    own = _read_levels(tmp_path / "scan.png", None, box=(0, 0, 30, 40))
    assert np.allclose(own.levels, 200 / 255.0)  # what the region alone would say


def test_a_region_beyond_the_image_is_refused_in_one_line():
    from img2dmp.data.images import _read_levels

    with pytest.raises(ValueError, match="region .* holds less than 2 x 2 pixels"):
        _read_levels(np.zeros((20, 30)), "page", box=(40, 0, 50, 10))


def _scan16(tmp_path, top: int):
    """A grey scan ``[301, 203]`` in 16 bits whose brightest level is ``top`` (4095: a
    12-bit scan stored in 16 bits), saved as PNG; its path and the levels."""
    rng = np.random.default_rng(1)
    a = rng.integers(0, top + 1, (301, 203)).astype(np.uint16)
    a[0, 0] = top
    path = tmp_path / f"scan{top}.png"
    Image.fromarray(a).save(path)
    assert Image.open(path).mode == "I;16"
    return path, a


@pytest.mark.parametrize("top", [4095, 65535])
def test_a_16_bit_scan_is_reduced_a_strip_at_a_time_to_the_same_levels(tmp_path, monkeypatch, top):
    """Reduced 3 x 3 (and 5 x 5) in strips of a few rows (``_STRIP_PIXELS`` lowered):
    the levels of converting the whole image to float and reducing it (PIL's area
    average), divided by its white (4095 for a 12-bit scan), within 1e-6; and no float
    copy of more than a strip is made (the whole scan's was 140 MB at 600 dpi)."""
    from img2dmp.data import images

    path, a = _scan16(tmp_path, top)
    monkeypatch.setattr(images, "_STRIP_PIXELS", 2_000, raising=False)
    converted = []
    convert = Image.Image.convert

    def spy(im, mode=None, *args, **kwargs):
        if mode == "F":
            converted.append(im.width * im.height)
        return convert(im, mode, *args, **kwargs)

    monkeypatch.setattr(Image.Image, "convert", spy)
    for factor in (3, 5):
        pixels = a.size // factor**2 + 1  # reduced by ``factor``
        whole = convert(Image.fromarray(a), "F").reduce(factor)
        want = np.asarray(whole, np.float32) / np.float32(top)
        for source in (path, a):
            converted.clear()
            levels, reduction, _, _ = images._levels_framed(source, None, pixels)
            assert reduction == factor and levels.shape == want.shape
            assert np.abs(levels - want).max() <= 1e-6
            assert max(converted, default=0) <= 2_000 + a.shape[1] * factor


@pytest.mark.parametrize("mode", ["L", "RGB", "I;16"])
def test_a_reduced_file_is_reduced_once_whatever_its_bits(tmp_path, mode):
    """A file over the work size is reduced ``factor`` times once: its levels are the
    file's size over the reduction it reports, for 8-bit grey as for colour and 16 bits
    (8-bit grey was reduced twice at c711c0a: a 1600-px page of Omniglot characters read
    at a quarter, its characters cut into pieces), and the levels are the area average
    of the file's."""
    from img2dmp.data import images

    rng = np.random.default_rng(2)
    a = rng.integers(0, 256, (301, 203)).astype(np.uint8)
    a[0, 0] = 255
    stored = a.astype(np.uint16) * 257 if mode == "I;16" else a
    im = Image.fromarray(stored)
    path = tmp_path / f"page_{mode.replace(';', '')}.png"
    (im.convert("RGB") if mode == "RGB" else im).save(path)
    for factor in (2, 3):
        levels, reduction, _, _ = images._levels_framed(path, None, a.size // factor**2 + 1)
        assert reduction == factor
        assert levels.shape[:2] == (-(-301 // factor), -(-203 // factor))
        grey = levels if levels.ndim == 2 else levels.mean(axis=2)
        want = np.asarray(Image.fromarray(a.astype(np.float32), mode="F").reduce(factor)) / 255
        assert np.abs(grey - want).max() <= 1.0 / 255 + 1e-6


@pytest.mark.parametrize("mode", ["L", "1"])
def test_a_grey_or_1_bit_page_file_over_the_work_size_reads_as_its_colour_twin(
    small_work, tmp_path, mode
):
    """A page stored in 8-bit grey (or 1 bit) and reduced to the work size finds the
    characters its colour file does, in the file's pixels (read at a quarter before:
    none of a 300-dpi scan's characters found, scanned_pages.py)."""
    canvas, true = _far_sheet(1.0)
    canvas.save(tmp_path / "rgb.png")
    grey = canvas.convert("L")
    (grey if mode == "L" else grey.point(lambda v: 255 if v > 128 else 0).convert("1")).save(
        tmp_path / "grey.png"
    )
    rgb, other = (small_work.segment_page(tmp_path / f) for f in ("rgb.png", "grey.png"))
    assert rgb.reduction == other.reduction == 3.0
    assert other.levels.shape[:2] == rgb.levels.shape[:2]
    found = [other.box_in_image(c) for c in other.layout.characters]
    assert _centres_inside(found, true) == len(true) == 11
