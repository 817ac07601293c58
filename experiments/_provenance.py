"""When, at which revision and by which command an experiment ran, to go with its results.

A dated table in ``experiments/RESULTS.md`` can be traced when the run that made it
recorded these three things beside its numbers, and the CPU it ran on. The experiment
scripts import this module from their own directory (Python puts a script's directory
on ``sys.path``); it also writes their reports and markdown tables.
"""

from __future__ import annotations

import datetime as _dt
import json
import shlex
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _git(root: Path, *args: str) -> subprocess.CompletedProcess | None:
    try:
        return subprocess.run(
            ["git", *args], cwd=root, capture_output=True, text=True, timeout=10, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None


def git_revision(root: Path = ROOT) -> str:
    """``git rev-parse --short HEAD`` in ``root``, with ``+changes`` when tracked files
    differ from it (the run's code is then not that revision's), or ``"unknown"``
    without git or a repository."""
    head = _git(root, "rev-parse", "--short", "HEAD")
    if head is None or head.returncode != 0 or not head.stdout.strip():
        return "unknown"
    diff = _git(root, "diff", "--quiet", "HEAD", "--")
    changed = diff is not None and diff.returncode == 1
    return head.stdout.strip() + ("+changes" if changed else "")


def run_record(script: str, argv: list[str]) -> dict[str, str]:
    """``{"date", "revision", "command"}`` of this run of ``experiments/<script>``.

    ``date`` is UTC, ISO 8601 to the second; ``command`` is the command line that
    repeats the run from the repository's root, with ``argv`` as given.
    """
    return {
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "revision": git_revision(),
        "command": shlex.join(["python", f"experiments/{Path(script).name}", *argv]),
    }


def format_record(record: dict) -> str:
    """One line for a results file or the terminal (results made before runs were recorded
    have an empty record)."""
    if not record:
        return "date, revision and command not recorded"
    date, rev, cmd = (record.get(k, "unknown") for k in ("date", "revision", "command"))
    return f"{date}, revision {rev}: `{cmd}`"


def write_report(out, name: str, report: dict, text: str | None = None) -> None:
    """``report`` as ``OUT/NAME.json`` and, when given, ``text`` as ``OUT/NAME.md`` (then
    also printed, with the run's ``wall_s`` after it); the folder made, each file written
    whole (a temporary file beside it, then renamed)."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    files = [(f"{name}.json", json.dumps(report, indent=1))]
    files += [(f"{name}.md", text)] if text is not None else []
    for file, content in files:
        tmp = folder / f".{file}.tmp"
        tmp.write_text(content)
        tmp.replace(folder / file)
    if text is not None:
        print(text + (f"({report['wall_s']:.0f} s)" if "wall_s" in report else ""))


def cpu_name() -> str:
    """The CPU's model name (``/proc/cpuinfo``), or ``"unknown"``."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown"


def markdown_table(head: list[str], rows: list[list]) -> list[str]:
    """A markdown table's lines, then a blank one."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    return lines + ["| " + " | ".join(str(v) for v in r) + " |" for r in rows] + [""]
