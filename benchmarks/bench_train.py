"""Speed of one training step with cost (9) vs cost (10), and of batch inference.

In one run, on the same batch and the same network (the paper's fully connected
encoder-decoder unless --config says otherwise), one step of the real training loop
(:func:`img2dmp.training.train_step`: network, cost, backward, Adam, and the batch's
Table I error that training records) with cost (9) and one with cost (10) are timed
alternately; the ratio of their medians is printed (target <= 1.10: the trajectory cost
rides on the fast rollout, so it should be almost free). Then the
throughput of batch inference (images -> DMP parameters) in images per second (target
>= 5,000 / s on the 2-core development machine), with the trajectory rollout added, and on
the NumPy backend (:mod:`img2dmp.nn._numpy_net`, what ``predict`` runs on the CPU).

Usage::

    python benchmarks/bench_train.py [--batch 128] [--repeats 30] [--threads 1]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np
import torch

from img2dmp.data.synthetic import generate
from img2dmp.dmp import DMPConfig
from img2dmp.nn import Cost, ModelConfig, ParamNormaliser, build_model
from img2dmp.nn.costs import dmp_trajectory
from img2dmp.training import load_config, train_step


def _median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform

    return platform.processor() or platform.machine()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", help="training config whose model to time (default: the paper's)")
    p.add_argument("--batch", type=int, default=128, help="training batch size")
    p.add_argument("--repeats", type=int, default=60, help="timed steps per cost")
    p.add_argument("--infer-batch", type=int, default=4096, help="inference batch size")
    # One intra-op thread: on a 2-core machine shared with other work, two threads
    # spin-wait on each other and a step gets several times slower (measured: 95 ms with
    # one thread, 790 ms with two, while other processes ran).
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)

    mcfg = load_config(args.config).model if args.config else ModelConfig()
    dmp = DMPConfig()
    rng = np.random.default_rng(0)
    data = generate(rng.integers(0, 10, max(args.batch, 256)), rng=rng, dmp_config=dmp)
    norm = ParamNormaliser.fit(data.params, dmp)
    b = slice(0, args.batch)
    images = torch.as_tensor(data.images[b])  # [B, H, W]
    times = torch.as_tensor(data.times[b])  # [B, T]
    traj = torch.as_tensor(data.trajectories[b])  # [B, T, 2]
    z_t = norm.normalise(torch.as_tensor(data.params[b], dtype=torch.float64)).float()

    model = build_model(mcfg, seed=0)
    opt = torch.optim.Adam(model.parameters(), lr=1e-6)  # tiny lr: the weights barely move
    costs = {name: Cost(name, norm, dmp) for name in ("parameter", "trajectory")}

    def step(name):
        return lambda: train_step(model, opt, costs[name], images, times, traj, z_t)

    for _ in range(5):  # warm-up (allocator, response table)
        step("parameter")()
        step("trajectory")()
    t9, t10 = [], []
    for _ in range(args.repeats):  # alternate so that load changes hit both alike
        t9.append(_median_time(step("parameter"), 1))
        t10.append(_median_time(step("trajectory"), 1))
    m9, m10 = statistics.median(t9), statistics.median(t10)
    b9, b10 = min(t9), min(t10)
    n_weights = sum(q.numel() for q in model.parameters())
    print(f"CPU: {_cpu_model()}; torch {torch.__version__}")
    print(
        f"model: {mcfg.encoder} encoder {mcfg.encoder_layers} decoder {mcfg.decoder_layers}, "
        f"{n_weights / 1e6:.2f} M weights; batch {args.batch} x {tuple(images.shape[1:])}, "
        f"T = {times.shape[1]} time stamps; threads {args.threads}"
    )
    print(f"training step, cost (9):  median {m9 * 1e3:8.2f} ms, best {b9 * 1e3:8.2f} ms")
    print(f"training step, cost (10): median {m10 * 1e3:8.2f} ms, best {b10 * 1e3:8.2f} ms")
    # The best of many alternated steps is least disturbed by other processes on a shared
    # machine; the median ratio is printed too.
    print(
        f"ratio cost (10) / cost (9): {b10 / b9:.3f} (best of {args.repeats}), "
        f"{m10 / m9:.3f} (median)   (target <= 1.10)"
    )

    model.eval()
    big = torch.as_tensor(data.images).repeat(
        (args.infer_batch + len(data.images) - 1) // len(data.images), 1, 1
    )[: args.infer_batch]  # [Bi, H, W]
    big_t = torch.as_tensor(data.times[:1]).expand(args.infer_batch, -1)  # [Bi, T]

    def infer():
        with torch.inference_mode():
            norm.denormalise(model(big))

    def infer_traj():
        with torch.inference_mode():
            dmp_trajectory(model(big), big_t, norm, dmp)

    infer()
    ti = _median_time(infer, 5)
    tt = _median_time(infer_traj, 5)
    print(
        f"batch inference (batch {args.infer_batch}): {args.infer_batch / ti:,.0f} images/s "
        f"(target >= 5,000 / s)"
    )
    print(
        f"  with the trajectory at {big_t.shape[1]} time stamps: "
        f"{args.infer_batch / tt:,.0f} images/s"
    )
    # The same network on the NumPy backend (what `predict` runs on the CPU), same weights
    # and images; its matrix products on NumPy's BLAS with that library's own threads.
    from img2dmp.nn._numpy_net import NumpyNetwork

    net = NumpyNetwork(mcfg, {k: v.numpy() for k, v in model.state_dict().items()})
    big_np = big.numpy()

    def infer_np():
        norm.denormalise_numpy(net(big_np).astype(np.float64))

    infer_np()
    tn = _median_time(infer_np, 5)
    print(
        f"  the NumPy backend (BLAS threads its own): {args.infer_batch / tn:,.0f} images/s, "
        f"{ti / tn:.2f}x torch's"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
