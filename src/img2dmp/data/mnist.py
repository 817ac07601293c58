"""Reading the MNIST digits from their IDX files (gzip-compressed or raw).

The IDX layout (LeCun et al.): a big-endian int32 magic number whose third byte is the
element type (``0x08`` = uint8) and whose fourth byte is the number of dimensions, one
big-endian int32 size per dimension, then the elements in row-major order. The image
files have magic 2051 (``0x00000803``, shape ``[n, 28, 28]``), the label files 2049
(``0x00000801``, shape ``[n]``).

Every reader here validates what it reads and raises ``ValueError`` naming the file:
a truncated gzip stream, a wrong magic number, a size that does not match the data, or
trailing bytes are reported, never skipped.
"""

from __future__ import annotations

import gzip
import os
import struct
import zlib
from pathlib import Path

import numpy as np

from .._files import atomic_write_bytes

IMAGES_MAGIC = 2051
LABELS_MAGIC = 2049
_GZIP_MAGIC = b"\x1f\x8b"

#: File stems of the two MNIST splits, as distributed (with or without ``.gz``).
MNIST_FILES = {
    "train": ("train-images-idx3-ubyte", "train-labels-idx1-ubyte"),
    "test": ("t10k-images-idx3-ubyte", "t10k-labels-idx1-ubyte"),
}


def _read_bytes(path: Path) -> bytes:
    """Whole file contents, transparently gunzipped; ``ValueError`` if the gzip is broken."""
    with open(path, "rb") as f:
        raw = f.read()
    if raw[:2] != _GZIP_MAGIC:
        return raw
    try:
        return gzip.decompress(raw)
    except (EOFError, OSError, zlib.error) as e:
        raise ValueError(f"{path}: corrupt or truncated gzip stream ({e})") from e


def read_idx(path: str | os.PathLike, expect_magic: int | None = None) -> np.ndarray:
    """Read one IDX file of unsigned bytes (gzip or raw).

    Parameters
    ----------
    path : path-like
        The IDX file, e.g. ``train-images-idx3-ubyte.gz``; gzip is detected from the
        content, not the name.
    expect_magic : int, optional
        Required magic number (2051 for images, 2049 for labels).

    Returns
    -------
    numpy.ndarray
        uint8 array with the shape stored in the header, e.g. ``[n, 28, 28]`` or ``[n]``.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        Naming the file, if the gzip stream is corrupt or truncated, the magic number is
        not an uint8 IDX one (or not ``expect_magic``), or the number of bytes does not
        match the sizes in the header.
    """
    path = Path(path)
    data = _read_bytes(path)
    if len(data) < 4:
        raise ValueError(f"{path}: too short for an IDX header ({len(data)} bytes)")
    (magic,) = struct.unpack(">i", data[:4])
    zero, dtype_code, ndim = data[0:2], data[2], data[3]
    if zero != b"\x00\x00" or dtype_code != 0x08 or ndim == 0:
        raise ValueError(
            f"{path}: bad IDX magic number {magic} (0x{magic & 0xFFFFFFFF:08x}); expected "
            f"an unsigned-byte IDX file such as {IMAGES_MAGIC} (images) or {LABELS_MAGIC} "
            "(labels)"
        )
    if expect_magic is not None and magic != expect_magic:
        raise ValueError(f"{path}: IDX magic number is {magic}, expected {expect_magic}")
    header_len = 4 + 4 * ndim
    if len(data) < header_len:
        raise ValueError(f"{path}: truncated IDX header (needs {header_len} bytes)")
    dims = struct.unpack(f">{ndim}i", data[4:header_len])
    if any(n < 0 for n in dims):
        raise ValueError(f"{path}: negative size in IDX header {dims}")
    expected = int(np.prod(dims, dtype=np.int64))
    got = len(data) - header_len
    if got != expected:
        what = "truncated" if got < expected else "has trailing bytes"
        raise ValueError(
            f"{path}: IDX data {what}: header says {'x'.join(map(str, dims))} = {expected} "
            f"bytes, the file holds {got}"
        )
    return np.frombuffer(data, dtype=np.uint8, offset=header_len).reshape(dims)


def find_mnist_file(directory: str | os.PathLike, stem: str) -> Path:
    """Path of ``stem.gz`` or ``stem`` in ``directory`` (also accepting ``stem.idx*`` dots).

    Raises ``FileNotFoundError`` naming both names tried.
    """
    directory = Path(directory)
    for name in (f"{stem}.gz", stem, stem.replace("-idx", ".idx")):
        p = directory / name
        if p.is_file():
            return p
    raise FileNotFoundError(f"no MNIST file {stem}.gz or {stem} in {directory}")


def load_mnist(directory: str | os.PathLike, split: str = "train") -> tuple[np.ndarray, np.ndarray]:
    """Images and labels of one MNIST split.

    Parameters
    ----------
    directory : path-like
        Folder holding the four standard IDX files (gzip or raw).
    split : {"train", "test"}
        ``"train"`` (60,000 digits) or ``"test"`` (the 10,000 ``t10k`` digits).

    Returns
    -------
    images : float32 [n, 28, 28]
        In [0, 1], ink = 1 (MNIST stores 0 = background, 255 = ink), row-major: pixel
        ``[i, j]`` is row i, column j, centred at ``(x=j, y=i)`` (docs/CONTRACTS.md).
    labels : int64 [n]
        Digit 0-9.

    Raises
    ------
    ValueError
        If a file is malformed (see :func:`read_idx`), the counts of images and labels
        differ, or a label is outside 0-9.
    """
    if split not in MNIST_FILES:
        raise ValueError(f"MNIST split must be one of {sorted(MNIST_FILES)}, got {split!r}")
    img_path = find_mnist_file(directory, MNIST_FILES[split][0])
    lab_path = find_mnist_file(directory, MNIST_FILES[split][1])
    images = read_idx(img_path, IMAGES_MAGIC)
    labels = read_idx(lab_path, LABELS_MAGIC)
    if images.ndim != 3:
        raise ValueError(f"{img_path}: expected a 3-D image array, got shape {images.shape}")
    if labels.ndim != 1:
        raise ValueError(f"{lab_path}: expected a 1-D label array, got shape {labels.shape}")
    if len(images) != len(labels):
        raise ValueError(
            f"{img_path} holds {len(images)} images but {lab_path} holds {len(labels)} labels"
        )
    if labels.size and labels.max() > 9:
        bad = int(np.flatnonzero(labels > 9)[0])
        raise ValueError(f"{lab_path}: label {int(labels[bad])} at index {bad} is not a digit")
    return images.astype(np.float32) / 255.0, labels.astype(np.int64)


def unlabelled_images(
    directory: str | os.PathLike, count: int | None = None, seed: int = 0
) -> np.ndarray:
    """MNIST images that may train without a recorded path, ``float32 [n, 28, 28]``.

    Every test image (``t10k``) and every training image whose index falls in the
    training part of the recorded paths' split rule
    (:func:`img2dmp.data.recorded.split_of_index` = 0): never an image of the validation
    or test part, so evaluation stays inductive. Shuffled with ``seed``; the first
    ``count`` (all if None).
    """
    from .recorded import split_of_index

    train, _ = load_mnist(directory, "train")
    test, _ = load_mnist(directory, "test")
    keep = split_of_index(range(len(train))) == 0
    images = np.concatenate([train[keep], test])
    order = np.random.default_rng(seed).permutation(len(images))
    if count is not None:
        if isinstance(count, bool) or int(count) < 1:
            raise ValueError(f"count must be an integer >= 1 or None, got {count!r}")
        order = order[: int(count)]
    return images[order]


def write_idx(path: str | os.PathLike, array: np.ndarray, compress: bool | None = None) -> None:
    """Write a uint8 array as an IDX file (gzip if ``compress`` or the name ends in .gz).

    The inverse of :func:`read_idx`; used to make small test files.
    """
    path = Path(path)
    a = np.ascontiguousarray(array, dtype=np.uint8)
    header = struct.pack(">BBBB", 0, 0, 0x08, a.ndim) + struct.pack(f">{a.ndim}i", *a.shape)
    payload = header + a.tobytes()
    if compress if compress is not None else path.suffix == ".gz":
        payload = gzip.compress(payload)
    atomic_write_bytes(path, payload)
