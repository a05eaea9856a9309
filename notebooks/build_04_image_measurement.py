"""Write notebooks/04_image_measurement.ipynb (without outputs).

Run: ``python notebooks/build_04_image_measurement.py``.  The notebook is
committed without outputs; tests/test_notebooks.py executes it.
"""

from _build import FIND_SHARED, write_notebook

CELLS = [
    (
        "md",
        """# Image measurement: edges, Hough, interest points, targets and matching

Every image coordinate that resection and bundle adjustment use has to be *measured*. This
notebook runs the operators of `photax.measure` (seed 004 of the course notes) on a crop of a
real aerial frame and on rendered images whose truth is known:

1. edge operators: Roberts, Sobel, Prewitt, Laplace, Laplacian of Gaussian, Canny;
2. the Hough transform for lines and circles, with its accumulator;
3. interest operators (Moravec, Förstner, Harris) and Förstner's sub-pixel corner locator with
   its error ellipses;
4. circular targets (Wong-Trinder, centroid, ellipse fit) and least-squares matching (LSM),
   with its pull-in range.

Pixel convention: (column, row), the centre of the top-left pixel at (0, 0).""",
    ),
    (
        "code",
        """import pathlib

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Ellipse

import photax as ptx
from photax.io import read_geotiff
from photax.scene import patterns


"""
        + FIND_SHARED
        + """

rng = np.random.default_rng(4)
ngi = find_shared("3324c_2015_1004_05_0182_RGB.tif")
if ngi is not None:
    rgb, _ = read_geotiff(ngi)  # (3, rows, cols) uint8
    grey = rgb[:3].mean(axis=0)
    r0, c0 = grey.shape[0] // 2 - 128, grey.shape[1] // 2 - 128
    crop = grey[r0:r0 + 256, c0:c0 + 256]  # a 256 x 256 px piece of the frame
    source = f"NGI aerial frame {ngi.name}, rows {r0}-{r0 + 255}, columns {c0}-{c0 + 255}"
else:  # no shared data: a rendered scene with blobs, edges and corners stands in
    crop = 255 * patterns.texture((256, 256), blobs=300, sigma=(2.0, 6.0), seed=1)
    crop += 60 * patterns.render(patterns.corner((128.3, 128.6), 0.3, 1.7), (256, 256))
    crop = np.clip(crop, 0, 255)
    source = "rendered stand-in (the NGI frame is not in ../../shared/data)"
print(f"image: {source}; {crop.shape[1]} x {crop.shape[0]} px, grey {crop.min():.0f}-{crop.max():.0f}")""",
    ),
    (
        "md",
        """## 1. Edge operators

First-derivative operators (Roberts' 2 x 2 cross, Sobel and Prewitt 3 x 3) give the gradient
magnitude; the Laplace operator and the Laplacian of Gaussian (LoG) the second derivative,
whose **zero crossings** mark edges. Canny smooths with a Gaussian, keeps only the local
maxima of the gradient magnitude across the edge (non-maximum suppression) and links them
with two thresholds (hysteresis). All of them agree with scikit-image to 1e-6
(tests/test_measure_operators.py).""",
    ),
    (
        "code",
        """m = ptx.measure
log_response, log_edges = m.log(crop, 2.0)
rng_grey = float(np.ptp(crop))
panels = {
    "image": crop,
    "Roberts": m.roberts(crop),
    "Sobel": m.sobel(crop),
    "Prewitt": m.prewitt(crop),
    "Laplace": m.laplace(crop),
    "LoG (sigma 2) zero crossings": log_edges,
    "Canny (sigma 1.5)": m.canny(crop, 1.5, 0.05 * rng_grey, 0.12 * rng_grey),
    "LoG response": log_response,
}
fig, axes = plt.subplots(2, 4, figsize=(13, 6.8))
for ax, (name, img) in zip(axes.ravel(), panels.items()):
    img = np.asarray(img)
    if name in ("Laplace", "LoG response"):
        v = np.percentile(np.abs(img), 99)
        ax.imshow(img, cmap="RdBu", vmin=-v, vmax=v)
    else:
        ax.imshow(img, cmap="gray")
    ax.set_title(name)
    ax.set_axis_off()
fig.tight_layout()""",
    ),
    (
        "md",
        """## 2. Hough transform

Each edge pixel (x, y) votes for every line through it, `rho = x cos(theta) + y sin(theta)`:
a sinusoid in the (theta, rho) accumulator. Lines are its peaks, refined below the bin size.
Circles of known radius: each edge pixel votes for the centres on a circle around it. Here on
a rendered image with known lines and discs, so the found parameters can be checked.""",
    ),
    (
        "code",
        """def band(theta, rho, width=1.5):
    return lambda x, y: (np.abs(x * np.cos(theta) + y * np.sin(theta) - rho) < width / 2).astype(float)


lines_true = [(np.radians(20.0), 60.0), (np.radians(100.0), 90.0), (np.radians(150.0), -40.0)]
circles_true = np.array([[50.3, 140.6], [130.7, 125.2]])


def scene(x, y):
    v = np.max([band(t, r)(x, y) for t, r in lines_true], axis=0)
    return np.maximum(v, np.max([patterns.disc(c, 12.0)(x, y) for c in circles_true], axis=0))


synth = patterns.render(scene, (180, 180), blur=0.7, noise=0.01, rng=rng, supersample=8)
edges = m.canny(synth, 1.0, 0.1, 0.25)
# lines: the votes of thin (1.5 px) line pixels, weighted by their grey value; circles: Canny edges
thin = patterns.render(lambda x, y: np.max([band(t, r)(x, y) for t, r in lines_true], 0), (180, 180), supersample=8)
hl = m.hough_lines(thin, max_lines=3)
hc = m.hough_circles(edges, [12.0], max_circles=2)
print("lines found (theta deg, rho px):", np.round(np.c_[np.degrees(hl.theta), hl.rho], 2).tolist())
print("true:", [(round(float(np.degrees(t)), 2), r) for t, r in lines_true])
print("circle centres found (col, row):", np.round(hc.xy, 2).tolist(), "true:", circles_true.tolist())

fig, axes = plt.subplots(1, 3, figsize=(14, 4.6))
axes[0].imshow(synth, cmap="gray")
for t, r in zip(hl.theta, hl.rho):  # draw the found lines
    xs = np.array([0.0, 179.0])
    if abs(np.sin(t)) > 0.3:
        axes[0].plot(xs, (r - xs * np.cos(t)) / np.sin(t), "y-", lw=0.8)
    else:
        ys = xs
        axes[0].plot((r - ys * np.sin(t)) / np.cos(t), ys, "y-", lw=0.8)
axes[0].plot(hc.xy[:, 0], hc.xy[:, 1], "r+", ms=12)
axes[0].set(xlim=(0, 179), ylim=(179, 0), title="image, found lines (yellow) and circle centres (+)")
axes[1].imshow(np.sqrt(hl.accumulator.T), aspect="auto", cmap="magma", origin="lower",
               extent=[np.degrees(hl.thetas[0]), np.degrees(hl.thetas[-1]), hl.rhos[0], hl.rhos[-1]])
axes[1].plot(np.degrees(hl.theta), hl.rho, "co", mfc="none", ms=12)
axes[1].set(xlabel="theta [deg]", ylabel="rho [px]", title="line accumulator (square root) and its peaks")
axes[2].imshow(hc.accumulator[0], cmap="magma")
axes[2].plot(hc.xy[:, 0], hc.xy[:, 1], "co", mfc="none", ms=12)
axes[2].set(title="circle accumulator (r = 12 px) and its peaks")
fig.tight_layout()""",
    ),
    (
        "md",
        """## 3. Interest points and their precision

Förstner's operator looks at the structure matrix `N = sum g g^T` of the gradients in a
window: its **w** (`det N / tr N`, the size of the inverse error ellipse) says how precisely
a point could be located there, its **q** (`4 det N / tr(N)^2`, the roundness) whether it is a
point (q near 1) or an edge (q near 0). Candidates above the seed's thresholds, thinned by
non-maximum suppression, are then located to sub-pixel by `locate_corners` (the least-squares
intersection of the edge lines in the window), whose covariance is drawn as error ellipses
(magnified 10x).""",
    ),
    (
        "code",
        """ip = {name: m.interest_points(crop, name, min_distance=6, max_points=60)
      for name in ("moravec", "foerstner", "harris")}
fine = m.locate_corners(crop, ip["foerstner"].xy, window=7, exclude=0.0)
print(f"Förstner points: {len(ip['foerstner'].xy)}; sub-pixel locator: {fine.summary()}")
ok = np.asarray(fine.valid)
sig = np.asarray(fine.sigma)[ok]
if ok.any():
    print(f"median sigma (col, row): {np.median(sig, axis=0).round(3)} px")

fig, axes = plt.subplots(1, 3, figsize=(15, 5.2))
for ax, (name, pts) in zip(axes[:2], [("moravec", ip["moravec"]), ("harris", ip["harris"])]):
    ax.imshow(crop, cmap="gray")
    ax.plot(pts.xy[:, 0], pts.xy[:, 1], "r+", ms=7)
    ax.set_title(f"{name}: {len(pts.xy)} points")
    ax.set_axis_off()
ax = axes[2]
ax.imshow(crop, cmap="gray")
for xy, cov in zip(np.asarray(fine.xy)[ok], np.asarray(fine.covariance)[ok]):
    val, vec = np.linalg.eigh(cov)
    ang = np.degrees(np.arctan2(vec[1, 1], vec[0, 1]))
    ax.add_patch(Ellipse(xy, 2 * 10 * np.sqrt(val[1]), 2 * 10 * np.sqrt(val[0]), angle=ang,
                         fill=False, color="yellow", lw=1))
ax.plot(*np.asarray(fine.xy)[ok].T, "r.", ms=3)
ax.set_title("Förstner points, sub-pixel, 1-sigma ellipses x 10")
ax.set_axis_off()
fig.tight_layout()""",
    ),
    (
        "md",
        """## 4. Circular targets

Three centring methods on rendered targets (radius 6 px, blur 0.7 px, noise 1 %) whose true
centres are known: **Wong-Trinder** (threshold, then the centre of the binary blob),
the **grey-value centroid** and an **ellipse** fitted to sub-pixel edge points. The RMSE over
the targets shows what each is worth; each result also carries its own covariance.""",
    ),
    (
        "code",
        """truth = np.stack(np.meshgrid(np.arange(20, 200, 30.0), np.arange(20, 140, 30.0)), -1).reshape(-1, 2)
truth = truth + rng.uniform(-0.5, 0.5, truth.shape)
targets = patterns.render(lambda x, y: np.max([patterns.disc(c, 6.0)(x, y) for c in truth], 0), (140, 200),
                         blur=0.7, noise=0.01, rng=rng, supersample=8)
approx = truth + rng.uniform(-1.5, 1.5, truth.shape)
print(f"{len(truth)} targets")
for method in ("wong-trinder", "centroid", "ellipse"):
    r = m.locate_targets(targets, approx, 6.0, method=method)
    err = np.asarray(r.xy) - truth
    print(f"{method:>13}: RMSE {np.sqrt(np.nanmean(np.sum(err**2, 1))):.4f} px, "
          f"mean predicted sigma {np.nanmean(np.asarray(r.sigma)):.4f} px  ({r.summary()})")""",
    ),
    (
        "md",
        """## 5. Least-squares matching and its pull-in range

LSM (Gruen 1985) fits 6 affine and 2 radiometric parameters so that the template matches the
search window in the least-squares sense, iterating Gauss-Newton steps. It needs an
approximation within a few pixels (from NCC, say). Below: a textured template, the same texture
shifted by a known amount with gain 0.9 and offset 0.05, and the start moved further and further
away from the true match: how many iterations LSM needs and where it stops converging.""",
    ),
    (
        "code",
        """shift = np.array([0.37, -0.21])
tpl = patterns.texture((80, 80), seed=3, noise=0.01, rng=rng)
srch = 0.9 * patterns.texture((80, 80), seed=3, shift=shift, noise=0.01 / 0.9, rng=rng) + 0.05
offsets = np.linspace(0, 6, 25)
angle = rng.uniform(0, 2 * np.pi, (len(offsets), 8))
start = 40.0 + shift + offsets[:, None, None] * np.stack([np.cos(angle), np.sin(angle)], -1)
start = start.reshape(-1, 2)
res = m.match_lsm(tpl, np.full_like(start, 40.0), srch, start, window=10, margin=8)
err = np.linalg.norm(np.asarray(res.xy) - (40.0 + shift), axis=1).reshape(len(offsets), -1)
conv = np.asarray(res.valid).reshape(len(offsets), -1) & (np.nan_to_num(err, nan=9.0) < 0.1)
its = np.asarray(res.iterations).reshape(len(offsets), -1).astype(float)
good = np.asarray(res.valid)
print(f"converged from {conv.mean():.0%} of the starts; error when converged: "
      f"RMSE {np.sqrt(np.nanmean(err[conv] ** 2)):.4f} px, predicted sigma "
      f"{np.nanmean(np.asarray(res.sigma)[good]):.4f} px")
fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
axes[0].plot(offsets, conv.mean(axis=1), "o-")
axes[0].set(xlabel="distance of the start from the match [px]", ylabel="fraction converged",
            title="LSM pull-in range (21 x 21 template)")
axes[1].plot(offsets, np.where(conv, its, np.nan).mean(axis=1), "o-")
axes[1].set(xlabel="distance of the start from the match [px]", ylabel="iterations (converged)",
            title="Gauss-Newton iterations to 1e-3 px")
fig.tight_layout()""",
    ),
]


if __name__ == "__main__":
    write_notebook(CELLS, "04_image_measurement.ipynb")
