"""Orthorectification: indirect mapping through the collinearity equations
and a DEM (:class:`OrthoModel`)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..camera import FrameCamera, distort, distortion_jacobian
from ..collinearity import ExteriorOrientation
from ..dem import DEM
from ..grid import Grid, gsd_hint, ortho_grid
from ..io.crs import check_dem
from ..io.sizes import check_output_size
from ..resampling import Resampling
from ._indirect import rectify


class OrthoModel(eqx.Module):
    """Ground ``(X, Y)`` -> image pixel ``(col, row)`` through a DEM.

    ``Z = dem.height(X, Y)`` (bilinear), then the collinearity equations and
    ``camera.image_to_pixel``.  NaN where the DEM has no height, the
    ground point is behind the camera, or its ray lies past the fold of the
    lens distortion (the distortion's Jacobian determinant is not positive:
    a strong barrel or rational model bends rays from outside the field of
    view back into the image, and their grey values would be another
    place's).  No occlusion test.
    """

    exterior: ExteriorOrientation
    camera: FrameCamera
    dem: DEM

    def __call__(self, xy: Array) -> Array:
        xy = jnp.asarray(xy, dtype=float)
        flat = xy.reshape(-1, 2)
        z = self.dem.height(flat[:, 0], flat[:, 1])
        ground = jnp.concatenate([flat, z[:, None]], axis=-1)
        q = self.exterior.points_in_camera(ground)
        xn = -q[:, :2] / q[:, 2:3]
        pix = self.camera.image_to_pixel(
            self.camera.principal_point[None] + self.camera.focal_length * distort(xn, self.camera.distortion)
        )
        j = distortion_jacobian(xn, self.camera.distortion)
        unfolded = j[:, 0, 0] * j[:, 1, 1] - j[:, 0, 1] * j[:, 1, 0] > 0
        ok = jnp.isfinite(z) & (q[:, 2] < 0) & unfolded
        return jnp.where(ok[:, None], pix, jnp.nan).reshape(xy.shape)


def orthorectify(
    image,
    exterior: ExteriorOrientation,
    camera: FrameCamera,
    dem: DEM,
    grid: Grid | None = None,
    *,
    resolution=None,
    resampling: Resampling | str = "bilinear",
    nodata=None,
    tile: int = 1024,
    progress: bool | str = False,
    approx: float | None = 0.125,
    info: dict | None = None,
) -> tuple[np.ndarray, Grid]:
    """Orthorectify a frame image with its orientation and a DEM.

    For every ground pixel centre ``(X, Y)`` of the output grid:
    ``Z = DEM(X, Y)`` (bilinear), ``(x, y) = project((X, Y, Z))`` by the
    collinearity equations, ``(col, row) = camera.image_to_pixel(x, y)``, and
    the grey value is resampled there.  Output pixels are ``nodata`` where
    the point falls outside the image, where the DEM is nodata or absent,
    behind the camera, and past the fold of the lens distortion (:class:`OrthoModel`).

    Occlusion is NOT handled: ground hidden from the camera by relief gets
    the grey value of the surface that hides it (double mapping).

    Args:
        image: ``(..., H, W)`` with ``(W, H) == camera.image_size``.
        exterior, camera: the image's orientation (``docs/conventions.md``).
        dem: heights in the same ground CRS and vertical datum as ``exterior``.
        grid: output grid; default the image footprint on the DEM
            (:func:`ortho_grid`) at ``resolution``.
        resolution: ground pixel size when ``grid`` is not given; default
            the mean ground sampling distance.
        resampling, nodata, tile, progress, approx, info: as in :func:`rectify`
            (the approximate mapping's check catches rough DEMs: chunks
            whose check error exceeds ``approx`` are mapped exactly).

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
        >>> _, own = ptx.orthorectify(scene.image, scene.exterior, scene.camera, scene.dem, resolution=15.0)
        >>> own.transform.a, own.shape  # a grid of its own: the footprint at 15 m
        (15.0, (...))
    """
    image = jnp.asarray(image)
    _check_image_size(image.shape, camera)
    if grid is None:
        grid = ortho_grid(exterior, camera, dem, resolution)
    check_dem(dem, grid)
    bands = int(np.prod(image.shape[:-2], dtype=np.int64))
    check_output_size(grid.shape, bands, image.dtype, hint=lambda: gsd_hint(exterior, camera, dem, grid))
    model = OrthoModel(exterior, camera, dem)
    out = rectify(
        image, model, grid, resampling=resampling, nodata=nodata, tile=tile, progress=progress, approx=approx, info=info
    )
    return out, grid


def _check_image_size(shape, camera: FrameCamera):
    if camera.image_size is not None and tuple(shape[-2:][::-1]) != tuple(camera.image_size):
        raise ValueError(
            f"image is {shape[-1]} x {shape[-2]} pixels but the camera's image_size is "
            f"{camera.image_size[0]} x {camera.image_size[1]}"
        )
