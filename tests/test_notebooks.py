"""Every notebooks/*.ipynb runs top to bottom (one test per notebook).

The kernel is this interpreter (a kernelspec written to a temporary folder,
so a ``python`` elsewhere on PATH cannot be picked up), started in
notebooks/ so relative paths in the notebooks work.  A cell that raises
fails the test, and so does a warning a cell prints on stderr.

All notebooks run in one kernel, one after the other, with the user
namespace emptied (``%reset -f``) and the figures closed between them: a
notebook still cannot use a name another one defined, but the modules it
imports are loaded and their functions traced once, as when a user opens
the notebooks in one Jupyter session (measured: 4 kernels started, imported
and traced the same functions for about 20 of the 67 s the notebooks took).
A notebook that kills the kernel gets a fresh one for the next.
"""

import asyncio
import json
import pathlib
import sys

import pytest
from conftest import ROOT, scaled

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
from jupyter_client.kernelspec import KernelSpecManager  # noqa: E402
from jupyter_client.manager import AsyncKernelManager  # noqa: E402

NB_DIR = ROOT / "notebooks"
NOTEBOOKS = sorted(NB_DIR.glob("*.ipynb"))
# Between notebooks: forget every name, close every figure.
_RESET = "%reset -f\nimport matplotlib.pyplot as _plt\n_plt.close('all')\ndel _plt"


def _kernel_dir(tmp: pathlib.Path) -> pathlib.Path:
    spec_dir = tmp / "photax-test"
    spec_dir.mkdir()
    spec = {
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "photax test kernel",
        "language": "python",
    }
    (spec_dir / "kernel.json").write_text(json.dumps(spec))
    return tmp


async def _run_all(kernel_dir: pathlib.Path) -> dict:
    """Execute every notebook in one kernel: {path: executed notebook or the exception}."""
    specs = KernelSpecManager(kernel_dirs=[str(kernel_dir)])
    km = None
    done = {}
    try:
        for path in NOTEBOOKS:
            if km is None or not await km.is_alive():
                if km is not None:
                    await km.shutdown_kernel(now=True)
                km = AsyncKernelManager(kernel_name="photax-test", kernel_spec_manager=specs)
                await km.start_kernel(cwd=str(NB_DIR))
            nb = nbformat.read(path, as_version=4)
            # First a reset; last, prove the kernel is this interpreter.
            nb.cells.insert(0, nbformat.v4.new_code_cell(_RESET))
            nb.cells.append(nbformat.v4.new_code_cell("import sys; print(sys.executable)"))
            client = nbclient.NotebookClient(
                nb, km=km, timeout=int(scaled(600)), resources={"metadata": {"path": str(NB_DIR)}}
            )
            try:
                done[path] = await client.async_execute(cleanup_kc=False)
            except Exception as exc:  # reported by that notebook's test
                done[path] = exc
            finally:
                if client.kc is not None:
                    client.kc.stop_channels()
    finally:
        if km is not None and km.has_kernel:
            await km.shutdown_kernel(now=True)
    return done


@pytest.fixture(scope="module")
def executed(tmp_path_factory) -> dict:
    return asyncio.run(_run_all(_kernel_dir(tmp_path_factory.mktemp("kernels"))))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, executed):
    nb = executed[path]
    if isinstance(nb, Exception):
        raise nb
    printed = "".join(o.get("text", "") for o in nb.cells[-1].outputs)
    assert pathlib.Path(printed.strip()).resolve() == pathlib.Path(sys.executable).resolve()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"]
    assert not errors
    # No warning printed by a cell either (e.g. tqdm's TqdmWarning when ipywidgets is missing).
    warned = [
        o.text
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.outputs
        if o.output_type == "stream" and o.name == "stderr" and "Warning" in o.text
    ]
    assert not warned, warned
