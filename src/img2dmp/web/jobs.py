"""Robot runs for the web API: the simulated KUKA iiwa writes a DMP in its own process.

Each job is a folder ``JOBS_DIR/<id>/`` holding what it writes (here the checked DMP
document, ``dmp.json``, written through :mod:`img2dmp.data.dmpfile`; a page's job, in
:mod:`.page_jobs`, its page document), then the outputs under fixed names (:data:`JOB_FILES`
for a DMP), the process's output (``job.log``) and its outcome (``result.json``). A job
runs in a process of its own (multiprocessing, "forkserver": a fresh Python started once,
which forks each run), so that pybullet never holds up the server's predictions; at most
``max_jobs`` run at once and the others wait in order, whatever they write. The fork
server is started with Ctrl-C ignored, and so are the runs it forks: Ctrl-C stops the
server, which ends them, instead of printing each one's traceback. The running process
reports through a shared array of doubles (:data:`SHARE`: the progress, 0-1;
:data:`BEGUN`: the characters of a page begun); a failure is one line in ``error``.
"""

from __future__ import annotations

import collections
import json
import math
import multiprocessing
import multiprocessing.forkserver
import os
import secrets
import shutil
import sys
import tempfile
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from .._files import atomic_write_text
from .._processes import children_ignore_interrupts
from ..data.dmpfile import FORMAT, VERSION, DMPFile, check_dmp_document, write_dmp_document
from ..predict import STROKES_FORMAT
from .errors import WebError, one_line, show

#: The outputs of a job, by the key of ``files`` in ``GET /api/jobs/{id}``.
JOB_FILES = {"paper": "paper.png", "animation": "animation.gif", "log": "log.csv"}
#: The image a DMP's job shows under its path in ``paper.png`` (in the job's folder, not
#: served), and the most pixels a side it may have.
PAPER_IMAGE, MAX_PAPER_IMAGE_PX = "image.png", 1024
#: Most jobs waiting to start; more are refused (429).
MAX_WAITING = 20
#: Simulated seconds between two frames of the animation (each shown that long).
FRAME_INTERVAL_S = 0.1
#: Most frames of a run's video (a 12 s time lapse); a longer run is filmed at longer
#: intervals (:func:`frame_interval_s`).
MAX_VIDEO_FRAMES = 120
#: Seconds of a DMP's run besides its tau (the approach and the lift), for the estimates.
RUN_EXTRA_S = 2.0
#: The controller's rate (that of ``img2dmp write``), for the progress estimate.
CONTROL_RATE_HZ = 240.0
#: Share of the progress bar the simulation fills; the pictures the rest.
SIMULATION_SHARE = 0.9
#: The places in a job's shared report: the progress (0-1), the characters begun.
SHARE, BEGUN = 0, 1
#: The error of a job the server's stop ended or forgot (and its folder's last line).
INTERRUPTED = "interrupted: the server stopped"
_POLL_S = 0.1


def run_job(job_dir: str, options: dict, report) -> None:
    """Write the job's DMP with the simulated arm (the child process's whole work).

    Reads ``job_dir/dmp.json``, writes the outputs of :data:`JOB_FILES` (the animation only
    with ``options["video"]``, a frame every ``options["frame_interval_s"]`` simulated
    seconds) and ``result.json`` (:func:`run_in_job_dir`), the hypothesis of rank
    ``options["hypothesis"]``. ``report[SHARE]``: the progress (0-1).
    """
    hypothesis = options["hypothesis"]
    interval_s = options.get("frame_interval_s", FRAME_INTERVAL_S) if options["video"] else None
    run_in_job_dir(job_dir, lambda d: {"summary": _write(d, hypothesis, interval_s, report)})


def run_in_job_dir(job_dir: str, work) -> None:
    """Run ``work(Path(job_dir))`` in a job's process, its output going to ``job.log``,
    and write its outcome, ``result.json``: ``{"status": "done", **work's dict}`` or
    ``{"status": "failed", "error": one line}``."""
    d = Path(job_dir)
    # The job's folder is new (made by submit); O_NOFOLLOW all the same: a log is never
    # written through a link.
    log = os.open(d / "job.log", os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW, 0o644)
    os.dup2(log, 1)
    os.dup2(log, 2)
    try:
        outcome = {"status": "done", **work(d)}
    except (ValueError, OSError) as e:  # the DMP cannot be written, or a file failed
        outcome = {"status": "failed", "error": one_line(str(e) or type(e).__name__)}
    except RuntimeError as e:  # the simulated arm failed (e.g. never settled)
        outcome = {"status": "failed", "error": one_line(f"simulation failed: {e}")}
    except Exception as e:
        traceback.print_exc()
        outcome = {"status": "failed", "error": one_line(f"internal error: {e!r}")}
    atomic_write_text(d / "result.json", json.dumps(outcome))
    sys.stdout.flush()
    sys.stderr.flush()


def _write(d: Path, hypothesis: int, interval_s: float | None, report) -> list[str]:
    from ..robot import (
        load_dmp_json,
        plot_writing,
        save_log_csv,
        save_video,
        summary_lines,
        write_dmp,
    )

    params, config, size = load_dmp_json(d / "dmp.json", hypothesis=hypothesis)
    image = _paper_image(d / PAPER_IMAGE)
    steps = {"done": 0}

    def advance(n: int) -> None:
        steps["done"] += n
        report[SHARE] = SIMULATION_SHARE * min(1.0, steps["done"] / steps["expected"])

    def on_tempo(tau_s: float) -> None:  # told again once slowed for the joints
        steps["expected"] = max(1.0, (tau_s + RUN_EXTRA_S) * CONTROL_RATE_HZ)

    on_tempo(float(params.tau))

    result = write_dmp(
        params,
        config,
        size,
        control_rate_hz=CONTROL_RATE_HZ,
        frame_interval_s=interval_s,
        render_size_px=None,
        progress=advance,
        on_tempo=on_tempo,
    )
    report[SHARE] = SIMULATION_SHARE
    name = f"hypothesis {hypothesis}"
    plot_writing(result, d / JOB_FILES["paper"], image, title=f"{name}: KUKA iiwa writes")
    save_log_csv(result, d / JOB_FILES["log"])
    lines = summary_lines(name, result)
    if interval_s is not None:
        save_video(result, d / JOB_FILES["animation"], FRAME_INTERVAL_S)
        if interval_s > FRAME_INTERVAL_S:
            lines.append(f"video: a time lapse, a frame every {interval_s:g} simulated s, "
                         f"{interval_s / FRAME_INTERVAL_S:.3g} times as fast")  # fmt: skip
    report[SHARE] = 1.0
    return lines


def _paper_image(path: Path):
    """The ink (``[H, W]``, 1 = ink) of the image a job was given (:func:`check_image`),
    None without one."""
    if not path.is_file():
        return None
    import numpy as np
    from PIL import Image

    with Image.open(path) as im:
        return 1.0 - np.asarray(im.convert("L"), dtype=np.float64) / 255.0


def check_image(data_url: str):
    """``POST /api/write``'s ``image`` (a data URL, dark ink on white, e.g. a
    prediction's ``input_image``) as a greyscale PIL image; 422 naming it when it does
    not decode or has more than :data:`MAX_PAPER_IMAGE_PX` pixels a side."""
    from .strokes import decode_data_url

    im = decode_data_url(data_url)
    if max(im.size) > MAX_PAPER_IMAGE_PX:
        raise WebError(422, f"image: {im.size[0]} x {im.size[1]} pixels; the image under the "
                       f"path is at most {MAX_PAPER_IMAGE_PX} a side (a prediction's "
                       "input_image is the model's input)")  # fmt: skip
    return im.convert("L")


def frame_interval_s(duration_s: float) -> float:
    """Simulated seconds between two video frames of a run of about ``duration_s``:
    FRAME_INTERVAL_S, or longer so that it keeps at most MAX_VIDEO_FRAMES."""
    return max(FRAME_INTERVAL_S, math.ceil(100 * duration_s / MAX_VIDEO_FRAMES) / 100)


def plan_write(doc, hypothesis, video: bool) -> tuple[dict, float | None]:
    """``POST /api/write``'s document checked (:func:`check_write`) and its path planned
    as its job will plan it (no simulation), before it is queued: 422 with the library's
    line for a DMP the arm cannot write (more control steps than it writes, e.g. a DMP
    slowed down 10,000 times, or a movement that is not finite). The document and the
    simulated seconds between two frames of its video (None without one):
    :func:`frame_interval_s` of its duration, so that a long DMP is filmed as a time
    lapse instead of filling the memory."""
    from ..robot import PaperMapping, WritingOptions, plan_path

    f = read_document(doc, hypothesis)
    params = f.hypothesis(hypothesis)
    tau = float(params.tau)
    interval_s = frame_interval_s(tau + RUN_EXTRA_S) if video else None
    options = WritingOptions(control_rate_hz=CONTROL_RATE_HZ, frame_interval_s=interval_s,
                             render_size_px=None)  # fmt: skip
    center_m = options.scene_config.paper_center_m
    try:
        options.check_video(tau)
        mapping = PaperMapping(f.image_size, options.writing_height_mm, center_m)
        plan_path(params, f.config, mapping, options.dt_s)
    except ValueError as e:
        raise WebError(422, f"dmp: {e}") from None
    return f.document, interval_s


def check_write(doc, hypothesis) -> dict:
    """The document of ``POST /api/write``, checked as ``img2dmp write --dmp`` checks a
    file (a version-1 document, without ``format`` and ``version``, is converted), with
    the hypothesis of rank ``hypothesis``; 422 naming the field otherwise."""
    return read_document(doc, hypothesis).document


#: What ``POST /api/write`` says of a stroke model's document sent as ``dmp``.
STROKES_ADVICE = ("the arm writes a stroke model's character from strokes_page (the page "
                  "document of its strokes, in POST /api/predict's answer)")  # fmt: skip


def read_document(doc, hypothesis, strokes_advice: str = STROKES_ADVICE) -> DMPFile:
    """:func:`check_write`'s check; the document read (its ``document``: version 2). A
    stroke model's document (``img2dmp-strokes``: several DMPs) is refused with
    ``strokes_advice``."""
    if not isinstance(doc, dict):
        raise WebError(422, f"dmp: must be a DMP document (a JSON object), got {show(doc)}")
    if doc.get("format") == STROKES_FORMAT:
        raise WebError(422, f"dmp: is a stroke model's character ({STROKES_FORMAT}: a DMP "
                       f"per stroke), not one DMP; {strokes_advice}")  # fmt: skip
    if "format" not in doc and "version" not in doc:
        doc = {"format": FORMAT, "version": VERSION, **doc}
    try:
        f = check_dmp_document(doc, "dmp")
        f.hypothesis(hypothesis)
    except ValueError as e:
        raise WebError(422, str(e)) from None
    return f


@dataclass
class Job:
    """One robot run and what is known of it.

    ``target(job_dir, options, report)`` is what its process runs; ``files`` its outputs
    (key of ``files`` in its state: file name); ``characters`` the indices of a page's
    characters it writes, in order (empty for one DMP); ``page`` a page's measures
    (the outcome's ``"page"``).
    """

    id: str
    dir: Path
    kind: str
    target: object
    options: dict
    files: dict
    characters: tuple = ()
    status: str = "queued"
    error: str | None = None
    summary: list = field(default_factory=list)
    page: dict | None = None
    report: object = None
    process: object = None
    last_report: tuple = (0.0, 0.0)
    started_at: float | None = None  # UNIX time
    ended_at: float | None = None


class JobManager:
    """Robot runs, at most ``max_jobs`` at a time, the rest waiting in order.

    Parameters
    ----------
    jobs_dir : path-like or None
        Where the jobs' folders go (None: a temporary folder, removed by :meth:`close`).
    max_jobs : int
        Runs at the same time.
    target : callable
        What the process of a DMP's job runs (:func:`run_job`; picklable, for "spawn").
    """

    def __init__(self, jobs_dir=None, max_jobs: int = 1, target=run_job):
        self._own_dir = jobs_dir is None
        self.dir = Path(tempfile.mkdtemp(prefix="img2dmp-jobs-") if jobs_dir is None else jobs_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.max_jobs = int(max_jobs)
        self.target = target
        self._ctx = multiprocessing.get_context("forkserver")
        # Started here (serve's main thread) rather than with the first run (the jobs'
        # thread, where signal handlers cannot be changed): its runs inherit SIGINT ignored.
        with children_ignore_interrupts():
            multiprocessing.forkserver.ensure_running()
        self._jobs: dict[str, Job] = {}
        self._waiting: collections.deque[Job] = collections.deque()
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def submit(self, doc: dict, hypothesis: int, video: bool,
               interval_s: float | None = FRAME_INTERVAL_S, image=None) -> dict:  # fmt: skip
        """Queue a run of a checked document (:func:`plan_write`), its video's frames
        ``interval_s`` simulated seconds apart, ``image`` (a PIL image of
        :func:`check_image`, or None) under its path in ``paper.png``; its state."""
        interval_s = FRAME_INTERVAL_S if interval_s is None else float(interval_s)
        options = {"hypothesis": hypothesis, "video": bool(video), "frame_interval_s": interval_s}

        def write_input(d: Path) -> None:
            write_dmp_document(d / "dmp.json", doc)
            if image is not None:
                image.save(d / PAPER_IMAGE, format="PNG")

        return self.submit_job("dmp", self.target, options, JOB_FILES, write_input)

    def submit_job(self, kind: str, target, options: dict, files: dict, write_input,
                   characters=()) -> dict:  # fmt: skip
        """Queue a job of any kind (a page's: :mod:`.page_jobs`); its state.
        ``write_input(job_dir)`` writes what its process reads; the rest as :class:`Job`."""
        with self._lock:
            if len(self._waiting) >= MAX_WAITING:
                raise WebError(429, f"{MAX_WAITING} robot runs are waiting already; try later")
            job = Job(secrets.token_hex(8), Path(), kind, target, dict(options), dict(files),
                      tuple(characters))  # fmt: skip
            job.dir = self.dir / job.id
            job.dir.mkdir()
            write_input(job.dir)
            self._jobs[job.id] = job
            self._waiting.append(job)
            state = self._state(job)
        self._ensure_thread()
        self._wake.set()
        return state

    def state(self, job_id: str) -> dict:
        """``GET /api/jobs/{id}``; 404 for an unknown id."""
        with self._lock:
            return self._state(self._job(job_id))

    def file(self, job_id: str, name: str) -> Path:
        """The output ``name`` (one of its ``files``' names) of a job; 404 unless the job
        is known and the file written."""
        with self._lock:
            job = self._job(job_id)
        if name not in job.files.values():
            raise WebError(404, f"name: no job file {show(name)}; the files are "
                           f"{', '.join(job.files.values())}")  # fmt: skip
        path = job.dir / name
        if job.status != "done" or not path.is_file():
            raise WebError(404, f"job {job_id} has no {name} (status {job.status})")
        return path

    def _job(self, job_id: str) -> Job:
        job = self._jobs.get(job_id)
        if job is None:
            raise WebError(404, f"id: no job {show(job_id)}")
        return job

    def _state(self, job: Job) -> dict:
        position = None
        if job.status == "queued":
            position = next(i for i, j in enumerate(self._waiting, start=1) if j is job)
        share, begun = job.last_report
        if job.status == "running" and job.report is not None:
            share, begun = job.report[SHARE], job.report[BEGUN]
        progress = {"queued": 0.0, "done": 1.0}.get(job.status, share)
        files = {
            key: f"/api/jobs/{job.id}/files/{name}"
            if job.status == "done" and (job.dir / name).is_file()
            else None
            for key, name in job.files.items()
        }
        return {"id": job.id, "kind": job.kind, "status": job.status, "position": position,
                "progress": round(float(progress), 4),
                "character": _character(job, int(begun)), "error": job.error,
                "summary": list(job.summary), "files": files, "page": job.page,
                "started_at": job.started_at, "ended_at": job.ended_at}  # fmt: skip

    def _ensure_thread(self) -> None:
        with self._lock:
            if self._thread is None and not self._stop.is_set():
                self._thread = threading.Thread(
                    target=self._run, name="img2dmp-robot-jobs", daemon=True
                )
                self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                self._reap()
                self._start_waiting()
            self._wake.wait(_POLL_S)
            self._wake.clear()

    def _start_waiting(self) -> None:
        running = sum(1 for j in self._jobs.values() if j.status == "running")
        while self._waiting and running < self.max_jobs:
            job = self._waiting.popleft()
            job.report = self._ctx.Array("d", 2, lock=False)  # SHARE, BEGUN
            args = (str(job.dir), job.options, job.report)
            process = self._ctx.Process(target=job.target, args=args, daemon=True)
            try:
                process.start()
            except Exception as e:  # no process: the job fails, the server goes on
                job.status = "failed"
                job.error = one_line(f"the robot process could not start: {e}")
                continue
            job.process, job.status, job.started_at = process, "running", time.time()
            running += 1

    def _reap(self) -> None:
        for job in self._jobs.values():
            if job.status != "running" or job.process.exitcode is None:
                continue
            job.last_report = (float(job.report[SHARE]), float(job.report[BEGUN]))
            code = job.process.exitcode
            job.process.join()
            job.process.close()
            job.process = None
            try:
                outcome = json.loads((job.dir / "result.json").read_text(encoding="utf-8"))
            except (OSError, ValueError):
                why = f"the robot process ended without a result (exit code {code})"
                outcome = {"status": "failed", "error": why}
            job.status = "done" if outcome.get("status") == "done" else "failed"
            job.ended_at = time.time()
            job.error = outcome.get("error")
            job.summary = list(outcome.get("summary", []))
            job.page = outcome.get("page")

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop: end the running processes (the ones started here), forget the waiting
        ones (each folder of these says so: :func:`_mark_interrupted`), remove the jobs'
        folder if it is a temporary one made here."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        with self._lock:
            for job in self._jobs.values():
                if job.process is not None and job.process.exitcode is None:
                    job.process.terminate()
                    job.process.join(timeout_s)
                if job.status in ("queued", "running"):
                    was = job.status
                    job.status, job.error = "failed", INTERRUPTED
                    if not self._own_dir:
                        _mark_interrupted(job.dir, was)
            self._waiting.clear()
        if self._own_dir:
            shutil.rmtree(self.dir, ignore_errors=True)

    def wait(self, job_id: str, timeout_s: float) -> dict:
        """The job's state once it is done or failed (or after ``timeout_s``)."""
        end = time.monotonic() + timeout_s
        while True:
            state = self.state(job_id)
            if state["status"] in ("done", "failed") or time.monotonic() > end:
                return state
            time.sleep(_POLL_S / 2)


def _mark_interrupted(job_dir: Path, was: str) -> None:
    """A job's folder after the server stopped it (``was``: "queued" or "running"): a
    line at the end of its ``job.log`` and its ``result.json`` saying so (the latter
    unless the run wrote its own just before it was ended)."""
    line = f"img2dmp serve: {INTERRUPTED} while the job was {was}; it will not be resumed\n"
    try:
        log = os.open(job_dir / "job.log", os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW,
                      0o644)  # fmt: skip
        with os.fdopen(log, "a", encoding="utf-8") as f:
            f.write(line)
        if not (job_dir / "result.json").exists():
            atomic_write_text(job_dir / "result.json",
                              json.dumps({"status": "failed", "error": INTERRUPTED}))  # fmt: skip
    except OSError:  # the folder is gone or read-only: the stop goes on
        pass


def _character(job: Job, begun: int) -> dict | None:
    """The page's character being written (``number`` of ``of`` in the job's order, and
    its ``index`` in the page), None unless a page's job is writing one."""
    if job.status != "running" or not 1 <= begun <= len(job.characters):
        return None
    return {"number": begun, "of": len(job.characters), "index": job.characters[begun - 1]}


__all__ = [
    "BEGUN",
    "JOB_FILES",
    "MAX_VIDEO_FRAMES",
    "SHARE",
    "Job",
    "JobManager",
    "check_image",
    "check_write",
    "frame_interval_s",
    "plan_write",
    "read_document",
    "run_in_job_dir",
    "run_job",
]
