"""The bundle adjustment problem: cameras, orientations, points, observations, and their validation."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np

from .._float64 import as_float64
from ..camera import FrameCamera
from ..collinearity import stack_exteriors
from ._structure import Analysis, _analyse, _gauge_mask, _origin, _same_topology, _Topology, _topology

ROLES = ("tie", "control", "check")
#: Interior-orientation parameters of a ``"brown"`` camera, in this order
#: (another distortion model's: :attr:`BundleProblem.intrinsic_names`).
INTRINSICS = ("f", "x0", "y0", "k1", "k2", "k3", "p1", "p2")
#: Exterior parameters of an image: the projection centre and the rotation
#: increments about the camera's own x, y, z axes.
EXTERIOR = ("X", "Y", "Z", "rx", "ry", "rz")

Loss = Literal["none", "huber", "cauchy"]
Gauge = Literal["fix_first_camera", "damped"]


class BundleProblem:
    """A block of images to adjust: cameras, orientations, points, observations.

    Build it from arrays (below), from a BAL file (:func:`photax.read_bal`)
    or from a block folder (:func:`read_block`).  All arrays are copied to
    float64 / int64 numpy arrays; the problem is immutable by convention
    (use :meth:`replace`).

    Args:
        cameras: one :class:`photax.FrameCamera` or a sequence of ``n_cameras``.
        exterior: ``n_images`` exterior orientations, a batched
            :class:`photax.ExteriorOrientation` of shape ``(n_images,)`` or a
            list.  NaN rows are unknown: :func:`initialize_block` fills them
            by resection from control points.  The result reports
            orientations in the same angle convention.
        points: ``(n_points, 3)`` ground coordinates: the surveyed values of
            control and check points, approximate values of tie points (NaN
            rows: unknown, filled by forward intersection).
        obs_image, obs_point: ``(k,)`` integer image and point index of each
            observation.
        obs_xy: ``(k, 2)`` measured **image-plane** coordinates (x right, y up,
            the camera's unit; :meth:`FrameCamera.pixel_to_image` converts
            pixels).
        obs_sigma: scalar, ``(k,)`` or ``(k, 2)`` standard deviation of the
            measurements, image-plane unit.  Default 1.
        image_camera: ``(n_images,)`` camera index of each image.  Default:
            all images share camera 0 when there is one camera, image ``i``
            uses camera ``i`` when there are as many cameras as images.
        roles: ``(n_points,)`` of ``"tie"``, ``"control"``, ``"check"``
            (default all ``"tie"``).
        point_sigma: scalar, ``(n_points,)`` or ``(n_points, 3)`` ground
            standard deviation of control points (ignored for the others);
            0 fixes the point.  Default 0 (fixed control).
        free_intrinsics: names from :attr:`intrinsic_names` (for ``"brown"``
            cameras :data:`INTRINSICS`) estimated for every camera (e.g.
            ``("f", "k1", "k2")``), or an ``(n_cameras, n_intrinsics)`` bool
            mask.  Default: interior orientation fixed.  All cameras of a
            problem share one distortion model
            (:data:`photax.camera.DISTORTION_MODELS`).
        fixed_exterior: ``(n_images,)`` or ``(n_images, 6)`` bool, parameters
            of :data:`EXTERIOR` held at their given values.  Default none.
        image_names, point_names: optional labels used in reports.
        gnss_position: ``(n_images, 3)`` GNSS (or any surveyed) positions of
            the images' antennas, ground unit, weighted observations of
            ``C + R lever_arm`` (NaN rows: no observation).  With three or more
            of them (not on one line) the block has a datum without control.
        gnss_sigma: scalar, ``(n_images,)`` or ``(n_images, 3)`` standard
            deviation of ``gnss_position`` per axis, ground unit, > 0
            (to hold a centre exactly, use ``fixed_exterior``).  Needed with
            ``gnss_position``.
        attitude: ``(n_images, 3)`` INS attitude angles, radians, in the
            convention of ``exterior`` (NaN rows: no observation).
        attitude_sigma: scalar, ``(n_images,)`` or ``(n_images, 3)`` standard
            deviation of ``attitude`` per angle, radians, > 0.
        lever_arm: ``(3,)`` or ``(n_images, 3)`` antenna offset from the
            projection centre in the camera frame (x right, y up, z back;
            ground unit).  Default 0.
        dem: a :class:`photax.DEM` of the ground, in the points' CRS and
            height system: each tie point's height is an observation of it,
            ``Z - DEM(X, Y) = 0`` with ``dem_sigma`` (Ames Stereo Pipeline's
            ``bundle_adjust --heights-from-dem``), bilinear heights and
            slopes at the point's adjusted ``(X, Y)``.  Tie points off the
            DEM or on its nodata at the start values get no observation
            (counted in the result).  The terrain's relief then holds the
            block's tilt and height (and, on sloping ground, its shift).
        dem_sigma: scalar or ``(n_points,)`` standard deviation of the DEM's
            height at the tie points, ground unit, > 0.  Needed with ``dem``.
        crs: the ground CRS of points and positions (text: WKT, EPSG...), or
            None; with ``dem`` the two horizontal CRSs must agree.

    Examples:
        Two nadir images 600 m apart, 1000 m up, seeing four control points and one tie point; the
        observations are the points' projections, listed image by image:

        >>> import numpy as np
        >>> import photax as ptx
        >>> camera = ptx.FrameCamera(focal_length=0.1)
        >>> exterior = [ptx.ExteriorOrientation([x, 0.0, 1000.0], [0.0, 0.0, 0.0]) for x in (0.0, 600.0)]
        >>> points = np.array([[-200.0, -200, 0], [800, -200, 10], [800, 200, 0], [-200, 200, 30], [300, 0, 20]])
        >>> xy = np.concatenate([np.asarray(ptx.project(points, e, camera)) for e in exterior])
        >>> problem = ptx.BundleProblem(camera, exterior, points, [0] * 5 + [1] * 5, [0, 1, 2, 3, 4] * 2, xy,
        ...                             obs_sigma=5e-6, roles=["control"] * 4 + ["tie"])
        >>> problem
        BundleProblem(2 images, 1 cameras, 5 points (4 control, 0 check), 10 observations)
        >>> problem.obs_sigma[0].tolist(), problem.image_camera.tolist()  # per observation; one shared camera
        ([5e-06, 5e-06], [0, 0])
        >>> problem.replace(point_sigma=0.05).point_sigma[0].tolist()  # control weighted, not fixed
        [0.05, 0.05, 0.05]
    """

    def __init__(
        self,
        cameras,
        exterior,
        points,
        obs_image,
        obs_point,
        obs_xy,
        *,
        obs_sigma=1.0,
        image_camera=None,
        roles=None,
        point_sigma=0.0,
        free_intrinsics: Sequence[str] | np.ndarray = (),
        fixed_exterior=None,
        image_names: Sequence[str] | None = None,
        point_names: Sequence[str] | None = None,
        gnss_position=None,
        gnss_sigma=None,
        attitude=None,
        attitude_sigma=None,
        lever_arm=None,
        dem=None,
        dem_sigma=None,
        crs: str | None = None,
    ):
        cams = (cameras,) if isinstance(cameras, FrameCamera) else tuple(cameras)
        if not cams or not all(isinstance(c, FrameCamera) for c in cams):
            raise ValueError("cameras must be a FrameCamera or a non-empty sequence of them")
        eo = stack_exteriors(exterior)
        n_img, n_cam = eo.position.shape[0], len(cams)
        pts = as_float64(points, "points").copy()
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must have shape (n_points, 3), got {pts.shape}")
        n_pts = len(pts)
        oi, op, xy = _observations(obs_image, obs_point, obs_xy, n_img, n_pts)
        sig = _per_row(obs_sigma, len(xy), 2)
        if not np.all(sig > 0):
            raise ValueError("obs_sigma must be positive")
        ic = _image_camera(image_camera, n_cam, n_img)
        role = np.array(["tie"] * n_pts if roles is None else [str(r) for r in roles], dtype=object)
        if role.shape != (n_pts,) or not set(role.tolist()) <= set(ROLES):
            bad = sorted(set(role.tolist()) - set(ROLES))
            raise ValueError(f"roles must be (n_points,) of {ROLES}; got shape {role.shape}, unknown {bad}")
        psig = _per_row(point_sigma, n_pts, 3)
        if np.any(psig < 0) or np.any(np.isnan(psig)):
            raise ValueError("point_sigma must be >= 0 (0 fixes a control point)")
        models = sorted({c.model for c in cams})
        if len(models) > 1:
            raise ValueError(f"the cameras of a bundle problem must share one distortion model, got {models}")
        self.intrinsic_names: tuple[str, ...] = cams[0].intrinsic_names
        free = _free_intrinsics(free_intrinsics, n_cam, self.intrinsic_names)
        fixed = _fixed_exterior(fixed_exterior, n_img)
        _check_datum(op, role, pts, point_names)
        self.gnss_position, self.gnss_sigma = _camera_observations(gnss_position, gnss_sigma, n_img, "gnss")
        self.attitude, self.attitude_sigma = _camera_observations(attitude, attitude_sigma, n_img, "attitude")
        self.lever_arm = _lever_arm(lever_arm, n_img, self.gnss_position)
        self.dem, self.dem_sigma = _dem_observations(dem, dem_sigma, n_pts, crs)
        self.crs = crs
        self.cameras: tuple[FrameCamera, ...] = cams
        self.exterior = eo
        self.points = pts
        self.obs_image, self.obs_point = oi.astype(np.int64), op.astype(np.int64)
        self.obs_xy, self.obs_sigma = xy, sig
        self.image_camera = ic.astype(np.int64)
        self.roles = role
        self.point_sigma = psig
        self.free_intrinsics = free
        self.fixed_exterior = fixed
        self.image_names = tuple(image_names) if image_names is not None else tuple(f"image {i}" for i in range(n_img))
        self.point_names = tuple(point_names) if point_names is not None else tuple(f"point {i}" for i in range(n_pts))
        if len(self.image_names) != n_img or len(self.point_names) != n_pts:
            raise ValueError("image_names / point_names must have one entry per image / point")
        self._topology: _Topology | None = None  # shared with replace()d problems of the same links
        self._analyses: dict = {}  # gauge -> Analysis

    n_images = property(lambda self: self.exterior.position.shape[0])
    n_cameras = property(lambda self: len(self.cameras))
    n_points = property(lambda self: len(self.points))
    n_observations = property(lambda self: len(self.obs_xy))

    def replace(self, **changes) -> BundleProblem:
        """A copy with some constructor arguments changed."""
        args = dict(
            cameras=self.cameras, exterior=self.exterior, points=self.points, obs_image=self.obs_image,
            obs_point=self.obs_point, obs_xy=self.obs_xy, obs_sigma=self.obs_sigma,
            image_camera=self.image_camera, roles=self.roles, point_sigma=self.point_sigma,
            free_intrinsics=self.free_intrinsics, fixed_exterior=self.fixed_exterior,
            image_names=self.image_names, point_names=self.point_names, gnss_position=self.gnss_position,
            gnss_sigma=self.gnss_sigma, attitude=self.attitude, attitude_sigma=self.attitude_sigma,
            lever_arm=self.lever_arm, dem=self.dem, dem_sigma=self.dem_sigma, crs=self.crs,
        )  # fmt: skip
        sig = self.dem_sigma
        if sig is not None and len(sig) and np.all(sig == sig[0]):
            args["dem_sigma"] = float(sig[0])  # one sigma for all: still so when points are added or dropped
        args.update(changes)
        new = BundleProblem(**args)
        if self._topology is not None and _same_topology(self, new):
            new._topology = self._topology  # e.g. Monte Carlo replicates: only obs_xy changed
        return new

    def analyse(self, gauge: Gauge | None = None) -> Analysis:
        """The problem's structure for the solver, analysed once and cached.

        ``gauge`` as in :func:`bundle_adjust` (its extra fixed parameters
        are part of the structure).  The index arrays that depend only on
        the observations' links (pairs, chunks of the reduced system) are
        computed on first use and shared with every problem :meth:`replace`
        derives with the same links, so replicates that change only the
        measurements, sigmas or start values skip that work.  The cache
        relies on the problem being immutable: change it with
        :meth:`replace`, never in place.
        """
        if gauge not in self._analyses:
            if self._topology is None:
                self._topology = _topology(self)
            origin = _origin(self)
            s, n_c, w = _analyse(self, _gauge_mask(self, gauge), origin, self._topology)
            self._analyses[gauge] = Analysis(s, n_c, w, origin)
        return self._analyses[gauge]

    def __repr__(self) -> str:
        n_ctrl = int(np.sum(self.roles == "control"))
        n_chk = int(np.sum(self.roles == "check"))
        n_gnss, n_att = int(self.gnss_observed.sum()), int(self.attitude_observed.sum())
        extra = (f", {n_gnss} GNSS positions" if n_gnss else "") + (f", {n_att} attitudes" if n_att else "")
        extra += ", DEM heights" if self.dem is not None else ""
        return (
            f"BundleProblem({self.n_images} images, {self.n_cameras} cameras, {self.n_points} points "
            f"({n_ctrl} control, {n_chk} check), {self.n_observations} observations{extra})"
        )

    @property
    def gnss_observed(self) -> np.ndarray:
        """``(n_images,)`` bool: images with a GNSS position observation."""
        return np.all(np.isfinite(self.gnss_position), axis=1)

    @property
    def attitude_observed(self) -> np.ndarray:
        """``(n_images,)`` bool: images with an attitude observation."""
        return np.all(np.isfinite(self.attitude), axis=1)


# --------------------------------------------------------------------------
# Validation of the constructor's arguments (in the order __init__ checks them)
# --------------------------------------------------------------------------


def _observations(obs_image, obs_point, obs_xy, n_img: int, n_pts: int):
    """``obs_image``, ``obs_point`` ``(k,)`` integer indices in range and
    ``obs_xy`` ``(k, 2)`` finite, as numpy arrays."""
    oi, op = np.asarray(obs_image), np.asarray(obs_point)
    xy = as_float64(obs_xy, "obs_xy").copy()
    k = len(xy)
    if xy.shape != (k, 2) or oi.shape != (k,) or op.shape != (k,):
        raise ValueError(f"obs_xy must be (k, 2) and obs_image, obs_point (k,); got {xy.shape}, {oi.shape}, {op.shape}")
    for name, idx, n in (("obs_image", oi, n_img), ("obs_point", op, n_pts)):
        if k and (not np.issubdtype(idx.dtype, np.integer) or idx.min() < 0 or idx.max() >= n):
            raise ValueError(f"{name} must be integers in [0, {n}), got range [{idx.min()}, {idx.max()}]")
    if not np.all(np.isfinite(xy)):
        raise ValueError(f"obs_xy has non-finite values at observation {int(np.argmax(~np.isfinite(xy).all(1)))}")
    return oi, op, xy


def _per_row(value, n: int, width: int) -> np.ndarray:
    """A scalar, ``(n,)`` or ``(n, width)`` value broadcast to a new ``(n, width)`` float array."""
    v = np.asarray(value, dtype=float)
    return np.broadcast_to(v[:, None] if v.ndim == 1 else v, (n, width)).copy()


def _image_camera(image_camera, n_cam: int, n_img: int) -> np.ndarray:
    """The camera index of each image; the default pairs one camera with all
    images, or camera ``i`` with image ``i``."""
    if image_camera is None:
        if n_cam == 1:
            image_camera = np.zeros(n_img, dtype=np.int64)
        elif n_cam == n_img:
            image_camera = np.arange(n_img)
        else:
            raise ValueError(f"image_camera is needed: {n_cam} cameras for {n_img} images")
    ic = np.asarray(image_camera)
    if ic.shape != (n_img,) or not np.issubdtype(ic.dtype, np.integer) or ic.min() < 0 or ic.max() >= n_cam:
        raise ValueError(f"image_camera must be (n_images,) = ({n_img},) integers in [0, {n_cam})")
    return ic


def _free_intrinsics(free_intrinsics, n_cam: int, names: tuple[str, ...] = INTRINSICS) -> np.ndarray:
    """``(n_cam, len(names))`` bool mask from a mask or names of the cameras'
    intrinsics ``names``."""
    if isinstance(free_intrinsics, np.ndarray) and free_intrinsics.dtype == bool:
        if free_intrinsics.shape[-1:] != (len(names),):
            raise ValueError(f"free_intrinsics as a mask must have one column per parameter of {names}")
        return np.broadcast_to(free_intrinsics, (n_cam, len(names))).copy()
    unknown = set(free_intrinsics) - set(names)
    if unknown or isinstance(free_intrinsics, str):
        raise ValueError(f"free_intrinsics must be names from {names}, got {free_intrinsics!r}")
    free = np.zeros((n_cam, len(names)), dtype=bool)
    free[:, [names.index(n) for n in free_intrinsics]] = True
    return free


def _fixed_exterior(fixed_exterior, n_img: int) -> np.ndarray:
    """``(n_img, 6)`` bool mask from None, ``(n_img,)`` or ``(n_img, 6)``."""
    fixed = np.zeros((n_img, 6), dtype=bool) if fixed_exterior is None else np.asarray(fixed_exterior, dtype=bool)
    if fixed.shape == (n_img,):
        fixed = np.repeat(fixed[:, None], 6, axis=1)
    if fixed.shape != (n_img, 6):
        raise ValueError(f"fixed_exterior must be (n_images,) or (n_images, 6), got {fixed.shape}")
    return fixed


def _camera_observations(values, sigma, n_img: int, name: str):
    """``(n_img, 3)`` per-image observations (NaN rows: none) and their
    ``(n_img, 3)`` sigmas (> 0 and finite where observed; NaN elsewhere)."""
    if values is None:
        if sigma is not None:
            raise ValueError(f"{name}_sigma is given without {'gnss_position' if name == 'gnss' else name}")
        return np.full((n_img, 3), np.nan), np.full((n_img, 3), np.nan)
    label = "gnss_position" if name == "gnss" else name
    v = np.array(values, dtype=float)
    if v.shape != (n_img, 3):
        raise ValueError(f"{label} must have shape (n_images, 3) = ({n_img}, 3), got {v.shape}")
    partial = np.any(np.isnan(v), axis=1) & ~np.all(np.isnan(v), axis=1)
    if np.any(partial) or np.any(np.isinf(v)):
        row = int(np.argmax(partial | np.any(np.isinf(v), axis=1)))
        raise ValueError(
            f"{label}: row {row} is partly missing or infinite (a row is all finite, or all NaN: no observation)"
        )
    if sigma is None:
        raise ValueError(f"{label} needs {name}_sigma (its standard deviation per axis)")
    sig = np.asarray(sigma, dtype=float)
    if sig.ndim > 2 or (sig.ndim >= 1 and sig.shape[0] != n_img) or (sig.ndim == 2 and sig.shape[1] != 3):
        raise ValueError(f"{name}_sigma must be a scalar, (n_images,) or (n_images, 3), got shape {sig.shape}")
    sig = _per_row(sig, n_img, 3)
    seen = np.all(np.isfinite(v), axis=1)
    bad = seen[:, None] & ~(np.isfinite(sig) & (sig > 0))
    if np.any(bad):
        i = int(np.argmax(bad.any(axis=1)))
        raise ValueError(
            f"{name}_sigma must be positive and finite where {label} is given: image {i} has "
            f"{sig[i].tolist()} (to hold a value exactly, fix it with fixed_exterior)"
        )
    return v, np.where(seen[:, None], sig, np.nan)


def _lever_arm(lever_arm, n_img: int, gnss: np.ndarray) -> np.ndarray:
    """``(n_img, 3)`` finite lever arms (default 0); only with GNSS positions."""
    if lever_arm is None:
        return np.zeros((n_img, 3))
    arm = np.array(lever_arm, dtype=float)
    if arm.shape not in ((3,), (n_img, 3)) or not np.all(np.isfinite(arm)):
        raise ValueError(f"lever_arm must be finite, (3,) or (n_images, 3), got shape {arm.shape}")
    arm = np.broadcast_to(arm, (n_img, 3)).copy()
    if np.any(arm != 0) and not np.any(np.isfinite(gnss)):
        raise ValueError("lever_arm is given without gnss_position (it offsets the GNSS antenna)")
    return arm


def _dem_observations(dem, dem_sigma, n_pts: int, crs):
    """The DEM (a :class:`photax.DEM`, or None) and ``(n_pts,)`` sigmas of its
    height observations (> 0 and finite); its horizontal CRS must be ``crs``'s
    where both are known."""
    if dem is None:
        if dem_sigma is not None:
            raise ValueError("dem_sigma is given without dem")
        return None, None
    from ..dem import DEM

    if not isinstance(dem, DEM):
        raise ValueError(f"dem must be a photax.DEM (photax.io.read_dem reads one), got {type(dem).__name__}")
    if dem_sigma is None:
        raise ValueError("dem needs dem_sigma (the standard deviation of its heights, ground unit)")
    sig = np.asarray(dem_sigma, dtype=float)
    if sig.ndim > 1 or (sig.ndim == 1 and sig.shape != (n_pts,)):
        raise ValueError(f"dem_sigma must be a scalar or (n_points,) = ({n_pts},), got shape {sig.shape}")
    sig = np.broadcast_to(sig, (n_pts,)).copy()
    if not np.all(np.isfinite(sig) & (sig > 0)):
        raise ValueError(f"dem_sigma must be positive and finite, got {sig[~(np.isfinite(sig) & (sig > 0))][0]:g}")
    if crs is not None and dem.crs is not None:
        from ..geo import require_same

        require_same(crs, "the block", dem.crs, "the DEM")  # the horizontal parts; heights are the user's
    return dem, sig


def _check_datum(obs_point: np.ndarray, role: np.ndarray, pts: np.ndarray, point_names) -> None:
    """Every point needs a datum: two rays, or one ray plus a control prior;
    control points need surveyed coordinates."""
    counts = np.bincount(obs_point, minlength=len(pts))
    weak = (counts < 2) & (role != "control")
    if np.any(weak):
        i = int(np.argmax(weak))
        label = point_names[i] if point_names is not None else i
        raise ValueError(
            f"point {label} ({role[i]}) is observed on {counts[i]} image(s): tie and check points need "
            "at least 2 to be intersected; drop it or make it a control point"
        )
    ctrl = role == "control"
    if np.any(ctrl & ~np.all(np.isfinite(pts), axis=1)):
        raise ValueError("control points need finite surveyed coordinates")
