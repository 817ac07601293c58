"""Readers that only read: where a data set's samples come from.

Each yields samples - an image, its pen path (strokes with times), its class, and its
split or the unit it is split by - into the one build step (:mod:`img2dmp.data.build`:
frame, resample, augment, fit, record, data set). Adding a source is adding a reader
here; the build does not change.

=========================  ==========================================================
module                     reads
=========================  ==========================================================
:mod:`.mnist`              MNIST's images with their pen paths: ``PrepareOptions``,
                           the samples' batch (:class:`.mnist.MnistSamples`), the
                           frame check
:mod:`.mnist_recorded`     the recorded human pen paths over MNIST training images
:mod:`.mnist_traced`       the traced stroke sequences of all MNIST digits
:mod:`.files`              folders of class folders and manifests: ``ImportOptions``,
                           :class:`.files.SampleSource`
:mod:`.trajectory`         one sample's trajectory file (CSV, JSON, ``.npy``, a
                           recording)
:mod:`.recordings`         the recordings of ``img2dmp serve --images``' Record page
:mod:`.omniglot`           Omniglot's trees (or zips) of images and stroke files
=========================  ==========================================================

The file formats below them stay where other parts of img2dmp read them too:
:mod:`img2dmp.data.mnist` (IDX files), :mod:`img2dmp.data.recorded` (the recorded-path
JSON), :mod:`img2dmp.data.strokes` (the stroke sequences and their timing).
"""

from __future__ import annotations

import os
from pathlib import Path

from ..build import Place
from ..resample import PenPath
from .files import SampleSource, folder_samples, manifest_samples
from .recordings import recording_samples, recordings_in


def find_samples(
    source: str | os.PathLike,
    *,
    skip_bad: bool = False,
    images: str | os.PathLike | None = None,
    split_by: str | None = None,
) -> tuple[list[SampleSource], list[str]]:
    """The samples of a folder of class folders, of a manifest, of a folder of
    recordings with the folder of the images they trace (``images``), or of Omniglot's
    trees of images and strokes (:mod:`img2dmp.data.importer`; ``split_by``:
    :mod:`.omniglot`).

    Returns the samples and, with ``skip_bad``, the one-line errors of the files that make
    no sample (an image without trajectory, a stray file, a bad manifest row); without it
    the first such error is raised. A source that is not a folder or manifest at all, a
    folder without class folders and a manifest with a bad header always raise.
    """
    from .omniglot import find_omniglot, omniglot_trees

    source = Path(source)
    if not source.exists():
        raise FileNotFoundError(f"import source {source} does not exist")
    trees = omniglot_trees(source, images)
    if trees is not None:
        samples, problems = find_omniglot(trees, split_by)
    elif split_by is not None:
        raise ValueError(
            f"{source}: split_by {split_by!r} (--split-by) is for Omniglot sources; the "
            "split of other sources comes from a manifest or is drawn per class"
        )
    else:
        samples, problems = _listed(source, images)
    if problems and not skip_bad:
        raise problems[0]
    return samples, [str(e) for e in problems]


def _listed(source: Path, images) -> tuple[list[SampleSource], list[Exception]]:
    """The samples of a folder of recordings, of class folders, or of a manifest."""
    recordings = recordings_in(source)
    if images is not None and not recordings:
        raise ValueError(
            f"{source}: holds no recordings (image_<n>.json); --images goes with a folder of "
            "recordings made by img2dmp serve --images"
        )
    if recordings:
        return recording_samples(source, recordings, images)
    if source.is_dir():
        _no_zips_alone(source)
        return folder_samples(source)
    if source.suffix.lower() in (".csv", ".json"):
        return manifest_samples(source)
    zipped = (
        "; a zip file is read only as Omniglot's strokes_NAME.zip (images_NAME beside it): "
        "unzip it and import what it holds"
        if source.suffix.lower() == ".zip"
        else ""
    )
    raise ValueError(
        f"{source}: the source must be a folder of class folders or a .csv or .json "
        f"manifest{zipped}"
    )


def _no_zips_alone(folder: Path) -> None:
    """Refuse a folder of zip files but no class folders: zips are read only as
    Omniglot's trees (``images_NAME.zip`` with ``strokes_NAME.zip``)."""
    entries = [p for p in folder.iterdir() if not p.name.startswith(".")]
    zips = sorted(p.name for p in entries if p.is_file() and p.suffix.lower() == ".zip")
    if zips and not any(p.is_dir() for p in entries):
        raise ValueError(
            f"{folder}: holds no class folders, and zip files ({', '.join(zips[:3])}"
            f"{' ...' if len(zips) > 3 else ''}) are read only as Omniglot's images_NAME.zip "
            "with strokes_NAME.zip; unzip them and import what they hold"
        )


def read_sample(src: SampleSource, time_unit: str = "s", spread_repeated: bool = False) -> tuple:
    """One listed sample read: ``(image, pen, clean, place)``, the image as
    :func:`img2dmp.data.images.prepare_image_framed` reads it, its :class:`PenPath`,
    whether the image is a photo to clean of its paper, and how the path is put on the
    prepared image (:data:`img2dmp.data.build.Place`; None: checked to lie within it).
    ``time_unit`` and ``spread_repeated``: a trajectory file's (:func:`.read_trajectory`)."""
    from . import omniglot
    from .trajectory import read_trajectory

    if src.format == omniglot.FORMAT:  # clean renderings (the omniglot module docstring)
        pen: PenPath = omniglot.read_strokes(src.trajectory)
        place: Place = omniglot.fit_to_image
        return omniglot.image_of(src.image), pen, False, place
    return src.image, read_trajectory(src.trajectory, time_unit, spread_repeated), True, None
