"""``photax measure`` and ``photax.io.write_gcps``.

Images are rendered (area-sampled discs and a wedge, photax.scene.patterns) with known
centres / corners; the CLI's CSV must give them back, with a sigma and a status per point,
and its GCP output must read back with read_gcps.
"""

import csv
import math

import numpy as np
import pytest

from photax.cli import main
from photax.io import read_gcps, write_gcps
from photax.io.gcp import GCPTable
from photax.scene import patterns

pytest.importorskip("rasterio")
import rasterio.transform  # noqa: E402

CENTRES = np.array([[20.3, 18.7], [61.45, 22.1], [24.8, 55.35], [70.2, 60.6]])  # col, row
RADIUS = 6.0


def _write_tif(path, image):
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=image.shape[1],
        height=image.shape[0],
        count=1,
        dtype=image.dtype,
        transform=rasterio.transform.from_origin(500000.0, 4100000.0, 0.5, 0.5),
    ) as dst:
        dst.write(image, 1)


@pytest.fixture(scope="module")
def targets_tif(tmp_path_factory):
    def pattern(x, y):
        return np.max([patterns.disc(c, RADIUS)(x, y) for c in CENTRES], axis=0)

    img = patterns.render(pattern, (80, 96), blur=0.7, noise=0.01, low=20.0, high=220.0, rng=np.random.default_rng(3))
    path = tmp_path_factory.mktemp("measure") / "targets.tif"
    _write_tif(path, np.clip(np.round(img * 100), 0, 65535).astype(np.uint16))  # uint16 input
    return path


def _read_csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _num(s):
    return float(s) if s else math.nan


def test_measure_targets_plain_csv(targets_tif, tmp_path):
    pts = tmp_path / "approx.csv"
    approx = CENTRES + [[1.2, -0.8], [-1.0, 1.1], [0.6, 0.9], [-1.3, -0.4]]
    lines = ["name,col,row"] + [f"t{i},{c:.1f},{r:.1f}" for i, (c, r) in enumerate(approx)] + ["off,2.0,40.0"]
    pts.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.csv"
    code = main(["measure", str(targets_tif), "--targets", str(pts), "--radius", str(RADIUS), "-o", str(out)])
    assert code == 1  # the point at the border fails, the others are measured
    rows = _read_csv(out)
    assert [r["name"] for r in rows] == ["t0", "t1", "t2", "t3", "off"]
    assert [r["status"] for r in rows] == ["ok"] * 4 + ["outside"]
    xy = np.array([[_num(r["col"]), _num(r["row"])] for r in rows[:4]])
    sig = np.array([[_num(r["sigma_col"]), _num(r["sigma_row"])] for r in rows[:4]])
    assert np.sqrt(np.mean((xy - CENTRES) ** 2)) < 0.03
    assert np.all((sig > 0) & (sig < 0.1))
    assert rows[4]["col"] == "" and rows[4]["sigma_col"] == ""  # a failed point has no position


def test_measure_targets_gcp_roundtrip(targets_tif, tmp_path):
    """A GCP file in, measured GCPs out: read_gcps reads them, with the measured sigma."""
    table = GCPTable(
        names=np.array(["A", "B", "C", "D"]),
        images=np.array(["img"] * 4),
        ground=np.array([[100.0, 200.0, 10.0], [110.0, 200.0, 11.0], [100.0, 190.0, 12.0], [110.0, 190.0, 13.0]]),
        pixel=np.round(CENTRES),
        image_xy=None,
        sigma=np.full(4, 2.0),
        role=np.array(["control", "control", "check", "control"]),
        crs="EPSG:32633",
    )
    gcp_in = tmp_path / "approx_gcps.csv"
    write_gcps(gcp_in, table)
    out, gcp_out = tmp_path / "out.csv", tmp_path / "measured_gcps.csv"
    code = main(
        [
            "measure",
            str(targets_tif),
            "--targets",
            str(gcp_in),
            "--radius",
            str(RADIUS),
            "--method",
            "wong-trinder",
            "-o",
            str(out),
            "--gcp-out",
            str(gcp_out),
        ]
    )
    assert code == 0
    back = read_gcps(gcp_out)
    assert back.names.tolist() == ["A", "B", "C", "D"] and back.crs == "EPSG:32633"
    assert back.role.tolist() == table.role.tolist()
    np.testing.assert_array_equal(back.ground, table.ground)
    rows = _read_csv(out)
    # the GCP file carries the CSV's measurements (the binary-moment method's precision is
    # tested in test_measure_locators.py; here only a sanity bound)
    np.testing.assert_allclose(back.pixel, [[float(r["col"]), float(r["row"])] for r in rows], atol=1e-4)
    assert np.max(np.abs(back.pixel - CENTRES)) < 0.25
    sig = np.array([[float(r["sigma_col"]), float(r["sigma_row"])] for r in rows])
    np.testing.assert_allclose(back.sigma, np.sqrt(np.mean(sig**2, axis=1)), rtol=2e-3)


def test_measure_interest_points_refined(tmp_path):
    """Interest points of a rendered square: its four corners, refined to sub-pixel with a sigma."""
    corners = np.array([[20.35, 15.6], [52.35, 15.6], [52.35, 47.6], [20.35, 47.6]])

    def square(x, y):
        return ((x >= 20.35) & (x <= 52.35) & (y >= 15.6) & (y <= 47.6)).astype(float)

    img = patterns.render(square, (64, 72), blur=0.7, noise=0.005, rng=np.random.default_rng(1))
    tif = tmp_path / "square.tif"
    _write_tif(tif, img)
    out = tmp_path / "ip.csv"
    code = main(["measure", str(tif), "--interest", "foerstner", "--count", "4", "-o", str(out)])
    rows = _read_csv(out)
    assert code == 0, rows
    assert len(rows) == 4 and all(r["status"] == "ok" and float(r["strength"]) > 0 for r in rows)
    xy = np.array([[float(r["col"]), float(r["row"])] for r in rows])
    d = np.linalg.norm(xy[:, None] - corners[None], axis=2).min(axis=1)
    # the locator's exclusion assumes straight edges >= 6 px long: these are 32 px
    assert np.all(d < 0.15), d
    assert all(float(r["sigma_col"]) > 0 for r in rows)


def test_measure_refuses_bad_input(targets_tif, tmp_path, capsys):
    pts = tmp_path / "approx.csv"
    pts.write_text("name,col,row\na,20,18\n")
    # output over an input: refused before any work
    assert main(["measure", str(targets_tif), "--targets", str(pts), "--radius", "6", "-o", str(pts)]) == 2
    assert "refusing to write" in capsys.readouterr().err
    assert pts.read_text() == "name,col,row\na,20,18\n"
    assert main(["measure", str(targets_tif), "--targets", str(pts), "-o", str(tmp_path / "o.csv")]) == 2
    assert "--radius" in capsys.readouterr().err
    pts.write_text("name,col,row\na,20,x\n")
    assert main(["measure", str(targets_tif), "--corners", str(pts), "-o", str(tmp_path / "o.csv")]) == 2
    assert "line 2" in capsys.readouterr().err


def test_write_gcps_roundtrip(tmp_path):
    rng = np.random.default_rng(0)
    for pixel in (True, False):
        coords = rng.normal(0, 1000, (5, 2)) * np.pi
        table = GCPTable(
            names=np.array([f"P{i}" for i in range(5)]),
            images=np.array(["a", "a", "b", "b", "b"]),
            ground=rng.normal(5e5, 1e3, (5, 3)),
            pixel=coords if pixel else None,
            image_xy=None if pixel else coords,
            sigma=np.array([0.3, math.nan, 1 / 3, 0.25, 2.0]),
            role=np.array(["control", "check", "control", "control", "check"]),
            crs="EPSG:32633" if pixel else None,
        )
        path = write_gcps(tmp_path / f"g{pixel}.csv", table)
        back = read_gcps(path)
        for field in ("names", "images", "role"):
            assert getattr(back, field).tolist() == getattr(table, field).tolist()
        np.testing.assert_array_equal(back.ground, table.ground)  # repr: exact float64 round trip
        np.testing.assert_array_equal(back.pixel if pixel else back.image_xy, coords)
        np.testing.assert_array_equal(back.sigma, table.sigma)  # NaN == NaN here
        assert back.crs == table.crs
    with pytest.raises(ValueError, match="non-finite"):
        bad = GCPTable(
            names=np.array(["a"]),
            images=np.array([""]),
            ground=np.zeros((1, 3)),
            pixel=np.array([[math.nan, 1.0]]),
            image_xy=None,
            sigma=np.array([1.0]),
            role=np.array(["control"]),
        )
        write_gcps(tmp_path / "bad.csv", bad)
