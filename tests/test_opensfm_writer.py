"""OpenSfM/ODM ``reconstruction.json`` and ODM ``cameras.json`` written by photax (issue 22).

References: photax's own readers (write -> read gives the same cameras and
orientations: positions to 1e-6 m, angles to 1e-9 rad, pixels to 1e-6 px),
orthority 0.7's ``OsfmReader`` and cameras (the same pixels as photax for the
ground points), and the real ODM reconstruction (read -> write -> read is the
identity).
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

import photax
from photax.io import (
    read_odm_cameras,
    read_opensfm_cameras,
    read_opensfm_shots,
    write_odm_cameras,
    write_opensfm_reconstruction,
)

CRS = "EPSG:32633"

CAMERAS = {
    "brown_px": photax.FrameCamera.from_pixels(
        3666.7, (5472, 3648), (2740.3, 1818.9), (-0.267, 0.112, -0.0332, 0.00092, -0.000088)
    ),
    # non-square pixels, portrait, in mm: read back in pixels
    "brown_tall": photax.FrameCamera(
        120.0, (0.3, -0.2), (0.01, -0.002, 0.0003, 1e-4, -2e-4), pixel_size=(0.144, 0.1446), image_size=(640, 1152)
    ),
    "brown_wide": photax.FrameCamera(
        120.0, (0.3, -0.2), (0.01, -0.002, 0.0003, 1e-4, -2e-4), pixel_size=(0.1446, 0.144), image_size=(1152, 640)
    ),
    # an opencv camera without its extra terms is OpenSfM's brown
    "opencv_as_brown": photax.FrameCamera.from_pixels(
        3000.0, (4000, 3000), (1990.0, 1510.0), (-0.1, 0.05, 0.0, 1e-4, -2e-4, 0, 0, 0, 0, 0, 0, 0), model="opencv"
    ),
    # fisheye_opencv (principal point off centre, k3 and k4)
    "fisheye_px": photax.FrameCamera.from_pixels(
        2400.0, (4000, 3000), (2010.0, 1490.0), (0.05, -0.01, 0.003, -0.0004), model="fisheye"
    ),
    # OpenSfM's plain fisheye (focal, k1, k2): the one orthority reads
    "fisheye_plain": photax.FrameCamera.from_pixels(
        1800.0, (3000, 2000), (1499.5, 999.5), (0.04, -0.008, 0.0, 0.0), model="fisheye"
    ),
}


def _table(n=4, seed=0, origin=(512000, 4103000)):
    rng = np.random.default_rng(seed)
    out = {}
    for k in range(n):
        position = (*(np.asarray(origin) + rng.uniform(-500, 500, 2)), rng.uniform(300, 900))
        angles = np.radians(rng.uniform([-10, -10, -180], [10, 10, 180]))
        out[f"IMG_{k:04d}"] = photax.ExteriorOrientation(
            position, angles, ["phi-omega-kappa", "omega-phi-kappa"][k % 2]
        )
    return out


def _rotation(eo):
    return np.asarray(photax.rotation_matrix(eo.angles, eo.convention))


def _ground(camera, eo, rng, n=30):
    """Ground points the camera sees: rays through pixels, 200-400 m out."""
    w, h = camera.image_size
    pix = rng.uniform((0, 0), (w - 1, h - 1), (n, 2))
    rays = np.asarray(camera.ray(camera.pixel_to_image(pix)))
    return np.asarray(eo.position) + rng.uniform(200, 400, (n, 1)) * (rays @ _rotation(eo).T)


def _pixels(camera, eo, ground):
    return np.asarray(camera.image_to_pixel(photax.project(ground, eo, camera)))


@pytest.mark.parametrize("name", list(CAMERAS))
def test_cameras_round_trip(tmp_path, name):
    camera = CAMERAS[name]
    eo = photax.ExteriorOrientation((0.0, 0.0, 500.0), np.radians([3.0, -2.0, 40.0]), "omega-phi-kappa")
    ground = _ground(camera, eo, np.random.default_rng(1))
    recon = write_opensfm_reconstruction(tmp_path / "r.json", {name: camera}, {"a": eo}, CRS)
    cams = write_odm_cameras(tmp_path / "cameras.json", {name: camera})
    for back in (read_opensfm_cameras(recon)[name], read_odm_cameras(cams)[name]):
        assert back.model == ("brown" if camera.model == "opencv" else camera.model)
        assert back.image_size == camera.image_size
        np.testing.assert_allclose(_pixels(back, eo, ground), _pixels(camera, eo, ground), rtol=0, atol=1e-6)
        if name.endswith("_px"):  # a pixel camera comes back as itself
            for key in ("focal_length", "principal_point", "distortion", "pixel_size"):
                np.testing.assert_allclose(np.asarray(getattr(back, key)), np.asarray(getattr(camera, key)), atol=1e-9)
    kind = json.loads(recon.read_text())[0]["cameras"][name]["projection_type"]
    assert kind == {"fisheye_px": "fisheye_opencv", "fisheye_plain": "fisheye"}.get(name, "brown")


# the last two: positions in UTM zone 32's grid, the reference (lon 15.1 E) in zone 33
@pytest.mark.parametrize(
    ("frame", "crs"), [("topocentric", CRS), ("grid", CRS), ("topocentric", "EPSG:32632"), ("grid", "EPSG:32632")]
)
def test_shots_round_trip(tmp_path, frame, crs):
    table = _table() if crs == CRS else _table(origin=(1042000, 4110000))
    camera = CAMERAS["brown_px"]
    # Moved between two grids, the meridian convergences (central differences of
    # projected points ~1e6 m apart from 0.1 m steps) carry ~1e-9 rad of rounding each
    # way: 2400 px x 1e-9 rad = 2.4e-6 px.  In the reference's own UTM zone they cancel.
    atol_rad, atol_px = (1e-9, 1e-6) if crs == CRS else (1e-8, 1e-5)
    path = write_opensfm_reconstruction(tmp_path / "r.json", {"v2 cam": camera}, table, crs, frame=frame)
    for frame_read in (None, frame):  # the frame told by the gps_position written, or named
        back, back_crs, image_cameras = read_opensfm_shots(path, crs=crs, frame=frame_read)
        assert back_crs == crs and set(back) == set(table) and set(image_cameras.values()) == {"cam"}
        rng = np.random.default_rng(2)
        for name, eo in table.items():
            got = back[name]
            np.testing.assert_allclose(np.asarray(got.position), np.asarray(eo.position), rtol=0, atol=1e-6)
            want = np.asarray(photax.convert_angles(eo.angles, eo.convention, "omega-phi-kappa"))
            np.testing.assert_allclose(np.asarray(got.angles), want, rtol=0, atol=atol_rad)
            ground = _ground(camera, eo, rng)
            np.testing.assert_allclose(_pixels(camera, got, ground), _pixels(camera, eo, ground), rtol=0, atol=atol_px)


@pytest.mark.parametrize("name", ["brown_px", "brown_wide", "fisheye_plain"])
def test_orthority_reads_what_photax_writes(tmp_path, name):
    """orthority's OsfmReader and cameras put ground points on photax's pixels.

    orthority takes every reconstruction to be in the grid frame, reads OpenSfM's
    plain ``fisheye`` only (not ``fisheye_opencv``), and, with no ``sensor_size``,
    takes the focal length as normalised by the image width where OpenSfM
    normalises by ``max(width, height)``: it misreads portrait cameras (not tested).
    """
    from orthority.camera import create_camera
    from orthority.param_io import OsfmReader

    camera, table = CAMERAS[name], _table(3, seed=3)
    path = write_opensfm_reconstruction(tmp_path / "r.json", {name: camera}, table, CRS, frame="grid")
    reader = OsfmReader(path, crs=CRS)
    int_params, ext_params = reader.read_int_param(), reader.read_ext_param()
    rng = np.random.default_rng(4)
    for image, eo in table.items():
        ground = _ground(camera, eo, rng)
        e = ext_params[image]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cam = create_camera(**int_params[e["camera"]], xyz=e["xyz"], opk=e["opk"])
        ref = cam.world_to_pixel(ground.T).T
        np.testing.assert_allclose(ref, _pixels(camera, eo, ground), rtol=0, atol=1e-6)


def test_refusals(tmp_path):
    out = tmp_path / "r.json"
    table = _table(2)
    full = photax.FrameCamera.from_pixels(3000.0, (400, 300), (200.0, 150.0), np.full(12, 1e-3), model="opencv")
    with pytest.raises(ValueError, match="k4-k6"):
        write_opensfm_reconstruction(out, {"c": full}, table, CRS)
    with pytest.raises(ValueError, match="pixel grid"):
        write_odm_cameras(out, {"c": photax.FrameCamera(8.8)})
    with pytest.raises(ValueError, match="image_cameras"):
        write_opensfm_reconstruction(out, {"a": CAMERAS["brown_px"], "b": CAMERAS["fisheye_px"]}, table, CRS)
    with pytest.raises(ValueError, match="not among"):
        write_opensfm_reconstruction(out, CAMERAS["brown_px"], table, CRS, image_cameras={"IMG_0000": "x"})
    with pytest.raises(ValueError, match="frame"):
        write_opensfm_reconstruction(out, CAMERAS["brown_px"], table, CRS, frame="utm")
    with pytest.raises(ValueError, match="no orientations"):
        write_opensfm_reconstruction(out, CAMERAS["brown_px"], {}, CRS)
    with pytest.raises(ValueError, match="not a projected CRS"):
        write_opensfm_reconstruction(out, CAMERAS["brown_px"], table, "EPSG:4326")
    assert not out.exists()


def test_real_odm_reconstruction_round_trip(tmp_path):
    """ODM's reconstruction of the orthority test images: read, written in the frame it
    was read in with its reference, read again: the same cameras and shots."""
    from conftest import shared_file

    src = shared_file("orthority/odm/opensfm/reconstruction.json")
    cameras = read_opensfm_cameras(src)
    shots, crs, image_cameras = read_opensfm_shots(src)
    ref = json.loads(src.read_text())[0]["reference_lla"]
    lla = (ref["latitude"], ref["longitude"], ref["altitude"])
    path = write_opensfm_reconstruction(tmp_path / "r.json", cameras, shots, crs, lla, "grid", image_cameras)
    cams2 = read_opensfm_cameras(path)
    shots2, crs2, image_cameras2 = read_opensfm_shots(path)
    assert crs2 == crs and image_cameras2 == image_cameras and set(cams2) == set(cameras)
    for name, cam in cameras.items():
        for key in ("focal_length", "principal_point", "distortion", "pixel_size"):
            np.testing.assert_allclose(np.asarray(getattr(cams2[name], key)), np.asarray(getattr(cam, key)), atol=1e-9)
    # the file's own numbers come back too
    orig, again = json.loads(src.read_text())[0], json.loads(path.read_text())[0]
    assert set(again["shots"]) == set(orig["shots"])
    for name, shot in orig["shots"].items():
        np.testing.assert_allclose(again["shots"][name]["translation"], shot["translation"], rtol=0, atol=1e-6)
        np.testing.assert_allclose(again["shots"][name]["rotation"], shot["rotation"], rtol=0, atol=1e-9)
    for name, eo in shots.items():
        np.testing.assert_allclose(np.asarray(shots2[name].position), np.asarray(eo.position), rtol=0, atol=1e-6)
        np.testing.assert_allclose(np.asarray(shots2[name].angles), np.asarray(eo.angles), rtol=0, atol=1e-9)


def test_real_odm_shots_through_the_topocentric_frame(tmp_path):
    """ODM's shots (grid frame) written in OpenSfM's topocentric frame: read back the
    same, and photax's orientation reader (what ``photax ortho --exterior`` uses)
    finds them in the written file."""
    from conftest import shared_file

    from photax.io import read_exteriors

    src = shared_file("orthority/odm/opensfm/reconstruction.json")
    cameras = read_opensfm_cameras(src)
    shots, crs, image_cameras = read_opensfm_shots(src)
    path = write_opensfm_reconstruction(tmp_path / "r.json", cameras, shots, crs, None, "topocentric", image_cameras)
    back, back_crs = read_exteriors(path, list(shots), crs=crs)
    assert back_crs == crs
    for name, eo in shots.items():
        np.testing.assert_allclose(np.asarray(back[name].position), np.asarray(eo.position), rtol=0, atol=1e-6)
        np.testing.assert_allclose(np.asarray(back[name].rotation), np.asarray(eo.rotation), rtol=0, atol=1e-9)
