"""Test configuration: float64 and strict promotion, as optimistix does."""

import gc
import importlib.util
import os
import pathlib
import subprocess
import tempfile

# One persistent compilation cache for the whole session, inherited by the
# notebook kernels and CLI subprocesses the tests start, so each of them
# does not compile resect & co. again. Set before jax is imported.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", tempfile.mkdtemp(prefix="photax-jax-cache-"))
# Every compilation, not only those over JAX's default 1 s: the xdist workers,
# notebook kernels and CLI subprocesses compile many of the same small
# functions (measured: the suite's CPU time 9 min 17 s -> 8 min 21 s).
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
# The suite is compile-bound: XLA's CPU back end at LLVM -O0 without its
# expensive passes compiles much faster (measured: test_compare + test_bundle
# 97 -> 69 CPU s) and only the speed of the compiled code changes, which the
# tests do not measure (benchmarks/ run at the default level).  Inherited by
# the notebook kernels and CLI subprocesses.  XLA:CPU's MLIR fusion emitters
# (the default) compile about twice as slowly as the classic ones at the same
# run time (measured: compare_models' first call 11.5/9.4 -> 6.9/5.0 CPU s,
# warm calls unchanged), so the session uses the classic ones.
_FAST_COMPILE = (
    "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true --xla_cpu_use_fusion_emitters=false"
)
if _FAST_COMPILE not in os.environ.get("XLA_FLAGS", ""):  # the xdist workers inherit it already set
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_FAST_COMPILE}".strip()

import jax  # noqa: E402 -- after XLA_FLAGS is set
import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402

# Property tests (docs/testing.md).  "ci", the default: a fixed seed (derandomize), so a run
# draws the same examples every time and the suite never fails at random; a crash the
# fuzzers find is kept as an explicit @example.  "deep", on demand: 10 times the examples
# and a new random seed each run, to find new crashes (pytest --hypothesis-profile=deep).
# Each test's budget is `fuzz_budget(n)`: its "ci" count, times the profile's factor.
CI_EXAMPLES = 100
_PROFILE = dict(deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
settings.register_profile("ci", max_examples=CI_EXAMPLES, derandomize=True, **_PROFILE)
settings.register_profile("deep", max_examples=10 * CI_EXAMPLES, derandomize=False, **_PROFILE)
settings.load_profile(os.environ.get("PHOTAX_HYPOTHESIS_PROFILE", "ci"))


def fuzz_budget(n: int) -> int:
    """``n`` examples under the "ci" profile, scaled by the loaded profile's ``max_examples``
    (10 x under "deep")."""
    return max(1, n * settings.default.max_examples // CI_EXAMPLES)


def load_factor() -> float:
    """How much slower than an idle machine this one runs now: the 1-minute load average per
    CPU (at least 1), times ``PHOTAX_TIMEOUT_SCALE`` when set (a slow emulator, a sanitiser)."""
    try:
        load = os.getloadavg()[0]
    except (OSError, AttributeError):  # no load average (Windows)
        load = 0.0
    factor = max(1.0, load / (os.cpu_count() or 1))
    return factor * float(os.environ.get("PHOTAX_TIMEOUT_SCALE", "1") or 1)


def scaled(seconds: float) -> float:
    """A time limit of ``seconds`` on an idle machine, scaled to this one's load
    (:func:`load_factor`, at most 20 x): a test's ``timeout=`` is a bound on a hang, not a
    benchmark, and a busy machine (CI's neighbours, two busy processes beside the suite)
    must not fail it (docs/testing.md)."""
    return seconds * min(load_factor(), 20.0)


@pytest.fixture
def spawn():
    """``subprocess.Popen`` for a test: a process still running when the test ends (a failed
    ``communicate(timeout=...)``) is killed and reaped then, not left for a later test's
    teardown to warn about (``ResourceWarning: subprocess ... is still running``, an error
    under -W error, blamed on whichever test ran next: issue 38's test_scale failure)."""
    procs = []

    def start(*args, **kwargs):
        procs.append(subprocess.Popen(*args, **kwargs))
        return procs[-1]

    yield start
    for p in procs:
        if p.poll() is None:
            p.kill()
        try:
            p.communicate(timeout=60)  # reaped, its pipes closed
        except subprocess.TimeoutExpired:
            pass


def _mappings() -> int:
    """How many memory mappings this process has (Linux; 0 elsewhere)."""
    try:
        with open("/proc/self/maps", "rb") as fh:
            return fh.read().count(b"\n")
    except OSError:
        return 0


@pytest.hookimpl(trylast=True)  # after the module's fixtures are finalised
def pytest_runtest_teardown(item, nextitem):
    """Compiled code released between test modules, and whenever a worker holds many mappings.

    Each XLA:CPU executable maps its code into the process, and JAX keeps every executable a jitted
    function has made.  A long-lived xdist worker that ran hundreds of tests' own ``jax.jit``s
    reached Linux's ``vm.max_map_count`` (65,530 mappings): the next compilation's mmap failed,
    XLA threw, and pyceres' glog failure handler, asked for a backtrace inside the unwinder,
    deadlocked: CI hung for 80 minutes in test_pushbroom_uncertainty (found with py-spy,
    65,444 mappings).  Clearing JAX's caches keeps a worker near 3,000-7,000 mappings; a later
    module that needs a program again finds it in the persistent compilation cache."""
    if nextitem is None or nextitem.module is not item.module or _mappings() > 30_000:
        jax.clear_caches()
        gc.collect()


def pytest_configure(config):
    # --hypothesis-profile wins over the default, whichever plugin is configured first.
    profile = config.getoption("--hypothesis-profile", None)
    if profile:
        settings.load_profile(profile)


# The xdist workers, notebook kernels and CLI subprocesses share the cache above: its entries are
# written atomically (photax._aot.atomic_jax_cache, as the CLI does), so that no process reads a
# half-written one (JAX warned, an error under -W error).
from photax import _aot  # noqa: E402

_aot.atomic_jax_cache()

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_numpy_dtype_promotion", "strict")

ROOT = pathlib.Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


@pytest.fixture
def shared_data():
    """Path to ../shared/data; skips the test cleanly when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present")
    return SHARED_DATA


def needs(*modules: str):
    """Skip mark for a test module whose optional dependencies are missing,
    found without importing them (``pytest.importorskip("rioxarray")`` at
    collection imported dask, xarray and rioxarray in every xdist worker:
    about 2.5 CPU s each, for files that run in one of them)."""
    missing = [m for m in modules if importlib.util.find_spec(m) is None]
    return pytest.mark.skipif(bool(missing), reason=f"{', '.join(missing)} not installed (the dask extra)")


def sample_ortho(resolution="4", exterior=None) -> list[str]:
    """``photax ortho`` of the bundled sample (``data/sample_*``: image, DEM, camera and its true
    orientation, or ``exterior``) at ``resolution`` with no bar: the arguments after ``photax``."""
    data = ROOT / "data"
    return [
        "ortho", str(data / "sample_image.tif"), "--dem", str(data / "sample_dem.tif"),
        "--camera", str(data / "sample_camera.yaml"), "--exterior", str(exterior or data / "sample_truth.json"),
        "--resolution", str(resolution), "--no-progress",
    ]  # fmt: skip


def shared_file(name: str) -> pathlib.Path:
    """A file of ../shared/data, or a clean skip when it is absent."""
    path = SHARED_DATA / name
    if not path.is_file():
        pytest.skip(f"../shared/data/{name} is not present")
    return path


# The files that take longest go to the two xdist workers first (--dist
# loadfile hands out files in collection order; longest first is the classic
# rule for balancing two machines): started last, the notebooks alone kept
# one worker busy for a minute after the other had finished.  Ordered by
# their measured wall time in the suite (2026-11-24); the rest keep their
# order.
_HEAVY_FIRST = (
    "test_notebooks.py",
    "test_matching.py",
    "test_bundle_real.py",
    "test_compare.py",
    "test_measure_locators.py",
    "test_rectify.py",
    "test_fuzz_readers.py",
    "test_resample.py",
    "test_bundle.py",
    "test_cli_errors.py",
    "test_cli_sample.py",
    "test_resection.py",
    "test_rectification_dask.py",
    "test_mosaic_block.py",
    "test_measure_operators.py",
    "test_uncertainty.py",
    "test_bundle_sparse.py",
    "test_polynomial.py",
    "test_cli.py",
    "test_progress.py",
    "test_epipolar.py",
    "test_registration.py",
    "test_bundle_dem.py",  # its NGI test matches real frames (~1 min on a loaded core)
)


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(_HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
