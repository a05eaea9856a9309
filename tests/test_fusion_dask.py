"""photax.fusion.pansharpen_dask: pan-sharpening as a lazy Dask graph, against the in-memory
pansharpen (the reference: the same method on the whole image at once)."""

import dask
import dask.array as da
import numpy as np
import pytest
import rasterio
from conftest import SHARED_DATA
from rasterio import Affine
from scipy import ndimage

from photax.cli import main
from photax.fusion import METHODS, pansharpen, pansharpen_dask
from photax.io.raster import read_geotiff, write_geotiff

PAIR = SHARED_DATA / "orthority" / "pan_sharp"


def _texture(shape, seed, sigma=2.0):
    return ndimage.gaussian_filter(np.random.default_rng(seed).normal(size=shape), sigma, mode="wrap")


def _pair():
    """A 100 x 100 PAN and a 3-band MS of 4 x larger pixels that starts 30 PAN columns in and 12 rows above
    the PAN (so the output is a window of the PAN, and some MS pixels lie outside it), with no-data in both."""
    r, size, shape = 4, 100, (112, 130)  # the truth: PAN rows 12.., MS columns 30..
    truth = np.stack([100 + 20 * _texture(shape, k) + 10 * _texture(shape, 9, 1.0) for k in range(3)])
    pan = np.tensordot([0.5, 0.3, 0.2], truth[:, 12:, :size], 1).astype(np.float32)
    ms = truth[:, :size, 30:].reshape(3, size // r, r, size // r, r).mean(axis=(2, 4)).astype(np.float32)
    pan[40:46, 50:58] = np.nan
    ms[:, 3, 5] = np.nan
    pan_t = Affine(1.0, 0, 1000.0, 0, -1.0, 2000.0)
    ms_t = Affine(4.0, 0, 1030.0, 0, -4.0, 2012.0)
    georef = dict(pan_transform=pan_t, ms_transform=ms_t, pan_crs="EPSG:32633", ms_crs="EPSG:32633")
    return pan, ms, georef


@pytest.mark.parametrize("method", METHODS)
def test_every_method_equals_the_in_memory_result_with_chunks_that_do_not_divide_the_image(method):
    pan, ms, georef = _pair()
    ref = pansharpen(pan, ms, method, **georef)
    info = {}
    out = pansharpen_dask(pan, ms, method, chunks=24, info=info, **georef)  # 100 = 4 x 24 + 4
    assert out.chunks[1][:2] == (24, 24) and out.shape == ref.image.shape
    got = out.compute(scheduler="threads").values
    assert np.array_equal(np.isnan(got), np.isnan(ref.image))
    ok = ~np.isnan(ref.image)
    assert np.allclose(got[ok], ref.image[ok], rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(info["gains"], ref.gains, rtol=1e-9)
    if ref.weights is not None:
        np.testing.assert_allclose(info["weights"], ref.weights, rtol=1e-9)
    t = out.rio.transform()
    assert t.almost_equals(ref.transform) and out.rio.crs == "EPSG:32633"


def test_nothing_is_read_or_computed_when_the_graph_is_built(tmp_path, monkeypatch):
    """The PAN as a Dask array whose chunks count their computations, and as a file whose windowed reads
    are counted; the graph is built under a scheduler that refuses to run anything."""
    pan, ms, georef = _pair()
    calls = []

    def counted(block):
        calls.append(block.shape)
        return block

    lazy_pan = da.from_array(pan, chunks=32).map_blocks(counted, meta=np.empty((0, 0), pan.dtype))
    write_geotiff(tmp_path / "pan.tif", pan[None], georef["pan_transform"], crs="EPSG:32633")
    write_geotiff(tmp_path / "ms.tif", ms, georef["ms_transform"], crs="EPSG:32633")
    from photax.fusion import _dask

    reads = []
    getitem = _dask._BandReader.__getitem__
    monkeypatch.setattr(_dask._BandReader, "__getitem__", lambda self, key: reads.append(key) or getitem(self, key))

    def refuse(*args, **kwargs):
        raise AssertionError("the graph was computed while it was built")

    with dask.config.set(scheduler=refuse):
        from_array = pansharpen_dask(lazy_pan, ms, "mtf_glp", chunks=32, **georef)
        from_files = pansharpen_dask(tmp_path / "pan.tif", tmp_path / "ms.tif", "gsa", chunks=32)
    assert calls == [] and reads == []
    ref = pansharpen(pan, ms, "mtf_glp", **georef).image
    np.testing.assert_allclose(from_array.compute(scheduler="sync").values, ref, rtol=1e-5, atol=1e-4)
    assert calls and reads == []
    ref = pansharpen(pan, ms, "gsa", **georef).image  # the files' georeference and CRS, read by the graph
    np.testing.assert_allclose(from_files.compute(scheduler="threads").values, ref, rtol=1e-5, atol=1e-4)
    assert reads


def test_bad_input_is_refused_when_the_graph_is_built():
    pan, ms, georef = _pair()
    with pytest.raises(ValueError, match="chunks must be at least 16"):
        pansharpen_dask(pan, ms, chunks=8, **georef)
    far = dict(georef, ms_transform=Affine(4.0, 0, 9000.0, 0, -4.0, 2000.0))
    with pytest.raises(ValueError, match="do not overlap"):
        pansharpen_dask(pan, ms, **far)
    with pytest.raises(ValueError, match="one band"):
        pansharpen_dask(pan, ms[:1], "gs", **georef)
    heavy = pan.copy()
    heavy[2:] = np.nan  # no MS pixel sees only valid PAN pixels
    with pytest.raises(ValueError, match="too few MS pixels"):  # a data error: when computed
        pansharpen_dask(heavy, ms, **georef).compute(scheduler="sync")


@pytest.mark.skipif(not (PAIR / "pan.tif").is_file(), reason="the orthority pan/MS pair is not in ../shared/data")
@pytest.mark.parametrize("method", METHODS)
def test_the_real_pair_from_its_files_equals_the_in_memory_result(method):
    """orthority's uint8 pair (1368 x 912 PAN, ratio 4), read window by window in chunks of 200 (which do
    not divide it): at most one grey level apart from the in-memory result, at rare pixels (float32 sums
    in another order, rounded)."""
    pan, _ = read_geotiff(PAIR / "pan.tif")
    ms, _ = read_geotiff(PAIR / "ms.tif")
    ref = pansharpen(pan[0], ms, method).image
    got = pansharpen_dask(PAIR / "pan.tif", PAIR / "ms.tif", method, chunks=200).compute(scheduler="threads")
    diff = np.abs(got.values.astype(int) - ref.astype(int))
    assert got.dtype == np.uint8 and diff.max() <= 1 and (diff > 0).mean() < 1e-4


def test_photax_sharpen_with_chunks_writes_what_the_in_memory_command_writes(tmp_path, capsys):
    pan, ms, georef = _pair()
    pan = np.nan_to_num(pan, nan=0).round().astype(np.uint16)[None]
    ms = np.nan_to_num(ms, nan=0).round().astype(np.uint16)
    write_geotiff(tmp_path / "pan.tif", pan, georef["pan_transform"], crs="EPSG:32633")
    write_geotiff(tmp_path / "ms.tif", ms, georef["ms_transform"], crs="EPSG:32633")
    args = ["sharpen", str(tmp_path / "pan.tif"), str(tmp_path / "ms.tif"), "--method", "hpf"]
    assert main([*args, "-o", str(tmp_path / "whole.tif")]) == 0
    assert main([*args, "-o", str(tmp_path / "chunked.tif"), "--chunks", "40"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].split("->")[1].split("(")[1] == printed[1].split("->")[1].split("(")[1]  # size, ratio
    with rasterio.open(tmp_path / "whole.tif") as a, rasterio.open(tmp_path / "chunked.tif") as b:
        assert a.transform == b.transform and a.crs == b.crs and a.shape == b.shape and a.dtypes == b.dtypes
        diff = np.abs(a.read().astype(int) - b.read().astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 1e-3


def test_an_ms_in_another_crs_gives_the_in_memory_result():
    """The MS on a UTM grid, the PAN on a Web Mercator one: the positions are no separable lattice (the JAX
    resampler, per chunk) and the MS pixel centres fall in the PAN's blocks along curved lines."""
    from rasterio.warp import transform_bounds

    left, bottom, right, top = transform_bounds("EPSG:32633", "EPSG:3857", 500000, 4000000, 500256, 4000256)
    pan_t = Affine(2.0, 0, left, 0, -2.0, top)
    shape = (int((top - bottom) / 2), int((right - left) / 2))
    pan = (100 + 20 * _texture(shape, 1) + 10 * _texture(shape, 2, 1.0)).astype(np.float32)
    ms = np.stack([100 + 20 * _texture((32, 32), k) for k in range(3)]).astype(np.float32)
    georef = dict(
        pan_transform=pan_t,
        ms_transform=Affine(8.0, 0, 500000.0, 0, -8.0, 4000256.0),
        pan_crs="EPSG:3857",
        ms_crs="EPSG:32633",
        weights="equal",
    )
    ref = pansharpen(pan, ms, "gs", **georef).image
    got = pansharpen_dask(pan, ms, "gs", chunks=70, **georef).compute(scheduler="threads").values
    assert np.array_equal(np.isnan(got), np.isnan(ref))
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-3)
