"""Traced kernels kept on disk, so that a new process does not trace them again.

JAX's persistent compilation cache stores compiled XLA only: every process
still traces the Python function and lowers it to StableHLO before it can
even compute the cache key.  For the rectification kernels (a ``while_loop``
with a ``cond`` between the exact and the interpolated mapping) tracing was
most of a warm command-line run (``benchmarks/bench_startup.py --only
breakdown``).  :func:`disk_cached` wraps a jitted function so that its
first call in a process looks for the function *exported* (``jax.export``:
serialised StableHLO, JAX's supported format for this) under a key made of
everything the tracing depends on, and calls it without tracing; its XLA
compilation is then found in JAX's persistent cache as usual.  On a miss it
traces once, exports and writes the entry.

(Serialising the compiled executable itself,
``jax.experimental.serialize_executable``, would also skip the lowering,
but on this jaxlib's CPU backend some deserialised executables crashed the
process (SIGSEGV, the resection solvers) or failed with "Function
<fusion> not found": not used.)

The key: the function's name, a digest of photax's own source files (any
edit to photax invalidates every entry), the JAX and jaxlib versions, the
backend and device kind, 64-bit mode, ``XLA_FLAGS``, the argument pytree
structure, every array argument's shape / dtype / weak type, and the
``repr`` of every non-array argument (equinox's static part).  Arguments
whose ``repr`` is not a faithful value (an object address ``0x...``) are
not cached on disk: the call falls back to the plain jitted function.
Entries live in ``<jax_compilation_cache_dir>/photax-aot``, and only after
:func:`enable` (the command line calls it) with that directory set: library
calls behave exactly as before unless a program opts in.  An unreadable
entry is ignored and rewritten.

``compiler_options`` (XLA's per-program options, as ``jax.jit`` takes them)
go with the exported function's compilation too, and into its key.
``call.prefetch(*args)`` makes and compiles the program for ``args`` in a
background thread (when disk caching is on and it is not made yet), so that
a command which will probably need a second program compiles both at once:
XLA compiles without holding the GIL, and this machine has two cores.
The thread is not a daemon: the interpreter waits for it at exit.  A
daemon thread still inside XLA when the interpreter finalises is ended by
``pthread_exit``, whose unwinding through the C++ frames aborted the
process (``terminate called ... FATAL: exception not rethrown``, SIGABRT,
after ``photax resect`` had printed its result); waiting also keeps the
compiled program for the next run.

Private utility module: other photax units import its names directly
(``tests/test_imports.py`` lists the modules allowed that).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import pathlib
import tempfile
import threading

_SRC = pathlib.Path(__file__).resolve().parent
_LOCK = threading.Lock()


@functools.cache
def _source_digest() -> str:
    h = hashlib.sha256()
    for p in sorted(_SRC.rglob("*.py")):
        h.update(str(p.relative_to(_SRC)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()


@functools.cache
def _environment() -> str:
    import jax
    import jaxlib

    dev = jax.devices()[0]
    return repr(
        (
            jax.__version__,
            jaxlib.__version__,
            dev.platform,
            dev.device_kind,
            jax.config.jax_enable_x64,
            os.environ.get("XLA_FLAGS", ""),
            _source_digest(),
        )
    )


_ENABLED = False


def enable() -> None:
    """Keep :func:`disk_cached` functions on disk from now on in this process
    (in ``<jax_compilation_cache_dir>/photax-aot``, when that is set)."""
    global _ENABLED
    _ENABLED = True
    _lapack_on_demand()
    atomic_jax_cache()


def write_atomically(path: pathlib.Path, data: bytes) -> bool:
    """Write ``data`` to ``path`` through a temporary file beside it and ``os.replace``: a reader
    in another process sees the whole entry or none, never a part.  Two writers of the same
    entry write the same bytes; the last rename wins.  False (and no temporary left) when it
    cannot be written: a cache that cannot be written is still no error."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp", delete=False) as fh:
            tmp = fh.name
            fh.write(data)
        os.replace(tmp, path)
        return True
    except OSError:  # a read-only or full cache
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        return False


def atomic_jax_cache() -> None:
    """JAX's persistent compilation cache, safe for processes sharing it (issue 38).

    Its file cache (``jax._src.lru_cache.LRUCache``, without eviction) writes an entry with
    ``write_bytes`` in place: a process starting at the same moment read the half-written
    entry and JAX warned "Error reading persistent compilation cache entry" (an error under
    the tests' ``-W error``), and ``exists()`` then ``read_bytes()`` raced a replacement
    (``FileNotFoundError``).  Here entries are written atomically (:func:`write_atomically`)
    and an entry that vanished is a miss.  JAX's private class: where it is gone or
    different, nothing changes."""
    try:
        from jax._src import lru_cache
    except ImportError:
        return
    cls = getattr(lru_cache, "LRUCache", None)
    suffix = getattr(lru_cache, "_CACHE_SUFFIX", None)
    if cls is None or suffix is None or getattr(cls.put, "photax_atomic", False):
        return
    put, get = cls.put, cls.get

    def atomic_put(self, key: str, value: bytes) -> None:
        if (
            getattr(self, "eviction_enabled", True)
            or not key
            or not isinstance(getattr(self, "path", None), pathlib.Path)
        ):
            return put(self, key, value)  # eviction: JAX's own file lock orders the writers
        path = self.path / f"{key}{suffix}"
        if not path.exists():
            write_atomically(path, value)

    def safe_get(self, key: str):
        try:
            return get(self, key)
        except FileNotFoundError:  # removed between JAX's exists() and its read: a miss
            return None

    atomic_put.photax_atomic = True
    cls.put, cls.get = atomic_put, safe_get


# Set while this thread lowers an exported program that has no custom call at all.
_PLAIN = threading.local()


def _lapack_on_demand() -> None:
    """Lowering any exported call makes JAX initialise LAPACK for CPU programs
    (``jax._src.export._export._ensure_backends_initialized``), which imports
    ``scipy.linalg``: 0.1-0.15 s of CPU in every process, a tenth of a warm
    ``photax ortho``, for programs that call no LAPACK routine.  A LAPACK routine
    is only ever reached through a custom call, so a program whose serialised
    module has none (:func:`_load_or_compile` looks) is lowered without it; any
    other program, and every ``jax.jit`` of photax or of the user, initialises
    LAPACK as before.  This is JAX's private function: where it is gone, nothing
    changes but the time."""
    try:
        from jax._src.export import _export
    except ImportError:
        return
    original = getattr(_export, "_ensure_backends_initialized", None)
    if original is None or getattr(original, "photax_plain", False):
        return

    def ensure(platforms):
        if not getattr(_PLAIN, "active", False):
            original(platforms)

    ensure.photax_plain = True
    _export._ensure_backends_initialized = ensure


def _folder() -> pathlib.Path | None:
    import jax

    if not _ENABLED:
        return None
    base = jax.config.jax_compilation_cache_dir
    return pathlib.Path(base) / "photax-aot" if base else None


def disk_cached(fn, name: str, compiler_options: dict | None = None):
    """``fn`` (a jitted function of pytrees of arrays and static values),
    with its compiled executable kept on disk between processes.

    Returns a function with ``fn``'s signature and results (a call with
    keyword arguments goes to ``fn`` itself), and a ``prefetch`` method.
    ``compiler_options``: those ``fn`` was jitted with, for the exported
    program's compilation.
    """
    import jax

    from ._pytree import is_array

    memory: dict[str, object] = {}
    locks: dict[str, threading.Lock] = {}  # one per key: two programs are made at once

    def _key(args):
        """``(key, path, leaves, treedef, static)`` or None when ``args`` have no safe key."""
        every, treedef = jax.tree_util.tree_flatten(args)
        arrays = tuple(is_array(x) for x in every)  # traced; the other leaves are static (equinox's partition)
        leaves = [x for x, a in zip(every, arrays) if a]
        static = (arrays, [x for x, a in zip(every, arrays) if not a])
        description = repr(
            (
                name,
                treedef,
                static,
                compiler_options,
                [(x.shape, str(x.dtype), bool(getattr(x, "weak_type", False))) for x in leaves],
            )
        )
        if " at 0x" in description:  # an object's identity, not its value: no safe key
            return None
        key = hashlib.sha256((_environment() + description).encode()).hexdigest()
        return key, _folder() / f"{name}-{key[:32]}.bin", leaves, treedef, static

    def call(*args, **kwargs):
        if _folder() is None or kwargs:
            return fn(*args, **kwargs)
        made = _key(args)
        if made is None:
            return fn(*args)
        key, path, leaves, treedef, static = made
        compiled = memory.get(key)
        if compiled is None:
            with _LOCK:
                lock = locks.setdefault(key, threading.Lock())
            with lock:
                compiled = memory.get(key) or _load_or_compile(fn, path, leaves, treedef, static, compiler_options)
                memory[key] = compiled
        if compiled is fn:
            return fn(*args)
        try:
            return jax.block_until_ready(compiled(leaves))  # an execution error surfaces here, not later
        except jax.errors.JaxRuntimeError:
            # Seen once under heavy load: "Function <fusion> not found" from an
            # executable.  Never trust it again; the plain function decides
            # (a genuine error is raised again from there).
            memory[key] = fn
            path.unlink(missing_ok=True)
            return fn(*args)

    def prefetch(*args) -> None:
        """Make and compile the program for ``args`` in a background thread
        (nothing when disk caching is off or it is made already); the
        arguments' values are computed on and thrown away, errors ignored:
        the real call reports them."""
        if _folder() is None or (made := _key(args)) is None or made[0] in memory:
            return

        def run():
            try:
                call(*args)
            except Exception:  # noqa: S110 - the real call raises it again, where it belongs
                pass

        threading.Thread(target=run, name=f"photax-prefetch-{name}", daemon=False).start()

    call.prefetch = prefetch
    return call


def _load_or_compile(fn, path: pathlib.Path, leaves, treedef, static, compiler_options=None):
    """``jit(exported.call)`` for the serialised StableHLO at ``path``, made
    (traced once, exported, written) when missing or unreadable; ``fn``
    itself when the function cannot be exported."""
    import jax
    from jax import export

    try:
        data = path.read_bytes()
        exported = export.deserialize(bytearray(data))
    except Exception:  # missing, truncated, or from an incompatible JAX: export again
        # jax.jit refuses compiler options on an inner jit: with options, export the function fn wraps
        # (the options then apply to the exported program's own compilation, below).
        inner = fn.__wrapped__ if compiler_options else fn

        def pure(dyn_leaves):
            arrays, others = static
            dyn, rest = iter(dyn_leaves), iter(others)
            every = [next(dyn) if a else next(rest) for a in arrays]
            return inner(*jax.tree_util.tree_unflatten(treedef, every))

        try:
            exported = export.export(jax.jit(pure))(leaves)
        except Exception:  # e.g. a custom call JAX does not guarantee stable: no disk entry
            return fn
        data = None
        try:
            data = exported.serialize()
        except ImportError:  # no flatbuffers: still compute
            pass
        if data is not None:  # atomic: another process reads the whole entry or none
            write_atomically(path, data)
    jitted = jax.jit(exported.call, compiler_options=compiler_options)
    if data is None or b"custom_call" in data:
        return jitted
    # No custom call, so no LAPACK call: compiled here (lowered without initialising LAPACK,
    # _lapack_on_demand); the key fixes every argument's shape and type, so one executable serves.
    _PLAIN.active = True
    try:
        return jitted.lower(leaves).compile()
    finally:
        _PLAIN.active = False
