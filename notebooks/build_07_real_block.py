"""Write notebooks/07_real_block.ipynb (without outputs).

Run: ``python notebooks/build_07_real_block.py``.  The notebook is
committed without outputs; tests/test_notebooks.py executes it.  It needs
orthority's test corpus in ``../../shared/data/orthority`` and says so, and
does nothing else, when it is absent.
"""

from _build import write_notebook

CELLS = [
    (
        "md",
        """# A real block, from raw files to one mosaic

Four frames of a real aerial survey (an Intergraph DMC of the South African NGI, downsampled to
640 x 1152 px; two strips flown in **opposite directions**), its DEM, and the orientations of the
survey's own aerial triangulation -- orthority's test corpus (`../../shared/data/orthority`,
see `SOURCES.md` there). A surveyor's chain, each step with what it tells about itself:

1. **orientations from approximate ones**: the survey's orientations, disturbed as a navigation
   grade GNSS/INS would give them (positions by 2 m, angles by 0.05 deg, seeded), are the start;
2. **tie points** between the overlapping frames, matched guided by those orientations and the DEM
   (`ptx.match_ties`);
3. a **GNSS/INS-aided bundle adjustment**: the start positions are observations with sigma 2 m,
   the angles loose ones with sigma 1 deg; no ground control. Its report, the residual vectors and
   the sigma of every camera; then the same adjustment with the DEM's heights as observations of
   the tie points (sigma 3 m, the DEM's measured error), and what that changes per camera;
4. the **orthos** of the four frames in one call, and one **mosaic** with its seamlines;
5. the drone images of the same corpus (ODM's `reconstruction.json`) orthorectified as they are.

The same chain from the shell is in the README ("real-block chain"). Resolutions are coarse
(10 m, 0.5 m) to keep the notebook quick.""",
    ),
    (
        "code",
        """import json
import pathlib
import tempfile
import warnings

import matplotlib.pyplot as plt
import numpy as np
import rasterio
from IPython.display import Markdown, display

import photax as ptx
from photax.io import read_exteriors, read_interior, read_opensfm_cameras, read_opensfm_shots
from photax.matching import bundle_problem


def find_corpus():
    \"\"\"orthority's test corpus, ../../shared/data/orthority relative to this notebook.\"\"\"
    here = pathlib.Path.cwd()
    for base in (here / "../../shared/data", here / "../shared/data", here / "shared/data"):
        if (base / "orthority" / "ngi" / "dem.tif").is_file():
            return (base / "orthority").resolve()
    return None


DATA = find_corpus()
have = DATA is not None
work = pathlib.Path(tempfile.mkdtemp(prefix="photax-nb07-"))
if have:
    print("orthority's corpus:", DATA)
else:
    display(Markdown("*orthority's corpus is not in `../../shared/data/orthority`: nothing to run.*"))""",
    ),
    (
        "md",
        """## 1. The raw files and the start orientations

The camera is orthority's interior file (focal length and sensor size in mm, principal point at
the centre); the exterior file gives X, Y, Z and omega-phi-kappa in degrees, in the CRS of the
`.prj` beside it. The survey's values are kept as the reference the adjustment is judged by.""",
    ),
    (
        "code",
        """if have:
    NGI, IO = DATA / "ngi", DATA / "io"
    names = sorted(p.stem for p in NGI.glob("3324c_*.tif"))
    short = [n[16:23] for n in names]  # strip_frame, e.g. 05_0182
    files = [NGI / f"{n}.tif" for n in names]
    camera = read_interior(IO / "ngi_int_param.yaml")
    survey, crs = read_exteriors(IO / "ngi_xyz_opk.csv", names)
    dem = ptx.read_dem(NGI / "dem.tif")
    rgb = [ptx.read_geotiff(f)[0] for f in files]
    grey = [im.astype(float).mean(axis=0) for im in rgb]

    # The start: the survey's orientations disturbed as a GNSS/INS would give them (seeded).
    rng = np.random.default_rng(21)
    start = []
    for n in names:
        e = survey[n]
        start.append(
            ptx.ExteriorOrientation(
                np.asarray(e.position) + rng.normal(0.0, 2.0, 3),
                np.asarray(e.angles) + np.radians(rng.normal(0.0, 0.05, 3)),
                convention=e.convention,
            )
        )
    for n, e in zip(names, start):
        kappa = np.degrees(np.asarray(e.angles))[2]
        print(f"{n}: X {float(e.X):.1f}  Y {float(e.Y):.1f}  Z {float(e.Z):.1f}  kappa {kappa:7.2f} deg")""",
    ),
    (
        "md",
        """## 2. Tie points, and the tie graph over the footprints

Interest points are matched between every pair of frames whose footprints overlap, each match
predicted from the start orientations and the DEM. The figure draws each frame's footprint on the
DEM (its image border monoplotted), the tie points on the ground, and a line between the centres of
two frames for every pair with ties (its width and label: the number of ties), a dashed one for
frames that overlap but gave no accepted tie. A pair without ties leaves
the block in parts that only the GNSS observations hold together; the bundle says so.""",
    ),
    (
        "code",
        """if have:
    ties = ptx.match_ties(grey, camera, start, dem)
    for (i, j), s in sorted(ties.pair_status.items()):
        if s != "no overlap":
            print(f"{short[i]} - {short[j]}: {ties.pair_ties.get((i, j), 0):3d} tracks seen in both ({s})")
    print(f"{ties.n_tracks} tie tracks, {len(ties.obs_xy)} observations")

    w, h = camera.image_size
    border = np.concatenate([np.linspace((0, 0), (w - 1, 0), 20), np.linspace((w - 1, 0), (w - 1, h - 1), 20),
                             np.linspace((w - 1, h - 1), (0, h - 1), 20), np.linspace((0, h - 1), (0, 0), 20)])
    feet = [np.asarray(ptx.image_to_ground(camera.pixel_to_image(border), e, camera, dem=dem)) for e in start]
    feet = [f[np.isfinite(f).all(axis=1)] for f in feet]  # where the ray leaves the DEM: no ground
    centres = np.array([np.nanmean(f[:, :2], axis=0) for f in feet])

    fig, ax = plt.subplots(figsize=(7, 8))
    colours = plt.cm.tab10(np.arange(len(names)))
    for k, (f, c) in enumerate(zip(feet, colours)):
        ax.fill(f[:, 0], f[:, 1], color=c, alpha=0.12)
        ax.plot(f[:, 0], f[:, 1], color=c, lw=1.5, label=short[k])
    first = np.asarray([ties.obs_image[ties.obs_point == t].min() for t in range(ties.n_tracks)])
    ax.scatter(ties.ground[:, 0], ties.ground[:, 1], s=10, c=colours[first], edgecolors="k", linewidths=0.3,
               zorder=3)
    most = max(ties.pair_ties.values(), default=1)
    for (i, j), count in ties.pair_ties.items():
        if ties.pair_status[(i, j)] == "ok":
            ax.plot(*centres[[i, j]].T, color="k", lw=1 + 5 * count / most, zorder=4)
            at = 0.6 * centres[i] + 0.4 * centres[j]  # off the middle: crossing lines keep their labels apart
            ax.annotate(str(count), at, ha="center", va="center", zorder=5,
                        bbox=dict(boxstyle="round", fc="w", ec="k", lw=0.5))
    for (i, j), status in ties.pair_status.items():
        if status not in ("ok", "no overlap"):  # overlapping, but no accepted ties
            ax.plot(*centres[[i, j]].T, color="r", ls="--", lw=1, zorder=4)
    ax.plot([], [], color="r", ls="--", lw=1, label="overlap, no ties")
    ax.plot(*centres.T, "ko", ms=6, zorder=5)
    ax.set_aspect("equal")
    ax.set_xlabel("X (m)")
    ax.set_ylabel("Y (m)")
    ax.set_title("footprints, tie points and the tie graph (ties per pair)")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()""",
    ),
    (
        "md",
        """## 3. The GNSS/INS-aided bundle adjustment

No ground control: the start positions enter as GNSS observations (sigma 2 m per axis) and the
start angles as INS observations (sigma 1 deg, loose: the ties decide them where they can). These
give the block its datum. The report has sigma0, the GNSS and attitude residuals, the precision and
the parts of the block that share no tie point.""",
    ),
    (
        "code",
        """if have:
    problem = bundle_problem(camera, start, ties, image_names=names)
    angles0 = np.stack([np.asarray(e.angles) for e in start])
    problem = problem.replace(
        gnss_position=np.stack([np.asarray(e.position) for e in start]), gnss_sigma=2.0,
        attitude=angles0, attitude_sigma=np.radians(1.0),
    )
    result = ptx.bundle_adjust(problem)
    print(result.report())""",
    ),
    (
        "md",
        """**Against the survey's own triangulation** (itself an adjustment, so not exact truth): how far
each adjusted projection centre and angle is from it, beside the sigma the adjustment reports.""",
    ),
    (
        "code",
        """if have:
    pos = np.asarray(result.exterior.position)
    ang = np.degrees(np.asarray(result.exterior.angles))
    std = np.asarray(result.exterior_std)
    rows = []
    for k, n in enumerate(names):
        d_pos = pos[k] - np.asarray(survey[n].position)
        d_ang = (ang[k] - np.degrees(np.asarray(survey[n].angles)) + 180) % 360 - 180
        rows.append(f"| {short[k]} | {np.linalg.norm(d_pos):.2f} | {np.linalg.norm(std[k, :3]):.2f} "
                    f"| {np.abs(d_ang).max():.3f} | {np.degrees(std[k, 3:]).max():.3f} |")
    display(Markdown("| image | position off (m) | its sigma (m) | largest angle off (deg) | its sigma (deg) |\\n"
                     "|---|---|---|---|---|\\n" + "\\n".join(rows)))""",
    ),
    (
        "md",
        """### Residual vectors and the sigma of each camera

Left: each tie observation's residual (measured minus adjusted projection) as an arrow on its
frame, strongly magnified; a pattern (rotation, radial flow) would mean a model error, random
arrows mean the ties fit. Right: the standard deviation of each camera's position and angles from
the adjustment's covariance.""",
    ),
    (
        "code",
        """if have:
    obs_img = np.asarray(problem.obs_image)
    obs_xy = np.asarray(camera.image_to_pixel(np.asarray(problem.obs_xy)))
    res_px = np.asarray(result.residuals) / np.asarray(problem.obs_sigma)  # in sigmas of each observation
    fig = plt.figure(figsize=(12, 9))
    ax = fig.add_subplot(2, 1, 1)
    scale = 0.25 * w / max(np.abs(res_px).max(), 1e-9)
    for k, c in enumerate(colours):
        sel = obs_img == k
        ax.quiver(obs_xy[sel, 0] + k * (w + 40), obs_xy[sel, 1], res_px[sel, 0] * scale, -res_px[sel, 1] * scale,
                  color=c, angles="xy", scale_units="xy", scale=1, width=0.002)
        ax.plot(obs_xy[sel, 0] + k * (w + 40), obs_xy[sel, 1], ".", color=c, ms=3)
        ax.add_patch(plt.Rectangle((k * (w + 40), 0), w, h, fill=False, ec=c))
        ax.text(k * (w + 40) + w / 2, -30, short[k], ha="center", fontsize=9)
    ax.set_xlim(-40, len(names) * (w + 40))
    ax.set_ylim(h + 40, -80)
    ax.set_aspect("equal")
    ax.set_axis_off()
    ax.set_title(f"tie residuals in sigmas of each observation, magnified so the longest is a quarter frame; "
                 f"sigma0 = {result.sigma0:.2f}", fontsize=10)
    x = np.arange(len(names))
    ax = fig.add_subplot(2, 2, 3)
    for i, lab in enumerate("XYZ"):
        ax.bar(x + (i - 1) * 0.25, std[:, i], 0.25, label=lab)
    ax.axhline(2.0, color="k", ls=":", lw=1, label="GNSS sigma")
    ax.set_xticks(x, short)
    ax.set_ylabel("m")
    ax.legend(fontsize=8, ncol=4)
    ax.set_title("sigma of each camera's position")
    ax = fig.add_subplot(2, 2, 4)
    for i, lab in enumerate(("omega", "phi", "kappa")):
        ax.bar(x + (i - 1) * 0.25, np.degrees(std[:, 3 + i]) * 3600, 0.25, label=lab)
    ax.axhline(3600.0, color="k", ls=":", lw=1, label="INS sigma")
    ax.set_yscale("log")
    ax.set_xticks(x, short)
    ax.set_ylabel("arcsec")
    ax.legend(fontsize=8, ncol=4)
    ax.set_title("sigma of each camera's angles")
    fig.tight_layout()""",
    ),
    (
        "md",
        """### The same adjustment with the DEM's heights

The DEM is one more observation the block already has: each tie point lies on the terrain, so its
height is an observation of the DEM at its position (`Z - DEM(X, Y) = 0`, `BundleProblem(dem=,
dem_sigma=)`; `photax bundle BLOCK --dem DEM --dem-sigma S`). The terrain's relief then holds the
block's tilt and height, where the four GNSS positions alone leave it free to turn.

Its sigma, **3 m**, is the DEM's error at the ties measured independently of any adjustment, not
tuned: `benchmarks/gnss_ngi.py --dem-sigma` intersects the ties with the survey's orientations
(`camera_pos_ori.txt`, held) and finds them 2.7-3.1 m RMS off the DEM (std 2.7-3.0 m, mean -0.3 to
-0.6 m, heavy tails from trees and buildings; six seeds). The cell below repeats that measurement on
this notebook's ties, then adjusts the same block, ties, GNSS and INS observations once more, now
with the DEM; its report ends with the DEM heights' residual RMS and the sigma the adjustment
estimates for them (a variance component: near 3 m if the 3 m was right).""",
    ),
    (
        "code",
        """if have:
    # The survey's own adjustment, camera_pos_ori.txt (X Y Z omega phi kappa, degrees): the reference.
    lines = (NGI / "camera_pos_ori.txt").read_text().splitlines()
    ref = {ln.split()[0]: np.array(ln.split()[1:7], float) for ln in lines if ln.strip()}
    ref_pos = np.stack([ref[n][:3] for n in names])
    ref_ang = np.stack([ref[n][3:] for n in names])
    # The DEM's error at these ties, independent of the adjustment: the ties intersected with the
    # survey's orientations (held: only the points are adjusted), their heights against the DEM's.
    held = ptx.bundle_adjust(problem.replace(
        exterior=ptx.ExteriorOrientation(ref_pos, np.radians(ref_ang), convention=start[0].convention),
        fixed_exterior=np.ones((len(names), 6), bool), gnss_position=None, gnss_sigma=None, attitude=None,
        attitude_sigma=None))
    dz = held.points[:, 2] - np.asarray(dem.height(held.points[:, 0], held.points[:, 1]))
    dz = dz[np.isfinite(dz)]
    print(f"these ties intersected with camera_pos_ori.txt ({len(dz)} on the DEM): Z - DEM RMS "
          f"{np.sqrt(np.mean(dz**2)):.2f} m, mean {dz.mean():+.2f} m, median |dZ| {np.median(np.abs(dz)):.2f} m")

    DEM_SIGMA = 3.0  # m: measured by benchmarks/gnss_ngi.py as above, not tuned
    with_dem = ptx.bundle_adjust(problem.replace(dem=dem, dem_sigma=DEM_SIGMA, crs=crs))
    print(with_dem.report(unit="m"))""",
    ),
    (
        "md",
        """**What the DEM changes, image by image.** Top: the sigma of each camera's position and angles
from the adjustment's covariance, without the DEM (pale, hatched) and with it (solid). Bottom: how
far the recovered positions and angles are from the survey's adjustment (`camera_pos_ori.txt`,
itself an adjustment, so not exact truth), with and without the DEM, each with its reported sigma as
an error bar; the dotted lines are the issue's targets (4 m, 0.05 deg). With the DEM the angles'
sigma falls below what the survey can check: with the positions held at the survey's, the ties alone
already differ from its angles by 0.015-0.02 deg (`benchmarks/gnss_ngi.py`), so an angle 2-3 sigma
off is that disagreement, not the DEM's.""",
    ),
    (
        "code",
        """if have:
    runs = {"without DEM": result, "with DEM": with_dem}
    comps = (("X", "Y", "Z"), ("omega", "phi", "kappa"))
    diffs, stds = {}, {}
    for label, r in runs.items():
        d_ang = (np.degrees(np.asarray(r.exterior.angles)) - ref_ang + 180) % 360 - 180
        diffs[label] = (np.asarray(r.exterior.position) - ref_pos, d_ang)
        s = np.asarray(r.exterior_std)
        stds[label] = (s[:, :3], np.degrees(s[:, 3:]))
    x = np.arange(len(names))
    fig, axes = plt.subplots(2, 2, figsize=(13, 8), sharex=True)
    for col, (unit, target) in enumerate((("m", 4.0), ("deg", 0.05))):
        for i, lab in enumerate(comps[col]):
            for half, (label, alpha, hatch) in enumerate((("without DEM", 0.35, "//"), ("with DEM", 1.0, None))):
                at = x + (i - 1) * 0.27 + (half - 0.5) * 0.13
                kw = dict(color=f"C{i}", alpha=alpha, hatch=hatch, edgecolor=f"C{i}", lw=0.5)
                axes[0, col].bar(at, stds[label][col][:, i], 0.13, label=f"{lab}, {label}", **kw)
                axes[1, col].bar(at, diffs[label][col][:, i], 0.13, yerr=stds[label][col][:, i],
                                 error_kw=dict(lw=0.8, capsize=2), **kw)
        axes[0, col].set_ylabel(unit)
        axes[0, col].set_title(f"sigma of each camera's {'position' if col == 0 else 'angles'}")
        axes[0, col].margins(y=0.3)  # room for the legend above the bars
        axes[0, col].legend(fontsize=7, ncol=3)
        axes[1, col].axhline(0, color="k", lw=0.5)
        for sign in (-1, 1):
            axes[1, col].axhline(sign * target, color="k", ls=":", lw=1)
        axes[1, col].set_ylabel(unit)
        axes[1, col].set_title(f"recovered {'position' if col == 0 else 'angles'} - camera_pos_ori.txt (bars: ±1 sigma)")
        axes[1, col].set_xticks(x, short)
    fig.tight_layout()
    for label in runs:
        print(f"{label}: median sigma omega, phi, kappa {np.round(np.median(stds[label][1], axis=0), 4)} deg, "
              f"X, Y, Z {np.round(np.median(stds[label][0], axis=0), 2)} m; largest difference to the survey "
              f"{np.abs(diffs[label][1]).max():.3f} deg, {np.abs(diffs[label][0]).max():.2f} m")""",
    ),
    (
        "md",
        """## 4. Orthos of the block in one call, and one mosaic with its seamlines

`ptx.orthorectify_files` writes every frame's ortho (each atomically) with the adjusted
orientations, in one process; `ptx.mosaic` balances gain and offset in the overlaps, cuts
seamlines of least difference and writes them (GeoJSON) with a source index (which frame each
pixel comes from).""",
    ),
    (
        "code",
        """if have:
    adjusted = [ptx.ExteriorOrientation(pos[k], np.radians(ang[k]), convention=result.exterior.convention)
                for k in range(len(names))]
    outs = [work / f"{n}_ortho.tif" for n in names]
    grids = ptx.orthorectify_files(files, outs, adjusted, camera, dem, resolution=10.0, crs=crs)
    for n, g in zip(names, grids):
        print(f"{n}: {g.width} x {g.height} px of 10 m" if isinstance(g, ptx.Grid) else f"{n}: failed: {g}")
    info = {}
    mosaic = ptx.mosaic([str(p) for p in outs], info=info, seamlines=work / "seams.geojson",
                        source_index=work / "source.tif").compute()
    print("gains per frame (R, G, B):", np.round(info["gains"], 3).tolist())""",
    ),
    (
        "code",
        """if have:
    seams = json.loads((work / "seams.geojson").read_text())
    img = np.moveaxis(mosaic.values, 0, -1)
    x, y = mosaic.x.values, mosaic.y.values
    extent = (x[0], x[-1], y[-1], y[0])
    with rasterio.open(work / "source.tif") as src:
        index = src.read(1)
    fig, axes = plt.subplots(1, 2, figsize=(12, 8), sharex=True, sharey=True)
    rgba = np.dstack([np.clip(np.nan_to_num(img) / 255, 0, 1), np.isfinite(img).all(axis=-1)])
    axes[0].imshow(rgba, extent=extent)
    masked = np.ma.masked_less(index, 0)
    axes[1].imshow(masked, extent=extent, cmap=plt.matplotlib.colors.ListedColormap(colours), vmin=-0.5,
                   vmax=len(names) - 0.5, alpha=0.6)
    for f in seams["features"]:
        geom = f["geometry"]
        polys = geom["coordinates"] if geom["type"] == "MultiPolygon" else [geom["coordinates"]]
        for poly in polys:
            ring = np.asarray(poly[0])
            for ax in axes:
                ax.plot(ring[:, 0], ring[:, 1], color="yellow", lw=1.2)
    axes[0].set_title("mosaic of the four frames, seamlines in yellow")
    axes[1].set_title("source index: the frame each pixel comes from")
    for ax in axes:
        ax.set_xlabel("X (m)")
    axes[0].set_ylabel("Y (m)")
    fig.tight_layout()""",
    ),
    (
        "md",
        """## 5. The drone images, orthorectified as ODM left them

Four DJI images (1368 x 912 px, downsampled) whose kappas differ by 90 and 180 deg, with ODM's
OpenSfM `reconstruction.json` (a `brown` camera, shots in a topocentric frame) and its DSM.
`read_opensfm_cameras` and `read_opensfm_shots` read them as they are (the shots into the DSM's
CRS); the orthos at 0.5 m, side by side.""",
    ),
    (
        "code",
        """if have:
    ODM = DATA / "odm"
    rec = ODM / "opensfm" / "reconstruction.json"
    dsm = ptx.read_dem(ODM / "odm_dem" / "dsm.tif")
    (drone_cam,) = read_opensfm_cameras(rec).values()
    shots, drone_crs, _ = read_opensfm_shots(rec, crs=dsm.crs)
    drone = sorted((ODM / "images").glob("*.tif"))
    d_outs = [work / f"{p.stem}_ortho.tif" for p in drone]
    # ODM's DSM covers the ground it reconstructed, not each image's whole footprint: the orthos are
    # nodata beyond it (the share below; orthorectify says so with a PartialDEMWarning, expected here)
    print("the DSM covers", ", ".join(f"{ptx.dem_coverage(shots[p.stem], drone_cam, dsm):.0%}" for p in drone),
          "of the four images")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ptx.PartialDEMWarning)
        d_grids = ptx.orthorectify_files(drone, d_outs, [shots[p.stem] for p in drone], drone_cam, dsm,
                                         resolution=0.5, crs=drone_crs)
    fig, axes = plt.subplots(1, len(drone), figsize=(14, 4))
    for ax, p, out in zip(axes, drone, d_outs):
        with rasterio.open(out) as src:
            b = src.bounds
            data = np.dstack([np.moveaxis(src.read((1, 2, 3)), 0, -1), src.read_masks(1)])
        ax.imshow(data, extent=(b.left, b.right, b.bottom, b.top))
        ax.set_title(p.stem, fontsize=9)
        ax.tick_params(labelsize=7)
    fig.suptitle("drone orthos at 0.5 m (same CRS, each on its own footprint)")
    fig.tight_layout()""",
    ),
    (
        "md",
        """**What to take from it.** The ties decide the relative orientation of the frames they connect;
GNSS gives the block its place, scale and, with the loose attitudes, its rotation where the ties
leave it free (between strips without cross-strip ties the block falls into parts, and the
report says so). Four GNSS positions hold that rotation only loosely; the DEM's heights at the
ties, at their measured sigma, hold the angles two to three times tighter here. Each step's own
measure of quality -- tie counts per pair, sigma0, GNSS and DEM residuals, sigma per camera, the
seams -- is what a surveyor checks before trusting the mosaic. `tests/test_real_block.py` checks
the same chain from the shell (the bundle with the DEM) and photax's orthos against orthority's
(mean absolute difference <= 0.3 grey levels, offset <= 0.05 px).""",
    ),
]


if __name__ == "__main__":
    write_notebook(CELLS, "07_real_block.ipynb")
