"""How the ``photax`` process ends (photax.cli._exit): without the interpreter's teardown, but
after photax's own threads and the ``atexit`` functions, with the command's exit status; and as
usual where a dependency's worker thread still runs (only the interpreter's shutdown stops it)."""

import subprocess
import sys

from conftest import ROOT, scaled

_SCRIPT = """
import atexit, sys, threading, time
from concurrent.futures import ThreadPoolExecutor
from photax.cli import _exit

atexit.register(lambda: print("atexit ran", flush=True))
done = []
threading.Thread(target=lambda: (time.sleep(0.5), done.append(1)), name="photax-prefetch-x").start()
atexit.register(lambda: print("prefetch finished" if done else "prefetch cut", flush=True))
if sys.argv[1] == "pool":  # a dependency's pool: a non-daemon worker waiting for work
    pool = ThreadPoolExecutor(1)
    pool.submit(lambda: None).result()
_exit(3)
sys.exit(4)  # only where _exit left it to the interpreter
"""


def _run(kind):
    env = {"PYTHONPATH": str(ROOT / "src"), "PATH": ""}
    return subprocess.run(
        [sys.executable, "-c", _SCRIPT, kind], capture_output=True, text=True, env=env, timeout=scaled(60)
    )


def test_the_process_ends_after_its_threads_and_atexit_with_its_status():
    p = _run("plain")
    assert p.returncode == 3, p.stderr
    assert p.stdout.split("\n")[:2] == ["prefetch finished", "atexit ran"]


def test_a_dependency_thread_leaves_the_end_to_the_interpreter():
    p = _run("pool")
    assert p.returncode == 4, p.stderr
    assert "atexit ran" in p.stdout and "prefetch finished" in p.stdout
