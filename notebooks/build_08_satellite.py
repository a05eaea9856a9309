"""Write notebooks/08_satellite.ipynb (without outputs).

Run: ``python notebooks/build_08_satellite.py``.  The notebook is committed without outputs;
tests/test_notebooks.py executes it.  (The push-broom -> RPC fit part belongs to the push-broom
model's own change.)
"""

from _build import FIND_SHARED, write_notebook

CELLS = [
    (
        "md",
        """# A satellite image: the RPC sensor model, its refinement on GCPs, and the ortho

Satellite images come with a **rational polynomial camera** (RPC): 80 coefficients that map longitude,
latitude and ellipsoidal height to a pixel, fitted by the vendor to its rigorous push-broom model. They
are good to a few pixels; a handful of ground control points (GCPs) remove the bias by an image-space
correction (Grodecki & Dial 2003). This notebook takes orthority's QuickBird scene and

1. shows the image, its GCPs and the DEM;
2. refines the RPC on the GCPs (shift, shift + drift, affine) and draws the residual vectors before and
   after, with leave-one-out residuals (each GCP predicted by a refinement without it);
3. orthorectifies the image with the refined RPC and maps how far off each ortho pixel may be
   (`photax.ortho_uncertainty`, from the refinement's covariance and the DEM's error);
4. compares the sensor model with the **polynomial correction of satellite images** that the course
   notes describe: an affine polynomial fitted to the same GCPs, and where it departs from the RPC.

The data (`../../shared/data/orthority/rpc/` and the NGI DEM, see `SOURCES.md`) are not in the clone;
without them the notebook prints a note and skips its parts. The DEM's heights are on the EGM2008 geoid,
not the ellipsoid the RPC wants; as in orthority's tests they are used as they are (photax warns).""",
    ),
    (
        "code",
        """import pathlib
import warnings

import matplotlib.pyplot as plt
import numpy as np
import pyproj
from IPython.display import Markdown, display

import photax as ptx
from photax.compare import compare_models
from photax.io import read_dem, read_gcps, read_geotiff
from photax.rectification import ortho_grid, orthorectify


"""
        + FIND_SHARED
        + """

files = {k: find_shared(f) for k, f in [("image", "orthority/rpc/qb2_basic1b.tif"), ("dem", "orthority/ngi/dem.tif"),
                                        ("gcps", "orthority/rpc/gcps.geojson")]}
have_qb = all(p is not None for p in files.values())
print("QuickBird scene:", "found" if have_qb else "not available - the notebook's parts are skipped")""",
    ),
    (
        "md",
        """## 1. The scene

An 850 x 1450 px QuickBird basic (not orthorectified) image, its RPC in the GeoTIFF's tags, 5 surveyed
GCPs (two of them measured just beyond this cut of the scene, still inside the RPC's image) and a 24 m
DEM in a transverse Mercator CRS.""",
    ),
    (
        "code",
        """if have_qb:
    rpc = ptx.read_rpc(files["image"])
    image, _ = read_geotiff(files["image"])
    image = image[0] if image.ndim == 3 else image
    dem = read_dem(files["dem"])
    table = read_gcps(files["gcps"])  # projected to their UTM zone by the reader
    lon, lat = pyproj.Transformer.from_crs(table.crs, "EPSG:4326", always_xy=True).transform(*table.ground[:, :2].T)
    ground = np.column_stack([lon, lat, table.ground[:, 2]])  # what the RPC wants: lon, lat, h
    pixel, names = table.pixel, list(table.names)
    print(f"RPC: image {rpc.image_size}, centre lon {float(rpc.offsets[0]):.4f}, lat {float(rpc.offsets[1]):.4f}, "
          f"heights {float(rpc.offsets[2] - rpc.scales[2]):.0f}..{float(rpc.offsets[2] + rpc.scales[2]):.0f} m")
    fig, axes = plt.subplots(1, 2, figsize=(11, 5.5), gridspec_kw={"width_ratios": [1, 1.2]})
    axes[0].imshow(image, cmap="gray")
    axes[0].plot(*pixel.T, "r+", ms=12, mew=2)
    for n, (c, r) in zip(names, pixel):
        axes[0].annotate(n, (c, r), color="r", fontsize=7, xytext=(4, 4), textcoords="offset points")
    axes[0].set_xlim(-250, rpc.image_size[0] + 350)
    axes[0].set_ylim(rpc.image_size[1], -100)
    axes[0].set_title("QuickBird basic image and its GCPs (px)")
    im = axes[1].imshow(np.asarray(dem.heights), cmap="terrain", extent=np.array(dem.bounds)[[0, 2, 1, 3]] / 1000)
    axes[1].set_title("DEM (m; km in Lo25)")
    fig.colorbar(im, ax=axes[1], shrink=0.8)
    fig.tight_layout()""",
    ),
    (
        "md",
        """## 2. Refining the RPC on the GCPs

`photax.refine_rpc` adjusts an image-space correction of increasing order by least squares: a shift
(2 parameters), shift + drift along the line time (4), affine (6). Its report gives sigma0, the
redundancy, the residuals, the leave-one-out residuals and the standardized residuals of data snooping.
With 5 GCPs the shift is what they support; the affine model has 4 redundant observations only.""",
    ),
    (
        "code",
        """if have_qb:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the two GCPs beyond the file are named in a warning
        fits = {m: ptx.refine_rpc(rpc, ground, pixel, m, names=names) for m in ("shift", "shift-drift", "affine")}
    display(Markdown("| model | parameters | GCP RMSE [px] | leave-one-out [px] | sigma0 [px] |\\n|---|---|---|---|---|\\n"
                     + f"| RPC as delivered | 0 | {fits['shift'].raw_rmse:.3f} | | |\\n"
                     + "\\n".join(f"| {m} | {f.covariance.shape[0]} | {f.rmse:.3f} | {f.loo_rmse:.3f} | {f.sigma0:.3f} |"
                                  for m, f in fits.items())))
    res = fits["shift"]
    print(res.report())
    fig, axes = plt.subplots(1, 2, figsize=(12, 6))
    panels = [(50.0, [("RPC as delivered", res.raw_residuals, "tab:red")]),
              (2000.0, [("refined (shift)", res.residuals, "tab:blue"), ("leave-one-out", res.loo_residuals, "tab:green")])]
    for ax, (scale, arrows) in zip(axes, panels):
        for label, v, colour in arrows:
            ax.quiver(*pixel.T, *(-v).T, angles="xy", scale_units="xy", scale=1 / scale, color=colour, label=label, width=0.006)
        ax.plot([0, 850, 850, 0, 0], [0, 0, 1450, 1450, 0], "k-", lw=0.8, label="image")
        ax.plot(*pixel.T, "k.")
        for n, (c, r) in zip(names, pixel):
            ax.annotate(n, (c, r), fontsize=7, xytext=(3, -8), textcoords="offset points")
        ax.set_xlim(-500, 1400)
        ax.set_ylim(1600, -450)
        ax.set_aspect("equal")
        ax.legend(loc="lower right", fontsize=8)
        ax.set_title(f"GCP residuals (arrow: model -> observed), drawn {scale:.0f} x")
    fig.tight_layout()""",
    ),
    (
        "md",
        """## 3. The RPC ortho and its uncertainty

The refined RPC goes to `orthorectify` as a frame camera does, with `None` for the exterior
orientation (the RPC carries its own); the output CRS can be any projected CRS (the RPC's lon, lat are
reached through pyproj), here the DEM's own. `ortho_uncertainty` takes the refinement itself: its
covariance (the shift's sigma0^2 Q) and, per pixel, a DEM error (2 m here) through the view's tangent
and the terrain's slope: where a slope falls away from the satellite almost along its line of sight, a
small height error moves the imaged ground point far, and the sigma there is large.""",
    ),
    (
        "code",
        """if have_qb:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # geoid heights taken as ellipsoidal; a few DEM cells below the RPC's range
        grid = ortho_grid(None, res.camera, dem, 10.0, crs=dem.crs)
        ortho, _ = orthorectify(image, None, res.camera, dem, grid, nodata=0)
    sigma = ptx.ortho_uncertainty(res, None, None, dem, grid, dem_sigma=2.0)
    ext = np.array(grid.bounds)[[0, 2, 1, 3]] / 1000
    fig, axes = plt.subplots(1, 2, figsize=(11, 6))
    axes[0].imshow(np.where(ortho > 0, ortho, np.nan), cmap="gray", extent=ext)
    axes[0].set_title(f"RPC ortho (shift-refined), {grid.width} x {grid.height} px of 10 m")
    s = sigma.ground_sigma[np.isfinite(sigma.ground_sigma)]
    im = axes[1].imshow(sigma.ground_sigma, cmap="viridis", extent=ext, vmax=np.percentile(s, 99.5))
    axes[1].set_title("ground position sigma (m): refinement + 2 m DEM error")
    fig.colorbar(im, ax=axes[1], shrink=0.8)
    for ax in axes:
        ax.set_xlabel("E (km, Lo25)")
    fig.tight_layout()
    print(f"ground sigma: median {np.median(s):.2f} m, 99 % below {np.percentile(s, 99):.2f} m, largest {s.max():.0f} m "
          f"(a slope facing away from the satellite, nearly along its view: the colour scale stops at 99.5 %); "
          f"image-position sigma {float(np.nanmean(sigma.image_std[0])):.3f} px")""",
    ),
    (
        "md",
        """## 4. Polynomial correction against the sensor model

`compare_models` with an RPC camera fits the same plane-to-plane polynomials as for a frame, beside the
raw and refined RPC, and maps how far each polynomial's image position departs from the refined RPC +
DEM over the scene. An affine polynomial (order 1) needs 3 GCPs; with 5 it has 4 redundant observations.
It fits the GCPs to about a pixel but cannot know the relief: between and beyond the GCPs it is tens
of pixels off.""",
    ),
    (
        "code",
        """if have_qb:
    x, y = pyproj.Transformer.from_crs("EPSG:4326", dem.crs, always_xy=True).transform(lon, lat)
    local = np.column_stack([x, y, ground[:, 2]])  # the GCPs in the DEM's CRS
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c = compare_models(local, pixel, rpc, dem, orders=(1,), projective=False, tps=False, piecewise_affine=False,
                           gcp_names=names)
    display(Markdown(c.table()))
    poly = c["polynomial 1"]
    fig, ax = plt.subplots(figsize=(6.5, 6))
    im = ax.imshow(poly.error_magnitude, cmap="magma", extent=np.array(c.grid.bounds)[[0, 2, 1, 3]] / 1000)
    ax.plot(x / 1000, y / 1000, "c+", ms=12, mew=2, label="GCPs")
    ax.legend(loc="lower left")
    ax.set_title("|refined RPC + DEM - affine polynomial| (px)")
    ax.set_xlabel("E (km, Lo25)")
    fig.colorbar(im, ax=ax, shrink=0.8)
    print(f"affine polynomial: {poly.gcp_rmse:.2f} px at the GCPs, {poly.error_rmse:.1f} px RMS and "
          f"{poly.error_max:.1f} px at most over the scene (x {c.gsd:.1f} m GSD)")""",
    ),
    (
        "md",
        """## 5. A rigorous push-broom model and the RPC fitted to it

Where an RPC comes from: the vendor fits it to the rigorous line-scanner model (every image line its own
orbit position and attitude), terrain-independently, over a 3-D grid of ground points spanning the
scene's height range (Tao & Hu 2001). `ptx.fit_rpc` does that for a `ptx.PushbroomCamera`; here on a
synthetic 620 km orbit looking 20 degrees across and 15 degrees along track (`ptx.pushbroom_scene`, no
shared data needed). The map shows the fitted RPC's error on check points between the fit grid's nodes
and layers: the RPC stands in for the rigorous model to a small fraction of a pixel.""",
    ),
    (
        "code",
        """scene = ptx.pushbroom_scene(roll=20.0, pitch=15.0, image_size=(3000, 3000))
fit = ptx.fit_rpc(scene.camera, scene.height_range)
err = np.hypot(*fit.check_residuals.T)
fig, ax = plt.subplots(figsize=(6.5, 6))
sc = ax.scatter(*fit.check_pixel.T, c=err, s=12, cmap="viridis")
ax.invert_yaxis()
ax.set_aspect("equal")
ax.set_xlabel("column (px)")
ax.set_ylabel("row (px)")
ax.set_title("|fitted RPC - rigorous push-broom| on the check points (px)")
fig.colorbar(sc, ax=ax, shrink=0.8)
print(f"RPC fit: {fit.points} fit points, RMS {fit.rmse:.1e} px; {fit.check_points} check points, "
      f"RMS {fit.check_rmse:.1e} px, largest {fit.check_max_error:.1e} px")""",
    ),
    (
        "md",
        """## 6. A crop of the scene, as vendors ship them, on a DEM that covers half of it

Vendors (and `gdal_translate -srcwin`) deliver a cut of a scene with the scene's RPC, its sample and
line offsets moved by the cut's origin (`SAMP_OFF - col_off`, `LINE_OFF - row_off`): the offsets can lie
far outside the crop. `RPCCamera.crop` writes that RPC. Here a 800 x 300 px crop holding the three GCPs
inside the file is orthorectified onto the DEM blanked south of the crop's centre: the ortho is nodata
where the DEM has no height, and photax says which share of the crop it covers (`ptx.dem_coverage`, a
`PartialDEMWarning` below 95 %). Its RPC is then refined on the GCPs inside it, in its own pixels: the
result is the crop's RPC still (its offsets and size), and the scene's shift refined on the same GCPs.""",
    ),
    (
        "code",
        """if have_qb:
    c0, r0, w, h = 40, 20, 800, 300
    crop = rpc.crop(c0, r0, w, h)
    print(f"scene SAMP_OFF, LINE_OFF {float(rpc.offsets[3]):.2f}, {float(rpc.offsets[4]):.2f} -> "
          f"crop {float(crop.offsets[3]):.2f}, {float(crop.offsets[4]):.2f}; image {crop.image_size}")
    centre = crop.to_ground_dem(np.array([[w / 2 - 0.5, h / 2 - 0.5]]), dem)[0]
    cx, cy = pyproj.Transformer.from_crs("EPSG:4326", dem.crs, always_xy=True).transform(*centre[:2])
    heights = np.array(dem.heights)
    t = np.asarray(dem.transform)
    heights[t[5] + t[4] * (np.arange(heights.shape[0]) + 0.5) < cy] = np.nan  # south of the crop's centre
    half = ptx.DEM(heights, t, dem.crs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        crop_grid = ortho_grid(None, crop, half, 5.0, crs=dem.crs)
        crop_ortho, _ = orthorectify(image[r0 : r0 + h, c0 : c0 + w], None, crop, half, crop_grid, nodata=0)
    partial = [x.message for x in caught if isinstance(x.message, ptx.PartialDEMWarning)]
    print(f"PartialDEMWarning: {partial[0]} (coverage {partial[0].coverage:.3f}; ptx.dem_coverage: "
          f"{ptx.dem_coverage(None, crop, half):.3f})")
    inside = np.all((pixel >= [c0, r0]) & (pixel < [c0 + w, r0 + h]), axis=1)
    crop_fit = ptx.refine_rpc(crop, ground[inside], pixel[inside] - [c0, r0], "shift",
                              names=[n for n, k in zip(names, inside) if k])
    scene_fit = ptx.refine_rpc(rpc, ground[inside], pixel[inside], "shift")
    print(crop_fit.report())
    same = np.abs(np.asarray(crop_fit.camera(ground)) - np.asarray(scene_fit.camera.crop(c0, r0, w, h)(ground))).max()
    print(f"refined crop RPC: offsets {np.asarray(crop_fit.camera.offsets)[3:]}, image {crop_fit.camera.image_size}; "
          f"against the scene's refinement cropped: {same:.1e} px")
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), gridspec_kw={"width_ratios": [1.6, 1]})
    axes[0].imshow(image[r0 : r0 + h, c0 : c0 + w], cmap="gray")
    axes[0].plot(*(pixel[inside] - [c0, r0]).T, "r+", ms=12, mew=2)
    axes[0].set_title(f"the crop ({w} x {h} px at {c0}, {r0}) and its GCPs")
    axes[1].imshow(np.where(crop_ortho > 0, crop_ortho, np.nan), cmap="gray",
                   extent=np.array(crop_grid.bounds)[[0, 2, 1, 3]] / 1000)
    axes[1].set_title(f"its ortho on the half DEM ({partial[0].coverage:.0%} covered)")
    axes[1].set_xlabel("E (km, Lo25)")
    fig.tight_layout()""",
    ),
]

if __name__ == "__main__":
    write_notebook(CELLS, "08_satellite.ipynb")
