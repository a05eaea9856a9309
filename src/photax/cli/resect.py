"""``photax resect``: space resection of every image in a GCP file.

Exit codes: 0 every requested image solved; 1 some were not (too few
points, not converged; ``--out`` is still written with a ``status`` per
image); 2 bad input (a one-line message on stderr, nothing written).
"""

from __future__ import annotations

import argparse

from ._common import CONVENTIONS

# Shown by ``photax resect --help`` and in the README (a test parses both with read_camera).
CAMERA_FILE_HELP = """\
camera file (YAML or JSON; photax.io.camera_file), in mm:

    # camera.yaml - lengths in mm; x right, y up, from the image centre
    focal_length: 8.8              # principal distance f
    unit: mm                       # unit of focal_length, principal_point, pixel_size: mm, m or px
    principal_point: [0.011, -0.0066]
    pixel_size: 0.0176             # one value, or [along columns, along rows]
    image_size: [1000, 750]        # width, height in pixels
    distortion: {k1: -0.02, k2: 0.004, k3: 0.0, p1: 0.0, p2: 0.0}

or in pixels (integer pixel = pixel centre, column right, row down):

    # camera.yaml - pixel units
    focal_length_px: 2904.0
    image_size: [4000, 3000]
    principal_point_px: [1999.5, 1499.5]   # optional, default the image centre
    distortion: {k1: -0.05}                # optional; k1 k2 k3 p1 p2, missing ones are 0

a scanned film frame adds the fitted film -> scan pixel transformation of its
fiducial marks (written by photax fiducials --camera-out; pixels go through it):

    focal_length: 152.9            # mm, from the calibration report
    unit: mm
    principal_point: [0.0, 0.0]
    image_size: [2400, 2400]       # the scan's width, height; no pixel_size
    scan: {model: affine, film_centre: [0.3, -0.1], film_scale: 149.8,
           params: [1199.6, 1563.2, 1.1, 1200.2, -0.9, 1563.5]}

exit status: 0 every image solved, 1 some not solved (-o still written,
with a status per image), 2 usage or input error, 130 interrupted.
"""


def add_parser(sub) -> None:
    p = sub.add_parser(
        "resect",
        help="space resection of images from ground control points",
        description="Estimate each image's exterior orientation from its GCPs and print parameters +- std, "
        "sigma0, per-point residuals, flagged blunders and check-point residuals.",
        epilog=CAMERA_FILE_HELP + "\nexample:\n  photax resect data/sample_gcps.csv --camera data/sample_camera.yaml "
        "-o resect.json\n  photax resect gcps.csv --camera camera.yaml --earth-curvature --refraction icao\n",
    )
    p.add_argument("gcp_file", metavar="GCP_FILE", help="GCP list: CSV with header, or OpenDroneMap gcp_list.txt")
    p.add_argument(
        "--camera",
        required=True,
        metavar="CAMERA_FILE",
        help="camera file (YAML/JSON; format below), orthority interior YAML or OpenSfM/ODM reconstruction.json",
    )
    p.add_argument("--image", metavar="NAME", help="only this image (default: every image with enough points)")
    p.add_argument("-o", "--out", metavar="OUT_JSON", help="also write the results as JSON")
    p.add_argument("--json", dest="out", help=argparse.SUPPRESS)  # the old name of --out
    p.add_argument(
        "--convention", choices=CONVENTIONS, default="phi-omega-kappa", help="angle convention of the result"
    )
    p.add_argument(
        "--no-robust",
        dest="robust",
        action="store_false",
        help="no robust start and no blunder detection (plain least squares)",
    )
    p.add_argument(
        "--sigma",
        type=float,
        metavar="PX",
        help="a-priori sigma of an image coordinate, in the file's unit (pixels for pixel "
        "columns); overrides the file's sigma column. Without either, blunders are tested "
        "against the a-posteriori sigma0 (tau test)",
    )
    p.add_argument(
        "--format",
        choices=("auto", "csv", "odm", "qgis", "geojson"),
        default="auto",
        help="GCP file format (qgis: Georeferencer .points; geojson: orthority's GCPs)",
    )
    p.add_argument(
        "--earth-curvature",
        action="store_true",
        help="correct the image coordinates for the earth's curvature (GCPs in a map projection, heights "
        "ellipsoidal; radius of curvature at the GCPs' latitude, from their CRS)",
    )
    p.add_argument(
        "--refraction",
        choices=("bertram", "icao"),
        help="correct the image coordinates for atmospheric refraction: Bertram's formula or the ICAO standard "
        "atmosphere (heights above sea level)",
    )
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.set_defaults(func=run)


def _sigma(table, camera, sigma_px):
    """A-priori sigma in image-plane units, or None (then tau test on sigma0)."""
    import numpy as np

    if sigma_px is not None:
        return sigma_px * (1.0 if table.pixel is None else float(np.mean(np.asarray(camera.pixel_size))))
    given = ~np.isnan(table.sigma)
    if not given.any():
        return None
    if not given.all():
        missing = ", ".join(table.names[~given][:5])
        raise ValueError(f"{table.source}: the sigma column is empty for {missing}; fill it or use --sigma")
    return table.image_plane_sigma(camera)


def _corrections(args, table):
    """The :class:`photax.ImageCorrections` the options ask for, or None; the latitude from the GCPs' CRS."""
    import numpy as np

    from ..earth import ImageCorrections

    if not (args.earth_curvature or args.refraction):
        return None
    latitude = None
    if args.earth_curvature:
        if table.crs is None:
            raise ValueError("--earth-curvature needs the GCPs' CRS (for their latitude); the GCP file names none")
        import pyproj

        x, y = np.mean(table.ground[:, :2], axis=0)
        to_geographic = pyproj.Transformer.from_crs(table.crs, "EPSG:4326", always_xy=True)
        latitude = float(to_geographic.transform(x, y)[1])
    return ImageCorrections(earth_curvature=args.earth_curvature, refraction=args.refraction, latitude=latitude)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..io.atomic import check_output_path
    from ..io.crs import require_projected
    from ..io.orientation import read_camera_unit, read_interior
    from ..io.results import write_json
    from ..progress import progress_bar
    from ..resection import resect
    from ._common import input_file, plural, read_gcps_3d

    gcp_path = input_file(args.gcp_file, "GCP file")
    camera_path = input_file(args.camera, "camera file")
    inputs = [gcp_path, camera_path]
    if args.out:
        check_output_path(args.out, inputs)  # fail before the work, not after
    if args.sigma is not None and not args.sigma > 0:
        raise ValueError(f"--sigma must be positive, got {args.sigma}")
    # One bar over the images (10^5 points take seconds to solve); the report is printed once the bar
    # is closed, so that the two do not interleave on a terminal.
    report = []

    def say(*parts):
        report.append(" ".join(str(p) for p in parts))

    table = read_gcps_3d(gcp_path, format=args.format)
    require_projected(table.crs, f"the GCPs ({args.gcp_file})")  # degrees are not metres
    camera = read_interior(camera_path)  # a photax camera file, an orthority interior, a reconstruction.json
    if table.pixel is not None and (camera.pixel_size is None or camera.image_size is None):
        raise ValueError(f"{args.camera}: the GCPs are in pixels, so the camera needs pixel_size and image_size")
    if args.image is not None:
        table.select(args.image)  # an unknown name is a usage error (exit 2), before any work
    corrections = _corrections(args, table)
    images = [args.image] if args.image is not None else table.image_names
    with progress_bar(args.progress and args.command, len(images), desc="resect", unit="image") as bar:
        results, failed = {}, 0
        for name in images:
            sub = table.select(name)
            bar.set_postfix_str(f"{name or 'image'}: {plural(len(sub), 'point')}")
            label = name or "(single image)"
            n_check = int(sub.check.sum())
            counts = f"{plural(len(sub), 'point')} ({len(sub) - n_check} control, {n_check} check)"
            try:
                res = resect(
                    sub.image_plane(camera),
                    sub.ground,
                    camera,
                    sigma=_sigma(sub, camera, args.sigma),
                    check=sub.check,
                    names=sub.names,
                    convention=args.convention,
                    robust=args.robust,
                    throw=False,
                    corrections=corrections,
                )
            except ValueError as exc:
                say(f"== {label}: NOT SOLVED, skipped ({counts}): {exc}")
                for note in sub.duplicates():
                    say(f"  note: {note}")
                say()
                results[name] = {"status": "skipped", "message": str(exc)}
                failed += 1
                bar.update()
                continue
            say(f"== {label}: {counts} ==")
            for note in sub.duplicates():  # only the notes about this image, under its header
                say(f"  note: {note}")
            say(res.summary(crs=table.crs, camera_unit=read_camera_unit(camera_path)))  # units on every number
            converged = bool(np.all(np.asarray(res.converged)))
            if not converged:
                say(f"  {label}: NOT SOLVED - {res.message}")
            say()
            failed += not converged
            bar.update()
            if args.out:  # the per-point dicts cost seconds for 10^5 points: only when written
                results[name] = {"status": "solved" if converged else "not converged", **res.to_dict()}
    print("\n".join(report))
    solved = len(images) - failed
    print(f"{solved} of {plural(len(images), 'image')} solved" + (f", {failed} not" if failed else ""))
    if args.out:
        write_json(
            {
                "gcp_file": str(args.gcp_file),
                "camera_file": str(args.camera),
                "crs": table.crs,
                "convention": args.convention,
                "images": results,
            },
            args.out,
            inputs=inputs,
        )
        print(f"wrote {args.out}")
    return 1 if failed else 0
