"""The blunder tests' critical values against scipy.stats.

photax computes them without importing scipy.stats (0.4-0.6 s of every
command's start-up): the normal and Student quantiles through
scipy.special, the two-coordinate ones in closed form.  The reference here
is scipy.stats' own distributions.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from photax.interior._fit import _critical2
from photax.resection._checks import _critical


@pytest.mark.parametrize("alpha", [1e-3, 0.01, 0.05])
@pytest.mark.parametrize("red", [2.0, 3.0, 6.0, 18.0, 200.0])
def test_tau_and_normal(alpha, red):
    assert _critical(alpha, True, red) == pytest.approx(stats.norm.ppf(1 - alpha / 2), rel=1e-12)
    # Pope's tau: tau^2 / r ~ Beta(1/2, (r - 1) / 2).
    tau = np.sqrt(red * stats.beta.ppf(1 - alpha, 0.5, 0.5 * (red - 1)))
    assert _critical(alpha, False, red) == pytest.approx(tau, rel=1e-9)


@pytest.mark.parametrize("alpha", [1e-3, 0.01, 0.05])
@pytest.mark.parametrize("red", [3, 4, 7, 40])
def test_two_coordinate(alpha, red):
    assert _critical2(alpha, True, red) == pytest.approx(np.sqrt(stats.chi2.ppf(1 - alpha, 2)), rel=1e-12)
    assert _critical2(alpha, False, red) == pytest.approx(
        np.sqrt(red * stats.beta.ppf(1 - alpha, 1.0, 0.5 * (red - 2))), rel=1e-12
    )


def test_no_estimate_without_redundancy():
    assert _critical(1e-3, False, 1.0) == np.inf
    assert _critical2(1e-3, False, 2) == np.inf
