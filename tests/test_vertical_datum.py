"""Vertical datums (issue 22): compound CRSs accepted, heights moved between the WGS84
ellipsoid and a geoid through pyproj, and a warning naming the grid -- never a silent
zero shift -- when the grid is missing (pyproj.network is off here).

References: a geoid grid written here (GTX, a linear field: its bilinear
interpolation is exact) and the closed form ``H = h - N(lat, lon)``; pyproj's own
transformation with that grid; PROJ's list of the grids EPSG:5773 needs.
"""

from __future__ import annotations

import struct
import warnings

import numpy as np
import pyproj
import pytest
from conftest import shared_file

from photax.io import read_exteriors
from photax.io._geo import projected_crs
from photax.io.crs import (
    VerticalDatumWarning,
    heights_from_ellipsoid,
    heights_to_ellipsoid,
    require_projected,
    require_same,
    vertical_crs,
)


def _egm96_installed() -> bool:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # pyproj's note on the missing grid
        return pyproj.transformer.TransformerGroup("EPSG:4979", "EPSG:4326+5773").best_available


LAT0, LON0, STEP, ROWS, COLS = 20.0, 115.0, 0.5, 21, 21  # covers the ODM test data (24.68 N, 120.95 E)


def _undulation(lat, lon):
    return 15.0 + 2.0 * (lat - LAT0) - 0.75 * (lon - LON0)


@pytest.fixture
def geoid(tmp_path):
    """A GTX geoid grid (big-endian: origin lat, lon, steps, rows, cols; float32 rows from the south)."""
    lat = LAT0 + STEP * np.arange(ROWS)[:, None]
    lon = LON0 + STEP * np.arange(COLS)[None, :]
    path = tmp_path / "test_geoid.gtx"
    with open(path, "wb") as fh:
        fh.write(struct.pack(">4d2i", LAT0, LON0, STEP, STEP, ROWS, COLS))
        fh.write(_undulation(lat, lon).astype(">f4").tobytes())
    return f"+proj=utm +zone=51 +datum=WGS84 +geoidgrids={path} +vunits=m +type=crs"


def test_compound_crs_accepted_horizontal_part_used():
    compound = "EPSG:32735+5773"
    require_projected(compound, "the DEM")  # no error
    require_same(compound, "the DEM", "EPSG:32735", "the orientation")  # horizontal parts equal
    with pytest.raises(ValueError, match="does not reproject"):
        require_same(compound, "the DEM", "EPSG:32736", "the orientation")
    assert projected_crs(compound) == pyproj.CRS("EPSG:32735")
    assert vertical_crs(compound) == pyproj.CRS("EPSG:5773")
    assert vertical_crs("EPSG:32735") is None


def test_missing_grid_warns_and_names_it():
    """EPSG:5773 (EGM96) needs us_nga_egm96_15.tif, absent here: a warning naming it and
    the error's size; heights unchanged, as said (PROJ alone would shift by zero silently)."""
    if _egm96_installed():
        pytest.skip("an EGM96 grid is installed here")
    with pytest.warns(VerticalDatumWarning, match=r"us_nga_egm96_15\.tif.*not available.*-107 m to \+86 m"):
        out = heights_from_ellipsoid(-25.0, 27.0, 1500.0, "EPSG:32735+5773")
    assert out == 1500.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no vertical part: nothing to say, nothing moved
        assert heights_from_ellipsoid(-25.0, 27.0, 1500.0, "EPSG:32735") == 1500.0


def test_geoid_grid_conversion_against_closed_form_and_pyproj(geoid):
    rng = np.random.default_rng(0)
    lat, lon = rng.uniform(LAT0 + 1, LAT0 + 9, 50), rng.uniform(LON0 + 1, LON0 + 9, 50)
    h = rng.uniform(0, 500, 50)
    with warnings.catch_warnings():
        warnings.simplefilter("error", VerticalDatumWarning)
        H = heights_from_ellipsoid(lat, lon, h, geoid)
    np.testing.assert_allclose(H, h - _undulation(lat, lon), rtol=0, atol=1e-4)  # float32 grid
    ref = pyproj.Transformer.from_crs("EPSG:4979", geoid, always_xy=True).transform(lon, lat, h)[2]
    np.testing.assert_allclose(H, ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(heights_to_ellipsoid(lat, lon, H, geoid), h, rtol=0, atol=1e-6)


def test_lla_exteriors_into_a_dem_vertical_datum(geoid):
    """Drone fixes (ellipsoidal heights) into a DEM's compound CRS: the same x, y as its
    horizontal CRS, heights on the geoid; a missing grid warns."""
    path = shared_file("orthority/io/odm_lla_rpy.csv")
    plain, crs = read_exteriors(path, crs="EPSG:32651")
    onto, crs2 = read_exteriors(path, crs=geoid)
    rows = {ln.split()[0].split(".")[0]: ln.split() for ln in path.read_text().splitlines()[1:] if ln.strip()}
    for name, eo in plain.items():
        lat, lon = float(rows[name][1]), float(rows[name][2])
        a, b = np.asarray(eo.position), np.asarray(onto[name].position)
        np.testing.assert_allclose(b[:2], a[:2], rtol=0, atol=1e-6)
        assert b[2] == pytest.approx(a[2] - _undulation(lat, lon), abs=1e-4)
        np.testing.assert_array_equal(np.asarray(onto[name].angles), np.asarray(eo.angles))
    if not _egm96_installed():
        with pytest.warns(VerticalDatumWarning, match="us_nga_egm96_15"):
            read_exteriors(path, crs="EPSG:32651+5773")
