"""Latency of the command line as a user meets it: whole processes, start to exit.

Times, as separate processes (``subprocess``, several runs in alternation; min / median /
max):

1. ``img2dmp --help`` (target <= 0.5 s);
2. ``img2dmp predict IMAGE`` with the shipped default model and the settings its card
   recommends (30 refinement steps), end to end: Python's start, the imports, loading and
   checking the model, preparing the image, the network, refinement, the rollout and the
   JSON on stdout, on the NumPy backend (``--backend numpy``, what ``auto`` takes on the
   CPU; target <= 1.0 s, issue 33) and on torch (``--backend torch``), side by side, with
   their ratio;
3. the same with ``--model RUN`` for a tiny network trained here (``--run-dir``-style
   models: a 40-sample synthetic data set of one digit, one epoch of the demo's network,
   about 10 s; target <= 1.5 s), with ``--tiny``.

The image is ``examples/samples/digit_3.png``. One untimed run of each command first warms
the caches (numba's compiled code, the DMP response table, the OS's file cache, Python's
bytecode).

Python's bytecode cache: an installed package has its modules compiled (pip compiles them
on install; Python writes the cache of an editable install on first import). Where
``PYTHONDONTWRITEBYTECODE`` is set, as on some CI machines, every process would compile
img2dmp's sources again, about 40 ms a prediction here; the timed commands then run
without it and keep their bytecode in a private folder (``PYTHONPYCACHEPREFIX``), which
the warm-up fills. ``--as-environment`` times them with the environment unchanged.

``--profile`` also prints where one prediction's time goes: the slowest imports
(``python -X importtime``) and the functions with the most cumulative time (cProfile).

Run: ``.venv/bin/python benchmarks/bench_latency.py [--runs 7] [--tiny] [--profile]``
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _machine

NUMPY, TORCH, TINY = "predict (numpy)", "predict (torch)", "predict --model tiny"
TARGETS = {"img2dmp --help": 0.5, NUMPY: 1.0, TORCH: 1.0, TINY: 1.5}
SAMPLE = Path(__file__).resolve().parents[1] / "examples" / "samples" / "digit_3.png"


def img2dmp_command() -> list[str]:
    """The ``img2dmp`` entry point next to this Python, else ``python -m img2dmp``."""
    script = Path(sys.executable).with_name("img2dmp")
    return [str(script)] if script.exists() else [sys.executable, "-m", "img2dmp"]


def run(cmd: list[str], cwd: Path, timeout: float = 300.0, env: dict | None = None) -> float:
    """Seconds from start to exit of ``cmd``; raises with its stderr when it fails."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return seconds


def make_model(work: Path, cli: list[str]) -> tuple[Path, Path]:
    """A tiny trained run directory and one PNG digit in ``work``."""
    import numpy as np
    from PIL import Image
    from safetensors.numpy import load_file

    data = work / "data.safetensors"
    gen = ["generate", "--out", str(data), "--digits", "2", "--per-digit", "40"]
    run(cli + gen + ["--workers", "1", "--no-progress"], work)
    config = Path(__file__).resolve().parents[1] / "src" / "img2dmp" / "configs" / "demo.yaml"
    train = ["train", "--config", str(config), "--data", str(data), "--run-dir", "run"]
    run(cli + train + ["--epochs", "1", "--no-progress"], work)
    image = load_file(str(data))["images"][0]  # ink = 1 on 0
    png = work / "digit.png"
    Image.fromarray((255 * (1 - np.clip(image, 0, 1))).astype(np.uint8)).save(png)
    return work / "run", png


def bytecode_env(work: Path, as_environment: bool) -> tuple[dict, str]:
    """The timed commands' environment and a line saying how Python caches bytecode in it
    (module docstring)."""
    env = dict(os.environ)
    if as_environment or not env.get("PYTHONDONTWRITEBYTECODE"):
        off = env.get("PYTHONDONTWRITEBYTECODE")
        return env, f"bytecode cache: {'off (PYTHONDONTWRITEBYTECODE)' if off else 'on'}"
    del env["PYTHONDONTWRITEBYTECODE"]
    env["PYTHONPYCACHEPREFIX"] = str(work / "pycache")
    return env, (
        "bytecode cache: on, in a private folder (PYTHONDONTWRITEBYTECODE is set here; "
        "--as-environment times without the cache)"
    )


def time_commands(commands: dict[str, list[str]], work: Path, runs: int, env: dict) -> dict:
    """``{name: [seconds]}``: the commands in alternation, ``runs`` rounds."""
    times = {name: [] for name in commands}
    for _ in range(runs):
        for name, cmd in commands.items():
            times[name].append(run(cmd, work, env=env))
    return times


def print_profile(cmd: list[str], work: Path, top: int = 15) -> None:
    """The slowest imports and the most expensive functions of one run of ``cmd``."""
    env = dict(os.environ, PYTHONPROFILEIMPORTTIME="1")
    proc = subprocess.run(cmd, cwd=work, capture_output=True, text=True, env=env)
    rows = []  # (cumulative us, depth, module)
    for line in proc.stderr.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)", line)
        if m:
            rows.append((int(m.group(2)), len(m.group(3)) // 2, m.group(4)))
    print(f"\nslowest imports (cumulative, depth <= 3) of: {' '.join(cmd[-4:])}")
    for us, depth, mod in sorted((r for r in rows if r[1] <= 3), reverse=True)[:top]:
        print(f"  {us / 1e6:6.3f} s  {'  ' * depth}{mod}")
    prof = work / "predict.prof"
    code = [sys.executable, "-m", "cProfile", "-o", str(prof), "-m", "img2dmp", *cmd[-4:]]
    subprocess.run(code, cwd=work, capture_output=True, check=True)
    import pstats

    print(f"\nmost cumulative time in img2dmp's own functions (cProfile, top {top}):")
    stats = pstats.Stats(str(prof))
    stats.sort_stats("cumulative").print_stats(r"/img2dmp/(?!__main__|cli\.py)", top)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7, help="timed runs of each command")
    ap.add_argument("--profile", action="store_true", help="also show where predict's time goes")
    ap.add_argument(
        "--as-environment",
        action="store_true",
        help="time with the environment as it is, even if it turns Python's bytecode cache off",
    )
    ap.add_argument("--tiny", action="store_true", help="also time a tiny run directory")
    args = ap.parse_args()
    cli = img2dmp_command()
    work = Path(tempfile.mkdtemp(prefix="img2dmp-latency-"))
    try:
        print(_machine.describe())
        predict = cli + ["predict", str(SAMPLE)]
        commands = {
            "img2dmp --help": cli + ["--help"],
            NUMPY: predict + ["--backend", "numpy"],
            TORCH: predict + ["--backend", "torch"],
        }
        if args.tiny:
            t0 = time.perf_counter()
            run_dir, png = make_model(work, cli)
            print(f"tiny model trained in {time.perf_counter() - t0:.1f} s ({work})")
            commands[TINY] = cli + ["predict", "--model", str(run_dir), str(png)]
        env, cache = bytecode_env(work, args.as_environment)
        print(cache)
        print(f"image {SAMPLE.name}, the shipped default model with its card's refinement")
        for cmd in commands.values():  # warm-up: numba, the response table, files, bytecode
            run(cmd, work, env=env)
        times = time_commands(commands, work, args.runs, env)
        print(f"\n{args.runs} runs each, as whole processes, in alternation")
        print(f"{'command':30s} {'min (s)':>8s} {'median':>8s} {'max':>8s} {'target':>8s}")
        for name, ts in times.items():
            med = statistics.median(ts)
            verdict = "ok" if med <= TARGETS[name] else "SLOWER"
            print(
                f"{name:30s} {min(ts):8.2f} {med:8.2f} {max(ts):8.2f} "
                f"{TARGETS[name]:7.1f}  {verdict}"
            )
        ratio = statistics.median(times[TORCH]) / statistics.median(times[NUMPY])
        print(f"torch / numpy (medians): {ratio:.2f}x")
        print(f"load average at the end {_machine.load_average()} (1/5/15 min)")
        if args.profile:
            print_profile(commands[NUMPY], work)
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
