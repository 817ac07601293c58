"""experiments/hidden_ends.py: hidden pen ends of the first templates, none in the current."""

from __future__ import annotations

import numpy as np

from img2dmp.data import synthetic as syn
from img2dmp.data.synthetic import SyntheticConfig


def test_closed_zero_hides_both_ends_and_sets_a_floor_the_open_one_does_not(experiment_script):
    mod = experiment_script("hidden_ends")
    cfg, rng = SyntheticConfig(), np.random.default_rng(0)
    start, end, floor = mod.measure(mod.FIRST_TEMPLATES[0], cfg, 40, 16, rng)
    assert start == end == 1.0 and 0.4 < floor < 1.5
    start, end, floor = mod.measure(syn.DIGIT_TEMPLATES[0], cfg, 40, 16, rng)
    assert start == end == 0.0 and floor == 0.0
    # A 9 whose loop closes over its start: the start is hidden, the stem's end is not.
    start, end, floor = mod.measure(mod.FIRST_TEMPLATES[9], cfg, 40, 16, rng)
    assert start > 0.9 and end == 0.0 and floor > 0.1
    assert mod.main(["--samples", "3", "--redraws", "2"]) == 0
