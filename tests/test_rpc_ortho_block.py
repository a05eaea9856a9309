"""``photax ortho A.tif B.tif --camera rpc --out-dir DIR``: several satellite images in one process, each
with its own RPC (issue 23), by the frame block's code (``photax.orthorectify_files``).

On the QuickBird scene (``../shared/data/orthority/rpc``; skipped when absent) given twice: as it is, and
a copy whose RPC is moved 3 lines (``line_off`` + 3, written into the copy by GDAL). Each ortho of the
block is, bit for bit, what ``photax ortho IMAGE -o OUT`` writes for that image alone, also refined on
its own GCPs (the GCP file names each image: b's refinement takes its RPC's 3 lines back, so both
orthos agree); a broken image is named, exits 1, the others written.
"""

import filecmp
import json
import shutil

import numpy as np
import pytest
from conftest import shared_file

from photax.cli import main

rasterio = pytest.importorskip("rasterio")


@pytest.fixture
def scene(tmp_path):
    tif = shared_file("orthority/rpc/qb2_basic1b.tif")
    dem = shared_file("orthority/ngi/dem.tif")
    gcps = json.loads(shared_file("orthority/rpc/gcps.geojson").read_text())
    folder = tmp_path / "in"
    folder.mkdir()
    a, b = folder / "a.tif", folder / "b.tif"
    for p in (a, b):
        shutil.copy(tif, p)
        p.chmod(0o644)
    with rasterio.open(b, "r+") as dst:
        rpcs = dst.rpcs
        rpcs.line_off += 3.0
        dst.rpcs = rpcs
    both = dict(gcps, features=[])
    for name in ("a.tif", "b.tif"):  # the same pixels: b's refinement takes its RPC's 3 lines back
        for f in gcps["features"]:
            g = json.loads(json.dumps(f))
            g["properties"]["filename"] = name
            both["features"].append(g)
    (tmp_path / "gcps.geojson").write_text(json.dumps(both))
    return a, b, dem, tmp_path / "gcps.geojson"


def _common(dem, gcps):
    return ["--camera", "rpc", "--dem", str(dem), "--crs", "EPSG:32735", "--resolution", "25", "--no-progress",
            "--gcps", str(gcps), "--refine", "shift-drift"]  # fmt: skip


def test_rpc_block_equals_single_runs_and_a_failure_exits_1(scene, tmp_path, capsys):
    a, b, dem, gcps = scene
    broken = a.with_name("broken.tif")
    broken.write_bytes(b"II*\x00" + b"\x17" * 500)  # a TIFF header and garbage
    rc = main(["ortho", str(a), str(broken), str(b), "--out-dir", str(tmp_path / "block"), *_common(dem, gcps)])
    out, err = capsys.readouterr()
    assert rc == 1, err
    assert f"{broken} failed" in err and "1 of 3 images failed" in err
    assert out.count("wrote ") == 2 and "a.tif:\nRPC refinement (shift-drift) on 5 GCPs" in out
    assert not (tmp_path / "block" / "broken_ortho.tif").exists()
    assert not list((tmp_path / "block").glob(".*part"))  # no temporary left
    (tmp_path / "single").mkdir()
    for image in (a, b):
        single = tmp_path / "single" / f"{image.stem}.tif"
        assert main(["ortho", str(image), "-o", str(single), *_common(dem, gcps)]) == 0
        assert filecmp.cmp(tmp_path / "block" / f"{image.stem}_ortho.tif", single, shallow=False)
    with (
        rasterio.open(tmp_path / "block" / "a_ortho.tif") as fa,
        rasterio.open(tmp_path / "block" / "b_ortho.tif") as fb,
    ):
        assert fa.transform == fb.transform  # each image refined on its GCPs: the same ground
        va, vb = fa.read(1).astype(float), fb.read(1).astype(float)
    both = (va > 0) & (vb > 0)
    assert both.mean() > 0.5 and np.abs(va - vb)[both].mean() < 1.0


def test_rpc_block_usage_errors_exit_2(scene, tmp_path, capsys):
    a, b, dem, gcps = scene
    unnamed = json.loads(gcps.read_text())
    for f in unnamed["features"]:
        del f["properties"]["filename"]
    (tmp_path / "unnamed.geojson").write_text(json.dumps(unnamed))
    rpb = tmp_path / "one.RPB"
    from photax.io.satellite import read_rpc, write_rpc

    write_rpc(read_rpc(a), rpb, "rpb")  # an RPC file (by content), one for two images
    out = ["--out-dir", str(tmp_path / "o")]
    common = _common(dem, gcps)
    cases = [
        ([*common[:-4], "--gcps", str(tmp_path / "unnamed.geojson"), *out], "name no image"),
        ([*common[2:-4], "--camera", str(rpb), *out], "one RPC for 2 images"),
        ([*common[:-4], "-o", str(tmp_path / "x.tif")], "give --out-dir"),
    ]
    for extra, message in cases:
        assert main(["ortho", str(a), str(b), *extra]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err
    only_a = json.loads(gcps.read_text())
    only_a["features"] = [f for f in only_a["features"] if f["properties"]["filename"] == "a.tif"]
    (tmp_path / "only_a.geojson").write_text(json.dumps(only_a))
    assert main(["ortho", str(a), str(b), *common[:-4], "--gcps", str(tmp_path / "only_a.geojson"), *out]) == 2
    err = capsys.readouterr().err
    assert f"{b}: " in err and "no GCP measured in b.tif" in err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_orthorectify_files_takes_one_camera_and_dem_per_image_or_one_shared(tmp_path):
    from photax.rectification import orthorectify_files

    with pytest.raises(ValueError, match="2 cameras for 3 images: give one shared, or one per image"):
        orthorectify_files(["a", "b", "c"], ["x", "y", "z"], None, [object(), object()], object())
    with pytest.raises(ValueError, match="1 DEMs for 2 images"):
        orthorectify_files(["a", "b"], ["x", "y"], None, object(), [object()])


def test_export_params_writes_each_images_rpc_for_orthority(scene, tmp_path, capsys):
    """``--export-params DIR`` with RPC images: their RPCs as orthority's rpc_param.yaml, each entry read
    back equal to the RPC in its image (b's moved 3 lines); a refined RPC (--gcps) is refused by name."""
    from photax.rpc import read_rpc

    a, b, dem, gcps = scene
    raw = _common(dem, gcps)[:-4]
    params = tmp_path / "params"
    assert main(["ortho", str(a), str(b), *raw, "--out-dir", str(tmp_path / "o"), "--export-params", str(params)]) == 0
    for image in (a, b):
        back, truth = read_rpc(params / "rpc_param.yaml", image.name), read_rpc(image)
        for field in ("coefficients", "offsets", "scales"):
            np.testing.assert_array_equal(np.asarray(getattr(back, field)), np.asarray(getattr(truth, field)))
    assert float(read_rpc(params / "rpc_param.yaml", "b.tif").offsets[4]) == float(read_rpc(a).offsets[4]) + 3.0
    capsys.readouterr()
    refined = [*_common(dem, gcps), "--out-dir", str(tmp_path / "o2"), "--export-params", str(tmp_path / "p2")]
    assert main(["ortho", str(a), str(b), *refined]) == 2
    assert "--export-params" in capsys.readouterr().err and not (tmp_path / "p2").exists()
