"""``photax bundle``: bundle adjustment of a BAL file, a block folder or a COLMAP model.

With ``--gcps`` and/or ``--gnss`` a COLMAP model (or a block in its own frame) is georeferenced
first (:func:`photax.georeference`: a 7-parameter similarity, then the
bundle with the control points, reporting the check points).

Prints one line per iteration and a final report.  Exit codes: 0 converged,
1 not converged, 2 bad input (a one-line message on stderr).
"""

from __future__ import annotations

import argparse
import math
import pathlib

from ..errors import CRSMismatchError


def add_parser(sub) -> None:
    p = sub.add_parser(
        "bundle",
        help="bundle adjustment of a block (BAL file or block folder)",
        description="Adjust exterior orientations, points and (optionally) interior orientation of a block "
        "by Levenberg-Marquardt with a Schur complement; print progress and a report.",
        epilog="examples:\n  photax bundle data/block --loss huber -o block.json\n"
        "  photax bundle problem-49-7776-pre.txt --gauge damped\n"
        "  photax bundle data/block --position-sigma 3 --attitude-sigma 0.1   # GNSS/INS-aided, no control\n"
        "  photax bundle BLOCK --position-sigma 2 --dem dem.tif --dem-sigma 3   # tie heights from a DEM\n"
        "  photax bundle colmap/sparse/0 --gcps gcp_list.txt --colmap-out georef   # georeference a COLMAP model\n",
    )
    p.add_argument("file", metavar="FILE", help="a BAL file (.txt or .txt.bz2), a block folder (block.json, "
                   "observations.csv, points.csv; see photax.io.block) or a COLMAP model folder (cameras, images, "
                   "points3D, .txt or .bin)")  # fmt: skip
    p.add_argument("--format", choices=("auto", "bal", "block", "colmap"), default="auto",
                   help="input format (auto: a folder with cameras.txt or cameras.bin is COLMAP, another folder a "
                   "block, a file BAL)")  # fmt: skip
    p.add_argument("--loss", choices=("none", "huber", "cauchy"), default="none", help="robust loss")
    p.add_argument("--loss-scale", type=float, default=1.0, metavar="D", help="loss scale in sigmas (default 1)")
    p.add_argument("--gauge", choices=("auto", "none", "fix_first_camera", "damped"), default="auto",
                   help="datum of a network without control (auto: 'damped' for BAL, none for blocks)")  # fmt: skip
    p.add_argument("--position-sigma", type=float, metavar="SIGMA",
                   help="take the images' start positions as GNSS observations of standard deviation SIGMA "
                   "(ground unit, > 0): with ties they give the block a datum without control")  # fmt: skip
    p.add_argument("--attitude-sigma", type=float, metavar="DEG",
                   help="take the images' start angles as INS attitude observations of standard "
                   "deviation DEG degrees (> 0)")  # fmt: skip
    p.add_argument("--lever-arm", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="GNSS antenna offset from the projection centre in the camera frame (x right, y up, "
                   "z back; ground unit), with --position-sigma")  # fmt: skip
    p.add_argument("--dem", metavar="DEM",
                   help="a DEM raster of the block's area in its CRS and height system: each tie point's height "
                   "is an observation of it (Z - DEM(X, Y) = 0, sigma --dem-sigma), so the terrain's relief holds "
                   "the block's tilt and height; ties off the DEM or on nodata are counted in the report")  # fmt: skip
    p.add_argument(
        "--dem-sigma",
        type=float,
        metavar="SIGMA",
        help="with --dem: standard deviation of the DEM's heights at the tie points (ground unit, > 0)",
    )
    p.add_argument(
        "--max-steps",
        "--max-iterations",
        dest="max_steps",
        type=int,
        default=50,
        help="LM iterations at most, accepted and rejected steps (--max-iterations is an alias)",
    )
    p.add_argument("--gcps", metavar="GCPS",
                   help="COLMAP model or block: georeference it with these control and check points (any GCP file "
                   "photax reads; pixels of the images, matched by name, file name or stem): a 7-parameter "
                   "similarity, then the bundle with the control points; check points reported with their std")  # fmt: skip
    p.add_argument("--gcp-sigma", type=float, default=0.0, metavar="SIGMA",
                   help="with --gcps: standard deviation of the control points' coordinates (ground unit); "
                   "0 (default) holds them fixed")  # fmt: skip
    p.add_argument("--gnss", metavar="FILE",
                   help="COLMAP model or block: georeference it with these GNSS positions of the images (any "
                   "exterior file photax reads: orthority CSV x y z or lat lon alt, Metashape / Pix4D OPK, "
                   "reconstruction.json, a photax result; or ODM's geo.txt), of standard deviation "
                   "--position-sigma; with or without --gcps")  # fmt: skip
    p.add_argument("--colmap-out", metavar="DIR",
                   help="also write the adjusted block as a COLMAP text model in DIR (new or empty), e.g. the "
                   "georeferenced model; written only when the adjustment converged")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no per-iteration lines")
    p.add_argument("-o", "--out", metavar="OUT_JSON", help="also write the results as JSON")
    p.add_argument("--json", dest="out", help=argparse.SUPPRESS)  # the old name of --out
    p.add_argument("--camera-out", metavar="OUT",
                   help="block folders: write the self-calibrated camera (one with 'free' intrinsics) as a photax "
                   "camera file OUT (.yaml or .json), ready for resect/ortho; with several, OUT is a folder of "
                   "NAME.yaml files. Written only when the adjustment converged")  # fmt: skip
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..bundle import bundle_adjust
    from ..io.atomic import check_output_path
    from ..io.bal import read_bal
    from ..io.block import read_block
    from ..io.results import write_json
    from ._common import input_file, input_folder, plural

    path = pathlib.Path(args.file)
    if not path.exists():
        raise ValueError(f"{path}: no such file or folder")
    fmt = args.format if args.format != "auto" else _detect(path)
    if fmt == "block":
        input_folder(path, "block folder")
        inputs = [path, *(input_file(path / n, "block file") for n in ("block.json", "points.csv", "observations.csv"))]
    elif fmt == "colmap":
        input_folder(path, "COLMAP model folder")
        inputs = [path, *path.iterdir()]
    else:
        inputs = [input_file(path, "BAL file")]
    if fmt == "colmap":
        from ..io.colmap import read_colmap

        problem = read_colmap(path)
    else:
        problem = read_block(path) if fmt == "block" else read_bal(path)
    georef = bool(args.gcps or args.gnss)
    if georef and fmt == "bal":
        raise ValueError("--gcps / --gnss need a COLMAP model or a block folder (a BAL camera has no pixel grid)")
    if georef and args.attitude_sigma is not None:
        raise ValueError("--attitude-sigma does not go with --gcps / --gnss: the start angles are in the model's frame")
    if args.gnss and args.position_sigma is None:
        raise ValueError("--gnss needs --position-sigma (the GNSS positions' standard deviation, ground unit)")
    problem = _with_camera_observations(problem, args, start_positions=not args.gnss)
    gcps, gnss, crs = _georeference_inputs(args, inputs)
    problem = _with_dem(problem, args, crs, inputs)
    if args.colmap_out:
        from ..io.atomic import check_output_path as _check
        from ..io.colmap import photax_camera_to_colmap

        out_dir = pathlib.Path(args.colmap_out)
        if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
            raise ValueError(f"--colmap-out {out_dir}: exists and is not an empty folder")
        _check(out_dir / "cameras.txt", inputs)
        for cam in problem.cameras:
            photax_camera_to_colmap(cam)  # a camera COLMAP cannot hold: refused before the work
    # After reading (the inputs now include the camera files block.json names), before the work:
    if args.out:
        check_output_path(args.out, inputs)
    cameras_out = _camera_outputs(args.camera_out, fmt, path, problem, inputs) if args.camera_out else []
    free = fmt in ("bal", "colmap") and not georef and args.position_sigma is None
    gauge = {"auto": "damped" if free else None, "none": None}.get(args.gauge, args.gauge)
    n_ctrl, n_chk = int((problem.roles == "control").sum()), int((problem.roles == "check").sum())
    print(
        f"{path}: {plural(problem.n_images, 'image')}, {plural(problem.n_cameras, 'camera')}, "
        f"{plural(problem.n_points, 'point')} ({n_ctrl} control, {n_chk} check), "
        f"{plural(problem.n_observations, 'observation')}"
    )
    options = dict(loss=args.loss, loss_scale=args.loss_scale, gauge=gauge, max_steps=args.max_steps,
                   verbose=not args.quiet, throw=False, progress=args.progress and args.command)  # fmt: skip
    if georef:
        from ..georeferencing import georeference

        geo = georeference(problem, gcps, gnss=gnss, gnss_sigma=args.position_sigma if gnss else None,
                           gcp_sigma=args.gcp_sigma, **options)  # fmt: skip
        result = geo.result
        print(geo.report())
    else:
        result = bundle_adjust(problem, **options)
        print(result.report())
    if args.out:
        data = result.to_dict()
        if georef:
            s = geo.similarity
            data["similarity"] = {"scale": s.scale, "rotation": s.rotation.tolist(),
                                  "translation": s.translation.tolist(), "rms": s.rms}  # fmt: skip
            if crs:
                data["crs"] = crs
        write_json(data, args.out, inputs=inputs)
        print(f"wrote {args.out}")
    if args.colmap_out and not result.converged:
        print(f"COLMAP model not written: the adjustment did not converge ({result.message})")
    elif args.colmap_out:
        from ..io.colmap import write_colmap

        write_colmap(result, args.colmap_out, inputs=inputs)
        print(f"wrote {args.colmap_out}")
    if cameras_out and not result.converged:
        print(f"camera files not written: the adjustment did not converge ({result.message})")
    elif cameras_out:
        from ..io.camera_file import write_camera

        for j, out, unit in cameras_out:
            out.parent.mkdir(parents=True, exist_ok=True)
            write_camera(result.cameras[j], out, unit=unit, inputs=inputs)
            print(f"wrote {out}")
    return 0 if result.converged else 1


def _georeference_inputs(args, inputs: list):
    """``(GCP table or None, {image: GNSS position} or None, ground CRS or None)`` of ``--gcps`` and
    ``--gnss``: a geographic GNSS file goes into the GCPs' CRS; two different CRSs are refused."""
    from ._common import input_file

    gcps = gnss = crs = None
    if args.gcps:
        if not (math.isfinite(args.gcp_sigma) and args.gcp_sigma >= 0):
            raise ValueError(f"--gcp-sigma must be >= 0, got {args.gcp_sigma:g}")
        from ..io.gcp import read_gcps

        gcps = read_gcps(input_file(args.gcps, "GCP file"))
        inputs.append(pathlib.Path(args.gcps))
        crs = gcps.crs
    elif args.gcp_sigma != 0.0:
        raise ValueError("--gcp-sigma needs --gcps")
    if args.gnss:
        from ..io.odm import is_odm_geo, read_odm_geo
        from ..io.orientation import read_exteriors

        path = input_file(args.gnss, "GNSS file")
        if is_odm_geo(path):  # ODM's geo.txt: positions only
            gnss, gnss_crs, _ = read_odm_geo(path, crs=crs)
            flat = [name for name, v in gnss.items() if not all(math.isfinite(float(c)) for c in v)]
            if flat:
                raise ValueError(f"--gnss {args.gnss}: no height (geo_z) for {', '.join(flat[:3])}: GNSS needs x, y, z")
        else:
            table, gnss_crs = read_exteriors(path, crs=crs)
            gnss = {name: eo.position for name, eo in table.items()}
        inputs.append(pathlib.Path(args.gnss))
        if crs is not None and gnss_crs is not None and not _same_crs(crs, gnss_crs):
            raise CRSMismatchError(f"--gnss {args.gnss} is in {gnss_crs}, the GCPs in {crs}: give both in one CRS")
        crs = crs or gnss_crs
    return gcps, gnss, crs


def _same_crs(a: str, b: str) -> bool:
    import pyproj

    try:
        return pyproj.CRS.from_user_input(a).equals(pyproj.CRS.from_user_input(b), ignore_axis_order=True)
    except pyproj.exceptions.CRSError:
        return a == b


def _detect(path: pathlib.Path) -> str:
    """The input format of ``--format auto``."""
    if not path.is_dir():
        return "bal"
    return "colmap" if any((path / f"cameras{e}").is_file() for e in (".txt", ".bin")) else "block"


def _with_camera_observations(problem, args, start_positions: bool = True):
    """The problem with its start positions / angles as GNSS / INS
    observations (``--position-sigma``, ``--attitude-sigma``,
    ``--lever-arm``); ValueError for a sigma that is not positive, or no
    start value to take."""
    import math

    import numpy as np

    changes = {}
    for flag, sigma, values, key in (
        ("--position-sigma", args.position_sigma, problem.exterior.position, "gnss"),
        ("--attitude-sigma", args.attitude_sigma, problem.exterior.angles, "attitude"),
    ):
        if sigma is None or (key == "gnss" and not start_positions):  # --gnss: positions from its file
            continue
        if not (math.isfinite(sigma) and sigma > 0):
            raise ValueError(f"{flag} must be a positive number, got {sigma:g}")
        values = np.asarray(values, dtype=float)
        if not np.isfinite(values).all(axis=1).any():
            what = "position" if key == "gnss" else "attitude"
            raise ValueError(f"{flag}: no image has a start {what} to take")
        if key == "gnss":
            changes.update(gnss_position=values, gnss_sigma=sigma)
        else:
            changes.update(attitude=values, attitude_sigma=math.radians(sigma))
    if args.lever_arm is not None:
        if not start_positions:
            raise ValueError(
                "--lever-arm does not go with --gnss (photax.georeference takes the antenna at the centre)"
            )
        if args.position_sigma is None:
            raise ValueError("--lever-arm needs --position-sigma (it offsets the GNSS antenna)")
        changes["lever_arm"] = args.lever_arm
    return problem.replace(**changes) if changes else problem


def _with_dem(problem, args, crs, inputs: list):
    """The problem with the tie points' heights as observations of ``--dem``
    (sigma ``--dem-sigma``); the DEM's CRS is checked against ``crs`` (that of
    ``--gcps`` / ``--gnss``) where both are known."""
    if args.dem is None:
        if args.dem_sigma is not None:
            raise ValueError("--dem-sigma needs --dem")
        return problem
    if args.dem_sigma is None:
        raise ValueError("--dem needs --dem-sigma (the standard deviation of its heights, ground unit)")
    if not (math.isfinite(args.dem_sigma) and args.dem_sigma > 0):
        raise ValueError(f"--dem-sigma must be a positive number, got {args.dem_sigma:g}")
    from ..io.raster import read_dem
    from ._common import input_file

    dem = read_dem(input_file(args.dem, "DEM"))
    inputs.append(pathlib.Path(args.dem))
    return problem.replace(dem=dem, dem_sigma=args.dem_sigma, crs=crs or problem.crs)


def _camera_outputs(out, fmt: str, folder: pathlib.Path, problem, inputs: list) -> list:
    """``[(camera index, path, unit)]`` for ``--camera-out``: the block's
    self-calibrated cameras, checked before the work (a BAL file, no free
    intrinsics, a camera name that is no file name, a path that is an input: ValueError).
    The camera files read are inputs already (recorded by the readers)."""
    from ..io.atomic import check_output_path, output_name
    from ..io.files import load_json, read_text
    from ..io.orientation import read_camera_unit

    if fmt != "block":
        raise ValueError("--camera-out needs a block folder (a BAL file's cameras are not photax cameras)")
    meta_path = folder / "block.json"
    meta = load_json(meta_path, read_text(meta_path, "block file"))["cameras"]  # read_block keeps this order
    names = list(meta)
    free = [j for j in range(len(names)) if problem.free_intrinsics[j].any()]
    if not free:
        raise ValueError("--camera-out: no camera of the block is self-calibrated (give it 'free' in block.json)")
    out = pathlib.Path(out)
    # a name from block.json becomes a file name in OUT, never a path out of it
    paths = [out] if len(free) == 1 else [out / f"{output_name(names[j], 'camera')}.yaml" for j in free]
    folded = [p.name.lower() for p in paths]
    if len(set(folded)) < len(folded):  # one file on a case-insensitive disk (macOS, Windows)
        raise ValueError("--camera-out: two self-calibrated cameras have the same name up to case")
    if len(free) > 1 and out.exists() and not out.is_dir():
        raise ValueError(f"--camera-out: {len(free)} self-calibrated cameras need a folder, {out} is a file")
    if len(free) == 1 and out.suffix.lower() not in (".yaml", ".yml", ".json"):
        raise ValueError(f"--camera-out: {out} must end in .yaml, .yml or .json")
    for p in paths:
        check_output_path(p, inputs)
    # pixels (focal_length_px) unless the camera came from a file in its own unit
    units = [read_camera_unit(folder / meta[names[j]]["file"]) if "file" in meta[names[j]] else "px" for j in free]
    return list(zip(free, paths, units))
