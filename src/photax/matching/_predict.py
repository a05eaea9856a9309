"""What tie matching and GCP transfer share: predicting where a ground point
images with the approximate orientations (and where an image point meets the
DEM), the local affine map between two views predicted from the DEM
(:func:`views`, and :func:`sensor_views` for any :class:`photax.Sensor`: the same
maps through the sensors' ``on_dem`` and ``project``; :func:`offsets`,
:func:`local_affine`, :func:`warpable`), and
matching with templates warped by it (:func:`match_warped`: NCC, then LSM with
gain and offset, optionally back), so that opposite strips and rotated images
match like parallel ones and both callers share one compilation.

Used by :mod:`.ties` and :mod:`.transfer`; :func:`project_pixels` and
:func:`monoplot_pixels` are re-exported by :mod:`photax.matching`.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation, depth, image_to_ground, project, stack_exteriors
from ..dem import DEM


@eqx.filter_jit
def _project_all(ground, eo, camera):
    """``(n, 3)`` ground -> ``(m, n, 2)`` pixels in each of the ``m`` images (NaN behind the camera)."""

    def one(e):
        px = camera.image_to_pixel(project(ground, e, camera))
        return jnp.where((depth(ground, e) > 0)[:, None], px, jnp.nan)

    return jax.vmap(one)(eo)


@eqx.filter_jit
def _monoplot_all(px, eo, camera, dem):
    """``(m, n, 2)`` pixels of each image -> ``(m, n, 3)`` ground on the DEM (NaN: ray misses it)."""
    return jax.vmap(lambda p, e: image_to_ground(camera.pixel_to_image(p), e, camera, dem=dem))(px, eo)


def _bucket(n: int, base: int = 32) -> int:
    """Padded length: few distinct shapes, so few compilations."""
    b = base
    while b < n:
        b *= 2
    return b


def project_pixels(ground, exterior: ExteriorOrientation, camera: FrameCamera) -> np.ndarray:
    """``(n, 3)`` ground points into ``m`` images: ``(m, n, 2)`` pixels (column, row), NaN behind."""
    g = np.asarray(ground, dtype=float)
    n = len(g)
    pad = np.zeros((_bucket(n), 3))
    pad[:n] = np.nan_to_num(g)
    out = np.array(_project_all(jnp.asarray(pad), exterior, camera))[:, :n]
    out[:, ~np.all(np.isfinite(g), axis=1)] = np.nan
    return out


def monoplot_pixels(px, exterior: ExteriorOrientation, camera: FrameCamera, dem: DEM) -> np.ndarray:
    """``(m, n, 2)`` pixels of each image -> ``(m, n, 3)`` ground on the DEM (NaN where the ray misses)."""
    px = np.asarray(px, dtype=float)
    m, n = px.shape[:2]
    pad = np.zeros((m, _bucket(n), 2))
    pad[:, :n] = np.nan_to_num(px)
    out = np.array(_monoplot_all(jnp.asarray(pad), exterior, camera, dem))[:, :n]
    out[~np.all(np.isfinite(px), axis=2)] = np.nan
    return out


@eqx.filter_jit
def _sensor_project(sensor, ground):
    return sensor.project(ground)


def project_sensors(ground, sensors) -> np.ndarray:
    """``(n, 3)`` ground points (the sensors' CRS) into each of ``m`` sensors' images: ``(m, n, 2)``
    pixels (column, row), NaN where a sensor cannot image a point (:meth:`photax.Sensor.project`)."""
    g = np.asarray(ground, dtype=float)
    n = len(g)
    pad = np.zeros((_bucket(n), 3))
    pad[:n] = np.nan_to_num(g)
    dev = jnp.asarray(pad)
    out = np.stack([np.asarray(_sensor_project(s, dev))[:n] for s in sensors])
    out[:, ~np.all(np.isfinite(g), axis=1)] = np.nan
    return out


def monoplot_sensors(px, sensors, dem: DEM) -> np.ndarray:
    """``(m, n, 2)`` pixels of each sensor's image -> ``(m, n, 3)`` ground on the DEM in the sensors'
    CRS (the sensor's ``on_dem``: a frame's ray cut with the DEM, an RPC's or a push-broom model's
    fixed point on the height), NaN where it misses the DEM."""
    px = np.asarray(px, dtype=float)
    m, n = px.shape[:2]
    out = np.full((m, n, 3), np.nan)
    for k, s in enumerate(sensors):
        pad = np.zeros((_bucket(n), 2))
        pad[:n] = np.nan_to_num(px[k])
        out[k] = np.asarray(s.on_dem(pad, dem))[:n]
    out[~np.all(np.isfinite(px), axis=2)] = np.nan
    return out


def inside(px, size, margin: float) -> np.ndarray:
    """Whether pixels ``(..., 2)`` lie at least ``margin`` px inside an image of ``size`` ``(w, h)``
    (scalars, or arrays broadcasting with the pixels' leading axes: one size per image)."""
    w, h = size
    px = np.asarray(px)
    with np.errstate(invalid="ignore"):
        return (
            np.all(np.isfinite(px), axis=-1)
            & (px[..., 0] >= margin)
            & (px[..., 0] <= w - 1 - margin)
            & (px[..., 1] >= margin)
            & (px[..., 1] <= h - 1 - margin)
        )


def check_block(images, camera: FrameCamera, exterior) -> tuple[np.ndarray, ExteriorOrientation]:
    """Images as one ``(m, h, w)`` float64 stack matching the camera and one orientation each."""
    if not isinstance(camera, FrameCamera) or camera.image_size is None:
        raise ValueError("camera: give a FrameCamera with image_size (the images' (width, height))")
    imgs = [np.asarray(im, dtype=float) for im in images]
    w, h = camera.image_size
    for k, im in enumerate(imgs):
        if im.shape != (h, w):
            raise ValueError(f"images[{k}]: shape {im.shape}, but camera.image_size is (w, h) = {(w, h)}")
    eo = stack_exteriors(exterior)
    if eo.position.shape[0] != len(imgs):
        raise ValueError(f"exterior: {eo.position.shape[0]} orientations for {len(imgs)} images")
    if not (np.all(np.isfinite(np.asarray(eo.position))) and np.all(np.isfinite(np.asarray(eo.angles)))):
        raise ValueError("exterior: approximate orientations must be finite (resect or initialise first)")
    return np.stack(imgs), eo


def padded(stack, pad: int) -> np.ndarray:
    """Images framed by ``pad`` px of zeros, so a search window near the border stays inside the array
    (a zero frame has no texture: windows reaching into it correlate badly and are rejected)."""
    return np.pad(stack, ((0, 0), (pad, pad), (pad, pad)))


def match_sigma(cov) -> np.ndarray:
    """``(n,)`` one sigma per matched point from ``(n, 2, 2)`` shift covariances, px."""
    cov = np.asarray(cov)
    return np.sqrt((cov[..., 0, 0] + cov[..., 1, 1]) / 2)


@dataclasses.dataclass(frozen=True)
class WarpMatches:
    """:func:`match_warped`'s output, ``(c, 1, ...)`` numpy arrays (``xy`` in the padded stack's pixels)."""

    ncc_valid: np.ndarray
    rho: np.ndarray
    lsm_valid: np.ndarray
    lsm_xy: np.ndarray
    lsm_cov: np.ndarray
    back_valid: np.ndarray | None
    back_xy: np.ndarray | None


# --------------------------------------------------------------------------- warped matching

STEP = 4.0  # px: half the baseline of the finite differences of the local affine map


def offsets(px, step: float = STEP) -> np.ndarray:
    """``(m, n, 2)`` pixels and their four neighbours ``+-step`` along column and row: ``(m, 5 n, 2)``
    (the points first), to monoplot and project in one call; :func:`local_affine` reads them back."""
    px = np.asarray(px, dtype=float)
    d = np.array([[step, 0.0], [-step, 0.0], [0.0, step], [0.0, -step]])
    return np.concatenate([px] + [px + e for e in d], axis=1)


def local_affine(pred, n: int, step: float = STEP) -> np.ndarray:
    """The local affine map (Jacobian) from an image's pixel offsets to another's, ``(..., n, 2, 2)``.

    ``pred (..., 5 n, 2)`` are the projections of the points of :func:`offsets` (monoplotted on the
    DEM from the first image, projected into the second): ``A[:, k] = (p(+step e_k) - p(-step e_k)) /
    (2 step)``, so ``offset in the second image ~ A @ offset in the first``; it holds the rotation
    (kappa), scale and shear between the two views and the terrain's slope.  NaN where a neighbour
    misses the DEM or falls behind the camera."""
    p = [pred[..., k * n : (k + 1) * n, :] for k in range(1, 5)]
    return np.stack([(p[0] - p[1]) / (2 * step), (p[2] - p[3]) / (2 * step)], axis=-1)


def views(px, eo: ExteriorOrientation, camera: FrameCamera, dem: DEM, *, step: float = STEP, extra=None):
    """Where the points ``px (m, n, 2)`` of each image meet the DEM, where they image in every image,
    and the local affine maps between the views, in one monoplot and one projection call
    (:func:`sensor_views` with the batched frame functions).

    Returns ``ground (m, n, 3)``, ``pred (m, m, n, 2)`` (``[j, i, p]``: point ``p`` of image ``i``
    in image ``j``), ``affine (m, m, n, 2, 2)`` (``[j, i, p]`` maps pixel offsets in ``i`` to
    offsets in ``j``, :func:`local_affine` with neighbours ``step`` px away) and the projections
    ``(m, m, q, 2)`` of ``extra (m, q, 2)`` pixels monoplotted alike (None without ``extra``).
    NaN points (unused slots) stay NaN."""
    return _views(
        px, lambda p: monoplot_pixels(p, eo, camera, dem), lambda g: project_pixels(g, eo, camera), step, extra
    )


def sensor_views(px, sensors, dem: DEM, *, step: float = STEP, extra=None):
    """:func:`views` for ``m`` sensors (:class:`photax.Sensor`: frames, RPCs, push-broom models alike):
    the points monoplotted by each sensor's ``on_dem`` and projected by every sensor's ``project``."""
    return _views(px, lambda p: monoplot_sensors(p, sensors, dem), lambda g: project_sensors(g, sensors), step, extra)


def _views(px, monoplot, project, step, extra):
    px = np.asarray(px, dtype=float)
    n = px.shape[1]
    allpx = offsets(px, step) if extra is None else np.concatenate([offsets(px, step), extra], axis=1)
    ground = monoplot(allpx)
    proj = project(ground.reshape(-1, 3)).reshape(len(px), len(px), -1, 2)
    affine = local_affine(proj[:, :, : 5 * n], n, step)
    return ground[:, :n], proj[:, :, :n], affine, None if extra is None else proj[:, :, 5 * n :]


def warpable(affine, max_scale: float = 2.0) -> np.ndarray:
    """Whether each affine map ``(..., 2, 2)`` is finite and scales by at most ``max_scale`` either
    way (beyond, the warped template would need an image pyramid)."""
    with np.errstate(invalid="ignore"):
        sv = np.linalg.svd(np.nan_to_num(affine, nan=1e9), compute_uv=False)
        return np.all(np.isfinite(affine), axis=(-2, -1)) & (sv[..., 0] <= max_scale) & (sv[..., 1] >= 1 / max_scale)


def frame_pad(window: int, search: int) -> int:
    """The frame of zeros (:func:`padded`) that :func:`match_warped` needs around images whose points
    and predictions lie inside them: its search crops and warped templates stay in the array."""
    return 2 * (window + search) + 8


WARP_BATCH = 128  # candidates per compiled call of match_warped: one shape, one compilation
# LSM from the NCC peak converges in a few steps; under vmap a batch runs as long as its slowest
# point, so a point still moving after 10 steps (it is rejected) must not hold 127 others for 30
LSM_ITERATIONS, LSM_TOL = 10, 1e-2


def _keys(t):
    """Keys' cubic convolution weights (a = -0.5), as :func:`photax.resample`'s ``"cubic"``."""
    t = jnp.abs(t)
    near = (1.5 * t - 2.5) * t * t + 1
    far = ((-0.5 * t + 2.5) * t - 4.0) * t + 2.0
    return jnp.where(t <= 1, near, jnp.where(t < 2, far, 0.0))


@jax.jit
def _sample(big, img, xy, grid):
    """Cubic samples ``(c, k, k)`` of ``big[img]`` at ``xy + grid`` (``img (c,)``, ``xy (c, 2)``,
    ``grid (c, k, k, 2)``), read straight from the padded stack (the points stay 2 px inside it)."""
    x = xy[:, None, None, 0] + grid[..., 0]
    y = xy[:, None, None, 1] + grid[..., 1]
    x0, y0 = jnp.floor(x), jnp.floor(y)
    k = jnp.arange(-1, 3, dtype=jnp.int32).reshape(1, 1, 1, 4)
    kf = k.astype(x.dtype)
    wx, wy = _keys(x[..., None] - x0[..., None] - kf), _keys(y[..., None] - y0[..., None] - kf)
    ix = jnp.clip(x0.astype(jnp.int32)[..., None] + k, 0, big.shape[2] - 1)
    iy = jnp.clip(y0.astype(jnp.int32)[..., None] + k, 0, big.shape[1] - 1)
    vals = big[jnp.asarray(img).reshape(-1, 1, 1, 1, 1), iy[..., :, None], ix[..., None, :]]
    return jnp.einsum("...i,...ij,...j->...", wy, vals, wx)


def _crop(big, img, xy, half: int):
    """Integer crops ``(c, 2 half + 1, 2 half + 1)`` of ``big[img]`` around ``round(xy)`` and their origins."""
    c0 = np.round(xy).astype(int) - half
    k = np.arange(2 * half + 1)
    rows = c0[:, 1, None, None] + k[None, :, None]
    cols = c0[:, 0, None, None] + k[None, None, :]
    return big[img[:, None, None], rows, cols], c0.astype(float)


def match_warped(
    big, ti, txy, si, sxy, affine, *, window: int, search: int, back: bool, margin: int = 5
) -> WarpMatches:
    """NCC then LSM (and LSM back) of templates warped by the predicted affine map, one point per row.

    ``big`` is a padded stack (:func:`padded`); row ``k`` matches the window of ``big[ti[k]]`` around
    ``txy[k]`` into ``big[si[k]]`` around ``sxy[k]``, where ``affine[k]`` ``(2, 2)`` maps offsets in the
    first image to offsets in the second.  The template is resampled (cubic) in the search image's
    geometry, ``T(u) = I_t(txy + affine^-1 u)``, so NCC and LSM work on the search image's own
    pixels, whatever the rotation, scale or shear between the views; LSM's affine and radiometric
    parameters then take up what the prediction missed.  The back match resamples the matched
    window of the search image in the first image's geometry, ``I_s(xy + affine u)``, and matches it
    into the first image.  Results are ``(c, 1, ...)`` arrays in ``big``'s pixels, as
    :class:`WarpMatches`; rows are matched in calls of :data:`WARP_BATCH` (padded), so every call
    with one ``window`` / ``search`` shares one compilation of :func:`photax.measure.match_ncc` and
    :func:`photax.measure.match_lsm`.
    """
    from ..measure import match_lsm, match_ncc

    ti, si = np.asarray(ti, dtype=int), np.asarray(si, dtype=int)
    txy, sxy, affine = (np.asarray(a, dtype=float) for a in (txy, sxy, affine))
    dev = jnp.asarray(big)
    ht = window + 2  # the template window and the 2 px that match_ncc / match_lsm read around it
    g = np.arange(-ht, ht + 1, dtype=float)
    grid = np.stack(np.meshgrid(g, g), axis=-1)  # (k, k, 2): (u, v) offsets, [row, col]
    fwd_half = window + search + margin + 3  # search crop: NCC's reach, then LSM's patch around its peak
    back_half = window + margin + 3
    centre = np.full((1, 2), float(ht))
    c = len(ti)
    pad = -c % WARP_BATCH
    rep = lambda a: np.concatenate([a, np.repeat(a[:1], pad, 0)]) if pad else a  # noqa: E731
    ti, si, txy, sxy, affine = (rep(a) for a in (ti, si, txy, sxy, affine))
    inv = np.linalg.inv(affine)
    keys = ("ncc_valid", "rho", "lsm_valid", "lsm_xy", "lsm_cov", "back_valid", "back_xy")
    out: dict[str, list] = {k: [] for k in keys}
    cen = np.broadcast_to(centre, (WARP_BATCH, 1, 2))
    for a in range(0, len(ti), WARP_BATCH):
        b = slice(a, a + WARP_BATCH)
        tw = _sample(dev, ti[b], txy[b], grid @ np.swapaxes(inv[b], 1, 2)[:, None])
        sc, s0 = _crop(big, si[b], sxy[b], fwd_half)
        T, S = jnp.asarray(tw), jnp.asarray(sc)
        ncc, rho = match_ncc(T, cen, S, (sxy[b] - s0)[:, None], window=window, search=search, return_rho=True)
        nxy = np.where(np.asarray(ncc.valid)[..., None], np.asarray(ncc.xy), (sxy[b] - s0)[:, None])
        fwd = match_lsm(T, cen, S, nxy, window=window, margin=margin, iterations=LSM_ITERATIONS, tol=LSM_TOL)
        fxy = np.asarray(fwd.xy) + s0[:, None]
        out["ncc_valid"].append(np.asarray(ncc.valid))
        out["rho"].append(np.asarray(rho))
        out["lsm_valid"].append(np.asarray(fwd.valid))
        out["lsm_xy"].append(fxy)
        out["lsm_cov"].append(np.asarray(fwd.covariance))
        if back:
            start = np.where(np.asarray(fwd.valid)[:, 0, None], fxy[:, 0], sxy[b])
            bw = _sample(dev, si[b], start, grid @ np.swapaxes(affine[b], 1, 2)[:, None])
            tc, t0 = _crop(big, ti[b], txy[b], back_half)
            bk = match_lsm(
                jnp.asarray(bw),
                cen,
                jnp.asarray(tc),
                (txy[b] - t0)[:, None],
                window=window,
                margin=margin,
                iterations=LSM_ITERATIONS,
                tol=LSM_TOL,
            )
            out["back_valid"].append(np.asarray(bk.valid))
            out["back_xy"].append(np.asarray(bk.xy) + t0[:, None])
    cat = {k: np.concatenate(v)[:c] if v else None for k, v in out.items()}
    return WarpMatches(**cat)
