"""The fused rollout kernels alone, per time stamp: nanoseconds and estimated cycles.

Calls the compiled forward and backward kernels of :mod:`img2dmp.dmp._kernels` directly
(no checks, no autograd, no loss) on ``bench_rollout.make_batch`` (d = 2, N = 25,
T = 301, tau in [2.5, 3.5] s) at B = 1, 128 and 4096 in float32 and float64, on one
thread, and prints the time per time stamp (one sample's one stamp) in ns and in
cycles. Cycles are estimated as ns times the clock that ``/proc/cpuinfo`` reports
("cpu MHz"; ``--ghz`` overrides it): on a virtual machine that is the nominal clock, so
the estimate is only as good as that number. Beside them: the floor the FMA units set
(5 multiply-adds per column and stamp forward, about 10 backward, over 2 pipes of
256-bit FMAs: 8 float64 or 16 float32 per cycle, as on AMD Zen 2-4) for the table's
padded width, and where the table starts relative to a cache line (64 bytes).

``--before REV`` (default ``main``) times the kernels of that git revision too
(``src/img2dmp/dmp/_kernels.py`` taken with ``git show`` and imported on its own,
compiled once into ``~/.cache/img2dmp/bench_kernel``): with its table where its own
``piece_table`` puts it, and copied to 16 and to 0 bytes past a cache line. Every
round builds each variant's inputs afresh and takes the variants in alternation;
the ratios are taken round by round. The numbers each variant gives are compared with
the current kernels' (largest difference relative to the largest value; forward:
positions, backward: the four gradients). ``--before ""`` skips it.

Run pinned to one core on a shared machine::

    taskset -c 1 python benchmarks/bench_kernel.py [--rounds 5] [--before main]
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

import _machine
from bench_rollout import make_batch
from img2dmp.dmp import _kernels
from img2dmp.dmp.rollout import _response_table

_KERNELS_FILE = "src/img2dmp/dmp/_kernels.py"


def clock_ghz() -> float:
    """The clock ``/proc/cpuinfo`` reports for the first CPU ("cpu MHz"), in GHz (0: unknown)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("cpu MHz"):
                    return float(line.split(":", 1)[1]) / 1000.0
    except (OSError, ValueError):
        pass
    return 0.0


def kernels_at(rev: str):
    """The ``_kernels`` module of git revision ``rev``, imported on its own (numba loaded)."""
    repo = Path(__file__).resolve().parents[1]
    source = subprocess.run(
        ["git", "show", f"{rev}:{_KERNELS_FILE}"], cwd=repo, capture_output=True, check=True
    ).stdout
    digest = hashlib.sha1(source).hexdigest()[:12]
    user = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    folder = Path(user) / "img2dmp" / "bench_kernel"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"kernels_{digest}.py"
    if not path.exists():
        path.write_bytes(source)
    spec = importlib.util.spec_from_file_location(f"kernels_{digest}", path)
    module = importlib.util.module_from_spec(spec)
    # numba's cached code looks its module up by name when it loads.
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    if not module.available():  # pragma: no cover - numba missing
        raise RuntimeError("the fused kernels need numba")
    return module


def kernel_inputs(module, b: int, dtype: torch.dtype, n_t: int = 301, offset=None):
    """Arguments of ``forward`` and ``backward`` of ``module`` for a batch of ``b``; with
    an ``offset`` its table copied to start that many bytes past a cache line."""
    cfg, p, t = make_batch(b=b, t_count=n_t)
    h, s_max, poly = _response_table(cfg, dtype, "cpu")
    tab = module.piece_table(poly.numpy())
    if offset is not None:
        raw = _kernels._aligned_zeros((tab.nbytes + 64,), np.uint8)
        placed = raw[offset : offset + tab.nbytes].view(tab.dtype).reshape(tab.shape)
        placed[...] = tab
        tab = placed
    one = tab.dtype.type(1.0)
    np_dtype = tab.dtype
    arrays = [np.ascontiguousarray(x, dtype=np_dtype) for x in (t, p.tau, p.w, p.g, p.y0)]
    consts = (tab, one / np_dtype.type(h), np_dtype.type(s_max), one, True)
    gy = np.random.default_rng(1).normal(size=(b, n_t, 2)).astype(np_dtype)
    return arrays, consts, gy


def calls(module, b: int, dtype: torch.dtype, n_t: int = 301, offset=None):
    """``(forward, backward, table offset)``: closures running one kernel call each and
    returning its output, and the table's first byte's address modulo 64."""
    forward, backward = module.kernels(module_width(module, dtype), 2, 1)
    arrays, consts, gy = kernel_inputs(module, b, dtype, n_t, offset)
    out = np.empty((b, n_t, 2), dtype=consts[0].dtype)
    grads = [np.empty_like(x) for x in (arrays[2], arrays[1], arrays[3], arrays[4])]

    def run_forward():
        forward(*arrays, *consts, out)
        return out

    def run_backward():
        backward(gy, *arrays, *consts, *grads, True)
        return grads

    return run_forward, run_backward, consts[0].ctypes.data % 64


def module_width(module, dtype: torch.dtype) -> int:
    """The padded number of columns of ``module``'s table (its kernels are built per width)."""
    cfg = make_batch(b=1, t_count=2)[0]
    return module.piece_table(_response_table(cfg, dtype, "cpu")[2].numpy()).shape[-1]


def time_per_call(fn, seconds: float) -> float:
    """Median seconds per call over about ``seconds`` of calls (in 5 chunks)."""
    fn()
    start = time.perf_counter()
    fn()
    once = max(time.perf_counter() - start, 1e-7)
    n = max(1, int(seconds / 5 / once))
    chunks = []
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(n):
            fn()
        chunks.append((time.perf_counter() - start) / n)
    return statistics.median(chunks)


def fma_floor(width: int, dtype: torch.dtype) -> tuple[float, float]:
    """Cycles per stamp the multiply-adds need at 2 x 256-bit FMAs a cycle: forward
    (Horner, 3 a column, and 2 dot products) and backward (Horner, 2 gradient sums,
    the derivative's 2 and the time gradient's 3)."""
    lanes = 16 if dtype == torch.float32 else 8
    return width * 5 / lanes, width * 10 / lanes


def largest_difference(a, b) -> float:
    a, b = np.concatenate([np.ravel(x) for x in a]), np.concatenate([np.ravel(x) for x in b])
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(a)), 1e-300))


def run(args) -> list[dict]:
    modules = {"now": (_kernels, None)}
    if args.before:
        old = kernels_at(args.before)
        modules[f"before ({args.before})"] = (old, None)
        modules[f"before ({args.before}), table at +16 B"] = (old, 16)
        modules[f"before ({args.before}), table at +0 B"] = (old, 0)
    _kernels.available()
    rows = []
    for dtype in args.dtypes:
        for b in args.batch:
            rows.extend(time_case(modules, b, dtype, args))
    return rows


def time_case(variants, b, dtype, args) -> list[dict]:
    """Forward and backward of every variant at one batch size and dtype, alternated.

    Every round builds each variant's inputs afresh (new addresses: how the arrays fall
    relative to each other moves a kernel's time by several per cent) and takes the
    variants in turn, in reverse order every other round. The outputs of the last
    round are compared with the first variant's.
    """
    n_t = args.time_stamps
    names = list(variants)
    ns = {(name, k): [] for name in names for k in range(2)}
    offsets = {name: set() for name in names}
    outs = {}
    for r in range(args.rounds):
        for name in names if r % 2 == 0 else names[::-1]:
            module, offset = variants[name]
            fns = calls(module, b, dtype, n_t, offset)
            offsets[name].add(fns[2])
            for k in range(2):
                ns[name, k].append(time_per_call(fns[k], args.seconds) / (b * n_t) * 1e9)
            outs[name] = [[np.copy(x) for x in _as_list(fn())] for fn in fns[:2]]
    rows = []
    for name in names:
        for k, pass_name in enumerate(("forward", "backward")):
            rows.append(
                dict(
                    dtype=str(dtype).replace("torch.", ""),
                    b=b,
                    pass_=pass_name,
                    kernels=name,
                    ns=ns[name, k],
                    diff=largest_difference(outs[names[0]][k], outs[name][k]),
                    width=module_width(variants[name][0], dtype),
                    offset="/".join(str(o) for o in sorted(offsets[name])),
                )
            )
    return rows


def _as_list(out) -> list:
    return out if isinstance(out, list) else [out]


def print_rows(rows, ghz: float, rounds: int) -> None:
    print(
        f"ns per time stamp, median (range) over {rounds} alternated rounds; cycles = ns x "
        f"{ghz:.3f} GHz; FMA floor for the table's padded width"
    )
    print(
        "| dtype | B | pass | kernels | table at (mod 64 B) | ns / stamp | cycles / stamp "
        "| FMA floor | now / this | max diff vs now |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    now = {}
    for r in rows:
        ns = statistics.median(r["ns"])
        key = (r["dtype"], r["b"], r["pass_"])
        if r["kernels"] == "now":
            now[key] = r["ns"]
            ratio = ""
        else:
            per = [a / b for a, b in zip(now[key], r["ns"], strict=True)]
            ratio = f"{statistics.median(per):.2f} ({min(per):.2f}-{max(per):.2f})"
        dt = torch.float32 if r["dtype"] == "float32" else torch.float64
        floor = fma_floor(r["width"], dt)[r["pass_"] == "backward"]
        print(
            f"| {r['dtype']} | {r['b']} | {r['pass_']} | {r['kernels']} | {r['offset']} | {ns:.2f} "
            f"({min(r['ns']):.2f}-{max(r['ns']):.2f}) | {ns * ghz:.1f} | {floor:.0f} | "
            f"{ratio} | {r['diff']:.1e} |"
        )


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 128, 4096])
    ap.add_argument("--dtypes", nargs="+", default=["float32", "float64"])
    ap.add_argument("--time-stamps", type=int, default=301)
    ap.add_argument("--rounds", type=int, default=5, help="alternated rounds")
    ap.add_argument("--seconds", type=float, default=0.2, help="per timing, about")
    ap.add_argument("--before", default="main", help='git revision to compare ("": none)')
    ap.add_argument("--ghz", type=float, default=0.0, help="clock for the cycle estimate")
    args = ap.parse_args(argv)
    args.dtypes = [getattr(torch, name) for name in args.dtypes]
    return args


def main(argv=None) -> list[dict]:
    args = parse_args(argv)
    torch.set_num_threads(1)
    ghz = args.ghz or clock_ghz() or 1.0
    print(_machine.describe())
    rows = run(args)
    print_rows(rows, ghz, args.rounds)
    print(f"load average at the end {_machine.load_average()}")
    return rows


if __name__ == "__main__":
    main()
