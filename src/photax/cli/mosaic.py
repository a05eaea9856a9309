"""``photax mosaic``: join orthophotos into one seamless mosaic (COG).

Two ways in:

* ``photax mosaic A.tif B.tif ... -o mosaic.tif``: orthos on one CRS and
  pixel lattice (e.g. from ``photax ortho --resolution R``);
* ``photax mosaic --block ORIENTATIONS --images DIR --camera CAM --dem DEM
  -o mosaic.tif``: the block workflow, ``photax ortho`` over every image of
  a block straight into the mosaic.  ``ORIENTATIONS`` is a ``photax bundle
  --json`` result (its ``images`` list), a ``photax resect --json`` result
  holding several images, or an orthority exterior CSV (+ ``.prj``); each
  image is the file of ``DIR`` with the same stem.  All orthos share one
  resolution (``--resolution``, default the median ground sampling distance)
  and so one pixel lattice; they are written to a temporary folder beside
  the output, removed at the end.

Then gains and offsets are balanced in the overlaps, seamlines of least
difference cut (kept off raised objects with ``--dsm``), the images
feathered across them and the mosaic written chunk by chunk as a
Cloud-Optimized GeoTIFF, atomically (:func:`photax.io.block_images`,
:func:`photax.rectification.orthorectify_block`, :func:`photax.mosaic_to_raster`: up to 1 GiB of
orthos on NumPy arrays and threads, without importing Dask or xarray; beyond, :func:`photax.mosaic` on
Dask).  Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

import pathlib

from ._common import RESAMPLING, add_grid_options, grid_spec, input_file, input_folder, plural


def add_parser(sub) -> None:
    p = sub.add_parser(
        "mosaic",
        help="join orthophotos, or orthorectify a whole block, into one seamless mosaic (Cloud-Optimized GeoTIFF)",
        description="Balance, cut seamlines of least difference and feather orthophotos into one mosaic. "
        "With --block, orthorectify every image of a block first.",
        epilog="examples:\n  photax mosaic A.tif B.tif -o mosaic.tif\n"
        "  photax mosaic --block bundle.json --images DIR --camera cam.yaml --dem dem.tif -o mosaic.tif\n",
    )
    p.add_argument(
        "orthos",
        nargs="*",
        metavar="ORTHO",
        help="orthophoto GeoTIFFs (one CRS, one pixel lattice, one number of bands: "
        "RGB orthos share one seam, each band gets its own gain)",
    )
    p.add_argument(
        "-o",
        "--out",
        required=True,
        help="output mosaic (Cloud-Optimized GeoTIFF, in the orthos' data type: uint8 orthos "
        "give a uint8 mosaic, rounded, with their nodata)",
    )
    p.add_argument(
        "--method",
        choices=("seamline", "voronoi"),
        default="seamline",
        help="seams of least difference (default) or nearest footprint centre",
    )
    p.add_argument(
        "--dsm", help="surface model raster: seams avoid raised objects (with --dem, or heights above ground)"
    )
    p.add_argument("--dem", help="terrain model raster: subtracted from --dsm; the DEM of --block's orthos")
    p.add_argument(
        "--raised", type=float, default=2.0, metavar="METRES", help="height above ground of a raised object (default 2)"
    )
    p.add_argument("--no-balance", dest="balance", action="store_false", help="no gain/offset balancing")
    p.add_argument("--feather", type=int, default=8, metavar="PX", help="blend half-width across seams (default 8)")
    p.add_argument(
        "--seamlines",
        metavar="PATH",
        help="also write the seamlines as GeoJSON: one polygon per ortho, the area it is the source of",
    )
    p.add_argument(
        "--source-index",
        metavar="PATH",
        help="also write a GeoTIFF of the index (0-based, in the order given; -1 none) of the "
        "ortho each pixel comes from",
    )
    p.add_argument("--chunks", type=int, default=1024, metavar="PX", help="chunk edge (memory ~ chunks^2)")
    b = p.add_argument_group("block workflow (instead of ORTHOs)")
    b.add_argument(
        "--block",
        metavar="ORIENTATIONS",
        help="photax bundle -o or photax resect -o result (JSON), or orthority exterior CSV",
    )
    b.add_argument("--images", metavar="DIR", help="folder of the block's images (matched by file stem)")
    b.add_argument(
        "--camera",
        "--interior",
        dest="camera",
        metavar="CAMERA_FILE",
        help="photax camera file or orthority interior YAML",
    )
    b.add_argument("--camera-name", metavar="NAME", help="camera name in a multi-camera orthority interior file")
    b.add_argument("--resampling", choices=RESAMPLING, default="bilinear", help="interpolation of the grey values "
                   "(also of ORTHOs put on another output grid)")  # fmt: skip
    add_grid_options(
        p,
        resolution_help="ground pixel size: of --block's orthos (default: the median ground sampling distance); "
        "ORTHOs are resampled to it",
        crs_help="the mosaic's CRS (ORTHOs are reprojected to it; a --block's frames are orthorectified in their "
        "orientations' CRS, another one is refused)",
    )
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.set_defaults(func=run, compiles=False)  # but --block does: run() enables the cache then


def run(args) -> int:
    import tempfile

    import numpy as np
    import rasterio

    from ..io.atomic import check_output_path
    from ..mosaicking import heights_on_grid, mosaic_grid, mosaic_to_raster, warp_to_grid
    from ..progress import progress_bar

    if args.chunks < 16:
        raise ValueError(f"--chunks must be at least 16 pixels, got {args.chunks}")
    if args.block:
        if args.orthos:
            raise ValueError("give ORTHO files or --block, not both")
        for opt in ("images", "camera", "dem"):
            if not getattr(args, opt):
                raise ValueError(f"--block needs --{opt}")
        inputs = [
            str(input_file(args.block, "block orientation file")),
            str(input_file(args.camera, "camera file")),
            str(input_file(args.dem, "DEM")),
        ]
        input_folder(args.images, "image folder")
    else:
        if not args.orthos:
            raise ValueError("give the ORTHO files to join, or --block with --images, --camera and --dem")
        if args.camera or args.images:
            raise ValueError("--images and --camera belong to --block")
        inputs = [str(input_file(p, "ortho")) for p in args.orthos]
    for f in (args.dsm, args.dem):
        if f:
            inputs.append(str(input_file(f, "DSM/DEM")))
    spec = grid_spec(args)  # the output grid, gdalwarp's way: --bounds, --resolution, --target-aligned, --size, --like
    asked = spec != type(spec)()  # any grid option given
    outs = [o for o in (args.out, args.seamlines, args.source_index) if o]
    if len({pathlib.Path(o).resolve() for o in outs}) < len(outs):
        raise ValueError("-o, --seamlines and --source-index must be different files")
    for o in outs:
        check_output_path(o, inputs)  # fail before the work, not after
    if args.block:  # only here JAX is imported (a mosaic of orthos needs none: ~0.5 s of start-up)
        from ..grid import check_frame_crs
        from ..io.orientation import block_images, read_interior
        from ..io.raster import read_dem
        from ..rectification import orthorectify_block
        from . import _enable_compilation_cache
        from ._common import check_crs

        _enable_compilation_cache()
        camera, dem = read_interior(args.camera, args.camera_name), read_dem(args.dem)
        images, exteriors, crs = block_images(args.block, args.images, crs=dem.crs)  # lat/lon: the DEM's CRS
        inputs += [str(p) for p in images]
        for o in outs:
            check_output_path(o, inputs)
        check_crs(crs, f"the block's orientations ({args.block})", dem.crs, f"the DEM ({args.dem})")
        check_frame_crs(spec, crs if crs is not None else dem.crs)
        if spec.size is not None and spec.bounds is None:
            raise ValueError("--size with --block needs --bounds (the orthos' resolution comes from them)")
    out_dir = pathlib.Path(args.out).resolve().parent
    # One bar, "mosaic": the block's images, then every tile (or Dask task) of the mosaic and of its writing.
    with (
        tempfile.TemporaryDirectory(dir=out_dir, prefix=".photax-mosaic-") as tmp,
        progress_bar(args.progress and args.command, None, desc="mosaic", unit="step") as bar,
    ):
        if args.block:
            bar.total = (bar.total or 0) + len(images)
            fixed = (
                spec.grid(crs=crs if crs is not None else dem.crs) if spec.fixed else None
            )  # the orthos made on the mosaic's own lattice
            paths = orthorectify_block(
                images,
                exteriors,
                camera,
                dem,
                tmp,
                resolution=None if fixed is not None else spec.resolution,
                grid=fixed,
                crs=crs,
                resampling=args.resampling,
                tile=args.chunks,
                callback=lambda k: bar.update(),
            )
        else:
            paths = list(args.orthos)
        dsm = dem_on_grid = None
        if args.dsm:
            grid = mosaic_grid(paths)
            dsm = heights_on_grid(args.dsm, grid)
            dem_on_grid = heights_on_grid(args.dem, grid) if args.dem else None
        if not paths:
            raise ValueError("no image of the block overlaps the output grid")
        target = None
        if asked:  # the mosaic is made on the orthos' union grid, then put on the grid asked for
            union = mosaic_grid(paths)
            target = spec.grid(union.bounds, (abs(union.transform.a), abs(union.transform.e)), union.crs)
            target = None if target == union else target
        index = pathlib.Path(tmp) / "index.tif"
        info = {}
        # Orthos up to 1 GiB in all are mosaicked in memory without Dask, xarray or rioxarray (their
        # imports were ~0.8 s of a 1.8 s mosaic of the NGI block); larger ones chunk by chunk on Dask's threads.
        mosaic_to_raster(
            [str(p) for p in paths],
            args.out if target is None else pathlib.Path(tmp) / "union.tif",
            method=args.method,
            dsm=dsm,
            dem=dem_on_grid,
            raised=args.raised,
            balance=args.balance,
            feather=args.feather,
            chunks=args.chunks,
            info=info,
            seamlines=args.seamlines,
            source_index=args.source_index if target is None or not args.source_index else index,
            inputs=inputs,
            progress=bar,
        )
        if target is not None:
            warp_to_grid(pathlib.Path(tmp) / "union.tif", args.out, target, resampling=args.resampling,
                         chunks=args.chunks, inputs=inputs)  # fmt: skip
            if args.source_index:
                warp_to_grid(index, args.source_index, target, resampling="nearest", chunks=args.chunks,
                             inputs=inputs, name="source_index")  # fmt: skip
    with rasterio.open(args.out) as ds:
        nb, rows, cols = ds.count, ds.height, ds.width
    gains = ", ".join("/".join(f"{x:.3f}" for x in np.atleast_1d(g)) for g in info["gains"])  # per band: a/b/c
    print(
        f"photax mosaic: {plural(len(paths), 'ortho')} -> {args.out} ({cols} x {rows} px"
        f"{f', {nb} bands' if nb > 1 else ''}; gains {gains})"
    )
    for what, path in (("seamlines", args.seamlines), ("source index", args.source_index)):
        if path:
            print(f"photax mosaic: {what} -> {path}")
    return 0
