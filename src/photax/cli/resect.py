"""``photax resect``: space resection of every image in a GCP file.

Exit codes: 0 all resected images converged, 1 some did not, 2 bad input
(a one-line message on stderr).
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np

from ..rotation import CONVENTIONS


def add_parser(sub) -> None:
    p = sub.add_parser(
        "resect",
        help="space resection of images from ground control points",
        description="Estimate each image's exterior orientation from its GCPs and print parameters +- std, "
        "sigma0, per-point residuals, flagged blunders and check-point residuals.",
    )
    p.add_argument("gcp_file", metavar="GCP_FILE", help="GCP list: CSV with header, or OpenDroneMap gcp_list.txt")
    p.add_argument("--camera", required=True, metavar="CAMERA_FILE", help="camera file (YAML/JSON, see photax.io.camera_file)")
    p.add_argument("--image", metavar="NAME", help="only this image (default: every image with enough points)")
    p.add_argument("--json", metavar="OUT", help="also write the results as JSON")
    p.add_argument("--convention", choices=CONVENTIONS, default="phi-omega-kappa", help="angle convention of the result")
    p.add_argument("--no-robust", dest="robust", action="store_false",
                   help="no robust start and no blunder detection (plain least squares)")
    p.add_argument("--sigma", type=float, metavar="PX",
                   help="a-priori sigma of an image coordinate, in the file's unit (pixels for pixel "
                   "columns); overrides the file's sigma column. Without either, blunders are tested "
                   "against the a-posteriori sigma0 (tau test)")
    p.add_argument("--format", choices=("auto", "csv", "odm"), default="auto", help="GCP file format")
    p.set_defaults(func=run)


def _sigma(table, camera, sigma_px):
    """A-priori sigma in image-plane units, or None (then tau test on sigma0)."""
    if sigma_px is not None:
        return sigma_px * (1.0 if table.pixel is None else float(np.mean(np.asarray(camera.pixel_size))))
    given = ~np.isnan(table.sigma)
    if not given.any():
        return None
    if not given.all():
        missing = ", ".join(table.names[~given][:5])
        raise ValueError(f"{table.source}: the sigma column is empty for {missing}; fill it or use --sigma")
    return table.image_plane_sigma(camera)


def _camera_unit(path) -> str | None:
    """The camera file's length unit (``unit:``; ``px`` for the pixel shorthand), for the report's labels."""
    from ..io.camera_file import _load

    data = _load(pathlib.Path(path))
    return "px" if "focal_length_px" in data else data.get("unit")


def run(args: argparse.Namespace) -> int:
    from ..io.camera_file import read_camera
    from ..io.gcp import read_gcps
    from ..io.atomic import check_output_path
    from ..io.results import write_json
    from ..resection import resect

    inputs = [args.gcp_file, args.camera]
    if args.json:
        check_output_path(args.json, inputs)  # fail before the work, not after
    if args.sigma is not None and not args.sigma > 0:
        raise ValueError(f"--sigma must be positive, got {args.sigma}")
    table = read_gcps(args.gcp_file, format=args.format)
    camera = read_camera(args.camera)
    if table.pixel is not None and (camera.pixel_size is None or camera.image_size is None):
        raise ValueError(f"{args.camera}: the GCPs are in pixels, so the camera needs pixel_size and image_size")
    for note in table.duplicates():
        print(f"note: {note}")
    images = [args.image] if args.image is not None else table.image_names
    results, failed = {}, 0
    for name in images:
        sub = table.select(name)
        label = name or "(single image)"
        try:
            res = resect(sub.image_plane(camera), sub.ground, camera, sigma=_sigma(sub, camera, args.sigma),
                         check=sub.check, names=sub.names, convention=args.convention,
                         robust=args.robust, throw=False)
        except ValueError as exc:
            if args.image is not None:
                raise ValueError(f"image {label}: {exc}") from None
            print(f"== {label}: skipped ({len(sub)} points): {exc}\n")
            results[name] = {"skipped": str(exc)}
            continue
        n_check = int(sub.check.sum())
        print(f"== {label}: {len(sub)} points ({len(sub) - n_check} control, {n_check} check) ==")
        print(res.summary(crs=table.crs, camera_unit=_camera_unit(args.camera)))  # units on every number
        print()
        failed += not res.converged
        results[name] = res
    if args.json:
        write_json({"gcp_file": str(args.gcp_file), "camera_file": str(args.camera), "crs": table.crs,
                    "convention": args.convention, "images": results}, args.json, inputs=inputs)
        print(f"wrote {args.json}")
    return 1 if failed else 0
