"""The page document ``img2dmp write --page`` reads: every character of a handwritten page.

``img2dmp predict PHOTO --page --out DIR`` writes it (``DIR/<stem>_page.json``), and
``Predictor.predict_page(PHOTO).to_document()`` returns it. Format ``"img2dmp-page"``,
version 1::

    {"format": "img2dmp-page", "version": 1,
     "image": "<the photo's path>" | null, "image_size_px": [W, H],
     "turned_deg": 0.0,            # optional: read turned level by this angle, written level
     "lines": [{"index": 0, "characters": [0, 1, 2]}, ...],   # top to bottom
     "characters": [                                          # in reading order
       {"index": 0, "line": 0,
        "box_image_px": [x0, y0, x1, y1],  # half-open integer pixel bounds in the photo
        "path_image_px": [[x, y], ...],    # the top hypothesis' path in the photo's pixels
        "pen": [1, 1, ..., 0, 1],          # one per path point, 1 down, 0 up
        "times_s": [...],                  # one per path point
        "confidence": 0.93, "fit": {"path_on_ink": 0.97, "ink_written": 0.95},
        "flags": [],                       # e.g. ["no_ink"]: still in the list
        "dmp": {...}}, ...]}               # the character's DMP file (img2dmp-dmp, v2)

Positions are the photo's pixels (x = column, y = row, the centre of pixel ``[i, j]`` at
``(j, i)``; docs/CONTRACTS.md). Each ``dmp`` is the document of the one DMP file
(:mod:`img2dmp.data.dmpfile`), checked by its own reader; its ``params`` are in the
model's frame, and its ``image_frame`` maps that frame to the photo (whose size must be
the page's ``image_size_px``). The robot writes the top hypothesis in the photo's
pixels: its ``params_image`` when the file gives it, else ``params`` mapped by
``image_frame.model_to_image`` (:func:`img2dmp.dmp.affine.affine_dmp`, exact). A DMP
made in the photo's own pixels (``"frame": "image"``, the photo's ``image_size``, no
``image_frame``) is written as it is.

Reading is strict in the way of the DMP file: every number a finite JSON number, every
field of the format present, indices that agree (``characters[i].index`` is ``i``, each
``line`` a line that lists the character, the lines together listing ``0 .. n - 1`` in
order, boxes inside the photo, one ``pen`` and one time per path point). Other keys, at
the top or in a character, are kept as notes and ignored. Every error is one line
naming the file and the field, e.g. ``page.json: field 'characters[2].box_image_px'
must be [x0, y0, x1, y1] with 0 <= x0 < x1 <= 300 and 0 <= y0 < y1 <= 120, got [...]``.
The path, pen and times are read and checked, but the robot executes the DMP.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from .._files import check_readable, parse_json
from ..data.dmpfile import DMPFile, box_around_px, check_dmp_document
from ..dmp import DMPParams
from ..dmp.affine import affine_dmp
from ..dmp.params import show_value, strict_numbers

FORMAT = "img2dmp-page"
VERSION = 1
# A page of a few hundred characters with two hypotheses each is a few MB.
MAX_FILE_BYTES = 64 << 20
MAX_CHARACTERS = 5000
#: Largest coordinate of a path point, pixels (as a DMP file's values: 1e9).
MAX_POSITION_PX = 1e9
TOP_FIELDS = ("format", "version", "image", "image_size_px", "lines", "characters")
CHARACTER_FIELDS = (
    "index",
    "line",
    "box_image_px",
    "path_image_px",
    "pen",
    "times_s",
    "confidence",
    "fit",
    "flags",
    "dmp",
)
FIT_FIELDS = ("path_on_ink", "ink_written")


def _bad(path, where: str, why: str) -> ValueError:
    return ValueError(f"{path}: field {where!r} {why}")


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


@dataclass(frozen=True)
class PageCharacter:
    """One character of a page document, checked.

    Attributes
    ----------
    index, line : int
        Its place in reading order and the line it is on.
    box_image_px : (x0, y0, x1, y1)
        Half-open integer pixel bounds in the photo (columns ``x0 <= j < x1``).
    path_image_px : ndarray [T, 2]
        The top hypothesis' path in the photo's pixels (as the document gives it).
    pen : ndarray [T] bool
        Pen down per path point.
    times_s : ndarray [T]
    confidence : float
    fit : dict
        ``path_on_ink``, ``ink_written`` (numbers in [0, 1] or None) and any others given.
    flags : tuple of str
        E.g. ``("no_ink",)``; empty for a character read without doubt.
    dmp : DMPFile
        The character's DMP file, read by :func:`img2dmp.data.dmpfile.check_dmp_document`.
    params_image : DMPParams
        The top hypothesis in the photo's pixels: what the robot writes.
    """

    index: int
    line: int
    box_image_px: tuple[int, int, int, int]
    path_image_px: np.ndarray
    pen: np.ndarray
    times_s: np.ndarray
    confidence: float
    fit: dict
    flags: tuple[str, ...]
    dmp: DMPFile = field(repr=False)
    params_image: DMPParams = field(repr=False)

    @property
    def config(self):
        """The DMP constants of :attr:`params_image`."""
        return self.dmp.config


@dataclass(frozen=True)
class Page:
    """A page document, checked (module docstring).

    Attributes
    ----------
    path : str
        Where it was read from (or what it was called), for messages.
    image : str or None
        The photo's path as the document gives it.
    image_size_px : (W, H)
        The photo's size.
    lines : tuple of tuple of int
        Per line (top to bottom) the indices of its characters (left to right).
    characters : tuple of PageCharacter
        In reading order.
    document : dict
        The document as read (notes included).
    turned_deg : float
        The angle the page was turned by to read its lines level (the document's
        optional ``turned_deg``, counter-clockwise as seen; 0: read as it stands). The
        robot writes the page turned the same way, level on the paper.
    """

    path: str
    image: str | None
    image_size_px: tuple[int, int]
    lines: tuple
    characters: tuple
    document: dict = field(default_factory=dict, repr=False)
    turned_deg: float = 0.0

    @property
    def written_area_px(self) -> tuple[int, int, int, int]:
        """``(x0, y0, x1, y1)``: the union of the characters' boxes (half-open); the
        whole photo for a page without characters."""
        if not self.characters:
            w, h = self.image_size_px
            return (0, 0, w, h)
        boxes = np.array([c.box_image_px for c in self.characters])  # [n, 4]
        x0, y0 = boxes[:, :2].min(axis=0)
        x1, y1 = boxes[:, 2:].max(axis=0)
        return (int(x0), int(y0), int(x1), int(y1))


def _check_header(path: str, doc: dict) -> tuple:
    """Format, version, image and image size; ``(image, (W, H))``."""
    if doc.get("format") != FORMAT:
        raise _bad(path, "format", f"must be {FORMAT!r}, got {show_value(doc.get('format'))}")
    v = doc.get("version")
    if not _is_int(v) or v < 1:
        raise _bad(path, "version", f"must be a whole number >= 1, got {show_value(v)}")
    if v > VERSION:
        raise _bad(
            path,
            "version",
            f"is {v}: written by a newer img2dmp; this one reads page version {VERSION}",
        )
    missing = [k for k in TOP_FIELDS if k not in doc]
    if missing:
        raise _bad(path, missing[0], "is missing")
    image = doc["image"]
    if image is not None and not isinstance(image, str):
        raise _bad(path, "image", f"must be the photo's path or null, got {show_value(image)}")
    size = doc["image_size_px"]
    if not (isinstance(size, list) and len(size) == 2 and all(_is_int(s) and s > 0 for s in size)):
        raise _bad(
            path, "image_size_px", f"must be [W, H], two positive integers, got {show_value(size)}"
        )
    return image, (size[0], size[1])


def _check_lines(path: str, raw, n_characters: int) -> tuple:
    """The lines, each an object {index, characters}; together they list the characters
    ``0 .. n - 1`` in reading order."""
    if not isinstance(raw, list):
        raise _bad(path, "lines", f"must be a list, got {show_value(raw)}")
    lines = []
    for i, line in enumerate(raw):
        where = f"lines[{i}]"
        if not isinstance(line, dict) or "index" not in line or "characters" not in line:
            raise _bad(
                path, where, f"must be an object with index and characters, got {show_value(line)}"
            )
        if not _is_int(line["index"]) or line["index"] != i:
            raise _bad(path, f"{where}.index", f"must be {i}, got {show_value(line['index'])}")
        chars = line["characters"]
        if not (isinstance(chars, list) and all(_is_int(c) for c in chars)):
            raise _bad(
                path,
                f"{where}.characters",
                f"must be a list of character indices, got {show_value(chars)}",
            )
        lines.append(tuple(chars))
    listed = [c for chars in lines for c in chars]
    if listed != list(range(n_characters)):
        raise _bad(
            path,
            "lines",
            f"must list the {n_characters} characters once each in reading order (0 .. "
            f"{n_characters - 1}, line by line), got {show_value(listed)}",
        )
    return tuple(lines)


def _box(path: str, where: str, raw, size: tuple[int, int]) -> tuple[int, int, int, int]:
    w, h = size
    ok = isinstance(raw, list) and len(raw) == 4 and all(_is_int(v) for v in raw)
    if ok:
        x0, y0, x1, y1 = raw
        ok = 0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h
    if not ok:
        raise _bad(
            path,
            where,
            f"must be [x0, y0, x1, y1], integers with 0 <= x0 < x1 <= {w} and "
            f"0 <= y0 < y1 <= {h} (half-open pixel bounds in the photo), got {show_value(raw)}",
        )
    return tuple(raw)


def _samples(path: str, where: str, raw) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``path_image_px [T, 2]``, ``pen [T]`` and ``times_s [T]`` of a character."""
    out = {}
    for key in ("path_image_px", "pen", "times_s"):
        try:
            out[key] = strict_numbers(f"field '{where}.{key}'", raw[key])
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None
    xy, pen, t = out["path_image_px"], out["pen"], out["times_s"]
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) < 1:
        raise _bad(
            path, f"{where}.path_image_px", f"must be [T][2] points, got shape {list(xy.shape)}"
        )
    if np.abs(xy).max() > MAX_POSITION_PX:  # 1e308 was planned and written (an audit)
        k = int(np.abs(xy).max(axis=1).argmax())
        raise _bad(path, f"{where}.path_image_px", f"point {k} is {xy[k].tolist()}, beyond "
                   f"the {MAX_POSITION_PX:g} px a photo's position may be")  # fmt: skip
    for key, a in (("pen", pen), ("times_s", t)):
        if a.shape != (len(xy),):
            raise _bad(
                path,
                f"{where}.{key}",
                f"must have one entry per path point ({len(xy)}), got shape {list(a.shape)}",
            )
    if not np.isin(pen, (0.0, 1.0)).all():
        raise _bad(path, f"{where}.pen", "must hold 1 (pen down) or 0 (pen up) per point")
    if np.any(np.diff(t) < 0):
        raise _bad(path, f"{where}.times_s", "must not decrease")
    return xy, pen.astype(bool), t


def _scores(path: str, where: str, raw: dict) -> tuple[float, dict, tuple[str, ...]]:
    """``confidence``, ``fit`` and ``flags`` of a character."""
    c = raw["confidence"]
    if not (_is_number(c) and 0.0 <= c <= 1.0):
        raise _bad(path, f"{where}.confidence", f"must be a number in [0, 1], got {show_value(c)}")
    fit = raw["fit"]
    if not isinstance(fit, dict) or any(k not in fit for k in FIT_FIELDS):
        raise _bad(
            path,
            f"{where}.fit",
            f"must be an object with {', '.join(FIT_FIELDS)}, got {show_value(fit)}",
        )
    for k, v in fit.items():
        if v is not None and not (_is_number(v) and 0.0 <= v <= 1.0):
            raise _bad(
                path, f"{where}.fit.{k}", f"must be a number in [0, 1] or null, got {show_value(v)}"
            )
    flags = raw["flags"]
    if not (isinstance(flags, list) and all(isinstance(f, str) and f for f in flags)):
        raise _bad(path, f"{where}.flags", f"must be a list of names, got {show_value(flags)}")
    return float(c), dict(fit), tuple(flags)


def _character_dmp(path: str, where: str, raw, size: tuple[int, int]):
    """The character's DMP file (checked by the DMP file's reader) and its top
    hypothesis in the photo's pixels."""
    if not isinstance(raw, dict):
        raise _bad(
            path, f"{where}.dmp", f"must be a DMP document (an object), got {show_value(raw)}"
        )
    dmp = check_dmp_document(raw, f"{path}: {where}.dmp")
    w, h = size
    if dmp.image_frame is None:
        if dmp.frame == "image" and tuple(dmp.image_size) == (h, w):
            return dmp, dmp.params  # a DMP made in the photo's own pixels
        raise _bad(
            path,
            f"{where}.dmp.image_frame",
            "is missing: a page's DMP needs the map from the model's frame to the photo "
            '(or "frame": "image" with the photo\'s image_size)',
        )
    if tuple(dmp.image_frame.image_size) != (h, w):
        raise _bad(
            path,
            f"{where}.dmp.image_frame.image_size",
            f"is {list(dmp.image_frame.image_size)} ([H, W]), but the page's image_size_px is "
            f"[{w}, {h}] ([W, H]): the DMP is not in this photo's pixels",
        )
    if dmp.hypotheses_image is not None:
        return dmp, dmp.hypotheses_image[0]
    return dmp, affine_dmp(dmp.params, dmp.config, dmp.image_frame.model_to_image)


def _check_character(path: str, i: int, raw, size, lines: tuple) -> PageCharacter:
    where = f"characters[{i}]"
    if not isinstance(raw, dict):
        raise _bad(path, where, f"must be an object, got {show_value(raw)}")
    missing = [k for k in CHARACTER_FIELDS if k not in raw]
    if missing:
        raise _bad(path, f"{where}.{missing[0]}", "is missing")
    if not _is_int(raw["index"]) or raw["index"] != i:
        raise _bad(
            path, f"{where}.index", f"must be {i} (reading order), got {show_value(raw['index'])}"
        )
    line = raw["line"]
    if not (_is_int(line) and 0 <= line < len(lines) and i in lines[line]):
        raise _bad(
            path,
            f"{where}.line",
            f"must be the index of the line that lists it, got {show_value(line)}",
        )
    box = _box(path, f"{where}.box_image_px", raw["box_image_px"], size)
    xy, pen, t = _samples(path, where, raw)
    confidence, fit, flags = _scores(path, where, raw)
    dmp, params_image = _character_dmp(path, where, raw["dmp"], size)
    return PageCharacter(i, line, box, xy, pen, t, confidence, fit, flags, dmp, params_image)


def check_page_document(doc, path: str = "page document") -> Page:
    """Check a page document (a dict as :func:`json.loads` gives it; the format in the
    module docstring) and return it as a :class:`Page`; ``ValueError`` naming ``path``,
    the field and the value otherwise."""
    path = os.fspath(path)
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: expected a JSON object at the top level, got {show_value(doc)}")
    image, size = _check_header(path, doc)
    raw_chars = doc["characters"]
    if not isinstance(raw_chars, list):
        raise _bad(path, "characters", f"must be a list, got {show_value(raw_chars)}")
    if len(raw_chars) > MAX_CHARACTERS:
        raise _bad(
            path,
            "characters",
            f"has {len(raw_chars)} entries, more than the {MAX_CHARACTERS} a page may have",
        )
    lines = _check_lines(path, doc["lines"], len(raw_chars))
    chars = tuple(_check_character(path, i, c, size, lines) for i, c in enumerate(raw_chars))
    return Page(path, image, size, lines, chars, doc, _turned_deg(path, doc))


def _turned_deg(path: str, doc: dict) -> float:
    """The optional ``turned_deg`` (0 when absent), a number of degrees in [-180, 180]."""
    v = doc.get("turned_deg", 0.0)
    if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            and -180.0 <= v <= 180.0):  # fmt: skip
        raise _bad(path, "turned_deg", f"must be a number of degrees in [-180, 180], got "
                                       f"{show_value(v)}")  # fmt: skip
    return float(v)


#: The format of a stroke model's prediction (:data:`img2dmp.predict.STROKES_FORMAT`,
#: docs/TRAINING.md), which :func:`strokes_page_document` turns into a page of its strokes.
STROKES_FORMAT = "img2dmp-strokes"
STROKES_VERSION = 1
#: Points of each stroke's path in that page (the robot executes the DMP, not the path).
STROKE_PATH_POINTS = 100


def strokes_page_document(doc, path: str = "stroke document") -> dict:
    """A stroke model's prediction (format ``img2dmp-strokes``, version 1, as ``img2dmp
    predict --out`` writes it) as the page document of its strokes, in the model's frame:
    one entry per stroke, all on line 0 in writing order, each its own 2-D DMP (checked
    by the DMP file's reader) with its path rolled out from it. What ``img2dmp write
    --dmp FILE`` writes, as ``StrokePrediction.to_page_document()`` is for ``write IMAGE``;
    ``ValueError`` naming ``path`` and the field otherwise."""
    from ..dmp._numpy_rollout import rollout_numpy

    path = os.fspath(path)
    if not isinstance(doc, dict) or doc.get("format") != STROKES_FORMAT:
        got = show_value(doc.get("format") if isinstance(doc, dict) else doc)
        raise _bad(path, "format", f"must be {STROKES_FORMAT!r}, got {got}")
    v = doc.get("version")
    if not (_is_int(v) and 1 <= v <= STROKES_VERSION):
        raise _bad(path, "version", f"must be 1 (a newer img2dmp wrote it?), got {show_value(v)}")
    missing = [k for k in ("dmp_config", "image_size", "strokes") if k not in doc]
    if missing:
        raise _bad(path, missing[0], "is missing")
    strokes = doc["strokes"]
    if not (isinstance(strokes, list) and 1 <= len(strokes) <= MAX_CHARACTERS):
        raise _bad(path, "strokes", f"must be a list of 1 to {MAX_CHARACTERS} strokes, got "
                   f"{show_value(strokes)}")  # fmt: skip
    entries = []
    for j, stroke in enumerate(strokes):
        if not (isinstance(stroke, dict) and "params" in stroke):
            raise _bad(path, f"strokes[{j}]", f"must be an object with params, got "
                       f"{show_value(stroke)}")  # fmt: skip
        dmp = {
            "format": "img2dmp-dmp",
            "version": 2,
            "dmp_config": doc["dmp_config"],
            "params": stroke["params"],
            "image_size": doc["image_size"],
            "frame": "image",
        }
        f = check_dmp_document(dmp, f"{path}: strokes[{j}]")
        t = np.linspace(0.0, float(f.params.tau), STROKE_PATH_POINTS)
        xy = rollout_numpy(f.params, t, f.config)[:, :2]
        presence = stroke.get("presence", 1.0)
        entries.append({
            "index": j, "line": 0, "box_image_px": box_around_px(xy, f.image_size),
            "path_image_px": np.round(xy, 3).tolist(), "pen": [1] * len(xy),
            "times_s": np.round(t, 6).tolist(),
            "confidence": presence if _is_number(presence) and 0 <= presence <= 1 else 1.0,
            "fit": {"path_on_ink": None, "ink_written": None}, "flags": [], "dmp": dmp,
            "stroke": j + 1,
        })  # fmt: skip
    h, w = f.image_size
    return {"format": FORMAT, "version": VERSION, "image": None, "image_size_px": [w, h],
            "frame": "model", "source": path,
            "lines": [{"index": 0, "characters": list(range(len(entries)))}],
            "characters": entries}  # fmt: skip


def read_page(path) -> Page:
    """Read and check a page document file (module docstring).

    Raises
    ------
    FileNotFoundError, IsADirectoryError, PermissionError
        If the file cannot be opened (the exception names it).
    ValueError
        If it is not a valid page document: one line naming the file and the field.
    """
    path = os.fspath(path)
    check_readable(path, "page document")
    with open(path, "rb") as f:
        raw = f.read(MAX_FILE_BYTES + 1)
    if len(raw) > MAX_FILE_BYTES:
        raise ValueError(f"{path}: larger than {MAX_FILE_BYTES >> 20} MiB; is it a page document?")
    return check_page_document(parse_json(raw, path, allow_nan=False), path)


__all__ = [
    "FORMAT",
    "VERSION",
    "Page",
    "PageCharacter",
    "check_page_document",
    "read_page",
    "strokes_page_document",
]
