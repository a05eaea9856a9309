"""Structure analysis of a problem (numpy): index arrays, masks and the
chunking of the reduced-system product.

Done once per problem (:meth:`BundleProblem.analyse` caches it) and in two
parts: the *topology* (:func:`_topology`: which images and points the
observations link, which intrinsics are free; the pair and chunk index
arrays, the costly part) is shared by every problem that
:meth:`BundleProblem.replace` derives with the same links, e.g. the
replicates of a Monte Carlo run that only change ``obs_xy``; the *data*
(measurements, sigmas, control priors, the gauge's fixed parameters) are
added per problem by :func:`_analyse`."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._triangulation import observation_pairs
from ..dem import DEM
from ..rotation import angles_from_matrix_unchecked, axis_angle_to_matrix, rotation_matrix
from ._sparse import band_layout


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
    gnss_xyz: Array  # (n_img, 3) GNSS antenna positions (local origin), 0 where none
    gnss_w: Array  # (n_img, 3) 1/sigma of the GNSS positions, 0 where none
    lever: Array  # (n_img, 3) antenna offset in the camera frame
    att_rot: Array  # (n_img, 3, 3) observed attitude as world_from_camera (identity where none)
    att_map: Array  # (n_img, 3, 3) diag(1/sigma) d(angles)/d(rotation vector) at att_rot, 0 where none
    dem: DEM  # the DEM of the tie points' height observations, local origin (heights too), cropped
    dem_w: Array  # (n_pts,) 1/sigma of each point's DEM height observation, 0 where none
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
    band_perm: Array  # (N, cw) banded layout of the reduced system (_sparse.BandLayout)
    band_border: Array  # (n_b,)
    band_chunk: Array  # (n_c,)
    band_offset: Array  # (n_c,)


class _Topology(NamedTuple):
    """The part of :class:`_Structure` fixed by the observations' links and
    the free intrinsics (device arrays, built once and shared), and the sizes
    ``n_c`` (camera-side unknowns) and ``w`` (camera-side columns per image)."""

    obs_image: Array
    obs_point: Array
    image_ext: Array
    pair_a: Array
    pair_b: Array
    chunk_a: Array
    chunk_b: Array
    chunk_key: Array
    key_a: Array
    key_b: Array
    key_off: Array
    image_chunk: Array
    image_of_chunk: Array
    active: Array
    image_camera: Array
    band_perm: Array
    band_border: Array
    band_chunk: Array
    band_offset: Array
    n_c: int
    w: int


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
    first = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1]]))  # key is sorted: no second sort (np.unique)
    uniq, counts = key[first], np.diff(np.append(first, len(key)))
    kid = np.repeat(np.arange(len(uniq)), counts)
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


def _gauge_mask(problem, gauge) -> np.ndarray:
    """``(n_images, 6)`` extra fixed exterior parameters (:data:`EXTERIOR`
    order) of the chosen gauge of a :class:`BundleProblem`."""
    fixed = np.zeros((problem.n_images, 6), dtype=bool)
    if gauge == "fix_first_camera":
        if problem.n_images < 2:
            raise ValueError("gauge='fix_first_camera' needs at least 2 images")
        fixed[0] = True
        # Scale: fix the second centre's largest baseline component.
        base = np.asarray(problem.exterior.position[1] - problem.exterior.position[0])
        fixed[1, int(np.argmax(np.abs(base)))] = True
    return fixed


def _same_topology(a, b) -> bool:
    """Whether two :class:`BundleProblem` link the same images, cameras and
    points by the same observations and free the same intrinsics (then
    :func:`_topology` gives the same arrays)."""
    return (
        a.n_images == b.n_images and a.n_cameras == b.n_cameras and a.n_points == b.n_points
        and np.array_equal(a.obs_image, b.obs_image) and np.array_equal(a.obs_point, b.obs_point)
        and np.array_equal(a.image_camera, b.image_camera)
        and np.array_equal(a.free_intrinsics.any(axis=0), b.free_intrinsics.any(axis=0))
    )  # fmt: skip


def _topology(problem) -> _Topology:
    """The index arrays of a :class:`BundleProblem` that depend only on its
    links (see :func:`_same_topology`): unknown columns, observation pairs,
    chunks of the reduced-system product."""
    n_img, n_cam = problem.n_images, problem.n_cameras
    active = np.flatnonzero(problem.free_intrinsics.any(axis=0))
    a = len(active)
    w = 6 + a
    cols = np.empty((n_img, w), dtype=np.int64)
    cols[:, :6] = 6 * np.arange(n_img)[:, None] + np.arange(6)[None, :]
    cols[:, 6:] = 6 * n_img + a * problem.image_camera[:, None] + np.arange(a)[None, :]
    n_c = 6 * n_img + a * n_cam
    pa, pb, *_ = observation_pairs(problem.obs_point, problem.obs_image, n_img)
    ca, cb, ck, ka, kb, koff = _chunks(pa, pb, problem.obs_image, problem.n_observations, n_img)
    band = band_layout(cols, ka, kb, n_c)
    # The per-observation and per-pair index arrays in int32 (bounds checked
    # below): they are read on every pass over the observations (the Schur
    # product gathers by chunk_a, chunk_b), half the bytes of int64.
    idx32 = [
        problem.obs_image,
        problem.obs_point,
        cols,
        pa,
        pb,
        ca,
        cb,
        ck,
        ka,
        kb,
        *_image_chunks(problem.obs_image, n_img),
    ]
    if max((int(np.max(v, initial=0)) for v in idx32), default=0) >= 2**31 - 1:
        raise ValueError("the problem has more than 2^31 observations or pairs: too large")
    i32 = [jnp.asarray(v, dtype=jnp.int32) for v in idx32]
    return _Topology(
        *i32[:10], jnp.asarray(koff, dtype=float), *i32[10:],
        jnp.asarray(active), jnp.asarray(problem.image_camera), *(jnp.asarray(v) for v in band), n_c, w,
    )  # fmt: skip


def _analyse(problem, fixed_extra: np.ndarray, origin: np.ndarray, topology: _Topology | None = None):
    """Index arrays, masks and sizes of a :class:`BundleProblem`, with
    ``fixed_extra`` ``(n_images, 6)`` exterior parameters fixed besides the
    problem's own and ground coordinates relative to ``origin`` ``(3,)``;
    ``topology`` (:func:`_topology`, computed when None) is reused as is.
    Returns ``(structure, n_unknowns_c, width)``."""
    t = _topology(problem) if topology is None else topology
    fixed = problem.fixed_exterior | fixed_extra  # EXTERIOR order (X, Y, Z, rx, ry, rz)
    fixed = np.concatenate([fixed[:, 3:], fixed[:, :3]], axis=1)  # internal order: rotation, centre
    active = np.asarray(t.active)
    mask_c = np.concatenate([(~fixed).ravel(), problem.free_intrinsics[:, active].ravel()])
    ctrl = problem.roles == "control"
    hard = ctrl[:, None] & (problem.point_sigma == 0)
    soft = ctrl[:, None] & (problem.point_sigma > 0)
    prior_w = np.where(soft, 1.0 / np.where(soft, problem.point_sigma, 1.0) ** 2, 0.0)
    prior = np.where(ctrl[:, None], problem.points - origin[None, :], 0.0)
    gnss, att = _camera_priors(problem, origin)
    dem, dem_w = _dem_structure(problem, origin)
    s = _Structure(
        t.obs_image, t.obs_point, jnp.asarray(problem.obs_xy), jnp.asarray(problem.obs_sigma), t.image_ext,
        jnp.asarray(mask_c, dtype=float), jnp.asarray(~hard, dtype=float), jnp.asarray(prior), jnp.asarray(prior_w),
        *gnss, *att, dem, jnp.asarray(dem_w),
        t.pair_a, t.pair_b, t.chunk_a, t.chunk_b, t.chunk_key, t.key_a, t.key_b, t.key_off, t.image_chunk,
        t.image_of_chunk, t.active, t.image_camera, t.band_perm, t.band_border, t.band_chunk, t.band_offset,
    )  # fmt: skip
    return s, t.n_c, t.w


@functools.partial(jax.jit, static_argnames=("convention",))
def _angle_jacobian(rot: Array, convention: str) -> Array:
    """``(n, 3, 3)`` d(angles)/d(rotation increment about camera axes): the
    attitude observations' weights (:func:`_camera_priors`) and the
    precision of the angles (:mod:`._precision`)."""

    def angles(dr, r):
        return angles_from_matrix_unchecked(r @ axis_angle_to_matrix(dr), convention)[0]

    return jax.vmap(jax.jacfwd(angles), in_axes=(None, 0))(jnp.zeros(3), rot)


def _camera_priors(problem, origin: np.ndarray):
    """The structure's arrays of the GNSS positions ``(xyz, 1/sigma,
    lever arm)`` and of the attitudes ``(R_obs, map)``: an attitude's
    weighted residual is ``map Log(R_obs^T R)``, its rotation vector mapped
    to angle differences (the convention's Jacobian at ``R_obs``) over
    their sigmas, so it needs no angle convention in the jitted code and
    does not wrap at +-pi."""
    seen = problem.gnss_observed[:, None]
    xyz = np.where(seen, problem.gnss_position - origin[None, :], 0.0)
    w = np.where(seen, 1.0 / np.where(seen, problem.gnss_sigma, 1.0), 0.0)
    gnss = (jnp.asarray(xyz), jnp.asarray(w), jnp.asarray(problem.lever_arm))
    n_img, conv = problem.n_images, problem.exterior.convention
    seen = problem.attitude_observed
    rot = np.broadcast_to(np.eye(3), (n_img, 3, 3)).copy()
    amap = np.zeros((n_img, 3, 3))
    if np.any(seen):
        r_obs = np.asarray(rotation_matrix(jnp.asarray(problem.attitude[seen]), conv))
        rot[seen] = r_obs
        jac = np.asarray(_angle_jacobian(jnp.asarray(r_obs), conv))
        amap[seen] = jac / problem.attitude_sigma[seen][:, :, None]
    return gnss, (jnp.asarray(rot), jnp.asarray(amap))


def dem_observed(problem) -> np.ndarray:
    """``(n_pts,)`` bool: the tie points of ``problem`` whose height is a DEM
    observation: finite start values where the DEM has a height (inside its
    outer pixel centres, no nodata corner)."""
    pts = problem.points
    if problem.dem is None:
        return np.zeros(len(pts), bool)
    ok = (problem.roles == "tie") & np.all(np.isfinite(pts), axis=1)
    z = np.full(len(pts), np.nan)
    if np.any(ok):
        z[ok] = np.asarray(problem.dem.height(jnp.asarray(pts[ok, 0]), jnp.asarray(pts[ok, 1])))
    return ok & np.isfinite(z)


def _dem_structure(problem, origin: np.ndarray):
    """The structure's DEM -- the problem's, cropped to its observed points
    with a margin of half their extent (at least 8 posts), in the local
    origin (``X``, ``Y`` and the heights less ``origin``) -- and the
    ``(n_pts,)`` weights ``1/sigma`` of its height observations (0 where
    none).  Without a DEM, a flat 2 x 2 grid and no weight (one pytree
    shape: the jitted steps need no second form).  ValueError when a DEM is
    given and no tie point lies on it."""
    if problem.dem is None:
        return DEM(np.zeros((2, 2)), (1.0, 0.0, -1.0, 0.0, -1.0, 1.0)), np.zeros(problem.n_points)
    seen = dem_observed(problem)
    if not np.any(seen):
        pts = problem.points[np.all(np.isfinite(problem.points), axis=1)]
        lo, hi = (pts.min(axis=0)[:2], pts.max(axis=0)[:2]) if len(pts) else (np.full(2, np.nan),) * 2
        raise ValueError(
            f"no tie point of the block lies on the DEM (its bounds {tuple(round(v, 1) for v in problem.dem.bounds)}, "
            f"the points' X {lo[0]:.1f}..{hi[0]:.1f}, Y {lo[1]:.1f}..{hi[1]:.1f}; nodata cells give no height): "
            "a DEM of the block's area and CRS is needed"
        )
    dem = problem.dem
    heights = np.asarray(dem.heights)
    a, b, c, d, e, f = np.asarray(dem.transform)
    xy = problem.points[seen, :2]
    margin = 0.5 * (xy.max(axis=0) - xy.min(axis=0))
    corners = np.array([[x, y] for x in (xy[:, 0].min() - margin[0], xy[:, 0].max() + margin[0])
                        for y in (xy[:, 1].min() - margin[1], xy[:, 1].max() + margin[1])])  # fmt: skip
    col, row = (np.asarray(v) for v in dem.ground_to_pixel(jnp.asarray(corners[:, 0]), jnp.asarray(corners[:, 1])))
    rows, cols = heights.shape
    c0 = int(np.clip(np.floor(col.min()) - 8, 0, cols - 2))
    c1 = int(np.clip(np.ceil(col.max()) + 9, c0 + 2, cols))
    r0 = int(np.clip(np.floor(row.min()) - 8, 0, rows - 2))
    r1 = int(np.clip(np.ceil(row.max()) + 9, r0 + 2, rows))
    # The crop's corner pixel (c0, r0) at ground (a c0 + b r0 + c, d c0 + e r0 + f), less the origin.
    x0 = a * c0 + b * r0 + c - origin[0]
    y0 = d * c0 + e * r0 + f - origin[1]
    local = DEM(heights[r0:r1, c0:c1] - origin[2], (a, b, x0, d, e, y0))
    return local, np.where(seen, 1.0 / problem.dem_sigma, 0.0)


class Analysis(NamedTuple):
    """A problem analysed for one gauge (:meth:`BundleProblem.analyse`):
    the structure (a pytree of device arrays for the jitted steps), the
    number of camera-side unknowns ``n_c``, the columns per image ``w`` and
    the local ``origin`` ``(3,)`` (ground unit) the solver works relative to
    (rounded mean of the finite points and projection centres)."""

    structure: _Structure
    n_c: int
    w: int
    origin: np.ndarray


def _origin(problem) -> np.ndarray:
    finite = np.all(np.isfinite(problem.points), axis=1)
    return np.round(np.mean(np.concatenate([problem.points[finite], np.asarray(problem.exterior.position)]), axis=0))
