"""Write notebooks/10_dense_stereo.ipynb (without outputs).

Run: ``python notebooks/build_10_dense_stereo.py``.  The notebook is
committed without outputs; tests/test_notebooks.py executes it.
"""

from _build import write_notebook

CELLS = [
    (
        "md",
        """# Dense stereo: disparities, points and a surface model

What ODM, s2p and NASA's Ames Stereo Pipeline do, in photax's steps (docs/stereo.md):

1. **matching** (`photax.disparity`, semi-global matching) on Middlebury's Motorcycle pair, beside
   OpenCV's SGBM and the pair's ground truth;
2. **a frame stereo pair to a DSM**: two aerial frames rendered over hills with a known DEM, made an
   epipolar pair, matched, intersected (`photax.stereo.pair_points`) and gridded
   (`photax.stereo.rasterize_points`), the result against the DEM it was rendered from;
3. **the edge of the overlap**: why the matcher leaves a band of the left image empty rather than guessing;
4. **precision**: each point's height sigma from the intersection geometry, against the errors;
5. the files: a Cloud-Optimized GeoTIFF and a PLY point cloud, and the command line that does it all.""",
    ),
    (
        "code",
        """import pathlib
import tempfile
import time

import cv2
import equinox as eqx
import matplotlib.pyplot as plt
import numpy as np
from skimage import data as skd
from skimage.color import rgb2gray

import photax as ptx
from photax.scene import render_image
from photax.stereo import pair_points, rasterize_points, write_cog""",
    ),
    (
        "md",
        """## 1. Matching: Motorcycle

`photax.disparity(left, right, disparity_range=(dmin, dmax))` returns, for each left pixel, the
column difference `d = col_left - col_right` of its match on the same row, NaN where it finds none
(occluded, not unique, failed the left-right check, a speckle). The score is Middlebury's *bad-2.0*:
the share of pixels more than 2 px from the ground truth, among the matcher's own estimates and among
all pixels with a truth (a missing value counted as bad).""",
    ),
    (
        "code",
        """left_rgb, right_rgb, gt = skd.stereo_motorcycle()  # gt: the left image's disparities, inf where unknown
left, right = rgb2gray(left_rgb) * 255, rgb2gray(right_rgb) * 255
known = np.isfinite(gt)


def bad2(d):
    ok = np.isfinite(d) & known
    e = np.abs(d - gt)
    return (e[ok] > 2).mean(), 1 - ((e <= 2) & ok).sum() / known.sum(), np.isfinite(d).mean()


t = time.perf_counter()
ours = ptx.disparity(left, right, disparity_range=(0, 63))
t_ours = time.perf_counter() - t
sgbm = cv2.StereoSGBM_create(0, 64, 3, P1=8 * 9, P2=32 * 9, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
t = time.perf_counter()
ref = sgbm.compute(left.astype(np.uint8), right.astype(np.uint8)).astype(float) / 16
t_ref = time.perf_counter() - t
ref[ref < 0] = np.nan
for name, d, secs in (("photax", ours, t_ours), ("OpenCV SGBM 3-way", ref, t_ref)):
    own, every, density = bad2(d)
    print(f"{name:18s} bad-2.0 {own:6.1%} of its estimates, {every:6.1%} of all; density {density:.3f}; {secs:.2f} s")
print("(photax's time includes its first call's compilation; benchmarks/bench_stereo.py times warm calls)")""",
    ),
    (
        "code",
        """fig, axes = plt.subplots(1, 4, figsize=(16, 3.4))
axes[0].imshow(left_rgb)
axes[0].set_title("left image")
for ax, d, title in ((axes[1], gt, "ground truth"), (axes[2], ours, "photax.disparity"), (axes[3], ref, "OpenCV SGBM")):
    im = ax.imshow(np.where(np.isfinite(d), d, np.nan), vmin=0, vmax=64, cmap="turbo")
    ax.set_title(title)
for ax in axes:
    ax.set_axis_off()
fig.colorbar(im, ax=axes, shrink=0.8, label="disparity (px)")
plt.show()""",
    ),
    (
        "md",
        """Black is NaN. photax leaves occlusions (the left of every object) and the textureless wall empty
rather than filling them; its estimates are wrong less often than SGBM's, at a similar density.

## 2. A frame stereo pair to a DSM

Two vertical frames 2.5 km above hills of 250 m (`photax.relief_scene`, `photax.scene.render_image`),
with 60 % overlap: base / height 0.37. The DEM they are rendered from is the truth.""",
    ),
    (
        "code",
        """scene = ptx.relief_scene(250.0, seed=3, image_size=(480, 360), focal_px=525.0, flying_height=2500.0,
                         tilt_deg=0.0, n_gcp=6, n_check=4)
base = 0.4 * 480 * scene.gsd  # metres between the projection centres
right_exterior = eqx.tree_at(lambda e: e.position, scene.exterior, scene.exterior.position + np.array([base, 0, 0]))
image_l, image_r = scene.image, render_image(scene.camera, right_exterior, scene.dem, origin=(500_000.0, 4_000_000.0))
per_px = scene.flying_height / (base / scene.gsd)  # height of one disparity pixel at the datum
print(f"GSD {scene.gsd:.2f} m, base {base:.0f} m, B/H {base / scene.flying_height:.2f}: "
      f"one disparity pixel is {per_px:.1f} m of height")

crs = "EPSG:32633"
points, info = pair_points(image_l, image_r, scene.camera, scene.exterior, right_exterior,
                           heights=(0.0, 250.0), crs=crs)
print(f"disparity range {info['disparity_range']} px, {info['valid']:.0%} of the left image matched, "
      f"{info['points']} points")
grid = ptx.Grid.from_bounds((points.x.min(), points.y.min(), points.x.max(), points.y.max()), 2 * scene.gsd, crs)
dsm = rasterize_points(points, grid)
xy = grid.xy()
truth = np.asarray(scene.dem.height(xy[..., 0], xy[..., 1]))
err = dsm.heights - truth
print(f"DSM {dsm.heights.shape}, {dsm.completeness:.0%} of the cells; median |dz| {np.nanmedian(np.abs(err)):.2f} m "
      f"({np.nanmedian(np.abs(err)) / per_px:.2f} px); off by more than one disparity pixel: "
      f"{np.mean(np.abs(err[np.isfinite(err)]) > per_px):.2%}")""",
    ),
    (
        "code",
        """x0, y0 = 500_000.0, 4_000_000.0  # the left frame's nadir: axes in metres from it
extent = grid.bounds[0] - x0, grid.bounds[2] - x0, grid.bounds[1] - y0, grid.bounds[3] - y0
fig, axes = plt.subplots(1, 4, figsize=(17, 3.8))
axes[0].imshow(image_l, cmap="gray")
axes[0].set_title("left frame")
axes[1].imshow(image_r, cmap="gray")
axes[1].set_title("right frame (black: beyond the DEM)")
im = axes[2].imshow(dsm.heights, extent=extent, vmin=0, vmax=250, cmap="terrain")
fig.colorbar(im, ax=axes[2], shrink=0.8, label="m")
axes[2].set_title("photax DSM")
im = axes[3].imshow(err, extent=extent, vmin=-per_px, vmax=per_px, cmap="RdBu_r")
fig.colorbar(im, ax=axes[3], shrink=0.8, label="m")
axes[3].set_title("DSM - true DEM (± one disparity pixel)")
for ax in axes[:2]:
    ax.set_axis_off()
for ax in axes[2:]:
    ax.set_xlabel("E from the left nadir (m)")
axes[2].set_ylabel("N from the left nadir (m)")
plt.show()""",
    ),
    (
        "md",
        """The DSM covers the overlap; its errors are a small part of a disparity pixel, larger along the
roads that run with the epipolar lines (a horizontal edge gives no horizontal disparity).

## 3. The edge of the overlap

Where the overlap ends, a left pixel's true match lies outside the right image. A matcher that compares
only the candidates it can still see picks the best of the wrong ones: a wrong height, with nothing to
tell it from a right one. `photax.disparity(..., whole_range=True)` keeps a disparity only where every
candidate of the search range was compared (OpenCV's SGBM leaves the same band invalid);
`pair_points` turns it on for frame pairs. Matching every pixel instead:""",
    ),
    (
        "code",
        """points_all, _ = pair_points(image_l, image_r, scene.camera, scene.exterior, right_exterior,
                             heights=(0.0, 250.0), crs=crs, matcher={"whole_range": False})
# one grid over both clouds (the second one reaches further west)
wide = ptx.Grid.from_bounds((points_all.x.min(), points_all.y.min(), points_all.x.max(), points_all.y.max()),
                            2 * scene.gsd, crs)
xy_wide = wide.xy()
truth_wide = np.asarray(scene.dem.height(xy_wide[..., 0], xy_wide[..., 1]))
err_whole = rasterize_points(points, wide).heights - truth_wide
err_all = rasterize_points(points_all, wide).heights - truth_wide
extent = wide.bounds[0] - x0, wide.bounds[2] - x0, wide.bounds[1] - y0, wide.bounds[3] - y0
for name, e in (("whole range (default)", err_whole), ("every pixel matched", err_all)):
    gross = np.mean(np.abs(e[np.isfinite(e)]) > per_px)
    print(f"{name:22s} {np.isfinite(e).mean():.0%} of the cells, {gross:.2%} off by more than a disparity pixel")
fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), sharey=True)
for ax, e, title in ((axes[0], err_whole, "whole range"), (axes[1], err_all, "every pixel matched")):
    im = ax.imshow(e, extent=extent, vmin=-5 * per_px, vmax=5 * per_px, cmap="RdBu_r")
    ax.set_title(f"DSM - DEM, {title}")
fig.colorbar(im, ax=axes, shrink=0.8, label="m")
plt.show()""",
    ),
    (
        "md",
        """## 4. Precision

Each point carries its height sigma from the intersection geometry and the matcher's disparity sigma
(0.3 px by default, `sigma_disparity=`). For a vertical pair it is close to the normal case's
`sigma_Z = Z^2 / (c B) sigma_p`. The DSM's cell sigma is the median of its points'.""",
    ),
    (
        "code",
        """depth = scene.flying_height - np.nanmedian(truth)
focal_px = float(scene.camera.focal_length / scene.camera.pixel_size[0])
normal_case = depth**2 / (focal_px * base) * 0.3
print(f"median point sigma_z {np.median(points.sigma_z):.2f} m; normal case Z^2/(c B) 0.3 px = {normal_case:.2f} m")
print(f"the errors' robust spread (1.4826 MAD) {1.4826 * np.nanmedian(np.abs(err - np.nanmedian(err))):.2f} m "
      "(synthetic images: the matcher is better than 0.3 px here)")
fig, ax = plt.subplots(figsize=(5, 3.5))
ax.hist(np.abs(err[np.isfinite(err)]), bins=np.linspace(0, 2 * per_px, 60), color="tab:blue")
ax.axvline(np.nanmedian(dsm.sigma), color="k", ls="--", label="median cell sigma")
ax.set_xlabel("|DSM - DEM| (m)")
ax.set_ylabel("cells")
ax.legend()
plt.show()""",
    ),
    (
        "md",
        """## 5. Files and the command line

`write_cog` writes the DSM as a Cloud-Optimized GeoTIFF (it refuses a blank one), and the points go to a
PLY with their colour, residual and sigma. `photax dsm LEFT RIGHT --camera ... -o dsm.tif` runs the whole
chain for frames (an OpenSfM/ODM reconstruction or a camera with exteriors) and for RPC / push-broom
images (`--camera rpc`), pair by pair, fused by the median (docs/stereo.md).""",
    ),
    (
        "code",
        """out = pathlib.Path(tempfile.mkdtemp())
write_cog(out / "dsm.tif", dsm.heights, grid)
points.write_ply(out / "points.ply")
print(sorted((p.name, p.stat().st_size) for p in out.iterdir()))
back = ptx.read_dem(out / "dsm.tif")
print("read back equal:", bool(np.allclose(np.asarray(back.heights), dsm.heights, equal_nan=True)))""",
    ),
]

if __name__ == "__main__":
    write_notebook(CELLS, "10_dense_stereo.ipynb")
