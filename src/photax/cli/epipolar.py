"""``photax epipolar``: resample a stereo pair into epipolar (normalised) images.

LEFT and RIGHT are two images of one camera (``--camera``: a photax camera
file or an orthority interior YAML) with their exterior orientations
(``--exterior``: a ``photax resect -o`` result holding both images, named
like the image files, or an orthority exterior CSV; or one file per image
with ``--exterior-left`` / ``--exterior-right``).  Writes
``OUT_left.tif`` and ``OUT_right.tif`` (float32, NaN outside the originals;
rows are epipolar lines; their transform is the pixel grid itself, x = col,
y = row) and ``OUT.json`` with the epipolar
rotation, principal distance, baseline and each side's pixel offsets
(:class:`photax.EpipolarPair`).

Two satellite images (``--camera rpc``: each image's own RPC, or a ``rpc_param.yaml`` naming both;
no exterior) are rectified over a tile of the left image (``--bounds COL0 ROW0 COL1 ROW1``, default
all of it) for terrain within ``--heights H_MIN H_MAX`` (default the RPCs' validity range) by s2p's
local affine approximation (:class:`photax.AffineEpipolarPair`); ``OUT.json`` then holds both
sides' affine maps (original pixel -> epipolar pixel), the disparity range and the residual
vertical disparity, which the command also prints.  Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

import argparse
import pathlib

from ._common import RESAMPLING


def add_parser(sub) -> None:
    p = sub.add_parser(
        "epipolar",
        help="resample a stereo pair into epipolar images (corresponding points on the same row)",
        description="Resample two oriented images of one camera onto a common plane parallel to their "
        "baseline, so that corresponding points lie on the same row.",
        epilog="example:\n  photax epipolar left.tif right.tif --camera cam.yaml --exterior oriented.json -o pair\n",
    )
    p.add_argument("left", metavar="LEFT", help="left image (any GDAL raster)")
    p.add_argument("right", metavar="RIGHT", help="right image")
    p.add_argument(
        "--camera",
        "--interior",
        dest="camera",
        required=True,
        metavar="CAMERA_FILE",
        help="photax camera file or orthority interior YAML; or 'rpc' (each image's RPC) or a rpc_param.yaml",
    )
    p.add_argument("--bounds", type=float, nargs=4, metavar=("COL0", "ROW0", "COL1", "ROW1"),
                   help="RPC images: the left tile to rectify (left pixels; default the whole image)")  # fmt: skip
    p.add_argument("--heights", type=float, nargs=2, metavar=("H_MIN", "H_MAX"),
                   help="RPC images: the terrain's ellipsoidal height range (default the RPCs' validity range)")  # fmt: skip
    p.add_argument("--exterior", help="orientation file holding both images (resect -o or orthority CSV)")
    p.add_argument("--exterior-left", metavar="FILE", help="the left image's orientation file")
    p.add_argument("--exterior-right", metavar="FILE", help="the right image's orientation file")
    p.add_argument("--camera-name", metavar="NAME", help="camera name in a multi-camera orthority interior file")
    p.add_argument("--resampling", choices=RESAMPLING, default="cubic", help="interpolation of the grey values")
    p.add_argument(
        "-o", "--out", required=True, metavar="OUT", help="output prefix: OUT_left.tif, OUT_right.tif and OUT.json"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np  # here, not at import: photax --help loads no numpy

    from ..io.atomic import check_output_path
    from ..io.orientation import read_exterior, read_interior
    from ..io.raster import read_geotiff, write_geotiff
    from ..io.results import write_json
    from ..matching import epipolar_pair
    from ._common import input_file

    input_file(args.left, "left image")
    input_file(args.right, "right image")
    from .ortho import _is_ground

    if _is_ground(args.camera):
        return _run_rpc(args)
    if args.bounds is not None or args.heights is not None:
        raise ValueError("--bounds and --heights: for RPC images only")
    input_file(args.camera, "camera file")
    if (args.exterior is None) == (args.exterior_left is None and args.exterior_right is None):
        raise ValueError("give --exterior (both images) or --exterior-left and --exterior-right")
    if args.exterior is None and (args.exterior_left is None or args.exterior_right is None):
        raise ValueError("give both --exterior-left and --exterior-right")
    files = [args.exterior] if args.exterior else [args.exterior_left, args.exterior_right]
    for f in files:
        input_file(f, "exterior file")
    inputs = [args.left, args.right, args.camera, *files]
    out = pathlib.Path(args.out)
    outs = [
        out.with_name(out.name + "_left.tif"),
        out.with_name(out.name + "_right.tif"),
        out.with_name(out.name + ".json"),
    ]
    for o in outs:
        check_output_path(o, inputs)
    camera = read_interior(args.camera, args.camera_name)
    ext_l, _ = read_exterior(args.exterior or args.exterior_left, args.left)
    ext_r, _ = read_exterior(args.exterior or args.exterior_right, args.right)
    img_l, _ = read_geotiff(args.left)
    img_r, _ = read_geotiff(args.right)
    pair = epipolar_pair(
        img_l.astype(np.float32), img_r.astype(np.float32), camera, ext_l, ext_r, resampling=args.resampling
    )
    # A pixel "georeference" x = col, y = row (pixel centres on the integers): readers see the epipolar
    # pixel coordinates, and nothing warns about a raster without a transform.
    pixel = (1.0, 0.0, -0.5, 0.0, 1.0, -0.5)
    write_geotiff(outs[0], pair.left.astype(np.float32), pixel, nodata=np.nan, inputs=inputs)
    write_geotiff(outs[1], pair.right.astype(np.float32), pixel, nodata=np.nan, inputs=inputs)
    write_json(
        {
            "rotation_world_from_epipolar": pair.rotation,
            "focal_px": pair.focal_px,
            "baseline": pair.baseline,
            "offsets": pair.offsets,
            "shape_left": list(pair.left.shape[-2:]),
            "shape_right": list(pair.right.shape[-2:]),
            "pixels": "col = x + offset[0], row = offset[1] - y (epipolar image plane, px, y up)",
        },
        outs[2],
        inputs=inputs,
    )
    print(
        f"wrote {outs[0]} ({pair.left.shape[-1]} x {pair.left.shape[-2]}), {outs[1]} "
        f"({pair.right.shape[-1]} x {pair.right.shape[-2]}) and {outs[2]}; baseline {pair.baseline:.4g}"
    )
    return 0


def _run_rpc(args: argparse.Namespace) -> int:
    """Two RPC images: the affine epipolar pair of a tile (module docstring)."""
    import numpy as np

    from ..io.atomic import check_output_path
    from ..io.raster import read_geotiff, write_geotiff
    from ..io.results import write_json
    from ..matching import epipolar_pair
    from ._common import input_file
    from .ortho import _image_camera

    if args.exterior or args.exterior_left or args.exterior_right:
        raise ValueError("--exterior: RPC images carry their own orientation")
    source = None if args.camera == "rpc" else input_file(args.camera, "camera file")
    if source is not None and source.suffix.lower() not in (".yaml", ".yml"):
        raise ValueError(f"--camera {source}: one RPC file for two images; use --camera rpc or a rpc_param.yaml")
    left, right = pathlib.Path(args.left), pathlib.Path(args.right)
    cameras = [_image_camera(source, image, True, False) for image in (left, right)]
    inputs = [args.left, args.right, *([source] if source else [])]
    out = pathlib.Path(args.out)
    outs = [out.with_name(out.name + s) for s in ("_left.tif", "_right.tif", ".json")]
    for o in outs:
        check_output_path(o, inputs)
    img_l, _ = read_geotiff(args.left)
    img_r, _ = read_geotiff(args.right)
    pair = epipolar_pair(
        img_l.astype(np.float32), img_r.astype(np.float32), cameras[0], None, None, camera_right=cameras[1],
        bounds=args.bounds, heights=args.heights, resampling=args.resampling,
    )  # fmt: skip
    pixel = (1.0, 0.0, -0.5, 0.0, 1.0, -0.5)
    write_geotiff(outs[0], pair.left.astype(np.float32), pixel, nodata=np.nan, inputs=inputs)
    write_geotiff(outs[1], pair.right.astype(np.float32), pixel, nodata=np.nan, inputs=inputs)
    write_json(
        {
            "affine_left": pair.homography_left,
            "affine_right": pair.homography_right,
            "bounds_left": list(pair.bounds),
            "heights": list(pair.heights),
            "disparity_range": list(pair.disparity_range),
            "vertical_residual_px": pair.vertical_residual,
            "vertical_rms_px": pair.vertical_rms,
            "pixels": "epipolar (col, row, 1) = affine @ original (col, row, 1); d = col_left - col_right",
        },
        outs[2],
        inputs=inputs,
    )
    print(
        f"wrote {outs[0]} ({pair.left.shape[-1]} x {pair.left.shape[-2]}), {outs[1]} "
        f"({pair.right.shape[-1]} x {pair.right.shape[-2]}) and {outs[2]}; disparities "
        f"{pair.disparity_range[0]}..{pair.disparity_range[1]}, residual vertical disparity "
        f"{pair.vertical_residual:.3f} px (RMS {pair.vertical_rms:.3f})"
    )
    return 0
