"""The first minute on a fresh machine: the wheel installed into a new virtual
environment, then ``img2dmp predict`` of a sample image, timed from its first run.

Steps (issue 34's target: the first prediction in under 2 s, no training, no data):

1. ``pip wheel --no-deps`` of this checkout (its size printed; target < 10 MB);
2. a new virtual environment in a temporary folder, the wheel installed into it with its
   dependencies (torch pinned to the version this environment has, so that pip takes the
   CPU build it already holds rather than a CUDA one);
3. ``img2dmp predict examples/samples/digit_3.png`` in that environment, from a folder
   outside the checkout, with ``XDG_CACHE_HOME`` pointing at an empty folder: the first
   run (nothing cached: the DMP response table is solved and saved, Python's bytecode was
   compiled by pip) and ``--runs`` more, each a whole process; ``--backend torch`` once
   more at the end for comparison.

The prediction is checked, not only timed: its DMP file is read back and its path must
lie on the digit's ink (the fit score ``path_on_ink`` >= 0.8).

Run: ``.venv/bin/python benchmarks/bench_first_run.py [--runs 5] [--keep DIR]``
(about 1-3 minutes, most of it pip).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _machine

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "samples" / "digit_3.png"
TARGET_S = 2.0
WHEEL_TARGET_MB = 10.0


def sh(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    """Run ``cmd``; its stderr in the error when it fails."""
    proc = subprocess.run(cmd, capture_output=True, text=True, **kw)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed:\n{proc.stderr[-3000:]}")
    return proc


def timed(cmd: list[str], **kw) -> tuple[float, subprocess.CompletedProcess]:
    t0 = time.perf_counter()
    proc = sh(cmd, **kw)
    return time.perf_counter() - t0, proc


def torch_pin() -> str:
    """``torch==X`` of this environment's torch (the CPU build pip has locally)."""
    from importlib.metadata import version

    return f"torch=={version('torch')}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="timed runs after the first")
    ap.add_argument("--keep", metavar="DIR", help="build in DIR and keep it (default: a temp dir)")
    args = ap.parse_args()
    work = Path(args.keep or tempfile.mkdtemp(prefix="img2dmp-first-run-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        print(_machine.describe())
        t0 = time.perf_counter()
        sh([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(work), str(ROOT)])
        wheel = next(work.glob("img2dmp-*.whl"))
        mb = wheel.stat().st_size / 1e6
        verdict = "ok" if mb < WHEEL_TARGET_MB else "LARGER"
        print(f"wheel {wheel.name}: {mb:.2f} MB (target < {WHEEL_TARGET_MB:g} MB) {verdict}")
        venv = work / "venv"
        sh([sys.executable, "-m", "venv", str(venv)])
        py = venv / "bin" / "python"
        sh([str(py), "-m", "pip", "install", "-q", str(wheel), torch_pin()])
        print(f"fresh environment with the wheel installed in {time.perf_counter() - t0:.0f} s")
        cache, out = work / "xdg-cache", work / "out"
        cache.mkdir(exist_ok=True)
        env = {"PATH": f"{venv / 'bin'}:/usr/bin:/bin", "HOME": str(work),
               "XDG_CACHE_HOME": str(cache)}  # fmt: skip
        cmd = [str(venv / "bin" / "img2dmp"), "predict", str(SAMPLE), "--out", str(out), "--force"]
        first, _ = timed(cmd, cwd=work, env=env)
        doc = json.loads((out / "digit_3_dmp.json").read_text())
        on_ink = doc["fit"]["path_on_ink"]
        later = [timed(cmd, cwd=work, env=env)[0] for _ in range(args.runs)]
        torch_s, _ = timed(cmd + ["--backend", "torch"], cwd=work, env=env)
        print(f"\nimg2dmp predict {SAMPLE.name} (shipped model, its card's refinement)")
        print(f"  first run on the fresh environment  {first:6.2f} s  (target < {TARGET_S:g} s) "
              f"{'ok' if first < TARGET_S else 'SLOWER'}")  # fmt: skip
        med = statistics.median(later)
        print(f"  next {args.runs} runs  min {min(later):.2f}  median {med:.2f}  "
              f"max {max(later):.2f} s")  # fmt: skip
        print(f"  --backend torch once               {torch_s:6.2f} s")
        print(f"  the path on the ink: {on_ink:.3f} ({'ok' if on_ink >= 0.8 else 'OFF THE INK'})")
        print(f"load average at the end {_machine.load_average()} (1/5/15 min)")
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
