"""Mosaics (photax.mosaic, photax/mosaicking.py) on rendered overlapping orthos with known faults --
a gain of 1.1, a 0.5 px misregistration, raised buildings displaced
differently in each ortho -- against rasterio.merge (first wins), the
reference users have (rasterio #1428)."""

import numpy as np
import pytest
import rasterio
import rasterio.merge

from photax.rectification import Grid
from photax.scene import texture

pytest.importorskip("dask")
pytest.importorskip("rioxarray")

from photax import mosaic  # noqa: E402
from photax.tiled import _dataarray, to_raster  # noqa: E402

ROWS, COLS, RES = 120, 200, 3.0
X0, Y1 = 500_000.0, 4_000_360.0


def _render(c0, c1, shift_px, gain, roof_shift, buildings):
    """Ortho of columns c0..c1: texture sampled ``shift_px`` off, times
    ``gain``; building roofs (0.95) drawn ``roof_shift`` px off their
    footprint (relief displacement, away from this image's nadir)."""
    r, c = np.mgrid[0:ROWS, c0:c1] + 0.5
    x, y = (c + shift_px) * RES, -r * RES
    v = np.asarray(texture(x, y)) * gain
    for br, bc in buildings:
        rr, cc = slice(br, br + 12), slice(bc + roof_shift - c0, bc + roof_shift - c0 + 12)
        v[rr, cc] = 0.95 * gain
    grid = Grid((RES, 0, X0 + c0 * RES, 0, -RES, Y1), (ROWS, c1 - c0), crs="EPSG:32633")
    return _dataarray(v.astype(np.float32), grid, np.asarray(np.nan, dtype=np.float32), "ortho")


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(5)
    buildings = [(int(rng.integers(5, ROWS - 17)), int(rng.integers(75, 113))) for _ in range(8)]
    a = _render(0, 130, 0.0, 1.0, 3, buildings)
    b = _render(70, 200, 0.5, 1.1, -3, buildings)
    dsm = np.zeros((ROWS, COLS))
    for br, bc in buildings:  # footprint plus where either ortho shows the roof
        dsm[br : br + 12, bc - 3 : bc + 15] = 10.0
    return a, b, dsm


def _seam(labels):
    """Pixels whose 4-neighbour has another label (both with data)."""
    s = np.zeros(labels.shape, dtype=bool)
    for ax in (0, 1):
        d = np.diff(labels, axis=ax) != 0
        ok = (np.delete(labels, 0, axis=ax) >= 0) & (np.delete(labels, -1, axis=ax) >= 0)
        d &= ok
        if ax == 0:
            s[1:] |= d
            s[:-1] |= d
        else:
            s[:, 1:] |= d
            s[:, :-1] |= d
    return s


def _energy(img, seam):
    gy, gx = np.gradient(np.asarray(img, dtype=float))
    return float(np.mean((gx * gx + gy * gy)[seam]))


def test_seams_beat_rasterio_merge_and_avoid_buildings(scene, tmp_path):
    a, b, dsm = scene
    for name, o in (("a", a), ("b", b)):
        o.rio.to_raster(tmp_path / f"{name}.tif")
    merged, _ = rasterio.merge.merge([str(tmp_path / "a.tif"), str(tmp_path / "b.tif")])
    merged = merged[0]
    merge_seam = np.zeros(merged.shape, dtype=bool)
    merge_seam[:, 129:131] = True  # rasterio.merge switches from a to b at a's edge
    info = {}
    out = mosaic([a, b], dsm=dsm, info=info)
    labels = info["labels"]
    seam = _seam(labels)
    assert out.shape == (ROWS, COLS) and seam.sum() > ROWS  # one seam across the overlap
    assert np.isfinite(out.values).all()
    ours, theirs = _energy(out.values, seam), _energy(merged, merge_seam)
    # Measured 1.6x lower (the issue asks >= 3x: see the xfail test below).
    assert ours * 1.3 <= theirs, (ours, theirs)
    assert np.mean(dsm[seam] > 2.0) < 0.01
    np.testing.assert_allclose(info["gains"][1] / info["gains"][0], 1 / 1.1, rtol=0.03)
    # Voronoi (nearest nadir) also joins them, with the seam down the middle of the overlap.
    vor_info = {}
    mosaic([a, b], method="voronoi", feather=0, balance=False, info=vor_info)
    assert set(np.unique(vor_info["labels"])) == {0, 1}
    # COG, atomically.
    to_raster(out, tmp_path / "m.tif", cog=True)
    with rasterio.open(tmp_path / "m.tif") as ds:
        assert ds.overviews(1) or min(ds.shape) < 512
        np.testing.assert_allclose(ds.read(1), out.values, rtol=1e-6)


def test_order_independent_and_bad_input(scene):
    a, b, dsm = scene
    one = mosaic([a, b], dsm=dsm)
    two = mosaic([b, a], dsm=dsm)
    np.testing.assert_array_equal(one.values, two.values)
    with pytest.raises(ValueError, match="CRS"):
        mosaic([a, b.rio.write_crs("EPSG:32634")])
    far = _render(0, 50, 0.0, 1.0, 0, [])
    far = far.assign_coords(x=far.x + 9_999.0).rio.write_transform(
        far.rio.transform() * rasterio.Affine.translation(9_999 / RES, 0))
    with pytest.raises(ValueError, match="overlaps no other"):
        mosaic([a, far])


@pytest.mark.xfail(strict=True, reason="issue 12's acceptance (>= 3x lower seam gradient energy than rasterio.merge) "
                   "is not reached: 1.6x on this scene, the texture's own gradient along the seam dominates")
def test_seam_energy_three_times_lower_than_merge(scene, tmp_path):
    a, b, dsm = scene
    merged = np.concatenate([a.values, b.values[:, 60:]], axis=1)  # rasterio.merge's result, first wins
    merge_seam = np.zeros(merged.shape, dtype=bool)
    merge_seam[:, 129:131] = True
    info = {}
    out = mosaic([a, b], dsm=dsm, info=info)
    assert _energy(out.values, _seam(info["labels"])) * 3 <= _energy(merged, merge_seam)


def test_cli_mosaic(scene, tmp_path, capsys):
    from photax.cli import main

    a, b, dsm = scene
    for name, o in (("a", a), ("b", b)):
        o.rio.to_raster(tmp_path / f"{name}.tif")
    ref = mosaic([a, b])
    out = tmp_path / "m.tif"
    assert main(["mosaic", str(tmp_path / "a.tif"), str(tmp_path / "b.tif"), "-o", str(out)]) == 0
    assert "2 orthos" in capsys.readouterr().out
    with rasterio.open(out) as ds:
        assert ds.transform.almost_equals(ref.rio.transform(), 1e-9) and ds.crs == rasterio.CRS.from_epsg(32633)
        np.testing.assert_allclose(ds.read(1), ref.values, rtol=1e-6)
    assert main(["mosaic", str(tmp_path / "a.tif"), str(tmp_path / "missing.tif"), "-o", str(out)]) == 2
