"""Calibrated linear starts: the orientation from control points without a guess.

Image points are undistorted to normalised coordinates first
(``camera.normalised``), in OpenCV's frame (x right, y down, z forward);
then two linear solvers, in ``jax.numpy``:

* a homography between the control points' best-fitting plane and the
  normalised image, decomposed with the known interior orientation (Zhang
  2000, sec. 3.1) - for (near-)planar GCPs, the common case;
* the calibrated DLT ``x ~ [M | m] X`` with ``M`` projected onto the
  rotations (Hartley & Zisserman 2003, sec. 7.1) - for 3-D GCP sets.

:func:`linear_start_lanes` solves both from all control points for a batch
of images on the last axis (:mod:`._lanes`: the cheap path);
:func:`candidates`, per image under ``vmap``, also from each random subset
(the robust path's LMedS start), in one batched Cholesky solve
(:func:`cho_solve`): the same formulas, written for each layout.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._linalg import cho_solve, inv3, nearest_rotation
from ..camera import OPENCV_FROM_PHOTAX, undistort
from ..rotation import angles_from_matrix_unchecked, rotation_matrix
from . import _lanes


def rotation(angles, pok):
    """world_from_camera; the convention is a traced flag (``pok``:
    phi-omega-kappa), so both conventions share one compilation."""
    return jnp.where(pok, rotation_matrix(angles, "phi-omega-kappa"), rotation_matrix(angles, "omega-phi-kappa"))


def angles(matrix, pok):
    """Angles of a world_from_camera matrix in the convention ``pok`` names."""
    a = angles_from_matrix_unchecked(matrix, "phi-omega-kappa")[0]
    b = angles_from_matrix_unchecked(matrix, "omega-phi-kappa")[0]
    return jnp.where(pok, a, b)


def opencv_uv(xy, camera):
    """Image-plane ``(m, 2)`` -> undistorted normalised coordinates, y down (OpenCV's frame);
    where the undistortion fails (past a fold) the distorted point, as in :func:`linear_start_lanes`."""
    xd = (xy - camera.principal_point[None]) / camera.focal_length
    xn = camera.normalised(xy)
    xn = jnp.where(jnp.isfinite(xn), xn, xd)
    return jnp.stack([xn[:, 0], -xn[:, 1]], axis=1)


def _normal_equations(rows: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Normal equations for ``v`` minimising ``|rows v|`` with ``v[-1] = 1``,
    padded to 11 unknowns (so homographies and DLTs solve in one call).

    The last unknown is the depth of the centroid of the (centred) ground
    points times the scale: never zero for a camera that sees them.
    """
    a, b = rows[:, :-1], rows[:, -1]
    k = a.shape[1]
    # element-wise sums: under vmap a tiny a.T @ a becomes a batched dot, one small kernel per system
    n = jnp.eye(11).at[:k, :k].set(jnp.sum(a[:, :, None] * a[:, None, :], axis=0))
    return n, jnp.zeros(11).at[:k].set(-jnp.sum(a * b[:, None], axis=0))


def _homography_rows(uv, plane_xy, w, scale):
    """DLT rows of the homography (plane -> normalised image)."""
    a, b = plane_xy[:, 0] / scale, plane_xy[:, 1] / scale
    u, v = uv[:, 0], uv[:, 1]
    o, z = jnp.ones_like(a), jnp.zeros_like(a)
    r1 = jnp.stack([a, b, o, z, z, z, -u * a, -u * b, -u], axis=1)
    r2 = jnp.stack([z, z, z, a, b, o, -v * a, -v * b, -v], axis=1)
    return jnp.concatenate([r1, r2], axis=0) * jnp.concatenate([w, w])[:, None]


def _pose_homography(sol, t_uv, scale, basis):
    """Calibrated homography decomposition -> (R_cv, C) (Zhang 2000, sec. 3.1).

    ``R_cv`` is OpenCV's cam_from_world (x right, y down, z forward).
    """
    h = inv3(t_uv) @ jnp.append(sol[:8], 1.0).reshape(3, 3)  # undo the image normalisation
    lam = 0.5 * (jnp.linalg.norm(h[:, 0]) + jnp.linalg.norm(h[:, 1]))
    c1, c2 = h[:, 0] / lam, h[:, 1] / lam
    r_cv = nearest_rotation(jnp.stack([c1, c2, jnp.cross(c1, c2)], axis=1)) @ basis.T
    return r_cv, -r_cv.T @ (h[:, 2] * scale / lam)


def _dlt_rows(uv, ground, w, scale):
    """Rows of the calibrated DLT ``x ~ [M | m] X``."""
    x = ground / scale
    u, v = uv[:, 0], uv[:, 1]
    xh = jnp.concatenate([x, jnp.ones_like(u)[:, None]], axis=1)
    z4 = jnp.zeros_like(xh)
    r1 = jnp.concatenate([xh, z4, -u[:, None] * xh], axis=1)
    r2 = jnp.concatenate([z4, xh, -v[:, None] * xh], axis=1)
    return jnp.concatenate([r1, r2], axis=0) * jnp.concatenate([w, w])[:, None]


def _pose_dlt(sol, t_uv, scale):
    """DLT solution -> (R_cv, C) (Hartley & Zisserman 2003, sec. 7.1)."""
    p = inv3(t_uv) @ jnp.append(sol, 1.0).reshape(3, 4)
    m = p[:, :3] / scale
    lam = jnp.mean(jnp.linalg.norm(m, axis=1))
    r_cv = nearest_rotation(m)
    return r_cv, -r_cv.T @ (p[:, 3] / lam)


def _sq_errors(r_cv, c, uv, ground):
    """Squared normalised reprojection errors; +inf behind the camera."""
    p = jnp.sum((ground - c[None, :])[:, None, :] * r_cv[None, :, :], axis=2)
    front = p[:, 2] > 0
    zs = jnp.where(front, p[:, 2], 1.0)
    e = jnp.sum((p[:, :2] / zs[:, None] - uv) ** 2, axis=1)
    return jnp.where(front & jnp.isfinite(e), e, jnp.inf)


def candidates(uv, ground, ctrl, basis, subsets):
    """Linear candidates: homography and DLT from all control points, then
    (``subsets`` ``(k, 6)`` indices, ``k`` may be 0) from each subset
    (homography on its first 4 points).

    Returns ``r_cv`` ``(2 + 2k, 3, 3)`` (OpenCV's cam_from_world),
    ``c`` ``(2 + 2k, 3)`` centres (in ``ground``'s frame), ``is_dlt``
    ``(2 + 2k,)`` numpy bool, ``err`` ``(2 + 2k, m)`` squared normalised
    errors (+inf behind the camera or for non-control points).
    """
    wf = ctrl.astype(float)
    n_ctrl = jnp.sum(wf)
    # Hartley normalisation of the image points; the ground is centred.
    mu = jnp.sum(uv * wf[:, None], axis=0) / n_ctrl
    su = jnp.sqrt(jnp.sum(wf * jnp.sum((uv - mu[None, :]) ** 2, axis=1)) / (2.0 * n_ctrl))
    t_uv = jnp.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]]) / su
    t_uv = t_uv.at[:2, 2].set(-mu / su).at[2, 2].set(1.0)
    uvn = (uv - mu[None, :]) / su
    centre = jnp.sum(ground * wf[:, None], axis=0) / n_ctrl
    g = (ground - centre[None, :]) * wf[:, None]
    scale = jnp.sqrt(jnp.sum(g * g) / n_ctrl)
    rel = ground - centre[None, :]
    plane = jnp.sum(rel[:, :, None] * basis[None, :, :2], axis=1)

    # All systems (homography, DLT; all points, then each subset) in one batched solve.
    systems = [
        _normal_equations(_homography_rows(uvn, plane, wf, scale)),
        _normal_equations(_dlt_rows(uvn, rel, wf, scale)),
    ]
    k = subsets.shape[0]
    if k:
        w4 = jnp.ones(subsets.shape[1]).at[4:].set(0.0)  # homography on the first 4
        w6 = jnp.ones(subsets.shape[1])
        systems.append(jax.vmap(lambda s: _normal_equations(_homography_rows(uvn[s], plane[s], w4, scale)))(subsets))
        systems.append(jax.vmap(lambda s: _normal_equations(_dlt_rows(uvn[s], rel[s], w6, scale)))(subsets))
    mats = jnp.concatenate([m[None] for m, _ in systems[:2]] + [m for m, _ in systems[2:]])
    rhs = jnp.concatenate([v[None] for _, v in systems[:2]] + [v for _, v in systems[2:]])
    sols = cho_solve(mats, rhs[..., None])[..., 0]
    is_dlt = np.array([False, True] + [False] * k + [True] * k)
    hom = jax.vmap(lambda s: _pose_homography(s, t_uv, scale, basis))(sols[~is_dlt])
    dlt = jax.vmap(lambda s: _pose_dlt(s, t_uv, scale))(sols[is_dlt])
    order = np.argsort(np.argsort(is_dlt, kind="stable"), kind="stable")  # back to the is_dlt order
    r_all = jnp.concatenate([hom[0], dlt[0]])[order]
    c_all = jnp.concatenate([hom[1], dlt[1]])[order]
    err = jax.vmap(lambda r, c: _sq_errors(r, c, uv, rel))(r_all, c_all)
    err = jnp.where(ctrl[None, :], err, jnp.inf)
    return r_all, c_all + centre[None, :], is_dlt, err


def to_parameters(r_cv, c, pok):
    """OpenCV's cam_from_world and a centre -> ``(C, angles)`` 6-vector."""
    return jnp.concatenate([c, angles(r_cv.T @ jnp.asarray(OPENCV_FROM_PHOTAX), pok)])


def linear_start(uv, ground, ctrl, basis, dlt_ok, pok):
    """The cheap start: homography or DLT from all control points, the one
    with the smaller sum of squared errors (the DLT only with ``dlt_ok``,
    6 or more points).  Returns the 6-vector and whether it is plausible
    (finite, every control point in front of the camera).
    """
    r_all, c_all, is_dlt, err = candidates(uv, ground, ctrl, basis, jnp.zeros((0, 6), int))
    total = jnp.sum(jnp.where(ctrl[None, :], err, 0.0), axis=1)
    total = jnp.where(jnp.asarray(is_dlt) & ~dlt_ok, jnp.inf, total)
    total = jnp.where(jnp.isnan(total), jnp.inf, total)
    best = jnp.argmin(total)
    p = to_parameters(r_all[best], c_all[best], pok)
    return p, jnp.isfinite(total[best]) & jnp.all(jnp.isfinite(p))


def _dlt_normal(xh, u, v, w):
    """Normal equations of the DLT-type rows ``[xh, 0, -u xh]``,
    ``[0, xh, -v xh]`` (``w`` 0 or 1: the control points; ``xh`` ``k`` ``(m, B)``
    arrays whose last is 1, the unknown fixed to 1), from the four weighted
    scatter sums ``sum w c xh xh^T``, ``c`` in ``(1, u, v, u^2 + v^2)``:
    ``(3k - 1, 3k - 1, B)`` and ``(3k - 1, B)``.  (The rows' products
    formed one by one, half of them zero, cost 4x more.)"""
    k = len(xh)
    pairs = [(i, j) for i in range(k) for j in range(i, k)]
    prod = jnp.stack([w * xh[i] * xh[j] for i, j in pairs])  # (np, m, B)
    s = jnp.sum(jnp.stack([jnp.ones_like(u), u, v, u * u + v * v])[:, None] * prod[None], axis=2)  # (4, np, B)
    idx, sign, ridx, rsign = _dlt_layout(k)
    flat = jnp.concatenate([s.reshape(-1, s.shape[-1]), jnp.zeros_like(s[0, :1])])  # last row: zero
    # one gather with a constant index table (stacking 121 entries one by one cost a second of compilation)
    return flat[idx] * sign[..., None], flat[ridx] * rsign[:, None]


@functools.lru_cache(maxsize=4)
def _dlt_layout(k: int):
    """Index and sign tables of :func:`_dlt_normal`: entry ``(r, c)`` of the
    normal matrix is ``sign * s[idx]``, ``s`` the scatter sums flattened
    ``(c, pair)`` with a zero appended."""
    pairs = [(i, j) for i in range(k) for j in range(i, k)]
    at = {pq: n for n, pq in enumerate(pairs)}
    zero = 4 * len(pairs)

    def sym(c, i, j):
        return c * len(pairs) + at[min(i, j), max(i, j)]

    def entry(r, c):
        (br, i), (bc, j) = divmod(r, k), divmod(c, k)
        if br > bc:
            return entry(c, r)
        if br == bc:
            return (sym(3, i, j), 1.0) if br == 2 else (sym(0, i, j), 1.0)
        if bc == 2:  # blocks (0, 2) and (1, 2): -sum u xh xh^T, -sum v xh xh^T
            return sym(1 + br, i, j), -1.0
        return zero, 0.0

    big = 3 * k - 1
    table = [[entry(r, c) for c in range(big)] for r in range(big)]
    rhs = (
        [(sym(1, i, k - 1), 1.0) for i in range(k)]
        + [(sym(2, i, k - 1), 1.0) for i in range(k)]
        + [(sym(3, i, k - 1), -1.0) for i in range(k - 1)]
    )
    return (
        np.array([[e[0] for e in row] for row in table]),
        np.array([[e[1] for e in row] for row in table]),
        np.array([e[0] for e in rhs]),
        np.array([e[1] for e in rhs]),
    )


def _sq_errors_lanes(r_cv, c, uv, rel, ctrl):
    """:func:`_sq_errors` per lane (``(3, 3, B)``, ``(3, B)``, ``(2, m, B)``,
    ``(3, m, B)``): ``(m, B)``, +inf behind the camera and off the control points."""
    p = jnp.stack([sum(r_cv[i, j][None] * (rel[j] - c[j][None]) for j in range(3)) for i in range(3)])
    front = p[2] > 0
    zs = jnp.where(front, p[2], 1.0)
    e = (p[0] / zs - uv[0]) ** 2 + (p[1] / zs - uv[1]) ** 2
    return jnp.where(front & jnp.isfinite(e) & ctrl, e, jnp.inf)


def linear_start_lanes(inp, opt):
    """:func:`linear_start` for a batch of lanes (``inp`` a lanes
    :class:`._types.Inputs`; the same formulas as :func:`candidates` with
    no subsets, written per lane): ``(6, B)`` and ``(B,)``."""
    cam = opt.camera
    xd = (inp.xy - cam.principal_point[:, None, None]) / cam.focal_length
    xd = jnp.moveaxis(xd, 0, -1)  # (m, B, 2)

    def undistorted():  # camera.undistort_normalised; where it fails (past a fold) the distorted point
        xn = undistort(xd, cam.distortion)  # serves as a start: the adjustment uses the forward model
        return jnp.where(jnp.isfinite(xn), xn, xd)

    # No distortion (the common case of a calibrated, undistorted camera): the points are the start.
    x, y = jnp.moveaxis(jax.lax.cond(jnp.any(cam.distortion != 0.0), undistorted, lambda: xd), -1, 0)
    uv = jnp.stack([x, -y])  # OpenCV's frame: y down
    wf = inp.ctrl.astype(float)
    n_ctrl = jnp.sum(wf, axis=0)
    # Hartley normalisation of the image points; the ground is centred.
    mu = jnp.sum(uv * wf[None], axis=1) / n_ctrl[None]
    su = jnp.sqrt(jnp.sum(wf * ((uv[0] - mu[0][None]) ** 2 + (uv[1] - mu[1][None]) ** 2), axis=0) / (2.0 * n_ctrl))
    un, vn = (uv[0] - mu[0][None]) / su[None], (uv[1] - mu[1][None]) / su[None]
    centre = jnp.sum(inp.ground * wf[None], axis=1) / n_ctrl[None]
    rel = inp.ground - centre[:, None]
    scale = jnp.sqrt(jnp.sum(rel * rel * wf[None], axis=(0, 1)) / n_ctrl)
    one = jnp.ones_like(un)
    z1, o1 = jnp.zeros_like(su), jnp.ones_like(su)
    t_inv = jnp.stack([jnp.stack([su, z1, mu[0]]), jnp.stack([z1, su, mu[1]]), jnp.stack([z1, z1, o1])])  # undoes it

    # homography (plane -> normalised image), Zhang 2000 sec. 3.1
    a = sum(rel[i] * inp.basis[i, 0][None] for i in range(3)) / scale[None]
    b = sum(rel[i] * inp.basis[i, 1][None] for i in range(3)) / scale[None]
    h = _lanes.solve_spd(*_dlt_normal([a, b, one], un, vn, wf))
    hm = _lanes.matmul3(t_inv, jnp.concatenate([h, one[:1]]).reshape(3, 3, -1))
    lam_h = 0.5 * (jnp.sqrt(jnp.sum(hm[:, 0] ** 2, axis=0)) + jnp.sqrt(jnp.sum(hm[:, 1] ** 2, axis=0)))
    c1, c2 = hm[:, 0] / lam_h[None], hm[:, 1] / lam_h[None]

    # calibrated DLT x ~ [M | m] X, Hartley & Zisserman 2003 sec. 7.1
    sol = _lanes.solve_spd(*_dlt_normal([rel[i] / scale[None] for i in range(3)] + [one], un, vn, wf))
    pm = jnp.stack(
        [
            sum(t_inv[i, k][None] * jnp.concatenate([sol, one[:1]]).reshape(3, 4, -1)[k] for k in range(3))
            for i in range(3)
        ]
    )  # (3, 4, B)
    mm = pm[:, :3] / _lanes.lane(scale, 3)
    lam_d = jnp.mean(jnp.sqrt(jnp.sum(mm * mm, axis=1)), axis=0)

    # Both rotations in one polar iteration (lanes side by side).
    b_ = un.shape[-1]
    rot = _lanes.nearest_rotation(jnp.concatenate([jnp.stack([c1, c2, _lanes.cross(c1, c2)], axis=1), mm], axis=-1))
    r_h = _lanes.matmul3(rot[..., :b_], jnp.swapaxes(inp.basis, 0, 1))
    r_d = rot[..., b_:]
    c_h = -_lanes.matmul3(jnp.swapaxes(r_h, 0, 1), hm[:, 2] * (scale / lam_h)[None])
    c_d = -_lanes.matmul3(jnp.swapaxes(r_d, 0, 1), pm[:, 3] / lam_d[None])
    two = lambda a: jnp.concatenate([a, a], axis=-1)  # noqa: E731
    err = _sq_errors_lanes(
        jnp.concatenate([r_h, r_d], axis=-1), jnp.concatenate([c_h, c_d], axis=-1), two(uv), two(rel), two(inp.ctrl)
    )
    tot = jnp.sum(jnp.where(two(inp.ctrl), err, 0.0), axis=0)
    tot_h, tot_d = tot[:b_], tot[b_:]
    tot_h = jnp.where(jnp.isnan(tot_h), jnp.inf, tot_h)
    tot_d = jnp.where(jnp.isnan(tot_d) | ~opt.dlt_ok, jnp.inf, tot_d)
    dlt = tot_d < tot_h  # ties: the homography (argmin's first)
    r_cv, c = _lanes.sel(dlt, r_d, r_h), _lanes.sel(dlt, c_d, c_h) + centre
    world = jnp.transpose(r_cv, (2, 1, 0)) * jnp.asarray(np.diag(OPENCV_FROM_PHOTAX))[None, None]  # (B, 3, 3): R_cv^T F
    p = jnp.concatenate([c, angles(world, opt.pok).T])
    return p, jnp.isfinite(jnp.minimum(tot_h, tot_d)) & jnp.all(jnp.isfinite(p), axis=0)
