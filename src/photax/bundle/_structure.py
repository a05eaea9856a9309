"""Structure analysis of a problem (numpy): index arrays, masks and the
chunking of the reduced-system product."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array

from .._triangulation import observation_pairs
from ._problem import BundleProblem


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
