"""Reading a page: every handwritten character of a photo or scan, as a DMP where it stands.

:func:`read_page` (``load_model(run).predict_page(photo)``, ``img2dmp predict PHOTO
--page``) runs in four steps:

1. the photo is read upright at most ``PAGE_WORK_PIXELS`` (area average), a shake's
   blur undone (:func:`img2dmp.data.shake.steadied`, in any direction), and its ink
   separated from the paper (:func:`img2dmp.data.paper.paper_ink`); a page whose
   characters come out under ``PAGE_SMALL_HEIGHT_PX`` tall (photographed from far away)
   is read again: a large photo reduced to ``PAGE_WORK_PIXELS`` from its file at a finer
   reduction, only the part that holds the characters found, then (either) enlarged if
   they are still small; one whose characters are under ``PAGE_MIN_HEIGHT_PX`` in the
   photo is flagged ``too_small``, no character given;
2. the characters are found and put in reading order
   (:func:`img2dmp.data.pages.find_characters`);
3. each character's own ink (a neighbour's reaching into its box left out) is framed as
   the model's input (:func:`img2dmp.data.images.frame_ink`), with the map back to the
   photo's pixels, and all are predicted in one batch (refined, when the model is);
4. each prediction is scored against its ink (:func:`img2dmp.predict.fit_score`) and
   flagged where it does not fit, or where the character touches the photo's border.

:func:`segment_page` is steps 1 and 2 alone (no model): what the command finds on a page.

:class:`PagePrediction` holds the result; :meth:`PagePrediction.save` writes the page
document ``<stem>_page.json`` (format ``img2dmp-page``, version 1, docs/PAGE.md) and a
picture of the whole page ``<stem>_page.png``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._files import atomic_write_bytes, atomic_write_text, check_stem
from .data import images as _images
from .data.pages import PageCharacter, PageLayout, find_characters
from .data.paper import paper_ink
from .data.shake import shake, steadied
from .data.sheet import sheet_factor

#: The page document's format name and version.
PAGE_FORMAT = "img2dmp-page"
PAGE_VERSION = 1
#: A page is read at most this many pixels (a 24-MP photo is reduced 3 x 3 to 2.7 MP):
#: characters of a handwritten page are then still tens of pixels tall.
PAGE_WORK_PIXELS = 2_000_000
#: On a page only each character's top hypothesis is refined (the one the robot writes and
#: the fit scores; alternatives as the network gave them): a quarter of the work.
PAGE_REFINE_TOP_ONLY = True
#: Whether a page read by a stroke model has its wide marks cut into characters and at
#: their waists, as a one-DMP model's digits are: not, since letters such as n, m and W
#: have the waists of two touching digits (chosen on Omniglot's validation drawers,
#: RESULTS 8.5).
STROKE_PAGE_CUT = False
#: Whether a page read by a stroke model joins neighbours that nearly touch side by side
#: and together are about one character wide into one character (a Korean syllable's
#: pieces; :data:`img2dmp.data.pages.SIDE_GAP`); a one-DMP model's digits never.
STROKE_PAGE_JOIN = True
#: Pixels of paper kept around a character's ink before it is framed.
_CROP_PAD_PX = 2
#: A page whose characters line up more steeply than this, degrees, is turned level
#: before they are found (a photo taken askew); within it the lines are followed at their
#: angle as they stand (up to ``MAX_RULE_ANGLE_DEG``, 6), and the characters read as they
#: lean. Above 6 by the estimate's error on a small page (a page of 9 digits written at
#: -3 to -4 degrees estimated at -7.2; RESULTS 7.12).
PAGE_LEVEL_DEG = 7.5
#: ... its writing's angle searched within this many degrees of the rows.
PAGE_MAX_TURN_DEG = 30.0
#: A page whose characters line up in columns better than this many times as well as in
#: rows is taken as photographed sideways (its lines running down the photo).
PAGE_SIDEWAYS_RATIO = 1.0
#: ... and read turned a quarter, it is kept so when the share of its characters flagged
#: is below this share of the reading as it stands.
PAGE_SIDEWAYS_GAIN = 0.5
#: ... and only a page of at least this many characters is turned (a few characters do
#: not line up: the angle would be one stroke's).
PAGE_TURN_MIN_CHARACTERS = 3
#: A page of which the model flags at least this share of characters is read upside down
#: too, and kept so when the share flagged there is below ``PAGE_SIDEWAYS_GAIN`` of it
#: (chosen on 96 generated validation pages: 7 of them read twice, none turned).
PAGE_UPSIDE_DOWN_SHARE = 0.15
#: A page whose characters are found under this many pixels tall, as read, is read again
#: enlarged (a page photographed from far away: its strokes a pixel wide or less, faint,
#: broken into specks, and the sheet's edge at the border darker than any of them), by
#: the whole factor that brings them to it, at most ``PAGE_ENLARGE_MAX`` and
#: ``PAGE_WORK_PIXELS`` in all (bicubic). Chosen on the two shared photos scaled by 0.35
#: to 0.18 and 8 generated validation pages scaled to characters 6 to 20 px tall (12 or
#: 16 and 4 did best; 12 leaves the generated pages with characters 13 px tall or more as
#: they were).
PAGE_SMALL_HEIGHT_PX = 12.0
PAGE_ENLARGE_MAX = 4
#: A photo reduced to ``PAGE_WORK_PIXELS`` whose characters come out under
#: ``PAGE_SMALL_HEIGHT_PX`` (a large photo of a sheet seen from far away) is first read
#: again from the file at a finer reduction, down to its own pixels: the part that holds
#: the characters found, with this many character heights of paper around them, at least
#: this share of the page's shorter side; only when that part allows a reading at least
#: ``PAGE_FINER_GAIN`` times as fine within ``PAGE_WORK_PIXELS``.
PAGE_FINER_MARGIN = 3.0
PAGE_FINER_MARGIN_SHARE = 0.05
PAGE_FINER_GAIN = 1.5
#: Characters under this many pixels tall in the photo are too small to read: the page is
#: flagged ``too_small`` and no character is given (a page's edge or a few specks would
#: otherwise be cut into dozens of characters a pixel tall).
PAGE_MIN_HEIGHT_PX = 4.0
#: Longest side of the page picture, pixels (a smaller photo is enlarged to it, up to
#: four times, so that the paths stay visible).
PICTURE_SIDE_PX = 1600


@dataclass
class CharacterPrediction:
    """One character of a page and its prediction.

    Attributes
    ----------
    character : PageCharacter
        Where it was found (in the pixels of the page as read: :attr:`PagePrediction.reduction`
        photo pixels per pixel).
    box_image : (x0, y0, x1, y1)
        Its box in the photo's own pixels (half-open, x = column).
    prediction : Prediction
        Its DMPs, ranked, in the model frame and the photo's (``prediction.frame`` maps
        between the model's input and the photo).
    flags : list of str
        The prediction's flags (:func:`img2dmp.predict.fit_flags`) and ``"cut_by_border"``
        when the character touches the photo's border.
    """

    character: PageCharacter
    box_image: tuple[int, int, int, int]
    prediction: object
    flags: list = field(default_factory=list)

    @property
    def confidence(self) -> float:
        """``path_on_ink x ink_written`` of the top hypothesis: 1 when the path lies on the
        ink and writes all of it."""
        f = self.prediction.fit
        return round(float(f["path_on_ink"] * f["ink_written"]), 4)

    def pen(self) -> np.ndarray:
        """Pen state ``[T]`` (1 down, 0 up) of the top hypothesis' path."""
        path = self.prediction.path_image[0]
        if path.shape[1] < 3:
            return np.ones(len(path), np.int64)
        return (path[:, 2] >= 0.5).astype(np.int64)

    def stroke_entries(self, dmp: bool = True) -> list[dict]:
        """A stroke model's character as page-document entries, one per stroke in writing
        order (without ``index`` and ``line``): its path, box and DMP in the photo's
        pixels, the character's fit and flags, and notes of which character and stroke
        it is (``character``, ``stroke``, ``n_strokes``, ``count_probability``: how sure
        the network is of that count, ``familiarity``: how familiar the character is to
        the model, None if it carries no familiarity, ``character_box_image_px``)."""
        c, p = self.character, self.prediction
        sure, known = p.count_probability, p.familiarity
        notes = {"character": c.index, "n_strokes": p.n_strokes,
                 "count_probability": None if sure is None else round(sure, 6),
                 "familiarity": None if known is None else round(known, 6),
                 "character_box_image_px": [int(v) for v in self.box_image],
                 "position": c.position, "word": c.word, "parts": c.parts,
                 "split": c.split}  # fmt: skip
        entries = []
        for e in p.stroke_entries(in_image=True):
            e.update(flags=list(self.flags), **notes)
            if not dmp:
                del e["dmp"]
            entries.append(e)
        return entries

    def to_dict(self, dmp: bool = True) -> dict:
        """The character's entry of the page document (without its ``"dmp"`` unless
        ``dmp``: a tenth of the size, for a quick look at the page)."""
        c, p = self.character, self.prediction
        path = p.path_image[0]
        entry = {
            "index": c.index,
            "line": c.line,
            "position": c.position,
            "word": c.word,
            "box_image_px": [int(v) for v in self.box_image],
            "path_image_px": np.round(path[:, :2], 3).tolist(),
            "pen": self.pen().tolist(),
            "times_s": np.round(p.times[0], 6).tolist(),
            "probability": round(float(p.probabilities[0]), 6),
            "confidence": self.confidence,
            "fit": dict(p.fit),
            "flags": list(self.flags),
            "parts": c.parts,
            "split": c.split,
        }
        if p.familiarity is not None:  # from a model that carries a familiarity
            entry["familiarity"] = round(p.familiarity, 6)
        if dmp:
            entry["dmp"] = p.to_document()
        return entry


class PagePrediction:
    """Every character of a page, predicted (:func:`read_page`).

    Attributes
    ----------
    characters : list of CharacterPrediction
        In reading order.
    layout : PageLayout
        The segmentation (lines, writing direction, character height) in the pixels of
        the page as read.
    image_size : (H, W)
        The photo's own size (upright), pixels.
    reduction : float
        Photo pixels per pixel of the page as read.
    source : str or None
        The photo's file, or None for an array or PIL image.
    flags : list of str
        Of the whole page: ``"no_ink"`` when nothing on it stands out from the paper,
        ``"too_small"`` when its characters are too small to read (``PAGE_MIN_HEIGHT_PX``;
        none is given), ``"mostly_unreadable"`` when more than half of its characters are
        flagged.
    removed : dict
        What the preparation dropped (:attr:`img2dmp.data.paper.PaperInk.removed`).
    glare_gain : float
        The largest factor a glare's lost contrast was given back by
        (:attr:`img2dmp.data.paper.PaperInk.glare_gain`; 1: no glare found).
    shake : (length_px, degrees) or None
        The shake undone before the ink was separated (:attr:`PageSegmentation.shake`).
    preview : uint8 [h, w, 3] or None
        The photo (upright, not turned), at most ``PICTURE_SIDE_PX`` on a side, for its
        picture.
    turn_deg : float
        The angle of the writing turned level before the characters were found (0: the
        page was read as it stands; :data:`PAGE_LEVEL_DEG`). ``layout`` is in the pixels
        of the page turned.
    turn : float64 [3, 3]
        The map of pixel-edge positions from the photo as read (``reduction``) to the
        pixels of ``layout`` (:attr:`PageSegmentation.turn`).
    origin : (x, y)
        The corner of the part of the photo read, in its pixels (:attr:`PageSegmentation.origin`;
        (0, 0) unless only the part that holds the writing was read).
    """

    def __init__(self, characters, layout, image_size, reduction, source, flags, removed,
                 user_image=None, refine_steps=0, refine_unfamiliar=None,
                 turn_deg=0.0, turn=None, origin=(0.0, 0.0), glare_gain=1.0,
                 shake=None):  # fmt: skip
        self.characters = list(characters)
        self.glare_gain = float(glare_gain)
        self.shake = None if shake is None else (float(shake[0]), float(shake[1]))
        self.origin = (float(origin[0]), float(origin[1]))
        self.turn_deg = float(turn_deg)
        self.turn = np.eye(3) if turn is None else np.asarray(turn, np.float64)
        self.layout, self.image_size, self.reduction = layout, tuple(image_size), reduction
        self.source, self._flags, self.removed = source, list(flags), dict(removed)
        self.user_image, self.refine_steps = user_image, int(refine_steps)
        self.refine_unfamiliar = None if refine_unfamiliar is None else int(refine_unfamiliar)
        self.preview = None

    @property
    def lines(self) -> list[list[int]]:
        return [list(idx) for idx in self.layout.lines]

    @property
    def flagged(self) -> list[CharacterPrediction]:
        return [c for c in self.characters if c.flags]

    @property
    def flags(self) -> list[str]:
        """The page's flags: ``"no_ink"``, ``"too_small"``, or ``"mostly_unreadable"``
        when more than half of its characters are flagged (a photo of something other
        than writing)."""
        if self._flags or not self.characters:
            return list(self._flags)
        return ["mostly_unreadable"] if 2 * len(self.flagged) > len(self.characters) else []

    def _refinement(self) -> dict:
        """The document's ``refinement``: the steps of every character, and those of the
        characters the model found unfamiliar when they differ."""
        entry = {"steps": self.refine_steps}
        if self.refine_unfamiliar is not None:
            entry["unfamiliar_steps"] = self.refine_unfamiliar
        return entry

    def _shake_entry(self) -> dict | None:
        """The document's ``shake``: the one undone, in the photo's pixels, or None."""
        if self.shake is None:
            return None
        return {"length_px": round(self.shake[0], 2), "direction_deg": round(self.shake[1], 1)}

    def to_document(self, dmps: bool = True) -> dict:
        """The page document (format ``img2dmp-page`` version 1; docs/PAGE.md); without
        the characters' ``"dmp"`` documents unless ``dmps``. Read by a stroke model, its
        entries are the characters' strokes (``"entries": "strokes"``, each entry's
        ``character`` and ``stroke`` say which), so that ``img2dmp write --page`` lifts
        the pen between them."""
        h, w = self.image_size
        strokes = any(hasattr(c.prediction, "n_strokes") for c in self.characters)
        if strokes:  # a stroke model's: one entry per stroke, each its own DMP
            entries, lines = [], [[] for _ in self.lines]
            for c in self.characters:
                for e in c.stroke_entries(dmps):
                    lines[c.character.line].append(len(entries))
                    entries.append({"index": len(entries), "line": c.character.line, **e})
        else:
            entries, lines = [c.to_dict(dmps) for c in self.characters], self.lines
        doc = {
            "format": PAGE_FORMAT,
            "version": PAGE_VERSION,
            "image": self.source,
            "image_size_px": [int(w), int(h)],
            "writing_angle_deg": round(float(self.layout.angle_deg) + self.turn_deg, 3),
            "turned_deg": round(self.turn_deg, 3),
            "character_height_px": round(float(self.layout.height_px * self.reduction), 3),
            "refinement": self._refinement(),
            "flags": self.flags,
            "removed": self.removed,
            "glare_gain": round(self.glare_gain, 3),
            "shake": self._shake_entry(),
            "lines": [{"index": i, "characters": idx} for i, idx in enumerate(lines)],
            "characters": entries,
        }
        if strokes:
            doc["entries"] = "strokes"
            doc["n_characters"] = len(self.characters)
        return doc

    def to_json(self) -> str:
        """The page document as compact JSON text (a page of 60 characters with four
        hypotheses each is a few MB; indented, Python's encoder takes seconds)."""
        import json

        return json.dumps(self.to_document(), allow_nan=False, separators=(",", ":")) + "\n"

    def save(self, out_dir: str | os.PathLike, stem: str, picture: bool = True) -> list[Path]:
        """Write ``<stem>_page.json`` and (``picture``) ``<stem>_page.png`` into
        ``out_dir``, atomically; returns the files written."""
        check_stem(stem)
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        written = [out / f"{stem}_page.json"]
        atomic_write_text(written[0], self.to_json())
        if picture:
            written.append(out / f"{stem}_page.png")
            page_picture(self, written[-1])
        return written

    def __repr__(self) -> str:
        return (
            f"PagePrediction({len(self.characters)} characters in {len(self.lines)} lines, "
            f"{len(self.flagged)} flagged, source {self.source or 'in memory'})"
        )


def _edge_shift(dx: float, dy: float) -> np.ndarray:
    m = np.eye(3)
    m[:2, 2] = dx, dy
    return m


def _character_ink(ink: np.ndarray, c: PageCharacter) -> tuple[np.ndarray, int, int]:
    """The ink of one character alone (its own pixels and the pixel around them, the
    neighbours' left out), with a little paper around it, and the crop's corner."""
    from .data.paper import dilate3

    x0, y0, x1, y1 = c.box
    h, w = ink.shape
    cx0, cy0 = max(0, x0 - _CROP_PAD_PX), max(0, y0 - _CROP_PAD_PX)
    cx1, cy1 = min(w, x1 + _CROP_PAD_PX), min(h, y1 + _CROP_PAD_PX)
    own = np.zeros((cy1 - cy0, cx1 - cx0), bool)
    own[y0 - cy0 : y1 - cy0, x0 - cx0 : x1 - cx0] = c.mask
    return np.where(dilate3(own), ink[cy0:cy1, cx0:cx1], 0.0), cx0, cy0


def _touches_border(box, shape, reduction: float) -> bool:
    x0, y0, x1, y1 = box
    margin = max(1, math.ceil(1.0 / reduction))
    return x0 < margin or y0 < margin or x1 > shape[1] - margin or y1 > shape[0] - margin


def _box_in_image(box, reduction: float, size, origin=(0.0, 0.0)) -> tuple[int, int, int, int]:
    x0, y0, x1, y1 = box
    h, w = size
    ox, oy = origin
    return (max(0, math.floor(x0 * reduction + ox)), max(0, math.floor(y0 * reduction + oy)),
            min(w, math.ceil(x1 * reduction + ox)),
            min(h, math.ceil(y1 * reduction + oy)))  # fmt: skip


def _preview(levels: np.ndarray) -> np.ndarray:
    """The page as read, as ``uint8 [h, w, 3]`` at most ``PICTURE_SIDE_PX`` on a side."""
    from PIL import Image

    rgb = levels if levels.ndim == 3 else np.repeat(levels[..., None], 3, axis=2)
    im = Image.fromarray(np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8), mode="RGB")
    scale = min(4.0, PICTURE_SIDE_PX / max(im.size))
    if scale != 1.0:
        im = im.resize((max(1, round(im.width * scale)), max(1, round(im.height * scale))),
                       Image.Resampling.BOX if scale < 1 else Image.Resampling.BICUBIC)  # fmt: skip
    return np.asarray(im)


def _frame_characters(predictor, seg, match_stroke_width):
    """Every character's model input ``[N, H, W]`` and :class:`ImageFrame` (model <->
    photo) of a :class:`PageSegmentation`."""
    width = predictor.stroke_width if match_stroke_width else None
    inputs, frames = [], []
    to_read = seg.photo_to_ink()  # photo -> page as read
    for c in seg.layout.characters:
        crop, cx0, cy0 = _character_ink(seg.ink.ink, c)
        out, edge = _images.frame_ink(crop, predictor.image_size, predictor.margin, width,
                                      f"{seg.label}: character {c.index}")  # fmt: skip
        to_model = edge @ _edge_shift(-cx0, -cy0) @ to_read
        frame = _images.ImageFrame(_images._centred(to_model), seg.size, predictor.image_size)
        frames.append(frame)
        inputs.append(out)
    return inputs, frames


@dataclass
class PageSegmentation:
    """Steps 1 and 2 of :func:`read_page`: the page as read and its characters.

    Attributes
    ----------
    levels : float array [h, w] or [h, w, 3]
        The page as read (at most ``PAGE_WORK_PIXELS``).
    reduction : float
        Photo pixels per pixel of ``levels`` (below 1: a page of small characters read
        enlarged, ``PAGE_SMALL_HEIGHT_PX``).
    size : (H, W)
        The photo's own size (upright).
    label : str
        The page's name in messages.
    ink : PaperInk or None
        The ink separated from the paper (None: nothing stands out from it), in the
        page's pixels as read: ``levels`` turned by ``turn``.
    layout : PageLayout
        The characters found on ``ink``, in reading order (empty without ink).
    turn : float64 [3, 3]
        The map of pixel-edge positions from ``levels`` to ``ink`` (the identity unless
        the page was turned level).
    turn_deg : float
        The angle of the writing that was turned level (0: read as it stands;
        ``PAGE_LEVEL_DEG``).
    sideways : float or None
        Read as it stands, its characters line up in columns better than in rows (a page
        stored sideways, or a few characters in a grid): the angle that would turn its
        columns level (counter-clockwise; the other way is 180 degrees less), for
        :func:`read_page` to read it turned too; else None.
    ink_as_it_stands : PaperInk or None
        A page turned: its ink as it stands, in the pixels of ``levels``, from which it
        is read turned another way (upside down, by :func:`read_page`); else None.
    too_small : bool
        Its characters are under ``PAGE_MIN_HEIGHT_PX`` tall in the photo: too small to
        read, and none is given (``layout`` is empty).
    origin : (x, y)
        The corner of ``levels`` in the photo's pixels (pixel edges): not (0, 0) when
        only the part of a reduced photo that holds its writing was read again at a
        finer reduction (:data:`PAGE_SMALL_HEIGHT_PX`); a photo position ``p`` (pixel
        edges) is at ``(p - origin) / reduction`` in ``levels``.
    overview : float array [h, w] or [h, w, 3] or None
        The whole photo as first read, when ``levels`` is a part of it (for the page's
        picture); else None (``levels`` is the whole photo).
    shake : (length_px, degrees) or None
        The shake undone before the ink was separated (:func:`img2dmp.data.shake.shake`),
        its length in the photo's pixels, its direction in degrees from the photo's rows
        (down the photo positive, ``[0, 180)``); None when none was read.
    """

    levels: np.ndarray
    reduction: float
    size: tuple[int, int]
    label: str
    ink: object
    layout: PageLayout
    turn: np.ndarray = field(default_factory=lambda: np.eye(3))
    turn_deg: float = 0.0
    sideways: float | None = None
    ink_as_it_stands: object = None
    too_small: bool = False
    origin: tuple[float, float] = (0.0, 0.0)
    overview: np.ndarray | None = None
    shake: tuple[float, float] | None = None

    def photo_to_levels(self) -> np.ndarray:
        """The map ``[3, 3]`` of pixel-edge positions from the photo's own pixels to
        those of ``levels``."""
        return _images._scaling(1.0 / self.reduction) @ _edge_shift(
            -self.origin[0], -self.origin[1]
        )

    def photo_to_ink(self) -> np.ndarray:
        """The map ``[3, 3]`` of pixel-edge positions from the photo's own pixels to
        those of ``ink`` and ``layout`` (the page as read, turned by ``turn``)."""
        return self.turn @ self.photo_to_levels()

    def whole(self) -> np.ndarray:
        """The whole photo as read: ``overview``, or ``levels`` when they are all of it."""
        return self.levels if self.overview is None else self.overview

    def levels_box(self, c: PageCharacter) -> tuple[int, int, int, int]:
        """Character ``c``'s box in the pixels of ``levels`` (half-open): around its own
        pixels turned back when the page was turned."""
        if not self.turn_deg:  # read as it stands
            return c.box
        ys, xs = np.nonzero(c.mask)
        back = np.linalg.inv(self.turn)
        x, y = xs + (c.box[0] + 0.5), ys + (c.box[1] + 0.5)  # the pixels' centres
        bx = back[0, 0] * x + back[0, 1] * y + back[0, 2]
        by = back[1, 0] * x + back[1, 1] * y + back[1, 2]
        return (math.floor(bx.min() - 0.5), math.floor(by.min() - 0.5),
                math.ceil(bx.max() + 0.5), math.ceil(by.max() + 0.5))  # fmt: skip

    def box_in_image(self, c: PageCharacter) -> tuple[int, int, int, int]:
        """Character ``c``'s box in the photo's own pixels (half-open)."""
        return _box_in_image(self.levels_box(c), self.reduction, self.size, self.origin)

    def touches_border(self, c: PageCharacter) -> bool:
        """Whether character ``c`` touches the photo's border (the border of ``levels``:
        of the part of the photo read, when only a part was)."""
        return _touches_border(self.levels_box(c), self.levels.shape[:2], self.reduction)


def _turn_matrix(shape, angle_deg: float) -> tuple[np.ndarray, tuple[int, int]]:
    """The map ``[3, 3]`` of pixel-edge positions from a page ``shape`` (h, w) to the same
    page turned so that lines at ``angle_deg`` lie level, about its centre, on a canvas
    that holds all of it; and that canvas's size (h, w)."""
    h, w = shape
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    out_h = math.ceil(h * abs(c) + w * abs(s) - 1e-9)
    out_w = math.ceil(w * abs(c) + h * abs(s) - 1e-9)
    turn = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    about_centre = _edge_shift(out_w / 2.0, out_h / 2.0) @ turn @ _edge_shift(-w / 2.0, -h / 2.0)
    return about_centre, (out_h, out_w)


def _turned(plane: np.ndarray, turn: np.ndarray, shape, fill: float) -> np.ndarray:
    """A ``float32 [h, w]`` plane turned by the map ``turn`` of pixel-edge positions onto
    a canvas of ``shape`` (bilinear; where the plane does not reach, ``fill``)."""
    from scipy import ndimage

    # output pixel centre -> input pixel centre, (x, y); ndimage indexes (row, column)
    m = _edge_shift(-0.5, -0.5) @ np.linalg.inv(turn) @ _edge_shift(0.5, 0.5)
    return ndimage.affine_transform(np.asarray(plane, np.float32), m[[1, 0]][:, [1, 0]],
                                    m[[1, 0], 2], output_shape=shape, order=1,
                                    cval=float(fill))  # fmt: skip


def _read_turned(levels: np.ndarray, found, angle_deg: float):
    """The ink of a page turned so that its lines at ``angle_deg`` lie level, and the map
    of :func:`_turn_matrix` (None when nothing stands out there).

    The turned page's ink is separated again, so that rules, level there, are found where
    they are looked for; ink is kept only where the page as it stands had it too
    (``found``: its sheet's edge, the desk and the specks stay removed, and the corners
    that the photo does not cover, shaded as its border, add nothing)."""
    from dataclasses import replace

    from .data.paper import dilate3

    turn, shape = _turn_matrix(levels.shape[:2], angle_deg)
    planes = levels[..., None] if levels.ndim == 2 else levels
    border = np.concatenate([planes[0], planes[-1], planes[:, 0], planes[:, -1]])
    turned = np.stack([_turned(planes[..., k], turn, shape, float(np.median(border[:, k])))
                       for k in range(planes.shape[2])], axis=2)  # fmt: skip
    # the sheet looked for at the page's own reduction: the canvas is larger, its rules
    # lie no farther apart (reduced 5 times instead of 3, a 22-px grid came too close for
    # the rule test, and the sheet was lost)
    again = paper_ink(turned[..., 0] if levels.ndim == 2 else turned,
                      sheet_factor=sheet_factor(levels.shape))  # fmt: skip
    if again is None:
        return None
    before = dilate3(_turned(found.mask, turn, shape, 0.0) > 0.25)
    mask = again.mask & before
    if not mask.any():
        return None
    ink = np.where(before, again.ink, 0).astype(again.ink.dtype)
    return replace(again, mask=mask, ink=ink), turn


#: Up to this many characters, every pair of centres is compared for the angle of the
#: lines; beyond, their counts in bins of a quarter of the pairs' reach (pairs cost 0.5 s
#: for a page of 1,360; every k-th character, a sample, can line up better in columns
#: or along a diagonal of a regular page than in its rows).
_ANGLE_PAIRS = 400
_ANGLE_BIN = 0.25
_ANGLE_KERNEL = np.exp(-0.5 * (np.arange(-16, 17) * _ANGLE_BIN) ** 2)


def _lines_angle(layout: PageLayout, max_deg: float, columns: bool = False) -> tuple[float, float]:
    """The angle (degrees, within +-``max_deg``, the sign of
    :func:`img2dmp.data.paper.dominant_angle`) along which the characters' centres line
    up best, and how well: the shear ``y - x tan(angle)`` under which most pairs of
    centres lie within a sixth of a character's height of each other (a smooth count of
    the pairs). The centres, not the ink: italic strokes and a stroke's own slope do not
    move them. ``columns``: x and y swapped (lines running down the page, as on a page
    photographed sideways)."""
    chars = layout.characters
    x = np.array([(c.box[0] + c.box[2]) / 2.0 for c in chars])
    y = np.array([(c.box[1] + c.box[3]) / 2.0 for c in chars])
    x, y = (y, x) if columns else (x, y)
    width = max(1.0, layout.height_px / 6.0)

    def score(deg: float) -> float:
        across = (y - x * math.tan(math.radians(deg))) / width
        if across.size <= _ANGLE_PAIRS:
            d = across[:, None] - across[None, :]
            return float(np.exp(-0.5 * d * d).sum())
        counts = np.bincount(np.round((across - across.min()) / _ANGLE_BIN).astype(np.int64))
        counts = counts.astype(np.float64)
        return float(counts @ np.convolve(counts, _ANGLE_KERNEL, mode="same"))

    coarse = np.arange(-max_deg, max_deg + 1e-9, 0.5)
    best = coarse[int(np.argmax([score(d) for d in coarse]))]
    fine = np.clip(best + np.arange(-0.5, 0.5 + 1e-9, 0.1), -max_deg, max_deg)
    scores = [score(d) for d in fine]
    return float(fine[int(np.argmax(scores))]), max(scores)


def _find_on(found, cut: bool, join_sides: bool) -> PageLayout:
    return find_characters(found.mask, core=found.core, grow=_grow(found.pen_width_px),
                           cut=cut, join_sides=join_sides)  # fmt: skip


def segment_page(image, *, name: str | None = None, cut: bool = True, join_sides: bool = False,
                 turn_deg: float | None = None) -> PageSegmentation:  # fmt: skip
    """The page read upright at most ``PAGE_WORK_PIXELS``, its ink separated from the paper
    and its characters found (:func:`read_page`'s steps 1 and 2, without a model).

    Parameters
    ----------
    image : path, PIL image or array
        As :func:`read_page` takes it.
    name : str, optional
        Names an array or PIL image in messages.
    cut : bool
        Cut wide marks into characters and at their waists (touching digits; default);
        False keeps each mark whole (:func:`img2dmp.data.pages.find_characters`).
    join_sides : bool
        Join neighbours that nearly touch side by side into one character when together
        they are about one character wide (letters of pieces side by side; default False).
    turn_deg : float, optional
        Turn the page by this angle (degrees; its lines at this angle made level) before
        its characters are found; 0: read it as it stands. Default: found from the
        characters (docs/PAGE.md, "A page photographed askew or sideways").
    """
    read = _images._read_levels(image, name, PAGE_WORK_PIXELS)
    levels, reduction, size, label = read.levels, read.reduction, read.size, read.label
    moved = shake(levels)  # a shaken photo's blur undone (img2dmp.data.shake)
    levels = levels if moved is None else steadied(levels, moved)
    found = paper_ink(levels)
    if found is None:
        return PageSegmentation(levels, reduction, size, label, None,
                                PageLayout(shape=levels.shape[:2]),
                                shake=_in_photo(moved, reduction))  # fmt: skip
    seg = PageSegmentation(levels, reduction, size, label, found, _find_on(found, cut, join_sides),
                           shake=_in_photo(moved, reduction))  # fmt: skip
    seg = _finer(seg, image, name, read.white, cut, join_sides)
    seg = _enlarged(seg, cut, join_sides)
    if seg.layout.characters and seg.layout.height_px * seg.reduction < PAGE_MIN_HEIGHT_PX:
        seg.layout, seg.too_small = PageLayout(shape=seg.layout.shape), True
        return seg
    if turn_deg is None:
        turn_deg, seg.sideways = _page_turn(seg.layout)
    return _turned_segmentation(seg, turn_deg, cut, join_sides) if turn_deg else seg


def _in_photo(moved, reduction: float) -> tuple[float, float] | None:
    """A :class:`img2dmp.data.shake.Shake` read at ``reduction``, in the photo's pixels."""
    return None if moved is None else (float(moved.length) * reduction, float(moved.degrees))


def _writing_box(seg: PageSegmentation) -> tuple[float, float, float, float]:
    """The part of the photo (its pixels, ``(x0, y0, x1, y1)``) that holds the characters
    found on ``seg`` (read as it stands), with ``PAGE_FINER_MARGIN`` character heights of
    paper around them (at least ``PAGE_FINER_MARGIN_SHARE`` of the page's shorter side)."""
    boxes = np.array([c.box for c in seg.layout.characters], np.float64)
    h, w = seg.levels.shape[:2]
    pad = max(PAGE_FINER_MARGIN * seg.layout.height_px, PAGE_FINER_MARGIN_SHARE * min(h, w))
    x0, y0 = max(0.0, boxes[:, 0].min() - pad), max(0.0, boxes[:, 1].min() - pad)
    x1, y1 = min(float(w), boxes[:, 2].max() + pad), min(float(h), boxes[:, 3].max() + pad)
    r, (ox, oy) = seg.reduction, seg.origin
    return x0 * r + ox, y0 * r + oy, x1 * r + ox, y1 * r + oy


def _finer(seg: PageSegmentation, image, name, white: float, cut: bool,
           join_sides: bool) -> PageSegmentation:  # fmt: skip
    """A reduced photo (``reduction`` above 1) whose characters come out under
    ``PAGE_SMALL_HEIGHT_PX`` read again from ``image`` at a finer reduction: the part
    that holds its writing (:func:`_writing_box`), at most ``PAGE_WORK_PIXELS``, its
    levels divided by the first reading's ``white``; ``seg`` itself when the photo was
    not reduced, its characters are not small, that part allows no finer reading, or no
    character is found there."""
    if seg.reduction <= 1 or not 0 < seg.layout.height_px < PAGE_SMALL_HEIGHT_PX:
        return seg
    box = _writing_box(seg)
    finer = math.ceil(math.sqrt((box[2] - box[0]) * (box[3] - box[1]) / PAGE_WORK_PIXELS))
    if PAGE_FINER_GAIN * finer > seg.reduction:
        return seg
    read = _images._read_levels(image, name, PAGE_WORK_PIXELS, box, white)
    moved = shake(read.levels)
    levels = read.levels if moved is None else steadied(read.levels, moved)
    found = paper_ink(levels)
    layout = None if found is None else _find_on(found, cut, join_sides)
    if layout is None or not layout.characters:
        return seg
    return PageSegmentation(levels, read.reduction, seg.size, seg.label, found, layout,
                            origin=read.origin, overview=seg.levels,
                            shake=_in_photo(moved, read.reduction))  # fmt: skip


def _enlargement(height_px: float, pixels: int) -> int:
    """The whole factor a page of ``pixels`` whose characters are ``height_px`` tall is
    read enlarged by (``PAGE_SMALL_HEIGHT_PX``; 1: as it is)."""
    if not 0 < height_px < PAGE_SMALL_HEIGHT_PX:
        return 1
    factor = min(PAGE_ENLARGE_MAX, math.ceil(PAGE_SMALL_HEIGHT_PX / height_px))
    return max(1, min(factor, math.isqrt(PAGE_WORK_PIXELS // max(1, pixels))))


def _enlarged(seg: PageSegmentation, cut: bool, join_sides: bool) -> PageSegmentation:
    """``seg`` read again enlarged when its characters are small (``PAGE_SMALL_HEIGHT_PX``),
    ``reduction`` then below 1; else ``seg`` itself (and when nothing stands out there)."""
    from scipy.ndimage import zoom

    factor = _enlargement(seg.layout.height_px, seg.levels.shape[0] * seg.levels.shape[1])
    if factor == 1:
        return seg
    scale = (factor, factor) + (1,) * (seg.levels.ndim - 2)
    # grid_mode: pixel edges map onto pixel edges, as ``reduction`` takes them
    levels = zoom(seg.levels, scale, order=3, mode="nearest", grid_mode=True)
    levels = np.clip(levels, 0.0, 1.0).astype(np.float32)
    found = paper_ink(levels)
    if found is None:
        return seg
    return PageSegmentation(levels, seg.reduction / factor, seg.size, seg.label, found,
                            _find_on(found, cut, join_sides), origin=seg.origin,
                            overview=seg.overview, shake=seg.shake)  # fmt: skip


def _turned_segmentation(seg: PageSegmentation, turn_deg: float, cut: bool,
                         join_sides: bool) -> PageSegmentation:  # fmt: skip
    """``seg`` with its characters found on the page turned by ``turn_deg`` from where
    it stands (a photo taken askew or sideways); ``seg`` itself when nothing stands out
    there. A page read turned is turned another way from its ink as it stands (its
    turned ink, turned again, was laid on the photo's pixels askew: an upside-down page
    first turned level lost all but one of its 14 characters)."""
    stands = seg.ink if seg.ink_as_it_stands is None else seg.ink_as_it_stands
    read = _read_turned(seg.levels, stands, float(turn_deg))
    if read is None:
        return seg
    found, turn = read
    return PageSegmentation(seg.levels, seg.reduction, seg.size, seg.label, found,
                            _find_on(found, cut, join_sides), turn, float(turn_deg),
                            ink_as_it_stands=stands, origin=seg.origin,
                            overview=seg.overview, shake=seg.shake)  # fmt: skip


def _page_turn(layout: PageLayout) -> tuple[float, float | None]:
    """The angle a page is turned by before its characters are found: its lines' when
    they slope more than ``PAGE_LEVEL_DEG`` (else 0); and, when they line up in columns
    better than in rows (``PAGE_SIDEWAYS_RATIO``), the angle that would turn the columns
    level (else None). A few characters in a grid line up both ways: whether the page is
    sideways, the model's reading decides (:func:`read_page`)."""
    if len(layout.characters) < PAGE_TURN_MIN_CHARACTERS:
        return 0.0, None
    skew, rows = _lines_angle(layout, PAGE_MAX_TURN_DEG)
    down, columns = _lines_angle(layout, PAGE_MAX_TURN_DEG, columns=True)
    if columns > PAGE_SIDEWAYS_RATIO * rows:
        return 0.0, 90.0 - down  # columns at ``down`` from the vertical: lines at 90 - down
    return (skew if abs(skew) > PAGE_LEVEL_DEG else 0.0), None


def read_page(predictor, image, *, n_points: int = 100, match_stroke_width: bool = True,
              name: str | None = None) -> PagePrediction:  # fmt: skip
    """Every character of a page (module docstring).

    Parameters
    ----------
    predictor : Predictor
        A loaded model (its refinement, if set, refines every character).
    image : path, PIL image or array
        The photo or scan (any size up to PIL's limit; read upright, at most
        ``PAGE_WORK_PIXELS``), dark ink on light paper or light on dark.
    n_points : int
        Samples of each character's trajectory over its own ``[0, tau]``.
    match_stroke_width : bool
        Bring each character's strokes to the training images' pen width.
    name : str, optional
        Names an array or PIL image in messages.
    """
    from .predict import MAX_POINTS, check_count

    n_points = check_count("n_points (--points)", n_points, 2, MAX_POINTS)
    letters = predictor.reads_letters
    cut, join_sides = not letters or STROKE_PAGE_CUT, letters and STROKE_PAGE_JOIN
    seg = segment_page(image, name=name, cut=cut, join_sides=join_sides)
    page = _read_segmentation(predictor, seg, image, n_points, match_stroke_width)
    # Its characters line up in columns: read it turned a quarter each way too. Many of
    # its characters flagged: read it upside down too. A turned reading is kept when it
    # flags clearly fewer characters (PAGE_SIDEWAYS_GAIN).
    how = (n_points, match_stroke_width, cut, join_sides)
    angles = [] if seg.sideways is None else [seg.sideways, seg.sideways - 180.0]
    best = _best_reading(predictor, seg, image, how, page, angles)
    if _flagged_share(best) < PAGE_UPSIDE_DOWN_SHARE or not best.characters:
        return best
    upside_down = best.turn_deg + 180.0 if best.turn_deg <= 0.0 else best.turn_deg - 180.0
    return _best_reading(predictor, seg, image, how, best, [upside_down])


def _best_reading(predictor, seg, image, how, page: PagePrediction, angles) -> PagePrediction:
    """``page`` or the reading of ``seg`` turned by one of ``angles`` that flags the
    smallest share of characters, below ``PAGE_SIDEWAYS_GAIN`` of ``page``'s, and reads
    no fewer characters unflagged than ``page`` (a turned reading that lost characters
    is no better for flagging few of the rest); ``how``:
    ``(n_points, match_stroke_width, cut, join_sides)``."""
    n_points, match_stroke_width, cut, join_sides = how
    best, share = page, _flagged_share(page)
    for angle in angles:
        turned = _turned_segmentation(seg, angle, cut, join_sides)
        if turned.turn_deg:
            other = _read_segmentation(predictor, turned, image, n_points, match_stroke_width)
            fewer = _flagged_share(other) < min(share, PAGE_SIDEWAYS_GAIN * _flagged_share(page))
            if fewer and _unflagged(other) >= _unflagged(page):
                best, share = other, _flagged_share(other)
    return best


def _unflagged(page: PagePrediction) -> int:
    return len(page.characters) - len(page.flagged)


def _flagged_share(page: PagePrediction) -> float:
    return len(page.flagged) / len(page.characters) if page.characters else 1.0


def _read_segmentation(predictor, seg, image, n_points, match_stroke_width) -> PagePrediction:
    """:func:`read_page`'s steps 3 and 4 on a :class:`PageSegmentation`."""
    reduction, size, found = seg.reduction, seg.size, seg.ink
    source = str(image) if isinstance(image, (str, os.PathLike)) else None
    o = predictor.refine_options
    steps, unfamiliar = (0, None) if o is None else (o.steps, predictor.refine_unfamiliar)
    page_flags = ["no_ink"] if found is None else ["too_small"] if seg.too_small else []
    page = PagePrediction([], seg.layout, size, reduction, source, page_flags,
                          {} if found is None else found.removed, refine_steps=steps,
                          refine_unfamiliar=unfamiliar, turn_deg=seg.turn_deg,
                          turn=seg.turn, origin=seg.origin,
                          glare_gain=1.0 if found is None else found.glare_gain,
                          shake=seg.shake)  # fmt: skip
    page.preview = _preview(seg.whole())
    if found is None or not page.layout.characters:
        return page
    inputs, frames = _frame_characters(predictor, seg, match_stroke_width)
    if predictor.strokes is not None:
        preds = _stroke_predictions(predictor, inputs, frames, source, n_points)
    else:
        preds = _dmp_predictions(predictor, inputs, frames, source, n_points)
    for c, pred in zip(page.layout.characters, preds, strict=True):
        flags = list(pred.flags) + (["cut_by_border"] if seg.touches_border(c) else [])
        page.characters.append(CharacterPrediction(c, seg.box_in_image(c), pred, flags))
    return page


def _stroke_predictions(predictor, inputs, frames, source, n_points) -> list:
    """A stroke model's characters (:class:`~img2dmp.predict.StrokePrediction`), all read
    (and refined) in one batch."""
    from .predict import StrokePrediction

    images = np.stack(inputs)
    strokes, counts = predictor.predict_strokes(images, return_counts=True)
    familiar, line = _familiarities(predictor, images)
    steps = predictor.refine_steps_for(images, familiarity=None if line is None else familiar)
    return [StrokePrediction(s, predictor.normaliser, predictor.strokes, frame, x,
                             source=source, refine_steps=n,
                             stroke_width_px=predictor.stroke_width, n_per_stroke=n_points,
                             count_views=predictor.count_views, count_probabilities=p,
                             familiarity=f, familiar_line=line)
            for s, p, f, n, frame, x in zip(strokes, counts, familiar, steps, frames, inputs,
                                            strict=True)]  # fmt: skip


def _dmp_predictions(predictor, inputs, frames, source, n_points) -> list:
    """A one-DMP model's characters (:class:`~img2dmp.predict.Prediction`, ranked
    hypotheses), all in one batch."""
    from .predict import Prediction

    # refined: the top hypothesis, the one written (PAGE_REFINE_TOP_ONLY)
    images = np.stack(inputs)
    params, probs = predictor.predict_hypotheses(images, refine_top_only=PAGE_REFINE_TOP_ONLY)
    times, paths = predictor.trajectories(params, n_points=n_points)  # [N, K, T], [N, K, T, d]
    familiar, line = _familiarities(predictor, images)
    steps = predictor.refine_steps_for(images, familiarity=None if line is None else familiar)
    return [Prediction(params[i], probs[i], times[i], paths[i], frames[i], predictor.dmp_config,
                       inputs[i], source=source, refine_steps=steps[i],
                       stroke_width_px=predictor.stroke_width, familiarity=familiar[i],
                       familiar_line=line)
            for i in range(len(inputs))]  # fmt: skip


def _familiarities(predictor, images) -> tuple[list, float | None]:
    """Each image's familiarity to the predictor's model (None each when it carries
    none) and the model's line."""
    if predictor.familiar is None:
        return [None] * len(images), None
    return list(predictor.familiarity(images)), predictor.familiar.line


def _grow(pen_width_px: float) -> int:
    """Pixels from a stroke's core to its edge: half the pen, at least two."""
    return max(2, math.ceil(0.5 * pen_width_px))


#: Box colours of successive lines in the page picture; flagged characters are red.
_LINE_COLOURS = ((0, 114, 178), (0, 158, 115), (204, 121, 167), (230, 159, 0), (86, 180, 233))
_FLAGGED = (213, 0, 0)
_PATH = (255, 0, 160)


def page_picture(page: PagePrediction, path: str | os.PathLike) -> None:
    """``path`` (PNG): the page with every character's box (coloured by line, red when
    flagged), its index in reading order and its predicted path (top hypothesis, pen
    down), written atomically."""
    import io

    from PIL import Image, ImageDraw

    im = Image.fromarray(page.preview).convert("RGB")
    draw = ImageDraw.Draw(im)
    s = im.width / page.image_size[1]  # picture pixels per photo pixel
    lw = max(1, round(im.width / 600))
    for ch in page.characters:
        x0, y0, x1, y1 = (v * s for v in ch.box_image)
        colour = _FLAGGED if ch.flags else _LINE_COLOURS[ch.character.line % len(_LINE_COLOURS)]
        draw.rectangle([x0, y0, x1, y1], outline=colour, width=lw)
        draw.text((x0 + 1, y1 + 1), str(ch.character.index), fill=colour)
        xy = (ch.prediction.path_image[0][:, :2] + 0.5) * s - 0.5
        pen = ch.pen()
        d = np.diff(np.concatenate([[0], pen, [0]]))
        for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True):
            if b - a > 1:  # one polyline per pen-down stroke
                draw.line([tuple(p) for p in xy[a:b]], fill=_PATH, width=lw, joint="curve")
    buf = io.BytesIO()
    im.save(buf, format="PNG", compress_level=3)
    atomic_write_bytes(path, buf.getvalue())


__all__ = [
    "PAGE_FORMAT",
    "PAGE_VERSION",
    "PAGE_WORK_PIXELS",
    "CharacterPrediction",
    "PagePrediction",
    "PageSegmentation",
    "page_picture",
    "read_page",
    "segment_page",
]
