"""``photax ties``: tie points between overlapping images (:func:`photax.match_ties`) as a bundle block.

IMAGES of one camera with approximate orientations (``--exterior``) and a DEM;
optionally GCP measurements (``--gcps``, e.g. from ``photax transfer``) joined
as control and check points.  Writes the bundle problem as a block folder
(:func:`photax.io.write_block`: the GCPs keep their control/check roles, the
camera its file, a scanned camera its film transformation) or, when OUT ends
in ``.txt``, ``.txt.bz2`` or ``.bal``, as a BAL file (one camera per image,
no roles: GCPs become points with their surveyed start values and the block
has no datum), and prints the matches per image pair.  ``photax bundle``
reads both.
Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

import argparse


def add_parser(sub) -> None:
    from ._common import add_oriented_images

    p = sub.add_parser(
        "ties",
        help="match tie points between overlapping images into a bundle block",
        description="Interest points matched between overlapping images, guided by approximate "
        "orientations and a DEM (NCC, least-squares matching, two-way check).",
        epilog="example:\n  photax ties img*.tif --camera cam.yaml --exterior approx.json "
        "--dem dem.tif --gcps measured.csv -o block\n",
    )
    add_oriented_images(p)
    p.add_argument("--gcps", help="GCP measurements in pixels to join (CSV or ODM list)")
    p.add_argument("--points", type=int, default=150, help="interest points per image (default 150)")
    p.add_argument("--min-rho", type=float, default=0.7,
                   help="smallest accepted correlation peak (default 0.7; 0.6 suits strips flown years or "
                   "hours apart and oblique views, whose windows correlate less)")  # fmt: skip
    p.add_argument("-o", "--out", required=True,
                   help="output block folder (new or empty; GCPs stay control/check points), or a BAL file when "
                   "OUT ends in .txt, .txt.bz2 or .bal")  # fmt: skip
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import pathlib

    import numpy as np  # here, not at import: photax --help loads no numpy

    from ..io import read_camera_unit, write_bal, write_block
    from ..io.atomic import check_output_path
    from ..io.block import check_block_output
    from ..io.orientation import camera_in_pixels
    from ..io.raster import read_dem
    from ..matching import bundle_problem, match_ties
    from ._common import read_gcps_3d, read_oriented_images

    files, camera, names, images, exterior = read_oriented_images(args, [args.gcps])
    bal = args.out.lower().endswith((".txt", ".txt.bz2", ".bal"))
    out = pathlib.Path(args.out)
    if not bal:  # before the matching, not after
        check_block_output(out, files)
        unit = read_camera_unit(args.camera)
        if unit is None:  # an orthority interior file: its unit is unnamed, the block's camera goes in pixels
            try:
                camera, unit = camera_in_pixels(camera), "px"
            except ValueError as exc:
                raise ValueError(f"{args.camera}: {exc}") from None
    else:
        check_output_path(out, files)
    if not 0.0 < args.min_rho < 1.0:
        raise ValueError(f"--min-rho: must lie between 0 and 1, got {args.min_rho}")
    dem = read_dem(args.dem)
    ties = match_ties(images, camera, exterior, dem, max_points=args.points, search=args.search, min_rho=args.min_rho)
    for k, s in enumerate(ties.image_status):
        if s != "ok":
            print(f"{names[k]}: {s}")
    for (i, j), s in ties.pair_status.items():
        if s != "no overlap":  # the predicted overlap says whether too few matches is the data or the start values
            print(
                f"{names[i]} - {names[j]}: {ties.pair_ties[i, j]} ties, predicted overlap "
                f"{100 * ties.pair_overlap[i, j]:.0f} %, {s}"
            )
    gcps = None
    if args.gcps:
        gcps = read_gcps_3d(args.gcps)
        gcps = gcps.subset(np.array([pathlib.Path(str(s)).stem in names for s in gcps.images], dtype=bool))
        gcps = dataclasses.replace(gcps, images=np.array([pathlib.Path(str(s)).stem for s in gcps.images], dtype=str))
    # the ground CRS is the DEM's (read_oriented_images checked the orientations against it): block.json keeps it,
    # so that `photax bundle --dem` refuses a DEM in another CRS
    problem = bundle_problem(camera, exterior, ties, gcps, image_names=names).replace(crs=dem.crs)
    if bal:
        # BAL stores one camera per image and no point roles: GCPs go in as (surveyed) points only
        problem = problem.replace(cameras=(camera,) * len(names), image_camera=np.arange(len(names)))
        write_bal(problem, args.out, inputs=files)
    else:
        write_block(problem, out, units=unit, inputs=files)
    print(f"wrote {args.out}: {ties.n_tracks} tie tracks, {problem.n_observations} observations")
    return 0
