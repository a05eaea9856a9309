"""A push-broom stereo pair rendered from a known surface and texture: what the synthetic RPC stereo
tests share (``test_stereo_synthetic``: the DSM of ``photax dsm``; ``test_ties_rpc``: tie matching and
the RPC block on it).

The surface is a tilted plane with a 40 m hill over UTM metres about ``(x0, y0)``; the texture a
band-limited random field on 1 m cells, ``x0 - 600 .. x0 + 600``.  :func:`render` localizes each pixel
centre on the surface with the *rigorous* camera (a fixed point on the height) and samples the texture
there, so an image knows nothing of the RPC fitted to its camera.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from photax.sensor import WGS84, _pyproj


def surface(x, y, x0, y0):
    """Height (m, ellipsoidal) at UTM ``(x, y)``: 150 m, 5 % slope eastwards, a 40 m hill of 60 m sigma."""
    return 150.0 + 0.05 * (x - x0) + 40.0 * np.exp(-((x - x0 - 20) ** 2 + (y - y0 + 15) ** 2) / (2 * 60.0**2))


def texture(seed: int = 7) -> np.ndarray:
    """``(1200, 1200)`` grey values (mean 100, sd 40) on 1 m cells, a Gaussian-filtered (2 cells) random field."""
    rng = np.random.default_rng(seed)
    tex = ndimage.gaussian_filter(rng.random((1200, 1200)), 2.0)
    return 100 + 40 * (tex - tex.mean()) / tex.std()


def on_surface(cam, px, crs, x0, y0, *, tol: float = 1e-3, steps: int = 40):
    """Pixels ``(n, 2)`` -> ``(n, 3)`` lon, lat, h on the surface and ``(n, 2)`` UTM x, y, by the camera
    ``cam`` (rigorous or RPC: anything with ``to_ground(pixel, h)``), iterated on the height to ``tol`` m."""
    hh = np.full(len(px), 170.0)
    for _ in range(steps):
        ll = np.asarray(cam.to_ground(px, hh))
        xy = _pyproj(ll, WGS84, crs)
        new = surface(xy[:, 0], xy[:, 1], x0, y0)
        done = np.nanmax(np.abs(new - hh)) < tol
        hh = new
        if done:
            break
    return np.column_stack([ll, hh]), xy


def render(cam, crs, x0, y0, tex, size, ss: int = 1) -> np.ndarray:
    """The ``(h, w)`` image ``cam`` takes of the textured surface: ``ss x ss`` samples per pixel, the
    texture bilinear at each sample's ground point."""
    w, h = size
    o = (np.arange(ss) + 0.5) / ss - 0.5
    cc, rr = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    img = np.zeros((h, w))
    for du in o:
        for dv in o:
            px = np.column_stack([cc.ravel() + du, rr.ravel() + dv])
            _, xy = on_surface(cam, px, crs, x0, y0)
            img += ndimage.map_coordinates(tex, [600 + y0 - xy[:, 1], xy[:, 0] - x0 + 600], order=1).reshape(h, w)
    return img / ss**2
