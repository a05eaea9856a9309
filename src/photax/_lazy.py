"""The lazy public names of a package, read from its ``__init__.pyi`` stub.

The stub is the one list of a package's public names: type checkers and IDEs
read it, and :func:`attach_stub` turns its ``from .module import name as name``
lines into a PEP 562 module ``__getattr__`` that imports ``module`` on first
use of ``name`` (``from . import sub as sub``: the submodule itself;
``__version__: str``: the installed distribution's version).  This is
scikit-image's arrangement (``lazy_loader.attach_stub``) in a few lines, so
that ``import photax`` loads neither JAX nor NumPy and no dependency is added.

Private utility module: other photax units import its names directly
(``tests/test_imports.py`` lists the modules allowed that).
"""

from __future__ import annotations

import ast
import importlib
import pathlib
import sys


def stub_names(init_file) -> tuple[dict[str, str], set[str], bool]:
    """``({public name: relative module}, {submodules}, has __version__)`` of the
    ``__init__.pyi`` beside ``init_file``.

    Raises:
        ValueError: a stub line other than ``from .m import x as x``,
            ``from . import sub as sub`` or ``__version__: str`` (a renamed
            or absolute import would make the stub and the package disagree).
    """
    stub = pathlib.Path(init_file).with_suffix(".pyi")
    tree = ast.parse(stub.read_text(encoding="utf-8"), str(stub))
    names: dict[str, str] = {}
    submodules: set[str] = set()
    version = False
    for node in tree.body:
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            continue  # the docstring
        if isinstance(node, ast.AnnAssign) and getattr(node.target, "id", None) == "__version__":
            version = True
            continue
        if not (
            isinstance(node, ast.ImportFrom) and node.level == 1 and all(a.asname in (None, a.name) for a in node.names)
        ):
            raise ValueError(f"{stub}, line {node.lineno}: expected 'from .module import name as name'")
        for a in node.names:
            if node.module is None:
                submodules.add(a.name)
            else:
                names[a.name] = "." + node.module
    return names, submodules, version


def attach_stub(package: str, init_file):
    """``(__getattr__, __dir__, __all__)`` for the package ``package`` whose
    ``__init__.py`` is ``init_file``: its public names are those of the stub,
    each imported on first use and then kept in the module's namespace."""
    names, submodules, version = stub_names(init_file)
    public = sorted([*names, *submodules, *(["__version__"] if version else [])])

    def __getattr__(name: str):
        if name in names:
            value = getattr(importlib.import_module(names[name], package), name)
        elif name in submodules:
            value = importlib.import_module(f".{name}", package)
        elif name == "__version__" and version:
            from importlib.metadata import version as installed

            value = installed(package)
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        setattr(sys.modules[package], name, value)  # later look-ups skip this function
        return value

    def __dir__() -> list[str]:
        return list(public)

    return __getattr__, __dir__, list(public)
