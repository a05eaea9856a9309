"""One stereo pair from images to points: epipolar pair -> (reduced) disparity map -> points.

:func:`pair_points` is what ``photax dsm`` runs for each pair; the disparity search range comes from
the terrain's height range: a frame pair's by cutting a lattice of left epipolar rays with the planes
at the lowest and highest height and projecting them into the right epipolar image
(:func:`frame_disparity_range`), an RPC pair's from its virtual correspondences
(:attr:`~photax.matching.epipolar_affine.AffineEpipolarPair.disparity_range`).
"""

from __future__ import annotations

import math

import numpy as np

from ._points import PointCloud
from ._triangulate import disparity_to_points


def reduce(image, zoom: int) -> np.ndarray:
    """``(..., rows // zoom, cols // zoom)`` block means of ``zoom x zoom`` pixels (NaN where a block has
    any NaN: no data is not averaged into data)."""
    a = np.asarray(image, dtype=np.float64)
    if zoom == 1:
        return a
    r, c = a.shape[-2] // zoom, a.shape[-1] // zoom
    if r < 1 or c < 1:
        raise ValueError(f"an image of {a.shape[-1]} x {a.shape[-2]} px cannot be reduced {zoom} times")
    a = a[..., : r * zoom, : c * zoom].reshape(*a.shape[:-2], r, zoom, c, zoom)
    return a.mean(axis=(-3, -1))


def frame_disparity_range(pair, heights, *, n: int = 15, margin: float = 0.1) -> tuple[int, int]:
    """``(d_min, d_max)`` of a frame :class:`photax.EpipolarPair` for terrain within ``heights``: an
    ``n x n`` lattice of the left epipolar image cut with the planes at both heights, projected into
    the right epipolar image; widened by ``margin`` of its width and 2 px on each side."""
    import jax.numpy as jnp

    from ..collinearity import image_to_ground
    from ..sensor import FrameSensor

    rows, cols = np.shape(pair.left)[-2:]
    cc, rr = np.meshgrid(np.linspace(0, cols - 1, n), np.linspace(0, rows - 1, n))
    el = np.column_stack([cc.ravel(), rr.ravel()])
    pl = pair.from_epipolar("left", el)
    ok = np.all(np.isfinite(pl), axis=1)
    right = FrameSensor(pair.exterior_right, pair.camera)
    d = []
    for h in heights:
        g = np.asarray(
            image_to_ground(pair.camera.pixel_to_image(jnp.asarray(pl[ok])), pair.exterior_left, pair.camera, height=h)
        )
        pr = np.asarray(right(jnp.asarray(g)))
        er = pair.to_epipolar("right", pr)
        d.append(el[ok, 0] - er[:, 0])
    d = np.concatenate(d)
    d = d[np.isfinite(d)]
    if d.size == 0:
        raise ValueError("the pair's rays do not reach the height range: no disparity range")
    pad = margin * float(np.ptp(d)) + 2.0
    return int(math.floor(d.min() - pad)), int(math.ceil(d.max() + pad))


def _grey(image) -> np.ndarray:
    a = np.asarray(image, dtype=np.float64)
    return a.mean(axis=0) if a.ndim == 3 else a


def pair_points(
    image_left,
    image_right,
    camera,
    exterior_left=None,
    exterior_right=None,
    *,
    camera_right=None,
    heights,
    bounds=None,
    zoom: int = 1,
    crs=None,
    sigma_disparity: float = 0.3,
    matcher: dict | None = None,
    max_area: float = 16.0,
) -> tuple[PointCloud, dict]:
    """Points of one stereo pair (module docstring).

    Args:
        image_left, image_right: ``(bands, H, W)`` or ``(H, W)`` images (bands are averaged to grey
            for the matching and kept as the points' colour).
        camera, exterior_left, exterior_right, camera_right, bounds: as :func:`photax.epipolar_pair`
            (two :class:`photax.Sensor` objects in the ``camera, exterior_left`` places too).
        heights: ``(h_min, h_max)`` of the terrain (sets the disparity search range).
        zoom: match the epipolar images reduced ``zoom`` times (block means): a DSM cell of several
            pixels needs no full-resolution matching, and the search range shrinks as much.
        crs: the points' CRS (RPC: the map CRS they are transformed into).
        matcher: keyword arguments for :func:`photax.disparity` (``whole_range`` is on for a frame
            pair, off for an RPC / push-broom pair, unless given).
        max_area: a frame pair's largest epipolar image, in original image areas (convergent
            oblique views need more than :func:`photax.epipolar_pair`'s default 4).

    Returns:
        ``(PointCloud, info)``, ``info`` with ``disparity_range`` (reduced px), ``valid`` (share of the
        left epipolar image's data pixels matched) and, for an RPC pair, ``vertical_residual`` (px).
    """
    from ..matching.epipolar import EpipolarPair, epipolar_pair, sensor_arguments
    from ..matching.sgm import disparity

    camera, exterior_left, exterior_right, camera_right = sensor_arguments(
        camera, exterior_left, exterior_right, camera_right
    )

    zoom = int(zoom)
    if zoom < 1:
        raise ValueError(f"zoom must be >= 1, got {zoom}")
    images = [_grey(i).astype(np.float32) for i in (image_left, image_right)]  # one band resampled, not three
    if isinstance(camera, tuple) or camera_right is not None:
        pair = epipolar_pair(*images, camera, None, None, camera_right=camera_right, bounds=bounds, heights=heights)
    else:
        if bounds is not None:
            raise ValueError("bounds= is for RPC / push-broom pairs")
        pair = epipolar_pair(*images, camera, exterior_left, exterior_right, max_area=max_area)
    if isinstance(pair, EpipolarPair):
        d_lo, d_hi = frame_disparity_range(pair, heights)
    else:
        d_lo, d_hi = pair.disparity_range
    left, right = reduce(_grey(pair.left), zoom), reduce(_grey(pair.right), zoom)
    if left.shape[0] != right.shape[0]:  # the same rows (a frame pair's sides share them)
        m = min(left.shape[0], right.shape[0])
        left, right = left[:m], right[:m]
    lo, hi = math.floor(d_lo / zoom), math.ceil(d_hi / zoom)
    import jax

    # the matcher's first version broadcasts implicitly (rank promotion), which a caller's
    # jax_numpy_rank_promotion="raise" (the tests') refuses: allowed for this call
    with jax.numpy_rank_promotion("allow"):
        # A frame pair's epipolar images are the whole frames: where the overlap ends, a left pixel's true
        # match is outside the right image, and whole_range makes that band a hole, not wrong heights
        # (tests/test_stereo_dsm.py: 10.9 % -> 0 % of the cells off by a disparity pixel).  An RPC pair's
        # right array is cut to hold every candidate of its tile; there the rule only took away good
        # cells at the right image's edge (tests/test_stereo_synthetic.py: 99 % -> 69 % complete).
        options = {"whole_range": isinstance(pair, EpipolarPair), **(matcher or {})}
        d = disparity(left, right, disparity_range=(lo, hi), **options)
    full = np.full((np.shape(pair.left)[-2] // zoom, np.shape(pair.left)[-1] // zoom), np.nan)
    full[: d.shape[0], : d.shape[1]] = d
    colour = reduce(pair.left, zoom)
    colour = colour[None] if colour.ndim == 2 else colour
    colour = colour[:, : full.shape[0], : full.shape[1]]
    pts = disparity_to_points(pair, full, zoom=zoom, crs=crs, colour=colour, sigma_disparity=sigma_disparity * zoom)
    data = np.isfinite(left)
    info = {
        "disparity_range": (lo, hi),
        "valid": float(np.isfinite(d[data[: d.shape[0]]]).mean()) if data.any() else 0.0,
        "points": len(pts),
    }
    if not isinstance(pair, EpipolarPair):
        info["vertical_residual"] = pair.vertical_residual
    return pts, info
