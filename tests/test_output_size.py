"""Output size and resolution checks before any work (issue 26 item 8, issue 27 "CRS checks").

A resolution typo used to allocate a grid of ~1e14 pixels ("unexpected MemoryError") and
``--resolution 1e308`` wrote a 1 x 1 image with exit 0.  References: the sample's ground sampling
distance in closed form (flying height over the DEM times pixel size over focal length), and the
output's bytes as rows x cols x bands x itemsize.
"""

import collections
import errno
import pathlib
import re
import shutil

import numpy as np
import pytest

from photax.demo import sample_scene
from photax.io import sizes as _size
from photax.rectification import ground_sampling_distance, ortho_grid, orthorectify, orthorectify_file

DATA = pathlib.Path(__file__).resolve().parents[1] / "data"


@pytest.fixture(scope="module")
def scene():
    return sample_scene()


def _closed_form_gsd(s):
    cam, ext, dem = s["camera"], s["exterior"], s["dem"]
    height = float(np.asarray(ext.position)[2]) - float(np.nanmean(np.asarray(dem.heights)))
    return height * float(np.asarray(cam.pixel_size).ravel()[0]) / float(cam.focal_length)


def test_gsd_matches_the_closed_form(scene):
    gsd = ground_sampling_distance(scene["exterior"], scene["camera"], scene["dem"])
    assert gsd == pytest.approx(_closed_form_gsd(scene), rel=0.03)  # tilt 1-2 deg, relief: a few %


@pytest.mark.parametrize("resolution", [1e308, 1000.0, 1e-4, 0.005])
def test_resolution_outside_the_supported_range(scene, resolution):
    gsd = _closed_form_gsd(scene)
    with pytest.raises(ValueError, match="outside what the image supports") as err:
        ortho_grid(scene["exterior"], scene["camera"], scene["dem"], resolution)
    lo, hi = (float(v) for v in re.search(r"choose from (\S+) to (\S+) ", str(err.value)).groups())
    assert lo == pytest.approx(gsd / 100, rel=0.03) and lo <= hi <= 100 * gsd * 1.03


def test_range_ends_are_accepted_and_give_at_least_16_pixels(scene):
    with pytest.raises(ValueError) as err:
        ortho_grid(scene["exterior"], scene["camera"], scene["dem"], 1e308)
    lo, hi = (float(v) for v in re.search(r"choose from (\S+) to (\S+) ", str(err.value)).groups())
    coarse = ortho_grid(scene["exterior"], scene["camera"], scene["dem"], hi * 0.999)
    assert min(coarse.shape) >= 16
    fine = ortho_grid(scene["exterior"], scene["camera"], scene["dem"], lo * 1.001)
    assert fine.width > 100 * 900  # the sample is 1000 x 750 px: 100 times finer
    with pytest.raises(ValueError):  # hi is the footprint / 16: 1.5 hi gives ~11 pixels on the short side
        ortho_grid(scene["exterior"], scene["camera"], scene["dem"], hi * 1.5)


def _image(s):
    w, h = s["camera"].image_size
    return np.full((h, w), 7, dtype=np.uint8)


def test_in_memory_output_refused_when_memory_is_short(scene, monkeypatch):
    grid = ortho_grid(scene["exterior"], scene["camera"], scene["dem"], 0.5)
    need = grid.height * grid.width * 1  # uint8, one band
    monkeypatch.setattr(_size, "_available_memory", lambda: need - 1)
    with pytest.raises(ValueError) as err:
        orthorectify(_image(scene), scene["exterior"], scene["camera"], scene["dem"], grid)
    msg = str(err.value)
    assert f"{grid.height * grid.width:,} pixels" in msg and "of memory available" in msg
    assert "orthorectify_file" in msg and "ground sampling distance" in msg
    monkeypatch.setattr(_size, "_available_memory", lambda: need)  # exactly enough: it runs
    out, _ = orthorectify(_image(scene), scene["exterior"], scene["camera"], scene["dem"], grid)
    assert out.shape == grid.shape


def test_file_output_refused_when_the_disk_is_short(scene, tmp_path, monkeypatch):
    src = DATA / "sample_image.tif"
    grid = ortho_grid(scene["exterior"], scene["camera"], scene["dem"], 0.5)
    need = grid.height * grid.width  # one uint8 band, uncompressed
    usage = collections.namedtuple("usage", "total used free")
    real = shutil.disk_usage
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(need * 10, need * 10 - need + 1, need - 1))
    out = tmp_path / "o.tif"
    with pytest.raises(OSError, match=r"no space left on device: .* free on the disk") as err:
        orthorectify_file(src, out, scene["exterior"], scene["camera"], scene["dem"], grid, compress=None)
    assert f"{need:,} pixels" in str(err.value) and "ground sampling distance" in str(err.value)
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(out)
    assert list(tmp_path.iterdir()) == []  # nothing written, no temporary left
    # compressed (the default), its size is not known: refused only where even 100:1 could not fit
    orthorectify_file(src, out, scene["exterior"], scene["camera"], scene["dem"], grid)
    out.unlink()
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(need * 10, need * 10, need // 100 - 1))
    with pytest.raises(OSError, match=r"even at 100:1 compression"):
        orthorectify_file(src, out, scene["exterior"], scene["camera"], scene["dem"], grid)
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(shutil, "disk_usage", real)
    orthorectify_file(src, out, scene["exterior"], scene["camera"], scene["dem"], grid)
    assert out.exists()


@pytest.mark.parametrize("resolution", ["1e308", "0.0001"])
def test_cli_ortho_typo_is_a_usage_error(tmp_path, capsys, resolution):
    from photax.cli import main

    ext = tmp_path / "ext.json"
    assert (
        main(
            ["resect", str(DATA / "sample_gcps.csv"), "--camera", str(DATA / "sample_camera.yaml"), "--json", str(ext)]
        )
        == 0
    )
    capsys.readouterr()
    code = main(
        [
            "ortho",
            str(DATA / "sample_image.tif"),
            "--dem",
            str(DATA / "sample_dem.tif"),
            "--camera",
            str(DATA / "sample_camera.yaml"),
            "--exterior",
            str(ext),
            "--out",
            str(tmp_path / "o.tif"),
            "--resolution",
            resolution,
            "--no-progress",
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and "ground sampling distance" in err and "choose from" in err
    assert not (tmp_path / "o.tif").exists()


def test_to_raster_refused_when_the_disk_is_short(tmp_path, monkeypatch):
    pytest.importorskip("rioxarray")
    from photax.io.lazy import dataarray, to_raster
    from photax.rectification import Grid

    grid = Grid.from_bounds((0.0, 0.0, 300.0, 200.0), 1.0)
    arr = dataarray(np.zeros((2, 200, 300), np.uint16), grid, np.asarray(0, np.uint16), "x")
    need = 2 * 200 * 300 * 2
    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(need * 10, need * 9, need - 1))
    with pytest.raises(OSError, match=r"60,000 pixels x 2 band\(s\) needs 240 kB"):
        to_raster(arr, tmp_path / "x.tif", compress=None)
    assert list(tmp_path.iterdir()) == []


def test_cli_rectify_resolution_outside_the_gcps_scale(tmp_path, capsys):
    """``photax rectify --resolution 1e308`` wrote a 1 x 1 image with exit 0 (issue 27)."""
    from photax.cli import main

    code = main(
        [
            "rectify",
            str(DATA / "sample_image.tif"),
            "--gcps",
            str(DATA / "sample_gcps.csv"),
            "--order",
            "1",
            "--out",
            str(tmp_path / "r.tif"),
            "--resolution",
            "1e308",
            "--no-progress",
        ]
    )
    assert code == 2 and "choose from" in capsys.readouterr().err and not (tmp_path / "r.tif").exists()
