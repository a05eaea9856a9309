"""``photax mosaic``: join orthophotos into one seamless mosaic (COG).

Reads the orthos (GeoTIFFs on one CRS and pixel lattice, e.g. from
``photax ortho``), balances gains and offsets in the overlaps, cuts
seamlines of least difference (kept off raised objects with ``--dsm``),
feathers across them and writes a Cloud-Optimized GeoTIFF atomically
(:func:`photax.mosaicking.mosaic`, :func:`photax.tiled.to_raster`).  Exit codes:
0 done, 2 bad input.
"""

from __future__ import annotations


def add_parser(sub) -> None:
    p = sub.add_parser(
        "mosaic",
        help="join orthophotos into one seamless mosaic (Cloud-Optimized GeoTIFF)",
        description="Balance, cut seamlines of least difference and feather orthophotos into one mosaic.",
    )
    p.add_argument("orthos", nargs="+", metavar="ORTHO", help="orthophoto GeoTIFFs (one CRS, one pixel lattice)")
    p.add_argument("-o", "--out", required=True, help="output mosaic (Cloud-Optimized GeoTIFF)")
    p.add_argument("--method", choices=("seamline", "voronoi"), default="seamline",
                   help="seams of least difference (default) or nearest footprint centre")
    p.add_argument("--dsm", help="surface model raster: seams avoid raised objects "
                   "(with --dem, or heights above ground)")
    p.add_argument("--dem", help="terrain model raster, subtracted from --dsm")
    p.add_argument("--raised", type=float, default=2.0, metavar="METRES",
                   help="height above ground of a raised object (default 2)")
    p.add_argument("--no-balance", dest="balance", action="store_false", help="no gain/offset balancing")
    p.add_argument("--feather", type=int, default=8, metavar="PX", help="blend half-width across seams (default 8)")
    p.set_defaults(func=run)


def _read(path):
    import rioxarray

    from ..io.raster import open_raster

    with open_raster(path):  # a clear error for a missing or unreadable file
        pass
    arr = rioxarray.open_rasterio(path, masked=True)
    if arr.sizes.get("band", 1) != 1:
        raise ValueError(f"{path}: {arr.sizes['band']} bands; photax mosaic joins single-band orthos")
    return arr.squeeze("band", drop=True)


def run(args) -> int:
    import numpy as np

    from ..mosaicking import _lattice, mosaic
    from ..rectification._grid import Grid
    from ..tiled import _dataarray, to_raster

    orthos = [_read(p) for p in args.orthos]
    dsm = None
    if args.dsm:
        transform, shape, crs, _ = _lattice(orthos)
        template = _dataarray(np.zeros(shape), Grid(transform, shape, crs), np.asarray(np.nan), "t")
        dsm = _read(args.dsm).rio.reproject_match(template).values
        if args.dem:
            dsm = dsm - _read(args.dem).rio.reproject_match(template).values
    info = {}
    out = mosaic(orthos, method=args.method, dsm=dsm, raised=args.raised, balance=args.balance,
                 feather=args.feather, info=info)
    to_raster(out.astype(np.float32), args.out, cog=True, inputs=[*args.orthos, args.dsm, args.dem])
    gains = ", ".join(f"{g:.3f}" for g in info["gains"])
    print(f"photax mosaic: {len(orthos)} orthos -> {args.out} ({out.shape[1]} x {out.shape[0]} px; gains {gains})")
    return 0
