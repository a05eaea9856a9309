"""``photax coregister``: register a target image to a reference image (:func:`photax.coregister`).

REFERENCE and TARGET in one CRS (or both without georeference: one pixel grid).  A global shift by phase
correlation, then a grid of windows, each tested for reliability; the affine, polynomial or thin-plate-
spline model fitted to the reliable ones.  ``--mode resample`` (default) writes every band of the target
resampled onto the reference grid; ``--mode georeference`` writes the target's pixels unchanged with a
corrected geotransform (affine model).  ``--report`` writes the windows (centre, shift, status) as JSON.
Exit codes: 0 done, 2 bad input or too few reliable windows.
"""

from __future__ import annotations

from ._common import RESAMPLING, input_file

MODELS = ("affine", "polynomial", "tps")  # = matching.coregister.MODELS


def add_parser(sub) -> None:
    p = sub.add_parser(
        "coregister",
        help="register a target image to a reference image (global and local shifts, like AROSICS)",
        description="Phase correlation of the whole overlap, then of a grid of windows (each tested: "
        "texture, peak ratio, SSIM, median test), fitted by an affine, polynomial or thin-plate-spline model.",
        epilog="examples:\n  photax coregister reference.tif target.tif -o target_on_reference.tif\n"
        "  photax coregister ref.tif tgt.tif -o tgt_fixed.tif --model affine --mode georeference "
        "--report windows.json\n",
    )
    p.add_argument("reference", metavar="REFERENCE", help="reference raster (its grid is kept)")
    p.add_argument("target", metavar="TARGET", help="raster to register (same CRS; any grid)")
    p.add_argument("-o", "--out", required=True, help="output GeoTIFF")
    p.add_argument("--model", choices=MODELS, default="affine", help="transformation fitted to the windows")
    p.add_argument("--order", type=int, default=2, help="polynomial order 1-5 (--model polynomial)")
    p.add_argument("--window", type=int, default=64, help="side of the measuring windows, px (even)")
    p.add_argument("--spacing", type=int, help="step of the window grid, px (default: the window side)")
    p.add_argument("--method", choices=("phase", "lsm"), default="phase", help="per window: phase correlation or LSM")
    p.add_argument("--band", type=int, default=1, help="band of both rasters to match (1-based)")
    p.add_argument(
        "--mode",
        choices=("resample", "georeference"),
        default="resample",
        help="resample the target onto the reference grid, or keep its pixels and correct its geotransform "
        "(affine model)",
    )
    p.add_argument("--resampling", choices=RESAMPLING, default="cubic", help="interpolation of the target")
    p.add_argument("--report", metavar="JSON", help="also write the windows (centre, shift, status) as JSON")
    p.set_defaults(func=run)


def _georef(profile):
    t, crs = profile.get("transform"), profile.get("crs")
    if crs is None and (t is None or t.is_identity):
        return None, None
    return tuple(t)[:6], crs


def run(args) -> int:
    import numpy as np

    from ..io.atomic import check_output_path
    from ..io.crs import require_same
    from ..io.raster import read_geotiff, write_geotiff
    from ..io.results import write_json
    from ..matching.coregister import coregister

    inputs = [str(input_file(args.reference, "reference raster")), str(input_file(args.target, "target raster"))]
    check_output_path(args.out, inputs)
    if args.report:
        check_output_path(args.report, inputs + [args.out])
    if args.mode == "georeference" and args.model != "affine":
        raise ValueError(f"--mode georeference needs --model affine, not {args.model}; resample instead")
    ref_all, ref_profile = read_geotiff(args.reference)
    tgt_all, tgt_profile = read_geotiff(args.target)
    for name, a in (("reference", ref_all), ("target", tgt_all)):
        if not 1 <= args.band <= a.shape[0]:
            raise ValueError(f"--band {args.band}: the {name} has {a.shape[0]} band(s)")
    ref_t, ref_crs = _georef(ref_profile)
    tgt_t, tgt_crs = _georef(tgt_profile)
    if (ref_t is None) != (tgt_t is None):
        raise ValueError("one raster has a georeference and the other not: give both or neither")
    require_same(ref_crs, f"the reference ({args.reference})", tgt_crs, f"the target ({args.target})")
    if args.mode == "georeference" and ref_t is None:
        raise ValueError("--mode georeference needs a georeferenced reference")

    def band(a, profile):
        x = a[args.band - 1].astype(np.float64)
        nodata = profile.get("nodata")
        return np.where(x == nodata, np.nan, x) if nodata is not None else x

    reg = coregister(
        band(ref_all, ref_profile),
        band(tgt_all, tgt_profile),
        reference_transform=ref_t,
        target_transform=tgt_t,
        window=args.window,
        spacing=args.spacing,
        model=args.model,
        order=args.order,
        method=args.method,
        resampling=args.resampling,
    )
    if args.mode == "resample":
        out = reg.resample(tgt_all, ref_all.shape[1:], args.resampling, nodata=tgt_profile.get("nodata"))
        write_geotiff(args.out, out, ref_t, crs=ref_crs, nodata=tgt_profile.get("nodata"), inputs=inputs)
    else:
        corrected = reg.corrected_transform(ref_t)
        write_geotiff(args.out, tgt_all, corrected, crs=ref_crs, nodata=tgt_profile.get("nodata"), inputs=inputs)
    if args.report:
        write_json(
            {
                "global_shift_px": reg.global_shift.tolist(),
                "model": reg.model_name,
                "rmse_px": reg.rmse,
                "counts": reg.counts,
                "windows": [
                    {"centre_px": c.tolist(), "shift_px": s.tolist(), "status": str(st)}
                    for c, s, st in zip(reg.centres, reg.shifts, reg.status)
                ],
            },
            args.report,
            inputs=inputs,
        )
    counts = ", ".join(f"{k} {v}" for k, v in reg.counts.items() if v)
    print(
        f"photax coregister: global shift {reg.global_shift[0]:+.3f} {reg.global_shift[1]:+.3f} px; windows: "
        f"{counts}; {reg.model_name} model, rmse {reg.rmse:.3f} px ({reg.iterations} passes) -> {args.out}"
    )
    return 0
