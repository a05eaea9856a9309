"""Readers of other tools' orientation files (issue 22): OpenSfM/ODM
``reconstruction.json``, orthority's brown/opencv interiors, exterior GeoJSON and
latitude/longitude/roll/pitch/yaw CSV.

References: OpenCV's ``projectPoints`` and PROJ's own topocentric conversion on
synthetic scenes (always run); orthority 0.7's readers, cameras and ``oty odm``
on the real files of ``../shared/data/orthority`` (skipped when absent).
"""

from __future__ import annotations

import json
import pathlib
import shutil
import subprocess
import sys
import warnings

import cv2
import numpy as np
import pyproj
import pytest
from conftest import shared_file

import photax
from photax.io import read_exteriors, read_interior
from photax.io.crs import same_crs
from photax.io.opensfm import read_opensfm_cameras, read_opensfm_shots
from photax.io.orientation import camera_in_pixels, read_camera_unit
from photax.io.orthority import read_orthority_exterior_crs, read_orthority_interior

REF = (24.6809, 120.9506, 12.0)  # the ODM test data's area: 2 degrees west of UTM 51's meridian
BROWN = dict(
    projection_type="brown",
    width=1368,
    height=912,
    focal_x=0.6664,
    focal_y=0.6701,
    c_x=-0.0015,
    c_y=0.0047,
    k1=-0.264,
    k2=0.1019,
    p1=0.00073,
    p2=0.00026,
    k3=-0.0258,
)


def _topocentric(lat, lon, h):
    """PROJ's topocentric conversion at REF (independent of photax.io._geo)."""
    t = pyproj.Transformer.from_pipeline(
        "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad +step +proj=cart +ellps=WGS84 "
        f"+step +proj=topocentric +ellps=WGS84 +lat_0={REF[0]} +lon_0={REF[1]} +h_0={REF[2]}"
    )
    return np.stack(t.transform(lon, lat, h), axis=-1)


def _k_and_dist(p):
    m = max(p["width"], p["height"])
    k = np.array(
        [
            [p["focal_x"] * m, 0, (p["width"] - 1) / 2 + p["c_x"] * m],
            [0, p["focal_y"] * m, (p["height"] - 1) / 2 + p["c_y"] * m],
            [0, 0, 1],
        ]
    )
    return k, np.array([p["k1"], p["k2"], p["p1"], p["p2"], p["k3"]])


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """Three shots over ground points given in latitude/longitude, their pixels by OpenCV."""
    rng = np.random.default_rng(3)
    ground = np.c_[
        REF[0] + rng.uniform(-8e-4, 8e-4, 60), REF[1] + rng.uniform(-8e-4, 8e-4, 60), rng.uniform(20, 60, 60)
    ]
    cams = [(REF[0] + 5e-4, REF[1] - 6e-4, 160.0), (REF[0] - 4e-4, REF[1] + 3e-4, 150.0), (REF[0], REF[1], 170.0)]
    shots, pixels = {}, {}
    g_topo = _topocentric(*ground.T)
    for j, lla in enumerate(cams):
        c = _topocentric(*lla)
        # look down at the ground centre: OpenCV frame (x right, y down, z forward)
        z = g_topo.mean(0) - c
        z /= np.linalg.norm(z)
        x = np.cross([np.sin(j), np.cos(j), 0.0], z)
        x /= np.linalg.norm(x)
        r = np.stack([x, np.cross(z, x), z])
        rvec, t = cv2.Rodrigues(r)[0].ravel(), -r @ c
        k, dist = _k_and_dist(BROWN)
        pixels[f"img{j}"] = cv2.projectPoints(g_topo, rvec, t, k, dist)[0][:, 0]
        shots[f"img{j}.JPG"] = {
            "rotation": rvec.tolist(),
            "translation": t.tolist(),
            "camera": "v2 cam",
            "gps_position": (c + rng.normal(0, 0.05, 3)).tolist(),
        }
    rec = [
        {
            "cameras": {"v2 cam": BROWN},
            "shots": shots,
            "reference_lla": dict(zip(("latitude", "longitude", "altitude"), REF)),
        }
    ]
    path = tmp_path_factory.mktemp("osfm") / "reconstruction.json"
    path.write_text(json.dumps(rec))
    # A conformal CRS with scale 1 at REF and 0.84 degrees of meridian convergence there.
    crs = f"+proj=lcc +lat_1={REF[0]} +lat_0={REF[0]} +lon_0={REF[1] + 2} +k_0=1 +ellps=WGS84 +units=m"
    xyz = np.stack(
        pyproj.Transformer.from_crs("EPSG:4979", crs, always_xy=True).transform(
            ground[:, 1], ground[:, 0], ground[:, 2]
        ),
        axis=-1,
    )
    return dict(path=path, crs=crs, ground=xyz, pixels=pixels)


PERSPECTIVE = {"projection_type": "perspective", "width": 900, "height": 1200, "focal": 0.81, "k1": -0.12, "k2": 0.03}


@pytest.mark.parametrize("model", ["brown", "perspective"])
def test_opensfm_camera_projects_as_opencv(synthetic, tmp_path, model):
    """In OpenSfM's units (normalised by max(width, height), here once by the height)."""
    params = BROWN if model == "brown" else PERSPECTIVE
    rec = json.loads(synthetic["path"].read_text())
    rec[0]["cameras"]["v2 cam"] = params
    path = tmp_path / "rec.json"
    path.write_text(json.dumps(rec))
    camera = read_opensfm_cameras(path)["cam"]
    full = {
        "focal_x": params.get("focal"),
        "focal_y": params.get("focal"),
        "c_x": 0.0,
        "c_y": 0.0,
        "k3": 0.0,
        "p1": 0.0,
        "p2": 0.0,
        **params,
    }
    k, dist = _k_and_dist(full)
    pts = np.random.default_rng(0).normal(0, 1, (50, 3)) + [0, 0, 4]  # OpenCV camera frame, in front
    ref = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), k, dist)[0][:, 0]
    ours = np.asarray(camera.image_to_pixel(camera.project(pts * [1, -1, -1])))  # photax frame: y up, z back
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize("frame, tol", [(None, 0.05), ("topocentric", 0.05), ("grid", None)])
def test_opensfm_shots_put_ground_points_on_their_pixels(synthetic, frame, tol):
    """Shots in OpenSfM's topocentric frame, read into a projected CRS with 0.84 deg
    of convergence: the ground points' projected coordinates land on OpenCV's pixels
    (tolerance: the Earth's curvature over 100 m, ~1 mm).  Read as ODM's grid-aligned
    frame they miss by pixels; the default picks the frame from gps_position."""
    camera = read_interior(synthetic["path"])
    table, _, names = read_opensfm_shots(synthetic["path"], crs=synthetic["crs"], frame=frame)
    assert set(table) == set(synthetic["pixels"]) and set(names.values()) == {"cam"}
    for name, ref in synthetic["pixels"].items():
        ours = np.asarray(camera.image_to_pixel(photax.project(synthetic["ground"], table[name], camera)))
        err = np.abs(ours - ref).max()
        assert err < tol if tol else err > 3


def test_opensfm_refusals(tmp_path, synthetic):
    rec = json.loads(synthetic["path"].read_text())
    rec[0]["cameras"]["v2 cam"] = {"projection_type": "spherical", "width": 10, "height": 10}
    bad = tmp_path / "fish.json"
    bad.write_text(json.dumps(rec))
    with pytest.raises(ValueError, match="'spherical'.*'perspective'.*'brown'.*no photax camera"):
        read_interior(bad)
    del rec[0]["cameras"]
    bad.write_text(json.dumps(rec))
    with pytest.raises(ValueError, match="fish.json: reconstruction 0 has no 'cameras'"):
        read_exteriors(bad)
    for s in rec[0]["shots"].values():
        del s["gps_position"]
    rec[0]["cameras"] = {"v2 cam": BROWN}
    bad.write_text(json.dumps(rec))
    with pytest.raises(ValueError, match="no shot has a gps_position"):
        read_exteriors(bad)
    with pytest.raises(ValueError, match="not a projected CRS"):
        read_opensfm_shots(synthetic["path"], crs="EPSG:4326")


# --- real files: ../shared/data/orthority --------------------------------------------


def _rot(eo):
    return np.asarray(eo.rotation)


def _orthority_opk_rotation(opk):
    from orthority.param_io import _opk_to_rotation

    return _opk_to_rotation(opk)


def test_odm_reconstruction_as_orthority_reads_it():
    """ODM's shots are in a grid-aligned frame (module docstring of photax.io.opensfm):
    photax chooses it from gps_position and then agrees with orthority's reader; the
    cameras project as orthority's do."""
    from orthority.camera import create_camera
    from orthority.param_io import OsfmReader

    path = shared_file("orthority/odm/opensfm/reconstruction.json")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = OsfmReader(path)
        int_param, ext_param = reader.read_int_param(), reader.read_ext_param()
        table, crs = read_exteriors(path)
        assert crs == reader.crs.to_string() == "EPSG:32651"
        camera = read_interior(path)
        for name, e in ext_param.items():
            np.testing.assert_allclose(np.asarray(table[name].position), e["xyz"], rtol=0, atol=1e-6)
            np.testing.assert_allclose(_rot(table[name]), _orthority_opk_rotation(e["opk"]), rtol=0, atol=1e-12)
            ref_cam = create_camera(**int_param[e["camera"]], xyz=e["xyz"], opk=e["opk"])
            ji = np.random.default_rng(0).uniform([0, 0], [1367, 911], (100, 2))
            xyz = ref_cam.pixel_to_world_z(ji.T, 80.0).T
            ours = np.asarray(camera.image_to_pixel(photax.project(xyz, table[name], camera)))
            np.testing.assert_allclose(ours, ref_cam.world_to_pixel(xyz.T).T, rtol=0, atol=1e-8)


def test_odm_gps_positions_are_topocentric():
    """The shots' gps_position (OpenSfM's topocentric frame) converted by photax.io._geo
    land on the same GNSS fixes of odm_lla_rpy.csv projected to UTM, to their
    rounding (8 decimals of a degree, 2 of a metre): the exact conversion is right,
    and the ~2 m between gps_position and the shots is ODM's frame, not photax's."""
    import pyproj

    from photax.geo import utm_crs
    from photax.io._geo import project_lla, topocentric_to_projected

    rec = json.loads(shared_file("orthority/odm/opensfm/reconstruction.json").read_text())[0]
    ref = [rec["reference_lla"][k] for k in ("latitude", "longitude", "altitude")]
    crs = pyproj.CRS(utm_crs(lon=ref[1], lat=ref[0]))
    lines = shared_file("orthority/io/odm_lla_rpy.csv").read_text().splitlines()[1:]
    fixes = {ln.split()[0].split(".")[0]: [float(v) for v in ln.split()[1:4]] for ln in lines}
    for name, shot in rec["shots"].items():
        ours = topocentric_to_projected(np.array(shot["gps_position"]), ref, crs)[0]
        truth = project_lla(*fixes[name], crs)
        np.testing.assert_allclose(ours[:2], truth[:2], rtol=0, atol=0.005)
        assert abs(ours[2] - truth[2]) < 0.006


# photax's orthos of the four images against ``oty odm`` (grey levels and geometric offset):
# tests/test_real_block.py::test_drone_orthos_match_oty_odm.


@pytest.mark.parametrize("kind", ["brown", "opencv"])
def test_orthority_brown_and_opencv_interiors_project_as_orthority(tmp_path, kind):
    from orthority.camera import create_camera
    from orthority.enums import CameraType

    params = {
        "im_size": (1368, 912),
        "focal_len": 0.6664,
        "cx": -0.0015,
        "cy": 0.0047,
        "k1": -0.264,
        "k2": 0.1019,
        "p1": 0.00073,
        "p2": 0.00026,
        "k3": -0.0258,
    }
    text = f"drone:\n  type: {kind}\n" + "".join(
        f"  {k}: {list(v) if isinstance(v, tuple) else v}\n" for k, v in params.items()
    )
    path = tmp_path / "int.yaml"
    path.write_text(text + ("  k4: 0.0\n  s1: 0\n" if kind == "opencv" else ""))
    camera = read_interior(path)
    xyz, opk = (10.0, 20.0, 150.0), tuple(np.radians([5.0, -8.0, 30.0]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # orthority: no sensor_size
        ref_cam = create_camera(CameraType(kind), **params, xyz=xyz, opk=opk)
    ground = np.c_[np.random.default_rng(1).uniform(-60, 80, (100, 2)), np.zeros(100)]
    ext = photax.ExteriorOrientation(xyz, opk, "omega-phi-kappa")
    ours = np.asarray(camera.image_to_pixel(photax.project(ground, ext, camera)))
    np.testing.assert_allclose(ours, ref_cam.world_to_pixel(ground.T).T, rtol=0, atol=1e-8)
    assert np.ptp(ours[:, 0]) > 300
    if kind == "opencv":
        path.write_text(text + "  tx: 0.01\n")  # the tilt: no photax model (k4 ... s4 are read)
        with pytest.raises(ValueError, match=r"opencv parameters \['tx'\] are not zero"):
            read_orthority_interior(path)


def test_orthority_geojson_as_orthority_reads_it():
    from orthority.param_io import OtyReader

    path = shared_file("orthority/io/ngi_ext_param.geojson")
    table, crs = read_exteriors(path)
    ref = OtyReader(path)
    assert pyproj.CRS(crs) == pyproj.CRS(ref.crs.to_wkt())
    for name, e in ref.read_ext_param().items():
        np.testing.assert_allclose(np.asarray(table[name].position), e["xyz"], rtol=0, atol=0)
        np.testing.assert_allclose(_rot(table[name]), _orthority_opk_rotation(e["opk"]), rtol=0, atol=1e-12)
    # the same orientations as the exterior CSV (3 decimals there)
    csv, _ = read_orthority_exterior_crs(shared_file("orthority/io/ngi_xyz_opk.csv"))
    for name, eo in csv.items():
        np.testing.assert_allclose(np.asarray(eo.position), np.asarray(table[name].position), atol=6e-4)


def test_lla_rpy_csv_as_orthority_converts_it():
    """odm_lla_rpy.csv -> UTM positions and omega, phi, kappa with the meridian
    convergence, against orthority's CsvReader: 1e-6 m, 1e-6 deg (measured: 0 m,
    ~1e-13 deg).  (odm_xyz_opk.csv is not its conversion: it holds the SfM
    solution, 2-5 cm and 0.4-1.1 deg from the GNSS fixes and nominal attitudes.)"""
    from orthority.param_io import CsvReader

    path = shared_file("orthority/io/odm_lla_rpy.csv")
    table, crs = read_exteriors(path)
    reader = CsvReader(path)
    assert crs == reader.crs.to_string() == "EPSG:32651"
    for name, e in reader.read_ext_param().items():
        eo = table[name.split(".")[0]]
        np.testing.assert_allclose(np.asarray(eo.position), e["xyz"], rtol=0, atol=1e-6)
        ang = np.degrees(photax.convert_angles(eo.angles, eo.convention, "omega-phi-kappa"))
        np.testing.assert_allclose(ang, np.degrees(e["opk"]), rtol=0, atol=1e-6)


def test_orthority_interior_in_a_block_goes_in_pixels(tmp_path):
    """``photax ties`` writes a block whose camera file needs a unit: an orthority
    interior names none, so its camera is written in pixels, the same geometry."""
    path = shared_file("orthority/io/ngi_int_param.yaml")
    assert read_camera_unit(path) is None
    camera = read_interior(path)
    px = camera_in_pixels(camera)
    pts = np.random.default_rng(2).normal(0, 1, (20, 3)) - [0, 0, 3]
    np.testing.assert_allclose(
        np.asarray(px.image_to_pixel(px.project(pts))),
        np.asarray(camera.image_to_pixel(camera.project(pts))),
        rtol=0,
        atol=1e-9,
    )
    assert read_camera_unit(shared_file("orthority/odm/opensfm/reconstruction.json")) == "px"


def test_cli_ties_with_an_orthority_interior(tmp_path):
    """``photax ties`` with ngi_int_param.yaml (refused before: "the block's camera
    file needs a unit") writes a block whose camera, in pixels, is the file's."""
    from photax.cli import main
    from photax.io import read_block

    ngi = shared_file("orthority/ngi/dem.tif").parent
    interior = shared_file("orthority/io/ngi_int_param.yaml")
    images = [str(ngi / f"3324c_2015_1004_05_018{k}_RGB.tif") for k in (2, 4)]
    out = tmp_path / "block"
    assert (
        main(
            [
                "ties",
                *images,
                "--camera",
                str(interior),
                "--exterior",
                str(shared_file("orthority/io/ngi_xyz_opk.csv")),
                "--dem",
                str(ngi / "dem.tif"),
                "--points",
                "50",
                "-o",
                str(out),
            ]
        )
        == 0
    )
    problem = read_block(out)
    camera, block_camera = read_interior(interior), problem.cameras[0]
    assert block_camera.image_size == camera.image_size == (640, 1152)
    # the block names its ground CRS (the DEM's), so `bundle --dem` can refuse a DEM in another one
    assert problem.crs is not None
    assert same_crs(problem.crs, shared_file("orthority/io/ngi_xyz_opk.prj").read_text())
    assert not same_crs(problem.crs, "EPSG:32735")
    pts = np.random.default_rng(4).normal(0, 1, (20, 3)) - [0, 0, 3]
    np.testing.assert_allclose(
        np.asarray(block_camera.image_to_pixel(block_camera.project(pts))),
        np.asarray(camera.image_to_pixel(camera.project(pts))),
        rtol=0,
        atol=1e-9,
    )


def test_oty_exported_params_read_as_the_reconstruction(tmp_path):
    """``oty odm --export-params`` writes the reconstruction as orthority files (a
    ``brown`` interior YAML, an exterior GeoJSON): photax reads both to the same
    cameras and orientations as the reconstruction itself."""
    odm = shared_file("orthority/odm/opensfm/reconstruction.json").parents[1]
    oty = shutil.which("oty", path=str(pathlib.Path(sys.executable).parent)) or shutil.which("oty")
    if oty is None:
        pytest.skip("orthority's oty command is not installed")
    subprocess.run(
        [oty, "odm", "-dd", str(odm), "-od", str(tmp_path), "--export-params"], check=True, capture_output=True
    )
    rec = odm / "opensfm" / "reconstruction.json"
    a, b = read_interior(tmp_path / "int_param.yaml"), read_interior(rec)
    pts = np.random.default_rng(5).normal(0, 1, (50, 3)) - [0, 0, 3]
    np.testing.assert_allclose(
        np.asarray(a.image_to_pixel(a.project(pts))), np.asarray(b.image_to_pixel(b.project(pts))), rtol=0, atol=1e-9
    )
    (ta, crs_a), (tb, crs_b) = read_exteriors(tmp_path / "ext_param.geojson"), read_exteriors(rec)
    assert set(ta) == set(tb) and pyproj.CRS(crs_a) == pyproj.CRS(crs_b)
    for name in tb:
        np.testing.assert_allclose(np.asarray(ta[name].position), np.asarray(tb[name].position), atol=1e-8)
        np.testing.assert_allclose(_rot(ta[name]), _rot(tb[name]), atol=1e-12)


def test_cli_resect_takes_an_orthority_interior(tmp_path):
    """``photax resect --camera`` reads an orthority brown interior as ``ortho`` does:
    the sample camera written in orthority's units resects the sample image to the
    same orientation as the photax camera file."""
    from photax.cli import main

    data = pathlib.Path(__file__).resolve().parents[1] / "data"
    m, size = 1000, 0.0176  # max(width, height) and the pixel size, mm
    (tmp_path / "int.yaml").write_text(
        "sample:\n  type: brown\n  im_size: [1000, 750]\n  focal_len: 8.8\n  sensor_size: [17.6, 13.2]\n"
        f"  cx: {0.011 / (m * size)!r}\n  cy: {0.0066 / (m * size)!r}\n  k1: -0.02\n  k2: 0.004\n"
    )
    results = []
    for camera in (data / "sample_camera.yaml", tmp_path / "int.yaml"):
        out = tmp_path / f"{camera.stem}.json"
        assert main(["resect", str(data / "sample_gcps.csv"), "--camera", str(camera), "-o", str(out)]) == 0
        results.append(json.loads(out.read_text()))
    (a, b) = (next(iter(r["images"].values())) for r in results)
    np.testing.assert_allclose(a["position"], b["position"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(a["angles_rad"], b["angles_rad"], rtol=0, atol=1e-9)


def test_odm_reconstruction_into_another_crs():
    """``crs=`` (the ortho command passes the DEM's): ODM's shots into TWD97 / TM2
    (EPSG:3826) are the UTM ones moved by PROJ, turned by the difference of the two
    grids' meridian convergences (pyproj's factors) about the vertical."""
    path = shared_file("orthority/odm/opensfm/reconstruction.json")
    utm, crs_utm = read_exteriors(path)
    tm2, crs_tm2 = read_exteriors(path, crs="EPSG:3826")
    assert (crs_utm, crs_tm2) == ("EPSG:32651", "EPSG:3826")
    to_tm2 = pyproj.Transformer.from_crs("EPSG:32651", "EPSG:3826", always_xy=True)
    to_ll = pyproj.Transformer.from_crs("EPSG:32651", "EPSG:4326", always_xy=True)
    for name, eo in utm.items():
        x, y, z = np.asarray(eo.position)
        np.testing.assert_allclose(np.asarray(tm2[name].position), [*to_tm2.transform(x, y), z], rtol=0, atol=1e-6)
        lon, lat = to_ll.transform(x, y)
        gamma = [pyproj.Proj(c).get_factors(lon, lat).meridian_convergence for c in ("EPSG:32651", "EPSG:3826")]
        turn = _rot(tm2[name]) @ _rot(eo).T
        np.testing.assert_allclose(turn[2], [0, 0, 1], atol=1e-12)
        angle = np.degrees(np.arctan2(turn[1, 0], turn[0, 0]))
        # grid azimuths are true azimuths minus the convergence: a turn by gamma_utm - gamma_tm2 the other way
        assert abs(angle - (gamma[1] - gamma[0])) < 1e-6 and abs(angle) > 0.5
