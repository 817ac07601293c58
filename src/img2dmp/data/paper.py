"""Separating handwriting from the paper it is on: the ink of a photo or scan.

A camera sees more than ink: the paper's tint, a lighting gradient and shadows, ruled,
squared or dotted lines, printed text showing through from the back, specks, and the
sheet's edge with the table beyond it. :func:`paper_ink` keeps the pen's strokes and
drops the rest, in named steps (each kept for a picture with ``keep_steps``;
:func:`img2dmp.data.plotting.paper_steps_figure` draws them):

0. **desk**: a sheet lying on a desk (darker or lighter than the paper) is found by its
   edges (:func:`img2dmp.data.sheet.find_sheet`) and the desk painted over with the
   paper's colour; nothing off the sheet is ink, and long lines beside it (the edge's
   own shadow or band) are dropped with the marks along the image's border (step 7);
1. **polarity**: dark ink on light paper, or light on dark (then inverted): which way
   the grey levels' tail reaches from their local median (ink is the minority), else
   from the border as :mod:`img2dmp.data.images` has always read it;
2. **background**: the paper's own colour at every pixel, per channel: for a small
   image (a character's crop, under ``SURFACE_MAX_SIDE``) a quadratic surface fitted to
   the pixels that are not darker than it, times the soft shadows its even cells show
   (a crop across a shadow's hard edge, which a smooth surface cannot follow, is read
   with cells too: :func:`crop_shade_step`, ``CROP_STEP_GAIN``);
   else the colour of the pixels at a high percentile of brightness in cells of about
   1/24 of the shorter side and at least ``CELL_PEN_WIDTHS`` pen widths (ink covers a
   minority of every cell; brightness, not each channel's own percentile, so that lines
   lighter than the paper in one channel do not raise it there), closed over 3 x 3 cells
   (so a cell full of ink takes its neighbours' paper) and interpolated bilinearly:
   lighting and tint divide out;
3. **darkness**: how much light the ink absorbs relative to that paper, the largest of
   the channels (blue ink on yellow paper is dark in red and green, black ink in all),
   each channel's against the paper's brightest (the blue that yellow paper hardly
   reflects carries the same noise as the others, not several times it); under a glare
   (a spot where paper and ink are brought towards white, the ink keeping a share of
   its contrast) the darkness is multiplied back, where the paper's grain is flattened
   as a glare flattens it (:func:`glare_gain`, ``GLARE_*``);
4. **sheet**: cells much darker than the paper and connected to the image's border are
   the table beyond the sheet's edge; nothing there is ink;
5. **rules**: thin straight lines along the page's two directions (the dominant angle of
   the dark pixels, within +-``MAX_RULE_ANGLE_DEG`` of the rows and columns, or of the
   sides of a sheet found on a desk) that run most of the sheet's width
   (``RULE_SHARE``; ``PERIODIC_RULE_SHARE`` when at least three run in parallel at an
   even spacing, as ruled and squared paper's do) are removed, except where a stroke
   crosses them (ink just above and just below a rule pixel keeps it), on rules as
   dark as the pen runs along them a short way between two places where it touches
   them, or is darker than the lines there (their level followed along each line, so
   that a wavy line is not darker than itself), in its darkest channel or in one alone
   (a colour the lines let through: a blue pen over a red margin as dark as it);
6. **strokes**: hysteresis: a connected set of dark pixels is ink when ``STRONG_SHARE``
   of its pixels are of at least ``strong`` darkness (a share of the page's ink level),
   so faint marks (text from the back, dotted lines, shadows' edges) go unless a stroke
   passes through; a component too faint as a whole is tried again in pieces, at a
   level half way to ``strong``, and its pieces of ``RESCUE_AREA_PEN2`` pen widths
   squared are ink (strokes that a remnant of curved rules joined into one net);
7. **shapes**: components smaller than a few pen widths squared (specks; not a pen's
   dot: about a pen width across, as dark as the pen, near a kept stroke and on no
   lattice, ``DOT_*``), small marks at an even spacing (the dots of dotted paper), marks
   along the image's border (the sheet's edge) and components much thicker than the pen
   (``THICK_FACTOR``: a shadow's band) are dropped;
8. **ink**: the darkness scaled so that the typical ink is 1, on the kept strokes and a
   pixel around them (anti-aliased edges kept), 0 elsewhere.

An image smaller than ``LOCAL_BACKGROUND_MIN_SIDE`` on its shorter side (an MNIST digit,
a model input) has one background level, the border's median, as before: there is no
lighting to flatten in 28 pixels. NumPy and SciPy only; work is linear in the pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .sheet import find_sheet

#: Below this shorter side, one background level for the whole image (the border's).
LOCAL_BACKGROUND_MIN_SIDE = 64
#: Below this shorter side (a character's crop), the paper is a smooth surface times a
#: soft shadow,
SURFACE_MAX_SIDE = 400
#: ... the shadow measured in cells whose brightness spreads less than this (paper).
EVEN_CELL = 0.08
#: A crop whose even cells, one or two apart, differ by ``SHADE_STEP`` of the paper's
#: level lies across a shadow's hard edge, which the smooth surface cannot follow: it is
#: read with cells too, and that reading is kept where it holds more than
#: ``CROP_STEP_GAIN`` times the smooth one's ink and the smooth one dropped at least
#: ``CROP_STEP_FAINT`` more marks as faint (the edge's band raised the ink's level, and
#: the strokes in the shade fell below it); or where the smooth one found no ink and
#: the cells keep a character's worth: ``CROP_STEP_INK_PEN2`` pen widths squared.
CROP_STEP_GAIN = 2.0
CROP_STEP_FAINT = 5
CROP_STEP_INK_PEN2 = 20
#: A glare (a lamp's or a window's reflection) brings the paper and the ink towards
#: white by a share ``s`` of the way: the paper's level rises from ``b0`` (the median of
#: the paper's cells) to ``b = b0 + s (1 - b0)`` and the ink keeps ``1 - s`` of its
#: contrast. Where a cell is brighter than ``b0``, its darkness is multiplied back by up
#: to ``b (1 - b0) / (b0 (1 - b))``, at most ``GLARE_MAX_GAIN``, when the paper's own
#: grain confirms it: a glare flattens the grain by ``1 - s`` as well, while light that
#: is merely brighter (a lamp's gradient, a window's side of the page) leaves it. The
#: cells whose share is at least ``GLARE_STRONG_SHARE`` vote, at least
#: ``GLARE_MIN_CELLS`` of them and ``GLARE_MIN_SHARE`` of the paper's cells: each the
#: share of the expected flattening its grain shows (against the paper's median cell's,
#: a brighter cell's sensor noise allowed for); their median is the share of the gain
#: applied; none when it is under ``GLARE_CONFIRMED`` (a lamp's brighter side, the
#: lit part of a page in shade: 0.0-0.3 on the shared photos and generated pages) or
#: their upper quartile exceeds ``GLARE_SPREAD`` (grain gone far beyond any glare's
#: doing: a JPEG's or a denoiser's flat paper). A crop (no cells) gets none.
GLARE_MAX_GAIN = 5.0
GLARE_STRONG_SHARE = 0.5
GLARE_MIN_CELLS = 5
GLARE_MIN_SHARE = 0.01
GLARE_SPREAD = 2.0
GLARE_CONFIRMED = 0.3
#: ... the grain of a cell measured no finer than this (8-bit levels' steps).
GLARE_GRAIN_FLOOR = 0.002
#: Cells of the polarity's local median: this many along the shorter side.
POLARITY_CELLS = 16
#: ... of which those whose median grey is within this of the typical cell's.
POLARITY_EVEN = 0.25
#: ... the pixels beyond this many times the paper's spread counted either way ...
POLARITY_SPREADS = 4.0
#: ... nor the cells whose median differs by this much from a neighbour's (a shadow's
#: hard edge; a lighting gradient changes by a few hundredths from cell to cell).
POLARITY_STEP = 0.1
#: ... when they are at least this share of the image.
POLARITY_MIN_SHARE = 0.0005
#: An image whose median grey is at least this light (or this dark, from black) is dark
#: ink on light paper (light ink on dark) whatever its cells say: a clipped white paper
#: has no spread, and in the cells of thick, tight writing its own pixels lie above the
#: cells' median as light ink's would.
POLARITY_PLAIN = 0.85
#: Cells of the background estimate: about this many along the shorter side.
BACKGROUND_CELLS = 24
#: ... and at least this many pen widths (:func:`rough_pen_width`) on a side.
CELL_PEN_WIDTHS = 2.5
#: The paper's colour in a cell: the mean colour of its pixels whose brightness (luma)
#: ranks within ``BACKGROUND_WINDOW`` percentiles of this one. Not each channel's own
#: percentile: lines lighter than the paper in one channel (blue rules on yellow paper in
#: blue, or a JPEG's chroma smeared beside them) raised that channel's level until the
#: whole sheet read as ink (``experiments/lines_on_photos.py``, yellow photo, blue squares
#: drawn over it: 2 of 66 characters found; ranked by brightness, 55).
BACKGROUND_PERCENTILE = 80
BACKGROUND_WINDOW = 10
#: A cell whose background is darker than this share of the paper's is off the sheet
#: (when it connects to the image's border).
TABLE_LEVEL = 0.45
#: ... and the cells joined to those that are darker than this share of it.
TABLE_GROW_LEVEL = 0.5
#: A region taken for the table (step 4) or the desk (step 0) is the paper in a shadow
#: (a phone's or a hand's, across the page) when it holds writing: at least
#: ``SHADE_MARKS`` marks as dark as the pen's strong level (read against the paper beside
#: each, the shadow's own), each ``SHADE_MARK_PEN2`` pen widths squared or more and no
#: thicker than ``SHADE_THIN`` pen widths, inside it by more than two pixels (a
#: character may straddle a shadow's edge).
SHADE_MARKS = 2
SHADE_MARK_PEN2 = 4.0
SHADE_THIN = 2.5
#: ... its holes smaller than this share of the image taken with it (the writing a region
#: of the desk's colour leaves out), not the sheet a desk all around it encloses.
SHADE_HOLE = 0.05
#: ... and it is not paper when more than this share of it is at least the pen's weak
#: level, and ``SHADE_TEXTURE_RATIO`` times the share of the rest of the image (a wooden
#: table's grain: 16-90 % on the generated pages; paper in a shadow, writing and all,
#: up to 5 %, as much as the lit paper).
SHADE_TEXTURE = 0.1
SHADE_TEXTURE_RATIO = 2.0
#: ... and not the marks that lie within a background cell of its outline for this share
#: of their pixels (lines along the sheet's edge, not across it).
SHADE_ALONG = 0.8
#: Where the paper's level steps by this share of it from one background cell to the
#: next (a shadow's hard edge; a lighting gradient steps by at most 0.05), the band
#: that the cells' interpolation leaves along the step inside the shadow is taken out of
#: the darkness: what a grey opening wider than ``THICK_FACTOR`` pen widths keeps.
SHADE_STEP = 0.1
#: ... where what the opening keeps is no darker than this (a band; a dark strip, the
#: desk's or a photo's own edge, stays whole for the edge's tests).
SHADE_BAND = 0.5
#: The rough pen width is measured on strokes, not on a mark of this share of the image
#: (:func:`rough_pen_width`).
ROUGH_BLOB = 0.1
#: On a sheet found on a desk, the rules' level beside its edge is read this many pixels
#: inside it (the desk is painted with the paper's colour up to the edge).
SHEET_EDGE_PX = 3
#: A component is ink when at least this share of its pixels (and two) are strong: a
#: pen's stroke mostly is, a smudge of shade or a crease's edge hardly.
STRONG_SHARE = 0.25
#: A faint component's piece at the half-way level (step 6) is a stroke when it covers at
#: least this many squared pen widths (on squared pages whose remnant rules joined them
#: the pen's pieces covered 140-250, the remnants' own pieces 1-5).
RESCUE_AREA_PEN2 = 20.0
#: A stroke's core is inked at least this much (of the typical ink).
CORE_LEVEL = 0.45
#: Rules are searched within this angle of the rows and columns, degrees.
MAX_RULE_ANGLE_DEG = 6.0
#: A straight run of dark pixels this share of the sheet's width (height) long is a rule.
RULE_SHARE = 0.9
#: ... and this share when at least three such runs are parallel and evenly spaced;
PERIODIC_RULE_SHARE = 0.4
#: ... and in an image this many pen widths across, a lone one whatever the other ink does.
PAGE_LINE_PENS = 40
#: A lone line at an angle of its own may break up (a faint margin line): gaps of up to
#: this share of the extent bridged, ...
LONE_GAP = 0.012
#: ... and this share of the extent inked.
LONE_INKED = 0.6
#: A stroke that runs along a rule for a while and leaves it again (a 0's or a 3's top, a
#: 7's bar on a grid line) keeps the rule's pixels between the two places where it
#: touches it when they are at most this share of the rules' spacing apart. Chosen on the
#: segmentation scan of validation seeds 100-299 (RESULTS 7.3), characters found of 977
#: squared / 979 ruled: none 930 / 965; without ``BRIDGE_CHAIN`` 0.2 940 / 961, 0.3
#: 940 / 963, 0.5 934 / 949 (a length of 8 pen widths instead: 941 / 960, a thick pen's
#: bridges as long as the gaps between its characters), ...
BRIDGE_SPACING = 0.3
#: ... touched by stroke pieces at least this many pen widths tall across the rule (grid
#: remnants along the line do not count; squared, at 8 pen widths: 0 gave 936 found and
#: 215 extra boxes instead of 83, 3 940 / 81, 4 941 / 81, 5 941 / 82), ...
BRIDGE_TALL_PENS = 4.0
#: ... and no stretch of a rule restored is longer than this many such lengths (a row of
#: characters sitting on a rule, one bridge after another, joined them: a thick pen's
#: ruled page, seed 124, lost 6; squared / ruled: 1 933 / 966, 2 935 / 967, 4 935 / 967;
#: the touches then taken through the line's thickness, two rows either way: 936 / 967).
#: Only on rules as dark as the pen: lighter ones keep a stroke's pixels by darkness.
BRIDGE_CHAIN = 2.0
#: A pixel taken with a rule stays ink when it is darker than the lines there (their
#: median over stretches of ``LINE_LEVEL_SHARE`` of the width along them) by this share
#: of the pen's ink, joined to a stroke: ink printed lines lie under.
#: Each line is followed along it first (its middle, a median over such a stretch, so
#: that a stroke along it for less than half a stretch moves neither): a wavy line drifts
#: across a straight stretch's rows, whose medians then read the paper on the line and
#: its pixels as darker than it (a ruled page, validation seed 140: 231 extra boxes,
#: followed 82; before this level was asked, 86). Less than 0.75 of a row is not
#: followed (a straight line a little turned lies half a row up or down by turns).
#: Asked in each channel alone as well (``experiments/lines_on_photos.py``'s yellow legal
#: pads: a blue pen's 7 along the red margin, as dark as the pen in the darkest channel,
#: was cut there; in red it is ink: 62 -> 64 of 66 on each pad).
LINE_INK_SHARE = 0.3
LINE_LEVEL_SHARE = 0.125
#: Components thicker than this many pen widths are not pen strokes.
THICK_FACTOR = 3.5
#: Components smaller than this many pen widths squared are specks,
SPECK_AREA_PEN2 = 2.5
#: ... and so is any of fewer pixels than this (a page of specks has no pen width);
MIN_STROKE_AREA_PX = 8
#: ... except a pen's dot (an i's, a diacritic): a speck of at least this many pen widths
#: squared (an ideal disc one pen width across: pi / 4; Omniglot's dots, in its
#: background-small-1 drawings: 1.09-2.05 by their pen width; of 2,400 square specks of
#: 1-3 px sides added 4-20 px from 400 of its characters, ``experiments/pen_dots.py``,
#: 0.5 kept 189, 0.6 28, 0.7 11, 0.8 5, 0.9 none; no dot lost at any of them),
DOT_AREA_PEN2 = 0.7
#: ... and this many pixels (a thin pen's 2 x 2 grain is no dot, its 3 x 3 dot is),
DOT_MIN_PX = 5
#: ... at least this many pen widths across both ways (Omniglot's: 1.04-1.6; a rule's
#: remnant is as thin as the rule) and at most ``DOT_SIZE_PEN``, not touching a rule's
#: removed pixels (a red margin line's bits where the rules cross it, 2 x 4 px beside a
#: 2.1-px pen: they cost the segmentation of validation seed 7 a character),
DOT_SIDE_PEN = 0.6
#: ... with at least this share of its pixels as dark as the pen's strong level,
DOT_STRONG_SHARE = 0.5
#: ... within this share of a kept stroke's longer side from that stroke's box (an i's
#: or j's dot sits up to 6.7 pen widths above its stem: Omniglot's Latin, 0.4-0.8 of
#: the stem's length; a reach of a few pen widths would drop them) ...
DOT_NEAR_SHARE = 1.0
#: ... and at most this many pen widths from it (1.5 times the farthest of Omniglot's
#: dots), and not on a lattice of such marks (dotted paper's).
DOT_NEAR_PEN = 10.0
#: Dots of dotted paper: marks at most this many pen widths across,
DOT_SIZE_PEN = 2.5
#: ... or filled discs: at most this many times their thickness (2 area / boundary) across
#: (an ideal disc: 2; a blurred, grainy printed dot 2.5-3.3),
DOT_DISC = 3.5
#: ... at least this many of them, evenly spaced.
MIN_DOTS = 8
#: A component that touches the image's border along this share of that side is the
#: sheet's edge (counted where it touches: a character cut by the border touches it
#: where its strokes cross it, a few pen widths, however tall it is).
EDGE_SHARE = 0.15
#: ... within this share of the shorter side from the border.
EDGE_BAND = 0.015
#: A mark beside the image's border or the desk (within ``EDGE_LINE_NEAR`` of the
#: shorter side) at least this share of the shorter side long is the sheet's edge when it
#: lies mostly (``EDGE_LINE_INSIDE``) in that band, or is straight: this many times as
#: long as thick (the spread of its pixels across and along it); no character is.
EDGE_LINE_SHARE = 0.25
EDGE_LINE_NEAR = 0.03
EDGE_LINE_INSIDE = 0.8
EDGE_LINE_THIN = 12.0
#: ... and one lying in that band (``EDGE_LINE_INSIDE``) from this share, when it is this
#: many times as long as thick (a piece of the edge's line that the margin cut), as a
#: whole or along each border it lies beside (the sheet's corner: two lines, an L).
EDGE_PIECE_SHARE = 0.08
EDGE_PIECE_THIN = 4.0


@dataclass
class PaperInk:
    """What :func:`paper_ink` found.

    Attributes
    ----------
    ink : float32 [H, W]
        Ink levels: 0 on paper, about 1 on typical ink (clipped to [0, 1]).
    mask : bool [H, W]
        The kept strokes' pixels.
    pen_width_px : float
        Typical stroke width of the kept ink (0: none).
    dark_on_light : bool
        The polarity read from the border.
    removed : dict
        Counts of what was dropped: ``rule_px``, ``off_sheet_px``, ``faint_components``,
        ``specks``, ``thick_components``, ``desk_px`` (the pixels of a desk around the
        sheet, :func:`img2dmp.data.sheet.find_sheet`; 0 when none was found).
    steps : dict of name -> array
        With ``keep_steps``: ``input`` (RGB or grey), ``background``, ``darkness``,
        ``sheet``, ``rules``, ``ink`` (see the module docstring), and ``glare`` (the gain
        :func:`glare_gain` gave the darkness, ``[H, W]``) where a glare was found; else
        empty. :func:`img2dmp.data.images.paper_steps` adds ``shake`` when asked to
        steady the image first.
    glare_gain : float
        The largest factor a glare's lost contrast was given back by (:func:`glare_gain`;
        1: no glare found).
    """

    ink: np.ndarray
    mask: np.ndarray
    pen_width_px: float
    dark_on_light: bool
    removed: dict = field(default_factory=dict)
    steps: dict = field(default_factory=dict)
    glare_gain: float = 1.0

    @property
    def core(self) -> np.ndarray:
        """The strokes' cores, ``bool [H, W]``: kept pixels at least ``CORE_LEVEL`` inked
        (a blurred photo's halos joined two strokes that the cores keep apart)."""
        return self.mask & (self.ink >= CORE_LEVEL)


_LUMA = (0.299, 0.587, 0.114)  # ITU-R 601-2, as PIL's "L"


def _planes(levels) -> np.ndarray:
    """Levels ``[H, W]`` or ``[H, W, 3]`` as contiguous channel planes ``float32
    [C, H, W]`` (each channel's arithmetic then runs over contiguous memory)."""
    a = np.asarray(levels, dtype=np.float32)
    if a.ndim == 2:
        return a[None].copy() if not a.flags.c_contiguous else a[None]
    return np.ascontiguousarray(np.moveaxis(a, 2, 0))


def _luma(planes: np.ndarray) -> np.ndarray:
    """Grey levels ``[..., H, W]`` of channel planes ``[C, ...]``."""
    if len(planes) == 1:
        return planes[0]
    return sum(w * p for w, p in zip(_LUMA, planes, strict=True))


def _ring(a: np.ndarray) -> np.ndarray:
    """The outer ring of ``a [..., H, W]`` (5 % of the shorter side, at least one pixel),
    flattened over its last two axes: ``[..., n]``."""
    r = max(1, round(0.05 * min(a.shape[-2:])))
    parts = [a[..., :r, :], a[..., -r:, :], a[..., :, :r], a[..., :, -r:]]
    return np.concatenate([p.reshape(*a.shape[:-2], -1) for p in parts], axis=-1)


def dark_on_light(planes: np.ndarray) -> bool:
    """Whether the ink is dark on light paper. Ink is the minority of an image: more
    pixels lie far below the local median (of cells of ``1 / POLARITY_CELLS`` of the
    shorter side; not the cells of a table beside the sheet) than far above it for dark
    ink, far above for light ink; far: ``POLARITY_SPREADS`` times the paper's own robust
    spread (shading and grain reach as far either way). An image whose median is
    lighter than ``POLARITY_PLAIN`` (or darker than its complement) needs no cells. For
    a small image, or when neither side has twice as many as the other, the border
    decides as it always has: brighter than the whole image's median, or than mid grey,
    is dark ink on light paper."""
    lum = _luma(planes)
    median = float(np.median(lum))
    if median >= POLARITY_PLAIN or median <= 1.0 - POLARITY_PLAIN:
        return median >= POLARITY_PLAIN  # the minority, ink, is the other way
    if min(lum.shape) >= LOCAL_BACKGROUND_MIN_SIDE:
        # against the local median (paper, whichever its polarity), so that a lighting
        # gradient's spread is not taken for ink
        cell = max(2, min(lum.shape) // POLARITY_CELLS)  # wide beside strokes
        grid, cell = _cell_percentile(lum[None], cell, 50)
        rest = lum - _upsample(grid, cell, lum.shape)[0]
        # not the cells of what lies beside the sheet (a dark table's cells have light
        # paper in them as the paper's cells have ink): the cells whose median is far
        # from the typical cell's
        from scipy.ndimage import binary_erosion

        usual = float(np.median(grid))
        even = np.abs(grid[0] - usual) < POLARITY_EVEN
        # ... or near the lightest common level (the lit paper, where a shadow across the
        # page holds the median cell)
        even |= np.abs(grid[0] - float(np.percentile(grid, 90))) < POLARITY_EVEN
        # ... nor those at a step to a neighbour (a shadow's hard edge across the page:
        # the median interpolated across it puts the lit side above it, the shaded below)
        # (between two cells of the paper's level: a table's edge is left out above)
        g, e = np.pad(grid[0], 1, mode="edge"), np.pad(even, 1, mode="edge")
        h, w = grid.shape[1:]
        step = np.max([np.abs(g[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] - grid[0])
                       * e[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w]
                       for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)  # fmt: skip
        even &= step < POLARITY_STEP
        # ... nor the cells beside those (the median interpolated across the edge)
        even = binary_erosion(even, np.ones((3, 3), bool), border_value=1)
        even = _upsample(even[None].astype(np.float32), cell, lum.shape)[0] > 0.99
        rest = rest[even] if even.mean() > 0.25 else rest
        sample = rest.ravel()[:: max(1, rest.size // 200_000)]
        # the tails beyond a few times the paper's own spread: shading within a cell and
        # the paper's grain reach as far either way, ink only its own way
        spread = 1.4826 * float(np.median(np.abs(sample - np.median(sample))))
        far = max(POLARITY_SPREADS * spread, 0.03)
        below = np.count_nonzero(sample < -far) / sample.size
        above = np.count_nonzero(sample > far) / sample.size
        if max(below, above) > POLARITY_MIN_SHARE and max(below, above) > 2 * min(below, above):
            return bool(below > above)
    border = float(np.median(_ring(lum)))
    return border > median or border > 0.5


def _cell_blocks(planes: np.ndarray, cell: int) -> tuple[np.ndarray, int]:
    """The pixels of every ``cell x cell`` block, ``[C, gh, gw, n]`` (blocks cut by the
    border padded by reflection), and the cells' side in pixels of ``planes`` (``cell``,
    or a little more after the averaging). Cells of more than 8 x 8 pixels are first
    area-averaged to about 8 x 8: the paper's level is smooth, and a stroke averaged with
    the paper beside it stays darker than the paper."""
    red = max(1, cell // 8)
    a = np.stack([_block_mean(p, red) for p in planes]) if red > 1 else planes
    small = -(-cell // red)
    c, h, w = a.shape
    gh, gw = -(-h // small), -(-w // small)
    a = np.pad(a, ((0, 0), (0, gh * small - h), (0, gw * small - w)), mode="reflect")
    blocks = a.reshape(c, gh, small, gw, small).transpose(0, 1, 3, 2, 4).reshape(c, gh, gw, -1)
    return blocks, small * red


def _cell_percentile(planes: np.ndarray, cell: int, q: float) -> tuple[np.ndarray, int]:
    """The ``q``-th percentile of every ``cell x cell`` block (:func:`_cell_blocks`), per
    channel: ``[C, gh, gw]``, and the cells' side."""
    blocks, side = _cell_blocks(planes, cell)
    k = min(blocks.shape[3] - 1, int(round(q / 100.0 * (blocks.shape[3] - 1))))
    return np.partition(blocks, k, axis=3)[..., k], side


def _cell_paper(planes: np.ndarray, cell: int) -> tuple[np.ndarray, int]:
    """The paper's colour in every ``cell x cell`` block (:func:`_cell_blocks`),
    ``[C, gh, gw]``: the mean, per channel, of the pixels whose brightness ranks within
    ``BACKGROUND_WINDOW`` percentiles of ``BACKGROUND_PERCENTILE`` (a grey image: its
    ``BACKGROUND_PERCENTILE``-th percentile); and the cells' side."""
    if len(planes) == 1:
        return _cell_percentile(planes, cell, BACKGROUND_PERCENTILE)
    blocks, side = _cell_blocks(planes, cell)
    n = blocks.shape[3]
    lo = int(round((BACKGROUND_PERCENTILE - BACKGROUND_WINDOW) / 100.0 * (n - 1)))
    hi = max(lo + 1, int(round((BACKGROUND_PERCENTILE + BACKGROUND_WINDOW) / 100.0 * (n - 1))) + 1)
    order = np.argsort(_luma(blocks), axis=-1)[..., lo:hi]  # [gh, gw, k] by brightness
    picked = np.take_along_axis(blocks, np.broadcast_to(order, (len(blocks), *order.shape)), -1)
    return picked.mean(axis=-1), side


def _block_mean(a: np.ndarray, factor: int) -> np.ndarray:
    """``a [H, W]`` area-averaged ``factor`` times per side (PIL's reduce: C speed)."""
    from PIL import Image

    im = Image.fromarray(np.ascontiguousarray(a, dtype=np.float32), mode="F")
    return np.asarray(im.reduce(factor), dtype=np.float32)


def _upsample(grid: np.ndarray, cell: int, shape: tuple[int, int]) -> np.ndarray:
    """Cell values ``[C, gh, gw]`` interpolated bilinearly to pixels ``[C, H, W]`` (cell
    centres at their pixels' centres; beyond the last cell, its value)."""
    from PIL import Image

    c, gh, gw = grid.shape
    out = np.empty((c, *shape), np.float32)
    for ch in range(c):
        im = Image.fromarray(np.ascontiguousarray(grid[ch], np.float32), mode="F")
        big = np.asarray(im.resize((gw * cell, gh * cell), Image.Resampling.BILINEAR))
        h, w = min(shape[0], big.shape[0]), min(shape[1], big.shape[1])
        out[ch, :h, :w] = big[:h, :w]
        out[ch, h:, :], out[ch, :, w:] = out[ch, h - 1 : h, :], out[ch, :, w - 1 : w]
    return out


def background(planes: np.ndarray, pen_width_px: float | None = None,
               cells: bool = False) -> tuple[np.ndarray, int]:  # fmt: skip
    """The paper's level at every pixel of channel planes ``[C, H, W]`` (dark-on-light
    levels), per channel, and the cell side used (0 for no cells: one level per channel,
    the border's median, for a tiny image, then ``[C, 1, 1]``; or the smooth surface of
    a character's crop, unless ``cells``)."""
    return _background(planes, pen_width_px, cells)[:2]


def _background(planes: np.ndarray, pen_width_px: float | None,
                cells: bool) -> tuple[np.ndarray, int, bool]:  # fmt: skip
    """:func:`background`, and whether a crop read with its smooth surface lies across a
    shadow's hard edge (:func:`crop_shade_step`; False for any other image)."""
    from scipy.ndimage import gaussian_filter, grey_closing

    if min(planes.shape[1:]) < LOCAL_BACKGROUND_MIN_SIDE:
        return np.median(_ring(planes), axis=-1).astype(np.float32)[:, None, None], 0, False
    width = rough_pen_width(planes) if pen_width_px is None else pen_width_px
    if min(planes.shape[1:]) < SURFACE_MAX_SIDE and not cells:
        surface = smooth_background(planes)
        ratio, lo, hi, cell = _shadow_cells(planes, surface, width)
        return surface * _factor(ratio.shape, lo, hi, cell), 0, _stepped(surface, lo, hi, cell)
    # A cell must hold paper beside a stroke: at least a few pen widths (a thick pen in a
    # small crop), and the closing over 3 x 3 cells then covers a cell full of ink.
    cell = max(2, min(planes.shape[1:]) // BACKGROUND_CELLS, math.ceil(CELL_PEN_WIDTHS * width))
    grid, cell = _cell_paper(planes, cell)
    grid = grey_closing(grid, size=(1, 3, 3))
    grid = gaussian_filter(grid, sigma=(0, 0.7, 0.7), mode="nearest")
    return _upsample(grid, cell, planes.shape[1:]), cell, False


def _surface_terms(h: int, w: int, rows, cols) -> np.ndarray:
    """The quadratic surface's terms ``[6, ...]`` at pixel ``rows``, ``cols`` (scaled to
    [-1, 1] over an image of ``h x w``)."""
    y = 2.0 * rows / max(h - 1, 1) - 1.0
    x = 2.0 * cols / max(w - 1, 1) - 1.0
    x, y = np.broadcast_arrays(x, y)
    return np.stack([np.ones_like(x), x, y, x * x, x * y, y * y])


def smooth_background(planes: np.ndarray) -> np.ndarray:
    """The paper of a small image (a character's crop) as a quadratic surface per channel
    ``[C, H, W]``: fitted to about 20,000 pixels, each fit leaving out the pixels well
    darker than the last (ink and rules), four times. A crop is too small for cells
    that hold more paper than ink, and its lighting is a gradient at most."""
    c, h, w = planes.shape
    step = max(1, round(math.sqrt(h * w / 20_000)))
    rows, cols = np.mgrid[0:h:step, 0:w:step]
    terms = _surface_terms(h, w, rows.ravel().astype(np.float64), cols.ravel().astype(np.float64))
    sub = planes[:, ::step, ::step].reshape(c, -1).astype(np.float64)
    lum, keep = _luma(sub), np.ones(sub.shape[1], bool)
    for _ in range(4):
        coef = np.linalg.lstsq(terms[:, keep].T, lum[keep], rcond=None)[0]
        resid = lum - coef @ terms
        sigma = 1.4826 * float(np.median(np.abs(resid[keep] - np.median(resid[keep]))))
        keep = resid > -2.5 * max(sigma, 1e-3)
    coefs = np.linalg.lstsq(terms[:, keep].T, sub[:, keep].T, rcond=None)[0]  # [6, C]
    full = _surface_terms(h, w, np.arange(h, dtype=np.float64)[:, None],
                          np.arange(w, dtype=np.float64)[None, :])  # fmt: skip
    out = np.einsum("kc,khw->chw", coefs, full)
    return np.clip(out, 1e-3, None).astype(np.float32)


def shadow_factor(planes: np.ndarray, surface: np.ndarray, pen_width_px: float) -> np.ndarray:
    """How much darker than the smooth ``surface`` the paper is locally (a soft shadow on
    a crop), ``float32 [H, W]``: in cells of at least ``CELL_PEN_WIDTHS`` pen widths, the
    80th percentile of the brightness against the surface where the cell is even (its
    20th and 80th percentiles within ``EVEN_CELL`` of each other: paper, lit or in
    shadow), spread into the cells that hold ink by normalised convolution; 1 where no
    even cell is near."""
    ratio, lo, hi, cell = _shadow_cells(planes, surface, pen_width_px)
    return _factor(ratio.shape, lo, hi, cell)


def _factor(shape, lo: np.ndarray, hi: np.ndarray, cell: int) -> np.ndarray:
    """:func:`shadow_factor` from its cells' percentiles (:func:`_shadow_cells`)."""
    from scipy.ndimage import gaussian_filter

    even = ((hi - lo) < EVEN_CELL)[0].astype(np.float32)
    weight = gaussian_filter(even, 1.0, mode="nearest")
    value = gaussian_filter(even * hi[0], 1.0, mode="nearest")
    factor = np.where(weight > 0.05, value / np.maximum(weight, 1e-6), 1.0)
    factor = np.clip(factor, 0.3, 1.0).astype(np.float32)
    return _upsample(factor[None], cell, shape)[0]


def glare_gain(planes: np.ndarray, bg: np.ndarray, cell: int, where=None) -> np.ndarray | None:
    """How much a glare has taken from the ink's contrast at every pixel (``GLARE_*``),
    ``float32 [H, W]`` of at least 1, from the paper ``bg`` read in cells of ``cell``
    pixels; None where there is no glare (or no cells). With ``where`` (``bool [H, W]``:
    the sheet, a desk painted over with the paper's colour beside it) only the cells
    wholly on it are read: the painted desk has no grain."""
    if cell <= 0:
        return None
    grid = _luma(bg[:, cell // 2 :: cell, cell // 2 :: cell]).astype(np.float64)
    paper = grid >= TABLE_LEVEL * np.percentile(grid, 95)
    if where is not None:
        paper &= _cells_within(where, cell, grid.shape)
        if not paper.any():
            return None
    b0 = min(float(np.median(grid[paper])), 0.999)
    share = np.clip((grid - b0) / (1.0 - b0), 0.0, 0.95)
    lost = 1.0 / (1.0 - share) - 1.0  # the contrast a glare of that share takes, less 1
    vote = (share >= GLARE_STRONG_SHARE) & paper
    if vote.sum() < max(GLARE_MIN_CELLS, GLARE_MIN_SHARE * paper.sum()):
        return None
    grain = _cell_grain(planes, bg, cell, grid.shape)
    flat = float(np.median(grain[paper])) / grain * b0 / np.maximum(grid, b0)
    shown = (flat[vote] - 1.0) / lost[vote]  # 1: flattened as a glare would
    confirmed, spread = np.percentile(shown, [50, 75])
    if spread > GLARE_SPREAD or confirmed < GLARE_CONFIRMED:
        return None
    gain = np.clip(grid * (1.0 - b0) / (b0 * np.maximum(1.0 - grid, 1e-3)), 1.0, GLARE_MAX_GAIN)
    gain = 1.0 + min(float(confirmed), 1.0) * (gain - 1.0)
    return _upsample(gain[None].astype(np.float32), cell, planes.shape[1:])[0]


def _cells_within(mask: np.ndarray, cell: int, shape) -> np.ndarray:
    """Whether every pixel of each ``cell x cell`` block (``shape``: the cells') lies in
    ``mask`` (``bool [H, W]``; beyond the image: no)."""
    gh, gw = shape
    m = np.zeros((gh * cell, gw * cell), bool)
    h, w = min(mask.shape[0], gh * cell), min(mask.shape[1], gw * cell)
    m[:h, :w] = mask[:h, :w]
    return m.reshape(gh, cell, gw, cell).all(axis=(1, 3))


def _cell_grain(planes: np.ndarray, bg: np.ndarray, cell: int, shape) -> np.ndarray:
    """The paper's grain in every cell (``shape``: the cells'): the robust spread (MAD)
    of the relative brightness ``1 - luma / luma(bg)``, median-filtered over 3 x 3 cells,
    at least ``GLARE_GRAIN_FLOOR``. Large cells are sampled every second pixel."""
    from scipy.ndimage import median_filter

    rel = 1.0 - _luma(planes) / np.maximum(_luma(bg), 1e-3)
    gh, gw = shape
    pad = ((0, max(0, gh * cell - rel.shape[0])), (0, max(0, gw * cell - rel.shape[1])))
    rel = np.pad(rel.astype(np.float32), pad, mode="reflect")[: gh * cell, : gw * cell]
    step = 2 if cell >= 16 else 1
    blocks = rel.reshape(gh, cell, gw, cell)[:, ::step, :, ::step]
    blocks = blocks.transpose(0, 2, 1, 3).reshape(gh, gw, -1)
    mad = np.median(np.abs(blocks - np.median(blocks, axis=-1, keepdims=True)), axis=-1)
    return np.maximum(median_filter(1.4826 * mad, 3, mode="nearest"), GLARE_GRAIN_FLOOR)


def _shadow_cells(planes: np.ndarray, surface: np.ndarray, pen_width_px: float):
    """The brightness against the smooth ``surface`` (``[H, W]``), its 20th and 80th
    percentiles in cells of at least ``CELL_PEN_WIDTHS`` pen widths (``[1, gh, gw]``
    each), and the cells' side."""
    ratio = _luma(planes) / np.maximum(_luma(surface), 1e-3)
    cell = max(8, min(ratio.shape) // 12, math.ceil(CELL_PEN_WIDTHS * pen_width_px))
    lo, _ = _cell_percentile(ratio[None], cell, 20)
    hi, cell = _cell_percentile(ratio[None], cell, 80)
    return ratio, lo, hi, cell


def crop_shade_step(planes: np.ndarray, pen_width_px: float) -> bool:
    """Whether a crop (under ``SURFACE_MAX_SIDE``) lies across a shadow's hard edge: two
    even cells (:func:`shadow_factor`'s, their spread within ``EVEN_CELL`` of the larger
    of 1 and their level against the surface) one or two cells apart whose paper differs
    by ``SHADE_STEP`` of the paper's level (a cell on the edge itself is not even)."""
    if not LOCAL_BACKGROUND_MIN_SIDE <= min(planes.shape[1:]) < SURFACE_MAX_SIDE:
        return False
    surface = smooth_background(planes)
    _, lo, hi, cell = _shadow_cells(planes, surface, pen_width_px)
    return _stepped(surface, lo, hi, cell)


def _stepped(surface: np.ndarray, lo: np.ndarray, hi: np.ndarray, cell: int) -> bool:
    """:func:`crop_shade_step` from the crop's smooth ``surface`` and its cells'
    percentiles against it (:func:`_shadow_cells`)."""
    even = ((hi - lo) < EVEN_CELL * np.maximum(hi, 1.0))[0]
    if not even.any():
        return False
    lum = _luma(surface)
    rows = np.minimum(np.arange(even.shape[0]) * cell + cell // 2, lum.shape[0] - 1)
    cols = np.minimum(np.arange(even.shape[1]) * cell + cell // 2, lum.shape[1] - 1)
    paper = hi[0] * lum[np.ix_(rows, cols)]  # the paper's level in each cell
    limit = SHADE_STEP * max(float(np.percentile(paper[even], 95)), 1e-3)
    for d in (1, 2):  # down the columns, then along the rows
        for e, p in ((even.T, paper.T), (even, paper)):
            jump = np.abs(p[:, d:] - p[:, :-d]) >= limit
            if (e[:, d:] & e[:, :-d] & jump).any():
                return True
    return False


def rough_pen_width(planes: np.ndarray) -> float:
    """A first estimate of the pen's width (pixels) before the paper is known: the
    strokes darker than half the darkest ink against the image's brightest tenth,
    measured as :func:`pen_width` measures them (not those that reach the border, the
    table's, while others do); on every s-th pixel of a large image (about a million).
    When what it would measure holds a mark of ``ROUGH_BLOB`` of the image (a shadow
    across a photographed character, its strokes joined to it), the darkness less a
    grey opening a tenth of the shorter side wide is measured instead: strokes, not
    the shade they lie in."""
    from scipy.ndimage import grey_opening, label

    step = max(1, round(math.sqrt(planes[0].size / 1_000_000)))
    lum = _luma(planes[:, ::step, ::step])
    dark = 1.0 - lum / max(float(np.percentile(lum, 90)), 1e-3)
    for shade in (False, True):
        if shade:
            dark = dark - grey_opening(dark, size=(max(3, min(dark.shape) // 10),) * 2)
        top = float(np.percentile(dark, 99.5))
        if top < 0.15:
            return 0.0
        mask = dark > 0.5 * top
        labels, n = label(mask, structure=np.ones((3, 3), bool))
        area = np.bincount(labels.ravel(), minlength=n + 1)
        boundary = np.bincount(labels[mask & ~_erode3(mask)], minlength=n + 1)
        keep = area >= 4
        keep[0] = False
        inside = keep.copy()  # the table or the sheet's edge beyond the border is no stroke
        inside[_ring_labels(labels)] = False
        use = inside if inside.any() else keep
        if shade or not np.any(area[use] > ROUGH_BLOB * mask.size):
            break
    return pen_width(area, boundary, use) * step


def darkness(planes: np.ndarray, bg: np.ndarray) -> np.ndarray:
    """How much light each pixel absorbs relative to its paper, the largest over the
    channels, in [0, 1] (``float32 [H, W]``): ``max_c (b_c - p_c) / max_c' b_c'`` for
    pixel ``p`` on paper ``b``, each channel's loss against the paper's brightest
    channel (grey: ``1 - p / b``). A photo's noise is about as large in every channel
    in absolute terms; against the channel's own level, the blue that yellow paper
    hardly reflects (0.4 of its red) made it about three times the others', and legal
    pads saved as JPEGs read as specks and joined characters. Light and tint divide out
    either way."""
    return np.max(channel_darkness(planes, bg), axis=0)


def channel_darkness(planes: np.ndarray, bg: np.ndarray) -> np.ndarray:
    """Each channel's loss of light against the paper's brightest channel,
    ``(b_c - p_c) / max_c' b_c'`` in [0, 1] (``float32 [C, H, W]``): :func:`darkness`
    before its largest is taken."""
    top = np.maximum(np.max(bg, axis=0), 1e-3)
    out = np.empty(planes.shape, np.float32)
    for c, (p, b) in enumerate(zip(planes, bg, strict=True)):
        np.divide(b - p, top, out=out[c], dtype=np.float32)
    return np.clip(out, 0.0, 1.0, out=out)


def _noise(planes: np.ndarray, bg: np.ndarray, where=None, gain=None) -> float:
    """Robust standard deviation of the paper's relative brightness (luma, MAD), from a
    strided sample of about 200,000 pixels (of ``where``, ``bool [H, W]``, when given:
    the sheet, not the desk painted smooth), times a glare's ``gain`` (``[H, W]``,
    :func:`glare_gain`) where given, as the darkness is."""
    step = max(1, planes[0].size // 200_000)
    lum = _luma(planes.reshape(len(planes), -1)[:, ::step])
    lb = _luma(np.broadcast_to(bg, planes.shape).reshape(len(planes), -1)[:, ::step])
    s = 1.0 - lum / np.maximum(lb, 1e-3)
    if gain is not None:
        s = s * gain.ravel()[::step]
    if where is not None and where.any():
        s = s[where.ravel()[::step]]
    return float(1.4826 * np.median(np.abs(s - np.median(s))))


def holds_writing(dark: np.ndarray, region: np.ndarray, lv: _Levels, pen: float,
                  cell: int) -> bool:  # fmt: skip
    """Whether ``region`` (``bool [H, W]``) holds writing and no table's texture
    (``SHADE_*``): the paper in a shadow, not a table or a desk. ``dark``: the darkness
    against the paper beside each pixel; ``lv``: the page's levels; ``pen``: the pen's
    width, ``cell``: the background's cell (pixels)."""
    from scipy.ndimage import binary_fill_holes, distance_transform_edt, label

    # its holes filled, but not the sheet a desk around it encloses (a region of the
    # desk's colour leaves the writing out)
    holes, n = label(binary_fill_holes(region) & ~region)
    if n:
        small = np.bincount(holes.ravel(), minlength=n + 1) < SHADE_HOLE * region.size
        small[0] = False
        region = region | small[holes]
    pen = max(pen, 1.0)
    strong = dark >= lv.strong
    if np.count_nonzero(strong & region) < SHADE_MARKS * SHADE_MARK_PEN2 * pen**2:
        return False  # not ink enough for that many marks (most desks: none at all)
    # how far inside it each pixel lies (the image's border is no outline)
    depth = distance_transform_edt(np.pad(region, 1, constant_values=True))[1:-1, 1:-1]
    inner = depth > 2.0
    if not inner.any() or region.all():
        return False
    textured, rest = (float(np.mean(dark[m] >= lv.weak)) for m in (inner, ~region))
    if textured > max(SHADE_TEXTURE, SHADE_TEXTURE_RATIO * rest):
        return False  # a table's grain or pattern, not paper
    for level in (lv.strong, lv.ink):  # at the pen's own level: the lines of squared
        # paper, lighter than the pen, no longer join its marks into one net
        if _shade_marks(inner & (dark >= level), dark, level, depth, pen, cell) >= SHADE_MARKS:
            return True
    return False


def _shade_marks(mask, dark, level: float, depth, pen: float, cell: int) -> int:
    """:func:`holds_writing`'s marks in ``mask``: components of ``SHADE_MARK_PEN2`` pen
    widths squared, thin, and not a line along the region's outline."""
    labels, area, boundary, _ = _components(mask, dark, level)
    thin = 2.0 * area / np.maximum(boundary, 1) <= SHADE_THIN * pen
    # not a line along its outline (the sheet's edge beside a desk, where the paper's
    # level read across it lags)
    along = np.bincount(labels.ravel(), weights=(depth <= max(cell, 2)).ravel(),
                        minlength=len(area)) >= SHADE_ALONG * area  # fmt: skip
    marks = (area >= SHADE_MARK_PEN2 * pen**2) & thin & ~along
    marks[0] = False
    return int(np.count_nonzero(marks))


def shade_test(planes: np.ndarray):
    """``region -> bool`` for :func:`img2dmp.data.sheet.find_sheet`: whether a region of
    the photo ``planes`` (``[C, H, W]``, as given, before any desk is painted over) that
    looks like a desk holds writing (:func:`holds_writing`, its paper read as it is,
    the page's levels from the rest of it): a shadow across the page. The photo's
    paper is read once, at the first call."""
    seen: dict = {}

    def written(region: np.ndarray) -> bool:
        if not seen:
            p = planes if dark_on_light(planes) else 1.0 - planes
            pen = rough_pen_width(p)
            bg, cell = background(p, pen)
            seen.update(p=p, pen=pen, bg=bg, cell=cell, dark=darkness(p, bg))
        if seen["cell"] == 0:
            return False
        noise = _noise(seen["p"], seen["bg"], ~region)
        lv = thresholds(seen["dark"], noise, exclude=region) or thresholds(seen["dark"], noise)
        return lv is not None and holds_writing(seen["dark"], region, lv, seen["pen"], seen["cell"])

    return written


def _cell_pixels(cells: np.ndarray, cell: int, shape: tuple[int, int]) -> np.ndarray:
    """A value per cell (``[gh, gw]``, one sample per ``cell`` pixels) at the pixels of
    ``shape`` (nearest; the rows and columns beyond the last cell take its value)."""
    full = np.repeat(np.repeat(cells, cell, axis=0), cell, axis=1)[: shape[0], : shape[1]]
    return np.pad(full, ((0, shape[0] - full.shape[0]), (0, shape[1] - full.shape[1])),
                  mode="edge")  # fmt: skip


def without_shade_bands(dark: np.ndarray, bg: np.ndarray, cell: int, pen: float) -> np.ndarray:
    """``dark`` with the bands along a shadow's hard edge taken out (``SHADE_STEP``): the
    paper's level read in cells lags a sharp step by a cell or two, and in that band
    the paper reads as faint ink that joins the characters it touches into one faint
    mark. Within a cell of such a step, the darkness less what a grey opening wider
    than ``THICK_FACTOR`` pen widths keeps of it, where that is at most ``SHADE_BAND``:
    strokes, thinner than the opening, keep their darkness over the band's."""
    from scipy.ndimage import binary_dilation, grey_opening

    if cell == 0:
        return dark
    lum = _luma(bg[:, cell // 2 :: cell, cell // 2 :: cell])
    limit = SHADE_STEP * max(float(np.percentile(lum, 95)), 1e-3)
    step = np.zeros(lum.shape, bool)
    for axis in (0, 1):
        big = np.abs(np.diff(lum, axis=axis)) >= limit
        lead = [slice(None), slice(None)]
        lead[axis] = slice(0, -1)
        step[tuple(lead)] |= big
        lead[axis] = slice(1, None)
        step[tuple(lead)] |= big
    if not step.any():
        return dark
    near = _cell_pixels(binary_dilation(step, np.ones((3, 3), bool)), cell, dark.shape)
    size = max(3, math.ceil(THICK_FACTOR * max(pen, 1.0)))
    r = max(1, size // 6)  # the opening on the darkness reduced: about 6 pixels wide
    small = _block_mean(dark, r) if r > 1 else dark
    opened = grey_opening(small, size=(math.ceil(size / r),) * 2)
    if r > 1:
        opened = _upsample(opened[None], r, dark.shape)[0]
    # a dark strip (the desk's, a photo's edge) loses no more than a band's level
    less = np.minimum(opened, SHADE_BAND)
    return np.where(near, np.clip(dark - less, 0.0, 1.0), dark).astype(np.float32)


def sheet_mask(bg: np.ndarray, cell: int, dark: np.ndarray | None = None, pen: float = 0.0,
               noise: float = 0.0) -> np.ndarray:  # fmt: skip
    """Where the sheet is (``bool [H, W]``): not the cells far darker than the paper
    (``TABLE_LEVEL``) that connect to the image's border, nor the cell beside them (the
    edge's own band). With ``dark`` (the darkness against the paper, ``pen`` and
    ``noise`` as :func:`paper_ink` reads them), a part of them that holds writing
    (:func:`holds_writing`) is the paper in a shadow and stays on the sheet."""
    from scipy.ndimage import binary_dilation, label

    h, w = bg.shape[1:]
    if cell == 0:
        return np.ones((h, w), bool)
    lum = _luma(bg[:, cell // 2 :: cell, cell // 2 :: cell])  # one sample per cell
    paper = np.percentile(lum, 95)
    far = lum < TABLE_LEVEL * paper
    labels, _ = label(far)
    edge = np.unique(np.concatenate([_ring_labels(labels)]))
    table = np.isin(labels, edge[edge > 0])
    # ... grown over the cells beside it that are still far darker than the paper (the
    # table's lighter grain)
    labels, _ = label(lum < TABLE_GROW_LEVEL * paper)
    grown = np.unique(labels[table])
    table |= np.isin(labels, grown[grown > 0])
    if not table.any():
        return np.ones((h, w), bool)
    full = _cell_pixels(~binary_dilation(table, np.ones((3, 3), bool)), cell, (h, w))
    if dark is None:
        return full
    parts, n = label(~full)
    lv = thresholds(dark, noise, exclude=~full) or thresholds(dark, noise)
    for k in range(1, n + 1) if lv is not None else ():
        part = parts == k
        if holds_writing(dark, part, lv, pen, cell):
            full |= part
    return full


def _ring_labels(labels: np.ndarray) -> np.ndarray:
    return np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])


def dominant_angle(mask: np.ndarray, max_deg: float = MAX_RULE_ANGLE_DEG,
                   centre_deg: float = 0.0) -> float:  # fmt: skip
    """The angle (degrees, within +-``max_deg`` of ``centre_deg``) of the rows along which
    the pixels of ``mask`` line up best: the shear ``r - c tan(angle)`` whose row
    histogram has the largest sum of squares (a straight rule or a text line is a sharp
    peak)."""
    rows, cols = np.nonzero(mask)
    if rows.size < 2:
        return 0.0
    step = max(1, rows.size // 150_000)  # a strided sample is enough for the peaks
    r, c = rows[::step].astype(np.float64), cols[::step].astype(np.float64)

    def score(deg: float) -> float:
        q = np.round(r - c * math.tan(math.radians(deg))).astype(np.int64)
        counts = np.bincount(q - q.min()).astype(np.float64)
        return float(counts @ counts)

    coarse = centre_deg + np.arange(-max_deg, max_deg + 1e-9, 0.5)
    best = coarse[int(np.argmax([score(d) for d in coarse]))]
    fine = np.clip(best + np.arange(-0.5, 0.5 + 1e-9, 0.1), centre_deg - max_deg,
                   centre_deg + max_deg)  # fmt: skip
    return float(fine[int(np.argmax([score(d) for d in fine]))])


def _shear_rows(shape, angle_deg: float) -> np.ndarray:
    """Row offset ``[W]`` of every column in the sheared frame (``r' = r + offset[c]``,
    all >= 0), which turns rows at ``angle_deg`` into rows."""
    cols = np.arange(shape[1], dtype=np.float64)
    off = -np.round(cols * math.tan(math.radians(angle_deg))).astype(np.int64)
    return off - off.min()


def _long_runs(rows_mask: np.ndarray, min_len: int, gap: int) -> np.ndarray:
    """``bool`` mask of the runs along the rows of ``rows_mask`` at least ``min_len``
    long, gaps of up to ``gap`` pixels bridged."""
    h, w = rows_mask.shape
    padded = np.zeros((h, w + 2), np.int8)
    padded[:, 1:-1] = rows_mask
    d = np.diff(padded.ravel())  # row-major: a run never spans two rows (the padding)
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)  # flat, in padded rows
    out = np.zeros(h * (w + 2), bool)
    if starts.size:
        # Bridge: a run joins the previous one in its row when the gap is small.
        joins = (starts[1:] - ends[:-1] <= gap) & (starts[1:] // (w + 2) == ends[:-1] // (w + 2))
        first = np.concatenate([[True], ~joins])
        last = np.concatenate([~joins, [True]])
        g_start, g_end = starts[first], ends[last]
        keep = (g_end - g_start) >= min_len
        g_start, g_end = g_start[keep], g_end[keep]
        if g_start.size:
            lengths = g_end - g_start
            base = np.repeat(g_start - np.cumsum(lengths) + lengths, lengths)
            out[base + np.arange(int(lengths.sum()))] = True
    return out.reshape(h, w + 2)[:, :w]


def _sheared(mask: np.ndarray, off: np.ndarray) -> np.ndarray:
    """``mask`` in the sheared frame of :func:`_shear_rows`: ``[H + max(off), W]``."""
    out = np.zeros((mask.shape[0] + int(off.max()), mask.shape[1]), bool)
    rr, cc = np.nonzero(mask)
    out[rr + off[cc], cc] = True
    return out


def _unsheared(sheared: np.ndarray, off: np.ndarray, height: int) -> np.ndarray:
    out = np.zeros((height, sheared.shape[1]), bool)
    rr, cc = np.nonzero(sheared)
    out[rr - off[cc], cc] = True
    return out


def _bands(rows: np.ndarray) -> list[tuple[int, int]]:
    """``(first, end)`` of every run of True in the 1-D ``rows``."""
    d = np.diff(np.concatenate([[0], rows.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def _evenly_spaced(centres: list[float]) -> bool:
    """At least three centres whose consecutive spacings agree within 15 % (ruled and
    squared paper: a missing or extra rule aside)."""
    if len(centres) < 3:
        return False
    gaps = np.diff(np.sort(centres))
    med = float(np.median(gaps))
    return med > 0 and float(np.median(np.abs(gaps - med))) <= 0.15 * med


def _spans_short_of_ends(mask: np.ndarray, extent: tuple[int, int]) -> bool:
    """Whether the pixels of ``mask`` [H', W] (but the outermost 0.5 % either way) keep
    clear of both ends of the columns ``extent`` (what a character crossed by a rule
    does, and a tight crop's stroke not)."""
    counts = mask.sum(axis=0)
    if not counts.any():
        return False
    cum = np.cumsum(counts) / counts.sum()  # a speck near an end does not count
    first, last = int(np.searchsorted(cum, 0.005)), int(np.searchsorted(cum, 0.995))
    margin = max(2, round(0.02 * (extent[1] - extent[0])))
    return bool(first >= extent[0] + margin and last < extent[1] - margin)


def _row_rules(mask: np.ndarray, extent: tuple[int, int], angle_deg: float, others=None,
               pen_width_px: float = 0.0, lone: bool = False):  # fmt: skip
    """Pixels of ``mask`` on rules along the rows at ``angle_deg`` (see the module
    docstring, step 5; ``bool [H, W]``), crossings not yet restored, and the rules'
    thickness (rows of the widest band, with two rows of slack either side). ``others``:
    rules already found across these (not ink that could reach the ends). A lone rule of
    an image at least ``PAGE_LINE_PENS`` pen widths across is a rule whatever the other
    ink does: no character's stroke is that long. ``lone``: only rules across
    ``RULE_SHARE`` of the extent (a second angle's single line, not a periodic set)."""
    off = _shear_rows(mask.shape, angle_deg)
    s = _sheared(mask, off)
    d = s.copy()  # two rows either side: a slightly wavy rule stays one run
    for k in (1, 2):
        d[k:] |= s[:-k]
        d[:-k] |= s[k:]
    width = extent[1] - extent[0]
    if lone:
        fresh = s & ~_sheared(others, off) if others is not None else s
        rule, reach = _lone_rule(s, d, fresh, width)
        page = pen_width_px > 0 and width >= PAGE_LINE_PENS * pen_width_px
        if not reach or not (page or _spans_short_of_ends(s & ~rule, extent)):
            return np.zeros(mask.shape, bool), 0
        return _unsheared(rule, off, mask.shape[0]), reach
    runs = _long_runs(d, max(8, math.ceil(PERIODIC_RULE_SHARE * width)), gap=3)
    full = _long_runs(d, max(8, math.ceil(RULE_SHARE * width)), gap=3)
    bands = _bands(runs.any(axis=1))
    if not bands:
        return np.zeros(mask.shape, bool), 0
    periodic = _evenly_spaced([(a + b) / 2 for a, b in bands])
    chosen = np.zeros(d.shape[0], bool)
    for a, b in bands:
        if periodic or full[a:b].any():
            chosen[a:b] = True
    rule = s & runs & chosen[:, None]
    rest = s & ~rule if others is None else s & ~rule & ~_sheared(others, off)
    page = pen_width_px > 0 and width >= PAGE_LINE_PENS * pen_width_px  # no tight crop
    if not periodic and not page and not _spans_short_of_ends(rest, extent):
        return np.zeros(mask.shape, bool), 0  # a tight crop's own stroke, not a rule
    return _unsheared(rule, off, mask.shape[0]), max(b - a for a, b in bands)


def _lone_rule(s: np.ndarray, d: np.ndarray, fresh: np.ndarray, width: int):
    """The pixels of ``s`` (sheared frame) on single lines across ``RULE_SHARE`` of the
    extent that may break up (gaps up to ``LONE_GAP`` of it bridged, ``LONE_INKED`` of it
    inked, ``LONE_INKED`` / 2 of it ``fresh``: on no rule found before), ``d``: ``s``
    grown two rows either way; and the lines' thickness (0: none)."""
    runs = _long_runs(
        d, max(8, math.ceil(RULE_SHARE * width)), gap=max(3, math.ceil(LONE_GAP * width))
    )
    rule, reach = np.zeros(s.shape, bool), 0
    for a, b in _bands(runs.any(axis=1)):
        span = runs[a:b].any(axis=0)
        if np.count_nonzero(d[a:b].any(axis=0) & span) < LONE_INKED * width:
            continue
        lo, hi = max(0, a - 2), b + 2
        if np.count_nonzero(fresh[lo:hi].any(axis=0) & span) < 0.5 * LONE_INKED * width:
            continue  # a rule found before, at an angle a little off
        cols = np.flatnonzero(span)
        c0, c1 = cols[0], cols[-1] + 1  # two rows either way: the line wavers
        rule[lo:hi, c0:c1] |= s[lo:hi, c0:c1]
        reach = max(reach, hi - lo)
    return rule, reach


def _crossings(strokes: np.ndarray, rule: np.ndarray, reach: int) -> np.ndarray:
    """Rule pixels with stroke pixels within ``reach`` rows above and below them (in the
    same column or the next): where a pen stroke crosses the rule."""
    near = strokes.copy()
    near[:, 1:] |= strokes[:, :-1]
    near[:, :-1] |= strokes[:, 1:]
    above = np.zeros_like(near)
    below = np.zeros_like(near)
    for k in range(1, reach + 1):
        above[k:] |= near[:-k]
        below[:-k] |= near[k:]
    return rule & above & below


def _bridges(strokes: np.ndarray, removed: np.ndarray, rule: np.ndarray,
             pen_width_px: float) -> np.ndarray:  # fmt: skip
    """Pixels of ``removed`` (everything taken for lines) on the rules ``rule`` between two
    places at most ``BRIDGE_SPACING`` of the rules' spacing apart along them where pieces
    of ``strokes`` at least ``BRIDGE_TALL_PENS`` pen widths tall touch them (all in the
    sheared frame of :func:`_shear_rows`, rows along the rules): a stroke that ran along
    the rule and left it again. Nothing for fewer than three rules (no spacing)."""
    from scipy.ndimage import find_objects, label

    centres = [(a + b) / 2 for a, b in _bands(rule.any(axis=1))]
    if len(centres) < 3 or pen_width_px <= 0:
        return np.zeros(rule.shape, bool)
    length = BRIDGE_SPACING * float(np.median(np.diff(centres)))
    labels, n = label(strokes, structure=np.ones((3, 3), bool))
    tall = np.zeros(n + 1, bool)
    for i, sl in enumerate(find_objects(labels)):
        tall[i + 1] = sl[0].stop - sl[0].start >= BRIDGE_TALL_PENS * pen_width_px
    near = dilate3(tall[labels] & strokes)
    for _ in range(2):  # through a line two rows thicker than the pen (its pieces grown)
        near = dilate3(near)
    line = removed.copy()  # one row either way: a wavering line stays one run along a row
    line[1:] |= removed[:-1]
    line[:-1] |= removed[1:]
    h, w = line.shape
    flat = np.zeros((h, w + 2), bool)  # a padding column: no run spans two rows
    flat[:, 1:-1] = line
    touch = np.zeros((h, w + 2), bool)
    touch[:, 1:-1] = line & near
    flat, touch = flat.ravel(), touch.ravel()
    run = np.cumsum(np.diff(np.concatenate([[False], flat]).astype(np.int8)) == 1)
    idx = np.arange(flat.size)
    last = np.maximum.accumulate(np.where(touch, idx, -1))  # the touch before, and after
    nxt = np.minimum.accumulate(np.where(touch, idx, flat.size)[::-1])[::-1]
    ok = flat & (last >= 0) & (nxt < flat.size)
    ok[ok] &= (run[last[ok]] == run[idx[ok]]) & (run[nxt[ok]] == run[idx[ok]])
    ok[ok] &= nxt[ok] - last[ok] <= length
    fill = ok.reshape(h, w + 2)[:, 1:-1]
    fill &= ~_long_runs(fill, math.floor(BRIDGE_CHAIN * length) + 1, gap=0)
    grown = fill.copy()  # the line's thickness in those columns (two rows either way,
    for k in (1, 2):  # as the rules were found)
        grown[k:] |= fill[:-k]
        grown[:-k] |= fill[k:]
    return removed & grown


def _rule_pieces(rest: np.ndarray, rule: np.ndarray, reach: int) -> np.ndarray:
    """The marks of ``rest`` that touch ``rule`` and continue it: at least three times as
    long along the rows as across, and no thicker than the rules (where a slightly bent
    rule left the one angle's straight band)."""
    from scipy.ndimage import find_objects, label

    labels, _ = label(rest, structure=np.ones((3, 3), bool))
    touching = np.unique(labels[dilate3(rule) & (labels > 0)])
    out = np.zeros(rest.shape, bool)
    objects = find_objects(labels)
    for lab in touching:
        sl = objects[lab - 1]
        h, w = sl[0].stop - sl[0].start, sl[1].stop - sl[1].start
        if w >= 3 * h and h <= reach + 2:
            out[sl] |= labels[sl] == lab
    return out


def rules(mask: np.ndarray, sheet: np.ndarray, dark: np.ndarray | None = None,
          pen_width_px: float = 0.0, channels: np.ndarray | None = None,
          sheet_deg: float = 0.0) -> tuple[np.ndarray, dict]:  # fmt: skip
    """Pixels of ``mask`` on ruled or squared paper's lines (both directions), and the
    angles found (``{"rows_deg", "columns_deg"}``): within ``MAX_RULE_ANGLE_DEG`` of the
    sheet's sides, ``sheet_deg`` (a sheet found on a desk lying askew,
    :attr:`img2dmp.data.sheet.Sheet.angle_deg`) from the rows and columns.

    Per direction, two passes: the rules at the direction's dominant angle, then a lone
    line across the whole extent that they left (broken up, as a faint margin line, or at
    an angle of its own, the page's perspective).

    A rule pixel stays ink where a stroke crosses the rule: stroke pixels (ink on no rule
    of either direction, so that squared paper's own crossings are not strokes) lie just
    before and just after it across the rule, or (given the darkness ``dark``) it is
    darker than its own set of lines by more than half the way to the strokes' ink:
    where rules of both directions meet also darker than two lines crossing, elsewhere
    joined to a stroke through such pixels (a stroke run along the rule)."""
    found, per_axis, angles = np.zeros(mask.shape, bool), [], {}
    for axis, name in ((0, "rows_deg"), (1, "columns_deg")):

        def along(a, axis=axis):  # rows of this direction
            return a if axis == 0 else a.T

        m, sh = along(mask), along(sheet)
        cols = np.flatnonzero(sh.any(axis=0))
        if cols.size < 8:
            continue
        extent = (int(cols[0]), int(cols[-1]) + 1)
        centre = sheet_deg if axis == 0 else -sheet_deg  # the columns' angle, transposed
        angles[name] = dominant_angle(m, centre_deg=centre)
        r, reach = _row_rules(m, extent, angles[name], along(found), pen_width_px)
        if reach:
            per_axis.append((axis, angles[name], r, reach))
            found |= along(r)
        rest = m & ~along(found)
        second = dominant_angle(rest, centre_deg=centre)
        r, reach = _row_rules(m, extent, second, along(found), pen_width_px, lone=True)
        r &= rest
        if reach and r.any():
            per_axis.append((axis, second, r, reach))
            found |= along(r)
    lines = [np.zeros(mask.shape, bool), np.zeros(mask.shape, bool)]  # each direction's
    for axis, _, r, reach in per_axis:
        grown = _rule_pieces((mask if axis == 0 else mask.T) & ~(found if axis == 0 else found.T),
                             r, reach)  # fmt: skip
        found |= grown if axis == 0 else grown.T
        lines[axis] |= (r | grown) if axis == 0 else (r | grown).T
    strokes = mask & ~found
    keep = np.zeros(mask.shape, bool)
    ink_level = None
    if dark is not None and found.any() and strokes.any():
        ink_level = float(np.percentile(dark[strokes], 90))
    for axis, angle, r, reach in per_axis:
        st = strokes if axis == 0 else strokes.T
        off = _shear_rows(st.shape, angle)
        s_st, s_r = _sheared(st, off), _sheared(r, off)
        cross = _crossings(s_st, s_r, reach)
        lighter = (
            ink_level is not None
            and r.any()
            and ink_level - float(np.median(dark[r if axis == 0 else r.T])) > 0.15
        )  # lighter rules keep a stroke's pixels by their darkness (below)
        if not lighter:
            removed = _sheared(found if axis == 0 else found.T, off)
            cross |= _bridges(s_st, removed, s_r, pen_width_px)
        cross = _unsheared(cross, off, st.shape[0])
        keep |= cross if axis == 0 else cross.T
    if ink_level is not None:
        keep |= _kept_by_darkness(found, per_axis, dark, strokes, keep, ink_level)
        keep |= _darker_than_lines(found, per_axis, dark, strokes, keep, ink_level, channels,
                                   lines)  # fmt: skip
    return found & ~keep, angles


def _line_level(dark: np.ndarray, rule: np.ndarray, angle_deg: float,
                where: np.ndarray | None = None, at: np.ndarray | None = None,
                ) -> np.ndarray:  # fmt: skip
    """The darkness ``[H, W]`` that the lines ``rule`` along the rows at ``angle_deg``
    give every pixel: per row of the sheared frame (:func:`_shear_rows`), the median of
    ``dark`` over stretches of ``LINE_LEVEL_SHARE`` of the width (a line's level where it
    is, the paper's beside it; a stroke running along a line for less than half a
    stretch does not move it), each line's band taken straightened along the line first
    (:func:`_line_middle`: a wavy line stays in its rows). ``dark`` may be a stack
    ``[K, H, W]`` (each channel's darkness; the result ``[K, H, W]``): the line is then
    followed by the first's. Given ``where`` (``bool [H, W]``), only the rows of the
    sheared frame that hold its pixels are read (0 elsewhere); given ``at`` (flat pixel
    indices ``[n]``), the level of those pixels only, ``[n]`` (``[K, n]``)."""
    stack = dark if dark.ndim == 3 else dark[None]
    k, h, w = stack.shape
    off = _shear_rows((h, w), angle_deg)
    cols = np.broadcast_to(np.arange(w)[None, :], (h, w))
    # every pixel's place in the sheared frame, flat (one index for all the channels)
    flat = ((np.arange(h)[:, None] + off[None, :]) * w + cols).ravel()
    s = np.zeros((k, (h + int(off.max())) * w), np.float32)
    s[:, flat] = stack.reshape(k, -1)
    s = s.reshape(k, -1, w)
    sr = _sheared(rule, off)
    block = max(16, math.ceil(LINE_LEVEL_SHARE * w))
    n = math.ceil(w / block)
    pad = n * block - w

    def medians(a: np.ndarray) -> np.ndarray:  # [K, R, W] -> per row and stretch
        padded = np.pad(a, ((0, 0), (0, 0), (0, pad)), mode="reflect" if pad < w else "edge")
        med = np.median(padded.reshape(k, a.shape[1], n, block), axis=3)  # [K, R, n]
        return np.repeat(med, block, axis=2)[..., :w]

    level = np.zeros(s.shape, np.float32)
    bands = [(a, b, _line_middle(s[0, a:b], sr[a:b], block)) for a, b in _bands(sr.any(axis=1))]
    read = np.zeros(s.shape[1], bool)  # the rows read as they lie
    if where is None:
        read[:] = True
    else:
        read[np.flatnonzero(_sheared(where, off).any(axis=1))] = True
        for a, b, shift in bands:  # a straight band (no shift) reads its rows as they lie
            if shift is not None and not shift.any():
                read[max(0, a - 2) : b + 2] = True
    level[:, read] = medians(s[:, read])
    moved = np.zeros(s.shape[1], bool)  # rows a moved band wrote into
    for a, b, shift in bands:
        if shift is None:
            continue
        if not shift.any():  # its rows as read above, unless a moved band wrote there
            lo, hi = max(0, a - 2), b + 2
            if moved[lo:hi].any():
                level[:, lo:hi] = medians(s[:, lo:hi])
            continue
        # the band and its two rows of slack, each column moved by the line's shift
        src = np.arange(a - 2, b + 2)[:, None] + shift[None, :]  # [R, W]
        inside = (src >= 0) & (src < s.shape[1])
        src = np.clip(src, 0, s.shape[1] - 1)
        places = src * w + cols[: src.shape[0]]  # flat, in the sheared frame
        straight = medians(s.reshape(k, -1)[:, places])
        level.reshape(k, -1)[:, places[inside]] = straight[:, inside]
        moved[src[inside]] = True
    if at is not None:
        out = level.reshape(k, -1)[:, flat[at]]
    else:
        out = level.reshape(k, -1)[:, flat].reshape(k, h, w)
    return out if dark.ndim == 3 else out[0]


def _line_middle(dark: np.ndarray, rule: np.ndarray, stretch: int) -> np.ndarray | None:
    """How far (rows, ``int [W]``) the middle of the line ``rule`` (``bool [R, W]``, one
    band of the sheared frame) lies from its usual row in every column: the mean row of
    its pixels weighted by ``dark``, interpolated where it has none, and the median of
    that over ``stretch`` columns (a stroke crossing it, or running along it for less
    than half of that, does not move it). None for a band with too few columns of line."""
    from scipy.ndimage import median_filter

    weight = np.where(rule, dark, 0.0)
    total = weight.sum(axis=0)
    have = np.flatnonzero(total > 0)
    if have.size < 8:
        return None
    middle = (weight[:, have] * np.arange(len(rule))[:, None]).sum(axis=0) / total[have]
    middle = np.interp(np.arange(rule.shape[1]), have, middle)
    middle = median_filter(middle, size=max(9, stretch) | 1, mode="nearest")
    # whole rows, and none for less than 0.75 of one: a straight line turned a little
    # lies half a row up or down by turns in the sheared frame, which straight rows read
    # as well as any, and rounding it row by row mixed its edge with the paper beside it
    drift = middle - np.median(middle)
    return np.fix(drift + 0.25 * np.sign(drift)).astype(np.int64)


def _darker_than_lines(found, per_axis, dark, strokes, keep, ink_level: float,
                       channels=None, lines=None) -> np.ndarray:  # fmt: skip
    """The pixels of the lines ``found`` that are ink over a line: darker by
    ``LINE_INK_SHARE`` of the pen's ``ink_level`` than the lines of both directions
    (:func:`_line_level`, combined as light passing through both) make them, and joined
    to ``strokes`` or to the pixels ``keep`` kept so far through such pixels. A stroke
    that runs along a rule and leaves it (a 7's bar on the line, a 1 along a squared
    paper's column) is ink printed lines lie under: as dark as ink where it covers the
    line, and beside the line (the two rows of slack a rule is taken with) as dark as
    itself."""
    from scipy.ndimage import binary_propagation

    # each channel alone: in a colour the lines let through (red through a red margin)
    # a stroke over them stands out though in its darkest channel it is no darker than
    # the lines by that much (a blue pen as dark as the margin). The darkest channel's
    # own test adds nothing: its level is at least that of the channel it takes there
    stack = dark[None] if channels is None or len(channels) < 2 else channels  # [K, H, W]
    on = np.flatnonzero(found)  # the lines' pixels, flat: only they are asked
    h, w = found.shape
    clear = np.ones((len(stack), on.size), np.float32)  # the light the lines let through
    for axis in (0, 1):
        angles = {angle for a, angle, _, _ in per_axis if a == axis}
        for angle in angles:
            rule = np.zeros(dark.shape if axis == 0 else dark.T.shape, bool)
            for a, an, r, _ in per_axis:  # the passes at this angle: their lines
                if a == axis and an == angle:
                    rule |= r
            tr = (lambda x: x) if axis == 0 else (lambda x: np.swapaxes(x, -1, -2))
            where = found if lines is None else lines[axis]  # no level where none lie
            at = on if axis == 0 else (on % w) * h + on // w  # [n] in its frame
            lv = _line_level(tr(stack), rule, angle, where=tr(where), at=at)
            clear *= 1.0 - np.clip(lv, 0.0, 1.0)
    darker = np.zeros(found.shape, bool)
    ink = stack.reshape(len(stack), -1)[:, on] > 1.0 - clear + LINE_INK_SHARE * ink_level
    darker.ravel()[on] = ink.any(axis=0)
    joined = binary_propagation(darker & dilate3(strokes | keep), mask=darker)
    return darker & joined


def _kept_by_darkness(found, per_axis, dark, strokes, keep, ink_level: float) -> np.ndarray:
    """The pixels of the lines ``found`` (the passes ``per_axis`` of :func:`rules`) that
    stay ink by their darkness ``dark``: on rules clearly lighter than the pen's
    ``ink_level``, darker than their own set of lines by half the way to the pen (where
    rules of both directions meet also darker than two lines crossing; elsewhere joined
    to ``strokes`` or to the pixels ``keep`` kept so far through such pixels)."""
    from scipy.ndimage import binary_propagation

    keep = keep.copy()
    passes = [r if axis == 0 else r.T for axis, _, r, _ in per_axis]
    pieces = found.copy()  # grown pieces: against all the rules' level
    for r in passes:
        pieces &= ~r
    # where rules of both directions meet (squared paper's crossings, a margin line
    # across the rules), and only there, two lines absorb as two
    by_axis = [np.zeros(found.shape, bool), np.zeros(found.shape, bool)]
    for (axis, _, _, _), r in zip(per_axis, passes, strict=True):
        by_axis[axis] |= r
    meet = dilate3(dilate3(by_axis[0])) & dilate3(dilate3(by_axis[1]))
    for pixels, level_of in [(p, p) for p in passes] + [(pieces, found)]:
        # each set of lines against its own level (a dark red margin line is not
        # where a stroke crosses the pale blue rules)
        if not pixels.any():
            continue
        level = float(np.median(dark[level_of]))
        if ink_level - level > 0.15:  # rules clearly lighter than the pen
            stroke = dark > level + 0.5 * (ink_level - level)
            # where two rules cross they absorb as two (1 - (1 - l)^2): no stroke
            crossing = dark > 1.0 - (1.0 - level) ** 2 + 0.05
            keep |= pixels & stroke & crossing
            # elsewhere a stroke's own level, on the pixels that join a stroke
            # (a stroke along a rule; not a dark grain that a line was found in)
            along = pixels & stroke & ~meet
            joined = binary_propagation(along & dilate3(strokes | keep), mask=dilate3(along))
            keep |= along & joined
    return keep


@dataclass
class _Levels:
    """The darkness thresholds of one image: ``weak`` (a pixel may be ink), ``strong``
    (a component holding such pixels is ink) and ``ink`` (typical ink, scaled to 1)."""

    weak: float
    strong: float
    ink: float


def thresholds(dark: np.ndarray, noise: float, exclude=None) -> _Levels | None:
    """The image's :class:`_Levels`, or None when nothing stands out from the paper's
    noise (no ink); ``exclude`` (``bool [H, W]``): pixels that are not the pen's (rules)."""
    floor = max(0.08, 4.0 * noise)
    candidates = dark[(dark > floor) & ~exclude] if exclude is not None else dark[dark > floor]
    if candidates.size < 4:
        return None
    ink = float(np.percentile(candidates, 90))
    weak = max(0.06, 3.0 * noise, 0.2 * ink)
    strong = max(0.15, 5.0 * noise, 0.5 * ink)
    if ink < strong:
        return None
    return _Levels(weak=weak, strong=strong, ink=ink)


def _border_marks(weak: np.ndarray) -> np.ndarray:
    """The pixels of the marks of ``weak`` that lie along the image's border
    (:func:`_along_border`: the sheet's edge, the desk beyond it) within its band
    (``EDGE_BAND``), which set no level of the pen's: on a page photographed from far
    away the edge stays as dark as it was while the pen's strokes, a pixel wide or less,
    grow faint, and the page's ink level, read with the edge, would leave every stroke
    below the strong level. Only the band: a page's writing joined to the border (by
    rules not removed) keeps its level."""
    from scipy.ndimage import label

    labels, n = label(weak, structure=np.ones((3, 3), bool))
    edge = _along_border(labels, n)
    edge[0] = False
    h, w = weak.shape
    m = max(2, round(EDGE_BAND * min(h, w)))
    band = np.zeros((h, w), bool)
    band[:m], band[-m:], band[:, :m], band[:, -m:] = True, True, True, True
    return edge[labels] & band


def dilate3(mask: np.ndarray) -> np.ndarray:
    """``mask`` grown by one pixel in all eight directions (a 3 x 3 dilation by slicing:
    several times faster than a general structuring element)."""
    rows = mask.copy()
    rows[1:] |= mask[:-1]
    rows[:-1] |= mask[1:]
    out = rows.copy()
    out[:, 1:] |= rows[:, :-1]
    out[:, :-1] |= rows[:, 1:]
    return out


def _erode3(mask: np.ndarray) -> np.ndarray:
    """``mask`` shrunk by one pixel in all eight directions (outside the image: empty)."""
    return ~dilate3(~np.pad(mask, 1))[1:-1, 1:-1]


def _components(mask: np.ndarray, dark: np.ndarray, strong: float):
    """Labels of the 8-connected components of ``mask``, and per label (index 0 unused)
    its area, boundary pixels and strong pixels."""
    from scipy.ndimage import label

    labels, n = label(mask, structure=np.ones((3, 3), bool))
    flat = labels.ravel()
    area = np.bincount(flat, minlength=n + 1)
    inner = _erode3(mask)
    boundary = np.bincount(flat[(mask & ~inner).ravel()], minlength=n + 1)
    strong_px = np.bincount(flat[(dark >= strong).ravel() & (flat > 0)], minlength=n + 1)
    return labels, area, boundary, strong_px


def pen_width(area: np.ndarray, boundary: np.ndarray, keep: np.ndarray) -> float:
    """Typical stroke width of the kept components: ``2 area / boundary`` (a stroke of
    width t and length L has area t L and about 2 L boundary pixels), the median over
    their length (so long strokes count more than specks, and a thick blob no more than
    its outline's half)."""
    idx = np.flatnonzero(keep)
    if idx.size == 0:
        return 0.0
    thick = 2.0 * area[idx] / np.maximum(boundary[idx], 1)
    order = np.argsort(thick)
    cum = np.cumsum(boundary[idx][order])
    return float(thick[order][np.searchsorted(cum, cum[-1] / 2.0)])


def _kept_strokes(mask, dark, lv: _Levels, shape_filters: bool, rough_pen: float = 0.0, ruled=None,
                  band=None):  # fmt: skip
    """The components of ``mask`` that are pen strokes (hysteresis; with
    ``shape_filters`` also not the sheet's edge, specks nor blobs), the pen width and
    what was dropped. ``rough_pen``: the pen width guessed before (pixels), for the
    pieces of faint components (``RESCUE_*``); ``ruled``: the rules' pixels removed
    (their remnants beside them are no pen dots); ``band``: the pixels beside the desk
    (:attr:`img2dmp.data.sheet.Sheet.band`), where long marks are the sheet's edge."""
    labels, area, boundary, strong_px = _components(mask, dark, lv.strong)
    keep = (strong_px >= 2) & (strong_px >= STRONG_SHARE * area)  # a stroke, not a smudge
    keep[0] = False
    removed = {"faint_components": int(np.count_nonzero(~keep[1:]))}
    faint = ~keep & (strong_px >= 2)
    faint[0] = False
    if shape_filters and faint.any():
        # strokes joined to faint lines (a rule's remnant, a shadow's band): the faint
        # component again at a level half way to the strong one, its pieces each tried
        mid = 0.5 * (lv.weak + lv.strong)
        faint_px = faint[labels]
        again = keep[labels] | (faint_px & (dark >= mid))
        labels, area, boundary, strong_px = _components(again, dark, lv.strong)
        was_faint = np.bincount(labels.ravel(), weights=faint_px.ravel(), minlength=len(area)) > 0
        keep = (strong_px >= 2) & (strong_px >= STRONG_SHARE * area)
        # a pen's piece is more than a remnant's specks
        keep &= ~was_faint | (area >= RESCUE_AREA_PEN2 * max(rough_pen, 1.0) ** 2)
        keep[0] = False
        removed["faint_components"] -= int(np.count_nonzero(keep & was_faint))
    if shape_filters:
        edge = keep & (_along_border(labels, len(area) - 1, ruled)
                       | _edge_lines(labels, band, ruled))  # fmt: skip
        if np.count_nonzero(keep & ~edge):  # the edge first: its band is no pen width
            keep &= ~edge
            removed["edge_components"] = int(edge.sum())
    width = pen_width(area, boundary, keep)
    if shape_filters and width > 0:
        thick = 2.0 * area / np.maximum(boundary, 1)
        speck = keep & (area < max(SPECK_AREA_PEN2 * width**2, MIN_STROKE_AREA_PX))
        beside = np.zeros(len(area), bool)  # what a rule's removal left of it
        if ruled is not None and ruled.any():
            beside[np.unique(labels[dilate3(ruled)])] = True
        speck &= ~_pen_dots(
            labels, area, boundary, strong_px, speck & ~beside, keep & ~speck, width
        )
        keep &= ~speck  # a page of specks alone holds no ink
        removed["specks"] = int(speck.sum())
        dots = _dot_lattice(labels, area, boundary, keep, width)
        keep &= ~dots
        removed["dots"] = int(dots.sum())
        # thick and faint: a shadow's band (a thick pen is as dark as a thin one)
        level = _component_medians(labels, dark, len(area) - 1)
        blob = keep & (thick > THICK_FACTOR * width) & (level < 0.6 * lv.ink)
        if np.count_nonzero(keep & ~blob):  # the only strokes are strokes
            removed["thick_components"] = int(blob.sum())
            keep &= ~blob
        width = pen_width(area, boundary, keep)
    return keep[labels], width, removed


def _pen_dots(labels, area, boundary, strong_px, speck, strokes, width: float) -> np.ndarray:
    """Per label: the ``speck`` components that are a pen's dots (an i's, a diacritic),
    not the paper's specks. A dot is about a pen width across (``DOT_AREA_PEN2`` pen
    widths squared and ``DOT_MIN_PX`` pixels at least, ``DOT_SIDE_PEN`` to
    ``DOT_SIZE_PEN`` pen widths on both sides of its box), as dark as the pen (a
    ``DOT_STRONG_SHARE`` of it strong) and near a stroke (within ``DOT_NEAR_SHARE`` of
    the longer side of one of the ``strokes``' boxes and ``DOT_NEAR_PEN`` pen widths
    of it); dust, grain and salt-and-pepper noise are smaller, text from the back
    fainter, a rule's remnant thinner (and beside the rule's removed pixels: not in
    ``speck``), and the dots of dotted paper lie on a lattice (:func:`_dot_lattice`,
    over all such marks)."""
    from scipy.ndimage import find_objects

    out = np.zeros(len(area), bool)
    if not strokes.any():
        return out
    boxes = np.zeros((len(area), 4))
    for lab, sl in enumerate(find_objects(labels), start=1):
        if sl is not None:
            boxes[lab] = sl[0].start, sl[1].start, sl[0].stop, sl[1].stop
    sides = np.stack([boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]], -1)
    dot = speck & (area >= max(DOT_AREA_PEN2 * width**2, DOT_MIN_PX))
    dot &= (sides.min(1) >= DOT_SIDE_PEN * width) & (sides.max(1) <= DOT_SIZE_PEN * width)
    dot &= strong_px >= DOT_STRONG_SHARE * area
    if dot.any():
        dot &= ~_dot_lattice(labels, area, boundary, dot | strokes, width)
    cand, near = np.flatnonzero(dot), np.flatnonzero(strokes)
    reach = np.minimum(DOT_NEAR_SHARE * sides[near].max(1), DOT_NEAR_PEN * width)
    for k in range(0, len(cand), 512):  # candidates x strokes, in slices
        b = boxes[cand[k : k + 512], None]
        gap_r = np.maximum(boxes[None, near, 0] - b[..., 2], b[..., 0] - boxes[None, near, 2])
        gap_c = np.maximum(boxes[None, near, 1] - b[..., 3], b[..., 1] - boxes[None, near, 3])
        gap = np.hypot(np.maximum(gap_r, 0), np.maximum(gap_c, 0))
        out[cand[k : k + 512]] = (gap <= reach[None]).any(1)
    return out


def _component_medians(labels: np.ndarray, dark: np.ndarray, n: int) -> np.ndarray:
    """Per label (index 0: the background): the median darkness of its pixels."""
    flat = labels.ravel()
    inside = flat > 0
    lab, val = flat[inside], dark.ravel()[inside]
    order = np.lexsort((val, lab))
    lab, val = lab[order], val[order]
    starts = np.searchsorted(lab, np.arange(n + 1))
    ends = np.searchsorted(lab, np.arange(n + 1), side="right")
    mid = np.minimum((starts + ends) // 2, max(len(val) - 1, 0))
    return np.where(ends > starts, val[mid] if len(val) else 0.0, 0.0)


def _dot_lattice(labels, area, boundary, keep, width: float):
    """Per label: the dots of dotted paper. Small marks (at most ``DOT_SIZE_PEN`` pen
    widths across, or filled discs: at most ``DOT_DISC`` times their own thickness
    across) are dots when at least ``MIN_DOTS`` of them sit at an even spacing (their
    nearest neighbours' distances agree within 25 %): a pen's own dots are few and
    scattered, a printed pattern's many and regular."""
    from scipy.ndimage import find_objects

    thick = 2.0 * area / np.maximum(boundary, 1)
    small = np.zeros(len(area), bool)
    for lab, sl in enumerate(find_objects(labels), start=1):
        if sl is not None and keep[lab]:
            size = max(sl[0].stop - sl[0].start, sl[1].stop - sl[1].start)
            # a dot: about as wide as the pen, or a filled disc of any size
            small[lab] = size <= DOT_SIZE_PEN * max(width, 1.0) or size <= DOT_DISC * thick[lab]
    idx = np.flatnonzero(small)
    if idx.size < MIN_DOTS:
        return np.zeros(len(area), bool)
    rows, cols = np.nonzero(np.isin(labels, idx))
    lab = labels[rows, cols]
    n = np.bincount(lab, minlength=len(area))[idx]
    centres = np.stack([np.bincount(lab, rows, len(area))[idx] / n,
                        np.bincount(lab, cols, len(area))[idx] / n], -1)  # fmt: skip
    even = on_lattice(centres)
    if np.count_nonzero(even) < MIN_DOTS:
        return np.zeros(len(area), bool)
    out = np.zeros(len(area), bool)
    out[idx[even]] = True
    return out


def on_lattice(centres: np.ndarray) -> np.ndarray:
    """Which of the points ``[n, 2]`` sit on one square lattice (dotted paper's): its
    spacing is the usual distance to the nearest point, its axes the median direction
    of those nearest steps (folded into 90 degrees); a point is on it when most of its
    neighbours within four spacings (two at least) lie a whole number of spacings away
    along both axes (within 0.2), as a printed pattern's dots do, holes and all, and a
    pen's dots near them do not. The spacing is the lower quartile of the nearest
    distances, for the holes of a lattice whose faint dots were dropped."""
    from scipy.spatial import cKDTree

    tree = cKDTree(centres)
    dist, near = tree.query(centres, k=2)
    spacing = float(np.percentile(dist[:, 1], 25))  # holes lengthen the others' steps
    if spacing <= 0:
        return np.zeros(len(centres), bool)
    step = centres[near[:, 1]] - centres
    close = np.abs(dist[:, 1] - spacing) <= 0.25 * spacing
    angles = np.arctan2(step[close, 0], step[close, 1])  # of (row, col) steps
    theta = float(np.median((angles + np.pi / 4) % (np.pi / 2) - np.pi / 4)) if close.any() else 0.0
    c, s_ = math.cos(theta), math.sin(theta)
    turned = centres @ np.array([[c, s_], [-s_, c]]) / spacing  # lattice units, axes aligned
    pairs = tree.query_pairs(4.2 * spacing, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros(len(centres), bool)
    off = turned[pairs[:, 1]] - turned[pairs[:, 0]]
    whole = np.all(np.abs(off - np.round(off)) <= 0.2, axis=1)
    total = np.bincount(pairs.ravel(), minlength=len(centres))
    good = np.bincount(pairs[whole].ravel(), minlength=len(centres))
    return (good >= 2) & (good >= 0.5 * total)


def _along_border(labels: np.ndarray, n: int, ruled=None) -> np.ndarray:
    """Per label (index 0 unused): whether the component touches one of the image's
    borders along at least ``EDGE_SHARE`` of that side (the sheet's edge, the table).
    With ``ruled`` (the rules' pixels removed, ``bool [H, W]``) the marks joined through
    the rules' pixels beside the border count as one: the sheet's edge that the rules
    cut into pieces (the marks' own pixels, not the rules', must touch the border along
    that share)."""
    from scipy.ndimage import label

    out = np.zeros(n + 1, bool)
    h, w = labels.shape
    m = max(2, round(EDGE_BAND * min(h, w)))  # the edge may stop short of the border
    near = np.zeros((h, w), bool)
    near[:m], near[-m:], near[:, :m], near[:, -m:] = True, True, True, True
    joined = labels
    if ruled is not None and (ruled & near).any():
        joined, _ = label((labels > 0) | (ruled & near), structure=np.ones((3, 3), bool))
    sides = ((np.s_[:m], 0, w), (np.s_[-m:], 0, w), (np.s_[:, :m], 1, h), (np.s_[:, -m:], 1, h))
    for where, axis, side in sides:
        marks = np.where(labels[where] > 0, joined[where], 0).max(axis)  # per column (row)
        count = np.bincount(marks[marks > 0], minlength=int(joined.max()) + 1)
        edge = np.flatnonzero(count >= EDGE_SHARE * side)
        if edge.size:
            band = labels[where]
            out[np.unique(band[np.isin(joined[where], edge) & (band > 0)])] = True
    return out


def _edge_lines(labels: np.ndarray, band=None, ruled=None) -> np.ndarray:
    """Per label (index 0 unused): whether the component is a line of the sheet's edge
    (``EDGE_LINE_*``) beside the image's border or the desk's ``band`` (``bool [H, W]``).
    With ``ruled`` (the rules' pixels removed) the marks joined through the rules' pixels
    in the desk's band count as one when they lie in the band: the sheet's edge along the
    rules, which their removal cut into pieces, as :func:`_along_border` joins them (a
    mark joined to no other is judged as it stands)."""
    from scipy.ndimage import label

    h, w = labels.shape
    n = int(labels.max())
    near = np.zeros((h, w), bool)
    m = max(2, round(EDGE_LINE_NEAR * min(h, w)))
    near[:m], near[-m:], near[:, :m], near[:, -m:] = True, True, True, True
    if band is not None:
        near |= band
    out = np.zeros(n + 1, bool)
    joined, k = labels, n
    if band is not None and ruled is not None and (ruled & band).any():
        joined, k = label((labels > 0) | (ruled & band), structure=np.ones((3, 3), bool))
    touching = np.unique(joined[near & (labels > 0)])
    if touching.size == 0:
        return out
    rows, cols = np.nonzero(np.isin(joined, touching) & (labels > 0))  # the marks' own
    lab = joined[rows, cols]
    count = np.bincount(lab, minlength=k + 1).astype(np.float64)
    inside = np.bincount(lab, weights=near[rows, cols], minlength=k + 1)
    c = np.maximum(count, 1)
    mr, mc = np.bincount(lab, rows, k + 1) / c, np.bincount(lab, cols, k + 1) / c
    vr = np.bincount(lab, (rows - mr[lab]) ** 2, k + 1) / c
    vc = np.bincount(lab, (cols - mc[lab]) ** 2, k + 1) / c
    vrc = np.bincount(lab, (rows - mr[lab]) * (cols - mc[lab]), k + 1) / c
    half, root = (vr + vc) / 2, np.sqrt(((vr - vc) / 2) ** 2 + vrc**2)
    length = np.sqrt(12 * (half + root))  # a uniform line's spread along it: L^2 / 12
    thick = np.sqrt(12 * np.maximum(half - root, 0))
    thick = np.maximum(thick, 1.0)
    line = (length >= EDGE_LINE_SHARE * min(h, w)) & (
        (inside >= EDGE_LINE_INSIDE * count) | (length >= EDGE_LINE_THIN * thick)
    )
    piece = (length >= EDGE_PIECE_SHARE * min(h, w)) & (length >= EDGE_PIECE_THIN * thick)
    # or the sheet's corner: straight along each border it lies beside, not as a whole
    sides, across = _along_sides(rows, cols, lab, k, (h, w), m)
    piece |= (sides >= EDGE_PIECE_SHARE * min(h, w)) & (sides >= EDGE_PIECE_THIN * across)
    piece &= inside >= EDGE_LINE_INSIDE * count
    if joined is not labels:  # joined by the rules: pieces of a line lying in the band
        pairs = np.unique(np.stack([lab, labels[rows, cols]]), axis=1)
        several = np.bincount(pairs[0], minlength=k + 1) > 1  # a mark alone: as it is
        line &= ~several | (inside >= EDGE_LINE_INSIDE * count)
    edge = np.zeros(k + 1, bool)
    edge[touching] = (line | piece)[touching]
    marks = labels > 0  # each mark takes its group's answer
    out[labels[marks]] = edge[joined[marks]]
    return out


def _along_sides(rows, cols, lab, k: int, shape, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Per label (``k + 1``): the length and thickness of a mark (its pixels ``rows``,
    ``cols`` with labels ``lab``) read along the image's borders that it comes within
    ``m`` pixels of: each pixel taken by the side it lies nearest to, counted from the
    mark's own nearest pixel to that side (the two lines of a sheet's corner, an L, each
    go to their own side); the lengths (the spread along each side, as a uniform line's)
    added, the thickness the largest spread across one (at least 1). A mark beside no
    border: length 0."""
    h, w = shape
    n = k + 1
    far = np.stack([rows, h - 1 - rows, cols, w - 1 - cols]).astype(np.float64)  # [4, P]
    nearest = np.full((4, n), np.inf)
    for s in range(4):
        np.minimum.at(nearest[s], lab, far[s])
    offset = far - nearest[:, lab]
    offset[nearest[:, lab] >= m] = np.inf  # a side the mark does not come near
    side = np.argmin(offset, axis=0)
    beside = np.isfinite(offset[side, np.arange(side.size)])
    along = np.where(side < 2, cols, rows).astype(np.float64)
    across = far[side, np.arange(side.size)]
    group = (lab * 4 + side)[beside]
    count = np.bincount(group, minlength=4 * n).astype(np.float64)
    c = np.maximum(count, 1)

    def spread(values: np.ndarray) -> np.ndarray:  # a uniform line's length: sqrt(12 var)
        v = values[beside]
        mean = np.bincount(group, v, 4 * n) / c
        return np.sqrt(12 * np.bincount(group, (v - mean[group]) ** 2, 4 * n) / c)

    length = np.where(count >= 2, spread(along), 0.0).reshape(n, 4).sum(axis=1)
    thick = np.maximum(np.where(count >= 2, spread(across), 0.0).reshape(n, 4).max(axis=1), 1.0)
    return length, thick


def _sheet_rules(weak, sheet, dark, pen: float, channels, desk) -> np.ndarray:
    """:func:`rules` of the sheet: on a sheet found on a ``desk``
    (:class:`img2dmp.data.sheet.Sheet`), at its sides' angle, and the darkness beside it
    that of the nearest pixel ``SHEET_EDGE_PX`` inside it (the lines' level read along a
    rule's last stretch is the rule's and the paper's, not the desk's none, nor the
    paper's colour painted up to the sheet's edge)."""
    if desk is None:
        return rules(weak, sheet, dark, pen, np.where(sheet, channels, 0.0))[0]
    from scipy.ndimage import distance_transform_edt, minimum_filter

    # eroded by SHEET_EDGE_PX (a square's erosion, in one pass)
    inner = minimum_filter(sheet, 2 * SHEET_EDGE_PX + 1, mode="constant", cval=False)
    inner = inner if inner.any() else sheet
    near = distance_transform_edt(~inner, return_distances=False, return_indices=True)
    off = np.flatnonzero(~sheet)  # the sheet's own pixels as they are
    src = near[0].ravel()[off] * sheet.shape[1] + near[1].ravel()[off]
    dark, channels = dark.copy(), channels.copy()
    dark.ravel()[off] = dark.ravel()[src]
    flat = channels.reshape(len(channels), -1)
    flat[:, off] = flat[:, src]
    return rules(weak & sheet, sheet, dark, pen, channels, desk.angle_deg)[0]


def paper_ink(
    levels, *, keep_steps: bool = False, sheet_factor: int | None = None
) -> PaperInk | None:
    """The handwriting of an image, separated from its paper (module docstring).

    Parameters
    ----------
    levels : float array [H, W] (grey) or [H, W, 3] (RGB), values in [0, 1]
    keep_steps : bool
        Keep each step's picture in :attr:`PaperInk.steps`.
    sheet_factor : int, optional
        The reduction :func:`img2dmp.data.sheet.find_sheet` looks for the sheet at
        (default: its own, from the image's size).

    Returns
    -------
    PaperInk, or None when nothing in the image stands out from the paper.
    """
    a = _planes(levels)
    # the sheet on a desk (not a shadow across the page): the paper's colour painted over it
    desk = find_sheet(a, sheet_factor, written=shade_test(a))
    if desk is not None:
        a = desk.fill
    polarity = dark_on_light(a)
    if not polarity:
        a = 1.0 - a
    pen = rough_pen_width(a)
    found, stepped = _ink_found(levels, a, desk, polarity, pen, keep_steps)
    if stepped:  # a crop across a shadow's hard edge: read with cells too (CROP_STEP_GAIN)
        again = _ink_found(levels, a, desk, polarity, pen, keep_steps, cells=True)[0]
        if again is not None and _lost_to_band(found, again):
            return again
    return found


def _lost_to_band(smooth: PaperInk | None, cells: PaperInk) -> bool:
    """Whether a crop's smooth reading (None: no ink) lost the strokes in a shadow that
    its reading with cells keeps, dropping fewer faint marks (``CROP_STEP_GAIN``,
    ``CROP_STEP_FAINT``)."""
    faint = cells.removed["faint_components"]
    if smooth is None:  # a character's ink, not a few pieces of the edge's band
        return bool(cells.mask.sum() >= CROP_STEP_INK_PEN2 * cells.pen_width_px**2)
    more = cells.mask.sum() > CROP_STEP_GAIN * smooth.mask.sum()
    return bool(more and smooth.removed["faint_components"] - faint >= CROP_STEP_FAINT)


def _ink_found(levels, a: np.ndarray, desk, polarity: bool, pen: float, keep_steps: bool,
               cells: bool = False) -> tuple[PaperInk | None, bool]:  # fmt: skip
    """:func:`paper_ink`'s steps from the background on, for dark-on-light planes ``a``
    (the desk painted over), with cells for a crop too when ``cells``; and whether the
    crop lies across a shadow's hard edge (:func:`crop_shade_step`)."""
    bg, cell, stepped = _background(a, pen, cells)
    channels = channel_darkness(a, bg)
    on_sheet = None if desk is None else desk.mask  # not the desk painted smooth
    gain = glare_gain(a, bg, cell, on_sheet)
    if gain is not None:  # a glare's lost contrast given back (GLARE_*)
        np.clip(np.multiply(channels, gain, out=channels), 0.0, 1.0, out=channels)
    dark = np.max(channels, axis=0)
    local = min(a.shape[1:]) >= LOCAL_BACKGROUND_MIN_SIDE  # not one level for the image
    noise = _noise(a, bg, on_sheet, gain) if local else 0.0
    dark = without_shade_bands(dark, bg, cell, pen)
    crop = min(a.shape[1:]) < SURFACE_MAX_SIDE  # a crop has no table beyond the sheet
    sheet = sheet_mask(bg, 0 if crop else cell, dark, pen, noise)  # a shadow across the page stays
    if desk is not None:
        sheet &= desk.mask
    dark = np.where(sheet, dark, 0.0).astype(np.float32)
    lv = thresholds(dark, noise)
    steps = {"input": np.asarray(levels), "background": bg, "darkness": dark, "sheet": sheet}
    if gain is not None:
        steps["glare"] = gain
    if lv is None:
        return None, stepped
    weak = dark >= lv.weak
    ruled = _sheet_rules(weak, sheet, dark, pen, channels, desk)
    edge = _border_marks(weak & ~ruled) if local else np.zeros_like(weak)
    if ruled.any() or edge.any():  # the pen's own level: many rules pull it down, the edge up
        lv = thresholds(dark, noise, exclude=ruled | edge)
        if lv is None:
            return None, stepped
        weak = dark >= lv.weak
    kept, width, removed = _kept_strokes(weak & ~ruled, dark, lv, local, pen, ruled,
                                         None if desk is None else desk.band)  # fmt: skip
    if not kept.any():
        return None, stepped
    halo = dilate3(kept) & ~ruled
    ink = np.where(halo, np.clip(dark / lv.ink, 0.0, 1.0), 0.0).astype(np.float32)
    removed.update(rule_px=int(ruled.sum()), off_sheet_px=int((~sheet).sum()),
                   desk_px=0 if desk is None else desk.desk_px)  # fmt: skip
    steps.update(rules=ruled, candidates=weak, ink=ink)
    glare = 1.0 if gain is None else float(gain.max())
    return PaperInk(
        ink, kept, width, polarity, removed, steps if keep_steps else {}, glare
    ), stepped


__all__ = [
    "PaperInk",
    "background",
    "crop_shade_step",
    "dark_on_light",
    "darkness",
    "dominant_angle",
    "glare_gain",
    "holds_writing",
    "paper_ink",
    "pen_width",
    "rules",
    "shade_test",
    "sheet_mask",
    "thresholds",
]
