"""Bundle adjustment of BAL problem-49-7776: photax vs SciPy vs Ceres.

Run:  python benchmarks/bench_bundle.py [--repeat 3] [--scipy-repeat 1]

Peers, all in this one process on the same input:

* **SciPy**: the SciPy Cookbook recipe "Large-scale bundle adjustment in
  scipy" reproduced as published (``least_squares(method='trf',
  x_scale='jac', ftol=1e-4, jac_sparsity=...)``, its own numpy projection).
  It stops early (published: cost 1.3409e+04 after 15 evaluations), so we
  also quote photax's time to reach SciPy's final cost, from photax's
  iteration history.
* **Ceres** 2.2 through pycolmap's C++ reprojection cost (COLMAP's RADIAL
  camera ``f, cx, cy, k1, k2`` is BAL's camera: see :func:`ceres_bal`),
  Levenberg–Marquardt, DENSE_SCHUR and SPARSE_SCHUR, no robust loss, Ceres'
  default tolerances (function 1e-6, gradient 1e-10, parameter 1e-8, 50
  iterations), ``num_threads = 2`` (this machine has 2 cores).

COLMAP's cost sets the residual of a point behind the camera to zero, BAL's
formula does not (it projects it through the mirror), and 10 points (31
observations) of problem-49-7776 lie behind the cameras that see them.  The
photax-vs-Ceres comparison therefore drops those 10 points for both solvers,
so both minimise the same function; every final cost printed is recomputed
with the numpy BAL formula from the solver's output parameters.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _common import mib, peak_memory, record, start  # noqa: E402

import photax  # noqa: E402
from photax.camera import OPENCV_FROM_PHOTAX  # noqa: E402
from photax.io.bal import BALData, bal_problem, photax_to_bal, read_bal_arrays  # noqa: E402

DATA = pathlib.Path(__file__).resolve().parents[2] / "shared" / "data" / "problem-49-7776-pre.txt"


# --------------------------------------------------------------------------
# Independent numpy BAL model
# --------------------------------------------------------------------------


def bal_points_in_camera(cameras, points, d: BALData):
    c = cameras[d.camera_index]
    return Rotation.from_rotvec(c[:, :3]).apply(points[d.point_index]) + c[:, 3:6]


def bal_cost(cameras, points, d: BALData) -> float:
    """BAL's 0.5 sum |r|^2, straight from the format's formula."""
    c = cameras[d.camera_index]
    P = bal_points_in_camera(cameras, points, d)
    p = -P[:, :2] / P[:, 2:3]
    r2 = np.sum(p * p, axis=1)
    r = (c[:, 6] * (1.0 + c[:, 7] * r2 + c[:, 8] * r2 * r2))[:, None] * p - d.observations
    return 0.5 * float(np.sum(r * r))


def drop_points_behind(d: BALData) -> BALData:
    """Remove points seen behind a camera (BAL ``P_z > 0``), reindexed."""
    behind = bal_points_in_camera(d.cameras, d.points, d)[:, 2] > 0
    keep = np.ones(len(d.points), dtype=bool)
    keep[d.point_index[behind]] = False
    sel = keep[d.point_index]
    new_id = np.cumsum(keep) - 1
    return BALData(d.cameras, d.points[keep], d.camera_index[sel], new_id[d.point_index[sel]], d.observations[sel])


# --------------------------------------------------------------------------
# SciPy Cookbook recipe (verbatim maths, wrapped in functions)
# --------------------------------------------------------------------------


def _rotate(points, rot_vecs):
    theta = np.linalg.norm(rot_vecs, axis=1)[:, np.newaxis]
    with np.errstate(invalid="ignore"):
        v = rot_vecs / theta
        v = np.nan_to_num(v)
    dot = np.sum(points * v, axis=1)[:, np.newaxis]
    cos_theta = np.cos(theta)
    sin_theta = np.sin(theta)
    return cos_theta * points + sin_theta * np.cross(v, points) + dot * (1 - cos_theta) * v


def _project(points, camera_params):
    points_proj = _rotate(points, camera_params[:, :3])
    points_proj += camera_params[:, 3:6]
    points_proj = -points_proj[:, :2] / points_proj[:, 2, np.newaxis]
    f, k1, k2 = camera_params[:, 6], camera_params[:, 7], camera_params[:, 8]
    n = np.sum(points_proj**2, axis=1)
    r = 1 + k1 * n + k2 * n**2
    points_proj *= (r * f)[:, np.newaxis]
    return points_proj


def _fun(params, n_cameras, n_points, camera_indices, point_indices, points_2d):
    camera_params = params[: n_cameras * 9].reshape((n_cameras, 9))
    points_3d = params[n_cameras * 9 :].reshape((n_points, 3))
    points_proj = _project(points_3d[point_indices], camera_params[camera_indices])
    return (points_proj - points_2d).ravel()


def _sparsity(n_cameras, n_points, camera_indices, point_indices):
    m = camera_indices.size * 2
    n = n_cameras * 9 + n_points * 3
    A = lil_matrix((m, n), dtype=int)
    i = np.arange(camera_indices.size)
    for s in range(9):
        A[2 * i, camera_indices * 9 + s] = 1
        A[2 * i + 1, camera_indices * 9 + s] = 1
    for s in range(3):
        A[2 * i, n_cameras * 9 + point_indices * 3 + s] = 1
        A[2 * i + 1, n_cameras * 9 + point_indices * 3 + s] = 1
    return A


def scipy_recipe(d: BALData):
    """The Cookbook run; returns (cameras, points, scipy result)."""
    m, n = len(d.cameras), len(d.points)
    x0 = np.hstack((d.cameras.ravel(), d.points.ravel()))
    A = _sparsity(m, n, d.camera_index, d.point_index)
    res = least_squares(
        _fun, x0, jac_sparsity=A, verbose=0, x_scale="jac", ftol=1e-4, method="trf",
        args=(m, n, d.camera_index, d.point_index, d.observations),
    )  # fmt: skip
    return res.x[: 9 * m].reshape(m, 9), res.x[9 * m :].reshape(n, 3), res


# --------------------------------------------------------------------------
# Ceres through pycolmap's C++ reprojection cost
# --------------------------------------------------------------------------

# COLMAP's camera looks along +z with y down; BAL's along -z with y up.
# P_colmap = F P_bal with F = photax.camera.OPENCV_FROM_PHOTAX = diag(1, -1, -1)
# (a rotation by pi about x; BAL's camera frame is photax's), so
# (x, y)_colmap = (P_x, P_y)/P_z in COLMAP = (x, -y)_bal, and RADIAL's
# f (1 + k1 r^2 + k2 r^4) on normalised coordinates with cx = cy = 0 is BAL's.
_FLIP = OPENCV_FROM_PHOTAX


def ceres_bal(d: BALData, linear_solver: str = "DENSE_SCHUR", num_threads: int = 2, *, loss: str = "none",
              loss_scale: float = 1.0, max_num_iterations: int | None = None):
    """Build the BAL problem as a pycolmap reconstruction and a Ceres solver.

    Returns ``(solve, to_bal)``: ``solve()`` runs Ceres and returns its
    summary; ``to_bal()`` returns the current ``(cameras (m, 9), points)``
    in BAL's convention.  Ceres' own default tolerances and iteration limit
    (unless ``max_num_iterations`` is given).  ``loss``: ``"none"``,
    ``"huber"`` or ``"cauchy"`` (Ceres' HuberLoss / CauchyLoss of parameter
    ``loss_scale`` pixels on each 2-vector reprojection residual).
    """
    import pyceres
    import pycolmap

    rec = pycolmap.Reconstruction()
    m = len(d.cameras)
    idx_in_image = np.empty(len(d.observations), dtype=np.int64)
    for i, cam in enumerate(d.cameras):
        rec.add_camera_with_trivial_rig(
            pycolmap.Camera(model="RADIAL", width=1, height=1, params=[cam[6], 0.0, 0.0, cam[7], cam[8]], camera_id=i + 1)
        )
        sel = np.flatnonzero(d.camera_index == i)
        idx_in_image[sel] = np.arange(len(sel))
        R = _FLIP @ Rotation.from_rotvec(cam[:3]).as_matrix()
        img = pycolmap.Image(name=str(i), keypoints=d.observations[sel] * np.array([[1.0, -1.0]]), camera_id=i + 1, image_id=i + 1)
        rec.add_image_with_trivial_frame(img, pycolmap.Rigid3d(np.hstack([R, (_FLIP @ cam[3:6])[:, None]])))
    order = np.argsort(d.point_index, kind="stable")
    tracks = np.split(order, np.flatnonzero(np.diff(d.point_index[order])) + 1)
    ids = [
        rec.add_point3D(d.points[j], pycolmap.Track([pycolmap.TrackElement(int(d.camera_index[o]) + 1, int(idx_in_image[o])) for o in obs]))
        for j, obs in enumerate(tracks)
    ]  # fmt: skip
    opts = pycolmap.BundleAdjustmentOptions(
        refine_focal_length=True, refine_extra_params=True, refine_principal_point=False, print_summary=False
    )
    opts.ceres.auto_select_solver_type = False
    opts.ceres.loss_function_type = getattr(pycolmap.LossFunctionType, {"none": "TRIVIAL"}.get(loss, loss.upper()))
    opts.ceres.loss_function_scale = loss_scale
    so, default = opts.ceres.solver_options, pyceres.SolverOptions()
    for name in ("function_tolerance", "gradient_tolerance", "parameter_tolerance", "max_num_iterations"):
        setattr(so, name, getattr(default, name))  # COLMAP overrides them; use Ceres' own
    if max_num_iterations is not None:
        so.max_num_iterations = max_num_iterations
    so.linear_solver_type = getattr(pyceres.LinearSolverType, linear_solver)
    so.num_threads = num_threads
    config = pycolmap.BundleAdjustmentConfig()
    for i in range(m):
        config.add_image(i + 1)
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(opts, config, rec)

    def solve(_alive=(rec, opts, config)):  # the adjuster points into these: keep them alive
        return adjuster.solve().ceres_summary

    def to_bal():
        cams = d.cameras.copy()
        for i in range(m):
            cfw = rec.image(i + 1).cam_from_world().matrix()
            p = rec.camera(i + 1).params
            cams[i, :3] = Rotation.from_matrix(_FLIP @ cfw[:, :3]).as_rotvec()
            cams[i, 3:] = [*(_FLIP @ cfw[:, 3]), p[0], p[3], p[4]]
        return cams, np.array([rec.point3D(k).xyz for k in ids])

    return solve, to_bal


# --------------------------------------------------------------------------
# photax
# --------------------------------------------------------------------------


def photax_bal(problem, **kw):
    """photax's adjustment of a BAL problem (LM, no robust loss, Ceres' tolerances)."""
    return photax.bundle_adjust(problem, gauge="damped", precision=False, throw=False, **kw)


def photax_solution(result):
    cams = photax_to_bal(result.cameras, result.rotation, np.asarray(result.exterior.position))
    return cams, np.asarray(result.points)


def time_to_cost(result, target: float) -> float:
    """Seconds photax needed to first reach ``cost <= target`` (setup included)."""
    setup = result.seconds - sum(h["seconds"] for h in result.history)
    t = setup
    for h in result.history:
        t += h["seconds"]
        if h["cost"] <= target:
            return t
    return float("nan")


def _child_peak(kind: str, path: str) -> int:
    """Peak memory of one solve, measured in a fresh process (spawned), so
    pages freed by earlier runs in the parent do not hide allocations."""
    clean = drop_points_behind(read_bal_arrays(path))
    if kind == "photax":
        photax_bal(bal_problem(clean))  # compile first: measure the warm run
        return peak_memory(lambda: photax_bal(bal_problem(clean)))[1]
    return peak_memory(lambda: ceres_bal(clean, kind, num_threads=2)[0]())[1]


def fresh_peak(kind: str, path) -> int:
    import multiprocessing

    pool = multiprocessing.get_context("spawn").Pool(1)
    try:
        return pool.apply(_child_peak, (kind, str(path)))
    finally:
        pool.close()  # a clean exit: terminate() would trip glog's SIGTERM handler in pycolmap
        pool.join()


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=pathlib.Path, default=DATA)
    ap.add_argument("--repeat", type=int, default=3, help="runs of photax and Ceres (median)")
    ap.add_argument("--scipy-repeat", type=int, default=1, help="runs of the SciPy recipe (~1-3 min each)")
    ap.add_argument("--no-scipy", action="store_true", help="skip the SciPy comparison (slow)")
    args = ap.parse_args(argv)
    start("bench_bundle")
    if not args.data.is_file():
        print(f"{args.data} not found: nothing to benchmark")
        return 1
    full = read_bal_arrays(args.data)
    clean = drop_points_behind(full)
    print(f"problem-49-7776: {len(full.cameras)} cameras, {len(full.points)} points, {len(full.observations)} observations")
    print(f"  without the points behind their cameras: {len(clean.points)} points, {len(clean.observations)} observations")
    print("  machine: 2 cores; Ceres num_threads=2; photax on JAX CPU; times are medians of --repeat runs;")
    print("  photax's time includes its structure analysis, Ceres' its preprocessor; peaks include building the problem\n")

    # ---- photax vs Ceres on the same (cheirality-clean) problem ----
    p_clean = bal_problem(clean)
    first_c, t_first_c = _timed(lambda: photax_bal(p_clean))

    def photax_run():  # memory: conversion + solve; time: the solve
        problem = bal_problem(clean)
        return _timed(lambda: photax_bal(problem))

    warm = []
    for _ in range(args.repeat):
        (res_c, t), peak_pc = peak_memory(photax_run)
        warm.append(t)
    t_pc = float(np.median(warm))
    c_pc = bal_cost(*photax_solution(res_c), clean)
    print("without the 10 points behind their cameras (the model pycolmap's Ceres cost implements)")
    print(f"  photax       : cost {c_pc:.6e} after {res_c.iterations} iterations, warm {t_pc:.2f} s, "
          f"first call {t_first_c:.2f} s, peak {mib(peak_pc)} (fresh process: {mib(fresh_peak('photax', args.data))})")  # fmt: skip
    for solver in ("DENSE_SCHUR", "SPARSE_SCHUR"):
        def ceres_run():  # memory: building the reconstruction + solve; time: the solve
            solve, to_bal = ceres_bal(clean, solver, num_threads=2)
            return _timed(solve), to_bal

        times = []
        for _ in range(args.repeat):
            ((summary, t), to_bal), peak = peak_memory(ceres_run)
            times.append(t)
        t_c = float(np.median(times))
        c_c = bal_cost(*to_bal(), clean)
        print(f"  Ceres {solver:12s}: cost {c_c:.6e} (Ceres reports {summary.final_cost:.6e}) after "
              f"{summary.num_successful_steps + summary.num_unsuccessful_steps} iterations, {t_c:.2f} s, peak {mib(fresh_peak(solver, args.data))} (fresh process; in this one "
              f"{mib(peak)}: Ceres reuses pages photax freed)")  # fmt: skip
        record(f"vs Ceres {solver}", photax_s=t_pc, peer_s=t_c, ratio=t_pc / t_c, first_call_ratio=t_first_c / t_c,
               cost_photax=c_pc, cost_peer=c_c)
        print(f"  ratio photax/Ceres {solver} (warm)       : {t_pc / t_c:.2f}")
        print(f"  ratio photax/Ceres {solver} (first call) : {t_first_c / t_c:.2f}")
        print(f"  cost photax - Ceres: {c_pc - c_c:+.4g} ({(c_pc - c_c) / c_c:+.2e} relative)")
    print()

    # ---- photax vs SciPy on the full problem ----
    if args.no_scipy:
        return 0
    p_full = bal_problem(full)
    first, t_first = _timed(lambda: photax_bal(p_full))
    warm, peak_px = [], 0
    for _ in range(args.repeat):
        (res, t), peak = peak_memory(lambda: (lambda problem: _timed(lambda: photax_bal(problem)))(bal_problem(full)))
        warm.append(t)
        peak_px = max(peak_px, peak)
    t_px = float(np.median(warm))
    c_px = bal_cost(*photax_solution(res), full)
    sp_times, peak_sp = [], 0
    for _ in range(args.scipy_repeat):
        ((cams, pts, sres), t), peak = peak_memory(lambda: _timed(lambda: scipy_recipe(full)))
        sp_times.append(t)
        peak_sp = max(peak_sp, peak)
    t_sp = float(np.median(sp_times))
    c_sp = bal_cost(cams, pts, full)
    t_reach = time_to_cost(res, c_sp)
    print("full problem (all 31843 observations)")
    print(f"  SciPy recipe : cost {c_sp:.6e} after {sres.nfev} evaluations, {t_sp:8.2f} s, peak {mib(peak_sp)}")
    print(f"  photax       : cost {c_px:.6e} after {res.iterations} iterations ({res.message}), "
          f"warm {t_px:.2f} s, first call {t_first:.2f} s (with jit), peak {mib(peak_px)}")  # fmt: skip
    print(f"  photax reaches SciPy's final cost after {t_reach:.2f} s (warm)")
    print(f"  ratio photax/scipy (time to SciPy's cost, warm)   : {t_reach / t_sp:.3f}  ({t_sp / t_reach:.1f}x faster)")
    print(f"  ratio photax/scipy (full convergence, warm)       : {t_px / t_sp:.3f}  ({t_sp / t_px:.1f}x faster)")
    print(f"  ratio photax/scipy (full convergence, first call) : {t_first / t_sp:.3f}\n")
    record("vs SciPy recipe, time to SciPy's cost", photax_s=t_reach, peer_s=t_sp, ratio=t_reach / t_sp)
    record("vs SciPy recipe, full convergence", photax_s=t_px, peer_s=t_sp, ratio=t_px / t_sp, first_call_ratio=t_first / t_sp)

    return 0


if __name__ == "__main__":
    sys.exit(main())
