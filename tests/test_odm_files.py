"""ODM's cameras.json and geo.txt (issue 22, photax.io.odm).

References: orthority 0.7's reader of cameras.json and its camera (the same
pixels for the same ground points); the ODM test data's reconstruction.json
(cameras.json holds its ``cameras`` object); pyproj's projection of the
geo.txt positions and orthority's conversion of the same fixes
(io/odm_lla_rpy.csv).
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pyproj
import pytest
from conftest import SHARED_DATA, fuzz_budget, shared_file

import photax
from photax.io import read_exteriors, read_interior
from photax.io.odm import odm_crs_text, read_odm_cameras, read_odm_geo
from photax.io.opensfm import read_opensfm_cameras
from photax.io.orientation import read_camera_unit

BROWN = {
    "projection_type": "brown",
    "width": 5472,
    "height": 3648,
    "focal_x": 0.6664,
    "focal_y": 0.6701,
    "c_x": -0.0015,
    "c_y": 0.0047,
    "k1": -0.264,
    "k2": 0.1019,
    "p1": 0.00073,
    "p2": 0.00026,
    "k3": -0.0258,
}


def test_cameras_json_projects_as_orthority(tmp_path):
    from orthority.camera import create_camera
    from orthority.param_io import read_osfm_int_param

    path = tmp_path / "cameras.json"
    name = "dji fc6310r 5472 3648 brown 0.6666"
    path.write_text(json.dumps({name: BROWN}))
    camera = read_interior(path)
    assert read_camera_unit(path) == "px"
    xyz, opk = (10.0, 20.0, 150.0), tuple(np.radians([5.0, -8.0, 30.0]))
    (ref_id, params), *_ = read_osfm_int_param(path).items()
    assert ref_id == name
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = create_camera(**params, xyz=xyz, opk=opk)
    ground = np.c_[np.random.default_rng(1).uniform(-60, 80, (100, 2)), np.zeros(100)]
    ext = photax.ExteriorOrientation(xyz, opk, "omega-phi-kappa")
    ours = np.asarray(camera.image_to_pixel(photax.project(ground, ext, camera)))
    np.testing.assert_allclose(ours, ref.world_to_pixel(ground.T).T, rtol=0, atol=1e-7)
    bad = dict(BROWN, projection_type="spherical")
    path.write_text(json.dumps({name: bad}))
    with pytest.raises(ValueError, match="spherical"):
        read_odm_cameras(path)


def test_cameras_json_of_the_odm_run(tmp_path):
    """The reconstruction's ``cameras`` object as ODM writes cameras.json: the same cameras."""
    rec = shared_file("orthority/odm/opensfm/reconstruction.json")
    cameras = json.loads(rec.read_text())[0]["cameras"]
    (tmp_path / "cameras.json").write_text(json.dumps(cameras))
    ours, ref = read_odm_cameras(tmp_path / "cameras.json"), read_opensfm_cameras(rec)
    assert [k.removeprefix("v2 ") for k in ours] == list(ref)
    for a, b in zip(ours.values(), ref.values()):
        for key in ("focal_length", "principal_point", "distortion", "pixel_size"):
            np.testing.assert_array_equal(np.asarray(getattr(a, key)), np.asarray(getattr(b, key)))


def test_geo_txt_geographic_and_utm(tmp_path):
    """EPSG:4326 lines (longitude first) -> the UTM zone of the points, as pyproj projects
    them and as orthority converts the same fixes; a 'WGS84 UTM 51N' file stays in EPSG:32651."""
    lla_csv = shared_file("orthority/io/odm_lla_rpy.csv")
    rows = [ln.split() for ln in lla_csv.read_text().splitlines()[1:] if ln.strip()]
    text = "EPSG:4326\n" + "".join(f"{r[0]} {r[2]} {r[1]} {r[3]} 0 0 0 0.02 0.05 label\n" for r in rows)
    (tmp_path / "geo.txt").write_text(text)
    table, crs, accuracy = read_odm_geo(tmp_path / "geo.txt")
    assert crs == "EPSG:32651"
    ref, _ = read_exteriors(lla_csv)
    t = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32651", always_xy=True)
    for r in rows:
        stem = r[0].split(".")[0]
        np.testing.assert_allclose(table[stem], np.asarray(ref[stem].position), rtol=0, atol=1e-6)
        np.testing.assert_allclose(table[stem][:2], t.transform(float(r[2]), float(r[1])), rtol=0, atol=1e-9)
        assert accuracy[stem] == (0.02, 0.05)
    utm = "WGS84 UTM 51N\n" + "".join(f"{k}.JPG {float(v[0])!r} {float(v[1])!r}\n" for k, v in table.items())
    (tmp_path / "utm.txt").write_text(utm)
    back, crs2, acc2 = read_odm_geo(tmp_path / "utm.txt")
    assert crs2 == "EPSG:32651" and acc2 == {}
    for k, v in table.items():
        np.testing.assert_array_equal(back[k][:2], v[:2])
        assert np.isnan(back[k][2])  # 2-D: no geo_z


@pytest.mark.parametrize(
    "text, match",
    [
        ("", "empty"),
        ("EPSG:4326\n", "no image positions"),
        ("EPSG:4326\na.jpg 120.9 95.0 10\n", "not a longitude, latitude"),
        ("EPSG:4326\na.jpg 120.9 24.6 x\n", "'x' is not a number"),
        ("EPSG:4326\na.jpg 120.9 24.6\na.JPG 120.9 24.6\n", "repeated"),
        ("WGS84 UTM 75N\na.jpg 1 2 3\n", "UTM zone 75"),
        ("not a crs at all\na.jpg 1 2 3\n", "not a CRS"),
        ("EPSG:4326\na.jpg 120.9 24.6 10 0 0 0 -1 1\n", "accuracies must be positive"),
    ],
)
def test_geo_txt_refusals(tmp_path, text, match):
    path = tmp_path / "geo.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=match) as exc:
        read_odm_geo(path)
    assert str(path) in str(exc.value)


def test_odm_crs_text():
    assert odm_crs_text("WGS84 UTM 16N") == "EPSG:32616"
    assert odm_crs_text("wgs84 utm 7s ") == "EPSG:32707"
    assert odm_crs_text("+proj=utm +zone=10 +datum=WGS84") == "+proj=utm +zone=10 +datum=WGS84"


def test_fuzz_read_odm_geo_and_cameras(tmp_path):
    """The readers' contract (photax.io): a sane result or a ValueError naming the file."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    geo = "EPSG:4326\na.JPG 120.95 24.68 186.5 0 0 0 0.02 0.05 x\nb.JPG 120.96 24.69 180\n"
    cams = json.dumps({"c": BROWN})
    hostile = ["nan", "-1", "0", "1e999", "9" * 400, "", "x", "WGS84 UTM 0N", "EPSG:99999", '"', "{", "null", "[]"]
    counter = iter(range(10**6))

    @settings(max_examples=fuzz_budget(80), deadline=None, database=None)  # seed: the profile's (conftest)
    @given(st.sampled_from([geo, cams]), st.lists(st.tuples(st.integers(0, 200), st.sampled_from(hostile)), max_size=3))
    def check(seed, edits):
        text = seed
        for at, value in edits:
            tokens = text.split(" ")
            tokens[at % len(tokens)] = value
            text = " ".join(tokens)
        path = tmp_path / f"f{next(counter)}{'.txt' if seed is geo else '.json'}"
        path.write_text(text)
        try:
            if seed is geo:
                table, _, acc = read_odm_geo(path)
                assert all(np.all(np.isfinite(v[:2])) for v in table.values())
                assert all(h > 0 and v > 0 for h, v in acc.values())
            else:
                for cam in read_odm_cameras(path).values():
                    assert float(cam.focal_length) > 0
        except ValueError as exc:
            assert str(path) in str(exc)

    check()


def test_geo_txt_writer_round_trips(tmp_path):
    """geo.txt written from the positions of orthority's io/odm_lla_rpy.csv (the drone's
    longitude, latitude, altitude, when the shared data is there; else synthetic ones)
    reads back: geographic -> the UTM positions pyproj gives, projected -> the same numbers."""
    from photax.io.odm import write_odm_geo

    lla_csv = SHARED_DATA / "orthority/io/odm_lla_rpy.csv"
    if lla_csv.is_file():
        rows = [ln.split() for ln in lla_csv.read_text().splitlines()[1:] if ln.strip()]
        lla = {r[0]: (float(r[2]), float(r[1]), float(r[3])) for r in rows}
    else:
        rng = np.random.default_rng(5)
        lla = {
            f"IMG_{k:04d}.JPG": (120.9 + rng.uniform(0, 0.01), 24.6 + rng.uniform(0, 0.01), 180 + k) for k in range(5)
        }
    path = write_odm_geo(tmp_path / "geo.txt", lla, "EPSG:4326")
    assert path.read_text().splitlines()[0] == "EPSG:4326"
    table, crs, acc = read_odm_geo(path)
    t = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    assert acc == {}
    for name, (lon, lat, h) in lla.items():
        stem = name.rsplit(".", 1)[0]
        np.testing.assert_allclose(table[stem][:2], t.transform(lon, lat), rtol=0, atol=1e-9)
        assert table[stem][2] == h
    # projected: the numbers come back as written, 2-D positions stay 2-D
    utm = {f"{k}.JPG": v for k, v in table.items()}
    utm[next(iter(utm))] = np.array([*next(iter(table.values()))[:2], np.nan])
    back, crs2, _ = read_odm_geo(write_odm_geo(tmp_path / "utm.txt", utm, crs))
    assert crs2 == crs
    for name, v in utm.items():
        np.testing.assert_array_equal(back[name.rsplit(".", 1)[0]], v)


@pytest.mark.parametrize(
    "positions, crs, match",
    [
        ({}, "EPSG:4326", "no positions"),
        ({"a.jpg": (1.0, np.nan, 2.0)}, "EPSG:32633", "must be finite"),
        ({"a.jpg": (1.0, 2.0, np.inf)}, "EPSG:32633", "must be finite"),
        ({"a b.jpg": (1.0, 2.0, 3.0)}, "EPSG:32633", "with spaces"),
        ({"a.jpg": (1.0, 2.0), "a.JPG": (1.0, 2.0)}, "EPSG:32633", "repeated stem"),
        ({"a.jpg": (1.0, 2.0)}, "not a crs", "not a CRS pyproj reads"),
    ],
)
def test_geo_txt_writer_refusals(tmp_path, positions, crs, match):
    from photax.io.odm import write_odm_geo

    with pytest.raises(ValueError, match=match):
        write_odm_geo(tmp_path / "geo.txt", positions, crs)
    assert not (tmp_path / "geo.txt").exists()
