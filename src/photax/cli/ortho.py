"""``photax ortho``: orthorectify an image with its orientation and a DEM.

``--camera`` (alias ``--interior``) is a photax camera file (YAML/JSON,
:mod:`photax.io.camera_file`) or an orthority interior YAML
(``--camera-name`` picks a camera of a multi-camera file); ``--exterior`` a
``photax resect --json`` result (the image named like IMAGE's stem when it
holds several) or an orthority exterior CSV (+ .prj beside it).  The output
GeoTIFF is written tile by tile into a temporary file renamed at the end; it
may not be an input or an input's sidecar.  Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

import argparse
import pathlib

RESAMPLING = ("nearest", "bilinear", "cubic", "lanczos", "bspline")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "ortho",
        help="orthorectify an image with a DEM (collinearity equations)",
        description="Orthorectify IMAGE: every ground pixel gets its height from the DEM and its grey value "
        "from the image position given by the collinearity equations. Occlusions are not detected.",
    )
    p.add_argument("image", metavar="IMAGE", help="the image (any GDAL raster)")
    p.add_argument("--dem", required=True, help="DEM raster in the ground CRS of the orientation")
    p.add_argument("--camera", "--interior", dest="camera", required=True, metavar="CAMERA_FILE",
                   help="photax camera file (see photax resect --help), or orthority interior YAML "
                   "(--interior is an alias)")  # fmt: skip
    p.add_argument("--exterior", required=True,
                   help="photax resect --json result (the image named like IMAGE when it holds several), "
                   "or orthority exterior CSV")  # fmt: skip
    p.add_argument("--out", required=True, help="output GeoTIFF")
    p.add_argument("--resolution", type=float, help="ground pixel size (default: the mean ground sampling distance)")
    p.add_argument("--resampling", choices=RESAMPLING, default="bilinear")
    p.add_argument("--camera-name", metavar="NAME", help="camera name in a multi-camera orthority interior file")
    p.add_argument("--tile", type=int, default=1024, help="output tile size in pixels (memory ~ tile^2)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.set_defaults(func=run)


def read_interior(path, name: str | None = None):
    """A FrameCamera from a photax camera file or an orthority interior YAML."""
    import yaml

    from ._common import input_file

    path = input_file(path, "camera file")
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
            raise ValueError(f"{path}: give --camera-name, one of {sorted(map(str, cameras))}")
        return cameras[name]
    from ..io.camera_file import read_camera

    return read_camera(path)


def _pick_image(path, images, image) -> dict:
    """The entry of a ``photax resect --json`` ``images`` mapping for ``image``."""
    if isinstance(images, list):  # a batch result: no names to match
        images = {str(k): v for k, v in enumerate(images)}
    if not isinstance(images, dict) or not images:
        raise ValueError(f"{path}: 'images' holds no image results")
    if len(images) == 1:
        name, entry = next(iter(images.items()))
    else:
        p = pathlib.Path(image)
        matches = [n for n in images if n in (p.name, p.stem) or pathlib.Path(n).stem == p.stem]
        if len(matches) != 1:
            raise ValueError(f"{path}: holds {len(images)} images {sorted(images)}, none named like "
                             f"{p.name!r}; rename the image or keep only its result")
        name, entry = matches[0], images[matches[0]]
    if not isinstance(entry, dict):
        raise ValueError(f"{path}: the result of image {name!r} is not an object")
    status = entry.get("status", "solved" if entry.get("converged", True) else "not converged")
    if status != "solved" or "skipped" in entry:
        why = entry.get("message") or entry.get("skipped") or status
        raise ValueError(f"{path}: image {name!r} was not solved ({why}); no orientation to use")
    return entry


def read_exterior(path, image):
    """``(ExteriorOrientation, crs or None)`` of ``image`` from a CSV or JSON file.

    A ``photax resect --json`` file holds ``images`` keyed by image name:
    with one image it is used whatever its name; with several, the one
    named like ``image`` (file name or stem).
    """
    from ..collinearity import ExteriorOrientation
    from ._common import input_file

    path = input_file(path, "exterior file")
    if path.suffix.lower() == ".json":
        from ..io.results import read_json

        data = read_json(path)
        crs = data.get("crs") if isinstance(data, dict) else None
        if isinstance(data, dict) and "images" in data:
            data = _pick_image(path, data["images"], image)
        data = data.get("exterior", data) if isinstance(data, dict) else data
        try:
            return ExteriorOrientation(data["position"], data["angles_rad"], data["convention"]), crs
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
    from ._common import ground_unit, input_file
    from ..io.raster import read_dem
    from ..rectify import ortho_grid, orthorectify_file

    image = input_file(args.image, "image")
    input_file(args.dem, "DEM")
    inputs = [args.image, args.dem, args.camera, args.exterior]
    check_output_path(args.out, inputs)  # fail before the work, not after
    if args.resolution is not None and not args.resolution > 0:
        raise ValueError(f"--resolution must be positive, got {args.resolution}")
    camera = read_interior(args.camera, args.camera_name)
    exterior, crs = read_exterior(args.exterior, args.image)
    dem = read_dem(args.dem)
    grid = ortho_grid(exterior, camera, dem, args.resolution)
    if crs is not None:
        import dataclasses

        grid = dataclasses.replace(grid, crs=crs)
    orthorectify_file(
        image, args.out, exterior, camera, dem, grid, resampling=args.resampling, tile=args.tile,
        progress=args.progress and args.command,  # one bar, labelled "ortho"
    )
    print(f"wrote {args.out}: {grid.width} x {grid.height} pixels of {abs(grid.transform.a):g} "
          f"{ground_unit(grid.crs)}")
    return 0
