"""img2dmp's rollout and fit against the DMP packages a user would otherwise pick.

Each peer is configured to img2dmp's DMP (``DMPConfig()``: N = 25 kernels, alpha_z = 48,
beta_z = 12, alpha_x = 2, kernels evenly spaced in time with img2dmp's widths, forcing
term scaled by ``g - y0``) through the parameters it exposes, the batch of
``bench_rollout.make_batch`` (d = 2, tau in [2.5, 3.5] s, goal and start in a 40-px
frame), ``T`` time stamps per sample over its own duration:

- **img2dmp fused** - ``img2dmp.dmp.rollout`` (exact unit responses, compiled loops).
- **MP_PyTorch ProDMP** (``img2dmp.interop.to_mp_pytorch(kind="prodmp")``): closed form
  with a basis tabulated by the trapezoidal rule (``--prodmp-steps`` per tau, built once,
  not timed) and interpolated linearly; batched, differentiable.
- **MP_PyTorch DMP** (``kind="dmp"``): explicit Euler at the time stamps; batched. Its
  loop writes each step in place into tensors autograd has saved (0.1.4), so a backward
  pass fails unless run inside ``torch.autograd.graph.allow_mutation_on_saved_tensors()``,
  which clones them: its forward + backward is timed so.
- **torchdiffeq rk4 / dopri5**: the same ODE written as a torch right-hand side (phase in
  closed form), one RK4 step per stamp interval / adaptive dopri5 (rtol 1e-7, atol 1e-9;
  float32 1e-5, 1e-6), autograd through the solver.
- **movement_primitives** (``img2dmp.interop.to_movement_primitives``, dt = tau/(T-1)):
  its compiled RK4 ``open_loop()``, one trajectory at a time, NumPy, no gradient. Its
  step evaluates the forcing term one step late (0.9.1), so its error is first order.
- **pydmps** (``DMPs_discrete``, widths set to img2dmp's): Python Euler steps, one
  trajectory at a time, phase integrated by Euler too; no gradient.

The peers that do not scale their forcing term get the amplitudes ``(g - y0) w``, as
functions of img2dmp's leaves, so that gradients are compared in img2dmp's parameters.
Per-trajectory peers are timed on at most ``--per-trajectory`` samples and scaled to the
batch (their cost is a loop over samples). float32 rows run the torch peers in float32;
movement_primitives and pydmps are float64 only.

Columns: milliseconds of img2dmp fused, and each peer's time over img2dmp's, taken round
by round (the methods of one batch size and dtype alternate, ``bench_rollout.
interleaved``) as a median and range over rounds. Accuracy: the largest deviation from
scipy's ``solve_ivp`` (DOP853, rtol = atol = 1e-10) over the first 4 samples of the
largest float64 batch. Gradient agreement: the largest difference of each peer's gradient
of ``sum(y^2)`` from img2dmp's, relative to the largest of img2dmp's, per field. Fitting:
``--fit-demos`` demonstrations (img2dmp rollouts of random DMPs) fitted by
``fit_dmp`` (one batched least squares on positions), movement_primitives' ``imitate``
and pydmps' ``imitate_path`` (regression on differentiated accelerations), with the fit's
largest distance from the demonstration when rolled out by the same package.

On a loaded machine torch's second thread waits for a busy core (small torch operations
ran 3x slower on 2 threads than on 1 next to other jobs): ``--threads 1`` then compares
every method on one thread.

Run: ``.venv/bin/python benchmarks/bench_peers.py [--threads 1]`` (15-30 minutes: dopri5
and rk4 at B = 4096 take tens of seconds a call);
smoke: ``--batch 1 --rounds 1 --fast-calls 1 --time-stamps 21 --fit-demos 4``.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import statistics
import time

import numpy as np
import torch

import _machine
from bench_rollout import interleaved, make_batch, reference
from img2dmp.dmp import DMPConfig, DMPParams, fit_dmp, kernel_centres, kernel_widths, rollout

PEERS = {  # name: (module that must import, pip package)
    "prodmp": ("mp_pytorch", "mp-pytorch"),
    "mp_pytorch_dmp": ("mp_pytorch", "mp-pytorch"),
    "torchdiffeq_rk4": ("torchdiffeq", "torchdiffeq"),
    "torchdiffeq_dopri5": ("torchdiffeq", "torchdiffeq"),
    "movement_primitives": ("movement_primitives", "movement-primitives"),
    "pydmps": ("pydmps", "pydmps"),
}
LABELS = {
    "fused": "img2dmp fused",
    "prodmp": "MP_PyTorch ProDMP",
    "mp_pytorch_dmp": "MP_PyTorch DMP (Euler)",
    "torchdiffeq_rk4": "torchdiffeq rk4",
    "torchdiffeq_dopri5": "torchdiffeq dopri5",
    "movement_primitives": "movement_primitives (RK4)",
    "pydmps": "pydmps (Euler)",
}
NUMPY_PEERS = ("movement_primitives", "pydmps")  # float64, forward only, per trajectory


def installed(names) -> tuple[list, list]:
    """``(present, missing)``: the peers whose package imports, and those that do not."""
    present, missing = [], []
    for name in names:
        module = PEERS[name][0]
        ok = importlib.util.find_spec(module) is not None
        if ok:
            try:
                importlib.import_module(
                    module if module != "movement_primitives" else module + ".dmp"
                )
            except ImportError:
                ok = False
        (present if ok else missing).append(name)
    return present, missing


def amplitudes(q: DMPParams, cfg: DMPConfig) -> torch.Tensor:
    """``S w`` [B, N, d] as a function of img2dmp's leaves (``S = g - y0`` or 1)."""
    if cfg.scaling == "goal-start":
        return q.w * (q.g - q.y0)[:, None, :]
    return q.w


# ---------------------------------------------------------------------------------------
# The peers, each ``roll(q, t) -> y [B, T, d]`` on torch leaves (torch peers) or
# ``run() -> list of (t, y)`` (NumPy peers)


def mp_pytorch_peer(kind: str, cfg, p_np, dtype, steps: int):
    from img2dmp import interop

    prim = interop.to_mp_pytorch(p_np, cfg, kind=kind, steps=steps, dtype=dtype, check=False).dmp

    def roll(q: DMPParams, t: torch.Tensor) -> torch.Tensor:
        b, d = q.g.shape
        amp = amplitudes(q, cfg).transpose(1, 2)  # [B, d, N]
        wg = torch.cat([amp, q.g[..., None]], dim=-1).reshape(b, -1)
        prim.reset()  # else its learnable tau stays the first one it was given
        prim.update_inputs(
            times=t,
            params=torch.cat([q.tau[:, None], wg], dim=-1),
            init_time=torch.zeros_like(q.tau),
            init_pos=q.y0,
            init_vel=torch.zeros_like(q.y0),
        )
        return prim.get_traj_pos()

    if kind == "dmp":
        # Its Euler loop writes the steps in place into tensors autograd saved (and divides
        # the velocities in place after): a backward pass needs torch to clone them.
        roll.context = torch.autograd.graph.allow_mutation_on_saved_tensors
    return roll


def torchdiffeq_peer(method: str, cfg):
    from torchdiffeq import odeint

    def roll(q: DMPParams, t: torch.Tensor) -> torch.Tensor:
        # In u = t / t_end on a grid shared by the batch; r = t_end / tau carries tau.
        t_end = t[:, -1].detach()
        u = t[0] / t_end[0]
        r = (t_end / q.tau)[:, None]  # [B, 1]
        c = torch.as_tensor(kernel_centres(cfg), dtype=t.dtype)
        h = torch.as_tensor(kernel_widths(cfg), dtype=t.dtype)
        amp, d = amplitudes(q, cfg), q.g.shape[-1]

        def rhs(uu, state):  # state [B, 2d]: y and v = tau dy/dt
            y, v = state[:, :d], state[:, d:]
            x = torch.exp(-cfg.alpha_x * uu * r)  # [B, 1]
            psi = torch.exp(-h * (x - c) ** 2)
            f = torch.einsum("bn,bnd->bd", psi * x / psi.sum(-1, keepdim=True), amp)
            dv = cfg.alpha_z * (cfg.beta * (q.g - y) - v) + f
            return torch.cat([r * v, r * dv], dim=-1)

        state0 = torch.cat([q.y0, torch.zeros_like(q.y0)], dim=-1)
        # float32 cannot meet float64's tolerances: the steps would shrink without end.
        tol = (1e-7, 1e-9) if t.dtype == torch.float64 else (1e-5, 1e-6)
        opts = {"rtol": tol[0], "atol": tol[1]} if method == "dopri5" else {}
        sol = odeint(rhs, state0, u, method=method, **opts)  # [T, B, 2d]
        return sol[..., :d].transpose(0, 1)

    return roll


def movement_primitives_peer(cfg, p_np, t_np):
    from img2dmp import interop

    dmps = interop.to_movement_primitives(
        p_np, cfg, dt=float(t_np[0, 1] - t_np[0, 0]), check=False
    ).dmp
    dmps = dmps if isinstance(dmps, list) else [dmps]
    for dmp, t in zip(dmps, t_np, strict=True):
        dmp.dt_ = float(t[1] - t[0])

    def run():
        return [dmp.open_loop() for dmp in dmps]

    return run


def pydmps_peer(cfg, p_np, t_np):
    from pydmps.dmp_discrete import DMPs_discrete

    n_t, items = t_np.shape[1], []
    for i in range(p_np.tau.shape[0]):
        s = p_np[i]
        w = s.w.T if cfg.scaling == "goal-start" else (s.w / (s.g - s.y0)).T
        dmp = DMPs_discrete(
            n_dmps=s.g.shape[0],
            n_bfs=cfg.n_kernels,
            dt=1.0 / (n_t - 1),  # its time runs over [0, 1]: normalised time
            y0=s.y0.copy(),
            goal=s.g.copy(),
            w=w.copy(),
            ay=np.full(s.g.shape, cfg.alpha_z),
            by=np.full(s.g.shape, cfg.beta),
            ax=cfg.alpha_x,
        )
        dmp.h = kernel_widths(cfg)  # its own are n_bfs^1.5 / c / ax
        items.append((dmp, t_np[i]))

    def run():
        out = []
        for dmp, t in items:
            y = dmp.rollout(timesteps=n_t - 1)[0]  # the states after each step
            out.append((t, np.concatenate([dmp.y0[None], y])))
        return out

    return run


# ---------------------------------------------------------------------------------------
# Timing


def leaves(p: DMPParams, grad: bool) -> DMPParams:
    return DMPParams(*(a.clone().requires_grad_(grad) for a in (p.w, p.tau, p.g, p.y0)))


def timed_call(roll, p: DMPParams, t: torch.Tensor, backward: bool):
    """A call of ``roll``: forward, or forward + backward of ``sum(y^2)``."""

    context = getattr(roll, "context", None) if backward else None

    def run():
        with context() if context else contextlib.nullcontext():
            q = leaves(p, backward)
            y = roll(q, t)
            if backward:
                (y**2).sum().backward()
        return y.detach()

    return run


def methods_for(b, dtype, backward, cfg, peers, args, cache):
    """``{name: (call, scale)}``: the timed calls of one batch size, dtype and mode; a
    per-trajectory peer's time is multiplied by ``scale`` (batch / samples it ran)."""
    p_np, t_np = cache["batch", b]
    p, t = p_np.to_torch(dtype), torch.as_tensor(t_np, dtype=dtype)
    fused = lambda q, tt: rollout(q, tt, cfg, backend="fused")  # noqa: E731
    out = {"fused": (timed_call(fused, p, t, backward), 1.0)}
    for name in peers:
        if name in NUMPY_PEERS:
            if backward or dtype != torch.float64:
                continue
            k = min(b, args.per_trajectory)
            key = name, b
            if key not in cache:
                make = movement_primitives_peer if name == "movement_primitives" else pydmps_peer
                cache[key] = make(cfg, p_np[:k], t_np[:k])
            out[name] = (cache[key], b / k)
            continue
        key = name, b, dtype
        if key not in cache:
            if name in ("prodmp", "mp_pytorch_dmp"):
                kind = "prodmp" if name == "prodmp" else "dmp"
                cache[key] = mp_pytorch_peer(kind, cfg, p_np, dtype, args.prodmp_steps)
            else:
                cache[key] = torchdiffeq_peer(name.split("_")[1], cfg)
        out[name] = (timed_call(cache[key], p, t, backward), 1.0)
    return out


def time_group(methods, args):
    """Seconds per round of each method (scaled), and each method's last output."""
    calls = {name: call for name, (call, _) in methods.items()}
    per_round, outs = interleaved(calls, args.rounds, args.fast_calls)
    scaled = {n: [s * methods[n][1] for s in secs] for n, secs in per_round.items()}
    return scaled, outs


def ratio_text(per_round: dict, name: str) -> str:
    r = sorted(a / b for a, b in zip(per_round[name], per_round["fused"], strict=True))
    fmt = (lambda x: f"{x:,.0f}") if r[0] >= 10 else (lambda x: f"{x:.1f}")
    rng = f" ({fmt(r[0])}-{fmt(r[-1])})" if len(r) > 1 else ""
    return f"{fmt(statistics.median(r))}x{rng}"


# ---------------------------------------------------------------------------------------
# Accuracy and gradients


def accuracy(outs, cfg, p_np, t_np) -> dict:
    """Largest deviation (px) from solve_ivp over the first 4 samples, per method."""
    errors = {}
    for name, out in outs.items():
        pairs = (
            out if isinstance(out, list) else [(t_np[i], out[i].numpy()) for i in range(len(out))]
        )
        worst = 0.0
        for i, (t, y) in enumerate(pairs[:4]):
            ref = reference(p_np[i], np.asarray(t, np.float64), cfg)
            n = min(len(ref), len(y))  # mp's open loop may add a stamp past tau
            worst = max(worst, float(np.abs(np.asarray(y[:n], np.float64) - ref[:n]).max()))
        errors[name] = worst
    return errors


def gradients(roll, p: DMPParams, t: torch.Tensor):
    with getattr(roll, "context", contextlib.nullcontext)():
        q = leaves(p, True)
        (roll(q, t) ** 2).sum().backward()
    return {k: getattr(q, k).grad for k in ("w", "tau", "g", "y0")}


def gradient_agreement(cfg, peers, cache, b) -> dict:
    """Per torch peer: the largest gradient difference from img2dmp's, relative, per field."""
    p_np, t_np = cache["batch", b]
    p, t = p_np.to_torch(torch.float64), torch.as_tensor(t_np)
    ref = gradients(lambda q, tt: rollout(q, tt, cfg, backend="fused"), p, t)
    out = {}
    for name in peers:
        if name in NUMPY_PEERS or (name, b, torch.float64) not in cache:
            continue
        got = gradients(cache[name, b, torch.float64], p, t)
        parts = []
        for k, g in ref.items():
            if got[k] is None or not bool(got[k].abs().max() > 0):
                parts.append(f"{k} none")
            else:
                rel = float((got[k] - g).abs().max() / g.abs().max())
                parts.append(f"{k} {rel:.0e}")
        out[name] = ", ".join(parts)
    return out


# ---------------------------------------------------------------------------------------
# Fitting


def fit_methods(cfg, peers, n_demos: int, n_t: int):
    """``{name: fit()}`` for img2dmp and the peers that fit, and the demonstrations."""
    _, p_np, t_np = make_batch(b=n_demos, t_count=n_t, seed=1)
    y = rollout(p_np.to_torch(), torch.as_tensor(t_np), cfg).numpy()
    methods = {"fused": lambda: fit_dmp(t_np, y, cfg).params}
    if "movement_primitives" in peers:
        from img2dmp import interop

        dmps = interop.to_movement_primitives(p_np, cfg, dt=float(t_np[0, 1]), check=False).dmp

        def mp_fit():
            for dmp, t, yy in zip(dmps, t_np, y, strict=True):
                dmp.imitate(t, yy)
            return dmps

        methods["movement_primitives"] = mp_fit
    if "pydmps" in peers:
        from pydmps.dmp_discrete import DMPs_discrete

        def make(i):
            dmp = DMPs_discrete(n_dmps=2, n_bfs=cfg.n_kernels, dt=1.0 / (n_t - 1), ax=cfg.alpha_x)
            dmp.ay, dmp.by = np.full(2, cfg.alpha_z), np.full(2, cfg.beta)
            dmp.h = kernel_widths(cfg)
            return dmp

        pdmps = [make(i) for i in range(n_demos)]

        def pydmps_fit():
            for dmp, yy in zip(pdmps, y, strict=True):
                dmp.imitate_path(y_des=yy.T.copy())
            return pdmps

        methods["pydmps"] = pydmps_fit
    return methods, (t_np, y)


def fit_errors(fitted: dict, cfg, demos, k: int = 8) -> dict:
    """Largest distance (px) of each method's fit, rolled out by itself, from the first
    ``k`` demonstrations."""
    t_np, y = demos
    out = {}
    for name, res in fitted.items():
        worst = 0.0
        for i in range(min(k, len(y))):
            if name == "fused":
                ours = rollout(res[i].to_torch(), torch.as_tensor(t_np[i]), cfg).numpy()
            elif name == "movement_primitives":
                res[i].dt_ = float(t_np[i, 1] - t_np[i, 0])
                ours = res[i].open_loop()[1][: len(t_np[i])]
            else:
                res[i].reset_state()
                steps = res[i].rollout(timesteps=len(t_np[i]) - 1)[0]
                ours = np.concatenate([res[i].y0[None], steps])
            worst = max(worst, float(np.linalg.norm(ours - y[i], axis=-1).max()))
        out[name] = worst
    return out


# ---------------------------------------------------------------------------------------


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", default="1,128,4096", help="batch sizes, comma-separated")
    ap.add_argument("--dtypes", default="float32,float64", help="float32 and/or float64")
    ap.add_argument("--peers", default=",".join(PEERS), help=f"any of {','.join(PEERS)}")
    ap.add_argument("--rounds", type=int, default=3, help="alternated rounds per group")
    ap.add_argument("--fast-calls", type=int, default=5, help="calls per round under 20 ms")
    ap.add_argument("--time-stamps", type=int, default=301, help="T per trajectory")
    ap.add_argument(
        "--per-trajectory", type=int, default=64, help="samples the per-trajectory peers run"
    )
    ap.add_argument("--prodmp-steps", type=int, default=1000, help="ProDMP table steps per tau")
    ap.add_argument("--fit-demos", type=int, default=1000, help="demonstrations to fit (0: none)")
    ap.add_argument("--fit-rounds", type=int, default=2, help="alternated rounds of the fits")
    ap.add_argument(
        "--threads", type=int, default=0, help="torch threads, the fused kernels' cap (0: default)"
    )
    args = ap.parse_args(argv)
    args.batch = [int(b) for b in args.batch.split(",")]
    names = [s for s in args.peers.split(",") if s]
    unknown = sorted(set(names) - set(PEERS))
    if unknown:
        ap.error(f"unknown peers {unknown}; known: {sorted(PEERS)}")
    args.peers = names
    args.dtypes = [getattr(torch, s) for s in args.dtypes.split(",")]
    return args


def main(argv=None) -> dict:
    args = parse_args(argv)
    before = torch.get_num_threads()
    if args.threads:
        torch.set_num_threads(args.threads)
    try:
        return run(args)
    finally:
        torch.set_num_threads(before)


def run(args) -> dict:
    cfg = DMPConfig()
    peers, missing = installed(args.peers)
    print(_machine.describe())
    for name in missing:
        print(f"not installed, skipped: {LABELS[name]} (pip install {PEERS[name][1]})")
    cache = {("batch", b): make_batch(b=b, t_count=args.time_stamps)[1:] for b in args.batch}
    results = {}
    started = time.perf_counter()
    for backward in (False, True):
        for dtype in args.dtypes:
            for b in args.batch:
                methods = methods_for(b, dtype, backward, cfg, peers, args, cache)
                results[backward, dtype, b] = time_group(methods, args)
                mode = "forward + backward" if backward else "forward"
                print(f"  timed {mode}, {str(dtype)[6:]}, B = {b} "
                      f"({time.perf_counter() - started:.0f} s)", flush=True)  # fmt: skip
    print(
        f"timings took {time.perf_counter() - started:.0f} s; load average at the end "
        f"{_machine.load_average()}"
    )
    b_acc = max(args.batch)
    forward64 = results.get((False, torch.float64, b_acc))
    errors = accuracy(forward64[1], cfg, *cache["batch", b_acc]) if forward64 else {}
    grads = gradient_agreement(cfg, peers, cache, b_acc) if torch.float64 in args.dtypes else {}
    print_tables(results, errors, grads, args, b_acc)
    fits = run_fits(cfg, peers, args) if args.fit_demos else {}
    print(f"load average at the end: {_machine.load_average()}")
    return {"results": results, "errors": errors, "gradients": grads, "fits": fits}


def print_tables(results, errors, grads, args, b_acc):
    names = ["fused", *[n for n in PEERS if n in args.peers]]
    for backward in (False, True):
        for dtype in args.dtypes:
            mode = "forward + backward of sum(y^2)" if backward else "forward"
            print(
                f"\n{mode}, {str(dtype)[6:]}, T = {args.time_stamps}, median of "
                f"{args.rounds} rounds (range), peers as time / img2dmp fused's"
            )
            head = f"{'method':28s}" + "".join(f"{f'B = {b}':>22s}" for b in args.batch)
            extra = not backward and dtype == torch.float64
            if extra:
                head += f"  {f'max err vs solve_ivp (B={b_acc})':>30s}"
            if backward and dtype == torch.float64:
                head += f"  gradient vs img2dmp's (B={b_acc}, max rel. diff)"
            print(head)
            for name in names:
                cells = []
                for b in args.batch:
                    per_round = results[backward, dtype, b][0]
                    if name not in per_round:
                        cells.append("-")
                    elif name == "fused":
                        cells.append(f"{statistics.median(per_round[name]) * 1e3:.3f} ms")
                    else:
                        cells.append(ratio_text(per_round, name))
                if all(c == "-" for c in cells):
                    continue
                line = f"{LABELS[name]:28s}" + "".join(f"{c:>22s}" for c in cells)
                if extra and name in errors:
                    line += f"  {errors[name]:30.1e}"
                if backward and dtype == torch.float64:
                    line += f"  {grads.get(name, '')}"
                print(line)


def run_fits(cfg, peers, args) -> dict:
    methods, demos = fit_methods(cfg, peers, args.fit_demos, args.time_stamps)
    per_round, outs = interleaved(methods, args.fit_rounds, 1)
    errs = fit_errors(outs, cfg, demos)
    print(
        f"\nfitting {args.fit_demos} demonstrations (T = {args.time_stamps}), median of "
        f"{args.fit_rounds} rounds; max distance of the fit from the first 8 demonstrations"
    )
    for name in methods:
        sec = statistics.median(per_round[name])
        rel = "" if name == "fused" else ratio_text(per_round, name)
        print(f"{LABELS[name]:28s} {sec * 1e3:10.1f} ms {rel:>22s} {errs[name]:10.2e} px")
    return {"per_round": per_round, "errors": errs}


if __name__ == "__main__":
    main()
