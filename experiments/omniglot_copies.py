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
from pathlib import Path, PurePosixPath


def trees(source: Path) -> dict[str, Path]:
    """The ``images_*`` and ``strokes_*`` trees in ``source``: name -> folder or zip (a
    folder wins over a zip of the same name)."""
    found: dict[str, Path] = {}
    for p in sorted(source.iterdir()):
        name = p.name[: -len(".zip")] if p.suffix.lower() == ".zip" else p.name
        if not name.startswith(("images_", "strokes_")):
            continue
        if p.is_dir() or (p.is_file() and p.suffix.lower() == ".zip" and name not in found):
            found[name] = p
    return found


def members(tree: Path, name: str):
    """``(parts below the tree's top, bytes)`` of every file of a tree (folder or zip)."""
    if tree.is_dir():
        for p in sorted(tree.rglob("*")):
            if p.is_file() and not p.name.startswith("."):
                yield p.relative_to(tree).parts, p.read_bytes()
        return
    with zipfile.ZipFile(tree) as z:
        for info in z.infolist():
            parts = PurePosixPath(info.filename).parts
            if info.is_dir() or not parts or parts[0] == "__MACOSX":
                continue
            if parts[0] == name:
                parts = parts[1:]
            if parts and not parts[-1].startswith("."):
                yield parts, z.read(info)


def write_copies(source: Path, out: Path, copies: int) -> dict[str, int]:
    """Every tree of ``source`` into ``out`` with each alphabet ``copies`` times; the
    files written per tree."""
    if copies < 1:
        raise ValueError(f"--copies must be >= 1, got {copies}")
    found = trees(source)
    if not found:
        raise ValueError(f"{source}: no images_NAME / strokes_NAME folder or zip in it")
    written = {}
    for name, tree in found.items():
        n = 0
        for parts, data in members(tree, name):
            if len(parts) < 2:  # a file beside the alphabets, not a drawing
                continue
            for k in range(1, copies + 1):
                target = out.joinpath(name, f"{parts[0]}_copy{k}", *parts[1:])
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(data)
                n += 1
        written[name] = n
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
