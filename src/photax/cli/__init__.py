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
SUBCOMMANDS = ["resect", "demo", "rectify", "ortho", "mosaic", "compare", "bundle", "measure", "fiducials", "epipolar",
               "transfer", "ties", "register"]


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

    JAX writes an entry only for a compilation that took at least
    ``jax_persistent_cache_min_compile_time_secs`` (1 s by default), so the
    rectification and bundle kernels (0.1-0.7 s each, but a dozen of them
    per run) and the small operations around them were compiled again in
    every process.  Reading an entry back costs milliseconds, so the CLI
    caches every compilation (``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS``
    set in the environment still wins).
    """
    import jax

    from .. import _aot

    _aot.enable()  # and the kernels' traced programs (photax._aot)
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    if os.environ.get("JAX_COMPILATION_CACHE_DIR") or jax.config.jax_compilation_cache_dir:
        return
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    jax.config.update("jax_compilation_cache_dir", os.path.join(base, "photax", "jax"))


def _one_line(exc: BaseException) -> str:
    """An exception as one line of text, in photax's words where we can."""
    if isinstance(exc, OSError) and exc.strerror and not isinstance(exc, FileExistsError):
        where = f"{exc.filename}: " if exc.filename else ""
        text = f"{where}{exc.strerror}"
        if isinstance(exc, IsADirectoryError):
            text += " (a folder where a file is expected)"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())  # no multi-line messages from dependencies


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``photax`` console script.

    Exit status: 0 when everything requested was done (every image solved,
    the adjustment converged); 1 when a run finished but some image was not
    solved or the adjustment did not converge (its outputs are still
    written, with a status); 2 for usage and input errors (one line on
    stderr, no output written); 130 on Ctrl-C (no partial output: every
    file is written to a temporary name and renamed at the end).  Set
    ``PHOTAX_TRACEBACK=1`` to see the traceback of an unexpected error.
    """
    command = "photax"
    try:
        args = build_parser().parse_args(argv)
        command = f"photax {args.command}"
        _enable_compilation_cache()
        from ..io._files import recording_inputs

        with recording_inputs():  # every file read is an input: never an output (photax.io.atomic)
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"\n{command}: interrupted; nothing written", file=sys.stderr)
        return 130
    except (ValueError, OSError) as exc:
        if os.environ.get("PHOTAX_TRACEBACK"):
            raise
        print(f"{command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except Exception as exc:  # a bug or a dependency's failure: still one line, no traceback
        if os.environ.get("PHOTAX_TRACEBACK"):
            raise
        print(f"{command}: error: unexpected {type(exc).__name__}: {_one_line(exc)} "
              "(PHOTAX_TRACEBACK=1 shows where)", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
