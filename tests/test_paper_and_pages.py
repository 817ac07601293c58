"""The ink separated from its paper (data/paper.py) and the characters of a page
(data/pages.py), on pages drawn here with known strokes."""

from __future__ import annotations

import numpy as np
import pytest

from drawn import ellipse as _ellipse
from drawn import glare, grainy_page
from drawn import ink as _ink
from drawn import on_paper as _on_paper
from drawn import page as _page
from drawn import ruled as _ruled
from drawn import stroke as _stroke
from img2dmp.data.pages import find_characters
from img2dmp.data.paper import dilate3, dominant_angle, paper_ink, rules

SIZE = (240, 320)
DIGIT = [_stroke([(100, 40), (150, 40), (115, 150)]), _ellipse(210, 95, 28, 50)]  # a 7, a 0


def _kept(found, truth) -> float:
    """Share of the true ink (> 0.5) kept as ink (> 0.2)."""
    t = truth > 0.5
    return float((found.ink[t] > 0.2).mean())


def test_ruled_lines_go_and_strokes_crossing_them_stay():
    truth = _ink(SIZE, DIGIT)
    found = paper_ink(_on_paper(truth, _ruled(SIZE, 30.0, angle_deg=1.5)))
    assert _kept(found, truth) > 0.97
    far = _ink(SIZE, DIGIT, width=14.0) < 0.01  # paper well away from the strokes
    assert (found.ink[far] > 0.2).mean() < 0.002, "rules left as ink"
    assert found.removed["rule_px"] > 1000
    # where the strokes cross a rule, they keep their pixels there
    cross = (truth > 0.5) & (_ruled(SIZE, 30.0, angle_deg=1.5)[..., 0] < 0.9)
    assert cross.sum() > 20 and (found.ink[cross] > 0.2).mean() > 0.9


def test_squared_paper_tint_and_a_lighting_gradient():
    truth = _ink(SIZE, DIGIT)
    paper = _ruled(SIZE, 24.0, angle_deg=-2.0, vertical=True, colour=(0.6, 0.6, 0.6))
    paper *= np.array([1.0, 0.95, 0.7], np.float32)  # yellow
    light = np.linspace(1.0, 0.55, SIZE[1], dtype=np.float32)[None, :, None]  # a shadow
    found = paper_ink(_on_paper(truth, paper * light, colour=(0.1, 0.2, 0.7)))  # blue ink
    assert _kept(found, truth) > 0.95
    far = _ink(SIZE, DIGIT, width=14.0) < 0.01
    assert (found.ink[far] > 0.2).mean() < 0.003


def test_text_from_the_back_specks_and_the_table_edge_go():
    rng = np.random.default_rng(3)
    truth = _ink(SIZE, DIGIT)
    paper = np.full((*SIZE, 3), 0.95, np.float32)
    faint = np.zeros(SIZE, np.float32)  # rows of blurred print showing through
    for r in range(20, SIZE[0] - 10, 18):
        for c in range(10, SIZE[1] - 20, 9):
            faint[r : r + 7, c : c + 5] = 0.12
    paper *= 1.0 - faint[..., None]
    paper[:, -14:] = 0.25  # the table beyond the sheet's edge
    img = _on_paper(truth, paper)
    specks = rng.integers(0, SIZE[0] * 300, 150)
    img.reshape(-1, 3)[specks] = 0.05
    found = paper_ink(img)
    assert _kept(found, truth) > 0.95
    far = _ink(SIZE, DIGIT, width=14.0) < 0.01
    assert (found.ink[far] > 0.2).mean() < 0.002


def test_nothing_but_paper_or_specks_is_no_ink():
    paper = np.full((200, 300, 3), 0.9, np.float32)
    assert paper_ink(paper) is None
    rng = np.random.default_rng(0)
    paper.reshape(-1, 3)[rng.integers(0, 60000, 400)] = 0.1
    assert paper_ink(paper) is None


def test_a_small_clean_image_keeps_its_strokes():
    """An MNIST-sized image (light ink on black) is read as before: every stroke kept."""
    truth = _ink((28, 28), [_stroke([(8, 6), (20, 6), (12, 22)])], width=2.5)
    found = paper_ink(truth)
    assert _kept(found, truth) == 1.0 and not found.dark_on_light


def _matches(layout, boxes, tol=4.0) -> bool:
    found = [c.box for c in layout.characters]
    if len(found) != len(boxes):
        return False
    return all(abs(a - b) <= tol for f, t in zip(found, boxes, strict=True)
               for a, b in zip(f, t, strict=True))  # fmt: skip


def test_characters_found_in_reading_order_on_two_lines():
    ink, boxes = _page([[("1", 40), ("7", 110), ("0", 190), ("5", 270)],
                        [("0", 60), ("5", 150), ("7", 240)]])  # fmt: skip
    layout = find_characters(ink > 0.5)
    assert _matches(layout, boxes), [c.box for c in layout.characters]
    assert [c.line for c in layout.characters] == [0, 0, 0, 0, 1, 1, 1]
    assert [len(x) for x in layout.lines] == [4, 3]
    five = layout.characters[3]
    assert five.parts == 2  # the 5's bar and its body are one character


def test_a_line_rotated_a_few_degrees_stays_one_line():
    ink, boxes = _page([[("1", 30), ("7", 100), ("0", 170), ("5", 240), ("7", 310), ("0", 380)],
                        [("5", 30), ("0", 120), ("1", 210), ("7", 300), ("0", 390)]],
                       angle_deg=4.0)  # fmt: skip
    assert abs(dominant_angle(ink > 0.5) - 4.0) < 1.0
    layout = find_characters(ink > 0.5)
    assert [len(x) for x in layout.lines] == [6, 5]
    assert _matches(layout, boxes)


def test_touching_characters_are_cut_apart():
    line = [("0", 40), ("7", 100), ("0", 160), ("0", 183), ("7", 260), ("0", 320)]
    ink, boxes = _page([line])
    mask = ink > 0.5
    labels = __import__("scipy.ndimage", fromlist=["label"]).label(mask, np.ones((3, 3)))[1]
    assert labels == 5  # the two zeros at 160 and 183 touch
    layout = find_characters(mask)
    assert len(layout.characters) == 6
    assert sum(c.split for c in layout.characters) == 2
    assert _matches(layout, boxes, tol=6.0)
    # cut=False (a stroke model's page): every mark stays whole, the touching pair one
    whole = find_characters(mask, cut=False)
    assert len(whole.characters) == 5 and not any(c.split for c in whole.characters)
    pair = whole.characters[2].box
    assert abs(pair[0] - boxes[2][0]) <= 4 and abs(pair[2] - boxes[3][2]) <= 4


def test_pieces_side_by_side_join_only_when_much_closer_than_the_lines_spacing():
    # two strokes 13 px apart where the line's neighbours are ~46 px apart: one character
    # of pieces side by side (a Korean syllable's); 27 px apart: two; two 0s as close:
    # too wide together for one character (pages.SIDE_GAP, SIDE_WIDTH)
    def boxes_of(line, join):
        ink, _ = _page([line])
        return [c.box for c in find_characters(ink > 0.5, cut=False, join_sides=join).characters]

    close = [("0", 40), ("7", 110), ("1", 180), ("1", 196), ("0", 250), ("7", 320)]
    apart = [("0", 40), ("7", 110), ("1", 180), ("1", 210), ("0", 264), ("7", 334)]
    zeros = [("0", 40), ("7", 110), ("0", 170), ("0", 202), ("0", 264), ("7", 334)]
    assert len(boxes_of(close, False)) == 6
    joined = boxes_of(close, True)
    assert len(joined) == 5 and joined[2][0] < 195 and joined[2][2] > 205  # both strokes
    assert len(boxes_of(apart, True)) == 6
    assert len(boxes_of(zeros, True)) == 6
    assert boxes_of(close, True)[:2] == boxes_of(close, False)[:2]


def test_a_1_touching_a_7_is_cut_though_no_wider_than_a_character():
    # the 1's top meets the 7's bar: one mark as narrow as a 0, two characters tall on
    # either side of the single stroke between them (pages.WAIST_TALL)
    line = [("0", 40), ("7", 110), ("1", 170), ("7", 180), ("0", 260)]
    ink, boxes = _page([line])
    mask = ink > 0.5
    labels = __import__("scipy.ndimage", fromlist=["label"]).label(mask, np.ones((3, 3)))[1]
    assert labels == 4  # the 1 and the second 7 touch
    layout = find_characters(mask)
    found = [c.box for c in layout.characters]
    assert [c.split for c in layout.characters] == [False, False, True, True, False], found
    one, seven = found[2], found[3]
    assert 176 <= one[0] and one[2] <= 192  # the 1 and a little of the bar it touches
    assert one[2] == seven[0] and abs(seven[2] - boxes[3][2]) <= 4  # the 7, cut on its bar
    assert _matches(layout.__class__(characters=[layout.characters[i] for i in (0, 1, 4)]),
                    [boxes[i] for i in (0, 1, 4)])  # fmt: skip


def test_a_4_whose_downstroke_leans_is_not_cut_where_its_bar_meets_it():
    # the column through the bar's junction with the leaning downstroke crosses one
    # stroke with full-height ink on either side, but that stroke runs far down the
    # column (pages.WAIST_RUN)
    x, y, h = 100.0, 60.0, 40.0
    four = [_stroke([(x + 14, y), (x, y + 26), (x + 26, y + 26)]),  # the open top and bar
            _stroke([(x + 21, y), (x + 15, y + h)])]  # the downstroke, leaning left  # fmt: skip
    zero = _ellipse(x + 70, y + h / 2, 12, h / 2)
    mask = _ink((160, 260), [*four, zero]) > 0.5
    layout = find_characters(mask)
    assert len(layout.characters) == 2, [c.box for c in layout.characters]
    assert not any(c.split for c in layout.characters)


def test_an_empty_mask_has_no_characters_and_a_bad_one_is_refused():
    assert find_characters(np.zeros((50, 60), bool)).characters == []
    with pytest.raises(ValueError, match="2-D"):
        find_characters(np.zeros((2, 3, 4), bool))


def _dotted(size, spacing: float, radius: float, holes: float = 0.0, seed: int = 0):
    """Paper [H, W, 3] with a square lattice of grey dots, a share ``holes`` missing."""
    rng = np.random.default_rng(seed)
    h, w = size
    rows, cols = np.mgrid[:h, :w].astype(np.float32)
    dots = np.zeros(size, np.float32)
    for cy in np.arange(spacing / 2, h, spacing):
        for cx in np.arange(spacing / 2, w, spacing):
            if rng.random() >= holes:
                d = np.hypot(rows - cy, cols - cx)
                dots = np.maximum(dots, np.clip(radius + 0.5 - d, 0.0, 1.0))
    paper = np.full((h, w, 3), 0.95, np.float32)
    return paper * (1.0 - 0.6 * dots[..., None])


@pytest.mark.parametrize("radius, holes", [(1.5, 0.0), (3.5, 0.3)])
def test_dotted_paper_s_dots_go_even_with_holes_and_the_strokes_stay(radius, holes):
    truth = _ink(SIZE, DIGIT)
    found = paper_ink(_on_paper(truth, _dotted(SIZE, 20.0, radius, holes)))
    assert _kept(found, truth) > 0.95
    far = _ink(SIZE, DIGIT, width=14.0) < 0.01
    assert (found.ink[far] > 0.2).mean() < 0.002, "dots left as ink"


def test_a_tinted_page_in_deep_shadow_is_dark_ink_on_light_paper():
    from img2dmp.data.paper import _planes, dark_on_light

    truth = _ink(SIZE, DIGIT)
    light = np.linspace(0.95, 0.35, SIZE[1], dtype=np.float32)[None, :, None]  # a shadow
    page = _on_paper(truth, np.full((*SIZE, 3), [0.7, 0.8, 0.75], np.float32) * light)
    assert dark_on_light(_planes(page))
    assert not dark_on_light(_planes(1.0 - page))  # chalk on a blackboard
    assert _kept(paper_ink(page), truth) > 0.95


def test_a_stroke_along_a_grid_line_as_dark_as_the_pen_keeps_its_pixels_there():
    # a 0 whose flat top runs 12 px along a line of squared paper drawn with the pen's
    # own colour and width: the line's pixels between where the 0 meets and leaves it
    # stay ink (the rest of the line goes)
    size, pen = (240, 320), (0.1, 0.2, 0.7)
    zero = [_stroke([(176, 128), (164, 128), (156, 142), (156, 172), (170, 188), (184, 172),
                     (184, 142), (176, 128)])]  # fmt: skip
    truth = _ink(size, zero)
    paper = _ruled(size, 64.0, vertical=True, colour=pen, width=3.0)
    found = paper_ink(_on_paper(truth, paper, colour=pen))
    top = np.zeros(size, bool)
    top[126:131, 166:175] = True  # the 0's top, on the line at row 128
    assert (found.ink[top & (truth > 0.5)] > 0.2).mean() > 0.9
    line = np.zeros(size, bool)
    line[126:131, 200:300] = True  # the same line away from the 0
    assert (found.ink[line] > 0.2).mean() < 0.05


def test_strokes_joined_to_a_net_of_faint_wavy_lines_stay_and_the_net_goes():
    # pale wavy lines (no rules: they bend too much) cross the whole image and join the
    # 7 and the 0 into one component, mostly faint: the strokes are its strong pieces
    size = SIZE
    rows, cols = np.mgrid[: size[0], : size[1]].astype(np.float32)
    line = np.zeros(size, np.float32)
    for coord in (rows + 8.0 * np.sin(cols / 13.0), cols + 8.0 * np.sin(rows / 11.0)):
        d = 20.0 - np.abs((coord % 40.0) - 20.0)  # to the nearest wavy line
        line = np.maximum(line, np.clip(1.5 - d, 0.0, 1.0))
    paper = np.ones(size + (3,), np.float32) * np.array([0.97, 0.96, 0.93], np.float32)
    paper *= 1.0 - 0.25 * line[..., None]  # a quarter as dark as the pen
    truth = _ink(size, DIGIT)
    found = paper_ink(_on_paper(truth, paper))
    assert found is not None
    assert _kept(found, truth) > 0.9
    far = _ink(size, DIGIT, width=14.0) < 0.01
    assert (found.ink[far] > 0.2).mean() < 0.01, "the faint lines left as ink"


def test_a_stroke_along_a_lighter_rule_keeps_its_pixels_on_it_where_no_rules_cross():
    # the darkness itself: ruled lines (0.57) lighter than the pen (0.84), and a stroke
    # that comes down, runs 40 px along the rule at row 100 (0.8 there: blurred, the
    # stroke over the rule is no darker than the pen) and goes down again; with no
    # columns there is no crossing of two rules, whose double darkness (0.87) the
    # stroke's own pixels do not reach
    dark = np.zeros((200, 300), np.float32)
    for r in (50, 100, 150):
        dark[r - 1 : r + 2] = 0.57
    dark[60:100, 120:123] = 0.84  # down to the rule
    dark[99:102, 120:163] = 0.80  # along it
    dark[100:140, 160:163] = 0.84  # and down again
    mask = dark >= 0.15
    removed, _ = rules(mask, np.ones(mask.shape, bool), dark, 3.0)
    assert removed[99:102, 200:290].all(), "the rule away from the stroke stays a rule"
    assert not removed[99:102, 125:158].any(), "the stroke along the rule is kept"


def test_one_image_counts_its_characters_as_digits_or_as_a_stroke_models_letters():
    from img2dmp.predict import count_characters

    # two 0s that touch (an "m"'s waist): two digits, one letter whole
    line = [("0", 40), ("7", 100), ("0", 160), ("0", 183), ("7", 260), ("0", 320)]
    ink, _ = _page([line])
    assert count_characters(ink > 0.5) == 6
    assert count_characters(ink > 0.5, letters=True) == 5
    # two strokes much closer than the line's spacing: one letter of pieces side by side
    ink, _ = _page([[("0", 40), ("7", 110), ("1", 180), ("1", 196), ("0", 250), ("7", 320)]])
    assert count_characters(ink > 0.5) == 6
    assert count_characters(ink > 0.5, letters=True) == 5


def _sheet_on_desk(desk_grey, *, angle_deg=0.0, margin=(40, 48), sides="all", grain=0.0, seed=0):
    """The two lines of :func:`_page` on a white sheet (lit a little unevenly) lying on a
    desk of ``desk_grey`` (with ``grain``: noise of that many levels), ``margin`` (rows,
    columns) of desk beyond it (``sides="left"``: on the left only), the sheet turned by
    ``angle_deg``, slightly blurred as a phone sees it; the image and the true boxes'
    centres."""
    from PIL import Image, ImageFilter

    lines = [[("1", 40), ("7", 110), ("0", 190), ("5", 270), ("7", 350)],
             [("0", 60), ("5", 150), ("7", 240), ("1", 330)]]  # fmt: skip
    ink, boxes = _page(lines)
    h, w = ink.shape
    light = np.linspace(1.0, 0.72, w, dtype=np.float32)[None, :, None]  # to the desk's level
    sheet = _on_paper(ink, np.full((h, w, 3), 0.93, np.float32) * light)
    photo = Image.fromarray((sheet * 255).astype(np.uint8)).convert("RGBA")
    photo = photo.rotate(angle_deg, resample=Image.Resampling.BICUBIC, expand=True)
    my, mx = margin
    out_h, out_w = photo.height + 2 * my, photo.width + (mx if sides == "left" else 2 * mx)
    desk = np.full((out_h, out_w, 3), desk_grey, np.float32)
    desk += np.random.default_rng(seed).normal(0.0, grain, (out_h, out_w, 1))
    im = Image.fromarray(np.clip(desk, 0, 255).astype(np.uint8))
    x0, y0 = mx, my
    if sides == "left":
        im = im.crop((0, my, out_w, my + photo.height))
        y0 = 0
    im.paste(photo, (x0, y0), photo)
    im = im.filter(ImageFilter.GaussianBlur(0.8))
    a = np.deg2rad(angle_deg)
    centres = []
    for b in boxes:  # the centres moved as the sheet was turned and put down
        dx, dy = (b[0] + b[2]) / 2 - w / 2, (b[1] + b[3]) / 2 - h / 2
        centres.append((x0 + photo.width / 2 + np.cos(a) * dx + np.sin(a) * dy,
                        y0 + photo.height / 2 - np.sin(a) * dx + np.cos(a) * dy))  # fmt: skip
    return np.asarray(im, np.float32) / 255.0, centres


def _found_at(img, centres):
    """The ink of ``img`` and whether its characters are exactly one box per true centre."""
    found = paper_ink(img)
    assert found is not None, "no ink found"
    boxes = [c.box for c in find_characters(found.mask, core=found.core).characters]
    inside = [[b[0] <= x < b[2] and b[1] <= y < b[3] for b in boxes] for x, y in centres]
    one_each = all(sum(row) == 1 for row in inside)
    return found, boxes, one_each and len(boxes) == len(centres)


@pytest.mark.parametrize("desk_grey", [120, 160, 255])
def test_a_sheet_on_a_desk_darker_or_lighter_than_it_keeps_only_its_characters(desk_grey):
    """The desk around the sheet (mid-grey, as light as the paper's shade, or lighter than
    the paper) and the sheet's edges are no ink: the nine characters, nothing more (120
    read no ink at all before the sheet was looked for). A desk darker than
    ``DESK_DARK`` of the paper is left to ``sheet_mask``, as before."""
    img, centres = _sheet_on_desk(desk_grey)
    found, boxes, ok = _found_at(img, centres)
    assert ok, (len(boxes), boxes)
    assert found.removed["desk_px"] > 0.15 * img.shape[0] * img.shape[1]
    assert 2.5 < found.pen_width_px < 4.5  # the pen's (3 px), not the edge's band


@pytest.mark.parametrize(("desk_grey", "grain"), [(120, 4.0), (150, 3.0)])
def test_a_turned_sheet_on_a_grainy_desk_keeps_only_its_characters(desk_grey, grain):
    img, centres = _sheet_on_desk(desk_grey, angle_deg=5.0, grain=grain, seed=1)
    found, boxes, ok = _found_at(img, centres)
    assert ok, (len(boxes), boxes)
    assert found.removed["desk_px"] > 0


def test_a_turned_sheet_with_its_corners_on_the_border_and_lighter_corners_beyond():
    """As a photo turned with its frame expanded: the corners beyond the sheet are lighter
    than its shade, and its edges run across the frame."""
    img, centres = _sheet_on_desk(245, angle_deg=-5.0, margin=(0, 0))
    found, boxes, ok = _found_at(img, centres)
    assert ok, (len(boxes), boxes)


def test_a_sheet_edge_inside_the_frame_on_one_side_only():
    img, centres = _sheet_on_desk(130, sides="left", grain=3.0)
    found, boxes, ok = _found_at(img, centres)
    assert ok, (len(boxes), boxes)
    assert found.removed["desk_px"] > 0


def test_no_desk_is_found_on_a_sheet_alone_nor_in_its_shadow():
    """A sheet that fills the photo, with a hard shadow across it (a step as sharp as an
    edge, but with writing on its far side), has no desk: all nine characters stay."""
    from scipy.ndimage import gaussian_filter

    from img2dmp.data.sheet import find_sheet

    img, centres = _sheet_on_desk(128, margin=(0, 0))
    assert find_sheet(np.ascontiguousarray(np.moveaxis(img, 2, 0))) is None
    rows, cols = np.mgrid[: img.shape[0], : img.shape[1]]
    shade = gaussian_filter(np.where(cols + 0.8 * rows > 330, 0.55, 1.0), 2.0)
    found, boxes, ok = _found_at((img * shade[..., None]).astype(np.float32), centres)
    assert found.removed["desk_px"] == 0


@pytest.mark.parametrize(
    ("level", "soft", "slope"),
    [(0.4, 1.0, 0.0), (0.3, 6.0, 0.0), (0.25, 3.0, -0.5), (0.6, 1.0, 0.35)],
)
def test_a_shadow_across_the_page_is_paper_with_its_writing_read(level, soft, slope):
    """A phone's shadow across half the sheet (hard or soft, straight or slanted), as
    dark as a table (``TABLE_LEVEL``) or a desk's shade: the paper in it holds writing,
    so it is no table and no desk (``holds_writing``), and the band its hard edge leaves
    in the paper's level joins nothing (``without_shade_bands``): all nine characters,
    nothing more. Before, the shaded half was off the sheet and its characters lost.
    The page is enlarged to 450 x 780 first: a smaller image is read as a crop, its
    paper one smooth surface."""
    from PIL import Image
    from scipy.ndimage import gaussian_filter

    small, centres = _sheet_on_desk(128, margin=(0, 0))
    im = Image.fromarray((small * 255).astype(np.uint8))
    im = im.resize((im.width * 3 // 2, im.height * 3 // 2), Image.Resampling.BICUBIC)
    img, centres = np.asarray(im, np.float32) / 255.0, [(1.5 * x, 1.5 * y) for x, y in centres]
    rows, cols = np.mgrid[: img.shape[0], : img.shape[1]]
    edge = cols - 0.5 * img.shape[1] + slope * (rows - 0.5 * img.shape[0])
    shade = gaussian_filter(np.where(edge > 0, level, 1.0), soft)
    found, boxes, ok = _found_at((img * shade[..., None]).astype(np.float32), centres)
    assert ok, (len(boxes), boxes)
    assert found.removed["off_sheet_px"] == 0 and found.removed["desk_px"] == 0


@pytest.mark.parametrize("level", [0.5, 0.25])
def test_a_photographed_character_half_in_a_shadow_keeps_its_strokes(level):
    """One character photographed (a crop under ``SURFACE_MAX_SIDE``, read with a smooth
    paper), the shadow's edge across it: its strokes joined to the shadow made one mark
    half the image wide, the rough pen width came out 40 px, and no ink was found. In a
    shadow of a quarter of the light the smooth reading found no ink either; the crop is
    read with cells then (``crop_shade_step``)."""
    from scipy.ndimage import gaussian_filter

    from img2dmp.data.paper import rough_pen_width

    truth = _ink((200, 200), [_stroke([(40, 40), (160, 40), (80, 170)]),
                              _stroke([(60, 110), (150, 110)])], width=5.0)  # fmt: skip
    img = _on_paper(truth, np.full((200, 200, 3), 0.9, np.float32))
    cols = np.mgrid[:200, :200][1]
    shaded = img * gaussian_filter(np.where(cols > 100, level, 1.0), 1.0)[..., None]
    assert rough_pen_width(np.moveaxis(shaded, 2, 0).astype(np.float32)) < 10.0
    found = paper_ink(shaded.astype(np.float32))
    assert found is not None and _kept(found, truth) > 0.9


def test_squared_paper_in_a_deep_shadow_is_paper_though_its_grid_joins_the_writing():
    """Squared paper half in a hard shadow of 0.3: the shaded half looks like a table
    beyond the sheet (``TABLE_LEVEL``) until it is seen to hold writing. Its grid, as
    dark as the pen's strong level there, joined every stroke into one net, one mark
    where ``holds_writing`` wants two: the half was off the sheet and 4 of the 9
    characters lost. Counted again at the pen's own level, the lighter grid no longer
    joins them: all nine, nothing more."""
    from PIL import Image
    from scipy.ndimage import gaussian_filter

    lines = [[("1", 40), ("7", 110), ("0", 190), ("5", 270), ("7", 350)],
             [("0", 60), ("5", 150), ("7", 240), ("1", 330)]]  # fmt: skip
    ink, boxes = _page(lines)
    img = _on_paper(ink, _ruled(ink.shape, 20.0, vertical=True, colour=(0.45, 0.45, 0.5),
                                width=1.2))  # fmt: skip
    im = Image.fromarray((img * 255).astype(np.uint8)).resize((780, 450), Image.Resampling.BICUBIC)
    img = np.asarray(im, np.float32) / 255.0
    centres = [(0.75 * (b[0] + b[2]), 0.75 * (b[1] + b[3])) for b in boxes]
    cols = np.mgrid[: img.shape[0], : img.shape[1]][1]
    shade = gaussian_filter(np.where(cols > img.shape[1] // 2, 0.3, 1.0), 1.0)
    found, got, ok = _found_at((img * shade[..., None]).astype(np.float32), centres)
    assert ok, (len(got), got)
    assert found.removed["off_sheet_px"] == 0


@pytest.mark.parametrize(("level", "soft", "slope"), [(0.3, 1.0, 0.0), (0.25, 1.5, -0.5),
                                                     (0.3, 6.0, 0.0)])  # fmt: skip
def test_a_small_page_across_a_deep_shadow_is_read_with_cells(level, soft, slope):
    """A page under ``SURFACE_MAX_SIDE`` (300 x 520, read as a crop: one smooth paper)
    half in a deep shadow: the smooth surface cannot follow the edge, whose band raised
    the ink's level so that the strokes in the shade were dropped as faint (4 of the 9
    characters found) or nothing was (no ink). The step between even cells is seen
    (``crop_shade_step``) and the crop read with cells too: all nine, nothing more."""
    from scipy.ndimage import gaussian_filter

    from img2dmp.data.paper import SURFACE_MAX_SIDE, crop_shade_step, rough_pen_width

    img, centres = _sheet_on_desk(128, margin=(0, 0))
    assert min(img.shape[:2]) < SURFACE_MAX_SIDE
    rows, cols = np.mgrid[: img.shape[0], : img.shape[1]]
    edge = cols - 0.5 * img.shape[1] + slope * (rows - 0.5 * img.shape[0])
    shaded = (img * gaussian_filter(np.where(edge > 0, level, 1.0), soft)[..., None]).astype(
        np.float32
    )
    planes = np.ascontiguousarray(np.moveaxis(shaded, 2, 0))
    assert crop_shade_step(planes, rough_pen_width(planes))
    found, boxes, ok = _found_at(shaded, centres)
    assert ok, (len(boxes), boxes)


def test_a_crop_without_a_shadow_has_no_shade_step():
    """The step test keeps a crop's smooth reading where there is no shadow: a page
    lit by a gradient and a character on plain paper are no step."""
    from img2dmp.data.paper import crop_shade_step, rough_pen_width

    img, _ = _sheet_on_desk(128, margin=(0, 0))
    light = np.linspace(1.0, 0.6, img.shape[1], dtype=np.float32)[None, :, None]
    truth = _ink((200, 200), [_stroke([(40, 40), (160, 40), (80, 170)])], width=5.0)
    char = _on_paper(truth, np.full((200, 200, 3), 0.9, np.float32))
    for lit in (img * light, char):
        planes = np.ascontiguousarray(np.moveaxis(lit.astype(np.float32), 2, 0))
        assert not crop_shade_step(planes, rough_pen_width(planes))


def test_a_faint_stroke_that_runs_beside_a_printed_rule_and_leaves_it_is_kept():
    # ruled lines (0.3) much lighter than the pen (0.8), printed under the ink; a thin
    # stroke (0.45: lighter than half way from the line to the pen) comes down, runs
    # 17 px along the rule at row 100 in the rows beside the line that a rule is taken
    # with (two rows of slack) and goes down again: darker than the line there is (none;
    # a stroke along it for over half of 1/8 of the width would raise that level)
    dark = np.zeros((200, 300), np.float32)
    for r in (50, 100, 150):
        dark[r - 1 : r + 2] = 0.3
    dark[60:104, 120:123] = 0.8  # down to the rule
    dark[102:104, 120:137] = 0.45  # beside it, along it
    dark[102:140, 134:137] = 0.8  # and down again
    mask = dark >= 0.15
    removed, _ = rules(mask, np.ones(mask.shape, bool), dark, 3.0)
    assert removed[99:102, 200:290].all(), "the rule away from the stroke stays a rule"
    assert not removed[102:104, 123:134].any(), "the stroke beside the rule is kept"


def test_the_sheet_s_edge_cut_into_pieces_by_rules_is_not_a_character():
    from scipy.ndimage import label

    from img2dmp.data.paper import _along_border

    size = (200, 300)
    marks, ruled = np.zeros(size, bool), np.zeros(size, bool)
    for c in range(0, 300, 20):  # the edge's dark band, a piece every 20 px, the
        marks[0:3, c + 4 : c + 20] = True  # rule's pixels between the pieces
        ruled[0:3, c : c + 4] = True
    marks[1:40, 150:153] = False
    marks[0:40, 150:153] = True  # a character reaching the edge joins it
    marks[120:199, 100:103] = True  # a 1 cut by the bottom border
    ruled[196:199] = True  # a rule along the bottom border, crossing it
    marks[196:199] &= ~ruled[196:199]
    marks[196:199, 100:103] = True
    labels, n = label(marks, structure=np.ones((3, 3), bool))
    assert not _along_border(labels, n).any(), "each piece alone is short of the share"
    edge = _along_border(labels, n, ruled)
    assert edge[np.unique(labels[0:3, 4:20])].all() and edge[labels[20, 151]]
    assert not edge[labels[150, 101]], "a character cut by the border is no edge"


def test_a_line_of_digits_most_of_which_touch_is_cut_into_them():
    """Written with a marker, most digits of a line touch: runs of 4, 3 and 3 zeros and
    three digits alone. The usual width is read from the marks about one digit wide
    (``ALONE_WIDTH``), not from the runs (the upper quartile of all widths is a run's:
    the run of 4 was kept whole); a page of letters still counts every mark."""
    from scipy.ndimage import label

    from img2dmp.data import pages

    runs = [20, 43, 66, 89, 150, 173, 196, 260, 283, 306]
    line = [("0", x) for x in runs] + [("1", 370), ("0", 410), ("7", 460)]
    ink, boxes = _page([line], size=(220, 520))
    mask = ink > 0.5
    assert label(mask, np.ones((3, 3)))[1] == 6  # three runs of touching zeros, three alone
    layout = find_characters(mask)
    assert len(layout.characters) == len(line) == 13
    assert _matches(layout, boxes, tol=8.0), [c.box for c in layout.characters]
    everything = pages.ALONE_WIDTH
    try:
        pages.ALONE_WIDTH = float("inf")  # every mark counts, as before
        assert len(find_characters(mask).characters) < 13
    finally:
        pages.ALONE_WIDTH = everything


def test_the_sheet_s_corner_beside_the_border_is_not_a_character():
    """The two thin lines of a sheet's corner, an L beside two borders (as the yellow
    shared photo's top right keeps once the desk's band above it is gone), are its edge;
    not as a whole (an L is as thick as it is long), but along each border. A 7 cut by
    the right border near that corner, and a 7 lying in the corner's band, stay."""
    from scipy.ndimage import label

    from img2dmp.data.paper import _edge_lines

    size = (410, 594)
    marks = np.zeros(size, bool)
    marks[8, 556:594] = True  # the top line, 8 px below the border
    marks[8:43, 593] = True  # the right one, on the border
    marks[150, 570:594] = True  # a 7's bar, cut by the right border ...
    for t in range(30):  # ... and its downstroke
        marks[150 + t, 590 - t // 3] = True
    marks[300, 582:594] = True  # a small 7 lying in the band beside the right border
    for t in range(25):
        marks[300 + t, 593 - t // 3] = True
    labels, n = label(marks, structure=np.ones((3, 3), bool))
    assert n == 3
    edge = _edge_lines(labels)
    assert edge[labels[8, 560]], "the corner's L is the sheet's edge"
    assert not edge[labels[150, 580]] and not edge[labels[300, 570]], "a 7 is no edge"
    marks[8:43, 593] = False  # one line alone, a piece of the edge: as it was
    labels, n = label(marks, structure=np.ones((3, 3), bool))
    assert _edge_lines(labels)[labels[8, 560]]


def test_the_yellow_photo_s_corner_is_no_character():
    """The yellow shared photo: its 64 digits in three lines of two numbers, and nothing
    in its top right corner (the sheet's corner, two thin lines, read as two characters
    before). Skips, saying so, without ``../shared/data/photos``."""
    import json
    from pathlib import Path

    from img2dmp.page import segment_page

    photos = Path(__file__).resolve().parents[2] / "shared" / "data" / "photos"
    if not (photos / "photos.json").is_file():
        pytest.skip(f"the shared phone photos are not at {photos} (../shared/data/photos)")
    listed = json.loads((photos / "photos.json").read_text())["photos"]
    lines = {p["file"]: p["lines"] for p in listed}
    truth = sum(len(line.replace(" ", "")) for line in lines["page_yellow_blue_ink.png"])
    seg = segment_page(photos / "page_yellow_blue_ink.png")
    boxes = [c.box for c in seg.layout.characters]
    assert not [b for b in boxes if b[1] < 40 and b[2] > 500], "a character in the corner"
    assert len(boxes) == truth


def _grid_cover(size, spacing: float, width: float = 1.6, columns: bool = True) -> np.ndarray:
    """The share ``[H, W]`` of every pixel covered by lines every ``spacing`` pixels along
    the rows (and the columns)."""
    rows, cols = np.mgrid[: size[0], : size[1]].astype(np.float32)
    cover = np.zeros(size, np.float32)
    for coord in (rows, cols) if columns else (rows,):
        d = spacing / 2 - np.abs((coord % spacing) - spacing / 2)  # to the nearest line
        cover = np.maximum(cover, np.clip(width / 2 + 0.5 - d, 0.0, 1.0))
    return cover


LARGE = (420, 560)  # cells of paper, not a crop's smooth surface
LARGE_DIGIT = [_stroke([(180, 120), (300, 120), (220, 330)]), _ellipse(400, 220, 50, 100)]


def test_lines_lighter_than_yellow_paper_in_blue_do_not_make_the_sheet_ink():
    # blue squares on yellow paper, drawn over it: darker than the paper in red and
    # green, lighter in blue (as a JPEG's chroma smears a blue rule, or an editor draws
    # it); a quarter of the pixels. The paper's colour taken channel by channel was the
    # lines' in blue, and the whole sheet read as ink
    truth = _ink(LARGE, LARGE_DIGIT)
    cover = _grid_cover(LARGE, 16.0)[..., None]
    yellow = np.array([0.96, 0.92, 0.55], np.float32)
    paper = np.ones((*LARGE, 3), np.float32) * yellow * (1 - cover)
    paper += cover * np.array([0.55, 0.65, 0.85], np.float32)
    found = paper_ink(_on_paper(truth, paper))
    assert found is not None, "the sheet was read as ink"
    assert _kept(found, truth) > 0.97
    far = _ink(LARGE, LARGE_DIGIT, width=14.0) < 0.01
    assert (found.ink[far] > 0.2).mean() < 0.002, "paper or lines left as ink"


def test_a_legal_pad_s_noisy_blue_channel_is_not_ink():
    # yellow paper reflects little blue, and a phone's JPEG adds as much noise there as
    # in the other channels: against the blue channel's own level it was three times
    # as large, and the paper broke into specks and faint marks
    truth = _ink(LARGE, LARGE_DIGIT)
    paper = np.ones((*LARGE, 3), np.float32) * np.array([0.98, 0.92, 0.42], np.float32)
    rules_ = _grid_cover(LARGE, 24.0, 0.8, columns=False)[..., None]  # pale blue rules
    paper = paper * (1.0 - rules_ * (1.0 - np.array([0.55, 0.7, 0.9], np.float32)))
    img = _on_paper(truth, paper, colour=(0.15, 0.2, 0.6))  # blue ink
    rng = np.random.default_rng(0)
    img[..., 2] += rng.normal(0.0, 0.02, LARGE).astype(np.float32)
    found = paper_ink(np.clip(img, 0.0, 1.0))
    assert _kept(found, truth) > 0.97
    far = _ink(LARGE, LARGE_DIGIT, width=14.0) < 0.01
    assert (found.ink[far] > 0.2).mean() < 0.002, "the blue channel's noise left as ink"
    assert found.removed["faint_components"] < 100


def test_a_wavy_rule_s_level_is_read_along_it_and_the_paper_s_beside_it():
    from img2dmp.data.paper import _line_level

    # rules (0.35, two rows thick) that wave 3 rows either way every 320 px: within a
    # stretch of 1/8 of the width no straight row holds the line for half of it, so the
    # rows' medians read the paper on 40 % of the line, whose pixels then stood out as
    # ink over it (a generated ruled page's extra boxes 86 -> 231); followed along the
    # line, the level on it is the line's, and beside it the paper's
    h, w = 240, 640
    dark = np.zeros((h, w), np.float32)
    cols = np.arange(w)
    for r0 in (60, 120, 180):
        middle = np.round(r0 + 3.0 * np.sin(2 * np.pi * cols / 320.0)).astype(int)
        for c in cols:
            dark[middle[c] - 1 : middle[c] + 1, c] = 0.35
    line = dark > 0
    level = _line_level(dark, line, 0.0)
    assert (level[line] > 0.3).mean() > 0.99, "the paper's level read on the line"
    beside = ~dilate3(dilate3(line))
    assert (level[beside] < 0.05).all(), "the line's level read on the paper"


def test_a_blue_stroke_along_a_red_margin_as_dark_as_the_pen_is_kept():
    # a legal pad: yellow paper, pale blue rules and a red double margin printed under
    # the ink, the margin (0.65) nearly as dark as the blue pen (0.7) in its darkest
    # channel; a 7 whose bar ends between the margin's two lines, its downstroke running
    # down between them and leaving over the left one (experiments/lines_on_photos.py's
    # legal pads: their 0 and 7 beside the margin). Over the line the stroke is no darker
    # than it by 0.3 of the pen in the darkest channel, and the 7 was cut in two there;
    # in red, which the margin lets through and the blue ink does not, it is ink
    from scipy.ndimage import label

    seven = [_stroke([(60, 120), (103, 120), (103, 140), (70, 330)]), _ellipse(300, 220, 50, 100)]
    truth = _ink(LARGE, seven)
    paper = np.ones((*LARGE, 3), np.float32) * np.array([0.99, 0.93, 0.59], np.float32)
    rules_ = _grid_cover(LARGE, 24.0, 0.8, columns=False)[..., None]  # pale blue rules
    paper = paper * (1.0 - rules_ * (1.0 - np.array([0.55, 0.7, 0.9], np.float32)))
    cols = np.arange(LARGE[1], dtype=np.float32)
    for x in (100.0, 106.0):  # the margin's two lines
        cover = np.clip(1.0 - np.abs(cols - x), 0.0, 1.0)[None, :, None]
        paper = paper * (1.0 - cover * (1.0 - np.array([0.86, 0.31, 0.31], np.float32)))
    found = paper_ink(_on_paper(truth, paper, colour=(0.3, 0.35, 0.75)))  # blue ink
    assert found.removed["rule_px"] > 1000, "the margin and the rules are lines"
    seven_px = _ink(LARGE, seven[:1]) > 0.5
    assert (found.ink[seven_px] > 0.2).mean() > 0.9, "the 7 over the margin cut with it"
    labels, _ = label(found.mask, structure=np.ones((3, 3), bool))
    assert len(np.unique(labels[seven_px & found.mask])) == 1, "the 7 in pieces"
    far = _ink(LARGE, seven, width=14.0) < 0.01
    assert (found.ink[far] > 0.2).mean() < 0.002, "the margin left as ink"


@pytest.mark.parametrize("strength", [0.8, 0.85])
def test_a_glare_s_washed_out_strokes_are_given_back_their_contrast(strength, monkeypatch):
    """A glare across the page's middle, the paper and ink brought towards white by 0.8
    (the ink keeps a fifth of its contrast there): the paper's level rises and its grain
    flattens as a glare's would, so the darkness there is multiplied back
    (``glare_gain``): all nine characters, nothing more. Without it, the washed-out
    strokes fall under the page's ink level and are lost."""
    from img2dmp.data import paper

    img, centres = grainy_page()
    washed = glare(img, strength)
    found, boxes, ok = _found_at(washed, centres)
    assert ok, (len(boxes), boxes)
    assert found.glare_gain > 2.0 and paper_ink(img).glare_gain == 1.0  # said, for the page
    monkeypatch.setattr(paper, "glare_gain", lambda *a: None)
    found, boxes, ok = _found_at(washed, centres)
    assert not ok  # the test can fail: without the gain the glare loses characters


def test_light_that_is_only_brighter_or_paper_without_grain_is_noglare():
    """A page lit brighter on one side (a lamp's gradient: the grain keeps its share of
    the light) and a page whose bright spot has no grain left to confirm a glare (a
    denoiser's or a JPEG's flat paper) get no gain: it would raise whatever is faint there."""
    from scipy.ndimage import gaussian_filter

    from img2dmp.data.paper import _background, _planes, glare_gain, rough_pen_width

    h, w = 450, 780
    lamp = np.linspace(0.75, 1.25, w, dtype=np.float32)[None, :].repeat(h, 0)
    img, _ = grainy_page(light=lamp)
    flat, _ = grainy_page()
    spot = (glare(np.zeros_like(flat), 1.0) > 0.3).all(axis=2)[..., None]
    flat = glare(np.where(spot, gaussian_filter(flat, (4, 4, 0)), flat), 0.8)  # grain gone
    for page in (img, flat):
        a = _planes(page)
        bg, cell, _ = _background(a, rough_pen_width(a), False)
        assert cell > 0
        assert glare_gain(a, bg, cell) is None


def test_the_shared_photos_have_no_glare_until_one_is_put_on_them():
    """The two shared phone photos as they are: no glare found (the white one's top is
    lit brighter, which raises its paper's level as a glare would, but not its grain).
    Under a 0.8 glare, large or small: found, and the gain given. Skips, saying so,
    without ``../shared/data/photos``."""
    from pathlib import Path

    from PIL import Image

    photos = Path(__file__).resolve().parents[2] / "shared" / "data" / "photos"
    if not (photos / "photos.json").is_file():
        pytest.skip(f"the shared phone photos are not at {photos} (../shared/data/photos)")
    for name in ("page_white_black_ink.png", "page_yellow_blue_ink.png"):
        img = np.asarray(Image.open(photos / name).convert("RGB"), np.float32) / 255.0
        assert paper_ink(img).glare_gain == 1.0, name
        for at, radius in (((0.6, 0.45), 0.4), ((0.3, 0.45), 0.25)):
            assert paper_ink(glare(img, 0.8, at, radius)).glare_gain > 1.5, (name, at)
