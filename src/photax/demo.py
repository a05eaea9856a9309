"""The photax demo: a report (Markdown + PNG figures) on the bundled sample data.

:func:`run_demo` runs each function of :data:`SECTIONS` in turn; a section
takes the output folder, writes its figures there and returns its Markdown.
Other parts of photax add their own section by appending a function to
``SECTIONS``, e.g. ``rectification_section(out)`` and ``bundle_section(out)``.

The sample scene (:func:`sample_scene`) is generated, not measured: a seeded
synthetic vertical aerial frame with ground control and check points, one of
which carries a deliberate blunder.  ``data/make_sample.py`` writes the same
scene to ``data/`` so it can be read without photax; the demo regenerates it
in its output folder, so it works from any installation and never writes
into the package or the repository.
"""

from __future__ import annotations

import pathlib
from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .camera import FrameCamera
from .collinearity import ExteriorOrientation, image_to_ground, project
from .dem import DEM
from .io.atomic import atomic_write
from .io.camera_file import read_camera, write_camera
from .io.gcp import GCPTable, read_gcps
from .io.results import write_json
from .scene import texture

# --------------------------------------------------------------------------- sample scene

SAMPLE_SEED = 20240917
SAMPLE_IMAGE = "IMG_0001"
SAMPLE_NOISE_PX = 0.3
SAMPLE_BLUNDER = ("P07", (15.0, 0.0))  # a point name and its deliberate error (column, row) in pixels
SAMPLE_CHECK = ("P03", "P06", "P11", "P14")
SAMPLE_CRS = "EPSG:32633"
SAMPLE_ORIGIN = (512_300.0, 4_103_800.0)  # local origin of the relief and the texture (UTM-like: photax must reduce)
SAMPLE_DEM_CELL = 5.0  # metres
SAMPLE_DEM_HALF = 600.0  # the DEM spans the origin +- this many metres (the footprint plus a margin)
SAMPLE_TARGET_RADIUS = 6.0  # metres: ground targets painted at the GCPs, ~8 px in the image


def _relief(x, y):
    """Terrain height in metres at local (x, y) metres: a hill and a slope, 40 .. 125 m."""
    return 60.0 + 0.03 * x + 45.0 * np.exp(-((x - 120.0) ** 2 + (y + 60.0) ** 2) / (2 * 180.0**2))


def _sample_dem() -> DEM:
    """The sample DEM: :func:`_relief` at the centres of 5 m cells, float32 as stored in the GeoTIFF."""
    x0, y0 = SAMPLE_ORIGIN
    n = int(round(2 * SAMPLE_DEM_HALF / SAMPLE_DEM_CELL))
    centres = -SAMPLE_DEM_HALF + SAMPLE_DEM_CELL * (np.arange(n) + 0.5)
    heights = _relief(centres[None, :], -centres[:, None]).astype(np.float32)  # row 0 is the north edge
    transform = (SAMPLE_DEM_CELL, 0.0, x0 - SAMPLE_DEM_HALF, 0.0, -SAMPLE_DEM_CELL, y0 + SAMPLE_DEM_HALF)
    return DEM(heights.astype(float), transform, crs=SAMPLE_CRS)


@eqx.filter_jit
def _monoplot(pixel, exterior, camera, dem):
    return image_to_ground(camera.pixel_to_image(pixel), exterior, camera, dem=dem)


def sample_scene() -> dict:
    """The sample scene: camera, true exterior orientation, DEM and the GCP table.

    A 1000 x 750 px frame camera (f = 8.8 mm, 17.6 um pixels, so f = 500 px;
    a small principal-point offset and radial distortion) about 380 m above
    hilly ground at UTM-scale coordinates (GSD ~ 0.76 m), tilted by about
    1 deg.  The terrain is the DEM :func:`_sample_dem` (5 m cells).  16 points
    on a jittered 4 x 4 grid of the image, monoplotted onto the DEM
    (:func:`photax.image_to_ground`): 12 control and 4 check points
    (:data:`SAMPLE_CHECK`), pixel noise 0.3 px (Gaussian, per coordinate),
    and a 15 px blunder on :data:`SAMPLE_BLUNDER`.

    Returns:
        dict with ``camera``, ``exterior`` (phi-omega-kappa), ``dem``,
        ``table`` (:class:`photax.io.GCPTable`, measured pixels),
        ``pixel_true`` ``(16, 2)`` noise-free pixels, ``crs``.
    """
    rng = np.random.default_rng(SAMPLE_SEED)
    width, height = 1000, 750
    camera = FrameCamera(8.8, (0.011, -0.0066), (-0.02, 0.004, 0.0, 0.0, 0.0),
                         pixel_size=0.0176, image_size=(width, height))
    origin = np.array([*SAMPLE_ORIGIN, 0.0])
    exterior = ExteriorOrientation(origin + np.array([8.0, -12.0, 450.0]),
                                   np.radians([1.2, -0.8, 35.0]), "phi-omega-kappa")
    dem = _sample_dem()
    # Jittered 4 x 4 grid in the image, kept ~40 px from the border.
    u = np.linspace(0.0625, 0.9375, 4) * width
    v = np.linspace(0.0833, 0.9167, 4) * height
    pix = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2) + rng.uniform(-25, 25, (16, 2))
    # Monoplot each pixel onto the DEM; survey the ground point to the millimetre.
    ground = np.round(np.asarray(_monoplot(jnp.asarray(pix), exterior, camera, dem)), 3)
    if not np.all(np.isfinite(ground)):  # pragma: no cover - a bug in the scene, not user input
        raise RuntimeError("a sample point's ray missed the DEM")
    pixel_true = np.asarray(camera.image_to_pixel(project(ground, exterior, camera)))
    pixel = pixel_true + rng.normal(0.0, SAMPLE_NOISE_PX, pixel_true.shape)
    names = np.array([f"P{k + 1:02d}" for k in range(16)])
    pixel[names == SAMPLE_BLUNDER[0]] += np.asarray(SAMPLE_BLUNDER[1])
    pixel = np.round(pixel, 3)
    table = GCPTable(
        names=names, images=np.full(16, SAMPLE_IMAGE), ground=ground, pixel=pixel, image_xy=None,
        sigma=np.full(16, SAMPLE_NOISE_PX), role=np.where(np.isin(names, SAMPLE_CHECK), "check", "control"),
        crs=SAMPLE_CRS)
    return {"camera": camera, "exterior": exterior, "dem": dem, "table": table, "pixel_true": pixel_true,
            "crs": table.crs}


def _targets(x, y, centres):
    """Survey targets: quartered black-and-white discs of radius :data:`SAMPLE_TARGET_RADIUS` m.

    ``x, y`` ``(n,)`` ground points, ``centres`` ``(k, 2)``; returns the
    target grey value ``(n,)`` and its opacity ``(n,)`` in [0, 1] (edges
    smoothed over ~0.4 m so the rendered image is not aliased).
    """
    dx = x[:, None] - centres[None, :, 0]
    dy = y[:, None] - centres[None, :, 1]
    r = jnp.hypot(dx, dy)
    nearest = jnp.argmin(r, axis=1)
    take = lambda a: jnp.take_along_axis(a, nearest[:, None], axis=1)[:, 0]  # noqa: E731
    dx, dy, r = take(dx), take(dy), take(r)
    grey = 0.5 + 0.45 * jnp.tanh(dx / 0.4) * jnp.tanh(dy / 0.4)
    return grey, jax.nn.sigmoid((SAMPLE_TARGET_RADIUS - r) / 0.3)


@eqx.filter_jit
def _render(pixel, exterior, camera, dem, origin, centres):
    g = image_to_ground(camera.pixel_to_image(pixel), exterior, camera, dem=dem)
    grey = texture(g[:, 0] - origin[0], g[:, 1] - origin[1])
    target, alpha = _targets(g[:, 0], g[:, 1], centres)
    return jnp.nan_to_num(grey * (1.0 - alpha) + target * alpha, nan=0.0)


def sample_image(scene: dict | None = None) -> np.ndarray:
    """The sample image ``(rows, cols)`` uint8, rendered by indirect mapping.

    Every pixel centre is monoplotted onto the sample DEM with the true
    orientation (:func:`photax.image_to_ground`) and the ground texture
    :func:`photax.scene.texture` (roads, fields, a ripple) is evaluated
    there, with a quartered survey target painted at every GCP's surveyed
    (X, Y).  The targets therefore appear at the noise-free pixel positions;
    the measured ones in ``sample_gcps.csv`` differ by the 0.3 px noise
    (and P07 by its 15 px blunder).
    """
    s = scene or sample_scene()
    w, h = s["camera"].image_size
    cc, rr = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    px = jnp.asarray(np.column_stack([cc.ravel(), rr.ravel()]))
    grey = np.asarray(_render(px, s["exterior"], s["camera"], s["dem"], jnp.asarray(SAMPLE_ORIGIN),
                              jnp.asarray(s["table"].ground[:, :2])))
    return np.clip(np.round(grey * 255.0), 0, 255).astype(np.uint8).reshape(h, w)


def write_sample(out_dir) -> dict[str, pathlib.Path]:
    """Write the sample scene: ``sample_gcps.csv``, ``sample_camera.yaml``, ``sample_truth.json``,
    ``sample_image.tif`` (uint8, no georeference: a raw photo) and ``sample_dem.tif`` (float32,
    EPSG:32633)."""
    from .io.raster import write_geotiff

    out = pathlib.Path(out_dir)
    s = sample_scene()
    t = s["table"]
    paths = {"gcps": out / "sample_gcps.csv", "camera": out / "sample_camera.yaml", "truth": out / "sample_truth.json",
             "image": out / "sample_image.tif", "dem": out / "sample_dem.tif"}
    with atomic_write(paths["gcps"], newline="") as fh:
        fh.write(f"# photax sample GCPs (synthetic, seed {SAMPLE_SEED}); pixels: integer = pixel centre, row down\n")
        fh.write(f"# crs: {t.crs}\n")
        fh.write("name,image,E,N,h,col,row,sigma,role\n")
        for k in range(len(t)):
            fh.write(f"{t.names[k]},{t.images[k]},{t.ground[k, 0]:.3f},{t.ground[k, 1]:.3f},{t.ground[k, 2]:.3f},"
                     f"{t.pixel[k, 0]:.3f},{t.pixel[k, 1]:.3f},{t.sigma[k]:g},{t.role[k]}\n")
    write_camera(s["camera"], paths["camera"], unit="mm")
    e = s["exterior"]
    write_json({
        "description": "true exterior orientation of the photax sample image (synthetic)",
        "seed": SAMPLE_SEED, "image": SAMPLE_IMAGE, "crs": t.crs, "convention": e.convention,
        "position": e.position, "angles_deg": np.degrees(np.asarray(e.angles)), "angles_rad": e.angles,
        "noise_px": SAMPLE_NOISE_PX, "blunder": {"name": SAMPLE_BLUNDER[0], "pixel_error": SAMPLE_BLUNDER[1]},
        "check_points": list(SAMPLE_CHECK),
        "pixel_true": {str(n): p for n, p in zip(t.names, s["pixel_true"])},
    }, paths["truth"])
    write_geotiff(paths["image"], sample_image(s), None)
    dem = s["dem"]
    write_geotiff(paths["dem"], np.asarray(dem.heights).astype(np.float32), tuple(np.asarray(dem.transform)),
                  crs=SAMPLE_CRS)
    return paths


# --------------------------------------------------------------------------- sections


def _residual_pixels(residuals, camera: FrameCamera) -> np.ndarray:
    """Image-plane residuals (y up) -> (column, row) pixel residuals."""
    ps = np.asarray(camera.pixel_size)
    return np.asarray(residuals) / ps[None, :] * np.array([1.0, -1.0])[None, :]


def resection_section(out: pathlib.Path) -> str:
    """Space resection of the sample image, compared with the truth."""
    import matplotlib

    matplotlib.use("Agg")  # the demo is headless
    import matplotlib.pyplot as plt

    from . import plot
    from .resection import resect

    paths = write_sample(out / "sample")
    table = read_gcps(paths["gcps"])
    camera = read_camera(paths["camera"])
    truth = sample_scene()["exterior"]
    res = resect(table.image_plane(camera), table.ground, camera, sigma=table.image_plane_sigma(camera),
                 check=table.check, names=table.names)
    write_json(res, out / "resection.json")

    fig, ax = plt.subplots(figsize=(8, 6.4))
    plot.residual_vectors(ax, table.pixel, _residual_pixels(res.residuals, camera), table.names,
                          outliers=res.outliers, check=res.check, image_size=camera.image_size,
                          title=f"{SAMPLE_IMAGE}: residuals after resection")
    fig.savefig(out / "resection_residuals.png", dpi=110, bbox_inches="tight")
    plt.close(fig)

    rows = plot.precision_rows(res, truth)
    md = ["## Space resection of the sample image", "",
          f"{len(table)} points on `{SAMPLE_IMAGE}` ({int((~table.check).sum())} control, "
          f"{int(table.check.sum())} check), read from `sample/sample_gcps.csv` with the camera "
          f"`sample/sample_camera.yaml`. The measurements carry {SAMPLE_NOISE_PX} px noise and "
          f"`{SAMPLE_BLUNDER[0]}` a deliberate {SAMPLE_BLUNDER[1][0]:g} px blunder.", "",
          f"Result: {res.message}; sigma0 = {res.sigma0:.3f} (a-priori sigma {SAMPLE_NOISE_PX} px), "
          f"control RMS = {res.rms / float(camera.pixel_size[0]):.3f} px, "
          f"check-point RMS = {res.check_rms / float(camera.pixel_size[0]):.3f} px.", "",
          "| parameter | estimate | std | truth | error | error/std |", "|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        f = "{:.3f}" if r["unit"] == "m" else "{:.5f}"
        md.append(f"| {r['parameter']} [{r['unit']}] | {f.format(r['value'])} | {f.format(r['std'])} | "
                  f"{f.format(r['true'])} | {f.format(r['error'])} | {r['ratio']:+.2f} |")
    flagged = [str(n) for n in np.asarray(res.names)[res.outliers]]
    verdict = ("found" if flagged == [SAMPLE_BLUNDER[0]] else "NOT found cleanly")
    md += ["", f"Blunders flagged by data snooping ({res.statistic} test, critical value {res.critical:.2f}): "
           f"{', '.join(flagged) or 'none'} - the planted blunder on {SAMPLE_BLUNDER[0]} was {verdict}.", "",
           "![residual vectors](resection_residuals.png)", "",
           "Full result: `resection.json`.", ""]
    return "\n".join(md)


def bundle_section(out: pathlib.Path) -> str:
    """Bundle adjustment of a synthetic aerial block, compared with the truth."""
    import matplotlib

    matplotlib.use("Agg")  # the demo is headless
    import matplotlib.pyplot as plt

    from . import plot
    from .bundle import bundle_adjust, synthetic_block

    problem, truth = synthetic_block(0, noise_px=0.5)
    res = bundle_adjust(problem)
    write_json(res.to_dict(), out / "bundle.json")
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    plot.convergence(axes[0], res)
    plot.bundle_residuals(axes[1], res)
    fig.savefig(out / "bundle.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    pos_err = np.linalg.norm(np.asarray(res.exterior.position) - np.asarray(truth.exterior.position), axis=1)
    tie = problem.roles == "tie"
    pt_err = np.abs(res.points - truth.points)[tie]
    md = ["## Bundle adjustment of a synthetic block", "",
          f"{problem!r}: 2 strips x 4 frames (f = 3000 px), {problem.obs_sigma[0, 0]:g} px image noise, "
          "control points fixed, check points adjusted as tie points. Start values: truth + ~5 m / 0.6 deg.", "",
          "```", res.report(), "```", "",
          f"Projection centres vs truth: max error {pos_err.max():.3f} m (reported median std "
          f"{np.median(np.linalg.norm(res.exterior_std[:, :3], axis=1)):.3f} m). "
          f"Tie points vs truth: RMS X/Y/Z {np.sqrt(np.mean(pt_err**2, axis=0)).round(3).tolist()} m "
          f"(reported median std {np.median(res.point_std[tie], axis=0).round(3).tolist()} m).", "",
          "![convergence and residuals](bundle.png)", "", "Full result: `bundle.json`.", ""]
    return "\n".join(md)


def rectification_section(out: pathlib.Path) -> str:
    """Collinearity + DEM against polynomials on a synthetic hilly scene."""
    import matplotlib

    matplotlib.use("Agg")  # the demo is headless
    import matplotlib.pyplot as plt

    from .compare import compare_models
    from .scene import relief_scene

    s = relief_scene(300.0, seed=0)
    c = compare_models(s.gcp_ground, s.gcp_pixel, s.camera, s.dem,
                       check_ground=s.check_ground, check_pixel=s.check_pixel)
    write_json(c.to_dict(), out / "comparison.json")
    images, grid = c.rectify(s.image, ["collinearity", "polynomial 1", "polynomial 5"])
    figures = {"comparison_error_maps.png": c.plot_error_maps(), "comparison_rmse.png": c.plot_rmse(),
               "comparison_rectified.png": c.plot_rectified(images, grid, reference=s.ortho,
                                                            reference_transform=s.ortho_transform, ncols=2)}
    for name, fig in figures.items():
        fig.savefig(out / name, dpi=100)
        plt.close(fig)
    poly = [c[n] for n in c.names if n.startswith("polynomial")]
    best = min(poly, key=lambda m: m.check_rmse)
    d = np.linalg.norm(c.relief_displacement(), axis=-1)
    md = ["## Rectification: collinearity + DEM against polynomials", "",
          f"A synthetic {s.camera.image_size[0]} x {s.camera.image_size[1]} px near-vertical frame (2 deg tilt, "
          f"f = 1000 px, {s.flying_height:.0f} m above the datum, GSD {c.gsd:.2f} m) over hills of "
          f"{float(np.ptp(np.asarray(s.dem.heights))):.0f} m; {len(s.gcp_pixel)} GCPs and {len(s.check_pixel)} "
          f"independent check points with {s.noise_px} px noise. All models are fitted to the same GCPs "
          "(`photax.compare_models`); polynomials see only (X, Y), so they cannot undo the relief "
          f"displacement d = r h / H, up to {np.nanmax(d):.0f} px here.", "",
          c.table(), "",
          f"Collinearity with the DEM fits the check points to {c['collinearity'].check_rmse:.2f} px "
          f"(the noise); the best polynomial (order {best.name.split()[-1]}) leaves {best.check_rmse:.1f} px, "
          f"and order 5 fits its GCPs to {c['polynomial 5'].gcp_rmse:.1f} px but misses the check points "
          f"by {c['polynomial 5'].check_rmse:.1f} px (overfitting).", "",
          "![error maps](comparison_error_maps.png)", "", "![RMSE per model](comparison_rmse.png)", "",
          "![rectified images](comparison_rectified.png)", "", "Full table: `comparison.json`.", ""]
    return "\n".join(md)


# Sections of the report, in order.  Each takes the output folder and returns Markdown.
SECTIONS: list[Callable[[pathlib.Path], str]] = [resection_section, rectification_section, bundle_section]


def _forbidden_roots() -> list[pathlib.Path]:
    package = pathlib.Path(__file__).resolve().parent
    return [package, package.parents[1] / "data"]


def run_demo(out_dir="photax-demo", *, progress: bool | str | Callable[[str], None] | None = None) -> pathlib.Path:
    """Run every section of :data:`SECTIONS` and write ``out_dir/report.md``.

    Args:
        out_dir: output folder (created); must not be inside the photax
            package or the repository's ``data/`` folder.
        progress: ``True`` or a label: one progress bar over the sections
            (labelled "demo", or the label; :mod:`photax.progress`), the
            current section as its postfix; a callable: called with a line
            of text as each section starts/ends; ``None``/``False``: quiet.

    Returns:
        the path of ``report.md``.
    """
    from .progress import progress_bar

    out = pathlib.Path(out_dir).resolve()
    for root in _forbidden_roots():
        if out == root or root in out.parents:
            raise ValueError(f"out_dir {out} is inside {root}; choose a folder of your own")
    out.mkdir(parents=True, exist_ok=True)
    say = progress if callable(progress) else (lambda _line: None)
    parts = ["# photax demo report", "",
             "Generated by `photax demo` on synthetic data with known truth.", ""]
    with progress_bar(None if callable(progress) else progress, len(SECTIONS), desc="demo", unit="section") as bar:
        for k, section in enumerate(SECTIONS, 1):
            name = section.__name__.replace("_section", "")
            say(f"[{k}/{len(SECTIONS)}] {name} ...")
            bar.set_postfix_str(name)
            parts.append(section(out))
            bar.update()
            say(f"[{k}/{len(SECTIONS)}] {name} done")
    report = out / "report.md"
    with atomic_write(report, encoding="utf-8") as fh:
        fh.write("\n".join(parts))
    return report
