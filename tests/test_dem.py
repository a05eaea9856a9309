"""DEM.height: bilinear interpolation next to nodata cells.

Reference: a closed form.  Bilinear interpolation reproduces any function
``f(c, r) = a + b c + g r + d c r`` exactly, so on a grid sampled from ``f``
every defined height must equal ``f`` at the query's (column, row), and the
gradient the closed-form partial derivatives.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from photax.dem import DEM

A, B, G, D = 100.0, 2.0, -3.0, 0.5
ROWS, COLS = 3, 4
# North-up, 1 m pixels, upper-left corner at (500, 1000): the centre of
# heights[r, c] is at x = 500.5 + c, y = 999.5 - r.
TRANSFORM = (1.0, 0.0, 500.0, 0.0, -1.0, 1000.0)
NODATA = (1, 2)


def f(c, r):
    return A + B * c + G * r + D * c * r


def xy(c, r):
    return 500.5 + c, 999.5 - r


@pytest.fixture(scope="module")
def dem():
    r, c = np.mgrid[0:ROWS, 0:COLS].astype(float)
    h = f(c, r)
    h[NODATA] = -9999.0
    return DEM(h, TRANSFORM, nodata=-9999.0)


@pytest.fixture(scope="module")
def jitted():
    return jax.jit(lambda d, x, y: d.height(x, y))


# (col, row) of queries whose every non-zero-weight corner is valid.
DEFINED = [
    (1.0, 1.0),  # cell centre left of the nodata cell (was NaN: NaN * 0)
    (2.0, 0.0),  # cell centre above it
    (3.0, 1.0),  # right of it: the right-most column, clipped cell
    (2.0, 2.0),  # below it: the last row
    (1.5, 0.0),  # on the line between two valid centres, beside nodata
    (1.0, 1.5),  # on a column line through valid centres only
    (0.3, 0.6),  # inside a fully valid cell
    (3.0, 2.0),  # the last centre of the grid
]
# Queries with a non-zero weight on the nodata cell, or outside the centres.
UNDEFINED = [(2.0, 1.0), (1.5, 1.0), (2.0, 0.5), (1.5, 0.5), (2.5, 1.5), (-0.1, 1.0), (3.2, 0.0), (1.0, 2.01)]


@pytest.mark.parametrize("use_jit", [False, True])
def test_heights_beside_nodata_match_the_closed_form(dem, jitted, use_jit):
    height = (lambda x, y: jitted(dem, x, y)) if use_jit else dem.height
    c, r = np.array(DEFINED).T
    z = np.asarray(height(*xy(c, r)))
    np.testing.assert_allclose(z, f(c, r), rtol=0, atol=1e-12)
    c, r = np.array(UNDEFINED).T
    assert np.all(np.isnan(np.asarray(height(*xy(c, r)))))


def test_gradients_finite_where_defined(dem):
    grad = jax.jit(jax.vmap(jax.grad(lambda x, y: dem.height(x, y), argnums=(0, 1))))
    c, r = np.array(DEFINED).T
    gx, gy = (np.asarray(g) for g in grad(*(jnp.asarray(v) for v in xy(c, r))))
    assert np.all(np.isfinite(gx)) and np.all(np.isfinite(gy))
    # In a fully valid cell: the closed form, dz/dx = df/dc, dz/dy = -df/dr.
    i = DEFINED.index((0.3, 0.6))
    c0, r0 = DEFINED[i]
    np.testing.assert_allclose([gx[i], gy[i]], [B + D * r0, -(G + D * c0)], rtol=0, atol=1e-12)
    # At the centre left of the nodata cell: the slope along the column is
    # the closed form; towards the nodata cell (+x) the surface is flat.
    np.testing.assert_allclose([gx[0], gy[0]], [0.0, -(G + D * 1.0)], rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "heights, transform, words",
    [
        (np.full((2, 2), np.inf), TRANSFORM, "heights must be finite"),
        (np.zeros((2, 2)), (1.0, 0.0, np.nan, 0.0, -1.0, 0.0), "transform must be finite"),
        (np.zeros((2, 2)), (1.0, 2.0, 0.0, 0.5, 1.0, 0.0), "singular"),
    ],
)
def test_insane_grids_are_refused(heights, transform, words):
    with pytest.raises(ValueError, match=words):
        DEM(heights, transform)


def test_flat_dem_is_its_height_everywhere_inside_its_bounds():
    """Every quadrant and corner of its bounds (was NaN but in the quadrant above and right of the centre)."""
    dem = DEM.flat(95.0, (100.0, 200.0, 300.0, 600.0))
    x = np.array([100.0, 300.0, 120.0, 280.0, 120.0, 280.0, 200.0])
    y = np.array([200.0, 600.0, 210.0, 210.0, 590.0, 590.0, 400.0])
    np.testing.assert_allclose(np.asarray(dem.height(x, y)), 95.0, rtol=1e-15)
    assert np.isnan(np.asarray(dem.height(np.array([99.0]), np.array([400.0]))))[0]  # outside: no height
