"""The ``Examples`` of photax's public names run, as doctests.

Each example builds small synthetic data with known truth (a closed form, a round trip through a
writer and its reader, or a :mod:`photax.scene` with its truth) and shows a check against it, so
an example that stops being true fails here.  Run by :mod:`doctest` on each public object's own
docstring (``pytest``'s ``addopts`` are left alone), with the suite's warning filters: a warning an
example triggers is an error.

The public names are those of ``photax/__init__.pyi`` and of the public subpackages
:mod:`photax.io`, :mod:`photax.measure` and :mod:`photax.fusion` (the API reference has a page for
each).  :data:`MIN_WITH_EXAMPLES` is the count reached: it may only go up.
"""

from __future__ import annotations

import doctest
import importlib

import pytest

import photax
from photax._lazy import stub_names

ENTRY_POINTS = [
    "resect", "resect_batch", "intersect", "fit_polynomial", "fit_projective", "rectify", "orthorectify",
    "compare_models", "bundle_adjust", "register_to_ortho", "ortho_uncertainty", "disparity",
]  # fmt: skip

#: Public names with a doctested Examples section (13 of 207 before issue 38, 146 of 234 before its leftover).
MIN_WITH_EXAMPLES = 227


def _public() -> dict[str, object]:
    """``{full name: object}`` of every public function and class."""
    top, _, _ = stub_names(photax.__file__)
    names = [f"photax.{n}" for n in top]
    for sub in ("io", "measure", "fusion"):
        module = importlib.import_module(f"photax.{sub}")
        public = getattr(module, "__all__", None) or [n for n in vars(module) if not n.startswith("_")]
        names += [f"photax.{sub}.{n}" for n in public]
    out = {}
    for full in sorted(set(names)):
        module, _, name = full.rpartition(".")
        obj = getattr(importlib.import_module(module), name)
        if isinstance(obj, type) or callable(obj):  # not data (RESULTS' members, METHODS) nor modules
            if not isinstance(obj, type(photax)):
                out[full] = obj
    return out


PUBLIC = _public()


def _tests(full: str):
    return [t for t in doctest.DocTestFinder(recurse=False).find(PUBLIC[full], full, globs={}) if t.examples]


WITH = [full for full in PUBLIC if _tests(full)]
# Each object once: photax.read_gcps is photax.io.read_gcps (the first name of each runs).
RUN = list({id(PUBLIC[full]): full for full in reversed(WITH)}.values())[::-1]


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_entry_points_show_enough(name):
    function = getattr(photax, name)
    assert "\n    Examples:\n" in function.__doc__, f"{name} has no Examples section"
    assert sum(len(t.examples) for t in _tests(f"photax.{name}")) >= 3, f"{name}'s Examples show too little"


def test_examples_do_not_regress(capsys):
    lacking = sorted(set(PUBLIC) - set(WITH))
    with capsys.disabled():
        print(f"\n{len(WITH)} of {len(PUBLIC)} public names have Examples; still lacking {len(lacking)}:")
        print("  " + ", ".join(lacking))
    assert len(WITH) >= MIN_WITH_EXAMPLES, f"only {len(WITH)} public names have Examples"


@pytest.mark.parametrize("name", RUN)
def test_examples_run(name):
    report: list[str] = []
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in _tests(name):
        runner.run(test, out=report.append)
    assert runner.failures == 0, "".join(report)
