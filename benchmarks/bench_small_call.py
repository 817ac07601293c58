"""One rollout of one DMP: where a small call's time goes, old path against new (issue 33).

B = 1 DMP, d = 2, N = 25 kernels, T = 301 time stamps over its duration, float64; the
parameters made once (``DMPParams``, torch tensors), the time stamps a 1-D tensor, the
call ``rollout(params, t)`` as a user writes it. Each method is called ``--calls`` times
after a warm-up, in ``--rounds`` alternated rounds (so that a shared machine's drift
hits every method alike); its minimum and median per call are printed, with the ratio to
the target of issue 33 (<= 60 us) and to the old path.

- new: ``rollout`` as it is (once the fused kernels are loaded, a call that records no
  gradient calls the compiled forward loop directly on NumPy views);
- old: the same call with the direct path switched off, i.e. through
  ``torch.autograd.Function`` and the checks as they were before (the same kernel);
- with validation (the default) and ``validate=False``; with the parameters built in the
  call (``DMPParams(...)`` checks their values); with ``w`` requiring a gradient
  (forward only: the autograd path); on the torch operations (``backend="torch"``, what
  the first small calls of a process take); NumPy's ``rollout_numpy``; and the fused
  forward kernel alone on ready arrays (the floor).

``--fresh-calls N`` also runs N calls in a new process and prints the median of its
first and last thousand calls and its slowest one: ``backend="auto"`` takes the torch
operations for small calls until loading the kernels (0.3-0.7 s) looks worth it.

Run: ``.venv/bin/python benchmarks/bench_small_call.py [--calls 3000] [--rounds 6]``
(``taskset -c 1`` pins it to one core on a shared machine).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import statistics
import subprocess
import sys
import time

import numpy as np
import torch

import _machine
from img2dmp.dmp import DMPConfig, DMPParams, rollout
from img2dmp.dmp._numpy_rollout import rollout_numpy

_rollout = importlib.import_module("img2dmp.dmp.rollout")  # the module, not the function
TARGET_S = 60e-6


def one_dmp(n_t: int = 301, seed: int = 0):
    """``(config, params as float64 tensors [1], t [T])``: one DMP of a 40-px frame."""
    rng = np.random.default_rng(seed)
    cfg = DMPConfig()
    p = DMPParams(
        w=rng.normal(0, 10, (1, 25, 2)),
        tau=np.array([3.0]),
        g=rng.uniform(0, 40, (1, 2)),
        y0=rng.uniform(0, 40, (1, 2)),
    )
    return cfg, p.to_torch(torch.float64), torch.linspace(0, 3.0, n_t, dtype=torch.float64)


@contextlib.contextmanager
def old_path(enabled: bool):
    """Inside: the rollout without its direct path (the general path, as before)."""
    if not enabled or not hasattr(_rollout, "_direct_rollout"):  # (a revision without it)
        yield
        return
    direct = _rollout._direct_rollout
    _rollout._direct_rollout = lambda *a: None
    try:
        yield
    finally:
        _rollout._direct_rollout = direct


def kernel_alone(cfg, p: DMPParams, t: torch.Tensor):
    """The fused forward kernel on ready NumPy arrays: no checks, no conversions."""
    inv_h, s_max, one, tab = _rollout._kernel_table(cfg, torch.float64)
    arrays = [a.numpy() for a in (t[None], p.tau, p.w, p.g, p.y0)]
    out = np.empty((1, t.shape[0], 2))
    forward = _rollout._fused_kernels(tab, 1, 2)[0]
    return lambda: forward(*arrays, tab, inv_h, s_max, one, True, out)


def methods(cfg, p: DMPParams, t: torch.Tensor) -> dict:
    """``name -> (call, old)``: ``old`` runs the call with the direct path switched off."""
    grad = DMPParams(p.w.clone().requires_grad_(True), p.tau, p.g, p.y0)
    p_np, t_np = p.to_numpy(), t.numpy()
    out = {}
    for old in (False, True):
        tag = "old" if old else "new"
        out[f"rollout(p, t), {tag}"] = (lambda: rollout(p, t), old)
        out[f"rollout(p, t, validate=False), {tag}"] = (
            lambda: rollout(p, t, validate=False),
            old,
        )
        out[f"rollout(DMPParams(w, tau, g, y0), t), {tag}"] = (
            lambda: rollout(DMPParams(p.w, p.tau, p.g, p.y0), t),
            old,
        )
    out["rollout, w requires grad (forward only)"] = (lambda: rollout(grad, t), False)
    out["rollout(p, t, backend='torch')"] = (lambda: rollout(p, t, backend="torch"), False)
    out["rollout_numpy(p, t) (NumPy, float64)"] = (lambda: rollout_numpy(p_np, t_np, cfg), False)
    out["fused forward kernel alone"] = (kernel_alone(cfg, p, t), False)
    return out


def time_calls(fn, n: int) -> list[float]:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def run(calls: int, rounds: int) -> dict:
    """``name -> [seconds per call]`` over ``rounds`` alternated rounds, ``calls`` in all."""
    cfg, p, t = one_dmp()
    rollout(p, t, cfg, backend="fused")  # loads the kernels: "auto" takes them from now on
    table = methods(cfg, p, t)
    per_call = {name: [] for name in table}
    for fn, old in table.values():  # warm-up
        with old_path(old):
            time_calls(fn, 200)
    per_round = -(-calls // rounds)
    for _ in range(rounds):
        for name, (fn, old) in table.items():
            with old_path(old):
                per_call[name] += time_calls(fn, per_round)
    return per_call


_FRESH = """
import sys, time, numpy as np
sys.path.insert(0, sys.argv[2])
import bench_small_call as b
from img2dmp.dmp import rollout
ro = sys.modules["img2dmp.dmp.rollout"]
cfg, p, t = b.one_dmp()
times, switched = [], 0
for i in range(int(sys.argv[1])):
    times += b.time_calls(lambda: rollout(p, t), 1)
    switched = switched or (i + 1 if ro._fused_loaded else 0)
print(switched, " ".join(f"{x:.9f}" for x in times))
"""


def fresh_process(calls: int) -> str:
    """N calls of ``rollout(p, t)`` in a new process, summarised in one line."""
    here = str(__import__("pathlib").Path(__file__).resolve().parent)
    done = subprocess.run(
        [sys.executable, "-c", _FRESH, str(calls), here],
        capture_output=True,
        text=True,
        check=True,
    )
    switched, *rest = done.stdout.split()
    times = np.array([float(x) for x in rest])
    k = min(1000, max(1, calls // 3))
    loaded = f"the kernels loaded at call {switched}" if int(switched) else "kernels not loaded"
    return (
        f"{calls} calls of rollout(p, t) in a new process: {times.sum():.2f} s in all; median "
        f"of the first {k} {np.median(times[:k]) * 1e6:.0f} us, of the last {k} "
        f"{np.median(times[-k:]) * 1e6:.0f} us; slowest {times.max() * 1e3:.0f} ms "
        f"(call {int(times.argmax()) + 1}); {loaded}"
    )


def print_table(per_call: dict) -> None:
    print(f"{'call (B = 1, d = 2, N = 25, T = 301, float64)':46s} {'min us':>8s} "
          f"{'median us':>10s} {'/ 60 us':>8s} {'old / new':>10s}")  # fmt: skip
    for name, times in per_call.items():
        lo, med = min(times), statistics.median(times)
        base = name[: -len(", old")] if name.endswith(", old") else None
        vs = ""
        if base is not None and f"{base}, new" in per_call:
            vs = f"{med / statistics.median(per_call[f'{base}, new']):9.1f}x"
        print(f"{name:46s} {lo * 1e6:8.1f} {med * 1e6:10.1f} {med / TARGET_S:7.2f}x {vs:>10s}")


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=3000, help="timed calls per method")
    ap.add_argument("--rounds", type=int, default=6, help="alternated rounds")
    ap.add_argument(
        "--fresh-calls", type=int, default=3000, help="calls in a new process (0: skip)"
    )
    return ap.parse_args(argv)


def main(argv=None) -> dict:
    args = parse_args(argv)
    print(_machine.describe())
    per_call = run(args.calls, args.rounds)
    print(f"at the end: load average {_machine.load_average()}\n")
    print_table(per_call)
    if args.fresh_calls:
        print("\n" + fresh_process(args.fresh_calls))
    return per_call


if __name__ == "__main__":
    main()
