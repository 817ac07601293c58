"""Latency and throughput of ``img2dmp serve``: ``POST /api/predict`` of a drawn digit.

Starts ``img2dmp serve`` (uvicorn) as a separate process on a free port of 127.0.0.1 and
sends it the strokes of a "7" drawn in a 280 x 280 canvas (the Draw page's request), over
keep-alive connections (``http.client``):

(a) ``--requests`` requests one after another, after ``--warmup`` untimed ones: p50, p95
    and max of the round trip (request sent to the whole answer read), next to the
    server's own ``elapsed_ms`` (drawing + preparation + network + rollout) and to
    ``Predictor.predict`` on the same drawn image in this process (one torch thread, as
    the server), with the ratios;
(b) ``--clients`` threads at once, each with its own connection, ``--total`` requests in
    all: throughput, latency under load and the number of errors (an answer other than
    200, or a failed connection).

Target (the issue): p95 <= 50 ms for (a) on 2 cores after warm-up; 0 errors under 50
clients. The model is ``--model RUN``, else ``out/demo/run`` if it exists (what
``make demo`` trains), else a tiny network trained here (one epoch on 40 synthetic
digits, a few seconds; it predicts nonsense, but costs what a small fully connected
network costs); the line ``model:`` says which.

``--refine N`` serves with ``img2dmp serve --refine N`` (0: the network's output as it
is); without it, as the model recommends (a shipped model's card: ``digits-real`` 30).

Run: ``.venv/bin/python benchmarks/bench_web.py [--model RUN] [--refine N] [--requests
200] [--clients 50] [--total 2000]``
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from img2dmp.commands._args import one_thread

one_thread()  # before NumPy starts its BLAS threads: compute as the server does, on one
import numpy as np  # noqa: E402

import _machine  # noqa: E402

#: The "7" of the Draw page: strokes of [x, y, t_ms] in a 280 x 280 canvas.
SEVEN = [[[70.0, 60.0, 0.0], [110.0, 59.0, 20.0], [150.0, 58.0, 40.0], [185.0, 60.0, 60.0],
          [215.0, 62.0, 80.0], [195.0, 105.0, 110.0], [170.0, 150.0, 140.0],
          [150.0, 192.0, 170.0], [130.0, 235.0, 200.0]]]  # fmt: skip
CANVAS = [280, 280]
TARGET_P95_MS = 50.0
DEMO_RUN = Path("out") / "demo" / "run"


def img2dmp_command() -> list[str]:
    """The ``img2dmp`` entry point next to this Python, else ``python -m img2dmp``."""
    script = Path(sys.executable).with_name("img2dmp")
    return [str(script)] if script.exists() else [sys.executable, "-m", "img2dmp"]


def tiny_model(work: Path) -> Path:
    """A run directory of a tiny network (one epoch on 40 synthetic digits)."""
    from img2dmp.data.store import save_dataset
    from img2dmp.data.synthetic import generate_dataset
    from img2dmp.training import TrainConfig, train

    save_dataset(work / "d.safetensors", generate_dataset(4, seed=5, progress=False))
    cfg = TrainConfig.from_dict(
        {
            "model": {"encoder_layers": [48, 20], "decoder_layers": [35]},
            "data": {"path": str(work / "d.safetensors")},
            "optim": {"epochs": 1, "batch_size": 16},
            "threads": 1,
            "progress": False,
        }
    )
    train(cfg, work / "tiny" / "run")
    return work / "tiny" / "run"


def choose_model(given: str | None, work: Path) -> tuple[Path, str]:
    """The run directory to serve and a phrase saying where it came from."""
    if given:
        return Path(given), f"{given} (--model)"
    if DEMO_RUN.is_dir():
        return DEMO_RUN, f"{DEMO_RUN} (the demo's)"
    t0 = time.perf_counter()
    run = tiny_model(work)
    return run, f"a tiny network trained here in {time.perf_counter() - t0:.1f} s ({run})"


def start_server(run: Path, work: Path, refine: int | None = None, timeout_s: float = 120.0):
    """``img2dmp serve --model RUN --port 0 [--refine N]``; the process and its (host,
    port)."""
    cmd = img2dmp_command() + ["serve", "--model", str(run), "--port", "0",
                               "--data-dir", str(work / "recordings")]  # fmt: skip
    cmd += [] if refine is None else ["--refine", str(refine)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = [None]
    reader = threading.Thread(target=lambda: line.__setitem__(0, proc.stdout.readline()))
    reader.start()
    reader.join(timeout_s)
    if not line[0] or "listening on http://" not in line[0]:
        proc.kill()
        raise RuntimeError(f"img2dmp serve did not start: {line[0]!r} {proc.stderr.read()[-2000:]}")
    address = line[0].split("http://")[1].split("/")[0]
    host, port = address.rsplit(":", 1)
    return proc, (host, int(port))


def stop_server(proc) -> None:
    """Ctrl+C, then wait (kill after 30 s)."""
    proc.send_signal(signal.SIGINT)
    try:
        proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()


def connect(address, timeout_s: float = 120.0) -> http.client.HTTPConnection:
    """A keep-alive connection with TCP_NODELAY, as browsers open them: http.client sends
    a request's headers and body in two writes, and without it the body waits for the
    server's delayed ACK (40 ms on Linux)."""
    conn = http.client.HTTPConnection(*address, timeout=timeout_s)
    conn.connect()
    conn.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return conn


def post(conn: http.client.HTTPConnection, body: bytes) -> tuple[int, bytes]:
    """``POST /api/predict`` on a kept-alive connection: status and the answer's bytes."""
    conn.request("POST", "/api/predict", body=body, headers={"Content-Type": "application/json"})
    r = conn.getresponse()
    return r.status, r.read()


def sequential(address, body: bytes, n: int, warmup: int) -> tuple[list, list]:
    """Round trips (ms) and the server's ``elapsed_ms`` of ``n`` requests in a row."""
    conn = connect(address)
    try:
        for _ in range(warmup):
            status, data = post(conn, body)
            if status != 200:
                raise RuntimeError(f"warm-up request answered {status}: {data[:300]!r}")
        trips, server = [], []
        for _ in range(n):
            t0 = time.perf_counter()
            status, data = post(conn, body)
            trips.append(1e3 * (time.perf_counter() - t0))
            if status != 200:
                raise RuntimeError(f"request answered {status}: {data[:300]!r}")
            server.append(json.loads(data)["elapsed_ms"])
        return trips, server
    finally:
        conn.close()


def concurrent(address, body: bytes, clients: int, total: int) -> dict:
    """``total`` requests from ``clients`` threads at once: wall time, latencies, errors."""
    counts = [total // clients + (1 if i < total % clients else 0) for i in range(clients)]
    latencies, errors, lock = [], [], threading.Lock()
    start = threading.Barrier(clients + 1)

    def client(n: int) -> None:
        conn = connect(address)
        start.wait()
        for _ in range(n):
            t0 = time.perf_counter()
            try:
                status, data = post(conn, body)
            except (OSError, http.client.HTTPException) as e:
                status, data = None, repr(e).encode()
                conn.close()
                conn = connect(address)
            with lock:
                latencies.append(1e3 * (time.perf_counter() - t0))
                if status != 200:
                    errors.append(f"{status}: {data[:200]!r}")
        conn.close()

    threads = [threading.Thread(target=client, args=(n,)) for n in counts]
    for t in threads:
        t.start()
    start.wait()
    t0 = time.perf_counter()
    for t in threads:
        t.join()
    return {"wall_s": time.perf_counter() - t0, "latencies": latencies, "errors": errors}


def in_process(run: Path, n: int, warmup: int, refine: int | None = None) -> list:
    """``Predictor.predict`` (ms) of the drawn "7" in this process, refined as the server
    refines (``refine``, else as the model recommends), one thread as the server."""
    from img2dmp import load_model
    from img2dmp.web.strokes import render_strokes

    model = load_model(run) if refine is None else load_model(run, refine=refine)
    image = render_strokes([np.array(s) for s in SEVEN], tuple(CANVAS))
    for _ in range(warmup):
        model.predict(image, clean=False)  # a drawing, as the server reads it
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        model.predict(image, clean=False)
        times.append(1e3 * (time.perf_counter() - t0))
    return times


def quantiles(ms: list) -> tuple[float, float, float]:
    """p50, p95 and max of a list of milliseconds."""
    a = np.asarray(ms, dtype=np.float64)
    return float(np.percentile(a, 50)), float(np.percentile(a, 95)), float(a.max())


def report(trips: list, server: list, local: list) -> None:
    """Table (a): round trip, the server's time, in-process predict, ratios."""
    rows = {"HTTP round trip": quantiles(trips), "server elapsed_ms": quantiles(server),
            "Predictor.predict in-process": quantiles(local)}  # fmt: skip
    print(f"\n(a) {len(trips)} sequential requests, one keep-alive connection")
    print(f"{'':30s} {'p50 ms':>8s} {'p95 ms':>8s} {'max ms':>8s}")
    for name, (p50, p95, top) in rows.items():
        print(f"{name:30s} {p50:8.2f} {p95:8.2f} {top:8.2f}")
    (t50, t95, _), (l50, l95, _) = rows["HTTP round trip"], rows["Predictor.predict in-process"]
    print(f"ratio round trip / in-process: p50 {t50 / l50:.2f}x, p95 {t95 / l95:.2f}x; "
          f"overhead p50 {t50 - l50:.2f} ms")  # fmt: skip
    verdict = "ok" if t95 <= TARGET_P95_MS else "SLOWER than the target"
    print(f"target p95 <= {TARGET_P95_MS:g} ms: {t95:.2f} ms, {verdict}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", metavar="RUN", help="run directory to serve")
    ap.add_argument("--requests", type=int, default=200, help="sequential requests (a)")
    ap.add_argument("--warmup", type=int, default=20, help="untimed requests first")
    ap.add_argument("--clients", type=int, default=50, help="concurrent clients (b)")
    ap.add_argument("--total", type=int, default=2000, help="requests of (b) in all")
    ap.add_argument("--refine", type=int, metavar="N",
                    help="serve with --refine N (default: as the model recommends)")  # fmt: skip
    args = ap.parse_args(argv)
    print(_machine.describe())
    work = Path(tempfile.mkdtemp(prefix="img2dmp-bench-web-"))
    proc = None
    try:
        run, said = choose_model(args.model, work)
        refine = "as the model recommends" if args.refine is None else args.refine
        print(f"model: {said}; refinement steps: {refine}")
        body = json.dumps({"strokes": SEVEN, "canvas": CANVAS}).encode()
        proc, address = start_server(run, work, args.refine)
        print(f"server: {' '.join(img2dmp_command())} serve on {address[0]}:{address[1]}, "
              f"pid {proc.pid}; request {len(body)} bytes")  # fmt: skip
        trips, server = sequential(address, body, args.requests, args.warmup)
        load = concurrent(address, body, args.clients, args.total)
        stop_server(proc)
        proc = None
        local = in_process(run, args.requests, args.warmup, args.refine)  # server stopped
        report(trips, server, local)
        p50, p95, top = quantiles(load["latencies"])
        print(f"\n(b) {args.clients} clients at once, {args.total} requests in all")
        rate = args.total / load["wall_s"]
        print(f"throughput {rate:.1f} requests/s over {load['wall_s']:.2f} s; latency p50 "
              f"{p50:.1f} ms, p95 {p95:.1f} ms, max {top:.1f} ms")  # fmt: skip
        errors = load["errors"]
        print(
            f"errors: {len(errors)}" + (f" (first: {errors[0]})" if errors else " (target 0: ok)")
        )
        print(f"load average at the end {_machine.load_average()} (1/5/15 min)")
        return 1 if load["errors"] else 0
    finally:
        if proc is not None:
            stop_server(proc)
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
