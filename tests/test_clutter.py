"""Generated paper, ink on it, the camera's finish and whole pages (img2dmp.data.clutter).

The paper's pattern is found again in its pixels (periods, isolated dots, flat plain
paper), ink is checked against the compositing formula, and a page's truth (boxes, ink,
control image, reading order) against characters rendered again on their own.
"""

from __future__ import annotations

import dataclasses
import re
import tarfile
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from img2dmp.data.clutter import (
    KINDS,
    LINE_COLOURS,
    PEN_COLOURS,
    TINTS,
    CharacterSource,
    PageOptions,
    PaperOptions,
    generate_page,
    page_sources_from_recorded,
    page_sources_from_strokes,
    page_sources_from_synthetic,
    pattern_phase,
    photo_finish,
    put_ink,
    random_paper,
    random_pen_colour,
)
from img2dmp.data.recorded import parse_recorded
from img2dmp.data.render import render_paths
from img2dmp.data.strokes import StrokeDigit

RECORDED = (
    Path(__file__).resolve().parents[1]
    / ".."
    / "shared"
    / "data"
    / "ijs-mnist-trajectories"
    / "trajectories.tar.gz"
)

# Only the printed pattern: no turn, bend, lighting, shadow, bleed-through or edge.
QUIET = PaperOptions(
    angle_deg=(0.0, 0.0),
    wave_rel=(0.0, 0.0),
    exposure=(1.0, 1.0),
    colour_cast=0.0,
    tint_jitter=0.0,
    gradient=(0.0, 0.0),
    vignette=(0.0, 0.0),
    shadow_probability=0.0,
    bleed_probability=0.0,
    edge_probability=0.0,
    margin_probability=0.0,
    line_strength=(0.8, 0.9),
)


def _darkness(rgb: np.ndarray) -> np.ndarray:
    # How much light the pattern takes away, relative to the paper's tint.
    return 1.0 - rgb.mean(-1) / rgb.mean(-1).max()


def _line_centres(profile: np.ndarray) -> np.ndarray:
    """Centroids of the runs of a 1-D profile (the whole footprint of each line)."""
    runs, n = ndimage.label(profile > 1e-3 * profile.max())
    return np.array(ndimage.center_of_mass(profile, runs, range(1, n + 1)))[:, 0]


def _periods(centres: np.ndarray, size: int, spacing: float) -> np.ndarray:
    # Whole periods away from the borders (a rule cut by the border has a biased centroid).
    inner = centres[(centres > spacing / 2) & (centres < size - 1 - spacing / 2)]
    return np.diff(inner)


SPACING = 17.3  # not a whole number of pixels


def test_ruled_paper_repeats_down_the_rows_at_the_drawn_spacing():
    paper = random_paper(
        np.random.default_rng(0),
        (300, 220),
        "ruled",
        options=dataclasses.replace(QUIET, spacing_px=(SPACING, SPACING)),
    )
    assert paper.kind == "ruled" and paper.meta["spacing_px"] == pytest.approx(SPACING)
    dark = _darkness(paper.rgb)
    rows, cols = dark.mean(1), dark.mean(0)
    assert cols.std() < 1e-4  # nothing runs down the columns
    periods = _periods(_line_centres(rows), 300, SPACING)
    assert len(periods) >= 12
    # Each centroid of a line sampled on whole rows is off by a fraction of a pixel.
    np.testing.assert_allclose(periods, SPACING, atol=0.3)
    assert periods.mean() == pytest.approx(SPACING, abs=0.03)
    # The rules sit where the paper says they do.
    centres = _line_centres(rows)
    phase = pattern_phase(paper.meta, (300, 220), np.full(centres.shape, 110.0), centres)
    assert np.abs(phase[1:-1]).max() < 0.3


def test_squared_paper_repeats_along_both_axes():
    options = dataclasses.replace(QUIET, spacing_px=(SPACING, SPACING))
    paper = random_paper(np.random.default_rng(1), (260, 300), "squared", options=options)
    dark = _darkness(paper.rgb)
    for profile, size in ((dark.mean(1), 260), (dark.mean(0), 300)):
        periods = _periods(_line_centres(profile - profile.min()), size, SPACING)
        assert len(periods) >= 10
        np.testing.assert_allclose(periods, SPACING, atol=0.3)
        assert periods.mean() == pytest.approx(SPACING, abs=0.03)


def test_dotted_paper_has_isolated_dots_on_a_lattice():
    options = dataclasses.replace(QUIET, spacing_px=(SPACING, SPACING))
    paper = random_paper(np.random.default_rng(2), (240, 280), "dotted", options=options)
    radius = paper.meta["dot_radius_px"]
    dark = _darkness(paper.rgb)
    blobs, n = ndimage.label(dark > 0.5 * dark.max())
    sizes = ndimage.sum_labels(np.ones_like(dark), blobs, range(1, n + 1))
    # One dot per lattice point (those cut by the border may be missing), each small.
    lattice = (240 / SPACING) * (280 / SPACING)
    assert lattice - (240 + 280) / SPACING - 4 <= n <= lattice + (240 + 280) / SPACING + 4
    assert sizes.max() <= (2 * radius + 3) ** 2
    centres = np.array(ndimage.center_of_mass(dark, blobs, range(1, n + 1)))  # [n, 2]
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    inner = np.all((centres > SPACING) & (centres < np.array([240, 280]) - SPACING), axis=1)
    np.testing.assert_allclose(d.min(1)[inner], SPACING, atol=0.3)  # neighbours, no lines


def test_plain_paper_has_no_pattern():
    paper = random_paper(np.random.default_rng(3), (200, 260), "plain", options=QUIET)
    dark = _darkness(paper.rgb)
    assert dark.max() < 1e-5
    assert paper.meta["line_width_px"] is None and paper.meta["dot_radius_px"] is None


def test_bleed_through_is_faint_rows_of_marks_on_the_paper_only():
    options = dataclasses.replace(
        QUIET, bleed_probability=1.0, bleed_strength=(0.1, 0.1), edge_probability=1.0
    )
    paper = random_paper(np.random.default_rng(14), (300, 400), "plain", options=options)
    assert paper.meta["bleed"]
    mask = paper.meta["sheet_mask"]
    sheet = ndimage.binary_erosion(mask, iterations=3)
    lum = paper.rgb.mean(-1)
    dark = 1.0 - lum / np.median(lum[sheet])
    assert 0.03 < dark[sheet].max() <= 0.1 + 1e-3  # faint, never darker than its strength
    # Rows of text (the sheet's pattern is turned by at most 2 degrees): runs of rows
    # with marks, separated by blank ones.
    on_sheet = sheet[:, 60:-60]
    rows = (dark[:, 60:-60] * on_sheet).sum(1) / np.maximum(on_sheet.sum(1), 1)
    runs, n = ndimage.label(rows > 0.5 * rows.max())
    assert n >= 3
    # The table beyond the edge shows no text: it is the same with the bleed-through off.
    plain = random_paper(
        np.random.default_rng(14),
        (300, 400),
        "plain",
        options=dataclasses.replace(options, bleed_strength=(0.0, 0.0)),
    )
    table = ~ndimage.binary_dilation(mask, iterations=2)
    np.testing.assert_allclose(paper.rgb[table], plain.rgb[table], atol=1e-6)


@pytest.mark.parametrize("kind", ["ruled", "squared", "dotted", "plain"])
def test_turned_and_bent_pattern_lies_where_the_meta_says(kind):
    # With the default turn and waviness, pixels on a rule (phase ~ 0) are darker than
    # pixels between rules; on plain paper (and for the columns of dotted paper) the
    # phase means nothing and nothing differs.
    options = dataclasses.replace(QUIET, angle_deg=(-3.0, 3.0), wave_rel=(0.002, 0.004))
    rng = np.random.default_rng(4)
    for _ in range(3):
        paper = random_paper(rng, (240, 320), kind, options=options)
        assert -3 <= paper.meta["angle_deg"] <= 3
        y, x = np.mgrid[0:240, 0:320]
        phase = np.abs(pattern_phase(paper.meta, (240, 320), x, y))
        dark = _darkness(paper.rgb)
        on, off = dark[phase < 0.3], dark[phase > paper.meta["spacing_px"] / 3]
        if kind == "plain":
            assert on.mean() == pytest.approx(off.mean(), abs=1e-5)
        elif kind == "dotted":  # dots sit on the rows of phase 0, nothing between them
            assert on.max() > 0.15 and off.max() < 0.01
        else:  # rules (and the grid's columns, which cross both alike)
            assert on.mean() > off.mean() + 0.05


def test_colours_tints_and_ranges():
    rng = np.random.default_rng(5)
    for _ in range(12):
        paper = random_paper(rng, (64, 80))
        rgb = paper.rgb
        assert rgb.dtype == np.float32 and rgb.shape == (64, 80, 3)
        assert np.isfinite(rgb).all() and rgb.min() >= 0 and rgb.max() <= 1
        m = paper.meta
        assert paper.kind in KINDS and m["tint"] in TINTS and m["line_colour"] in LINE_COLOURS
        # The tint is the named one, moved by at most its jitter and the light's cast.
        named = np.array(TINTS[m["tint"]])
        assert np.all(np.abs(np.array(m["tint_rgb"]) / named - 1) <= 0.02 / named + 0.041)
        assert m["sheet_mask"].shape == (64, 80) and m["sheet_mask"].dtype == bool
    colours = np.array([c for c, _ in PEN_COLOURS.values()])
    for _ in range(30):
        pen = random_pen_colour(rng)
        assert pen.shape == (3,) and pen.dtype == np.float32
        assert np.abs(colours - pen).max(1).min() <= 0.04 + 1e-6


@pytest.mark.parametrize("seed", range(4))
def test_sheet_mask_follows_the_edge_and_the_table_is_darker(seed):
    options = PaperOptions(
        edge_probability=1.0,
        edge_two_sides_probability=0.0,
        shadow_probability=0.0,
        vignette=(0.0, 0.0),
    )
    paper = random_paper(np.random.default_rng(seed), (200, 240), options=options)
    (side,) = paper.meta["edge"]
    mask = paper.meta["sheet_mask"]
    # Turn the picture so that the table is on the left: then every row is table, then
    # paper, the table at most edge_depth_rel of the width deep.
    turn = {"left": 0, "top": 1, "right": 2, "bottom": 3}[side]
    m = np.rot90(mask, turn)
    lum = np.rot90(paper.rgb.mean(-1), turn)
    first_paper = m.argmax(1)
    assert np.all(m[np.arange(m.shape[0]), first_paper])
    assert all(m[i, j:].all() and not m[i, :j].any() for i, j in enumerate(first_paper))
    assert first_paper.max() <= 0.1 * m.shape[1] + 1 and first_paper.min() >= 1
    table = ~ndimage.binary_dilation(m, iterations=2)
    sheet = ndimage.binary_erosion(m, iterations=2)
    assert lum[table].mean() < 0.8 * lum[sheet].mean()


def test_put_ink_darkens_exactly_where_the_ink_is():
    rng = np.random.default_rng(6)
    paper = random_paper(rng, (50, 60)).rgb
    before = paper.copy()
    ink = np.zeros((50, 60), np.float32)
    ink[10:20, 10:30] = 1.0
    ink[30:40, 5:50] = rng.random((10, 45), dtype=np.float32)
    colour = (0.1, 0.2, 0.6)
    out = put_ink(paper, ink, colour, opacity=0.9)
    assert out.dtype == np.float32 and np.array_equal(paper, before)  # input kept
    blank = ink == 0
    assert np.array_equal(out[blank], paper[blank])
    expected = paper * (1 - 0.9 * ink[..., None] * (1 - np.array(colour, np.float32)))
    np.testing.assert_allclose(out, expected, rtol=1e-6, atol=1e-7)
    assert np.all(out[~blank] < paper[~blank])
    np.testing.assert_allclose(put_ink(paper, ink, colour, opacity=0.0), paper)


def test_photo_finish_keeps_the_picture_and_adds_the_asked_noise():
    rng = np.random.default_rng(7)
    scene = put_ink(random_paper(rng, (120, 160)).rgb, np.zeros((120, 160), np.float32), (0, 0, 0))
    exact = np.round(scene * 255)
    clean = photo_finish(rng, scene, jpeg_quality=95, blur_px=0.0, noise=0.0, sharpen=0.0)
    assert clean.dtype == np.uint8 and clean.shape == (120, 160, 3)
    assert np.abs(clean - exact).mean() < 1.5
    flat = np.full((200, 200, 3), 0.5, np.float32)
    noisy = photo_finish(rng, flat, jpeg_quality=100, blur_px=0.0, noise=0.04, sharpen=0.0)
    inner = noisy[2:-2, 2:-2].astype(np.float64).mean(-1)  # luminance noise
    assert inner.std() == pytest.approx(0.04 * 255, rel=0.15)
    blurred = photo_finish(rng, scene, jpeg_quality=95, blur_px=1.5, noise=0.0, sharpen=0.0)
    assert (
        np.abs(np.diff(blurred.astype(float), axis=0)).mean()
        < np.abs(np.diff(clean.astype(float), axis=0)).mean()
    )


# Small writing keeps the pages small and the tests fast.
SMALL = PageOptions(char_height_px=(30.0, 50.0))


def _synthetic_page(seed: int, n: int = 14, **kwargs):
    rng = np.random.default_rng(seed)
    kwargs.setdefault("options", SMALL)
    return generate_page(rng, page_sources_from_synthetic(rng, n), **kwargs)


@pytest.fixture(scope="module")
def page():
    return _synthetic_page(8, kind="ruled", size_hw=(420, 640))


def test_boxes_hold_the_paths_and_their_ink(page):
    h, w = page.ink.shape
    union = np.zeros((h, w), np.float32)
    for box, path in zip(page.boxes, page.paths, strict=True):
        x0, y0, x1, y1 = (int(v) for v in box)
        assert 0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h
        down = path[path[:, 2] > 0.5, :2]
        # Pixel j spans [j - 0.5, j + 0.5): the box's edges, give or take one pixel.
        assert np.all(down[:, 0] >= x0 - 1.5) and np.all(down[:, 0] < x1 + 0.5)
        assert np.all(down[:, 1] >= y0 - 1.5) and np.all(down[:, 1] < y1 + 0.5)
        # The character rendered again on its own, on a crop of our own choosing.
        cx0, cy0 = (int(v) - 25 for v in np.floor(down.min(0)))
        cx1, cy1 = (int(v) + 25 for v in np.ceil(down.max(0)))
        local = path - (cx0, cy0, 0)
        own = render_paths(local.astype(np.float32), (cy1 - cy0, cx1 - cx0), page.pen_width_px)
        own = own.numpy()
        rows = np.flatnonzero((own > 0.5).any(1)) + cy0
        cols = np.flatnonzero((own > 0.5).any(0)) + cx0
        assert (cols[0], rows[0], cols[-1] + 1, rows[-1] + 1) == (x0, y0, x1, y1)
        assert cx0 >= 0 and cy0 >= 0 and cx1 <= w and cy1 <= h  # inside the margins
        np.maximum(union[cy0:cy1, cx0:cx1], own, out=union[cy0:cy1, cx0:cx1])
    # No other ink on the page. (The page renders its characters in batches, whose
    # longest segment sets how finely all of them are sampled; that moves the ink at the
    # ends of strokes by a few hundredths, as test_render_affine measures.)
    np.testing.assert_allclose(page.ink, union, atol=0.03)
    assert np.mean(np.abs(page.ink - union)) < 1e-4
    inside = np.zeros((h, w), bool)
    for x0, y0, x1, y1 in page.boxes:
        inside[y0:y1, x0:x1] = True
    assert not np.any((page.ink > 0.5) & ~inside)


def test_characters_have_the_page_height(page):
    h = page.meta["char_height_px"]
    heights = page.boxes[:, 3] - page.boxes[:, 1]
    assert np.median(heights) == pytest.approx(h + page.pen_width_px, rel=0.15)


def test_plain_image_is_the_same_ink_on_white(page):
    colour = page.pen_colour.astype(np.float64)
    opacity = page.meta["opacity"]
    expected = 255 * (1 - opacity * page.ink[..., None] * (1 - colour))
    assert page.plain_image.dtype == np.uint8 and page.plain_image.shape == page.image.shape
    assert np.abs(page.plain_image - expected).max() <= 1.0
    assert np.all(page.plain_image[page.ink == 0] == 255)
    # On the photo the ink darkens the paper around it, character by character.
    lum = page.image.astype(np.float64).mean(-1)
    for x0, y0, x1, y1 in page.boxes:
        around = np.s_[y0 - 10 : y1 + 10, x0 - 10 : x1 + 10]
        ink, seen = page.ink[around], lum[around]
        assert seen[ink > 0.9].mean() < seen[ink == 0].mean() - 20


@pytest.mark.parametrize("seed", range(3))
def test_reading_order_and_lines_agree_with_positions(seed):
    options = dataclasses.replace(SMALL, n_lines=(2, 4), tight_probability=0.5)
    page = _synthetic_page(seed, n=18, options=options)
    lines, boxes = page.lines, page.boxes.astype(float)
    assert np.array_equal(page.order, np.arange(18))
    assert lines[0] == 0 and np.all(np.diff(lines) >= 0) and np.all(np.diff(lines) <= 1)
    assert np.all(np.diff(page.words) >= 0)
    centre = 0.5 * (boxes[:, :2] + boxes[:, 2:])  # [N, 2] (x, y)
    for k in range(lines.max() + 1):
        assert np.all(np.diff(centre[lines == k, 0]) > 0)  # left to right
    for k in range(lines.max()):
        above, below = np.flatnonzero(lines == k), np.flatnonzero(lines == k + 1)
        for a in above:
            for b in below:
                if boxes[a, 0] < boxes[b, 2] and boxes[b, 0] < boxes[a, 2]:  # x overlap
                    assert centre[b, 1] > centre[a, 1]


def test_gaps_are_between_the_inked_edges():
    # Synthetic digits are one stroke each, so each is one blob of ink unless it touches
    # a neighbour: pages with positive gaps (even with the widest pen) never touch, pages
    # with negative ones do.
    apart = dataclasses.replace(SMALL, tight_probability=0.0, pen_width_max_rel=0.2)
    touching = dataclasses.replace(SMALL, tight_probability=1.0, tight_gap_rel=(-0.25, -0.2))
    for seed in range(2):
        for options, together in ((apart, False), (touching, True)):
            page = _synthetic_page(seed, n=10, options=options, pen_width_px=6.0)
            _, blobs = ndimage.label(page.ink > 0.5)
            assert (blobs < 10) == together


def test_writing_on_the_rules_sits_on_them():
    options = dataclasses.replace(SMALL, on_rules_probability=1.0, n_lines=(2, 3))
    for seed in range(2):
        page = _synthetic_page(seed, n=12, kind="ruled", options=options)
        assert page.meta["on_rules"]
        h = page.meta["char_height_px"]
        for k in range(page.lines.max() + 1):
            paths = [p[p[:, 2] > 0] for p, i in zip(page.paths, page.lines, strict=True) if i == k]
            x = np.array([p[:, 0].mean() for p in paths])
            bottom = np.array([p[:, 1].max() for p in paths])  # the baseline, jittered
            phase = pattern_phase(page.meta["paper"], page.ink.shape, x, bottom)
            assert -0.15 * h < np.median(phase) < 0.05 * h  # on the rule or just above it


def test_the_same_seed_gives_the_same_page():
    a = _synthetic_page(9, n=6)
    b = _synthetic_page(9, n=6)
    c = _synthetic_page(10, n=6)
    assert np.array_equal(a.image, b.image) and np.array_equal(a.boxes, b.boxes)
    assert all(np.array_equal(p, q) for p, q in zip(a.paths, b.paths, strict=True))
    assert a.image.shape != c.image.shape or not np.array_equal(a.image, c.image)


def test_pen_up_travel_leaves_no_ink():
    # Two strokes: a bar and a post far to its right; the travel between is not written.
    xy = np.array([[0.0, 0.0], [0.3, 0.0], [0.55, 0.0], [0.8, 0.0], [0.8, 1.0]])
    pen = np.array([1, 1, 0, 1, 1])
    stroke = StrokeDigit(0, 4, [xy[:2], xy[3:]], "fake")
    (from_strokes,) = page_sources_from_strokes([stroke])
    np.testing.assert_array_equal(from_strokes.pen, pen)
    page = generate_page(np.random.default_rng(11), [from_strokes], pen_width_px=3.0)
    path = page.paths[0]
    gap = np.round(path[2, :2]).astype(int)  # the pen-up point, halfway along the travel
    assert page.ink[gap[1], gap[0]] < 1e-3
    for i in (0, 1, 3, 4):
        x, y = np.round(path[i, :2]).astype(int)
        assert page.ink[y, x] > 0.3


def test_recorded_paths_make_pages():
    if not RECORDED.exists():
        pytest.skip(f"recorded MNIST paths not found at {RECORDED} (../shared/data)")
    recorded = []
    with tarfile.open(RECORDED) as archive:
        for member in archive:
            if member.isfile() and member.name.endswith(".json"):
                recorded.append(parse_recorded(archive.extractfile(member).read(), member.name))
            if len(recorded) == 12:
                break
    sources = page_sources_from_recorded(recorded)
    assert [s.label for s in sources] == [str(r.label) for r in recorded]
    page = generate_page(np.random.default_rng(12), sources, kind="squared", options=SMALL)
    assert page.labels == [str(r.label) for r in recorded]
    for path in page.paths:
        x, y = np.round(path[:, :2]).astype(int).T
        assert np.mean(page.ink[y, x] > 0.5) > 0.95  # the path lies on its ink


def test_a_big_photo_stays_in_bounded_memory():
    rng = np.random.default_rng(13)
    options = PaperOptions(edge_probability=1.0, bleed_probability=1.0, shadow_probability=1.0)
    tracemalloc.start()
    paper = random_paper(rng, (1200, 1600), "squared", options=options)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    output = paper.rgb.nbytes + paper.meta["sheet_mask"].nbytes
    assert peak < output + 0.35 * paper.rgb.nbytes  # a few bands of temporaries


def _bad(call, **kwargs):
    return lambda: call(**kwargs)


RNG = np.random.default_rng(0)
INK = np.zeros((10, 10), np.float32)
PAPER = np.ones((10, 10, 3), np.float32)
DOT = CharacterSource(xy=np.zeros((1, 2)), label="x")


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (_bad(random_paper, rng=RNG, size_hw=(0, 10)), "size_hw"),
        (_bad(random_paper, rng=RNG, size_hw=(6001, 4001)), "size_hw"),
        (_bad(random_paper, rng=RNG, size_hw=(9000, 100)), "size_hw"),
        (_bad(random_paper, rng=RNG, size_hw=(10.5, 10)), "size_hw"),
        (_bad(random_paper, rng=0, size_hw=(10, 10)), "rng"),
        (_bad(random_paper, rng=RNG, size_hw=(10, 10), kind="lined"), "kind"),
        (_bad(random_paper, rng=RNG, size_hw=(10, 10), options={}), "options"),
        (_bad(PaperOptions, spacing_rel=(0.3, 0.1)), "spacing_rel"),
        (_bad(PaperOptions, kinds=("wavy",)), "kinds"),
        (_bad(PaperOptions, shadow_probability=1.5), "shadow_probability"),
        (_bad(PaperOptions, angle_deg=(-90.0, 0.0)), "angle_deg"),
        (_bad(put_ink, paper_rgb=PAPER, ink=INK, colour=(2, 0, 0)), "colour"),
        (_bad(put_ink, paper_rgb=PAPER, ink=INK, colour=(0, 0, 0), opacity=1.5), "opacity"),
        (_bad(put_ink, paper_rgb=PAPER, ink=INK[:5], colour=(0, 0, 0)), "ink"),
        (_bad(put_ink, paper_rgb=PAPER[..., 0], ink=INK, colour=(0, 0, 0)), "paper_rgb"),
        (_bad(put_ink, paper_rgb=PAPER, ink=INK + 2, colour=(0, 0, 0)), "ink"),
        (_bad(photo_finish, rng=RNG, rgb=PAPER, jpeg_quality=0), "jpeg_quality"),
        (_bad(photo_finish, rng=RNG, rgb=PAPER, jpeg_quality=80.0), "jpeg_quality"),
        (_bad(photo_finish, rng=RNG, rgb=PAPER, blur_px=-1.0), "blur_px"),
        (_bad(photo_finish, rng=RNG, rgb=PAPER, noise=float("nan")), "noise"),
        (_bad(photo_finish, rng=RNG, rgb=PAPER[..., :2]), "rgb"),
        (_bad(generate_page, rng=RNG, characters=[]), "characters"),
        (_bad(generate_page, rng=RNG, characters=[DOT, "7"]), "characters[1]"),
        (_bad(generate_page, rng=RNG, characters=[DOT], kind="lined"), "kind"),
        (_bad(generate_page, rng=RNG, characters=[DOT], size_hw=(10, 10)), "size_hw"),
        (_bad(generate_page, rng=RNG, characters=[DOT], pen_width_px=0.5), "pen_width_px"),
        (_bad(generate_page, rng=RNG, characters=[DOT], pen_colour=(1, 1)), "pen_colour"),
        (_bad(generate_page, rng=RNG, characters=[DOT] * 5001), "characters"),
        (_bad(PageOptions, n_lines=(0, 2)), "n_lines"),
        (_bad(PageOptions, char_height_px=(120.0, 30.0)), "char_height_px"),
        (_bad(PageOptions, max_per_line=0), "max_per_line"),
        (_bad(CharacterSource, xy=np.full((3, 2), np.nan), label="1"), "xy"),
        (_bad(CharacterSource, xy=np.zeros((3, 2)), label="1", pen=np.zeros(3)), "pen"),
        (_bad(CharacterSource, xy=np.zeros((3, 2)), label=1), "label"),
        (_bad(page_sources_from_synthetic, rng=RNG, n=0), "n"),
        (_bad(page_sources_from_synthetic, rng=RNG, n=3, digits=[12]), "digits"),
        (_bad(page_sources_from_recorded, recorded_paths=[DOT]), "recorded_paths[0]"),
    ],
)
def test_bad_arguments_are_refused_by_name(call, name):
    with pytest.raises(ValueError, match="^" + re.escape(name) + " "):
        call()
