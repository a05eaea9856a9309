"""Iterations of the robust bundle adjustment of ``data/block``: photax vs
Ceres from the same start, same loss, scale and stopping rule.

Run:  python benchmarks/robust_iterations.py [huber] [cauchy]

Ceres 2.2 through pyceres: one Python cost function per observation (the
residual ``(x - xy) / sigma`` of photax's collinearity model, ``docs/
conventions.md``, with its closed-form Jacobian), the attitude as a unit
quaternion on Ceres' ``QuaternionManifold``, control points constant,
``HuberLoss(1)`` / ``CauchyLoss(1)`` on the sigma-scaled residuals (photax's
``loss_scale=1``), LM with DENSE_SCHUR, Ceres' default tolerances, one
thread.  Both start from photax's ``initialize_block`` values, so their
initial costs agree (printed).  Measured (2026-11): Huber photax 9, Ceres
163; Cauchy photax 14, Ceres 44; photax's final cost the lower in both.
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pyceres
from scipy.spatial.transform import Rotation

import photax as ptx
from photax.bundle import initialize_block
from photax.io.block import read_block

BLOCK = pathlib.Path(__file__).resolve().parents[1] / "data" / "block"


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class _Reprojection(pyceres.CostFunction):
    """``(x0 - f q_xy / q_z - xy) / sigma`` with ``q = R^T (X - C)``, ``R``
    of the unit quaternion ``(w, u)``: ``R^T = (w^2 - |u|^2) I + 2 u u^T - 2 w [u]_x``."""

    def __init__(self, xy, f, x0, sigma):
        super().__init__()
        self.set_num_residuals(2)
        self.set_parameter_block_sizes([4, 3, 3])
        self.xy, self.f, self.x0, self.sigma = xy, f, x0, sigma

    def Evaluate(self, params, residuals, jacobians):
        quat, centre, point = params
        w, u = quat[0], quat[1:]
        v = point - centre
        rt = (w * w - u @ u) * np.eye(3) + 2.0 * np.outer(u, u) - 2.0 * w * _skew(u)
        q = rt @ v
        residuals[:] = (self.x0 - self.f * q[:2] / q[2] - self.xy) / self.sigma
        if jacobians is not None:
            dq = self.f / self.sigma * np.array([[-1 / q[2], 0, q[0] / q[2] ** 2], [0, -1 / q[2], q[1] / q[2] ** 2]])
            if jacobians[0] is not None:
                dw = 2.0 * w * v - 2.0 * np.cross(u, v)
                du = -2.0 * np.outer(v, u) + 2.0 * (u @ v) * np.eye(3) + 2.0 * np.outer(u, v) + 2.0 * w * _skew(v)
                jacobians[0][:] = (dq @ np.column_stack([dw, du])).ravel()
            if jacobians[1] is not None:
                jacobians[1][:] = (-dq @ rt).ravel()
            if jacobians[2] is not None:
                jacobians[2][:] = (dq @ rt).ravel()
        return True


def ceres_block(problem, loss: str):
    """Ceres' summary on ``problem`` (``initialize_block``-ed) with ``loss``."""
    origin = np.round(problem.points.mean(0))
    rot = np.asarray(ptx.rotation_matrix(problem.exterior.angles, convention=problem.exterior.convention))
    quats = [np.roll(Rotation.from_matrix(r).as_quat(), 1).copy() for r in rot]  # (w, x, y, z)
    centres = [np.array(c) for c in np.asarray(problem.exterior.position) - origin]
    points = [np.array(x) for x in problem.points - origin]
    cam = problem.cameras[0]
    if len(problem.cameras) != 1 or np.any(np.asarray(cam.distortion) != 0) or problem.free_intrinsics.any():
        raise ValueError("this comparison models one fixed distortion-free camera (data/block)")
    lossf = {"none": None, "huber": pyceres.HuberLoss(1.0), "cauchy": pyceres.CauchyLoss(1.0)}[loss]
    prob, keep = pyceres.Problem(), []
    for k in range(problem.n_observations):
        i, j = problem.obs_image[k], problem.obs_point[k]
        c = _Reprojection(problem.obs_xy[k].copy(), float(cam.focal_length), np.asarray(cam.principal_point),
                          float(np.ravel(problem.obs_sigma[k])[0]))  # fmt: skip
        keep.append(c)
        prob.add_residual_block(c, lossf, [quats[i], centres[i], points[j]])
    for q in quats:
        prob.set_manifold(q, pyceres.QuaternionManifold())
    for j in np.flatnonzero(problem.roles == "control"):
        prob.set_parameter_block_constant(points[j])
    opts = pyceres.SolverOptions()
    opts.linear_solver_type = pyceres.LinearSolverType.DENSE_SCHUR
    opts.max_num_iterations = 300
    opts.num_threads = 1
    summary = pyceres.SolverSummary()
    pyceres.solve(opts, prob, summary)
    return summary


def main(argv=None) -> int:
    losses = (argv if argv is not None else sys.argv[1:]) or ["huber", "cauchy"]
    problem = initialize_block(read_block(BLOCK))
    for loss in losses:
        s = ceres_block(problem, loss)
        res = ptx.bundle_adjust(problem, loss=loss, throw=False)
        print(f"{loss}: Ceres {s.num_successful_steps + s.num_unsuccessful_steps} iterations, cost "
              f"{s.initial_cost:.6f} -> {s.final_cost:.8f} ({s.termination_type.name}); photax {res.iterations} "
              f"iterations, cost {res.initial_cost:.6f} -> {res.cost:.8f} ({res.message})")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
