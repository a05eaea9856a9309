"""``photax measure``: measure points in an image (photax.measure).

Three modes, one output format:

* ``--interest METHOD``: interest points (Förstner, Harris or Moravec), the
  ``--count`` strongest, each refined by Förstner's sub-pixel locator
  (:func:`photax.measure.locate_corners`), which gives its sigma;
* ``--targets POINTS --radius R``: centres of circular targets (discs, or
  quartered black-and-white discs: ``--method``, chosen from the image by
  default) near the approximate positions in POINTS
  (:func:`photax.measure.locate_targets`);
* ``--corners POINTS``: corners near the approximate positions
  (:func:`photax.measure.locate_corners`).

POINTS is a GCP file as :func:`photax.io.read_gcps` reads it (pixel columns;
``--image`` picks one image when it has several) or a plain CSV with the
columns ``name,col,row``.  The output CSV has one row per point:
``name,approx_col,approx_row,col,row,sigma_col,sigma_row,status`` (and
``strength`` for interest points); failed points keep their row with empty
``col .. sigma_row`` and the reason in ``status``.  ``--gcp-out`` writes the
measured points of a GCP input as a GCP file (measured pixels, sigma
``sqrt((s_col^2 + s_row^2) / 2)`` px) that ``photax resect`` reads.

Exit codes: 0 every point measured, 1 some failed, 2 bad input.
"""

from __future__ import annotations

import argparse
import csv
import math

_METHODS = ("auto", "quartered", "ellipse", "wong-trinder", "centroid")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "measure",
        help="measure interest points, target centres or corners in an image (sub-pixel, with sigma)",
        description="Measure points in an image: interest points, or the sub-pixel centres of circular targets "
        "or corners near approximate positions. Writes a CSV with sigma per coordinate and a status per point.",
        epilog="examples:\n  photax measure data/sample_image.tif --targets data/sample_gcps.csv --radius 6 "
        "-o measured.csv --gcp-out gcps.csv\n"
        "  photax measure image.tif --interest foerstner --count 200 -o points.csv\n",
    )
    p.add_argument("image", metavar="IMAGE", help="image file (GeoTIFF, PNG, ... read with rasterio)")
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument(
        "--interest",
        choices=("foerstner", "harris", "moravec"),
        metavar="METHOD",
        help="interest points by METHOD: foerstner, harris or moravec",
    )
    mode.add_argument(
        "--targets",
        metavar="POINTS",
        help="centres of circular targets near these approximate positions (GCP CSV or name,col,row CSV)",
    )
    mode.add_argument("--corners", metavar="POINTS", help="corners near these approximate positions")
    p.add_argument("-o", "--out", required=True, metavar="OUT_CSV", help="the measured points (CSV)")
    p.add_argument("--gcp-out", metavar="GCP_CSV", help="with a GCP input: the measured points as a GCP file")
    p.add_argument("--image-name", metavar="NAME", help="with a GCP input holding several images: this image's points")
    p.add_argument(
        "--band",
        type=int,
        metavar="N",
        help="band to measure (1-based); default the mean of the first three bands (or the only one)",
    )
    p.add_argument("--count", type=int, default=500, help="interest points: at most this many, strongest first")
    p.add_argument("--min-distance", type=int, default=5, help="interest points: px between two points")
    p.add_argument("--radius", type=float, help="targets: image radius of a target in px (required)")
    p.add_argument(
        "--method",
        choices=_METHODS,
        default="auto",
        help="targets: centring method: quartered (black-and-white sectors: Förstner's crossing "
        "point), ellipse, wong-trinder or centroid (discs); auto (default) picks quartered or "
        "ellipse from the grey values around the approximate positions",
    )
    p.add_argument("--polarity", choices=("bright", "dark"), default="bright", help="targets: bright or dark")
    p.add_argument("--window", type=int, help="half-size of the measuring window in px (default per locator)")
    p.set_defaults(func=run)


def _write_csv(out, names, approx, res, strength, inputs) -> None:
    import numpy as np

    from ..io.atomic import atomic_write
    from ..measure import Status

    xy, sig, status = np.asarray(res.xy), np.asarray(res.sigma), np.asarray(res.status)
    fmt = lambda v: "" if not math.isfinite(v) else f"{v:.4f}"  # noqa: E731  (0.1 mpx: below any sigma)
    fsig = lambda v: "" if not math.isfinite(v) else f"{v:.4g}"  # noqa: E731
    header = ["name", "approx_col", "approx_row", "col", "row", "sigma_col", "sigma_row", "status"]
    with atomic_write(out, inputs=inputs, newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header + (["strength"] if strength is not None else []))
        for i, name in enumerate(names):
            row = [
                name,
                fmt(approx[i, 0]),
                fmt(approx[i, 1]),
                fmt(xy[i, 0]),
                fmt(xy[i, 1]),
                fsig(sig[i, 0]),
                fsig(sig[i, 1]),
                Status(int(status[i])).name.lower(),
            ]
            w.writerow(row + ([f"{strength[i]:.6g}"] if strength is not None else []))


def run(args: argparse.Namespace) -> int:
    import dataclasses

    import numpy as np

    from .. import measure
    from ..io.atomic import check_output_path
    from ..io.gcp import write_gcps
    from ..io.points import read_pixel_points
    from ..io.raster import read_grey

    points = args.targets or args.corners
    inputs = [p for p in (args.image, points) if p]
    for out in (args.out, args.gcp_out):
        if out:
            check_output_path(out, inputs)
    if args.gcp_out and not points:
        raise ValueError("--gcp-out needs a GCP input (--targets or --corners)")
    if args.targets and args.radius is None:
        raise ValueError("--targets needs --radius (the target's image radius in px)")
    if args.count < 1:
        raise ValueError(f"--count must be >= 1, got {args.count}")
    image = read_grey(args.image, args.band)
    strength, table = None, None
    if args.interest:
        found = measure.interest_points(image, args.interest, min_distance=args.min_distance, max_points=args.count)
        approx = np.asarray(found.xy, dtype=float).reshape(-1, 2)
        names = np.asarray([f"p{i + 1}" for i in range(len(approx))])
        strength = np.asarray(found.strength)
    else:
        names, approx, table = read_pixel_points(points, args.image_name)
    kw = {} if args.window is None else {"window": args.window}
    if len(approx) == 0:
        res = None
    elif args.targets:
        method = args.method
        if method == "auto":
            kind = measure.target_kind(image, approx, args.radius)
            method = "quartered" if kind == "quartered" else "ellipse"
            print(f"targets look {'quartered' if method == 'quartered' else 'like discs'}: --method {method}")
        res = measure.locate_targets(image, approx, args.radius, method=method, polarity=args.polarity, **kw)
    else:
        res = measure.locate_corners(image, approx, **kw)
    if res is None:
        print(f"no interest points found in {args.image}")
        empty = measure.LocateResult(
            np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros(0, np.int32), np.zeros(0), np.zeros(0, np.int32)
        )
        _write_csv(args.out, names, approx, empty, strength, inputs)
        return 0
    _write_csv(args.out, names, approx, res, strength, inputs)
    valid = np.asarray(res.valid)
    print(f"{len(names)} points: {res.summary()}; wrote {args.out}")
    for name, msg in zip(names[~valid], np.asarray(res.messages())[~valid]):
        print(f"  {name}: {msg}")
    if args.gcp_out:
        if table is None:
            raise ValueError("--gcp-out needs a GCP file as input (with ground coordinates), not a name,col,row list")
        sig = np.asarray(res.sigma)
        sub = table.subset(valid)
        sub = dataclasses.replace(sub, pixel=np.asarray(res.xy)[valid], sigma=np.sqrt(np.mean(sig[valid] ** 2, axis=1)))
        write_gcps(args.gcp_out, sub, inputs=inputs)
        print(f"wrote {int(valid.sum())} measured GCPs to {args.gcp_out}")
    return 0 if valid.all() else 1
