"""Every notebooks/*.ipynb runs top to bottom (one test per notebook).

The kernel is this interpreter (a kernelspec written to a temporary folder,
so a ``python`` elsewhere on PATH cannot be picked up), started in
notebooks/ so relative paths in the notebooks work.  A cell that raises
fails the test, and so does a warning a cell prints on stderr.
"""

import json
import pathlib
import sys

import pytest
from conftest import ROOT

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
from jupyter_client.kernelspec import KernelSpecManager  # noqa: E402
from jupyter_client.manager import AsyncKernelManager  # noqa: E402

NB_DIR = ROOT / "notebooks"
NOTEBOOKS = sorted(NB_DIR.glob("*.ipynb"))


@pytest.fixture(scope="module")
def kernel_dir(tmp_path_factory) -> pathlib.Path:
    spec_dir = tmp_path_factory.mktemp("kernels") / "photax-test"
    spec_dir.mkdir()
    spec = {"argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
            "display_name": "photax test kernel", "language": "python"}
    (spec_dir / "kernel.json").write_text(json.dumps(spec))
    return spec_dir.parent


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, kernel_dir):
    nb = nbformat.read(path, as_version=4)
    # One extra cell: prove the kernel is this interpreter.
    nb.cells.append(nbformat.v4.new_code_cell("import sys; print(sys.executable)"))
    km = AsyncKernelManager(kernel_name="photax-test", kernel_spec_manager=KernelSpecManager(kernel_dirs=[str(kernel_dir)]))
    client = nbclient.NotebookClient(nb, km=km, timeout=600, resources={"metadata": {"path": str(NB_DIR)}})
    client.execute(cleanup_kc=True)  # we made km, so nbclient would leave the kernel running
    printed = "".join(o.get("text", "") for o in nb.cells[-1].outputs)
    assert pathlib.Path(printed.strip()).resolve() == pathlib.Path(sys.executable).resolve()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"]
    assert not errors
    # No warning printed by a cell either (e.g. tqdm's TqdmWarning when ipywidgets is missing).
    warned = [o.text for c in nb.cells if c.cell_type == "code" for o in c.outputs
              if o.output_type == "stream" and o.name == "stderr" and "Warning" in o.text]
    assert not warned, warned
