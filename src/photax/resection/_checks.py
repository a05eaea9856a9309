"""Input validation and plausibility checks of a resection.

:func:`validate` is the one validation of :func:`photax.resect` and
:func:`photax.resect_batch` (a single image is a batch of one with names,
check points and the detailed geometry checks).  :func:`implausible`
screens a batch for solutions that converged but cannot be right, and
:func:`_plausibility` words the reason for the images it flags:

more than a third of the control points excluded; residuals above 2 % of
the frame diagonal; the mirror-image solution of level, planar GCPs (the
camera below their plane, looking up at it; Z is up); image
coordinates outside 1.5 times the frame, or spanning less than 1 % of it
(without a frame: farther than 4 f from the centre, or spanning less than
0.005 f) - a wrong unit.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from .._float64 import as_float64
from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from ..errors import DegenerateGeometryError
from ..rotation import check_convention

_PLANAR = 0.1  # smallest / largest spread of the GCPs below this: "planar" for the 4-point minimum
CAUSES = (
    "likely causes: swapped or mirrored axes (image column/row or x/y, ground E/N), wrong units "
    "(image coordinates in another unit than the camera's), or control points measured on another image"
)
_MAX_EXCLUDED = 1.0 / 3.0  # more blunders than this share of the control points: the data do not fit
_MAX_RMS = 0.02  # rms above this share of the frame diagonal (or of f): not a measurement error
_FRAME_MARGIN = 1.5  # image points farther out than this times the half frame: not on this camera's image
_MAX_FIELD = 4.0  # no frame known: image points farther out than this times f (152 deg field of view): wrong unit
# Image points spanning less than this share of the frame (40 px of 4000), or of f without a frame: a wrong unit
# (metres for mm shrink the points 1000-fold: a GCP set spanning the whole frame would span 1e-3 of it).
_MIN_SPREAD, _MIN_SPREAD_F = 0.01, 5e-3
# A mirrored image of planar GCPs is fitted exactly by the camera reflected through their plane: the
# data cannot tell the two apart, only which side of the plane can be seen. For level planar GCPs (the
# ground: slope below this, relief below _PLANAR of their extent) that is the upper side; a façade can be
# seen from either side, and GCPs with relief decide it themselves (resect compares the mirrored fit).
_MAX_TILT = 60.0  # degrees
MIRROR = "the solution is a mirror image"


def _as_points(a, name: str, width: int, batch: bool) -> np.ndarray:
    a = as_float64(a, name)
    want = 3 if batch else 2
    if a.ndim != want or a.shape[-1] != width:
        shape = f"(b, n, {width})" if batch else f"(n, {width})"
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    return a


def _point_label(names, k: int) -> str:
    return f"{names[k]!r} (index {k})" if names is not None else f"index {k}"


def _sigma_weights(sigma, shape, name="sigma") -> np.ndarray:
    """A-priori sigmas -> weights 1/sigma^2 with the shape of the image points."""
    if sigma is None:
        return np.ones(shape)
    s = np.asarray(sigma, dtype=float)
    if s.ndim == len(shape) - 1 and s.shape == shape[:-1]:
        s = s[..., None]
    elif s.ndim > 0 and s.shape != shape:
        raise ValueError(f"{name} must be a scalar, (n,) or (n, 2) like the image points {shape}, got {s.shape}")
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ValueError(f"{name} must be finite and positive")
    return np.broadcast_to(1.0 / s**2, shape).copy()


def _n_distinct(rows: np.ndarray) -> int:
    """Number of distinct rows (a lexicographic sort: cheaper than np.unique(axis=0))."""
    s = rows[np.lexsort(rows.T[::-1])]
    return 1 + int(np.sum(np.any(s[1:] != s[:-1], axis=1)))


def _check_geometry(ground: np.ndarray, xy: np.ndarray, ctrl: np.ndarray, names, need_init: bool) -> np.ndarray:
    """Degenerate configurations -> ValueError.

    Returns the ``(3, 3)`` right-handed principal axes of the control points
    (the last one the normal of their best-fitting plane) and whether they are planar
    (relief below ``_PLANAR`` of their extent, or fewer than 4 distinct points).
    """
    idx = np.flatnonzero(ctrl)
    g, x = ground[idx], xy[idx]
    rows = np.concatenate([g, x], axis=1)
    if _n_distinct(rows) < len(rows):
        dup = [k for k in idx if np.sum(np.all(rows == rows[np.searchsorted(idx, k)], axis=1)) > 1]
        raise ValueError(
            "duplicated control points (same ground and image coordinates): "
            + ", ".join(_point_label(names, k) for k in dup)
        )
    distinct = _n_distinct(g)
    if distinct < 3:
        raise ValueError(f"need at least 3 distinct control points, got {distinct}")
    _, s, vt = np.linalg.svd(g - g.mean(0), full_matrices=False)
    if s[0] == 0 or s[1] < 1e-6 * s[0]:
        raise ValueError(
            "the control points are (nearly) collinear: the orientation is not determined; "
            "points " + ", ".join(_point_label(names, k) for k in idx)
        )
    planar = distinct < 4 or s[2] < _PLANAR * s[0]
    if need_init:
        if planar and distinct < 4:
            raise ValueError(
                f"the automatic start needs at least 4 distinct control points, got {distinct}; "
                "give initial= to resect from 3"
            )
        if not planar and distinct < 6:
            raise ValueError(
                f"the automatic start needs at least 6 control points for a non-planar GCP set "
                f"(relief {s[2] / s[0]:.2f} of the extent), got {distinct}; give initial= or more points"
            )
    return np.stack([vt[0], np.cross(vt[2], vt[0]), vt[2]], axis=1), planar


def _bucket(n: int, batch: bool = False) -> int:
    """Points padded to: a few sizes for a single image (16, 32, ...), so that a new number of
    points rarely means a new compilation; for a batch, the next multiple of 4, as padded points
    cost as much as real ones (12 GCPs padded to 16: the cheap path 1.3x slower)."""
    if batch:
        return -(-n // 4) * 4
    return max(16, 1 << (n - 1).bit_length())


def _critical(alpha: float, sigma_known: bool, red: float) -> float:
    """Baarda's normal critical value, or Pope's tau with ``red`` dof."""
    # scipy.special, not scipy.stats: the same quantile functions (stats calls
    # them) without the 0.4-0.6 s that importing scipy.stats costs a command.
    from scipy import special

    if sigma_known:
        return float(special.ndtri(1.0 - alpha / 2.0))
    if red < 2:
        return np.inf
    t = special.stdtrit(red - 1, 1.0 - alpha / 2.0)
    return float(t * np.sqrt(red) / np.sqrt(red - 1 + t * t))


@functools.lru_cache(maxsize=64)
def _critical_table(alpha: float, sigma_known: bool, m: int) -> np.ndarray:
    """Critical values indexed by the number of control points in use (0..m): :func:`_critical`
    for each, computed as arrays (one scalar call each was 2.5 s of a 10^5-point resection)."""
    from scipy import special

    red = 2.0 * np.arange(m + 1) - 6.0
    if sigma_known:
        return np.full(m + 1, _critical(alpha, True, 0.0))
    out = np.full(m + 1, np.inf)
    ok = red >= 2
    t = special.stdtrit(red[ok] - 1, 1.0 - alpha / 2.0)
    out[ok] = t * np.sqrt(red[ok]) / np.sqrt(red[ok] - 1 + t * t)
    return out


def _pixel_size(camera: FrameCamera) -> float | None:
    return None if camera.pixel_size is None else float(np.mean(np.asarray(camera.pixel_size)))


def _frame(camera: FrameCamera) -> tuple[np.ndarray | None, float]:
    """Half frame ``(2,)`` in image-plane units (None without a pixel grid) and f."""
    f = float(camera.focal_length)
    if camera.pixel_size is None or camera.image_size is None:
        return None, f
    return 0.5 * np.asarray(camera.image_size, float) * np.asarray(camera.pixel_size, float), f


def units_wrong(xy, ctrl, half, f) -> bool:
    """Whether the control points' image coordinates are in a wrong unit -- the
    decision behind :func:`_plausibility`'s "wrong units" reasons, so that a
    caller decides on it, not on the words (``xy`` (n, 2), ``ctrl`` (n,) mask,
    ``half`` half frame or None, ``f`` focal length)."""
    c = np.asarray(xy, float)[np.asarray(ctrl, bool)]
    spread = np.ptp(c, axis=0).max() if len(c) else 0.0
    if half is not None:
        out = np.abs(c) > _FRAME_MARGIN * half[None, :]
        if np.any(out):
            return not np.all(np.abs(c[:, ::-1]) <= _FRAME_MARGIN * half[None, :])
        return bool(spread < _MIN_SPREAD * 2.0 * half.max())
    return bool(np.any(np.hypot(*c.T) > _MAX_FIELD * f) or spread < _MIN_SPREAD_F * f)


def _plausibility(xy, ctrl, outliers, centre, axis, normal, planar, rms, half, f):
    """Checks that make a converged adjustment a failure, with the reason.

    A resection can converge to a wrong answer when image and ground do not
    belong together: it then excludes many points as blunders, fits with
    residuals no measurement has, or finds the mirror image of the true
    orientation (swapping x/y or E/N reflects the scene, and a reflected
    planar scene is seen exactly from the camera reflected through its
    plane).  Only for level planar GCPs (the ground) is the side known: the
    camera below them, looking up, is the mirror.  Returns None when it passes.

    ``xy`` (n, 2) image points; ``ctrl``, ``outliers`` (n,) masks;
    ``centre`` (3,) projection centre relative to a point of the GCPs'
    plane; ``axis`` (3,) viewing direction;
    ``normal`` (3,) normal of the GCPs' best-fitting plane, ``planar`` whether they
    lie on it; ``rms`` of the
    control inliers; ``half`` half frame or None; ``f`` focal length.
    """
    c = xy[ctrl]
    spread = np.ptp(c, axis=0).max() if len(c) else 0.0
    if half is not None:
        out = np.abs(c) > _FRAME_MARGIN * half[None, :]
        if np.any(out):
            swapped = np.all(np.abs(c[:, ::-1]) <= _FRAME_MARGIN * half[None, :])
            return (
                f"image coordinates of {int(np.any(out, axis=1).sum())} control points lie outside the camera's "
                f"frame (half size {half[0]:.4g} x {half[1]:.4g}): "
                + (
                    "they would fit with x and y (column and row) swapped"
                    if swapped
                    else "wrong units (e.g. pixels or micrometres for a mm camera), or a camera file that does not "
                    "belong to these measurements"
                )
            )
        if spread < _MIN_SPREAD * 2.0 * half.max():
            return (
                f"the control points span only {spread:.3g} on the image plane, {spread / (2 * half.max()):.1e} of "
                "the frame: wrong units (e.g. metres for a mm camera)"
            )
    elif np.any(np.hypot(*c.T) > _MAX_FIELD * f):
        return (
            f"image coordinates up to {np.hypot(*c.T).max():.4g} from the centre with a focal length of {f:.4g} "
            f"(a field of view over {2 * np.degrees(np.arctan(_MAX_FIELD)):.0f} degrees): wrong units "
            "(e.g. mm or pixels for a camera in metres)"
        )
    elif spread < _MIN_SPREAD_F * f:
        return (
            f"the control points span only {spread:.3g} on the image plane, {spread / f:.1e} of the focal length: "
            "wrong units (e.g. metres for a mm camera)"
        )
    n_ctrl, n_out = int(ctrl.sum()), int(outliers.sum())
    if n_out > _MAX_EXCLUDED * n_ctrl:
        return (
            f"{n_out} of {n_ctrl} control points had to be excluded as blunders (more than a third): "
            "image and ground coordinates do not fit together"
        )
    size = 2.0 * np.hypot(*half) if half is not None else f
    if rms > _MAX_RMS * size:
        return (
            f"the residuals (rms {rms:.4g}) are {rms / size:.1%} of the {'frame diagonal' if half is not None else 'focal length'}, "
            "far beyond measurement error: image and ground coordinates do not fit together"
        )
    n = normal if normal[2] >= 0 else -normal
    if planar and n[2] > np.cos(np.radians(_MAX_TILT)):
        if float(centre @ n) < 0 and float(axis @ n) > 0:
            return (
                f"{MIRROR}: the camera is below the level, planar control points, looking up at "
                "them - a mirrored image or ground is fitted exactly by the camera reflected through "
                "their plane, and ground is seen from above (Z must be up; a swap of image column/row "
                "or x/y, or of ground E/N, mirrors the scene)"
            )
    return None


def implausible(xy, ctrl, outliers, centre, axis, normal, planar, rms, half, f) -> np.ndarray:
    """:func:`_plausibility`'s decision for a batch, vectorised: ``(b,)`` True
    where a converged solution cannot be right (arguments with a leading
    ``b`` axis; ``half`` and ``f`` shared)."""
    if ctrl.all():  # resect_batch (no check points): no masking, and the x and y extents from contiguous rows
        cols = xy.transpose(2, 0, 1)
        spread = np.maximum(np.ptp(cols[0], axis=1), np.ptp(cols[1], axis=1))
    else:
        hi = np.max(np.where(ctrl[..., None], xy, -np.inf), axis=1)
        lo = np.min(np.where(ctrl[..., None], xy, np.inf), axis=1)
        spread = np.max(hi - lo, axis=1)
    with np.errstate(invalid="ignore"):
        if half is not None:
            bad = np.any(ctrl[..., None] & (np.abs(xy) > _FRAME_MARGIN * half), axis=(1, 2))
            bad |= spread < _MIN_SPREAD * 2.0 * half.max()
            size = 2.0 * np.hypot(*half)
        else:
            bad = np.any(ctrl & (np.hypot(xy[..., 0], xy[..., 1]) > _MAX_FIELD * f), axis=1)
            bad |= spread < _MIN_SPREAD_F * f
            size = f
        bad |= np.sum(outliers, axis=1) > _MAX_EXCLUDED * np.sum(ctrl, axis=1)
        bad |= rms > _MAX_RMS * size
        n = np.where(normal[:, 2:] >= 0, normal, -normal)
        flat = planar & (n[:, 2] > np.cos(np.radians(_MAX_TILT)))
        bad |= flat & (np.sum(centre * n, axis=1) < 0) & (np.sum(axis * n, axis=1) > 0)
    return bad


@dataclasses.dataclass
class Prepared:
    """Validated inputs of a resection, as a batch of ``b`` images (numpy)."""

    xy: np.ndarray  # (b, n, 2)
    ground: np.ndarray  # (b, n, 3) as given
    weight: np.ndarray  # (b, n, 2)
    is_check: np.ndarray  # (b, n) bool
    origin: np.ndarray  # (b, 3) centroid of the control points
    basis: np.ndarray  # (b, 3, 3) principal axes of the control points
    planar: np.ndarray  # (b,) the control points lie on a plane (relief below _PLANAR of their extent)
    init: np.ndarray  # (b, 6) user start relative to origin, or zeros
    has_initial: bool
    names: list | None
    sigma_known: bool
    ctrl_idx: np.ndarray  # control points of the single image (batch: all)

    @property
    def local(self) -> np.ndarray:
        return self.ground - self.origin[:, None, :]


def validate(image_xy, ground_xyz, camera, sigma, check, names, initial, convention, alpha, batch: bool) -> Prepared:
    """The one validation of resect and resect_batch: ValueError naming the argument, or the points."""
    check_convention(convention)
    xy = _as_points(image_xy, "image_xy", 2, batch)
    ground = _as_points(ground_xyz, "ground_xyz", 3, batch)
    if not batch:
        if len(ground) != len(xy):
            raise ValueError(f"image_xy has {len(xy)} points but ground_xyz has {len(ground)}")
        xy, ground = xy[None], ground[None]
    elif ground.shape[:2] != xy.shape[:2]:
        raise ValueError(f"image_xy has shape {xy.shape} but ground_xyz has {ground.shape}")
    b, n = xy.shape[:2]
    if names is not None:
        names = [str(s) for s in names]
        if len(names) != n:
            raise ValueError(f"names has {len(names)} entries for {n} points")
    # (a whole-array test first: the per-point one only to name the points, when something is not finite)
    if not (np.isfinite(xy).all() and np.isfinite(ground).all()):
        bad = ~(np.all(np.isfinite(xy), axis=2) & np.all(np.isfinite(ground), axis=2))
        if batch:
            where = [f"image {i} point {k}" for i, k in zip(*np.nonzero(bad))][:10]
            raise ValueError("non-finite (NaN/inf) coordinates at " + ", ".join(where))
        raise ValueError(
            "non-finite (NaN/inf) coordinates at points "
            + ", ".join(_point_label(names, k) for k in np.flatnonzero(bad[0]))
        )
    if not isinstance(camera, FrameCamera):
        raise ValueError(f"camera must be a photax.FrameCamera, got {type(camera).__name__}")
    weight = _sigma_weights(sigma, xy.shape if batch else xy.shape[1:])
    weight = weight if batch else weight[None]
    is_check = np.zeros(n, bool) if check is None else np.asarray(check)
    if is_check.shape != (n,) or is_check.dtype != bool:
        raise ValueError(f"check must be a boolean array of shape ({n},), got {is_check.dtype} {is_check.shape}")
    ctrl = ~is_check
    if ctrl.sum() < 3:
        raise ValueError(f"need at least 3 control points, got {int(ctrl.sum())} (of {n}, the rest are check points)")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    if batch:
        origin = ground.mean(axis=1)
        basis, planar = _batch_geometry(ground, origin, initial is None)
    else:
        basis, planar = _check_geometry(ground[0], xy[0], ctrl, names, initial is None)
        basis, planar = basis[None], np.array([planar])
        origin = ground[0][ctrl].mean(axis=0)[None]
    init = np.zeros((b, 6))
    if initial is not None:
        if not isinstance(initial, ExteriorOrientation):
            raise ValueError("initial must be a photax.ExteriorOrientation")
        e0 = initial.to_convention(convention)
        init = np.concatenate(
            [np.asarray(e0.position) - (origin if batch else origin[0]), np.asarray(e0.angles)], axis=-1
        )
        if not np.all(np.isfinite(init)):
            raise ValueError("initial has non-finite values")
        if init.shape != ((b, 6) if batch else (6,)):
            raise ValueError(f"initial must have batch shape ({b},), got {init.shape[:-1]}")
        init = init.reshape(b, 6)
    return Prepared(
        xy,
        ground,
        weight,
        np.broadcast_to(is_check, (b, n)),
        origin,
        basis,
        planar,
        init,
        initial is not None,
        names,
        sigma is not None,
        np.flatnonzero(ctrl),
    )


def _batch_geometry(ground: np.ndarray, origin: np.ndarray, need_init: bool) -> np.ndarray:
    """Vectorised degeneracy checks of a batch; ``(b, 3, 3)`` principal axes."""
    b, n = ground.shape[:2]
    if n < 4 and need_init:
        raise ValueError(f"the automatic start needs at least 4 points per image, got {n}")
    s, vt = _principal_axes(ground - origin[:, None, :])
    collinear = (s[:, 0] == 0) | (s[:, 1] < 1e-6 * s[:, 0])
    if np.any(collinear):
        raise DegenerateGeometryError(f"collinear control points in images {np.flatnonzero(collinear)[:10].tolist()}")
    flat = s[:, 2] < _PLANAR * s[:, 0]
    if need_init and n < 6:
        if not np.all(flat):
            raise ValueError(
                f"images {np.flatnonzero(~flat)[:10].tolist()} have non-planar GCPs: "
                "the automatic start needs 6 points for them"
            )
    return np.stack([vt[:, 0], np.cross(vt[:, 2], vt[:, 0]), vt[:, 2]], axis=2), flat


def _principal_axes(centred: np.ndarray, sweeps: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Singular values ``(b, 3)`` (descending) and right singular vectors
    ``(b, 3, 3)`` (rows) of a batch of ``(b, n, 3)`` centred point sets.

    Cyclic Jacobi on the 3x3 scatter matrices ``S = X^T X`` (Golub & Van
    Loan 2013, sec. 8.5), entry by entry and vectorised over the batch:
    numpy's batched SVD calls LAPACK once per image (tens of microseconds
    each).  Quadratic convergence: 6 sweeps reach rounding level; it stops
    earlier when every matrix of the batch has (typically after 3-4).
    """
    cols = [np.ascontiguousarray(centred[:, :, i]) for i in range(3)]
    a = {(i, j): np.sum(cols[i] * cols[j], axis=1) for i in range(3) for j in range(i, 3)}
    v = [[np.full(len(centred), float(i == j)) for j in range(3)] for i in range(3)]  # v[row][col]
    key = lambda i, j: (min(i, j), max(i, j))  # noqa: E731
    for sweep in range(sweeps):
        # converged everywhere (off-diagonal below rounding of the diagonal): further sweeps change nothing
        if sweep and np.all(
            np.abs(a[0, 1]) + np.abs(a[0, 2]) + np.abs(a[1, 2])
            <= 1e-17 * (np.abs(a[0, 0]) + np.abs(a[1, 1]) + np.abs(a[2, 2]))
        ):
            break
        for p, q, r in ((0, 1, 2), (0, 2, 1), (1, 2, 0)):
            apq, app, aqq = a[p, q], a[p, p], a[q, q]
            with np.errstate(all="ignore"):
                theta = (aqq - app) / (2.0 * apq)
                t = np.sign(theta) / (np.abs(theta) + np.sqrt(theta * theta + 1.0))
            t = np.where(theta == 0, 1.0, np.where(np.isfinite(t) & (apq != 0), t, 0.0))
            c = 1.0 / np.sqrt(t * t + 1.0)
            sn = t * c
            arp, arq = a[key(r, p)], a[key(r, q)]
            a[p, p], a[q, q], a[p, q] = app - t * apq, aqq + t * apq, np.zeros_like(apq)
            a[key(r, p)], a[key(r, q)] = c * arp - sn * arq, sn * arp + c * arq
            for row in range(3):
                vp, vq = v[row][p], v[row][q]
                v[row][p], v[row][q] = c * vp - sn * vq, sn * vp + c * vq
    lam = np.stack([a[0, 0], a[1, 1], a[2, 2]], axis=1)
    vec = np.stack([np.stack(v[i], axis=1) for i in range(3)], axis=1)  # (b, row, col): columns are eigenvectors
    order = np.argsort(-lam, axis=1)
    s = np.sqrt(np.maximum(np.take_along_axis(lam, order, axis=1), 0.0))
    vt = np.take_along_axis(vec, order[:, None, :], axis=2).transpose(0, 2, 1)
    return s, vt
