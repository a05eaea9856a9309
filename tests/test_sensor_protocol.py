"""One Sensor protocol for frame, RPC and push-broom images, and the products that take it (issue 34).

Three synthetic sensors with known truth: a frame over relief (photax.relief_scene, in UTM 33N), an
RPC fitted to that frame (photax.fit_rpc through the frame sensor's own ``localize``: terrain-
independent, Tao & Hu 2001), and a push-broom model (photax.pushbroom_scene).  Each product
(orthorectify, ortho_grid / ground_sampling_distance -- the footprint -- and ortho_uncertainty) runs on
one sensor of each kind through the same ``(..., sensor, dem, ...)`` signature; the frame's numbers are
those of the older ``(exterior, camera)`` call exactly, the RPC's agree with the frame it was fitted to
(to its fit error), and a ground sensor's equal its ``(None, camera)`` call exactly.
"""

from __future__ import annotations

import contextlib
import warnings

import jax.numpy as jnp
import numpy as np
import pytest

import photax as ptx
from photax.dem import DEM
from photax.errors import CRSMismatchError
from photax.geo import same_crs
from photax.grid import ground_sampling_distance
from photax.pushbroom import fit_rpc
from photax.rectification import OrthoModel, ortho_grid, orthorectify
from photax.scene import pushbroom_scene
from photax.sensor import FrameSensor, GroundSensor, Sensor, sensor_of

pyproj = pytest.importorskip("pyproj")

UTM = "EPSG:32633"
HEIGHT = 700.0  # the push-broom scene's flat ground (ellipsoidal, m)


class _FrameAsGroundCamera:
    """A frame sensor seen in lon, lat (WGS84) and height: what fit_rpc asks of a model."""

    def __init__(self, sensor: FrameSensor):
        self.sensor, self.image_size = sensor, sensor.image_size
        self.to_ll = pyproj.Transformer.from_crs(UTM, "EPSG:4326", always_xy=True)

    def to_ground(self, pixel, height):
        ground, ok = self.sensor.localize(pixel, height)
        g = np.asarray(ground)
        lon, lat = self.to_ll.transform(g[:, 0], g[:, 1])
        return np.where(np.asarray(ok)[:, None], np.stack([lon, lat], -1), np.nan)


@pytest.fixture(scope="module")
def frame():
    scene = ptx.relief_scene(200.0, seed=2, image_size=(160, 120), focal_px=160.0, tilt_deg=3.0)
    dem = DEM(scene.dem.heights, scene.dem.transform, crs=UTM)
    return scene, dem, FrameSensor(scene.exterior, scene.camera, UTM)


@pytest.fixture(scope="module")
def rpc(frame):
    scene, dem, fs = frame
    h = np.asarray(dem.heights)
    fit = fit_rpc(_FrameAsGroundCamera(fs), (float(h.min()) - 50.0, float(h.max()) + 50.0), grid=11, layers=5)
    assert fit.check_max_error < 0.02  # px: a cubic RPC holds a frame camera over this relief
    return fit.camera, GroundSensor(fit.camera, UTM)


@pytest.fixture(scope="module")
def broom():
    scene = pushbroom_scene(roll=12.0, pitch=-10.0, gsd=10.0, image_size=(96, 80), n_gcp=6, n_check=0)
    cam = scene.camera
    w, lines = cam.image_size
    lon, lat = np.asarray(cam.to_ground(jnp.array([(w - 1) / 2, (lines - 1) / 2]), HEIGHT))
    crs = ptx.utm_crs(lon=float(lon), lat=float(lat))
    x0, y0, x1, y1 = GroundSensor(cam, crs).box()
    dem = DEM(np.full((2, 2), HEIGHT), DEM.flat(HEIGHT, (x0, y0, x1, y1)).transform, crs=crs)
    rng = np.random.default_rng(0)
    image = rng.uniform(0.0, 1.0, (lines, w))
    return cam, GroundSensor(cam, crs), dem, image


@contextlib.contextmanager
def _quiet():
    """The DEM of a ground sensor here is not labelled ellipsoidal: check_rpc_dem says so, rightly."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


# --- the protocol ---------------------------------------------------------------


def test_every_kind_is_a_sensor_and_localize_inverts_project(frame, rpc, broom):
    scene, dem, fs = frame
    rs, bs = rpc[1], broom[1]
    assert [s.kind for s in (fs, rs, bs)] == ["frame", "rpc", "pushbroom"]
    for s, h in ((fs, 300.0), (rs, 300.0), (bs, HEIGHT)):
        assert isinstance(s, Sensor)
        w, lines = s.image_size
        px = np.stack(np.meshgrid(np.linspace(5, w - 6, 4), np.linspace(5, lines - 6, 3)), -1).reshape(-1, 2)
        ground, ok = s.localize(jnp.asarray(px), h)
        assert np.all(np.asarray(ok)) and np.allclose(np.asarray(ground)[:, 2], h)
        back = np.asarray(s.project(ground))
        assert np.max(np.abs(back - px)) < 1e-6, (s.kind, np.max(np.abs(back - px)))
    assert fs.validity.height_range is None and fs.validity.ground_box is None and fs.crs == UTM
    off, sc = np.asarray(rpc[0].offsets), np.asarray(rpc[0].scales)
    assert rs.validity.height_range == pytest.approx((off[2] - sc[2], off[2] + sc[2]))
    x0, y0, x1, y1 = bs.validity.ground_box  # NaN just outside the box, a pixel inside
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    assert np.isnan(np.asarray(bs.project(jnp.array([x1 + 0.01 * (x1 - x0), cy, HEIGHT])))).all()
    assert np.isfinite(np.asarray(bs.project(jnp.array([cx, cy, HEIGHT])))).all()


def test_the_rpc_of_the_frame_maps_the_grid_as_the_frame_does(frame, rpc):
    # an independent check of the RPC path: the fitted RPC (in lon, lat) and the frame's collinearity
    # equations (in UTM) send the ortho grid's ground points to the same pixels, to the RPC's fit error
    scene, dem, fs = frame
    grid = ortho_grid(fs, dem, 20.0)
    xy = jnp.asarray(grid.xy().reshape(-1, 2))
    a = np.asarray(OrthoModel(None, rpc[1], dem, UTM)(xy))
    b = np.asarray(OrthoModel(scene.exterior, scene.camera, dem)(xy))
    both = np.isfinite(a).all(1) & np.isfinite(b).all(1)
    assert both.mean() > 0.5
    assert np.max(np.abs(a[both] - b[both])) < 0.05


# --- orthorectify --------------------------------------------------------------


def test_orthorectify_frame_sensor_is_the_old_call_exactly(frame):
    scene, dem, fs = frame
    new, g_new = orthorectify(scene.image, fs, dem, resolution=20.0)
    old, g_old = orthorectify(scene.image, scene.exterior, scene.camera, dem, resolution=20.0)
    assert g_new == g_old
    assert np.array_equal(new, old, equal_nan=True) and np.isfinite(new).mean() > 0.5


def test_orthorectify_rpc_sensor(frame, rpc):
    scene, dem, fs = frame
    ortho_f, grid = orthorectify(scene.image, fs, dem, resolution=20.0)
    with _quiet():
        new, g = orthorectify(scene.image, rpc[1], dem, grid)
        old, _ = orthorectify(scene.image, None, rpc[0], dem, grid)
    assert g == grid and np.array_equal(new, old, equal_nan=True)
    both = np.isfinite(new) & np.isfinite(ortho_f)
    assert both.mean() > 0.5
    # 0.05 px of the RPC's error times the image's grey gradient (the scene's: < 40 grey levels per px)
    assert np.max(np.abs(new[both] - ortho_f[both])) < 0.05 * 40


def test_orthorectify_pushbroom_sensor(broom):
    cam, bs, dem, image = broom
    with _quiet():
        new, g = orthorectify(image, bs, dem, resolution=20.0)
        old, g_old = orthorectify(image, None, cam, dem, resolution=20.0)
    # the same grid; its CRS the sensor's (as WKT) where the older call names the UTM zone by its code
    assert (g.transform, g.shape) == (g_old.transform, g_old.shape) and g.crs == bs.crs
    assert same_crs(g.crs, g_old.crs) and g_old.crs == ptx.utm_crs(*cam.ground_box()[0])
    assert np.array_equal(new, old, equal_nan=True) and np.isfinite(new).mean() > 0.3


def test_a_sensor_in_another_crs_is_refused(frame, rpc):
    scene, dem, fs = frame
    grid = ortho_grid(fs, dem, 20.0)
    other = ptx.Grid(grid.transform, grid.shape, "EPSG:32634")
    with pytest.raises(CRSMismatchError, match="EPSG:32633"):
        orthorectify(scene.image, rpc[1], dem, other)
    with pytest.raises(CRSMismatchError, match="the DEM"):
        orthorectify(scene.image, FrameSensor(scene.exterior, scene.camera, "EPSG:32634"), dem)


# --- the footprint: ortho_grid and the ground sampling distance -------------------


def test_footprint_of_each_kind(frame, rpc, broom):
    scene, dem, fs = frame
    assert ortho_grid(fs, dem, 20.0) == ortho_grid(scene.exterior, scene.camera, dem, 20.0)
    gsd = ground_sampling_distance(fs, dem)
    assert gsd == ground_sampling_distance(scene.exterior, scene.camera, dem)
    rs = rpc[1]
    g_f, g_r = ortho_grid(fs, dem, 20.0), ortho_grid(rs, dem, 20.0)
    assert g_r.crs == rs.crs and np.allclose(tuple(g_r.transform)[:6], tuple(g_f.transform)[:6], atol=20.0)
    assert abs(g_r.shape[0] - g_f.shape[0]) <= 1 and abs(g_r.shape[1] - g_f.shape[1]) <= 1
    assert ground_sampling_distance(rs, dem) == pytest.approx(gsd, rel=1e-3)  # the same footprint
    cam, bs, bdem, _ = broom
    g_new, g_old = ortho_grid(bs, bdem, 20.0), ortho_grid(None, cam, bdem, 20.0)
    assert (g_new.transform, g_new.shape) == (g_old.transform, g_old.shape) and same_crs(g_new.crs, g_old.crs)
    assert ground_sampling_distance(bs, bdem) == ground_sampling_distance(None, cam, bdem, crs=bs.crs)


# --- the ortho sigma map -----------------------------------------------------------


def test_ortho_uncertainty_of_each_kind(frame, rpc, broom):
    scene, dem, fs = frame
    grid = ortho_grid(fs, dem, 20.0)
    cov = np.diag([0.5, 0.5, 0.5, 1e-4, 1e-4, 1e-4]) ** 2
    new = ptx.ortho_uncertainty(fs, cov, dem, grid, dem_sigma=1.0, coarsen=2)
    old = ptx.ortho_uncertainty(scene.exterior, cov, scene.camera, dem, grid, dem_sigma=1.0, coarsen=2)
    assert np.array_equal(new.image_var, old.image_var, equal_nan=True)
    assert np.array_equal(new.ground_var, old.ground_var, equal_nan=True)

    rcov = np.diag([0.3, 1e-5, 1e-5, 0.3, 1e-5, 1e-5]) ** 2  # pixels (a0..b2)
    r_new = ptx.ortho_uncertainty(rpc[1], rcov, dem, grid, coarsen=2)
    r_old = ptx.ortho_uncertainty(None, rcov, rpc[0], dem, grid, coarsen=2)
    assert np.array_equal(r_new.image_var, r_old.image_var, equal_nan=True)
    seen = np.isfinite(r_new.image_var[0])
    assert seen.mean() > 0.5  # a shift of 0.3 px is 0.3 px everywhere (plus the tiny drift terms)
    assert np.allclose(np.sqrt(r_new.image_var[0][seen]), 0.3, rtol=0.1)

    cam, bs, bdem, _ = broom
    bgrid = ortho_grid(bs, bdem, 20.0)
    p = len(cam.parameter_names)
    bcov = np.eye(p) * 1e-12
    b_new = ptx.ortho_uncertainty(bs, bcov, bdem, bgrid, coarsen=2)
    b_old = ptx.ortho_uncertainty(None, bcov, cam, bdem, bgrid, coarsen=2)
    assert np.array_equal(b_new.ground_var, b_old.ground_var, equal_nan=True)
    assert np.isfinite(b_new.ground_var).mean() > 0.3


def test_sensor_of_passes_a_sensor_through(frame, rpc):
    scene, dem, fs = frame
    assert sensor_of(None, fs) is fs and sensor_of(None, rpc[1]) is rpc[1]
