"""The ``photax`` command line.

One module per subcommand; each defines ``add_parser(subparsers)`` (which
registers its parser and sets ``func`` to its runner) and a runner
``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

# Subcommand modules, in the order ``photax --help`` lists them.
SUBCOMMANDS = ["resect", "demo", "rectify", "ortho", "compare", "bundle", "measure"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="photax",
        description="Photogrammetry on JAX: resection, bundle adjustment, rectification.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in SUBCOMMANDS:
        importlib.import_module(f"{__name__}.{name}").add_parser(sub)
    return parser


def _enable_compilation_cache() -> None:
    """Keep compiled solvers between runs (JAX's persistent cache).

    A command-line run otherwise compiles resection and friends anew every
    time.  ``JAX_COMPILATION_CACHE_DIR`` overrides the place; the default
    follows XDG (``~/.cache/photax/jax``).
    """
    import jax

    if os.environ.get("JAX_COMPILATION_CACHE_DIR") or jax.config.jax_compilation_cache_dir:
        return
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    jax.config.update("jax_compilation_cache_dir", os.path.join(base, "photax", "jax"))


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``photax`` console script."""
    args = build_parser().parse_args(argv)
    _enable_compilation_cache()
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, FileExistsError) as exc:
        print(f"photax {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
