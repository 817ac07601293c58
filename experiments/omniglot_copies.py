"""A larger Omniglot source for timing a recipe: every alphabet of ``--omniglot`` written
``--copies`` times under new names (``Greek_copy1``, ``Greek_copy2``, ...), images and
stroke files alike, as ``images_NAME`` / ``strokes_NAME`` folders in ``--out``.

It stands in for a data set of more alphabets when what is measured is the time and
memory a command takes as the drawings grow (``make model-omniglot OMNIGLOT=OUT``: the
sample limit of ``--config omniglot``, RESULTS 8.17). Its characters are the same ones
again, so it says nothing about how well a model reads more alphabets.

With ``--transforms`` the copies are new characters instead: copy k is mirrored
left-right, upside down or turned half round (k = 2, 3, 4; then again), image and
strokes alike, each stroke keeping its order and times. Their stroke counts are the
originals', so a model has ``--copies`` times the characters to learn, each with the
counts people drew (RESULTS 8.19).

Run from the repository's root::

    python experiments/omniglot_copies.py --omniglot ../shared/data/omniglot --copies 4 \\
        --out runs/omniglot_x4
    make model-omniglot OMNIGLOT=runs/omniglot_x4 OMNI=runs/omniglot_x4_run

The source's trees may be folders or zips, as Omniglot ships them; a zip's ``__MACOSX``
and dot files are left out. ``OUT`` must not exist yet (``--force`` replaces it); it is
written beside as ``OUT.partial`` and renamed when whole.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import zipfile
from io import BytesIO
from pathlib import Path

from PIL import Image

from _provenance import format_record, run_record
from img2dmp.data.omniglot import (
    MAX_IMAGE_BYTES,
    ArchiveMember,
    omniglot_trees,
    tree_files,
    tree_name,
)

# Copy k's transform: (mirror left-right, upside down); copy 1 is the original.
TRANSFORMS = ((False, False), (True, False), (False, True), (True, True))


def transform_image(data: bytes, mirror: bool, upside_down: bool) -> bytes:
    """A PNG's bytes mirrored left-right and/or upside down, as PNG bytes."""
    with Image.open(BytesIO(data)) as im:
        if mirror:
            im = im.transpose(Image.Transpose.FLIP_LEFT_RIGHT)
        if upside_down:
            im = im.transpose(Image.Transpose.FLIP_TOP_BOTTOM)
        buf = BytesIO()
        im.save(buf, format="PNG")
    return buf.getvalue()


def transform_strokes(text: str, size: tuple[int, int], mirror: bool, upside_down: bool) -> str:
    """A stroke file's points moved as :func:`transform_image` moves its image's pixels:
    pixel ``[i, j]`` lies at ``(x=j, y=-i)`` (the Omniglot source's convention), so a
    mirror maps x to ``width - 1 - x`` and upside down maps y to ``-(height - 1) - y``."""
    width, height = size
    lines = []
    for line in text.splitlines():
        parts = line.strip().split(",")
        if len(parts) == 3:
            x, y = float(parts[0]), float(parts[1])
            if mirror:
                x = width - 1 - x
            if upside_down:
                y = -(height - 1) - y
            line = f"{x:.6f},{y:.6f},{parts[2].strip()}"
        lines.append(line)
    return "\n".join(lines) + "\n"


def write_copies(source: Path, out: Path, copies: int, transforms: bool = False) -> dict[str, int]:
    """Every tree of ``source`` (:func:`~img2dmp.data.omniglot.omniglot_trees`) into
    ``out`` with each alphabet ``copies`` times, mirrored or turned with ``transforms``;
    the files written per tree."""
    if copies < 1:
        raise ValueError(f"--copies must be >= 1, got {copies}")
    pairs = omniglot_trees(source)
    if not pairs:
        raise ValueError(f"{source}: no images_NAME / strokes_NAME folder or zip in it")
    written = {}
    sizes: dict[tuple[str, str, str], tuple[int, int]] = {}  # a drawing's image size
    # The image trees first: a stroke file is moved within its drawing's image.
    trees = sorted((t for pair in pairs for t in pair), key=lambda t: "strokes" in tree_name(t))
    for tree in trees:
        name = tree_name(tree)
        files, _elsewhere = tree_files(tree)  # what is no drawing is left out
        for (alphabet, character, file), entry in files.items():
            data = (
                entry.read_bytes(MAX_IMAGE_BYTES)
                if isinstance(entry, ArchiveMember)
                else entry.read_bytes()
            )
            stem = (alphabet, character, Path(file).stem)
            is_image = file.lower().endswith(".png")
            if transforms and is_image:
                with Image.open(BytesIO(data)) as im:
                    sizes[stem] = im.size
            for k in range(1, copies + 1):
                mirror, upside_down = (
                    TRANSFORMS[(k - 1) % len(TRANSFORMS)] if transforms else (False, False)
                )
                moved = data
                if is_image and (mirror or upside_down):
                    moved = transform_image(data, mirror, upside_down)
                elif mirror or upside_down:
                    if stem not in sizes:
                        raise ValueError(f"{tree}: {'/'.join(stem)} has strokes but no image")
                    text = transform_strokes(data.decode("utf-8"), sizes[stem], mirror, upside_down)
                    moved = text.encode("utf-8")
                target = out / name / f"{alphabet}_copy{k}" / character / file
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(moved)
        written[name] = copies * len(files)
    return written


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--omniglot", type=Path, required=True, help="folder of the trees")
    ap.add_argument("--copies", type=int, default=4, help="times each alphabet (4)")
    ap.add_argument(
        "--transforms",
        action="store_true",
        help="copies 2-4 mirrored, upside down, turned: new characters (module docstring)",
    )
    ap.add_argument("--out", type=Path, required=True, help="new folder")
    ap.add_argument("--force", action="store_true", help="replace OUT if it exists")
    args = ap.parse_args(argv)
    print(format_record(run_record(__file__, sys.argv[1:] if argv is None else argv)))
    if args.out.exists():
        if not args.force:
            print(f"error: {args.out} exists (--force replaces it)", file=sys.stderr)
            return 2
        shutil.rmtree(args.out)
    partial = args.out.with_name(args.out.name + ".partial")  # OUT appears whole or not
    shutil.rmtree(partial, ignore_errors=True)
    try:
        written = write_copies(args.omniglot, partial, args.copies, args.transforms)
    except (ValueError, OSError, zipfile.BadZipFile) as e:  # a bad text is a ValueError
        shutil.rmtree(partial, ignore_errors=True)
        print(f"error: {e}", file=sys.stderr)
        return 2
    partial.rename(args.out)
    for name, n in written.items():
        print(f"{args.out / name}: {n} files")
    return 0


if __name__ == "__main__":
    sys.exit(main())
