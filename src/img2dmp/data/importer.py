"""Your own images and pen paths to an img2dmp data set (``img2dmp import``).

A sample is an image of one written shape (a letter, symbol, digit, any class) and the
pen path that wrote it. :func:`import_dataset` reads them from

- a **folder** with one sub-folder per class, named after the class, each holding one
  image per sample (``.png``, ``.jpg``, ``.jpeg``, ``.bmp``, ``.gif``, ``.tif``, ``.tiff``,
  ``.webp``) and its trajectory file of the same stem (``.csv``, ``.json`` or ``.npy``)::

      letters/L/001.png  letters/L/001.csv  letters/T/001.png  letters/T/001.json ...

  Files and folders whose names start with ``.`` are ignored; so are files at the top
  that are not images (a manifest, a README, the data set written there). Every other
  file is part of a sample or refused.
- a **manifest**, a CSV file with the header ``image,trajectory,class`` and optionally
  ``split`` (``train``, ``validation`` or ``test``), or a JSON list of objects with those
  keys. Paths are relative to the manifest's folder (or absolute).
- a **folder of recordings** made on the Record page of ``img2dmp serve --images DIR``
  (``image_<n>.json``, each naming its ``"Image file"`` and digit), with ``images``, the
  folder of the images they trace.
- **Omniglot**: a folder holding ``images_NAME`` and ``strokes_NAME`` (folders, or the
  zip files as distributed), or ``strokes_NAME`` itself with its images beside it or
  given as ``images``; classes ``alphabet/character``, split by drawer (or ``split_by``
  character or alphabet). Its stroke files and their rules: :mod:`img2dmp.data.omniglot`.

**Trajectory files** (:func:`read_trajectory`), in pixels of the sample's own image:
x = column, y = row (y points down), the centre of pixel ``[i, j]`` at ``(x=j, y=i)``;
t in seconds (``time_unit="ms"``: milliseconds), strictly increasing (with
``spread_repeated_times`` a repeated stamp is spread, as Omniglot's reader does).

- CSV with the header ``x,y,t`` or ``x,y,t,pen`` (any column order): ``pen`` is 1 where
  the pen touches the paper and 0 where it is lifted, so one file holds any number of
  strokes (each a run of pen-down points; the points between are pen-up travel);
- JSON: ``{"x": [...], "y": [...], "t": [...]}`` (optionally ``"pen": [...]``), or a list
  of strokes, each ``{"x": [...], "y": [...], "t": [...]}`` or a list of ``[x, y, t]``
  points (the pen is lifted between strokes), or ``{"strokes": [...]}``;
- NumPy ``.npy``: ``[T, 3]`` (x, y, t) or ``[T, 4]`` (x, y, t, pen);
- a recording in the recorded-path format (:mod:`img2dmp.data.recorded`: a JSON object
  with ``"Path"``, times in milliseconds, the image covering ``[0, W] x [0, H]``, and
  optionally ``"Strokes"``, the pen-down spans), read in its own units and frame.

**What happens to a sample** (:func:`import_samples`):

1. The trajectory is read and checked (numbers, finite, at least 2 points, t strictly
   increasing, pen 0 or 1, every stroke at least 2 points), and must lie within its
   image (no point beyond the border by more than ``OUTSIDE_TOLERANCE`` of the image's
   side).
2. The image is prepared as :func:`img2dmp.data.images.prepare_image` prepares an image
   for a model (polarity from the border, crop to the ink, square with ``margin`` on
   every border, optionally the strokes brought to ``stroke_width_px``, resized to
   ``image_size``): training and prediction then see the same framing.
   :func:`~img2dmp.data.images.prepare_image_framed` gives the map of that crop, pad and
   resize (an :class:`~img2dmp.data.images.ImageFrame`), which moves the path along
   (stored per row in the metadata). At least ``min_on_ink`` of the pen-down path must
   then lie on the prepared image's ink (:func:`img2dmp.metrics.on_ink_share`), which
   catches swapped axes, y pointing up and paths of another image.
3. The path is resampled to ``n_times`` instants (linear interpolation; with strokes,
   ``(x, y, pen)``, the pen 1 on a stroke and 0 on the pen-up travel between): allocated
   per stroke and pen-up stretch in proportion to their durations, at least
   ``min(points, MIN_STROKE_INSTANTS)`` per stroke (a dot: one) and one per stretch, so
   that every stroke keeps its own (:func:`resample_strokes`; ``resample="uniform"``:
   evenly over the path's duration, :func:`resample_pen_path`, which refuses a path whose
   short strokes or lifts fall between its instants); each stroke's first and last
   instant are kept (the data set's ``stroke_spans``). With ``duration_s`` the path is
   rescaled to last that long.

Then ``augment`` random affine copies of every training sample are added
(:func:`img2dmp.data.affine.sample_affine` / ``warp_images`` / ``warp_points``, as
``img2dmp prepare`` does, seeded) and a DMP is fitted to every path
(:func:`img2dmp.data.build.fit_paths`). Splits come from the manifest, or are drawn per
class with ``seed`` (``val_fraction``, ``test_fraction`` of each class).

**Where the code is.** The readers only read (:mod:`img2dmp.data.sources`: ``files``
lists folders and manifests and holds :class:`ImportOptions`, ``trajectory`` reads the
trajectory files, ``recordings`` and ``omniglot`` their sources); steps 2-3 and
everything after them are the one build step shared with ``img2dmp prepare``
(:mod:`img2dmp.data.build`, :mod:`img2dmp.data.resample`). This module joins them and
keeps the names it always had.

**Classes** are any names: the classes found, sorted (or ``classes``, in its order; a
sample of another class is refused). The data set stores them as ``class_names`` in its
metadata and its ``labels`` index into them (:mod:`img2dmp.data.store`). Classes all named
``"0"`` .. ``"9"`` keep the digits as labels.

**Errors.** Every bad sample raises one ``ValueError`` (or ``FileNotFoundError``) naming
its file and the field, point or value at fault; nothing is skipped silently. With
``skip_bad=True`` bad samples are left out instead and listed, with their errors, in the
metadata (``source.skipped``) and the returned data's ``meta``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._progress import bar as progress_bar
from .build import (
    MAX_AUGMENT,
    OUTSIDE_TOLERANCE,
    Framed,
    FramedSample,
    build_dataset,
    check_within_image,
    draw_splits,
    fit_statistics,
    frame_pen_path,
)
from .resample import (
    MIN_STROKE_INSTANTS,
    RESAMPLING,
    PenPath,
    Resampled,
    resample,
    resample_pen_path,
    resample_strokes,
)
from .sources import find_samples, read_sample
from .sources.files import (
    IMAGE_SUFFIXES,
    MANIFEST_COLUMNS,
    OMNIGLOT_SPLIT_BY,
    ImportOptions,
    SampleSource,
    check_class_name,
)
from .sources.recordings import RECORDING_NAME
from .sources.trajectory import (
    MAX_POINTS,
    MAX_TRAJECTORY_BYTES,
    TIME_UNITS,
    TRAJECTORY_SUFFIXES,
    read_trajectory,
)
from .store import DIGIT_NAMES, STROKE_SPANS_KEY, DigitData

__all__ = [
    "IMAGE_SUFFIXES",
    "MANIFEST_COLUMNS",
    "MAX_AUGMENT",
    "MAX_POINTS",
    "MAX_TRAJECTORY_BYTES",
    "MIN_STROKE_INSTANTS",
    "OMNIGLOT_SPLIT_BY",
    "OUTSIDE_TOLERANCE",
    "PLAUSIBLE_MEDIAN_S",
    "PLAUSIBLE_MIN_MEDIAN_S",
    "POOR_FIT_PX",
    "RECORDING_NAME",
    "RESAMPLING",
    "TIME_UNITS",
    "TRAJECTORY_SUFFIXES",
    "ImportOptions",
    "PenPath",
    "Resampled",
    "SampleSource",
    "check_class_name",
    "check_within_image",
    "find_samples",
    "import_dataset",
    "import_samples",
    "read_trajectory",
    "resample",
    "resample_pen_path",
    "resample_strokes",
]


@dataclass
class _Imported:
    """One listed sample, read and framed."""

    source: SampleSource
    sample: FramedSample
    pen: PenPath  # as read, for the pen's checks


def _import_one(src: SampleSource, opt: ImportOptions) -> _Imported:
    """Read one listed sample and frame it (module docstring, steps 1-3)."""
    if opt.classes is not None and src.class_name not in opt.classes:
        raise ValueError(
            f"{src.name}: class {src.class_name!r} is not one of the classes {list(opt.classes)}"
        )
    image, pen, clean, place = read_sample(src, opt.time_unit, opt.spread_repeated_times)
    sample = frame_pen_path(image, pen, opt, name=str(src.image), clean=clean, place=place)
    return _Imported(src, sample, pen)


def _read_all(samples, opt: ImportOptions, progress: bool, skip_bad: bool, skipped: list):
    """Every good sample read and framed, and ``n_dims``; bad ones raise or join
    ``skipped``."""
    good = []
    for src in progress_bar(samples, desc="import", unit="sample", enabled=progress):
        try:
            good.append(_import_one(src, opt))
        except (ValueError, OSError) as e:
            e = _in_row(e, src)
            if not skip_bad:
                raise e
            skipped.append(str(e))
    n_dims = opt.n_dims or (3 if any(g.pen.needs_pen for g in good) else 2)
    if n_dims == 2:
        kept = []
        for g in good:
            if g.pen.needs_pen:
                e = ValueError(
                    f"{g.source.trajectory}: lifts the pen ({g.pen.n_strokes} stroke(s)), but "
                    "a data set of d = 2 holds one pen-down stroke per sample; import with "
                    "--dims 3"
                )
                if not skip_bad:
                    raise e
                skipped.append(str(e))
            else:
                kept.append(g)
        good = kept
    if not good:
        raise ValueError(
            f"no sample could be imported ({len(skipped)} skipped"
            + (f"; the first: {skipped[0]}" if skipped else "")
            + ")"
        )
    return good, n_dims


def _in_row(e: Exception, src: SampleSource) -> Exception:
    """``e`` with the manifest row of ``src`` in front of its message (a folder's samples
    are named by their files, which every message holds already)."""
    if not src.where or str(e).startswith(src.where):
        return e
    try:
        out = type(e)(f"{src.where}: {e}")
    except TypeError:  # an exception class of other arguments
        out = ValueError(f"{src.where}: {e}")
    out.__cause__ = e
    return out


def _class_labels(names: list[str], classes) -> tuple[tuple[str, ...] | None, np.ndarray]:
    """The class names the labels index into (None: the digits themselves) and the labels."""
    if classes is None:
        found = sorted(set(names))
        if all(n in DIGIT_NAMES for n in found):
            return None, np.array([int(n) for n in names], np.int64)
        classes = tuple(found)
    index = {n: i for i, n in enumerate(classes)}
    return tuple(classes), np.array([index[n] for n in names], np.int64)


def _splits(sources: list[SampleSource], labels: np.ndarray, opt: ImportOptions, rng):
    """The split of every sample: the manifest's, or drawn per class, or whole units
    (Omniglot by character or alphabet) per stratum."""
    units = None
    if any(s.unit is not None for s in sources):
        units = [(s.stratum or "", s.unit or s.name) for s in sources]
    return draw_splits(
        [s.split for s in sources],
        labels,
        units,
        (opt.val_fraction, opt.test_fraction),
        rng,
        [s.name for s in sources],
    )


def _relative(path, root: Path | None) -> str:
    """A sample's file relative to the source (a file in a zip: ``ARCHIVE/MEMBER``, the
    archive relative to it)."""
    if not isinstance(path, Path):
        return f"{_relative(path.archive, root)}/{path.name}"
    try:
        return str(path.relative_to(root)) if root is not None else str(path)
    except ValueError:
        return str(path)


def import_samples(
    samples: list[SampleSource],
    options: ImportOptions | None = None,
    *,
    source: str | os.PathLike | None = None,
    progress: bool = False,
    skip_bad: bool = False,
    skipped: list[str] | None = None,
) -> DigitData:
    """Build a data set from listed samples (the steps of the module docstring).

    Parameters
    ----------
    samples : list of SampleSource
    options : ImportOptions
        Default ``ImportOptions()``.
    source : path, optional
        The folder or manifest they came from (recorded in the metadata; the rows' files
        are stored relative to it).
    progress : bool
        Progress bars (one line each when not on a terminal).
    skip_bad : bool
        Leave bad samples out, listed in ``meta["source"]["skipped"]``, instead of raising.
    skipped : list of str, optional
        Errors of files already left out while listing (:func:`find_samples`).

    Returns
    -------
    DigitData
        Not yet written (:func:`img2dmp.data.store.save_dataset`).
    """
    opt = options or ImportOptions()
    skipped = list(skipped or [])
    n_unread = len(skipped)  # the source's entries that make no sample, found before reading
    good, n_dims = _read_all(samples, opt, progress, skip_bad, skipped)
    config = opt.dmp_config(n_dims)
    class_names, labels = _class_labels([g.source.class_name for g in good], opt.classes)
    split_rng, augment_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(opt.seed).spawn(2)
    )
    framed = Framed(
        images=np.stack([g.sample.image for g in good]).astype(np.float32),
        paths=np.stack([g.sample.path[:, :n_dims] for g in good]),
        times=np.stack([g.sample.times for g in good]),
        labels=labels,
        split=_splits([g.source for g in good], labels, opt, split_rng),
    )
    root = None if source is None else Path(source)
    root = root.parent if root is not None and not root.is_dir() else root

    def source_meta(rows, copy, fit):
        meta = _meta(opt, config, good, (class_names, labels[rows]), rows, copy, fit, root)
        meta["source"] = _source_record(opt, good, source, root, skipped, n_unread)
        return meta

    return build_dataset(
        framed, options=opt, config=config, rng=augment_rng, source_meta=source_meta,
        progress=progress,
    )  # fmt: skip


def _source_record(
    opt: ImportOptions, good: list[_Imported], source, root, skipped: list[str], n_entries: int
) -> dict:
    """The data set's ``meta["source"]``: where the samples came from, and Omniglot's
    split and the drawings moved onto their ink. ``skipped``: the errors left out, the
    first ``n_entries`` of them the source's entries that make no sample (a stray file, an
    empty folder, an image without its path), the rest samples that failed to read."""
    record = {
        "kind": "import",
        "path": None if source is None else str(source),
        "samples": len(good),
        "skipped": skipped,
        "skipped_entries": n_entries,
        "median_duration_s": float(np.median([g.pen.t_s[-1] - g.pen.t_s[0] for g in good])),
    }
    if any(g.source.format == "omniglot" for g in good):
        shifted = {
            _relative(g.source.trajectory, root): list(g.sample.shift)
            for g in good
            if g.sample.shift
        }
        record.update(format="omniglot", split_by=opt.split_by or "drawer", shifted=shifted)
    return record


def _meta(opt, config, good, classes, rows, copy, fit, root: Path | None) -> dict:
    """The source's part of the data set's metadata; ``classes`` is ``(class names or
    None, labels [M])`` of the stored rows."""
    class_names, labels = classes
    names = class_names or DIGIT_NAMES
    sources = [good[r].source for r in rows]
    # Every class named (``classes`` may name one no sample has: 0), or the digits found.
    counted = np.unique(labels) if class_names is None else range(len(class_names))
    meta = {
        "import": {**opt.to_dict(), "n_dims": config.n_dims, "scaling": config.scaling},
        "counts_by_class": {names[c]: int((labels == c).sum()) for c in counted},
        "units": "pixels of the stored images (x = column, y = row); a point (x, y) of a "
        "row's own image is at A @ (x, y) + b in the stored image before any augmentation, "
        "[A | b] = rows.image_to_model (img2dmp.data.images.ImageFrame)",
        "rows": {
            "image": [_relative(s.image, root) for s in sources],
            "trajectory": [_relative(s.trajectory, root) for s in sources],
            "image_size": [list(good[r].sample.frame.image_size) for r in rows],
            "image_to_model": [good[r].sample.frame.image_to_model.tolist() for r in rows],
            "augment_copy": copy.tolist(),
        },
        "fit": _fit_record(fit, labels, names, [s.trajectory for s in sources], root),
        STROKE_SPANS_KEY: [[list(span) for span in good[r].sample.spans] for r in rows],
    }
    if class_names is not None:
        meta["class_names"] = list(class_names)
    return meta


#: Longest median duration (s) of a data set's paths, as read, that ``img2dmp import``
#: takes for handwriting timed in seconds; beyond it, it notes that the files' t may be
#: milliseconds (``--time-unit ms``). Omniglot's 2,720 drawings
#: (``strokes_background_small1``) last 3.5 s in the median, 99 % of them under 35 s; a
#: character timed in ms and read as seconds lasts a thousand times as long.
PLAUSIBLE_MEDIAN_S = 60.0
#: Shortest median duration (s) taken for handwriting timed in milliseconds (Omniglot's
#: stroke files, ``--time-unit ms``): MNIST's recorded digits last 0.118 s at the least,
#: and a character timed in seconds and read as ms lasts a thousandth as long.
PLAUSIBLE_MIN_MEDIAN_S = 0.1


def time_unit_note(meta: dict) -> str | None:
    """A one-line note when an imported data set's paths last implausibly long or short
    for handwriting (their median beyond ``PLAUSIBLE_MEDIAN_S`` with t read in seconds,
    or under ``PLAUSIBLE_MIN_MEDIAN_S`` with t read in milliseconds; no ``duration_s``),
    suggesting the other unit; else None. Omniglot's stroke files are read in ms."""
    median = meta["source"].get("median_duration_s")
    opt = meta["import"]
    if median is None or opt.get("duration_s") is not None:  # rescaled: no matter
        return None
    omniglot = meta["source"].get("format") == "omniglot"
    unit = "ms" if omniglot else opt.get("time_unit")
    if median > PLAUSIBLE_MEDIAN_S and unit == "s":
        return (
            f"note: the paths last {median:.4g} s in the median (t read in seconds), "
            f"implausibly long for handwriting (more than {PLAUSIBLE_MEDIAN_S:g} s; "
            "Omniglot's drawings: 3.5 s); if the files' t are milliseconds, import again "
            "with --time-unit ms"
        )
    if median < PLAUSIBLE_MIN_MEDIAN_S and unit == "ms":
        remedy = (
            "Omniglot's stroke files give t in milliseconds: if these give seconds, write "
            "them in ms, or rescale every path with --duration SECONDS"
            if omniglot
            else "if the files' t are seconds, import again without --time-unit ms"
        )
        return (
            f"note: the paths last {median:.4g} s in the median (t read in milliseconds), "
            f"implausibly short for handwriting (less than {PLAUSIBLE_MIN_MEDIAN_S:g} s; "
            f"Omniglot's drawings: 3.5 s); {remedy}"
        )
    return None


#: A DMP fit whose mean error exceeds this (px) is reported as poor (``fit.poor``).
POOR_FIT_PX = 1.0


def _fit_record(fit, labels, names, files, root: Path | None) -> dict:
    """The ``fit`` record: errors overall and per class, the pen's agreement for d = 3,
    and the poor fits (the paper's goal-start scaling fails where start and goal nearly
    coincide: closed shapes)."""
    poor = np.flatnonzero(fit.error_px > POOR_FIT_PX)
    worst = int(np.argmax(fit.error_px))
    return {
        **fit_statistics(fit, labels, names, "class"),
        "poor": {
            "threshold_px": POOR_FIT_PX,
            "rows": int(len(poor)),
            "worst_row": worst,
            "worst_trajectory": _relative(files[worst], root),
            "worst_mean_error_px": float(fit.error_px[worst]),
        },
    }


def import_dataset(
    source: str | os.PathLike,
    options: ImportOptions | None = None,
    *,
    progress: bool = False,
    skip_bad: bool = False,
    images: str | os.PathLike | None = None,
) -> DigitData:
    """Your images and pen paths, from a folder of class folders, a manifest, or a folder
    of recordings and the folder of their ``images``, as a data set (see the module
    docstring for the layout, the formats and the checks).

    ``img2dmp import SOURCE --out FILE`` runs this and saves the result with
    :func:`img2dmp.data.store.save_dataset`. Raises ``ValueError`` or
    ``FileNotFoundError`` naming the file (and row, field or value) of the first bad
    sample, unless ``skip_bad``: then bad samples are left out and listed in
    ``meta["source"]["skipped"]``.
    """
    opt = options or ImportOptions()
    samples, skipped = find_samples(source, skip_bad=skip_bad, images=images, split_by=opt.split_by)
    return import_samples(
        samples, opt, source=source, progress=progress, skip_bad=skip_bad, skipped=skipped
    )
