"""``photax fiducials``: interior orientation of a scanned photograph from its fiducial marks.

FIDUCIALS is a CSV ``name,x,y`` of the calibrated mark positions (film mm, x
right, y up, from the camera's calibration report).  The marks are found by
template matching near approximate positions (``--approx`` CSV
``name,col,row``, or the scan's centre and ``--pixel-size`` mm per pixel),
checked against the calibrated pattern, and the film -> pixel transformation
(``--model``) is fitted (:func:`photax.interior.find_fiducials`).

Outputs: ``--out`` JSON (model, parameters, sigma0, rmse, covariance, and per
mark its measured pixel, residual, statistic and status), optionally
``--csv`` (``name,x,y,col,row,residual_col,residual_row,status``) and
``--camera-out``: the calibrated camera (``--camera``: focal length,
principal point, distortion in mm) with the fitted transformation as a
``scan`` block (:mod:`photax.io.camera_file`), which ``photax resect``,
``ortho``, ``register``, ``transfer`` and ``ties`` read as a
:class:`photax.interior.ScannedCamera` (the scan's pixels go through it).

Exit codes: 0 every mark found and consistent, 1 some mark flagged (not used),
2 bad input (or too few marks for the model).
"""

from __future__ import annotations

import argparse
import csv


def add_parser(sub) -> None:
    p = sub.add_parser(
        "fiducials",
        help="measure the fiducial marks of a scan and fit its interior orientation (film -> pixel)",
        description="Find the fiducial marks of a scanned photograph by template matching, check them against "
        "the calibrated pattern (blunder test), and fit the film -> pixel transformation.",
        epilog="example:\n  photax fiducials scan.tif --fiducials marks.csv --pixel-size 0.5 "
        "--camera calibrated.yaml --camera-out scan_camera.yaml -o interior.json\n",
    )
    p.add_argument("scan", metavar="SCAN", help="the scanned image (any GDAL raster; first band or mean of RGB)")
    p.add_argument("--fiducials", required=True, metavar="CSV", help="calibrated marks: name,x,y in mm (y up)")
    p.add_argument("--pixel-size", type=float, metavar="MM", help="scan resolution in mm per pixel (without --approx)")
    p.add_argument("--approx", metavar="CSV", help="approximate mark positions: name,col,row")
    p.add_argument(
        "--model",
        choices=("similarity", "affine", "bilinear", "projective"),
        default="affine",
        help="film -> pixel transformation (similarity: 4 parameters, affine 6, bilinear 8, projective 8)",
    )
    p.add_argument("--mark", choices=("cross", "dot", "ring"), default="cross", help="the marks' shape")
    p.add_argument(
        "--mark-size",
        type=float,
        default=1.0,
        metavar="MM",
        help="half-length of a cross's bars, or a dot's / ring's radius, mm",
    )
    p.add_argument("--line-width", type=float, default=0.2, metavar="MM", help="bar or ring line width, mm")
    p.add_argument("--dark", action="store_true", help="the marks are darker than their surroundings")
    p.add_argument("--search", type=int, default=15, metavar="PX", help="search radius around the approximations")
    p.add_argument("--sigma", type=float, default=0.1, metavar="PX", help="a-priori precision of a mark, px")
    p.add_argument("-o", "--out", required=True, metavar="JSON", help="the interior orientation (JSON)")
    p.add_argument("--csv", metavar="CSV", help="the marks, one row each")
    p.add_argument(
        "--camera",
        metavar="CAMERA_FILE",
        help="the calibrated camera (photax camera file in mm: focal_length, principal_point, "
        "distortion), for --camera-out",
    )
    p.add_argument(
        "--camera-out",
        metavar="YAML",
        help="write the scanned camera: --camera with the fitted film -> pixel transformation "
        "(a 'scan' block; photax resect / ortho / register read it)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np  # here, not at import: photax --help loads no numpy

    from ..interior import find_fiducials
    from ..io.atomic import atomic_write, check_output_path
    from ..io.points import read_named_points
    from ..io.raster import read_grey
    from ..io.results import write_json
    from ._common import input_file

    input_file(args.scan, "scan")
    input_file(args.fiducials, "fiducial file")
    inputs = [args.scan, args.fiducials] + ([args.approx] if args.approx else [])
    if bool(args.camera) != bool(args.camera_out):
        raise ValueError("--camera and --camera-out go together (the calibrated camera and the scanned one to write)")
    if args.camera:
        input_file(args.camera, "camera file")
        inputs.append(args.camera)
    for out in (args.out, args.csv, args.camera_out):
        if out:
            check_output_path(out, inputs)
    outs = [o for o in (args.out, args.csv, args.camera_out) if o]
    if len(set(map(str, outs))) != len(outs):
        raise ValueError("-o, --csv and --camera-out must be different files")
    base_camera = unit = None
    if args.camera:
        from ..io.camera_file import read_camera
        from ..io.orientation import read_camera_unit

        base_camera, unit = read_camera(args.camera), read_camera_unit(args.camera)
        if unit not in ("mm", "m"):
            raise ValueError(
                f"{args.camera}: the calibrated camera must be in film units (unit: mm or m), "
                f"got {unit!r}: the fiducials are in them"
            )
    names, fid = read_named_points(args.fiducials, ("x", "y"), "fiducial file")
    approx = None
    if args.approx:
        input_file(args.approx, "approximate positions")
        anames, axy = read_named_points(args.approx, ("col", "row"), "approximate positions")
        missing = sorted(set(names) - set(anames))
        if missing:
            raise ValueError(f"{args.approx}: no approximate position for the marks {', '.join(missing)}")
        approx = axy[[anames.index(n) for n in names]]
    elif args.pixel_size is None:
        raise ValueError("give --pixel-size (the scan resolution, mm per pixel) or --approx")
    scan = read_grey(args.scan)
    res = find_fiducials(
        scan,
        fid,
        pixel_size=args.pixel_size,
        approx_xy=approx,
        mark=args.mark,
        mark_size=args.mark_size,
        line_width=args.line_width,
        bright=not args.dark,
        search=args.search,
        model=args.model,
        sigma=args.sigma,
    )
    io = res.orientation
    marks = [
        {
            "name": n,
            "x": float(f[0]),
            "y": float(f[1]),
            "col": float(p[0]),
            "row": float(p[1]),
            "residual_col": float(v[0]),
            "residual_row": float(v[1]),
            "statistic": float(s),
            "used": not bool(fl),
            "status": m,
        }
        for n, f, p, v, s, fl, m in zip(names, fid, res.xy, io.residuals, io.statistic, res.flagged, res.messages)
    ]
    t = io.transform
    write_json(
        {
            "model": io.model,
            "params": np.asarray(t.params),
            "film_centre_mm": np.asarray(t.film_centre),
            "film_scale_mm": float(t.film_scale),
            "sigma0": io.sigma0,
            "rmse_px": io.rmse,
            "covariance": io.covariance,
            "redundancy": io.redundancy,
            "critical": io.critical,
            "pixel_size_mm": t.scale(),
            "image_size": [scan.shape[1], scan.shape[0]],
            "message": io.message,
            "marks": marks,
        },
        args.out,
        inputs=inputs,
    )
    if args.csv:
        with atomic_write(args.csv, "w", inputs=inputs, newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["name", "x", "y", "col", "row", "residual_col", "residual_row", "status"])
            for m in marks:
                nums = [
                    f"{m[k]:.4f}" if np.isfinite(m[k]) else "" for k in ("col", "row", "residual_col", "residual_row")
                ]
                w.writerow([m["name"], m["x"], m["y"], *nums, m["status"]])
    if args.camera_out:
        from ..io.camera_file import write_camera

        c = base_camera
        scanned = io.camera(c.focal_length, c.principal_point, c.distortion, image_size=(scan.shape[1], scan.shape[0]))
        write_camera(scanned, args.camera_out, unit=unit, inputs=inputs)
    n_bad = int(res.flagged.sum())
    print(f"{io.message}; rmse {io.rmse:.3f} px; wrote " + ", ".join(map(str, outs)))
    for m in marks:
        if not m["used"]:
            print(f"  {m['name']}: {m['status']}")
    return 1 if n_bad else 0
