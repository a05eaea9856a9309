"""photax.morph (issue 24, item 5): Beier-Neely field morphing, the thin-plate warp, the cross-dissolve.

References: the identity (identical lines), a similarity map (which each line's transform equals, so the
whole warp must), an affine map on the lines themselves, the inputs at t = 0 and 1, and the cross-dissolve
of two images that need no warp."""

import numpy as np
import pytest

import photax as ptx
from photax.morphing import field_warp


def _image(seed=0, shape=(60, 80)):
    from scipy.ndimage import gaussian_filter

    return gaussian_filter(np.random.default_rng(seed).random(shape), 1.5)


LINES = np.array([[[10.0, 10.0], [50.0, 14.0]], [[20.0, 45.0], [65.0, 40.0]], [[70.0, 8.0], [72.0, 50.0]]])


def _apply(m, t, x):
    return x @ m.T + t


def test_identical_lines_give_the_identity():
    grid = np.stack(np.meshgrid(np.arange(80.0), np.arange(60.0)), axis=-1)
    np.testing.assert_allclose(field_warp(grid, LINES, LINES), grid, atol=1e-9)
    img = _image()
    for t in (0.0, 0.3, 1.0):
        np.testing.assert_allclose(ptx.morph(img, img, LINES, LINES, t), img, atol=1e-9)


def test_t0_and_t1_return_the_inputs():
    img_a, img_b = _image(0), _image(1)
    moved = LINES + [[2.0, -1.5]]
    np.testing.assert_allclose(ptx.morph(img_a, img_b, LINES, moved, 0.0), img_a, atol=1e-9)
    np.testing.assert_allclose(ptx.morph(img_a, img_b, LINES, moved, 1.0), img_b, atol=1e-9)
    pts = LINES.reshape(-1, 2)
    np.testing.assert_allclose(ptx.morph(img_a, img_b, pts, pts + [1.0, 2.0], 1.0), img_b, atol=1e-9)


def test_a_similarity_is_reproduced_everywhere_and_an_affine_on_the_lines():
    ang, s = np.deg2rad(7.0), 1.1
    m = s * np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    shift = np.array([3.0, -2.0])
    q = np.random.default_rng(2).uniform(0, 80, (500, 2))
    np.testing.assert_allclose(field_warp(q, LINES, _apply(m, shift, LINES)), _apply(m, shift, q), atol=1e-9)
    # Beier-Neely's original (v in pixels) reproduces rigid motions only
    rigid = m / s
    np.testing.assert_allclose(
        field_warp(q, LINES, _apply(rigid, shift, LINES), keep_distance=True), _apply(rigid, shift, q), atol=1e-9
    )
    # a general affine (shear): exact on the lines, away from their ends (where other lines pull)
    aff = np.array([[1.05, 0.12], [-0.04, 0.93]])
    u = np.linspace(0.1, 0.9, 9)[:, None]
    on = np.concatenate([ln[0] + u * (ln[1] - ln[0]) for ln in LINES])
    np.testing.assert_allclose(field_warp(on, LINES, _apply(aff, shift, LINES)), _apply(aff, shift, on), atol=1e-3)
    off = np.array([[40.0, 28.0], [5.0, 55.0]])
    assert np.abs(field_warp(off, LINES, _apply(aff, shift, LINES)) - _apply(aff, shift, off)).max() > 0.05


def test_the_frame_is_the_cross_dissolve_of_the_two_warps():
    """With B the image of A moved by a similarity and the lines moved with it, every frame at t shows A
    moved by the interpolated lines' similarity; with no motion the frame is (1 - t) A + t B."""
    img_a, img_b = _image(0), _image(1)
    np.testing.assert_allclose(ptx.morph(img_a, img_b, LINES, LINES, 0.25), 0.75 * img_a + 0.25 * img_b, atol=1e-9)
    shift = np.array([4.0, 2.0])
    yy, xx = np.mgrid[0:60, 0:80].astype(float)
    moved = np.asarray(ptx.resample(img_a, xx - shift[0], yy - shift[1], "bilinear"))  # B(x) = A(x - shift)
    frame = ptx.morph(img_a, moved, LINES, LINES + shift, 0.5, resampling="bilinear")
    half = np.asarray(ptx.resample(img_a, xx - 2.0, yy - 1.0, "bilinear"))  # A moved by half the shift
    inner = (slice(8, -8), slice(8, -8))
    np.testing.assert_allclose(frame[inner], half[inner], atol=1e-6)


def test_points_give_a_thin_plate_warp():
    img_a, img_b = _image(0), _image(1)
    pa = np.array([[5.0, 5.0], [70.0, 8.0], [40.0, 30.0], [10.0, 50.0], [75.0, 55.0]])
    pb = pa + [[1.0, 0.0], [0.0, 2.0], [-1.5, 1.0], [0.5, -0.5], [2.0, 2.0]]
    frame = ptx.morph(img_a, img_b, pa, pb, 0.5)
    assert frame.shape == img_a.shape and np.isfinite(frame).mean() > 0.95
    # at each control point of the frame (halfway), the frame is the dissolve of A and B at their points
    pt = 0.5 * (pa + pb)
    k = 2  # an interior point
    va = float(ptx.resample(img_a, pa[k, 0], pa[k, 1], "bilinear"))
    vb = float(ptx.resample(img_b, pb[k, 0], pb[k, 1], "bilinear"))
    vf = float(ptx.resample(frame, pt[k, 0], pt[k, 1], "bilinear"))
    assert vf == pytest.approx(0.5 * va + 0.5 * vb, abs=0.02)


def test_sequence_written_as_gif_and_frames(tmp_path):
    from PIL import Image

    img_a, img_b = _image(0), _image(1)
    seq = ptx.morph_sequence(img_a, img_b, LINES, LINES + [[1.0, 1.0]], frames=5)
    assert seq.shape == (5, 60, 80)
    np.testing.assert_allclose(seq[0], img_a, atol=1e-9)
    gif = ptx.write_sequence(seq, tmp_path / "morph.gif")
    with Image.open(gif) as im:
        assert im.n_frames == 5 and im.size == (80, 60)
    folder = ptx.write_sequence(np.stack([seq] * 3, axis=1), tmp_path / "frames")  # (n, 3, H, W) colour
    assert sorted(p.name for p in folder.iterdir()) == [f"frame_{i:03d}.png" for i in range(5)]
    with pytest.raises(FileExistsError):
        ptx.write_sequence(seq, folder)


def test_bad_input():
    img = _image()
    with pytest.raises(ValueError, match=r"t must be a number in \[0, 1\]"):
        ptx.morph(img, img, LINES, LINES, 1.2)
    with pytest.raises(ValueError, match=r"t must be"):
        ptx.morph(img, img, LINES, LINES, -0.1)
    zero = LINES.copy()
    zero[1, 1] = zero[1, 0]
    with pytest.raises(ValueError, match=r"lines_b has lines of zero length at rows \[1\]"):
        ptx.morph(img, img, LINES, zero, 0.5)
    with pytest.raises(ValueError, match="one shape"):
        ptx.morph(img, img, LINES, LINES[:2], 0.5)
    with pytest.raises(ValueError, match="one shape"):
        ptx.morph(img, img[:-1], LINES, LINES, 0.5)
    with pytest.raises(ValueError, match="at least 3 control points"):
        ptx.morph(img, img, LINES[0], LINES[0], 0.5)
    with pytest.raises(ValueError, match="frames must be"):
        ptx.morph_sequence(img, img, LINES, LINES, frames=1)
