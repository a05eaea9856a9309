"""Palette images keep their colour indices and colour map (issue 27 "Images as they are"): a palette
GeoTIFF was resampled bilinearly (215 invented indices) and its colour map dropped.  Reference: the
index array rectified in memory by nearest neighbour, and the input's colour map."""

import jax.numpy as jnp
import numpy as np
import pytest

rasterio = pytest.importorskip("rasterio")

from photax.rectification import Grid, rectify, rectify_file  # noqa: E402

H, W = 60, 80
CMAP = {1: (255, 0, 0, 255), 3: (0, 255, 0, 255), 5: (0, 0, 255, 255)}
GRID = Grid.from_bounds((-10.0, -10.0, 90.0, 70.0), 0.7, crs="EPSG:32633")


def model(xy):  # map -> pixel: a rotation by 20 degrees about the image centre
    c, s = np.cos(0.35), np.sin(0.35)
    x, y = xy[..., 0] - W / 2, xy[..., 1] - H / 2
    return jnp.stack([c * x - s * y + W / 2, s * x + c * y + H / 2], axis=-1)


@pytest.fixture
def palette_tif(tmp_path):
    idx = np.ones((H, W), np.uint8)
    idx[:, 25:50] = 3
    idx[20:45, :] = 5
    path = tmp_path / "palette.tif"
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=W,
        height=H,
        count=1,
        dtype="uint8",
        crs="EPSG:32633",
        transform=rasterio.transform.from_origin(0, H, 1, 1),
    ) as dst:
        dst.write(idx, 1)
        dst.write_colormap(1, CMAP)
    return path, idx


def test_palette_is_resampled_by_nearest_and_keeps_its_colour_map(palette_tif, tmp_path):
    path, idx = palette_tif
    out = tmp_path / "out.tif"
    rectify_file(path, out, model, GRID, resampling=None)  # None: nearest for a palette image
    ref = rectify(idx, model, GRID, resampling="nearest", approx=0)
    with rasterio.open(out) as ds:
        data, valid = ds.read(1), ds.read_masks(1) > 0
        assert ds.colorinterp[0] == rasterio.enums.ColorInterp.palette
        cmap = ds.colormap(1)
    assert all(cmap[k] == v for k, v in CMAP.items())
    assert valid.sum() > 2000 and set(np.unique(data[valid])) <= {1, 3, 5}  # no invented index
    assert np.array_equal(data[valid], np.asarray(ref)[valid])


@pytest.mark.parametrize("kernel", ["bilinear", "cubic"])
def test_palette_refuses_interpolating_kernels(palette_tif, tmp_path, kernel):
    path, _ = palette_tif
    with pytest.raises(ValueError, match="palette image.*nearest"):
        rectify_file(path, tmp_path / "out.tif", model, GRID, resampling=kernel)
    assert not (tmp_path / "out.tif").exists()


def test_palette_refused_by_dask_kernels(palette_tif):
    pytest.importorskip("dask")
    pytest.importorskip("rioxarray")
    from photax.demo import sample_scene
    from photax.rectification import orthorectify_dask

    s = sample_scene()
    path, _ = palette_tif
    with pytest.raises(ValueError, match="palette image"):
        orthorectify_dask(path, s["exterior"], s["camera"], s["dem"], GRID, resampling="bilinear")
