"""Triangulation: corresponding pixels of two images, and disparity maps of epipolar pairs, to 3-D.

* Frame cameras: the two lines of sight (collinearity, the pixel through the camera's distortion)
  cut in the least-squares sense: the midpoint of their common perpendicular (Hartley & Sturm 1997's
  "midpoint method"; Kraus 2007 sec. 4.3).
* Ground cameras (:class:`photax.RPCCamera`, :class:`photax.PushbroomCamera`): lines of sight are
  not straight in lon, lat, h; the point ``(lon, lat, h)`` minimising the four reprojection errors is
  found by Gauss--Newton on east, north, up metres about the left pixel localized at the middle
  height (the Jacobian by ``jax.jacfwd``; six steps: the problem is nearly linear).

Each point carries its *intersection residual* (RMS of its four reprojection errors, px) and a
*height sigma* ``sigma_z = |dZ / dd| sigma_d``: how far the height moves for a disparity error of
``sigma_d`` (default 0.3 px), by central differences of the triangulation along the epipolar line.
"""

from __future__ import annotations

import numpy as np

from ._points import PointCloud

SIGMA_DISPARITY = 0.3  # px: the default standard deviation of a matched disparity
_R_EARTH = 6_378_137.0
_GN_STEPS = 6


def _frame_rays(camera, exterior, pixel):
    import jax.numpy as jnp

    d = np.asarray(camera.ray(camera.pixel_to_image(jnp.asarray(pixel, dtype=float))), dtype=float)
    d = d @ np.asarray(exterior.rotation, dtype=float).T
    return np.asarray(exterior.position, dtype=float), d / np.linalg.norm(d, axis=1, keepdims=True)


def _midpoint(c1, d1, c2, d2):
    """Midpoints of the common perpendiculars of lines ``c1 + s d1`` and ``c2 + t d2`` (unit ``d``)."""
    w = c1 - c2
    b = np.sum(d1 * d2, axis=1)
    d, e = np.sum(d1 * w, axis=1), np.sum(d2 * w, axis=1)
    den = 1.0 - b**2
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (b * e - d) / den
        t = (e - b * d) / den
    p = 0.5 * ((c1 + s[:, None] * d1) + (c2 + t[:, None] * d2))
    ahead = (s > 0) & (t > 0) & (den > 1e-12)
    p[~ahead] = np.nan
    return p


def _frame_sensor(camera, exterior):
    from ..sensor import FrameSensor

    return FrameSensor(exterior, camera)


def _reprojection_rms(sensors, pixels, points) -> np.ndarray:
    import jax.numpy as jnp

    err = [np.asarray(s(jnp.asarray(points)), dtype=float) - p for s, p in zip(sensors, pixels)]
    return np.sqrt(np.mean(np.concatenate(err, axis=1) ** 2, axis=1))


def _gauss_newton(camera_left, camera_right, pixel_left, pixel_right, start):
    """``(n, 3)`` lon, lat, h minimising the reprojection errors, from ``start``; compiled once."""
    return np.asarray(_gn(camera_left, camera_right, pixel_left, pixel_right, start), dtype=float)


def _gn_impl(camera_left, camera_right, pl, pr, start):
    import jax
    import jax.numpy as jnp

    def one(p_l, p_r, x0):
        lat = jnp.radians(x0[1])
        to_deg = jnp.array([1.0 / (_R_EARTH * jnp.cos(lat)), 1.0 / _R_EARTH, 1.0])
        scale = jnp.array([jnp.degrees(to_deg[0]), jnp.degrees(to_deg[1]), 1.0])

        def res(m):  # m: east, north, up metres from x0
            x = x0 + m * scale
            return jnp.concatenate([camera_left(x) - p_l, camera_right(x) - p_r])

        def step(m, _):
            r = res(m)
            j = jax.jacfwd(res)(m)
            dm = jnp.linalg.solve(j.T @ j, -j.T @ r)
            return m + dm, None

        m, _ = jax.lax.scan(step, jnp.zeros(3), None, length=_GN_STEPS)
        return x0 + m * scale

    return jax.vmap(one)(pl, pr, start)


_gn_jit = None


def _gn(camera_left, camera_right, pl, pr, start):
    global _gn_jit
    import jax.numpy as jnp

    from .._pytree import filter_jit

    if _gn_jit is None:
        _gn_jit = filter_jit(_gn_impl)
    n = len(pl)
    m = max(256, 1 << max(n - 1, 1).bit_length())  # a power of two: a few compilations for all sizes
    pad = lambda a: np.concatenate([a, np.repeat(a[:1], m - n, axis=0)])  # noqa: E731
    out = _gn_jit(camera_left, camera_right, jnp.asarray(pad(pl)), jnp.asarray(pad(pr)), jnp.asarray(pad(start)))
    return np.asarray(out)[:n]


def triangulate_pair(
    camera_left,
    camera_right,
    pixel_left,
    pixel_right,
    *,
    exterior_left=None,
    exterior_right=None,
    heights=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Intersect corresponding pixels of two images (module docstring).

    Args:
        camera_left, camera_right: two :class:`photax.FrameCamera` (with ``exterior_left`` and
            ``exterior_right``), or two ground cameras (RPC, push-broom; no exteriors).
        pixel_left, pixel_right: ``(n, 2)`` corresponding original pixels (column, row).
        heights: ground cameras: ``(h_min, h_max)``, the start's height is their middle
            (default the left RPC's height offset).

    Returns:
        ``(points (n, 3), residual (n,))``: frame: ground ``(X, Y, Z)`` of the orientations' CRS;
        ground cameras: lon, lat (deg), ellipsoidal h (m).  ``residual``: the RMS of the four
        reprojection errors (px).  NaN where the rays do not meet in front of both cameras (frame)
        or the start does not localize (ground).
    """
    from ..camera import FrameCamera

    pl = np.asarray(pixel_left, dtype=float)
    pr = np.asarray(pixel_right, dtype=float)
    if pl.ndim != 2 or pl.shape[1] != 2 or pl.shape != pr.shape:
        raise ValueError(f"pixel_left and pixel_right must both have shape (n, 2), got {pl.shape}, {pr.shape}")
    frame = [isinstance(c, FrameCamera) for c in (camera_left, camera_right)]
    if any(frame):
        if not all(frame) or exterior_left is None or exterior_right is None:
            raise ValueError("frame cameras: both cameras FrameCamera, with exterior_left and exterior_right")
        c1, d1 = _frame_rays(camera_left, exterior_left, pl)
        c2, d2 = _frame_rays(camera_right, exterior_right, pr)
        pts = _midpoint(np.broadcast_to(c1, d1.shape), d1, np.broadcast_to(c2, d2.shape), d2)
        sensors = (_frame_sensor(camera_left, exterior_left), _frame_sensor(camera_right, exterior_right))
        return pts, _reprojection_rms(sensors, (pl, pr), pts)
    from ..sensor import GroundCamera

    for name, c in (("camera_left", camera_left), ("camera_right", camera_right)):
        if not isinstance(c, GroundCamera):
            raise ValueError(f"{name} must be a FrameCamera, RPCCamera or PushbroomCamera, got {type(c).__name__}")
    if exterior_left is not None or exterior_right is not None:
        raise ValueError("RPC and push-broom cameras carry their own orientation: pass no exteriors")
    from ..matching.epipolar_affine import localize

    if heights is None:
        rng = getattr(camera_left, "height_range", None)
        if rng is None:
            raise ValueError("heights=(h_min, h_max) is required for a push-broom camera")
        heights = rng
    h_mid = 0.5 * (float(heights[0]) + float(heights[1]))
    out = np.full((len(pl), 3), np.nan)
    res = np.full(len(pl), np.nan)
    if len(pl) == 0:
        return out, res
    start = localize(camera_left, pl, h_mid)
    ok = np.all(np.isfinite(start), axis=1) & np.all(np.isfinite(pl), axis=1) & np.all(np.isfinite(pr), axis=1)
    if ok.any():
        pts = _gauss_newton(camera_left, camera_right, pl[ok], pr[ok], start[ok])
        out[ok] = pts
        res[ok] = _reprojection_rms((camera_left, camera_right), (pl[ok], pr[ok]), pts)
    return out, res


def _to_map(llh, crs):
    """``(n, 3)`` lon, lat, h -> ``(n, 3)`` X, Y of ``crs`` (pyproj), h."""
    import pyproj

    t = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    x, y = t.transform(llh[:, 0], llh[:, 1], errcheck=False)
    xy = np.column_stack([np.asarray(x, dtype=float), np.asarray(y, dtype=float)])
    xy[~np.isfinite(xy).all(axis=1)] = np.nan
    return np.column_stack([xy, llh[:, 2]])


def default_crs(pair):
    """The map CRS of a ground-camera pair's points: the UTM zone of the left camera's scene centre."""
    from ..sensor import utm_crs

    return utm_crs(*np.asarray(pair.camera_left.ground_box()[0], dtype=float))


def _matches(pair, disparity, step, zoom):
    d = np.asarray(disparity, dtype=float)
    shape = np.shape(pair.left)[-2:]
    want = (shape[0] // zoom, shape[1] // zoom)
    if d.shape != want:
        raise ValueError(
            f"disparity has shape {d.shape}, the left epipolar image {shape}"
            + (f" reduced {zoom} times: {want}" if zoom > 1 else "")
        )
    rows, cols = np.mgrid[0 : d.shape[0] : step, 0 : d.shape[1] : step]
    dd = d[rows, cols]
    ok = np.isfinite(dd)
    # a reduced pixel is the mean of zoom x zoom full pixels: its centre is at (c + 0.5) zoom - 0.5
    left = (np.column_stack([cols[ok], rows[ok]]).astype(float) + 0.5) * zoom - 0.5
    return left, dd[ok] * zoom, (rows[ok], cols[ok])


def disparity_to_points(
    pair,
    disparity,
    *,
    sigma_disparity: float = SIGMA_DISPARITY,
    colour=None,
    crs=None,
    step: int = 1,
    zoom: int = 1,
    max_residual: float | None = 1.0,
) -> PointCloud:
    """The points of a disparity map of an epipolar pair (``d = col_left - col_right``, NaN invalid).

    Args:
        pair: a :class:`photax.EpipolarPair` (frame) or an
            :class:`~photax.matching.epipolar_affine.AffineEpipolarPair` (RPC, push-broom)
            whose left epipolar image the disparity map covers.
        disparity: ``(rows, cols)`` of the left epipolar image.
        sigma_disparity: the disparity's standard deviation (px) for ``sigma_z``.
        colour: ``(rows, cols)`` or ``(3, rows, cols)`` grey values for the points (default the left
            epipolar image, scaled to 0..255), or False for none.
        crs: ground cameras: the points' map CRS (default the UTM zone of the scene); frame: the
            orientations' CRS, recorded as it is.
        step: every ``step``-th row and column.
        zoom: the disparity map is of the epipolar pair reduced ``zoom`` times (block means:
            :func:`reduce`): its pixel ``(c, r)`` is the full array's ``((c + 0.5) zoom - 0.5, ...)`` and
            its disparities are in reduced pixels; ``colour`` then defaults to none.
        max_residual: points with a larger intersection residual (px) are dropped (None: keep all).

    Returns:
        :class:`PointCloud`.
    """
    from ..matching.epipolar import EpipolarPair
    from ..matching.epipolar_affine import AffineEpipolarPair

    if not sigma_disparity > 0:
        raise ValueError(f"sigma_disparity must be > 0, got {sigma_disparity}")
    if int(step) < 1 or int(zoom) < 1:
        raise ValueError(f"step and zoom must be >= 1, got {step}, {zoom}")
    if colour is None and int(zoom) > 1:
        colour = False
    left, d, (ri, ci) = _matches(pair, disparity, int(step), int(zoom))
    xyz, residual, zs = _triangulate_epipolar(pair, left, d, sigma_disparity, crs)
    keep = np.all(np.isfinite(xyz), axis=1)
    if max_residual is not None:
        keep &= residual <= max_residual
    col = None
    if colour is not False:
        src = np.asarray(pair.left if colour is None else colour, dtype=float)
        src = src[None] if src.ndim == 2 else src
        if src.shape[-2:] != np.shape(disparity):
            raise ValueError(f"colour has shape {src.shape}, the disparity map {np.shape(disparity)}")
        vals = src[:, ri, ci].T
        if vals.shape[1] == 1:
            vals = np.repeat(vals, 3, axis=1)
        vals = vals[:, :3]
        fin = vals[np.isfinite(vals)]
        lo, hi = (float(np.min(fin)), float(np.max(fin))) if fin.size else (0.0, 1.0)
        if hi <= 255 and lo >= 0 and hi > 1:
            lo, hi = 0.0, 255.0
        col = np.clip(np.nan_to_num((vals - lo) / max(hi - lo, 1e-12) * 255.0), 0, 255).round()
    if not isinstance(pair, (EpipolarPair, AffineEpipolarPair)):
        raise ValueError(f"pair must be an EpipolarPair or an AffineEpipolarPair, got {type(pair).__name__}")
    out_crs = crs if crs is not None or isinstance(pair, EpipolarPair) else default_crs(pair)
    return PointCloud(xyz[keep], residual[keep], zs[keep], None if col is None else col[keep], out_crs)


def _triangulate_epipolar(pair, left, d, sigma_d, crs):
    """``(xyz, residual, sigma_z)`` of epipolar left pixels and their disparities."""
    from ..matching.epipolar import EpipolarPair

    def right_of(dd):
        return np.column_stack([left[:, 0] - dd, left[:, 1]])

    if isinstance(pair, EpipolarPair):
        xyz = pair.ground(left, right_of(d))
        lo, hi = pair.ground(left, right_of(d - 0.5)), pair.ground(left, right_of(d + 0.5))
        sz = np.abs(hi[:, 2] - lo[:, 2]) * sigma_d
        pl, pr = pair.from_epipolar("left", left), pair.from_epipolar("right", right_of(d))
        ok = np.all(np.isfinite(xyz), axis=1)
        res = np.full(len(left), np.nan)
        if ok.any():
            sensors = (
                _frame_sensor(pair.camera, pair.exterior_left),
                _frame_sensor(pair.camera, pair.exterior_right),
            )
            res[ok] = _reprojection_rms(sensors, (pl[ok], pr[ok]), xyz[ok])
        return xyz, res, sz
    if crs is None:
        crs = default_crs(pair)
    pl = pair.from_epipolar("left", left)
    cams = (pair.camera_left, pair.camera_right)
    llh, res = triangulate_pair(*cams, pl, pair.from_epipolar("right", right_of(d)), heights=pair.heights)
    sz = np.full(len(left), height_per_disparity(pair) * sigma_d)
    return _to_map(llh, crs), res, sz


def height_per_disparity(pair) -> float:
    """``|dh / dd|`` (m per px) of a ground-camera pair over its tile: the pair is affine there, so the
    least-squares plane ``h = h0 + a u + b v + c d`` through its virtual correspondences (the left
    tile's lattice at several heights, epipolar ``u, v`` and disparity ``d``) gives ``|c|``."""
    from ..matching.epipolar_affine import virtual_matches

    left, right, h = virtual_matches(pair.camera_left, pair.camera_right, pair.bounds, pair.heights, 7, 5)
    ul, ur = pair.to_epipolar("left", left), pair.to_epipolar("right", right)
    design = np.column_stack([np.ones(len(h)), ul, ul[:, 0] - ur[:, 0]])
    return float(abs(np.linalg.lstsq(design, h, rcond=None)[0][3]))
