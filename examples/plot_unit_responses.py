"""The idea behind the fast rollout: a DMP is a sum of precomputed unit responses.

With tau fixed, y(s) = g + (y0 - g) a(s) + S sum_k w_k R_k(s) (s = t / tau). This script
plots the free response a(s), the kernel responses R_k(s) and the kernels phi_k(x(s))
that drive them.

Run: ``.venv/bin/python examples/plot_unit_responses.py --out out/unit_responses.png``
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import torch

from img2dmp.dmp import DMPConfig, basis_functions, kernel_centres, kernel_widths, unit_responses


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/unit_responses.png"))
    args = ap.parse_args()
    cfg = DMPConfig()
    s = torch.linspace(0, 1.5, 600, dtype=torch.float64)
    a, r = unit_responses(s, cfg)
    phi = basis_functions(np.exp(-cfg.alpha_x * s.numpy()), kernel_centres(cfg), kernel_widths(cfg))
    fig, axes = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
    axes[0].plot(s, phi)
    axes[0].set_ylabel("phi_k(x(s))")
    axes[0].set_title("kernels (eq. 7) along normalised time s = t / tau")
    axes[1].plot(s, r.numpy())
    axes[1].set_ylabel("R_k(s)")
    axes[1].set_title("response of the transformation system to each kernel")
    axes[2].plot(s, a.numpy(), color="k")
    axes[2].set_ylabel("a(s)")
    axes[2].set_xlabel("s = t / tau")
    axes[2].set_title("free response to a unit start offset (y0 - g)")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
