"""photax._aot: traced (exported) kernels kept on disk, loaded without tracing.

Each check counts traces with a Python side effect in the traced function
(it runs only while JAX traces), and compares results with numpy.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import scaled

from photax import _aot

TRACES = []
_REAL_FOLDER = _aot._folder


@eqx.filter_jit
def _kernel(x, scale, mode):
    TRACES.append(mode)  # only while tracing
    return x * scale if mode == "mul" else x + scale


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.setattr(_aot, "_folder", lambda: tmp_path)
    TRACES.clear()
    return tmp_path


def test_a_new_process_loads_the_function_without_tracing(folder):
    x = np.arange(5.0)
    np.testing.assert_array_equal(_aot.disk_cached(_kernel, "k")(x, 2.0, "mul"), x * 2.0)
    assert len(TRACES) == 1 and len(list(folder.glob("k-*.bin"))) == 1
    # a fresh wrapper stands for a new process: it reads the file, no trace
    fresh = _aot.disk_cached(_kernel, "k")
    np.testing.assert_array_equal(fresh(x + 1.0, 2.0, "mul"), (x + 1.0) * 2.0)
    assert len(TRACES) == 1
    # a different static value or shape is a different entry
    np.testing.assert_array_equal(fresh(x, 3.0, "add"), x + 3.0)
    np.testing.assert_array_equal(fresh(np.arange(3.0), 2.0, "mul"), np.arange(3.0) * 2.0)
    assert len(TRACES) == 3 and len(list(folder.glob("k-*.bin"))) == 3


def test_a_damaged_entry_is_compiled_again(folder):
    x = jnp.ones(4)
    _aot.disk_cached(_kernel, "d")(x, 1.0, "add")
    (entry,) = folder.glob("d-*.bin")
    entry.write_bytes(b"not an executable")
    np.testing.assert_array_equal(_aot.disk_cached(_kernel, "d")(x, 1.0, "add"), np.full(4, 2.0))
    assert entry.stat().st_size > 100  # compiled again and rewritten


def test_no_cache_folder_or_no_faithful_key_calls_the_function(folder, monkeypatch):
    class Opaque:  # repr is an address: not a key that can be trusted
        pass

    @eqx.filter_jit
    def g(x, obj):
        return x + 1.0

    np.testing.assert_array_equal(_aot.disk_cached(g, "g")(jnp.zeros(2), Opaque()), np.ones(2))
    monkeypatch.setattr(_aot, "_ENABLED", False)  # a library call: off unless a program enables it
    assert _REAL_FOLDER() is None
    monkeypatch.setattr(_aot, "_folder", lambda: None)
    np.testing.assert_array_equal(_aot.disk_cached(_kernel, "n")(jnp.zeros(2), 1.0, "add"), np.ones(2))
    assert not list(folder.iterdir())


def test_an_entry_that_fails_to_run_is_dropped_for_the_function(folder, monkeypatch):
    import jax

    def broken(*_):
        raise jax.errors.JaxRuntimeError("NOT_FOUND: Function slice_divide_fusion.3 not found (injected)")

    def load(fn, path, *_):  # as if the entry had been read from disk
        path.write_bytes(b"an executable")
        return broken

    monkeypatch.setattr(_aot, "_load_or_compile", load)
    f = _aot.disk_cached(_kernel, "b")
    np.testing.assert_array_equal(f(jnp.arange(3.0), 2.0, "mul"), np.arange(3.0) * 2.0)
    np.testing.assert_array_equal(f(jnp.arange(3.0), 2.0, "mul"), np.arange(3.0) * 2.0)  # no second try
    assert not list(folder.glob("b-*.bin"))  # the entry is gone


def test_compiler_options_and_prefetch(folder):
    """A function jitted with XLA options is exported through the function it
    wraps (jax.jit refuses options on an inner jit), its options are part of
    the key, and ``prefetch`` makes the entry in a background thread."""
    import threading
    import time

    import jax

    opts = {"xla_cpu_use_fusion_emitters": False}

    def plain(x):
        TRACES.append("opt")
        return jnp.sin(x) * 2.0

    x = np.linspace(0.0, 1.0, 7)
    f = _aot.disk_cached(jax.jit(plain, compiler_options=opts), "o", opts)
    f.prefetch(x)
    deadline = time.monotonic() + 60
    while not list(folder.glob("o-*.bin")) and time.monotonic() < deadline:
        time.sleep(0.05)
    while any(t.name == "photax-prefetch-o" for t in threading.enumerate()) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(list(folder.glob("o-*.bin"))) == 1  # made by the thread
    n = len(TRACES)
    np.testing.assert_allclose(f(x), np.sin(x) * 2.0, rtol=1e-15)
    assert len(TRACES) == n  # the call found what the thread made: no new trace
    f.prefetch(x)  # made already: nothing to do
    assert not any(t.name == "photax-prefetch-o" for t in threading.enumerate())
    # the same function without options is another entry
    np.testing.assert_allclose(_aot.disk_cached(jax.jit(plain), "o")(x), np.sin(x) * 2.0, rtol=1e-15)
    assert len(list(folder.glob("o-*.bin"))) == 2


def test_a_prefetch_still_running_at_exit_is_waited_for(tmp_path):
    """The interpreter waits for a prefetch thread instead of killing it.  A
    daemon thread inside XLA at interpreter exit aborted ``photax resect``
    after it had printed its result (SIGABRT, "FATAL: exception not
    rethrown"); here the traced function sleeps, so the process exits while
    the thread is busy, and the entry exists only if the thread finished."""
    import subprocess
    import sys

    script = f"""
import time, jax, jax.numpy as jnp
jax.config.update("jax_compilation_cache_dir", {str(tmp_path)!r})
from photax import _aot
_aot.enable()
def slow(x):
    time.sleep(1.5)  # while tracing, in the prefetch thread
    return jnp.cos(x)
_aot.disk_cached(jax.jit(slow), "slow").prefetch(jnp.zeros(3))
"""
    proc = subprocess.run(
        [sys.executable, "-c", script], check=False, capture_output=True, text=True, timeout=scaled(120)
    )
    assert proc.returncode == 0, proc.stderr
    assert len(list((tmp_path / "photax-aot").glob("slow-*.bin"))) == 1


def test_lapack_is_initialised_only_for_programs_that_call_it(tmp_path):
    """A program without a custom call is loaded in a new process without JAX's LAPACK
    initialisation (which imports scipy.linalg: a tenth of a warm ``photax ortho``); one that
    calls LAPACK (a linear solve) still gets it and computes the right answer when loaded
    from disk by a new process (uninitialised, it would crash or give garbage)."""
    import subprocess
    import sys

    script = f"""
import sys, jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_compilation_cache_dir", {str(tmp_path)!r})
from photax import _aot
_aot.enable()
x = np.linspace(0.0, 1.0, 5)
np.testing.assert_allclose(_aot.disk_cached(jax.jit(lambda v: jnp.sin(v) * 2.0), "plain")(x), np.sin(x) * 2.0)
print("scipy.linalg" in sys.modules)
if sys.argv[1] == "solve":
    a = np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 1.0], [0.0, 1.0, 2.0]])
    got = _aot.disk_cached(jax.jit(jnp.linalg.solve), "solve")(a, np.arange(3.0))
    np.testing.assert_allclose(got, np.linalg.solve(a, np.arange(3.0)), rtol=1e-12)
"""
    runs = [subprocess.run([sys.executable, "-c", script, part], capture_output=True, text=True, timeout=scaled(120))
            for part in ("plain", "solve", "plain", "solve")]  # fmt: skip
    for proc in runs:
        assert proc.returncode == 0, proc.stderr
    assert len(list((tmp_path / "photax-aot").glob("*.bin"))) == 2
    assert runs[2].stdout.split() == ["False"]  # loaded from disk: no LAPACK, no scipy.linalg


def test_jax_cache_entries_are_whole_or_absent_for_a_concurrent_reader(tmp_path, monkeypatch):
    """issue 38: JAX's file cache wrote an entry in place, so a process starting at the same
    moment read half of it (JAX warned "Error reading persistent compilation cache entry").
    After :func:`photax._aot.atomic_jax_cache` a reader polling the entry while it is written
    sees nothing or all of it; an entry that vanishes between JAX's exists() and read is a miss."""
    import threading

    from jax._src.lru_cache import LRUCache

    _aot.atomic_jax_cache()
    _aot.atomic_jax_cache()  # once only: not wrapped twice
    cache = LRUCache(str(tmp_path), max_size=-1)
    value = np.random.default_rng(0).bytes(64 << 20)  # 64 MiB: a write takes milliseconds
    seen, done = [], threading.Event()

    def read():
        while not done.is_set():
            got = cache.get("k")
            seen.append(None if got is None else len(got))

    reader = threading.Thread(target=read)
    reader.start()
    try:
        cache.put("k", value)
    finally:
        done.set()
        reader.join()
    assert cache.get("k") == value
    assert set(seen) <= {None, len(value)}, sorted({s for s in seen if s is not None})[:5]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k-cache"]  # no temporary left

    # removed by another process between JAX's exists() and its read_bytes(): a miss
    monkeypatch.setattr(type(tmp_path), "exists", lambda self: True)
    assert cache.get("gone") is None


def test_write_atomically_leaves_nothing_when_it_cannot_write(tmp_path):
    import os

    target = tmp_path / "ro" / "entry.bin"
    target.parent.mkdir()
    assert _aot.write_atomically(target, b"abc") and target.read_bytes() == b"abc"
    assert _aot.write_atomically(target, b"abcd") and target.read_bytes() == b"abcd"  # replaced whole
    os.chmod(target.parent, 0o500)
    try:
        if os.access(target.parent, os.W_OK):  # root writes anyway: a folder that is a file instead
            blocked = tmp_path / "file"
            blocked.write_text("x")
            assert not _aot.write_atomically(blocked / "entry.bin", b"abc")
        else:
            assert not _aot.write_atomically(target, b"new")
            assert target.read_bytes() == b"abcd"
    finally:
        os.chmod(target.parent, 0o700)
    assert sorted(p.name for p in target.parent.iterdir()) == ["entry.bin"]
