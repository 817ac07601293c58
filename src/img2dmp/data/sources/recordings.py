"""Recordings made on the Record page of ``img2dmp serve --images DIR``: a folder of
``image_<n>.json`` files (the recorded-path format of :mod:`img2dmp.data.recorded`), each
naming the image it traces (``"Image file"``, in the folder ``images``) and its digit
(``"Image shape"``, the class). The recording itself is read as a trajectory file
(:func:`.trajectory.read_trajectory`).
"""

from __future__ import annotations

import re
from pathlib import Path

from ...errors import show
from .files import SampleSource
from .trajectory import load_json

#: A recording's file name (``img2dmp serve``'s Record page, the shared recordings).
RECORDING_NAME = re.compile(r"image_(\d+)\.json")


def recordings_in(source: Path) -> list[Path]:
    """The recordings (``image_<n>.json``) of a folder that holds no class folders."""
    if not source.is_dir():
        return []
    entries = [p for p in sorted(source.iterdir()) if not p.name.startswith(".")]
    if any(p.is_dir() for p in entries):
        return []
    return [p for p in entries if RECORDING_NAME.fullmatch(p.name)]


def recording_samples(root: Path, files: list[Path], images) -> tuple[list, list]:
    """The samples of a folder of recordings of the images in ``images`` (the Record page
    of ``img2dmp serve --images DIR``): each names its image (``"Image file"``) and its
    digit (``"Image shape"``, the class)."""
    if images is None:
        raise ValueError(
            f"{root}: holds recordings (image_<n>.json); give the folder of the images they "
            "trace with --images DIR (the folder given to img2dmp serve --images)"
        )
    images = Path(images)
    if not images.is_dir():
        raise FileNotFoundError(f"images folder {images} does not exist")
    samples, problems = [], []
    for p in files:
        try:
            doc = load_json(p)
            if not isinstance(doc, dict):
                raise ValueError(f"{p}: expected a recording (a JSON object)")
            name, label = doc.get("Image file"), doc.get("Image shape")
            if name is None:
                raise ValueError(
                    f'{p}: records MNIST image {show(doc.get("Image number"))} (no "Image file"); '
                    f"make a data set of MNIST recordings with img2dmp prepare --recorded {root}"
                )
            ok = isinstance(name, str) and name and "\0" not in name
            if not ok or Path(name).name != name:
                raise ValueError(f'{p}: "Image file" must be a file name, got {show(name)}')
            if not isinstance(label, int) or isinstance(label, bool) or not 0 <= label <= 9:
                raise ValueError(f'{p}: "Image shape" (the digit) must be 0-9, got {show(label)}')
            samples.append(SampleSource(images / name, p, str(label)))
        except (ValueError, OSError) as e:
            problems.append(e)
    return samples, problems
