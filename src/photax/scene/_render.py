"""Images of a textured DEM seen by a frame camera: the renderer of synthetic scenes.

:func:`render_image` is the general form of what :func:`photax.scene.render_sample_image`
does for the sample image: every sample point of the image is monoplotted
onto the DEM (:func:`photax.image_to_ground`, the ray cut iteratively with
the terrain) and the ground texture is evaluated where the ray meets it,
with quartered survey targets (discs) at given ground points.  Unlike the
sample image it is *area-sampled*: ``supersample^2`` sample points per pixel,
averaged (the detector integrates over its pixel), then blurred by a Gaussian
PSF and noised, so a point's grey value does not depend on where in its pixel
it falls (no aliasing of the roads, edges and targets).

Pixels whose rays miss the DEM are 0.  No occlusion: the first DEM crossing
the monoplotting converges to is used (fine for the gentle relief of the tests).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from scipy.ndimage import gaussian_filter

from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation, image_to_ground
from ..dem import DEM
from ._sample import _targets
from ._texture import detailed_texture, texture

_CHUNK = 1 << 17  # sample points per compiled call: one compilation for any image size


@eqx.filter_jit
def _grey(px, exterior, camera, dem, origin, centres, radius, detail):
    g = image_to_ground(camera.pixel_to_image(px), exterior, camera, dem=dem)
    x, y = g[:, 0] - origin[0], g[:, 1] - origin[1]
    grey = jnp.where(detail, detailed_texture(x, y), texture(x, y))
    target, alpha = _targets(g[:, 0], g[:, 1], centres, radius)
    return jnp.nan_to_num(grey * (1.0 - alpha) + target * alpha, nan=0.0)


def render_image(
    camera: FrameCamera,
    exterior: ExteriorOrientation,
    dem: DEM,
    *,
    origin,
    targets=None,
    target_radius: float = 6.0,
    detail: bool = True,
    supersample: int = 4,
    blur: float = 0.5,
    noise: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """Render the image a frame camera takes of a textured DEM.

    Args:
        camera: interior orientation with a pixel grid (``image_size`` ``(w, h)``).
        exterior: the image's exterior orientation.
        dem: the terrain; rays are cut with it.
        origin: ``(X0, Y0)`` ground origin of the texture (metres).
        targets: ``(k, 2+)`` ground points where survey targets (quartered
            discs of ``target_radius`` m) are painted, or None.
        detail: paint :func:`detailed_texture` (two-dimensional metre-scale
            detail, for matching) rather than :func:`texture`.
        supersample: sample points per pixel along each axis (averaged).
        blur: Gaussian PSF standard deviation, px (0: none).
        noise: standard deviation of white Gaussian noise, grey values.
        seed: seeds the noise.

    Returns:
        ``(h, w)`` float64 grey values (about 0..1, noise on top).
    """
    if camera.image_size is None:
        raise ValueError("camera: give image_size (the rendered image's (width, height))")
    if supersample < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    w, h = camera.image_size
    s = int(supersample)
    sub = (np.arange(s) + 0.5) / s - 0.5
    cols = (np.arange(w)[:, None] + sub[None, :]).ravel()
    rows = (np.arange(h)[:, None] + sub[None, :]).ravel()
    cc, rr = np.meshgrid(cols, rows)
    px = np.column_stack([cc.ravel(), rr.ravel()])
    centres = np.full((1, 2), 1e12) if targets is None else np.asarray(targets, dtype=float)[:, :2]
    if centres.ndim != 2 or len(centres) == 0:
        raise ValueError(f"targets must have shape (k, 2+), got {np.shape(targets)}")
    origin = jnp.asarray(np.asarray(origin, dtype=float))
    out = np.empty(len(px))
    for a in range(0, len(px), _CHUNK):
        chunk = px[a : a + _CHUNK]
        pad = np.pad(chunk, ((0, _CHUNK - len(chunk)), (0, 0)), mode="edge")
        out[a : a + len(chunk)] = np.asarray(
            _grey(
                jnp.asarray(pad),
                exterior,
                camera,
                dem,
                origin,
                jnp.asarray(centres),
                float(target_radius),
                bool(detail),
            )
        )[: len(chunk)]
    img = out.reshape(h, s, w, s).mean(axis=(1, 3))
    if blur > 0:
        img = gaussian_filter(img, blur, mode="nearest")
    if noise > 0:
        img = img + np.random.default_rng(seed).normal(0.0, noise, img.shape)
    return img
