"""experiments/joint_sources.py: the exported joints' smoothness and jitter measures, and
one sample written and its three joint trajectories replayed (needs pybullet)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from img2dmp.robot import available
from img2dmp.robot.joints import JointTrajectory


def test_smoothness_reads_a_cubic_s_acceleration_and_jerk(experiment_script):
    mod = experiment_script("joint_sources")
    rate = 100.0
    t = np.arange(201) / rate
    q = np.zeros((len(t), 7))
    q[:, 2] = 0.5 * t**3  # qdd = 3 t, jerk = 3, on joint 3 alone
    traj = JointTrajectory(t, q, np.gradient(q, t, axis=0), control_rate_hz=rate)
    got = mod.smoothness(traj)
    assert got["qdd_peak_joint"] == 3
    assert got["qdd_peak_rad_s2"] == pytest.approx(3 * t[-2], rel=1e-6)  # central difference
    assert got["jerk_p99_rad_s3"] == pytest.approx(3.0, rel=1e-5)
    assert got["jerk_peak_rad_s3"] == pytest.approx(3.0, rel=1e-5)


def test_jitter_is_the_part_off_the_smooth_course(experiment_script):
    mod = experiment_script("joint_sources")
    dt = 1e-3
    t = np.arange(2000) * dt
    qdd = np.zeros((len(t), 7))
    qdd[:, 0] = 2.0 * np.sin(2 * np.pi * t)  # slow: followed by the 25 ms mean
    qd = np.cumsum(qdd, axis=0) * dt
    inner = np.zeros(len(t), dtype=bool)
    inner[100:-100] = True
    smooth = mod.jitter(qd, dt, inner)
    assert smooth["hf_peak_rad_s2"] < 0.01 and smooth["peak_rad_s2"] > 1.9
    qdd[:, 1] = 0.5 * (-1.0) ** np.arange(len(t))  # a jolt every step
    jolted = mod.jitter(np.cumsum(qdd, axis=0) * dt, dt, inner)
    assert jolted["hf_peak_rad_s2"] == pytest.approx(0.5, rel=0.1)


def test_an_unknown_case_is_one_line_naming_it(experiment_script, tmp_path, capsys):
    mod = experiment_script("joint_sources")
    with pytest.raises(SystemExit) as e:
        mod.main(["--out", str(tmp_path), "--cases", "digit_3,digit_9"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "digit_9" in err and "Traceback" not in err


@pytest.mark.skipif(not available(), reason="pybullet is not installed (img2dmp[robot])")
def test_one_sample_s_reference_replays_on_the_path_at_the_set_force(experiment_script, tmp_path):
    mod = experiment_script("joint_sources")
    assert mod.main(["--out", str(tmp_path), "--cases", "digit_3", "--rates", "240"]) == 0
    report = json.loads((tmp_path / "joint_sources.json").read_text())
    assert (tmp_path / "joint_sources.md").read_text().count("digit_3.png") == 5
    (row,) = report["rows"]
    assert row["rate_hz"] == 240 and row["steps"] > 100
    got = {k: v["replay"] for k, v in row["sources"].items()}
    for source in ("reference", "measured"):
        assert got[source]["force_mean_n"] == pytest.approx(5.0, abs=0.5)
        assert got[source]["inked_share"] > 0.95 and got[source]["pen_down_share"] > 0.95
    # q_d as solved sits at the commanded height, below the pen's depth: it presses harder
    assert got["q_d as solved"]["force_mean_n"] > 6.5
    assert got["reference"]["ink_to_path_max_mm"] < got["measured"]["ink_to_path_max_mm"]
