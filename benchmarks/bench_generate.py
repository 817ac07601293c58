"""Speed of synthetic data generation: 20,000 digits with their DMP fits.

Target (issue 3): all 20,000 samples in <= 20 s on a 2-core machine. Prints the
wall-clock time and samples per second of ``generate_dataset`` (rendering, affine
transform, blur, noise and DMP fits included), the time per stage for one chunk in one
process, the mean DMP fit error, and the machine's load average, since other work on the
same cores slows every number here down.

    python benchmarks/bench_generate.py                  # 2,000 per digit, 2 workers
    python benchmarks/bench_generate.py --per-digit 200 --workers 1
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from img2dmp.data import render, synthetic
from img2dmp.data.affine import sample_affine, warp_images
from img2dmp.data.recorded import share_on_ink
from img2dmp.dmp import fit_dmp


def stage_times(n: int, seed: int = 0) -> tuple[dict[str, float], dict[str, float]]:
    """Seconds per stage for ``n`` samples in this process (one torch thread), and the
    share of path points on ink (bilinear intensity > 0.5) after the rendering, the affine
    transform and the noise."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        cfg = synthetic.SyntheticConfig()
        rng = np.random.default_rng(seed)
        synthetic.generate(np.arange(10), cfg, rng)  # warm-up: DMP response table, allocator
        labels = rng.integers(0, 10, n)
        h = cfg.image_size[0]
        out = {}
        t = time.perf_counter()
        raw, traj, mats = synthetic._paths_and_transforms(labels, cfg, rng)
        out["pen paths + min-jerk timing"] = time.perf_counter() - t
        t = time.perf_counter()
        rendered = render.render_paths(raw, cfg.image_size, cfg.pen_width_rel * h)
        out["rendering"] = time.perf_counter() - t
        t = time.perf_counter()
        sample_affine(rng, n, cfg.image_size, cfg.affine)
        moved = warp_images(rendered, mats)
        out["affine warp"] = time.perf_counter() - t
        t = time.perf_counter()
        img = render.gaussian_filter(moved, cfg.blur_sigma_rel * h)
        img = render.salt_and_pepper(img, cfg.noise_amount, rng)
        out["blur + noise"] = time.perf_counter() - t
        t = time.perf_counter()
        fit_dmp(cfg.times(), traj, ridge=cfg.ridge)
        out["DMP fit"] = time.perf_counter() - t
        on_ink = {
            name: float(np.mean([share_on_ink(im, xy) for im, xy in zip(ims, paths, strict=True)]))
            for name, ims, paths in (
                ("rendered", rendered.numpy(), raw),
                ("after the affine transform", moved.numpy(), traj),
                ("after blur and noise", img.numpy(), traj),
            )
        }
        return out, on_ink
    finally:
        torch.set_num_threads(threads)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--per-digit", type=int, default=2000, help="samples per digit (x 10)")
    ap.add_argument("--workers", type=int, default=2, help="generating processes")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    n_stage = synthetic.CHUNK
    stages, on_ink = stage_times(n_stage, args.seed)
    print(f"stages for one chunk of {n_stage} samples, one process, one thread:")
    for name, sec in stages.items():
        print(f"  {name:30s} {sec:7.3f} s   {n_stage / sec:9.0f} samples/s")
    total_stage = sum(stages.values())
    print(f"  {'sum':30s} {total_stage:7.3f} s   {n_stage / total_stage:9.0f} samples/s")
    print("share of path points on ink (bilinear intensity > 0.5) in that chunk:")
    for name, share in on_ink.items():
        print(f"  {name:30s} {share:7.1%}")

    load_before = os.getloadavg()[0]
    cpu0 = time.process_time()
    t0 = time.perf_counter()
    data = synthetic.generate_dataset(
        args.per_digit, seed=args.seed, workers=args.workers, progress=False
    )
    wall = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    n = len(data)
    err = data.fit_error_px
    print(
        f"generate_dataset: {n} samples, {args.workers} worker(s): {wall:.2f} s wall, "
        f"{n / wall:.0f} samples/s (target: 20000 in <= 20 s, i.e. >= 1000 samples/s)"
    )
    print(
        f"  parent-process CPU {cpu:.2f} s; load average before {load_before:.2f}, "
        f"after {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores"
    )
    print(f"  DMP fit error: mean {err.mean():.4f} px, max {err.max():.4f} px")
    weight_table(data)


def weight_table(data) -> None:
    """Per digit: DMP weight magnitudes, the smallest start-goal gap and the fit error.

    With the paper's scaling ``S = g - y0`` the weights grow like ``1 / (g - y0)``, so
    their tails follow the smallest gaps.
    """
    cfg = data.dmp_config
    n_w = cfg.n_kernels * cfg.n_dims
    print(
        "digit |   |w| median      p95      p99      max | min |g-y0| px | fit error mean / max px"
    )
    for d in np.unique(data.labels):
        m = data.labels == d
        w = np.abs(data.params[m, :n_w])
        gap = np.abs(data.trajectories[m, -1, :2] - data.trajectories[m, 0, :2]).min(-1)
        e = data.fit_error_px[m]
        q = np.percentile(w, [50, 95, 99])
        print(
            f"{d:5d} | {q[0]:12.0f} {q[1]:8.0f} {q[2]:8.0f} {w.max():8.0f} | {gap.min():13.2f} | "
            f"{e.mean():.3f} / {e.max():.3f}"
        )


if __name__ == "__main__":
    main()
