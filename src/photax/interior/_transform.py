"""The film -> pixel models of an interior orientation (see :mod:`photax.interior`)."""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..camera import FrameCamera

Model = Literal["similarity", "affine", "bilinear", "projective"]

N_PARAMS = {"similarity": 4, "affine": 6, "bilinear": 8, "projective": 8}


# --------------------------------------------------------------------------- the transformation


def _cr(model: str, p, u, v, xp=jnp):
    """Pixel ``(c, r)`` from normalised film ``(u, v)`` (v down) with parameters ``p`` (module docstring)."""
    if model == "similarity":
        return p[0] + p[2] * u - p[3] * v, p[1] + p[3] * u + p[2] * v
    if model == "affine":
        return p[0] + p[1] * u + p[2] * v, p[3] + p[4] * u + p[5] * v
    if model == "bilinear":
        return p[0] + p[1] * u + p[2] * v + p[3] * u * v, p[4] + p[5] * u + p[6] * v + p[7] * u * v
    w = p[6] * u + p[7] * v + 1.0
    return (p[0] * u + p[1] * v + p[2]) / w, (p[3] * u + p[4] * v + p[5]) / w


class PixelTransform(eqx.Module):
    """Film (image plane, mm, y up) <-> scan pixels (column, row), fitted by :func:`interior_orientation`.

    Attributes:
        params: ``(k,)`` parameters on normalised film coordinates (module docstring).
        film_centre: ``(2,)`` centroid of the fiducials ``(u, v)`` used (mm, v = -y).
        film_scale: rms distance of the fiducials from it (mm).
        model: ``"similarity"``, ``"affine"``, ``"bilinear"`` or ``"projective"``.
    """

    params: Array
    film_centre: Array
    film_scale: Array
    model: str = eqx.field(static=True)

    def _norm(self, xy):
        xy = jnp.asarray(xy, dtype=float)
        u = (xy[..., 0] - self.film_centre[0]) / self.film_scale
        v = (-xy[..., 1] - self.film_centre[1]) / self.film_scale
        return u, v

    def pixel_from_film(self, xy) -> Array:
        """``(..., 2)`` film ``(x, y)`` mm -> pixel ``(column, row)``."""
        c, r = _cr(self.model, self.params, *self._norm(xy))
        return jnp.stack([c, r], axis=-1)

    def film_from_pixel(self, colrow, iterations: int = 6) -> Array:
        """``(..., 2)`` pixel ``(column, row)`` -> film ``(x, y)`` mm.

        Closed form for the similarity, affine and projective models; for the
        bilinear one Newton's method from the affine part (``iterations``
        steps: quadratic convergence, the ``u v`` term being a small correction).
        """
        colrow = jnp.asarray(colrow, dtype=float)
        c, r = colrow[..., 0], colrow[..., 1]
        p = self.params
        if self.model == "projective":
            h = jnp.array([[p[0], p[1], p[2]], [p[3], p[4], p[5]], [p[6], p[7], 1.0]])
            g = jnp.linalg.inv(h)
            w = g[2, 0] * c + g[2, 1] * r + g[2, 2]
            u = (g[0, 0] * c + g[0, 1] * r + g[0, 2]) / w
            v = (g[1, 0] * c + g[1, 1] * r + g[1, 2]) / w
        else:
            if self.model == "similarity":
                a = jnp.array([[p[2], -p[3]], [p[3], p[2]]])
                t = jnp.array([p[0], p[1]])
            else:
                k = 3 if self.model == "affine" else 4
                a = jnp.array([[p[1], p[2]], [p[k + 1], p[k + 2]]])
                t = jnp.array([p[0], p[k]])
            ai = jnp.linalg.inv(a)
            dc, dr = c - t[0], r - t[1]
            u = ai[0, 0] * dc + ai[0, 1] * dr
            v = ai[1, 0] * dc + ai[1, 1] * dr
            if self.model == "bilinear":

                def newton(_, uv):
                    u, v = uv
                    fc, fr = _cr("bilinear", p, u, v)
                    j11, j12 = p[1] + p[3] * v, p[2] + p[3] * u
                    j21, j22 = p[5] + p[7] * v, p[6] + p[7] * u
                    det = j11 * j22 - j12 * j21
                    ec, er = c - fc, r - fr
                    return u + (j22 * ec - j12 * er) / det, v + (j11 * er - j21 * ec) / det

                u, v = jax.lax.fori_loop(0, iterations, newton, (u, v))
        x = u * self.film_scale + self.film_centre[0]
        y = -(v * self.film_scale + self.film_centre[1])
        return jnp.stack([x, y], axis=-1)

    def scale(self) -> float:
        """Mean pixel size on the film (mm per pixel) at the centroid of the fiducials:
        ``|det J|^-1/2`` with ``J = d pixel / d film`` there (``u = v = 0``; numpy, no tracing)."""
        p = np.asarray(self.params)
        if self.model == "similarity":
            j = [[p[2], -p[3]], [p[3], p[2]]]
        elif self.model == "affine":
            j = [[p[1], p[2]], [p[4], p[5]]]
        elif self.model == "bilinear":
            j = [[p[1], p[2]], [p[5], p[6]]]
        else:  # d/du of (p0 u + p1 v + p2) / (p6 u + p7 v + 1) at 0
            j = [[p[0] - p[2] * p[6], p[1] - p[2] * p[7]], [p[3] - p[5] * p[6], p[4] - p[5] * p[7]]]
        return float(np.asarray(self.film_scale) / np.sqrt(abs(np.linalg.det(np.asarray(j)))))


class ScannedCamera(FrameCamera):
    """A :class:`photax.FrameCamera` (mm) whose pixels go through a fitted :class:`PixelTransform`.

    ``pixel_to_image`` is ``transform.film_from_pixel`` and ``image_to_pixel``
    ``transform.pixel_from_film``, so everything that converts pixels through
    the camera (:func:`photax.orthorectify`, ``LocateResult.image_sigma``,
    the resection's input ``camera.pixel_to_image(pixels)``) uses the
    interior orientation.  ``pixel_size`` is the transform's mean scale and
    ``image_size`` the scan's size (used for plausibility checks and sigma
    conversions only).  The bundle adjustment's self-calibration adjusts the
    camera inside the film (focal length, principal point, distortion) and
    keeps the transform (the scanner is not adjusted).  A camera file's
    ``scan`` block stores it (:mod:`photax.io.camera_file`).

    Examples:
        A scan at 50 px/mm whose film centre lies at pixel (5600, 5620): the camera's pixels go to
        the film through the fitted transformation and back, and it projects like any frame camera:

        >>> import numpy as np
        >>> import photax as ptx
        >>> film = np.array([[-106.0, -106.0], [106.0, -106.0], [106.0, 106.0], [-106.0, 106.0], [0.0, 110.0]])
        >>> io = ptx.interior_orientation(film * [50.0, -50.0] + [5600.0, 5620.0], film, "similarity")

        >>> camera = io.camera(152.0, image_size=(11200, 11240))
        >>> type(camera).__name__, round(float(np.mean(camera.pixel_size)), 9)  # mm per pixel
        ('ScannedCamera', 0.02)
        >>> print(np.round(np.asarray(camera.pixel_to_image(np.array([[5600.0, 5620.0], [5650.0, 5620.0]]))), 9) + 0.0)
        [[0. 0.]
         [1. 0.]]
        >>> back = camera.image_to_pixel(camera.pixel_to_image(np.array([[123.0, 4567.0]])))
        >>> print(np.round(np.asarray(back), 6))
        [[ 123. 4567.]]
    """

    transform: PixelTransform

    def __init__(
        self,
        focal_length,
        principal_point=(0.0, 0.0),
        distortion=None,
        *,
        transform: PixelTransform,
        image_size: tuple[int, int] | None = None,
        pixel_size=None,
    ):
        if pixel_size is None:
            pixel_size = transform.scale()
        super().__init__(focal_length, principal_point, distortion, pixel_size=pixel_size, image_size=image_size)
        self.transform = transform

    def _pixel_grid(self):
        if self.image_size is None:
            raise ValueError("this scanned camera has no image_size: give the scan's (width, height)")
        return super()._pixel_grid()

    def pixel_to_image(self, colrow) -> Array:
        """``(..., 2)`` scan pixel (column, row) -> film (x right, y up, mm)."""
        return self.transform.film_from_pixel(colrow)

    def image_to_pixel(self, xy) -> Array:
        """``(..., 2)`` film (x right, y up, mm) -> scan pixel (column, row)."""
        return self.transform.pixel_from_film(xy)


# --------------------------------------------------------------------------- the fit


def _design(model: str, p, u, v):
    """``(2n, k)`` design matrix ``d (c, r) / d p`` (rows c0, r0, c1, r1, ...)."""
    n = u.size
    one, zero = np.ones(n), np.zeros(n)
    if model == "similarity":
        dc = np.stack([one, zero, u, -v], 1)
        dr = np.stack([zero, one, v, u], 1)
    elif model == "affine":
        dc = np.stack([one, u, v, zero, zero, zero], 1)
        dr = np.stack([zero, zero, zero, one, u, v], 1)
    elif model == "bilinear":
        z4 = np.zeros((n, 4))
        dc = np.concatenate([np.stack([one, u, v, u * v], 1), z4], 1)
        dr = np.concatenate([z4, np.stack([one, u, v, u * v], 1)], 1)
    else:
        w = p[6] * u + p[7] * v + 1.0
        c = (p[0] * u + p[1] * v + p[2]) / w
        r = (p[3] * u + p[4] * v + p[5]) / w
        dc = np.stack([u / w, v / w, one / w, zero, zero, zero, -c * u / w, -c * v / w], 1)
        dr = np.stack([zero, zero, zero, u / w, v / w, one / w, -r * u / w, -r * v / w], 1)
    return np.stack([dc, dr], 1).reshape(2 * n, -1)


def _solve(model: str, u, v, obs, wgt):
    """Weighted least-squares parameters ``(k,)`` of ``model`` for ``(n, 2)`` pixels ``obs`` (weights ``1/sigma``)."""
    sw = wgt.reshape(-1)
    if model != "projective":
        a = _design(model, None, u, v) * sw[:, None]
        return np.linalg.lstsq(a, obs.reshape(-1) * sw, rcond=None)[0]
    # Start: the linear (DLT) solution, pixels normalised too; then Gauss-Newton on the pixel residuals.
    mc = obs.mean(0)
    sc = np.sqrt(np.mean(np.sum((obs - mc) ** 2, 1)))
    c, r = ((obs - mc) / sc).T
    one, zero = np.ones_like(u), np.zeros_like(u)
    rows = np.concatenate(
        [
            np.stack([u, v, one, zero, zero, zero, -c * u, -c * v, -c], 1),
            np.stack([zero, zero, zero, u, v, one, -r * u, -r * v, -r], 1),
        ]
    )
    h = np.linalg.svd(rows)[2][-1].reshape(3, 3)
    h = np.array([[sc, 0, mc[0]], [0, sc, mc[1]], [0, 0, 1]]) @ h
    p = (h / h[2, 2]).ravel()[:8]
    for _ in range(20):
        pc, pr = _cr(model, p, u, v, np)
        res = (obs - np.stack([pc, pr], 1)).reshape(-1) * sw
        dp = np.linalg.lstsq(_design(model, p, u, v) * sw[:, None], res, rcond=None)[0]
        p = p + dp
        if np.all(np.abs(dp) <= 1e-12 * (1 + np.abs(p))):
            break
    return p
