"""Write notebooks/06_mosaic_and_uncertainty.ipynb (without outputs).

Run: ``python notebooks/build_06_mosaic_and_uncertainty.py``.  The notebook is
committed without outputs; tests/test_notebooks.py executes it.
"""

from _build import write_notebook

CELLS = [
    (
        "md",
        """# Orthos on Dask, a mosaic without seams, and how far off each pixel may be

A survey is many overlapping frames. This notebook takes a small rendered strip of three
frames over a hill and

1. orthorectifies each one lazily on Dask (`photax.orthorectify_dask`);
2. joins the orthos with `photax.mosaic` (seamlines of least difference, feathering, gain
   balancing) and compares that with `rasterio.merge`;
3. maps the **geolocation uncertainty** of every mosaic pixel (`photax.ortho_uncertainty`):
   the standard deviation, in metres, of the ground position that the pixel shows.

Everything is small (240 x 360 px frames, a 1 m ortho grid) so that it runs in seconds.""",
    ),
    (
        "code",
        """import pathlib
import tempfile

import matplotlib.pyplot as plt
import numpy as np
import rasterio.merge
from matplotlib.colors import ListedColormap

import photax as ptx
from photax.rectification import ortho_grid
from photax.scene import render_image

X0, Y0, FLY = 500_000.0, 4_000_000.0, 320.0  # UTM-like ground origin, flying height (m)
W, H = 360, 240
camera = ptx.FrameCamera.from_pixels(300.0, (W, H))  # 300 px principal distance: ~1 m per pixel
cell, n = 2.0, 360  # +-360 m: the DEM covers every frame's whole footprint (no PartialDEMWarning)
c = -360 + cell * (np.arange(n) + 0.5)
xx, yy = c[None, :], c[:, None]
heights = 20 + 15 * np.exp(-((xx - 40) ** 2 + (yy + 30) ** 2) / (2 * 90.0**2)) + 0.02 * xx  # a hill
dem = ptx.DEM(heights, (cell, 0.0, X0 - 360, 0.0, -cell, Y0 + 360), crs="EPSG:32633")

# Three frames along a strip, 60 % forward overlap, slightly tilted; each with its own
# exposure (gain 1.0, 1.1, 0.95) -- the radiometric difference a mosaic has to hide.
base = 0.4 * W * (FLY - 25.0) / 300.0
rng = np.random.default_rng(6)
exteriors = [ptx.ExteriorOrientation([X0 + (k - 1) * base, Y0, FLY + rng.uniform(-3, 3)],
                                     np.radians(rng.uniform(-2, 2, 3))) for k in range(3)]
gains = [1.0, 1.1, 0.95]
images = [g * render_image(camera, e, dem, origin=(X0, Y0), supersample=2, blur=0.5, noise=0.005, seed=k)
          for k, (g, e) in enumerate(zip(gains, exteriors))]
grids = [ortho_grid(e, camera, dem, resolution=1.0) for e in exteriors]  # each frame's footprint, 1 m pixels

fig, axes = plt.subplots(1, 4, figsize=(15, 3.2), gridspec_kw={"width_ratios": [1.3, 1, 1, 1]})
ext = np.array(dem.bounds)[[0, 2, 1, 3]] - [X0, X0, Y0, Y0]
im = axes[0].imshow(heights, extent=ext, cmap="terrain", vmin=0, vmax=45)
for k, g in enumerate(grids):
    x0, y0, x1, y1 = np.array(g.bounds) - [X0, Y0, X0, Y0]
    axes[0].plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], lw=1.5, label=f"frame {k}")
axes[0].legend(fontsize=7, loc="lower left")
axes[0].set_title("DEM (m) and the frames' footprints")
fig.colorbar(im, ax=axes[0], shrink=0.8)
for k, (ax, img) in enumerate(zip(axes[1:], images)):
    ax.imshow(img, cmap="gray", vmin=0, vmax=1.1)
    ax.set_title(f"frame {k} (gain {gains[k]})")
    ax.set_axis_off()
fig.tight_layout()""",
    ),
    (
        "md",
        """## 1. Orthos on Dask

`orthorectify_dask` takes the same arguments as `orthorectify` and returns a lazy, chunked
`xarray.DataArray` with its CRS and transform (rioxarray): nothing runs until `.compute()`,
`.rio.to_raster(...)` or a `dask.distributed` client asks for it, and each chunk reads only
the window of the image it needs. The tiles are the same as the whole-image function's, bit
for bit (tests/test_rectification_dask.py).""",
    ),
    (
        "code",
        """lazy = [ptx.orthorectify_dask(img, e, camera, dem, g, chunks=128, approx=None)
        for img, e, g in zip(images, exteriors, grids)]
print(f"ortho 0: {lazy[0].shape} px, chunks {lazy[0].chunks}, {lazy[0].rio.crs}, dask: {type(lazy[0].data).__name__}")
orthos = [o.compute() for o in lazy]

fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), sharey=True)
for k, (ax, o) in enumerate(zip(axes, orthos)):
    x0, y0, x1, y1 = o.rio.bounds()
    ax.imshow(o.values, cmap="gray", vmin=0, vmax=1.1, extent=(x0 - X0, x1 - X0, y0 - Y0, y1 - Y0))
    ax.set_title(f"ortho {k}")
    ax.set_xlabel("E - 500000 (m)")
axes[0].set_ylabel("N - 4000000 (m)")
fig.tight_layout()""",
    ),
    (
        "md",
        """## 2. Mosaic: seamlines, feathering, gain balancing -- against `rasterio.merge`

`rasterio.merge` puts the orthos on one grid and keeps the first valid value (or the last, min,
max): the seams run along the footprints' edges and the exposure steps show. `photax.mosaic`
estimates a gain and an offset per ortho by least squares in the overlaps, cuts each overlap
along the path where the orthos differ least (red), and blends 8 px across the cut.""",
    ),
    (
        "code",
        """info = {}
mosaic = ptx.mosaic(orthos, info=info).compute()
# Index of the ortho each pixel comes from (-1: no data), from the seam grid's cells of seam_scale px.
s = info["seam_scale"]
labels = np.repeat(np.repeat(info["labels"], s, 0), s, 1)[: mosaic.shape[0], : mosaic.shape[1]]
with tempfile.TemporaryDirectory() as tmp:
    paths = [str(pathlib.Path(tmp) / f"ortho{k}.tif") for k in range(len(orthos))]
    for o, p in zip(orthos, paths):
        o.rio.to_raster(p)
    merged, _ = rasterio.merge.merge(paths)  # first wins
# The estimated gains undo the rendered exposures: their products are (nearly) one constant.
print("estimated gain x rendered exposure:", np.round(np.asarray(info["gains"]) * gains, 3))

x0, y0, x1, y1 = mosaic.rio.bounds()
extent = (x0 - X0, x1 - X0, y0 - Y0, y1 - Y0)
seam = np.zeros(labels.shape, dtype=bool)  # seam pixels: the pixel above or left comes from another ortho
seam[1:] |= (labels[1:] != labels[:-1]) & (labels[1:] >= 0) & (labels[:-1] >= 0)
seam[:, 1:] |= (labels[:, 1:] != labels[:, :-1]) & (labels[:, 1:] >= 0) & (labels[:, :-1] >= 0)

fig, axes = plt.subplots(1, 2, figsize=(14, 4.4), sharey=True)
axes[0].imshow(merged[0], cmap="gray", vmin=0, vmax=1.1, extent=extent)
axes[0].set_title("rasterio.merge (first wins): exposure steps at the footprint edges")
axes[1].imshow(mosaic.values, cmap="gray", vmin=0, vmax=1.1, extent=extent)
axes[1].imshow(np.ma.masked_where(~seam, seam), cmap="autumn", extent=extent, interpolation="nearest")
axes[1].set_title("photax.mosaic, seamlines in red")
for ax in axes:
    ax.set_xlabel("E - 500000 (m)")
axes[0].set_ylabel("N - 4000000 (m)")
fig.tight_layout()""",
    ),
    (
        "md",
        """## 3. How far off may each pixel be?

An ortho pixel shows the ground point where the ray through its image position meets the DEM.
If the exterior orientation is uncertain, so is that point. `ortho_uncertainty` propagates the
orientation's covariance (and, when given, the intrinsics' and the DEM's) to every pixel with
the Jacobians of the collinearity model, to first order (within 10 % of a Monte Carlo
propagation, tests/test_uncertainty.py). A `ResectionResult`, or a `BundleResult` with
`image=i`, can be passed in place of the exterior and its covariance; here each frame gets the
precision a resection on a few control points typically has, frame 2 a 1.5 times weaker one
(as if it had fewer, badly spread points). The mosaic's map takes, pixel by pixel, the map of
the frame that the mosaic took the pixel from.""",
    ),
    (
        "code",
        """mosaic_grid = ptx.Grid(mosaic.rio.transform(), mosaic.shape, crs=mosaic.rio.crs)
std = np.array([0.1, 0.1, 0.1, *np.radians([0.05, 0.05, 0.05])])  # X0, Y0, Z0 (m), omega, phi, kappa (rad)
scale = [1.0, 1.0, 1.5]
sigma = np.full(mosaic.shape, np.nan)
for k, e in enumerate(exteriors):
    u = ptx.ortho_uncertainty(e, np.diag((scale[k] * std) ** 2), camera, dem, mosaic_grid)
    sigma[labels == k] = u.ground_sigma[labels == k]  # radial sigma sqrt(sX^2 + sY^2), metres

fig, axes = plt.subplots(1, 2, figsize=(14, 4.4), sharey=True)
im = axes[0].imshow(sigma, cmap="viridis", extent=extent)
axes[0].imshow(np.ma.masked_where(~seam, seam), cmap=ListedColormap(["white"]), extent=extent,
               interpolation="nearest")
fig.colorbar(im, ax=axes[0], shrink=0.85, label="horizontal position sigma (m)")
axes[0].set_title("geolocation sigma of each mosaic pixel (m)")
axes[1].imshow(mosaic.values, cmap="gray", vmin=0, vmax=1.1, extent=extent)
cs = axes[1].contour(sigma, levels=np.arange(0.2, 2.0, 0.05), cmap="autumn",
                     extent=extent, origin="upper", linewidths=1.2)
axes[1].clabel(cs, fmt="%.2f m", fontsize=8)
axes[1].set_title("the same sigma as contour lines over the mosaic")
for ax in axes:
    ax.set_xlabel("E - 500000 (m)")
axes[0].set_ylabel("N - 4000000 (m)")
fig.tight_layout()""",
    ),
    (
        "md",
        """**How to read it:** where the map says 0.5 m, the ground point that the pixel shows is,
in root mean square, 0.5 m away from where the mosaic puts it (the seamlines in white); the
error grows away from each frame's nadir (the angles' errors lever over a longer,
more oblique ray) and jumps at the seamlines, where the mosaic switches to a frame with another
orientation -- here to the weaker frame 2 on the right.""",
    ),
]


if __name__ == "__main__":
    write_notebook(CELLS, "06_mosaic_and_uncertainty.ipynb")
