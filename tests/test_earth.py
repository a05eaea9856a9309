"""Earth curvature and atmospheric refraction for frame images (issue 23, item 5): the image-space
corrections against a synthetic frame imaged in true 3-D geometry (pyproj's ellipsoid) and against a
ray trace through the ICAO standard atmosphere; a resection in a map projection with the corrections
equals one in a local ENU frame."""

import numpy as np
import pytest

from photax.camera import FrameCamera
from photax.collinearity import ExteriorOrientation, project
from photax.earth import ImageCorrections, LocalFrame, correct_image, radii_of_curvature, refraction_coefficient
from photax.resection import resect

pyproj = pytest.importorskip("pyproj")

LON0, LAT0, H = 10.0, 45.0, 5000.0  # the camera 5,000 m above the ellipsoid over (LON0, LAT0)
F_PX = 5000.0  # 1 m pixels on the ground at the nadir: +-10 km is +-10,000 px
CAMERA = FrameCamera.from_pixels(F_PX, (20001, 20001))
FRAME = LocalFrame(LON0, LAT0, 0.0)


def _aeqd_to_geographic(e, n):
    """Azimuthal equidistant map about the nadir (distances from it kept on the ellipsoid)."""
    t = pyproj.Transformer.from_crs(f"+proj=aeqd +lat_0={LAT0} +lon_0={LON0} +ellps=WGS84 +units=m", "EPSG:4326",
                                    always_xy=True)  # fmt: skip
    return t.transform(e, n)


@pytest.mark.parametrize("angles", [(0.0, 0.0, 0.0), (0.12, -0.08, 0.4)], ids=["vertical", "tilted"])
def test_curvature_displacement_of_a_synthetic_frame(angles):
    e, n = (a.ravel() for a in np.meshgrid(np.linspace(-10e3, 10e3, 21), np.linspace(-10e3, 10e3, 21)))
    h = np.where(np.arange(e.size) % 2 == 0, 0.0, 600.0)
    lon, lat = _aeqd_to_geographic(e, n)
    enu = FRAME.from_geographic(lon, lat, h)
    ext = ExteriorOrientation([0.0, 0.0, H], angles)
    true_xy = np.asarray(project(enu, ext, CAMERA))  # what the camera sees: the earth is curved
    map_xy = np.asarray(project(np.column_stack([e, n, h]), ext, CAMERA))  # what the map frame predicts
    fixed = correct_image(true_xy, ext, CAMERA, h, ImageCorrections(earth_curvature=True, latitude=LAT0))
    shift = np.hypot(*(map_xy - true_xy).T)
    assert shift.max() > 10.0  # the displacement is large (px) ...
    np.testing.assert_allclose(fixed, map_xy, atol=1e-3)  # ... and removed to 1e-3 px
    if angles == (0.0, 0.0, 0.0):
        # the textbook's first-order formula dr = H r^3 / (2 R f^2) at ground height 0, Gauss's mean radius:
        # its neglected terms are of relative order S^2 / (R H) (S the ground distance): 0.7 % at the corners
        # here (14 km)
        m, nn = radii_of_curvature(LAT0)
        r = np.hypot(*true_xy.T)
        textbook = (H - h) * r**3 / (2.0 * np.sqrt(m * nn) * F_PX**2)
        flat = h == 0
        np.testing.assert_allclose(shift[flat], textbook[flat], rtol=1e-2, atol=1e-6)


def _icao_ray_trace(theta_camera, big_h, h):
    """Nadir angle of the straight chord camera -> ground point, for a ray leaving the camera at
    ``theta_camera``: Snell's law in flat layers (``n sin theta`` constant) through the ICAO standard
    atmosphere, the pressure from the hydrostatic equation integrated numerically (independent of the
    closed forms in photax.earth)."""
    from scipy import integrate

    g, m, r, lapse, t0, p0 = 9.80665, 0.0289644, 8.31446, 0.0065, 288.15, 1013.25

    def temperature(z):
        return t0 - lapse * z

    sol = integrate.solve_ivp(lambda z, p: -p * g * m / (r * temperature(z)), (0.0, big_h), [p0], rtol=1e-12,
                              atol=1e-12, dense_output=True)  # fmt: skip

    def n(z):
        return 1.0 + 77.6e-6 * sol.sol(z)[0] / temperature(z)

    invariant = n(big_h) * np.sin(theta_camera)
    dist = integrate.quad(lambda z: np.tan(np.arcsin(invariant / n(z))), h, big_h, epsabs=1e-10, epsrel=1e-13)[0]
    return np.arctan(dist / (big_h - h))


@pytest.mark.parametrize("ground", [0.0, 800.0])
def test_refraction_matches_a_ray_trace(ground):
    theta = np.radians([5.0, 20.0, 35.0, 50.0, 60.0])
    observed = np.column_stack([F_PX * np.tan(theta), np.zeros(5)])  # a vertical image, points along x
    straight = F_PX * np.tan([_icao_ray_trace(t, H, ground) for t in theta])
    ext = ExteriorOrientation([0.0, 0.0, H], [0.0, 0.0, 0.0])
    fixed = correct_image(observed, ext, CAMERA, ground, ImageCorrections(refraction="icao"))
    assert np.max(observed[:, 0] - straight) > 1.0  # refraction pushes points outwards by px here
    np.testing.assert_allclose(fixed[:, 0], straight, atol=1e-3)
    np.testing.assert_allclose(fixed[:, 1], 0.0, atol=1e-9)
    # the textbook's dr = K (r + r^3/f^2) with the same K
    k = refraction_coefficient(H, ground, "icao")
    r = observed[:, 0]
    np.testing.assert_allclose(r - straight, k * (r + r**3 / F_PX**2), atol=1e-3)
    if ground == 0.0:  # Bertram's formula was fitted to another model atmosphere (ARDC): close, not equal
        assert abs(refraction_coefficient(H, ground, "bertram") / k - 1.0) < 0.05


def test_refraction_bad_input():
    with pytest.raises(ValueError, match="above the ground"):
        refraction_coefficient(100.0, 200.0)
    with pytest.raises(ValueError, match="model"):
        refraction_coefficient(5000.0, 0.0, "saastamoinen")
    with pytest.raises(ValueError, match="refraction"):
        ImageCorrections(refraction="nope")


def test_local_frame_round_trip_and_axes():
    rng = np.random.default_rng(0)
    lon, lat, h = LON0 + rng.uniform(-0.2, 0.2, 20), LAT0 + rng.uniform(-0.2, 0.2, 20), rng.uniform(0, 3000, 20)
    enu = FRAME.from_geographic(lon, lat, h)
    np.testing.assert_allclose(FRAME.to_geographic(enu), np.column_stack([lon, lat, h]), atol=1e-9)
    # the E, N, U axes: 1 m up is +1 in U, a point due north has E = 0
    np.testing.assert_allclose(FRAME.from_geographic(LON0, LAT0, 1.0), [0.0, 0.0, 1.0], atol=1e-9)
    assert abs(FRAME.from_geographic(LON0, LAT0 + 0.1, 0.0)[0]) < 1e-6
    utm = FRAME.to_crs("EPSG:32632", enu)
    np.testing.assert_allclose(FRAME.from_crs("EPSG:32632", utm[:, 0], utm[:, 1], utm[:, 2]), enu, atol=1e-6)


def test_resection_in_a_map_projection_equals_one_in_enu():
    """The same noisy observations of a frame over +-9 km, with refraction, resected (a) in the local ENU
    frame with refraction corrected, (b) in a transverse Mercator map (scale 1 on the nadir's meridian,
    ellipsoidal heights) with earth curvature and refraction corrected: (b) taken to ENU equals (a)."""
    rng = np.random.default_rng(4)
    k = 30
    e, n = rng.uniform(-9e3, 9e3, k), rng.uniform(-9e3, 9e3, k)
    h = rng.uniform(0.0, 700.0, k)
    lon, lat = _aeqd_to_geographic(e, n)
    enu = FRAME.from_geographic(lon, lat, h)
    tm = f"+proj=tmerc +lat_0={LAT0} +lon_0={LON0} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m"
    x, y = pyproj.Transformer.from_crs("EPSG:4326", tm, always_xy=True).transform(lon, lat)
    map_ground = np.column_stack([x, y, h])
    truth = ExteriorOrientation([0.0, 0.0, H], [0.03, -0.02, 0.5])
    straight = np.asarray(project(enu, truth, CAMERA))
    refr = ImageCorrections(refraction="icao")
    observed = straight.copy()
    for _ in range(6):  # the refracted image: the point whose correction is the straight ray's
        observed += straight - correct_image(observed, truth, CAMERA, enu[:, 2], refr)
    observed += rng.normal(0.0, 0.2, observed.shape)
    a = resect(observed, enu, CAMERA, sigma=0.2, corrections=refr)
    both = ImageCorrections(earth_curvature=True, refraction="icao", latitude=LAT0)
    b = resect(observed, map_ground, CAMERA, sigma=0.2, corrections=both)
    plain = resect(observed, map_ground, CAMERA, sigma=0.2, robust=False)
    assert a.converged and b.converged and b.corrections == both and a.corrections.names == ("refraction (icao)",)
    assert "earth curvature, refraction (icao)" in b.summary()
    # (a) recovers the truth within its precision
    assert np.all(np.abs(np.asarray(a.exterior.position) - [0.0, 0.0, H]) < 3 * a.std[:3])
    # (b) in ENU: the camera's geographic position from the map, then ENU
    xb, yb, zb = np.asarray(b.exterior.position)
    lon_b, lat_b = pyproj.Transformer.from_crs(tm, "EPSG:4326", always_xy=True).transform(xb, yb)
    b_enu = FRAME.from_geographic(lon_b, lat_b, zb)
    diff = b_enu - np.asarray(a.exterior.position)
    assert np.all(np.abs(diff) < 0.1 * a.std[:3]), (diff, a.std[:3])  # far inside their precision (cm)
    np.testing.assert_allclose(np.asarray(b.exterior.rotation), np.asarray(a.exterior.rotation), atol=1e-6)
    # without the corrections the map resection is metres off and fits worse
    xp, yp, zp = np.asarray(plain.exterior.position)
    lon_p, lat_p = pyproj.Transformer.from_crs(tm, "EPSG:4326", always_xy=True).transform(xp, yp)
    assert np.max(np.abs(FRAME.from_geographic(lon_p, lat_p, zp) - np.asarray(a.exterior.position))) > 1.0
    assert plain.rmse > 3 * b.rmse


def test_cli_resect_with_corrections_matches_the_api(tmp_path, capsys):
    """``photax resect --earth-curvature --refraction icao`` on GCPs in UTM: the report names the
    corrections and the JSON holds the API's result with the latitude taken from the GCPs' CRS."""
    import json

    from photax.cli import main

    rng = np.random.default_rng(5)
    lon, lat = _aeqd_to_geographic(rng.uniform(-8e3, 8e3, 12), rng.uniform(-8e3, 8e3, 12))
    h = rng.uniform(0.0, 500.0, 12)
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(lon, lat)
    xs, ys = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(LON0, LAT0)
    ground = np.column_stack([x, y, h])
    truth = ExteriorOrientation([xs, ys, H], [0.02, 0.01, 0.2])
    pix = np.asarray(CAMERA.image_to_pixel(project(ground, truth, CAMERA))) + rng.normal(0, 0.3, (12, 2))
    rows = [f"P{i},img,{e:.4f},{n:.4f},{z:.4f},{c:.4f},{r:.4f}" for i, (e, n, z, c, r) in
            enumerate(np.column_stack([ground, pix]))]  # fmt: skip
    gcps = tmp_path / "gcps.csv"
    gcps.write_text("# crs: EPSG:32632\nname,image,E,N,h,col,row\n" + "\n".join(rows) + "\n")
    cam = tmp_path / "camera.yaml"
    cam.write_text(f"focal_length_px: {F_PX}\nimage_size: [20001, 20001]\n")
    out = tmp_path / "r.json"
    args = ["resect", str(gcps), "--camera", str(cam), "--earth-curvature", "--refraction", "icao", "-o", str(out)]
    assert main([*args, "--no-progress"]) == 0
    assert "image corrected for earth curvature, refraction (icao)" in capsys.readouterr().out
    got = json.loads(out.read_text())["images"]["img"]
    assert got["corrections"] == ["earth curvature", "refraction (icao)"]
    latitude = pyproj.Transformer.from_crs("EPSG:32632", "EPSG:4326", always_xy=True).transform(*ground[:, :2].mean(0))[
        1
    ]
    want = resect(np.asarray(CAMERA.pixel_to_image(pix)), ground, CAMERA,
                  corrections=ImageCorrections(earth_curvature=True, refraction="icao", latitude=latitude))  # fmt: skip
    np.testing.assert_allclose(got["position"], np.asarray(want.exterior.position), atol=1e-6)
    plain = resect(np.asarray(CAMERA.pixel_to_image(pix)), ground, CAMERA)
    assert np.max(np.abs(np.asarray(plain.exterior.position) - got["position"])) > 0.5  # the option did something
