"""How heavy-tailed are the DMP weights a network must output (issue 21)?

Table I's cost (9) is the squared error of the (normalised) DMP parameters. With the
paper's forcing term diag(g - y0) F(x), the weights w_k absorb 1 / (g - y0): a sample
whose start and goal are close in one dimension needs large weights there. This script
prints, for a data-set file, the spread of the per-sample largest |w|, the share of the
squared total that the top 1 % of standardised weight entries carry and their kurtosis
(3 for a Gaussian), and the same for the forcing amplitudes (g - y0) w_k, which do not
carry the 1 / (g - y0).

Run: ``python experiments/weight_tails.py DATA.safetensors`` (e.g. the training file of
``reproduce_table1.py``, ``OUT/data/train.safetensors``).
"""

from __future__ import annotations

import argparse

import numpy as np

from img2dmp.data.store import load_dataset


def tail_stats(x: np.ndarray) -> tuple[float, float]:
    """(share of the squared total in the top 1 % of entries, kurtosis) of ``x [n, m]``
    standardised per column."""
    z = (x - x.mean(0)) / x.std(0)
    sq = np.sort((z**2).ravel())[::-1]
    return float(sq[: max(1, len(sq) // 100)].sum() / sq.sum()), float(np.mean(z**4))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("data", help="data-set file (.safetensors)")
    args = p.parse_args(argv)
    d = load_dataset(args.data)
    params = d.dmp_params().to_numpy()
    w, g, y0 = (np.asarray(v, dtype=np.float64) for v in (params.w, params.g, params.y0))
    print(f"{args.data}: {len(w)} samples, {d.dmp_config.n_kernels} kernels x "
          f"{d.dmp_config.n_dims} dims, scaling {d.dmp_config.scaling}")  # fmt: skip
    peak = np.abs(w).reshape(len(w), -1).max(1)
    q = np.percentile(peak, [50, 90, 99, 99.9, 100])
    print(
        "largest |w| of a sample, percentiles 50/90/99/99.9/100: "
        + " / ".join(f"{v:.0f}" for v in q)
    )
    gap = np.abs(g - y0)
    print("|g - y0| (px), percentiles 0.1/1/50: "
          + " / ".join(f"{v:.2f}" for v in np.percentile(gap, [0.1, 1, 50])))  # fmt: skip
    for name, x in (("weights w_k", w), ("amplitudes (g - y0) w_k", (g - y0)[:, None, :] * w)):
        share, kurt = tail_stats(x.reshape(len(x), -1))
        print(f"{name}: top 1 % of standardised entries carry {100 * share:.1f} % of the "
              f"squared total; kurtosis {kurt:.1f} (Gaussian 3)")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
