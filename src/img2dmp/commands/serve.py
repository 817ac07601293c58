"""Serve the browser front end: draw a digit and see the predicted movement, have the
simulated KUKA iiwa write it, trace images to record new demonstrations (docs/WEB.md).

The pages are at http://HOST:PORT/ (Draw), /page (Page: every character of a photo of a
page) and /record (Record); the HTTP API under /api, its reference at /docs. Predictions
run in the server's thread pool, one at a time per model (torch on one thread); each
robot run in a process of its own, at most --max-jobs at once, the others waiting in
turn. Recordings are written as DATA_DIR/image_<n>.json in the recorded-path format,
atomically and under a lock on DATA_DIR, so `img2dmp prepare --recorded DATA_DIR --mnist
DIR` reads them; an existing recording is replaced only when the page asks to. Nothing is
written outside --data-dir and --jobs-dir.

The server answers only to the names it is bound to (127.0.0.1, localhost, [::1], --host)
and those given with --allowed-host: a request for any other Host is refused (400), so a
web page that makes its own name point at 127.0.0.1 (DNS rebinding) cannot use it; a
request that changes something (a recording, a robot run) must come from the server's own
pages (its Origin), else 403.

Needs the optional extra: pip install -e '/path/to/img2dmp[web]' (and img2dmp[robot] for the arm).

Without --model the default shipped model (digits-real, img2dmp models) answers, refined
as its card recommends (--refine 30) unless --refine says otherwise; a run directory is
read as its training configuration's reading recommends (docs/TRAINING.md).

  img2dmp serve
  img2dmp serve --model digits-real --model out/demo/run --mnist ../shared/data/mnist \\
      --data-dir recordings/
"""

from __future__ import annotations

import argparse
import importlib.util
import ipaddress
import os
import signal
import sys
import threading

from . import _args

HELP = "the browser front end: draw, predict, write with the robot, record"
#: Largest photo of a page, MB (img2dmp.web.pages.PAGE_UPLOAD_MB; a literal: this module
#: must not import torch).
PAGE_UPLOAD_MB = 64.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--model",
        action="append",
        default=[],
        metavar="RUN|NAME",
        help="run directory, checkpoint or shipped model's name to serve; repeat for "
        "several, the first is the default (none given: the shipped model "
        f"{_args.DEFAULT_MODEL_NAME})",
    )
    source = p.add_mutually_exclusive_group()
    source.add_argument(
        "--mnist", metavar="DIR", help="the Record page shows MNIST's training images (IDX files)"
    )
    source.add_argument(
        "--images", metavar="DIR", help="the Record page shows this folder's PNG/JPEG files"
    )
    p.add_argument("--data-dir", default="recordings", metavar="DIR",
                   help="where recordings are written (created if missing)")  # fmt: skip
    p.add_argument("--host", default="127.0.0.1", help="bind address (loopback only by default)")
    p.add_argument(
        "--allowed-host",
        action="append",
        default=[],
        metavar="NAME",
        help="a name browsers may use for this server besides 127.0.0.1, localhost, [::1] and "
        "--host (the Host header; others are refused, against DNS rebinding); repeat for "
        "several, e.g. the machine's LAN name or address with --host 0.0.0.0",
    )
    p.add_argument("--port", type=_args.int_at_least(0, 65535), default=8000,
                   help="port (0: any free one, printed)")  # fmt: skip
    p.add_argument("--max-jobs", metavar="N", type=_args.int_at_least(1), default=1,
                   help="robot runs at the same time; more wait in a queue")  # fmt: skip
    p.add_argument("--max-upload-mb", metavar="X", type=_args.positive_float, default=4.0,
                   help="larger request bodies are refused (413)")  # fmt: skip
    p.add_argument("--max-page-mb", metavar="X", type=_args.positive_float,
                   default=PAGE_UPLOAD_MB, help="larger photos of a page (the Page view's "
                   "upload) are refused (413)")  # fmt: skip
    _args.add_refine(p)
    p.add_argument("--jobs-dir", metavar="DIR",
                   help="where robot runs write their pictures (default: a temporary "
                   "folder, removed at the end)")  # fmt: skip
    p.add_argument("--verbose", action="store_true", help="log every request (access log)")


def _models(args) -> list[str]:
    """``--model`` as given, or the default shipped model."""
    return list(args.model) if args.model else [_args.model_or_default(None)]


def _socket(host: str, port: int):
    """A listening TCP socket on ``host:port`` (``OSError`` naming it if taken)."""
    import socket

    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as e:
        sock.close()
        raise OSError(e.errno, f"cannot listen on {host}:{port}: {e.strerror}") from None
    sock.listen(128)
    sock.set_inheritable(True)
    return sock


def _loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


def run(args: argparse.Namespace) -> int:
    if not all(importlib.util.find_spec(m) for m in ("fastapi", "uvicorn", "fastapi_offline")):
        print("img2dmp serve: error: install img2dmp[web] (pip install -e '/path/to/img2dmp[web]')",
              file=sys.stderr)  # fmt: skip
        return 2
    _args.one_thread()  # one image at a time: one thread is the fastest (before NumPy)
    import uvicorn

    from ..web import create_app

    for path in ([args.mnist] if args.mnist else []) + ([args.images] if args.images else []):
        if not os.path.isdir(path):
            raise NotADirectoryError(f"{path} is not a directory")
    app = create_app(
        _models(args),
        mnist=args.mnist,
        images=args.images,
        data_dir=args.data_dir,
        max_jobs=args.max_jobs,
        max_upload_mb=args.max_upload_mb,
        max_page_mb=args.max_page_mb,
        jobs_dir=args.jobs_dir,
        refine=args.refine,
        refine_unfamiliar=args.refine_unfamiliar,
        allowed_hosts=[args.host, *args.allowed_host],
    )
    _args.one_thread()  # torch too, if the models brought it in (--backend torch)
    from ..web.models import warm_up

    for model in app.state.img2dmp.models.values():
        warm_up(model)
    sock = _socket(args.host, args.port)
    level = "info" if args.verbose else "warning"
    config = uvicorn.Config(app, log_level=level, access_log=args.verbose, timeout_keep_alive=30)
    host, port = sock.getsockname()[:2]
    shown = f"[{host}]" if ":" in host else host
    if not _loopback(host):
        names = ", ".join(args.allowed_host) or "none: give --allowed-host NAME"
        print(f"img2dmp serve: note: listening on {host}: other machines can reach this server "
              f"by the names it answers to ({host}, {names})")  # fmt: skip
    server = _server_class(uvicorn)(config)
    previous = _stop_on_signals(server)  # first: a stop may come as soon as the line is out
    try:
        print(f"img2dmp serve: listening on http://{shown}:{port}/ (Ctrl+C stops)", flush=True)
        server.run(sockets=[sock])
    finally:
        sock.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print("img2dmp serve: stopped", flush=True)
    return 0


def _server_class(uvicorn):
    """uvicorn's server without its own signal handlers: serve's (:func:`_stop_on_signals`)
    stand from before the listening line to the end."""
    import contextlib

    class Server(uvicorn.Server):
        @contextlib.contextmanager
        def capture_signals(self):  # (uvicorn's installs none outside the main thread)
            yield

    return Server


def _stop_on_signals(server) -> dict:
    """Ctrl+C and SIGTERM (``kill``, a service manager) ask ``server`` to stop, at any
    moment from here on: before it has started it stops as soon as it has, a second one
    stops it without waiting for its connections. No KeyboardInterrupt is raised, so a
    stop takes one path whenever it comes (a Ctrl+C right after the listening line,
    raised while uvicorn and asyncio were still setting up, once left the process running
    in a CI run), and SIGTERM does not kill the process before its clean-up (no
    "stopped", temporary folders left). The handlers before, to put back; none outside
    the main thread."""
    if threading.current_thread() is not threading.main_thread():
        return {}

    def stop(signum, frame):
        if server.should_exit:
            server.force_exit = True
        server.should_exit = True

    return {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
