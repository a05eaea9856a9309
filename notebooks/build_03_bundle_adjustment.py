"""Write notebooks/03_bundle_adjustment.ipynb (without outputs).

Run: ``python notebooks/build_03_bundle_adjustment.py``.  The notebook is
committed without outputs; tests/test_notebooks.py executes it.
"""

from _build import write_notebook

CELLS = [
    (
        "md",
        """# Bundle adjustment

Adjust a whole block of images at once with `photax.bundle_adjust`: every exterior orientation,
the ground coordinates of the tie points and, optionally, the interior orientation
(self-calibration), with their precision and a residual report.

1. a synthetic aerial block with known truth: 2 strips x 4 frames, 6 control points, 4 check points;
2. what the result says about itself (convergence, residuals, precision) and how that compares with the truth;
3. a blunder and a robust loss;
4. the same block read from a folder of CSV files (`../data/block`, the `photax bundle` format);
5. a real *Bundle Adjustment in the Large* problem (`../../shared/data`, skipped when absent).""",
    ),
    (
        "code",
        """import pathlib

import matplotlib.pyplot as plt
import numpy as np

import photax as ptx
from photax import plot
from photax.scene import synthetic_block


def find_shared(name):
    \"\"\"../../shared/data/<name> relative to this notebook, or None.\"\"\"
    for base in (pathlib.Path.cwd() / "../../shared/data", pathlib.Path.cwd() / "../shared/data"):
        if (base / name).is_file():
            return (base / name).resolve()
    return None""",
    ),
    (
        "md",
        """## 1. A synthetic block

4000 x 3000 px frames with f = 3000 px, flown about 630 m above terrain of 0..60 m (GSD ~0.2 m),
60 % forward and 30 % side overlap. Image measurements carry 0.5 px Gaussian noise
(`obs_sigma = 0.5`). Start values are the truth perturbed by ~5 m and ~0.6 degrees; tie points by ~3 m.
Control points are fixed (`point_sigma = 0`); check points are adjusted like tie points and only
compared with their surveyed coordinates afterwards.""",
    ),
    (
        "code",
        """problem, truth = synthetic_block(0, noise_px=0.5)
print(problem)
result = ptx.bundle_adjust(problem, verbose=True)
print(result.report())""",
    ),
    (
        "code",
        """fig, axes = plt.subplots(1, 2, figsize=(12, 4))
plot.convergence(axes[0], result)
plot.bundle_residuals(axes[1], result)
plt.show()""",
    ),
    (
        "md",
        """## 2. Precision vs truth

The standard deviations come from the inverse normal matrix (the reduced camera system is
inverted, point blocks follow from the Schur relations), scaled by sigma0. If the model is right,
the actual errors should be of the size of the reported standard deviations.""",
    ),
    (
        "code",
        """err_pos = np.asarray(result.exterior.position) - np.asarray(truth.exterior.position)
fig, axes = plt.subplots(1, 2, figsize=(12, 4))
x = np.arange(problem.n_images)
for k, name in enumerate("XYZ"):
    axes[0].bar(x + (k - 1) * 0.25, result.exterior_std[:, k], 0.25, alpha=0.5, label=f"std {name}")
    axes[0].plot(x + (k - 1) * 0.25, np.abs(err_pos[:, k]), "k.", ms=8)
axes[0].set_xticks(x, problem.image_names)
axes[0].set_ylabel("m")
axes[0].set_title("projection centres: reported std (bars) and |error| (dots)")
axes[0].legend()

tie = problem.roles == "tie"
z = (result.points - truth.points)[tie] / result.point_std[tie]
axes[1].hist(z.ravel(), bins=30, density=True, alpha=0.6, label="error / std, tie points")
t = np.linspace(-4, 4, 200)
axes[1].plot(t, np.exp(-t**2 / 2) / np.sqrt(2 * np.pi), "k-", label="N(0, 1)")
axes[1].legend()
axes[1].set_title("tie-point errors in units of their std")
plt.show()
print("check points (adjusted - surveyed, m):")
for name, r in zip(result.check_names, result.check_residuals):
    print(f"  {name}: {np.round(r, 3)}")""",
    ),
    (
        "md",
        """## 3. A blunder and a robust loss

One tie observation is moved 50 px. Least squares spreads the error over the block; the Huber
loss (reweighting as Ceres does, plus a per-point pass after each step) gives it a small weight.""",
    ),
    (
        "code",
        """counts = np.bincount(problem.obs_point)
bad = np.flatnonzero((problem.roles[problem.obs_point] == "tie") & (counts[problem.obs_point] >= 4))[0]
obs = problem.obs_xy.copy()
obs[bad, 0] += 50.0
blundered = problem.replace(obs_xy=obs)
ls = ptx.bundle_adjust(blundered)
huber = ptx.bundle_adjust(blundered, loss="huber", loss_scale=2.0)
k = problem.obs_point[bad]
for name, r in (("least squares", ls), ("Huber", huber)):
    print(f"{name:14s} point error {np.linalg.norm(r.points[k] - truth.points[k]):6.2f} m, "
          f"weight of the blunder {r.weights[bad]:.3f}, sigma0 {r.sigma0:.2f}")
fig, ax = plt.subplots(figsize=(7, 3.5))
plot.bundle_residuals(ax, huber, title="Huber: residuals, the blunder down-weighted")
plt.show()""",
    ),
    (
        "md",
        """## 4. The block folder format

`photax bundle data/block` reads `block.json` (cameras, images, angle convention),
`observations.csv` (pixel measurements) and `points.csv` (tie/control/check points). Here the
tie points have no coordinates: `bundle_adjust` starts them by forward intersection
(`photax.intersect`) before adjusting.""",
    ),
    (
        "code",
        """from photax.io.block import read_block

folder = pathlib.Path.cwd() / "../data/block"
if folder.is_dir():
    block = read_block(folder)
    print(block)
    res = ptx.bundle_adjust(block)
    print(res.report())
else:
    print("../data/block is not here (the notebook runs from notebooks/)")""",
    ),
    (
        "md",
        """## 5. Bundle Adjustment in the Large

BAL problems have no control points: the solution is defined only up to a similarity (7
parameters). `gauge="damped"` leaves that datum defect to the Levenberg-Marquardt damping, as
Ceres does; precision is then not reported. The BAL camera is photax's `FrameCamera` (f, principal
point 0, k1 and k2) with `world_from_camera = R^T` and centre `-R^T t`. Larger problems run from the
shell: `photax bundle ../../shared/data/problem-49-7776-pre.txt`.""",
    ),
    (
        "code",
        """from photax.io.bal import read_bal

path = find_shared("dubrovnik-3-7-pre.txt")
if path is None:
    print("../../shared/data/dubrovnik-3-7-pre.txt is absent: skipped")
else:
    bal = read_bal(path)
    print(bal)
    # 3 cameras x 9 + 7 points x 3 = 48 unknowns for 38 residuals: under-determined, so the
    # cost keeps creeping down; stop after 10 iterations (converged=False is the honest status).
    res = ptx.bundle_adjust(bal, gauge="damped", max_iterations=10, throw=False)
    print(res.report())
    print("RMS reprojection error before/after [px]:",
          np.sqrt(2 * res.initial_cost / bal.n_observations / 2), np.sqrt(2 * res.cost / bal.n_observations / 2))""",
    ),
]


if __name__ == "__main__":
    write_notebook(CELLS, "03_bundle_adjustment.ipynb")
