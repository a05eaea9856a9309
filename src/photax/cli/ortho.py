"""``photax ortho``: orthorectify an image with its orientation and a DEM.

``--camera`` (alias ``--interior``) is a photax camera file (YAML/JSON,
:mod:`photax.io.camera_file`) or an orthority interior YAML
(``--camera-name`` picks a camera of a multi-camera file); ``--exterior`` a
``photax resect --json`` or ``photax bundle --json`` result (the image named
like IMAGE's stem when it holds several) or an orthority exterior CSV (+ .prj beside it): the formats
are told apart by :mod:`photax.io.orientation`.  The output
GeoTIFF is written tile by tile into a temporary file renamed at the end; it
may not be an input or an input's sidecar.  Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

import argparse

from ._common import RESAMPLING


def add_parser(sub) -> None:
    p = sub.add_parser(
        "ortho",
        help="orthorectify an image with a DEM (collinearity equations)",
        description="Orthorectify IMAGE: every ground pixel gets its height from the DEM and its grey value "
        "from the image position given by the collinearity equations. Occlusions are not detected.",
    )
    p.add_argument("image", metavar="IMAGE", help="the image (any GDAL raster)")
    p.add_argument("--dem", required=True, help="DEM raster in the ground CRS of the orientation")
    p.add_argument("--camera", "--interior", dest="camera", required=True, metavar="CAMERA_FILE",
                   help="photax camera file (see photax resect --help), or orthority interior YAML "
                   "(--interior is an alias)")  # fmt: skip
    p.add_argument("--exterior", required=True,
                   help="photax resect or bundle --json result (the image named like IMAGE when it holds several), "
                   "or orthority exterior CSV")  # fmt: skip
    p.add_argument("--out", required=True, help="output GeoTIFF")
    p.add_argument("--resolution", type=float, help="ground pixel size (default: the mean ground sampling distance)")
    p.add_argument("--resampling", choices=RESAMPLING, default="bilinear")
    p.add_argument("--camera-name", metavar="NAME", help="camera name in a multi-camera orthority interior file")
    p.add_argument("--tile", type=int, default=1024, help="output tile size in pixels (memory ~ tile^2)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..io.atomic import check_output_path
    from ..io.orientation import read_exterior, read_interior
    from ..io.raster import read_dem
    from ..rectification import ortho_grid, orthorectify_file
    from ._common import check_crs, ground_unit, input_file

    image = input_file(args.image, "image")
    input_file(args.dem, "DEM")
    input_file(args.camera, "camera file")
    input_file(args.exterior, "exterior file")
    inputs = [args.image, args.dem, args.camera, args.exterior]
    check_output_path(args.out, inputs)  # fail before the work, not after
    if args.resolution is not None and not args.resolution > 0:
        raise ValueError(f"--resolution must be positive, got {args.resolution}")
    camera = read_interior(args.camera, args.camera_name)
    exterior, crs = read_exterior(args.exterior, args.image)
    dem = read_dem(args.dem)
    check_crs(crs, f"the orientation ({args.exterior})", dem, f"the DEM ({args.dem})")
    grid = ortho_grid(exterior, camera, dem, args.resolution)
    if crs is not None:
        import dataclasses

        grid = dataclasses.replace(grid, crs=crs)
    orthorectify_file(
        image, args.out, exterior, camera, dem, grid, resampling=args.resampling, tile=args.tile,
        progress=args.progress and args.command,  # one bar, labelled "ortho"
    )
    print(f"wrote {args.out}: {grid.width} x {grid.height} pixels of {abs(grid.transform.a):g} "
          f"{ground_unit(grid.crs)}")
    return 0
