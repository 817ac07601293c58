"""Forward + backward time of four ways to roll out a batch of DMPs, side by side.

Same batch for all: B = 128 DMPs, d = 2, N = 25 kernels, 301 time stamps per sample over
its own duration (tau in [2.5, 3.5] s), loss = sum of squared positions.

1. ``img2dmp.dmp.rollout`` - precomputed unit responses, in its two implementations:
   ``backend="fused"`` (the default on the CPU: compiled forward and backward loops) and
   ``backend="torch"`` (torch operations: a GEMM, a gather, a hand-written backward).
2. Autograd through an explicit Euler loop in torch, one step per time stamp, as Neural
   Dynamic Policies integrates its DMP layer: (a) written as NDP writes it, each step's
   position assigned in place into a preallocated [B*d, T] tensor, in float32 (NDP's
   dtype) and float64; (b) a leaner variant that collects the steps in a list and stacks
   them once.
3. ``img2dmp.dmp.rollout_sensitivity`` - the paper's sensitivity equations (RK4).
4. ``img2dmp.dmp.DMPIntegrator`` - the float64 step-by-step reference integrator, one
   trajectory at a time, forward only (it computes no gradient).
5. The harness alone: a "rollout" that copies a stored output and stored gradients, so
   that only the leaf copies, autograd and the loss are timed: what every method above
   pays besides its own work, and so a bound on the ratios (its error column is that of
   the stored fused output). And the fused kernels alone (forward and backward called
   directly, no checks, autograd or loss): the fused rollout's own maths. The fused
   rollout's time less these two is its glue (checks, conversions, autograd nodes).

Each method's largest deviation from a scipy ``solve_ivp`` solution (rtol 1e-10) of the
first 4 samples is printed too: speed is only worth comparing at equal accuracy.

The fused kernels are also timed at a fixed 1 and 2 threads (torch's and numba's),
next to the default, which follows the thread rule of ``img2dmp.dmp.rollout.fused_threads``
(no more threads than idle cores). ``--load`` runs the whole benchmark next to a busy-loop
process on one core, to show how each method degrades on a loaded machine.

The methods are timed in alternation (:func:`interleaved`), and each ratio is taken
round by round, so that a slow drift of a shared machine does not favour one side. The
CPU, the threads, the load averages at start and end and whether the response tables
hold subnormal numbers are printed with the table.

Run: ``.venv/bin/python benchmarks/bench_rollout.py [--repeats 10] [--load]``
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import statistics
import time

import numpy as np
import torch
from scipy.integrate import solve_ivp

import _machine
from img2dmp.dmp import (
    DMPConfig,
    DMPIntegrator,
    DMPParams,
    forcing_term,
    kernel_centres,
    kernel_widths,
    rollout,
    rollout_sensitivity,
)

_rollout = importlib.import_module("img2dmp.dmp.rollout")  # the module, not the function


def make_batch(b=128, n=25, t_count=301, seed=0):
    rng = np.random.default_rng(seed)
    cfg = DMPConfig(n_kernels=n)
    tau = rng.uniform(2.5, 3.5, b)
    p = DMPParams(
        w=rng.normal(0, 10, (b, n, 2)),
        tau=tau,
        g=rng.uniform(0, 40, (b, 2)),
        y0=rng.uniform(0, 40, (b, 2)),
    )
    t = np.linspace(0, 1, t_count)[None] * tau[:, None]
    return cfg, p, t


def euler_rollout(p: DMPParams, t: torch.Tensor, cfg: DMPConfig) -> torch.Tensor:
    """Explicit Euler on (y, z, x), one step per time stamp, differentiated by autograd."""
    c = torch.as_tensor(kernel_centres(cfg), dtype=t.dtype)
    h = torch.as_tensor(kernel_widths(cfg), dtype=t.dtype)
    y, z = p.y0, torch.zeros_like(p.y0)
    x = torch.ones_like(p.tau)
    tau = p.tau[:, None]
    out = [y]
    for j in range(1, t.shape[1]):
        dt = (t[:, j] - t[:, j - 1])[:, None]
        psi = torch.exp(-h * (x[:, None] - c) ** 2)
        f = torch.einsum("bn,bnd->bd", psi * x[:, None] / psi.sum(-1, keepdim=True), p.w)
        dz = cfg.alpha_z * (cfg.beta * (p.g - y) - z) + (p.g - p.y0) * f
        y, z = y + dt * z / tau, z + dt * dz / tau
        x = x - dt[:, 0] * cfg.alpha_x * x / p.tau
        out.append(y)
    return torch.stack(out, 1)


def euler_rollout_ndp(p: DMPParams, t: torch.Tensor, cfg: DMPConfig) -> torch.Tensor:
    """The same Euler loop in the layout of NDP's ``dmp_layer.integrate``.

    Dimensions are flattened into the batch (rows ``b*d + j``) and every step's position
    is written in place into a preallocated ``[B*d, T]`` tensor, which autograd records as
    one copy-into-slice per step.
    """
    c = torch.as_tensor(kernel_centres(cfg), dtype=t.dtype)
    h = torch.as_tensor(kernel_widths(cfg), dtype=t.dtype)
    b, n, d = p.w.shape
    w = p.w.transpose(1, 2).reshape(b * d, n)
    goal, y0 = p.g.reshape(-1), p.y0.reshape(-1)
    tau = p.tau.repeat_interleave(d)
    tt = t.repeat_interleave(d, dim=0)  # [B*d, T]
    y, z, x = y0, torch.zeros_like(y0), torch.ones_like(y0)
    out = torch.zeros(b * d, t.shape[1], dtype=t.dtype)
    out[:, 0] = y
    for j in range(1, t.shape[1]):
        dt = tt[:, j] - tt[:, j - 1]
        x = x + dt * (-cfg.alpha_x * x / tau)
        psi = torch.exp(-h * (x[:, None] - c) ** 2)
        fx = (w * psi).sum(-1) * x * (goal - y0) / psi.sum(-1)
        dz = cfg.alpha_z * (cfg.beta * (goal - y) - z) + fx
        y, z = y + dt * z / tau, z + dt * dz / tau
        out[:, j] = y
    return out.view(b, d, -1).transpose(1, 2)


def reference(p: DMPParams, t: np.ndarray, cfg: DMPConfig) -> np.ndarray:
    c, h = kernel_centres(cfg), kernel_widths(cfg)
    tau = float(p.tau)

    def rhs(tt, u):
        x = np.exp(-cfg.alpha_x * tt / tau)
        f = forcing_term(np.array(x), p.w, c, h)
        dz = cfg.alpha_z * (cfg.beta * (p.g - u[:2]) - u[2:]) + (p.g - p.y0) * f
        return np.concatenate([u[2:] / tau, dz / tau])

    u0 = np.concatenate([p.y0, [0.0, 0.0]])
    sol = solve_ivp(rhs, (0, t[-1]), u0, t_eval=t, rtol=1e-10, atol=1e-10, method="DOP853")
    return sol.y[:2].T


def timed(fn, repeats):
    fn()  # warm-up (builds cached tables)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def forward_backward(roll, p, t):
    def run():
        leaves = [a.clone().requires_grad_(True) for a in (p.w, p.tau, p.g, p.y0)]
        y = roll(DMPParams(*leaves), t)
        (y**2).sum().backward()
        return y.detach()

    return run


@contextlib.contextmanager
def fixed_threads(n: int | None):
    """Inside: torch and the fused kernels on ``n`` threads (None: leave them alone)."""
    if n is None:
        yield
        return
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    _rollout.fix_fused_threads(n)
    try:
        yield
    finally:
        _rollout.fix_fused_threads(None)
        torch.set_num_threads(before)


def interleaved(methods, rounds: int, fast_calls: int, threads=None):
    """Time the methods in alternation: ``rounds`` rounds, each timing every method once.

    A method faster than 20 ms counts as the median of ``fast_calls`` consecutive calls
    in its round. Alternating keeps slow drifts of the machine (other tenants, clock
    changes) out of the ratios. ``threads`` maps a method's name to the thread count it
    runs at (set outside the timed calls; default: unchanged). Returns
    ``{name: [seconds per round]}`` and each method's last output.
    """
    threads = threads or {}
    outs, per_round = {}, {name: [] for name in methods}
    for name, fn in methods.items():  # warm-up (builds cached tables, compiles kernels)
        with fixed_threads(threads.get(name)):
            outs[name] = fn()
    for _ in range(rounds):
        for name, fn in methods.items():
            n = fast_calls if (not per_round[name] or per_round[name][-1] < 0.02) else 1
            times = []
            with fixed_threads(threads.get(name)):
                for _ in range(n):
                    t0 = time.perf_counter()
                    fn()
                    times.append(time.perf_counter() - t0)
            per_round[name].append(statistics.median(times))
    return per_round, outs


def subnormal_entries(cfg: DMPConfig) -> str:
    """How many entries of the fused kernels' response tables are subnormal, per dtype."""
    parts = []
    for dtype in (torch.float32, torch.float64):
        tab = _rollout._kernel_table(cfg, dtype)[3]
        n = int(((np.abs(tab) < np.finfo(tab.dtype).tiny) & (tab != 0)).sum())
        parts.append(f"{str(dtype)[6:]} {n} of {tab.size}")
    return "subnormal table entries: " + ", ".join(parts)


def rule_threads(b: int) -> str:
    return (
        f"fused kernels' default threads for B={b}: {_rollout.fused_threads(b)} "
        f"(idle cores seen: {_rollout.idle_cores()})"
    )


class _Replay(torch.autograd.Function):
    """A "rollout" that costs nothing: it copies a stored output and stored gradients."""

    @staticmethod
    def forward(ctx, tau, w, g, y0, stored):
        ctx.stored = stored
        return stored["y"].clone()

    @staticmethod
    def backward(ctx, gy):
        s = ctx.stored
        return s["tau"].clone(), s["w"].clone(), s["g"].clone(), s["y0"].clone(), None


def harness_floor(cfg, p: DMPParams, t: torch.Tensor):
    """The benchmark's own cost around a rollout (leaf copies, autograd, the loss and its
    backward) with a rollout that takes no time: what any method pays here."""
    leaves = [a.clone().requires_grad_(True) for a in (p.w, p.tau, p.g, p.y0)]
    y = rollout(DMPParams(*leaves), t, cfg)
    (y**2).sum().backward()
    grads = (a.grad for a in leaves)
    stored = {"y": y.detach(), **dict(zip(("w", "tau", "g", "y0"), grads, strict=True))}
    return forward_backward(lambda q, tt: _Replay.apply(q.tau, q.w, q.g, q.y0, stored), p, t)


def kernels_alone(cfg, p: DMPParams, t: torch.Tensor):
    """The fused forward and backward kernels called directly on ready arrays (no checks,
    no autograd, no loss; the gradient of sum(y^2)): what the fused rollout's own maths
    costs."""
    dtype = p.w.dtype
    inv_h, s_max, one, tab = _rollout._kernel_table(cfg, dtype)
    arrays = [a.detach().numpy() for a in (t, p.tau, p.w, p.g, p.y0)]
    y = np.empty((*t.shape, p.w.shape[-1]), tab.dtype)
    grads = [np.empty(a.shape, tab.dtype) for a in (arrays[2], arrays[1], arrays[3], arrays[4])]
    scaled = cfg.scaling == "goal-start"

    def run():
        forward, backward = _rollout._fused_kernels(tab, t.shape[0], p.w.shape[-1])
        forward(*arrays, tab, inv_h, s_max, one, scaled, y)
        backward(2 * y, *arrays, tab, inv_h, s_max, one, scaled, *grads, True)
        return torch.from_numpy(y)

    return run


def build_methods(cfg, p_np, t_np):
    """The timed methods, and the thread counts of those that run at a fixed one."""
    methods, threads = {}, {}
    for backend in ("fused", "torch"):
        for dtype in (torch.float32, torch.float64):
            p, t = p_np.to_torch(dtype), torch.as_tensor(t_np, dtype=dtype)
            name = f"fast rollout, {backend} ({str(dtype)[6:]})"
            fb = forward_backward(lambda q, tt, b=backend: rollout(q, tt, cfg, backend=b), p, t)
            methods[name] = fb
            if backend == "fused":
                for n in (1, 2):
                    methods[f"{name}, {n} thread{'s' if n > 1 else ''}"] = fb
                    threads[f"{name}, {n} thread{'s' if n > 1 else ''}"] = n
    for name, fn, dtype in (
        ("Euler loop + autograd, NDP layout (float32)", euler_rollout_ndp, torch.float32),
        ("Euler loop + autograd, NDP layout (float64)", euler_rollout_ndp, torch.float64),
        ("Euler loop + autograd, lean (float64)", euler_rollout, torch.float64),
    ):
        p, t = p_np.to_torch(dtype), torch.as_tensor(t_np, dtype=dtype)
        methods[name] = forward_backward(lambda q, tt, fn=fn: fn(q, tt, cfg), p, t)
    p, t = p_np.to_torch(torch.float64), torch.as_tensor(t_np, dtype=torch.float64)
    methods["harness alone: a rollout taking no time (float64)"] = harness_floor(cfg, p, t)
    methods["fused kernels alone, no autograd (float64)"] = kernels_alone(cfg, p, t)
    return methods, threads


def parse_args():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=10, help="rounds of alternated timings")
    ap.add_argument(
        "--fast-calls",
        type=int,
        default=15,
        help="calls per round of a method faster than 20 ms (their median counts)",
    )
    ap.add_argument(
        "--reference-samples",
        type=int,
        default=8,
        help="trajectories the (slow, forward-only) reference integrator runs; "
        "its time is scaled to the batch",
    )
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    ap.add_argument(
        "--load",
        action="store_true",
        help="run next to a busy-loop process on one core (killed at the end, at most 15 min)",
    )
    return ap.parse_args()


def main():
    args = parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    cfg, p_np, t_np = make_batch()
    b = t_np.shape[0]
    with _machine.busy_neighbour(900.0, enabled=args.load) as neighbour:
        print(_machine.describe())
        print(f"neighbour: {neighbour or 'none started (--load starts one)'}")
        print(f"{subnormal_entries(cfg)}; {rule_threads(b)}")
        per_round, rows = run_methods(cfg, p_np, t_np, args)
        print(f"at the end: load average {_machine.load_average()}; {rule_threads(b)}\n")
    print_table(rows, per_round, cfg, p_np, t_np, args)


def run_methods(cfg, p_np, t_np, args):
    """Time every method; ``(per_round, rows)`` with rows ``(name, seconds, output)``."""
    b = t_np.shape[0]
    methods, threads = build_methods(cfg, p_np, t_np)
    per_round, outs = interleaved(methods, args.repeats, args.fast_calls, threads)
    rows = [(name, statistics.median(per_round[name]), outs[name]) for name in methods]
    p, t = p_np.to_torch(torch.float64), torch.as_tensor(t_np)
    fb = forward_backward(lambda q, tt: rollout_sensitivity(q, tt, cfg), p, t)
    rows.append(("sensitivity equations, RK4 (float64)", *timed(fb, 1)))
    k = args.reference_samples

    def ref_run():
        return np.stack([DMPIntegrator(p_np[i], cfg).run(t_np[i]) for i in range(k)])

    sec, out = timed(ref_run, 1)
    rows.append((f"reference integrator, forward only (x{b}/{k})", sec * b / k, out))
    return per_round, rows


def print_table(rows, per_round, cfg, p_np, t_np, args):
    b = t_np.shape[0]
    refs = np.stack([reference(p_np[i], t_np[i], cfg) for i in range(4)])
    base = rows[0][1]
    print(
        f"B={b}, d=2, N=25, T={t_np.shape[1]}, forward + backward, median of "
        f"{args.repeats} alternated rounds, torch threads={torch.get_num_threads()}"
        f"{', next to a busy neighbour' if args.load else ''}"
    )
    print(f"{'method':46s} {'time (ms)':>10s} {'/ fused f32':>11s} {'max err px':>11s}")
    for name, sec, out in rows:
        err = np.abs(np.asarray(out[:4], dtype=np.float64) - refs[: len(out)]).max()
        print(f"{name:46s} {sec * 1e3:10.2f} {sec / base:10.1f}x {err:11.2e}")

    def ratio(slow: str, fast: str, digits: int = 0) -> str:
        # Per round, so that both sides of each ratio saw the same machine state.
        r = sorted(a / b for a, b in zip(per_round[slow], per_round[fast], strict=True))
        return f"{statistics.median(r):.{digits}f}x (rounds {r[0]:.{digits}f}-{r[-1]:.{digits}f}x)"

    euler, fused = "Euler loop + autograd, NDP layout", "fast rollout, fused"
    print(
        f"\nfused rollout vs the Euler loop in NDP's layout, same dtype, median over rounds:"
        f"\n  float32 {ratio(f'{euler} (float32)', f'{fused} (float32)')}, "
        f"float64 {ratio(f'{euler} (float64)', f'{fused} (float64)')} "
        "(target >= 100x)"
        f"\n  the float64 Euler loop against the harness alone (a rollout taking no time): "
        f"{ratio(f'{euler} (float64)', 'harness alone: a rollout taking no time (float64)')}, "
        f"against the fused kernels alone: "
        f"{ratio(f'{euler} (float64)', 'fused kernels alone, no autograd (float64)')}"
        f"\ntorch-operations rollout, same comparison:"
        f"\n  float32 {ratio(f'{euler} (float32)', 'fast rollout, torch (float32)')}, "
        f"float64 {ratio(f'{euler} (float64)', 'fast rollout, torch (float64)')}"
        f"\nfused rollout, time on 1 thread / time on 2 threads (above 1: 2 threads are faster):"
        f"\n  float32 {ratio(f'{fused} (float32), 1 thread', f'{fused} (float32), 2 threads', 2)}, "
        f"float64 {ratio(f'{fused} (float64), 1 thread', f'{fused} (float64), 2 threads', 2)}"
    )


if __name__ == "__main__":
    main()
