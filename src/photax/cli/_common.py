"""Helpers shared by the subcommands: input checks, units, plurals."""

from __future__ import annotations

import math
import os
import pathlib

from ..errors import UnreadableFileError

# Choices of --convention and --resampling, written out here so that building
# the parser (``photax --help``) imports neither JAX nor numpy; they must equal
# photax.rotation.CONVENTIONS and photax.resampling.RESAMPLING (a test checks).
CONVENTIONS = ("phi-omega-kappa", "omega-phi-kappa")
RESAMPLING = ("nearest", "bilinear", "cubic", "lanczos", "lanczos4", "bspline")


NODATA_HELP = (
    "value of output pixels without data, recorded as the file's nodata (default: the input's "
    "nodata; else NaN for float images, and for integer images no value but an internal mask "
    "band, so that no grey value, true black included, is lost)"
)


# Set by photax.cli.main when it turned Python's cyclic garbage collector off for the start-up.
_GC_PAUSED = [False]


def start_gc() -> None:
    """The command's start-up is over: Python's cyclic garbage collector, which
    :func:`photax.cli.main` turns off while the command imports JAX, parses and reads
    its inputs, goes back on.  Start-up makes about a million objects (JAX's import
    alone) and next to no cyclic garbage, yet the collector scanned them again and
    again: 0.1-0.2 s of a warm ``photax ortho`` of four frames.  What start-up made is
    frozen first (``gc.freeze``), so no later collection scans it.  Nothing when the
    collector was not paused by ``main`` (an in-process ``main(argv)``, a library user)."""
    import gc

    if _GC_PAUSED[0]:
        _GC_PAUSED[0] = False
        gc.freeze()
        gc.enable()


def nodata_value(text: str) -> float:
    """``--nodata``: a number or ``nan``."""
    import argparse

    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number or nan, got {text!r}") from None


def input_file(path, what: str) -> pathlib.Path:
    """``path`` as a Path after checking it is a readable file.

    Raises:
        ValueError: one line naming ``what`` (e.g. "GCP file") and the path:
            missing, a folder where a file is expected, or not readable.
    """
    from ..io.files import check_regular, opensfm_frame  # not io.orientation: it imports JAX (0.4 s)

    p = pathlib.Path(opensfm_frame(path)[1])  # grid:FILE, topocentric:FILE (a reconstruction.json's frame)
    if not p.exists():
        raise ValueError(f"{what} {p}: no such file")
    if p.is_dir():
        raise ValueError(f"{what} {p}: is a folder, expected a file")
    try:
        check_regular(p, what)  # a FIFO would block the open() below, a device never end
    except ValueError as exc:
        raise ValueError(f"{what} {exc}") from None
    try:
        with open(p, "rb"):
            pass
    except PermissionError:
        raise UnreadableFileError(f"{what} {p}: permission denied (cannot read it)") from None
    except OSError as exc:
        raise UnreadableFileError(f"{what} {p}: cannot read it ({exc.strerror or exc})") from None
    return p


def input_folder(path, what: str) -> pathlib.Path:
    """``path`` as a Path after checking it is a readable folder."""
    p = pathlib.Path(path)
    if not p.exists():
        raise ValueError(f"{what} {p}: no such folder")
    if not p.is_dir():
        raise ValueError(f"{what} {p}: is a file, expected a folder")
    if not os.access(p, os.R_OK | os.X_OK):
        raise UnreadableFileError(f"{what} {p}: permission denied (cannot read it)")
    return p


def output_folder(path, what: str) -> pathlib.Path:
    """``path`` as a Path after checking it is a folder or nothing yet (the writers make it)."""
    p = pathlib.Path(path)
    if p.exists() and not p.is_dir():
        raise ValueError(f"{what} {p}: is a file, expected a folder")
    return p


def read_gcps_3d(path, format: str = "auto"):
    """:func:`photax.io.read_gcps` for a command that needs heights: a 2-D file (QGIS ``.points``)
    is refused."""
    import numpy as np

    from ..io.gcp import read_gcps

    table = read_gcps(path, format=format)
    if not np.all(np.isfinite(table.ground[:, 2])):
        raise ValueError(f"{path}: the GCPs have no heights (a QGIS .points file is 2-D); this command needs E, N, h")
    return table


def plural(n: int, word: str, words: str | None = None) -> str:
    """``"1 camera"``, ``"2 cameras"``, ``"0 cameras"``."""
    return f"{n} {word if n == 1 else (words or word + 's')}"


def ground_unit(crs, default: str = "ground units") -> str:
    """The CRS's unit symbol (``"m"``, ``"ft"``...) or ``default`` when unknown."""
    from ..io.raster import crs_unit

    return crs_unit(crs) or default


def add_oriented_images(p) -> None:
    """The arguments :func:`read_oriented_images` reads: IMAGES of one camera, their
    approximate orientations, the DEM, and the matching search radius."""
    p.add_argument("images", nargs="+", metavar="IMAGE", help="images of one camera (any GDAL raster)")
    p.add_argument(
        "--camera",
        "--interior",
        dest="camera",
        required=True,
        metavar="CAMERA_FILE",
        help="photax camera file or orthority interior YAML (--interior is an alias)",
    )
    p.add_argument("--exterior", required=True, help="approximate orientations (resect -o, orthority CSV, "
                   "reconstruction.json, or exif: each image's GPS and DJI gimbal tags)")  # fmt: skip
    p.add_argument("--dem", required=True, help="DEM raster in the ground CRS")
    p.add_argument("--search", type=int, default=12, help="search radius around the prediction, px (default 12)")


def read_oriented_images(args, extra: list) -> tuple[list, object, list[str], list, list]:
    """The inputs of a multi-image command (``photax transfer``, ``photax ties``):
    ``(files, camera, names, images, exteriors)`` from ``args.images``,
    ``args.camera``, ``args.exterior`` and ``args.dem`` plus the ``extra`` files,
    each checked as readable, and ``args.out`` checked against all of them."""

    from ..io.atomic import check_output_path
    from ..io.orientation import exif_attitude, read_exteriors, read_interior
    from ..io.raster import open_raster, read_geotiff

    exif = exif_attitude(args.exterior) is not None  # --exterior exif: the images' own tags
    files = [*args.images, args.camera, *([] if exif else [args.exterior]), args.dem, *[f for f in extra if f]]
    for f in files:
        input_file(f, "input file")
    check_output_path(args.out, files)
    camera = read_interior(args.camera)
    names = [pathlib.Path(f).stem for f in args.images]
    images = [read_geotiff(f)[0][0].astype(float) for f in args.images]
    with open_raster(args.dem) as src:  # the DEM's CRS against the orientations' (the caller reads the heights)
        dem_crs = src.crs.to_wkt() if src.crs else None
    # the file parsed once; latitudes/longitudes (a drone's CSV, its tags) go into the DEM's CRS
    table, crs = read_exteriors(args.exterior, args.images, crs=dem_crs)
    exterior = [table[f] for f in args.images]
    check_crs(crs, f"the orientations ({args.exterior})", dem_crs, f"the DEM ({args.dem})")
    return files, camera, names, images, exterior


def check_crs(orientation_crs, what_orientation: str, dem_crs, what_dem: str) -> None:
    """Where an orientation meets a DEM: neither geographic, both in one CRS (:mod:`photax.io.crs`)."""
    from ..io.crs import require_projected, require_same

    require_projected(orientation_crs, what_orientation)
    require_projected(dem_crs, what_dem)
    require_same(orientation_crs, what_orientation, dem_crs, what_dem)


def add_grid_options(p, *, resolution_help: str, crs_help: str):
    """The output grid's options, gdalwarp's: ``--resolution`` (``-tr``), ``--bounds`` (``-te``),
    ``--target-aligned`` (``-tap``), ``--size`` (``-ts``), ``--like`` (a raster's CRS, transform and
    shape) and ``--crs`` (``-t_srs``), read back by :func:`grid_spec`.  Returns their argument group."""
    g = p.add_argument_group("output grid (as gdalwarp's -tr, -te, -tap, -ts, -t_srs)")
    g.add_argument("--resolution", type=float, metavar="RES", help=resolution_help)
    g.add_argument("--bounds", nargs=4, type=float, metavar=("XMIN", "YMIN", "XMAX", "YMAX"),
                   help="output extent in the output CRS (gdalwarp -te): the grid covers it whole, its origin at "
                   "(XMIN, YMAX); with --resolution the far edges are rounded to whole pixels")  # fmt: skip
    g.add_argument("--target-aligned", action="store_true",
                   help="with --resolution: edges snapped outwards to multiples of it (gdalwarp -tap), so grids "
                   "of one resolution line up; a grid over the image's footprint always is")  # fmt: skip
    g.add_argument("--size", nargs=2, type=int, metavar=("W", "H"),
                   help="output size in pixels (gdalwarp -ts; one of them 0: square pixels); not with --resolution")  # fmt: skip
    g.add_argument("--like", metavar="RASTER", help="the CRS, transform and shape of RASTER (no other grid option)")
    g.add_argument("--crs", metavar="CRS", help=crs_help)
    return g


def grid_spec(args):
    """The :class:`photax.GridSpec` of :func:`add_grid_options`' options, refusing contradictions
    (named as the options): ``--size`` with ``--resolution``, ``--target-aligned`` without
    ``--resolution``, ``--like`` with any other grid option, a resolution not positive."""
    from ..grid import Grid, GridSpec

    res, bounds, size, like, crs = args.resolution, args.bounds, args.size, args.like, args.crs
    if res is not None and not (res > 0 and math.isfinite(res)):
        raise ValueError(f"--resolution must be positive, got {res}")
    if like is not None:
        given = [o for o, v in (("--resolution", res), ("--bounds", bounds), ("--size", size), ("--crs", crs)) if v]
        given += ["--target-aligned"] if args.target_aligned else []
        if given:
            raise ValueError(f"--like takes RASTER's CRS, transform and shape: leave out {', '.join(given)}")
        return GridSpec(like=Grid.like(input_file(like, "--like raster")))
    if size is not None and res is not None:
        raise ValueError("--size and --resolution exclude each other (gdalwarp: -ts and -tr)")
    if args.target_aligned and res is None:
        raise ValueError("--target-aligned needs --resolution (gdalwarp: -tap needs -tr)")
    if size is not None and (min(size) < 0 or max(size) == 0):
        raise ValueError(f"--size W H: whole numbers >= 0, not both 0, got {size[0]} {size[1]}")
    if bounds is not None and not (bounds[2] > bounds[0] and bounds[3] > bounds[1]):
        raise ValueError(
            f"--bounds XMIN YMIN XMAX YMAX: need XMAX > XMIN and YMAX > YMIN, got {' '.join(map(str, bounds))}"
        )
    return GridSpec(bounds=bounds, resolution=res, size=size, target_aligned=args.target_aligned, crs=crs)
