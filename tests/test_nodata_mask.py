"""Orthos of integer images keep every grey value: no-data is a mask band, not the value 0
(issue 26 item 6: a 100 x 100 true-black patch lost 8,413 output pixels to nodata 0), and the
input's own mask is respected (issue 27 "Images as they are").

Reference: the same image as float64, whose ortho marks no-data by NaN (unambiguous), resampled by
nearest neighbour so that the values agree exactly.
"""

import pathlib

import numpy as np
import pytest

rasterio = pytest.importorskip("rasterio")

from photax.demo import sample_scene  # noqa: E402
from photax.io.raster import open_raster, read_geotiff  # noqa: E402
from photax.rectification import ortho_grid, orthorectify_file  # noqa: E402

DATA = pathlib.Path(__file__).resolve().parents[1] / "data"
# the inputs are raw photos (no georeference), as the sample image is
pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    s = sample_scene()
    tmp = tmp_path_factory.mktemp("mask")
    with open_raster(DATA / "sample_image.tif") as src:
        img, profile = src.read(1), dict(src.profile)
    profile.pop("transform", None)
    img = np.maximum(img, 1)  # no zero anywhere ...
    img[300:400, 450:550] = 0  # ... but a 100 x 100 true-black patch
    profile.update(nodata=None)
    paths = {}
    for name, data in (("u8", img), ("f64", img.astype(np.float64))):
        paths[name] = tmp / f"{name}.tif"
        with rasterio.open(paths[name], "w", **dict(profile, dtype=data.dtype)) as dst:
            dst.write(data, 1)
    grid = ortho_grid(s["exterior"], s["camera"], s["dem"], 2.0)
    return s, tmp, paths, grid


def _ortho(s, grid, src, out, **kw):
    orthorectify_file(src, out, s["exterior"], s["camera"], s["dem"], grid, resampling="nearest", **kw)
    with rasterio.open(out) as ds:
        return ds.read(1), ds.read_masks(1), ds.nodata, ds.mask_flag_enums[0]


def test_black_patch_survives_and_the_mask_is_the_footprint(setup):
    s, tmp, paths, grid = setup
    ref, _, ref_nodata, _ = _ortho(s, grid, paths["f64"], tmp / "f.tif")
    assert np.isnan(ref_nodata)
    data, mask, nodata, flags = _ortho(s, grid, paths["u8"], tmp / "u.tif")
    footprint = np.isfinite(ref)
    assert nodata is None and rasterio.enums.MaskFlags.per_dataset in flags
    assert np.array_equal(mask > 0, footprint)  # valid pixels = the footprint, exactly
    black = footprint & (ref == 0)
    assert black.sum() > 1000  # the patch, ~39 x 39 output pixels at 2 m
    assert np.all(data[black] == 0) and np.array_equal(data[footprint], ref[footprint].astype(np.uint8))
    # the readers see the mask: rasterio's masked read and photax's own
    with rasterio.open(tmp / "u.tif") as ds:
        m = ds.read(1, masked=True)
    mine, _ = read_geotiff(tmp / "u.tif", masked=True)
    assert np.array_equal(~np.ma.getmaskarray(m), footprint)
    assert np.array_equal(~np.ma.getmaskarray(mine[0]), footprint)
    # and so does the mosaic's reader (rioxarray, masked): black is 0, outside is NaN
    rioxarray = pytest.importorskip("rioxarray")
    arr = rioxarray.open_rasterio(tmp / "u.tif", masked=True).values[0]
    assert np.array_equal(np.isfinite(arr), footprint) and np.all(arr[black] == 0)


def test_nodata_option_records_a_value_and_no_mask(setup):
    s, tmp, paths, grid = setup
    data, mask, nodata, flags = _ortho(s, grid, paths["u8"], tmp / "n.tif", nodata=255)
    assert nodata == 255 and rasterio.enums.MaskFlags.per_dataset not in flags
    ref, *_ = _ortho(s, grid, paths["f64"], tmp / "f2.tif")
    assert np.array_equal(data == 255, ~np.isfinite(ref) | (ref == 255))


def _masked_inputs(tmp, paths):
    """The uint8 input with an internal mask over a block, and the same as float64 with NaN there."""
    with open_raster(paths["u8"]) as src:
        img, profile = src.read(1), dict(src.profile)
    profile.pop("transform", None)
    invalid = np.zeros(img.shape, bool)
    invalid[100:250, 100:300] = True
    masked_in = tmp / "masked_in.tif"
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True), rasterio.open(masked_in, "w", **profile) as dst:
        dst.write(img, 1)
        dst.write_mask(np.where(invalid, 0, 255).astype(np.uint8))
    nan_in = tmp / "nan_in.tif"
    with rasterio.open(nan_in, "w", **dict(profile, dtype="float64")) as dst:
        dst.write(np.where(invalid, np.nan, img.astype(np.float64)), 1)
    return masked_in, nan_in


def test_input_mask_is_respected(setup):
    s, tmp, paths, grid = setup
    masked_in, nan_in = _masked_inputs(tmp, paths)
    ref, *_ = _ortho(s, grid, nan_in, tmp / "rf.tif")  # nearest: NaN input pixels give NaN exactly
    data, mask, _, _ = _ortho(s, grid, masked_in, tmp / "rm.tif")
    plain, *_ = _ortho(s, grid, paths["f64"], tmp / "rp.tif")
    assert (np.isfinite(plain) & ~np.isfinite(ref)).sum() > 1000  # the masked region is in the ortho
    assert np.array_equal(mask > 0, np.isfinite(ref))


def test_cli_nodata(setup, tmp_path, capsys):
    from photax.cli import main

    s, tmp, paths, grid = setup
    ext = tmp_path / "ext.json"
    assert (
        main(
            ["resect", str(DATA / "sample_gcps.csv"), "--camera", str(DATA / "sample_camera.yaml"), "--json", str(ext)]
        )
        == 0
    )
    base = [
        "ortho",
        str(paths["u8"]),
        "--dem",
        str(DATA / "sample_dem.tif"),
        "--camera",
        str(DATA / "sample_camera.yaml"),
        "--exterior",
        str(ext),
        "--resolution",
        "2",
        "--no-progress",
    ]
    assert main([*base, "--out", str(tmp_path / "a.tif")]) == 0
    assert main([*base, "--out", str(tmp_path / "b.tif"), "--nodata", "7"]) == 0
    assert main([*base, "--out", str(tmp_path / "c.tif"), "--nodata", "300"]) == 2  # not a uint8 value
    with rasterio.open(tmp_path / "a.tif") as a, rasterio.open(tmp_path / "b.tif") as b:
        assert a.nodata is None and rasterio.enums.MaskFlags.per_dataset in a.mask_flag_enums[0]
        assert b.nodata == 7


def test_dask_ortho_with_its_mask(setup):
    pytest.importorskip("dask")
    pytest.importorskip("rioxarray")
    from photax.io.lazy import to_raster
    from photax.rectification import orthorectify_dask

    s, tmp, paths, grid = setup
    ref, *_ = _ortho(s, grid, paths["f64"], tmp / "fd.tif", tile=256)
    ortho, valid = orthorectify_dask(
        paths["u8"], s["exterior"], s["camera"], s["dem"], grid, chunks=256, resampling="nearest", mask=True
    )
    to_raster(ortho, tmp / "d.tif", mask=valid)
    with rasterio.open(tmp / "d.tif") as ds:
        data, mask = ds.read(1), ds.read_masks(1)
        assert ds.nodata is None
    footprint = np.isfinite(ref)
    assert np.array_equal(mask > 0, footprint)
    assert np.array_equal(data[footprint], ref[footprint].astype(np.uint8))
    assert np.sum(data[footprint] == 0) > 1000


def test_dask_ortho_respects_the_input_mask(setup):
    pytest.importorskip("dask")
    pytest.importorskip("rioxarray")
    from photax.rectification import orthorectify_dask

    s, tmp, paths, grid = setup
    masked_in, nan_in = _masked_inputs(tmp, paths)
    ref, *_ = _ortho(s, grid, nan_in, tmp / "rfd.tif", tile=256)
    ortho, valid = orthorectify_dask(
        masked_in, s["exterior"], s["camera"], s["dem"], grid, chunks=256, resampling="nearest", mask=True
    )
    valid, data = valid.values, ortho.values[0]  # from a file: (band, y, x)
    assert np.array_equal(valid, np.isfinite(ref))
    assert np.all(data[~valid] == 0) and np.array_equal(data[valid], ref[valid].astype(np.uint8))


def test_write_geotiff_mask_round_trip(tmp_path):
    from photax.io import write_geotiff

    data = np.zeros((2, 40, 50), np.uint8)  # all true black
    valid = np.zeros((40, 50), bool)
    valid[5:30, 10:45] = True
    write_geotiff(tmp_path / "m.tif", data, (1, 0, 0, 0, -1, 40), "EPSG:32633", mask=valid)
    with rasterio.open(tmp_path / "m.tif") as ds:
        assert ds.nodata is None and np.array_equal(ds.read_masks(1) > 0, valid)
    back, _ = read_geotiff(tmp_path / "m.tif", masked=True)
    assert np.array_equal(~np.ma.getmaskarray(back[1]), valid) and np.all(back[:, valid] == 0)
    with pytest.raises(ValueError, match="mask"):
        write_geotiff(tmp_path / "n.tif", data, None, mask=valid[:-1])
