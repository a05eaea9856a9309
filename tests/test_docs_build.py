"""The documentation site builds with the documented command, warnings as errors
(``sphinx-build -W -b html docs docs/_build/html``, here into ``tmp_path``), and has a page for every
public name and a section for every ``photax`` subcommand.

The public names are read here independently of ``docs/_ext/photax_docs.py`` (which writes the
pages): from ``photax/__init__.pyi`` through :func:`photax._lazy.stub_names` and from the public
subpackages' ``__all__``; the subcommands from :data:`photax.cli.SUBCOMMANDS` and the parser itself.
"""

import argparse
import html
import importlib
import os
import re
import subprocess
import sys

import pytest
from conftest import ROOT

pytest.importorskip("sphinx")
pytest.importorskip("pydata_sphinx_theme")
pytest.importorskip("myst_nb")

import photax  # noqa: E402
from photax._lazy import stub_names  # noqa: E402


def _public_names() -> list[str]:
    top, _, _ = stub_names(photax.__file__)
    names = [f"photax.{n}" for n in top]
    for sub in ("io", "measure", "fusion"):
        module = importlib.import_module(f"photax.{sub}")
        public = getattr(module, "__all__", None) or [n for n in vars(module) if not n.startswith("_")]
        names += [f"photax.{sub}.{n}" for n in public if not isinstance(getattr(module, n, None), type(photax))]
    return sorted(set(names))


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    out = tmp_path_factory.mktemp("html")
    env = dict(os.environ, PYTHONWARNINGS="ignore", JAX_PLATFORMS="cpu")
    cmd = [sys.executable, "-m", "sphinx", "-W", "-b", "html", "-q", "docs", str(out)]
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    return out


def test_every_public_name_has_a_page_with_its_docstring(site):
    names = _public_names()
    assert len(names) > 150  # photax, photax.io, photax.measure, photax.fusion
    missing = [n for n in names if not (site / "api" / f"{n}.html").is_file()]
    assert not missing, f"no API page for {missing}"
    index = (site / "api" / "index.html").read_text(encoding="utf-8")
    assert not [n for n in names if f"{n}.html" not in index], "the API index does not link every page"
    page = (site / "api" / "photax.orthorectify.html").read_text(encoding="utf-8")
    assert 'id="photax.orthorectify"' in page and "collinearity" in page  # the object and its docstring


def test_cli_page_lists_every_subcommand_with_its_options(site):
    from photax.cli import SUBCOMMANDS, build_parser

    page = (site / "cli.html").read_text(encoding="utf-8")
    text = html.unescape(re.sub(r"<[^>]+>", "", page))  # the page's text, as a reader sees it
    parser = build_parser()
    assert len(SUBCOMMANDS) == len(parser.subcommands) >= 16
    for name in SUBCOMMANDS:
        assert f'id="photax-{name}"' in page, f"photax {name} has no section"
        for action in parser.subcommands[name]._actions:  # every option its --help shows
            if action.help == argparse.SUPPRESS:  # old spellings kept working, not shown
                continue
            for opt in action.option_strings:
                assert opt in text, f"photax {name}: {opt} not on the CLI page"


def test_notebooks_and_pages_are_in_the_site(site):
    for nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
        assert (site / "notebooks" / f"{nb.stem}.html").is_file(), nb.name
    for page in ("getting-started", "guide", "cli", "formats", "conventions", "maths", "architecture", "performance"):
        assert (site / f"{page}.html").is_file(), page
    assert (site / "_images" / "sample_ortho.png").is_file() or (site / "_static" / "sample_ortho.png").is_file()
