"""Omniglot's drawings as a source of ``img2dmp import``.

Omniglot (Lake, Salakhutdinov & Tenenbaum, "Human-level concept learning through
probabilistic program induction", Science 2015) holds characters of many alphabets, each
drawn once by 20 people online, as an image and the pen strokes that drew it, in two
trees of the same layout::

    images_background_small1/Balinese/character01/0108_01.png
    strokes_background_small1/Balinese/character01/0108_01.txt

``<id>_<drawer>``: the character's number and the drawer's, 01-20. :func:`find_omniglot`
lists the drawings of such a pair of trees (:func:`omniglot_trees` finds them), either
as they unzip (folders) or straight from the zip files as distributed; the class of a
drawing is ``alphabet/character`` (``Balinese/character01``). ``img2dmp import DIR``
reads every pair ``images_NAME`` / ``strokes_NAME`` (folder or ``.zip``; a folder wins
over a zip of the same name) in ``DIR``; ``img2dmp import strokes_NAME[.zip]`` one pair,
its images beside it or given with ``--images``. In a zip the tree lies under the folder
named like the zip, at any depth (as re-packed: ``omniglot-master/python/strokes_NAME/``),
else under one top folder, else at the top. Files and folders whose names start with
``.`` and a zip's ``__MACOSX`` folder are ignored; every other file is a drawing or
refused by name, and so is a character folder of which neither tree holds a file (an
empty character). Names are compared in Unicode NFC (a tree re-packed on macOS spells
``ö`` as ``o`` and an accent). ``images_NAME`` given as the source, or without its
``strokes_NAME``, is refused saying what to give.

**Splits** (:class:`~img2dmp.data.sources.files.ImportOptions` ``split_by``):

- ``"drawer"`` (the default): drawers 1-15 train, 16-17 validation, 18-20 test: new
  writers of characters seen in training;
- ``"character"``: each character's 20 drawings go to one split, drawn per alphabet with
  ``val_fraction`` and ``test_fraction`` of its characters (``seed``): characters never
  seen;
- ``"alphabet"``: each alphabet's characters go to one split, drawn the same way over the
  alphabets: never-seen alphabets.

**A stroke file** (:func:`parse_strokes`) holds lines ``x,y,t``: pixels of the drawing's
image with **y pointing up** (row = -y; the ink is centred on the path, pixel ``[i, j]``
at ``(x=j, y=-i)``), t in milliseconds since the drawing began; a line ``START`` before
the first stroke and ``BREAK`` after each stroke. Its rules:

- A stroke of a single point is a dot, kept as a stroke of its own (one instant of the
  time grid, :func:`img2dmp.data.resample.resample_strokes`).
- A time stamp that repeats the one before it (the tablet logs two points in one
  millisecond) is spread: the points of a run of equal stamps are placed evenly between
  that stamp and the next one of the stroke (at a stroke's end, between the stamp before
  and theirs). A stamp earlier than the one before it by at most
  ``MAX_CLOCK_STEP_BACK_MS`` is clock jitter and taken as repeating it; a larger step
  back is refused, and so is a stroke of several points that all share one stamp and a
  stroke that begins before the one before it ended.
- In a few drawings the image lies a few pixels off its strokes (in
  ``images_background_small1`` 15 drawings, by up to 5.5 px, all by drawer 07 of Greek
  and 10 of Korean). Strokes of which less than ``ALIGN_BELOW`` of the points inside the
  image lie on its ink are moved by the shift, within ``MAX_SHIFT_PX``, that best puts
  them on it (:func:`onto_ink`), and the shift is kept in the data set's metadata
  (``source.shifted``).
- Points beyond the image's border (the tablet's canvas reached past the image) are
  moved onto it (:func:`fit_to_image`); a point beyond it by more than ``MAX_OUTSIDE``
  of the image's side is refused.
- An empty stroke (``BREAK`` right after ``START`` or ``BREAK``) is left out. An empty
  character (no point at all), a single point, a second ``START``, a point before
  ``START``, a stroke without its ``BREAK`` (a truncated file) and a line that is none of
  ``x,y,t``, ``START`` or ``BREAK`` are refused. Any number of strokes is read; the time
  grid must hold them (``--n-times``).

Every refusal is one ``ValueError`` naming the file and its line. The images are black
ink on white, as rendered from the strokes: they are read without the paper cleaning
meant for photos (:func:`img2dmp.data.paper.paper_ink`), which takes a long straight
stroke of a clean image for a ruled line (and a dot beside it for a rule's remnant).
"""

from __future__ import annotations

import io
import os
import unicodedata
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ...errors import show
from ...metrics import bilinear
from ..images import ImageFrame
from ..resample import PenPath
from .files import IMAGE_SUFFIXES, OMNIGLOT_SPLIT_BY, SampleSource, check_class_name
from .recordings import recordings_in
from .trajectory import (
    MAX_PATH_DURATION_S,
    MAX_POINTS,
    MAX_TRAJECTORY_BYTES,
    spread_repeated_stamps,
)

#: The source format of the samples listed here (:attr:`SampleSource.format`).
FORMAT = "omniglot"
#: The ways of splitting Omniglot's drawings (module docstring), the first the default.
SPLIT_BY = OMNIGLOT_SPLIT_BY
#: The split of each drawer for ``split_by="drawer"``.
DRAWER_SPLITS = {
    **{d: "train" for d in range(1, 16)},
    **{d: "validation" for d in (16, 17)},
    **{d: "test" for d in (18, 19, 20)},
}
#: A time stamp this much earlier (ms) than the one before it is clock jitter.
MAX_CLOCK_STEP_BACK_MS = 100.0
#: Points beyond the image by at most this share of its side are moved onto it.
MAX_OUTSIDE = 0.5
#: Strokes with less than this share of their points on the ink are shifted onto it.
ALIGN_BELOW = 0.9
#: Largest shift (pixels of the drawing's image, in x and in y) and the step tried.
MAX_SHIFT_PX = 8.0
SHIFT_STEP_PX = 0.5
#: Blur (pixels of the prepared image) of the ink the shift is fitted to: a stroke's
#: blurred ink peaks on its centre line, so the best shift centres the path there.
ALIGN_BLUR_PX = 1.0
#: Largest image file read from a zip.
MAX_IMAGE_BYTES = 64 << 20
STROKE_SUFFIX = ".txt"
#: How a stroke file gives positions (:attr:`PenPath.file_frame`).
FILE_FRAME = "x = column and y = -row (y up, as Omniglot's stroke files have it)"


@dataclass(frozen=True)
class ArchiveMember:
    """A file inside a zip file: what a sample's image or strokes are when read straight
    from Omniglot's zips. ``str()`` gives ``ARCHIVE/MEMBER``, as messages name it.

    Attributes
    ----------
    archive : Path
        The zip file.
    name : str
        The member's name in it (``strokes_background_small1/Greek/character01/...``).
    zip : zipfile.ZipFile
        The archive, open: one for all its members (a zip's directory is read once).
    """

    archive: Path
    name: str
    zip: zipfile.ZipFile = field(repr=False, compare=False)

    def __str__(self) -> str:
        return f"{self.archive}/{self.name}"

    def read_bytes(self, limit: int) -> bytes:
        """The member's bytes; ``ValueError`` naming it if it is larger than ``limit``
        or cannot be read."""
        try:
            info = self.zip.getinfo(self.name)
            if info.file_size > limit:
                raise ValueError(f"{self}: has {info.file_size} bytes, more than {limit}")
            return self.zip.read(info)
        except (zipfile.BadZipFile, OSError, EOFError, RuntimeError, KeyError) as e:
            raise ValueError(f"{self}: cannot be read from its zip file ({e})") from None


Entry = Path | ArchiveMember


# --- one stroke file ------------------------------------------------------------------


def read_strokes(entry: Entry) -> PenPath:
    """The pen path of an Omniglot stroke file (a path or a zip member): its text read
    and given to :func:`parse_strokes`."""
    if isinstance(entry, ArchiveMember):
        data = entry.read_bytes(MAX_TRAJECTORY_BYTES)
    else:
        size = entry.stat().st_size
        if size > MAX_TRAJECTORY_BYTES:
            raise ValueError(f"{entry}: has {size} bytes, more than {MAX_TRAJECTORY_BYTES}")
        data = entry.read_bytes()
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise ValueError(f"{entry}: not a text (UTF-8) stroke file ({e})") from None
    return parse_strokes(text, str(entry))


def _point(name: str, line: str, number: int) -> tuple[float, float, float]:
    """``(x, y, t)`` of a point line, else ``ValueError`` naming the line."""
    fields = line.split(",")
    shown = line if len(line) <= 40 else line[:40] + "..."
    if len(fields) != 3:
        raise ValueError(
            f"{name}: line {number} is {shown!r}: expected x,y,t (t in ms), START or BREAK"
        )
    values = []
    for key, text in zip("xyt", fields, strict=True):
        try:
            v = float(text)
        except ValueError:
            raise ValueError(
                f"{name}: line {number}: field {key!r} is {show(text.strip())}, not a number"
            ) from None
        if not np.isfinite(v):
            raise ValueError(f"{name}: line {number}: field {key!r} is {v!r}, not finite")
        if key == "t" and abs(v) > MAX_PATH_DURATION_S * 1e3:
            raise ValueError(
                f"{name}: line {number}: field 't' is {v!r} ms, beyond the "
                f"{MAX_PATH_DURATION_S:g} s since the drawing began that a pen path may last"
            )
        values.append(v)
    return values[0], values[1], values[2]


def _stroke_lines(text: str, name: str) -> list[list[tuple[float, float, float, int]]]:
    """The strokes of a stroke file, each a list of ``(x, y, t, line)``; empty strokes
    left out; the layout checked (module docstring)."""
    strokes: list[list[tuple[float, float, float, int]]] = []
    current: list | None = None  # None until START
    count, last = 0, 0
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line:
            continue
        last = number
        if line == "START":
            if current is not None:
                raise ValueError(f"{name}: line {number}: a second START (one begins a drawing)")
            current = []
        elif current is None:
            raise ValueError(
                f"{name}: line {number} comes before START; a stroke file is START, then "
                "lines x,y,t with a line BREAK after each stroke"
            )
        elif line == "BREAK":
            if current:
                strokes.append(current)
            current = []
        else:
            count += 1
            if count > MAX_POINTS:
                raise ValueError(f"{name}: has more than {MAX_POINTS} points")
            current.append((*_point(name, line, number), number))
    if current:
        raise ValueError(
            f"{name}: line {last}: stroke {len(strokes)} has no BREAK after it (a truncated file?)"
        )
    if not strokes:
        raise ValueError(f"{name}: holds no point: an empty character")
    if count < 2:
        raise ValueError(
            f"{name}: line {strokes[0][0][3]}: the drawing is a single point; a movement "
            "needs at least 2 points at different times"
        )
    return strokes


def _stroke_times(name: str, k: int, points: list) -> np.ndarray:
    """Strictly increasing stamps (ms) of stroke ``k``'s points (module docstring)."""
    t = np.array([p[2] for p in points])  # [n]
    top = np.maximum.accumulate(t)
    back = top - t
    if back.max() > MAX_CLOCK_STEP_BACK_MS:
        j = int(np.argmax(back > MAX_CLOCK_STEP_BACK_MS))
        raise ValueError(
            f"{name}: line {points[j][3]}: time stamp {t[j]:g} ms lies {back[j]:g} ms before "
            f"one before it ({top[j]:g} ms); more than {MAX_CLOCK_STEP_BACK_MS:g} ms back is "
            "no clock jitter"
        )
    if len(t) > 1 and top[0] == top[-1]:
        raise ValueError(
            f"{name}: lines {points[0][3]}-{points[-1][3]}: the {len(t)} points of stroke {k} "
            f"all have the time stamp {t[0]:g} ms; a stroke of several points takes time"
        )
    return spread_repeated_stamps(top) if len(t) > 1 else top


def parse_strokes(text: str, name: str = "stroke file") -> PenPath:
    """The pen path of the text of an Omniglot stroke file (the module docstring's
    rules), in pixels of its image with y pointing down (x = column, y = row), t in
    seconds; every point named by its line in messages.

    Raises ``ValueError`` naming ``name`` and the line at fault.
    """
    strokes = _stroke_lines(text, name)
    times = []
    for k, points in enumerate(strokes):
        t = _stroke_times(name, k, points)
        if times and t[0] <= times[-1][-1]:
            raise ValueError(
                f"{name}: line {points[0][3]}: stroke {k} begins at {t[0]:g} ms, not after "
                f"stroke {k - 1} ended ({times[-1][-1]:g} ms)"
            )
        times.append(t)
    lines = [p[3] for s in strokes for p in s]
    xy = np.array([(p[0], -p[1]) for s in strokes for p in s], dtype=np.float64)  # [T, 2]
    stroke = np.concatenate([np.full(len(s), k, np.int64) for k, s in enumerate(strokes)])

    def point_name(k: int) -> str:
        return f"line {lines[k]}"

    return PenPath(
        xy=xy,
        t_s=np.concatenate(times) * 1e-3,
        stroke=stroke,
        name=name,
        point_name=point_name,
        file_frame=FILE_FRAME,
    )


def _beyond(pen: PenPath, size: tuple[int, int]) -> np.ndarray:
    """Pixels ``[T]`` by which each point lies beyond the border of an image of ``size =
    (H, W)`` (0 or less inside; the image covers ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``)."""
    h, w = size
    lo, hi = np.array([-0.5, -0.5]), np.array([w - 0.5, h - 0.5])
    return np.maximum(lo - pen.xy, pen.xy - hi).max(axis=1)


def _ink_share(image: np.ndarray, points: np.ndarray) -> float:
    """Share of ``points [n, 2]`` (prepared image pixels) on the ink of ``image``."""
    return float((bilinear(image[None], points[None])[0] > 0.5).mean())


def onto_ink(
    pen: PenPath, image: np.ndarray, frame: ImageFrame
) -> tuple[PenPath, tuple[float, float] | None]:
    """``pen`` moved onto the ink of its prepared ``image`` when less than
    ``ALIGN_BELOW`` of its points within the image lie on it, and the shift (pixels of
    the drawing's image; None: not moved).

    The shift, on a grid of ``SHIFT_STEP_PX`` within ``MAX_SHIFT_PX`` in x and y, is the
    one with the most ink under those points once the ink is blurred by
    ``ALIGN_BLUR_PX``; it is kept only if it puts more of them on the ink than before.
    Points beyond the border are left out of both: no shift could put them on ink the
    image does not show, and a drawing that runs off the image is not misplaced.
    """
    from scipy.ndimage import gaussian_filter

    inside = pen.xy[_beyond(pen, frame.image_size) <= 0]  # [n, 2]
    share = _ink_share(image, frame.to_model(inside)) if len(inside) else 1.0
    if share >= ALIGN_BELOW:
        return pen, None
    steps = np.arange(-MAX_SHIFT_PX, MAX_SHIFT_PX + SHIFT_STEP_PX / 2, SHIFT_STEP_PX)
    grid = np.stack(np.meshgrid(steps, steps, indexing="ij"), -1).reshape(-1, 2)  # [K, 2]
    blurred = gaussian_filter(image.astype(np.float64), ALIGN_BLUR_PX)  # [S, S]
    moved = frame.to_model(inside[None] + grid[:, None])  # [K, n, 2]
    score = bilinear(np.broadcast_to(blurred, (len(grid), *blurred.shape)), moved).mean(1)
    # Of shifts that score alike (a straight stroke slides along itself), the shortest.
    best = grid[int(np.argmax(score - 1e-9 * np.hypot(grid[:, 0], grid[:, 1])))]  # [2]
    if _ink_share(image, frame.to_model(inside + best)) <= share:
        return pen, None
    return replace(pen, xy=pen.xy + best), (float(best[0]), float(best[1]))


def fit_to_image(
    pen: PenPath, image: np.ndarray, frame: ImageFrame, image_name: str
) -> tuple[PenPath, tuple[float, float] | None]:
    """An Omniglot drawing's pen path placed on its image (module docstring): refused
    (``ValueError`` naming the line) if a point lies beyond the image's border by more
    than ``MAX_OUTSIDE`` of its longer side, then shifted onto the ink if it lies off it
    (:func:`onto_ink`; the shift, or None), and its points beyond the border moved onto
    it. ``image`` is the prepared image, ``frame`` the map to it."""
    h, w = frame.image_size
    off = _beyond(pen, (h, w))  # [T]
    limit = MAX_OUTSIDE * max(h, w)
    if off.max() > limit:
        k = int(np.argmax(off > limit))
        x, y = pen.xy[k]
        raise ValueError(
            f"{pen.name}: {pen.point_name(k)} (x={x:g}, row={y:g}) lies {off[k]:.1f} px "
            f"outside the {w} x {h} image {image_name}, more than {MAX_OUTSIDE:.0%} of its "
            "side (Omniglot's y points up: row = -y)"
        )
    pen, shift = onto_ink(pen, image, frame)
    return replace(pen, xy=np.clip(pen.xy, -0.5, [w - 0.5, h - 0.5])), shift


def image_of(entry: Entry):
    """What :func:`img2dmp.data.images.prepare_image_framed` reads for an image: its path,
    or a zip member's image decoded (a ``PIL.Image``)."""
    if not isinstance(entry, ArchiveMember):
        return entry
    from PIL import Image, UnidentifiedImageError

    data = entry.read_bytes(MAX_IMAGE_BYTES)
    try:
        im = Image.open(io.BytesIO(data))
        im.load()
    except (UnidentifiedImageError, OSError, SyntaxError, Image.DecompressionBombError) as e:
        raise ValueError(f"cannot decode image file {entry}: {e}") from None
    return im


# --- the trees of images and strokes --------------------------------------------------


def tree_name(path: Path) -> str:
    """A tree's name without its ``.zip`` (``strokes_background_small1``)."""
    return path.name[: -len(".zip")] if path.name.lower().endswith(".zip") else path.name


def _tree_beside(folder: Path, name: str) -> Path | None:
    """The folder ``name`` in ``folder``, else the zip ``name.zip``, else None."""
    for candidate in (folder / name, folder / f"{name}.zip"):
        if candidate.is_dir() or (candidate.is_file() and candidate.suffix.lower() == ".zip"):
            return candidate
    return None


def omniglot_trees(source: Path, images=None) -> list[tuple[Path, Path]] | None:
    """The ``(strokes, images)`` trees (folders or zips) of an Omniglot source, or None
    when ``source`` is none (module docstring); ``FileNotFoundError`` for strokes
    without their images."""
    source = Path(source)
    name = tree_name(source)
    if name.startswith("strokes_") and source.is_dir() and _flat(source):
        if recordings_in(source):
            return None  # named like Omniglot's strokes, but a folder of recordings
        raise ValueError(
            f"{source}: a folder named strokes_* is read as Omniglot's strokes "
            f"({source}/ALPHABET/CHARACTER/NNNN_NN.txt), but it holds no folders; a folder "
            "of class folders, or of recordings (image_<n>.json), may not be named strokes_*"
        )
    _images_given(source, name)
    if name.startswith("strokes_") and (source.is_dir() or source.suffix.lower() == ".zip"):
        image_name = "images_" + name[len("strokes_") :]
        found = Path(images) if images is not None else _tree_beside(source.parent, image_name)
        if found is None or not found.exists():
            raise FileNotFoundError(
                f"{source}: Omniglot strokes without their images: no {image_name} (folder "
                f"or .zip) {'at ' + str(images) if images else 'beside it'}; give them with "
                "--images"
            )
        return [(source, found)]
    if not source.is_dir():
        return None
    names = sorted({tree_name(p) for p in source.iterdir() if p.name.startswith("strokes_")})
    names = [n for n in names if _tree_beside(source, n) is not None]
    if not names:
        _images_alone(source)
        return None
    if images is not None:
        raise ValueError(
            f"{source}: holds Omniglot trees; --images goes with a SOURCE strokes_NAME "
            "(folder or .zip) whose images lie elsewhere"
        )
    pairs = []
    for n in names:
        image_name = "images_" + n[len("strokes_") :]
        found = _tree_beside(source, image_name)
        if found is None:
            raise FileNotFoundError(
                f"{source / n}: Omniglot strokes without their images: no {image_name} "
                f"(folder or .zip) in {source}"
            )
        pairs.append((_tree_beside(source, n), found))
    return pairs


def _images_given(source: Path, name: str) -> None:
    """Refuse Omniglot's images tree given as SOURCE (a zip ``images_NAME.zip``, or a
    folder ``images_NAME`` with its strokes beside it), saying what to give instead."""
    if not name.startswith("images_"):
        return
    is_zip = source.is_file() and source.suffix.lower() == ".zip"
    strokes_name = "strokes_" + name[len("images_") :]
    strokes = _tree_beside(source.parent, strokes_name)
    if strokes is None and is_zip:
        raise FileNotFoundError(
            f"{source}: Omniglot's images without their strokes: no {strokes_name} (folder "
            "or .zip) beside it; import strokes_NAME (its images found beside it or given "
            "with --images), or the folder that holds both"
        )
    if strokes is not None and (is_zip or source.is_dir()):
        raise ValueError(
            f"{source}: Omniglot's images; import its strokes, {strokes} (the images are "
            f"found beside it), or the folder {source.parent} that holds both"
        )


def _images_alone(folder: Path) -> None:
    """Refuse a folder holding Omniglot's ``images_NAME.zip`` without its strokes."""
    alone = sorted(
        p.name
        for p in folder.iterdir()
        if p.name.startswith("images_") and p.is_file() and p.suffix.lower() == ".zip"
    )
    if alone:
        strokes = "strokes_" + tree_name(Path(alone[0]))[len("images_") :]
        raise FileNotFoundError(
            f"{folder}: holds Omniglot's {', '.join(alone)} but no {strokes} (folder or "
            ".zip): each images_NAME needs its strokes_NAME beside it"
        )


def _flat(folder: Path) -> bool:
    """Whether a folder holds no folders (but ``.``-hidden ones): no Omniglot tree."""
    return not any(p.is_dir() and not p.name.startswith(".") for p in folder.iterdir())


def _hidden(parts) -> bool:
    return any(p.startswith(".") or p == "__MACOSX" for p in parts)


def _key(parts) -> tuple[str, ...]:
    """A file's ``(alphabet, character, file)`` in Unicode NFC: a tree zipped or unzipped
    on macOS names ``Ñkö`` with combining accents (NFD), its partner may not."""
    return tuple(unicodedata.normalize("NFC", p) for p in parts)


def _in_zip(parts: tuple[str, ...], tree: str) -> tuple[str, ...]:
    """A member's path within its tree: after the last folder named like the zip (as
    distributed, the tree's one top folder; re-packed, it may lie deeper, as in
    ``omniglot-master/python/strokes_evaluation/...``), else after one top folder of
    another name, else the whole path."""
    folders = [i for i, p in enumerate(parts[:-1]) if p == tree]
    if folders:
        return parts[folders[-1] + 1 :]
    return parts[1:] if len(parts) == 4 else parts


def _zip_files(path: Path) -> tuple[dict[tuple[str, ...], Entry], list[Exception]]:
    """The files of a zip tree by ``(alphabet, character, file)``; members elsewhere and
    empty character folders as problems."""
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as e:
        raise ValueError(f"{path}: not a readable zip file ({e})") from None
    files, problems, folders = {}, [], {}
    tree = tree_name(path)
    for info in zf.infolist():
        parts = tuple(p for p in info.filename.split("/") if p)
        if not parts or _hidden(parts):
            continue
        member = ArchiveMember(path, info.filename, zf)
        if info.is_dir():  # placed as a file in it would be
            if len(rel := _in_zip((*parts, ""), tree)[:-1]) == 2:
                folders[_key(rel)] = member
            continue
        rel = _in_zip(parts, tree)
        if len(rel) != 3:
            problems.append(ValueError(f"{member}: is not ALPHABET/CHARACTER/FILE in the zip"))
        else:
            files[_key(rel)] = member
    drawn = {k[:2] for k in files}
    problems += [EmptyCharacter(k, m) for k, m in sorted(folders.items()) if k not in drawn]
    return files, problems


class EmptyCharacter(ValueError):
    """A character folder without files, as a problem of :func:`tree_files`; ``key`` is
    its ``(alphabet, character)``. :func:`find_omniglot` refuses it when the other tree
    has no file of that character either (else that tree's files are named)."""

    def __init__(self, key: tuple[str, ...], folder) -> None:
        super().__init__(
            f"{folder}: a character folder without drawings (an empty character); remove "
            "it, or --skip-bad to leave it out"
        )
        self.key = key


def _folder_files(root: Path) -> tuple[dict[tuple[str, ...], Entry], list[Exception]]:
    """The files of a folder tree by ``(alphabet, character, file)``; files elsewhere and
    empty character folders as problems."""
    inner = [p for p in root.iterdir() if not p.name.startswith(".")]
    if len(inner) == 1 and inner[0].is_dir() and inner[0].name == root.name:
        root = inner[0]  # unzipped into a folder of its own name
    files, problems = {}, []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        rel = Path(dirpath).relative_to(root).parts
        filenames = sorted(f for f in filenames if not f.startswith("."))
        for f in filenames:
            if len(rel) != 2:
                problems.append(
                    ValueError(f"{Path(dirpath) / f}: is not {root}/ALPHABET/CHARACTER/FILE")
                )
            else:
                files[_key((*rel, f))] = Path(dirpath) / f
        if len(rel) == 2 and not filenames and not dirnames:
            problems.append(EmptyCharacter(_key(rel), Path(dirpath)))
        if len(rel) >= 2:
            for d in dirnames:
                problems.append(ValueError(f"{Path(dirpath) / d}: a folder in a character folder"))
            dirnames[:] = []
    return files, problems


def tree_files(tree: Path) -> tuple[dict[tuple[str, ...], Entry], list[Exception]]:
    """The files of one tree of :func:`omniglot_trees` (folder or zip) by ``(alphabet,
    character, file)``, and the files that lie elsewhere in it (as problems)."""
    return _zip_files(tree) if tree.is_file() else _folder_files(tree)


def _by_stem(files: dict, suffixes: tuple[str, ...], kind: str, problems: list) -> dict:
    """``(alphabet, character, stem)`` -> file of those of a tree with one of
    ``suffixes``; the others join ``problems``."""
    out = {}
    for (alphabet, character, name), entry in sorted(files.items(), key=lambda kv: kv[0]):
        p = Path(name)
        if p.suffix.lower() not in suffixes:
            problems.append(ValueError(f"{entry}: is no {kind} file ({', '.join(suffixes)})"))
        elif (alphabet, character, p.stem) in out:
            problems.append(ValueError(f"{entry}: a second {kind} file of {p.stem}"))
        else:
            out[(alphabet, character, p.stem)] = entry
    return out


def _drawer(entry: Entry, stem: str) -> int:
    """The drawer of a drawing, from its name ``<id>_<drawer>``."""
    _, _, tail = stem.rpartition("_")
    if not tail.isdigit() or not 1 <= int(tail) <= 99:
        raise ValueError(
            f"{entry}: the name {stem!r} is not <character id>_<drawer> (e.g. 0108_01)"
        )
    return int(tail)


def _sample(key: tuple[str, str, str], strokes: Entry, image: Entry, split_by: str):
    """The :class:`SampleSource` of one drawing."""
    alphabet, character, stem = key
    name = check_class_name(f"{alphabet}/{character}", str(strokes))
    drawer = _drawer(strokes, stem)
    kw: dict = {}
    if split_by == "drawer":
        if drawer not in DRAWER_SPLITS:
            raise ValueError(
                f"{strokes}: drawer {drawer} is in no split by drawer (1-15 train, 16-17 "
                "validation, 18-20 test); import with --split-by character or alphabet"
            )
        kw["split"] = DRAWER_SPLITS[drawer]
    elif split_by == "character":
        kw.update(unit=name, stratum=alphabet)
    else:
        kw.update(unit=alphabet, stratum="")
    return SampleSource(image=image, trajectory=strokes, class_name=name, format=FORMAT, **kw)


def _where(tree: Path) -> str:
    """Where a drawing's missing partner was looked for, in a message: the tree, and a
    zip of its name beside a folder read instead (a zip half unzipped)."""
    twin = tree.with_name(tree.name + ".zip")
    if tree.is_dir() and twin.is_file():
        return f"in {tree} (the folder is read, not {twin.name} beside it)"
    return f"in {tree}"


def _truly_empty(problems: list[Exception], drawn: set) -> list[Exception]:
    """``problems`` without the empty characters of which the other tree has files
    (those files are named instead), each empty character once."""
    out, seen = [], set()
    for e in problems:
        if isinstance(e, EmptyCharacter):
            if e.key in drawn or e.key in seen:
                continue
            seen.add(e.key)
        out.append(e)
    return out


def find_omniglot(
    trees: list[tuple[Path, Path]], split_by: str | None = None
) -> tuple[list[SampleSource], list[Exception]]:
    """The drawings of Omniglot's ``(strokes, images)`` trees (:func:`omniglot_trees`),
    with their splits (``split_by``: module docstring; None: by drawer), and the files
    that make no drawing (a stroke file without its image, a stray file ...)."""
    split_by = split_by or SPLIT_BY[0]
    if split_by not in SPLIT_BY:
        raise ValueError(f"split_by must be one of {list(SPLIT_BY)}, got {show(split_by)}")
    samples, problems, seen = [], [], {}
    for strokes_tree, images_tree in trees:
        stroke_files, found = tree_files(strokes_tree)
        image_files, stray = tree_files(images_tree)
        found = _truly_empty(found + stray, {k[:2] for k in (*stroke_files, *image_files)})
        strokes = _by_stem(stroke_files, (STROKE_SUFFIX,), "stroke", found)
        images = _by_stem(image_files, IMAGE_SUFFIXES, "image", found)
        if not strokes and not found:
            raise ValueError(f"{strokes_tree}: holds no stroke file (ALPHABET/CHARACTER/*.txt)")
        for key in sorted(set(strokes) | set(images)):
            if key not in images:
                where = _where(images_tree)
                found.append(FileNotFoundError(f"{strokes[key]}: no image {key[2]}.png {where}"))
                continue
            if key not in strokes:
                where = _where(strokes_tree)
                found.append(
                    FileNotFoundError(f"{images[key]}: no stroke file {key[2]}.txt {where}")
                )
                continue
            if key[:2] in seen and seen[key[:2]] != strokes_tree:
                raise ValueError(
                    f"{strokes_tree}: holds the character {key[0]}/{key[1]} that "
                    f"{seen[key[:2]]} holds too (Omniglot's background_small1 and _small2 "
                    "are parts of background); import one of them (SOURCE strokes_NAME), "
                    "or a folder of only the pairs to read"
                )
            seen[key[:2]] = strokes_tree
            try:
                samples.append(_sample(key, strokes[key], images[key], split_by))
            except ValueError as e:
                found.append(e)
        problems += found
    return samples, problems
