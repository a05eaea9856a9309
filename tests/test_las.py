"""LAS 1.4 / LAZ point clouds (issue 36's leftover): :meth:`PointCloud.write_las` read back by laspy
itself and by the header's bytes as the specification lays them out (ASPRS LAS 1.4 R15, table 3),
against photax's own PLY of the same cloud (an independent path), at UTM coordinates (x ~ 5e5,
y ~ 4e6) where the 1 mm integers must hold the precision; :func:`photax.stereo.read_las` on a file of
another writer; and the refusals (an empty cloud, laspy or lazrs missing: the message names the
extra; ``photax dsm --points`` with a bad suffix or without laspy).  ``photax dsm --points x.laz``
on a rendered RPC pair is checked in ``test_stereo_synthetic`` (its pair is rendered once there).
"""

from __future__ import annotations

import doctest
import struct
import sys

import numpy as np
import pytest

laspy = pytest.importorskip("laspy")
pyproj = pytest.importorskip("pyproj")

from photax.cli import main  # noqa: E402
from photax.errors import CRSMismatchError, MalformedFileError, UnreadableFileError  # noqa: E402
from photax.stereo import PointCloud, read_las, read_ply  # noqa: E402

CRS = "EPSG:32633"
X0, Y0 = 500_000.0, 4_000_000.0
HAS_LAZ = bool(laspy.LazBackend.detect_available())
SUFFIXES = [".las", pytest.param(".laz", marks=pytest.mark.skipif(not HAS_LAZ, reason="no LAZ backend (lazrs)"))]


def utm_cloud(n=5000, seed=0, colour=True, crs=CRS):
    """Points over 1 km at UTM coordinates, sub-millimetre digits everywhere, random colour and extras."""
    rng = np.random.default_rng(seed)
    xyz = np.column_stack([X0 + rng.uniform(0, 1000, n), Y0 + rng.uniform(0, 1000, n), rng.uniform(80, 420, n)])
    rgb = rng.integers(0, 256, (n, 3), dtype=np.uint8) if colour else None
    return PointCloud(xyz, rng.gamma(2.0, 0.2, n), rng.uniform(0.05, 2.0, n), rgb, crs)


def wkt_vlr(las):
    return next(v for v in las.header.vlrs if v.user_id == "LASF_Projection" and v.record_id == 2112)


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_round_trip_by_laspy(tmp_path, suffix):
    cloud = utm_cloud()
    path = cloud.write_las(tmp_path / f"points{suffix}")
    las = laspy.read(path)
    assert (las.header.version.major, las.header.version.minor) == (1, 4)
    assert las.header.point_format.id == 7 and las.header.global_encoding.wkt
    assert las.header.are_points_compressed == (suffix == ".laz")
    assert len(las.points) == len(cloud)
    # 1 mm integers: each coordinate within half a step; quantisation error uniform, mean step / 4
    np.testing.assert_array_equal(las.header.scales, [1e-3, 1e-3, 1e-3])
    decoded = np.column_stack([las.x, las.y, las.z])
    err = np.abs(decoded - cloud.xyz)
    assert err.max() <= 0.5e-3 + 1e-9
    assert 0.2e-3 < err.mean() < 0.3e-3
    # the offsets: the minimum rounded down to whole metres, a multiple of the scale
    np.testing.assert_array_equal(las.header.offsets, np.floor(cloud.xyz.min(axis=0)))
    # the CRS: the WKT VLR is the cloud's CRS
    assert pyproj.CRS.from_wkt(wkt_vlr(las).string).equals(pyproj.CRS.from_user_input(cloud.crs))
    assert las.header.parse_crs().equals(pyproj.CRS.from_user_input(cloud.crs))
    # RGB at 16 bits, full scale
    for k, band in enumerate(("red", "green", "blue")):
        np.testing.assert_array_equal(las[band], cloud.colour[:, k].astype(np.uint16) * 257)
    # the photax extras: float32, named and described
    assert set(las.point_format.extra_dimension_names) == {"residual", "sigma_z"}
    np.testing.assert_array_equal(las.residual, cloud.residual.astype(np.float32))
    np.testing.assert_array_equal(las.sigma_z, cloud.sigma_z.astype(np.float32))
    extra_bytes = next(v for v in las.header.vlrs if v.user_id == "LASF_Spec" and v.record_id == 4)
    desc = {s.name.rstrip(b"\0"): s.description.rstrip(b"\0") for s in extra_bytes.extra_bytes_structs}
    assert b"(px)" in desc[b"residual"] and b"(m)" in desc[b"sigma_z"]


def test_header_bytes_by_the_specification(tmp_path):
    """The public header block read with struct at the offsets of LAS 1.4 R15, table 3 (not laspy)."""
    cloud = utm_cloud(n=777)
    raw = cloud.write_las(tmp_path / "p.las").read_bytes()
    assert raw[:4] == b"LASF"
    (encoding,) = struct.unpack_from("<H", raw, 6)
    assert encoding & 0b10000  # bit 4: the CRS is WKT
    assert struct.unpack_from("<BB", raw, 24) == (1, 4)
    point_format, record_length = struct.unpack_from("<BH", raw, 104)
    assert point_format == 7 and record_length == 36 + 2 * 4  # format 7 plus two float32 extras
    scale = struct.unpack_from("<3d", raw, 131)
    offset = struct.unpack_from("<3d", raw, 155)
    max_x, min_x, max_y, min_y, max_z, min_z = struct.unpack_from("<6d", raw, 179)
    (count,) = struct.unpack_from("<Q", raw, 247)
    assert count == len(cloud) and scale == (1e-3, 1e-3, 1e-3)
    lo, hi = cloud.xyz.min(axis=0), cloud.xyz.max(axis=0)
    np.testing.assert_allclose([min_x, min_y, min_z], lo, atol=0.5e-3 + 1e-9, rtol=0)
    np.testing.assert_allclose([max_x, max_y, max_z], hi, atol=0.5e-3 + 1e-9, rtol=0)
    # the first point's integers, at the offset to point data (bytes 96..99)
    (start,) = struct.unpack_from("<I", raw, 96)
    ints = np.array(struct.unpack_from("<3i", raw, start))
    np.testing.assert_allclose(ints * np.array(scale) + np.array(offset), cloud.xyz[0], atol=0.5e-3 + 1e-9, rtol=0)


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_same_points_as_the_ply(tmp_path, suffix):
    """LAS and PLY of one cloud, each read by its own reader (laspy; photax's PLY reader)."""
    cloud = utm_cloud(seed=3)
    ply = read_ply(cloud.write_ply(tmp_path / "p.ply"))
    las = laspy.read(cloud.write_las(tmp_path / f"p{suffix}"))
    for axis in "xyz":
        np.testing.assert_allclose(np.asarray(las[axis]), ply[axis], atol=0.5e-3 + 1e-9, rtol=0)
    for band in ("red", "green", "blue"):
        np.testing.assert_array_equal(np.asarray(las[band]) >> 8, ply[band])
    for extra in ("residual", "sigma_z"):
        np.testing.assert_array_equal(las[extra], ply[extra])  # both float32


@pytest.mark.skipif(not HAS_LAZ, reason="no LAZ backend (lazrs)")
def test_laz_holds_the_las_points(tmp_path, capsys):
    cloud = utm_cloud(n=20000, seed=5)
    a, b = cloud.write_las(tmp_path / "p.las"), cloud.write_las(tmp_path / "p.laz")
    la, lb = laspy.read(a), laspy.read(b)
    for dim in ("X", "Y", "Z", "red", "green", "blue", "residual", "sigma_z"):
        np.testing.assert_array_equal(la[dim], lb[dim])
    with capsys.disabled():
        print(f"\nLAZ {b.stat().st_size} B / LAS {a.stat().st_size} B of {len(cloud)} points")
    assert b.stat().st_size < a.stat().st_size


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_read_las_gives_the_cloud_back(tmp_path, suffix):
    cloud = utm_cloud(n=500, seed=2)
    back = read_las(cloud.write_las(tmp_path / f"p{suffix}"))
    assert isinstance(back, PointCloud) and back.crs == CRS
    np.testing.assert_allclose(back.xyz, cloud.xyz, atol=0.5e-3 + 1e-9, rtol=0)
    np.testing.assert_array_equal(back.colour, cloud.colour)
    np.testing.assert_array_equal(back.residual, cloud.residual.astype(np.float32))
    plain = read_las(utm_cloud(n=10, colour=False, crs=None).write_las(tmp_path / f"q{suffix}"))
    assert plain.colour is None and plain.crs is None
    assert laspy.read(tmp_path / f"q{suffix}").header.point_format.id == 6


def test_geographic_cloud_at_1e8_degree(tmp_path):
    """A 3-D geographic CRS (WKT1 cannot say it: WKT2) and a scale of 1e-8 degree (about 1.1 mm)."""
    rng = np.random.default_rng(4)
    n = 300
    xyz = np.column_stack([10 + rng.uniform(0, 0.01, n), 45 + rng.uniform(0, 0.01, n), rng.uniform(0, 50, n)])
    cloud = PointCloud(xyz, np.zeros(n), np.ones(n), None, "EPSG:4979")
    las = laspy.read(cloud.write_las(tmp_path / "g.las"))
    np.testing.assert_array_equal(las.header.scales, [1e-8, 1e-8, 1e-3])
    err = np.abs(np.column_stack([las.x, las.y]) - xyz[:, :2])
    assert err.max() <= 0.5e-8 + 1e-12
    assert pyproj.CRS.from_wkt(wkt_vlr(las).string).equals(pyproj.CRS("EPSG:4979"))
    assert read_las(tmp_path / "g.las").crs == "EPSG:4979"


def test_read_las_of_another_writer(tmp_path):
    """LAS 1.2, point format 3, the CRS as GeoTIFF keys (laspy's add_crs), no photax extras."""
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.01, 0.01, 0.01], [X0, Y0, 0]
    header.add_crs(pyproj.CRS(CRS))
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.array([[X0 + 1.25, X0 + 2.5], [Y0 + 3.75, Y0 + 5.0], [100.5, 101.0]])
    las.red, las.green, las.blue = np.array([[65535, 256], [0, 512], [32768, 1024]], dtype=np.uint16)
    las.write(tmp_path / "other.las")
    cloud = read_las(tmp_path / "other.las")
    np.testing.assert_allclose(cloud.xyz, [[X0 + 1.25, Y0 + 3.75, 100.5], [X0 + 2.5, Y0 + 5.0, 101.0]])
    assert cloud.colour.tolist() == [[255, 0, 128], [1, 2, 4]]
    assert np.isnan(cloud.residual).all() and np.isnan(cloud.sigma_z).all()
    assert pyproj.CRS(cloud.crs).equals(pyproj.CRS(CRS))


def test_refusals(tmp_path, monkeypatch):
    out = tmp_path / "p.las"
    with pytest.raises(ValueError, match="no points"):
        PointCloud(np.zeros((0, 3)), [], []).write_las(out)
    with pytest.raises(ValueError, match="not finite"):
        PointCloud([[X0, Y0, np.nan], [X0, Y0, 1.0]], [0, 0], [0, 0]).write_las(out)
    with pytest.raises(ValueError, match="32-bit"):  # 3000 km at 1 mm: more than 2**31 steps
        PointCloud([[0.0, 0.0, 0.0], [3e6, 0.0, 0.0]], [0, 0], [0, 0]).write_las(out)
    with pytest.raises(CRSMismatchError, match="not one pyproj reads"):
        PointCloud([[X0, Y0, 1.0]], [0], [0], crs="EPSG:no such code").write_las(out)
    assert not out.exists()
    with pytest.raises(ValueError, match="input"):
        utm_cloud(10).write_las(out, inputs=[out])
    # a failing write leaves the previous file as it was, and no temporary
    first = utm_cloud(10).write_las(out).read_bytes()

    def broken(self, f, **kwargs):
        f.write(b"LASF half a file")
        raise OSError("disk gone")

    monkeypatch.setattr(laspy.LasData, "write", broken)
    with pytest.raises(OSError):
        utm_cloud(20, seed=9).write_las(out)
    assert out.read_bytes() == first and [p.name for p in tmp_path.iterdir()] == ["p.las"]
    not_las = tmp_path / "x.las"
    not_las.write_bytes(b"ply\nformat binary_little_endian 1.0\n")
    with pytest.raises(MalformedFileError, match="not a LAS"):
        read_las(not_las)
    with pytest.raises(UnreadableFileError, match="no such file"):
        read_las(tmp_path / "none.las")


def test_missing_laspy_or_lazrs_names_the_extra(tmp_path, monkeypatch):
    cloud = utm_cloud(10)
    monkeypatch.setattr(laspy.LazBackend, "detect_available", staticmethod(lambda: ()))
    with pytest.raises(ModuleNotFoundError, match=r'lazrs.*pip install "photax\[las\]"') as exc:
        cloud.write_las(tmp_path / "p.laz")
    assert exc.value.name == "lazrs"
    monkeypatch.setitem(sys.modules, "laspy", None)  # import laspy: ModuleNotFoundError
    for call in (lambda: cloud.write_las(tmp_path / "p.las"), lambda: read_las(tmp_path / "p.las")):
        with pytest.raises(ModuleNotFoundError, match=r'laspy.*pip install "photax\[las\]"') as exc:
            call()
        assert exc.value.name == "laspy"
    assert not list(tmp_path.iterdir())


def test_cli_refuses_before_matching(tmp_path, monkeypatch, capsys):
    """Bad --points (suffix, laspy missing) fail at once, before any image is read."""
    a, b = tmp_path / "a.tif", tmp_path / "b.tif"
    a.write_bytes(b"not read"), b.write_bytes(b"not read")
    args = ["dsm", str(a), str(b), "--camera", "rpc", "-o", str(tmp_path / "dsm.tif"), "--no-progress"]
    assert main([*args, "--points", str(tmp_path / "p.xyz")]) == 2
    assert ".ply, .las or .laz" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "laspy", None)
    assert main([*args, "--points", str(tmp_path / "p.las")]) == 2
    assert 'needs laspy, in the las extra: pip install "photax[las]"' in capsys.readouterr().err


def test_examples_run():
    """The doctested Examples of write_las and read_las (photax.stereo is not in test_doctests' list)."""
    for obj, name in ((PointCloud.write_las, "write_las"), (read_las, "read_las")):
        tests = doctest.DocTestFinder(recurse=False).find(obj, name, globs={})
        assert tests and tests[0].examples, f"{name} has no Examples"
        runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
        report: list[str] = []
        for t in tests:
            runner.run(t, out=report.append)
        assert runner.failures == 0, "".join(report)
