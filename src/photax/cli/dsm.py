"""``photax dsm``: a digital surface model from two or more oriented images (dense stereo).

IMAGEs take the sensors ``photax ortho`` takes: frame images with ``--camera`` (a photax camera
file, an orthority interior YAML, an OpenSfM/ODM ``reconstruction.json``) and ``--exterior`` (a
``photax resect/bundle`` result, an orthority exterior file, a ``reconstruction.json``); or
satellite images with ``--camera rpc`` (each image's RPC), a ``rpc_param.yaml``, ``.RPB`` /
``_RPC.TXT`` files, or a photax push-broom camera file, and no ``--exterior``.

Every pair of images (frame: each pair whose geometry allows epipolar resampling; satellite: each
pair, the left image cut into ``--tile`` tiles, each rectified by its local affine approximation)
is resampled into an epipolar pair, matched by semi-global matching (:func:`photax.disparity`) on
images reduced ``--zoom`` times, and triangulated (:mod:`photax.stereo`); each pair's points are
rasterised onto one grid (``--resolution``, ``--crs``, ``--bounds``; default: the points' extent
at 4 times the matching's ground spacing), small holes filled, and the pairs fused by the median
per cell.  Writes OUT (a Cloud-Optimized GeoTIFF, float32, NaN nodata, the grid's CRS), optionally
the points of all pairs (colour, residual and height sigma; the CRS): ``--points`` by its suffix
(``.ply`` binary PLY, ``.las`` LAS 1.4, ``.laz`` LAZ; LAS and LAZ need the ``las`` extra),
``--ply`` a binary PLY whatever the name.  ``--heights H_MIN H_MAX`` (the terrain's heights,
ellipsoidal for satellites) bound the disparity search; required for frame images, default the
RPCs' validity range for satellites.  A report gives each pair's points, the
DSM's completeness and median height sigma.  Exit codes: 0 written, 1 no height at all (a blank
DSM: nothing written), 2 bad input.
"""

from __future__ import annotations

import argparse
import itertools
import pathlib


def add_parser(sub) -> None:
    p = sub.add_parser(
        "dsm",
        help="a digital surface model (COG) from two or more oriented images by dense stereo matching",
        description="Match every pair of the images in epipolar geometry (semi-global matching), "
        "triangulate the disparities and fuse the pairs' heights on one grid into a DSM.",
        epilog="examples:\n"
        "  photax dsm a.tif b.tif c.tif --camera reconstruction.json --exterior reconstruction.json "
        "--heights 40 140 --resolution 0.8 -o dsm.tif\n"
        "  photax dsm left.tif right.tif --camera rpc --heights 0 500 --crs EPSG:32633 -o dsm.tif --points pts.laz\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("image", metavar="IMAGE", nargs="+", help="two or more images (any GDAL raster)")
    p.add_argument("--camera", "--interior", dest="camera", required=True, metavar="CAMERA_FILE",
                   help="as photax ortho: a frame camera file or reconstruction.json, or 'rpc', a "
                   "rpc_param.yaml, .RPB / _RPC.TXT, or a push-broom camera file")  # fmt: skip
    p.add_argument("--exterior", help="frame images: the orientation file (as photax ortho)")
    p.add_argument("--camera-name", metavar="NAME", help="camera name in a multi-camera orthority interior file")
    p.add_argument("-o", "--out", required=True, metavar="OUT_TIF", help="output DSM (Cloud-Optimized GeoTIFF)")
    p.add_argument("--points", metavar="POINTS",
                   help="also write the points, the format by the suffix: .ply binary PLY, .las LAS 1.4, .laz LAZ "
                   '(LAS/LAZ: x y z to 1 mm, RGB, residual and sigma_z extra bytes, the CRS as WKT; '
                   'pip install "photax[las]")')  # fmt: skip
    p.add_argument("--ply", metavar="PLY", help="also write the points as a binary PLY (whatever the name)")
    p.add_argument("--resolution", type=float, help="DSM cell size (default 4 x the matching's ground spacing)")
    p.add_argument("--crs", help="the DSM's CRS (satellite images; default the UTM zone of the scene)")
    p.add_argument("--bounds", type=float, nargs=4, metavar=("XMIN", "YMIN", "XMAX", "YMAX"),
                   help="the DSM's extent in its CRS (default the points' extent)")  # fmt: skip
    p.add_argument("--heights", type=float, nargs=2, metavar=("H_MIN", "H_MAX"),
                   help="the terrain's height range (the disparity search); required for frame images")  # fmt: skip
    p.add_argument("--zoom", type=int, default=1, help="match the epipolar images reduced this many times (1)")
    p.add_argument("--tile", type=int, default=500, help="satellite images: left tile size in pixels (500)")
    p.add_argument("--reducer", choices=("median", "max"), default="median", help="height of a cell's points")
    p.add_argument("--fill", type=int, default=3, help="fill enclosed holes up to this many cells across (3)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.set_defaults(func=run)


def _pairs(n: int):
    return list(itertools.combinations(range(n), 2))


def _tiles(w: int, h: int, size: int):
    """Left-image tiles ``(col0, row0, col1, row1)`` of about ``size`` pixels (inclusive pixel bounds)."""
    nx, ny = max(1, round(w / size)), max(1, round(h / size))
    xs, ys = [round(i * (w - 1) / nx) for i in range(nx + 1)], [round(j * (h - 1) / ny) for j in range(ny + 1)]
    return [(xs[i], ys[j], xs[i + 1], ys[j + 1]) for j in range(ny) for i in range(nx)]


def run(args: argparse.Namespace) -> int:
    import sys
    import warnings

    import numpy as np

    from ..io.atomic import check_output_path
    from ..io.raster import read_geotiff
    from ..progress import progress_bar
    from ..stereo import PointCloud, fuse_dsms, pair_points, rasterize_points
    from ._common import input_file
    from .ortho import _is_ground

    if len(args.image) < 2:
        raise ValueError("give at least two images")
    if len(set(map(str, args.image))) != len(args.image):
        raise ValueError("an image is given twice")
    for image in args.image:
        input_file(image, "image")
    if args.zoom < 1 or args.tile < 64 or args.fill < 0:
        raise ValueError("--zoom must be >= 1, --tile >= 64 and --fill >= 0")
    if args.resolution is not None and not args.resolution > 0:
        raise ValueError(f"--resolution must be positive, got {args.resolution}")
    if args.heights is not None and not args.heights[1] > args.heights[0]:
        raise ValueError(f"--heights: H_MAX must be above H_MIN, got {args.heights}")
    ground = _is_ground(args.camera)
    inputs = [*args.image, *(f for f in (None if args.camera == "rpc" else args.camera, args.exterior) if f)]
    out = check_output_path(pathlib.Path(args.out), inputs)
    ply = check_output_path(pathlib.Path(args.ply), inputs) if args.ply else None
    points = _points_output(args.points, inputs) if args.points else None
    if ply is not None and points is not None and ply.resolve() == points.resolve():
        raise ValueError(f"--ply and --points name one file: {ply}")
    if ground:
        if args.exterior is not None:
            raise ValueError("--exterior: satellite images (RPC, push-broom) carry their own orientation")
        cameras, crs, heights = _ground_cameras(args)
        jobs = [(i, j, t) for i, j in _pairs(len(args.image)) for t in _tiles(*cameras[i].image_size, args.tile)]
    else:
        if args.exterior is None:
            raise ValueError("--exterior is required with a frame camera (only an RPC camera carries its orientation)")
        if args.heights is None:
            raise ValueError("--heights H_MIN H_MAX is required for frame images (the terrain's height range)")
        if args.crs is not None:
            raise ValueError("--crs: for satellite images only (a frame DSM is in its orientation's CRS)")
        camera, exteriors, crs = _frame_cameras(args)
        heights = tuple(args.heights)
        jobs = [(i, j, None) for i, j in _pairs(len(args.image))]
    images = [read_geotiff(image)[0] for image in args.image]
    clouds, report = [], []
    with progress_bar(args.progress and args.command, len(jobs), desc="dsm", unit="pair") as bar:
        for i, j, tile in jobs:
            name = f"{pathlib.Path(args.image[i]).name} + {pathlib.Path(args.image[j]).name}"
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    if ground:
                        pts, info = pair_points(images[i], images[j], cameras[i], camera_right=cameras[j],
                                                heights=heights, bounds=tile, zoom=args.zoom, crs=crs)  # fmt: skip
                    else:
                        pts, info = pair_points(images[i], images[j], camera, exteriors[i], exteriors[j],
                                                heights=heights, zoom=args.zoom, crs=crs)  # fmt: skip
            except ValueError as exc:  # a pair whose geometry allows no epipolar pair: skipped, said
                report.append(f"  {name}{'' if tile is None else f' tile {tile}'}: skipped ({exc})")
                bar.update(1)
                continue
            keep = (pts.z >= heights[0] - 0.5 * (heights[1] - heights[0])) & (
                pts.z <= heights[1] + 0.5 * (heights[1] - heights[0])
            )
            pts = pts.select(keep)
            clouds.append((i, j, pts))
            extra = f", vertical residual {info['vertical_residual']:.2f} px" if "vertical_residual" in info else ""
            report.append(
                f"  {name}{'' if tile is None else f' tile {tile}'}: {len(pts)} points, "
                f"{info['valid']:.0%} matched, disparities {info['disparity_range'][0]}..{info['disparity_range'][1]}"
                f"{extra}"
            )
            bar.update(1)
    every = [c for _, _, c in clouds if len(c)]
    if not every:
        print("\n".join(report), file=sys.stderr)
        print(f"{args.command}: no pair gave any point: no DSM written", file=sys.stderr)
        return 1
    allpts = PointCloud.concatenate(every)
    grid = _grid(args, allpts, crs)
    # one surface per pair (its tiles together), then the median of the pairs
    per_pair = {}
    for i, j, c in clouds:
        per_pair.setdefault((i, j), []).append(c)
    models = [
        rasterize_points(PointCloud.concatenate(cs), grid, reducer=args.reducer, fill=args.fill)
        for cs in per_pair.values()
        if sum(len(c) for c in cs)
    ]
    dsm = fuse_dsms(models) if len(models) > 1 else models[0]
    print("\n".join(report))
    if not np.isfinite(dsm.heights).any():
        print(f"{args.command}: the DSM has no height on its grid: nothing written", file=sys.stderr)
        return 1
    dsm.write(out, inputs=inputs)
    for path in (p for p in (ply, points) if p is not None):
        if path is ply or path.suffix.lower() == ".ply":
            allpts.write_ply(path)
        else:
            allpts.write_las(path, inputs=inputs)
    sig = dsm.sigma[np.isfinite(dsm.heights) & np.isfinite(dsm.sigma)]
    print(
        f"wrote {out}: {grid.width} x {grid.height} cells of {abs(grid.transform.a):g}, "
        f"completeness {dsm.completeness:.1%}, median height sigma {np.median(sig) if sig.size else float('nan'):.3g} "
        f"(from {len(allpts)} points of {len(models)} pair(s))"
        + "".join(f"; points in {p}" for p in (ply, points) if p is not None)
    )
    return 0


def _points_output(path, inputs) -> pathlib.Path:
    """``--points``: the path, checked before any matching (its suffix; for LAS / LAZ that laspy, and
    lazrs for LAZ, are installed)."""
    from ..io.atomic import check_output_path

    path = check_output_path(pathlib.Path(path), inputs)
    suffix = path.suffix.lower()
    if suffix not in (".ply", ".las", ".laz"):
        raise ValueError(f"--points {path}: the suffix says the format: .ply, .las or .laz")
    if suffix != ".ply":
        import laspy  # ModuleNotFoundError: the CLI names the las extra

        if suffix == ".laz" and not laspy.LazBackend.detect_available():
            raise ModuleNotFoundError("no LAZ backend for laspy", name="lazrs")
    return path


def _grid(args, pts, crs):
    import numpy as np

    from ..grid import Grid

    if args.bounds is not None:
        bounds = tuple(args.bounds)
        if not (bounds[2] > bounds[0] and bounds[3] > bounds[1]):
            raise ValueError(f"--bounds must be XMIN YMIN XMAX YMAX with max > min, got {bounds}")
    else:
        lo, hi = np.percentile(pts.xyz[:, :2], [0.1, 99.9], axis=0)
        bounds = (lo[0], lo[1], hi[0], hi[1])
    res = args.resolution
    if res is None:  # 4 x the points' mean spacing: about 16 points per cell of each pair
        area = (bounds[2] - bounds[0]) * (bounds[3] - bounds[1])
        res = 4.0 * float(np.sqrt(area / max(len(pts), 1)))
    return Grid.from_bounds(bounds, res, crs)


def _frame_cameras(args):
    from ..io.orientation import read_exteriors
    from .ortho import _read_camera

    camera = _read_camera(args, args.image)
    table, crs = read_exteriors(args.exterior, args.image)
    return camera, [table[image] for image in args.image], crs


def _ground_cameras(args):
    import numpy as np

    from ..io.pushbroom_file import is_pushbroom_file
    from ..sensor import utm_crs
    from ._common import input_file
    from .ortho import _image_camera

    source = None if args.camera == "rpc" else input_file(args.camera, "camera file")
    pushbroom = source is not None and is_pushbroom_file(source)
    several = len(args.image) > 1
    if source is not None and not pushbroom and source.suffix.lower() not in (".yaml", ".yml"):
        raise ValueError(
            f"--camera {source}: one RPC file for several images; give each image its own "
            "(--camera rpc: the RPC in each image or beside it; or a rpc_param.yaml naming every image)"
        )
    if pushbroom:
        raise ValueError("--camera: one push-broom camera file describes one image; give RPCs (photax rpc)")
    cameras = [_image_camera(source, pathlib.Path(image), several, pushbroom) for image in args.image]
    crs = args.crs or utm_crs(*np.asarray(cameras[0].ground_box()[0], dtype=float))
    if args.heights is not None:
        heights = tuple(args.heights)
    else:
        ranges = [c.height_range for c in cameras]
        heights = (max(r[0] for r in ranges), min(r[1] for r in ranges))
    return cameras, crs, heights
