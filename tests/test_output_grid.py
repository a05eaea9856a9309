"""Output grid control as gdalwarp has it (issue 37, item 5): ``--bounds`` (``-te``), ``--resolution``
(``-tr``), ``--target-aligned`` (``-tap``), ``--size`` (``-ts``), ``--like`` and ``--crs``, in the
Python API (:meth:`photax.Grid.from_bounds`, :meth:`photax.Grid.like`, :class:`photax.GridSpec`)
and on ``photax ortho`` and ``photax rectify``.

Reference: the grid gdalwarp itself writes (``gdalwarp -of VRT``: the georeference and size only, no
pixel is warped), compared exactly (transform coefficients and shape, to the bit); skipped cleanly
where gdalwarp is not installed.  ``rasterio.warp.aligned_target`` (GDAL's ``-tap`` rule as rasterio
ships it) is a second reference that needs no gdalwarp.  Real data: one NGI frame of orthority's
corpus (../shared/data, as tests/test_ortho_real.py), orthorectified on such a grid.
"""

import shutil
import subprocess

import numpy as np
import pytest
import rasterio
import test_mosaic_block as tb
from conftest import ROOT, shared_file
from rasterio.transform import from_origin
from test_mosaic_block import block  # noqa: F401 -- its rendered strip, a fixture here too

import photax
from photax.cli import main
from photax.errors import OutputCRSError
from photax.grid import Grid, GridSpec, ortho_grid

CRS = "EPSG:32633"
GDALWARP = shutil.which("gdalwarp")
needs_gdalwarp = pytest.mark.skipif(GDALWARP is None, reason="gdalwarp (gdal-bin) is not installed")

# Extents with awkward decimals, negative ones, and far edges on both sides of a half pixel.
BOUNDS = [
    (500123.37, 4100456.91, 501987.13, 4101766.02),
    (-1234.5678, -987.6543, 2345.6789, 1876.5432),
    (500000.0, 4100000.0, 500012.49, 4100012.51),
]


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    """A 10 m raster in EPSG:32633 covering every extent above: what gdalwarp warps (same CRS, so
    its suggested resolution is the source's 10 m)."""
    path = tmp_path_factory.mktemp("grid") / "src.tif"
    profile = dict(driver="GTiff", width=64, height=64, count=1, dtype="uint8", crs=CRS)
    for i, (x, y) in enumerate([(495000.0, 4105000.0), (-5000.0, 5000.0)]):
        p = path.with_name(f"src{i}.tif")
        with rasterio.open(p, "w", transform=from_origin(x, y, 160.0, 160.0), **profile) as dst:
            dst.write(np.ones((1, 64, 64), np.uint8))
    return path.parent


def _src(source, bounds):
    return source / ("src1.tif" if bounds[0] < 0 else "src0.tif")


def gdalwarp_grid(src, tmp_path, *options) -> Grid:
    """The grid ``gdalwarp -of VRT src out.vrt *options`` writes."""
    out = tmp_path / "out.vrt"
    subprocess.run([GDALWARP, "-q", "-overwrite", "-of", "VRT", *map(str, options), str(src), str(out)], check=True)
    with rasterio.open(out) as ds:
        return Grid(ds.transform, (ds.height, ds.width), ds.crs)


def same(a: Grid, b: Grid) -> None:
    assert tuple(a.transform)[:6] == tuple(b.transform)[:6]  # exactly, not approximately
    assert a.shape == b.shape


@needs_gdalwarp
@pytest.mark.parametrize("bounds", BOUNDS)
@pytest.mark.parametrize(
    "options, kwargs",
    [
        (("-tr", 5, 5, "-tap"), dict(resolution=5.0, target_aligned=True)),
        (("-tr", 5, 5), dict(resolution=5.0)),
        (("-tr", 3, 7, "-tap"), dict(resolution=(3.0, 7.0), target_aligned=True)),
        (("-tr", 0.3, 0.3, "-tap"), dict(resolution=0.3, target_aligned=True)),
        (("-ts", 123, 77), dict(size=(123, 77))),
        (("-ts", 123, 0), dict(size=(123, 0))),
        (("-ts", 0, 50), dict(size=(0, 50))),
    ],
)
def test_from_bounds_is_gdalwarps_grid(source, tmp_path, bounds, options, kwargs):
    ref = gdalwarp_grid(_src(source, bounds), tmp_path, "-te", *bounds, *options)
    same(Grid.from_bounds(bounds, **kwargs), ref)
    same(GridSpec(bounds=bounds, **kwargs).grid(), ref)


@needs_gdalwarp
@pytest.mark.parametrize("bounds", BOUNDS[:2])
def test_bounds_alone_round_the_suggested_resolution_as_gdalwarp(source, tmp_path, bounds):
    """``-te`` alone: gdalwarp's suggested resolution (the source's 160 m here), rounded to whole
    pixels over the bounds; GridSpec gets the image's sampling distance in its place."""
    ref = gdalwarp_grid(_src(source, bounds), tmp_path, "-te", *bounds)
    same(GridSpec(bounds=bounds).grid(default_resolution=160.0), ref)


@needs_gdalwarp
def test_like_is_the_rasters_grid(source, tmp_path):
    like = source / "src0.tif"
    with rasterio.open(like) as ds:
        b, size = ds.bounds, (ds.width, ds.height)
    ref = gdalwarp_grid(source / "src1.tif", tmp_path, "-te", *b, "-ts", *size, "-t_srs", CRS)
    grid = Grid.like(like)
    same(grid, ref)
    assert rasterio.CRS.from_user_input(grid.crs) == ref.crs
    same(GridSpec(like=like).grid(footprint=(0.0, 0.0, 1.0, 1.0)), ref)  # the footprint plays no part


@pytest.mark.parametrize("bounds", BOUNDS)
@pytest.mark.parametrize("res", [5.0, 0.3, 7.25])
def test_target_aligned_is_rasterios_aligned_target(bounds, res):
    """GDAL's -tap as rasterio ships it (``aligned_target``), without gdalwarp."""
    from rasterio.warp import aligned_target

    xmin, ymin, xmax, ymax = bounds
    t = from_origin(xmin, ymax, res, res)
    w, h = (xmax - xmin) / res, (ymax - ymin) / res
    transform, width, height = aligned_target(t, w, h, res)
    grid = Grid.from_bounds(bounds, res, target_aligned=True)
    assert tuple(grid.transform)[:6] == tuple(transform)[:6]
    # rasterio counts pixels by ceil((snapped xmax - xmin) / res), gdalwarp by rounding: they differ
    # only where that quotient is a whole number plus float noise (0.3 m over 1.9 km).
    x1, y1 = np.ceil(xmax / res) * res, np.ceil(ymax / res) * res
    quotients = ((y1 - transform.f + transform.f - np.floor(ymin / res) * res) / res, (x1 - transform.c) / res)
    for got, theirs, q in zip(grid.shape, (height, width), quotients):
        assert got == theirs or (abs(q - round(q)) < 1e-6 and got == round(q))


def test_crop_stays_on_the_lattice():
    grid = Grid.from_bounds((0.0, 0.0, 100.0, 50.0), 2.0)
    sub = grid.crop((11.0, 7.5, 40.2, 30.0))
    assert tuple(sub.transform)[:6] == (2.0, 0.0, 10.0, 0.0, -2.0, 30.0)
    assert sub.shape == (12, 16)  # rows 30 -> 6 (7.5 rounded out), cols 10 -> 42
    np.testing.assert_array_equal(sub.xy(), grid.xy(slice(10, 22), slice(5, 21)))
    with pytest.raises(ValueError, match="do not overlap"):
        grid.crop((200.0, 0.0, 300.0, 10.0))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(resolution=5.0, size=(10, 10)), "not both"),
        (dict(target_aligned=True), "needs a resolution"),
        (dict(target_aligned=True, size=(10, 10)), "not both|needs a resolution"),
        (dict(resolution=-1.0), "positive"),
        (dict(size=(0, 0)), "not both 0"),
        (dict(size=(10.5, 3)), "whole"),
        (dict(bounds=(1.0, 0.0, 0.0, 1.0), resolution=1.0), "max > min"),
        (dict(like=Grid.from_bounds((0.0, 0.0, 10.0, 10.0), 1.0), resolution=1.0), "leave out bounds, resolution"),
    ],
)
def test_contradictions_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        GridSpec(**{"bounds": (0.0, 0.0, 10.0, 10.0), **kwargs})


def test_from_bounds_refuses_contradictions():
    with pytest.raises(ValueError, match="-tr and -ts"):
        Grid.from_bounds((0, 0, 10, 10), 1.0, size=(5, 5))
    with pytest.raises(ValueError, match="-tap needs -tr"):
        Grid.from_bounds((0, 0, 10, 10), size=(5, 5), target_aligned=True)
    with pytest.raises(ValueError, match="no whole pixel"):
        Grid.from_bounds((0, 0, 1, 1), 5.0)


# --- the commands ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ngi(tmp_path_factory):
    """One NGI frame, its orientation and the DEM tagged with the orientation's CRS (as
    tests/test_ortho_real.py), and the frame's footprint grid at 5 m."""
    from photax.io import read_dem, read_orthority_exterior, read_orthority_interior

    image = shared_file("3324c_2015_1004_05_0182_RGB.tif")
    csv, interior = shared_file("ngi_xyz_opk.csv"), shared_file("ngi_int_param.yaml")
    prj = shared_file("ngi_xyz_opk.prj").read_text()
    tmp = tmp_path_factory.mktemp("ngi_grid")
    with rasterio.open(shared_file("dem.tif")) as src:
        profile, heights = src.profile, src.read()
    profile.update(crs=rasterio.CRS.from_string(prj))
    dem = tmp / "dem.tif"
    with rasterio.open(dem, "w", **profile) as dst:
        dst.write(heights)
    exterior = read_orthority_exterior(csv)[image.stem]
    camera = next(iter(read_orthority_interior(interior).values()))
    footprint = ortho_grid(exterior, camera, read_dem(dem), 5.0)
    return dict(image=image, csv=csv, interior=interior, dem=dem, tmp=tmp, prj=prj, footprint=footprint,
                exterior=exterior, camera=camera)  # fmt: skip


def _ortho(ngi, out, *options):
    argv = ["ortho", str(ngi["image"]), "--dem", str(ngi["dem"]), "--interior", str(ngi["interior"])]
    return main([*argv, "--exterior", str(ngi["csv"]), "-o", str(out), "--no-progress", *map(str, options)])


def _inner_bounds(footprint: Grid):
    """Awkward bounds inside the frame's footprint (a third of it, off the 5 m lattice)."""
    x0, y0, x1, y1 = footprint.bounds
    dx, dy = (x1 - x0) / 3, (y1 - y0) / 3
    return (x0 + dx + 1.37, y0 + dy + 2.91, x1 - dx - 0.83, y1 - dy + 1.49)


def _written(path) -> Grid:
    with rasterio.open(path) as ds:
        return Grid(ds.transform, (ds.height, ds.width), ds.crs)


@needs_gdalwarp
def test_cli_ortho_bounds_target_aligned_is_gdalwarps_grid(ngi, tmp_path):
    """``photax ortho --bounds B --resolution 5 --target-aligned`` writes the grid of
    ``gdalwarp -te B -tr 5 5 -tap``, and the frame's pixels fill it (it lies inside the footprint)."""
    bounds = _inner_bounds(ngi["footprint"])
    out = tmp_path / "o.tif"
    assert _ortho(ngi, out, "--bounds", *bounds, "--resolution", 5, "--target-aligned") == 0
    ref = gdalwarp_grid(ngi["dem"], tmp_path, "-te", *bounds, "-tr", 5, 5, "-tap")
    got = _written(out)
    same(got, ref)
    assert got.crs == rasterio.CRS.from_string(ngi["prj"])
    assert tuple(got.transform)[2] % 5 == 0 and tuple(got.transform)[5] % 5 == 0
    with rasterio.open(out) as ds:
        assert ds.read_masks(1).all()  # all inside the frame: every pixel has data
    # The Python API gives the same grid.
    api = ortho_grid(
        ngi["exterior"], ngi["camera"], photax.io.read_dem(ngi["dem"]), 5.0, bounds=bounds, target_aligned=True
    )
    same(api, ref)


@needs_gdalwarp
def test_cli_ortho_size_and_bounds_are_gdalwarps(ngi, tmp_path):
    bounds = _inner_bounds(ngi["footprint"])
    out = tmp_path / "s.tif"
    assert _ortho(ngi, out, "--bounds", *bounds, "--size", 97, 61) == 0
    same(_written(out), gdalwarp_grid(ngi["dem"], tmp_path, "-te", *bounds, "-ts", 97, 61))
    out2 = tmp_path / "r.tif"  # -tr without -tap: the origin at (XMIN, YMAX), whole pixels
    assert _ortho(ngi, out2, "--bounds", *bounds, "--resolution", 5) == 0
    same(_written(out2), gdalwarp_grid(ngi["dem"], tmp_path, "-te", *bounds, "-tr", 5, 5))


def test_cli_ortho_like_takes_the_rasters_grid(ngi, tmp_path):
    like = tmp_path / "like.tif"
    grid = Grid.from_bounds(_inner_bounds(ngi["footprint"]), (4.0, 6.0))
    profile = dict(driver="GTiff", width=grid.width, height=grid.height, count=1, dtype="uint8")
    with rasterio.open(like, "w", transform=grid.transform, crs=rasterio.CRS.from_string(ngi["prj"]), **profile):
        pass
    out = tmp_path / "l.tif"
    assert _ortho(ngi, out, "--like", like) == 0
    same(_written(out), grid)


@pytest.mark.parametrize(
    "options, message",
    [
        (("--size", 10, 10, "--resolution", 5), "--size and --resolution exclude each other"),
        (("--target-aligned",), "--target-aligned needs --resolution"),
        (
            ("--like", "LIKE", "--bounds", 0, 0, 1, 1),
            "--like takes RASTER's CRS, transform and shape: leave out --bounds",
        ),
        (("--bounds", 10, 0, 0, 10), "XMAX > XMIN"),
        (("--bounds", 0, 0, 10, 10, "--resolution", 5), "does not overlap the image's footprint"),
        (("--crs", "EPSG:4326"), "is not the frame orientation's"),
    ],
)
def test_cli_ortho_refuses_contradictions(ngi, tmp_path, capsys, options, message):
    options = [str(ngi["dem"]) if o == "LIKE" else o for o in options]
    assert _ortho(ngi, tmp_path / "x.tif", *options) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "x.tif").exists()


def test_frame_ortho_into_another_crs_is_a_typed_error(ngi):
    dem = photax.io.read_dem(ngi["dem"])
    with pytest.raises(OutputCRSError, match="reproject the ortho afterwards"):
        ortho_grid(ngi["exterior"], ngi["camera"], dem, spec=GridSpec(resolution=5.0, crs="EPSG:32735"))
    # The orientation's own CRS, named: accepted, the same grid.
    own = ortho_grid(ngi["exterior"], ngi["camera"], dem, spec=GridSpec(resolution=5.0, crs=ngi["prj"]))
    same(own, ngi["footprint"])


@needs_gdalwarp
def test_cli_rectify_bounds_target_aligned_is_gdalwarps_grid(tmp_path):
    data = ROOT / "data"
    bounds = (511950.31, 4103850.77, 512101.09, 4103999.43)
    out = tmp_path / "r.tif"
    argv = ["rectify", str(data / "sample_image.tif"), "--gcps", str(data / "sample_gcps.csv"), "-o", str(out)]
    assert main([*argv, "--bounds", *map(str, bounds), "--resolution", "2", "--target-aligned", "--no-progress"]) == 0
    src = tmp_path / "ref.tif"
    with rasterio.open(src, "w", driver="GTiff", width=8, height=8, count=1, dtype="uint8", crs=CRS,
                       transform=from_origin(511000.0, 4105000.0, 500.0, 500.0)):  # fmt: skip
        pass
    same(_written(out), gdalwarp_grid(src, tmp_path, "-te", *bounds, "-tr", 2, 2, "-tap"))
    assert _written(out).crs == rasterio.CRS.from_user_input(CRS)


# --- photax mosaic -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def orthos(tmp_path_factory):
    """Two overlapping float32 orthos on one 3 m lattice whose origin is a multiple of 3 (so the
    target-aligned grid of 3 m is their lattice), and their mosaic on the union grid."""
    tmp = tmp_path_factory.mktemp("mosaic_grid")
    rng = np.random.default_rng(37)
    x0, y1, res = 500_001.0, 4_000_362.0, 3.0
    paths = []
    for name, c0, gain in (("a", 0, 1.0), ("b", 70, 1.1)):
        v = (rng.random((60, 130)) * gain).astype(np.float32)
        path = tmp / f"{name}.tif"
        with rasterio.open(path, "w", driver="GTiff", width=130, height=60, count=1, dtype="float32", crs=CRS,
                           transform=from_origin(x0 + c0 * res, y1, res, res), nodata=np.nan) as dst:  # fmt: skip
            dst.write(v[None])
        paths.append(path)
    union = tmp / "union.tif"
    assert main(["mosaic", *map(str, paths), "-o", str(union), "--no-progress"]) == 0
    return tmp, paths, union


def test_cli_mosaic_on_the_target_aligned_grid_copies_its_lattice(orthos, tmp_path):
    tmp, paths, union = orthos
    bounds = (500_100.2, 4_000_250.7, 500_500.9, 4_000_340.1)
    out = tmp_path / "m.tif"
    argv = ["mosaic", *map(str, paths), "-o", str(out), "--no-progress"]
    assert main([*argv, "--bounds", *map(str, bounds), "--resolution", "3", "--target-aligned"]) == 0
    got = _written(out)
    if GDALWARP is not None:
        same(got, gdalwarp_grid(union, tmp_path, "-te", *bounds, "-tr", 3, 3, "-tap"))
    same(got, Grid.from_bounds(bounds, 3.0, target_aligned=True))
    with rasterio.open(union) as u, rasterio.open(out) as m:
        window = rasterio.windows.from_bounds(*got.bounds, transform=u.transform).round_offsets().round_lengths()
        np.testing.assert_array_equal(m.read(1), u.read(1, window=window))  # the same pixels, not resampled


@needs_gdalwarp
def test_cli_mosaic_off_the_lattice_is_resampled_as_gdalwarp(orthos, tmp_path):
    """--bounds without --target-aligned (origin at XMIN, YMAX: off the orthos' lattice): the mosaic
    is resampled by GDAL's warper, pixel for pixel what gdalwarp makes of the union mosaic."""
    tmp, paths, union = orthos
    bounds = (500_100.2, 4_000_250.7, 500_500.9, 4_000_340.1)
    out = tmp_path / "m.tif"
    argv = ["mosaic", *map(str, paths), "-o", str(out), "--no-progress", "--bounds", *map(str, bounds)]
    assert main([*argv, "--resolution", "2.5"]) == 0
    ref = tmp_path / "ref.tif"
    subprocess.run([GDALWARP, "-q", "-te", *map(str, bounds), "-tr", "2.5", "2.5", "-r", "bilinear", str(union),
                    str(ref)], check=True)  # fmt: skip
    same(_written(out), _written(ref))
    with rasterio.open(out) as m, rasterio.open(ref) as r:
        a, b = m.read(1), r.read(1)
    both = np.isfinite(a) & np.isfinite(b)
    assert both.mean() > 0.9
    np.testing.assert_allclose(a[both], b[both], rtol=0, atol=1e-5)


def test_cli_mosaic_like_and_contradictions(orthos, tmp_path, capsys):
    tmp, paths, union = orthos
    like = tmp_path / "like.tif"
    grid = Grid.from_bounds((500_030.0, 4_000_200.0, 500_300.0, 4_000_350.0), 3.0)
    with rasterio.open(like, "w", driver="GTiff", width=grid.width, height=grid.height, count=1, dtype="uint8",
                       crs=CRS, transform=grid.transform):  # fmt: skip
        pass
    out = tmp_path / "l.tif"
    argv = ["mosaic", *map(str, paths), "-o", str(out), "--no-progress"]
    assert main([*argv, "--like", str(like)]) == 0
    same(_written(out), grid)
    assert main([*argv, "--like", str(like), "--resolution", "3"]) == 2
    assert "--like takes RASTER's CRS" in capsys.readouterr().err
    assert main([*argv, "--size", "10", "10", "--resolution", "3"]) == 2
    assert "--size and --resolution exclude each other" in capsys.readouterr().err


def test_cli_mosaic_block_on_a_given_grid(block, tmp_path):  # noqa: F811 -- the imported fixture
    """``photax mosaic --block ... --bounds B --resolution 2 --target-aligned``: the orthos are made
    on the mosaic's own lattice (no second resampling) and the mosaic is the texture the block saw
    (tests/test_mosaic_block.py's rendered strip and truth)."""
    bounds = (tb.X0 - 150.3, tb.Y0 - 80.7, tb.X0 + 170.9, tb.Y0 + 60.2)
    out = tmp_path / "m.tif"
    argv = ["mosaic", "--block", str(block / "bundle.json"), "--images", str(block / "images"), "--camera",
            str(block / "camera.yaml"), "--dem", str(block / "dem.tif"), "-o", str(out), "--chunks", "64",
            "--no-progress", "--bounds", *map(str, bounds), "--resolution", "2", "--target-aligned"]  # fmt: skip
    assert main(argv) == 0
    got = _written(out)
    same(got, Grid.from_bounds(bounds, 2.0, target_aligned=True))
    if GDALWARP is not None:
        same(got, gdalwarp_grid(block / "dem.tif", tmp_path, "-te", *bounds, "-tr", 2, 2, "-tap"))
    with rasterio.open(out) as ds:
        v = ds.read(1, masked=True).filled(np.nan).astype(float)
    rms, ok = tb._rms_vs_truth(v, got.transform)
    assert ok.mean() > 0.9 and rms < 0.01, (ok.mean(), rms)


def test_cli_rectify_like_and_size(tmp_path):
    data = ROOT / "data"
    argv = ["rectify", str(data / "sample_image.tif"), "--gcps", str(data / "sample_gcps.csv"), "--no-progress"]
    like = tmp_path / "like.tif"
    grid = Grid.from_bounds((511950.0, 4103850.0, 512100.0, 4104000.0), (3.0, 2.0), CRS)
    with rasterio.open(like, "w", driver="GTiff", width=grid.width, height=grid.height, count=1, dtype="uint8",
                       crs=CRS, transform=grid.transform):  # fmt: skip
        pass
    assert main([*argv, "-o", str(tmp_path / "l.tif"), "--like", str(like)]) == 0
    same(_written(tmp_path / "l.tif"), grid)
    bounds = (511950.31, 4103850.77, 512101.09, 4103999.43)
    assert main([*argv, "-o", str(tmp_path / "s.tif"), "--bounds", *map(str, bounds), "--size", "64", "0"]) == 0
    same(_written(tmp_path / "s.tif"), Grid.from_bounds(bounds, size=(64, 0)))
