"""Turn real handwriting into an img2dmp data set: MNIST images with the recorded human pen
paths (``--source recorded``) or the traced stroke sequences (``--source strokes``),
resampled to the DMP time grid, optionally affine-augmented, with fitted DMPs and a fixed
train / validation / test split by MNIST index. Formats, frames and the split:
docs/MNIST.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "make a data set from MNIST with recorded or traced pen paths"


def _digits(text: str) -> tuple[int, ...]:
    try:
        out = tuple(int(d) for d in text.replace(",", " ").split())
    except ValueError:
        raise argparse.ArgumentTypeError(f"digits must be numbers 0-9, got {text!r}") from None
    if not out or any(not 0 <= d <= 9 for d in out):
        raise argparse.ArgumentTypeError(f"digits must be numbers 0-9, got {text!r}")
    return out


# Literal copies of img2dmp.data.prepare's SOURCES, RESIZE_MODES and DEFAULT_DATA_DIR, so
# that building the CLI parser does not import torch; PrepareOptions validates them again.
SOURCES = ("recorded", "strokes")
RESIZE_MODES = ("scale", "pad")
DEFAULT_DATA_DIR = "../shared/data"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--source", choices=SOURCES, default="recorded", help="pen paths to use")
    parser.add_argument(
        "--digits", type=_digits, default=tuple(range(10)), help='labels to keep, e.g. "3,5"'
    )
    parser.add_argument(
        "--out", "-o", help="output .safetensors file (required unless --check-frames)"
    )
    parser.add_argument(
        "--check-frames",
        action="store_true",
        help="only measure how well each source's paths lie on the ink of their images "
        "under trial shifts of the frame, and print it (docs/MNIST.md)",
    )
    parser.add_argument(
        "--data", default=DEFAULT_DATA_DIR, help="root of the real data (see docs/MNIST.md)"
    )
    parser.add_argument("--mnist", help="folder of the MNIST IDX files (default DATA/mnist)")
    parser.add_argument(
        "--recorded",
        help="trajectories.tar.gz or its unpacked folder "
        "(default DATA/ijs-mnist-trajectories/trajectories.tar.gz)",
    )
    parser.add_argument(
        "--strokes", help="folder of the stroke sequences (default DATA/mnist-stroke-sequences)"
    )
    parser.add_argument(
        "--augment", type=int, default=0, help="affine copies added per training sample"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the augmentation")
    parser.add_argument("--image-size", type=int, default=28, help="side of the stored images")
    parser.add_argument(
        "--resize", choices=RESIZE_MODES, default="scale", help="how to reach --image-size"
    )
    parser.add_argument("--n-times", type=int, default=100, help="instants per trajectory")
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="SECONDS",
        help="rescale every path to last this long before fitting (removes the writer's "
        "speed, which an image does not show; default: real timing)",
    )
    parser.add_argument(
        "--dims",
        type=int,
        choices=(2, 3),
        help="2 = (x, y), 3 = (x, y, pen); default 2 for recorded, 3 for strokes",
    )
    parser.add_argument(
        "--scaling",
        choices=("goal-start", "none"),
        help="DMP forcing-term scaling; default goal-start for d=2, none for d=3",
    )
    parser.add_argument("--n-kernels", type=int, default=25, help="DMP kernels per dimension")
    parser.add_argument(
        "--mnist-split",
        choices=("train", "test", "both"),
        default="train",
        help="strokes only: MNIST split(s) whose traces to use",
    )
    parser.add_argument(
        "--limit-per-digit", type=int, help="keep at most this many samples per digit"
    )
    parser.add_argument(
        "--pen-speed", type=float, default=51.0, help="strokes: mean pen speed, px/s"
    )
    parser.add_argument(
        "--pen-up-s", type=float, default=0.2, help="strokes: duration of a pen-up travel"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


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
    from img2dmp.data.prepare import PrepareOptions, prepare_dataset
    from img2dmp.data.store import save_dataset
    from img2dmp.data.strokes import SpeedProfile

    if args.check_frames:
        return _check_frames(args)
    if not args.out:
        raise ValueError("--out is required (the data-set file to write)")
    options = PrepareOptions(
        source=args.source,
        digits=args.digits,
        n_dims=args.dims,
        n_times=args.n_times,
        image_size=args.image_size,
        resize_mode=args.resize,
        augment=args.augment,
        seed=args.seed,
        scaling=args.scaling,
        n_kernels=args.n_kernels,
        mnist_split=args.mnist_split,
        limit_per_digit=args.limit_per_digit,
        speed_profile=SpeedProfile(pen_speed_px_s=args.pen_speed, pen_up_s=args.pen_up_s),
        duration_s=args.duration,
    )
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
    save_dataset(out, data)
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
