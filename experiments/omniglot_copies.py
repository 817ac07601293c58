"""A larger Omniglot source for timing a recipe: every alphabet of ``--omniglot`` written
``--copies`` times under new names (``Greek_copy1``, ``Greek_copy2``, ...), images and
stroke files alike, as ``images_NAME`` / ``strokes_NAME`` folders in ``--out``.

It stands in for a data set of more alphabets when what is measured is the time and
memory a command takes as the drawings grow (``make model-omniglot OMNIGLOT=OUT``: the
sample limit of ``--config omniglot``, RESULTS 8.17). Its characters are the same ones
again, so it says nothing about how well a model reads more alphabets.

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
from pathlib import Path

from img2dmp.data.omniglot import (
    MAX_IMAGE_BYTES,
    ArchiveMember,
    omniglot_trees,
    tree_files,
    tree_name,
)


def write_copies(source: Path, out: Path, copies: int) -> dict[str, int]:
    """Every tree of ``source`` (:func:`~img2dmp.data.omniglot.omniglot_trees`) into
    ``out`` with each alphabet ``copies`` times; the files written per tree."""
    if copies < 1:
        raise ValueError(f"--copies must be >= 1, got {copies}")
    pairs = omniglot_trees(source)
    if not pairs:
        raise ValueError(f"{source}: no images_NAME / strokes_NAME folder or zip in it")
    written = {}
    for tree in (t for pair in pairs for t in pair):
        name = tree_name(tree)
        files, _elsewhere = tree_files(tree)  # what is no drawing is left out
        for (alphabet, character, file), entry in files.items():
            data = (
                entry.read_bytes(MAX_IMAGE_BYTES)
                if isinstance(entry, ArchiveMember)
                else entry.read_bytes()
            )
            for k in range(1, copies + 1):
                target = out / name / f"{alphabet}_copy{k}" / character / file
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(data)
        written[name] = copies * len(files)
    return written


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--omniglot", type=Path, required=True, help="folder of the trees")
    ap.add_argument("--copies", type=int, default=4, help="times each alphabet (4)")
    ap.add_argument("--out", type=Path, required=True, help="new folder")
    ap.add_argument("--force", action="store_true", help="replace OUT if it exists")
    args = ap.parse_args(argv)
    if args.out.exists():
        if not args.force:
            print(f"error: {args.out} exists (--force replaces it)", file=sys.stderr)
            return 2
        shutil.rmtree(args.out)
    partial = args.out.with_name(args.out.name + ".partial")  # OUT appears whole or not
    shutil.rmtree(partial, ignore_errors=True)
    try:
        written = write_copies(args.omniglot, partial, args.copies)
    except (ValueError, OSError, zipfile.BadZipFile) as e:
        shutil.rmtree(partial, ignore_errors=True)
        print(f"error: {e}", file=sys.stderr)
        return 2
    partial.rename(args.out)
    for name, n in written.items():
        print(f"{args.out / name}: {n} files")
    return 0


if __name__ == "__main__":
    sys.exit(main())
