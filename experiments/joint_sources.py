"""Which joints to send a real iiwa: the controller's reference, the measured joints, q_d?

``img2dmp write --export-joints FILE`` writes the run's joint trajectory for a
position-controlled iiwa (``--joints reference``, the default, or ``measured``;
docs/ROBOT.md, "The joint trajectory"). For each sample (``--cases``, default all four
of ``examples/samples/``) and control rate (``--rates``, default 240 and 1000 Hz) this
runs ``img2dmp write`` and builds three trajectories from the run's result:

- **reference**: ``JointTrajectory.from_result(result, "reference")``, what ``write``
  exports by default (the controller's q_d moved along the pen to the measured depth);
- **measured**: ``JointTrajectory.from_result(result, "measured")``, the simulated
  arm's joints (``--joints measured``);
- **q_d as solved**: the controller's reference as its IK solved it, at the admittance
  law's commanded height (``log.joint_q_ref_rad``, velocities ``log.joint_qd_ref_rad_s``),
  which ``reference`` corrects.

Each is replayed by joint position control in a fresh cell
(:func:`img2dmp.robot.replay_joint_trajectory`) and measured on the paper, on the
original run's pen-down steps with the DMP's clock running: the ink's distance to the
planned pen-down path (RMS / max, mm; the path densified to 20 um), the share of the
path inked (within ``INK_TOLERANCE_M``, weighted by stroke length), the share of the
steps with the pen down, the contact force's mean over those and its share within
+-20 % of the set force, and the tracking (replayed tip to the commanded point, RMS /
max, mm); and over the whole run, the steps on which the pen touched the paper in one but
not the other (the replay against the run: where it lands and lifts). Of the exported
positions: the peak acceleration (second differences at the control rate, and its
joint), the peak and the 99th percentile of the jerk (third differences, max over the
joints per sample), and ``JointTrajectory.acceleration_peak`` (the JSON's). Of the
run: the jitter of the controller's qdd_d (qd_d's differences) over the writing phase,
its high-frequency part (minus its centred 25 ms box mean): RMS and peak, with the peak
of qdd_d itself; and the same of the measured joints' accelerations.

``write`` is run through the command line (:func:`img2dmp.cli.main`), with its result
kept by wrapping ``img2dmp.commands.write._joint_trajectory`` for the run: the samples
take four paths of ``write`` (a digit model, a stroke model's strokes, a page read by a
digit model, a page read by a stroke model), each with the model's recommended
refinement and the default slowing, which the command sets up from its arguments; the
CLI is the one way to get exactly what a user's ``write`` simulates.

``--out DIR`` gets ``joint_sources.json`` (date, revision, command, CPU, every figure)
and ``joint_sources.md`` (the tables). The simulation is deterministic: a rerun gives the
same figures, the wall times aside. All four samples at both rates take about a minute
and a half on two cores.

    python experiments/joint_sources.py --out /tmp/joints [--cases digit_3,page] [--rates 240]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import sys
import tempfile
import time

import numpy as np

from _provenance import ROOT, cpu_name, format_record, run_record, write_report
from _provenance import markdown_table as _table

#: The samples and the arguments ``img2dmp write`` takes for each (paths relative to the
#: repository's root).
CASES = {
    "digit_3": ("examples/samples/digit_3.png",),
    "character_f": ("examples/samples/character_f.png", "--model", "omniglot-strokes"),
    "page": ("examples/samples/page.jpg", "--page"),
    "letters_page": ("examples/samples/letters_page.png", "--page", "--model", "omniglot-strokes"),
}
RATES_HZ = (240.0, 1000.0)
SOURCES = ("reference", "measured", "q_d as solved")
#: The planned path is densified to this spacing before the ink's distance to it is taken.
PATH_SPACING_M = 2e-5
#: The force's band around the set force (the run's metrics use the same).
FORCE_BAND = 0.2
#: qdd_d's smooth course: its centred box mean over this long.
JITTER_WINDOW_S = 0.025


def written(args: tuple[str, ...], rate_hz: float):
    """``(WritingResult, wall_s)`` of ``img2dmp write ARGS --rate-hz RATE`` (files in a
    temporary folder; the command's own lines swallowed)."""
    import img2dmp.commands.write as write
    from img2dmp.cli import main

    kept = {}
    original = write._joint_trajectory

    def keep(cli_args, result, name, n_inputs):
        kept["result"] = result
        return original(cli_args, result, name, n_inputs)

    argv = [str(ROOT / args[0]), *args[1:], "--rate-hz", f"{rate_hz:g}", "--no-progress"]
    write._joint_trajectory = keep
    try:
        with tempfile.TemporaryDirectory() as folder, contextlib.redirect_stdout(io.StringIO()):
            start = time.perf_counter()
            code = main(["write", *argv, "--out-dir", folder])
            wall_s = time.perf_counter() - start
    finally:
        write._joint_trajectory = original
    if code != 0 or "result" not in kept:
        sys.exit(f"img2dmp write {' '.join(args)} --rate-hz {rate_hz:g}: exit status {code}")
    return kept["result"], wall_s


def trajectories(result) -> dict:
    """The three joint trajectories of a run, by :data:`SOURCES`."""
    from img2dmp.robot import JointTrajectory

    measured = JointTrajectory.from_result(result, "measured")
    log = result.log
    as_solved = dataclasses.replace(
        measured,
        position_rad=np.vstack([result.start_joints_rad, log.joint_q_ref_rad]),
        velocity_rad_s=np.vstack([np.zeros(7), log.joint_qd_ref_rad_s]),
        joints="reference",
    )
    return {
        "reference": JointTrajectory.from_result(result, "reference"),
        "measured": measured,
        "q_d as solved": as_solved,
    }


def planned_path(plan):
    """``(strokes, tree)``: the plan's pen-down strokes (``[n, 2]`` each, metres) and a
    KD-tree of their points densified to :data:`PATH_SPACING_M`."""
    from scipy.spatial import cKDTree

    from img2dmp.robot.strokes import stroke_spans

    strokes = [plan.xy_m[a : b + 1] for a, b in stroke_spans(plan.pen_down)]
    dense = []
    for p in strokes:
        for a, b in zip(p[:-1], p[1:], strict=True):
            n = max(2, int(np.ceil(np.linalg.norm(b - a) / PATH_SPACING_M)) + 1)
            dense.append(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
        dense.append(p[-1:])
    return strokes, cKDTree(np.vstack(dense))


def on_paper(tip_m, force_n, result, path) -> dict:
    """What a run or a replay (tip ``[S, 3]``, force ``[S]``, one per step of the run's
    log) did on the paper, on the run's pen-down steps with the DMP's clock running."""
    from img2dmp.robot.strokes import INK_TOLERANCE_M, coverage, ink_points

    log, (strokes, tree) = result.log, path
    sel = log.in_phase("write") & log.pen_down & ~log.dwell  # [S]
    err_mm = np.linalg.norm(tip_m[sel, :2] - log.cmd_m[sel, :2], axis=1) * 1e3
    ink = ink_points(tip_m[:, :2], force_n > 0)
    to_path_mm = tree.query(ink)[0] * 1e3
    inked = np.array([coverage(p, ink, INK_TOLERANCE_M) for p in strokes])
    lengths = np.array([np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in strokes])
    f, f_set = force_n[sel], float(result.metrics["force_set_n"])
    down = f[f > 0]
    return {
        "track_rms_mm": float(np.sqrt(np.mean(err_mm**2))),
        "track_max_mm": float(err_mm.max()),
        "ink_to_path_rms_mm": float(np.sqrt(np.mean(to_path_mm**2))),
        "ink_to_path_max_mm": float(to_path_mm.max()),
        "inked_share": float(np.sum(inked * lengths) / lengths.sum()),
        "stroke_inked_min": float(inked.min()),
        "pen_down_share": float(np.mean(f > 0)),
        "force_mean_n": float(down.mean()) if len(down) else 0.0,
        "force_std_n": float(down.std()) if len(down) else 0.0,
        "force_max_n": float(f.max()),
        "force_in_band_share": float(np.mean(np.abs(f - f_set) <= FORCE_BAND * f_set)),
        "contact_differs_steps": int(np.sum((force_n > 0) != (log.force_n > 0))),
        "contact_steps": int(np.sum(force_n > 0)),
    }


def smoothness(trajectory) -> dict:
    """Peak acceleration and jerk of the exported positions (finite differences at the
    control rate), and the trajectory's own ``acceleration_peak``."""
    q, dt = trajectory.position_rad, 1.0 / trajectory.control_rate_hz
    qdd = np.abs(np.diff(q, 2, axis=0)) / dt**2  # [N-2, 7]
    jerk = np.abs(np.diff(q, 3, axis=0)).max(axis=1) / dt**3  # [N-3]
    i, j = np.unravel_index(int(np.argmax(qdd)), qdd.shape)
    return {
        "qdd_peak_rad_s2": float(qdd[i, j]),
        "qdd_peak_joint": int(j) + 1,
        "qdd_peak_time_s": float(trajectory.time_s[i + 1]),
        "jerk_peak_rad_s3": float(jerk.max()),
        "jerk_p99_rad_s3": float(np.percentile(jerk, 99)),
        "acceleration_peak": trajectory.acceleration_peak(),
    }


def jitter(qd, dt: float, mask) -> dict:
    """The high-frequency part of the accelerations of velocities ``qd [S, 7]`` (from
    rest; minus their centred :data:`JITTER_WINDOW_S` box mean) on the steps ``mask``."""
    from scipy.ndimage import uniform_filter1d

    qdd = np.diff(np.vstack([np.zeros(7), qd]), axis=0) / dt  # [S, 7]
    n = max(3, round(JITTER_WINDOW_S / dt) | 1)
    smooth = uniform_filter1d(qdd, n, axis=0, mode="nearest")
    high = (qdd - smooth)[mask]
    return {
        "hf_rms_rad_s2": float(np.sqrt(np.mean(high**2))),
        "hf_peak_rad_s2": float(np.abs(high).max()),
        "peak_rad_s2": float(np.abs(qdd[mask]).max()),
    }


def measure(case: str, rate_hz: float) -> dict:
    """Every figure of one sample at one rate (see the module's docstring)."""
    from img2dmp.robot import replay_joint_trajectory

    result, wall_s = written(CASES[case], rate_hz)
    log, dt = result.log, 1.0 / rate_hz
    path = planned_path(result.plan)
    write = log.in_phase("write")
    row = {
        "case": case,
        "args": list(CASES[case]),
        "rate_hz": rate_hz,
        "steps": int(log.n_steps),
        "write_wall_s": round(wall_s, 2),
        "run": on_paper(log.tip_m, log.force_n, result, path),
        "jitter_qdd_d": jitter(log.joint_qd_ref_rad_s, dt, write),
        "jitter_qdd_measured": jitter(log.joint_qd_rad_s, dt, write),
        "sources": {},
    }
    for source, trajectory in trajectories(result).items():
        start = time.perf_counter()
        replay = replay_joint_trajectory(trajectory)
        row["sources"][source] = {
            "replay": on_paper(replay.tip_m, replay.force_n, result, path),
            "replay_wall_s": round(time.perf_counter() - start, 2),
            "exported": smoothness(trajectory),
        }
    return row


def _input(row: dict) -> str:
    first, *rest = row["args"]
    return "`" + " ".join([first.rsplit("/", 1)[-1], *rest]) + "`"


def _rate(row: dict) -> str:
    return f"{row['rate_hz'] / 1000:g} kHz" if row["rate_hz"] >= 1000 else f"{row['rate_hz']:g} Hz"


def summary_cells(row: dict) -> list:
    """docs/ROBOT.md's table: reference / measured (ink), reference / measured / q_d as
    solved (force, peak acceleration, jerk p99)."""
    s = row["sources"]
    ref, meas, qd = (s[k]["replay"] for k in SOURCES)
    ink = [f"{p['ink_to_path_rms_mm']:.3f} / {p['ink_to_path_max_mm']:.3f}" for p in (ref, meas)]
    force = " / ".join(f"{p['force_mean_n']:.2f}" for p in (ref, meas, qd))
    acc = " / ".join(f"{s[k]['exported']['qdd_peak_rad_s2']:.1f}" for k in SOURCES)
    jerk = " / ".join(f"{s[k]['exported']['jerk_p99_rad_s3']:.0f}" for k in SOURCES)
    return [_input(row), _rate(row), *ink, force, acc, jerk]


def source_cells(row: dict, source: str) -> list:
    p, e = row["sources"][source]["replay"], row["sources"][source]["exported"]
    a = e["acceleration_peak"]
    return [
        _input(row), _rate(row), source,
        f"{p['ink_to_path_rms_mm']:.3f} / {p['ink_to_path_max_mm']:.3f}",
        f"{p['track_rms_mm']:.3f} / {p['track_max_mm']:.3f}",
        f"{p['pen_down_share']:.3f}", f"{p['inked_share']:.3f}",
        f"{p['force_mean_n']:.2f} ± {p['force_std_n']:.2f} ({p['force_max_n']:.2f})",
        f"{p['force_in_band_share']:.3f}",
        f"{p['contact_differs_steps']} of {p['contact_steps']}",
        f"{e['qdd_peak_rad_s2']:.2f} (joint {e['qdd_peak_joint']})",
        f"{abs(a['acceleration_rad_s2']):.2f}",
        f"{e['jerk_peak_rad_s3']:.0f} / {e['jerk_p99_rad_s3']:.0f}",
    ]  # fmt: skip


def jitter_cells(row: dict) -> list:
    cells = [_input(row), _rate(row), row["steps"], f"{row['write_wall_s']:.1f}"]
    for key in ("jitter_qdd_d", "jitter_qdd_measured"):
        j = row[key]
        cells.append(f"{j['hf_rms_rad_s2']:.3f} / {j['hf_peak_rad_s2']:.2f} / "
                     f"{j['peak_rad_s2']:.2f}")  # fmt: skip
    return cells


def markdown(report: dict) -> str:
    rows = report["rows"]
    out = [f"Joint sources: {format_record(report['run'])}; CPU {report['cpu']}", ""]
    out += ["Replayed by position control; ink to the planned pen-down path RMS / max; "
            "force, peak acceleration and jerk p99 of the exported positions: reference / "
            "measured / q_d as solved:", ""]  # fmt: skip
    out += _table(["input", "rate", "ink to path, reference (mm)", "ink to path, measured (mm)",
                   "force N", "peak acceleration (rad/s²)", "jerk p99 (rad/s³)"],
                  [summary_cells(r) for r in rows])  # fmt: skip
    out += ["Every source: ink to path and tracking RMS / max (mm), shares of the pen-down "
            "steps with the pen down and of the path inked, force mean ± std (max) and "
            "share in ±20 % of the set force, steps touching in the replay or the run but "
            "not both (of the replay's touching steps), peak acceleration of the positions "
            "(2nd differences) and acceleration_peak (of the velocities), jerk peak / p99:",
            ""]  # fmt: skip
    out += _table(["input", "rate", "source", "ink to path", "tracking", "pen down", "inked",
                   "force N", "in band", "contact ≠ run", "qdd peak", "acceleration_peak",
                   "jerk"],
                  [source_cells(r, s) for r in rows for s in SOURCES])  # fmt: skip
    out += ["The run's accelerations over the writing, high-frequency RMS / high-frequency "
            "peak / peak (rad/s²; high frequency: minus the centred 25 ms mean):", ""]  # fmt: skip
    out += _table(["input", "rate", "steps", "write s", "qdd_d (controller)",
                   "measured joints"], [jitter_cells(r) for r in rows])  # fmt: skip
    return "\n".join(out)


def _choices(text: str, known, what: str) -> list:
    names = [t.strip() for t in text.split(",") if t.strip()]
    bad = [n for n in names if n not in known]
    if bad or not names:
        raise ValueError(f"{what}: unknown {bad or text!r}; choose from {', '.join(known)}")
    return names


def _rates(text: str) -> list[float]:
    try:
        rates = [float(t) for t in text.split(",")]
    except ValueError:
        raise ValueError(f"--rates takes numbers separated by commas, got {text!r}") from None
    if not rates or not all(np.isfinite(r) and r > 0 for r in rates):
        raise ValueError(f"--rates must be > 0 Hz, got {text!r}")
    return rates


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="folder for joint_sources.json and .md")
    p.add_argument("--cases", default=",".join(CASES),
                   help=f"samples, comma-separated (default: {','.join(CASES)})")  # fmt: skip
    p.add_argument("--rates", default=",".join(f"{r:g}" for r in RATES_HZ),
                   help="control rates in Hz, comma-separated (default: 240,1000)")  # fmt: skip
    args = p.parse_args(argv)
    try:
        cases = _choices(args.cases, CASES, "--cases")
        rates = _rates(args.rates)
    except ValueError as e:
        p.error(str(e))
    report = {"run": run_record(__file__, argv), "cpu": cpu_name(), "rows": []}
    print(format_record(report["run"]), f"\nCPU: {report['cpu']}", flush=True)
    start = time.perf_counter()
    for case in cases:
        for rate in rates:
            row = measure(case, rate)
            report["rows"].append(row)
            print("| " + " | ".join(summary_cells(row)) + " |", flush=True)
    report["wall_s"] = round(time.perf_counter() - start, 1)
    write_report(args.out, "joint_sources", report, markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
