"""Orthorectification: indirect mapping through the collinearity equations
and a DEM (:class:`OrthoModel`)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jax import Array

from .._pytree import Module
from ..dem import DEM
from ..geo import check_dem, same_crs
from ..grid import Grid, check_coverage, gsd_hint, ortho_grid
from ..io.sizes import check_output_size
from ..resampling import Resampling
from ..sensor import FrameSensor, GroundSensor, LocalTransform, check_rpc_dem, is_sensor, sensor_arguments, sensor_of
from ._indirect import rectify
from ._occlusion import occluded


class OrthoModel(Module):
    """Ground ``(X, Y)`` -> image pixel ``(col, row)`` through a DEM.

    ``Z = dem.height(X, Y)`` (bilinear), then the sensor (:mod:`photax.sensor`): for a frame camera
    the collinearity equations and ``camera.image_to_pixel``; for an RPC camera (``exterior=None``)
    the RPC at the point's lon, lat (from the grid's ``crs``, default the DEM's) and height ``Z``.
    NaN where the DEM has no height or the sensor cannot image the point (behind a frame camera or
    past the fold of its lens distortion,
    outside an RPC's validity volume).  No occlusion test.

    For an RPC the DEM may be in another CRS than ``crs``: it is sampled at the point transformed
    into its CRS (pyproj), never resampled.
    """

    sensor: FrameSensor | GroundSensor
    dem: DEM
    to_dem: LocalTransform | None  # grid CRS -> the DEM's, where they differ (an RPC only)

    def __init__(self, exterior, camera, dem: DEM, crs=None):
        self.sensor = sensor_of(exterior, camera, dem.crs if crs is None else crs)
        self.dem = dem
        self.to_dem = None
        if self.sensor.kind != "frame" and dem.crs is not None and not same_crs(dem.crs, self.sensor.crs):
            self.to_dem = LocalTransform.fit(self.sensor.crs, dem.crs, self.sensor.box())

    def __call__(self, xy: Array) -> Array:
        xy = jnp.asarray(xy, dtype=float)
        flat = xy.reshape(-1, 2)
        at = flat if self.to_dem is None else self.to_dem(flat)
        z = self.dem.height(at[:, 0], at[:, 1])
        pix = self.sensor(jnp.concatenate([flat, z[:, None]], axis=-1))
        return jnp.where(jnp.isfinite(z)[:, None], pix, jnp.nan).reshape(xy.shape)


def orthorectify(
    image,
    exterior,
    camera=None,
    dem: DEM | None = None,
    grid: Grid | None = None,
    *,
    resolution=None,
    resampling: Resampling | str = "bilinear",
    nodata=None,
    tile: int = 1024,
    progress: bool | str = False,
    approx: float | None = 0.125,
    info: dict | None = None,
    occlusion: str | None = None,
) -> tuple[np.ndarray, Grid]:
    """Orthorectify an image with its sensor and a DEM: ``orthorectify(image, sensor, dem, grid=None, ...)``.

    ``sensor`` any :class:`photax.sensor.Sensor` (a frame, an RPC, a push-broom model, one signature);
    the older ``orthorectify(image, exterior, camera, dem, grid=None, ...)`` (``exterior`` None for an
    RPC or a push-broom camera) is the same computation, the sensor built from the pair.

    For every ground pixel centre ``(X, Y)`` of the output grid:
    ``Z = DEM(X, Y)`` (bilinear), ``(x, y) = project((X, Y, Z))`` by the
    collinearity equations, ``(col, row) = camera.image_to_pixel(x, y)``, and
    the grey value is resampled there.  Output pixels are ``nodata`` where
    the point falls outside the image, where the DEM is nodata or absent,
    behind the camera, and past the fold of the lens distortion (:class:`OrthoModel`).

    By default occlusion is NOT handled: ground hidden from the camera by relief gets
    the grey value of the surface that hides it (double mapping, "ghosts").  With
    ``occlusion="mark"`` and a DSM, the hidden cells (:func:`photax.occlusion_mask`, a z-buffer)
    are ``nodata``; :func:`photax.true_ortho` fills them from other images of a block.

    Args:
        image: ``(..., H, W)`` with ``(W, H) == camera.image_size``.
        exterior, camera: the image's orientation (``docs/conventions.md``); or ``None`` and an
            :class:`photax.rpc.RPCCamera` (refined or not) or a :class:`photax.PushbroomCamera` (any
            :class:`photax.sensor.GroundCamera`), any grid CRS (:class:`OrthoModel`).
        dem: heights in the same ground CRS and vertical datum as ``exterior``; for an RPC
            ellipsoidal heights in any CRS (a warning when its CRS does not say ellipsoidal; an
            error when its heights under the grid all lie outside the RPC's height range).
        grid: output grid; default the image footprint on the DEM
            (:func:`ortho_grid`) at ``resolution``.
        resolution: ground pixel size when ``grid`` is not given; default
            the mean ground sampling distance.
        resampling, nodata, tile, progress, approx, info: as in :func:`rectify`
            (the approximate mapping's check catches rough DEMs: chunks
            whose check error exceeds ``approx`` are mapped exactly).
        occlusion: ``None`` (no test) or ``"mark"``: cells the DEM (a DSM) hides from the image
            become ``nodata`` (:func:`photax.occlusion_mask` with its defaults).

    Returns:
        ``(ortho, grid)``: the ``(..., rows, cols)`` orthophoto in the input
        dtype and its grid.

    Examples:
        A frame over 300 m of relief, orthorectified with its true orientation onto the grid of the
        scene's true orthophoto, which it reproduces:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.relief_scene(300.0, seed=0, image_size=(400, 300), focal_px=400.0)
        >>> grid = ptx.Grid(scene.ortho_transform, scene.ortho.shape)
        >>> ortho, grid = ptx.orthorectify(scene.image, scene.exterior, scene.camera, scene.dem, grid)
        >>> seen = np.isfinite(ortho)  # NaN outside the image
        >>> bool(np.corrcoef(ortho[seen], scene.ortho[seen])[0, 1] > 0.95)
        True
        >>> sensor = ptx.FrameSensor(scene.exterior, scene.camera)  # any photax.Sensor: frame, RPC, push-broom
        >>> same, _ = ptx.orthorectify(scene.image, sensor, scene.dem, grid)
        >>> bool(np.array_equal(same, ortho, equal_nan=True))
        True
        >>> _, own = ptx.orthorectify(scene.image, scene.exterior, scene.camera, scene.dem, resolution=15.0)
        >>> own.transform.a, own.shape  # a grid of its own: the footprint at 15 m
        (15.0, (...))
    """
    if is_sensor(exterior):
        sensor = exterior
        exterior, camera, dem, grid, _ = sensor_arguments(sensor, (camera, dem, grid))
        if grid is None:
            grid = ortho_grid(exterior, camera, dem, resolution, crs=sensor.crs)
    image = jnp.asarray(image)
    _check_image_size(image.shape, camera)
    if grid is None:
        grid = ortho_grid(exterior, camera, dem, resolution)
    model = check_ortho_inputs(exterior, camera, dem, grid)
    bands = int(np.prod(image.shape[:-2], dtype=np.int64))
    check_output_size(grid.shape, bands, image.dtype, hint=lambda: gsd_hint(exterior, camera, dem, grid))
    if occlusion not in (None, "mark"):
        raise ValueError(f"occlusion must be None or 'mark', got {occlusion!r}")
    out = rectify(
        image, model, grid, resampling=resampling, nodata=nodata, tile=tile, progress=progress, approx=approx, info=info
    )
    if occlusion == "mark":
        from ._tiling import _fill_value

        out[..., occluded(model, grid)] = _fill_value(out.dtype, nodata)
    return out, grid


def occlusion_mask(
    exterior,
    camera,
    dsm: DEM,
    grid: Grid,
    *,
    supersample: int = 2,
    tolerance: float | None = None,
    buffer_cell: int | None = None,
) -> np.ndarray:
    """Which cells of an output grid a DSM hides from an image: a z-buffer of the DSM's surface
    in the image (:mod:`photax.rectification._occlusion`).

    Args:
        exterior, camera: the image's orientation, as in :func:`orthorectify` (a frame camera and
            its exterior orientation, depth = distance to the projection centre; or ``None`` and an
            RPC / push-broom camera, depth = -height along its nearly parallel rays).
        dsm: the surface model (buildings, trees: a DSM, not a bare-earth DEM), in the frame's
            ground CRS (an RPC's: ellipsoidal heights, any CRS).
        grid: the output grid.
        supersample: surface samples per DSM cell (or per buffer cell, the finer) along each
            axis (walls are sampled by the bilinear DSM at these points).
        tolerance: depth margin (m) before a cell counts as hidden; default twice the larger of
            the grid cell and the buffer cell's ground size.
        buffer_cell: buffer cell edge in image pixels; default about one grid cell's image size.

    Returns:
        ``(rows, cols)`` bool, True where the cell's surface point is hidden by a nearer surface;
        False where it is visible and where it is not imaged at all (off the image, no DSM height:
        the ortho is nodata there anyway).

    Examples:
        A 20 m block from x = -30 to -20 m under a nadir camera 100 m up: it hides the ground behind
        it out to ``x = -30 * 100 / (100 - 20) = -37.5`` m:

        >>> import numpy as np
        >>> import photax as ptx
        >>> camera = ptx.FrameCamera.from_pixels(100.0, (100, 100))
        >>> exterior = ptx.ExteriorOrientation([0.0, 0.0, 100.0], [0.0, 0.0, 0.0])
        >>> heights = np.zeros((100, 100))
        >>> heights[40:60, 20:30] = 20.0  # 1 m cells from (-50, 50): y 10 .. -10, x -30 .. -20
        >>> dsm = ptx.DEM(heights, (1.0, 0.0, -50.0, 0.0, -1.0, 50.0))
        >>> hidden = ptx.occlusion_mask(exterior, camera, dsm, ptx.Grid.from_bounds((-50.0, -50.0, 50.0, 50.0), 1.0))
        >>> (np.flatnonzero(hidden[50]) - 50 + 0.5).tolist()  # the cell centres hidden along y = -0.5
        [-36.5, -35.5, -34.5, -33.5, -32.5, -31.5, -30.5]
    """

    if not isinstance(grid, Grid):
        raise ValueError(f"grid must be a photax Grid, got {type(grid).__name__}")
    model = check_ortho_inputs(exterior, camera, dsm, grid)
    return occluded(model, grid, supersample=supersample, tolerance=tolerance, buffer_cell=buffer_cell)


def check_ortho_inputs(exterior, camera, dem: DEM, grid: Grid) -> OrthoModel:
    """The model of an ortho after the DEM's checks: a frame's DEM projected and in the grid's CRS
    (:func:`photax.io.crs.check_dem`), an RPC's heights in its range (:func:`photax.sensor.check_rpc_dem`),
    the share of the image the DEM covers (:func:`photax.grid.check_coverage`: a warning below 95 %,
    an error at none)."""
    model = OrthoModel(exterior, camera, dem, grid.crs)
    if model.sensor.kind != "frame":
        check_rpc_dem(model.sensor, dem, grid)
    else:
        check_dem(dem, grid)
    if model.sensor.image_size is not None:
        check_coverage(model.sensor, dem, stacklevel=4)  # a DEM on part of the image: a warning with the share
    return model


def _check_image_size(shape, camera):
    if camera.image_size is not None and tuple(shape[-2:][::-1]) != tuple(camera.image_size):
        raise ValueError(
            f"image is {shape[-1]} x {shape[-2]} pixels but the camera's image_size is "
            f"{camera.image_size[0]} x {camera.image_size[1]}"
        )
