"""``photax ortho``: orthorectify images with their orientations and a DEM (or flat ground, ``--height``).

``--camera`` (alias ``--interior``) is a photax camera file (YAML/JSON,
:mod:`photax.io.camera_file`), an orthority interior YAML or an OpenSfM/ODM
``reconstruction.json`` (``--camera-name`` picks a camera of a multi-camera file); ``--exterior`` a
``photax resect -o`` or ``photax bundle -o`` result (the image named
like IMAGE's stem when it holds several), an orthority exterior CSV (+ .prj beside it) or GeoJSON,
or a ``reconstruction.json``: the formats
are told apart by :mod:`photax.io.orientation`.  The output
GeoTIFF is written tile by tile into a temporary file renamed at the end; it
may not be an input or an input's sidecar.  Several images (``--out-dir DIR``) run in one process
under one progress bar (:func:`photax.orthorectify_files`): each ortho is ``DIR/STEM_ortho.tif``,
bit for bit what the command writes for that image alone; the orientation file is parsed once.
Exit codes: 0 done, 1 some image failed (named on stderr; the others are written), 2 bad input.

The output grid is gdalwarp's (docs/output-grid.md): ``--bounds`` (``-te``), ``--resolution``
(``-tr``), ``--target-aligned`` (``-tap``), ``--size`` (``-ts``), ``--like RASTER``, ``--crs``
(``-t_srs``; a frame image's ortho stays in its orientation's CRS: another one is refused with
:class:`photax.errors.OutputCRSError`).  Without ``--bounds`` the grid covers the footprint, target aligned.

A satellite image with an RPC (``--camera rpc``: the RPC in IMAGE's metadata or side files, as GDAL
reads them; or ``--camera`` any RPC file, recognised by content: DIMAP, Maxar ISD XML, ``KEY: value`` text,
``.RPB``, orthority's ``rpc_param.yaml``, rpcm/s2p JSON; ``docs/formats.md``) needs no
``--exterior``: the ortho is made in ``--crs`` (default the UTM zone of the scene), optionally after
refining the RPC on ``--gcps`` (``--refine``, :func:`photax.rpc.refine_rpc`, whose report is
printed). The DEM's heights must be ellipsoidal (a warning says when its CRS does not say so).
A push-broom image (``--camera`` a photax push-broom camera file, :mod:`photax.io.pushbroom_file`) is
made like an RPC one (no ``--gcps``: its orbit and attitude are adjusted by
:func:`photax.resect_pushbroom`); ``photax rpc`` fits and writes an RPC to it.
Several satellite images (``--out-dir``) run like a frame block, through the same code, each with its
own RPC (``--camera rpc``: each image's; a ``rpc_param.yaml``: each image's entry by file name; one
``.RPB`` for several images is refused); with ``--gcps`` each image is refined on the GCPs the file
says were measured in it (GCPs naming no image are refused: a pixel position belongs to one image),
all before any ortho, so that a GCP problem is a usage error (exit 2) naming the image.
"""

from __future__ import annotations

import argparse
import math

from ._common import NODATA_HELP, RESAMPLING, add_grid_options, grid_spec, nodata_value, output_folder, start_gc


def add_parser(sub) -> None:
    p = sub.add_parser(
        "ortho",
        help="orthorectify an image with a DEM or on flat ground (collinearity equations)",
        description="Orthorectify IMAGE (or every IMAGE, into --out-dir): every ground pixel gets its "
        "height from the DEM (or --height) and "
        "its grey value from the image position given by the collinearity equations. Occlusions are not "
        "detected.",
        epilog="examples:\n  photax ortho data/sample_image.tif --dem data/sample_dem.tif "
        "--camera data/sample_camera.yaml --exterior resect.json -o ortho.tif\n"
        "  photax ortho ngi/*.tif --dem dem.tif --camera cam.yaml --exterior ext.csv --out-dir orthos  "
        "# a block, one process\n"
        "  photax ortho IMAGE.tif --height 120 --camera cam.yaml --exterior resect.json -o ortho.tif  "
        "# flat ground at Z = 120\n"
        "  photax ortho DJI_0001.JPG --dem dsm.tif --camera cam.yaml --exterior exif -o ortho.tif  "
        "# position and gimbal angles from the image's EXIF/XMP\n"
        "  photax ortho qb2_basic1b.tif --camera rpc --dem dem.tif --crs EPSG:32735 --resolution 5 "
        "--gcps gcps.geojson --refine shift -o o.tif  # a satellite image's own RPC, refined on GCPs\n"
        "  photax ortho a.tif b.tif --camera rpc --dem dem.tif --crs EPSG:32735 --out-dir orthos  "
        "# several satellite images, each with its own RPC\n",
    )
    p.add_argument("image", metavar="IMAGE", nargs="+", help="the image(s) (any GDAL raster)")
    ground = p.add_mutually_exclusive_group(required=True)
    ground.add_argument("--dem", help="DEM raster in the ground CRS of the orientation")
    ground.add_argument(
        "--height",
        type=float,
        metavar="H",
        help="flat ground at height H instead of a DEM (a constant-height DEM under the image)",
    )
    p.add_argument("--camera", "--interior", dest="camera", required=True, metavar="CAMERA_FILE",
                   help="photax camera file (see photax resect --help), orthority interior YAML, "
                   "OpenSfM/ODM reconstruction.json or ODM cameras.json, or exif: the camera the image's "
                   "tags describe (DJI DewarpData, else EXIF focal length), as orthority reads it "
                   "(--interior is an alias); or an RPC: 'rpc' (the one in IMAGE's metadata) or any RPC file "
                   "(DIMAP, Maxar XML, KEY: value text, .RPB, orthority rpc_param.yaml, rpcm/s2p JSON; read "
                   "by content); or a photax push-broom camera file (type: "
                   "pushbroom)")  # fmt: skip
    p.add_argument("--exterior",
                   help="photax resect or bundle -o result (the image named like IMAGE when it holds "
                   "several), "
                   "orthority exterior CSV (x y z omega phi kappa, or latitude longitude altitude roll pitch "
                   "yaw) or GeoJSON, OpenSfM/ODM reconstruction.json, or exif: each image's GPS and DJI "
                   "gimbal angles (exif:flight: the airframe's, for a camera fixed to it looking down); "
                   "required, except with an RPC")  # fmt: skip
    out = p.add_mutually_exclusive_group(required=True)
    out.add_argument("-o", "--out", metavar="OUT_TIF", help="output GeoTIFF (one IMAGE)")
    out.add_argument("--out-dir", metavar="DIR", help="output folder: DIR/STEM_ortho.tif for each IMAGE")
    add_grid_options(
        p,
        resolution_help="ground pixel size (gdalwarp -tr; default: the mean ground sampling distance)",
        crs_help="output CRS (EPSG code, PROJ or WKT): for an RPC or push-broom image any (default the WGS84 UTM "
        "zone of the scene); a frame image's ortho is in its orientation's CRS (another one is refused: reproject "
        "the ortho afterwards)",
    )
    p.add_argument(
        "--resampling",
        choices=RESAMPLING,
        default=None,
        help="resampling kernel (default: bilinear; nearest for a palette image, which takes no other)",
    )
    p.add_argument("--camera-name", metavar="NAME", help="camera name in a multi-camera orthority interior file")
    p.add_argument("--nodata", type=nodata_value, metavar="VALUE", help=NODATA_HELP)
    p.add_argument("--tile", type=int, default=1024, help="output tile size in pixels (memory ~ tile^2)")
    p.add_argument(
        "--export-params",
        metavar="DIR",
        help="also write the interior and exterior orientations used as orthority files: DIR/int_param.yaml, "
        "DIR/ext_param.csv (+ .prj) and, with a CRS, DIR/ext_param.geojson (oty ortho reads them); RPC images: "
        "their raw RPCs as DIR/rpc_param.yaml (oty rpc --rpc-file)",
    )
    p.add_argument("--gcps", metavar="GCP_FILE", help="RPC camera only: GCPs to refine the RPC with (any "
                   "format photax reads: orthority GeoJSON, CSV, ODM; those of IMAGE, or without an image name for one "
                   "IMAGE; with several, each refined on its own)")  # fmt: skip
    p.add_argument("--refine", choices=("shift", "shift-drift", "affine"), default=None,
                   help="with --gcps: the image-space correction refined (default: shift; at least 1, 2, 3 GCPs)")  # fmt: skip
    p.add_argument("--occlusion", choices=("mark",), default=None,
                   help="with --dem a DSM (buildings, trees): cells it hides from the camera are nodata (a z-buffer: "
                   "a true ortho without ghosts; one frame IMAGE, docs/true-ortho.md)")  # fmt: skip
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.set_defaults(func=run, starts_gc=True)  # start_gc() once the inputs are read


def run(args: argparse.Namespace) -> int:
    if getattr(args, "occlusion", None) is not None and (
        args.dem is None or _is_ground(args.camera) or args.out_dir is not None or len(args.image) > 1
    ):
        # The z-buffer needs a surface model; the streamed RPC and --out-dir paths do not take it yet.
        raise ValueError("--occlusion mark: one frame IMAGE with -o and a --dem (a DSM) only")
    if _is_ground(args.camera):
        start_gc()  # refining RPCs traces JAX functions: their cyclic garbage is collected
        return _run_ground(args)
    import os

    from ..io.satellite import families

    # a camera file that is not an RPC: say so, with what photax recognises as one
    rpc = f"; {args.camera} is no RPC file photax reads ({families()})" if os.path.isfile(args.camera) else ""
    rpc_only = [o for o, v in (("--gcps", args.gcps), ("--refine", args.refine)) if v is not None]
    if rpc_only:
        raise ValueError(f"{', '.join(rpc_only)}: for an RPC camera only{rpc}")
    if args.exterior is None:
        raise ValueError(
            f"--exterior is required with a frame camera (only an RPC camera carries its orientation{rpc})"
        )
    if args.out_dir is not None:
        return _run_block(args)
    if len(args.image) > 1:
        raise ValueError(f"-o/--out names one output for {len(args.image)} images: give --out-dir DIR")
    args.image = args.image[0]
    return _run_one(args)


def _check_inputs(args: argparse.Namespace) -> None:
    """The shared inputs exist and the numbers make sense: before any work."""
    from ._common import input_file

    if args.dem is not None:
        input_file(args.dem, "DEM")
    elif not math.isfinite(args.height):
        raise ValueError(f"--height must be a finite number, got {args.height}")
    from ..io.orientation import exif_attitude

    if args.camera != "exif":
        input_file(args.camera, "camera file")
    if exif_attitude(args.exterior) is None:
        input_file(args.exterior, "exterior file")
    if args.resolution is not None and not args.resolution > 0:
        raise ValueError(f"--resolution must be positive, got {args.resolution}")


def _run_one(args: argparse.Namespace) -> int:
    import pathlib

    from ..grid import ortho_grid
    from ..io.atomic import check_output_path
    from ..io.orientation import read_exterior
    from ..io.raster import read_dem
    from ..rectification import orthorectify_file
    from ._common import check_crs, ground_unit, input_file

    image = input_file(args.image, "image")
    _check_inputs(args)
    inputs = [p for p in (args.image, args.dem, args.camera, args.exterior) if p is not None]
    check_output_path(args.out, inputs)  # fail before the work, not after
    camera = _read_camera(args, [args.image])
    dem = read_dem(args.dem) if args.dem is not None else None
    # positions given in latitude/longitude or a topocentric frame go into the DEM's CRS
    exterior, crs = read_exterior(args.exterior, args.image, crs=dem.crs if dem is not None else None)
    dem = dem if dem is not None else _flat_dem(args.height, exterior)
    if args.dem is not None:
        check_crs(crs, f"the orientation ({args.exterior})", dem.crs, f"the DEM ({args.dem})")
    grid = ortho_grid(exterior, camera, dem, crs=crs, spec=grid_spec(args))
    _export_params(args, camera, {pathlib.Path(args.image).name: exterior}, crs)
    start_gc()
    orthorectify_file(
        image,
        args.out,
        exterior,
        camera,
        dem,
        grid,
        resampling=args.resampling,
        nodata=args.nodata,
        tile=args.tile,
        progress=args.progress and args.command,  # one bar, labelled "ortho"
        occlusion=getattr(args, "occlusion", None),
    )
    print(f"wrote {args.out}: {grid.width} x {grid.height} pixels of {abs(grid.transform.a):g} {ground_unit(grid.crs)}")
    return 0


def _run_block(args: argparse.Namespace) -> int:
    """Every IMAGE into --out-dir, in one process: a failed image is named, the others written (exit 1)."""
    import pathlib

    from ..grid import check_frame_crs
    from ..io.orientation import read_exterior, read_exteriors
    from ..io.raster import read_dem
    from ..rectification import orthorectify_files
    from ._common import check_crs, input_file

    _check_inputs(args)
    spec = grid_spec(args)
    outputs = _block_outputs(args, [args.dem, args.camera, args.exterior])
    camera = _read_camera(args, args.image)
    dem = read_dem(args.dem) if args.dem is not None else None
    dem_crs = dem.crs if dem is not None else None  # positions in latitude/longitude go into the DEM's CRS
    failed = {}
    try:  # the file parsed once
        table, crs = read_exteriors(args.exterior, args.image, crs=dem_crs)
    except ValueError:  # some image has no orientation there: each image found (or named) on its own
        table, crs = {}, None
        for image in args.image:
            try:
                table[image], crs = read_exterior(args.exterior, image, crs=dem_crs)
            except ValueError as exc:
                failed[image] = exc
    for image in args.image:
        if image not in failed:
            try:
                input_file(image, "image")
            except ValueError as exc:
                failed[image] = exc
    todo = [k for k, image in enumerate(args.image) if image not in failed]
    exteriors = [table[args.image[k]] for k in todo]
    if dem is not None:
        check_crs(crs, f"the orientations ({args.exterior})", dem.crs, f"the DEM ({args.dem})")
    check_frame_crs(spec, crs if crs is not None or dem is None else dem.crs)  # a usage error, not each image's
    if dem is None:
        dem = _flat_dem(args.height, exteriors) if exteriors else None
    if exteriors:
        _export_params(args, camera, {pathlib.Path(args.image[k]).name: table[args.image[k]] for k in todo}, crs)
    start_gc()
    results = (
        orthorectify_files(
            [args.image[k] for k in todo],
            [outputs[k] for k in todo],
            exteriors,
            camera,
            dem,
            crs=crs,
            resampling=args.resampling,
            nodata=args.nodata,
            tile=args.tile,
            progress=args.progress and args.command,
            spec=spec,
        )
        if todo
        else []
    )
    return _block_report(args, outputs, todo, results, failed)


def _block_outputs(args: argparse.Namespace, inputs: list) -> list:
    """``DIR/STEM_ortho.tif`` of every IMAGE, checked before any work: two images of one name, or an
    output that would overwrite an image or one of ``inputs``, are refused."""
    import pathlib

    from ..io.atomic import check_output_path, output_name

    folder = output_folder(args.out_dir, "--out-dir")
    outputs = [folder / f"{output_name(pathlib.Path(i).stem, 'image name')}_ortho.tif" for i in args.image]
    seen = {}
    for image, out in zip(args.image, outputs):
        if out in seen:
            raise ValueError(f"images {seen[out]} and {image} would both be written to {out}: same name")
        seen[out] = image
    inputs = [*args.image, *(p for p in inputs if p is not None)]
    for out in outputs:
        check_output_path(out, inputs)  # fail before the work, not after
    return outputs


def _block_report(args: argparse.Namespace, outputs: list, todo: list, results: list, failed: dict) -> int:
    """Each ortho written (``results`` of the images ``todo``: a grid or an exception) and each image
    failed, named on stderr: exit 1 if any failed (the others are written), else 0."""
    import sys

    from ._common import ground_unit

    for k, grid in zip(todo, results):
        if isinstance(grid, Exception):
            failed[args.image[k]] = grid
        else:
            print(
                f"wrote {outputs[k]}: {grid.width} x {grid.height} pixels of {abs(grid.transform.a):g} "
                f"{ground_unit(grid.crs)}"
            )
    for image in args.image:
        if image in failed:
            print(f"{args.command}: {image} failed: {failed[image]}", file=sys.stderr)
    if failed:
        print(
            f"{args.command}: {len(failed)} of {len(args.image)} images failed; the others are written", file=sys.stderr
        )
        return 1
    return 0


def _read_camera(args: argparse.Namespace, images: list):
    """``--camera``: a file, or ``exif``: the camera the images' tags describe (DJI
    DewarpData, else EXIF focal length; :func:`photax.io.exif.camera_from_tags`), the
    same for every image."""
    import numpy as np

    from ..io.orientation import read_interior

    if args.camera != "exif":
        return read_interior(args.camera, args.camera_name)
    from ..io.exif import camera_from_tags, read_drone_tags

    cameras = [camera_from_tags(read_drone_tags(image)) for image in images]
    fields = ("focal_length", "principal_point", "distortion", "pixel_size")
    for image, cam in zip(images[1:], cameras[1:]):
        same = cam.image_size == cameras[0].image_size and all(
            np.array_equal(np.asarray(getattr(cam, f)), np.asarray(getattr(cameras[0], f))) for f in fields
        )
        if not same:
            raise ValueError(f"--camera exif: {image} has another camera than {images[0]}: orthorectify them apart")
    return cameras[0]


def _export_params(args: argparse.Namespace, camera, exteriors: dict, crs) -> None:
    """``--export-params DIR``: the orientations used, as orthority's files (before the orthos)."""

    from ..io.orthority import write_orthority_exterior, write_orthority_geojson, write_orthority_interior

    if args.export_params is None:
        return
    folder = output_folder(args.export_params, "--export-params")
    inputs = [*(args.image if isinstance(args.image, list) else [args.image]), args.camera, args.exterior]
    inputs += [args.dem] if args.dem is not None else []
    name = args.camera_name or "photax_camera"
    write_orthority_interior(folder / "int_param.yaml", {name: camera}, inputs=inputs)
    write_orthority_exterior(folder / "ext_param.csv", exteriors, crs, inputs=inputs)
    if crs is not None:
        write_orthority_geojson(folder / "ext_param.geojson", exteriors, crs, camera=name, inputs=inputs)
    print(f"wrote {folder}/int_param.yaml, ext_param.csv{' and ext_param.geojson' if crs is not None else ''}")


def _export_rpcs(args: argparse.Namespace, cameras: dict, inputs: list) -> None:
    """``--export-params DIR`` for RPC images: their RPCs as orthority's ``rpc_param.yaml`` (``oty rpc
    --rpc-file``), before the orthos."""
    import pathlib

    from ..io.orthority import write_orthority_rpc

    folder = output_folder(args.export_params, "--export-params")
    if cameras:
        named = {pathlib.Path(image).name: camera for image, camera in cameras.items()}
        written = write_orthority_rpc(folder / "rpc_param.yaml", named, inputs=[*args.image, *inputs])
        print(f"wrote {written}")


def _flat_dem(height: float, exterior):
    """``--height``: a constant-height DEM under the camera (a list: under every camera), valid
    within 1000 flying heights of its nadir (a ray reaching the ground farther out is within
    0.06 degrees of the horizon); ortho_grid cuts the grid down to the image's footprint."""
    import numpy as np

    from ..dem import DEM

    boxes = []
    for e in exterior if isinstance(exterior, list) else [exterior]:
        x, y, z = np.asarray(e.position, dtype=float)
        r = 1e3 * max(abs(z - height), 1.0)
        boxes.append((x - r, y - r, x + r, y + r))
    b = np.array(boxes)
    return DEM.flat(height, (*b[:, :2].min(axis=0), *b[:, 2:].max(axis=0)))


def _is_ground(camera: str) -> bool:
    """``--camera rpc``, a file of any RPC family photax reads (by content:
    :data:`photax.io.satellite.FORMATS`), or a photax push-broom camera file: a camera that carries its
    own orientation."""
    import pathlib

    from ..errors import UnsupportedFormatError
    from ..io.pushbroom_file import is_pushbroom_file
    from ..io.satellite import rpc_format

    path = pathlib.Path(camera)
    if camera == "rpc" or is_pushbroom_file(path):
        return True
    if not path.is_file():
        return False  # the frame readers say what is wrong with it
    try:
        rpc_format(path)
    except (UnsupportedFormatError, OSError, ValueError):
        return False  # not an RPC file: a frame camera file, whose readers say what is wrong with it
    return True


def _run_ground(args: argparse.Namespace) -> int:
    """Satellite images, each with its own RPC (refined on --gcps when given) or push-broom camera: one
    into -o/--out, or several into --out-dir, by the frame block's code (:func:`photax.orthorectify_files`, one bar, a
    failed image named and the others written, exit 1)."""
    import sys
    import warnings

    from ..io.atomic import check_output_path
    from ..io.pushbroom_file import is_pushbroom_file
    from ..io.raster import read_dem
    from ..io.satellite import rpc_images
    from ..rectification import orthorectify_files
    from ._common import ground_unit, input_file

    if args.exterior is not None:
        raise ValueError("--exterior: an RPC or push-broom camera carries its own orientation; leave --exterior out")
    if args.refine is not None and args.gcps is None:
        raise ValueError("--refine needs --gcps (the GCPs to refine the RPC on)")
    if args.out_dir is None and len(args.image) > 1:
        raise ValueError(f"-o/--out names one output for {len(args.image)} images: give --out-dir DIR")
    if args.dem is not None:
        input_file(args.dem, "DEM")
    elif not math.isfinite(args.height):
        raise ValueError(f"--height must be a finite number, got {args.height}")
    spec = grid_spec(args)
    crs = spec.like.crs if spec.like is not None else args.crs
    source = None if args.camera == "rpc" else input_file(args.camera, "camera file")
    pushbroom = source is not None and is_pushbroom_file(source)
    if args.export_params is not None and (pushbroom or args.gcps is not None):
        raise ValueError(
            "--export-params: orthority's rpc_param.yaml holds a raw RPC, not a "
            + ("push-broom camera (photax rpc fits and writes one)" if pushbroom else "refined one (--gcps)")
        )
    if pushbroom and args.gcps is not None:
        raise ValueError(
            "--gcps: refines an RPC; a push-broom model's orbit and attitude are adjusted on GCPs by "
            "photax.resect_pushbroom (Python), whose camera write_pushbroom writes for --camera"
        )
    if source is not None and len(args.image) > 1 and (pushbroom or rpc_images(source) is None):
        raise ValueError(
            f"--camera {source}: one {'push-broom camera' if pushbroom else 'RPC'} for {len(args.image)} images; "
            "give each image its own (--camera rpc: the RPC in each image or in the .RPB / _RPC.TXT beside it; "
            "or a file naming every image: orthority's rpc_param.yaml, s2p's config.json)"
        )
    inputs = [args.dem, source, args.gcps]
    if args.out_dir is not None:
        outputs = _block_outputs(args, inputs)
    else:
        outputs = [args.out]
        check_output_path(args.out, [*args.image, *(p for p in inputs if p is not None)])
    single = args.out_dir is None
    failed, cameras = {}, {}
    for image in args.image:  # each image's own RPC; in a block a bad one fails that image only
        try:
            cameras[image] = _image_camera(source, input_file(image, "image"), len(args.image) > 1, pushbroom)
        except (ValueError, OSError) as exc:
            if single:
                raise
            failed[image] = exc
    todo = [k for k, image in enumerate(args.image) if image in cameras]
    if args.export_params is not None:
        _export_rpcs(args, cameras, inputs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if args.gcps is not None:  # every refinement before any ortho: a bad GCP file is a usage error
            for image in cameras:
                try:
                    cameras[image] = _refine(cameras[image], args.gcps, image, args.refine or "shift", not single)
                except ValueError as exc:
                    if single:
                        raise
                    raise _about(exc, image) from None
        cams = [cameras[args.image[k]] for k in todo]
        dem = read_dem(args.dem) if args.dem is not None else [_flat_ground(args.height, c, crs) for c in cams]
        results = orthorectify_files(
            [args.image[k] for k in todo],
            [outputs[k] for k in todo],
            None,
            cams,
            dem,
            spec=spec,
            crs=crs,
            resampling=args.resampling,
            nodata=args.nodata,
            tile=args.tile,
            progress=args.progress and args.command,
        )
    for w in dict.fromkeys(str(w.message) for w in caught):
        print(f"{args.command}: warning: {w}", file=sys.stderr)
    if not single:
        return _block_report(args, outputs, todo, results, failed)
    grid = results[0]
    if isinstance(grid, Exception):
        raise grid
    print(f"wrote {args.out}: {grid.width} x {grid.height} pixels of {abs(grid.transform.a):g} {ground_unit(grid.crs)}")
    return 0


def _about(exc: ValueError, image) -> ValueError:
    """``exc`` with ``IMAGE: `` before its message, of the same type where that type takes one message
    (so that the exit status, chosen by type, is the same for one image of a block as for a lone one)."""
    try:
        return type(exc)(f"{image}: {exc}")
    except TypeError:  # a type with another signature: a plain ValueError
        return ValueError(f"{image}: {exc}")


def _image_camera(source, image, several: bool, pushbroom: bool):
    """IMAGE's camera: a push-broom camera file (``pushbroom``); or its RPC: from the image (``source``
    None: its metadata or the side files GDAL reads), its entry of a file of one RPC per image
    (orthority's ``rpc_param.yaml``, s2p's ``config.json``: by file name; a one-entry file named
    otherwise for a lone image), or any other RPC file (by content, :func:`photax.io.satellite.read_rpc`);
    its image size the image's where the file has none."""
    from ..io.pushbroom_file import read_pushbroom
    from ..io.raster import open_raster
    from ..io.satellite import read_rpc, rpc_images

    if pushbroom:
        return read_pushbroom(source)
    if source is None:
        camera = read_rpc(image)
    else:
        names = rpc_images(source)
        if names is None:
            camera = read_rpc(source)
        elif image.name in names or several or len(names) != 1:
            camera = read_rpc(source, image.name)
        else:
            camera = read_rpc(source)  # a file of one entry named otherwise
    if camera.image_size is None:
        with open_raster(image) as src:
            size = (src.width, src.height)
        camera = camera.replace(image_size=size)
    return camera


def _flat_ground(height: float, camera, crs):
    """``--height`` under a ground camera: flat ground over its validity box, in the output CRS
    (``crs``, default the UTM zone of its scene, as :func:`photax.ortho_grid` takes it)."""
    from ..dem import DEM
    from ..geo import utm_crs
    from ..sensor import GroundSensor

    crs = crs if crs is not None else utm_crs(*(float(v) for v in camera.ground_box()[0]))
    dem = DEM.flat(height, GroundSensor(camera, crs).box())
    return DEM(dem.heights, dem.transform, crs=crs)


def _refine(camera, gcp_path, image, model: str, several: bool = False):
    """The RPC refined on the control points of ``gcp_path`` measured in ``image`` (by file name; for a
    lone image also those without an image name: several images cannot share pixel positions); its
    report printed; check points, when the file marks some, reported apart."""
    import pathlib

    import numpy as np
    import pyproj

    from ..io.gcp import read_gcps
    from ..rpc import refine_rpc
    from ._common import input_file

    image_name = pathlib.Path(image).name
    table = read_gcps(input_file(gcp_path, "GCP file"))
    if several and (table.images == "").any():
        raise ValueError(
            f"{gcp_path}: {int((table.images == '').sum())} GCPs name no image; with several images each GCP's "
            "pixel position must say which image it was measured in"
        )
    if table.pixel is None:
        raise ValueError(f"{gcp_path}: gives image-plane coordinates; an RPC needs pixel positions")
    mine = np.isin(table.images, [image_name, ""])
    if not mine.any():
        raise ValueError(f"{gcp_path}: no GCP measured in {image_name} (it names {', '.join(table.image_names)})")
    ground = table.ground[mine].copy()
    if not np.all(np.isfinite(ground)):
        raise ValueError(f"{gcp_path}: GCPs without a height; the RPC needs lon, lat and height")
    if table.crs is not None:  # the reader projects lon, lat to a map CRS: back to lon, lat
        t = pyproj.Transformer.from_crs(table.crs, "EPSG:4326", always_xy=True)
        ground[:, 0], ground[:, 1] = t.transform(ground[:, 0], ground[:, 1])
    names, pixel, check = table.names[mine], table.pixel[mine], table.check[mine]
    res = refine_rpc(camera, ground[~check], pixel[~check], model, names=names[~check])
    if several:
        print(f"{image_name}:")
    print(res.report())
    if check.any():
        v = np.asarray(res.camera(ground[check])) - pixel[check]  # computed - observed
        rmse = float(np.sqrt(np.mean(np.sum(v**2, axis=1))))
        print(f"check points: {int(check.sum())}, RMSE {rmse:.3f} px")
    return res.camera
