"""Write notebooks/05_automatic_orientation.ipynb (without outputs).

Run: ``python notebooks/build_05_automatic_orientation.py``.  The notebook is
committed without outputs; tests/test_notebooks.py executes it.  It is kept
cheap (small rendered images, one matching shape for transfer and ties).
"""

from _build import write_notebook

CELLS = [
    (
        "md",
        """# From raw images to orientations without clicking

The course notes (seed 004: interior orientation, image matching, epipolar images; seed 000:
registration) describe the chain from a photograph to its orientation. This notebook runs it
on **rendered** images whose geometry is known exactly (`photax.scene.render_image`: a
textured DEM seen by a frame camera, area-sampled, blurred and noised), so every result
can be compared with the truth:

1. **interior orientation** of a scanned film frame from its fiducial marks;
2. **GCP transfer** and **tie points** over a block, guided by approximate orientations;
3. the **bundle adjustment** of that block;
4. an **epipolar** (normalised) pair;
5. **registration** of an image to a reference orthophoto.

Pixel convention: (column, row), the centre of the top-left pixel at (0, 0).""",
    ),
    (
        "code",
        """import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection

import photax as ptx
from photax import plot
from photax.collinearity import stack_exteriors
from photax.interior import find_fiducials
from photax.scene import detailed_texture, fiducial_scan, render_image
from photax.matching import bundle_problem, match_ties, project_pixels, transfer_points

rng = np.random.default_rng(5)""",
    ),
    (
        "md",
        """## 1. Fiducial marks: interior orientation of a scan

A film frame with 8 fiducial crosses (calibrated positions in mm, from the camera's
calibration report) is scanned at 0.5 mm per pixel by a scanner that rotates, shears and
slightly bends the film (an affine mapping plus a bilinear term). One mark is painted 5 px
off, as a mark of the neighbouring frame would be. `find_fiducials` matches a cross
template near where the calibration report puts each mark, refines the peak to sub-pixel
and fits the film -> pixel transformation with a blunder test per mark.""",
    ),
    (
        "code",
        """FID = np.array([[-106, 106], [0, 110], [106, 106], [110, 0], [106, -106], [0, -110], [-106, -106], [-110, 0]], float)


def scanner(f):  # the scan's true geometry: film (mm, y up) -> pixel (column, row)
    u, v = f[:, 0], -f[:, 1]
    th = np.radians(0.8)
    c = 257.0 + 1.002 * (np.cos(th) * u - np.sin(th) * v) / 0.5 + 2.5 * u * v / 110**2
    r = 246.0 + (np.sin(th) * u + np.cos(th) * v + 0.003 * u) / 0.5 - 1.8 * u * v / 110**2
    return np.column_stack([c, r])


scan, truth_marks = fiducial_scan(FID, scanner, (520, 500), mark_size=4.0, line_width=0.8, seed=2,
                                  displaced={3: (3.0, -4.0)})
found = find_fiducials(scan, FID, pixel_size=0.5, mark_size=4.0, line_width=0.8, model="bilinear")
io = found.orientation
ok = ~found.flagged
print(io.message)
print(f"marks used: rmse of the fit {io.rmse:.3f} px; error against the truth "
      f"{np.sqrt(np.mean((found.xy[ok] - truth_marks[ok]) ** 2)):.3f} px rms")
for k in np.flatnonzero(found.flagged):
    print(f"mark {k + 1}: {found.messages[k]}")

fig, axes = plt.subplots(1, 2, figsize=(11, 5), gridspec_kw={"width_ratios": [1.1, 1]})
axes[0].imshow(scan, cmap="gray")
names = [f"F{k + 1}" for k in range(len(FID))]
plot.residual_vectors(axes[0], found.xy, io.residuals, names, outliers=found.flagged, image_size=(520, 500))
axes[0].set_title("fiducial marks: residual vectors (exaggerated; F4 flagged)", pad=22)
k = int(np.flatnonzero(found.flagged)[0])
c, r = np.round(found.xy[k]).astype(int)
axes[1].imshow(scan[r - 20:r + 21, c - 20:c + 21], cmap="gray", extent=(c - 20.5, c + 20.5, r + 20.5, r - 20.5))
axes[1].plot(*found.xy[k], "r+", ms=14, label="measured (flagged)")
axes[1].plot(*io.pixel_from_film(FID[k:k + 1])[0], "gx", ms=10, label="where the fit puts it")
axes[1].set_title(f"mark F{k + 1}: 5 px off its calibrated place")
axes[1].legend(loc="lower right")
plt.tight_layout()""",
    ),
    (
        "md",
        """The fitted transformation becomes a camera: `io.camera(focal_length, principal_point,
image_size=...)` is a `ScannedCamera` whose pixels go through it, which `resect`,
`bundle_adjust` and `orthorectify` accept. On the command line, `photax fiducials scan.tif
--fiducials marks.csv --pixel-size 0.5 --camera calibrated.yaml --camera-out scan_camera.yaml`
writes it as a camera file (a `scan:` block) that `photax resect`, `ortho`, `register`,
`transfer` and `ties` read back.""",
    ),
    (
        "code",
        """camera_scan = io.camera(153.0, (0.0, 0.0), image_size=(520, 500))
print(type(camera_scan).__name__, "- mean scan pixel on the film:", round(float(camera_scan.pixel_size[0]), 5), "mm")
from photax.io.camera_file import camera_to_dict

print(camera_to_dict(camera_scan, unit="mm")["scan"])""",
    ),
    (
        "md",
        """## 2. A rendered block: GCP transfer and tie points

Six images in two strips (60 % forward, 30 % side overlap) over gentle terrain, with five
survey targets (quartered discs) on the ground. The approximate orientations are the truth
moved by 5 m and turned by 1° in random directions — as from a GNSS/IMU, or a rough resection.

* `transfer_points`: the GCPs are known only on the ground. Each is predicted in the image
  that sees it most centrally, found there by matching a drawn target template, then
  transferred into every other image (predicted with the approximate orientations and the
  DEM, measured by normalised cross-correlation and least-squares matching on a template warped
  by the local affine map between the two views, as for tie points, so that opposite strips and
  rotated frames match; checked back from the other image).
* `match_ties`: Förstner interest points in each image, predicted in the overlapping images
  through the DEM, matched by NCC then LSM, checked back and against the pair's smooth
  prediction error.""",
    ),
    (
        "code",
        """X0, Y0 = 500_000.0, 4_000_000.0
W, H = 240, 160
CAM = ptx.FrameCamera.from_pixels(240.0, (W, H))
FLY = 320.0
GSD = (FLY - 25.0) / 240.0  # m per pixel at the mean terrain height
n, cell = 300, 2.0
cc = -300 + cell * (np.arange(n) + 0.5)
h = 20 + 15 * np.exp(-((cc[None, :] - 40) ** 2 + (cc[:, None] + 30) ** 2) / (2 * 90.0**2)) + 0.02 * cc[None, :]
dem = ptx.DEM(h, (cell, 0.0, X0 - 300, 0.0, -cell, Y0 + 300))

base, side = 0.4 * W * GSD, 0.7 * H * GSD
truth = [ptx.ExteriorOrientation([X0 + (c - 1) * base, Y0 + (0.5 - r) * side, FLY + rng.uniform(-3, 3)],
                                 np.radians(rng.uniform(-1, 1, 3))) for r in range(2) for c in range(3)]
gx = X0 + np.array([-1.0, 0.05, 1.0, -0.95, 0.9]) * base
gy = Y0 + np.array([0.45, 0.2, 0.45, -0.45, -0.4]) * side
gcp = np.column_stack([gx, gy, np.asarray(dem.height(jnp.asarray(gx), jnp.asarray(gy)))])
roles = ["control", "check", "control", "control", "check"]
images = [render_image(CAM, e, dem, origin=(X0, Y0), targets=gcp, target_radius=5.0, supersample=2, blur=0.5,
                       noise=0.005, seed=k) for k, e in enumerate(truth)]


def unit(v):
    return v / np.linalg.norm(v)


start = [ptx.ExteriorOrientation(np.asarray(e.position) + 5.0 * unit(rng.normal(size=3)),
                                 np.asarray(e.angles) + np.radians(1.0) * unit(rng.normal(size=3))) for e in truth]
t = np.arange(-10, 11) * GSD  # the target as drawn on a survey sheet, at the GSD, north up
xx, yy = np.meshgrid(t, -t)
template = np.where(np.hypot(xx, yy) < 5.0, 0.5 + 0.45 * np.tanh(xx / 0.4) * np.tanh(yy / 0.4), 0.5)
transfer = transfer_points(images, CAM, start, dem, gcp, target_template=template, roles=roles, search=15)
ties = match_ties(images, CAM, start, dem, search=15, max_points=50)
table = transfer.table
true_px = project_pixels(gcp, stack_exteriors(truth), CAM)
err = table.pixel - true_px[table.images.astype(int), [int(s[3:]) - 1 for s in table.names]]
print(f"GCPs: {len(table)} measurements of {len(set(table.names.tolist()))} points, "
      f"{np.sqrt(np.mean(err**2)):.3f} px rms from the truth")
print(f"ties: {ties.n_tracks} tracks, {len(ties.obs_image)} observations; pairs:",
      {f"{i}-{j}": f"{ties.pair_ties[i, j]} ({s})" for (i, j), s in ties.pair_status.items() if s != "no overlap"})""",
    ),
    (
        "md",
        """The tie-point graph: every track on the ground (coloured by the number of images that see
it), the camera stations, and a line for every tied image pair, as thick as the number of tracks
the two images share. The GCPs are triangles (control) and circles (check).""",
    ),
    (
        "code",
        """fig, axes = plt.subplots(1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [1.4, 1]})
ax = axes[0]
rays = np.bincount(ties.obs_point, minlength=ties.n_tracks)
sc = ax.scatter(ties.ground[:, 0] - X0, ties.ground[:, 1] - Y0, c=rays, s=8, cmap="viridis", vmin=2, vmax=rays.max())
fig.colorbar(sc, ax=ax, label="images per tie point", shrink=0.8)
pos = np.array([np.asarray(e.position) for e in start]) - [X0, Y0, 0]
counts = {pr: c for pr, c in ties.pair_ties.items() if ties.pair_status[pr] == "ok"}
segs = [[pos[i, :2], pos[j, :2]] for i, j in counts]
ax.add_collection(LineCollection(segs, linewidths=[0.5 + 4 * c / max(counts.values()) for c in counts.values()],
                                 colors="tab:red", alpha=0.7))
ax.plot(pos[:, 0], pos[:, 1], "s", color="tab:red", ms=9)
for k, p in enumerate(pos):
    ax.annotate(f"img {k}", p[:2], xytext=(6, 6), textcoords="offset points", color="tab:red")
ctrl = np.array(roles) == "control"
ax.plot(gcp[ctrl, 0] - X0, gcp[ctrl, 1] - Y0, "^", color="k", ms=9, label="control")
ax.plot(gcp[~ctrl, 0] - X0, gcp[~ctrl, 1] - Y0, "o", mfc="none", mec="k", ms=9, label="check")
ax.set_aspect("equal")
ax.set_xlabel("E - 500 000 (m)")
ax.set_ylabel("N - 4 000 000 (m)")
ax.set_title("tie-point graph over the block")
ax.legend(loc="lower right")
ax = axes[1]
k = 1
ax.imshow(images[k], cmap="gray")
mine = ties.obs_image == k
ax.scatter(*ties.obs_xy[mine].T, s=10, facecolors="none", edgecolors="tab:orange", label="tie observations")
sel = table.images == str(k)
ax.scatter(*table.pixel[sel].T, marker="+", s=120, color="tab:cyan", label="GCPs (transferred / template)")
ax.set_title(f"image {k}: what was measured in it")
ax.legend(loc="lower right", fontsize=8)
plt.tight_layout()""",
    ),
    (
        "md",
        """## 3. Bundle adjustment of the block

The tie tracks and the transferred GCPs become a `BundleProblem` (`bundle_problem`), adjusted
from the approximate orientations. The check points are left out of the adjustment and
compared with their surveyed coordinates afterwards.""",
    ),
    (
        "code",
        """result = ptx.bundle_adjust(bundle_problem(CAM, start, ties, table))
print(result.report())
eo = stack_exteriors(truth)
d = np.concatenate([np.asarray(result.exterior.position) - np.asarray(eo.position),
                    np.degrees(np.asarray(result.exterior.angles) - np.asarray(eo.angles))], axis=1)
std = np.concatenate([result.exterior_std[:, :3], np.degrees(result.exterior_std[:, 3:])], axis=1)
d0 = np.concatenate([pos + [X0, Y0, 0] - np.asarray(eo.position),
                     np.degrees(np.array([np.asarray(e.angles) for e in start]) - np.asarray(eo.angles))], axis=1)
fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
x = np.arange(len(truth))
for j, lab in enumerate("XYZ"):
    axes[0].semilogy(x + 0.1 * j, np.abs(d0[:, j]), "x", color=f"C{j}", label=f"{lab} start")
    axes[0].semilogy(x + 0.1 * j, np.abs(d[:, j]), "o", color=f"C{j}", label=f"{lab} adjusted")
axes[0].set(xlabel="image", ylabel="|position error| (m)", title="camera positions against the truth")
axes[0].legend(fontsize=7, ncol=2)
for j, lab in enumerate(["X", "Y", "Z", "angle 1", "angle 2", "angle 3"]):
    axes[1].plot(x + 0.1 * j - 0.25, d[:, j] / std[:, j], "o", color=f"C{j}", label=lab)
axes[1].axhspan(-3, 3, color="0.9", zorder=0)
axes[1].set(xlabel="image", ylabel="adjusted error / reported sigma", title="adjusted orientations: within 3 sigma?")
axes[1].legend(fontsize=7, ncol=2)
plt.tight_layout()
print("adjusted errors within 3 sigma:", bool(np.all(np.abs(d) <= 3 * std)))""",
    ),
    (
        "md",
        """## 4. An epipolar pair

`epipolar_pair` resamples two images onto a common plane parallel to their baseline, so that
corresponding points lie on the same row (here images 0 and 1 with their adjusted
orientations). The lines are every 20th row of the epipolar images: the same features lie
on the same line in both.""",
    ),
    (
        "code",
        """adjusted = [ptx.ExteriorOrientation(p, a, result.exterior.convention)
            for p, a in zip(np.asarray(result.exterior.position), np.asarray(result.exterior.angles))]
ep = ptx.epipolar_pair(images[0], images[1], CAM, adjusted[0], adjusted[1])
fig, axes = plt.subplots(1, 2, figsize=(12, 4), sharey=True)
for ax, img, name in ((axes[0], ep.left, "left (image 0)"), (axes[1], ep.right, "right (image 1)")):
    ax.imshow(img, cmap="gray")
    for r in range(10, img.shape[0], 20):
        ax.axhline(r, color="tab:orange", lw=0.6)
    ax.set_title(f"epipolar {name}: {img.shape[1]} x {img.shape[0]} px")
# a few tie points of the pair, carried into both epipolar images: equal rows
pair = [t for t in range(ties.n_tracks) if set(ties.obs_image[ties.obs_point == t]) >= {0, 1}][:12]
xl = np.array([ties.obs_xy[(ties.obs_point == t) & (ties.obs_image == 0)][0] for t in pair])
xr = np.array([ties.obs_xy[(ties.obs_point == t) & (ties.obs_image == 1)][0] for t in pair])
el, er = ep.to_epipolar("left", xl), ep.to_epipolar("right", xr)
axes[0].plot(*el.T, "c+", ms=10)
axes[1].plot(*er.T, "c+", ms=10)
plt.tight_layout()
print(f"y-parallax of {len(pair)} tie points: {np.sqrt(np.mean((el[:, 1] - er[:, 1]) ** 2)):.3f} px rms")""",
    ),
    (
        "md",
        """## 5. Registration to a reference orthophoto

`register_to_ortho` refines an approximate orientation by rendering the reference
orthophoto into the image (collinearity + DEM + resampling) and minimising the grey-value
differences by Gauss–Newton on JAX derivatives, coarse to fine. The reference here is the
ground texture itself, sampled at 1 m (a perfect orthophoto); the start is 5 m and 0.2°
off.""",
    ),
    (
        "code",
        """k = 1
ortho_x = np.asarray(truth[k].position)[0] - X0 - 50 + (np.arange(100) + 0.5)  # 100 m x 70 m at 1 m
ortho_y = np.asarray(truth[k].position)[1] - Y0 + 35 - (np.arange(70) + 0.5)
ortho = np.asarray(detailed_texture(jnp.asarray(ortho_x)[None, :], jnp.asarray(ortho_y)[:, None]))
otr = (1.0, 0.0, X0 + ortho_x[0] - 0.5, 0.0, -1.0, Y0 + ortho_y[0] + 0.5)
off = ptx.ExteriorOrientation(np.asarray(truth[k].position) + [4.0, -3.0, 0.0],
                              np.asarray(truth[k].angles) + np.radians([0.2, -0.15, 0.1]))
reg = ptx.register_to_ortho(images[k], CAM, off, ortho, otr, dem, levels=(4, 2, 1))
ground = np.column_stack([X0 + rng.uniform(ortho_x[0], ortho_x[-1], 200), Y0 + rng.uniform(ortho_y[-1], ortho_y[0], 200)])
ground = np.column_stack([ground, np.asarray(dem.height(jnp.asarray(ground[:, 0]), jnp.asarray(ground[:, 1])))])
px = project_pixels(ground, stack_exteriors([truth[k], off, reg.exterior]), CAM)
before, after = (np.sqrt(np.mean(np.sum((px[j] - px[0]) ** 2, 1))) for j in (1, 2))
print(reg.message)
print(f"reprojection error against the truth: {before:.2f} px before, {after:.4f} px after")

hist = reg.history
fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
for level in sorted({h["level"] for h in hist}, reverse=True):
    idx = [i for i, h in enumerate(hist) if h["level"] == level]
    axes[0].plot(idx, [hist[i]["rmse"] for i in idx], "o-", label=f"level {level} " + (f"(blur {level / 2:g} px)" if level > 1 else "(no blur)"))
    axes[1].semilogy(idx, [hist[i]["shift_px"] for i in idx], "o-", label=f"level {level}")
axes[1].axhline(1e-3, color="gray", ls=":", label="tolerance")
axes[0].set(xlabel="Gauss-Newton step", ylabel="grey rms before the step", title="registration: residuals")
axes[1].set(xlabel="Gauss-Newton step", ylabel="largest image shift of the step (px)", title="registration: steps")
axes[0].legend()
axes[1].legend()
plt.tight_layout()""",
    ),
    (
        "md",
        """Registration converges from offsets of up to about 21 px of reprojection error on these
images (tests/test_registration.py); further off, the status says it did not converge. A
reference that the image does not see gives a status saying so, not a wrong orientation.

## The same chain on the command line

```
photax fiducials scan.tif --fiducials marks.csv --pixel-size 0.5 --camera calibrated.yaml \\
    --camera-out scan_camera.yaml -o interior.json
photax transfer img*.tif --camera cam.yaml --exterior approx.json --dem dem.tif --gcps gcps.csv \\
    --template target.tif -o measured.csv
photax ties img*.tif --camera cam.yaml --exterior approx.json --dem dem.tif --gcps measured.csv -o block
photax bundle block --camera-out calibrated.yaml   # with "free" intrinsics in block/block.json
photax epipolar left.tif right.tif --camera cam.yaml --exterior oriented.json -o pair
photax register img.tif --camera cam.yaml --exterior approx.json --ortho reference.tif --dem dem.tif -o refined.json
```""",
    ),
]


if __name__ == "__main__":
    write_notebook(CELLS, "05_automatic_orientation.ipynb")
