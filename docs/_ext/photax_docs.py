"""Sphinx extension of photax's site: the API reference and the CLI reference are generated, not
written by hand, so that neither falls behind the code.

* ``api/``: one page per public name (the names of ``photax/__init__.pyi`` and of the public
  subpackages :mod:`photax.io`, :mod:`photax.measure` and :mod:`photax.fusion`), grouped by the
  stage of the pipeline the name's module belongs to, and an index of the groups.  Written at
  ``builder-inited`` into ``docs/api/`` (ignored by git), each file only when its text changed.
* ``notebooks/``: ``notebooks/*.ipynb`` of the repository copied beside the pages (Sphinx reads
  only its source folder); rendered by myst-nb with their stored outputs, not executed.
* ``.. photax-cli::``: the ``photax`` command's parser (:func:`photax.cli.build_parser`) walked: a
  section per subcommand with its description and its ``--help`` text, as the command prints it.
"""

from __future__ import annotations

import ast
import importlib
import pathlib
import shutil

from docutils import nodes
from docutils.parsers.rst import Directive

DOCS = pathlib.Path(__file__).resolve().parents[1]
ROOT = DOCS.parent
SRC = ROOT / "src" / "photax"

#: Pipeline stages: (title, one line, the modules of photax whose names go there).  A module's
#: name is matched by its dotted path below ``photax`` (``"io"`` covers ``photax.io.*``).
STAGES = [
    ("Model: cameras, orientations, rotations, terrain",
     "The ground floor: camera models, exterior orientation and the collinearity equations, rotation "
     "conventions, the DEM and the output grid, satellite sensors, the earth and its coordinate systems.",
     ["camera", "collinearity", "rotation", "dem", "grid", "sensor", "earth", "geo", "rpc", "pushbroom"]),
    ("Estimation: resection, intersection, bundle adjustment",
     "Orientations and their precision from measurements: space resection, intersection, interior "
     "orientation of scans, bundle adjustment, georeferencing, RPC refinement and block adjustment.",
     ["resection", "intersection", "interior", "bundle", "georeferencing", "rpc_block"]),
    ("Rectification models",
     "Plane-to-plane models fitted to control points: polynomials of order 1-5, projective, "
     "thin-plate spline, piecewise affine.",
     ["polynomial"]),
    ("Rectification, orthorectification and resampling",
     "Images onto a map grid: rectification by a fitted model, orthorectification with a camera and "
     "a DEM (in memory, on files, on Dask), the resampling kernels.",
     ["rectification", "resampling"]),
    ("Products: mosaics, uncertainty, fusion, morphing",
     "What is made from orthos: seamline mosaics, per-pixel geolocation uncertainty, pan-sharpening, "
     "morphing.",
     ["mosaicking", "uncertainty", "fusion", "morphing"]),
    ("Matching and registration",
     "Points found between images: GCP transfer, tie points, epipolar pairs, registration to an "
     "ortho and image-to-image co-registration.",
     ["matching"]),
    ("Surfaces: dense stereo, point clouds, DSMs",
     "Disparities of epipolar pairs triangulated into points, rasterised into DSMs and fused.",
     ["stereo"]),
    ("Image measurement (photax.measure)",
     "Edge and interest operators, the Hough transform and the sub-pixel locators.",
     ["measure"]),
    ("Files (photax.io)",
     "Readers and writers of photogrammetric files (the formats page tells them apart by family).",
     ["io"]),
    ("Synthetic scenes, comparisons and errors",
     "Scenes with known truth (the examples' data), the comparison of rectification models, "
     "photax's outcome codes and errors.",
     ["scene", "compare", "errors"]),
]  # fmt: skip

#: Public subpackages documented name by name besides the top level.
SUBPACKAGES = ["io", "measure", "fusion"]


def _stub_names(path: pathlib.Path) -> dict[str, str]:
    """``{public name: module below photax}`` of a package's ``__init__.pyi`` or ``__init__.py``:
    its ``from .module import name as name`` lines (submodules and private names left out)."""
    package = ".".join(path.parent.relative_to(SRC.parent).parts)
    out = {}
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.ImportFrom) and node.level >= 1 and node.module:
            base = package.split(".")[: len(package.split(".")) - node.level + 1]
            module = ".".join([*base, node.module])
            for a in node.names:
                if a.asname in (None, a.name) and not a.name.startswith("_"):
                    out[a.name] = module
    return out


def public_names() -> dict[str, str]:
    """``{full public name: its defining module}``, e.g. ``{"photax.resect": "photax.resection"}``:
    every name of ``photax/__init__.pyi`` and of the public subpackages."""
    names = {f"photax.{n}": m for n, m in _stub_names(SRC / "__init__.pyi").items()}
    for sub in SUBPACKAGES:
        init = SRC / sub / "__init__.pyi"
        if not init.exists():
            init = SRC / sub / "__init__.py"
        names.update({f"photax.{sub}.{n}": m for n, m in _stub_names(init).items()})
    return names


def stage_of(module: str) -> int:
    """The index in :data:`STAGES` of the module ``photax.<...>``."""
    parts = module.split(".")[1:]
    for k, (_, _, modules) in enumerate(STAGES):
        if parts and parts[0] in modules:
            return k
    raise ValueError(f"{module}: no stage in docs/_ext/photax_docs.py STAGES names it")


def _write(path: pathlib.Path, text: str) -> None:
    """Write ``text`` unless the file holds it already (Sphinx then rebuilds nothing)."""
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)


def _kind(full: str) -> str:
    module, _, name = full.rpartition(".")
    obj = getattr(importlib.import_module(module), name)
    if isinstance(obj, type):
        return "class"
    if callable(obj):
        return "function"
    return "data"


def _page(full: str) -> str:
    module, _, name = full.rpartition(".")
    kind = _kind(full)
    title = f"{full}\n{'=' * len(full)}\n\n.. currentmodule:: {module}\n\n"
    if kind == "class":
        return title + f".. autoclass:: {name}\n   :members:\n   :show-inheritance:\n"
    if kind == "function":
        return title + f".. autofunction:: {name}\n"
    return title + f".. autodata:: {name}\n   :no-value:\n"


def generate_api(app=None) -> dict[str, str]:
    """Write ``docs/api/<full name>.rst`` for every public name and ``docs/api/index.rst``; remove
    pages of names no longer public.  Returns :func:`public_names`."""
    names = public_names()
    api = DOCS / "api"
    groups: dict[int, list[str]] = {}
    for full, module in names.items():
        groups.setdefault(stage_of(module), []).append(full)
    for full in names:
        _write(api / f"{full}.rst", _page(full))
    for old in api.glob("photax*.rst"):
        if old.stem not in names:
            old.unlink()
    lines = [
        "API reference",
        "=============",
        "",
        "Every public name of photax, grouped by the stage of the pipeline it belongs to; "
        "``import photax as ptx`` gives the top-level names, the subpackages "
        ":mod:`photax.io`, :mod:`photax.measure` and :mod:`photax.fusion` the others.  "
        "Conventions (frames, angles, units) are on :doc:`../conventions`.",
        "",
    ]
    for k, (title, blurb, _) in enumerate(STAGES):
        members = sorted(groups.get(k, []), key=lambda f: (f.count("."), f.lower()))
        if not members:
            continue
        lines += [title, "-" * len(title), "", blurb, "", ".. autosummary::", ""]
        lines += [f"   {full}" for full in members]
        lines += ["", ".. toctree::", "   :hidden:", ""] + [f"   {full}" for full in members] + [""]
    _write(api / "index.rst", "\n".join(lines))
    return names


def copy_notebooks(app=None) -> list[str]:
    """``notebooks/*.ipynb`` -> ``docs/notebooks/`` (changed ones only); returns their stems."""
    out = DOCS / "notebooks"
    out.mkdir(exist_ok=True)
    stems = []
    for nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
        target = out / nb.name
        if not target.exists() or target.read_bytes() != nb.read_bytes():
            shutil.copyfile(nb, target)
        stems.append(nb.stem)
    for old in out.glob("*.ipynb"):
        if old.stem not in stems:
            old.unlink()
    index = ["# Tutorials (notebooks)", "",
             "The notebooks of `notebooks/` in the repository, rendered as they are stored (the test "
             "suite runs them top to bottom; open them in Jupyter to run them: "
             "`pip install -e \".[notebooks]\" && jupyter lab notebooks/`).", "",
             "```{toctree}", ":maxdepth: 1", "", *stems, "```", ""]  # fmt: skip
    _write(out / "index.md", "\n".join(index))
    return stems


def _help(parser) -> nodes.literal_block:
    """A parser's ``--help`` as a literal block of plain text (not highlighted as code)."""
    text = parser.format_help()
    block = nodes.literal_block(text, text)
    block["language"] = "text"
    return block


class CLIDirective(Directive):
    """``.. photax-cli::`` -- every subcommand of ``photax``: its description and ``--help``."""

    has_content = False

    def run(self):
        from photax.cli import SUBCOMMANDS, build_parser

        parser = build_parser()
        result = []
        top = nodes.section(ids=["photax-command"], names=["photax"])
        top += nodes.title(text="photax")
        top += _help(parser)
        result.append(top)
        for name in SUBCOMMANDS:
            sub = parser.subcommands[name]
            section = nodes.section(ids=[f"photax-{name}"], names=[f"photax {name}"])
            section += nodes.title(text=f"photax {name}")
            if sub.description:
                section += nodes.paragraph(text=" ".join(sub.description.split()))
            section += _help(sub)
            result.append(section)
        return result


def setup(app):
    app.connect("builder-inited", generate_api)
    app.connect("builder-inited", copy_notebooks)
    app.add_directive("photax-cli", CLIDirective)
    return {"parallel_read_safe": True, "parallel_write_safe": True, "version": "1"}
