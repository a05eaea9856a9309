"""``photax demo``: run the demo report on the bundled (generated) sample data."""

from __future__ import annotations

import argparse


def add_parser(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="write a demo report (Markdown + figures) on synthetic sample data",
        description="Run photax on its sample scene and write report.md with figures.",
        epilog="example:\n  photax demo -o photax-demo\n",
    )
    p.add_argument(
        "-o", "--out-dir", default="photax-demo", metavar="DIR", help="output folder (default: ./photax-demo)"
    )
    # the old name of --out-dir
    p.add_argument("--out", dest="out_dir", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..demo import run_demo

    report = run_demo(args.out_dir, progress=args.progress and args.command)
    print(f"report: {report}")
    return 0
