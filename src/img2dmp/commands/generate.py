"""Write a synthetic data set: images, pen paths, time stamps, labels, fitted DMPs.

Digits are built from straight lines and elliptic arcs with a minimum-jerk speed profile,
rendered, blurred, moved by a random affine transform together with their paths, and
sprinkled with salt-and-pepper noise, as in the first experiments of Pahič et al. (2018).
The file format is described in docs/DATASET.md. The same seed gives identical data.
"""

from __future__ import annotations

import argparse
import json
import os

HELP = "generate a synthetic handwritten-digit data set (images + paths + fitted DMPs)"


def parse_digits(text: str) -> tuple[int, ...]:
    """``"0-9"``, ``"2"``, ``"1,4,7"`` or ``"0-3,8"`` -> a tuple of digits."""
    digits: list[int] = []
    for part in text.replace(" ", "").split(","):
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            a, b = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise ValueError(f"--digits: {part!r} is not a digit or a range like 0-9") from None
        if a > b:
            raise ValueError(f"--digits: range {part!r} runs backwards")
        digits.extend(range(a, b + 1))
    if not digits:
        raise ValueError("--digits must name at least one digit, e.g. 0-9 or 2")
    return tuple(digits)


def parse_splits(text: str) -> tuple[float, float, float]:
    """``"0.8,0.1,0.1"`` -> (train, validation, test) fractions."""
    try:
        parts = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--splits must be three numbers like 0.8,0.1,0.1, got {text!r}") from None
    if len(parts) != 3:
        raise ValueError(f"--splits must be three numbers like 0.8,0.1,0.1, got {text!r}")
    return parts


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output .safetensors file")
    p.add_argument("--digits", default="0-9", help="digits to include: 0-9, 2, 1,4,7 ...")
    p.add_argument("--per-digit", type=int, default=2000, help="samples of each digit")
    p.add_argument("--image-size", type=int, default=40, help="image height = width (px)")
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed, same data)")
    p.add_argument("--splits", default="0.8,0.1,0.1", help="train,validation,test fractions")
    p.add_argument(
        "--config",
        default=None,
        help="YAML or JSON file of SyntheticConfig fields (ranges, pen, noise, affine ...); "
        "--digits and --image-size override it",
    )
    p.add_argument(
        "--workers", type=int, default=min(2, os.cpu_count() or 1), help="parallel processes"
    )
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def load_config_file(path: str) -> dict:
    """Fields of :class:`SyntheticConfig` from a YAML (or JSON) file."""
    import yaml

    with open(path, encoding="utf-8") as f:
        d = yaml.safe_load(f)
    if not isinstance(d, dict):
        raise ValueError(f"{path}: expected a mapping of SyntheticConfig fields")
    return d


def run(args: argparse.Namespace) -> int:
    from ..data.store import save_dataset
    from ..data.synthetic import SyntheticConfig, generate_dataset

    fields = load_config_file(args.config) if args.config else {}
    fields["digits"] = parse_digits(args.digits)
    fields["image_size"] = (args.image_size, args.image_size)
    config = SyntheticConfig.from_dict(fields)
    if os.path.exists(args.out) and not args.force:
        raise FileExistsError(f"{args.out} exists; pass --force to overwrite it")
    data = generate_dataset(
        args.per_digit,
        config,
        seed=args.seed,
        splits=parse_splits(args.splits),
        progress=not args.no_progress,
        workers=args.workers,
    )
    save_dataset(args.out, data)
    err = data.fit_error_px
    summary = {
        "file": args.out,
        "samples": len(data),
        "digits": list(config.digits),
        "image_size": list(config.image_size),
        "splits": {
            k: int((data.split == v).sum())
            for k, v in (("train", 0), ("validation", 1), ("test", 2))
        },
        "fit_error_px": {"mean": float(err.mean()), "max": float(err.max())},
    }
    print(json.dumps(summary))
    return 0
