"""CRS checks where the orientation, the DEM, the GCPs and the output grid meet (issue 27).

References: rasterio's CRS (EPSG definitions), the sample data's EPSG:32633.
A DEM in another CRS, or any geographic CRS where metres are needed, is an
error naming the CRSs (exit 2 on the command line), never used as metres.
"""

import json

import numpy as np
import pyproj
import pytest
import rasterio
from conftest import ROOT
from rasterio.crs import CRS
from rasterio.transform import from_origin

import photax as ptx
from photax.cli import main
from photax.io import crs as pcrs

DATA = ROOT / "data"
CAMERA, IMAGE, DEM, TRUTH = (
    DATA / "sample_camera.yaml",
    DATA / "sample_image.tif",
    DATA / "sample_dem.tif",
    DATA / "sample_truth.json",
)


def _dem(path, crs, transform=None):
    """The sample DEM's heights under another CRS label (and georeference)."""
    with rasterio.open(DEM) as src:
        heights, t = src.read(1), src.transform
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=heights.shape[1],
        height=heights.shape[0],
        count=1,
        dtype=heights.dtype,
        crs=crs,
        transform=transform or t,
    ) as dst:
        dst.write(heights, 1)
    return path


def _exterior(path, crs):
    data = json.loads(TRUTH.read_text())
    path.write_text(json.dumps({**data, "crs": crs}))
    return path


def _ortho(tmp_path, dem=DEM, exterior=TRUTH):
    return main(
        [
            "ortho",
            str(IMAGE),
            "--dem",
            str(dem),
            "--camera",
            str(CAMERA),
            "--exterior",
            str(exterior),
            "--out",
            str(tmp_path / "o.tif"),
            "--no-progress",
        ]
    )


def test_dem_in_another_transverse_mercator_is_refused(tmp_path, capsys):
    dem = _dem(tmp_path / "dem35s.tif", "EPSG:32735")
    assert _ortho(tmp_path, dem=dem) == 2
    err = capsys.readouterr().err
    assert "EPSG:32633" in err and "EPSG:32735" in err and "does not reproject" in err
    assert not (tmp_path / "o.tif").exists()


def test_geographic_orientation_and_dem_are_refused(tmp_path, capsys):
    """The issue's case: both in EPSG:4326 made a 1 x 1 pixel 'ortho' of 5.8 degrees, exit 0."""
    dem = _dem(tmp_path / "dem4326.tif", "EPSG:4326", from_origin(15.0, 37.1, 5e-5, 5e-5))
    assert _ortho(tmp_path, dem=dem, exterior=_exterior(tmp_path / "e.json", "EPSG:4326")) == 2
    err = capsys.readouterr().err
    assert "geographic CRS (EPSG:4326" in err and "metres" in err
    assert not (tmp_path / "o.tif").exists()


def test_geographic_dem_under_a_projected_orientation_names_the_crs(tmp_path, capsys):
    dem = _dem(tmp_path / "dem4326.tif", "EPSG:4326", from_origin(15.0, 37.1, 5e-5, 5e-5))
    assert _ortho(tmp_path, dem=dem) == 2
    err = capsys.readouterr().err
    assert "the DEM" in err and "geographic CRS (EPSG:4326" in err and "overlap" not in err


def test_library_refuses_a_geographic_dem_and_a_grid_in_another_crs():
    truth = json.loads(TRUTH.read_text())
    eo = ptx.ExteriorOrientation(truth["position"], truth["angles_rad"])
    cam = ptx.read_camera(CAMERA)
    dem = ptx.io.read_dem(DEM)
    grid = ptx.rectification.ortho_grid(eo, cam, dem)
    image = np.zeros((750, 1000))
    geo = ptx.DEM(np.asarray(dem.heights), (5e-5, 0.0, 15.0, 0.0, -5e-5, 37.1), "EPSG:4326")
    with pytest.raises(ValueError, match=r"the DEM is in a geographic CRS \(EPSG:4326"):
        ptx.rectification.ortho_grid(eo, cam, geo)
    with pytest.raises(ValueError, match=r"the DEM is in EPSG:32633 but the output grid in EPSG:32735"):
        ptx.orthorectify(image, eo, cam, dem, ptx.Grid(grid.transform, grid.shape, "EPSG:32735"))
    with pytest.raises(ValueError, match="geographic"):
        ptx.ortho_uncertainty(eo, np.eye(6) * 1e-6, cam, geo, grid)


def test_footprint_outside_the_dem_says_where_both_are():
    truth = json.loads(TRUTH.read_text())
    eo = ptx.ExteriorOrientation(np.asarray(truth["position"]) + [5e4, 0.0, 0.0], truth["angles_rad"])
    where = r"footprint \(E 56.*\) does not overlap the DEM \(E 511700.0..512900.0, N .*EPSG:32633\)"
    with pytest.raises(ValueError, match=where):
        ptx.rectification.ortho_grid(eo, ptx.read_camera(CAMERA), ptx.io.read_dem(DEM))


def test_metres_labelled_geographic_are_refused_by_resect(tmp_path, capsys):
    # Geographic GCPs are projected to their UTM zone (tests/test_gcp_formats.py);
    # metres labelled degrees are refused.
    gcps = tmp_path / "g.csv"
    gcps.write_text((DATA / "sample_gcps.csv").read_text().replace("# crs: EPSG:32633", "# crs: EPSG:4326"))
    assert main(["resect", str(gcps), "--camera", str(CAMERA), "--no-progress"]) == 2
    assert "is not a longitude, latitude" in capsys.readouterr().err


def test_one_crs_in_any_spelling_is_the_same():
    wkt = CRS.from_epsg(32633).to_wkt()
    pcrs.require_same("EPSG:32633", "a", wkt, "b")
    pcrs.require_same("+proj=utm +zone=33 +datum=WGS84 +units=m +no_defs", "a", "EPSG:32633", "b")
    pcrs.require_same(None, "a", "EPSG:4326", "b")  # unknown: nothing to compare
    with pytest.raises(ValueError, match="EPSG:32633 but b in EPSG:32733"):
        pcrs.require_same(wkt, "a", "EPSG:32733", "b")


@pytest.mark.parametrize("command", ["compare", "transfer", "register"])
def test_every_command_that_meets_a_dem_compares_crs(tmp_path, capsys, command):
    dem = str(_dem(tmp_path / "dem35s.tif", "EPSG:32735"))
    gcps, out = str(DATA / "sample_gcps.csv"), str(tmp_path / "out")
    argv = {
        "compare": ["compare", gcps, "--camera", str(CAMERA), "--dem", dem, "--image", str(IMAGE), "--out", out],
        "transfer": [
            "transfer",
            str(IMAGE),
            "--camera",
            str(CAMERA),
            "--exterior",
            str(TRUTH),
            "--dem",
            dem,
            "--gcps",
            gcps,
            "--template",
            str(IMAGE),
            "--out",
            out,
        ],
        "register": [
            "register",
            str(IMAGE),
            "--camera",
            str(CAMERA),
            "--exterior",
            str(TRUTH),
            "--dem",
            dem,
            "--ortho",
            str(DEM),
            "--out",
            out,
        ],
    }[command]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "EPSG:32633" in err and "EPSG:32735" in err, err


def test_a_compound_crs_meets_its_horizontal_part():
    """The NGI DEM is transverse Mercator + a vertical CRS, its orientations the transverse Mercator alone:
    the same ground coordinates (a real pair, orthority's test data, refused before the horizontal
    comparison); another horizontal CRS under the same vertical one is still refused."""
    from photax.io.crs import require_same

    tm = "+proj=tmerc +lat_0=0 +lon_0=25 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs"
    compound = pyproj.CRS.from_user_input("EPSG:32735+5773").to_wkt()
    require_same(compound, "the DEM", "EPSG:32735", "the orientations")
    tm_compound = pyproj.crs.CompoundCRS("tm + EGM96", [pyproj.CRS(tm), pyproj.CRS("EPSG:5773")]).to_wkt()
    require_same(tm_compound, "the DEM", tm, "the orientations")
    with pytest.raises(ValueError, match="does not reproject"):
        require_same(compound, "the DEM", "EPSG:32734", "the orientations")
