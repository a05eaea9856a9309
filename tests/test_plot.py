"""Plots draw what they are given: arrow positions, directions and colours."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import photax as ptx  # noqa: E402
from photax import plot  # noqa: E402


def test_residual_vectors_draws_scaled_arrows_per_role():
    xy = np.array([[100.0, 200.0], [300.0, 50.0], [250.0, 250.0]])
    v = np.array([[1.0, -2.0], [0.5, 0.5], [30.0, 0.0]])
    fig, ax = plt.subplots()
    scale = plot.residual_vectors(ax, xy, v, ["a", "b", "c"], outliers=[False, False, True],
                                  check=[False, True, False], image_size=(400, 300))
    # Default exaggeration: the largest inlier vector (|(1, -2)|) spans 8 % of the width.
    np.testing.assert_allclose(scale, 0.08 * 400 / np.hypot(1.0, 2.0))
    quivers = [c for c in ax.collections if isinstance(c, matplotlib.quiver.Quiver)]
    assert len(quivers) == 3  # control, check, blunder
    for q, k in zip(quivers, (0, 1, 2)):
        np.testing.assert_allclose(q.get_offsets(), xy[k : k + 1])
        np.testing.assert_allclose([q.U[0], q.V[0]], v[k] * scale)
    assert ax.yaxis_inverted()  # rows grow downwards
    assert [t.get_text() for t in ax.texts if t.get_text() in "abc"] == ["a", "b", "c"]
    plt.close(fig)


def test_precision_rows_error_over_std():
    eo = ptx.ExteriorOrientation([10.0, 20.0, 30.0], np.radians([1.0, 2.0, 179.9]))
    truth = ptx.ExteriorOrientation([10.5, 20.0, 30.0], np.radians([1.0, 2.0, -179.9]))

    class Result:  # the two attributes precision_rows reads
        exterior = eo
        std = np.array([0.25, 1, 1, 1, 1, np.radians(0.1)])

    rows = plot.precision_rows(Result, truth.to_convention("omega-phi-kappa"))
    assert rows[0]["ratio"] == -2.0  # (10 - 10.5) / 0.25
    # kappa 179.9 vs -179.9 deg is 0.2 deg apart, not 359.8
    np.testing.assert_allclose(rows[5]["error"], -0.2, atol=1e-9)
    np.testing.assert_allclose(rows[5]["ratio"], -2.0, atol=1e-9)
