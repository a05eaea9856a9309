"""GCP files from other tools (issue 22): ODM lists in geographic coordinates, QGIS
Georeferencer ``.points``, orthority's GeoJSON.  References: pyproj's own conversions,
orthority's reader, QGIS's documented pixel convention (GDAL pixel/line: the
first pixel's corner at 0, its centre at 0.5, rows as negative sourceY)."""

from __future__ import annotations

import json
import pathlib

import numpy as np
import pyproj
import pytest
import rasterio
from conftest import SHARED_DATA

from photax.io.gcp import read_gcps, write_gcps
from photax.polynomial import fit_polynomial

ROOT = pathlib.Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data" / "sample_gcps.csv"
ODM_LIST = SHARED_DATA / "gcp_list_floatxy_raw.txt"  # EPSG:32722 (PROJ string), real ODM sample
OTY_GCPS = SHARED_DATA / "orthority" / "rpc" / "gcps.geojson"

needs_odm = pytest.mark.skipif(not ODM_LIST.is_file(), reason="../shared/data not present")
needs_oty = pytest.mark.skipif(not OTY_GCPS.is_file(), reason="../shared/data/orthority not present")


# --- ODM gcp_list.txt in geographic coordinates ----------------------------------


def _geographic_copy(tmp_path, header: str) -> pathlib.Path:
    """The ODM sample with its E, N converted to longitude, latitude by pyproj."""
    lines = ODM_LIST.read_text().splitlines()
    to_ll = pyproj.Transformer.from_crs("EPSG:32722", "EPSG:4326", always_xy=True)
    out = [header]
    for ln in lines[1:]:
        f = ln.split()
        if not f:
            continue
        lon, lat = to_ll.transform(float(f[0]), float(f[1]))
        out.append(" ".join([repr(lon), repr(lat), *f[2:]]))
    path = tmp_path / "gcp_list.txt"
    path.write_text("\n".join(out) + "\n")
    return path


@needs_odm
@pytest.mark.parametrize("header", ["WGS84", "EPSG:4326", "+proj=longlat +datum=WGS84 +no_defs"])
def test_odm_geographic_list_reads_back_in_utm(tmp_path, header):
    original = read_gcps(ODM_LIST)
    table = read_gcps(_geographic_copy(tmp_path, header))
    assert table.crs == "EPSG:32722"  # the UTM zone of the points (22 south), found, not given
    np.testing.assert_allclose(table.ground, original.ground, rtol=0, atol=1e-3)
    np.testing.assert_array_equal(table.ground[:, 2], original.ground[:, 2])  # heights as given
    np.testing.assert_array_equal(table.pixel, original.pixel)
    assert table.names.tolist() == original.names.tolist()


@needs_odm
def test_odm_geographic_list_into_a_given_crs(tmp_path):
    original = read_gcps(ODM_LIST)
    table = read_gcps(_geographic_copy(tmp_path, "EPSG:4326"), crs="EPSG:32723")
    x, y = pyproj.Transformer.from_crs("EPSG:32722", "EPSG:32723", always_xy=True).transform(
        original.ground[:, 0], original.ground[:, 1]
    )
    assert table.crs == "EPSG:32723"
    np.testing.assert_allclose(table.ground[:, :2], np.column_stack([x, y]), rtol=0, atol=1e-3)
    # A projected file is reprojected to crs= too (pyproj's conversion), and kept as it is without it.
    moved = read_gcps(ODM_LIST, crs="EPSG:32723")
    np.testing.assert_allclose(moved.ground[:, :2], np.column_stack([x, y]), rtol=0, atol=1e-6)
    assert read_gcps(ODM_LIST).crs == original.crs


@needs_odm
def test_odm_utm_zone_line_is_read_as_its_epsg_code(tmp_path):
    """ODM writes ``WGS84 UTM 22S``: the same CRS as the sample's own PROJ string (EPSG:32722)."""
    lines = ODM_LIST.read_text().splitlines()
    path = tmp_path / "gcp_list.txt"
    path.write_text("\n".join(["WGS84 UTM 22S", *lines[1:]]) + "\n")
    table = read_gcps(path)
    assert pyproj.CRS(table.crs) == pyproj.CRS(32722)
    np.testing.assert_array_equal(table.ground, read_gcps(ODM_LIST).ground)
    moved = read_gcps(path, crs="EPSG:32723")  # a known CRS, so it can be reprojected
    np.testing.assert_allclose(moved.ground, read_gcps(ODM_LIST, crs="EPSG:32723").ground, rtol=0, atol=1e-9)
    path.write_text("\n".join(["WGS84 UTM 61N", *lines[1:]]) + "\n")
    with pytest.raises(ValueError, match=r"line 1: UTM zone 61"):
        read_gcps(path)


def test_geographic_crs_with_metres_is_refused(tmp_path):
    path = tmp_path / "gcp_list.txt"
    path.write_text("WGS84\n658528.361 7167002.098 890.6 10 20 a.jpg P1\n")
    with pytest.raises(ValueError, match=r", line 2: .*not a longitude, latitude"):
        read_gcps(path)


def test_geographic_csv_crs_is_projected(tmp_path):
    path = tmp_path / "g.csv"
    path.write_text("# crs: EPSG:4326\nname,E,N,h,col,row\nA,15.0,40.0,10,1,2\nB,15.001,40.001,12,3,4\n")
    table = read_gcps(path)
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32633", always_xy=True).transform(
        [15.0, 15.001], [40, 40.001]
    )
    assert table.crs == "EPSG:32633"
    np.testing.assert_allclose(table.ground, np.column_stack([x, y, [10, 12]]), rtol=0, atol=1e-6)


# --- QGIS Georeferencer .points ----------------------------------------------------


def _points_text(table, crs_line=True) -> str:
    """The .points file QGIS writes for ``table`` (written here from the documented convention)."""
    head = f"#CRS: {pyproj.CRS(table.crs).to_wkt()}\n" if crs_line else ""
    rows = [
        f"{x!r},{y!r},{c + 0.5!r},{-(r + 0.5)!r},{0 if role == 'check' else 1},0,0,0"
        for (x, y, _), (c, r), role in zip(table.ground.tolist(), table.pixel.tolist(), table.role.tolist())
    ]
    return head + "mapX,mapY,sourceX,sourceY,enable,dX,dY,residual\n" + "\n".join(rows) + "\n"


def test_qgis_points_pixel_convention(tmp_path):
    path = tmp_path / "a.points"
    head = "mapX,mapY,sourceX,sourceY,enable,dX,dY,residual\n"
    path.write_text(head + "10,20,0.5,-0.5,1,0,0,0\n30,40,100,-50,0,0,0,0\n")
    t = read_gcps(path)
    np.testing.assert_array_equal(t.pixel, [[0.0, 0.0], [99.5, 49.5]])  # first pixel's centre -> (0, 0)
    np.testing.assert_array_equal(t.ground[:, :2], [[10, 20], [30, 40]])
    assert np.all(np.isnan(t.ground[:, 2])) and t.crs is None
    assert t.role.tolist() == ["control", "check"] and t.images.tolist() == ["", ""]
    path.write_text("mapX,mapY,sourceX,sourceY,enable\n10,20,5,3,1\n")
    with pytest.raises(ValueError, match=r"a\.points, line 2: sourceY 3 is positive"):
        read_gcps(path)


def test_qgis_points_round_trip(tmp_path):
    table = read_gcps(SAMPLE)
    out = write_gcps(tmp_path / "s.points", table)
    assert out.read_text().startswith("#CRS: PROJCRS[")
    back = read_gcps(out)
    assert back.crs == table.crs == "EPSG:32633"
    np.testing.assert_array_equal(back.ground[:, :2], table.ground[:, :2])
    np.testing.assert_allclose(back.pixel, table.pixel, rtol=0, atol=1e-9)
    assert back.role.tolist() == table.role.tolist()
    # ... and what QGIS would have written reads the same
    qgis = tmp_path / "q.points"
    qgis.write_text(_points_text(table))
    np.testing.assert_allclose(read_gcps(qgis).pixel, table.pixel, rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="image-plane"):
        write_gcps(tmp_path / "x.points", read_gcps(_xy_csv(tmp_path)))


def _xy_csv(tmp_path):
    p = tmp_path / "xy.csv"
    p.write_text("name,X,Y,Z,x,y\nA,1,2,3,0.1,0.2\nB,4,5,6,-0.1,0.3\n")
    return p


def test_qgis_points_and_csv_give_the_same_rectification(tmp_path):
    from photax.cli import main

    table = read_gcps(SAMPLE)
    points = tmp_path / "sample.points"
    points.write_text(_points_text(table))
    q = read_gcps(points)
    for order in (1, 2):
        a = fit_polynomial(table.ground[~table.check, :2], table.pixel[~table.check], order)
        b = fit_polynomial(q.ground[~q.check, :2], q.pixel[~q.check], order)
        np.testing.assert_allclose(np.asarray(b.coef), np.asarray(a.coef), rtol=1e-9, atol=1e-9)
    image = ROOT / "data" / "sample_image.tif"
    outs = []
    for gcps in (SAMPLE, points):
        out = tmp_path / f"{gcps.stem}.tif"
        args = ["rectify", str(image), "--gcps", str(gcps), "--order", "2", "-o", str(out), "--no-progress"]
        assert main(args) == 0
        with rasterio.open(out) as ds:
            outs.append((ds.transform, ds.crs, ds.read()))
    assert outs[0][0] == outs[1][0] and outs[0][1] == outs[1][1]
    assert np.abs(outs[0][2].astype(int) - outs[1][2]).max() <= 1  # pixels 1e-13 apart: a grey level at most


# --- orthority GeoJSON -------------------------------------------------------------


@needs_oty
def test_orthority_geojson_reads_into_utm():
    from orthority.param_io import read_oty_gcps

    table = read_gcps(OTY_GCPS)
    doc = json.loads(OTY_GCPS.read_text())
    lon, lat, h = np.array([f["geometry"]["coordinates"] for f in doc["features"]]).T
    assert len(table) == 5 and table.crs == "EPSG:32735"  # lon 24.4 E, lat 33.6 S: UTM zone 35 south
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32735", always_xy=True).transform(lon, lat)
    np.testing.assert_allclose(table.ground, np.column_stack([x, y, h]), rtol=0, atol=1e-6)
    np.testing.assert_array_equal(table.ground[:, 2], h)  # heights as given
    oty = read_oty_gcps(OTY_GCPS)["qb2_basic1b.tif"]
    np.testing.assert_array_equal(table.pixel, [g["ji"] for g in oty])
    assert table.names.tolist() == [g["id"] for g in oty]
    assert set(table.images.tolist()) == {"qb2_basic1b.tif"}
    utm34 = read_gcps(OTY_GCPS, crs="EPSG:32734")
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32734", always_xy=True).transform(lon, lat)
    np.testing.assert_allclose(utm34.ground[:, :2], np.column_stack([x, y]), rtol=0, atol=1e-6)


@needs_oty
def test_orthority_geojson_round_trip(tmp_path):
    from orthority.param_io import read_oty_gcps

    table = read_gcps(OTY_GCPS)
    out = write_gcps(tmp_path / "g.geojson", table)
    back = read_gcps(out)
    np.testing.assert_allclose(back.ground, table.ground, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(back.pixel, table.pixel)
    assert back.names.tolist() == table.names.tolist() and back.crs == table.crs
    # orthority reads what photax writes, with the original longitude, latitude
    orig, ours = read_oty_gcps(OTY_GCPS)["qb2_basic1b.tif"], read_oty_gcps(out)["qb2_basic1b.tif"]
    np.testing.assert_allclose([g["xyz"] for g in ours], [g["xyz"] for g in orig], rtol=0, atol=1e-9)
    assert [g["ji"] for g in ours] == [g["ji"] for g in orig]


def test_geojson_errors(tmp_path):
    path = tmp_path / "g.geojson"
    path.write_text(
        '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"ji": [1]},'
        ' "geometry": {"type": "Point", "coordinates": [24, -33, 100]}}]}'
    )
    with pytest.raises(ValueError, match=r"g\.geojson, feature 1: properties\.ji must be 2"):
        read_gcps(path)
    path.write_text('{"type": "Feature"}')
    with pytest.raises(ValueError, match="FeatureCollection"):
        read_gcps(path)
    t = read_gcps(SAMPLE)
    with pytest.raises(ValueError, match="needs a CRS"):
        write_gcps(tmp_path / "x.geojson", type(t)(**{**t.__dict__, "crs": None}))


def test_format_detection_and_choice(tmp_path):
    table = read_gcps(SAMPLE)
    for name, fmt in (("a.points", "qgis"), ("a.geojson", "geojson"), ("a.csv", "csv")):
        path = write_gcps(tmp_path / name, table)
        auto, named = read_gcps(path), read_gcps(path, format=fmt)
        np.testing.assert_allclose(auto.ground[:, :2], named.ground[:, :2], rtol=0, atol=1e-6)
        np.testing.assert_allclose(auto.ground[:, :2], table.ground[:, :2], rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="format must be one of"):
        read_gcps(SAMPLE, format="kml")


def test_commands_needing_heights_refuse_2d_points(tmp_path, capsys):
    from photax.cli import main

    points = write_gcps(tmp_path / "s.points", read_gcps(SAMPLE))
    data = ROOT / "data"
    camera, image, dem = data / "sample_camera.yaml", data / "sample_image.tif", data / "sample_dem.tif"
    assert main(["resect", str(points), "--camera", str(camera), "--no-progress"]) == 2
    assert "no heights" in capsys.readouterr().err
    args = ["compare", str(points), "--image", str(image), "--camera", str(camera), "--dem", str(dem)]
    assert main([*args, "-o", str(tmp_path / "cmp"), "--no-progress"]) == 2
    assert "no heights" in capsys.readouterr().err


def _rectify(tmp_path, gcps, *extra):
    from photax.cli import main

    out = tmp_path / f"{gcps.stem}_{len(extra)}.tif"
    image = ROOT / "data" / "sample_image.tif"
    args = ["rectify", str(image), "--gcps", str(gcps), "--order", "1", "-o", str(out), "--no-progress"]
    args += extra
    assert main(args) == 0
    with rasterio.open(out) as ds:
        return ds.transform, ds.crs.to_epsg()


def test_rectify_geographic_gcps_and_crs(tmp_path):
    table = read_gcps(SAMPLE)
    lon, lat = pyproj.Transformer.from_crs("EPSG:32633", "EPSG:4326", always_xy=True).transform(
        table.ground[:, 0], table.ground[:, 1]
    )
    geo = tmp_path / "geo.csv"
    h, pixel = table.ground[:, 2].tolist(), table.pixel.tolist()
    rows = zip(table.names, lon.tolist(), lat.tolist(), h, pixel, table.role)
    geo.write_text(
        "# crs: EPSG:4326\nname,E,N,h,col,row,role\n"
        + "".join(f"{n},{a!r},{b!r},{h!r},{c!r},{r!r},{role}\n" for n, a, b, h, (c, r), role in rows)
    )
    (t0, crs0), (t1, crs1) = _rectify(tmp_path, SAMPLE), _rectify(tmp_path, geo)
    assert crs0 == crs1 == 32633  # the UTM zone of the points
    np.testing.assert_allclose(np.array(t1)[:6], np.array(t0)[:6], rtol=0, atol=1e-3)
    t2, crs2 = _rectify(tmp_path, geo, "--crs", "EPSG:32634")
    x, y = pyproj.Transformer.from_crs("EPSG:32633", "EPSG:32634", always_xy=True).transform(
        table.ground[~table.check, 0], table.ground[~table.check, 1]
    )
    assert crs2 == 32634  # the grid covers pyproj's conversion of the control points, to a pixel (snapped)
    assert x.min() - t2.a <= t2.c <= x.min() and y.max() <= t2.f <= y.max() + t2.a
