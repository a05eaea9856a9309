"""Bundle adjustment of BAL problem-49-7776 and of synthetic BAL blocks: photax vs SciPy vs Ceres.

Run:  python benchmarks/bench_bundle.py [--repeat 3] [--scipy-repeat 1]
      python benchmarks/bench_bundle.py --grid 10 20 30 [--ceres-up-to 30] [--seed 0]
      python benchmarks/bench_bundle.py --grid 100 --ceres-up-to 50      (10,000 images; the block is generated in ~20 s)
      python benchmarks/bench_bundle.py --report       (table and plot from the saved rows)

With ``--grid``, synthetic blocks of ``g x g`` images (:func:`synthetic_bal`,
BAL camera model, 70 % / 40 % overlap, perturbed start) are adjusted by
photax (warm; the first call with compilation is printed too) and by Ceres
SPARSE_SCHUR (2 threads, same tolerances), each size in one process so the
ratio survives the machine's load; then photax's precision at its solution
(gauge ``fix_first_camera``: every image's exterior orientation and
intrinsics, every point).  Time, iterations, final cost (recomputed with the
numpy BAL formula) and peak memory go to
``benchmarks/results/bench_bundle_block_<images>.json`` (one file per size,
so runs of different sizes in different processes add up); the growth
table over all of them to ``results/bundle_growth.md`` and the log-log plot
to ``results/bundle_growth.png``.

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
import os
import pathlib
import sys
import time

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _common import RESULTS, mib, peak_memory, record, start  # noqa: E402

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


def ceres_bal(
    d: BALData,
    linear_solver: str = "DENSE_SCHUR",
    num_threads: int = 2,
    *,
    loss: str = "none",
    loss_scale: float = 1.0,
    max_num_iterations: int | None = None,
    refine_intrinsics: bool = True,
    progress: bool = False,
    initial_trust_radius: float | None = None,
):
    """Build the BAL problem as a pycolmap reconstruction and a Ceres solver.

    Returns ``(solve, to_bal)``: ``solve()`` runs Ceres and returns its
    summary; ``to_bal()`` returns the current ``(cameras (m, 9), points)``
    in BAL's convention.  Ceres' own default tolerances and iteration limit
    (unless ``max_num_iterations`` is given).  ``loss``: ``"none"``,
    ``"huber"`` or ``"cauchy"`` (Ceres' HuberLoss / CauchyLoss of parameter
    ``loss_scale`` pixels on each 2-vector reprojection residual).
    ``refine_intrinsics=False`` holds ``f, k1, k2`` at their start values;
    ``progress`` prints Ceres' one line per iteration;
    ``initial_trust_radius`` overrides Ceres' 1e4.
    """
    import pyceres
    import pycolmap

    rec = pycolmap.Reconstruction()
    m = len(d.cameras)
    idx_in_image = np.empty(len(d.observations), dtype=np.int64)
    for i, cam in enumerate(d.cameras):
        rec.add_camera_with_trivial_rig(
            pycolmap.Camera(
                model="RADIAL", width=1, height=1, params=[cam[6], 0.0, 0.0, cam[7], cam[8]], camera_id=i + 1
            )
        )
        sel = np.flatnonzero(d.camera_index == i)
        idx_in_image[sel] = np.arange(len(sel))
        R = _FLIP @ Rotation.from_rotvec(cam[:3]).as_matrix()
        img = pycolmap.Image(
            name=str(i), keypoints=d.observations[sel] * np.array([[1.0, -1.0]]), camera_id=i + 1, image_id=i + 1
        )
        rec.add_image_with_trivial_frame(img, pycolmap.Rigid3d(np.hstack([R, (_FLIP @ cam[3:6])[:, None]])))
    order = np.argsort(d.point_index, kind="stable")
    tracks = np.split(order, np.flatnonzero(np.diff(d.point_index[order])) + 1)
    ids = [
        rec.add_point3D(d.points[j], pycolmap.Track([pycolmap.TrackElement(int(d.camera_index[o]) + 1, int(idx_in_image[o])) for o in obs]))
        for j, obs in enumerate(tracks)
    ]  # fmt: skip
    opts = pycolmap.BundleAdjustmentOptions(
        refine_focal_length=refine_intrinsics,
        refine_extra_params=refine_intrinsics,
        refine_principal_point=False,
        print_summary=False,
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
    so.minimizer_progress_to_stdout = progress
    if initial_trust_radius is not None:
        so.initial_trust_region_radius = initial_trust_radius
    if progress:
        so.logging_type = pyceres.LoggingType.PER_MINIMIZER_ITERATION
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
# Synthetic BAL blocks of any size
# --------------------------------------------------------------------------


def synthetic_bal(
    grid: int, seed: int = 0, points_per_image: int = 160, noise_px: float = 0.5, relief: float = 150.0
) -> BALData:
    """A BAL-style aerial block of ``grid x grid`` images from the one scene
    generator (:func:`photax.scene.block_scene`): downward-looking frames
    (4000 x 3000 px, f = 3000 px, flown 600 m above terrain of ``relief`` m,
    tilts up to 2 deg), 70 % forward and 40 % side overlap,
    ``points_per_image x grid^2`` tie points each seen on 2 or more images,
    Gaussian noise ``noise_px``.  Start values: the truth perturbed (5 m,
    0.01 rad, 3 m).  Each image is its own BAL camera (``f, k1, k2``; the
    truth has no distortion); coordinates are shifted to the block's mean so
    Ceres and photax both see moderate numbers.

    Why 150 m of relief.  Each image has its own focal length, and over
    flat ground a change of ``f`` is undone by one of the flying height
    (``x = f X / Z``): only the relief separates them.  The resulting weak
    modes set the iteration count of both solvers, not the start error
    (10 x 10 images, Ceres: 14 iterations for start errors of 0.5, 1 or 5 m;
    51 without convergence at 0 m relief; 8 at 400 m).  At 150 m the 30 x 30
    block has the issue's size (144,000 points, 686,888 observations against
    "144k, 686k") and the issue's final cost (Ceres 1.16325e5 against
    1.163144e5); Ceres then needs 28 iterations (the issue: 7; 8 when the
    intrinsics are held fixed, so the issue's block was probably better
    determined in ``f`` than any we could generate with that count)."""
    from photax.scene import block_scene

    b = block_scene(seed, strips=grid, images_per_strip=grid, n_tie=points_per_image * grid * grid, n_control=0,
                    n_check=0, noise_px=noise_px, forward_overlap=0.7, side_overlap=0.4, relief=relief)  # fmt: skip
    origin = np.round(np.mean(b.start_points, axis=0))
    eo = b.start_exterior
    cams = photax_to_bal([b.camera] * len(b.image_names), np.asarray(eo.rotation),
                         np.asarray(eo.position) - origin[None, :])  # fmt: skip
    return BALData(cams, b.start_points - origin[None, :], b.obs_image, b.obs_point, np.asarray(b.obs_xy))


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


def _cpu() -> float:
    """CPU seconds of this process (all threads) and its children."""
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _timed_cpu(fn):
    """``(out, wall s, CPU s)`` of ``fn()``."""
    c0 = _cpu()
    out, wall = _timed(fn)
    return out, wall, _cpu() - c0


def precision_at(result):
    """photax's precision at an adjusted BAL block: the problem at the
    solution, gauge ``fix_first_camera``, no iteration (``max_steps=0``)."""
    p = result.problem.replace(cameras=result.cameras, exterior=result.exterior, points=result.points)
    return photax.bundle_adjust(p, gauge="fix_first_camera", max_steps=0, throw=False, precision=True)


def block_comparison(grids, seed: int, ceres_up_to: int, single_from: int, radius: float | None = None) -> list[dict]:
    """photax vs Ceres SPARSE_SCHUR on synthetic blocks of ``g x g`` images.

    Below ``single_from`` photax runs twice (the first call, with
    compilation, then the timed warm run); from it on once, with one line
    per iteration, and its time includes compilation (a few seconds, noise
    at that size).  ``radius``: both solvers' initial trust radius (None:
    their default, 1e4).  Each size's row goes to
    ``results/bench_bundle_block_<images>.json`` as soon as it is measured."""
    rows = []
    for g in grids:
        t0 = time.perf_counter()
        d = synthetic_bal(g, seed)
        print(f"{g} x {g} block: {len(d.cameras)} images, {len(d.points)} points, {len(d.observations)} observations "
              f"(generated in {time.perf_counter() - t0:.0f} s), load average {os.getloadavg()}", flush=True)  # fmt: skip
        once = g >= single_from
        tr = {} if radius is None else dict(initial_trust_radius=radius)
        t_first = float("nan")
        if not once:
            _, t_first = _timed(lambda: photax_bal(bal_problem(d), **tr))
        (res, t_warm, cpu_warm), peak = peak_memory(
            lambda: (lambda problem: _timed_cpu(lambda: photax_bal(problem, verbose=once, **tr)))(bal_problem(d))
        )
        if once:
            t_first = t_warm
        cost = bal_cost(*photax_solution(res), d)
        print(f"  photax : cost {cost:.7e} after {res.iterations} iterations ({res.message}), "
              f"{'warm ' if not once else ''}{t_warm:.2f} s (first call {t_first:.2f} s), CPU {cpu_warm:.2f} s "
              f"({cpu_warm / max(res.iterations, 1):.3f} s per iteration), peak {mib(peak)}, "
              f"load average {os.getloadavg()}", flush=True)  # fmt: skip
        (prec, t_prec), peak_prec = peak_memory(lambda: _timed(lambda: precision_at(res)))
        ok = prec.exterior_std is not None and bool(np.all(np.isfinite(prec.exterior_std[1:])))
        row = dict(grid=g, initial_trust_radius=radius, images=len(d.cameras), points=len(d.points), observations=len(d.observations),
                   photax_s=t_warm, photax_cpu_s=cpu_warm, photax_first_call_s=t_first, photax_iterations=res.iterations, photax_cost=cost,
                   photax_converged=res.converged, photax_peak_bytes=peak, precision_s=t_prec,
                   precision_peak_bytes=peak_prec, precision_ok=ok, solver=_solver_of(res),
                   median_exterior_std=np.median(prec.exterior_std, axis=0).tolist() if ok else None,
                   load_average=[round(v, 2) for v in os.getloadavg()])  # fmt: skip
        print(f"  photax precision {t_prec:.2f} s ({'ok' if ok else 'MISSING'}), peak {mib(peak_prec)}", flush=True)
        _save_row(row)
        if g <= ceres_up_to:

            def ceres_run():
                solve, to_bal = ceres_bal(d, "SPARSE_SCHUR", num_threads=2, progress=once, initial_trust_radius=radius)
                return _timed_cpu(solve), to_bal

            ((summary, t_c, cpu_c), to_bal), peak_c = peak_memory(ceres_run)
            c_c = bal_cost(*to_bal(), d)
            row.update(ceres_s=t_c, ceres_cpu_s=cpu_c, cpu_ratio=cpu_warm / cpu_c,
                       ceres_iterations=summary.num_successful_steps + summary.num_unsuccessful_steps,
                       ceres_cost=c_c, ceres_peak_bytes=peak_c, ratio=t_warm / t_c, first_call_ratio=t_first / t_c,
                       cost_excess=(cost - c_c) / c_c, ceres_load_average=[round(v, 2) for v in os.getloadavg()])  # fmt: skip
            print(f"  Ceres  : cost {c_c:.7e} after {row['ceres_iterations']} iterations, {t_c:.2f} s (CPU {cpu_c:.2f} s, "
                  f"{cpu_c / max(row['ceres_iterations'], 1):.3f} s per iteration; photax/Ceres CPU {cpu_warm / cpu_c:.2f}), peak "
                  f"{mib(peak_c)} (in this process); ratio photax/Ceres {t_warm / t_c:.2f} (first call "
                  f"{t_first / t_c:.2f}), cost {(cost - c_c) / c_c:+.2e} relative", flush=True)  # fmt: skip
            _save_row(row)
        print(f"  load average {os.getloadavg()}", flush=True)
        record(f"block {g}x{g}", **row)
        rows.append(row)
    return rows


def _solver_of(result) -> str:
    from photax.bundle._sparse import choose_solver

    s, n_c, _, _ = result.problem.analyse("damped")
    return choose_solver(s.band_perm.shape, s.band_border.shape[0], n_c)


def _save_row(row: dict) -> None:
    import datetime
    import json

    from _common import machine

    out = dict(row, date=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
               command="python " + " ".join([os.path.relpath(sys.argv[0])] + sys.argv[1:]), machine=machine())  # fmt: skip
    tag = "" if row.get("initial_trust_radius") is None else f"_tr{row['initial_trust_radius']:g}"
    path = RESULTS / f"bench_bundle_block_{row['images']}{tag}.json"
    if "ceres_s" not in row and path.is_file():  # Ceres not re-run: keep its figures, say when they were measured
        before = json.loads(path.read_text())
        if "ceres_s" in before:
            keep = (
                "ceres_s",
                "ceres_cpu_s",
                "ceres_iterations",
                "ceres_cost",
                "ceres_peak_bytes",
                "ceres_load_average",
            )
            out.update({k: before[k] for k in keep if k in before}, ceres_date=before.get("ceres_date", before["date"]),
                       ratio=row["photax_s"] / before["ceres_s"], cost_excess=(row["photax_cost"] - before["ceres_cost"]) / before["ceres_cost"])  # fmt: skip
    path.write_text(json.dumps(out, indent=1) + "\n")


def growth_report() -> None:
    """The growth table (Markdown) and a log-log plot of time and memory
    against images, from every ``results/bench_bundle_block_*.json``."""
    import json

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [json.loads(p.read_text()) for p in RESULTS.glob("bench_bundle_block_*.json")]
    rows = sorted((r for r in rows if r.get("initial_trust_radius") is None), key=lambda r: r["images"])
    lines = ["| images | points | observations | photax s | iterations | peak MiB | precision s | precision MiB | "
             "Ceres s | Ceres it. | Ceres MiB | ratio | load |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        c = (f"{r['ceres_s']:.1f} | {r['ceres_iterations']} | {r['ceres_peak_bytes'] / 2**20:.0f} | {r['ratio']:.2f}"
             if "ceres_s" in r else "- | - | - | -")  # fmt: skip
        lines.append(f"| {r['images']} | {r['points']} | {r['observations']} | {r['photax_s']:.1f} | "
                     f"{r['photax_iterations']}{'' if r.get('photax_converged', True) else ' (not converged)'} | "
                     f"{r['photax_peak_bytes'] / 2**20:.0f} | {r['precision_s']:.1f} | "
                     f"{r.get('precision_peak_bytes', 0) / 2**20:.0f} | {c} | {r['load_average'][0]:.1f} |")  # fmt: skip
    lines += ["", "Times in seconds (photax warm below 2,500 images, with compilation from it on), peaks in MiB "
              "above the process's start; load = 1-min load average of the 2-core machine during the run. "
              "Where photax was re-run without Ceres, Ceres' figures (and the ratio) are those measured earlier "
              "on the same block (its JSON's `ceres_date`)."]  # fmt: skip
    lines += [f"Measured: {r['images']} images {r['date'][:16]} UTC ({r['command']})"
              + ("; Ceres not run at this size" if "ceres_s" not in r else
                 f"; Ceres measured separately {r['ceres_date'][:16]} UTC at load {r['ceres_load_average'][0]:.1f}, "
                 "so its ratio mixes two loads" if "ceres_date" in r else "") for r in rows]  # fmt: skip
    lines += ["At 10,000 images, before the memory cuts of docs/architecture.md (bundle), the OOM killer ended photax at 14 GB in "
              "its 8th iteration (`bench_bundle_10000_oom.log`); the row above is the run after them and after the "
              "LM fix (`bench_bundle_10000.log`: one line per iteration, the process's RSS by /usr/bin/time; "
              "`bench_bundle_10000_before_lmfix.log`: the same block before it, 1,897 s at load 6-15, final cost "
              "1.35772e6)."]  # fmt: skip
    (RESULTS / "bundle_growth.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    n = [r["images"] for r in rows]
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.6))
    ax[0].loglog(n, [r["photax_s"] for r in rows], "o-", label="photax (banded Schur)")
    ax[0].loglog(n, [r["photax_s"] / r["photax_iterations"] for r in rows], "o:", label="photax per iteration")
    ax[0].loglog(n, [r["precision_s"] for r in rows], "s--", label="photax precision")
    ce = [r for r in rows if "ceres_s" in r]
    if ce:
        ax[0].loglog([r["images"] for r in ce], [r["ceres_s"] for r in ce], "^-", label="Ceres SPARSE_SCHUR")
    ax[0].set(xlabel="images", ylabel="seconds", title="time")
    ax[1].loglog(n, [r["photax_peak_bytes"] / 2**20 for r in rows], "o-", label="photax")
    ax[1].loglog(n, [r.get("precision_peak_bytes", 0) / 2**20 for r in rows], "s--", label="photax precision")
    if ce:
        ax[1].loglog([r["images"] for r in ce], [r["ceres_peak_bytes"] / 2**20 for r in ce], "^-", label="Ceres")
    ax[1].set(xlabel="images", ylabel="MiB", title="peak memory")
    for a in ax:
        a.legend(fontsize=8)
        a.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(RESULTS / "bundle_growth.png", dpi=100)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=int, nargs="+", help="synthetic g x g blocks instead of problem-49-7776")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ceres-up-to", type=int, default=30, help="largest grid also solved by Ceres")
    ap.add_argument(
        "--single-from",
        type=int,
        default=60,
        help="from this grid on photax runs once (with compilation) and prints each iteration",
    )
    ap.add_argument("--report", action="store_true", help="only rebuild the growth table and plot")
    ap.add_argument(
        "--initial-trust-radius",
        type=float,
        default=None,
        help="both solvers' initial trust radius (default: theirs, 1e4); rows kept apart",
    )
    ap.add_argument("--data", type=pathlib.Path, default=DATA)
    ap.add_argument("--repeat", type=int, default=3, help="runs of photax and Ceres (median)")
    ap.add_argument("--scipy-repeat", type=int, default=1, help="runs of the SciPy recipe (~1-3 min each)")
    ap.add_argument("--no-scipy", action="store_true", help="skip the SciPy comparison (slow)")
    args = ap.parse_args(argv)
    if args.report:
        growth_report()
        return 0
    if args.grid:
        start("bench_bundle_blocks_" + "_".join(map(str, args.grid)))
        block_comparison(args.grid, args.seed, args.ceres_up_to, args.single_from, args.initial_trust_radius)
        growth_report()
        return 0
    start("bench_bundle")
    if not args.data.is_file():
        print(f"{args.data} not found: nothing to benchmark")
        return 1
    full = read_bal_arrays(args.data)
    clean = drop_points_behind(full)
    print(
        f"problem-49-7776: {len(full.cameras)} cameras, {len(full.points)} points, {len(full.observations)} observations"
    )
    print(
        f"  without the points behind their cameras: {len(clean.points)} points, {len(clean.observations)} observations"
    )
    print("  machine: 2 cores; Ceres num_threads=2; photax on JAX CPU; times are medians of --repeat runs;")
    print(
        "  photax's time includes its structure analysis, Ceres' its preprocessor; peaks include building the problem\n"
    )

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
        record(
            f"vs Ceres {solver}",
            photax_s=t_pc,
            peer_s=t_c,
            ratio=t_pc / t_c,
            first_call_ratio=t_first_c / t_c,
            cost_photax=c_pc,
            cost_peer=c_c,
        )
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
    record(
        "vs SciPy recipe, full convergence",
        photax_s=t_px,
        peer_s=t_sp,
        ratio=t_px / t_sp,
        first_call_ratio=t_first / t_sp,
    )

    return 0


if __name__ == "__main__":
    sys.exit(main())
