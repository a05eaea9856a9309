"""``photax rpc``: fit an RPC to a push-broom camera (:func:`photax.fit_rpc`) and write it as
orthority's ``rpc_param.yaml`` (which ``photax ortho --camera``, ``oty rpc`` and :func:`photax.rpc.read_rpc`
read), printing the fit error on the fit points and on a check grid between them.

CAMERA is a photax push-broom camera file (:mod:`photax.io.pushbroom_file`); ``--heights`` the
ellipsoidal height range the RPC must serve (the terrain's, with a margin).  Exit codes: 0 done,
2 bad input.
"""

from __future__ import annotations

import argparse


def add_parser(sub) -> None:
    p = sub.add_parser(
        "rpc",
        help="fit an RPC to a push-broom camera and write it (rpc_param.yaml)",
        description="Fit a terrain-independent RPC (RPC00B, Tao & Hu 2001) to a push-broom camera over a "
        "height range and write it as orthority's rpc_param.yaml; the fit error is printed.",
        epilog="example:\n  photax rpc scene_pushbroom.yaml --heights 0 1500 --image scene.tif -o rpc_param.yaml\n",
    )
    p.add_argument("camera", metavar="CAMERA", help="photax push-broom camera file (YAML or JSON, type: pushbroom)")
    p.add_argument("--heights", nargs=2, type=float, required=True, metavar=("H_MIN", "H_MAX"),
                   help="ellipsoidal heights (m) the RPC must serve")  # fmt: skip
    p.add_argument("--image", metavar="NAME", help="the image file name the RPC is written for (the entry's "
                   "key, which photax ortho and oty look up; default CAMERA's stem + .tif)")  # fmt: skip
    p.add_argument("--grid", type=int, default=15, help="image points per axis of the fit grid (default: 15)")
    p.add_argument("--layers", type=int, default=7, help="height layers of the fit grid (default: 7)")
    p.add_argument("-o", "--out", required=True, metavar="OUT_YAML", help="output rpc_param.yaml")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import pathlib

    from ..io.atomic import check_output_path
    from ..io.orthority import write_orthority_rpc
    from ..io.pushbroom_file import read_pushbroom
    from ..pushbroom import fit_rpc
    from ._common import input_file

    source = input_file(args.camera, "camera file")
    out = pathlib.Path(args.out)
    if out.suffix.lower() not in (".yaml", ".yml"):
        raise ValueError(f"-o/--out {out}: writes orthority's rpc_param.yaml; give a .yaml file")
    check_output_path(out, [source])  # fail before the work, not after
    camera = read_pushbroom(source)
    fit = fit_rpc(camera, tuple(args.heights), grid=args.grid, layers=args.layers)
    name = args.image if args.image is not None else f"{source.stem}.tif"
    write_orthority_rpc(out, {name: fit.camera}, inputs=[source])
    print(
        f"RPC fit: {fit.points} points, RMSE {fit.rmse:.2e} px, max {fit.max_error:.2e} px; "
        f"check grid: {fit.check_points} points, RMSE {fit.check_rmse:.2e} px, max {fit.check_max_error:.2e} px"
    )
    print(f"wrote {out} (entry {name})")
    return 0
