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
