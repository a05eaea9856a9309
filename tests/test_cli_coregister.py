"""``photax coregister`` (issue 24, item 3): the command writes what the library computes, in both modes."""

import json

import numpy as np
import pytest
from test_coregister import _pair

import photax as ptx
from photax.cli import main

T_REF = (2.0, 0.0, 500000.0, 0.0, -2.0, 4000000.0)


@pytest.fixture(scope="module")
def rasters(tmp_path_factory):
    d = tmp_path_factory.mktemp("coreg")
    ref, tgt, truth, _, _ = _pair(256, 64, (1.6, -0.7))
    ptx.write_geotiff(d / "ref.tif", ref.astype(np.float32), T_REF, crs=32633)
    ptx.write_geotiff(d / "tgt.tif", np.stack([tgt, 2 * tgt]).astype(np.float32), T_REF, crs=32633)
    return d, ref, tgt, truth


def test_resample_mode_writes_the_target_on_the_reference_grid(rasters, capsys):
    d, ref, tgt, truth = rasters
    out, report = d / "out.tif", d / "windows.json"
    assert main(["coregister", str(d / "ref.tif"), str(d / "tgt.tif"), "-o", str(out), "--report", str(report)]) == 0
    text = capsys.readouterr().out
    gx, gy = (float(v) for v in text.split("global shift ")[1].split(" px")[0].split())
    assert abs(gx - 1.6) < 0.02 and abs(gy + 0.7) < 0.02 and "affine model" in text
    img, profile = ptx.read_geotiff(out)
    assert img.shape == (2, 256, 256) and tuple(profile["transform"])[:6] == pytest.approx(T_REF)
    reg = ptx.coregister(ref, tgt.astype(np.float32).astype(float))
    np.testing.assert_allclose(img[0], reg.resample(tgt.astype(np.float32), ref.shape), atol=1e-5)
    inner = (slice(16, -16), slice(16, -16))
    assert np.abs(img[0][inner] - ref[inner]).max() < 0.05 * np.ptp(ref)
    windows = json.loads(report.read_text())
    assert windows["counts"]["ok"] == reg.counts["ok"] and len(windows["windows"]) == len(reg.centres)


def test_georeference_mode_moves_the_transform_by_the_shift(rasters):
    d, _, tgt, _ = rasters
    out = d / "geo.tif"
    assert main(["coregister", str(d / "ref.tif"), str(d / "tgt.tif"), "-o", str(out), "--mode", "georeference"]) == 0
    img, profile = ptx.read_geotiff(out)
    np.testing.assert_array_equal(img[0], tgt.astype(np.float32))  # the pixels untouched
    t = tuple(profile["transform"])[:6]
    # the target is the reference moved by (1.6, -0.7) px: its origin moves back by that many 2 m pixels
    assert t[2] == pytest.approx(T_REF[2] - 2 * 1.6, abs=0.05) and t[5] == pytest.approx(T_REF[5] - 2 * 0.7, abs=0.05)


def test_usage_errors_exit_2(rasters, capsys):
    d = rasters[0]
    argv = ["coregister", str(d / "ref.tif"), str(d / "tgt.tif")]
    assert main([*argv, "-o", str(d / "x.tif"), "--model", "tps", "--mode", "georeference"]) == 2
    assert "needs --model affine" in capsys.readouterr().err
    assert main([*argv, "-o", str(d / "ref.tif")]) == 2  # never overwrite an input
    assert main([*argv, "-o", str(d / "x.tif"), "--band", "3"]) == 2
    assert "--band 3" in capsys.readouterr().err
