"""A synthetic aerial frame over relief with known truth: terrain, camera, image, control points.

:func:`relief_scene` builds a vertical (optionally tilted) aerial frame over
hilly or flat terrain.  Everything is generated from one seed, so tests,
notebooks and the demo see the same scene:

* a :class:`photax.DEM` of a few Gaussian hills and a valley, rescaled to
  heights ``0 .. relief`` above the datum ``Z = 0`` (all zeros when
  ``relief == 0``);
* a ground texture (roads every 250 m on a 500 m checkerboard with a fine
  ripple) that is a function of ground ``(X, Y)``, so relief displacement
  shows as bent roads;
* the image rendered from it by the collinearity model: each pixel centre is
  monoplotted onto the DEM (:func:`photax.collinearity.image_to_ground`) and
  the texture is evaluated where its ray meets the ground;
* control points (GCPs) spread over the image on a jittered grid, and
  independent check points, with ground XYZ exact and pixel measurements
  carrying Gaussian noise.

Ground coordinates are UTM-like (``origin`` ~ 5e5, 4e6 m) so code that
forgets to reduce them to a local origin shows it.  Frames and units:
``docs/conventions.md``.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation, image_to_ground, look_at, project
from ..dem import DEM
from ._texture import _texture, texture


@dataclasses.dataclass(frozen=True)
class Scene:
    """A synthetic aerial frame with its truth.

    Attributes:
        image: ``(height, width)`` float64 grey values in [0, 1].
        dem: the terrain; heights in metres above the datum ``Z = 0``.
        camera: interior orientation (pixel units, no distortion).
        exterior: true exterior orientation (phi-omega-kappa).
        ortho: ``(rows, cols)`` the ground texture sampled on ``ortho_transform``
            (what a perfect orthophoto of the image shows).
        ortho_transform: ``(6,)`` affine (rasterio order) of ``ortho``.
        gcp_ground, check_ground: ``(n, 3)`` exact ground XYZ (metres).
        gcp_pixel, check_pixel: ``(n, 2)`` measured (column, row), with noise.
        gcp_pixel_true, check_pixel_true: ``(n, 2)`` noise-free projections.
        noise_px: standard deviation of the pixel noise per coordinate.
        gsd: ground sampling distance at the datum, metres per pixel.

    Examples:
        What :func:`relief_scene` returns: an image with its camera, true orientation and DEM, GCPs
        and check points with their measured and true pixels:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.relief_scene(100.0, seed=2, image_size=(200, 150), focal_px=200.0, n_gcp=8, n_check=4)
        >>> scene.gcp_ground.shape, scene.check_ground.shape, scene.image.shape
        ((8, 3), (4, 3), (150, 200))
        >>> noise = scene.gcp_pixel - scene.gcp_pixel_true
        >>> bool(0 < np.abs(noise).max() < 6 * scene.noise_px)  # the measurements carry the stated noise
        True
    """

    image: np.ndarray
    dem: DEM
    camera: FrameCamera
    exterior: ExteriorOrientation
    ortho: np.ndarray
    ortho_transform: tuple[float, ...]
    gcp_ground: np.ndarray
    gcp_pixel: np.ndarray
    gcp_pixel_true: np.ndarray
    check_ground: np.ndarray
    check_pixel: np.ndarray
    check_pixel_true: np.ndarray
    noise_px: float
    gsd: float

    @property
    def flying_height(self) -> float:
        """Height of the projection centre above the datum ``Z = 0``, metres."""
        return float(self.exterior.Z)


_look_at = jax.jit(look_at)  # one compilation, not one per operation


@eqx.filter_jit
def _locate(px, exterior, camera, dem, origin):
    """Pixels -> ground on the DEM, their exact reprojection, and the texture there."""
    g = image_to_ground(camera.pixel_to_image(px), exterior, camera, dem=dem)
    reproj = camera.image_to_pixel(project(g, exterior, camera))
    return g, reproj, jnp.nan_to_num(texture(g[:, 0] - origin[0], g[:, 1] - origin[1]), nan=0.0)


def _terrain(rng: np.random.Generator, x: np.ndarray, y: np.ndarray, relief: float) -> np.ndarray:
    """Hills and a valley over local ``(x, y)``, rescaled to ``0 .. relief``."""
    if relief == 0:
        return np.zeros(np.broadcast(x, y).shape)
    t = np.zeros(np.broadcast(x, y).shape)
    for _ in range(6):  # hills of 250-450 m radius: too sharp for a polynomial
        cx, cy = rng.uniform(-1400, 1400), rng.uniform(-1100, 1100)
        s = rng.uniform(250, 450)
        t += rng.uniform(0.5, 1.0) * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))
    angle = rng.uniform(0, np.pi)
    across = -np.sin(angle) * x + np.cos(angle) * y
    t -= 0.6 * np.exp(-(across**2) / (2 * 200.0**2))  # a valley across the scene
    return relief * (t - t.min()) / (t.max() - t.min())


def _spread(rng: np.random.Generator, n: int, size: tuple[int, int], margin: float) -> np.ndarray:
    """``n`` pixel positions spread over the image: one per cell of a jittered grid."""
    w, h = size
    if n == 0:
        return np.zeros((0, 2))
    nx = int(np.ceil(np.sqrt(n * w / h)))
    ny = int(np.ceil(n / nx))
    cells = rng.permutation(nx * ny)[:n]
    u = (cells % nx + rng.uniform(0.1, 0.9, n)) / nx
    v = (cells // nx + rng.uniform(0.1, 0.9, n)) / ny
    return np.column_stack([margin + u * (w - 1 - 2 * margin), margin + v * (h - 1 - 2 * margin)])


def relief_scene(
    relief: float = 300.0,
    *,
    seed: int = 0,
    image_size: tuple[int, int] = (1000, 800),
    focal_px: float = 1000.0,
    flying_height: float = 3000.0,
    tilt_deg: float = 2.0,
    n_gcp: int = 30,
    n_check: int = 60,
    noise_px: float = 0.3,
    origin: tuple[float, float] = (500_000.0, 4_000_000.0),
) -> Scene:
    """A synthetic aerial frame over hills (or flat land) with known truth.

    Args:
        relief: height range of the terrain in metres (0 gives a flat datum).
        seed: seeds the terrain, the camera tilt direction, the points and
            the noise.
        image_size: ``(width, height)`` in pixels.
        focal_px: principal distance in pixels (1000 px on a 1000 px wide
            frame is a wide-angle survey camera, ~53 degrees across).
        flying_height: projection-centre height above the datum, metres.
        tilt_deg: angle between the optical axis and the vertical; 0 gives a
            true vertical image (nadir at the principal point).
        n_gcp, n_check: numbers of control and check points.
        noise_px: standard deviation of the measurement noise, pixels.
        origin: ground ``(X, Y)`` of the nadir point, metres.

    Returns:
        A :class:`Scene`.  Relief displacement at radial distance ``r`` from
        the nadir is ``d = r h / H`` (``h`` = height, ``H`` = flying height).

    Examples:
        A synthetic aerial frame over hills with its truth: the examples' and tests' data:

        >>> import numpy as np
        >>> import photax as ptx
        >>> scene = ptx.relief_scene(200.0, seed=0, image_size=(400, 300), focal_px=400.0)
        >>> scene.image.shape, scene.gcp_ground.shape, scene.gcp_pixel.shape
        ((300, 400), (30, 3), (30, 2))
        >>> err = np.asarray(scene.camera.image_to_pixel(ptx.project(scene.gcp_ground, scene.exterior, scene.camera))) - scene.gcp_pixel_true
        >>> bool(np.abs(err).max() < 1e-6)  # the true pixels are the projections of the ground points
        True
    """
    if relief < 0 or flying_height <= relief:
        raise ValueError(f"need 0 <= relief < flying_height, got relief={relief}, flying_height={flying_height}")
    if n_gcp < 3 or n_check < 0:
        raise ValueError(f"n_gcp must be >= 3 and n_check >= 0, got {n_gcp}, {n_check}")
    # One function on purpose (> 80 lines): every draw comes from this one generator in a
    # fixed order, and the tests' and notebooks' figures depend on that order.
    rng = np.random.default_rng(seed)
    x0, y0 = origin
    w, h = image_size
    gsd = flying_height / focal_px
    camera = FrameCamera.from_pixels(focal_px, (w, h))

    # DEM: 10 m cells over the footprint at the datum plus a margin.
    half_x, half_y = 0.5 * w * gsd + 500.0, 0.5 * h * gsd + 500.0
    cell = 10.0
    cols, rows = int(2 * half_x / cell), int(2 * half_y / cell)
    transform = (cell, 0.0, x0 - half_x, 0.0, -cell, y0 + half_y)
    xc = -half_x + cell * (np.arange(cols) + 0.5)
    yc = half_y - cell * (np.arange(rows) + 0.5)
    heights = _terrain(rng, xc[None, :], yc[:, None], relief)
    dem = DEM(heights, transform)

    # Camera over the origin, tilted towards a random azimuth.
    azimuth = rng.uniform(0, 2 * np.pi)
    offset = flying_height * np.tan(np.radians(tilt_deg))
    target = np.array([x0 + offset * np.cos(azimuth), y0 + offset * np.sin(azimuth), 0.0])
    exterior = _look_at(np.array([x0, y0, flying_height]), target)

    # One call for the image and the points: compiling is the slow part here.
    cc, rr = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    picked = [_spread(rng, n, (w, h), margin=20.0) for n in (n_gcp, n_check)]
    px = np.concatenate([np.column_stack([cc.ravel(), rr.ravel()]), *picked])
    ground, reproj, grey = (np.asarray(a) for a in _locate(jnp.asarray(px), exterior, camera, dem, jnp.array([x0, y0])))
    image = grey[: w * h].reshape(h, w)
    gcp_ground, gcp_true = ground[w * h : w * h + n_gcp], reproj[w * h : w * h + n_gcp]
    check_ground, check_true = ground[w * h + n_gcp :], reproj[w * h + n_gcp :]
    gcp_pixel = gcp_true + rng.normal(0.0, noise_px, gcp_true.shape)
    check_pixel = check_true + rng.normal(0.0, noise_px, check_true.shape)

    # The orthophoto of the same texture, at the datum GSD over the DEM area.
    ocols, orows = int(2 * half_x / gsd), int(2 * half_y / gsd)
    ortho_transform = (gsd, 0.0, x0 - half_x, 0.0, -gsd, y0 + half_y)
    ox = -half_x + gsd * (np.arange(ocols) + 0.5)
    oy = half_y - gsd * (np.arange(orows) + 0.5)
    ortho = np.asarray(_texture(jnp.asarray(ox)[None, :], jnp.asarray(oy)[:, None]))

    if np.isnan(gcp_ground).any() or np.isnan(check_ground).any():  # pragma: no cover - a bug, not user input
        raise RuntimeError("a control point ray missed the DEM")
    return Scene(
        image=image, dem=dem, camera=camera, exterior=exterior, ortho=ortho, ortho_transform=ortho_transform,
        gcp_ground=gcp_ground, gcp_pixel=gcp_pixel, gcp_pixel_true=gcp_true,
        check_ground=check_ground, check_pixel=check_pixel, check_pixel_true=check_true,
        noise_px=float(noise_px), gsd=float(gsd),
    )  # fmt: skip
