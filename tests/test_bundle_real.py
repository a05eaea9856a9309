"""Real data: BAL problem-49-7776 converges at least as far as Ceres.

Ceres runs in the test (pycolmap's C++ RADIAL reprojection cost, which is
BAL's camera; see benchmarks/bench_bundle.py), LM with DENSE_SCHUR, no
robust loss, Ceres' default tolerances.  COLMAP zeroes the residual of a
point behind its camera where BAL's formula does not, so the 10 such points
are dropped for both solvers.  Both final costs are recomputed from the
solvers' output parameters with the numpy BAL formula.
"""

import importlib.util

import numpy as np
import pytest
from conftest import ROOT, shared_file

from photax.io.bal import bal_problem, read_bal_arrays


def _bench():
    spec = importlib.util.spec_from_file_location("bench_bundle", ROOT / "benchmarks" / "bench_bundle.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_problem_49_reaches_ceres_cost():
    pytest.importorskip("pyceres")
    pytest.importorskip("pycolmap")
    bench = _bench()
    d = bench.drop_points_behind(read_bal_arrays(shared_file("problem-49-7776-pre.txt")))
    assert (len(d.points), len(d.observations)) == (7766, 31812)

    solve, to_bal = bench.ceres_bal(d, "DENSE_SCHUR", num_threads=2)
    summary = solve()
    ceres_cost = bench.bal_cost(*to_bal(), d)
    # Same model: Ceres' own cost equals the BAL formula at its solution.
    assert ceres_cost == pytest.approx(summary.final_cost, rel=1e-9)
    assert ceres_cost < 1.34e4  # and it converged far below the start (8.5e5)

    result = bench.photax_bal(bal_problem(d))
    assert result.converged, result.message
    ours = bench.bal_cost(*bench.photax_solution(result), d)
    assert ours == pytest.approx(result.cost, rel=1e-9)
    # Both stop on the same rule, |dcost|/cost <= 1e-6 between iterations;
    # a remaining difference below that resolution is not a difference.
    assert ours <= ceres_cost * (1.0 + 1e-6), (ours, ceres_cost)


def test_bench_helpers_model_equivalence():
    # The COLMAP mapping really is BAL's camera: before any solve, Ceres'
    # initial cost equals the numpy BAL cost of the same data.
    pytest.importorskip("pycolmap")
    bench = _bench()
    d = bench.drop_points_behind(read_bal_arrays(shared_file("dubrovnik-3-7-pre.txt")))
    solve, to_bal = bench.ceres_bal(d, "DENSE_SCHUR", num_threads=1)
    cams, pts = to_bal()
    np.testing.assert_allclose(cams, d.cameras, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(pts, d.points, rtol=0, atol=0)
    summary = solve()
    assert summary.initial_cost == pytest.approx(bench.bal_cost(d.cameras, d.points, d), rel=1e-12)
