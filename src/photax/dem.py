"""Digital elevation models: a height grid with an affine georeference.

The affine transform is GDAL's / rasterio's: for a pixel *corner* at
(column c, row r), ``X = a c + b r + xoff`` and ``Y = d c + e r + yoff``,
stored as ``(a, b, xoff, d, e, yoff)`` (``rasterio.Affine`` order).  A height
``heights[r, c]`` belongs to the pixel *centre* ``(c + 0.5, r + 0.5)``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ._pytree import Module, field
from .errors import DegenerateGeometryError


class DEM(Module):
    """A gridded height model, sampled bilinearly.

    Attributes:
        heights: ``(rows, cols)`` heights; nodata cells hold NaN.
        transform: ``(6,)`` affine ``(a, b, xoff, d, e, yoff)`` of the grid.
        crs: the CRS as text (WKT, PROJ or EPSG), or ``None``.

    Examples:
        Heights on a grid with its affine georeference (5 m cells from (1000, 2000), row down),
        read at any ground point by bilinear interpolation; a plane is reproduced exactly:

        >>> import numpy as np
        >>> import photax as ptx
        >>> rows, cols = np.mgrid[0:20, 0:30]
        >>> x, y = 1000.0 + 5.0 * (cols + 0.5), 2000.0 - 5.0 * (rows + 0.5)  # cell centres
        >>> dem = ptx.DEM(0.1 * x - 0.05 * y, (5.0, 0.0, 1000.0, 0.0, -5.0, 2000.0))
        >>> print(np.round(np.asarray(dem.height(np.array([1033.3, 1101.7]), np.array([1977.0, 1960.2]))), 6))  # 0.1 x - 0.05 y
        [ 4.48 12.16]
    """

    heights: Array
    transform: Array
    crs: str | None = field(static=True, default=None)

    def __init__(self, heights, transform, crs: str | None = None, nodata: float | None = None):
        h = np.asarray(heights, dtype=float)
        if h.ndim != 2 or min(h.shape) < 2:
            raise ValueError(f"heights must be a 2-D grid of at least 2 x 2, got shape {h.shape}")
        if nodata is not None and not np.isnan(nodata):
            h = np.where(h == nodata, np.nan, h)
        t = np.asarray(tuple(transform)[:6], dtype=float)
        if t.shape != (6,):
            raise ValueError("transform must have 6 affine coefficients (a, b, xoff, d, e, yoff)")
        if np.any(np.isinf(h)):
            raise ValueError("heights must be finite, or NaN for nodata; got an infinite height")
        if not np.all(np.isfinite(t)):
            raise ValueError(f"transform must be finite, got {t.tolist()}")
        with np.errstate(over="ignore", under="ignore"):  # a pixel of 1e200 m: no RuntimeWarning
            det = t[0] * t[4] - t[1] * t[3]
        if det == 0:
            raise DegenerateGeometryError("transform is singular")
        if not np.isfinite(det):
            raise DegenerateGeometryError(f"transform out of range (pixel area overflows), got {t.tolist()}")
        self.heights = jnp.asarray(h, dtype=float)  # with a dtype: a transfer, not an eager program
        self.transform = jnp.asarray(t, dtype=float)
        self.crs = crs

    @classmethod
    def flat(cls, height: float, bounds: tuple[float, float, float, float]) -> DEM:
        """A constant-height DEM over ``(xmin, ymin, xmax, ymax)``: its 2 x 2 pixel centres are
        those corners, so :meth:`height` is ``height`` everywhere inside them (it was NaN in all
        but the quadrant above and right of the centre)."""
        xmin, ymin, xmax, ymax = bounds
        w, h = xmax - xmin, ymax - ymin
        return cls(np.full((2, 2), float(height)), (w, 0, xmin - w / 2, 0, -h, ymax + h / 2))

    @jax.jit
    def ground_to_pixel(self, x: Array, y: Array) -> tuple[Array, Array]:
        """Ground (X, Y) -> fractional (column, row) of pixel centres."""
        a, b, c, d, e, f = (self.transform[i] for i in range(6))
        det = a * e - b * d
        dx, dy = x - c, y - f
        col = (e * dx - b * dy) / det
        row = (-d * dx + a * dy) / det
        return col - 0.5, row - 0.5

    @jax.jit
    def height(self, x: Array, y: Array) -> Array:
        """Bilinear height at ground ``(x, y)`` (any broadcastable shapes).

        With ``(col, row)`` the fractional pixel-centre position (see
        :meth:`ground_to_pixel`), ``c0 = floor(col)``, ``tc = col - c0`` (and
        likewise ``r0``, ``tr``)::

            z = h[r0, c0] (1-tc)(1-tr) + h[r0, c0+1] tc (1-tr)
              + h[r0+1, c0] (1-tc) tr  + h[r0+1, c0+1] tc tr

        NaN outside the grid (beyond the outermost pixel centres) and where a
        corner with a non-zero weight is nodata.  A nodata corner whose weight
        is exactly 0 does not count: at a cell centre, or on the line between
        two valid centres, the height is defined even beside a nodata cell
        (``NaN * 0`` would otherwise make it NaN).  Gradients are the bilinear
        ones; towards a nodata corner of weight 0 the surface is taken as flat
        (the one-sided slope there does not exist), so they stay finite
        wherever the height is.
        """
        col, row = self.ground_to_pixel(jnp.asarray(x, dtype=float), jnp.asarray(y, dtype=float))
        rows, cols = self.heights.shape
        inside = (col >= 0) & (col <= cols - 1) & (row >= 0) & (row <= rows - 1)
        c0 = jnp.clip(jnp.floor(col), 0, cols - 2)
        r0 = jnp.clip(jnp.floor(row), 0, rows - 2)
        tc, tr = col - c0, row - r0
        ci, ri = c0.astype(int), r0.astype(int)
        corners = [
            (self.heights[ri, ci], (1 - tc) * (1 - tr)),
            (self.heights[ri, ci + 1], tc * (1 - tr)),
            (self.heights[ri + 1, ci], (1 - tc) * tr),
            (self.heights[ri + 1, ci + 1], tc * tr),
        ]
        valid = [~jnp.isnan(h) for h, _ in corners]
        # Nodata enters neither the value nor (through 0 * NaN) the gradient.
        safe = [jnp.where(ok, h, 0.0) for (h, _), ok in zip(corners, valid)]
        z_valid = sum(h * w for h, (_, w) in zip(safe, corners))
        # Give each nodata corner the interpolated height itself (no gradient):
        # its weight is 0 wherever the result is kept, so the value is that of
        # the valid corners, and the slope towards it is 0, not -z.
        flat = jax.lax.stop_gradient(z_valid)
        z = sum(jnp.where(ok, h, flat) * w for h, ok, (_, w) in zip(safe, valid, corners))
        blocked = sum(((w != 0) & ~ok).astype(int) for ok, (_, w) in zip(valid, corners)) > 0
        return jnp.where(inside & ~blocked, z, jnp.nan)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of the grid's outer pixel edges."""
        rows, cols = self.heights.shape
        a, b, c, d, e, f = np.asarray(self.transform)
        xs = [c, c + a * cols, c + b * rows, c + a * cols + b * rows]
        ys = [f, f + d * cols, f + e * rows, f + d * cols + e * rows]
        return min(xs), min(ys), max(xs), max(ys)
