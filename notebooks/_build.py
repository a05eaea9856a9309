"""What every notebooks/build_*.py script shares: its ``CELLS`` written as a
notebook without outputs (tests/test_notebooks.py executes it).

``CELLS`` is a list of ``("md" | "code", source)``.
"""

import pathlib

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

#: The notebooks' finder of the shared data (``../../shared/data`` beside the clone), pasted into
#: each notebook that reads it (a notebook runs on its own, so the function is in its cells).
FIND_SHARED = '''def find_shared(name):
    """../../shared/data/<name> relative to this notebook (or the current folder)."""
    here = pathlib.Path.cwd()
    for base in (here / "../../shared/data", here / "../shared/data", here / "shared/data"):
        if (base / name).is_file():
            return (base / name).resolve()
    return None
'''


def write_notebook(cells, name: str) -> pathlib.Path:
    """Write ``cells`` to ``notebooks/<name>`` (a Python 3 kernel, no outputs) and say so."""
    nb = new_notebook()
    nb.cells = [new_markdown_cell(src) if kind == "md" else new_code_cell(src) for kind, src in cells]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nb.metadata["language_info"] = {"name": "python"}
    out = pathlib.Path(__file__).with_name(name)
    nbformat.write(nb, out)
    print("wrote", out)
    return out
