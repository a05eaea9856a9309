"""``photax ties``: tie points between overlapping images (:func:`photax.match_ties`) as a BAL block.

IMAGES of one camera with approximate orientations (``--exterior``) and a DEM;
optionally GCP measurements (``--gcps``, e.g. from ``photax transfer``) joined
as control and check points.  Writes the bundle problem as a BAL file
(``photax bundle`` reads it; BAL keeps no control/check roles, so GCPs
are written as points with their surveyed start values) and prints the
matches per image pair.
Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

import argparse


def add_parser(sub) -> None:
    from ._common import add_oriented_images

    p = sub.add_parser("ties", help="match tie points between overlapping images into a bundle block (BAL)",
                       description="Interest points matched between overlapping images, guided by approximate "
                       "orientations and a DEM (NCC, least-squares matching, two-way check).")
    add_oriented_images(p)
    p.add_argument("--gcps", help="GCP measurements in pixels to join (CSV or ODM list)")
    p.add_argument("--points", type=int, default=150, help="interest points per image (default 150)")
    p.add_argument("-o", "--out", required=True, help="output BAL file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import pathlib

    import numpy as np  # here, not at import: photax --help loads no numpy

    from ..io import read_gcps, write_bal
    from ..io.raster import read_dem
    from ..ties import bundle_problem, match_ties
    from ._common import read_oriented_images

    files, camera, names, images, exterior = read_oriented_images(args, [args.gcps])
    ties = match_ties(images, camera, exterior, read_dem(args.dem), max_points=args.points, search=args.search)
    for k, s in enumerate(ties.image_status):
        if s != "ok":
            print(f"{names[k]}: {s}")
    for (i, j), s in ties.pair_status.items():
        if s != "no overlap":
            print(f"{names[i]} - {names[j]}: {ties.pair_counts.get((i, j), 0)} matches, {s}")
    gcps = None
    if args.gcps:
        gcps = read_gcps(args.gcps)
        gcps = gcps.subset(np.array([pathlib.Path(str(s)).stem in names for s in gcps.images], dtype=bool))
        gcps = dataclasses.replace(gcps, images=np.array([pathlib.Path(str(s)).stem for s in gcps.images], dtype=str))
    problem = bundle_problem(camera, exterior, ties, gcps, image_names=names)
    # BAL stores one camera per image and no point roles: GCPs go in as (surveyed) points only
    problem = problem.replace(cameras=(camera,) * len(names), image_camera=np.arange(len(names)))
    write_bal(problem, args.out, inputs=files)
    print(f"wrote {args.out}: {ties.n_tracks} tie tracks, {problem.n_observations} observations")
    return 0
