"""Write notebooks/02_rectification.ipynb (without outputs).

Run: ``python notebooks/build_02_rectification.py``.  The notebook is
committed without outputs; tests/test_notebooks.py executes it.
"""

from _build import FIND_SHARED, write_notebook

CELLS = [
    (
        "md",
        """# Rectification: collinearity + DEM against polynomials

Two ways to put an aerial image onto a map:

* **orthorectification** with the collinearity equations and a DEM: every ground point
  (X, Y) gets its height Z from the DEM and is projected into the image (`ptx.orthorectify`);
* **polynomial rectification** (orders 1-5) or the projective transform fitted to ground
  control points: a smooth plane-to-plane mapping (X, Y) -> (column, row) that never sees Z.

A point at height h above the datum, imaged at radial distance r from the nadir of a vertical
image taken from a flying height H, is displaced radially by **d = r h / H**
(relief displacement). Collinearity removes it; a polynomial can only bend smoothly between
its control points. Part 1 orthorectifies a real aerial frame; part 2 measures, on a synthetic
scene with known truth, how far each model is off, and where.""",
    ),
    (
        "code",
        """import pathlib

import matplotlib.pyplot as plt
import numpy as np
from IPython.display import Markdown, display

import photax as ptx
from photax.io import read_dem, read_geotiff, read_orthority_exterior, read_orthority_interior


"""
        + FIND_SHARED
        + """

NGI_IMAGE = "3324c_2015_1004_05_0182_RGB"
ngi_files = {k: find_shared(f) for k, f in [("image", NGI_IMAGE + ".tif"), ("dem", "dem.tif"),
                                              ("interior", "ngi_int_param.yaml"), ("exterior", "ngi_xyz_opk.csv")]}
have_ngi = all(p is not None for p in ngi_files.values())
print("NGI aerial frame:", "found" if have_ngi else "not available - part 1 is skipped")""",
    ),
    (
        "md",
        """## 1. A real aerial frame, orthorectified

A downsampled Intergraph DMC frame from the South African NGI (640 x 1152 px, f = 120 mm) with
its DEM and its exterior orientation from aerial triangulation (data from orthority's test set,
see `../../shared/data/SOURCES.md`). The orientation file gives omega-phi-kappa angles in degrees;
`read_orthority_exterior` reads them as photax's `"omega-phi-kappa"` convention (it never guesses).
If the data are absent this part prints a note and the notebook goes on.""",
    ),
    (
        "code",
        """if have_ngi:
    rgb, _ = read_geotiff(ngi_files["image"])  # (3, rows, cols) uint8
    dem = read_dem(ngi_files["dem"])
    camera = next(iter(read_orthority_interior(ngi_files["interior"]).values()))
    exterior = read_orthority_exterior(ngi_files["exterior"])[NGI_IMAGE]
    ortho, grid = ptx.orthorectify(rgb.astype(float), exterior, camera, dem, resampling="bilinear")
    print(f"camera: f = {float(camera.focal_length)} mm, image {camera.image_size}; "
          f"centre at Z = {float(exterior.Z):.0f} m, DEM {float(np.nanmin(dem.heights)):.0f}-"
          f"{float(np.nanmax(dem.heights)):.0f} m")
    print(f"orthophoto: {grid.width} x {grid.height} px of {grid.transform.a:.2f} m")
else:
    display(Markdown("*The NGI files are not in `../../shared/data`: part 1 skipped.*"))""",
    ),
    (
        "code",
        """if have_ngi:
    # How far the terrain moves each ground point in the image, against a flat plane at the
    # DEM's mean height: pixel(X, Y, DEM) - pixel(X, Y, mean height).
    xy = grid.xy()
    z = np.asarray(dem.height(xy[..., 0], xy[..., 1]))
    mean_h = float(np.nanmean(dem.heights))

    def to_pixel(zz):
        g = np.concatenate([xy, np.broadcast_to(zz, z.shape)[..., None]], axis=-1).reshape(-1, 3)
        return np.asarray(camera.image_to_pixel(ptx.project(g, exterior, camera))).reshape(xy.shape)

    shift = np.linalg.norm(to_pixel(z) - to_pixel(mean_h), axis=-1)
    shift[~np.isfinite(ortho[0])] = np.nan

    fig, ax = plt.subplots(1, 4, figsize=(17, 5.5), constrained_layout=True)
    ax[0].imshow(np.moveaxis(rgb, 0, -1))
    ax[0].set_title("aerial frame (as taken)")
    x0, y0, x1, y1 = dem.bounds
    im = ax[1].imshow(np.asarray(dem.heights), extent=(x0, x1, y0, y1), cmap="terrain")
    gx0, gy0, gx1, gy1 = grid.bounds
    ax[1].plot([gx0, gx1, gx1, gx0, gx0], [gy0, gy0, gy1, gy1, gy0], "r-", label="orthophoto")
    ax[1].plot(float(exterior.X), float(exterior.Y), "k*", ms=12, label="nadir")
    ax[1].legend(loc="lower left")
    ax[1].set_title("DEM")
    fig.colorbar(im, ax=ax[1], shrink=0.7, label="height [m]")
    ext = (gx0, gx1, gy0, gy1)
    ax[2].imshow(np.clip(np.moveaxis(np.nan_to_num(ortho), 0, -1) / 255, 0, 1), extent=ext)
    ax[2].set_title("orthophoto (collinearity + DEM)")
    im = ax[3].imshow(shift, extent=ext, cmap="magma")
    fig.colorbar(im, ax=ax[3], shrink=0.7, label="px")
    ax[3].set_title("relief displacement vs a flat plane")
    for a in ax[1:]:
        a.ticklabel_format(useOffset=False, style="plain")
        a.tick_params(labelsize=7)
    plt.show()
    print(f"relief displacement over the frame: median {np.nanmedian(shift):.1f} px, max {np.nanmax(shift):.1f} px "
          "- what a polynomial rectification of this frame would have to get wrong")""",
    ),
    (
        "md",
        """## 2. Collinearity + DEM against polynomials, on a scene with known truth

`ptx.relief_scene` renders a 1000 x 800 px frame (f = 1000 px, 3000 m above the datum,
2 deg tilt) over hills of 300 m, with a road grid on a checkerboard so distortions are visible.
30 GCPs and 60 independent check points carry 0.3 px of measurement noise.""",
    ),
    (
        "code",
        """scene = ptx.relief_scene(300.0, seed=0)
fig, ax = plt.subplots(1, 2, figsize=(13, 4.6), constrained_layout=True)
ax[0].imshow(scene.image, cmap="gray")
ax[0].plot(*scene.gcp_pixel.T, "r+", ms=8, label="GCP")
ax[0].plot(*scene.check_pixel.T, "o", mfc="none", color="lime", ms=4, label="check point")
ax[0].legend(loc="lower right")
ax[0].set_title("the image: the roads are straight on the ground")
x0, y0, x1, y1 = scene.dem.bounds
im = ax[1].imshow(np.asarray(scene.dem.heights), extent=(x0, x1, y0, y1), cmap="terrain")
fig.colorbar(im, ax=ax[1], label="height [m]")
ax[1].set_title("DEM")
ax[1].ticklabel_format(useOffset=False, style="plain")
plt.show()""",
    ),
    (
        "md",
        """All models are fitted to the same GCPs: collinearity by space resection (`ptx.resect`),
the polynomials and the projective transform by least squares on (X, Y) -> (column, row).
*map* columns: the error of each model against collinearity + DEM over the whole footprint.""",
    ),
    (
        "code",
        """cmp = ptx.compare_models(scene.gcp_ground, scene.gcp_pixel, scene.camera, scene.dem,
                         check_ground=scene.check_ground, check_pixel=scene.check_pixel)
display(Markdown(cmp.table()))""",
    ),
    (
        "md",
        """Reading the table: collinearity fits the check points to the noise (radial RMS of
0.3 px per coordinate is about 0.42 px). The polynomials fit their GCPs better with every order,
but the check points stay several pixels off at every order, and the highest order is worse on
them than a lower one: it spends its 42 parameters on the GCPs (overfitting).""",
    ),
    (
        "code",
        """fig = cmp.plot_rmse()
plt.show()
fig = cmp.plot_error_maps()
plt.show()""",
    ),
    (
        "md",
        """The error maps show *where*: the errors follow the hills and the valley (heights the
polynomial cannot see) and grow outside the GCPs' hull, where a high-order polynomial extrapolates
wildly. Below, the same image rectified by each model: the roads of the orthophoto are straight,
those of the polynomial rectifications bend over the hills.""",
    ),
    (
        "code",
        """# progress=True: one bar over the four models (a widget in Jupyter: ipywidgets, in the "notebooks" extra)
images, grid = cmp.rectify(scene.image, ["collinearity", "polynomial 1", "polynomial 3", "polynomial 5"],
                           progress=True)
fig = cmp.plot_rectified(images, grid, reference=scene.ortho, reference_transform=scene.ortho_transform, ncols=3)
plt.show()""",
    ),
    (
        "md",
        """### The closed form

For every cell of the comparison grid, the shift of its image position caused by the terrain
(collinearity with the DEM height minus collinearity on the datum Z = 0) against r h / H,
with r measured from the nadir. The 2 deg tilt makes the formula approximate; on a truly
vertical image it is exact (`tests/test_compare.py` checks that to 1e-8 px).""",
    ),
    (
        "code",
        """d = np.linalg.norm(cmp.relief_displacement(datum=0.0), axis=-1)
xy = cmp.grid.xy()
h = np.asarray(scene.dem.height(xy[..., 0], xy[..., 1]))
pix = np.asarray(cmp["collinearity"].model(xy))
nadir = np.asarray(scene.camera.image_to_pixel(ptx.project(
    np.array([[float(scene.exterior.X), float(scene.exterior.Y), 0.0]]), scene.exterior, scene.camera)))[0]
r = np.linalg.norm(pix - nadir, axis=-1)
ok = np.isfinite(d) & np.isfinite(cmp["collinearity"].error[..., 0])
fig, ax = plt.subplots(figsize=(5, 4.5))
ax.plot((r * h / scene.flying_height)[ok], d[ok], ",", alpha=0.5)
lim = float(np.nanmax(d[ok]))
ax.plot([0, lim], [0, lim], "k--", lw=1, label="d = r h / H")
ax.set_xlabel("r h / H [px]")
ax.set_ylabel("collinearity: DEM minus datum [px]")
ax.legend()
plt.show()""",
    ),
    (
        "md",
        """### Flat terrain: the models agree

On flat ground the scene is a plane, and a plane maps to the image by a projective
transform: here the projective model and polynomials of order >= 2 are as good as collinearity.""",
    ),
    (
        "code",
        """flat = ptx.relief_scene(0.0, seed=1)
cmp_flat = ptx.compare_models(flat.gcp_ground, flat.gcp_pixel, flat.camera, flat.dem,
                              check_ground=flat.check_ground, check_pixel=flat.check_pixel, orders=(1, 2, 3))
display(Markdown(cmp_flat.table()))""",
    ),
]


if __name__ == "__main__":
    write_notebook(CELLS, "02_rectification.ipynb")
