"""``photax compare``: collinearity + DEM against polynomials on the same GCPs.

Resects the image from the control points (``role`` = control), fits
polynomials of the requested orders and the projective transform to the same
points, evaluates all of them on the check points (``role`` = check) and over
the image footprint, prints the table and, with ``--out-dir``, writes
``comparison.md``, ``comparison.json``, ``error_maps.png``, ``rmse.png`` and
(with ``--image``) ``rectified.png``, each atomically.  Exit codes: 0 done,
2 bad input.
"""

from __future__ import annotations

import argparse
import pathlib
import shutil


def parse_orders(text: str) -> tuple[int, ...]:
    """``"1-5"`` -> (1, 2, 3, 4, 5); ``"1,3,5"`` -> (1, 3, 5); ``"2"`` -> (2,)."""
    try:
        orders = []
        for part in text.split(","):
            lo, _, hi = part.strip().partition("-")
            orders += range(int(lo), int(hi or lo) + 1)
    except ValueError:
        raise argparse.ArgumentTypeError(f"orders must look like 1-5 or 1,3,5, got {text!r}") from None
    if not orders or not all(1 <= k <= 5 for k in orders):
        raise argparse.ArgumentTypeError(f"orders must lie in 1..5, got {text!r}")
    return tuple(dict.fromkeys(orders))


def add_parser(sub) -> None:
    p = sub.add_parser(
        "compare",
        help="compare collinearity+DEM with polynomial rectification on the same GCPs",
        description="Fit collinearity (by resection) and polynomials to the same GCPs; report GCP and "
        "check-point RMSE, redundancy, condition and error maps against collinearity with the DEM.",
        epilog="example:\n  photax compare data/sample_gcps.csv --camera data/sample_camera.yaml "
        "--dem data/sample_dem.tif --image data/sample_image.tif --orders 1-5 -o compare\n",
    )
    p.add_argument(
        "gcps", metavar="GCP_FILE", help="GCP list with pixel positions (CSV with optional role column, or ODM)"
    )
    p.add_argument("--camera", required=True, help="photax camera file, or orthority interior YAML")
    p.add_argument("--camera-name", metavar="NAME", help="camera name in a multi-camera orthority file")
    p.add_argument("--dem", required=True, help="DEM raster in the GCPs' CRS and vertical datum")
    p.add_argument("--image", help="the image: also write the rectified images side by side")
    p.add_argument("--image-name", metavar="NAME", help="which image of a multi-image GCP file")
    p.add_argument("--orders", type=parse_orders, default=(1, 2, 3, 4, 5), help="polynomial orders (default 1-5)")
    p.add_argument("-o", "--out-dir", metavar="DIR", help="folder for the table (md, json) and figures (png)")
    p.add_argument("--out", dest="out_dir", help=argparse.SUPPRESS)  # the old name of --out-dir
    p.add_argument(
        "--resolution",
        type=float,
        metavar="SIZE",
        help="ground pixel size of the rectified images in rectified.png (default: the GSD)",
    )
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.set_defaults(func=run)


def _select_image(table, args):
    names = table.image_names
    if args.image_name is None and len(names) <= 1:
        return table
    stem = pathlib.Path(args.image).name if args.image else None
    name = args.image_name or next((n for n in names if stem and n in (stem, pathlib.Path(stem).stem)), None)
    if name is None:
        raise ValueError(f"{args.gcps}: several images {names}; give --image-name")
    return table.select(name)


def run(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from ..compare import compare_models
    from ..io.atomic import atomic_path, atomic_write, check_output_path
    from ..io.orientation import read_interior
    from ..io.raster import read_dem, read_geotiff
    from ..io.results import write_json
    from ._common import check_crs, input_file, output_folder, read_gcps_3d

    gcp_path = input_file(args.gcps, "GCP file")
    input_file(args.camera, "camera file")
    input_file(args.dem, "DEM")
    if args.image:
        input_file(args.image, "image")
    inputs = [p for p in (args.gcps, args.camera, args.dem, args.image) if p]
    if args.out_dir is not None:
        out = output_folder(args.out_dir, "--out-dir")
        for name in ("comparison.md", "comparison.json", "error_maps.png", "rmse.png", "rectified.png"):
            check_output_path(out / name, inputs)  # fail before the work, not after
    if args.resolution is not None and not args.resolution > 0:
        raise ValueError(f"--resolution must be positive, got {args.resolution}")
    table = _select_image(read_gcps_3d(gcp_path), args)
    camera = read_interior(args.camera, args.camera_name)
    if camera.image_size is None:
        raise ValueError(f"{args.camera}: the camera needs image_size (and a pixel size)")
    pixel = table.pixel if table.pixel is not None else np.asarray(camera.image_to_pixel(table.image_xy))
    dem = read_dem(args.dem)
    check_crs(table.crs, f"the GCPs ({args.gcps})", dem.crs, f"the DEM ({args.dem})")
    check = table.check
    comparison = compare_models(
        table.ground[~check],
        pixel[~check],
        camera,
        dem,
        check_ground=table.ground[check] if check.any() else None,
        check_pixel=pixel[check] if check.any() else None,
        orders=args.orders,
        gcp_names=table.names[~check],
    )
    print(comparison.table("text"))
    if args.out_dir is None:
        return 0
    figures = {"error_maps.png": comparison.plot_error_maps(), "rmse.png": comparison.plot_rmse()}
    if args.image:
        image, _ = read_geotiff(args.image)
        image = image.astype(float)
        image = (image - np.nanmin(image)) / max(float(np.nanmax(image) - np.nanmin(image)), 1e-12)
        shown = image[:3] if image.shape[0] in (3, 4) else image.mean(axis=0)  # RGB in colour, else grey
        names = ["collinearity", *(n for n in comparison.names if n.startswith("polynomial"))]
        grid = None
        if args.resolution is not None:
            from ..grid import ortho_grid

            grid = ortho_grid(comparison.exterior, camera, dem, args.resolution)
        rectified, grid = comparison.rectify(shown, names, grid=grid, progress=args.progress and args.command)
        figures["rectified.png"] = comparison.plot_rectified(rectified, grid)
    # Everything is computed before the first file is written; a failure
    # while writing (a full disk) takes back the files written before it
    # (the command runs all or nothing: photax.io.atomic.all_or_nothing)
    # and the folder made here.
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
        with atomic_write(out / "comparison.md", inputs=inputs) as fh:
            fh.write(comparison.table() + "\n")
        write_json(comparison.to_dict(), out / "comparison.json", inputs=inputs)
        for name, fig in figures.items():
            with atomic_path(out / name, inputs=inputs) as tmp:
                fig.savefig(tmp, format="png", dpi=110)
            plt.close(fig)
    except BaseException:
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    print(f"wrote {', '.join(['comparison.md', 'comparison.json', *figures])} to {out}")
    return 0
