"""A scanned film frame with fiducial marks, for testing the interior orientation.

:func:`fiducial_scan` paints the marks of a calibration report (film x right,
y up, mm) into a scan whose geometry is any film -> pixel mapping the caller
gives (a distorted scanner: affine, bilinear, projective, or anything else),
area-sampled (``supersample^2`` samples per pixel, averaged), blurred by a
Gaussian PSF and noised.  Each pixel's film position is found by inverting
the mapping with Newton's method (central-difference Jacobian), so the
rendering does not depend on :mod:`photax.interior`'s own inverse.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from ..interior import mark_coverage


def _invert(pixel_from_film, target: np.ndarray, start: np.ndarray, steps: int = 3) -> np.ndarray:
    """Film points ``(m, 2)`` whose image under ``pixel_from_film`` is ``target`` (Newton, numeric Jacobian)."""
    x = start.copy()
    e = 1e-4
    for _ in range(steps):
        f = pixel_from_film(x)
        jx = (pixel_from_film(x + [e, 0.0]) - pixel_from_film(x - [e, 0.0])) / (2 * e)
        jy = (pixel_from_film(x + [0.0, e]) - pixel_from_film(x - [0.0, e])) / (2 * e)
        r = target - f
        det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
        x = x + np.column_stack(
            [(jy[:, 1] * r[:, 0] - jy[:, 0] * r[:, 1]) / det, (jx[:, 0] * r[:, 1] - jx[:, 1] * r[:, 0]) / det]
        )
    return x


def fiducial_scan(
    fiducial_xy,
    pixel_from_film,
    size: tuple[int, int],
    *,
    mark: str = "cross",
    mark_size: float = 1.0,
    line_width: float = 0.2,
    background: float = 0.15,
    foreground: float = 0.85,
    blur: float = 0.7,
    noise: float = 0.01,
    seed: int = 0,
    displaced: dict | None = None,
    supersample: int = 6,
) -> tuple[np.ndarray, np.ndarray]:
    """A scan of a film frame's fiducial marks with a known film -> pixel geometry.

    Args:
        fiducial_xy: ``(n, 2)`` calibrated mark centres, film mm (x right, y up).
        pixel_from_film: vectorised ``(m, 2)`` film mm -> ``(m, 2)`` pixel
            (column, row) numpy function: the scan's true geometry.
        size: scan ``(width, height)`` px.
        mark, mark_size, line_width: the marks (:func:`photax.interior.mark_coverage`; mm).
        background, foreground: grey values of the film base and of the marks.
        blur: Gaussian PSF standard deviation, px.
        noise: standard deviation of white Gaussian noise, grey values.
        seed: seeds the noise.
        displaced: ``{mark index: (dc, dr)}``: paint that mark shifted by
            ``(dc, dr)`` px from where it belongs (a mark of the neighbouring
            frame, a wrong mark); the returned truth stays where it belongs.
        supersample: samples per pixel along each axis.

    Returns:
        ``(image (h, w) float64, truth (n, 2))``: the scan and each mark's
        true pixel position ``pixel_from_film(fiducial_xy)``.
    """
    fid = np.asarray(fiducial_xy, dtype=float)
    w, h = size
    truth = np.asarray(pixel_from_film(fid), dtype=float)
    cover = np.zeros((h, w))
    sub = (np.arange(supersample) + 0.5) / supersample - 0.5
    for i, (f, p) in enumerate(zip(fid, truth)):
        shift = np.asarray((displaced or {}).get(i, (0.0, 0.0)), dtype=float)
        centre = p + shift
        # local scale: pixels per mm at the mark, for the window's extent
        jac = (
            np.column_stack(
                [pixel_from_film(f[None] + [[1e-3, 0.0]])[0] - p, pixel_from_film(f[None] + [[0.0, 1e-3]])[0] - p]
            )
            / 1e-3
        )
        ext = int(np.ceil(1.5 * (mark_size + line_width) * np.abs(jac).max())) + 2
        c0, r0 = int(round(centre[0])) - ext, int(round(centre[1])) - ext
        cc = c0 + np.arange(2 * ext + 1)
        rr = r0 + np.arange(2 * ext + 1)
        if cc[0] < 0 or rr[0] < 0 or cc[-1] >= w or rr[-1] >= h:
            raise ValueError(f"mark {i} at pixel {centre} does not fit in the {w} x {h} scan")
        sx = (cc[:, None] + sub[None, :]).ravel()
        sy = (rr[:, None] + sub[None, :]).ravel()
        gx, gy = np.meshgrid(sx, sy)
        target = np.column_stack([gx.ravel(), gy.ravel()]) - shift
        start = f + np.linalg.solve(jac, (target - p).T).T
        film = _invert(pixel_from_film, target, start)
        on = mark_coverage(mark, film[:, 0] - f[0], film[:, 1] - f[1], mark_size, line_width)
        k = 2 * ext + 1
        cover[rr[0] : rr[-1] + 1, cc[0] : cc[-1] + 1] = on.reshape(k, supersample, k, supersample).mean(axis=(1, 3))
    img = background + (foreground - background) * cover
    if blur > 0:
        img = gaussian_filter(img, blur, mode="nearest")
    if noise > 0:
        img = img + np.random.default_rng(seed).normal(0.0, noise, img.shape)
    return img, truth
