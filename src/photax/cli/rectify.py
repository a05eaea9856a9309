"""``photax rectify``: plane-to-plane rectification of an image from GCPs.

A polynomial of order N (map -> pixel, docs/maths.md), a thin-plate spline
(``--model tps``) or a piecewise-affine map (``--model piecewise-affine``) is
fitted to the GCPs' ground (X, Y) and pixel positions, and the image is resampled onto a north-up
grid covering the GCPs' footprint (indirect mapping, tile by tile, written
atomically).  Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

import argparse

from ._common import NODATA_HELP, RESAMPLING, add_grid_options, grid_spec, nodata_value

MODELS = ("polynomial", "tps", "piecewise-affine")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "rectify",
        help="polynomial, thin-plate-spline or piecewise-affine rectification of an image from GCPs",
        description="Fit a map -> pixel model to the GCPs and resample IMAGE onto a map grid covering them.",
        epilog="examples:\n  photax rectify data/sample_image.tif --gcps data/sample_gcps.csv --order 3 -o rect.tif\n"
        "  photax rectify data/sample_image.tif --gcps data/sample_gcps.csv --model tps -o rect_tps.tif\n",
    )
    p.add_argument("image", metavar="IMAGE", help="the image (any GDAL raster)")
    p.add_argument(
        "--gcps",
        required=True,
        metavar="GCP_FILE",
        help="GCP list with pixel positions (CSV, ODM, QGIS .points or GeoJSON)",
    )
    p.add_argument(
        "--model",
        choices=MODELS,
        default="polynomial",
        help="polynomial (of --order; default); tps: thin-plate spline through the GCPs (GDAL's -tps); "
        "piecewise-affine: one affine per Delaunay triangle of the GCPs, no-data outside their convex hull",
    )
    p.add_argument("--order", type=int, default=None, help="polynomial order 1-5 (default 1); --model polynomial only")
    p.add_argument("-o", "--out", required=True, metavar="OUT_TIF", help="output GeoTIFF")
    add_grid_options(
        p,
        resolution_help="map pixel size (gdalwarp -tr; default: the mean GCP scale)",
        crs_help="projected CRS of the output, the GCPs reprojected to it (default: the GCPs' own; "
        "longitude/latitude GCPs go to the UTM zone of the points)",
    )
    p.add_argument(
        "--resampling",
        choices=RESAMPLING,
        default=None,
        help="resampling kernel (default: bilinear; nearest for a palette image, which takes no other)",
    )
    p.add_argument("--image-name", metavar="NAME", help="which image of a multi-image GCP file")
    p.add_argument("--nodata", type=nodata_value, metavar="VALUE", help=NODATA_HELP)
    p.add_argument("--tile", type=int, default=1024, help="output tile size in pixels (memory ~ tile^2)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import pathlib

    import numpy as np

    from ..grid import check_resolution
    from ..io.atomic import check_output_path
    from ..io.gcp import read_gcps
    from ..polynomial import fit_piecewise_affine, fit_polynomial, fit_tps
    from ..rectification import rectify_file
    from ._common import ground_unit, input_file, plural

    if args.order is not None and args.model != "polynomial":
        raise ValueError(f"--order is for --model polynomial, not --model {args.model}")
    order = 1 if args.order is None else args.order
    image = input_file(args.image, "image")
    gcp_path = input_file(args.gcps, "GCP file")
    spec = grid_spec(args)
    check_output_path(args.out, [image, gcp_path])  # fail before the work, not after
    table = read_gcps(gcp_path, crs=spec.like.crs if spec.like is not None else args.crs)
    names = table.image_names
    if args.image_name is not None or len(names) > 1:
        stem = pathlib.Path(args.image).name
        name = args.image_name or next((n for n in names if n in (stem, pathlib.Path(stem).stem)), None)
        if name is None:
            raise ValueError(f"{args.gcps}: several images {names}; give --image-name")
        table = table.select(name)
    if table.pixel is None:
        raise ValueError(f"{args.gcps}: rectify needs pixel positions (col, row), not image-plane x, y")
    control = ~table.check
    ground, pixel = table.ground[control, :2], table.pixel[control]
    if args.model == "polynomial":
        model, what = fit_polynomial(ground, pixel, order), f"order {order}"
    elif args.model == "tps":
        model, what = fit_tps(ground, pixel), "thin-plate spline"
    else:
        model, what = fit_piecewise_affine(ground, pixel), "piecewise affine"
    # the interpolating models fit the GCPs exactly: their leave-one-out residuals are the honest figure
    v2 = np.sum(np.asarray(model.loo_residuals) ** 2, axis=1)
    loo = float(np.sqrt(np.nanmean(v2))) if np.isfinite(v2).any() else float("nan")
    # Map units per pixel from the GCP spread (square root of the area ratio): the image's sampling distance.
    span = np.ptp(ground, axis=0).prod() / max(np.ptp(pixel, axis=0).prod(), 1e-12)
    gsd = float(np.sqrt(span))
    bounds = (*ground.min(axis=0), *ground.max(axis=0))
    if args.resolution is not None and spec.bounds is None:
        check_resolution(args.resolution, gsd, bounds, "the GCPs' footprint")
    grid = spec.grid(bounds, gsd, table.crs)
    resolution = abs(grid.transform.a)
    rectify_file(
        image,
        args.out,
        model,
        grid,
        resampling=args.resampling,
        nodata=args.nodata,
        tile=args.tile,
        progress=args.progress and args.command,
        inputs=[args.gcps],
    )
    print(
        f"wrote {args.out}: {grid.width} x {grid.height} pixels of {resolution:g} {ground_unit(table.crs, 'map units')}, "
        f"{what}, {plural(len(ground), 'GCP')}, rmse {float(model.rmse):.3g} px, leave-one-out rmse {loo:.3g} px"
    )
    return 0
