"""experiments/metric_readings.py on hand-made errors."""

from __future__ import annotations

import numpy as np


def test_a_constant_offset_reads_as_its_four_reductions(experiment_script):
    mod = experiment_script("metric_readings")
    demo = np.zeros((2, 5, 2))
    y = demo + np.array([3.0, 4.0])  # every point 5 px off: 3 in x, 4 in y
    r = mod.readings(y, demo)
    assert np.allclose(r["mean Euclidean distance (ours)"], 5.0)
    assert np.allclose(r["mean absolute error per coordinate"], 3.5)
    assert np.allclose(r["RMS distance"], 5.0)
    assert np.allclose(r["RMS per coordinate"], np.sqrt(12.5))


def test_the_readings_part_where_errors_vary_over_time(experiment_script):
    mod = experiment_script("metric_readings")
    demo = np.zeros((1, 2, 2))
    y = np.array([[[0.0, 0.0], [0.0, 2.0]]])  # 0 px, then 2 px off in y
    r = mod.readings(y, demo)
    assert np.allclose(r["mean Euclidean distance (ours)"], 1.0)
    assert np.allclose(r["mean absolute error per coordinate"], 0.5)
    assert np.allclose(r["RMS distance"], np.sqrt(2.0))
    assert np.allclose(r["RMS per coordinate"], 1.0)
