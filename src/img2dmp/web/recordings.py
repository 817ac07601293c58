"""The Record page's side: the images to trace and the recordings written of them.

Images come from MNIST's training IDX files (:class:`MnistImages`, labelled) or a folder
of PNG/JPEG files sorted by name (:class:`FolderImages`, unlabelled). A recording of
image ``n`` is ``DATA_DIR/image_<n>.json`` in the recorded-path format of
:mod:`img2dmp.data.recorded` (the shared recordings' keys and corner convention: the
image covers ``[0, W] x [0, H]``), written atomically under a lock on the data directory
(:class:`Recordings`), so that recordings from several browsers or servers are never lost
and ``img2dmp prepare --recorded DATA_DIR`` reads them as they are.
"""

from __future__ import annotations

import datetime
import fcntl
import json
import os
import re
import threading
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .. import __version__
from .._files import atomic_write_text, open_lock_file
from ..data.images import shown_size, upright
from ..data.mnist import IMAGES_MAGIC, LABELS_MAGIC, MNIST_FILES, find_mnist_file, read_idx
from ..data.recorded import parse_recorded
from .errors import WebError, show
from .strokes import check_strokes, grey_png

#: Image files a folder source shows.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
#: Most pixels of one image of a folder source.
MAX_FOLDER_IMAGE_PIXELS = 16_777_216
#: A recording may last at most this long (milliseconds from its first point).
MAX_DURATION_MS = 3_600_000.0
#: Seconds a write waits for another process's lock on the data directory.
LOCK_TIMEOUT_S = 10.0
_RECORDING = re.compile(r"image_(\d+)\.json")


class MnistImages:
    """MNIST's training images (light ink on black in the files), read once.

    Raises ``FileNotFoundError`` or ``ValueError`` (naming the file) for a folder
    without valid training IDX files.
    """

    kind = "mnist"

    def __init__(self, directory: str | os.PathLike):
        self.directory = Path(directory)
        images_file = find_mnist_file(self.directory, MNIST_FILES["train"][0])
        labels_file = find_mnist_file(self.directory, MNIST_FILES["train"][1])
        self.images = read_idx(images_file, IMAGES_MAGIC)
        self.labels = read_idx(labels_file, LABELS_MAGIC)
        if self.images.ndim != 3 or self.labels.ndim != 1:
            raise ValueError(f"{images_file}: expected images [n, H, W] and labels [n]")
        if len(self.images) != len(self.labels):
            raise ValueError(
                f"{images_file} holds {len(self.images)} images but {labels_file} holds "
                f"{len(self.labels)} labels"
            )
        if self.labels.size and int(self.labels.max()) > 9:
            raise ValueError(f"{labels_file}: a label is not a digit 0-9")
        self.count = len(self.images)

    def label(self, n: int) -> int | None:
        """MNIST's label of image ``n``."""
        return int(self.labels[n])

    def size(self, n: int) -> tuple[int, int]:
        """``(H, W)`` of image ``n``."""
        return int(self.images.shape[1]), int(self.images.shape[2])

    def name(self, n: int) -> str:
        """``train-images-idx3-ubyte[n]``."""
        return f"{MNIST_FILES['train'][0]}[{n}]"

    def png(self, n: int) -> bytes:
        """Image ``n`` as a PNG, dark ink on white."""
        return grey_png(255 - self.images[n])


class FolderImages:
    """The PNG and JPEG files of a folder, sorted by name, unlabelled.

    Every file's header is read at the start: one that is no image, or one of more than
    ``MAX_FOLDER_IMAGE_PIXELS`` pixels, is refused with a ``ValueError`` naming it.
    """

    kind = "folder"

    def __init__(self, directory: str | os.PathLike):
        from PIL import Image, UnidentifiedImageError

        self.directory = Path(directory)
        if not self.directory.is_dir():
            raise NotADirectoryError(f"--images {self.directory} is not a directory")
        self.files = sorted(
            p
            for p in self.directory.iterdir()
            if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()
        )
        if not self.files:
            raise ValueError(f"--images {self.directory} holds no PNG or JPEG files")
        self.sizes = []
        for p in self.files:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", Image.DecompressionBombWarning)
                    with Image.open(p) as im:
                        h, w = shown_size(im)  # as the browser and the importer turn it
            except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as e:
                raise ValueError(f"image file {p} cannot be read as an image: {e}") from None
            if w * h > MAX_FOLDER_IMAGE_PIXELS:
                raise ValueError(f"image file {p}: {w} x {h} pixels is too large to trace")
            self.sizes.append((h, w))
        self.count = len(self.files)

    def label(self, n: int) -> int | None:
        """None: a folder's images have no labels."""
        return None

    def size(self, n: int) -> tuple[int, int]:
        """``(H, W)`` of image ``n``."""
        return self.sizes[n]

    def name(self, n: int) -> str:
        """The file name of image ``n``."""
        return self.files[n].name

    def png(self, n: int) -> bytes:
        """Image ``n`` as a grey PNG, dark ink on white (transparency on white; an image
        whose border is dark is inverted)."""
        from PIL import Image

        with Image.open(self.files[n]) as im:
            rgba = upright(im).convert("RGBA")
        white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        grey = np.asarray(Image.alpha_composite(white, rgba).convert("L"))
        border = np.concatenate([grey[0], grey[-1], grey[:, 0], grey[:, -1]])
        return grey_png(255 - grey if border.mean() < 128 else grey)


def _number(v: float) -> str:
    text = f"{v:.3f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _times(strokes: list) -> np.ndarray:
    """Every point's time in milliseconds from the first, in microsecond steps, strictly
    increasing (a time equal to the one before moves on by 0.001 ms); 422 for a time
    before the one before it."""
    t = np.concatenate([a[:, 2] for a in strokes])
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        k = int(back[0]) + 1
        ends = np.cumsum([len(a) for a in strokes])
        i = int(np.searchsorted(ends, k, side="right"))
        j = k - (int(ends[i - 1]) if i else 0)
        raise WebError(
            422,
            f"strokes[{i}][{j}]: t_ms {t[k]:g} is before the point before it ({t[k - 1]:g}); "
            "times must not decrease",
        )
    # The range first, in floating point: 1e17 ms in microseconds overflows an int64.
    if t[-1] - t[0] > MAX_DURATION_MS:
        raise WebError(
            422, f"strokes: the recording lasts {(t[-1] - t[0]) / 1e3:.6g} s, more than 1 hour"
        )
    us = np.round((t - t[0]) * 1000.0).astype(np.int64)
    steps = np.arange(len(us))
    us = np.maximum.accumulate(us - steps) + steps
    if us[-1] > MAX_DURATION_MS * 1000.0:
        raise WebError(422, f"strokes: the recording lasts {us[-1] / 1e6:g} s, more than 1 hour")
    return us / 1000.0


def recording_document(n: int, label: int, strokes: list, source, now: str) -> dict:
    """The JSON document of a recording of image ``n`` (docs/WEB.md, the keys of the
    shared recordings), from checked strokes ``[k, 3]``."""
    t = _times(strokes)
    xy = np.concatenate([a[:, :2] for a in strokes])
    path = ", ".join(
        f"[{_number(x)}, {_number(y)}, {_number(s)}]" for (x, y), s in zip(xy, t, strict=True)
    )
    ends = np.cumsum([len(a) for a in strokes])
    spans = [[int(e - len(a)), int(e - 1)] for a, e in zip(strokes, ends, strict=True)]
    doc = {"Image number": n, "Image shape": label, "Path": path, "Strokes": spans,
           "Recorded with": f"img2dmp {__version__}", "Recorded at": now}  # fmt: skip
    if source.kind == "folder":
        doc["Image file"] = source.name(n)
        doc["Image size"] = list(source.size(n))
    return doc


class Recordings:
    """Recordings of one image source in one data directory.

    ``source`` is an :class:`MnistImages`, a :class:`FolderImages` or None (no image
    source: every call that needs one answers 409).
    """

    def __init__(self, data_dir: str | os.PathLike, source=None):
        self.data_dir = Path(data_dir)
        if self.data_dir.exists() and not self.data_dir.is_dir():
            raise NotADirectoryError(f"--data-dir {self.data_dir} is a file, not a directory")
        if source is not None:  # without images to record on, nothing is ever written
            self.data_dir.mkdir(parents=True, exist_ok=True)
        if self.data_dir.is_dir():
            os.close(open_lock_file(self.data_dir, "--data-dir"))  # a planted link: refused now
        self.source = source
        self._lock = threading.Lock()

    def _source(self):
        if self.source is None:
            raise WebError(
                409, "no image source: start img2dmp serve with --mnist DIR or --images DIR"
            )
        return self.source

    def index(self, n, field: str = "image", status: int = 404) -> int:
        """``n`` if it is an image of the source, else ``status`` naming ``field``."""
        source = self._source()
        if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n < source.count:
            raise WebError(
                status, f"{field}: no image {show(n)}; the images are 0..{source.count - 1}"
            )
        return n

    def path(self, n: int) -> Path:
        """The recording of image ``n`` (``n`` a checked index: the name is built from it)."""
        return self.data_dir / f"image_{int(n)}.json"

    def recorded(self) -> set[int]:
        """Indices of the source's images that have a recording."""
        count = self.source.count if self.source is not None else 0
        found = set()
        with os.scandir(self.data_dir) as entries:
            for e in entries:
                m = _RECORDING.fullmatch(e.name)
                if m and int(m.group(1)) < count:
                    found.add(int(m.group(1)))
        return found

    def summary(self) -> dict:
        """``GET /api/images``: the source, its size, how many are recorded, the first
        image without a recording (None when all are)."""
        if self.source is None:
            return {"source": None, "count": 0, "recorded": 0, "next": None}
        done = self.recorded()
        nxt = next((n for n in range(self.source.count) if n not in done), None)
        return {"source": self.source.kind, "count": self.source.count,
                "recorded": len(done), "next": nxt}  # fmt: skip

    def meta(self, n) -> dict:
        """``GET /api/images/{n}/meta``."""
        n = self.index(n)
        h, w = self.source.size(n)
        return {"index": n, "label": self.source.label(n), "width": w, "height": h,
                "name": self.source.name(n), "recorded": self.path(n).exists()}  # fmt: skip

    def png(self, n) -> bytes:
        """``GET /api/images/{n}``: the image as PNG, dark ink on white."""
        return self._source().png(self.index(n))

    def _label(self, n: int, label) -> int:
        known = self.source.label(n)
        if label is None:
            if known is None:
                raise WebError(422, "label: required for this image source (a digit 0-9)")
            return known
        if isinstance(label, bool) or not isinstance(label, int) or not 0 <= label <= 9:
            raise WebError(422, f"label: must be a digit 0-9, got {show(label)}")
        if known is not None and label != known:
            raise WebError(422, f"label: {label} disagrees with MNIST's label {known} of image {n}")
        return label

    @contextmanager
    def _locked(self):
        """This process's threads one at a time, and other processes through
        ``fcntl.flock`` on ``DATA_DIR/.lock`` (503 after ``LOCK_TIMEOUT_S``)."""
        with self._lock:
            try:
                fd = open_lock_file(self.data_dir, "--data-dir")
            except OSError as e:  # the folder changed under the server
                raise WebError(503, f"the recordings cannot be locked: {e}") from None
            try:
                deadline = time.monotonic() + LOCK_TIMEOUT_S
                while True:
                    try:
                        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                        break
                    except BlockingIOError:
                        if time.monotonic() > deadline:
                            raise WebError(
                                503, f"data directory {self.data_dir} is locked; try again"
                            ) from None
                        time.sleep(0.01)
                yield
            finally:
                os.close(fd)

    def write(self, n, label, strokes, replace: bool) -> dict:
        """Check and write one recording (``POST /api/recordings``); its 201 answer.

        Raises ``WebError``: 409 without an image source or for an image already recorded
        (unless ``replace``), 422 for a bad image index, label or stroke.
        """
        source = self._source()
        n = self.index(n, status=422)
        label = self._label(n, label)
        h, w = source.size(n)
        arrays = check_strokes(strokes, (-w / 2, 1.5 * w, -h / 2, 1.5 * h), f"image {n}")
        points = sum(len(a) for a in arrays)
        if points < 2:
            raise WebError(422, f"strokes: a recording needs at least 2 points, got {points}")
        now = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
        doc = recording_document(n, label, arrays, source, now.replace("+00:00", "Z"))
        text = json.dumps(doc, ensure_ascii=False) + "\n"
        path = self.path(n)
        parse_recorded(text, path.name)  # what load_recorded reads; a failure here is a bug
        with self._locked():
            if path.exists() and not replace:
                raise WebError(409, f"image {n} is already recorded ({path.name}); replace: true")
            atomic_write_text(path, text)
        summary = self.summary()
        return {"file": path.name, "points": points, "strokes": len(arrays),
                "recorded": summary["recorded"], "next": summary["next"]}  # fmt: skip


__all__ = [
    "FolderImages",
    "IMAGE_SUFFIXES",
    "MnistImages",
    "Recordings",
    "recording_document",
]
