"""How often a stroke model's rule for lines of writing flags one drawn character.

A stroke model reads at most 8 strokes, so a page of up to 8 characters could be read as
one character of that many strokes without a flag. ``Predictor.predict`` of a stroke
model flags ``several_characters`` also where the characters found in the image
(:func:`img2dmp.predict.count_characters`, as a stroke model's pages find them) stand in
two or more lines, two or more a line on average (:func:`img2dmp.predict.character_lines`).
This counts, on every drawing of Omniglot's ``images_*.zip`` (one character each), how
many the rule flags, and how the drawings are found (characters, lines), prepared as
``predict`` prepares an image (no network).

    python experiments/stroke_page_flag.py ../shared/data/omniglot/images_background_small1.zip
"""

from __future__ import annotations

import argparse
import io
import sys
import time
import zipfile

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("zips", nargs="+", help="Omniglot images_*.zip files")
    args = ap.parse_args(argv)
    from PIL import Image

    from img2dmp.data.images import prepare_image_found
    from img2dmp.predict import character_lines

    start, counts, flagged, total = time.perf_counter(), {}, 0, 0
    for path in args.zips:
        with zipfile.ZipFile(path) as z:
            for name in (n for n in z.namelist() if n.endswith(".png")):
                grey = np.asarray(Image.open(io.BytesIO(z.read(name))).convert("L"), np.float64)
                _, _, mask = prepare_image_found(grey / 255.0, (40, 40))
                found, lines = character_lines(mask)
                counts[(found, lines)] = counts.get((found, lines), 0) + 1
                flagged += lines >= 2 and found >= 2 * lines
                total += 1
    print(
        f"{total} drawings; flagged as lines of writing: {flagged} ({100 * flagged / total:.2f} %)"
    )
    print(
        "found as (characters, lines): " + ", ".join(f"{k}: {v}" for k, v in sorted(counts.items()))
    )
    print(f"{time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
