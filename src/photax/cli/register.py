"""``photax register``: refine an image's orientation against a reference orthophoto (:func:`photax.register_to_ortho`).

IMAGE with its camera and approximate orientation, a reference orthophoto and
a DEM in the same ground CRS.  Writes the refined orientation as JSON
(``{"exterior": {...}, "converged", "result", "correlation", "message"}``, read back by
``--exterior`` options) and prints the status.  Exit codes: 0 converged,
1 not converged (the JSON is still written), 2 bad input.
"""

from __future__ import annotations

import argparse


def add_parser(sub) -> None:
    p = sub.add_parser(
        "register",
        help="refine an orientation by matching the image to a reference orthophoto",
        description="Gauss-Newton on the grey-value differences between the image and the "
        "reference orthophoto rendered into it, coarse to fine.",
        epilog="example:\n  photax register img.tif --camera cam.yaml --exterior approx.json "
        "--ortho reference.tif --dem dem.tif -o refined.json\n",
    )
    p.add_argument("image", metavar="IMAGE", help="the image to orient (any GDAL raster)")
    p.add_argument(
        "--camera",
        "--interior",
        dest="camera",
        required=True,
        metavar="CAMERA_FILE",
        help="photax camera file or orthority interior YAML (--interior is an alias)",
    )
    p.add_argument("--exterior", required=True, help="approximate orientation (resect -o or orthority CSV)")
    p.add_argument("--ortho", required=True, help="reference orthophoto (GeoTIFF, ground CRS)")
    p.add_argument("--dem", required=True, help="DEM raster in the ground CRS")
    p.add_argument(
        "--levels",
        default="8,4,2,1",
        metavar="L,...",
        help="coarse-to-fine levels, px of blur and sampling step (default 8,4,2,1; a start within a "
        "few px of the truth needs fewer, e.g. 4,2,1)",
    )
    p.add_argument("--max-steps", type=int, default=15, metavar="N", help="Gauss-Newton steps per level at most")
    p.add_argument("-o", "--out", required=True, help="output JSON with the refined orientation")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..io.atomic import check_output_path
    from ..io.crs import require_same
    from ..io.orientation import read_exterior, read_interior
    from ..io.raster import read_dem, read_geotiff
    from ..io.results import write_json
    from ..matching import register_to_ortho
    from ._common import check_crs, input_file

    files = [args.image, args.camera, args.exterior, args.ortho, args.dem]
    for f in files:
        input_file(f, "input file")
    check_output_path(args.out, files)
    try:
        levels = tuple(int(v) for v in args.levels.split(","))
    except ValueError:
        raise ValueError(
            f"--levels must be whole numbers separated by commas, e.g. 4,2,1; got {args.levels!r}"
        ) from None
    if not levels or min(levels) < 1 or args.max_steps < 1:
        raise ValueError(
            f"--levels must be positive and --max-steps at least 1, got {args.levels!r} and {args.max_steps}"
        )
    camera = read_interior(args.camera)
    exterior, crs = read_exterior(args.exterior, args.image)
    image = read_geotiff(args.image)[0][0].astype(float)
    ortho, profile = read_geotiff(args.ortho)
    transform = tuple(profile["transform"])[:6]
    dem = read_dem(args.dem)
    check_crs(crs, f"the orientation ({args.exterior})", dem.crs, f"the DEM ({args.dem})")
    require_same(dem.crs, f"the DEM ({args.dem})", profile.get("crs"), f"the ortho ({args.ortho})")
    res = register_to_ortho(
        image,
        camera,
        exterior,
        ortho[0].astype(float),
        transform,
        dem,
        levels=levels,
        max_steps=args.max_steps,
        throw=False,
    )
    e = res.exterior
    write_json(
        {
            "exterior": {"position": e.position, "angles_rad": e.angles, "convention": e.convention},
            "status": "solved" if res.converged else "not converged",
            "converged": res.converged,
            "result": res.result.name,
            "correlation": res.correlation,
            "steps": res.steps,
            "rmse": res.rmse,
            "history": res.history,
            "message": res.message,
        },
        args.out,
        inputs=files,
    )
    print(f"{'converged' if res.converged else 'NOT converged'}: {res.message}; wrote {args.out}")
    return 0 if res.converged else 1
