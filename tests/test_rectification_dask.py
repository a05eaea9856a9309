"""Orthorectification on Dask (photax.rectification._dask): lazy chunks equal the
whole-image photax.orthorectify bit for bit, from an array and from a file,
on the threaded scheduler and on a 2-process dask.distributed cluster;
georeference read back with rasterio; atomic writing.

Reference: photax.orthorectify on the whole image (itself tested against
scipy, OpenCV and orthority in test_rectify.py / test_ortho_real.py).
"""

import numpy as np
import pytest
import rasterio
from conftest import needs, scaled

import photax
from photax.io.raster import write_geotiff
from photax.rectification import Grid, ortho_grid
from photax.rectification._tiling import tile_windows

pytestmark = needs("dask", "rioxarray")

from photax.io.lazy import to_raster  # noqa: E402
from photax.rectification._dask import orthorectify_dask  # noqa: E402


@pytest.fixture(scope="module")
def scene():
    s = photax.relief_scene(300.0, image_size=(120, 96), focal_px=120.0, n_gcp=3, n_check=0)
    grid = ortho_grid(s.exterior, s.camera, s.dem)
    # Widen the grid beyond the DEM on the right: chunks there see no DEM height.
    x0, y0, x1, y1 = grid.bounds
    grid = Grid.from_bounds((x0, y0, x1 + 0.4 * (x1 - x0), y1), grid.transform.a, crs="EPSG:32633")
    return s, grid


def _ortho(s, grid, image, **kw):
    return photax.orthorectify(image, s.exterior, s.camera, s.dem, grid, **kw)[0]


# Several chunk sizes (each a different kernel shape) over the kernels, with
# the exact mapping.  (The approximate mapping's kernels cost ~10 s of
# compilation more; its chunks are the tiles of orthorectify(tile=chunks),
# equal bit for bit when checked by hand, but not tested here.)
@pytest.mark.parametrize(
    "resampling, chunks, approx",
    [
        ("nearest", 37, None),
        ("bilinear", 48, None),
        ("cubic", 50, None),
        ("lanczos", 1000, None),
        ("bspline", 37, None),
    ],
)
def test_tiled_equals_whole_image_exactly(scene, resampling, chunks, approx):
    s, grid = scene
    image = s.image.astype(np.float32)
    ref = _ortho(s, grid, image, resampling=resampling, approx=approx, tile=chunks)
    arr = orthorectify_dask(
        image, s.exterior, s.camera, s.dem, grid, chunks=chunks, resampling=resampling, approx=approx
    )
    assert arr.dims == ("y", "x") and arr.dtype == np.float32 and arr.shape == grid.shape
    tiles = list(tile_windows(grid.shape, chunks))
    assert arr.chunks[0] == tuple(t[2] for t in tiles if t[1] == 0)
    assert arr.chunks[1] == tuple(t[3] for t in tiles if t[0] == 0)
    out = arr.compute().values
    np.testing.assert_array_equal(out, ref)
    assert np.isnan(out[:, -5:]).all() and np.isfinite(out).mean() > 0.4  # off the DEM: nodata


def test_file_input_georeference_and_atomic_write(scene, tmp_path, monkeypatch):
    s, grid = scene
    image = np.stack([(s.image * 250).astype(np.uint8) + b for b in (1, 3)])
    src = tmp_path / "frame.tif"
    write_geotiff(src, image, None, None, nodata=0)
    arr = orthorectify_dask(src, s.exterior, s.camera, s.dem, grid, chunks=40, resampling="cubic", approx=None)
    assert arr.dims == ("band", "y", "x") and arr.dtype == np.uint8
    assert arr.rio.crs == rasterio.CRS.from_epsg(32633) and arr.rio.transform() == grid.transform
    assert arr.rio.nodata == 0
    out = tmp_path / "ortho.tif"
    assert to_raster(arr, out) == out
    ref = _ortho(s, grid, image, resampling="cubic", approx=None, nodata=0)
    with rasterio.open(out) as ds:
        assert ds.transform.almost_equals(grid.transform, 1e-9) and ds.nodata == 0
        assert ds.crs == rasterio.CRS.from_epsg(32633)
        np.testing.assert_array_equal(ds.read(), ref)
    # A chunk that fails mid-run: the previous file stays, no partial file is left.
    import photax.rectification._dask as tiled

    real, calls = tiled._ortho_chunk, []

    def failing(*args):
        calls.append(1)
        if len(calls) == 3:
            raise RuntimeError("worker lost (injected)")
        return real(*args)

    monkeypatch.setattr(tiled, "_ortho_chunk", failing)
    broken = orthorectify_dask(src, s.exterior, s.camera, s.dem, grid, chunks=40, resampling="cubic", approx=None)
    out.write_bytes(b"previous result")
    with pytest.raises(RuntimeError, match="injected"):
        to_raster(broken, out, cog=True)
    assert out.read_bytes() == b"previous result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame.tif", "ortho.tif"]


def test_bad_input(scene):
    s, grid = scene
    with pytest.raises(ValueError, match="chunks"):
        orthorectify_dask(s.image, s.exterior, s.camera, s.dem, grid, chunks=0)
    with pytest.raises(ValueError, match="image_size"):
        orthorectify_dask(s.image[:-1], s.exterior, s.camera, s.dem, grid)
    with pytest.raises(ValueError, match="resampling"):
        orthorectify_dask(s.image, s.exterior, s.camera, s.dem, grid, resampling="cubicspline")


@pytest.fixture(scope="module")
def cluster():
    """A dask.distributed cluster of 2 worker processes (one thread each), shared by the tests below."""
    distributed = pytest.importorskip("distributed")
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=50
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        yield cluster, client


def test_local_cluster_two_processes(scene, cluster, tmp_path):
    _, client = cluster
    s, grid = scene
    image = s.image.astype(np.float32)
    ref = _ortho(s, grid, image, approx=None)
    arr = orthorectify_dask(image, s.exterior, s.camera, s.dem, grid, chunks=48, approx=None)  # as above
    futures = client.compute(arr.data, optimize_graph=False)
    out = futures.result()
    ran = client.run(lambda: __import__("os").getpid())
    assert len(set(ran.values())) == 2
    to_raster(arr, tmp_path / "o.tif")
    np.testing.assert_array_equal(out, ref)
    with rasterio.open(tmp_path / "o.tif") as ds:
        np.testing.assert_array_equal(ds.read(1), ref)


def test_dead_worker_is_retried_and_a_failed_write_leaves_nothing(scene, cluster, tmp_path):
    """Issue 12, bad input: a worker process that dies mid-run (``os._exit`` from a task, on the
    first attempt only: a marker file says it happened) is replaced by its nanny and its task rerun
    by dask.distributed: the written ortho is complete and equal to the in-memory one.  A write
    that fails for good on the cluster leaves the previous file as it was and no partial file."""
    import os

    _, client = cluster
    s, grid = scene
    image = s.image.astype(np.float32)
    ref = _ortho(s, grid, image, approx=None)
    arr = orthorectify_dask(image, s.exterior, s.camera, s.dem, grid, chunks=48, approx=None)
    marker = str(tmp_path / "died")

    def die_once(block, marker):  # defined here: cloudpickle sends it by value to the workers
        if not block.size:  # (dask's meta call, in this process)
            return block
        try:
            os.close(os.open(marker, os.O_CREAT | os.O_EXCL))
        except FileExistsError:
            return block
        os._exit(1)  # a worker lost mid-task (out of memory, killed, node down)

    pids = set(client.run(os.getpid).values())
    out = tmp_path / "o.tif"
    to_raster(arr.copy(data=arr.data.map_blocks(die_once, marker, meta=arr.data._meta)), out)
    assert os.path.exists(marker)
    client.wait_for_workers(2, timeout=scaled(30))
    assert len(set(client.run(os.getpid).values()) - pids) == 1  # one worker process was replaced
    with rasterio.open(out) as ds:
        np.testing.assert_array_equal(ds.read(1), ref)

    # A write that fails for good (a task raising on a worker; a worker dying more than the scheduler's
    # allowed-failures times ends the same way, with KilledWorker: not repeated here, each death
    # respawns a worker process): the previous file stays and no partial file is left.
    def fail(block):
        if block.size:
            raise RuntimeError("chunk failed (injected)")
        return block

    out.write_bytes(b"previous result")
    with pytest.raises(RuntimeError, match="injected"):
        to_raster(arr.copy(data=arr.data.map_blocks(fail, meta=arr.data._meta)), out, cog=True)
    assert out.read_bytes() == b"previous result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["died", "o.tif"]


def test_window_check_by_strips_equals_whole_chunk():
    """The chunk's window check reads the sample bounds strip by strip (no float64 copy of the
    chunk's positions): the same bounds as the whole-chunk formula it replaced, with NaN
    positions, samples outside the image, a chunk cropped from its padded shape and several strips."""
    from photax.rectification._dask import _STRIP, _sample_bounds

    rng = np.random.default_rng(3)
    h, w, size = 2 * _STRIP + 5, 37, (50, 60)
    pos = rng.uniform(-20, 70, (2, h + 3, w + 4)).astype(np.float32)
    pos[0, 5, 6] = np.nan
    pos[:, h:, :] = 1e6  # padding rows beyond the chunk: ignored
    origin = np.array([3.25, -2.5])
    p = pos[:, :h, :w].astype(float) + origin[:, None, None]  # the formula before (whole chunk at once)
    ok = np.isfinite(p).all(axis=0)
    ok &= (p[0] >= -0.5) & (p[0] <= size[1] - 0.5) & (p[1] >= -0.5) & (p[1] <= size[0] - 0.5)
    want = p[0][ok].min(), p[0][ok].max(), p[1][ok].min(), p[1][ok].max()
    assert _sample_bounds(pos, origin, h, w, size) == want
    assert _sample_bounds(pos + 500, origin, h, w, size) is None  # nothing inside the image


def test_write_one_writer_bounded_chunks_aligned_tiles(scene, tmp_path, monkeypatch):
    """Issue 12, memory of the write: ``to_raster`` on the threaded scheduler with 2 threads
    computes one chunk at a time while its writer thread writes (counted by hooks on the chunk
    kernel and on the writer, not by timing), holds at most 3 computed chunks not yet written
    (one being written, one queued, one waiting in its worker: the hook counts it on arrival), writes with GDAL's block cache
    bounded (``GDAL_CACHEMAX`` seen by the writer) and with GeoTIFF tiles that divide the chunks
    (read back from the file), and the file equals the in-memory ortho."""
    import threading

    import dask
    from rasterio.env import get_gdal_config

    import photax.rectification._dask as tiled
    from photax.io import lazy

    s, grid = scene
    image = np.stack([(s.image * 250).astype(np.uint8) + b for b in (1, 3)])  # as above: its kernels, compiled
    state = {
        "computed": 0,
        "handed": 0,
        "written": 0,
        "running": 0,
        "most_running": 0,
        "most_unwritten": 0,
        "cache": set(),
    }
    mutex = threading.Lock()
    real_chunk, real_hand, real_write = tiled._ortho_chunk, lazy._Writer.__setitem__, lazy._Writer._write

    def chunk(*args):
        with mutex:
            state["running"] += 1
            state["most_running"] = max(state["most_running"], state["running"])
        out = real_chunk(*args)
        with mutex:
            state["running"] -= 1
            state["computed"] += 1
        return out

    def hand(self, key, block):  # a computed chunk (or a fill, off the DEM), as its worker hands it over
        with mutex:
            state["handed"] += 1
            state["most_unwritten"] = max(state["most_unwritten"], state["handed"] - state["written"])
        real_hand(self, key, block)

    def write(self, key, block):
        state["cache"].add(get_gdal_config("GDAL_CACHEMAX"))
        real_write(self, key, block)
        with mutex:
            state["written"] += 1

    monkeypatch.setattr(tiled, "_ortho_chunk", chunk)
    monkeypatch.setattr(lazy._Writer, "__setitem__", hand)
    monkeypatch.setattr(lazy._Writer, "_write", write)
    arr = orthorectify_dask(image, s.exterior, s.camera, s.dem, grid, chunks=40, resampling="cubic", approx=None)
    with dask.config.set(scheduler="threads", num_workers=2):
        to_raster(arr, tmp_path / "o.tif")
    n = len(list(tile_windows(grid.shape, 40)))
    assert state["computed"] >= n // 2 and state["handed"] == state["written"] == n  # (fills off the DEM)
    assert state["most_running"] == 1 and 1 <= state["most_unwritten"] <= 3
    assert state["cache"] == {16 << 20}
    with rasterio.open(tmp_path / "o.tif") as ds:
        np.testing.assert_array_equal(ds.read(), _ortho(s, grid, image, resampling="cubic", approx=None))
        ((th, tw),) = set(ds.block_shapes)
    for edges, tile in zip(arr.data.chunks[-2:], (th, tw)):
        assert tile % 16 == 0 and all(e % tile == 0 for e in edges[:-1])


def test_write_error_leaves_nothing_and_returns(scene, tmp_path, monkeypatch):
    """A write that fails in the writer thread (disk full, say) is raised in the caller's thread
    (the workers waiting to hand it a chunk stop too: no hang), the previous file stays and no
    partial file is left; the same on the synchronous scheduler."""
    import dask

    from photax.io import lazy

    s, grid = scene
    arr = orthorectify_dask(s.image.astype(np.float32), s.exterior, s.camera, s.dem, grid, chunks=40, approx=None)
    real, calls = lazy._Writer._write, []

    def failing(self, key, block):
        calls.append(1)
        if len(calls) == 2:
            raise OSError("No space left on device (injected)")
        real(self, key, block)

    monkeypatch.setattr(lazy._Writer, "_write", failing)
    out = tmp_path / "o.tif"
    for scheduler in ("threads", "sync"):
        calls.clear()
        out.write_bytes(b"previous result")
        # said in photax's words, naming the output (photax.io.atomic)
        error = pytest.raises(OSError, match="no space left on device.*o.tif")
        with dask.config.set(scheduler=scheduler), error:
            to_raster(arr, out)
        assert out.read_bytes() == b"previous result"
        assert [p.name for p in tmp_path.iterdir()] == ["o.tif"]


def test_write_other_schedulers_band_chunks_and_dims(scene, tmp_path):
    """``to_raster`` on the processes scheduler (its chunks computed on threads: the writer is in
    this process) and the synchronous one, with bands in separate chunks, writes the in-memory
    ortho; an array with its bands last is refused, not written scrambled."""
    import dask

    s, grid = scene
    image = np.stack([(s.image * 250).astype(np.uint8) + b for b in (1, 3)])
    arr = orthorectify_dask(image, s.exterior, s.camera, s.dem, grid, chunks=40, resampling="cubic", approx=None)
    ref = _ortho(s, grid, image, resampling="cubic", approx=None)
    for scheduler in ("processes", "sync"):
        with dask.config.set(scheduler=scheduler):
            to_raster(arr.chunk({"band": 1}), tmp_path / f"{scheduler}.tif")
        with rasterio.open(tmp_path / f"{scheduler}.tif") as ds:
            np.testing.assert_array_equal(ds.read(), ref)
            assert ds.descriptions == ("ortho", "ortho")
    with pytest.raises(ValueError, match="transpose"):
        to_raster(arr.transpose("y", "x", "band"), tmp_path / "t.tif")
    assert not (tmp_path / "t.tif").exists()


def test_tile_edge_divides_chunks():
    from photax.io.lazy import _tile_edge

    assert _tile_edge((1008,) * 19 + (848,)) == 336  # 1008 = 3 x 336
    assert _tile_edge((2000,) * 10) == 400
    assert _tile_edge((512, 512, 100)) == 256
    assert _tile_edge((100, 100, 7)) == 256  # no multiple of 16 divides 100: GDAL's default
    assert _tile_edge((48,)) == 48
