"""Folders of class folders and manifests: where your own samples are (``img2dmp import``).

:func:`folder_samples` lists a folder with one sub-folder per class, each holding one
image per sample and its trajectory file of the same stem; :func:`manifest_samples` a CSV
(``image,trajectory,class[,split]``) or JSON manifest. Both only list: a
:class:`SampleSource` names a sample's files, its class and its split if given; reading
and checking the trajectory is :mod:`.trajectory`'s, the rest the build's
(:mod:`img2dmp.data.build`). :class:`ImportOptions` holds the options of the samples
listed here, by recordings (:mod:`.recordings`) and by Omniglot (:mod:`.omniglot`).
"""

from __future__ import annotations

import csv
import unicodedata
from dataclasses import dataclass
from pathlib import Path

from ...errors import show
from ..build import BuildOptions, check_number
from ..images import DEFAULT_MARGIN
from ..resample import RESAMPLING
from ..store import MAX_CLASS_NAME_CHARS, MAX_CLASSES, SPLITS
from .trajectory import TIME_UNITS, TRAJECTORY_SUFFIXES, load_json

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".gif", ".tif", ".tiff", ".webp")
MANIFEST_COLUMNS = ("image", "trajectory", "class", "split")
#: The ways of splitting Omniglot's drawings (img2dmp.data.sources.omniglot.SPLIT_BY).
OMNIGLOT_SPLIT_BY = ("drawer", "character", "alphabet")


@dataclass
class ImportOptions(BuildOptions):
    """Everything that decides how your samples become a data set: the shared
    :class:`~img2dmp.data.build.BuildOptions` (``image_size``, ``n_times``, ``n_dims``,
    ``scaling``, ``n_kernels``, ``ridge``, ``augment``, ``affine``, ``seed``,
    ``duration_s``; here ``n_dims`` None is 3 if any sample has pen-up points or several
    strokes, else 2, and ``seed`` also draws the split) and these.

    Attributes
    ----------
    margin : float
        Share of the side left empty around the ink on every border
        (:func:`img2dmp.data.images.prepare_image`), in [0, 0.45].
    resample : {"strokes", "uniform"}
        How the instants are placed: ``"strokes"`` allocates them per stroke and pen-up
        stretch, so that every stroke and dot keeps its own
        (:func:`img2dmp.data.resample.resample_strokes`); ``"uniform"`` spreads them
        evenly over the path's duration, refusing a path whose strokes or lifts that grid
        loses (:func:`img2dmp.data.resample.resample_pen_path`, the only way before).
    time_unit : {"s", "ms"}
        Unit of the files' ``t``.
    spread_repeated_times : bool
        Spread a time stamp equal to the one before it, as Omniglot's reader does
        (:func:`~.trajectory.spread_repeated_stamps`), instead of refusing the file.
    val_fraction, test_fraction : float
        Share of each class put in validation / test when the source gives no split (of
        each alphabet's characters, or of the alphabets, with ``split_by``).
    split_by : {"drawer", "character", "alphabet"} or None
        How Omniglot's drawings are split (:mod:`img2dmp.data.sources.omniglot`); None: by
        drawer. Other sources refuse it.
    classes : tuple of str or None
        The class names in label order; None: the classes found, sorted.
    min_on_ink : float
        Least share of a pen-down path on its prepared image's ink, in [0, 1] (0: off).
    stroke_width_px : float or None
        Bring every image's strokes to this pen width in stored pixels (as ``img2dmp
        predict`` does for a model's images), up to a quarter of ``image_size``; None keeps
        each image's own width (scaled with its framing).
    """

    image_size: int = 40
    margin: float = DEFAULT_MARGIN
    resample: str = "strokes"
    time_unit: str = "s"
    spread_repeated_times: bool = False
    val_fraction: float = 0.1
    test_fraction: float = 0.2
    split_by: str | None = None
    classes: tuple[str, ...] | None = None
    min_on_ink: float = 0.5
    stroke_width_px: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        check_number("margin", self.margin, 0.0, 0.45)
        check_number("min_on_ink", self.min_on_ink, 0.0, 1.0)
        check_number("val_fraction", self.val_fraction, 0.0, 0.9)
        check_number("test_fraction", self.test_fraction, 0.0, 0.9)
        if self.val_fraction + self.test_fraction >= 1.0:
            raise ValueError(
                f"val_fraction + test_fraction must be < 1 (some samples must train), got "
                f"{self.val_fraction} + {self.test_fraction}"
            )
        if self.stroke_width_px is not None:
            widest = self.image_size / 4.0
            check_number("stroke_width_px", self.stroke_width_px, 0.0, widest, open_low=True)
        if self.split_by not in (None, *OMNIGLOT_SPLIT_BY):
            raise ValueError(
                f"split_by must be one of {list(OMNIGLOT_SPLIT_BY)} or None, "
                f"got {show(self.split_by)}"
            )
        if self.resample not in RESAMPLING:
            raise ValueError(
                f"resample must be one of {list(RESAMPLING)}, got {show(self.resample)}"
            )
        if not isinstance(self.spread_repeated_times, bool):
            raise ValueError(
                "spread_repeated_times must be true or false, got "
                f"{show(self.spread_repeated_times)}"
            )
        if self.time_unit not in TIME_UNITS:
            raise ValueError(
                f"time_unit must be one of {list(TIME_UNITS)}, got {show(self.time_unit)}"
            )
        if self.classes is not None:
            self.classes = _check_class_list(tuple(self.classes))

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["classes"] = None if self.classes is None else list(self.classes)
        return d


def check_class_name(name, where: str) -> str:
    """``name`` in Unicode NFC if it can name a class (non-empty printable text of at most
    ``MAX_CLASS_NAME_CHARS`` characters, no surrounding spaces, no comma), else
    ``ValueError``. NFC: an "é" written as one character or as "e" and its accent (as
    macOS names folders) is one class; a comma would split the name in ``--classes``."""
    if not isinstance(name, str):
        raise ValueError(f"{where}: class {show(name)} must be text")
    if not name or name != name.strip() or not name.isprintable():
        raise ValueError(
            f"{where}: class {show(name)} is no class name (non-empty printable text without "
            "surrounding spaces)"
        )
    name = unicodedata.normalize("NFC", name)
    if "," in name:
        raise ValueError(
            f"{where}: class {name!r} holds a comma, which --classes reads as a separator "
            "(this class could never be selected); rename it without one"
        )
    if len(name) > MAX_CLASS_NAME_CHARS:
        raise ValueError(
            f"{where}: class name {name[:20]!r}... has {len(name)} characters, more than "
            f"{MAX_CLASS_NAME_CHARS}"
        )
    return name


def _check_class_list(names: tuple) -> tuple[str, ...]:
    """The class names ``names`` in NFC (:func:`check_class_name`), each once."""
    if not 1 <= len(names) <= MAX_CLASSES:
        raise ValueError(f"classes must name 1 to {MAX_CLASSES} classes, got {len(names)}")
    names = tuple(check_class_name(name, f"classes entry {i}") for i, name in enumerate(names))
    for i, name in enumerate(names):
        if names.index(name) != i:
            raise ValueError(f"classes entry {i} repeats {name!r}")
    return names


# --- where the samples are ------------------------------------------------------------


@dataclass(frozen=True)
class SampleSource:
    """One sample to import.

    Attributes
    ----------
    image, trajectory : Path or img2dmp.data.omniglot.ArchiveMember
        Its image file and its trajectory file (or a file in a zip).
    class_name : str
    split : {"train", "validation", "test"} or None
        None: drawn at random (:class:`ImportOptions` ``val_fraction``, ``test_fraction``).
    where : str
        Where it was listed, for messages (``manifest.csv: row 3``); empty for a folder.
    format : str
        How the trajectory is read: ``""`` by its suffix (:func:`read_trajectory`),
        ``"omniglot"`` as an Omniglot stroke file (:mod:`img2dmp.data.omniglot`).
    unit, stratum : str or None
        With ``unit``, the samples of one unit go to one split together, the units of
        each ``stratum`` drawn as a class's samples are (Omniglot by character: unit the
        character, stratum its alphabet); None: each sample is its own unit, drawn among
        its class.
    """

    image: Path
    trajectory: Path
    class_name: str
    split: str | None = None
    where: str = ""
    format: str = ""
    unit: str | None = None
    stratum: str | None = None

    @property
    def name(self) -> str:
        """How messages name it: its manifest row, else its trajectory file."""
        return self.where or str(self.trajectory)


def folder_samples(root: Path) -> tuple[list[SampleSource], list[Exception]]:
    samples: list[SampleSource] = []
    problems: list[Exception] = []
    class_dirs = []
    for p in sorted(root.iterdir()):
        if p.name.startswith("."):
            continue
        if p.is_dir():
            class_dirs.append(p)
        elif p.suffix.lower() in IMAGE_SUFFIXES:
            problems.append(
                ValueError(
                    f"{p}: an image at the top of {root}; put every sample in the folder "
                    f"of its class ({root / 'CLASS' / p.name}), or give a manifest as the source"
                )
            )
    if not class_dirs:
        raise ValueError(
            f"{root}: holds no class folders; expected {root}/CLASS/NAME.png with "
            f"{root}/CLASS/NAME.csv (or .json, .npy), one folder per class"
        )
    for d in class_dirs:
        try:
            name = check_class_name(d.name, str(d))
        except ValueError as e:
            problems.append(e)
            continue
        found, bad = _class_folder(d, name)
        samples += found
        problems += bad
    return samples, problems


def _class_folder(d: Path, name: str) -> tuple[list[SampleSource], list[Exception]]:
    """The samples in the folder of class ``name``, and the files that make none."""
    images: dict[str, Path] = {}
    trajectories: dict[str, Path] = {}
    problems: list[Exception] = []
    for p in sorted(d.iterdir()):
        suffix = p.suffix.lower()
        if p.name.startswith("."):
            continue
        if p.is_dir():
            problems.append(ValueError(f"{p}: a folder in the class folder {d}; samples go in {d}"))
            continue
        group = images if suffix in IMAGE_SUFFIXES else trajectories
        if suffix not in IMAGE_SUFFIXES + TRAJECTORY_SUFFIXES:
            problems.append(
                ValueError(
                    f"{p}: neither an image ({', '.join(IMAGE_SUFFIXES)}) nor a trajectory "
                    f"({', '.join(TRAJECTORY_SUFFIXES)}) file"
                )
            )
        elif p.stem in group:
            problems.append(
                ValueError(f"{p}: {group[p.stem].name} has the same name; one file of each kind")
            )
        else:
            group[p.stem] = p
    samples = []
    for stem in sorted(set(images) | set(trajectories)):
        if stem not in trajectories:
            problems.append(
                FileNotFoundError(f"{images[stem]}: no trajectory file {stem}.csv, .json or .npy")
            )
        elif stem not in images:
            problems.append(
                FileNotFoundError(f"{trajectories[stem]}: no image {stem}.png (.jpg ...)")
            )
        else:
            samples.append(SampleSource(images[stem], trajectories[stem], name))
    if not images and not trajectories and not problems:
        problems.append(ValueError(f"{d}: the folder of class {name!r} holds no samples"))
    return samples, problems


def _manifest_rows(path: Path) -> tuple[list[str], list[dict], str]:
    """The columns and rows (dicts) of a manifest, and what a row is called in messages
    (``row`` n of a CSV file, counted from 1 after the header; ``entry`` n of a JSON list,
    counted from 0)."""
    if path.suffix.lower() == ".json":
        doc = load_json(path)
        if not isinstance(doc, list) or not all(isinstance(r, dict) for r in doc):
            raise ValueError(
                f'{path}: a JSON manifest is a list of objects {{"image": ..., "trajectory": '
                '..., "class": ..., "split": ...}'
            )
        return sorted({k for r in doc for k in r}), doc, "entry"
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            rows = [r for r in csv.reader(f) if any(c.strip() for c in r)]
    except (UnicodeDecodeError, csv.Error) as e:
        raise ValueError(f"{path}: not a readable UTF-8 CSV manifest ({e})") from None
    if not rows:
        raise ValueError(f"{path}: is empty; expected the header image,trajectory,class[,split]")
    header = [c.strip().lower() for c in rows[0]]
    out = []
    for i, r in enumerate(rows[1:]):
        if len(r) != len(header):
            raise ValueError(f"{path}: row {i + 1} has {len(r)} fields, the header {len(header)}")
        out.append(dict(zip(header, (c.strip() for c in r), strict=True)))
    return header, out, "row"


def manifest_samples(path: Path) -> tuple[list[SampleSource], list[Exception]]:
    columns, rows, word = _manifest_rows(path)
    unknown = [c for c in columns if c not in MANIFEST_COLUMNS]
    missing = [c for c in MANIFEST_COLUMNS[:3] if c not in columns]
    if unknown or missing or len(set(columns)) != len(columns):
        raise ValueError(
            f"{path}: has the columns {show(list(columns))}; expected image, trajectory, class "
            "and optionally split"
        )
    if not rows:
        raise ValueError(f"{path}: lists no samples")
    samples, problems, seen = [], [], {}
    for i, row in enumerate(rows):
        where = f"{path}: {word} {i + 1 if word == 'row' else i}"
        try:
            sample = _manifest_sample(path.parent, row, where)
            key = sample.trajectory.resolve()
            if key in seen:
                raise ValueError(f"{where}: repeats the trajectory of {seen[key]}")
            seen[key] = where.split(": ", 1)[1]
            samples.append(sample)
        except ValueError as e:
            problems.append(e)
    return samples, problems


def _manifest_sample(base: Path, row: dict, where: str) -> SampleSource:
    for key in ("image", "trajectory", "class"):
        if key not in row or not isinstance(row[key], str) or not row[key].strip():
            raise ValueError(
                f"{where}: field {key!r} is {show(row.get(key))}; it must be non-empty text"
            )
    for key in ("image", "trajectory"):
        if "\0" in row[key]:
            raise ValueError(
                f"{where}: field {key!r} is {show(row[key].strip())}, which holds a NUL byte "
                "(\\x00); no file name holds one"
            )
    split = row.get("split")
    if split in ("", None):
        split = None
    elif not isinstance(split, str) or split not in SPLITS:
        raise ValueError(f"{where}: field 'split' is {show(split)}; expected one of {list(SPLITS)}")
    name = check_class_name(row["class"].strip(), where)
    return SampleSource(
        image=base / row["image"].strip(),
        trajectory=base / row["trajectory"].strip(),
        class_name=name,
        split=split,
        where=where,
    )
