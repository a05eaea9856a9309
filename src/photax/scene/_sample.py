"""The photax sample scene: one seeded aerial frame with GCPs and a blunder.

What ``data/make_sample.py`` and ``photax demo`` write (through
:func:`photax.demo.write_sample`, which packs the points into a
:class:`photax.io.GCPTable`): a 1000 x 750 px frame camera (f = 8.8 mm,
17.6 um pixels, so f = 500 px; a small principal-point offset and radial
distortion) about 380 m above hilly ground at UTM-scale coordinates (GSD ~
0.76 m), tilted by about 1 deg; 16 points on a jittered 4 x 4 grid of the
image, monoplotted onto the DEM (:func:`photax.image_to_ground`): 12 control
and 4 check points (:data:`SAMPLE_CHECK`), pixel noise 0.3 px (Gaussian,
per coordinate), and a 15 px blunder on :data:`SAMPLE_BLUNDER`.

Changing anything here changes the committed sample files: regenerate them
(``python data/make_sample.py``); ``tests/test_cli.py`` checks they are current.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation, image_to_ground, project
from ..dem import DEM
from ._texture import texture

SAMPLE_SEED = 20240917
SAMPLE_IMAGE = "IMG_0001"
SAMPLE_NOISE_PX = 0.3
SAMPLE_BLUNDER = ("P07", (15.0, 0.0))  # a point name and its deliberate error (column, row) in pixels
SAMPLE_CHECK = ("P03", "P06", "P11", "P14")
SAMPLE_CRS = "EPSG:32633"
SAMPLE_ORIGIN = (512_300.0, 4_103_800.0)  # local origin of the relief and the texture (UTM-like: photax must reduce)
SAMPLE_DEM_CELL = 5.0  # metres
SAMPLE_DEM_HALF = 600.0  # the DEM spans the origin +- this many metres (the footprint plus a margin)
SAMPLE_TARGET_RADIUS = 6.0  # metres: ground targets painted at the GCPs, ~8 px in the image


def _sample_terrain(x, y):
    """Terrain height in metres at local (x, y) metres: a hill and a slope, 40 .. 125 m."""
    return 60.0 + 0.03 * x + 45.0 * np.exp(-((x - 120.0) ** 2 + (y + 60.0) ** 2) / (2 * 180.0**2))


def sample_dem() -> DEM:
    """The sample DEM: the terrain at the centres of 5 m cells, float32 as stored in the GeoTIFF."""
    x0, y0 = SAMPLE_ORIGIN
    n = int(round(2 * SAMPLE_DEM_HALF / SAMPLE_DEM_CELL))
    centres = -SAMPLE_DEM_HALF + SAMPLE_DEM_CELL * (np.arange(n) + 0.5)
    heights = _sample_terrain(centres[None, :], -centres[:, None]).astype(np.float32)  # row 0 is the north edge
    transform = (SAMPLE_DEM_CELL, 0.0, x0 - SAMPLE_DEM_HALF, 0.0, -SAMPLE_DEM_CELL, y0 + SAMPLE_DEM_HALF)
    return DEM(heights.astype(float), transform, crs=SAMPLE_CRS)


@eqx.filter_jit
def _monoplot(pixel, exterior, camera, dem):
    return image_to_ground(camera.pixel_to_image(pixel), exterior, camera, dem=dem)


def sample_points() -> dict:
    """The sample scene's truth and measurements (module docstring).

    Returns:
        dict with ``camera``, ``exterior`` (phi-omega-kappa), ``dem``,
        ``names`` ``(16,)``, ``ground`` ``(16, 3)`` (rounded to the
        millimetre, as surveyed), ``pixel`` ``(16, 2)`` measured (column,
        row; noise and the blunder, rounded to 0.001 px), ``pixel_true``
        ``(16, 2)`` noise-free, ``sigma`` ``(16,)`` px, ``role``
        ``(16,)`` "control" / "check", ``crs``.
    """
    rng = np.random.default_rng(SAMPLE_SEED)
    width, height = 1000, 750
    camera = FrameCamera(
        8.8, (0.011, -0.0066), (-0.02, 0.004, 0.0, 0.0, 0.0), pixel_size=0.0176, image_size=(width, height)
    )
    origin = np.array([*SAMPLE_ORIGIN, 0.0])
    exterior = ExteriorOrientation(
        origin + np.array([8.0, -12.0, 450.0]), np.radians([1.2, -0.8, 35.0]), "phi-omega-kappa"
    )
    dem = sample_dem()
    # Jittered 4 x 4 grid in the image, kept ~40 px from the border.
    u = np.linspace(0.0625, 0.9375, 4) * width
    v = np.linspace(0.0833, 0.9167, 4) * height
    pix = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2) + rng.uniform(-25, 25, (16, 2))
    # Monoplot each pixel onto the DEM; survey the ground point to the millimetre.
    ground = np.round(np.asarray(_monoplot(jnp.asarray(pix), exterior, camera, dem)), 3)
    if not np.all(np.isfinite(ground)):  # pragma: no cover - a bug in the scene, not user input
        raise RuntimeError("a sample point's ray missed the DEM")
    pixel_true = np.asarray(camera.image_to_pixel(project(ground, exterior, camera)))
    pixel = pixel_true + rng.normal(0.0, SAMPLE_NOISE_PX, pixel_true.shape)
    names = np.array([f"P{k + 1:02d}" for k in range(16)])
    pixel[names == SAMPLE_BLUNDER[0]] += np.asarray(SAMPLE_BLUNDER[1])
    pixel = np.round(pixel, 3)
    return {
        "camera": camera,
        "exterior": exterior,
        "dem": dem,
        "names": names,
        "ground": ground,
        "pixel": pixel,
        "pixel_true": pixel_true,
        "sigma": np.full(16, SAMPLE_NOISE_PX),
        "role": np.where(np.isin(names, SAMPLE_CHECK), "check", "control"),
        "crs": SAMPLE_CRS,
    }


def _targets(x, y, centres, radius=SAMPLE_TARGET_RADIUS):
    """Survey targets: quartered black-and-white discs of ``radius`` m (default :data:`SAMPLE_TARGET_RADIUS`).

    ``x, y`` ``(n,)`` ground points, ``centres`` ``(k, 2)``; returns the
    target grey value ``(n,)`` and its opacity ``(n,)`` in [0, 1] (edges
    smoothed over ~0.4 m so the rendered image is not aliased).
    """
    dx = x[:, None] - centres[None, :, 0]
    dy = y[:, None] - centres[None, :, 1]
    r = jnp.hypot(dx, dy)
    nearest = jnp.argmin(r, axis=1)
    take = lambda a: jnp.take_along_axis(a, nearest[:, None], axis=1)[:, 0]  # noqa: E731
    dx, dy, r = take(dx), take(dy), take(r)
    grey = 0.5 + 0.45 * jnp.tanh(dx / 0.4) * jnp.tanh(dy / 0.4)
    return grey, jax.nn.sigmoid((radius - r) / 0.3)


@eqx.filter_jit
def _render(pixel, exterior, camera, dem, origin, centres):
    g = image_to_ground(camera.pixel_to_image(pixel), exterior, camera, dem=dem)
    grey = texture(g[:, 0] - origin[0], g[:, 1] - origin[1])
    target, alpha = _targets(g[:, 0], g[:, 1], centres)
    return jnp.nan_to_num(grey * (1.0 - alpha) + target * alpha, nan=0.0)


def render_sample_image(camera: FrameCamera, exterior: ExteriorOrientation, dem: DEM, ground) -> np.ndarray:
    """The sample image ``(rows, cols)`` uint8, rendered by indirect mapping.

    Every pixel centre is monoplotted onto ``dem`` with ``exterior``
    (:func:`photax.image_to_ground`) and the ground texture
    (:func:`photax.scene.texture`: roads, fields, a ripple) is evaluated
    there, with a quartered survey target painted at each ``ground`` ``(k,
    2+)`` point's (X, Y).
    """
    w, h = camera.image_size
    cc, rr = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    px = jnp.asarray(np.column_stack([cc.ravel(), rr.ravel()]))
    grey = np.asarray(
        _render(px, exterior, camera, dem, jnp.asarray(SAMPLE_ORIGIN), jnp.asarray(np.asarray(ground)[:, :2]))
    )
    return np.clip(np.round(grey * 255.0), 0, 255).astype(np.uint8).reshape(h, w)
