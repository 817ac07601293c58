"""experiments/page_reading.py: the matching of found to true characters, and the ink
measures of real photos, on hand-made cases."""

from __future__ import annotations

import numpy as np


def test_a_character_is_found_only_when_one_box_covers_it_alone(experiment_script):
    pr = experiment_script("page_reading")
    true = [(0, 0, 10, 20), (12, 0, 22, 20), (30, 0, 40, 20), (50, 0, 60, 20)]
    found = [
        (0, 0, 10, 20),  # exact
        (12, 0, 40, 20),  # the second and third merged: neither counts
        (50, 0, 55, 20),  # half of the fourth ...
        (55, 0, 60, 20),  # ... and its other half: split, does not count
    ]
    assert pr.match(found, true) == {0: 0}
    assert pr.match([], true) == {}
    assert pr.match(true, true) == {k: k for k in range(4)}


def test_on_ink_and_written_shares_of_paths_on_a_mask(experiment_script):
    pr = experiment_script("page_reading")
    mask = np.zeros((20, 40), bool)
    mask[10, 5:35] = True  # a horizontal stroke
    along = [np.stack([np.linspace(5, 34, 30), np.full(30, 10.0)], -1)]
    assert pr._on_mask(mask, along) == 1.0
    assert pr._written(mask, along, 1.5) == 1.0
    half = [np.stack([np.linspace(5, 19, 15), np.full(15, 10.0)], -1)]
    assert abs(pr._written(mask, half, 1.5) - 16 / 30) < 0.05
    off = [np.stack([np.linspace(5, 34, 30), np.full(30, 2.0)], -1)]
    assert pr._on_mask(mask, off) == 0.0


def test_a_line_found_too_many_costs_its_characters_not_the_lines_after_it(experiment_script):
    pr = experiment_script("page_reading")
    assert pr.miscounted([21, 21, 22], [21, 21, 22]) == 0
    assert pr.miscounted([21, 21, 22], [2, 21, 21, 22]) == 2  # an extra line of two marks
    assert pr.miscounted([7, 7], [7, 8]) == 1
    # two lines read as one: one line's characters missing, as many extra on the other
    assert pr.miscounted([7, 7], [14]) == 14
    assert pr.miscounted([5], []) == 5


def test_the_segmentation_scan_names_what_became_of_each_character(experiment_script):
    ps = experiment_script("page_segmentation")
    true = [(0, 0, 10, 20), (12, 0, 22, 20), (30, 0, 40, 20), (50, 0, 60, 20), (70, 0, 80, 20)]
    found = [
        (0, 0, 10, 20),  # found
        (12, 0, 22, 20),  # found
        (30, 0, 35, 20),  # the third in two halves: split
        (35, 0, 40, 20),
        (50, 0, 52, 20),  # a sliver of the fourth: missed
        (100, 0, 110, 20),  # on no character: extra
    ]
    classes, extra = ps.classify(found, true)
    assert classes == ["found", "found", "split", "missed", "missed"]
    assert extra == 1
    merged, _ = ps.classify([(0, 0, 22, 20)], true[:2])
    assert merged == ["merged", "merged"]
