"""Epipolar pairs on rendered images of a textured DEM, for four baseline geometries.

Truth: the rendering orientations and DEM (photax.scene.render_image).  A
left epipolar point is carried to the ground (monoplotting on the DEM) and
into the right image, independently of the epipolar code; least-squares
matching (photax.measure.match_lsm) then measures the y-parallax on the
resampled images, and the x-parallax's heights are compared with the DEM
against the precision the geometry predicts.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import photax
from photax.matching.epipolar import epipolar_pair
from photax.measure import match_lsm
from photax.scene import render_image

X0, Y0 = 500_000.0, 4_000_000.0
CAM = photax.FrameCamera.from_pixels(300.0, (200, 160))  # GSD ~1 m from 300 m
E = photax.ExteriorOrientation
LEFT = E([X0 - 30, Y0, 320.0], np.radians([0.5, -0.3, 1.0]))
RIGHT = {
    "along": E([X0 + 30, Y0 + 2, 321.0], np.radians([-0.4, 0.6, -0.5])),  # baseline along the images' x
    "across": E([X0 - 28, Y0 + 40, 320.0], np.radians([0.3, 0.4, 0.8])),  # along their y: rows turn 90 deg
    "vertical": E([X0 + 25, Y0 - 3, 345.0], np.radians([-0.6, 0.2, 0.5])),  # 25 m climb over 55 m
}
N = 224  # matched points per pair (a fixed count: one LSM compilation)


def _dem():
    n, cell = 300, 2.0
    c = -300 + cell * (np.arange(n) + 0.5)
    h = 20 + 15 * np.exp(-((c[None, :] - 40) ** 2 + (c[:, None] + 30) ** 2) / (2 * 90.0**2)) + 0.02 * c[None, :]
    return photax.DEM(h, (cell, 0.0, X0 - 300, 0.0, -cell, Y0 + 300))


@pytest.fixture(scope="module")
def scene():
    dem = _dem()
    kw = dict(origin=(X0, Y0), supersample=3, blur=0.5, noise=0.005)
    images = {"left": render_image(CAM, LEFT, dem, seed=1, **kw)}
    for k, e in RIGHT.items():
        images[k] = render_image(CAM, e, dem, seed=2, **kw)
    mono = jax.jit(lambda px, e: photax.image_to_ground(CAM.pixel_to_image(px), e, CAM, dem=dem))
    proj = jax.jit(lambda g, e: CAM.image_to_pixel(photax.project(g, e, CAM)))
    return dem, images, mono, proj


def _case(scene, name):
    """``(image_left, ext_left, image_right, ext_right)``; "before" swaps the along-track pair."""
    _, img, _, _ = scene
    if name == "before":  # the right image taken before (and to the left of) the left one
        return img["along"], RIGHT["along"], img["left"], LEFT
    return img["left"], LEFT, img[name], RIGHT[name]


def _inside(px, m=12):
    w, h = CAM.image_size
    return (
        np.all(np.isfinite(px), 1) & (px[:, 0] > m) & (px[:, 0] < w - 1 - m) & (px[:, 1] > m) & (px[:, 1] < h - 1 - m)
    )


def _canvas(img, size=300):
    out = np.zeros((size, size))
    out[: img.shape[0], : img.shape[1]] = np.nan_to_num(img)
    return out


@pytest.mark.parametrize("name", ["along", "before", "across", "vertical"])
def test_rows_are_epipolar_and_heights_follow_the_dem(scene, name):
    dem, _, mono, proj = scene
    il, el, ir, er = _case(scene, name)
    pair = epipolar_pair(il, ir, CAM, el, er)

    # Neither flipped nor scaled: the mapping original -> epipolar keeps orientation (det > 0) and scale,
    # and with the baseline along the images' x (either way) the rows keep their direction.
    c = np.array([[99.5, 79.5], [100.5, 79.5], [99.5, 80.5]])
    for side in ("left", "right"):
        e = pair.to_epipolar(side, c)
        j = np.column_stack([e[1] - e[0], e[2] - e[0]])
        assert np.linalg.det(j) > 0 and 0.8 < np.sqrt(np.linalg.det(j)) < 1.25, (side, j)
        angle = np.degrees(np.arctan2(j[1, 0], j[0, 0]))
        assert abs(angle) < 10 if name != "across" else 80 < abs(angle) < 100, angle
    assert np.sign(pair.baseline) == (-1 if name == "before" else 1)

    # Truth: left epipolar grid -> original left pixel -> DEM -> right pixel -> right epipolar pixel.
    hh, ww = pair.left.shape
    gc, gr = np.meshgrid(np.linspace(12, ww - 13, 30), np.linspace(12, hh - 13, 30))
    lxy = np.column_stack([gc.ravel(), gr.ravel()])
    lpx = pair.from_epipolar("left", lxy)
    ground = np.asarray(mono(jnp.asarray(np.nan_to_num(lpx)), el))
    rpx = np.asarray(proj(jnp.asarray(np.nan_to_num(ground)), er))
    ok = _inside(lpx) & _inside(rpx) & np.all(np.isfinite(ground), 1)
    assert ok.sum() >= N, ok.sum()
    pick = np.flatnonzero(ok)[np.linspace(0, ok.sum() - 1, N).astype(int)]
    lxy, rxy = lxy[pick], pair.to_epipolar("right", rpx[pick])
    np.testing.assert_allclose(rxy[:, 1], lxy[:, 1], atol=1e-6)  # the geometry itself: same row
    np.testing.assert_allclose(pair.from_epipolar("right", rxy), rpx[pick], atol=1e-6)  # and both ways

    # Measured on the resampled images: LSM from 0.3 px off (on one canvas size: one compilation).
    res = match_lsm(_canvas(pair.left), lxy, _canvas(pair.right), rxy + 0.3, window=7)
    v = np.asarray(res.valid)
    assert v.sum() >= 200, res.summary()
    m = np.asarray(res.xy)[v]
    assert np.sqrt(np.mean((m[:, 1] - lxy[v, 1]) ** 2)) <= 0.05  # y-parallax, px rms

    # x-parallax -> heights, against the DEM, within what the geometry predicts:
    # sigma_Z ~ q_z^2 / (f |B|) sigma_p, sigma_p = sqrt(2) sigma_LSM (both images carry noise)
    p = pair.ground(lxy[v], m)
    dz = p[:, 2] - np.asarray(dem.height(jnp.asarray(p[:, 0]), jnp.asarray(p[:, 1])))
    qz = (p - np.asarray(el.position)) @ pair.rotation[:, 2]
    sig = qz**2 / (pair.focal_px * abs(pair.baseline)) * np.sqrt(2 * np.asarray(res.covariance)[v, 0, 0])
    assert np.sqrt(np.mean(dz**2)) <= 2.0 * np.sqrt(np.mean(sig**2)), (np.sqrt(np.mean(dz**2)), np.mean(sig))


def test_bad_geometry_is_refused(scene):
    _, img, _, _ = scene
    with pytest.raises(ValueError, match="same projection centre"):
        epipolar_pair(img["left"], img["left"], CAM, LEFT, LEFT)
    forward = E(np.asarray(LEFT.position) + [0.0, 0.0, -100.0], LEFT.angles)  # moving along the optical axis
    with pytest.raises(ValueError, match="viewing direction"):
        epipolar_pair(img["left"], img["left"], CAM, LEFT, forward)
    with pytest.raises(ValueError, match="image_right"):
        epipolar_pair(img["left"], img["left"][:-1], CAM, LEFT, RIGHT["along"])
    pair = epipolar_pair(img["left"], img["along"], CAM, LEFT, RIGHT["along"])
    with pytest.raises(ValueError, match="side"):
        pair.to_epipolar("middle", [[1.0, 2.0]])


def test_cli_epipolar(scene, tmp_path):
    pytest.importorskip("rasterio")
    import rasterio.transform

    from photax.cli import main

    _, img, _, _ = scene
    paths = {}
    for name, e in (("left", LEFT), ("along", RIGHT["along"])):
        p = tmp_path / f"{name}.tif"
        with rasterio.open(
            p,
            "w",
            driver="GTiff",
            width=200,
            height=160,
            count=1,
            dtype="float32",
            transform=rasterio.transform.from_origin(500000.0, 4100000.0, 0.5, 0.5),
        ) as dst:
            dst.write(img[name].astype(np.float32), 1)
        photax.write_json(
            {"exterior": {"position": e.position, "angles_rad": e.angles, "convention": e.convention}},
            tmp_path / f"{name}.json",
        )
        paths[name] = p
    photax.write_camera(CAM, tmp_path / "cam.yaml")
    out = tmp_path / "pair"
    code = main(
        [
            "epipolar",
            str(paths["left"]),
            str(paths["along"]),
            "--camera",
            str(tmp_path / "cam.yaml"),
            "--exterior-left",
            str(tmp_path / "left.json"),
            "--exterior-right",
            str(tmp_path / "along.json"),
            "-o",
            str(out),
        ]
    )
    assert code == 0
    pair = epipolar_pair(img["left"], img["along"], CAM, LEFT, RIGHT["along"])
    with rasterio.open(tmp_path / "pair_left.tif") as src:
        np.testing.assert_allclose(src.read(1), pair.left.astype(np.float32), atol=1e-4)
    meta = photax.read_json(tmp_path / "pair.json")
    np.testing.assert_allclose(meta["baseline"], pair.baseline)
    assert (
        main(
            [
                "epipolar",
                str(paths["left"]),
                str(paths["along"]),
                "--camera",
                str(tmp_path / "cam.yaml"),
                "-o",
                str(out),
            ]
        )
        == 2
    )  # no orientation given


def test_a_pair_of_sensors_is_the_pair_of_their_cameras(scene):
    """``epipolar_pair(a, b, FrameSensor, FrameSensor)`` is the ``(camera, exterior, exterior)`` call,
    array for array; a frame pair of two different cameras, and a sensor beside a camera, are refused."""
    import equinox as eqx

    from photax.sensor import FrameSensor

    _, img, _, _ = scene
    old = epipolar_pair(img["left"], img["along"], CAM, LEFT, RIGHT["along"])
    new = epipolar_pair(img["left"], img["along"], FrameSensor(LEFT, CAM), FrameSensor(RIGHT["along"], CAM))
    np.testing.assert_array_equal(new.left, old.left)
    np.testing.assert_array_equal(new.right, old.right)
    np.testing.assert_array_equal(new.baseline, old.baseline)
    other = eqx.tree_at(lambda c: c.focal_length, CAM, CAM.focal_length * 1.01)
    with pytest.raises(ValueError, match="one camera"):
        epipolar_pair(img["left"], img["along"], FrameSensor(LEFT, CAM), FrameSensor(RIGHT["along"], other))
    with pytest.raises(ValueError, match="two sensors"):
        epipolar_pair(img["left"], img["along"], FrameSensor(LEFT, CAM), RIGHT["along"])
    with pytest.raises(ValueError, match="pass no exterior"):
        epipolar_pair(img["left"], img["along"], FrameSensor(LEFT, CAM), FrameSensor(RIGHT["along"], CAM), LEFT)
