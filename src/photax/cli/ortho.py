"""``photax ortho``: orthorectify an image with its orientation and a DEM (or flat ground, ``--height``).

``--camera`` (alias ``--interior``) is a photax camera file (YAML/JSON,
:mod:`photax.io.camera_file`), an orthority interior YAML or an OpenSfM/ODM
``reconstruction.json`` (``--camera-name`` picks a camera of a multi-camera file); ``--exterior`` a
``photax resect -o`` or ``photax bundle -o`` result (the image named
like IMAGE's stem when it holds several), an orthority exterior CSV (+ .prj beside it) or GeoJSON,
or a ``reconstruction.json``: the formats
are told apart by :mod:`photax.io.orientation`.  The output
GeoTIFF is written tile by tile into a temporary file renamed at the end; it
may not be an input or an input's sidecar.  Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

import argparse
import math

from ._common import RESAMPLING


def add_parser(sub) -> None:
    p = sub.add_parser(
        "ortho",
        help="orthorectify an image with a DEM or on flat ground (collinearity equations)",
        description="Orthorectify IMAGE: every ground pixel gets its height from the DEM (or --height) and "
        "its grey value from the image position given by the collinearity equations. Occlusions are not "
        "detected.",
        epilog="examples:\n  photax ortho data/sample_image.tif --dem data/sample_dem.tif "
        "--camera data/sample_camera.yaml --exterior resect.json -o ortho.tif\n"
        "  photax ortho IMAGE.tif --height 120 --camera cam.yaml --exterior resect.json -o ortho.tif  "
        "# flat ground at Z = 120\n",
    )
    p.add_argument("image", metavar="IMAGE", help="the image (any GDAL raster)")
    ground = p.add_mutually_exclusive_group(required=True)
    ground.add_argument("--dem", help="DEM raster in the ground CRS of the orientation")
    ground.add_argument("--height", type=float, metavar="H",
                        help="flat ground at height H instead of a DEM (a constant-height DEM under "
                        "the image)")
    p.add_argument("--camera", "--interior", dest="camera", required=True, metavar="CAMERA_FILE",
                   help="photax camera file (see photax resect --help), orthority interior YAML or "
                   "OpenSfM/ODM reconstruction.json (--interior is an alias)")  # fmt: skip
    p.add_argument("--exterior", required=True,
                   help="photax resect or bundle -o result (the image named like IMAGE when it holds "
                   "several), "
                   "orthority exterior CSV (x y z omega phi kappa, or latitude longitude altitude roll pitch "
                   "yaw) or GeoJSON, or OpenSfM/ODM reconstruction.json")  # fmt: skip
    p.add_argument("-o", "--out", required=True, metavar="OUT_TIF", help="output GeoTIFF")
    p.add_argument("--resolution", type=float, help="ground pixel size (default: the mean ground sampling distance)")
    p.add_argument("--resampling", choices=RESAMPLING, default="bilinear",
                   help="interpolation of the grey values")
    p.add_argument("--camera-name", metavar="NAME", help="camera name in a multi-camera orthority interior file")
    p.add_argument("--tile", type=int, default=1024, help="output tile size in pixels (memory ~ tile^2)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..io.atomic import check_output_path
    from ..io.orientation import read_exterior, read_interior
    from ..io.raster import read_dem
    from ..grid import ortho_grid
    from ..rectification import orthorectify_file
    from ._common import ground_unit, input_file

    image = input_file(args.image, "image")
    if args.dem is not None:
        input_file(args.dem, "DEM")
    elif not math.isfinite(args.height):
        raise ValueError(f"--height must be a finite number, got {args.height}")
    input_file(args.camera, "camera file")
    input_file(args.exterior, "exterior file")
    inputs = [p for p in (args.image, args.dem, args.camera, args.exterior) if p is not None]
    check_output_path(args.out, inputs)  # fail before the work, not after
    if args.resolution is not None and not args.resolution > 0:
        raise ValueError(f"--resolution must be positive, got {args.resolution}")
    camera = read_interior(args.camera, args.camera_name)
    dem = read_dem(args.dem) if args.dem is not None else None
    # positions given in latitude/longitude or a topocentric frame go into the DEM's CRS
    exterior, crs = read_exterior(args.exterior, args.image, crs=dem.crs if dem is not None else None)
    dem = dem if dem is not None else _flat_dem(args.height, exterior)
    grid = ortho_grid(exterior, camera, dem, args.resolution, crs=crs)
    orthorectify_file(
        image, args.out, exterior, camera, dem, grid, resampling=args.resampling, tile=args.tile,
        progress=args.progress and args.command,  # one bar, labelled "ortho"
    )
    print(f"wrote {args.out}: {grid.width} x {grid.height} pixels of {abs(grid.transform.a):g} "
          f"{ground_unit(grid.crs)}")
    return 0


def _flat_dem(height: float, exterior):
    """``--height``: a constant-height DEM under the camera, valid within 1000 flying heights
    of its nadir (a ray reaching the ground farther out is within 0.06 degrees of the horizon);
    ortho_grid cuts the grid down to the image's footprint."""
    import numpy as np

    from ..dem import DEM

    x, y, z = np.asarray(exterior.position, dtype=float)
    r = 1e3 * max(abs(z - height), 1.0)
    return DEM.flat(height, (x - r, y - r, x + r, y + r))
