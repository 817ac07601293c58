"""experiments/neighbour_paths.py on made-up circles whose writers are known."""

from __future__ import annotations

import numpy as np

from img2dmp.data.store import DigitData


def _circle(start: float, clockwise: bool, radius: float = 8.0, t_count: int = 60):
    """A circle round (14, 14) from angle ``start``, either way round."""
    a = start + np.linspace(0, 2 * np.pi, t_count) * (1 if clockwise else -1)
    return np.stack([14 + radius * np.cos(a), 14 + radius * np.sin(a)], axis=1)


def _data(paths, images, split) -> DigitData:
    n = len(paths)
    return DigitData(
        images=np.asarray(images, np.float32),
        trajectories=np.asarray(paths, np.float32),
        times=np.tile(np.linspace(0, 1, len(paths[0])), (n, 1)).astype(np.float32),
        labels=np.zeros(n, np.int64),
        params=np.zeros((n, 55), np.float32),
        fit_error_px=np.zeros(n, np.float32),
        split=np.asarray(split, np.uint8),
    )


def test_the_shape_oracle_finds_the_same_curve_and_the_direction_is_what_is_left(
    experiment_script,
):
    mod = experiment_script("neighbour_paths")
    rng = np.random.default_rng(0)
    # Training: the test's ring written from 12 start angles, all counter-clockwise, and
    # 12 smaller rings; every image random. The test writer goes round the other way,
    # and its image is a copy of a small ring's.
    starts = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    paths = [_circle(s, clockwise=False) for s in starts]
    paths += [_circle(s, clockwise=False, radius=4.0) for s in starts]
    paths += [_circle(starts[3], clockwise=True)]
    images = rng.uniform(0, 1, (25, 28, 28))
    images[24] = images[20]
    data = _data(paths, images, [0] * 24 + [2])
    tables, oracle_rows = mod.references(data.select_split(0), data.select_split(2), candidates=24)
    assert oracle_rows.shape == (1,) and oracle_rows[0] < 12  # one of the big rings

    err, cham = tables["path error (px), image neighbours, as written"]
    assert err.shape == (1, 16)
    assert cham[0] > 3.0  # the nearest image's writer drew the small ring
    written, cham = tables["path error (px), shape oracle, as written"]
    assert cham[0] < 0.3  # the oracle's first drew the test's ring (0.4 px resampling)...
    assert written[0, :12].min() > 2.0  # ...but none went round the test writer's way
    either, _ = tables["path error (px), shape oracle, either direction"]
    # Reversed, the ring started at starts[3] is the test path, among the 12 rings.
    assert either[0, :12].min() < 0.05
    timed, _ = tables["Table I's error (px), shape oracle"]
    assert timed.shape == (1, 16) and timed[0, :12].min() > 2.0


def test_tables_are_left_out_where_the_time_grids_differ(experiment_script):
    mod = experiment_script("neighbour_paths")
    paths = [_circle(s, clockwise=False) for s in (0.0, 1.0, 2.0)]
    data = _data(paths, np.zeros((3, 28, 28)), [0, 0, 2])
    data.times[1] *= 1.5
    tables, _ = mod.references(data.select_split(0), data.select_split(2))
    assert not any(title.startswith("Table I") for title in tables)
    err, _ = tables["path error (px), image neighbours, as written"]
    assert err.shape == (1, 2)  # as many hypotheses as there are training samples


def _arc_points(paths, n=64):
    from img2dmp.metrics import resample_by_arc_length

    return resample_by_arc_length(np.asarray(paths, float), n)


def test_a_path_moved_onto_the_curve_keeps_its_own_order(experiment_script):
    mod = experiment_script("neighbour_paths")
    ref = _arc_points([_circle(0.0, clockwise=False)])[0]
    # Another writer: a wider ring (0.5 px outside) from another start, the other way.
    other = _arc_points([_circle(2.0, clockwise=True, radius=8.5)])
    moved = mod.on_curve(ref, other)[0]
    want = _arc_points([_circle(2.0, clockwise=True)])[0]  # the person's ring, that order
    assert np.linalg.norm(moved - want, axis=-1).mean() < 0.1
    assert np.linalg.norm(other[0] - want, axis=-1).mean() > 0.45  # it was moved


def test_geometric_median_and_medoids(experiment_script):
    mod = experiment_script("neighbour_paths")
    a, b = np.zeros((5, 2)), np.full((5, 2), 3.0)
    # Two paths of three agree: the geometric median is theirs (the mean would not be).
    assert np.abs(mod.geometric_median(np.stack([a, a, b])) - a).max() < 1e-6
    # Two groups of writers. One medoid: the one nearest to all (2, toward the far group).
    x = np.array([0.0, 0.1, 0.2, 5.0, 5.1])
    cost = np.abs(x[:, None] - x[None])
    assert mod.k_medoids(cost, 1).tolist() == [2]
    # Two: the greedy choice (2, then 3) is mended by a swap into each group's middle.
    assert sorted(mod.k_medoids(cost, 2).tolist()) == [1, 3]
    assert len(mod.k_medoids(cost, 9)) == 5  # no more medoids than candidates


def test_known_curve_scores_the_majority_order_and_one_path_per_writer(experiment_script):
    mod = experiment_script("neighbour_paths")
    ref = _arc_points([_circle(0.0, clockwise=False)])  # [1, n, 2]
    same = _circle(0.0, clockwise=False, radius=8.3)  # the person's order, a wider ring
    other = _circle(3.0, clockwise=True, radius=7.8)  # the other way, from elsewhere
    hyp = _arc_points([same, same, same, other])[None]  # [1, 4, n, 2]
    writers = np.array([[0, 1, 2, 3]])
    err = mod.known_curve(ref, hyp, writers, pool=4)
    ks = list(mod.KS)
    assert err.shape == (1, len(ks))
    assert err[0, 0] < 0.1  # three writers of four agree with the person
    # Writer 7's two copies (nearest in shape) enter a pool of 2 once, so writer 8's
    # order, the person's, is in it too.
    other2 = _circle(3.0, clockwise=True, radius=7.9)
    copies = _arc_points([other, other2, same])[None]
    per_writer = mod.known_curve(ref, copies, np.array([[7, 7, 8]]), pool=2)
    assert per_writer[0, ks.index(2)] < 0.1
    as_rows = mod.known_curve(ref, copies, np.array([[0, 1, 2]]), pool=2)
    assert as_rows[0, ks.index(2)] > 2.0
    # Moved onto a shrunken curve instead of the person's, the same order scores worse.
    small = _arc_points([_circle(0.0, clockwise=False, radius=6.0)])
    assert mod.known_curve(ref, hyp, writers, curve=small, pool=4)[0, 0] > 1.5


def test_writers_are_read_from_the_rows_record(experiment_script):
    mod = experiment_script("neighbour_paths")
    paths = [_circle(s, clockwise=False) for s in (0.0, 1.0, 2.0, 3.0)]
    data = _data(paths, np.zeros((4, 28, 28)), [0, 2, 0, 0])
    assert mod.writers_of(data.select_split(0)).tolist() == [0, 1, 2]  # rows, not recorded
    data.meta = {"rows": {"mnist_index": [5, 5, 9, 9]}}
    assert mod.writers_of(data).tolist() == [5, 5, 9, 9]
    # A part of a data set read from a file knows its rows there.
    data.origin = "made-up.safetensors"
    assert mod.writers_of(data.select_split(0)).tolist() == [5, 9, 9]
    # A part made in memory does not: every row its own writer rather than a wrong one.
    data.origin = None
    assert mod.writers_of(data.select_split(0)).tolist() == [0, 1, 2]


def test_known_curve_with_time_stamps_keeps_the_pool_s_timing(experiment_script):
    mod = experiment_script("neighbour_paths")
    u = np.linspace(0, 1, 60)

    def ring(phase, radius=8.0):  # counter-clockwise from angle 0, along phase(u) in [0, 1]
        a = -2 * np.pi * phase
        return np.stack([14 + radius * np.cos(a), 14 + radius * np.sin(a)], axis=1)

    person = ring(u)[None]  # [1, T, 2]: even speed
    even, slow_start = ring(u, 8.3), ring(u**2, 8.3)  # the same order, two timings
    ref = _arc_points(person)
    for pool_paths, timing_agrees in (([even] * 3 + [slow_start], True), ([slow_start] * 4, False)):
        train_t = np.asarray(pool_paths)
        hyp = _arc_points(train_t)[None]
        idx, writers = np.arange(4)[None], np.arange(4)[None]
        untimed = mod.known_curve(ref, hyp, writers, pool=4)[0, 0]
        timed = mod.known_curve(ref, hyp, writers, pool=4, timed=(person, train_t, idx))[0, 0]
        assert untimed < 0.1  # the order is the person's either way
        assert (timed < 0.1) == timing_agrees  # the timing only where most writers share it
