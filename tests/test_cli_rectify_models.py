"""``photax rectify --model tps | piecewise-affine`` (issue 24, item 4): the command writes what the library
writes with fit_tps / fit_piecewise_affine on the same control GCPs and grid."""

import numpy as np
import pytest
from conftest import ROOT

import photax as ptx
from photax.cli import main
from photax.io.gcp import read_gcps

DATA = ROOT / "data"
RES = 8.0  # map units per pixel: a small output, a fast test


@pytest.mark.parametrize("name, fit", [("tps", ptx.fit_tps), ("piecewise-affine", ptx.fit_piecewise_affine)])
def test_cli_output_equals_the_library(tmp_path, capsys, name, fit):
    out = tmp_path / "rect.tif"
    argv = ["rectify", str(DATA / "sample_image.tif"), "--gcps", str(DATA / "sample_gcps.csv"), "--model", name]
    assert main([*argv, "--resolution", str(RES), "--no-progress", "-o", str(out)]) == 0
    assert "leave-one-out rmse" in capsys.readouterr().out
    table = read_gcps(DATA / "sample_gcps.csv")
    control = ~table.check
    ground, pixel = table.ground[control, :2], table.pixel[control]
    # the command's grid over the GCPs' footprint is target aligned (gdalwarp -tap)
    grid = ptx.Grid.from_bounds((*ground.min(axis=0), *ground.max(axis=0)), RES, crs=table.crs, target_aligned=True)
    image = ptx.read_geotiff(DATA / "sample_image.tif")[0][0]
    written, profile = ptx.read_geotiff(out)
    written = written[0]
    assert tuple(profile["transform"])[:6] == pytest.approx(tuple(grid.transform)[:6])
    expected = ptx.rectify(image.astype(np.float64), fit(ground, pixel), grid)
    assert written.shape == expected.shape
    valid = np.isfinite(expected)
    assert valid.mean() > 0.5
    np.testing.assert_array_equal(written[valid], np.round(expected[valid]))  # uint8 written: rounded


def test_order_is_for_the_polynomial_only(tmp_path, capsys):
    argv = ["rectify", str(DATA / "sample_image.tif"), "--gcps", str(DATA / "sample_gcps.csv"), "--model", "tps"]
    assert main([*argv, "--order", "2", "-o", str(tmp_path / "r.tif")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("photax rectify: error:") and "--order is for --model polynomial" in err
