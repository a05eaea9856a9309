"""The ``photax`` command line.

One module per subcommand; each defines ``add_parser(subparsers)`` (which
registers its parser and sets ``func`` to its runner) and a runner
``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import os
import signal
import sys
import threading
import warnings

# Imported here, not in the handler: a Ctrl-C while main() imported it made the handler's own
# import fail ("partially initialized module").  Cheap: pathlib, tempfile, threading.
from ..io.atomic import interrupted

# Subcommand modules, in the order ``photax --help`` lists them.
SUBCOMMANDS = [
    "resect",
    "demo",
    "rectify",
    "ortho",
    "mosaic",
    "compare",
    "bundle",
    "measure",
    "fiducials",
    "epipolar",
    "dsm",
    "transfer",
    "ties",
    "register",
    "sharpen",
    "coregister",
    "rpc",
]


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``photax`` parser; with ``command`` (one of :data:`SUBCOMMANDS`) only that subcommand's
    parser under it, as the full parser has it: a run imports and builds one subcommand's parser,
    not sixteen (25 ms of a process's start-up)."""
    parser = argparse.ArgumentParser(
        prog="photax",
        description="Photogrammetry on JAX: resection, bundle adjustment, rectification.",
    )
    parser.add_argument("--version", action=_Version, help="show the installed photax version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)
    for name in SUBCOMMANDS if command is None else [command]:
        importlib.import_module(f"{__name__}.{name}").add_parser(sub)
    parser.subcommands = sub.choices  # name -> its parser, for errors in its own words
    return parser


class _Formatter(argparse.HelpFormatter):
    """Every option's default in its help, unless the help already says it."""

    def _get_help_string(self, action):
        text = action.help or ""
        unset = any(action.default is x for x in (None, False, True, argparse.SUPPRESS))  # 0 and 1.0 are values
        shown = action.option_strings and not unset
        return f"{text} (default: %(default)s)" if shown and "default" not in text else text


class _Parser(argparse.ArgumentParser):
    """A subcommand's parser: defaults shown, and its epilog (the examples) printed as written."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)

    def format_help(self) -> str:
        epilog, self.epilog = self.epilog, None
        try:
            text = super().format_help()
        finally:
            self.epilog = epilog
        return f"{text}\n{epilog.strip(chr(10))}\n" if epilog else text


class _Version(argparse.Action):
    """``--version``: argparse's, the version looked up only when asked (importlib.metadata, with the
    email package, is ~45 ms of every command's start-up)."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, argparse.SUPPRESS, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog} {_version()}")
        parser.exit()


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("photax")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "(not installed)"


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


# Optional dependencies -> the extra of pyproject.toml that brings them.
_EXTRAS = {
    "dask": "dask",
    "xarray": "dask",
    "rioxarray": "dask",
    "distributed": "dask",
    "odc": "bench",
    "laspy": "las",
    "lazrs": "las",
}


# Exit status of a command that failed, by the type of what it raised (the first that matches), never by
# its words (photax.errors).  A NotConvergedError is "ran, not solved" (1) as a solver's status is; input
# and usage errors of every kind, and an output that could not be written, are 2.
_EXIT_STATUS = (
    ("NotConvergedError", 1),
    ("PhotaxError", 2),
)


def _exit_status(exc: BaseException) -> int:
    """The exit status for ``exc``, from its type alone (:data:`_EXIT_STATUS`; 2 otherwise)."""
    from .. import errors

    for name, status in _EXIT_STATUS:
        if isinstance(exc, getattr(errors, name)):
            return status
    return 2


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


class _CtrlC:
    """The SIGINT handler of a command: Ctrl-C at any moment ends it with 130 and nothing written.

    Ctrl-C sets :data:`photax.io.atomic.interrupted` (no output is committed
    after it) and raises ``KeyboardInterrupt`` -- but not while a C extension
    module starts (jaxlib, GDAL: raised there it crashed the process or came
    out as "ImportError: Encountered an error while initializing the
    extension") or in a garbage-collector callback (JAX has one; Python drops
    their exceptions), nor again while the first one unwinds (so that
    temporaries are removed).  Until :func:`main` has seen it, the handler
    looks again every 0.1 s: a ``KeyboardInterrupt`` that a dependency
    caught let the command run on to its end.
    """

    def __init__(self):
        self.raised = self.waiting = self.done = False

    def __call__(self, signum, frame) -> None:
        interrupted.set()
        if self.done:
            return
        self._look_again()
        if _not_now(frame) or (self.raised and sys.exc_info()[0] is not None):
            return  # not now; or the first one still unwinding
        self.raised = True
        raise KeyboardInterrupt

    def _look_again(self) -> None:
        if not self.waiting:
            self.waiting = True
            timer = threading.Timer(0.1, self._again)
            timer.daemon = True
            timer.start()

    def _again(self) -> None:
        self.waiting = False
        if not self.done and signal.getsignal(signal.SIGINT) is self:
            os.kill(os.getpid(), signal.SIGINT)


def _not_now(frame) -> bool:
    """Whether a ``KeyboardInterrupt`` raised in ``frame`` would crash or vanish: inside
    the start of a C extension module (``import jaxlib``...) or a garbage-collector
    callback (Python ignores their exceptions)."""
    from importlib.machinery import ExtensionFileLoader

    callbacks = {getattr(cb, "__code__", None) for cb in gc.callbacks}
    while frame is not None:
        if frame.f_code in callbacks or isinstance(frame.f_locals.get("self"), ExtensionFileLoader):
            return True
        frame = frame.f_back
    return False


@contextlib.contextmanager
def _all_or_nothing(command: list[str]):
    """Run the command all or nothing (:func:`photax.io.atomic.all_or_nothing`:
    when it fails, the outputs it completed are taken back); SIGTERM, SIGHUP
    and SIGINT first remove the temporaries being written and take back the
    outputs (:func:`photax.io.atomic.cleanup_temporaries`):
    SIGINT then raises KeyboardInterrupt as usual, SIGTERM and SIGHUP end the
    process with status 128 + the signal's number.  Only in the main thread
    (where Python runs signal handlers); the previous handlers come back after."""
    from ..io.atomic import all_or_nothing, cleanup_temporaries

    def handler(signum, frame):
        cleanup_temporaries()
        name = signal.Signals(signum).name
        print(f"\n{command[0]}: stopped by {name}; nothing written", file=sys.stderr, flush=True)
        os._exit(128 + signum)  # now, not after Dask's or GDAL's threads finish

    wanted = [getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n)]
    previous = {}
    if threading.current_thread() is threading.main_thread():
        previous = {s: signal.signal(s, handler) for s in wanted}
    try:
        with all_or_nothing():  # and a command that fails writes nothing
            yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``photax`` console script.

    Exit status, chosen by the outcome or by the type of the error (never
    its words; :mod:`photax.errors`): 0 when everything requested was done
    (every image solved, the adjustment converged); 1 when a run finished
    but some image was not solved or the adjustment did not converge (its
    outputs are still written, with a status), or when an estimate the
    command needs did not converge (:class:`photax.errors.NotConvergedError`:
    nothing written); 2 for usage and input errors (one line on
    stderr, no output written), and for an output that could not be written
    (a full disk, ``ulimit -f``: the message says what was needed and what is
    free; the previous file is kept); 130 on Ctrl-C, at any moment, 143 on
    SIGTERM, 129 on SIGHUP (no partial output: every file is written to a
    temporary name, synced and renamed at the end; nothing is renamed after a
    Ctrl-C, and a command that fails takes back the outputs it had finished).
    Set ``PHOTAX_TRACEBACK=1`` to see the traceback of an unexpected error.

    As the process's entry point (``argv`` None) it runs the command's start-up without
    Python's cyclic garbage collector, until :func:`photax.cli._common.start_gc`.
    """
    from ..io.atomic import cleanup_temporaries
    from ._common import _GC_PAUSED

    if argv is None and gc.isenabled():  # the process is this command: no cyclic GC in its start-up
        gc.disable()
        _GC_PAUSED[0] = True
    handler, previous = None, None
    if threading.current_thread() is threading.main_thread():
        handler = _CtrlC()
        previous = signal.signal(signal.SIGINT, handler)
    try:
        interrupted.clear()  # an earlier in-process run's
        status = _main(argv)
    finally:
        if handler is not None:
            handler.done = True
            signal.signal(signal.SIGINT, previous)
    if status == 130:
        cleanup_temporaries()
    if status == 130 and argv is None:
        # The process ends here: Python's own shutdown, with JAX's threads
        # (a compilation in flight) half-way, crashed it (SIGSEGV) now and then.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    if argv is None:  # the process ends here (the console script, python -m photax.cli)
        _exit(status)
    return status


def _exit(status: int) -> None:
    """End the process as the interpreter would, without its teardown: photax's own
    non-daemon threads are waited for (photax._aot's prefetch) and the ``atexit``
    functions run (temporary folders, logging, coverage), then ``os._exit``.  The
    teardown of every module and object cost 0.2-0.3 s of CPU with JAX loaded
    (a warm ``photax ortho`` of four frames: 2.2 s in all), for nothing: every
    output is written, synced and renamed by then.  Where another non-daemon
    thread runs (a dependency's worker pool, which only the interpreter's own
    shutdown tells to stop), the interpreter ends the process as usual."""
    import atexit

    others = [t for t in threading.enumerate() if t is not threading.current_thread() and not t.daemon]
    if any(not t.name.startswith("photax-") for t in others):
        return
    for thread in others:
        thread.join()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can be said
            pass
    os._exit(status)


@contextlib.contextmanager
def _told(command: str):
    """photax's warnings about the run (:class:`photax.errors.PartialDEMWarning`: the DEM covers part of
    an image, which is nodata there) are one line on stderr each, ``COMMAND: warning: ...``, whatever the
    interpreter's warning filters (``-W error`` included): the run goes on and its exit status stands."""
    from ..errors import PartialDEMWarning

    with warnings.catch_warnings():  # restores the filters and showwarning on the way out
        warnings.simplefilter("always", PartialDEMWarning)
        others = warnings.showwarning

        def show(message, category, *rest, **kw):
            if issubclass(category, PartialDEMWarning):
                print(f"{command}: warning: {message}", file=sys.stderr)
            else:
                others(message, category, *rest, **kw)

        warnings.showwarning = show
        yield


def _main(argv: list[str] | None) -> int:
    command = ["photax"]  # a list: the SIGTERM handler sees the subcommand once it is known

    def stopped() -> int:
        print(f"\n{command[0]}: interrupted; nothing written", file=sys.stderr)
        return 130

    try:
        with _all_or_nothing(command):  # a command that fails writes nothing
            words = sys.argv[1:] if argv is None else argv
            parser = build_parser(words[0] if words and words[0] in SUBCOMMANDS else None)
            args, extra = parser.parse_known_args(argv)
            if extra:  # in the subcommand's words (argparse's own error shows the top-level usage)
                parser.subcommands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
            command[0] = f"photax {args.command}"
            if getattr(args, "compiles", True):  # a command that compiles nothing need not import JAX for it
                _enable_compilation_cache()
            from ..io.files import recording_inputs
            from ._common import start_gc

            if not getattr(args, "starts_gc", False):  # else the command says when its start-up ends
                start_gc()
            with recording_inputs(), _told(command[0]):  # every file read is an input (photax.io.atomic)
                status = int(args.func(args) or 0)
    except KeyboardInterrupt:
        return stopped()
    except (ValueError, OSError) as exc:
        if interrupted.is_set():
            return stopped()
        if os.environ.get("PHOTAX_TRACEBACK"):
            raise
        print(f"{command[0]}: error: {_one_line(exc)}", file=sys.stderr)
        return _exit_status(exc)
    except Exception as exc:  # a bug or a dependency's failure: still one line, no traceback
        if interrupted.is_set():  # e.g. ImportError from a Ctrl-C inside a C extension's start
            return stopped()
        extra = _EXTRAS.get((getattr(exc, "name", None) or "").partition(".")[0])
        if isinstance(exc, ModuleNotFoundError) and extra:  # a usage error: say what to install
            module = exc.name.partition(".")[0]
            print(
                f'{command[0]}: error: needs {module}, in the {extra} extra: pip install "photax[{extra}]"',
                file=sys.stderr,
            )
            return 2
        if os.environ.get("PHOTAX_TRACEBACK"):
            raise
        print(
            f"{command[0]}: error: unexpected {type(exc).__name__}: {_one_line(exc)} (PHOTAX_TRACEBACK=1 shows where)",
            file=sys.stderr,
        )
        return 2
    if interrupted.is_set():  # after its last output was written: say so
        print(f"\n{command[0]}: interrupted as it ended (what it wrote was written before)", file=sys.stderr)
        return 130
    return status


if __name__ == "__main__":
    sys.exit(main())
