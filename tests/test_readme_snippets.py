"""The README's Python example and the getting-started page's snippets run as written from the
clone root (issue 26 item 7: they used ``image`` and ``dem`` without saying how to read them, and
``read_bal`` pointed at a file that is not in the clone; issue 38: the README's example is the whole
chain, GCPs to a written orthophoto, in ten lines)."""

import os
import pathlib
import re

import numpy as np
import pytest
import rasterio
from conftest import SHARED_DATA

import photax

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _snippets(page="docs/getting-started.md"):
    return re.findall(r"```python\n(.*?)```", (ROOT / page).read_text(), flags=re.S)


def test_readme_example_is_ten_lines_and_writes_the_ortho_of_the_true_orientation(tmp_path, monkeypatch):
    (code,) = _snippets("README.md")
    assert len(code.strip().splitlines()) <= 10
    (tmp_path / "data").symlink_to(ROOT / "data", target_is_directory=True)  # a clone's root, written to tmp
    monkeypatch.chdir(tmp_path)
    ns = {}
    exec(compile(code, "README.md", "exec"), ns)
    with rasterio.open(tmp_path / "ortho.tif") as src:
        written, crs = src.read(1), src.crs
    assert crs.to_epsg() == 32633 and written.shape == ns["grid"].shape
    # the truth: the same ortho from the sample's true orientation (data/sample_truth.json)
    exterior, _ = photax.io.read_exterior(ROOT / "data" / "sample_truth.json", "IMG_0001")
    true, grid = photax.orthorectify(ns["image"], exterior, ns["camera"], ns["dem"], ns["grid"])
    both = (written > 0) & (true > 0)
    assert both.mean() > 0.3  # the footprint, turned by kappa = 35 deg, fills half the grid
    assert np.abs(written[both].astype(float) - true[both]).mean() < 3.0  # grey levels of 0-255
    assert ns["res"].outliers[list(ns["gcps"].names).index("P07")]  # the planted blunder is found


def test_resection_and_rectification_snippets_run(monkeypatch):
    monkeypatch.chdir(ROOT)
    ns = {}
    resection, rectification = _snippets()[:2]
    # up to the model comparison (a relief scene and five fits: a minute, tested in test_compare.py)
    for code in (resection, rectification.split("\nscene = ")[0]):
        exec(compile(code, "docs/getting-started.md", "exec"), ns)
    assert ns["ortho"].shape == ns["grid"].shape and ns["out"].ndim == 2


def test_bal_snippet_names_a_file_that_exists_from_the_clone_root():
    code = _snippets()[2]
    name = re.search(r'read_bal\(data / "([^"]+)"\)', code).group(1)  # data: the public data sets' folder
    if not SHARED_DATA.is_dir():
        pytest.skip(f"{SHARED_DATA}: the public data sets are not beside this checkout")
    assert os.path.isfile(SHARED_DATA / name)
