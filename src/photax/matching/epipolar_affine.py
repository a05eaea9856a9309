"""Epipolar pairs of two ground cameras (RPC, push-broom): the local affine rectification of s2p.

A satellite's lines of sight are nearly parallel over a tile, so the pair behaves like two affine
cameras there (de Franchis et al. 2014, "On stereo-rectification of pushbroom images", ICIP; s2p's
``rectification.py``).  *Virtual correspondences* give the geometry without any matching: a
``grid x grid`` lattice of the left tile is localized at ``layers`` heights over the tile's height
range (:meth:`~photax.rpc.RPCCamera.to_ground`) and projected into the right image.  They fit the
affine fundamental matrix (Hartley & Zisserman 2003, sec. 14.2; linear, by SVD on centred and
scaled points)::

    a x_r + b y_r + c x_l + d y_l + e = 0

(x = column, y = row, original pixels).  Two similarities make the rows epipolar lines: with
``r = |(c, d)|``, ``s = |(a, b)|``, ``k = sqrt(r s)``::

    left:   (u, v)_l = ((d x_l - c y_l) / k,  (c x_l + d y_l + e / 2) / k)
    right:  (u, v)_r = ((a y_r - b x_r) / k, -(a x_r + b y_r + e / 2) / k)

so ``v_l - v_r`` is the constraint divided by ``k``: zero for a true correspondence.  Both are
turned by 180 degrees when the left one would otherwise turn the image by more than 90 (the pair
stays upright), and translated so that each epipolar array starts at 0; the right array is given
the columns the left tile's points can reach over the height range.

What the affine model leaves over the tile is measured on the virtual correspondences (and on a
check lattice between them) and reported as :attr:`AffineEpipolarPair.vertical_residual` (the
largest ``|v_l - v_r|``, px).  Disparities ``d = col_left - col_right`` of the two arrays: the range
the heights allow is :attr:`AffineEpipolarPair.disparity_range`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..resampling import Resampling, resample

_MIN_GRID = 3  # virtual correspondences per axis, at least
_MIN_LAYERS = 2


def localize(camera, pixel, h) -> np.ndarray:
    """``(n, 2)`` pixels at ``(n,)`` ellipsoidal heights -> ``(n, 3)`` lon, lat, h of a ground camera
    (NaN where its inverse does not converge)."""
    import jax.numpy as jnp

    pixel = np.asarray(pixel, dtype=float).reshape(-1, 2)
    h = np.broadcast_to(np.asarray(h, dtype=float), (len(pixel),))
    ll = np.asarray(camera.to_ground(jnp.asarray(pixel), jnp.asarray(h)), dtype=float)
    return np.column_stack([ll, h])


def project(camera, llh) -> np.ndarray:
    """``(n, 3)`` lon, lat, h -> ``(n, 2)`` pixels of a ground camera."""
    import jax.numpy as jnp

    return np.asarray(camera(jnp.asarray(np.asarray(llh, dtype=float))), dtype=float)


def virtual_matches(camera_left, camera_right, bounds, heights, grid: int = 9, layers: int = 5):
    """``(left (n, 2), right (n, 2), h (n,))``: a ``grid x grid`` lattice of the left tile ``bounds``
    ``(col0, row0, col1, row1)`` at ``layers`` heights, localized by the left camera and projected
    by the right one (points that fail either are dropped)."""
    c0, r0, c1, r1 = bounds
    cc, rr, hh = np.meshgrid(np.linspace(c0, c1, grid), np.linspace(r0, r1, grid), np.linspace(*heights, layers))
    left = np.column_stack([cc.ravel(), rr.ravel()])
    llh = localize(camera_left, left, hh.ravel())
    right = project(camera_right, llh)
    ok = np.all(np.isfinite(right), axis=1) & np.all(np.isfinite(llh), axis=1)
    return left[ok], right[ok], hh.ravel()[ok]


def affine_fundamental(left, right) -> np.ndarray:
    """``(5,)`` ``(a, b, c, d, e)`` of ``a x_r + b y_r + c x_l + d y_l + e = 0`` fitted to ``(n, 2)``
    correspondences (the smallest right singular vector of the centred, scaled ``[x_r y_r x_l y_l]``)."""
    m = np.column_stack([right, left]).astype(float)
    mean = m.mean(axis=0)
    scale = np.sqrt(np.mean(np.sum((m - mean) ** 2, axis=1))) or 1.0
    n = np.linalg.svd((m - mean) / scale, full_matrices=False)[2][-1]  # normalised coefficients
    return np.concatenate([n, [-float(n @ mean)]])  # n . (p - mean) / scale = 0, times scale


def rectifying_affinities(f) -> tuple[np.ndarray, np.ndarray]:
    """``(H_left, H_right)``: the two ``(3, 3)`` similarities (module docstring) of an affine fundamental
    matrix's ``(a, b, c, d, e)``: the rows of both are its epipolar lines, same row, same scale ratio."""
    a, b, c, d, e = (float(v) for v in f)
    r, s = np.hypot(c, d), np.hypot(a, b)
    if not (r > 0 and s > 0):
        raise ValueError("the virtual correspondences define no epipolar direction (degenerate stereo geometry)")
    k = np.sqrt(r * s)
    hl = np.array([[d, -c, 0.0], [c, d, e / 2], [0.0, 0.0, k]]) / k
    hr = np.array([[-b, a, 0.0], [-a, -b, -e / 2], [0.0, 0.0, k]]) / k
    if hl[0, 0] < 0:  # the left image would turn by more than 90 degrees: turn both by 180
        flip = np.diag([-1.0, -1.0, 1.0])
        hl, hr = flip @ hl, flip @ hr
    return hl, hr


def _apply(h, xy) -> np.ndarray:
    xy = np.asarray(xy, dtype=float)
    return xy @ h[:2, :2].T + h[:2, 2]


def _translate(h, du, dv) -> np.ndarray:
    t = np.eye(3)
    t[0, 2], t[1, 2] = du, dv
    return t @ h


@dataclasses.dataclass(frozen=True)
class AffineEpipolarPair:
    """Two ground-camera images (RPC, push-broom) rectified over a tile of the left one
    (module docstring).

    Attributes:
        left, right: the epipolar arrays ``(..., rows, cols)`` (NaN, or 0 for integer images,
            outside the originals).
        homography_left, homography_right: ``(3, 3)`` affine maps original pixel (column, row, 1)
            -> epipolar array pixel of each side.
        camera_left, camera_right: the two ground cameras (lon, lat, ellipsoidal h -> pixel).
        bounds: the left tile ``(col0, row0, col1, row1)`` (original left pixels).
        heights: ``(h_min, h_max)`` the tile's height range (m, ellipsoidal).
        disparity_range: ``(d_min, d_max)`` of ``col_left - col_right`` in the arrays over ``heights``
            (whole pixels, widened by ``margin``).
        vertical_residual: the largest ``|row_left - row_right|`` of the virtual correspondences and
            the check lattice between them (px): what the affine model leaves over the tile.
        vertical_rms: their RMS (px).
    """

    left: np.ndarray
    right: np.ndarray
    homography_left: np.ndarray
    homography_right: np.ndarray
    camera_left: object
    camera_right: object
    bounds: tuple[float, float, float, float]
    heights: tuple[float, float]
    disparity_range: tuple[int, int]
    vertical_residual: float
    vertical_rms: float

    def _h(self, side: str) -> np.ndarray:
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        return self.homography_left if side == "left" else self.homography_right

    def to_epipolar(self, side: str, xy) -> np.ndarray:
        """``(n, 2)`` original pixels (column, row) of ``side`` -> its epipolar array's pixels."""
        return _apply(self._h(side), _points(xy))

    def from_epipolar(self, side: str, xy) -> np.ndarray:
        """``(n, 2)`` epipolar array pixels of ``side`` -> the original image's pixels."""
        return _apply(np.linalg.inv(self._h(side)), _points(xy))


def _points(xy) -> np.ndarray:
    xy = np.asarray(xy, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"xy must have shape (n, 2) (column, row), got {xy.shape}")
    return xy


def _default_heights(camera_left, camera_right):
    ranges = [getattr(c, "height_range", None) for c in (camera_left, camera_right)]
    ranges = [r for r in ranges if r is not None]
    if not ranges:
        raise ValueError("heights=(h_min, h_max) is required for cameras without a height range (push-broom)")
    return max(r[0] for r in ranges), min(r[1] for r in ranges)


def affine_epipolar_pair(
    image_left,
    image_right,
    camera_left,
    camera_right,
    *,
    bounds=None,
    heights=None,
    grid: int = 9,
    layers: int = 5,
    margin: float = 0.1,
    resampling: Resampling | str = "cubic",
    nodata=None,
) -> AffineEpipolarPair:
    """Rectify a tile of two ground-camera images by the local affine approximation (module docstring).

    Args:
        image_left, image_right: ``(..., H, W)`` images of the two cameras.
        camera_left, camera_right: :class:`photax.RPCCamera` or :class:`photax.PushbroomCamera`
            (anything with ``to_ground(pixel, h)`` and ``__call__(lon_lat_h)``).
        bounds: the left tile ``(col0, row0, col1, row1)`` in left pixels (default the whole image).
        heights: ``(h_min, h_max)`` ellipsoidal heights of the tile's terrain (default the RPCs'
            common validity range, offset +- scale: wide, so a wide disparity range).
        grid, layers: virtual correspondences: ``grid x grid`` points at ``layers`` heights.
        margin: the disparity range is widened by this share of its width (and 2 px) on each side.
        resampling, nodata: as :func:`photax.resample`.

    Returns:
        :class:`AffineEpipolarPair`, with :attr:`~AffineEpipolarPair.vertical_residual` the largest
        row difference the affine model leaves over the tile.

    Raises:
        ValueError: a tile outside the left image, a bad height range, too few virtual
            correspondences (the right camera does not see the tile), or epipolar arrays too large.
    """
    method = Resampling.check(resampling)
    if grid < _MIN_GRID or layers < _MIN_LAYERS:
        raise ValueError(f"grid must be >= {_MIN_GRID} and layers >= {_MIN_LAYERS}, got {grid}, {layers}")
    hl_img, wl_img = np.shape(image_left)[-2:]
    hr_img, wr_img = np.shape(image_right)[-2:]
    for name, cam, shape in (("left", camera_left, (wl_img, hl_img)), ("right", camera_right, (wr_img, hr_img))):
        size = getattr(cam, "image_size", None)
        if size is not None and tuple(size) != shape:
            raise ValueError(f"image_{name} is {shape[0]} x {shape[1]} px, camera_{name}'s image_size is {size}")
    if bounds is None:
        bounds = (0.0, 0.0, wl_img - 1.0, hl_img - 1.0)
    c0, r0, c1, r1 = (float(v) for v in bounds)
    if not (0 <= c0 < c1 <= wl_img - 1 + 1e-9 and 0 <= r0 < r1 <= hl_img - 1 + 1e-9):
        raise ValueError(
            f"bounds {tuple(bounds)} must be (col0, row0, col1, row1) inside the left image "
            f"(0 .. {wl_img - 1}, 0 .. {hl_img - 1}) with col0 < col1 and row0 < row1"
        )
    if heights is None:
        heights = _default_heights(camera_left, camera_right)
    h0, h1 = (float(v) for v in heights)
    if not (np.isfinite(h0) and np.isfinite(h1) and h1 > h0):
        raise ValueError(f"heights must be (h_min, h_max) with h_max > h_min, got {heights}")
    bounds = (c0, r0, c1, r1)
    left, right, hh = virtual_matches(camera_left, camera_right, bounds, (h0, h1), grid, layers)
    if len(left) < 0.5 * grid * grid * layers:
        raise ValueError(
            f"only {len(left)} of {grid * grid * layers} virtual correspondences: the right camera does not "
            "see the left tile over the height range"
        )
    f = affine_fundamental(left, right)
    h_l, h_r = rectifying_affinities(f)
    # the check: the lattice between the fitting points, between their heights
    step_c, step_r, step_h = (c1 - c0) / (grid - 1), (r1 - r0) / (grid - 1), (h1 - h0) / (layers - 1)
    cl, cr_, ch = virtual_matches(
        camera_left,
        camera_right,
        (c0 + step_c / 2, r0 + step_r / 2, c1 - step_c / 2, r1 - step_r / 2),
        (h0 + step_h / 2, h1 - step_h / 2),
        grid - 1,
        layers - 1,
    )
    all_l, all_r = np.concatenate([left, cl]), np.concatenate([right, cr_])
    ul, ur = _apply(h_l, all_l), _apply(h_r, all_r)
    dv = ul[:, 1] - ur[:, 1]
    # the left array: the tile's outline; the right: what the tile's points reach over the heights
    corners = np.array([[c0, r0], [c1, r0], [c0, r1], [c1, r1]])
    uc = _apply(h_l, corners)
    u_lo, v_lo = np.floor(uc.min(axis=0))
    u_hi, v_hi = np.ceil(uc.max(axis=0))
    disp = ul[:, 0] - ur[:, 0]
    pad = margin * float(np.ptp(disp)) + 2.0
    d_lo, d_hi = float(disp.min()) - pad, float(disp.max()) + pad
    ur_lo, ur_hi = np.floor(u_lo - d_hi), np.ceil(u_hi - d_lo)
    h_l = _translate(h_l, -u_lo, -v_lo)
    h_r = _translate(h_r, -ur_lo, -v_lo)
    rows = int(v_hi - v_lo) + 1
    cols_l, cols_r = int(u_hi - u_lo) + 1, int(ur_hi - ur_lo) + 1
    area = (c1 - c0 + 1) * (r1 - r0 + 1)
    if rows * max(cols_l, cols_r) > 16 * area:
        raise ValueError(
            f"the epipolar arrays would be {cols_l} / {cols_r} x {rows} px for a tile of {area:.0f} px: "
            "the height range is too wide for the tile (give heights=)"
        )
    # disparities of the arrays: col_l - col_r = (u_l - u_lo) - (u_r - ur_lo)
    shift = ur_lo - u_lo
    d_range = (int(np.floor(d_lo + shift)), int(np.ceil(d_hi + shift)))
    images = {}
    for side, img, h, cols in (("left", image_left, h_l, cols_l), ("right", image_right, h_r, cols_r)):
        cc, rr = np.meshgrid(np.arange(cols, dtype=float), np.arange(rows, dtype=float))
        src = _apply(np.linalg.inv(h), np.column_stack([cc.ravel(), rr.ravel()]))
        out = np.asarray(resample(img, src[:, 0], src[:, 1], method, nodata=nodata))
        images[side] = out.reshape(out.shape[:-1] + (rows, cols))
    return AffineEpipolarPair(
        left=images["left"],
        right=images["right"],
        homography_left=h_l,
        homography_right=h_r,
        camera_left=camera_left,
        camera_right=camera_right,
        bounds=bounds,
        heights=(h0, h1),
        disparity_range=d_range,
        vertical_residual=float(np.max(np.abs(dv))),
        vertical_rms=float(np.sqrt(np.mean(dv**2))),
    )
