"""How much of a trained network's error comes from the images' salt-and-pepper noise.

Draws fresh synthetic samples twice from one seed, once with the generator's noise and
once without. The paths and everything else are identical: the noise is the generator's
last random draw. Reports the network's Table I error on both sets, and how far
:class:`~img2dmp.nn.model.ImpulseFilter` brings the noisy images back to the clean ones
(root mean square over pixels). A model trained with ``model.input_filter: impulse``
applies the filter itself, so its "noisy" row already includes it. Prints the date, the
git revision and its command line first, to go with its numbers in
``experiments/RESULTS.md``. From the repository's root:

    python experiments/noise_effect.py runs/d2_2000/digit2_cost9 --digits 2
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import numpy as np
import torch

from img2dmp.data.synthetic import SyntheticConfig, generate
from img2dmp.evaluate import error_statistics
from img2dmp.nn.costs import trajectory_error_px
from img2dmp.nn.model import ImpulseFilter
from img2dmp.predict import Predictor

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record


def paired_samples(labels, config: SyntheticConfig, seed: int):
    """The same samples drawn with ``config``'s noise and with none: (noisy, clean)."""
    noisy = generate(labels, config, np.random.default_rng(seed))
    clean = generate(labels, replace(config, noise_amount=0.0), np.random.default_rng(seed))
    if not np.array_equal(noisy.trajectories, clean.trajectories):
        raise RuntimeError("the generator's noise is no longer its last draw: paths differ")
    return noisy, clean


def noise_effect(predictor: Predictor, labels, config: SyntheticConfig, seed: int) -> dict:
    """Error statistics (px) on the noisy and the clean images, and image rms errors."""
    noisy, clean = paired_samples(labels, config, seed)
    out = {}
    for name, d in (("noisy", noisy), ("clean", clean)):
        y = torch.as_tensor(predictor.trajectories_for_images(d.images, d.times))
        errors = trajectory_error_px(y, torch.as_tensor(d.trajectories))  # Table I's metric
        out[name] = error_statistics(errors.numpy())
    a, b = torch.as_tensor(noisy.images), torch.as_tensor(clean.images)
    out["image_rms"] = float((a - b).square().mean().sqrt())
    out["filtered_image_rms"] = float((ImpulseFilter()(a) - b).square().mean().sqrt())
    out["fit_floor_px"] = float(np.mean(noisy.fit_error_px))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("model", help="run directory or checkpoint (.safetensors)")
    p.add_argument("--digits", type=int, nargs="+", default=list(range(10)))
    p.add_argument("--per-digit", type=int, default=500)
    p.add_argument("--seed", type=int, default=7)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = p.parse_args(argv)
    print(format_record(run_record(__file__, argv)))
    predictor = Predictor.load(args.model)
    labels = np.repeat(np.asarray(args.digits), args.per_digit)
    config = SyntheticConfig(digits=tuple(sorted(set(args.digits))))
    r = noise_effect(predictor, labels, config, args.seed)
    print(
        f"model {args.model} (input_filter: {predictor.meta['model'].get('input_filter', 'none')})"
    )
    print(f"{len(labels)} fresh samples of digits {args.digits}, seed {args.seed}")
    print("images     mean px   std px   median   p95")
    for name in ("noisy", "clean"):
        s = r[name]
        print(f"{name:8s} {s['mean']:9.4f} {s['std']:8.4f} {s['median']:8.4f} {s['p95']:7.4f}")
    print(f"noisy / clean error: {r['noisy']['mean'] / r['clean']['mean']:.3f}")
    print(f"DMP fit floor: {r['fit_floor_px']:.4f} px")
    print(
        f"image rms against the clean images: {r['image_rms']:.4f} with the noise, "
        f"{r['filtered_image_rms']:.4f} after the impulse filter"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
