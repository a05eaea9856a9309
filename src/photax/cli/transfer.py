"""``photax transfer``: measure GCPs in every image that sees them (:func:`photax.transfer_points`).

IMAGES of one camera (``--camera``) with approximate orientations
(``--exterior``: a ``photax resect -o`` file holding them, or an orthority
exterior CSV), a DEM and a GCP file (``--gcps``, CSV or ODM list).  GCPs
measured in one of the IMAGES (the file's image column names it) are
transferred from there; the others, known only on the ground, are found with
``--template`` (a raster of the target, centred on it).  Writes the GCP list
(``--format csv`` or ``odm``) and prints one status line per point and image.
Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

import argparse


def add_parser(sub) -> None:
    from ._common import add_oriented_images

    p = sub.add_parser(
        "transfer",
        help="transfer GCPs into every image that sees them (NCC + least-squares matching)",
        description="Predict ground control points in every image with approximate orientations "
        "and the DEM, and measure them there by image matching.",
        epilog="example:\n  photax transfer img*.tif --camera cam.yaml --exterior approx.json "
        "--dem dem.tif --gcps gcps.csv --template target.tif -o measured.csv\n",
    )
    add_oriented_images(p)
    p.add_argument("--gcps", required=True, help="GCP file (CSV or ODM gcp_list.txt)")
    p.add_argument("--template", help="raster of the survey target, for points measured in no image")
    p.add_argument(
        "--format",
        choices=("csv", "odm"),
        default="csv",
        help="format of the output GCP list: photax CSV or OpenDroneMap gcp_list.txt",
    )
    p.add_argument("-o", "--out", required=True, help="output GCP list")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import pathlib

    import numpy as np  # here, not at import: photax --help loads no numpy

    from ..io.raster import read_dem, read_geotiff
    from ..matching import transfer_points
    from ._common import read_gcps_3d, read_oriented_images

    files, camera, names, images, exterior = read_oriented_images(args, [args.gcps, args.template])
    dem = read_dem(args.dem)
    table = read_gcps_3d(args.gcps)
    if table.pixel is None:
        raise ValueError(f"{args.gcps}: give pixel (col, row) measurements")
    points = list(dict.fromkeys(table.names.tolist()))
    ground = np.array([table.ground[table.names == n][0] for n in points])
    roles = [str(table.role[table.names == n][0]) for n in points]
    ref_i, ref_xy = np.full(len(points), -1), np.full((len(points), 2), np.nan)
    stems = {pathlib.Path(s).stem: k for k, s in enumerate(args.images)}
    for r in range(len(table)):
        k = stems.get(pathlib.Path(str(table.images[r])).stem)
        p = points.index(str(table.names[r]))
        if k is not None and ref_i[p] < 0:
            ref_i[p], ref_xy[p] = k, table.pixel[r]
    template = read_geotiff(args.template)[0][0].astype(float) if args.template else None
    res = transfer_points(
        images,
        camera,
        exterior,
        dem,
        ground,
        names=points,
        image_names=names,
        reference_image=ref_i,
        reference_xy=ref_xy,
        target_template=template,
        roles=roles,
        search=args.search,
        crs=table.crs or dem.crs,
    )
    for it in res.items:
        if it["status"] != "not in image":
            print(f"{it['name']:>10} {it['image']:>12}  {it['status']}")
    if len(res.table) == 0:
        raise ValueError("no GCP could be measured in any image (see the statuses above)")
    res.write(args.out, format=args.format)
    print(f"wrote {args.out}: {len(res.table)} measurements of {len(set(res.table.names.tolist()))} points")
    return 0
