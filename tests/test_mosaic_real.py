"""photax.mosaic on real data (issue 21): the four NGI frames of orthority's test corpus
(../shared/data/orthority; skipped cleanly when absent), orthorectified by photax at 5 m on one lattice,
then mosaicked with the default options.

References: rasterio.merge (first wins) on the same files, the orthos' own pixels, and the grey-level
means of each overlap (the strips differ by 39-54 grey levels before balancing)."""

import json

import numpy as np
import pytest
import rasterio
import rasterio.features
import rasterio.merge
from conftest import SHARED_DATA, needs

pytestmark = needs("dask", "rioxarray")

NGI = SHARED_DATA / "orthority"


@pytest.fixture(scope="module")
def orthos(tmp_path_factory):
    if not (NGI / "ngi" / "dem.tif").is_file():
        pytest.skip("../shared/data/orthority is not present")
    from photax.io import read_dem
    from photax.io.orientation import block_images, read_interior
    from photax.rectification import orthorectify_block

    tmp = tmp_path_factory.mktemp("ngi_mosaic")
    # The DEM tagged with the orientation's horizontal CRS, heights as stored (as tests/test_ortho_real.py).
    prj = (NGI / "io" / "ngi_xyz_opk.prj").read_text()
    with rasterio.open(NGI / "ngi" / "dem.tif") as src:
        profile, heights = src.profile, src.read()
    profile.update(crs=rasterio.CRS.from_string(prj))
    with rasterio.open(tmp / "dem.tif", "w", **profile) as dst:
        dst.write(heights)
    images, exteriors, crs = block_images(NGI / "io" / "ngi_xyz_opk.csv", NGI / "ngi")
    camera = read_interior(NGI / "io" / "ngi_int_param.yaml", None)
    paths = orthorectify_block(
        images,
        exteriors,
        camera,
        read_dem(tmp / "dem.tif"),
        tmp,
        resolution=5.0,
        crs=crs,
    )
    return [str(p) for p in paths], tmp


def _on_union(paths):
    """Each ortho ``(bands, rows, cols)`` on rasterio.merge's union grid (NaN outside), merge's result and
    its transform."""
    merged, transform = rasterio.merge.merge(paths, nodata=0)
    stack = []
    for p in paths:
        with rasterio.open(p) as ds:
            v = ds.read(masked=True).astype(float).filled(np.nan)
            r = round((ds.transform.f - transform.f) / transform.e)
            c = round((ds.transform.c - transform.c) / transform.a)
        full = np.full(merged.shape, np.nan)
        full[:, r : r + v.shape[1], c : c + v.shape[2]] = v
        stack.append(full)
    return np.array(stack), merged, transform


def test_ngi_mosaic_is_balanced_and_equals_the_orthos_away_from_seams(orthos):
    from photax import mosaic

    paths, tmp = orthos
    info = {}
    out = mosaic(
        paths,
        info=info,
        seamlines=tmp / "seams.geojson",
        source_index=tmp / "source.tif",
    )
    m = out.values
    stack, merged, transform = _on_union(paths)
    assert m.shape == merged.shape and out.rio.transform().almost_equals(transform)
    g, o = info["gains"], info["offsets"]  # (4 orthos, 3 bands)
    # Not blank (before issue 21: every gain 0.000, every pixel ~1e-12), gains sane.
    assert np.all((g > 0.7) & (g < 1.4)), g
    valid = np.all(np.isfinite(stack), axis=1).any(axis=0)
    assert np.isfinite(m[0][valid]).mean() > 0.99 and np.nanstd(m) > 20
    # Balanced: the overlaps' mean grey levels, up to 57 apart between the raw orthos, agree to 5 (measured
    # 3.2: 6 overlaps, 8 unknowns per band, and real differences -- relief, sun angle -- no gain removes).
    raw, bal = [], []
    for i in range(4):
        for j in range(i + 1, 4):
            both = np.all(np.isfinite(stack[i]) & np.isfinite(stack[j]), axis=0)
            if both.sum() > 10_000:
                for b in range(3):
                    a, c = stack[i][b][both], stack[j][b][both]
                    raw.append(abs(a.mean() - c.mean()))
                    bal.append(abs((g[i, b] * a + o[i, b]).mean() - (g[j, b] * c + o[j, b]).mean()))
    assert max(raw) > 30 and max(bal) < min(5, max(raw) / 10), (raw, bal)
    # Away from the seams (feather + a seam cell from any label change), each pixel is its source ortho,
    # balanced: g v + o to float32 rounding.  rasterio.merge shows the first ortho there instead, raw: where
    # the sources agree the difference is exactly the balance, |(g - 1) v + o|.
    with rasterio.open(tmp / "source.tif") as ds:
        src = ds.read(1)
        assert ds.transform.almost_equals(transform) and ds.nodata == -1
    from scipy import ndimage

    s, feather = info["seam_scale"], 8
    first = np.argmax(np.all(np.isfinite(stack), axis=1), axis=0)  # merge's source (first wins)
    checked = 0
    for k in range(4):
        inner = ndimage.binary_erosion(src == k, iterations=feather + s)
        ours = g[k][:, None] * stack[k][:, inner] + o[k][:, None]
        np.testing.assert_allclose(m[:, inner], ours, atol=1e-3)
        same = inner & (first == k)
        np.testing.assert_allclose(
            m[:, same],
            merged[:, same],
            rtol=0,
            atol=np.max(np.abs((g[k] - 1)[:, None] * merged[:, same] + o[k][:, None])) + 1e-3,
        )
        checked += inner.sum()
    assert checked > 0.7 * valid.sum()
    # The seamlines GeoJSON: one polygon per ortho, rasterised back it is the source index.
    doc = json.loads((tmp / "seams.geojson").read_text())
    assert [f["properties"]["index"] for f in doc["features"]] == [0, 1, 2, 3]
    assert doc["features"][0]["properties"]["source"] == paths[0]
    back = rasterio.features.rasterize(
        ((f["geometry"], f["properties"]["index"]) for f in doc["features"]),
        out_shape=src.shape,
        transform=transform,
        fill=-1,
        dtype="int16",
    )
    assert np.mean(back == src) > 0.999


def test_ngi_cli_mosaic_writes_seamlines_and_source_index(orthos, tmp_path, capsys):
    from photax.cli import main

    paths, _ = orthos
    out = tmp_path / "m.tif"
    args = [
        "mosaic",
        *paths,
        "-o",
        str(out),
        "--seamlines",
        str(tmp_path / "s.geojson"),
        "--source-index",
        str(tmp_path / "i.tif"),
        "--no-progress",
    ]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "4 orthos" in text and "seamlines ->" in text and "source index ->" in text
    with rasterio.open(out) as ds, rasterio.open(tmp_path / "i.tif") as idx:
        assert ds.shape == idx.shape and set(np.unique(idx.read(1))) == {-1, 0, 1, 2, 3}
        # In the orthos' type (uint8, nodata 0), as they are: the library's mosaic rounded.
        assert ds.dtypes[0] == "uint8" and ds.nodata == 0
        written = ds.read()
    from photax import mosaic

    ref = mosaic(paths).values
    ok = np.isfinite(ref)
    assert np.array_equal(written == 0, ~ok)
    np.testing.assert_array_equal(written[ok], np.clip(np.round(ref[ok]), 1, 255))
    assert main(args[:-5] + ["--seamlines", str(out), "--no-progress"]) == 2  # one file for two outputs


def test_ngi_mosaic_to_raster_is_byte_identical_to_the_lazy_mosaic(orthos, tmp_path, monkeypatch):
    """``photax mosaic``'s way (mosaic_to_raster: NumPy arrays and threads, no Dask graph; issue 21's
    whole-process speed) writes, for the NGI block, the very file of the lazy mosaic (Dask) rounded into
    uint8 (1..255, 0 no data, as the orthos) and written as a COG by to_raster, byte for byte; the same
    seamlines; a source index that is the seam-grid labels at full resolution."""
    import photax.mosaicking as mosaicking
    from photax import mosaic, mosaic_to_raster, to_raster

    paths, _ = orthos
    out = mosaic(paths, info=(ref_info := {}), seamlines=tmp_path / "ref.geojson")
    rounded = out.data.map_blocks(lambda v: np.where(np.isnan(v), 0, np.clip(np.rint(v), 1, 255)).astype(np.uint8))
    to_raster(out.copy(data=rounded).rio.write_nodata(0, encoded=False), tmp_path / "ref.tif", cog=True)
    monkeypatch.setattr(mosaicking, "_lazy", lambda plan: pytest.fail("a Dask graph"))
    mosaic_to_raster(
        paths,
        tmp_path / "m.tif",
        info=(info := {}),
        seamlines=tmp_path / "m.geojson",
        source_index=tmp_path / "i.tif",
    )
    assert (tmp_path / "m.tif").read_bytes() == (tmp_path / "ref.tif").read_bytes()
    assert json.loads((tmp_path / "m.geojson").read_text()) == json.loads((tmp_path / "ref.geojson").read_text())
    np.testing.assert_array_equal(info["labels"], ref_info["labels"])
    s = info["seam_scale"]
    with rasterio.open(tmp_path / "i.tif") as ds, rasterio.open(tmp_path / "m.tif") as m:
        assert ds.dtypes[0] == "int16" and ds.nodata == -1 and ds.transform == m.transform and ds.shape == m.shape
        full = np.repeat(np.repeat(info["labels"], s, 0), s, 1)[: ds.shape[0], : ds.shape[1]]
        np.testing.assert_array_equal(ds.read(1), full)
