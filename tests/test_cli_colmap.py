"""``photax bundle`` on a COLMAP model, georeferenced with ``--gcps`` (synthetic truth of test_georeference)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_georeference import _model_and_gcps

from photax.cli import main
from photax.io import read_colmap, read_exterior, read_exteriors, read_interior, write_colmap, write_gcps


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("colmap_cli")
    model, gcps, truth, _ = _model_and_gcps(noise_px=0.0)
    write_colmap(model, folder / "sparse", binary=True)
    write_gcps(folder / "gcps.csv", gcps)
    return folder, truth


def test_bundle_georeferences_a_colmap_model(files, capsys):
    folder, truth = files
    out, model_out = folder / "out.json", folder / "georef"
    args = ["bundle", str(folder / "sparse"), "--gcps", str(folder / "gcps.csv"), "--quiet", "--no-progress"]
    assert main([*args, "-o", str(out), "--colmap-out", str(model_out)]) == 0
    text = capsys.readouterr().out
    assert "similarity model -> ground" in text and "check points (4)" in text
    data = json.loads(out.read_text())
    assert len(data["check_points"]) == 4 and data["similarity"]["scale"] == pytest.approx(1 / 0.013)
    assert max(abs(v) for c in data["check_points"] for v in c["residual"]) < 1e-4
    # the result reads as exteriors (ortho --exterior out.json) and the written model as COLMAP, in ground units
    table, _ = read_exteriors(out)
    assert np.allclose([table[k].position for k in table], truth.exterior.position, atol=1e-4)
    with pytest.warns(UserWarning, match=r"point\(s\) seen in fewer than 2 images left out"):
        back = read_colmap(model_out)  # the control point seen in one image
    np.testing.assert_allclose(back.exterior.position, truth.exterior.position, rtol=0, atol=1e-4)
    # its files as --camera and --exterior (ortho, resect ...), found by content
    cam = read_interior(model_out / "cameras.txt")
    assert float(cam.focal_length) == pytest.approx(float(truth.camera.focal_length), rel=1e-12)
    eo, crs = read_exterior(model_out / "images.txt", "S1_3.tif")
    assert crs is None
    assert np.allclose(eo.rotation, np.asarray(truth.exterior.rotation)[2], atol=1e-9)
    np.testing.assert_allclose(eo.position, truth.exterior.position[2], atol=1e-4)
    assert pycolmap_images(model_out) == 8


def test_bundle_colmap_usage_errors(files, capsys):
    folder, _ = files
    sparse = str(folder / "sparse")
    assert main(["bundle", sparse, "--gcp-sigma", "0.1", "--no-progress"]) == 2
    assert "--gcp-sigma needs --gcps" in capsys.readouterr().err
    assert main(["bundle", sparse, "--gcps", str(folder / "gcps.csv"), "--gcp-sigma", "-1", "--no-progress"]) == 2
    assert main(["bundle", sparse, "--colmap-out", sparse, "--no-progress"]) == 2
    assert "not an empty folder" in capsys.readouterr().err


def test_bundle_georeferences_with_gnss_positions(files, capsys):
    """GNSS centres from an orthority CSV (x y z omega phi kappa: the angles are not used)."""
    folder, truth = files
    gnss = folder / "gnss.csv"
    rows = [f"{n},{x!r},{y!r},{z!r},0,0,0" for n, (x, y, z) in
            zip([f"{n}.jpg" for n in truth_names()], np.asarray(truth.exterior.position).tolist())]  # fmt: skip
    gnss.write_text("filename,x,y,z,omega,phi,kappa\n" + "\n".join(rows) + "\n")
    out = folder / "gnss.json"
    args = ["bundle", str(folder / "sparse"), "--gnss", str(gnss), "--position-sigma", "0.05", "--quiet"]
    assert main([*args, "--no-progress", "-o", str(out)]) == 0
    assert "GNSS positions (8)" in capsys.readouterr().out
    table, _ = read_exteriors(out)
    assert np.allclose([table[k].position for k in table], truth.exterior.position, atol=1e-4)
    assert main([*args[:4], "--no-progress"]) == 2  # --gnss without --position-sigma
    assert "--gnss needs --position-sigma" in capsys.readouterr().err


def truth_names():
    from photax.scene import synthetic_block

    return synthetic_block(0, noise_px=0.0)[0].image_names


def pycolmap_images(folder) -> int:
    pycolmap = pytest.importorskip("pycolmap")
    return pycolmap.Reconstruction(str(folder)).num_reg_images()


def test_gcps_and_gnss_in_two_crss_are_refused(files, capsys):
    import dataclasses

    from photax.io import read_gcps

    folder, truth = files
    gcps = dataclasses.replace(read_gcps(folder / "gcps.csv"), crs="EPSG:32633")
    write_gcps(folder / "gcps33.csv", gcps)
    gnss = folder / "gnss34.csv"
    rows = [f"{n}.jpg,{x!r},{y!r},{z!r},0,0,0" for n, (x, y, z) in
            zip(truth_names(), np.asarray(truth.exterior.position).tolist())]  # fmt: skip
    gnss.write_text("filename,x,y,z,omega,phi,kappa\n" + "\n".join(rows) + "\n")
    gnss.with_suffix(".prj").write_text("EPSG:32634\n")
    args = ["bundle", str(folder / "sparse"), "--gcps", str(folder / "gcps33.csv"), "--gnss", str(gnss),
            "--position-sigma", "0.05", "--no-progress"]  # fmt: skip
    assert main(args) == 2
    assert "give both in one CRS" in capsys.readouterr().err


def test_bundle_takes_odm_geo_txt_as_gnss(files, capsys):
    """ODM's geo.txt (written by photax.io.write_odm_geo) is a --gnss file as it is; 2-D positions
    are refused, and as an --exterior it is refused by name (positions, no attitude)."""
    from photax.io import write_odm_geo

    folder, truth = files
    names = [f"{n}.jpg" for n in truth_names()]
    positions = dict(zip(names, np.asarray(truth.exterior.position)))
    geo = write_odm_geo(folder / "geo.txt", positions, "EPSG:32633")
    out = folder / "geo.json"
    args = [
        "bundle",
        str(folder / "sparse"),
        "--gnss",
        str(geo),
        "--position-sigma",
        "0.05",
        "--quiet",
        "--no-progress",
    ]
    assert main([*args, "-o", str(out)]) == 0
    assert "GNSS positions (8)" in capsys.readouterr().out
    table, crs = read_exteriors(out)
    assert np.allclose([table[k].position for k in table], truth.exterior.position, atol=1e-4)
    flat = write_odm_geo(folder / "geo2d.txt", {k: v[:2] for k, v in positions.items()}, "EPSG:32633")
    assert main([*args[:3], str(flat), *args[4:]]) == 2
    assert "no height (geo_z)" in capsys.readouterr().err
    with pytest.raises(ValueError, match="holds positions, no attitude"):
        read_exteriors(geo)
