"""Rendering, blur, noise and the joint image/point affine transform, against known facts."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import ndimage

from img2dmp.data.affine import (
    AffineRanges,
    affine_matrix,
    sample_affine,
    warp_images,
    warp_images_numpy,
    warp_points,
)
from img2dmp.data.render import gaussian_filter, render_paths, salt_and_pepper


def _line(p0, p1, n):
    f = np.linspace(0.0, 1.0, n)[:, None]
    return (np.asarray(p0) + f * (np.asarray(p1) - np.asarray(p0))).astype(np.float32)


@pytest.mark.parametrize("width", [1.5, 2.4, 4.0])
def test_straight_stroke_has_the_pen_width(width):
    # Ink per unit length of a straight stroke is about the pen's width, wherever the
    # stroke lies relative to the pixel grid (anti-aliasing).
    for offset in (0.0, 0.25, 0.5):
        y = 20 + offset
        img = render_paths(_line((5, y), (35, y), 50)[None], 40, width)[0].numpy()
        assert img[:, 20].sum() == pytest.approx(width, rel=0.1)
    img = render_paths(_line((5, 20), (35, 20), 50)[None], 40, width)[0].numpy()
    column = img[:, 20]
    assert column[20] > 0.85  # on the centre line (a thin pen does not quite saturate)
    assert column[: int(20 - width)].max() < 1e-3  # nothing far away
    assert img[:, : int(5 - width / 2 - 1)].max() < 1e-3  # round caps at the ends
    # A pixel centre exactly w/2 from the centre line is half inked.
    y = 20 - width / 2
    edge = render_paths(_line((5, y), (35, y), 50)[None], 40, width)[0].numpy()
    assert edge[20, 20] == pytest.approx(0.5, abs=0.01)


def test_ink_does_not_depend_on_how_densely_or_evenly_the_path_is_sampled():
    u = np.linspace(0, 1, 301)
    s = 10 * u**3 - 15 * u**4 + 6 * u**5  # crowded at both ends
    uneven = np.stack([6 + 28 * s, 8 + 24 * s], -1).astype(np.float32)
    sparse = _line((6, 8), (34, 32), 2)  # one long segment, subdivided inside
    a = render_paths(uneven[None], 40, 2.4)[0]
    b = render_paths(sparse[None], 40, 2.4)[0]
    assert (a - b).abs().max() < 0.04  # the largest differences sit at the ends
    assert (a - b).abs().mean() < 1e-3


def test_pen_up_segments_are_not_drawn_and_dots_are():
    pts = np.array([[5, 5], [15, 5], [25, 30], [35, 30], [20, 20]], np.float32)
    pen = np.array([1, 1, 1, 1, 0], bool)
    pen_gap = np.array([1, 1, 0, 1, 1], bool)  # lift between the strokes
    with_travel = render_paths(pts[None], 40, 2.0, pen[None])[0].numpy()
    lifted = render_paths(pts[None], 40, 2.0, pen_gap[None])[0].numpy()
    mid = (12, 18)  # [row, col] 0.2 px from the travel segment (15, 5) -> (25, 30)
    assert with_travel[mid] > 0.9
    assert lifted[mid] < 1e-3
    assert lifted[5, 10] > 0.9 and lifted[25, 27] > 0.9  # both strokes still there
    # Point 4 (20, 20) is pen-down but isolated in `dots`: it is drawn as a dot.
    dots = np.array([1, 1, 0, 0, 1], bool)
    img = render_paths(pts[None], 40, 2.0, dots[None])[0].numpy()
    assert img[20, 20] > 0.9 and img[25, 27] < 1e-3
    # The pen state may come as a third column instead.
    with_col = np.concatenate([pts, pen_gap[:, None].astype(np.float32)], -1)
    np.testing.assert_array_equal(render_paths(with_col[None], 40, 2.0)[0].numpy(), lifted)


def test_rendering_any_size_and_batch_shape():
    pts = np.zeros((2, 3, 4, 2), np.float32)
    pts[..., 0] = 45.0  # x = 45: column 45
    pts[..., 1] = 5.0  # y = 5: row 5
    img = render_paths(pts, (30, 50), 2.0)
    assert img.shape == (2, 3, 30, 50) and img.dtype == torch.float32
    flat = img.reshape(6, -1).argmax(-1)
    assert (flat == 5 * 50 + 45).all()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"pen_width_px": -1.0}, "pen_width_px"),
        ({"image_size": (0, 40)}, "image size"),
        ({"image_size": -5}, "image size"),
    ],
)
def test_render_rejects_bad_arguments(kwargs, message):
    with pytest.raises(ValueError, match=message):
        render_paths(np.zeros((1, 3, 2), np.float32), **kwargs)
    with pytest.raises(ValueError, match="points"):
        render_paths(np.zeros((1, 3, 4), np.float32))


def test_gaussian_filter_matches_scipy():
    rng = np.random.default_rng(0)
    img = rng.random((3, 24, 31)).astype(np.float32)
    ours = gaussian_filter(img, 1.2).numpy()
    ref = np.stack([ndimage.gaussian_filter(a, 1.2, mode="constant", truncate=3.0) for a in img])
    # scipy's kernel radius is int(3 sigma + 0.5) = 4, ours ceil(3 sigma) = 4: same kernel.
    np.testing.assert_allclose(ours, ref, atol=1e-5)
    np.testing.assert_array_equal(gaussian_filter(img, 0).numpy(), img)
    with pytest.raises(ValueError, match="sigma_px"):
        gaussian_filter(img, -1)


def test_salt_and_pepper_stays_on_the_foreground():
    img = np.zeros((200, 40, 40), np.float32)
    img[:, 10:30, 10:30] = 0.7
    out = salt_and_pepper(img, 0.1, np.random.default_rng(1)).numpy()
    changed = out != img
    assert not changed[:, :10].any() and not changed[:, :, 30:].any()  # background untouched
    assert changed.mean() / (img > 0.1).mean() == pytest.approx(0.1, rel=0.05)
    assert set(np.unique(out[changed])) <= {0.0, 1.0}
    assert (out[changed] == 1.0).mean() == pytest.approx(0.5, abs=0.03)
    again = salt_and_pepper(img, 0.1, np.random.default_rng(1)).numpy()
    np.testing.assert_array_equal(out, again)
    with pytest.raises(ValueError, match="amount"):
        salt_and_pepper(img, 1.5, np.random.default_rng(1))


def test_integer_translation_and_quarter_turn_move_pixels_exactly():
    img = np.zeros((41, 41), np.float32)
    img[20, 25] = 1.0  # x = 25, y = 20
    shift = affine_matrix((41, 41), np.array([3.0, -2.0]), 0.0, 1.0, 0.0)
    out = warp_images(img, shift).numpy()
    assert out[18, 28] == pytest.approx(1.0) and out.sum() == pytest.approx(1.0)
    # +90 degrees turns x towards y: (25, 20) about the centre (20, 20) goes to (20, 25).
    turn = affine_matrix((41, 41), np.zeros(2), 90.0, 1.0, 0.0)
    out = warp_images(img, turn).numpy()
    assert out[25, 20] == pytest.approx(1.0, abs=1e-5) and out.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(warp_points(np.array([[25.0, 20.0]]), turn), [[20.0, 25.0]])


def test_warped_image_is_the_input_read_at_the_inverse_map():
    # Bilinear interpolation reproduces affine functions exactly, so a ramp image tells
    # where every output pixel was read from: it must be A^-1 (p' - b).
    ys, xs = np.mgrid[:40, :40].astype(np.float64)
    ramp = (0.2 + 0.01 * xs + 0.005 * ys).astype(np.float32)
    rng = np.random.default_rng(3)
    mats = sample_affine(rng, 8, 40, AffineRanges(scale=(0.8, 1.2), shear_deg=(-20, 20)))
    out = warp_images(np.repeat(ramp[None], 8, 0), mats).numpy()
    for m, o in zip(mats, out, strict=True):
        dst = np.stack([xs.ravel(), ys.ravel()])  # [2, H*W]
        src = np.linalg.solve(m[:, :2], dst - m[:, 2:])
        inside = (src >= 0).all(0) & (src[0] <= 39) & (src[1] <= 39)
        expect = 0.2 + 0.01 * src[0] + 0.005 * src[1]
        np.testing.assert_allclose(o.ravel()[inside], expect[inside], atol=2e-5)
        assert inside.mean() > 0.5


def test_images_and_points_stay_aligned_under_random_transforms():
    rng = np.random.default_rng(3)
    n = 64
    pts = rng.uniform(12, 28, (n, 1, 2)).astype(np.float32)
    dots = render_paths(pts, 40, 3.0)  # [n, 40, 40] round blobs centred on the points
    mats = sample_affine(rng, n, 40, AffineRanges(scale=(0.8, 1.2), shear_deg=(-20, 20)))
    moved = warp_images(dots, mats).numpy()
    target = warp_points(pts, mats)[:, 0]  # [n, 2]
    ys, xs = np.mgrid[:40, :40]
    mass = moved.sum((1, 2))
    centroid = np.stack([(moved * xs).sum((1, 2)), (moved * ys).sum((1, 2))], -1) / mass[:, None]
    # A blob's centroid on the pixel grid wobbles by a tenth of a pixel or two.
    assert np.abs(centroid - target).max() < 0.3  # px
    assert np.abs(centroid - target).mean() < 0.1


def test_sample_affine_respects_its_ranges():
    rng = np.random.default_rng(5)
    np.testing.assert_allclose(
        sample_affine(rng, 4, 40, AffineRanges.identity()),
        np.broadcast_to([[1, 0, 0], [0, 1, 0]], (4, 2, 3)),
        atol=1e-12,
    )
    r = AffineRanges(translation_rel=(-0.1, 0.1), rotation_deg=(5, 15), scale=(0.8, 1.25))
    m = sample_affine(rng, 2000, (40, 60), r)
    det = np.linalg.det(m[:, :, :2])  # rotation and shear keep area: det = scale^2
    assert det.min() >= 0.8**2 - 1e-9 and det.max() <= 1.25**2 + 1e-9
    centre = np.array([29.5, 19.5])
    t = m[:, :, :2] @ centre + m[:, :, 2] - centre  # where the centre goes
    assert np.abs(t[:, 0]).max() <= 6.0 + 1e-9 and np.abs(t[:, 1]).max() <= 4.0 + 1e-9
    assert np.abs(t[:, 0]).max() > 5.0  # and the range is actually used
    # Without shear the first column is scale * (cos, sin) of the rotation.
    angle = np.degrees(np.arctan2(m[:, 1, 0], m[:, 0, 0]))
    plain = sample_affine(rng, 500, 40, AffineRanges(rotation_deg=(5, 15), shear_deg=(0, 0)))
    angle = np.degrees(np.arctan2(plain[:, 1, 0], plain[:, 0, 0]))
    assert angle.min() >= 5 - 1e-9 and angle.max() <= 15 + 1e-9


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"scale": (0.0, 1.0)}, "scale"),
        ({"rotation_deg": (10, -10)}, "rotation_deg"),
        ({"shear_deg": (-85, 0)}, "shear_deg"),
        ({"translation_rel": (0.1,)}, "translation_rel"),
    ],
)
def test_affine_ranges_validate(kwargs, message):
    with pytest.raises(ValueError, match=message):
        AffineRanges(**kwargs)


def test_warp_points_passes_the_pen_channel_through():
    pts = np.array([[[1.0, 2.0, 1.0], [3.0, 4.0, 0.0]]])
    m = affine_matrix((40, 40), np.array([1.0, 1.0]), 0.0, 1.0, 0.0)
    np.testing.assert_allclose(warp_points(pts, m), [[[2.0, 3.0, 1.0], [4.0, 5.0, 0.0]]])
    with pytest.raises(ValueError, match="batch shape"):
        warp_points(pts, np.zeros((3, 2, 3)))


def test_the_numpy_warp_is_the_torch_warp():
    rng = np.random.default_rng(5)
    images = rng.random((4, 40, 30)).astype(np.float32)
    m = sample_affine(rng, 4, (40, 30), AffineRanges(translation_rel=(-0.5, 0.5)))
    np.testing.assert_allclose(warp_images_numpy(images, m), warp_images(images, m).numpy(),
                               atol=1e-5)  # fmt: skip
    one = m[0]  # one matrix for a batch, and a single image
    np.testing.assert_allclose(warp_images_numpy(images[0], one),
                               warp_images(images[0], one).numpy(), atol=1e-5)  # fmt: skip
    with pytest.raises(ValueError, match="affine matrix must have shape"):
        warp_images_numpy(images, np.eye(3))
