"""The ``Examples`` of photax's top-level entry points run, as doctests, on :mod:`photax.scene` data.

Each example builds a synthetic scene with known truth and shows a check against it (a position
within 3 sigma, a check-point error of the noise's size, a correlation with the true orthophoto),
so an example that stops being true fails here.  Run by :mod:`doctest` on each function's
docstring only (``pytest``'s ``addopts`` are left alone), with the suite's warning filters: a
warning an example triggers is an error.
"""

from __future__ import annotations

import doctest

import pytest

import photax

ENTRY_POINTS = [
    "resect", "resect_batch", "intersect", "fit_polynomial", "fit_projective", "rectify", "orthorectify",
    "compare_models", "bundle_adjust", "register_to_ortho", "ortho_uncertainty", "disparity",
]  # fmt: skip


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_examples_run(name):
    function = getattr(photax, name)
    assert "\n    Examples:\n" in function.__doc__, f"{name} has no Examples section"
    tests = doctest.DocTestFinder(recurse=False).find(function, name, globs={})
    assert sum(len(t.examples) for t in tests) >= 3, f"{name}'s Examples show too little"
    report: list[str] = []
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in tests:
        runner.run(test, out=report.append)
    assert runner.failures == 0, "".join(report)
