"""Turn real handwriting into an img2dmp data set: MNIST images with the recorded human pen
paths (--source recorded) or the traced stroke sequences (--source strokes), resampled to
the DMP time grid, optionally affine-augmented, with fitted DMPs and a fixed
train / validation / test split by MNIST index. Formats, frames and the split:
docs/MNIST.md.

The options (img2dmp.data.prepare.PrepareOptions: source, digits, n_dims, n_times,
image_size, resize_mode, augment, affine, seed, scaling, n_kernels, ridge, mnist_split,
limit_per_digit, speed_profile, duration_s) come from the defaults, then --config FILE,
then the option flags below (each only when given), then --set KEY=VALUE. Nested
sections: affine (AffineRanges: translation_rel, rotation_deg, scale, shear_deg) and
speed_profile (pen_speed_px_s, min_stroke_s, pen_up_s).

Note: here --data is the ROOT DIRECTORY of the real data (holding mnist/,
ijs-mnist-trajectories/ and mnist-stroke-sequences/), not a data-set file as in the other
commands; --out names the data-set file written, and an existing one is replaced only with
--force (checked before the data are read).

  img2dmp prepare --digits 3,5 --augment 10 --out mnist35.safetensors
  img2dmp prepare --config prep.yaml --set augment=4 --set 'affine.rotation_deg=[-5, 5]' \\
      --out mnist.safetensors
  img2dmp prepare --check-frames
"""

from __future__ import annotations

import argparse
from pathlib import Path

from . import _args

HELP = "make a data set from MNIST with recorded or traced pen paths"

# Literal copies of img2dmp.data.prepare's SOURCES, RESIZE_MODES and DEFAULT_DATA_DIR and
# of PrepareOptions' defaults (shown in --help), so that building the CLI parser does not
# import torch; tests check them against the library, and PrepareOptions validates again.
SOURCES = ("recorded", "strokes")
RESIZE_MODES = ("scale", "pad")
DEFAULT_DATA_DIR = "../shared/data"
DEFAULTS = {
    "source": "recorded",
    "n_times": 100,
    "image_size": 28,
    "resize_mode": "scale",
    "augment": 0,
    "paper": 0.0,
    "seed": 0,
    "n_kernels": 25,
    "mnist_split": "train",
    "speed_profile.pen_speed_px_s": 51.0,
    "speed_profile.pen_up_s": 0.2,
}

#: Option flag (its ``args`` name) -> the PrepareOptions field it sets (dots: nested).
FLAG_FIELDS = {
    "source": "source",
    "digits": "digits",
    "dims": "n_dims",
    "n_times": "n_times",
    "image_size": "image_size",
    "resize": "resize_mode",
    "augment": "augment",
    "paper": "paper",
    "seed": "seed",
    "scaling": "scaling",
    "n_kernels": "n_kernels",
    "mnist_split": "mnist_split",
    "limit_per_digit": "limit_per_digit",
    "pen_speed": "speed_profile.pen_speed_px_s",
    "pen_up_s": "speed_profile.pen_up_s",
    "duration": "duration_s",
}


def _field(flag: str, text: str, default: str | None = None) -> str:
    """Help text naming the field a flag sets and its default."""
    key = FLAG_FIELDS[flag]
    if default is None and key in DEFAULTS:
        default = str(DEFAULTS[key])
    return f"{text} (= {key}; default {default})" if default else f"{text} (= {key})"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    _paths(parser)
    _args.add_config(parser, "PrepareOptions fields, with affine and speed_profile sections")
    _args.add_set(parser, "--set augment=4 --set 'affine.scale=[0.95, 1.05]'")
    _options(parser)
    _args.add_no_progress(parser)


def _paths(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        "-o",
        metavar="FILE",
        help="output .safetensors file (required unless --check-frames)",
    )
    _args.add_force(parser, "--out file")
    parser.add_argument(
        "--check-frames",
        action="store_true",
        help="only measure how well each source's paths lie on the ink of their images "
        "under trial shifts of the frame, and print it (docs/MNIST.md)",
    )
    parser.add_argument(
        "--data",
        default=DEFAULT_DATA_DIR,
        metavar="DIR",
        help="ROOT DIRECTORY of the real data, holding mnist/, ijs-mnist-trajectories/ and "
        "mnist-stroke-sequences/ (here not a data-set file; see docs/MNIST.md)",
    )
    parser.add_argument(
        "--mnist", metavar="DIR", help="folder of the MNIST IDX files (default DATA/mnist)"
    )
    parser.add_argument(
        "--recorded",
        metavar="PATH",
        help="trajectories.tar.gz or its unpacked folder "
        "(default DATA/ijs-mnist-trajectories/trajectories.tar.gz)",
    )
    parser.add_argument(
        "--strokes",
        metavar="DIR",
        help="folder of the stroke sequences (default DATA/mnist-stroke-sequences)",
    )


def _share(text: str) -> float:
    """A number in [0, 1] (argparse type)."""
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a share in [0, 1], got {text!r}")
    return v


def _options(parser: argparse.ArgumentParser) -> None:
    # Every flag defaults to None: it overrides --config only when given.
    def add(flag: str, text: str, shown_default: str | None = None, **kwargs) -> None:
        name = flag[2:].replace("-", "_")
        parser.add_argument(flag, help=_field(name, text, shown_default), **kwargs)

    n, pos = {"metavar": "N"}, {"metavar": "X"}
    add("--source", "pen paths to use", choices=SOURCES)
    _args.add_digits(parser, _field("digits", "labels to keep", "0-9"))
    add("--augment", "affine copies added per training sample", type=_args.int_at_least(0), **n)
    add(
        "--paper",
        "share of the affine copies photographed on generated paper (ruled, squared, "
        "dotted, plain; shading, blur, noise, JPEG) and read back as a photo is",
        type=_share,
        metavar="SHARE",
    )
    add("--seed", "seed of the augmentation", type=_args.int_at_least(0), **n)
    add("--image-size", "side of the stored images", type=_args.int_at_least(8), metavar="PX")
    add("--resize", "how to reach --image-size", choices=RESIZE_MODES)
    add("--n-times", "instants per trajectory", type=_args.int_at_least(2), **n)
    add(
        "--duration",
        "rescale every path to last this long before fitting (removes the writer's speed, "
        "which an image does not show)",
        "real timing",
        type=_args.positive_float,
        metavar="SECONDS",
    )
    _args.add_dmp_fit_options(add, "2 for recorded, 3 for strokes")
    add(
        "--mnist-split",
        "strokes only: MNIST split(s) whose traces to use",
        choices=("train", "test", "both"),
    )
    add(
        "--limit-per-digit",
        "keep at most this many samples per digit",
        "all",
        type=_args.int_at_least(1),
        **n,
    )
    add("--pen-speed", "strokes: mean pen speed, px/s", type=_args.positive_float, **pos)
    add("--pen-up-s", "strokes: duration of a pen-up travel, s", type=_args.positive_float, **pos)


def prepare_options(args: argparse.Namespace):
    """The :class:`~img2dmp.data.prepare.PrepareOptions` of the command line: defaults,
    then ``--config``, then the flags given, then ``--set``."""
    from ..config import apply_overrides, from_mapping, merge, read_config_of
    from ..data.prepare import PrepareOptions

    d = read_config_of(PrepareOptions, args.config) if args.config else {}
    flags: dict = {}
    for flag, key in FLAG_FIELDS.items():
        value = getattr(args, flag)
        if value is None:
            continue
        *sections, leaf = key.split(".")
        node = flags
        for s in sections:
            node = node.setdefault(s, {})
        node[leaf] = list(value) if isinstance(value, tuple) else value
    return from_mapping(PrepareOptions, apply_overrides(merge(d, flags), args.set))


def _check_frames(args: argparse.Namespace) -> int:
    from img2dmp.data.prepare import frame_alignment

    report = frame_alignment(
        args.data,
        mnist_dir=args.mnist,
        recorded_path=args.recorded,
        strokes_dir=args.strokes,
        progress=not args.no_progress,
    )
    print("share of path points on ink (bilinear intensity > 0.5), mean over digits")
    print(
        f"{'source':16s} {'digits':>6s} {'raw':>6s} {'chosen':>7s} {'offset':>7s} "
        f"{'transp.':>7s}  best shift (dx,dy)"
    )
    for name, r in report.items():
        print(
            f"{name:16s} {r['n_digits']:6d} {r['share_raw']:6.3f} {r['share_chosen']:7.3f} "
            f"{r['chosen_offset_px']:+7.1f} {r['share_transposed']:7.3f}  "
            f"{r['best_shift']} -> {r['best_share']:.3f}"
        )
    return 0


def run(args: argparse.Namespace) -> int:
    from img2dmp.data.prepare import prepare_dataset

    from .generate import save_new_dataset

    if args.check_frames:
        return _check_frames(args)
    if not args.out:
        raise ValueError("--out is required (the data-set file to write)")
    options = prepare_options(args)
    inputs = [("--data folder", args.data), ("--mnist folder", args.mnist)]
    inputs += [("--recorded paths", args.recorded), ("--strokes folder", args.strokes)]
    _args.check_outputs([(args.out, None)], args.force, inputs + _args.config_inputs(args))
    data = prepare_dataset(
        options,
        data_dir=args.data,
        mnist_dir=args.mnist,
        recorded_path=args.recorded,
        strokes_dir=args.strokes,
        progress=not args.no_progress,
    )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_new_dataset(out, data, args.force)
    fit = data.meta["fit"]
    counts = data.meta["counts_by_split"]
    print(
        f"wrote {out}: {len(data)} samples (train {counts['train']}, validation "
        f"{counts['validation']}, test {counts['test']}), images {data.image_size}, "
        f"d={data.trajectories.shape[-1]}, DMP fit error {fit['mean_error_px']:.3f} px mean"
        + (
            f", pen state agreement {fit['pen_agreement_mean']:.4f}"
            if "pen_agreement_mean" in fit
            else ""
        )
    )
    return 0
