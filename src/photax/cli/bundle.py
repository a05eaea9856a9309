"""``photax bundle``: bundle adjustment of a BAL file or a block folder.

Prints one line per iteration and a final report.  Exit codes: 0 converged,
1 not converged, 2 bad input (a one-line message on stderr).
"""

from __future__ import annotations

import argparse
import pathlib


def add_parser(sub) -> None:
    p = sub.add_parser(
        "bundle",
        help="bundle adjustment of a block (BAL file or block folder)",
        description="Adjust exterior orientations, points and (optionally) interior orientation of a block "
        "by Levenberg-Marquardt with a Schur complement; print progress and a report.",
    )
    p.add_argument("file", metavar="FILE", help="a BAL file (.txt or .txt.bz2) or a block folder (block.json, "
                   "observations.csv, points.csv; see photax.io.block)")  # fmt: skip
    p.add_argument("--format", choices=("auto", "bal", "block"), default="auto",
                   help="input format (auto: a folder is a block, a file is BAL)")  # fmt: skip
    p.add_argument("--loss", choices=("none", "huber", "cauchy"), default="none", help="robust loss")
    p.add_argument("--loss-scale", type=float, default=1.0, metavar="D", help="loss scale in sigmas (default 1)")
    p.add_argument("--gauge", choices=("auto", "none", "fix_first_camera", "damped"), default="auto",
                   help="datum of a network without control (auto: 'damped' for BAL, none for blocks)")  # fmt: skip
    p.add_argument("--max-steps", "--max-iterations", dest="max_steps", type=int, default=50,
                   help="LM iterations at most, accepted and rejected steps (--max-iterations is an alias)")
    p.add_argument("--quiet", action="store_true", help="no per-iteration lines")
    p.add_argument("--json", metavar="OUT", help="also write the results as JSON")
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
    fmt = args.format if args.format != "auto" else ("block" if path.is_dir() else "bal")
    if fmt == "block":
        input_folder(path, "block folder")
        inputs = [path, *(input_file(path / n, "block file") for n in ("block.json", "points.csv", "observations.csv"))]
    else:
        inputs = [input_file(path, "BAL file")]
    if args.json:
        check_output_path(args.json, inputs)  # fail before the work, not after
    problem = read_block(path) if fmt == "block" else read_bal(path)
    gauge = {"auto": "damped" if fmt == "bal" else None, "none": None}.get(args.gauge, args.gauge)
    n_ctrl, n_chk = int((problem.roles == "control").sum()), int((problem.roles == "check").sum())
    print(f"{path}: {plural(problem.n_images, 'image')}, {plural(problem.n_cameras, 'camera')}, "
          f"{plural(problem.n_points, 'point')} ({n_ctrl} control, {n_chk} check), "
          f"{plural(problem.n_observations, 'observation')}")
    result = bundle_adjust(problem, loss=args.loss, loss_scale=args.loss_scale, gauge=gauge,
                           max_steps=args.max_steps, verbose=not args.quiet, throw=False,
                           progress=args.progress and args.command)  # fmt: skip
    print(result.report())
    if args.json:
        write_json(result.to_dict(), args.json, inputs=inputs)
        print(f"wrote {args.json}")
    return 0 if result.converged else 1
