"""``photax ortho``: orthorectify an image with its orientation and a DEM.

INTERIOR is a photax camera file (YAML/JSON, :mod:`photax.io.camera_file`)
or an orthority interior YAML; EXTERIOR a ``photax resect --json`` result or
an orthority exterior CSV (+ .prj beside it).  The output GeoTIFF is written
tile by tile into a temporary file renamed at the end; it may not be an
input.  Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

import argparse
import pathlib

from ..resampling import RESAMPLING


def add_parser(sub) -> None:
    p = sub.add_parser(
        "ortho",
        help="orthorectify an image with a DEM (collinearity equations)",
        description="Orthorectify IMAGE: every ground pixel gets its height from the DEM and its grey value "
        "from the image position given by the collinearity equations. Occlusions are not detected.",
    )
    p.add_argument("image", metavar="IMAGE", help="the image (any GDAL raster)")
    p.add_argument("--dem", required=True, help="DEM raster in the ground CRS of the orientation")
    p.add_argument("--interior", required=True, help="photax camera file, or orthority interior YAML")
    p.add_argument("--exterior", required=True, help="photax resect --json result, or orthority exterior CSV")
    p.add_argument("--out", required=True, help="output GeoTIFF")
    p.add_argument("--resolution", type=float, help="ground pixel size (default: the mean ground sampling distance)")
    p.add_argument("--resampling", choices=RESAMPLING, default="bilinear")
    p.add_argument("--camera", metavar="NAME", help="camera name in a multi-camera orthority interior file")
    p.add_argument("--tile", type=int, default=1024, help="output tile size in pixels (memory ~ tile^2)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.set_defaults(func=run)


def read_interior(path, name: str | None = None):
    """A FrameCamera from a photax camera file or an orthority interior YAML."""
    import yaml

    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such interior file: {path}")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError:
        data = None
    if isinstance(data, dict) and data and all(isinstance(v, dict) and "type" in v for v in data.values()):
        from ..io.orthority import read_orthority_interior

        cameras = read_orthority_interior(path)
        if name is None and len(cameras) == 1:
            return next(iter(cameras.values()))
        if name not in cameras:
            raise ValueError(f"{path}: give --camera, one of {sorted(map(str, cameras))}")
        return cameras[name]
    from ..io.camera_file import read_camera

    return read_camera(path)


def read_exterior(path, image):
    """``(ExteriorOrientation, crs or None)`` of ``image`` from a CSV or JSON file."""
    from ..collinearity import ExteriorOrientation

    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such exterior file: {path}")
    if path.suffix.lower() == ".json":
        from ..io.results import read_json

        data = read_json(path)
        if isinstance(data, dict) and "images" in data:
            if len(data["images"]) != 1:
                raise ValueError(f"{path}: holds {len(data['images'])} images; give a single-image result")
            data = data["images"][0]
        data = data.get("exterior", data) if isinstance(data, dict) else data
        try:
            return ExteriorOrientation(data["position"], data["angles_rad"], data["convention"]), None
        except (KeyError, TypeError):
            raise ValueError(f"{path}: expected 'position', 'angles_rad' and 'convention' (photax resect --json)") from None
    from ..io.orthority import read_orthority_crs, read_orthority_exterior

    table = read_orthority_exterior(path)
    stem = pathlib.Path(image).stem
    if stem not in table:
        raise ValueError(f"{path}: no orientation for image {stem!r}")
    return table[stem], read_orthority_crs(path)


def run(args: argparse.Namespace) -> int:
    from ..io.atomic import check_output_path
    from ..io.raster import read_dem
    from ..rectification import ortho_grid, orthorectify_file

    inputs = [args.image, args.dem, args.interior, args.exterior]
    check_output_path(args.out, inputs)  # fail before the work, not after
    if args.resolution is not None and not args.resolution > 0:
        raise ValueError(f"--resolution must be positive, got {args.resolution}")
    camera = read_interior(args.interior, args.camera)
    exterior, crs = read_exterior(args.exterior, args.image)
    dem = read_dem(args.dem)
    grid = ortho_grid(exterior, camera, dem, args.resolution)
    if crs is not None:
        import dataclasses

        grid = dataclasses.replace(grid, crs=crs)
    orthorectify_file(
        args.image, args.out, exterior, camera, dem, grid, resampling=args.resampling, tile=args.tile,
        progress=args.progress and args.command,  # one bar, labelled "ortho"
    )
    print(f"wrote {args.out}: {grid.width} x {grid.height} pixels of {abs(grid.transform.a):g} ground units")
    return 0
