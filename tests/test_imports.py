"""The package's import graph has no cycle, and every module imports.

The graph is read statically (``ast``) from every ``import`` statement in
``src/photax`` -- module level *and* inside functions: a deferred import
that only exists to break a cycle is still a cycle in the design.  Edges go
from a module to the photax modules it names; a package's ``__init__`` is
its own node (``photax.io``), and importing ``photax.io.gcp`` from outside
``photax.io`` also imports ``photax.io`` (Python runs the package's
``__init__`` first), so that edge counts too.
"""

from __future__ import annotations

import ast
import importlib
import os
import pathlib
import subprocess
import sys

import pytest
from conftest import scaled

import photax

SRC = pathlib.Path(photax.__file__).resolve().parent


def _module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _graph() -> dict[str, set[str]]:
    """``{module: {photax modules it imports}}`` for every ``.py`` under ``src/photax``."""
    files = {_module_name(p): p for p in SRC.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        is_pkg = path.name == "__init__.py"
        package = name if is_pkg else name.rpartition(".")[0]
        edges: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[: len(base) - (node.level - 1)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                # "from pkg import sub" names the submodule when there is one.
                subs = [f"{mod}.{a.name}" for a in node.names if f"{mod}.{a.name}" in files]
                targets = subs if subs and len(subs) == len(node.names) else [mod, *subs]
            else:
                continue
            for t in targets:
                # Python imports every enclosing package first, unless we are inside it.
                parts = t.split(".")
                for k in range(2, len(parts) + 1):
                    anc = ".".join(parts[:k])
                    if anc in files and anc != name and not (name + ".").startswith(anc + "."):
                        edges.add(anc)
        graph[name] = edges
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as ``[a, b, ..., a]``, or None (depth-first search)."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return stack[stack.index(n) :] + [n]
            if n not in state and (found := visit(n)):
                return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_cycle_finder_finds_a_planted_cycle():
    # The checker itself must be able to fail.
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_graph_sees_known_edges():
    g = _graph()
    assert "photax.collinearity" in g["photax.bundle._problem"]
    assert "photax.camera" in g["photax.intersection"]
    assert {"photax.io", "photax.io.results"} <= g["photax.demo"]  # the package's __init__ runs first
    assert "photax.io" not in g["photax.io.gcp"]  # ... but not for its own modules
    assert len(g) > 30


def test_no_import_cycle():
    cycle = _cycle(_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


# --- private names stay inside their unit ------------------------------------

# Private utility modules other units may import from (each says so in its docstring).
PRIVATE_UTILITIES = (
    "photax._aot",
    "photax._values",
    "photax._rasterio",
    "photax._deprecation",
    "photax._float64",
    "photax._lazy",
    "photax._linalg",
    "photax._triangulation",
    "photax._pytree",
)


def _unit(module: str) -> str:
    """The top-level unit of a module: ``photax.rectification._files`` -> ``photax.rectification``."""
    return ".".join(module.split(".")[:2])


def _private_crossings(sources: dict[str, tuple[str, bool]]) -> list[str]:
    """``"importer: module.name"`` for every private name (``_x``, or any name reached through a
    private module) imported from another top-level unit, outside :data:`PRIVATE_UTILITIES`.
    ``sources``: ``{module: (source text, is a package __init__)}``."""
    found = []
    for name, (text, is_pkg) in sources.items():
        package = name if is_pkg else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    mod = ".".join(base[: len(base) - (node.level - 1)] + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [f"{mod}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            for t in targets:
                if t.split(".")[0] != "photax" or _unit(t) == _unit(name):
                    continue
                if any(t == m or t.startswith(m + ".") for m in PRIVATE_UTILITIES):
                    continue
                if any(s.startswith("_") and not s.startswith("__") for s in t.split(".")[1:]):
                    found.append(f"{name}: {t}")
    return sorted(found)


def test_crossing_finder_finds_planted_crossings():
    src = {
        "photax.a": ("from .rectification._tiling import tiles\nfrom .b import _x\nfrom ._linalg import inv3", False),
        "photax.rectification._dask": ("from ._tiling import _tiles\nfrom ..resampling import _source", False),
        "photax.cli": ("from photax import _aot\nimport photax.bundle._schur", True),
    }
    assert _private_crossings(src) == [
        "photax.a: photax.b._x",
        "photax.a: photax.rectification._tiling.tiles",
        "photax.cli: photax.bundle._schur",
        "photax.rectification._dask: photax.resampling._source",
    ]


def test_no_private_name_crosses_units():
    sources = {_module_name(p): (p.read_text(), p.name == "__init__.py") for p in SRC.rglob("*.py")}
    assert _private_crossings(sources) == []
    for m in PRIVATE_UTILITIES:  # and each says what it is
        doc = ast.get_docstring(ast.parse(sources[m][0])) or ""
        assert "Private utility module" in doc, m


@pytest.mark.parametrize("name", sorted(_module_name(p) for p in SRC.rglob("*.py")))
def test_every_module_imports(name):
    assert importlib.import_module(name).__name__ == name


# --- start-up: lazy public names ---------------------------------------------


@pytest.mark.parametrize("package", ["photax", "photax.io"])
def test_the_stub_is_the_one_list_of_public_names(package):
    # photax/__init__.pyi (photax.io's too) names every public name once; each resolves to the object
    # of the module the stub names, and dir() lists exactly these (no TYPE_CHECKING, os, sys, ...).
    from photax._lazy import stub_names

    mod = importlib.import_module(package)
    names, submodules, version = stub_names(mod.__file__)
    public = {*names, *submodules, *(["__version__"] if version else [])}
    assert dir(mod) == sorted(public) == mod.__all__
    for name, home in sorted(names.items()):
        assert getattr(mod, name) is getattr(importlib.import_module(home, package), name), name
    for name in submodules:
        assert getattr(mod, name) is importlib.import_module(f"{package}.{name}")
    with pytest.raises(AttributeError, match="no_such_name"):
        mod.no_such_name  # noqa: B018


def test_readers_of_the_readme_are_top_level():
    import photax.io

    for name in ("read_geotiff", "read_dem", "write_geotiff"):
        assert getattr(photax, name) is getattr(photax.io, name)
    assert not {"TYPE_CHECKING", "annotations", "importlib", "os", "sys"} & set(dir(photax))


def test_stub_reader_refuses_what_it_cannot_mirror(tmp_path):
    from photax._lazy import stub_names

    (tmp_path / "__init__.pyi").write_text("from .a import x as y\n")
    with pytest.raises(ValueError, match="line 1"):
        stub_names(tmp_path / "__init__.py")
    (tmp_path / "__init__.pyi").write_text(
        '"""doc"""\nfrom . import sub as sub\nfrom .a import x as x, z\n__version__: str\n'
    )
    assert stub_names(tmp_path / "__init__.py") == ({"x": ".a", "z": ".a"}, {"sub"}, True)


def test_the_stubs_ship():
    # setuptools installs only .py files unless package-data names the stubs.
    import tomllib

    data = tomllib.loads((SRC.parents[1] / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    assert "*.pyi" in data["photax"] and (SRC / "__init__.pyi").is_file() and (SRC / "io" / "__init__.pyi").is_file()


def test_cli_choices_are_the_library_lists():
    # written out in cli/_common.py so that --help needs no JAX
    from photax.cli import _common
    from photax.resampling import RESAMPLING
    from photax.rotation import CONVENTIONS

    assert _common.RESAMPLING == RESAMPLING
    assert _common.CONVENTIONS == CONVENTIONS


_PROBE = """
import sys
import photax
after_import = sorted(m for m in {heavy} if m in sys.modules)
from photax.cli import build_parser
text = build_parser().format_help()
after_help = sorted(m for m in {heavy} if m in sys.modules)
import jax.numpy as jnp
print(after_import, after_help, "ortho" in text, jnp.zeros(1).dtype)
"""


def test_import_photax_and_help_load_no_heavy_module():
    # One cheap subprocess: a fresh interpreter is the only honest place to
    # see what ``import photax`` and building the CLI parser pull in.
    heavy = ("jax", "numpy", "scipy", "scipy.stats", "rasterio", "matplotlib", "equinox", "optimistix")
    env = {k: v for k, v in os.environ.items() if k != "JAX_ENABLE_X64"}
    out = subprocess.run(
        [sys.executable, "-c", _PROBE.format(heavy=heavy)],
        capture_output=True,
        text=True,
        env=env,
        timeout=scaled(120),
        check=True,
    ).stdout.split()
    # and 64-bit mode is still on when JAX comes later
    assert out == ["[]", "[]", "True", "float64"], out


# --- stages: imports point one way ----------------------------------------------

# The floor: CRS rules and errors (photax.geo), which import nothing of photax but the errors.
FLOOR = {"photax.geo": {"photax.errors"}, "photax.errors": set()}
# The models and the estimators: none of them reads or writes a file, makes a product or parses a command
# line, so none imports those stages (issue 34: bundle/_problem imported io/crs, the one upward arrow).
MODELS_AND_ESTIMATORS = (
    "photax.geo", "photax.rotation", "photax.camera", "photax.collinearity", "photax.dem", "photax.earth",
    "photax.rpc", "photax.rpc_block", "photax.pushbroom", "photax.sensor", "photax.grid", "photax.polynomial",
    "photax.resection", "photax.bundle", "photax.intersection", "photax.kernels", "photax.resampling",
    "photax.measure", "photax.interior",
)  # fmt: skip
HIGHER = ("photax.io", "photax.cli", "photax.rectification", "photax.matching", "photax.mosaicking",
          "photax.fusion", "photax.compare", "photax.demo", "photax.uncertainty", "photax.plot", "photax.scene",
          "photax.georeferencing", "photax.morphing")  # fmt: skip


# Known upward arrows, each with its way out (issue 34's package split moves them); nothing else may join.
ALLOWED_UPWARD: dict[str, str] = {}


def _upward(graph: dict[str, set[str]]) -> list[str]:
    """``"importer -> imported"`` for every edge from a lower stage to a higher one, and from the floor
    to anything of photax but what :data:`FLOOR` allows (private utilities aside)."""
    found = []
    for m, edges in graph.items():
        unit = _unit(m)
        for e in sorted(edges):
            if _unit(e) == unit or e in PRIVATE_UTILITIES:
                continue
            if unit in FLOOR and e not in FLOOR[unit]:
                found.append(f"{m} -> {e}")
            elif unit in MODELS_AND_ESTIMATORS and _unit(e) in HIGHER:
                found.append(f"{m} -> {e}")
    return sorted(found)


def test_upward_finder_finds_planted_arrows():
    planted = {
        "photax.bundle._problem": {"photax.io.crs", "photax.geo", "photax.camera"},
        "photax.geo": {"photax.errors", "photax.camera"},
        "photax.io.gcp": {"photax.bundle", "photax.geo"},  # io above the models: allowed
    }
    assert _upward(planted) == ["photax.bundle._problem -> photax.io.crs", "photax.geo -> photax.camera"]


def test_no_lower_stage_imports_a_higher_one():
    assert [a for a in _upward(_graph()) if a not in ALLOWED_UPWARD] == []


def test_one_utm_crs():
    # one rule, keyword-friendly, (lon, lat); its old public home is the same object
    import photax.sensor
    from photax.geo import utm_crs

    assert photax.utm_crs is photax.sensor.utm_crs is utm_crs
    defs = [p for p in SRC.rglob("*.py") if "def utm_crs" in p.read_text()]
    assert defs == [SRC / "geo.py"]
    assert utm_crs(lon=15.2, lat=45.8) == utm_crs(15.2, 45.8) == "EPSG:32633"  # zone 33: 12..18 E
    assert utm_crs(lon=-0.1, lat=-0.1) == "EPSG:32730" and utm_crs(lon=0.0, lat=0.0) == "EPSG:32631"
    assert utm_crs(lon=180.0, lat=10.0) == "EPSG:32660"
