"""The ``photax`` process's start-up (issue 21 item 4): what it does differently from a library
call, and that the outputs do not change."""

import subprocess
import sys

from conftest import ROOT, sample_ortho, scaled

# photax ortho's work (orthorectify_file / orthorectify_files) replaced by a probe of the garbage
# collector's state: paused through the start-up, on (with start-up's objects frozen) for the work.
_GC_SCRIPT = """
import gc, sys
import photax.rectification as r
import photax.cli.ortho as o

seen = {}
run = o.run
def probe_run(args):
    seen["start-up"] = gc.isenabled()
    return run(args)
def probe_work(*a, **k):
    seen["work"] = gc.isenabled()
    seen["frozen"] = gc.get_freeze_count() > 0
    print(seen, flush=True)
    return []
o.run, r.orthorectify_files, r.orthorectify_file = probe_run, probe_work, probe_work
from photax.cli import main
if sys.argv[1] == "process":
    sys.argv = ["photax", *sys.argv[2:]]
    main()
else:
    main(sys.argv[2:])
    print({"after": gc.isenabled(), "frozen": gc.get_freeze_count() > 0}, flush=True)
"""


def _probe(tmp_path, kind, *out):
    args = [*sample_ortho(), *out]
    env = {"PYTHONPATH": str(ROOT / "src"), "PATH": "", "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "cache")}
    p = subprocess.run(
        [sys.executable, "-c", _GC_SCRIPT, kind, *args], capture_output=True, text=True, env=env, timeout=scaled(300)
    )
    return p


def test_the_process_starts_without_cyclic_gc_and_works_with_it(tmp_path):
    for out in (["--out", str(tmp_path / "o.tif")], ["--out-dir", str(tmp_path / "d")]):
        p = _probe(tmp_path, "process", *out)
        assert p.returncode == 0, p.stderr
        assert "{'start-up': False, 'work': True, 'frozen': True}" in p.stdout, (p.stdout, p.stderr)


def test_an_in_process_main_leaves_the_collector_alone(tmp_path):
    p = _probe(tmp_path, "in-process", "--out", str(tmp_path / "o.tif"))
    assert p.returncode == 0, p.stderr
    assert "{'start-up': True, 'work': True, 'frozen': False}" in p.stdout, (p.stdout, p.stderr)
    assert "{'after': True, 'frozen': False}" in p.stdout
