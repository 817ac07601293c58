"""Finding the characters of a page and their reading order (NumPy, SciPy).

:func:`find_characters` takes the ink of a page (:func:`img2dmp.data.paper.paper_ink`'s
mask of pen strokes) and returns its characters, each a box and its own pixels, grouped
into text lines and ordered for reading:

1. **marks**: the 8-connected components of the ink, and the page's scale, the typical
   character height ``height_px`` (the median component height, weighted by ink);
2. **joined parts**: pieces of one stroke broken by a scanner's threshold or a large
   scan's reduction (an end of one facing an end of the other across at most
   ``BREAK_GAP`` heights, or ``BREAK_MIN_PX``, and a pixel: :func:`join_breaks`); then
   components that stack over one another (a 5's bar over its body,
   the two strokes of a 4) are one character when one lies within the other's columns
   (``JOIN_OVERLAP``), or is low (``SMALL_PART``) and overlaps them, they are at most
   ``JOIN_GAP`` character heights apart and together no taller than ``JOIN_HEIGHT``
   heights; a small fragment joins the character it nearly touches;
3. **lines**: the page's writing direction (the angle along which the ink lines up,
   :func:`img2dmp.data.paper.dominant_angle`), and the characters sorted across it: a
   new line begins where the next character's middle row is more than ``LINE_GAP``
   heights past the current line's;
4. **touching characters**: the pitch (the median distance between neighbouring
   characters' centres in a line) and the usual character width (on a page of digits,
   of the marks at most ``ALONE_WIDTH`` heights wide) say how many
   characters a wide mark holds; it is cut near equal divisions at the columns that
   cross the fewest strokes, at least ``MIN_CUT_PITCH`` divisions apart; and a mark (or
   piece) of any width is cut at a column that crosses a single stroke with ink at least
   ``WAIST_TALL`` of its height tall on either side (two characters that touch).
   On a page of letters (``join_sides``: a stroke model's) nothing is cut, and instead
   neighbours in a line whose boxes overlap or lie apart by at most ``SIDE_GAP`` of the
   line's usual gap, together at most ``SIDE_WIDTH`` character widths wide, are one
   character of pieces side by side (a Korean syllable);
5. **reading order**: lines top to bottom, characters left to right; words where the
   gap is wider than ``WORD_GAP`` heights and twice the line's usual gap; marks smaller
   than ``MIN_CHARACTER`` heights on their longer side are left out.

Positions are the ink map's pixels: boxes ``[x0, y0, x1, y1]`` are half-open (columns
``x0 <= j < x1``), x = column, y = row (docs/CONTRACTS.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: Parts stack into one character when the narrower lies within the wider's columns:
#: their union is at most this much wider than the wider part.
JOIN_OVERLAP = 1.15
#: ... and at most this many character heights apart (vertically),
JOIN_GAP = 0.45
#: ... and together at most this many character heights tall.
JOIN_HEIGHT = 1.7
#: A fragment (at most this share of a character height on its longer side) joins the
#: nearest character within this share of a height.
FRAGMENT_SIZE = 0.3
#: A mark at most this share of a character height tall that overlaps another's columns
#: and lies over or under it (sharing at most 30 % of its rows, within ``JOIN_GAP``) is
#: part of it (a 5's bar, a 7's bar).
SMALL_PART = 0.4
#: A new line starts this many character heights below the current one's middle.
LINE_GAP = 0.55
#: A mark holds one more character for every character width it spans beyond this many
#: (widths: the upper quartile of the page's characters', so narrow 1s do not count).
SPLIT_WIDTHS = 1.7
#: On a page of digits (not ``join_sides``) that width is read from the marks at most
#: this many character heights wide: a wider mark holds several (written with a marker,
#: most of a line's digits may touch, and the width of such marks would make each look
#: like one character). Chosen on the validation pages, ``page_segmentation.py`` (200
#: pages, found on cluttered + plain paper of 7,678) and ``photo_conditions.py --pages 12``
#: (as they are, far, pencil and marker, of 1,491), every mark / 2.0 / 1.5 / 1.3 / 1.2:
#: 7,581 / 7,581 / 7,589 / 7,593 / 7,587 and 1,425 / 1,438 / 1,443 / 1,443 / 1,446; the
#: shared photos under a marker and far-0.18 matched 111 / 114 / 114 / 122 / 122 of 156
#: (RESULTS 7.26). A page of letters counts every mark (an m, a Korean syllable's pieces).
ALONE_WIDTH = 1.3
#: Cuts through touching characters are at least this share of the pitch apart.
MIN_CUT_PITCH = 0.45
#: A mark is two touching characters, whatever its width, where one column crosses a
#: single stroke and the ink on either side of it (one piece each side) is at least this
#: share of the mark's height (and of the character height) tall: a 1 leaning on a 7,
#: two 0s kissing. Chosen on the segmentation scan of validation pages
#: (``experiments/page_segmentation.py``, seeds 100-299, 3,839 characters on cluttered
#: paper, 3,681 found without the cut), with ``WAIST_RUN`` 0.45 and before the one-piece
#: condition: 0.70 / 0.75 / 0.80 / 0.85 / 0.90 found 3,737 / 3,743 / 3,748 / 3,744 /
#: 3,735 (lower cuts 4s and 0s open at the top: 51 / 43 / 32 / 27 / 26 split).
WAIST_TALL = 0.80
#: ... and that column is at least this many character heights from the mark's ends.
WAIST_SIDE = 0.08
#: ... and the stroke it crosses is at most this many character heights long down the
#: column (not a downstroke the column runs along). Same scan, ``WAIST_TALL`` 0.80, the
#: one-piece condition: 0.45 / 0.6 / 0.8 / none found 3,748 / 3,754 / 3,750 / 3,740
#: (29 / 30 / 33 / 42 split); none of them changed the two photos' counts
#: (``../shared/data/photos``; 0.6 without the one-piece condition cut the white one's 4).
#: 0.45, not 0.6: from 0.6 a 4 leaning 8 degrees is cut where its bar meets the
#: downstroke (the column's run there is 0.45 to 0.5 character heights).
WAIST_RUN = 0.45
#: On a page of letters (``find_characters(..., join_sides=True)``) two neighbours in a
#: line are one character of pieces side by side (a Korean syllable's consonant and
#: vowel) when their boxes overlap, touch, or lie apart by at most this share of the
#: line's usual gap between neighbours (the writer's own spacing), ``SIDE_WIDTH``. Chosen
#: with ``experiments/stroke_page.py`` on the validation drawers 16 and 17 (136
#: characters each, in cells or 0.3 / 0.15 / 0.05 character heights apart: 1,088 placed):
#: 0 (boxes touching) / 0.3 / 0.5 / 0.7 found 1,030 / 1,048 / 1,054 / 1,045 whole (not
#: joining: 1,016), and joined two neighbours as one 0 / 0 / 0 / 14 times (at 0.05
#: heights); 0.5 joined two 1s of ``../shared/data/photos``' yellow page (3 px apart), 0.3
#: nothing there.
SIDE_GAP = 0.3
#: ... and together they are at most this many usual character widths wide (the upper
#: quartile of the page's characters' widths, as for ``SPLIT_WIDTHS``). Scanned on the same
#: pages (RESULTS 8.10): 1.1 / 1.3 / 1.6 / 2.0 found 1,027 / 1,048 / 1,058 / 1,054 whole,
#: joined two neighbours 0 / 0 / 0 / 4 times; 1.6 joined two more pairs of digits on the
#: yellow photo (61 characters found with 1.3, 59 with 1.6; it has 64 digits).
SIDE_WIDTH = 1.3
#: A mark smaller than this share of a character height on its longer side is not a
#: character (what the paper left: a rule's crossing, a speck at the page's scale).
MIN_CHARACTER = 0.3
#: A gap wider than this many character heights (and twice the line's usual) is a space.
WORD_GAP = 0.6
#: The most characters a page may hold.
MAX_CHARACTERS = 5000
#: Pieces of one stroke broken by a scanner's threshold (a 1-bit scan) or by the
#: reduction of a large scan are joined when an end of one faces an end of the other
#: across at most this share of the typical character height (plus a pixel) of paper:
#: the nearest pixels of the two are each at an end of their piece (the piece's ink
#: within ``BREAK_REACH`` heights of it runs away from the other piece in one
#: direction, ``BREAK_END``), and one of the two is at least ``MIN_CHARACTER`` heights
#: on its longer side (crumbs of a removed rule in a shadow, end to end, stay crumbs).
#: Two characters side by side face each other with the sides of their strokes or the
#: corners of their bowls, not with ends.
BREAK_GAP = 0.06
#: ... or at least this many pixels (two pixels straight, one on the diagonal: a thin
#: line of a large scan reduced to a page's working size, its core broken);
BREAK_MIN_PX = 2.0
#: ... the reach around an end that says which way its piece runs, character heights;
BREAK_REACH = 0.3
#: ... and how much its pixels there lie in one direction (the length of the mean of
#: the unit vectors from the end to them: 1 a straight line, 0 a stroke passing by).
BREAK_END = 0.75
#: On a page of letters (``join_sides``), whose marks are not cut afterwards, two pieces
#: each over ``MIN_CHARACTER`` heights wide are not joined where together they would be
#: wider than this many heights: two letters written close, their ends nearly meeting.
#: ``stroke_page.py``, drawers 16 and 17 written 0.05 heights apart (RESULTS 7.27):
#: 121 and 108 of 136 found whole without it, 128 and 129 with it (1.2 the same).
BREAK_WIDE = 1.5


@dataclass
class PageCharacter:
    """One character of a page.

    Attributes
    ----------
    box : (x0, y0, x1, y1)
        Half-open pixel bounds of its ink in the page's ink map.
    mask : bool [y1 - y0, x1 - x0]
        Its own pixels in the box (a neighbour's ink reaching into the box is not).
    line, position, word : int
        Its text line (0 = top), its place in the line (0 = left) and its word in the line.
    index : int
        Its place in reading order over the page.
    parts : int
        Components joined into it (1: one connected mark).
    split : bool
        Cut from a mark of touching characters.
    """

    box: tuple[int, int, int, int]
    mask: np.ndarray
    line: int = 0
    position: int = 0
    word: int = 0
    index: int = 0
    parts: int = 1
    split: bool = False

    @property
    def centre(self) -> tuple[float, float]:
        x0, y0, x1, y1 = self.box
        return (x0 + x1) / 2.0, (y0 + y1) / 2.0


@dataclass
class PageLayout:
    """The characters of a page in reading order, and what they were found with.

    Attributes
    ----------
    characters : list of PageCharacter
    lines : list of list of int
        The indices of each line's characters, left to right.
    angle_deg : float
        The writing direction (degrees; positive: lines rise to the left, falling to the right).
    height_px : float
        The typical character height.
    shape : (H, W)
        The ink map's size.
    """

    characters: list[PageCharacter] = field(default_factory=list)
    lines: list[list[int]] = field(default_factory=list)
    angle_deg: float = 0.0
    height_px: float = 0.0
    shape: tuple[int, int] = (0, 0)


@dataclass
class _Mark:
    """A group of components under construction: its box and the labels it holds."""

    x0: int
    y0: int
    x1: int
    y1: int
    labels: list[int]
    area: int

    @property
    def width(self) -> int:
        return self.x1 - self.x0

    @property
    def height(self) -> int:
        return self.y1 - self.y0


def _marks(mask: np.ndarray) -> tuple[np.ndarray, list[_Mark]]:
    """Labels of the 8-connected components of ``mask`` and one :class:`_Mark` each."""
    from scipy.ndimage import find_objects, label

    labels, n = label(mask, structure=np.ones((3, 3), bool))
    if n > MAX_CHARACTERS * 4:
        raise ValueError(
            f"the page holds {n} separate marks, more than {MAX_CHARACTERS * 4}: is it a "
            "page of handwriting?"
        )
    area = np.bincount(labels.ravel(), minlength=n + 1)
    marks = []
    for i, sl in enumerate(find_objects(labels), start=1):
        if sl is not None:
            marks.append(_Mark(sl[1].start, sl[0].start, sl[1].stop, sl[0].stop, [i], int(area[i])))
    return labels, marks


def typical_height(marks: list[_Mark]) -> float:
    """The median height of the marks, each weighted by its ink (specks count little)."""
    if not marks:
        return 0.0
    h = np.array([m.height for m in marks], float)
    w = np.array([m.area for m in marks], float)
    order = np.argsort(h)
    cum = np.cumsum(w[order])
    return float(h[order][np.searchsorted(cum, cum[-1] / 2.0)])


def _end_facing(pixels: np.ndarray, at: np.ndarray, toward: np.ndarray, reach: float) -> bool:
    """Whether ``at`` (row, column), a pixel of a piece ``pixels [n, 2]``, is an end of it
    that faces ``toward``: seen from ``at``, the piece's other pixels within ``reach`` lie
    in one direction (the mean of their unit directions at least ``BREAK_END`` long: a
    stroke running away, not a stroke passing by or a bowl's corner), within 60 degrees
    of straight away from ``toward``."""
    d = pixels - at
    r = np.hypot(d[:, 0], d[:, 1])
    near = (r > 0) & (r <= reach)
    if not near.any():
        return True  # a piece of a pixel: no way it runs
    mean = (d[near] / r[near, None]).mean(axis=0)
    u = (toward - at) / max(1e-9, float(np.hypot(*(toward - at))))
    length = float(np.hypot(*mean))
    return length >= BREAK_END and float(mean @ u) <= -0.5 * length


def _near_box(pixels: np.ndarray, m: _Mark, limit: float) -> np.ndarray:
    """The pixels ``[n, 2]`` (row, column) within ``limit`` of ``m``'s box."""
    r, c = pixels[:, 0], pixels[:, 1]
    keep = (r > m.y0 - 1 - limit) & (r < m.y1 + limit) & (c > m.x0 - 1 - limit) & (c < m.x1 + limit)
    return pixels[keep]


def _nearest(pa: np.ndarray, pb: np.ndarray, limit: float, chunk: int = 4096):
    """The nearest pair of pixels ``(of pa, of pb)`` at most ``limit`` apart, or None."""
    best, pair = limit * limit, None
    for k in range(0, len(pb), chunk):
        part = pb[k : k + chunk]
        d = ((pa[:, None, :] - part[None, :, :]) ** 2).sum(axis=2)  # [n_a, n_part]
        if d.size and d.min() <= best:
            ia, ib = np.unravel_index(int(np.argmin(d)), d.shape)
            best, pair = float(d[ia, ib]), (pa[ia], part[ib])
    return pair


def join_breaks(labels: np.ndarray, marks: list[_Mark], height: float,
                letters: bool = False) -> list[_Mark]:  # fmt: skip
    """``marks`` with the pieces of broken strokes merged (``BREAK_GAP``): an end of one
    facing an end of the other across a gap of at most ``BREAK_GAP`` heights and a
    pixel (a 1-bit scan's threshold, a large scan's reduction), one of the two at least
    ``MIN_CHARACTER`` heights on its longer side; with ``letters`` (a page of letters,
    nothing cut afterwards), not two pieces that would be wider than ``BREAK_WIDE``."""
    limit = max(BREAK_GAP * height, BREAK_MIN_PX) + 1.0
    if len(marks) < 2:
        return marks
    reach = max(3.0, BREAK_REACH * height)
    order = sorted(range(len(marks)), key=lambda i: marks[i].x0)
    parent = list(range(len(marks)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    cache: dict[int, np.ndarray] = {}
    box = {i: (m.x0, m.x1) for i, m in enumerate(marks)}  # each group's columns

    def coords(i: int) -> np.ndarray:
        if i not in cache:
            m = marks[i]
            rows, cols = np.nonzero(labels[m.y0 : m.y1, m.x0 : m.x1] == m.labels[0])
            cache[i] = np.column_stack([rows + m.y0, cols + m.x0]).astype(np.float64)
        return cache[i]

    for k, i in enumerate(order):
        a = marks[i]
        for j in order[k + 1 :]:
            b = marks[j]
            if b.x0 - a.x1 >= limit:
                break
            if max(a.y0, b.y0) - min(a.y1, b.y1) >= limit or root(i) == root(j):
                continue
            if max(a.width, a.height, b.width, b.height) < MIN_CHARACTER * height:
                continue  # two crumbs (of a rule, of the paper's grain): no stroke to mend
            (a0, a1), (b0, b1) = box[root(i)], box[root(j)]
            wide = min(a1 - a0, b1 - b0) > MIN_CHARACTER * height
            if letters and wide and max(a1, b1) - min(a0, b0) > BREAK_WIDE * height:
                continue  # two letters' pieces, not one stroke's (nothing cuts them later)
            pa, pb = coords(i), coords(j)
            near = _nearest(_near_box(pa, b, limit), _near_box(pb, a, limit), limit)
            if near is None:
                continue
            at_a, at_b = near
            if _end_facing(pa, at_a, at_b, reach) and _end_facing(pb, at_b, at_a, reach):
                parent[root(j)] = root(i)
                box[root(i)] = (min(a0, b0), max(a1, b1))
    groups: dict[int, _Mark] = {}
    for i, m in enumerate(marks):
        r = root(i)
        groups[r] = _merge(groups[r], m) if r in groups else m
    return list(groups.values())


def _stack(a: _Mark, b: _Mark, height: float) -> bool:
    """Whether ``a`` and ``b`` are parts of one character (step 2 of the module docstring)."""
    union_w = max(a.x1, b.x1) - min(a.x0, b.x0)
    union_h = max(a.y1, b.y1) - min(a.y0, b.y0)
    gap_y = max(a.y0, b.y0) - min(a.y1, b.y1)
    gap_x = max(a.x0, b.x0) - min(a.x1, b.x1)
    if union_h > JOIN_HEIGHT * height:
        return False
    if max(a.width, a.height, b.width, b.height) > 0 and (
        min(max(a.width, a.height), max(b.width, b.height)) <= FRAGMENT_SIZE * height
    ):
        return max(gap_x, gap_y) <= FRAGMENT_SIZE * height  # a fragment near its character
    low = min(a.height, b.height)
    stacked = -0.3 * low <= gap_y <= JOIN_GAP * height  # over or under, rows hardly shared
    if low <= SMALL_PART * height and gap_x < 0 and stacked:
        return True  # a low mark over or under a character's columns: a bar, a hook
    return union_w <= JOIN_OVERLAP * max(a.width, b.width) and gap_y <= JOIN_GAP * height


def _merge(a: _Mark, b: _Mark) -> _Mark:
    return _Mark(min(a.x0, b.x0), min(a.y0, b.y0), max(a.x1, b.x1), max(a.y1, b.y1),
                 a.labels + b.labels, a.area + b.area)  # fmt: skip


def join_parts(marks: list[_Mark], height: float) -> list[_Mark]:
    """Marks merged into characters until no two are parts of one (:func:`_stack`);
    only marks whose boxes come within a character height of each other are compared."""
    marks = sorted(marks, key=lambda m: m.x0)
    changed = True
    while changed:
        changed = False
        out: list[_Mark] = []
        for m in marks:
            for k in range(len(out) - 1, -1, -1):
                o = out[k]
                if o.x1 + height < m.x0 and o.x0 + 4 * height < m.x0:
                    continue  # far to the left: sorted by x0, nothing to join there
                if _stack(o, m, height):
                    out[k] = _merge(o, m)
                    changed = True
                    break
            else:
                out.append(m)
        marks = sorted(out, key=lambda m: m.x0)
    return marks


def _own_pixels(labels: np.ndarray, m: _Mark) -> np.ndarray:
    """The pixels of ``m``'s components in its box, ``bool [height, width]``."""
    crop = labels[m.y0 : m.y1, m.x0 : m.x1]
    return np.isin(crop, m.labels)


def _middle_row(pixels: np.ndarray, y0: int) -> float:
    """The median row of a character's pixels (a long tail moves it less than the box)."""
    counts = pixels.sum(axis=1).cumsum()
    return y0 + float(np.searchsorted(counts, counts[-1] / 2.0))


def group_lines(mids: np.ndarray, xs: np.ndarray, angle_deg: float, height: float):
    """Line of every character (0 = top) from its middle row ``mids`` and centre column
    ``xs``: sorted across the writing direction, a new line where the next middle is
    more than ``LINE_GAP`` heights past the current line's median."""
    across = mids - xs * math.tan(math.radians(angle_deg))
    order = np.argsort(across, kind="stable")
    line = np.zeros(len(mids), np.int64)
    current: list[float] = []
    n = 0
    for i in order:
        if current and across[i] - float(np.median(current)) > LINE_GAP * height:
            n, current = n + 1, []
        current.append(float(across[i]))
        line[i] = n
    return line


def _pitch(lines: list[list[int]], centres: np.ndarray, height: float) -> float:
    """The page's usual distance between neighbouring characters' centres in a line
    (0.8 heights where no line has two)."""
    steps = [np.diff(np.sort(centres[idx])) for idx in lines if len(idx) > 1]
    steps = np.concatenate(steps) if steps else np.array([])
    steps = steps[steps < 2.5 * height]  # spaces between words are not the pitch
    return float(np.median(steps)) if steps.size else 0.8 * height


def _cut_columns(pixels: np.ndarray, k: int) -> list[int]:
    """``k - 1`` columns at which to cut a mark ``pixels [h, w]`` of touching characters:
    near each equal division, the column that crosses the fewest strokes (runs of ink:
    two characters touch where one stroke meets another), then the least ink, then the
    nearest to the division; at least ``MIN_CUT_PITCH`` divisions from the last cut."""
    runs = np.count_nonzero(np.diff(pixels.astype(np.int8), axis=0, prepend=0) == 1, axis=0)
    ink = pixels.sum(axis=0) / max(1, int(pixels.sum(axis=0).max()))
    width = pixels.shape[1]
    step = width / k
    cuts: list[int] = []
    for j in range(1, k):
        lo = max(int(j * step - 0.4 * step), (cuts[-1] if cuts else 0) + int(MIN_CUT_PITCH * step))
        hi = min(int(j * step + 0.4 * step), width - int(MIN_CUT_PITCH * step))
        if hi <= lo:
            continue
        c = np.arange(lo, hi)
        cost = runs[c] + 0.5 * ink[c] + 0.5 * ((c - j * step) / (0.4 * step)) ** 2
        cuts.append(lo + int(np.argmin(cost)))
    return cuts


def _waist(pixels: np.ndarray, height: float) -> int | None:
    """The column at which a mark ``pixels [h, w]`` of two touching characters is cut
    whatever its width (``WAIST_TALL``): of the columns crossing one stroke with at least
    ``WAIST_TALL`` heights of ink on either side, the one with the least ink; None
    where there is none."""
    w = pixels.shape[1]
    side = max(1, math.ceil(WAIST_SIDE * height))
    if w < 2 * side + 1:
        return None
    runs = np.count_nonzero(np.diff(pixels.astype(np.int8), axis=0, prepend=0) == 1, axis=0)
    rows = np.arange(pixels.shape[0])[:, None]
    top = np.where(pixels, rows, pixels.shape[0]).min(axis=0)
    bottom = np.where(pixels, rows, -1).max(axis=0)
    # the ink's extent left of column c (columns < c) and from c on
    left = np.maximum.accumulate(bottom) - np.minimum.accumulate(top) + 1
    right = (np.maximum.accumulate(bottom[::-1]) - np.minimum.accumulate(top[::-1]) + 1)[::-1]
    c = np.arange(side, w - side)
    tall = WAIST_TALL * max(height, pixels.shape[0])
    extent = bottom - top + 1  # the one stroke's extent down the column, where runs == 1
    ok = c[(runs[c] == 1) & (extent[c] <= WAIST_RUN * height)
           & (left[c - 1] >= tall) & (right[c] >= tall)]  # fmt: skip
    ink = pixels.sum(axis=0)
    for col in ok[np.argsort(ink[ok] + np.abs(ok - w / 2.0) / w, kind="stable")]:
        # tall on either side as one piece: not a 4 whose leaning downstroke's foot
        # reaches past the column where the bar meets it
        if min(_tallest(pixels[:, :col]), _tallest(pixels[:, col:])) >= tall:
            return int(col)
    return None


def _tallest(pixels: np.ndarray) -> int:
    """The height of the tallest 8-connected piece of ``pixels``."""
    from scipy.ndimage import find_objects, label

    labels, n = label(pixels, structure=np.ones((3, 3), bool))
    return max((sl[0].stop - sl[0].start for sl in find_objects(labels) if sl is not None),
               default=0)  # fmt: skip


def _pieces_at_waists(box, pixels: np.ndarray, height: float, depth: int = 3):
    """``[(box, pixels), ...]``: a piece cut where it has a waist (:func:`_waist`), its
    parts again, at most ``depth`` times."""
    c = _waist(pixels, height) if depth > 0 else None
    if c is None:
        return [(box, pixels)]
    out = []
    for a, b in ((0, c), (c, pixels.shape[1])):
        part = pixels[:, a:b]
        rows, cols = np.nonzero(part)
        if rows.size == 0:
            continue
        r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min() + a, cols.max() + 1 + a
        sub = (box[0] + int(c0), box[1] + int(r0), box[0] + int(c1), box[1] + int(r1))
        out += _pieces_at_waists(sub, pixels[r0:r1, c0:c1], height, depth - 1)
    return out


def _split(m: _Mark, pixels: np.ndarray, pitch: float, width: float, height: float):
    """``m`` as ``[(box, pixels), ...]``, cut into the characters it holds when it is
    wider than one (step 4 of the module docstring): as many as the pitch fits in its
    width beyond a character's, or as character widths fit in it (``SPLIT_WIDTHS``
    short of a whole one: a wide character is not cut)."""
    by_pitch = round((m.width - width) / max(pitch, 1.0)) + 1 if m.width > width else 1
    k = max(1, by_pitch, math.floor(m.width / max(width, 1.0) + 2.0 - SPLIT_WIDTHS))
    cuts = _cut_columns(pixels, k) if k > 1 else []
    pieces = []
    for a, b in zip([0, *cuts], [*cuts, m.width], strict=True):
        part = np.zeros_like(pixels)
        part[:, a:b] = pixels[:, a:b]
        rows, cols = np.nonzero(part)
        if rows.size == 0:
            continue
        r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
        box = (m.x0 + int(c0), m.y0 + int(r0), m.x0 + int(c1), m.y0 + int(r1))
        pieces += _pieces_at_waists(box, part[r0:r1, c0:c1], height)
    return pieces


def _words(chars: list[PageCharacter], height: float) -> None:
    """Number the words of one line's characters (left to right): a new word after a
    gap wider than ``WORD_GAP`` heights and twice the line's median gap."""
    gaps = np.array([b.box[0] - a.box[2] for a, b in zip(chars, chars[1:], strict=False)])
    usual = float(np.median(gaps)) if gaps.size else 0.0
    word = 0
    for i, c in enumerate(chars):
        if i and gaps[i - 1] > max(WORD_GAP * height, 2.0 * usual):
            word += 1
        c.word, c.position = word, i


def _own_ink(layout: PageLayout, mask: np.ndarray, grow: int) -> None:
    """Give every character the pixels of ``mask`` within ``grow`` pixels of its own
    (found on the cores), nearest first; its box and mask become theirs."""
    from scipy.ndimage import maximum_filter

    owner = np.zeros(mask.shape, np.int32)
    for c in layout.characters:
        x0, y0, x1, y1 = c.box
        owner[y0:y1, x0:x1][c.mask] = c.index + 1
    for _ in range(grow):  # one ring of pixels at a time: the nearest character's
        grown = maximum_filter(owner, size=3)
        owner = np.where((owner == 0) & mask, grown, owner)
    _absorb_small(layout, mask, owner)
    for c, sl in zip(layout.characters, _objects(owner, len(layout.characters)), strict=True):
        if sl is None:
            continue
        c.mask = owner[sl] == c.index + 1
        c.box = (sl[1].start, sl[0].start, sl[1].stop, sl[0].stop)
    kept = [c for c in layout.characters if (owner == c.index + 1).any()]
    _renumber(layout, kept)


def _absorb_small(layout: PageLayout, mask: np.ndarray, owner: np.ndarray) -> None:
    """A small character (at most ``SMALL_PART`` heights on either side) whose ink is
    joined to exactly one other character's in ``mask`` is part of it (a 5's bar whose
    junction is fainter than the core): ``owner`` gives it that character's label."""
    from scipy.ndimage import label

    full, n = label(mask, structure=np.ones((3, 3), bool))
    k = len(layout.characters) + 1
    pairs = np.unique(owner[mask].astype(np.int64) * (n + 1) + full[mask])
    who, comp = pairs // (n + 1), pairs % (n + 1)
    limit = SMALL_PART * layout.height_px
    for c in layout.characters:
        x0, y0, x1, y1 = c.box
        if max(x1 - x0, y1 - y0) > limit:
            continue
        mine = comp[who == c.index + 1]
        partners = np.unique(who[np.isin(comp, mine) & (who != c.index + 1) & (who > 0)])
        if len(partners) == 1 and partners[0] < k:
            owner[owner == c.index + 1] = partners[0]
            who[who == c.index + 1] = partners[0]


def _renumber(layout: PageLayout, kept: list[PageCharacter]) -> None:
    """``layout`` with only the characters ``kept``, in their lines' order, renumbered."""
    keep = {id(c) for c in kept}
    chars, lines = [], []
    for idx in layout.lines:
        line = [layout.characters[i] for i in idx if id(layout.characters[i]) in keep]
        if not line:
            continue
        for pos, c in enumerate(line):
            c.position, c.line = pos, len(lines)
        lines.append(list(range(len(chars), len(chars) + len(line))))
        chars += line
    for i, c in enumerate(chars):
        c.index = i
    layout.characters, layout.lines = chars, lines


def _objects(labels: np.ndarray, n: int):
    from scipy.ndimage import find_objects

    found = find_objects(labels, max_label=n)
    return found + [None] * (n - len(found))


def find_characters(mask, *, angle_deg: float | None = None, core=None, grow: int = 4,
                    cut: bool = True, join_sides: bool = False) -> PageLayout:  # fmt: skip
    """The characters of a page's ink mask, in reading order (module docstring).

    Parameters
    ----------
    mask : bool array [H, W]
        The pen strokes (e.g. :attr:`img2dmp.data.paper.PaperInk.mask`).
    angle_deg : float, optional
        The writing direction, if known; found from the ink otherwise.
    core : bool array [H, W], optional
        The strokes' cores (:attr:`img2dmp.data.paper.PaperInk.core`): the characters are
        found on them, then each takes the pixels of ``mask`` within ``grow`` pixels.
    cut : bool
        Cut a mark wider than one character into the characters it holds, and at its
        waists (step 4; default): touching digits. False keeps every mark (joined
        parts included) whole: letters such as n, m and W have waists a touching pair
        of digits also has (what a stroke model reads, RESULTS 8.5).
    join_sides : bool
        Join neighbours in a line that nearly touch side by side and together are about
        one character wide (``SIDE_GAP``, ``SIDE_WIDTH``): characters of pieces side by
        side, as Korean syllables are (a stroke model's pages; default False: digits).

    Returns
    -------
    PageLayout
        Empty (no characters) for a mask without ink.
    """
    mask = np.asarray(mask, dtype=bool)
    if mask.ndim != 2:
        raise ValueError(f"mask must be a 2-D array [H, W], got shape {mask.shape}")
    if core is not None:
        layout = _find(np.asarray(core, bool) & mask, angle_deg, cut, join_sides)
        _own_ink(layout, mask, grow)  # small parts joined to their characters first
    else:
        layout = _find(mask, angle_deg, cut, join_sides)
    small = MIN_CHARACTER * layout.height_px
    _renumber(layout, [c for c in layout.characters
                       if max(c.box[2] - c.box[0], c.box[3] - c.box[1]) >= small])  # fmt: skip
    return layout


def _join_sides(line: list[int], marks: list[_Mark], width: float) -> list[int]:
    """One line's marks (indices, left to right), each run of neighbours that are one
    character of pieces side by side (``SIDE_GAP``, ``SIDE_WIDTH``) merged into a new
    mark appended to ``marks``."""
    gaps = [marks[b].x0 - marks[a].x1 for a, b in zip(line, line[1:], strict=False)]
    limit = SIDE_GAP * max(0.0, float(np.median(gaps))) if gaps else 0.0
    out: list[int] = []
    for i in line:
        if out:
            a, b = marks[out[-1]], marks[i]
            if b.x0 - a.x1 <= limit and max(a.x1, b.x1) - min(a.x0, b.x0) <= SIDE_WIDTH * width:
                marks.append(_merge(a, b))
                out[-1] = len(marks) - 1
                continue
        out.append(i)
    return out


def _find(mask: np.ndarray, angle_deg: float | None, cut: bool = True,
          join_sides: bool = False) -> PageLayout:  # fmt: skip
    """:func:`find_characters` on one mask, before the marks too small to be characters
    are left out."""
    from .paper import dominant_angle

    labels, marks = _marks(mask)
    if not marks:
        return PageLayout(shape=mask.shape)
    marks = join_breaks(labels, marks, typical_height(marks), letters=join_sides)
    marks = join_parts(marks, typical_height(marks))
    if len(marks) > MAX_CHARACTERS:
        raise ValueError(
            f"the page holds {len(marks)} characters, more than {MAX_CHARACTERS}: is it a "
            "page of handwriting?"
        )
    height = typical_height(marks)
    angle = dominant_angle(mask) if angle_deg is None else float(angle_deg)
    pixels = [_own_pixels(labels, m) for m in marks]
    mids = np.array([_middle_row(p, m.y0) for p, m in zip(pixels, marks, strict=True)])
    xs = np.array([(m.x0 + m.x1) / 2.0 for m in marks])
    line = group_lines(mids, xs, angle, height)
    along = xs + mids * math.tan(math.radians(angle))
    by_line = [list(np.flatnonzero(line == n)[np.argsort(along[line == n])]) for n in
               range(int(line.max()) + 1)]  # fmt: skip
    pitch = _pitch(by_line, along, height)
    tall = [m.width for m in marks if m.height >= 0.5 * height]
    alone = [w for w in tall if w <= ALONE_WIDTH * height]
    if not join_sides and len(alone) >= 3:  # digits: a wider mark holds several
        tall = alone
    width = float(np.percentile(tall, 75)) if tall else height
    if join_sides:
        n_before = len(marks)
        by_line = [_join_sides(idx, marks, width) for idx in by_line]
        pixels += [_own_pixels(labels, m) for m in marks[n_before:]]
    layout = PageLayout(angle_deg=angle, height_px=height, shape=mask.shape)
    for n, idx in enumerate(by_line):
        chars = []
        for i in idx:
            m = marks[i]
            whole = [((m.x0, m.y0, m.x1, m.y1), pixels[i])]
            pieces = _split(m, pixels[i], pitch, width, height) if cut else whole
            chars += [PageCharacter(box, px, line=n, parts=len(m.labels),
                                    split=len(pieces) > 1) for box, px in pieces]  # fmt: skip
        _words(chars, height)
        first = len(layout.characters)
        layout.lines.append(list(range(first, first + len(chars))))
        layout.characters += chars
    for i, c in enumerate(layout.characters):
        c.index = i
    return layout


__all__ = [
    "MAX_CHARACTERS",
    "PageCharacter",
    "PageLayout",
    "find_characters",
    "group_lines",
    "join_breaks",
    "join_parts",
    "typical_height",
]
