"""A drone image's own position and attitude (issue 22): EXIF GPS and DJI XMP tags
(photax.io.exif) and ``photax ortho IMG --exterior exif``.

References: orthority 0.7's ExifReader on the ODM images' real tags (their
gimbal roll is 0, where its pitch + 90 body convention and photax's gimbal
frame agree); orthority's conversion of io/odm_lla_rpy.csv (the same fixes and
nominal attitudes); closed forms (degrees-minutes-seconds, the gimbal lock of
a nadir frame: roll 180 at pitch -90 is yaw + 180).
"""

from __future__ import annotations

import dataclasses
import pathlib
import warnings

import numpy as np
import pytest
import rasterio
import rasterio.errors
from conftest import SHARED_DATA, fuzz_budget, shared_file

import photax
from photax.io.exif import DroneTags, exterior_from_tags, read_drone_tags, read_exif_exteriors
from photax.io.orientation import read_exterior, read_exteriors

ODM = SHARED_DATA / "orthority" / "odm"

XMP = """<?xpacket begin="" id="W5M0MpCehiHzreSzNTczkc9d"?>
<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
<rdf:Description rdf:about="DJI Meta Data" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"
 drone-dji:AbsoluteAltitude="+120.50" drone-dji:RelativeAltitude="+80.25"
 drone-dji:GpsLatitude="-33.9" drone-dji:GpsLongtitude="18.45"
 drone-dji:GimbalRollDegree="+0.00" drone-dji:GimbalPitchDegree="-90.00" drone-dji:GimbalYawDegree="+45.0"
 drone-dji:FlightRollDegree="+1.5" drone-dji:FlightPitchDegree="-2.0" drone-dji:FlightYawDegree="+44.0"
 drone-dji:RtkFlag="50" drone-dji:RtkStdLon="0.01" drone-dji:RtkStdLat="0.02" drone-dji:RtkStdHgt="0.03">
</rdf:Description></rdf:RDF></x:xmpmeta>
<?xpacket end="w"?>"""

EXIF = {  # as GDAL writes EXIF into a TIFF's metadata (the ODM images carry theirs so)
    "EXIF_GPSLatitude": "(33) (54) (3.6)",
    "EXIF_GPSLatitudeRef": "S",
    "EXIF_GPSLongitude": "(18) (27) (0)",
    "EXIF_GPSLongitudeRef": "E",
    "EXIF_GPSAltitude": "(12.5)",
    "EXIF_GPSAltitudeRef": "0x01",
    "EXIF_FocalLength": "(8.8)",
    "EXIF_FocalLengthIn35mmFilm": "24",
    "EXIF_Make": "DJI",
}


def _image(path, exif=None, xmp=None):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        return _write(path, exif, xmp)


def _write(path, exif, xmp):
    with rasterio.open(path, "w", driver="GTiff", width=8, height=6, count=1, dtype="uint8") as ds:
        ds.write(np.zeros((1, 6, 8), np.uint8))
        if exif:
            ds.update_tags(**exif)
        if xmp:
            ds.update_tags(ns="xml:XMP", **{"xml:XMP": xmp})
    return path


def _rotation(eo):
    return np.asarray(photax.rotation_matrix(eo.angles, eo.convention))


def _opk_deg(eo):
    return np.degrees(np.asarray(photax.convert_angles(eo.angles, eo.convention, "omega-phi-kappa")))


def test_exif_gps_alone(tmp_path):
    """EXIF GPS: degrees-minutes-seconds with its hemisphere, altitude below sea level for ref 1."""
    t = read_drone_tags(_image(tmp_path / "a.tif", EXIF))
    assert t.latitude == pytest.approx(-(33 + 54 / 60 + 3.6 / 3600), abs=1e-12)
    assert t.longitude == pytest.approx(18.45, abs=1e-12)
    assert t.altitude == -12.5
    assert (t.focal_length_mm, t.focal_length_35mm, t.make, t.image_size) == (8.8, 24.0, "DJI", (8, 6))
    assert t.gimbal_rpy is None and t.flight_rpy is None
    with pytest.raises(ValueError, match="no DJI gimbal roll/pitch/yaw"):
        exterior_from_tags(t)


def test_dji_xmp_over_exif(tmp_path):
    t = read_drone_tags(_image(tmp_path / "b.tif", EXIF, XMP))
    assert (t.latitude, t.longitude, t.altitude, t.relative_altitude) == (-33.9, 18.45, 120.5, 80.25)
    assert t.gimbal_rpy == (0.0, -90.0, 45.0) and t.flight_rpy == (1.5, -2.0, 44.0)
    assert t.rtk_flag == 50 and t.rtk_std == (0.01, 0.02, 0.03)
    table, crs = exterior_from_tags(t)
    assert crs == "EPSG:32734"  # UTM 34 south
    eo = table["b"]
    # straight down, the image's top (camera y) towards the yaw, 45 degrees from true north
    r = _rotation(eo)
    np.testing.assert_allclose(r @ [0, 0, -1], [0, 0, -1], atol=1e-9)
    import pyproj

    convergence = pyproj.Proj(crs).get_factors(18.45, -33.9).meridian_convergence
    heading = np.degrees(np.arctan2(*(r @ [0, 1, 0])[:2]))  # from grid north, clockwise
    assert heading == pytest.approx(45.0 - convergence, abs=1e-6)
    # the airframe's attitude only when named; both named: different cameras
    flight = exterior_from_tags(t, "flight")[0]["b"]
    assert not np.allclose(_rotation(flight), r, atol=1e-3)
    with pytest.raises(ValueError, match="named, never guessed"):
        exterior_from_tags(t, "auto")


def test_gimbal_lock_nadir_frame_looks_down():
    """orthority #36: DJI tags some nadir frames roll +180 at pitch -90; that is the
    rotation of roll 0, yaw + 180 (gimbal lock), still looking down."""
    base = dict(path=pathlib.Path("n.jpg"), image_size=(10, 10), latitude=24.68, longitude=120.95, altitude=100.0)
    a = exterior_from_tags(DroneTags(**base, gimbal_rpy=(180.0, -90.0, 30.0)))[0]["n"]
    b = exterior_from_tags(DroneTags(**base, gimbal_rpy=(0.0, -90.0, 210.0)))[0]["n"]
    np.testing.assert_allclose(_rotation(a), _rotation(b), atol=1e-12)
    assert (_rotation(a) @ [0, 0, -1])[2] == pytest.approx(-1.0, abs=1e-12)


def test_malformed_tags_are_refused(tmp_path):
    with pytest.raises(ValueError, match="GpsLatitude"):
        read_drone_tags(_image(tmp_path / "c.tif", None, XMP.replace('"-33.9"', '"-133.9"')))
    with pytest.raises(ValueError, match="not well-formed"):
        read_drone_tags(_image(tmp_path / "d.tif", None, XMP.replace("</rdf:RDF>", "")))
    (tmp_path / "e.jpg").write_bytes(b"not an image")
    with pytest.raises(ValueError, match="not an image"):
        read_drone_tags(tmp_path / "e.jpg")
    with pytest.raises(ValueError, match="no GPS"):
        exterior_from_tags(read_drone_tags(_image(tmp_path / "f.tif")))


def _odm_images():
    if not (ODM / "images").is_dir():
        pytest.skip("../shared/data/orthority/odm is not present")
    return sorted((ODM / "images").glob("*.tif"))


def test_odm_images_as_orthority_reads_them():
    """The ODM images' DJI tags -> UTM positions and omega, phi, kappa: orthority's
    ExifReader on the same files, 1e-6 m, 1e-6 deg (measured: 0 m, 1e-14 deg); and
    odm_lla_rpy.csv (the same fixes; pitch there is gimbal pitch + 90)."""
    from orthority.param_io import ExifReader

    images = _odm_images()
    table, crs = read_exif_exteriors(images)
    reader = ExifReader(images)
    assert crs == reader.crs.to_string() == "EPSG:32651"
    for name, e in reader.read_ext_param().items():
        eo = table[pathlib.Path(name).stem]
        np.testing.assert_allclose(np.asarray(eo.position), e["xyz"], rtol=0, atol=1e-6)
        np.testing.assert_allclose(_opk_deg(eo), np.degrees(e["opk"]), rtol=0, atol=1e-6)
    csv, _ = read_exteriors(shared_file("orthority/io/odm_lla_rpy.csv"))
    for name, eo in csv.items():
        np.testing.assert_allclose(np.asarray(table[name].position), np.asarray(eo.position), atol=1e-6)
        np.testing.assert_allclose(_opk_deg(table[name]), _opk_deg(eo), atol=1e-6)


def test_exterior_exif_word(tmp_path):
    """``--exterior exif`` reads the image's tags, into the CRS asked (a DEM's)."""
    image = _odm_images()[0]
    eo, crs = read_exterior("exif", image, crs="EPSG:32651")
    table, _ = read_exif_exteriors([image], "gimbal", "EPSG:32651")
    assert crs == "EPSG:32651"
    np.testing.assert_allclose(_rotation(eo), _rotation(table[image.stem]), atol=0)
    flight, _ = read_exterior("exif:flight", image)
    assert not np.allclose(_rotation(flight), _rotation(eo), atol=1e-3)
    many, _ = read_exteriors("exif", [str(p) for p in _odm_images()])
    assert len(many) == 4


def test_cli_ortho_from_the_image_alone(tmp_path):
    """``photax ortho IMG --camera reconstruction.json --exterior exif``: the ortho
    of the orientation orthority converts from the same fixes (odm_lla_rpy.csv),
    pixel for pixel."""
    from photax.cli import main

    image = _odm_images()[0]
    camera = shared_file("orthority/odm/opensfm/reconstruction.json")
    dem = shared_file("orthority/odm/odm_dem/dsm.tif")
    argv = ["ortho", str(image), "--dem", str(dem), "--camera", str(camera), "--resolution", "0.5", "--no-progress"]
    assert main([*argv, "--exterior", "exif", "-o", str(tmp_path / "exif.tif")]) == 0
    lla = shared_file("orthority/io/odm_lla_rpy.csv")
    assert main([*argv, "--exterior", str(lla), "-o", str(tmp_path / "csv.tif")]) == 0
    with rasterio.open(tmp_path / "exif.tif") as a, rasterio.open(tmp_path / "csv.tif") as b:
        assert a.crs == b.crs and a.transform == b.transform
        x, y = a.read(), b.read()
    assert (x != 0).mean() > 0.2
    np.testing.assert_array_equal(x, y)


HOSTILE = ["nan", "-1", "0", "1e999", "-1e999", "9" * 400, "", "abc", "+", "(1) (2) (3) (4)", "0x02", "&amp;", "<"]


def test_fuzz_read_drone_tags(tmp_path):
    """The readers' contract (photax.io): a sane result or a ValueError naming the
    file, whatever the tags hold (hostile values in every DJI and EXIF field)."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    fields = [m.group(1) for m in __import__("re").finditer(r'drone-dji:(\w+)="', XMP)]
    counter = iter(range(10**6))

    @settings(max_examples=fuzz_budget(60), deadline=None, database=None)  # seed: the profile's (conftest)
    @given(st.dictionaries(st.sampled_from(fields + list(EXIF)), st.sampled_from(HOSTILE), max_size=4))
    def check(changes):
        import re

        xmp, exif = XMP, dict(EXIF)
        for key, value in changes.items():
            if key in exif:
                exif[key] = value
            else:
                xmp = re.sub(rf'drone-dji:{key}="[^"]*"', f'drone-dji:{key}="{value}"', xmp)
        path = _image(tmp_path / f"f{next(counter)}.tif", exif, xmp)
        try:
            t = read_drone_tags(path)
        except ValueError as exc:
            assert str(path) in str(exc)
            return
        for v in (t.latitude, t.longitude, t.altitude, *(t.gimbal_rpy or ()), *(t.flight_rpy or ())):
            assert v is None or np.isfinite(v)
        try:
            table, _ = exterior_from_tags(t)
        except ValueError as exc:
            assert str(path) in str(exc)
            return
        assert np.all(np.isfinite(np.asarray(table[path.stem].position)))

    check()


def test_camera_from_tags_as_orthority_builds_it():
    """DJI DewarpData -> a brown camera, against orthority's ExifReader camera: the same
    pixels for the same ground points (1e-6 px)."""
    from orthority.camera import create_camera
    from orthority.param_io import ExifReader

    from photax.io.exif import camera_from_tags

    image = _odm_images()[0]
    camera = camera_from_tags(read_drone_tags(image))
    (_, params), *_ = ExifReader([image]).read_int_param().items()
    xyz, opk = (10.0, 20.0, 150.0), tuple(np.radians([5.0, -8.0, 30.0]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = create_camera(**params, xyz=xyz, opk=opk)
    ground = np.c_[np.random.default_rng(1).uniform(-60, 80, (100, 2)), np.zeros(100)]
    eo = photax.ExteriorOrientation(xyz, opk, "omega-phi-kappa")
    ours = np.asarray(camera.image_to_pixel(photax.project(ground, eo, camera)))
    np.testing.assert_allclose(ours, ref.world_to_pixel(ground.T).T, rtol=0, atol=1e-6)
    assert np.ptp(ours[:, 0]) > 300
    with pytest.raises(ValueError, match="no DJI DewarpData"):
        camera_from_tags(DroneTags(pathlib.Path("x.jpg"), (10, 10)))


def test_cli_ortho_camera_and_exterior_exif_match_oty_exif(tmp_path):
    """``photax ortho IMG --camera exif --exterior exif --dem dsm.tif``: the ortho from the
    image alone, against ``oty exif`` on the same image (bilinear, lossless): mean
    absolute difference <= 0.3 grey levels, no offset."""
    import shutil
    import subprocess
    import sys

    from photax.cli import main

    oty = shutil.which("oty", path=str(pathlib.Path(sys.executable).parent)) or shutil.which("oty")
    if oty is None:
        pytest.skip("orthority's oty command is not installed")
    image = _odm_images()[0]
    dem = shared_file("orthority/odm/odm_dem/dsm.tif")
    out = tmp_path / "oty"
    out.mkdir()
    args = ["-d", str(dem), "-od", str(out), "-r", "0.4", "-ap", "-i", "bilinear", "-di", "bilinear"]
    subprocess.run([oty, "exif", *args, "-cm", "deflate", "-nwm", "-o", str(image)], check=True, capture_output=True)
    ours = tmp_path / "ours.tif"
    argv = ["ortho", str(image), "--camera", "exif", "--exterior", "exif", "--dem", str(dem)]
    assert main([*argv, "--resolution", "0.4", "--no-progress", "-o", str(ours)]) == 0
    with rasterio.open(ours) as a, rasterio.open(out / f"{image.stem}_ORTHO.tif") as b:
        assert a.crs == b.crs
        from rasterio.windows import from_bounds

        left, top = max(a.bounds.left, b.bounds.left), min(a.bounds.top, b.bounds.top)
        right, bottom = min(a.bounds.right, b.bounds.right), max(a.bounds.bottom, b.bounds.bottom)
        wa = from_bounds(left, bottom, right, top, a.transform).round_offsets().round_lengths()
        wb = from_bounds(left, bottom, right, top, b.transform).round_offsets().round_lengths()
        x, y = a.read(window=wa).astype(float), b.read(window=wb).astype(float)
    both = (x != 0).any(0) & (y != 0).any(0)
    assert both.sum() > 0.8 * min((x != 0).any(0).sum(), (y != 0).any(0).sum())
    d = (x - y)[:, both]
    print(f"mean |d| {np.abs(d).mean():.3f}, mean d {d.mean():+.3f}")
    assert np.abs(d).mean() <= 0.3, np.abs(d).mean()
    assert abs(d.mean()) < 0.05


def test_multi_image_commands_take_exterior_exif(tmp_path):
    """``photax ties`` / ``transfer`` ``--exterior exif`` (cli._common.read_oriented_images):
    the images' tags, in the DEM's CRS, as read_exif_exteriors gives them."""
    import argparse

    from photax.cli._common import read_oriented_images

    images = [str(p) for p in _odm_images()[:2]]
    rec = shared_file("orthority/odm/opensfm/reconstruction.json")
    dem = shared_file("orthority/odm/odm_dem/dsm.tif")
    args = argparse.Namespace(images=images, camera=str(rec), exterior="exif", dem=str(dem), out=str(tmp_path / "b"))
    files, _, names, _, exterior = read_oriented_images(args, [])
    assert "exif" not in files
    with rasterio.open(dem) as src:
        table, _ = read_exif_exteriors(images, "gimbal", src.crs.to_wkt())
    for name, eo in zip(names, exterior):
        np.testing.assert_array_equal(np.asarray(eo.position), np.asarray(table[name].position))
        np.testing.assert_array_equal(_rotation(eo), _rotation(table[name]))


def test_dji_jpeg(tmp_path):
    """A JPEG as a DJI drone writes it: EXIF in its APP1 segment (GDAL's JPEG driver
    writes the ODM image's), the DJI XMP packet in another APP1 (inserted here): the
    same tags as the TIFF's, and orthority's ExifReader reads the same orientation."""
    from orthority.param_io import ExifReader
    from rasterio.shutil import copy

    tif = _odm_images()[0]
    jpg = tmp_path / "DJI_0001.JPG"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        copy(tif, jpg, driver="JPEG")
        with rasterio.open(tif) as src:
            packet = src.tags(ns="xml:XMP")["xml:XMP"].encode()
    pathlib.Path(str(jpg) + ".aux.xml").unlink(missing_ok=True)  # the tags must come from the JPEG itself
    data = jpg.read_bytes()
    body = b"http://ns.adobe.com/xap/1.0/\x00" + packet
    jpg.write_bytes(data[:2] + b"\xff\xe1" + (len(body) + 2).to_bytes(2, "big") + body + data[2:])
    a, b = read_drone_tags(jpg), read_drone_tags(tif)
    assert dataclasses.replace(a, path=b.path) == b
    table, _ = read_exif_exteriors([jpg])
    for name, e in ExifReader([jpg]).read_ext_param().items():
        eo = table[pathlib.Path(name).stem]
        np.testing.assert_allclose(np.asarray(eo.position), e["xyz"], rtol=0, atol=1e-6)
        np.testing.assert_allclose(_opk_deg(eo), np.degrees(e["opk"]), rtol=0, atol=1e-6)
