"""Bundle adjustment: the problem, a Schur-complement Levenberg–Marquardt
solver, robust losses, self-calibration and precision.

The model is the collinearity equations (``docs/conventions.md``) of
:func:`photax.project`: observation ``o`` of point ``X_p`` on image ``i``
(camera ``c = image_camera[i]``) has the residual::

    r_o = (project(X_p; R_i, C_i, camera_c) - xy_o) / sigma_o       (2,)

and the solver minimises (Ceres' convention, 0.5 times the sum of squares)::

    cost = 0.5 sum_o rho(|r_o|^2) + 0.5 sum_{control p} |(X_p - X_p^survey) / sigma_p|^2

with ``rho(s) = s`` (no loss), Huber ``rho(s) = s`` for ``s <= d^2`` else
``2 d sqrt(s) - d^2``, or Cauchy ``rho(s) = d^2 log(1 + s / d^2)``
(``d = loss_scale``, in units of the observation's sigma).  Robust losses
enter each linearisation through Triggs' corrected residual and Jacobian
(Triggs et al. 2000, sec. 4.3; Ceres' ``corrector.cc``; see
:func:`_corrector`)::

    J~ = sqrt(rho') (I - alpha r r^T / |r|^2) J,   1 - alpha = sqrt(max(D, D_min)),
    D  = 1 + 2 |r|^2 rho'' / rho'

so the gradient is exact (``rho' J^T r``) and ``J~^T J~`` carries the loss'
curvature along ``r``.  The first steps reweight only (``alpha = 0``, as Ceres
does for Huber and Cauchy; its quadratic model majorises the loss, a safe
globalisation far from the minimum); once an accepted step lowers the cost by
less than :data:`SECOND_ORDER_AFTER` the correction is switched on, with the
radial curvature floored at :data:`MIN_RADIAL_CURVATURE`.  The LM damping
uses the diagonal of the reweighted matrix ``J^T rho' J`` throughout.  A step
whose cost or norm is not finite is rejected (more damping), never taken.

This is a tuned compromise, not Newton's method: the local rate stays linear
(the floor overestimates the curvature along residuals beyond the scale:
gain ratios near 2 on ``data/block`` with Huber), and both constants come from
a sweep on ``data/block`` and BAL problem-49-7776.  The exact projected
Hessian (floor 0) converges worse: a point whose residuals lie mostly beyond
the scale keeps only their tangential curvature, so the Gauss-Newton matrix
is nearly singular along its depth, its Newton step there is long and
governed by the neglected second derivatives of ``r`` and by residuals
crossing the scale, and one global damping parameter cannot hold those
directions without slowing all others (measured: 25-89 iterations where the
floor 0.1 needs 15-64; Huber on problem-49-7776 stopped at a higher cost).

Parameters (analysed once on the numpy side, then solved by jitted steps):

* per image: the projection centre ``C`` (ground unit) and the attitude
  ``R`` (world_from_camera), updated on the manifold ``R <- R Exp(dr)``
  with ``dr`` a rotation vector about the camera axes, so any orientation
  works (BAL cameras look everywhere);
* per camera (shared by its images): ``f, x0, y0, k1, k2, k3, p1, p2``,
  each free or fixed (self-calibration);
* per point: ``X, Y, Z``.  Tie and check points are free; control points
  are free with a prior ``sigma`` (pseudo-observations), or fixed when
  their sigma is 0.  Check points are adjusted as tie points and compared
  with their surveyed coordinates afterwards.

Each LM step solves ``(J^T J + lambda D) dx = -J^T r`` with
``D = diag(J^T J)`` clamped to ``[1e-6, 1e32]`` (Ceres; with a robust loss
``J~^T J~`` and ``J~^T r~`` and ``D = diag(J^T rho' J)``).  Ordering camera
unknowns ``c`` before points ``p``::

    [U  W] [dc]   [-g_c]                  S  = U - W V^-1 W^T
    [W' V] [dp] = [-g_p]      ->          S dc = -g_c + W V^-1 g_p
                                          dp = -V^-1 (g_p + W^T dc)

``V`` is block diagonal (3x3 per point), so ``V^-1`` is a batch of 3x3
inverses and ``S`` (the reduced camera system) is accumulated from
per-observation blocks: block ``(i, j)`` sums ``W_a V^-1 W_b^T`` over the
pairs of observations ``a`` (image ``i``), ``b`` (image ``j``) of one point,
grouped on the numpy side into fixed-size chunks of one block each so that
the sum is a batch of small GEMMs (see :func:`_reduced_system`).  Jacobians
are closed-form (:func:`_project_obs`).  ``S`` is solved by a dense
Cholesky (fast up to a few thousand camera unknowns: 49 BAL images x 9 =
441) on one BLAS thread.  A rejected step re-solves with the same
linearisation (only the damping changes).  References: Triggs et al.,
"Bundle adjustment — a modern synthesis" (2000); Agarwal et al., "Bundle
adjustment in the large" (ECCV 2010); Ceres Solver's trust-region minimiser.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import sys
import time
from typing import Literal, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ._triangulation import observation_pairs, triangulate
from .camera import FrameCamera
from .collinearity import ExteriorOrientation, stack_exteriors
from .errors import ConvergenceError
from .rotation import angles_from_matrix_unchecked, axis_angle_to_matrix, rotation_matrix
from .scene import block_scene

ROLES = ("tie", "control", "check")
#: Interior-orientation parameters of a camera, in this order.
INTRINSICS = ("f", "x0", "y0", "k1", "k2", "k3", "p1", "p2")
#: Exterior parameters of an image: the projection centre and the rotation
#: increments about the camera's own x, y, z axes.
EXTERIOR = ("X", "Y", "Z", "rx", "ry", "rz")

#: Up to this many camera unknowns the reduced system is solved densely.
DENSE_LIMIT = 4000

Loss = Literal["none", "huber", "cauchy"]
Gauge = Literal["fix_first_camera", "damped"]


# --------------------------------------------------------------------------
# The problem
# --------------------------------------------------------------------------


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
        free_intrinsics: names from :data:`INTRINSICS` estimated for every
            camera (e.g. ``("f", "k1", "k2")``), or an ``(n_cameras, 8)`` bool
            mask.  Default: interior orientation fixed.
        fixed_exterior: ``(n_images,)`` or ``(n_images, 6)`` bool, parameters
            of :data:`EXTERIOR` held at their given values.  Default none.
        image_names, point_names: optional labels used in reports.
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
    ):
        cams = (cameras,) if isinstance(cameras, FrameCamera) else tuple(cameras)
        if not cams or not all(isinstance(c, FrameCamera) for c in cams):
            raise ValueError("cameras must be a FrameCamera or a non-empty sequence of them")
        eo = stack_exteriors(exterior)
        n_img, n_cam = eo.position.shape[0], len(cams)
        pts = np.array(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must have shape (n_points, 3), got {pts.shape}")
        n_pts = len(pts)
        oi, op = np.asarray(obs_image), np.asarray(obs_point)
        xy = np.array(obs_xy, dtype=float)
        k = len(xy)
        if xy.shape != (k, 2) or oi.shape != (k,) or op.shape != (k,):
            raise ValueError(
                f"obs_xy must be (k, 2) and obs_image, obs_point (k,); got {xy.shape}, {oi.shape}, {op.shape}"
            )
        for name, idx, n in (("obs_image", oi, n_img), ("obs_point", op, n_pts)):
            if k and (not np.issubdtype(idx.dtype, np.integer) or idx.min() < 0 or idx.max() >= n):
                raise ValueError(f"{name} must be integers in [0, {n}), got range [{idx.min()}, {idx.max()}]")
        if not np.all(np.isfinite(xy)):
            raise ValueError(f"obs_xy has non-finite values at observation {int(np.argmax(~np.isfinite(xy).all(1)))}")
        sig = np.asarray(obs_sigma, dtype=float)
        sig = np.broadcast_to(sig[:, None] if sig.ndim == 1 else sig, (k, 2)).copy()
        if not np.all(sig > 0):
            raise ValueError("obs_sigma must be positive")
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
        role = np.array(["tie"] * n_pts if roles is None else [str(r) for r in roles], dtype=object)
        if role.shape != (n_pts,) or not set(role.tolist()) <= set(ROLES):
            bad = sorted(set(role.tolist()) - set(ROLES))
            raise ValueError(f"roles must be (n_points,) of {ROLES}; got shape {role.shape}, unknown {bad}")
        psig = np.asarray(point_sigma, dtype=float)
        psig = np.broadcast_to(psig[:, None] if psig.ndim == 1 else psig, (n_pts, 3)).copy()
        if np.any(psig < 0) or np.any(np.isnan(psig)):
            raise ValueError("point_sigma must be >= 0 (0 fixes a control point)")
        if isinstance(free_intrinsics, np.ndarray) and free_intrinsics.dtype == bool:
            free = np.broadcast_to(free_intrinsics, (n_cam, 8)).copy()
        else:
            unknown = set(free_intrinsics) - set(INTRINSICS)
            if unknown or isinstance(free_intrinsics, str):
                raise ValueError(f"free_intrinsics must be names from {INTRINSICS}, got {free_intrinsics!r}")
            free = np.zeros((n_cam, 8), dtype=bool)
            free[:, [INTRINSICS.index(n) for n in free_intrinsics]] = True
        fixed = np.zeros((n_img, 6), dtype=bool) if fixed_exterior is None else np.asarray(fixed_exterior, dtype=bool)
        if fixed.shape == (n_img,):
            fixed = np.repeat(fixed[:, None], 6, axis=1)
        if fixed.shape != (n_img, 6):
            raise ValueError(f"fixed_exterior must be (n_images,) or (n_images, 6), got {fixed.shape}")
        # Every point needs a datum: two rays, or one ray plus a control prior.
        counts = np.bincount(op, minlength=n_pts)
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

    n_images = property(lambda self: self.exterior.position.shape[0])
    n_cameras = property(lambda self: len(self.cameras))
    n_points = property(lambda self: len(self.points))
    n_observations = property(lambda self: len(self.obs_xy))

    def replace(self, **changes) -> "BundleProblem":
        """A copy with some constructor arguments changed."""
        args = dict(
            cameras=self.cameras, exterior=self.exterior, points=self.points, obs_image=self.obs_image,
            obs_point=self.obs_point, obs_xy=self.obs_xy, obs_sigma=self.obs_sigma,
            image_camera=self.image_camera, roles=self.roles, point_sigma=self.point_sigma,
            free_intrinsics=self.free_intrinsics, fixed_exterior=self.fixed_exterior,
            image_names=self.image_names, point_names=self.point_names,
        )  # fmt: skip
        args.update(changes)
        return BundleProblem(**args)

    def __repr__(self) -> str:
        n_ctrl = int(np.sum(self.roles == "control"))
        n_chk = int(np.sum(self.roles == "check"))
        return (
            f"BundleProblem({self.n_images} images, {self.n_cameras} cameras, {self.n_points} points "
            f"({n_ctrl} control, {n_chk} check), {self.n_observations} observations)"
        )


# --------------------------------------------------------------------------
# Structure analysis (numpy, once per problem)
# --------------------------------------------------------------------------


class _Structure(NamedTuple):
    """Index arrays and masks of a problem; a pytree of arrays for jit."""

    obs_image: Array  # (k,)
    obs_point: Array  # (k,)
    obs_xy: Array  # (k, 2)
    obs_sigma: Array  # (k, 2)
    image_ext: Array  # (n_img, w) unknown index of each image's camera-side column
    mask_c: Array  # (N,) 1 free, 0 fixed
    mask_p: Array  # (n_pts, 3)
    prior_xyz: Array  # (n_pts, 3) surveyed control coordinates (local origin)
    prior_w: Array  # (n_pts, 3) 1/sigma^2 of control priors, 0 elsewhere
    pair_a: Array  # (n_pairs,) observations a < b of the same point (covariances)
    pair_b: Array
    chunk_a: Array  # (n_pieces, piece, CHUNK) observation pairs (a, b) of one block of S; k = padding
    chunk_b: Array
    chunk_key: Array  # (n_pieces * piece,) sorted block id of each chunk
    key_a: Array  # (n_keys,) images of each block of S (row, column)
    key_b: Array
    key_off: Array  # (n_keys,) 1.0 for pairs a != b (the block's transpose is added too)
    image_chunk: Array  # (n_ichunks, CHUNK) observations of one image; k = padding
    image_of_chunk: Array  # (n_ichunks,) sorted
    active: Array  # (a,) indices into INTRINSICS estimated for some camera
    image_camera: Array  # (n_img,)


class _State(NamedTuple):
    rot: Array  # (n_img, 3, 3) world_from_camera
    centre: Array  # (n_img, 3) local origin
    intr: Array  # (n_cam, 8)
    xyz: Array  # (n_pts, 3) local origin


#: Observation pairs per chunk of the reduced-system product (one small GEMM
#: per chunk: 16-32 is fastest on XLA CPU for BAL problems), and chunks per
#: piece: pieces are done one after the other so that their gathered operands
#: (a few MB) stay in cache (2x faster than one pass on problem-49-7776).
CHUNK, PIECE = 16, 512


def _chunks(pa: np.ndarray, pb: np.ndarray, obs_image: np.ndarray, n_obs: int, n_img: int):
    """Group observation pairs ``(a, b)`` of the same point -- the pairs
    ``a < b`` and the observations themselves ``(a, a)`` -- by the block of
    ``S`` they add to (image pair, and whether the transpose is added), in
    padded chunks of :data:`CHUNK` pairs of one block each, in pieces of
    :data:`PIECE` chunks: ``(n_pieces, piece, CHUNK)``."""
    a = np.concatenate([np.arange(n_obs), pa])
    b = np.concatenate([np.arange(n_obs), pb])
    off = np.concatenate([np.zeros(n_obs, np.int64), np.ones(len(pa), np.int64)])
    key = (off * n_img + obs_image[a]) * n_img + obs_image[b]
    srt = np.argsort(key, kind="stable")
    a, b, key = a[srt], b[srt], key[srt]
    uniq, kid, counts = np.unique(key, return_inverse=True, return_counts=True)
    n_ch = -(-counts // CHUNK)  # chunks per block
    first_pair = np.concatenate([[0], np.cumsum(counts)[:-1]])
    first_chunk = np.concatenate([[0], np.cumsum(n_ch)[:-1]])
    pos = np.arange(len(key)) - first_pair[kid]
    slot = (first_chunk[kid] + pos // CHUNK) * CHUNK + pos % CHUNK
    piece = max(1, min(PIECE, int(n_ch.sum())))
    n_pieces = -(-int(n_ch.sum()) // piece)
    ca = np.full(n_pieces * piece * CHUNK, n_obs, np.int64)  # padding: index k, gathered as zeros
    cb = ca.copy()
    ca[slot], cb[slot] = a, b
    key_of_chunk = np.full(n_pieces * piece, len(uniq) - 1)
    key_of_chunk[: n_ch.sum()] = np.repeat(np.arange(len(uniq)), n_ch)
    rows, cols = (uniq // n_img) % n_img, uniq % n_img
    shape = (n_pieces, piece, CHUNK)
    return ca.reshape(shape), cb.reshape(shape), key_of_chunk, rows, cols, uniq >= n_img * n_img


def _image_chunks(obs_image: np.ndarray, n_img: int):
    """Observations grouped by image in padded chunks of :data:`CHUNK`."""
    order = np.argsort(obs_image, kind="stable")
    counts = np.bincount(obs_image, minlength=n_img)
    n_ch = -(-counts // CHUNK)
    pos = np.arange(len(order)) - np.repeat(np.cumsum(counts) - counts, counts)
    first_chunk = np.cumsum(n_ch) - n_ch
    idx = np.full(n_ch.sum() * CHUNK, len(order), np.int64)
    idx[(np.repeat(first_chunk, counts) + pos // CHUNK) * CHUNK + pos % CHUNK] = order
    return idx.reshape(-1, CHUNK), np.repeat(np.arange(n_img), n_ch)


def _analyse(problem: BundleProblem, fixed_extra: np.ndarray, origin: np.ndarray) -> tuple[_Structure, int, int]:
    """Index arrays, masks and sizes; returns (structure, n_unknowns_c, width)."""
    n_img, n_cam = problem.n_images, problem.n_cameras
    active = np.flatnonzero(problem.free_intrinsics.any(axis=0))
    a = len(active)
    w = 6 + a
    cols = np.empty((n_img, w), dtype=np.int64)
    cols[:, :6] = 6 * np.arange(n_img)[:, None] + np.arange(6)[None, :]
    cols[:, 6:] = 6 * n_img + a * problem.image_camera[:, None] + np.arange(a)[None, :]
    n_c = 6 * n_img + a * n_cam
    fixed = problem.fixed_exterior | fixed_extra  # EXTERIOR order (X, Y, Z, rx, ry, rz)
    fixed = np.concatenate([fixed[:, 3:], fixed[:, :3]], axis=1)  # internal order: rotation, centre
    mask_c = np.concatenate([(~fixed).ravel(), problem.free_intrinsics[:, active].ravel()])
    ctrl = problem.roles == "control"
    hard = ctrl[:, None] & (problem.point_sigma == 0)
    soft = ctrl[:, None] & (problem.point_sigma > 0)
    prior_w = np.where(soft, 1.0 / np.where(soft, problem.point_sigma, 1.0) ** 2, 0.0)
    prior = np.where(ctrl[:, None], problem.points - origin[None, :], 0.0)
    pa, pb, *_ = observation_pairs(problem.obs_point, problem.obs_image, n_img)
    ca, cb, ck, ka, kb, koff = _chunks(pa, pb, problem.obs_image, problem.n_observations, n_img)
    s = _Structure(
        *(jnp.asarray(v) for v in (problem.obs_image, problem.obs_point, problem.obs_xy, problem.obs_sigma, cols)),
        jnp.asarray(mask_c, dtype=float), jnp.asarray(~hard, dtype=float), jnp.asarray(prior),
        jnp.asarray(prior_w), *(jnp.asarray(v) for v in (pa, pb, ca, cb, ck, ka, kb)), jnp.asarray(koff, dtype=float),
        *(jnp.asarray(v) for v in _image_chunks(problem.obs_image, n_img)), jnp.asarray(active),
        jnp.asarray(problem.image_camera),
    )  # fmt: skip
    return s, n_c, w


# --------------------------------------------------------------------------
# Numerics (jitted; sizes are static, so same-shaped problems share a compile)
# --------------------------------------------------------------------------


def _project_obs(state: _State, s: _Structure, jacobians: bool = False):
    """Image-plane projection of every observation's point, and optionally
    the closed-form Jacobians ``(k, 2, 6 + a)`` w.r.t. the camera-side
    unknowns ``(dr, dC, d_intr_active)`` and ``(k, 2, 3)`` w.r.t. the point.

    With ``q = R^T (X - C)`` (camera frame) and ``R <- R Exp(dr)``::

        dq/ddr = [q]_x,   dq/dC = -R^T,   dq/dX = R^T
        u = -q_xy / q_z,  du/dq = -1/q_z [I_2 | u]

    then the Brown–Conrady distortion (:mod:`photax.camera`) and
    ``x = x0 + f d(u)``, differentiated by hand (no autodiff through
    Rodrigues: 3-5x faster on CPU)."""
    rot = state.rot[s.obs_image]
    k = state.intr[s.image_camera[s.obs_image]]
    q = jnp.einsum("kji,kj->ki", rot, state.xyz[s.obs_point] - state.centre[s.obs_image])
    x, y = -q[:, 0] / q[:, 2], -q[:, 1] / q[:, 2]
    f, k1, k2, k3, p1, p2 = k[:, 0], k[:, 3], k[:, 4], k[:, 5], k[:, 6], k[:, 7]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    proj = k[:, 1:3] + f[:, None] * jnp.stack([xd, yd], axis=1)
    if not jacobians:
        return proj
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    dxx = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    dxy = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y  # = d yd / dx
    dyy = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    g = -f / q[:, 2]
    # d image / d q: f Dd du/dq, rows x and y.
    jq = jnp.stack(
        [jnp.stack([dxx, dxy, dxx * x + dxy * y], axis=1), jnp.stack([dxy, dyy, dxy * x + dyy * y], axis=1)], axis=1
    ) * g[:, None, None]
    qx = jnp.stack([jnp.cross(q, e[None, :]) for e in jnp.eye(3)], axis=-1)  # [q]_x: column i is q x e_i
    j_rot = jnp.einsum("kri,kij->krj", jq, qx)
    jp = jnp.einsum("kri,kji->krj", jq, rot)  # jq R^T
    one, zero = jnp.ones_like(x), jnp.zeros_like(x)
    r4 = r2 * r2
    j_intr = jnp.stack(
        [
            jnp.stack([xd, one, zero, f * x * r2, f * x * r4, f * x * r4 * r2, 2.0 * f * x * y, f * (r2 + 2.0 * x * x)], 1),
            jnp.stack([yd, zero, one, f * y * r2, f * y * r4, f * y * r4 * r2, f * (r2 + 2.0 * y * y), 2.0 * f * x * y], 1),
        ],
        axis=1,
    )  # fmt: skip
    jc = jnp.concatenate([j_rot, -jp, j_intr[:, :, s.active]], axis=2)
    return proj, jc, jp


def _residuals(state: _State, s: _Structure) -> Array:
    """``(k, 2)`` weighted residuals ``(projected - observed) / sigma``."""
    return (_project_obs(state, s) - s.obs_xy) / s.obs_sigma


_LOSS_CODE = {"none": 0, "huber": 1, "cauchy": 2}


def _rho(sq: Array, loss: Array, scale: Array) -> tuple[Array, Array, Array]:
    """Loss ``rho(s)``, ``rho'(s)`` and ``rho''(s)`` for squared norms ``s``;
    ``loss`` is a traced code (0 none, 1 Huber, 2 Cauchy) so changing it
    does not recompile.  Huber outside ``d^2``: ``rho' = d / sqrt(s)``,
    ``rho'' = -rho' / (2 s)``; Cauchy: ``rho' = 1 / (1 + s/d^2)``,
    ``rho'' = -rho'^2 / d^2`` (Ceres' ``HuberLoss``, ``CauchyLoss``)."""
    d2 = scale * scale
    root = jnp.sqrt(jnp.maximum(sq, d2))
    inside = sq <= d2
    h1 = jnp.where(inside, 1.0, scale / root)
    huber = (jnp.where(inside, sq, 2.0 * scale * root - d2), h1, jnp.where(inside, 0.0, -0.5 * h1 / root**2))
    c1 = 1.0 / (1.0 + sq / d2)
    cauchy = (d2 * jnp.log1p(sq / d2), c1, -c1 * c1 / d2)
    rho = jnp.select([loss == 1, loss == 2], [huber[0], cauchy[0]], sq)
    drho = jnp.select([loss == 1, loss == 2], [huber[1], cauchy[1]], jnp.ones_like(sq))
    d2rho = jnp.select([loss == 1, loss == 2], [huber[2], cauchy[2]], jnp.zeros_like(sq))
    return rho, drho, d2rho


#: Floor of the radial curvature factor ``D = 1 + 2 s rho''/rho'`` of a
#: robust residual (see :func:`_corrector`): Huber's ``D`` is 0 beyond its
#: scale and Cauchy's negative beyond it, where the exact per-residual
#: Hessian is singular or indefinite; 0.1 keeps ``1 - alpha >= 0.32``.
#: Tuned: iterations (data/block Huber, Cauchy; problem-49-7776 Cauchy,
#: Huber) were 36 25 89 89 with floor 0, 32 25 90 59 with 0.01, 21 28 87 53
#: with 0.03, 23 15 64 55 with 0.1 and 50+ 21 85 52 with 0.3.
MIN_RADIAL_CURVATURE = 0.1
#: The second-order correction starts after the first accepted step that
#: lowers the cost by less than this fraction: far from the minimum, plain
#: reweighting (whose model overestimates the curvature, a safe majorant) is
#: the more robust globalisation; near it, the corrected model converges
#: faster.
SECOND_ORDER_AFTER = 1e-2


def _corrector(r: Array, rho1: Array, rho2: Array) -> tuple[Array, Array]:
    """Triggs' robustified residual and Jacobian (Triggs et al. 2000, sec.
    4.3; Ceres' ``internal/ceres/corrector.cc``) for ``(k, 2)`` residuals.

    With ``s = |r|^2``, the Hessian of ``0.5 rho(s)`` w.r.t. the residual is
    ``rho' I + 2 rho'' r r^T``, i.e. ``rho'`` across ``r`` and ``rho' D``
    along it, ``D = 1 + 2 s rho''/rho'``.  Its square root is
    ``sqrt(rho') (I - alpha r r^T / s)`` with ``1 - alpha = sqrt(D)``, so::

        J~ = sqrt(rho') (I - alpha r r^T / s) J,   r~ = sqrt(rho') r / (1 - alpha)

    give ``J~^T r~ = rho' J^T r`` (the exact gradient) and ``J~^T J~`` the
    Hessian of the loss up to the second derivatives of ``r`` (Gauss-Newton).
    Ceres applies the correction only where ``rho'' > 0`` and otherwise uses
    plain reweighting (``alpha = 0``), which makes Huber and Cauchy converge
    only linearly when many residuals are beyond the loss scale: their
    curvature along ``r`` is overestimated (by ``1/D``).  Here ``D`` is used
    wherever it is defined, floored at :data:`MIN_RADIAL_CURVATURE` where it
    drops to 0 (Huber) or below (Cauchy): the per-residual Hessian stays
    positive definite and ``1 - alpha`` bounded away from 0.  ``s == 0``:
    ``alpha = 0``.  The solver uses plain reweighting until the cost
    decrease slows (:data:`SECOND_ORDER_AFTER`), then this correction.

    Returns ``(sqrt(rho'), alpha / s)``, ``(k,)`` each; ``alpha / s`` is 0
    for least squares (``rho'' = 0``), so its results are unchanged."""
    sq = jnp.sum(r * r, axis=1)
    radial = jnp.maximum(1.0 + 2.0 * sq * rho2 / rho1, MIN_RADIAL_CURVATURE)
    alpha = 1.0 - jnp.sqrt(radial)
    alpha_sq = jnp.where(sq > 0, alpha / jnp.where(sq > 0, sq, 1.0), 0.0)
    return jnp.sqrt(rho1), alpha_sq


def _prior_residuals(state: _State, s: _Structure) -> Array:
    return (state.xyz - s.prior_xyz) * jnp.sqrt(s.prior_w)


@jax.jit
def _cost(state: _State, s: _Structure, loss: Array, scale: Array) -> Array:
    r = _residuals(state, s)
    rho, _, _ = _rho(jnp.sum(r * r, axis=1), loss, scale)
    return 0.5 * jnp.sum(rho) + 0.5 * jnp.sum(_prior_residuals(state, s) ** 2)


def _outer_sum(a: Array, b: Array) -> Array:
    """``(n, p, q)`` batched ``a @ b^T`` for ``a (n, p, L)``, ``b (n, q, L)``
    with small ``L``, written as ``L`` fused outer products: XLA on CPU runs
    this faster than a batched dot of tiny matrices."""
    return sum(a[:, :, None, l] * b[:, None, :, l] for l in range(a.shape[2]))


def _inv3(m: Array) -> Array:
    """``(n, 3, 3)`` inverses by the adjugate: columns ``r1 x r2, r2 x r0,
    r0 x r1`` over the determinant (rows ``r``); elementwise, so much faster
    than a batched LU on CPU.  A singular block gives inf/NaN, which the
    solver reports as a singular system."""
    r0, r1, r2 = m[:, 0], m[:, 1], m[:, 2]
    adj = jnp.stack([jnp.cross(r1, r2), jnp.cross(r2, r0), jnp.cross(r0, r1)], axis=-1)
    return adj / jnp.sum(r0 * adj[:, :, 0], axis=1)[:, None, None]


class _Lin(NamedTuple):
    cost: Array
    r: Array  # (k, 2) residuals (projected - observed) / sigma, not robustified
    weight: Array  # (k,) rho'(|r|^2) (1 without a robust loss)
    wt: Array  # (k, 3, w) W^T per observation: Jp^T Jc
    u_img: Array  # (n_img, w, w) sum of Jc^T Jc per image
    v: Array  # (n_pts, 3, 3)
    g_img: Array  # (n_img, w)
    g_c: Array  # (N,)
    g_p: Array  # (n_pts, 3)
    d_c: Array  # (N,) diag(J^T J), clamped
    d_p: Array  # (n_pts, 3)
    gmax: Array  # max |g|


@functools.partial(jax.jit, static_argnames=("n_c",))
def _linearise(state: _State, s: _Structure, loss: Array, scale: Array, n_c: int, second_order: Array = True) -> _Lin:
    n_img, n_pts = state.centre.shape[0], state.xyz.shape[0]
    w = 6 + s.active.shape[0]
    proj, jc, jp = _project_obs(state, s, jacobians=True)
    r0 = (proj - s.obs_xy) / s.obs_sigma
    rho, weight, rho2 = _rho(jnp.sum(r0 * r0, axis=1), loss, scale)
    rp = _prior_residuals(state, s)
    cost = 0.5 * jnp.sum(rho) + 0.5 * jnp.sum(rp * rp)
    sqrt_rho1, alpha_sq = _corrector(r0, weight, rho2)
    alpha_sq = jnp.where(second_order, alpha_sq, 0.0)
    # Corrected Jacobian sqrt(rho') (I - alpha r r^T / s) J / sigma (see
    # _corrector); the gradient rho' J^T r / sigma is formed from J itself,
    # which equals J~^T r~ without dividing by 1 - alpha.
    rg = r0 * weight[:, None]

    def correct(j, mask):
        j = j / s.obs_sigma[:, :, None] * mask[:, None, :]
        g = jnp.einsum("kri,kr->ki", j, rg)
        d = jnp.sum(j * j, axis=1) * weight[:, None]  # diagonal of the reweighted J^T rho' J
        j = j - (alpha_sq[:, None] * r0)[:, :, None] * jnp.einsum("kr,krj->kj", r0, j)[:, None, :]
        return j * sqrt_rho1[:, None, None], g, d

    jc, g_obs_c, d_obs_c = correct(jc, s.mask_c[s.image_ext[s.obs_image]])
    jp, g_obs_p, d_obs_p = correct(jp, s.mask_p[s.obs_point])
    seg = functools.partial(jax.ops.segment_sum, num_segments=n_img)
    segp = functools.partial(jax.ops.segment_sum, num_segments=n_pts)
    jct, jpt = jnp.swapaxes(jc, 1, 2), jnp.swapaxes(jp, 1, 2)
    # U_i = sum Jc^T Jc over the image's observations: GEMMs over chunks of them.
    jcc = jnp.take(jc, s.image_chunk, axis=0, mode="fill", fill_value=0.0).reshape(s.image_chunk.shape[0], -1, w)
    u_img = jax.ops.segment_sum(jax.lax.dot_general(jcc, jcc, (((1,), (1,)), ((0,), (0,)))), s.image_of_chunk,
                                num_segments=n_img, indices_are_sorted=True)  # fmt: skip
    g_img = seg(g_obs_c, s.obs_image)
    pw = s.prior_w * s.mask_p
    v = segp(_outer_sum(jpt, jpt), s.obs_point) + pw[:, :, None] * jnp.eye(3)[None, :, :]
    g_p = segp(g_obs_p, s.obs_point) + pw * (state.xyz - s.prior_xyz)
    flat = s.image_ext.ravel()
    g_c = jnp.zeros(n_c).at[flat].add(g_img.ravel())
    # LM damping D: the diagonal of the reweighted normal matrix J^T rho' J
    # (Ceres' damping for Huber and Cauchy, whose robustified Jacobian has
    # alpha = 0), not that of the corrected matrix, which shrinks (by up to
    # 1 / MIN_RADIAL_CURVATURE) along residuals beyond the loss scale, where
    # the corrected model is least reliable: damping those directions less
    # gave long steps and runs of rejections right after the switch (BAL
    # problem-49-7776, Cauchy: 95 iterations, 17 rejected; with this D: 64).
    # Without the correction both are the same matrix: its diagonal is used
    # as before, so least squares is unchanged bit for bit.
    use_irls = (loss != 0) & jnp.any(alpha_sq != 0.0)
    d_c = jnp.where(use_irls, jnp.zeros(n_c).at[flat].add(seg(d_obs_c, s.obs_image).ravel()),
                    jnp.zeros(n_c).at[flat].add(jnp.diagonal(u_img, axis1=1, axis2=2).ravel()))  # fmt: skip
    d_p = jnp.where(use_irls, segp(d_obs_p, s.obs_point) + pw, jnp.diagonal(v, axis1=1, axis2=2))
    clamp = functools.partial(jnp.clip, min=1e-6, max=1e32)
    gmax = jnp.maximum(jnp.max(jnp.abs(g_c), initial=0.0), jnp.max(jnp.abs(g_p), initial=0.0))
    return _Lin(cost, r0, weight, _outer_sum(jpt, jct), u_img, v, g_img, g_c, g_p, clamp(d_c), clamp(d_p), gmax)


def _schur_parts(lin: _Lin, s: _Structure, lam: Array, n_c: int):
    """Damped ``V^-1``, ``Y^T = V^-1 W^T`` per observation ``(k, 3, w)`` and
    the reduced right-hand side ``g_c - W V^-1 g_p`` (in unknown order)."""
    n_img = lin.u_img.shape[0]
    v = lin.v + (lam * lin.d_p * s.mask_p + (1.0 - s.mask_p))[:, :, None] * jnp.eye(3)[None, :, :]
    vinv = _inv3(v)
    vo = vinv[s.obs_point]
    # Unrolled over the 3-long axis: faster than a batched dot of tiny matrices on XLA CPU.
    yt = sum(vo[:, :, j, None] * lin.wt[:, None, j, :] for j in range(3))
    vg = sum(vo[:, :, j] * lin.g_p[s.obs_point][:, j, None] for j in range(3))  # V^-1 g_p per observation
    rhs_img = lin.g_img - jax.ops.segment_sum(jnp.sum(lin.wt * vg[:, :, None], axis=1), s.obs_image, num_segments=n_img)
    rhs = jnp.zeros(n_c).at[s.image_ext.ravel()].add(rhs_img.ravel())
    return vinv, yt, rhs


def _reduced_system(lin: _Lin, s: _Structure, lam: Array, n_c: int):
    """Dense Schur complement ``S`` (undamped diagonal) and right-hand side.

    ``S = U - W V^-1 W^T``, block ``(i, j)`` summed over the points seen
    by images ``i`` and ``j``: ``- sum Y_a W_b^T`` over pairs of
    observations ``(a, b)`` of one point (``a == b`` included).  The pairs
    come in chunks of one block each, so the sum is batched GEMMs of
    ``(w x 3 CHUNK) (3 CHUNK x w)`` products and a small sorted segment sum;
    blocks of pairs ``a < b`` are added with their transposes."""
    vinv, yt, rhs = _schur_parts(lin, s, lam, n_c)
    n_pieces, piece, _ = s.chunk_a.shape
    w = yt.shape[2]
    take = functools.partial(jnp.take, axis=0, mode="fill", fill_value=0.0)  # index k pads the chunks

    def products(idx):  # (piece, w, w): Y_a W_b^T summed over each chunk
        ya, wb = take(yt, idx[0]).reshape(piece, -1, w), take(lin.wt, idx[1]).reshape(piece, -1, w)
        return jax.lax.dot_general(ya, wb, (((1,), (1,)), ((0,), (0,))))

    prod = jax.lax.map(products, (s.chunk_a, s.chunk_b)).reshape(n_pieces * piece, w, w)
    blocks = jax.ops.segment_sum(prod, s.chunk_key, num_segments=s.key_a.shape[0], indices_are_sorted=True)
    ext = s.image_ext
    ra, cb = ext[s.key_a], ext[s.key_b]
    S = jnp.zeros((n_c, n_c)).at[ext[:, :, None], ext[:, None, :]].add(lin.u_img)
    S = S.at[ra[:, :, None], cb[:, None, :]].add(-blocks)
    S = S.at[cb[:, :, None], ra[:, None, :]].add(-jnp.swapaxes(blocks, 1, 2) * s.key_off[:, None, None])
    return S, rhs, vinv


def _solve_cg(lin: _Lin, s: _Structure, lam: Array, n_c: int):
    """Solve the damped reduced system matrix-free by conjugate gradients
    (Ceres' ITERATIVE_SCHUR with a Jacobi preconditioner): ``S x`` is
    ``U x - W (V^-1 (W^T x))`` with per-observation blocks, so ``S`` is
    never formed; memory stays linear in the observations."""
    vinv, yt, rhs = _schur_parts(lin, s, lam, n_c)
    ext, n_img, n_pts, wo = s.image_ext, lin.u_img.shape[0], lin.v.shape[0], jnp.swapaxes(lin.wt, 1, 2)
    damp = lam * lin.d_c * s.mask_c + (1.0 - s.mask_c)
    diag_img = jnp.diagonal(lin.u_img, axis1=1, axis2=2) - jax.ops.segment_sum(
        jnp.sum(yt * lin.wt, axis=1), s.obs_image, num_segments=n_img
    )
    pre = jnp.zeros(n_c).at[ext.ravel()].add(diag_img.ravel()) + damp

    def matvec(x):
        xe = x[ext]  # (n_img, w)
        ux = jnp.einsum("nij,nj->ni", lin.u_img, xe)
        t = jax.ops.segment_sum(jnp.einsum("kij,ki->kj", wo, xe[s.obs_image]), s.obs_point, num_segments=n_pts)
        z = jnp.einsum("pij,pj->pi", vinv, t)
        wz = jax.ops.segment_sum(jnp.einsum("kij,kj->ki", wo, z[s.obs_point]), s.obs_image, num_segments=n_img)
        return jnp.zeros(n_c).at[ext.ravel()].add((ux - wz).ravel()) + damp * x

    x, _ = jax.scipy.sparse.linalg.cg(matvec, rhs, tol=1e-8, maxiter=200, M=lambda v: v / pre)
    return x, vinv


@functools.partial(jax.jit, static_argnames=("n_c", "solver"))
def _trial(state: _State, lin: _Lin, s: _Structure, lam: Array, loss: Array, scale: Array, n_c: int,
           solver: str = "dense"):  # fmt: skip
    """One damped step: returns the candidate state, its cost, the predicted
    decrease, the step norm and the parameter norm."""
    if solver == "dense":
        S, rhs, vinv = _reduced_system(lin, s, lam, n_c)
        S = S + jnp.diag(lam * lin.d_c * s.mask_c + (1.0 - s.mask_c))
        chol = (jax.lax.linalg.cholesky(S, symmetrize_input=False), True)  # S is symmetric by construction
        dc = -jax.scipy.linalg.cho_solve(chol, rhs) * s.mask_c
    else:
        x, vinv = _solve_cg(lin, s, lam, n_c)
        dc = -x * s.mask_c
    dce = dc[s.image_ext]  # (n_img, w)
    wdc = jax.ops.segment_sum(jnp.sum(lin.wt * dce[s.obs_image][:, None, :], axis=2), s.obs_point,
                              num_segments=state.xyz.shape[0])  # fmt: skip
    dp = -jnp.sum(vinv * (lin.g_p + wdc)[:, None, :], axis=2) * s.mask_p
    n_img, n_cam = state.centre.shape[0], state.intr.shape[0]
    a = s.active.shape[0]
    dimg = dc[: 6 * n_img].reshape(n_img, 6)
    dintr = dc[6 * n_img :].reshape(n_cam, a)
    new = _State(
        state.rot @ axis_angle_to_matrix(dimg[:, :3]),
        state.centre + dimg[:, 3:],
        state.intr.at[:, s.active].add(dintr),
        state.xyz + dp,
    )
    # Model decrease L(0) - L(h) = 0.5 h^T (lam D h - g)  (Madsen et al. 2004).
    pred = 0.5 * (jnp.sum(dc * (lam * lin.d_c * dc - lin.g_c)) + jnp.sum(dp * (lam * lin.d_p * dp - lin.g_p)))
    step = jnp.sqrt(jnp.sum(dc * dc) + jnp.sum(dp * dp))
    xnorm = jnp.sqrt(jnp.sum(new.centre**2) + jnp.sum(new.intr**2) + jnp.sum(new.xyz**2))
    new_cost = _cost(new, s, loss, scale)
    ok = jnp.isfinite(new_cost) & jnp.isfinite(step)
    return new, jnp.where(ok, new_cost, jnp.inf), pred, step, xnorm


@functools.partial(jax.jit, static_argnames=("n_c",))
def _covariances(lin: _Lin, s: _Structure, n_c: int):
    """Cofactor matrices (inverse normal matrix blocks) at ``lam = 0``:
    the full reduced-camera inverse ``(N, N)`` and the point blocks
    ``(n_pts, 3, 3)`` via ``Q_p = V^-1 + Y^T S^-1 Y`` with ``Y = W V^-1``."""
    S, _, vinv = _reduced_system(lin, s, jnp.zeros(()), n_c)
    S = S + jnp.diag(1.0 - s.mask_c)
    chol = (jax.lax.linalg.cholesky(S, symmetrize_input=False), True)  # S is symmetric by construction
    q_c = jax.scipy.linalg.cho_solve(chol, jnp.eye(n_c)) * (s.mask_c[:, None] * s.mask_c[None, :])
    y = jnp.einsum("kji,kjl->kil", lin.wt, vinv[s.obs_point])
    ext = s.image_ext
    eo = ext[s.obs_image]
    n_pts = lin.v.shape[0]
    qd = jnp.einsum("kia,kij,kjb->kab", y, q_c[eo[:, :, None], eo[:, None, :]], y)
    ea, eb = eo[s.pair_a], eo[s.pair_b]
    qo = jnp.einsum("pia,pij,pjb->pab", y[s.pair_a], q_c[ea[:, :, None], eb[:, None, :]], y[s.pair_b])
    q_p = vinv + jax.ops.segment_sum(qd, s.obs_point, num_segments=n_pts)
    q_p = q_p + jax.ops.segment_sum(qo + jnp.swapaxes(qo, 1, 2), s.obs_point[s.pair_a], num_segments=n_pts)
    q_p = q_p * (s.mask_p[:, :, None] * s.mask_p[:, None, :])
    return q_c, q_p, jnp.all(jnp.isfinite(chol[0]))


@functools.partial(jax.jit, static_argnames=("convention",))
def _angle_jacobian(rot: Array, convention: str) -> Array:
    """``(n, 3, 3)`` d(angles)/d(rotation increment about camera axes)."""

    def angles(dr, r):
        return angles_from_matrix_unchecked(r @ axis_angle_to_matrix(dr), convention)[0]

    return jax.vmap(jax.jacfwd(angles), in_axes=(None, 0))(jnp.zeros(3), rot)


# --------------------------------------------------------------------------
# The result
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class BundleResult:
    """Adjusted block, its precision and the solver's report.

    Attributes:
        exterior: ``(n_images,)`` adjusted :class:`ExteriorOrientation`, in the
            problem's angle convention.
        rotation: ``(n_images, 3, 3)`` world_from_camera matrices (well
            defined even where angles are in gimbal lock).
        cameras: adjusted cameras (self-calibrated parameters updated).
        points: ``(n_points, 3)`` adjusted ground coordinates.
        cost: final ``0.5 sum rho(|r|^2)`` (+ control priors), weighted.
        initial_cost: the cost at the start values.
        history: one dict per iteration: ``iteration, cost, lambda,
            step_norm, gradient_max, accepted, seconds``.
        converged, message: stopping status; ``message`` names the rule.
        iterations: number of iterations (accepted and rejected steps).
        residuals: ``(k, 2)`` image-plane residuals ``projected - observed``
            (camera unit).
        weights: ``(k,)`` final IRLS weights (1 without a robust loss).
        sigma0: a-posteriori standard deviation of unit weight
            ``sqrt(sum w r^2 / redundancy)``.
        redundancy: observations minus free parameters (plus the datum
            defect for ``gauge="damped"``).
        exterior_std: ``(n_images, 6)`` standard deviations of ``X, Y, Z``
            and the three angles (radians, the convention's order), or None
            when the datum is not defined (``gauge="damped"``).
        camera_std: ``(n_cameras, 8)`` std of :data:`INTRINSICS` (0 = fixed).
        point_std: ``(n_points, 3)`` std of ``X, Y, Z``.
        point_cov: ``(n_points, 3, 3)`` covariances.
        check_residuals: ``(n_check, 3)`` adjusted minus surveyed check points.
        problem: the adjusted problem (for :meth:`to_problem`).
    """

    exterior: ExteriorOrientation
    rotation: np.ndarray
    cameras: tuple[FrameCamera, ...]
    points: np.ndarray
    cost: float
    initial_cost: float
    history: list
    converged: bool
    message: str
    iterations: int
    residuals: np.ndarray
    weights: np.ndarray
    sigma0: float
    redundancy: int
    exterior_std: np.ndarray | None
    camera_std: np.ndarray | None
    point_std: np.ndarray | None
    point_cov: np.ndarray | None
    check_residuals: np.ndarray
    problem: BundleProblem
    seconds: float = 0.0

    @property
    def check_names(self) -> list[str]:
        return [n for n, r in zip(self.problem.point_names, self.problem.roles) if r == "check"]

    def to_problem(self) -> BundleProblem:
        """The problem with the adjusted values as start values."""
        tie = (self.problem.roles == "tie")[:, None]
        pts = np.where(tie, self.points, self.problem.points)
        return self.problem.replace(cameras=self.cameras, exterior=self.exterior, points=pts)

    def report(self, unit: str | None = None) -> str:
        """A plain-text summary: convergence, sigma0, residuals, precision.

        ``unit``: the ground CRS's unit (``"m"``, ``"ft"``...) for the
        exterior and point precision; default "ground units".
        """
        p = self.problem
        rms = np.sqrt(np.mean(self.residuals**2, axis=0))
        u = unit or "ground units"

        def n_of(n, word):  # "1 camera", "2 cameras"
            return f"{n} {word}{'' if n == 1 else 's'}"

        n_ctrl, n_chk = int(np.sum(p.roles == "control")), int(np.sum(p.roles == "check"))
        lines = [
            f"bundle adjustment: {n_of(p.n_images, 'image')}, {n_of(p.n_cameras, 'camera')}, "
            f"{n_of(p.n_points, 'point')} ({n_ctrl} control, {n_chk} check), {n_of(p.n_observations, 'observation')}",
            f"  {'converged' if self.converged else 'NOT converged'}: {self.message} after {n_of(self.iterations, 'iteration')} "
            f"({self.seconds:.2f} s)",
            f"  cost {self.initial_cost:.6g} -> {self.cost:.6g}; sigma0 {self.sigma0:.4g} (redundancy {self.redundancy})",
            f"  image residual RMS x {rms[0]:.4g}, y {rms[1]:.4g} (camera units); max |r| "
            f"{np.max(np.abs(self.residuals)):.4g}",
        ]
        if np.any(self.weights < 0.5):
            lines.append(f"  {n_of(int(np.sum(self.weights < 0.5)), 'observation')} down-weighted below 0.5 by the robust loss")
        if self.exterior_std is not None:
            s = np.median(self.exterior_std, axis=0)
            lines.append(
                f"  median std of exterior: X {s[0]:.4g}, Y {s[1]:.4g}, Z {s[2]:.4g} {u}, angles "
                f"{np.degrees(s[3]) * 3600:.3g}\" {np.degrees(s[4]) * 3600:.3g}\" {np.degrees(s[5]) * 3600:.3g}\""
            )
            ps = np.median(self.point_std[p.roles != "control"], axis=0) if np.any(p.roles != "control") else None
            if ps is not None:
                lines.append(f"  median std of tie/check points: X {ps[0]:.4g}, Y {ps[1]:.4g}, Z {ps[2]:.4g} {u}")
        else:
            lines.append("  precision not reported: the datum is free (gauge='damped')")
        free = p.free_intrinsics
        for c, cam in enumerate(self.cameras):
            if free[c].any():
                vals = np.concatenate([[float(cam.focal_length)], np.asarray(cam.principal_point), np.asarray(cam.distortion)])
                parts = [
                    f"{n} {vals[j]:.6g}" + (f" +- {self.camera_std[c, j]:.2g}" if self.camera_std is not None else "")
                    for j, n in enumerate(INTRINSICS) if free[c, j]
                ]  # fmt: skip
                lines.append(f"  camera {c}: " + ", ".join(parts))
                if c >= 5 and len(self.cameras) > 6:
                    lines.append(f"  ... ({n_of(len(self.cameras) - 6, 'more self-calibrated camera')})")
                    break
        if len(self.check_residuals):
            crms = np.sqrt(np.mean(self.check_residuals**2, axis=0))
            lines.append(
                f"  check points ({len(self.check_residuals)}): RMS X {crms[0]:.4g}, Y {crms[1]:.4g}, Z {crms[2]:.4g} {u}"
            )
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-ready summary (lists of floats)."""
        p = self.problem
        eo = self.exterior
        out = {
            "converged": self.converged, "message": self.message, "iterations": self.iterations,
            "cost": self.cost, "initial_cost": self.initial_cost, "sigma0": self.sigma0 if math.isfinite(self.sigma0) else None,
            "redundancy": self.redundancy, "convention": eo.convention, "seconds": self.seconds,
            "history": self.history,
            "images": [
                {"name": n, "position": np.asarray(eo.position[i]).tolist(), "angles_rad": np.asarray(eo.angles[i]).tolist(),
                 **({"std": self.exterior_std[i].tolist()} if self.exterior_std is not None else {})}
                for i, n in enumerate(p.image_names)
            ],
            "cameras": [
                {"focal_length": float(c.focal_length), "principal_point": np.asarray(c.principal_point).tolist(),
                 "distortion": np.asarray(c.distortion).tolist(),
                 **({"std": self.camera_std[j].tolist()} if self.camera_std is not None else {})}
                for j, c in enumerate(self.cameras)
            ],
            "check_points": [
                {"name": n, "residual": r.tolist()} for n, r in zip(self.check_names, self.check_residuals)
            ],
        }  # fmt: skip
        return out


# --------------------------------------------------------------------------
# The solver
# --------------------------------------------------------------------------


def _datum_constraints(problem: BundleProblem) -> int:
    """Rough count of datum constraints (a network needs 7)."""
    n_ctrl = int(np.sum(problem.roles == "control"))
    return 3 * n_ctrl + int(problem.fixed_exterior.sum())


def _gauge_mask(problem: BundleProblem, gauge) -> np.ndarray:
    """Extra fixed exterior parameters for the chosen gauge."""
    fixed = np.zeros((problem.n_images, 6), dtype=bool)
    if gauge == "fix_first_camera":
        if problem.n_images < 2:
            raise ValueError("gauge='fix_first_camera' needs at least 2 images")
        fixed[0] = True
        # Scale: fix the second centre's largest baseline component.
        base = np.asarray(problem.exterior.position[1] - problem.exterior.position[0])
        fixed[1, int(np.argmax(np.abs(base)))] = True
    return fixed


def _blas_threads(n_c: int):
    """One BLAS thread for the small dense factorisations of the reduced
    system: OpenBLAS' thread pool spins, and on a busy 2-core machine a
    441 x 441 Cholesky took 10-100x longer with 2 threads than with 1."""
    if n_c > 1500:  # large systems gain from threads
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits

    return threadpool_limits(1, user_api="blas")


def bundle_adjust(
    problem: BundleProblem,
    *,
    loss: Loss = "none",
    loss_scale: float = 1.0,
    method: Literal["levenberg-marquardt", "gauss-newton"] = "levenberg-marquardt",
    gauge: Gauge | None = None,
    max_steps: int = 50,
    function_tolerance: float = 1e-6,
    gradient_tolerance: float = 1e-10,
    parameter_tolerance: float = 1e-8,
    initial_trust_radius: float = 1e4,
    linear_solver: Literal["auto", "dense", "cg"] = "auto",
    precision: bool = True,
    initialize: bool | Literal["auto"] = "auto",
    verbose: bool = False,
    progress: bool | str = False,
    throw: bool = True,
    max_iterations: int | None = None,
) -> BundleResult:
    """Adjust a block by (robust) Levenberg–Marquardt with a Schur complement.

    Args:
        problem: the :class:`BundleProblem`.
        loss: ``"none"`` (least squares), ``"huber"`` or ``"cauchy"``.
        loss_scale: ``d``, the residual norm (in sigmas) where the robust loss
            starts to down-weight.
        method: ``"levenberg-marquardt"`` (Ceres-like trust region) or
            ``"gauss-newton"`` (undamped steps, all accepted).
        gauge: the datum of a network without enough control:
            ``"fix_first_camera"`` fixes the first image's orientation and
            the largest baseline component of the second image's centre (7
            parameters); ``"damped"`` leaves the 7-parameter datum defect to
            the LM damping, as Ceres does for BAL problems (the solution is
            one of the equivalent ones; precision is not reported).  ``None``
            (default) refuses a network whose datum is not defined by control
            points or fixed orientations.
        max_steps: iterations counted as Ceres does (accepted and
            rejected steps).  ``max_iterations`` is its old name (still
            accepted).
        function_tolerance, gradient_tolerance, parameter_tolerance: the
            stopping rule (Ceres' defaults), tested after each step::

                |cost_old - cost_new| <= function_tolerance * cost_old      (accepted steps)
                max |g| <= gradient_tolerance,  g = J^T r                   (at each new point)
                |dx| <= parameter_tolerance * (|x| + parameter_tolerance)   (each computed step)

            ``|x|`` is the norm of centres, intrinsics and points (local
            origin).
        initial_trust_radius: ``mu``; the damping is ``lambda = 1/mu``.  After
            a step with gain ratio ``rho > 1e-3``: ``mu /= max(1/3, 1 -
            (2 rho - 1)^3)``, else ``mu /= nu, nu *= 2`` (Nielsen; Ceres).
        linear_solver: how the reduced camera system ``S`` is solved:
            ``"dense"`` Cholesky (``S`` formed, ``N^2`` memory), ``"cg"``
            matrix-free preconditioned conjugate gradients (``S`` never
            formed; for large blocks), ``"auto"``: dense up to
            :data:`DENSE_LIMIT` camera unknowns.
        precision: compute sigma0 and standard deviations (needs the dense
            inverse of ``S``: skipped with a note above
            :data:`DENSE_LIMIT` x 2 unknowns).
        initialize: fill NaN orientations / points with
            :func:`initialize_block` (``"auto"``: only when some are NaN).
        verbose: print one line per iteration.
        progress: a progress bar over the iterations: ``True`` (labelled
            "bundle"), a label, or an open bar (:mod:`photax.progress`).
        throw: raise :class:`photax.ConvergenceError` when the adjustment fails
            (no convergence within ``max_steps``, singular normal
            equations); else return the result with ``converged=False``.

    Returns:
        :class:`BundleResult`.
    """
    # photax says max_steps (as optimistix and resect do); the loop below still
    # counts in Ceres' word, max_iterations.
    max_iterations = max_steps if max_iterations is None else max_iterations
    if loss not in ("none", "huber", "cauchy"):
        raise ValueError(f"loss must be 'none', 'huber' or 'cauchy', got {loss!r}")
    if method not in ("levenberg-marquardt", "gauss-newton"):
        raise ValueError(f"method must be 'levenberg-marquardt' or 'gauss-newton', got {method!r}")
    if gauge not in (None, "fix_first_camera", "damped"):
        raise ValueError(f"gauge must be None, 'fix_first_camera' or 'damped', got {gauge!r}")
    if not loss_scale > 0:
        raise ValueError(f"loss_scale must be positive, got {loss_scale}")
    if gauge is None and _datum_constraints(problem) < 7:
        raise ValueError(
            "the network has no datum: fewer than 3 control points and no fixed orientations "
            "(7 parameters: translation, rotation, scale are free). Add control points, fix "
            "orientations (fixed_exterior=), or choose gauge='fix_first_camera' or gauge='damped' "
            "(LM damping handles the defect, as Ceres does for BAL)"
        )
    if initialize is True or (initialize == "auto" and _needs_init(problem)):
        problem = initialize_block(problem)
    if _needs_init(problem):
        raise ValueError("problem has NaN orientations or points: give start values or initialize=True")
    t_start = time.perf_counter()
    finite = np.all(np.isfinite(problem.points), axis=1)
    origin = np.round(np.mean(np.concatenate([problem.points[finite], np.asarray(problem.exterior.position)]), axis=0))
    s, n_c, _ = _analyse(problem, _gauge_mask(problem, gauge), origin)
    intr = np.stack([np.concatenate([[float(c.focal_length)], np.asarray(c.principal_point), np.asarray(c.distortion)]) for c in problem.cameras])
    state = _State(
        _rotation(problem.exterior.angles, convention=problem.exterior.convention),
        jnp.asarray(np.asarray(problem.exterior.position) - origin[None, :]),
        jnp.asarray(intr), jnp.asarray(problem.points - origin[None, :]),
    )  # fmt: skip
    if linear_solver not in ("auto", "dense", "cg"):
        raise ValueError(f"linear_solver must be 'auto', 'dense' or 'cg', got {linear_solver!r}")
    solver = linear_solver if linear_solver != "auto" else ("dense" if n_c <= DENSE_LIMIT else "cg")
    kw = dict(loss=jnp.asarray(_LOSS_CODE[loss]), scale=jnp.asarray(float(loss_scale)), n_c=n_c)
    with _blas_threads(n_c):
        second = loss == "none"
        lin = _linearise(state, s, **kw, second_order=second)
        cost = initial_cost = float(lin.cost)
        gn = method == "gauss-newton"
        mu, nu = float(initial_trust_radius), 2.0
        history: list[dict] = []
        message, converged = "", False
        bar = None
        if progress:  # one bar, labelled "bundle" or by the caller (photax.progress)
            from .progress import progress_bar

            bar_context = progress_bar(progress, max_iterations, desc="bundle", unit="it")
            bar = bar_context.__enter__()
        gmax = float(lin.gmax)
        if gmax <= gradient_tolerance:
            message, converged = f"gradient tolerance: max|g| = {gmax:.3g} <= {gradient_tolerance:g}", True
        it = 0
        while not converged and it < max_iterations:
            it += 1
            t0 = time.perf_counter()
            lam = 0.0 if gn else 1.0 / mu
            new, new_cost, pred, step, xnorm = _trial(state, lin, s, jnp.asarray(lam), **kw, solver=solver)
            new_cost, pred, step, xnorm = float(new_cost), float(pred), float(step), float(xnorm)
            rho = (cost - new_cost) / pred if pred > 0 else -1.0
            accepted = (gn and math.isfinite(new_cost)) or (rho > 1e-3 and math.isfinite(new_cost))
            old = cost
            if accepted:
                state, cost = new, new_cost
                if not second and old - cost <= SECOND_ORDER_AFTER * old:
                    second = True
                lin = _linearise(state, s, **kw, second_order=second)
                gmax = float(lin.gmax)
                mu = mu / max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                mu, nu = min(mu, 1e16), 2.0
            else:
                mu, nu = mu / nu, nu * 2.0
            history.append(dict(iteration=it, cost=cost, candidate_cost=new_cost if math.isfinite(new_cost) else None, relative_decrease=rho, trust_radius=mu,
                                step_norm=step, gradient_max=gmax, accepted=bool(accepted), seconds=time.perf_counter() - t0))  # fmt: skip
            if verbose:
                status = "ok" if accepted else "rejected" if math.isfinite(new_cost) else "rejected (no finite step)"
                line = (f"{it:4d}  cost {cost:.6e}  cost_change {old - cost:+.3e}  |g| {gmax:.2e}  |step| {step:.2e}  "
                        f"tr_radius {mu:.2e}  {status}")  # fmt: skip
                if hasattr(bar, "write"):  # through the bar, which clears and redraws itself around the line
                    bar.write(line, file=sys.stdout)
                else:
                    print(line, flush=True)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(cost=f"{cost:.4g}")
            if not math.isfinite(step) and (gn or mu < 1e-32):
                message = "the normal equations are singular (datum defect or undetermined parameters)"
                break
            if accepted and abs(old - cost) <= function_tolerance * old:
                message, converged = f"function tolerance: |dcost|/cost = {abs(old - cost) / max(old, 1e-300):.3g} <= {function_tolerance:g}", True
            elif accepted and gmax <= gradient_tolerance:
                message, converged = f"gradient tolerance: max|g| = {gmax:.3g} <= {gradient_tolerance:g}", True
            elif math.isfinite(step) and step <= parameter_tolerance * (xnorm + parameter_tolerance):
                message, converged = f"parameter tolerance: |dx| = {step:.3g} <= {parameter_tolerance:g} (|x| + tol)", True
            elif not gn and mu < 1e-32:
                message = "trust region radius below 1e-32: no decrease possible"
                break
        if bar is not None:
            bar_context.__exit__(None, None, None)  # closes a bar of its own, not a caller's
        if not converged and not message:
            message = f"no convergence within max_iterations = {max_iterations}"
        return _finish(problem, state, lin, s, n_c, origin, gauge, precision, cost, initial_cost, history, converged,
                       message, it, throw, time.perf_counter() - t_start)  # fmt: skip


# Jitted once: eagerly, each of their few dozen jnp operations compiles on first use.
_rotation = jax.jit(rotation_matrix, static_argnames="convention")
_angles = jax.jit(angles_from_matrix_unchecked, static_argnames="convention")


def _finish(problem, state, lin, s, n_c, origin, gauge, precision, cost, initial_cost, history, converged, message,
            iterations, throw, seconds) -> BundleResult:  # fmt: skip
    conv = problem.exterior.convention
    rot = np.asarray(state.rot)
    angles, _ = _angles(state.rot, convention=conv)
    eo = ExteriorOrientation(np.asarray(state.centre) + origin[None, :], np.asarray(angles), conv)
    intr = np.asarray(state.intr)
    cams = tuple(
        FrameCamera(k[0], k[1:3], k[3:], pixel_size=c.pixel_size, image_size=c.image_size)
        for k, c in zip(intr, problem.cameras)
    )
    pts = np.asarray(state.xyz) + origin[None, :]
    weight = np.asarray(lin.weight)
    residuals = np.asarray(lin.r) * problem.obs_sigma
    n_free = int(np.asarray(s.mask_c).sum() + np.asarray(s.mask_p).sum())
    n_prior = int(np.sum(np.asarray(s.prior_w) > 0))
    redundancy = 2 * problem.n_observations + n_prior - n_free + (7 if gauge == "damped" else 0)
    wsq = float(np.sum(weight[:, None] * np.asarray(lin.r) ** 2) + np.sum((np.asarray(state.xyz) - np.asarray(s.prior_xyz)) ** 2 * np.asarray(s.prior_w)))
    sigma0 = math.sqrt(wsq / redundancy) if redundancy > 0 else float("nan")
    eo_std = cam_std = pt_std = pt_cov = None
    if precision and n_c > 2 * DENSE_LIMIT:
        message += f"; precision not computed ({n_c} camera unknowns > {2 * DENSE_LIMIT})"
    elif precision and gauge != "damped":
        q_c, q_p, ok = _covariances(lin, s, n_c)
        if not bool(ok):
            converged = False
            message = "the normal equations are singular at the solution (datum defect or undetermined parameters)"
        else:
            var0 = sigma0**2 if redundancy > 0 else 1.0
            q_c, q_p = np.asarray(q_c), np.asarray(q_p)
            n_img = problem.n_images
            blocks = np.stack([q_c[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] for i in range(n_img)])
            # Reorder to (centre, rotation) and map rotation increments to angles.
            cen = blocks[:, 3:, 3:]
            jac = np.asarray(_angle_jacobian(state.rot, conv))
            ang = np.einsum("nij,njk,nlk->nil", jac, blocks[:, :3, :3], jac)
            eo_std = np.sqrt(var0 * np.concatenate([np.diagonal(cen, 0, 1, 2), np.diagonal(ang, 0, 1, 2)], axis=1))
            a = np.asarray(s.active)
            cam_std = np.zeros((problem.n_cameras, 8))
            dq = np.diagonal(q_c)[6 * n_img :].reshape(problem.n_cameras, len(a))
            cam_std[:, a] = np.sqrt(var0 * np.maximum(dq, 0.0))
            pt_cov = var0 * q_p
            pt_std = np.sqrt(np.maximum(np.diagonal(pt_cov, 0, 1, 2), 0.0))
    check = problem.roles == "check"
    result = BundleResult(
        exterior=eo, rotation=rot, cameras=cams, points=pts, cost=float(cost), initial_cost=float(initial_cost),
        history=history, converged=bool(converged), message=message, iterations=iterations, residuals=residuals,
        weights=weight, sigma0=sigma0, redundancy=redundancy, exterior_std=eo_std, camera_std=cam_std,
        point_std=pt_std, point_cov=pt_cov, check_residuals=pts[check] - problem.points[check], problem=problem,
        seconds=seconds,
    )  # fmt: skip
    if throw and not result.converged:
        raise ConvergenceError(f"bundle adjustment failed: {message}")
    return result


# --------------------------------------------------------------------------
# Start values
# --------------------------------------------------------------------------


def _needs_init(problem: BundleProblem) -> bool:
    eo = np.concatenate([np.asarray(problem.exterior.position), np.asarray(problem.exterior.angles)], axis=1)
    return bool(np.any(~np.isfinite(eo)) or np.any(~np.isfinite(problem.points)))


def initialize_block(problem: BundleProblem, *, min_control: int = 4) -> BundleProblem:
    """Start values for a block: resection, then forward intersection.

    Images whose orientation is NaN are resected (:func:`photax.resect`)
    from the control points they see (at least ``min_control``); then tie
    and check points whose coordinates are NaN are intersected
    (:func:`photax.intersect`) from all oriented images that see them.
    Check points are never used as control here.
    """
    pos = np.array(problem.exterior.position)
    ang = np.array(problem.exterior.angles)
    conv = problem.exterior.convention
    pts = problem.points.copy()
    ctrl = problem.roles == "control"
    todo = ~np.all(np.isfinite(np.concatenate([pos, ang], axis=1)), axis=1)
    if np.any(todo):
        from .resection import resect

        for i in np.flatnonzero(todo):
            sel = (problem.obs_image == i) & ctrl[problem.obs_point]
            if sel.sum() < min_control:
                raise ValueError(
                    f"{problem.image_names[i]}: no start orientation and only {int(sel.sum())} control points "
                    f"(resection needs {min_control}); give its exterior orientation"
                )
            cam = problem.cameras[problem.image_camera[i]]
            res = resect(problem.obs_xy[sel], pts[problem.obs_point[sel]], cam, sigma=problem.obs_sigma[sel, 0],
                         convention=conv, throw=True)  # fmt: skip
            ext = res.exterior
            pos[i], ang[i] = np.asarray(ext.position), np.asarray(ext.angles)
    exterior = ExteriorOrientation(pos, ang, conv)
    missing = ~np.all(np.isfinite(pts), axis=1) & ~ctrl
    if np.any(missing):
        # The linear intersection of photax.intersect (without its refinement,
        # which is a bundle adjustment itself).
        sel = missing[problem.obs_point]
        new_index = np.cumsum(missing) - 1
        cams = [problem.cameras[c] for c in problem.image_camera]
        xyz, *_ = triangulate(
            problem.obs_xy[sel], problem.obs_image[sel], new_index[problem.obs_point[sel]], int(missing.sum()),
            exterior, cams,
        )  # fmt: skip
        pts[missing] = xyz
    return problem.replace(exterior=exterior, points=pts)


# --------------------------------------------------------------------------
# A synthetic block with known truth (tests, notebook, demo, data/block);
# generated by photax.scene.block_scene, packed here into a BundleProblem
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SyntheticBlock:
    """Truth of :func:`synthetic_block`: the problem was generated from it."""

    exterior: ExteriorOrientation
    points: np.ndarray
    camera: FrameCamera


def synthetic_block(
    seed: int = 0,
    *,
    strips: int = 2,
    images_per_strip: int = 4,
    n_tie: int = 100,
    n_control: int = 6,
    n_check: int = 4,
    noise_px: float = 0.5,
    flying_height: float = 600.0,
    relief: float = 60.0,
    tilt_deg: float = 2.0,
    focal_px: float = 3000.0,
    distortion=(0.0, 0.0, 0.0, 0.0, 0.0),
    start_error: tuple[float, float, float] = (5.0, 0.01, 3.0),
    unknown_start: bool = False,
    convention: str = "omega-phi-kappa",
) -> tuple[BundleProblem, SyntheticBlock]:
    """An aerial block (strips of 60 % forward / 30 % side overlap) with truth.

    4000 x 3000 px frames, ``focal_px`` principal distance, flown at
    ``flying_height`` m over terrain of heights ``0 .. relief`` m, each image
    tilted by up to ``tilt_deg``.  Ground coordinates are UTM-like (~5e5,
    4e6 m).  Control points sit on the block's border (``n_control``), check
    points inside.  Control points are fixed (sigma 0); give them a sigma
    with :meth:`BundleProblem.replace` (``point_sigma=``).
    Measurements are the true projections plus Gaussian noise of
    ``noise_px`` (and ``obs_sigma = noise_px``, or 1 px for noise 0).

    Start values: the truth perturbed by ``start_error = (position m,
    angle rad, tie-point m)``, or NaN (``unknown_start=True``) for
    :func:`initialize_block`.

    Returns:
        ``(problem, truth)``.
    """
    b = block_scene(
        seed, strips=strips, images_per_strip=images_per_strip, n_tie=n_tie, n_control=n_control, n_check=n_check,
        noise_px=noise_px, flying_height=flying_height, relief=relief, tilt_deg=tilt_deg, focal_px=focal_px,
        distortion=distortion, start_error=start_error, unknown_start=unknown_start, convention=convention,
    )  # fmt: skip
    problem = BundleProblem(
        b.camera, b.start_exterior, b.start_points, b.obs_image, b.obs_point, b.obs_xy,
        obs_sigma=b.obs_sigma, roles=b.roles, image_names=b.image_names, point_names=b.point_names,
    )  # fmt: skip
    return problem, SyntheticBlock(b.exterior, b.points, b.camera)
