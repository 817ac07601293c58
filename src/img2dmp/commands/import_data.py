"""Import your own images and pen paths, of any classes, as an img2dmp data set.

SOURCE is a folder with one sub-folder per class (the folder's name is the class: a
letter, a symbol, a shape, a digit), each holding one image per sample and its
trajectory file of the same name:

  letters/L/001.png  letters/L/001.csv
  letters/T/001.png  letters/T/001.json ...

or a manifest: a CSV file with the header image,trajectory,class[,split] (or a JSON list
of such objects), paths relative to the manifest; or a folder of recordings made on the
Record page of `img2dmp serve --images DIR` (image_<n>.json) with --images DIR; or
Omniglot: a folder holding images_NAME and strokes_NAME, as folders or as the zip files
it comes in (classes alphabet/character, split by drawer 1-15 / 16-17 / 18-20, or
--split-by character or alphabet for characters never seen), or strokes_NAME itself
(folder or zip) with its images beside it or given with --images.
Trajectories are in pixels of their own image, x = column and y = row (y down), t in
seconds (--time-unit ms: milliseconds):
CSV with the header x,y,t or x,y,t,pen (pen 1 down, 0 up: any number of strokes), JSON
{"x": [...], "y": [...], "t": [...]} (optionally "pen") or a list of strokes, NumPy .npy
[T, 3] or [T, 4]. Formats and checks: docs/DATASET.md.

Each image is prepared as `img2dmp predict` prepares one (crop to the ink, square with
--margin, resized to --image-size) and its path is mapped by the same crop and resize;
the path is resampled to --n-times instants (allocated per stroke, so that every stroke
and dot keeps its own; --resample uniform: evenly over the path, as before), --augment
affine copies of every training sample are added, and a DMP is fitted to every path.
The split comes from the manifest's split column, or is drawn per class (--val-fraction,
--test-fraction, --seed). Classes are stored with their names (labels index into the
metadata's class_names).

A bad sample (a missing trajectory or image, an unreadable file, NaN, time stamps that do
not increase (--spread-repeated-times spreads a repeated one), too few points, a path off
its image, an unknown class ...) stops the import with one line naming the file and what
is wrong; --skip-bad leaves such samples out and lists them instead. An existing --out
file is replaced only with --force (checked before anything is read).

The options (img2dmp.data.importer.ImportOptions: image_size, margin, n_times, resample,
duration_s, time_unit, spread_repeated_times, n_dims, scaling, n_kernels, ridge, augment,
affine, seed, val_fraction, test_fraction, split_by, classes, min_on_ink,
stroke_width_px) come from the defaults, then
--config FILE, then the flags below (each only when given), then --set KEY=VALUE.

  img2dmp import letters --out letters.safetensors --augment 10
  img2dmp import manifest.csv --out shapes.safetensors --classes circle,square --dims 3
  img2dmp import recordings --images photos --out mine.safetensors
  img2dmp import omniglot --out omniglot.safetensors --split-by character
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from . import _args

#: The command's name: ``import`` is a Python keyword, so the module is ``import_data``.
NAME = "import"
HELP = "make a data set from your own images and pen paths (any class names)"

# Literal copies of ImportOptions' defaults (shown in --help), so that building the
# parser does not import the library; ImportOptions validates every value again.
DEFAULTS = {
    "image_size": 40,
    "margin": 0.175,
    "n_times": 100,
    "resample": "strokes",
    "time_unit": "s",
    "n_kernels": 25,
    "augment": 0,
    "seed": 0,
    "val_fraction": 0.1,
    "test_fraction": 0.2,
    "min_on_ink": 0.5,
}

#: Beyond this many classes the summary gives their number, not each one's count.
MAX_CLASSES_LISTED = 12

#: Option flag (its ``args`` name) -> the ImportOptions field it sets.
FLAG_FIELDS = {
    "image_size": "image_size",
    "margin": "margin",
    "n_times": "n_times",
    "resample": "resample",
    "duration": "duration_s",
    "time_unit": "time_unit",
    "spread_repeated_times": "spread_repeated_times",
    "dims": "n_dims",
    "scaling": "scaling",
    "n_kernels": "n_kernels",
    "augment": "augment",
    "seed": "seed",
    "val_fraction": "val_fraction",
    "test_fraction": "test_fraction",
    "split_by": "split_by",
    "classes": "classes",
    "min_on_ink": "min_on_ink",
    "stroke_width": "stroke_width_px",
}


def _fraction(text: str) -> float:
    """An argparse ``type``: a number in [0, 1]."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a number from 0 to 1, got {text}")
    return v


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "source",
        metavar="SOURCE",
        help="folder of class folders, a .csv / .json manifest, a folder of recordings "
        "(with --images), or Omniglot (a folder of images_NAME and strokes_NAME, folders or "
        ".zip, or strokes_NAME itself)",
    )
    p.add_argument(
        "--images",
        metavar="DIR",
        help="with a SOURCE folder of recordings made on img2dmp serve's Record page "
        "(image_<n>.json): the folder of the images they trace (serve's --images); with "
        "SOURCE Omniglot's strokes_NAME: its images_NAME (folder or .zip)",
    )
    p.add_argument("--out", "-o", required=True, metavar="FILE", help="output .safetensors file")
    _args.add_force(p, "--out file")
    p.add_argument(
        "--skip-bad",
        action="store_true",
        help="leave bad samples out and list them (default: stop at the first, naming it)",
    )
    _args.add_config(p, "ImportOptions fields, with an affine section")
    _args.add_set(p, "--set augment=4 --set 'affine.rotation_deg=[-5, 5]'")
    _options(p)
    _args.add_no_progress(p)


def _options(p: argparse.ArgumentParser) -> None:
    # Every flag defaults to None: it overrides --config only when given.
    def add(flag: str, text: str, shown: str | None = None, **kwargs) -> None:
        key = FLAG_FIELDS[flag[2:].replace("-", "_")]
        default = shown if shown is not None else DEFAULTS.get(key)
        suffix = f" (= {key}; default {default})" if default is not None else f" (= {key})"
        p.add_argument(flag, help=text + suffix, **kwargs)

    n = {"metavar": "N"}
    add("--image-size", "side of the stored images", type=_args.int_at_least(8, 1024), metavar="PX")
    add("--margin", "share of the side left empty around the ink", type=_fraction, metavar="X")
    add("--n-times", "instants per trajectory", type=_args.int_at_least(2), **n)
    add(
        "--resample",
        "instants per stroke and pen lift, so that every stroke and dot keeps its own "
        "(strokes), or evenly over the path, refusing a path whose short strokes or lifts "
        "fall between them (uniform)",
        choices=("strokes", "uniform"),
    )
    add(
        "--duration",
        "rescale every path to last this long (removes the writer's speed, which an image "
        "does not show)",
        "recorded timing",
        type=_args.positive_float,
        metavar="SECONDS",
    )
    add("--time-unit", "unit of the files' t", choices=("s", "ms"))
    add(
        "--spread-repeated-times",
        "spread a time stamp equal to the one before it (two points logged in one clock "
        "tick) evenly up to the next, as Omniglot's reader does, instead of refusing the file",
        "refuse",
        action="store_const",
        const=True,
    )
    _args.add_dmp_fit_options(add, "3 if any sample has strokes")
    add("--augment", "affine copies added per training sample", type=_args.int_at_least(0), **n)
    add("--seed", "seed of the augmentation and the random split", type=_args.int_at_least(0), **n)
    add(
        "--val-fraction",
        "share of each class in validation (no split given)",
        type=_fraction,
        metavar="X",
    )
    add(
        "--test-fraction",
        "share of each class in test (no split given)",
        type=_fraction,
        metavar="X",
    )
    add(
        "--split-by",
        "Omniglot: drawers 1-15 train, 16-17 validation, 18-20 test (drawer), or whole "
        "characters (character) or alphabets (alphabet) drawn with --val-fraction and "
        "--test-fraction: characters never seen",
        "drawer",
        choices=("drawer", "character", "alphabet"),
    )
    add(
        "--classes",
        "class names in label order, e.g. L,T,V,O; a sample of another class is refused",
        "the classes found, sorted",
        type=_args.parse_classes,
        metavar="NAMES",
    )
    add(
        "--stroke-width",
        "bring every image's strokes to this pen width (as predict does)",
        "each image's own",
        type=_args.positive_float,
        metavar="PX",
    )
    add(
        "--min-on-ink",
        "least share of each pen-down path on its image's ink (0 = no check)",
        type=_fraction,
        metavar="X",
    )


def import_options(args: argparse.Namespace):
    """The :class:`~img2dmp.data.importer.ImportOptions` of the command line: defaults,
    then ``--config``, then the flags given, then ``--set``."""
    from ..config import apply_overrides, from_mapping, merge, read_config_of
    from ..data.importer import ImportOptions

    d = read_config_of(ImportOptions, args.config) if args.config else {}
    flags = {key: getattr(args, flag) for flag, key in FLAG_FIELDS.items()}
    flags = {k: v for k, v in flags.items() if v is not None}
    return from_mapping(ImportOptions, apply_overrides(merge(d, flags), args.set))


def run(args: argparse.Namespace) -> int:
    from ..data.importer import import_dataset
    from .generate import save_new_dataset

    source = Path(args.source)
    if not source.exists():
        raise FileNotFoundError(f"import source {source} does not exist")
    options = import_options(args)
    inputs = [("source", source), ("images folder", args.images)]
    _args.check_outputs([(args.out, None)], args.force, inputs + _args.config_inputs(args))
    data = import_dataset(
        source,
        options,
        progress=not args.no_progress,
        skip_bad=args.skip_bad,
        images=args.images,
    )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_new_dataset(out, data, args.force)
    _report(out, data)
    return 0


def _report(out: Path, data) -> None:
    """What was written, then a note for each thing a user may want to act on."""
    from ..data.importer import time_unit_note

    meta = data.meta
    counts = meta["counts_by_split"]
    by_class = meta["counts_by_class"]
    classes = ", ".join(f"{k} {v}" for k, v in by_class.items())
    if len(by_class) > MAX_CLASSES_LISTED:
        least, most = min(by_class.values()), max(by_class.values())
        each = f"{least}" if least == most else f"{least}-{most}"
        classes = f"{len(by_class)} of {each} samples each"
    print(
        f"wrote {out}: {len(data)} samples (train {counts['train']}, validation "
        f"{counts['validation']}, test {counts['test']}), classes: {classes}; images "
        f"{data.image_size}, d={data.trajectories.shape[-1]}, DMP fit error "
        f"{meta['fit']['mean_error_px']:.3f} px mean"
    )
    if note := _empty_split_note(meta) or _characters_not_split_note(data):
        print(note)
    if note := time_unit_note(meta):
        print(note)
    if empty := [name for name, n in by_class.items() if not n]:
        print(
            f"note: no sample has the class(es) {', '.join(map(repr, empty))} given (--classes): "
            "they keep their labels, but nothing in the data set teaches or tests them; check "
            "the names against the source's classes, or leave them out of --classes"
        )
    if meta["fit"]["poor"]["rows"]:
        print(_poor_fit_note(data))
    shifted = meta["source"].get("shifted") or {}
    if shifted:
        far = max(max(abs(v) for v in s) for s in shifted.values())
        print(
            f"note: {len(shifted)} Omniglot drawing(s) lay off their image's ink; their "
            f"strokes were shifted onto it (up to {far:g} px; metadata source.shifted)"
        )
    for line in meta["source"]["skipped"]:
        print(f"skipped: {line}")
    if meta["source"]["skipped"]:
        print(_skipped_summary(meta["source"]))


def _skipped_summary(source: dict) -> str:
    """The line after ``--skip-bad``'s list: how many samples failed to read and how many
    of the source's entries (stray files, empty folders) made none."""
    entries = source.get("skipped_entries", 0)
    samples = len(source["skipped"]) - entries
    parts = [f"{samples} bad sample(s)"] if samples else []
    if entries:
        parts.append(f"{entries} file(s) or folder(s) of the source that make no sample")
    return f"skipped {' and '.join(parts)}, listed above"


def _empty_split_note(meta) -> str | None:
    """The note on an Omniglot import whose validation or test split came out empty: by
    drawer, the drawers' numbers; by character or alphabet, fractions of too few of them
    that round to none."""
    counts, source = meta["counts_by_split"], meta["source"]
    empty = [name for name in ("validation", "test") if not counts[name]]
    if not empty or source.get("format") != "omniglot":
        return None
    what = " or ".join(empty)
    split_by = source.get("split_by")
    if split_by == "drawer":
        return (
            f"note: no drawing in {what}: the split by drawer puts drawers 1-15 "
            "in training, 16-17 in validation and 18-20 in test (a file's number after its "
            "'_'); number your drawers into those, or --split-by character to test on "
            "whole characters never seen in training"
        )
    per_alphabet: dict[str, int] = {}  # characters drawn, by alphabet
    for name, n in meta["counts_by_class"].items():
        if n:
            alphabet = name.split("/")[0]
            per_alphabet[alphabet] = per_alphabet.get(alphabet, 0) + 1
    if split_by == "alphabet":
        n = len(per_alphabet)
        units = f"{n} alphabet(s)"
    else:
        n = max(per_alphabet.values())
        units = f"an alphabet's {n} character(s) (at most)"
    held = (
        "; train then holds out some of the training drawings (of "
        f"{split_by}s it trains on) for validation"
        if "validation" in empty
        else ""
    )
    if n < 1 + len(empty):  # at least one unit stays in training
        return (
            f"note: no drawing in {what}: --split-by {split_by} keeps whole {split_by}s in "
            f"one split and at least one in training, of {units}"
            f"{held}; import more, or --split-by "
            f"{'character' if split_by == 'alphabet' else 'drawer'}"
        )
    options = meta.get("import", {})
    given = ", ".join(f"{_FRACTION_FLAGS[e]} {options.get(_FRACTION_FIELDS[e])}" for e in empty)
    # The least share of n units that rounds to one (the split's rule: half up).
    enough = " ".join(f"{_FRACTION_FLAGS[e]} {math.ceil(100 / n) / 100:g}" for e in empty)
    return (
        f"note: no drawing in {what}: --split-by {split_by} draws {given} of {units}, "
        f"which rounds to none{held}; {enough} puts one there"
    )


def _characters_not_split_note(data) -> str | None:
    """The note on the characters of an Omniglot import split by drawer that have no
    drawing in validation or in test (a character drawn by fewer drawers, or by others
    than 16-20), which those splits' figures then leave out."""
    from ..data.store import SPLITS

    source = data.meta["source"]
    if source.get("format") != "omniglot" or source.get("split_by") != "drawer":
        return None
    names = data.label_names
    lacking = []
    for split, drawers in (("validation", "16-17"), ("test", "18-20")):
        held = set(data.labels[data.split == SPLITS[split]].tolist())
        missing = [str(names[k]) for k in sorted(set(data.labels.tolist()) - held)]
        if missing:
            shown = ", ".join(missing[:3]) + (" ..." if len(missing) > 3 else "")
            lacking.append(
                f"{len(missing)} character(s) without a drawing in {split} (drawers "
                f"{drawers}): {shown}"
            )
    if not lacking:
        return None
    return (
        f"note: {'; '.join(lacking)}; those splits' figures leave them out, though they are "
        "trained on; --split-by character holds out whole characters instead"
    )


_FRACTION_FIELDS = {"validation": "val_fraction", "test": "test_fraction"}
_FRACTION_FLAGS = {"validation": "--val-fraction", "test": "--test-fraction"}


def _poor_fit_note(data) -> str:
    """The note on the DMP fits that miss their drawings by more than the threshold, with
    the remedy for the data set's scaling and, for a data set of strokes, whose fit it
    is."""
    from ..data.store import STROKE_SPANS_KEY

    poor = data.meta["fit"]["poor"]
    # Without the goal-start scaling, what a fit misses is detail: many strokes or a
    # long drawing for the kernels.
    remedy = (
        "where a path ends near its start in x or y the goal-start scaling fails: try "
        "--scaling none"
        if data.dmp_config.scaling == "goal-start"
        else f"many strokes or a long path need more than {data.dmp_config.n_kernels} "
        "kernels: try a larger --n-kernels"
    )
    if any(len(spans) > 1 for spans in data.meta.get(STROKE_SPANS_KEY) or []):
        # The fit is the whole drawing's one DMP; a stroke model does not learn it.
        remedy += (
            " for a model of one DMP per drawing; a stroke model (--config omniglot) "
            "does not learn this fit: each stroke is its own DMP (strokes.n_kernels)"
        )
    return (
        f"note: {poor['rows']} DMP fit(s) are off by more than {poor['threshold_px']:g} px "
        f"on average (worst {poor['worst_mean_error_px']:.2f} px, "
        f"{poor['worst_trajectory']}); {remedy}"
    )
