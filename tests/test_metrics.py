"""Timing-free path measures (img2dmp.metrics) against hand-made cases."""

from __future__ import annotations

import numpy as np
import pytest

from img2dmp.data.render import render_paths
from img2dmp.metrics import (
    CLOSED_DIGITS,
    area_ratio,
    bilinear,
    chamfer_px,
    enclosed_area_px2,
    on_ink_share,
    path_error_px,
    resample_by_arc_length,
    start_error_px,
    width_ratio,
)


def circle(r, n=200, centre=(20.0, 20.0), turns=1.0):
    u = np.linspace(0, 2 * np.pi * turns, n)
    return np.stack([centre[0] + r * np.cos(u), centre[1] + r * np.sin(u)], -1)  # [n, 2]


def line(x0, x1, y, n=50):
    return np.stack([np.linspace(x0, x1, n), np.full(n, float(y))], -1)  # [n, 2]


def pen(path, down=1.0):
    return np.concatenate([path, np.full((len(path), 1), down)], -1)  # [n, 3]


def two_strokes():
    """Two 10 px strokes (y = 10 and y = 30) joined by a 20-point pen-up travel."""
    travel = np.linspace([15.0, 10.0], [5.0, 30.0], 22)[1:-1]
    return np.concatenate([pen(line(5, 15, 10)), pen(travel, 0.0), pen(line(5, 15, 30))])


def old_path_error_px(y_a, y_b, n_points=64):
    """path_error_px as it was in img2dmp.evaluate before the move (d = 2)."""
    a = np.asarray(y_a, dtype=np.float64)[..., :2]
    b = np.asarray(y_b, dtype=np.float64)[..., :2]

    def fractions(paths):
        seg = np.linalg.norm(np.diff(paths, axis=1), axis=-1)
        length = np.concatenate([np.zeros((len(paths), 1)), np.cumsum(seg, axis=1)], axis=1)
        return length / np.maximum(length[:, -1:], 1e-12)

    def at(path, f_path, f):
        keep = np.concatenate([[True], np.diff(f_path) > 0])
        return np.stack([np.interp(f, f_path[keep], path[keep, k]) for k in range(2)], -1)

    def by_arc(paths):
        grid = np.linspace(0.0, 1.0, n_points)
        return np.stack([at(p, f, grid) for p, f in zip(paths, fractions(paths), strict=True)])

    return np.linalg.norm(by_arc(a) - by_arc(b), axis=-1).mean(-1)


def test_area_ratio_of_a_circle_and_one_of_half_its_radius():
    big, small = circle(8.0)[None], circle(4.0, centre=(15.0, 22.0))[None]
    for method in ("winding", "shoelace"):
        assert area_ratio(small, big, method)[0] == pytest.approx(0.25, rel=0.01)
        assert enclosed_area_px2(big, method)[0] == pytest.approx(np.pi * 64, rel=0.01)
    assert area_ratio(big, big)[0] == pytest.approx(1.0, rel=1e-3)
    assert CLOSED_DIGITS == (0, 6, 8, 9)


def test_the_loops_of_an_eight_both_count():
    # One stroke, two loops turning opposite ways: the signed areas cancel, |w| does not.
    s = np.linspace(0, 2 * np.pi, 400)
    eight = np.stack([20 + 5 * np.sin(2 * s), 20 + 8 * np.sin(s)], -1)[None]
    one_loop = eight[:, :200]  # the upper loop alone (closed by its own ends)
    area = enclosed_area_px2(eight)[0]
    assert area == pytest.approx(2 * enclosed_area_px2(one_loop, "shoelace")[0], rel=0.01)
    assert enclosed_area_px2(eight, "shoelace")[0] < 0.01 * area
    with pytest.raises(ValueError, match="method"):
        enclosed_area_px2(eight, "pixels")


def test_a_path_and_itself():
    rng = np.random.default_rng(1)
    paths = rng.normal(size=(5, 40, 2)).cumsum(1) + 20  # [5, 40, 2]
    assert np.all(chamfer_px(paths, paths) == 0)
    assert np.all(path_error_px(paths, paths) == 0)
    assert np.all(start_error_px(paths, paths) == 0)
    assert np.allclose(width_ratio(paths, paths), 1.0)


def test_a_line_and_the_same_line_shifted_across():
    a = line(5, 30, 12)[None]
    b = a + [0.0, 1.5]
    assert chamfer_px(a, b)[0] == pytest.approx(1.5, abs=1e-12)
    assert path_error_px(a, b)[0] == pytest.approx(1.5, abs=1e-12)
    # a line twice as long: from a, 1.5 px everywhere; from it, 1.5 px on its first half
    # and sqrt(t^2 + 1.5^2) at t = 0 .. 25 px past a's end on its second half
    longer = line(5, 55, 13.5)[None]
    t = np.linspace(0, 25, 100001)
    beyond = np.sqrt(t**2 + 1.5**2).mean()
    assert chamfer_px(a, longer)[0] == pytest.approx(0.5 * (1.5 + 0.5 * (1.5 + beyond)), abs=0.05)


def test_a_reversed_path_is_the_same_ink_but_not_the_same_movement():
    a = line(5, 30, 12, n=37)[None]
    rev = a[:, ::-1]
    assert chamfer_px(a, rev)[0] == pytest.approx(0.0, abs=1e-9)
    assert path_error_px(a, rev)[0] > 5
    assert start_error_px(a, rev)[0] == pytest.approx(25.0)  # the line's length
    curve = circle(8.0, turns=0.75)[None]
    assert chamfer_px(curve, curve[:, ::-1])[0] == pytest.approx(0.0, abs=1e-9)
    assert start_error_px(curve, curve[:, ::-1])[0] == pytest.approx(np.hypot(8, 8))


def test_the_speed_along_the_path_does_not_count():
    u = np.linspace(0, 1, 150)
    even = np.stack([20 + 8 * np.cos(4 * u), 20 + 8 * np.sin(4 * u)], -1)[None]
    slow_start = np.stack([20 + 8 * np.cos(4 * u**3), 20 + 8 * np.sin(4 * u**3)], -1)[None]
    assert chamfer_px(even, slow_start)[0] < 0.02
    assert path_error_px(even, slow_start)[0] < 0.02
    pts = resample_by_arc_length(slow_start, 33)[0]
    steps = np.linalg.norm(np.diff(pts, axis=0), axis=-1)
    assert steps.max() - steps.min() < 0.01  # evenly spaced whatever the speed


def test_on_ink_share_along_and_beside_a_drawn_line():
    path = line(8, 32, 20)[None]  # [1, 50, 2]
    image = render_paths(path, 40, pen_width_px=2.4).numpy()  # [1, 40, 40]
    assert on_ink_share(image, path)[0] == 1.0
    assert on_ink_share(image, path + [0.0, 5.0])[0] == 0.0
    assert on_ink_share(image, path[:, ::-1])[0] == 1.0
    # half of a path that runs on past the stroke's end is off the ink
    assert on_ink_share(image, line(8, 56, 20)[None])[0] == pytest.approx(0.5, abs=0.05)


def test_bilinear_between_pixel_centres_and_zero_outside():
    img = np.zeros((1, 4, 5))
    img[0, 1, 2] = 1.0
    img[0, 0, 0] = 0.8
    pts = np.array([[[2.0, 1.0], [2.5, 1.0], [2.5, 1.5], [0.0, -0.5], [-1.0, 0.0], [99, 9]]])
    assert np.allclose(bilinear(img, pts), [[1.0, 0.5, 0.25, 0.4, 0.0, 0.0]])
    assert bilinear(img, np.array([[[np.nan, 1.0]]]))[0, 0] == 0.0


def test_a_pen_up_jump_is_not_part_of_the_path():
    two = two_strokes()[None]  # [1, 70, 3]
    drawn_as_one = two[..., :2]  # the same points with the pen always down
    # another travel between the same strokes: the same writing
    other = two.copy()
    other[0, 50:70, :2] = np.linspace([15.0, 10.0], [-20.0, 60.0], 22)[1:-1]
    assert chamfer_px(two, other)[0] == pytest.approx(0.0, abs=1e-9)
    assert chamfer_px(two, drawn_as_one)[0] > 0.5
    pts = resample_by_arc_length(two, 64)[0]
    assert np.all((pts[:, 1] == 10) | (pts[:, 1] == 30))  # nothing on the travel
    assert (pts[:, 1] == 10).sum() == 32  # equal strokes share the points equally
    image = render_paths(two, 40, pen_width_px=2.4).numpy()  # the pen channel: no travel
    assert on_ink_share(image, two)[0] == 1.0
    assert on_ink_share(image, other)[0] == 1.0
    assert on_ink_share(image, drawn_as_one)[0] < 0.8
    # the pen starts writing at the first pen-down point, not where it hovered
    hover = np.concatenate([pen(line(0, 4, 0, n=5), 0.0), two[0]])[None]
    assert start_error_px(hover, two)[0] == 0.0
    assert chamfer_px(hover, two)[0] == pytest.approx(0.0, abs=1e-9)


def test_a_pen_that_never_writes_is_taken_whole():
    a = pen(line(5, 30, 12), 0.0)[None]
    assert np.allclose(resample_by_arc_length(a, 5)[0, :, 0], [5, 11.25, 17.5, 23.75, 30])
    dot = pen(np.full((10, 2), 7.0))[None]
    assert np.all(resample_by_arc_length(dot, 4) == 7.0)


def test_path_error_is_unchanged_by_the_move():
    rng = np.random.default_rng(7)
    a = rng.normal(size=(60, 50, 2)).cumsum(1) + 20  # [60, 50, 2]
    b = rng.normal(size=(60, 50, 2)).cumsum(1) + 20
    a[:, 10:14] = a[:, 10:11]  # the pen rests
    b[:, -5:] = b[:, -6:-5]  # at the end too
    b[3] = 4.0  # and never moves
    for n in (64, 17):
        assert np.allclose(path_error_px(a, b, n), old_path_error_px(a, b, n), rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="shape"):
        path_error_px(a[0], b[0])


def test_width_ratio_of_a_stretched_path():
    a = circle(5.0)[None]
    wide = a * [2.0, 1.0]
    assert width_ratio(wide, a)[0] == pytest.approx(2.0)
    assert np.isnan(width_ratio(a, np.full((1, 5, 2), 3.0))[0])  # no width to compare with
