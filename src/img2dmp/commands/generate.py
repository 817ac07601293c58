"""Write a synthetic data set: images, pen paths, time stamps, labels, fitted DMPs.

Digits are built from straight lines and elliptic arcs with a minimum-jerk speed profile,
rendered, blurred, moved by a random affine transform together with their paths, and
sprinkled with salt-and-pepper noise, as in the first experiments of Pahič et al. (2018).
The file format is described in docs/DATASET.md. The same seed gives identical data.

The generator's settings (img2dmp.data.synthetic.SyntheticConfig: digits, image_size,
duration_s, dt_s, ranges of the template parameters, pen width, blur, noise_amount,
affine ranges, ridge ...) come from the defaults, then --config FILE, then --digits and
--image-size (when given), then --set KEY=VALUE. The DMPs are fitted with --scaling and
--n-kernels (the other constants: img2dmp.dmp.DMPConfig's). An existing --out file is
replaced only with --force (checked before anything is generated). Examples:

  img2dmp generate --out twos.safetensors --digits 2 --per-digit 500
  img2dmp generate --out d28.safetensors --image-size 28 --scaling none   # digits-real's
  img2dmp generate --out d.safetensors --config synth.yaml --set noise_amount=0.1 \\
      --set 'affine.scale=[0.9, 1.0]'
"""

from __future__ import annotations

import argparse
import json

from .._processes import machine_cores
from . import _args

HELP = "generate a synthetic handwritten-digit data set (images + paths + fitted DMPs)"


def parse_splits(text: str) -> tuple[float, float, float]:
    """``"0.8,0.1,0.1"`` -> (train, validation, test) fractions."""
    msg = f"must be three fractions >= 0 summing to 1 like 0.8,0.1,0.1, got {text!r}"
    try:
        parts = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(msg) from None
    if len(parts) != 3 or min(parts) < 0 or abs(sum(parts) - 1.0) > 1e-6:
        raise argparse.ArgumentTypeError(msg)
    return parts


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, metavar="FILE", help="output .safetensors file")
    _args.add_digits(p, "digits to include (default: the config file's, else 0-9)")
    p.add_argument(
        "--per-digit",
        metavar="N",
        type=_args.int_at_least(1),
        default=2000,
        help="samples of each digit",
    )
    p.add_argument(
        "--image-size",
        type=_args.int_at_least(8),
        metavar="PX",
        help="image height = width in pixels (default: the config file's, else 40)",
    )
    p.add_argument(
        "--seed",
        metavar="N",
        type=_args.int_at_least(0),
        default=0,
        help="random seed (same seed, same data)",
    )
    p.add_argument(
        "--splits", type=parse_splits, default="0.8,0.1,0.1", help="train,validation,test fractions"
    )
    p.add_argument(
        "--scaling",
        choices=("goal-start", "none"),
        default="goal-start",
        help="the fitted DMPs' forcing-term scaling (a model to fine-tune on the data needs "
        "its own: the shipped digits-real's is none)",
    )
    p.add_argument(
        "--n-kernels",
        metavar="N",
        type=_args.int_at_least(1),
        default=25,
        help="the fitted DMPs' kernels per dimension",
    )
    _args.add_config(p, "SyntheticConfig fields (ranges, pen, noise, affine ...)")
    _args.add_set(p, "--set noise_amount=0.1 --set 'affine.scale=[0.9, 1.0]'")
    p.add_argument(
        "--workers",
        metavar="N",
        type=_args.int_at_least(1, machine_cores()),
        default=min(2, machine_cores()),
        help="parallel processes, at most the machine's cores (the data do not depend on it)",
    )
    _args.add_force(p, "--out file")
    _args.add_no_progress(p)


def synthetic_config(args: argparse.Namespace):
    """The :class:`~img2dmp.data.synthetic.SyntheticConfig` of the command line: file,
    then ``--digits`` / ``--image-size`` if given, then ``--set``."""
    from ..config import apply_overrides, check_known, read_config_of
    from ..data.synthetic import SyntheticConfig

    fields = read_config_of(SyntheticConfig, args.config) if args.config else {}
    if args.digits is not None:
        fields["digits"] = list(args.digits)
    if args.image_size is not None:
        fields["image_size"] = [args.image_size, args.image_size]
    fields = apply_overrides(fields, args.set)
    check_known(SyntheticConfig, fields)  # a misspelt --set key said as every command says it
    return SyntheticConfig.from_dict(fields)


def save_new_dataset(out, data, force: bool) -> None:
    """``data`` to ``out`` atomically; without ``force`` not over a file that appeared
    while the data were made (the overwrite rule holds to the end)."""
    from ..data.store import save_dataset

    try:
        save_dataset(out, data, overwrite=force)
    except FileExistsError:
        raise FileExistsError(
            f"{out} was created by someone else while the data were made; pass --force to "
            "replace it"
        ) from None


def run(args: argparse.Namespace) -> int:
    from ..data.synthetic import generate_dataset
    from ..dmp import DMPConfig

    config = synthetic_config(args)
    dmp_config = DMPConfig(n_kernels=args.n_kernels, scaling=args.scaling)
    _args.check_outputs([(args.out, None)], args.force, _args.config_inputs(args))
    _args.check_file_dir(args.out)
    data = generate_dataset(
        args.per_digit,
        config,
        seed=args.seed,
        splits=args.splits,
        dmp_config=dmp_config,
        progress=not args.no_progress,
        workers=args.workers,
    )
    save_new_dataset(args.out, data, args.force)
    err = data.fit_error_px
    summary = {
        "file": args.out,
        "samples": len(data),
        "digits": list(config.digits),
        "image_size": list(config.image_size),
        "dmp": {"scaling": dmp_config.scaling, "n_kernels": dmp_config.n_kernels},
        "splits": {
            k: int((data.split == v).sum())
            for k, v in (("train", 0), ("validation", 1), ("test", 2))
        },
        "fit_error_px": {"mean": float(err.mean()), "max": float(err.max())},
    }
    print(json.dumps(summary))
    return 0
