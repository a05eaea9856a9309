"""``photax sharpen``: pan-sharpen a multispectral image with a panchromatic one.

The output is on the PAN grid (cropped to what the MS covers), in the MS dtype: integers rounded and
clipped to their range (the count of clipped values is printed).  An image without georeference (no CRS,
identity transform) is taken to cover the other's bounds, as orthority does.  ``--assess`` prints the
quality table: Wald's protocol (the pair reduced by the size ratio, fused, compared with the MS) and QNR of
the output.  ``--chunks PX`` (automatic for a PAN over 2**27 pixels) runs
:func:`photax.fusion.pansharpen_dask` instead: the statistics streamed over the PAN, the output computed and
written chunk by chunk (:func:`photax.to_raster`), so the PAN and the output are never held in memory.
Exit codes: 0 done, 2 bad input.
"""

from __future__ import annotations

from ._common import RESAMPLING, input_file, plural

AUTO_CHUNKS = 1 << 27  # PAN pixels above which the command runs chunk by chunk (1024-pixel chunks)
METHODS = ("brovey", "ihs", "pca", "gs", "gsa", "hpf", "sfim", "mtf_glp", "mtf_glp_hpm")  # = fusion.METHODS


def add_parser(sub) -> None:
    p = sub.add_parser(
        "sharpen",
        help="pan-sharpen a multispectral image (component substitution or multiresolution analysis)",
        description="Bring a multispectral image to the resolution of a panchromatic one: Brovey, IHS, PCA, "
        "Gram-Schmidt, GSA, HPF, SFIM, MTF-GLP, MTF-GLP-HPM.",
        epilog="examples:\n  photax sharpen pan.tif ms.tif -o sharp.tif\n"
        "  photax sharpen pan.tif ms.tif -o sharp.tif --method mtf_glp --nyquist-gain 0.3 --assess\n"
        "  photax sharpen pan.tif ms.tif -o sharp.tif --chunks 1024   # larger than memory, on Dask\n",
    )
    p.add_argument("pan", metavar="PAN", help="panchromatic raster")
    p.add_argument("ms", metavar="MS", help="multispectral raster (larger pixels; any CRS and extent)")
    p.add_argument("-o", "--out", required=True, help="output GeoTIFF, on the PAN grid")
    p.add_argument("--method", choices=METHODS, default="gs", help="pan-sharpening method")
    p.add_argument(
        "--weights",
        type=float,
        nargs="+",
        metavar="W",
        help="band weights of the intensity (brovey, ihs, gs), one per MS band (default: estimated from the images)",
    )
    p.add_argument("--equal-weights", action="store_true", help="equal band weights (the textbook IHS, Brovey)")
    p.add_argument(
        "--resampling", choices=RESAMPLING, default="cubic", help="interpolation of the MS onto the PAN grid"
    )
    p.add_argument(
        "--nyquist-gain",
        type=float,
        nargs="+",
        default=[0.3],
        metavar="G",
        help="MS sensor MTF at Nyquist, one value or one per band (gsa, mtf_glp, mtf_glp_hpm; default 0.3)",
    )
    p.add_argument("--pan-band", type=int, default=1, help="band of PAN to use (1-based)")
    p.add_argument(
        "--assess",
        action="store_true",
        help="print the quality table: Wald's protocol (ERGAS, SAM, Q2n, UIQI, SCC) and QNR",
    )
    p.add_argument(
        "--chunks",
        type=int,
        metavar="PX",
        help="compute and write chunk by chunk on Dask, chunks of PX pixels (memory ~ bands x PX^2 per thread; "
        f"default: in memory, or 1024 for a PAN over {AUTO_CHUNKS:,} pixels)",
    )
    # Axis-aligned grids (the usual pair) run in numpy and scipy: no JAX to import, nothing to compile.
    p.set_defaults(func=run, compiles=False)


def _georef(profile):
    """``(transform, crs)`` of a raster profile; ``(None, None)`` when it has no georeference."""
    t, crs = profile.get("transform"), profile.get("crs")
    if crs is None and (t is None or t.is_identity):
        return None, None
    return t, crs


def _pair_georef(pan_profile, ms_profile):
    """``(pan_t, pan_crs, ms_t, ms_crs)``: both georeferences, or none when one image has none."""
    pan_t, pan_crs = _georef(pan_profile)
    ms_t, ms_crs = _georef(ms_profile)
    if (pan_t is None) != (ms_t is None):
        which = "PAN" if pan_t is None else "MS"
        print(f"photax sharpen: the {which} image has no georeference: taken to cover the other's bounds")
        return None, None, None, None
    return pan_t, pan_crs, ms_t, ms_crs


def _gain_weights(args):
    gain = args.nyquist_gain[0] if len(args.nyquist_gain) == 1 else args.nyquist_gain
    return gain, "equal" if args.equal_weights else args.weights


def _summary(args, shape, dtype, ratio, weights, clipped):
    rows, cols = shape[1:]
    note = f"; {clipped} values clipped to the {dtype} range" if clipped else ""
    w = "" if weights is None else ", weights " + "/".join(f"{x:.3f}" for x in weights)
    bands = plural(shape[0], "band")
    print(f"photax sharpen: {args.method} -> {args.out} ({cols} x {rows} px, {bands}, ratio {ratio:.3g}{w}{note})")


def _run_chunked(args, inputs, chunks) -> int:
    """The Dask path: the graph built from the files, written chunk by chunk (atomic)."""
    from ..fusion import pansharpen_dask
    from ..io.lazy import to_raster
    from ..io.raster import open_raster

    with open_raster(args.pan) as p, open_raster(args.ms) as m:
        pan_profile, ms_profile = p.profile, m.profile
    pan_t, pan_crs, ms_t, ms_crs = _pair_georef(pan_profile, ms_profile)
    gain, weights = _gain_weights(args)
    info = {}
    out = pansharpen_dask(
        args.pan,
        args.ms,
        args.method,
        chunks=chunks,
        pan_transform=pan_t,
        ms_transform=ms_t,
        pan_crs=pan_crs,
        ms_crs=ms_crs,
        weights=weights,
        resampling=args.resampling,
        nyquist_gain=gain,
        pan_nodata=pan_profile.get("nodata"),
        ms_nodata=ms_profile.get("nodata"),
        pan_band=args.pan_band,
        info=info,
    )
    to_raster(out, args.out, inputs=inputs)
    _summary(args, out.shape, out.dtype, info["ratio"], info["weights"], info.get("clipped", 0))
    return 0


def run(args) -> int:
    import numpy as np

    from ..fusion import assess, pansharpen, qnr, wald_protocol
    from ..io.atomic import check_output_path
    from ..io.raster import open_raster, read_geotiff, write_geotiff

    inputs = [str(input_file(args.pan, "PAN raster")), str(input_file(args.ms, "MS raster"))]
    check_output_path(args.out, inputs)
    if args.weights and args.equal_weights:
        raise ValueError("give --weights or --equal-weights, not both")
    if args.chunks is not None and args.chunks < 16:
        raise ValueError(f"--chunks must be at least 16 pixels, got {args.chunks}")
    with open_raster(args.pan) as src:
        pan_shape, pan_count = src.shape, src.count
    if not 1 <= args.pan_band <= pan_count:
        raise ValueError(f"--pan-band {args.pan_band}: {args.pan} has {pan_count} band(s)")
    chunks = args.chunks or (1024 if pan_shape[0] * pan_shape[1] > AUTO_CHUNKS else None)
    if chunks and args.assess:
        raise ValueError("--assess reads the whole images: not with --chunks (or a PAN this large)")
    if chunks:
        return _run_chunked(args, inputs, chunks)
    pan, pan_profile = read_geotiff(args.pan)
    ms, ms_profile = read_geotiff(args.ms)
    pan = pan[args.pan_band - 1]
    pan_t, pan_crs, ms_t, ms_crs = _pair_georef(pan_profile, ms_profile)
    gain, weights = _gain_weights(args)
    ratio = pan.shape[0] / ms.shape[1]
    same_bounds = ratio == pan.shape[1] / ms.shape[2] == round(ratio) and (
        pan_t is None or (pan_crs == ms_crs and (pan_t * pan_t.scale(ratio)).almost_equals(ms_t))
    )
    if args.assess and not same_bounds:
        raise ValueError("--assess needs PAN and MS covering the same bounds with an integer pixel-size ratio")
    opts = {
        "weights": weights,
        "resampling": args.resampling,
        "nyquist_gain": gain,
        "pan_nodata": pan_profile.get("nodata"),
        "ms_nodata": ms_profile.get("nodata"),
    }
    out = pansharpen(
        pan, ms, args.method, pan_transform=pan_t, ms_transform=ms_t, pan_crs=pan_crs, ms_crs=ms_crs, **opts
    )
    write_geotiff(args.out, out.image, out.transform, crs=pan_crs, nodata=out.nodata, inputs=inputs)
    _summary(args, out.image.shape, out.image.dtype, out.ratio, out.weights, out.clipped)
    if args.assess:
        opts.pop("pan_nodata"), opts.pop("ms_nodata")
        r = round(ratio)
        wald = wald_protocol(pan, ms, args.method, **opts)
        full = qnr(out.image.astype(np.float64), ms.astype(np.float64), pan, r)
        exp = assess(wald["ms_low"].repeat(r, 1).repeat(r, 2), wald["reference"], r)  # no sharpening at all
        print(f"quality of {args.method} (Wald's protocol at 1/{r} scale; ideal: ERGAS 0, SAM 0, Q2n/UIQI/SCC 1):")
        print(f"  {'':10s} {'ERGAS':>8s} {'SAM(deg)':>8s} {'Q2n':>8s} {'UIQI':>8s} {'SCC':>8s}")
        for name, row in ((args.method, wald), ("nearest", exp)):
            print(
                f"  {name:10s} "
                + " ".join(
                    f"{row[k]:8.4f}" if np.isfinite(row[k]) else f"{'-':>8s}"
                    for k in ("ERGAS", "SAM", "Q2n", "UIQI", "SCC")
                )
            )
        print(
            f"without reference, at full scale (ideal 1, 0, 0): QNR {full['QNR']:.4f}, "
            f"D_lambda {full['D_lambda']:.4f}, D_s {full['D_s']:.4f}"
        )
    return 0
