"""The arm writes a page read in the browser: ``POST /api/pages/{id}/write`` (docs/WEB.md).

A page's job is a robot job (:mod:`.jobs`: queued with the DMPs' jobs, in its own
process) that writes the whole page document of a page read lately (the
:class:`~.pages.PageStore`'s, every character's DMP) with
:func:`img2dmp.robot.page.write_page`'s two steps, as ``img2dmp write PAGE.json --page``
does:

1. before it is queued, :func:`plan_page_job` checks the document and lays the page out
   (:func:`~img2dmp.robot.page.plan_page`: no simulation), so that a page that does not
   fit the sheet at the width asked for is refused at once with the library's one line
   (naming the widest width that fits);
2. its process (:func:`run_page_job`) plans it again from ``page.json``, slows the
   characters a real iiwa's joints need slower (:func:`expected_steps`, so that the
   progress counts that time) and writes it
   (:func:`~img2dmp.robot.page.write_page_plan`), reporting the characters it begins, then
   writes :data:`PAGE_FILES` and the measures of the page and of every character.

The video is a time lapse of at most :data:`MAX_PAGE_FRAMES` frames, each shown 0.1 s
(as one long DMP's, :func:`~.jobs.frame_interval_s`): a frame costs about 0.09 s to
render and 0.03 s to encode (AMD EPYC, 2 cores shared) and 0.5 MB of memory until the
GIF is written, so a page of a few minutes kept every 0.1 s would take longer to film
than to write and hold gigabytes.

A stroke model's character is written the same way (``POST /api/write`` with
``strokes_page``, :func:`submit_strokes`): its strokes as a page of one line, as
``img2dmp write IMAGE --model STROKE_MODEL`` writes them.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path, PurePath

from .._files import atomic_write_text
from ..robot.page import DEFAULT_WIDTH_MM, STROKE_LIFT_M, TRAVEL_HEIGHT_M
from .errors import WebError
from .jobs import (
    BEGUN,
    CONTROL_RATE_HZ,
    FRAME_INTERVAL_S,
    JOB_FILES,
    MAX_VIDEO_FRAMES,
    SHARE,
    SIMULATION_SHARE,
    frame_interval_s,
    run_in_job_dir,
)

#: The outputs of a page's job, by the key of ``files`` in ``GET /api/jobs/{id}``.
PAGE_FILES = {**JOB_FILES, "characters": "characters.csv"}
#: Most frames of a page's video (a 12 s time lapse); a longer page is kept at longer
#: intervals (:func:`~.jobs.frame_interval_s`, as one DMP's).
MAX_PAGE_FRAMES = MAX_VIDEO_FRAMES
#: The page's totals in the job's answer (:func:`img2dmp.robot.page.page_metrics` and
#: the run's), those of the first lines of ``img2dmp write --page``.
_TOTALS = (
    "characters", "characters_written", "characters_skipped", "width_mm", "height_mm",
    "ink_share", "ink_on_path_share", "placement_error_max_mm", "travel_contact_s",
    "force_mean_n", "force_std_n", "force_set_n", "force_in_band_share",
    "tracking_error_mean_mm", "tracking_error_max_mm", "simulated_s", "control_rate_hz",
)  # fmt: skip


def plan_page_job(text: str, filename: str, width_mm: float | None, skip_flagged: bool,
                  travel_height_m: float = TRAVEL_HEIGHT_M) -> tuple:  # fmt: skip
    """The indices of the characters a job of this page document (its JSON ``text``, named
    ``filename``) writes, in order, from its layout at ``width_mm``; 422 with the
    library's one line when it cannot be written (e.g. it does not fit the sheet)."""
    try:
        plan = _plan(json.loads(text), filename, width_mm, skip_flagged, travel_height_m)
    except ValueError as e:
        raise WebError(422, str(e)) from None
    return tuple(cp.character.index for cp in plan.characters)


def _plan(doc: dict, filename: str, width_mm: float | None, skip_flagged: bool,
          travel_height_m: float = TRAVEL_HEIGHT_M):  # fmt: skip
    from ..robot import WritingOptions, check_page_document, plan_page

    page = check_page_document(doc, filename)
    options = WritingOptions(control_rate_hz=CONTROL_RATE_HZ, render_size_px=None)
    return plan_page(page, options, width_mm=width_mm, skip_flagged=skip_flagged,
                     travel_height_m=travel_height_m)  # fmt: skip


def submit_page(jobs, pages, page_id: str, width_mm: float | None, skip_flagged: bool,
                video: bool):  # fmt: skip
    """Queue the arm writing page ``page_id`` of ``pages`` (404 if not kept) with the
    ``jobs`` manager; the job's state."""
    text, filename = pages.document(page_id)
    width_mm = None if width_mm is None else float(width_mm)  # None: plan_page's default
    options = {"filename": filename, "width_mm": width_mm,
               "skip_flagged": bool(skip_flagged), "video": bool(video)}  # fmt: skip
    return _submit(jobs, "page", text, options)


def submit_strokes(jobs, doc, video: bool) -> dict:
    """Queue the arm writing a stroke model's character with the ``jobs`` manager: ``doc``
    is the page document of its strokes (a prediction's ``strokes_page``,
    :meth:`~img2dmp.predict.StrokePrediction.to_page_document`), written as ``img2dmp
    write`` writes it: each stroke pen down, the pen lifted
    :data:`~img2dmp.robot.page.STROKE_LIFT_M` above the lift height between them, the
    model's frame ``writing_height_mm`` (40 mm) high. The job's state; 422 with the
    library's line for a document that does not check or cannot be written."""
    from ..robot import WritingOptions, check_page_document

    try:
        text = json.dumps(doc, allow_nan=False)
        page = check_page_document(json.loads(text), "strokes_page")
    except ValueError as e:
        raise WebError(422, str(e)) from None
    x0, _, x1, _ = page.written_area_px
    writing = WritingOptions()
    options = {
        "filename": "character.json",
        "width_mm": writing.writing_height_mm * (x1 - x0) / page.image_size_px[1],
        "skip_flagged": False,
        "video": bool(video),
        "travel_height_m": writing.controller_config.lift_height_m + STROKE_LIFT_M,
        "noun": "stroke",
    }
    return _submit(jobs, "strokes", text, options)


def _submit(jobs, kind: str, text: str, options: dict) -> dict:
    """Queue a job of ``kind`` writing the page document ``text`` as ``options`` (those of
    :func:`run_page_job`) say, planned first (422 if it cannot be written); its state."""
    travel_m = options.get("travel_height_m", TRAVEL_HEIGHT_M)
    characters = plan_page_job(text, options["filename"], options["width_mm"],
                               options["skip_flagged"], travel_m)  # fmt: skip
    return jobs.submit_job(
        kind,
        run_page_job,
        options,
        PAGE_FILES,
        lambda d: atomic_write_text(d / "page.json", text),
        characters,
    )


def run_page_job(job_dir: str, options: dict, report) -> None:
    """The process of a page's job: write ``job_dir/page.json`` with the arm
    (:func:`run_in_job_dir`) as ``options`` say: ``filename``, ``width_mm``,
    ``skip_flagged``, ``video`` and, for a stroke model's character, ``travel_height_m``
    and ``noun`` (``"stroke"``: what the summary calls its entries). ``report[SHARE]``:
    the progress (0-1); ``report[BEGUN]``: the characters begun."""
    run_in_job_dir(job_dir, lambda d: _write_page(d, options, report))


def _write_page(d: Path, options: dict, report) -> dict:
    from ..robot import page_summary_lines

    doc = json.loads((d / "page.json").read_text(encoding="utf-8"))
    filename, name = options["filename"], PurePath(options["filename"]).stem
    travel_m, noun = options.get("travel_height_m", TRAVEL_HEIGHT_M), options.get("noun")
    plan = _plan(doc, filename, options["width_mm"], options["skip_flagged"], travel_m)
    plan, expected = expected_steps(plan)
    interval_s = frame_interval_s(expected / CONTROL_RATE_HZ) if options["video"] else None
    plan = dataclasses.replace(
        plan, options=dataclasses.replace(plan.options, frame_interval_s=interval_s)
    )
    result = _run(plan, expected, report)
    report[SHARE] = SIMULATION_SHARE
    # a stroke model's character names its strokes; a page its characters (or strokes)
    what, noun = plan.words() if noun is None else (f"{len(plan.characters)} {noun}s", noun)
    _save_outputs(result, d, f"{name}: KUKA iiwa writes {what}", video=interval_s is not None,
                  owners=plan.entry_owners())  # fmt: skip
    report[SHARE] = 1.0
    speed = None if interval_s is None else interval_s / FRAME_INTERVAL_S
    lines = page_summary_lines(name, result, noun, plan.entry_labels())
    return {"summary": lines, "page": page_measures(result, speed)}


def expected_steps(plan) -> tuple:
    """``(plan, steps)``: the plan readied as it will be written, its characters slowed
    where a real iiwa's joints need it (:func:`~img2dmp.robot.page.ready_page_plan`), and
    about how many control steps it takes, the slowing counted, for the progress."""
    from ..robot import ready_page_plan

    plan = ready_page_plan(plan)
    return plan, max(1, plan.estimated_steps())


def _run(plan, expected: int, report):
    """The simulation of a planned page, reporting its progress and the characters begun."""
    from ..robot import write_page_plan

    steps = [0]

    def advance(n: int) -> None:
        steps[0] += n
        report[SHARE] = SIMULATION_SHARE * min(1.0, steps[0] / expected)

    def begin(_character) -> None:
        report[BEGUN] += 1

    return write_page_plan(plan, progress=advance, on_character=begin)


def _save_outputs(result, d: Path, title: str, video: bool, owners=None) -> None:
    from ..robot import plot_page, save_characters_csv, save_log_csv, save_video

    plot_page(result, d / PAGE_FILES["paper"], title=title)
    save_characters_csv(result, d / PAGE_FILES["characters"], owners)
    save_log_csv(result, d / PAGE_FILES["log"])
    if video:
        # Every frame shown FRAME_INTERVAL_S: a long page plays as a time lapse.
        save_video(result, d / PAGE_FILES["animation"], FRAME_INTERVAL_S)


def page_measures(result, video_speed: float | None) -> dict:
    """The ``"page"`` of a finished page's job: ``totals`` (:func:`page_metrics`' numbers),
    one entry per character in reading order (``index, line, written, flags`` and, when
    written, the numbers of ``characters.csv``), and how many times faster than the
    simulation the video plays (null without a video). Not-a-number is null."""
    from ..robot.outputs import CHARACTERS_CSV_HEADER

    m = result.metrics
    totals = {k: _number(m[k]) for k in _TOTALS}
    chars = []
    for r in result.characters:
        c = r.character
        entry = {"index": c.index, "line": c.line, "written": r.written, "flags": list(c.flags)}
        if r.written:
            entry["strokes"] = len(r.metrics["strokes"])
            entry.update({k: _number(r.metrics[k]) for k in CHARACTERS_CSV_HEADER[8:]})
            entry.update(start_s=_number(r.metrics["start_s"]), end_s=_number(r.metrics["end_s"]))
        chars.append(entry)
    speed = None if video_speed is None else round(float(video_speed), 3)
    return {"totals": totals, "characters": chars, "video_speed": speed}


def _number(value) -> float | int | None:
    """A measure for strict JSON: ints stay ints, NaN and infinities become None."""
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    value = float(value)
    return round(value, 6) if math.isfinite(value) else None


__all__ = [
    "DEFAULT_WIDTH_MM",
    "MAX_PAGE_FRAMES",
    "PAGE_FILES",
    "expected_steps",
    "page_measures",
    "plan_page_job",
    "run_page_job",
    "submit_page",
    "submit_strokes",
]
