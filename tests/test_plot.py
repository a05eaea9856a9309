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
    scale = plot.residual_vectors(
        ax, xy, v, ["a", "b", "c"], outliers=[False, False, True], check=[False, True, False], image_size=(400, 300)
    )
    # Default exaggeration: the largest inlier vector (|(1, -2)|) spans 8 % of the width.
    np.testing.assert_allclose(scale, 0.08 * 400 / np.hypot(1.0, 2.0))
    quivers = [c for c in ax.collections if isinstance(c, matplotlib.quiver.Quiver)]
    assert len(quivers) == 3  # control, check, blunder
    for q, k in zip(quivers, (0, 1, 2)):
        np.testing.assert_allclose(q.get_offsets(), xy[k : k + 1])
        np.testing.assert_allclose([q.U[0], q.V[0]], -v[k] * scale)  # arrows: observed - computed = -residual
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


# --- bundle convergence -------------------------------------------------------


def test_convergence_starts_at_the_initial_cost_with_whole_iterations():
    class Result:  # what bundle_adjust returns, the attributes convergence reads
        initial_cost = 5.0e4
        history = [
            dict(iteration=1, cost=900.0, accepted=True, candidate_cost=900.0),
            dict(iteration=2, cost=900.0, accepted=False, candidate_cost=2.0e3),
            dict(iteration=3, cost=120.0, accepted=True, candidate_cost=120.0),
        ]

    fig, ax = plt.subplots()
    plot.convergence(ax, Result)
    line = ax.lines[0]
    np.testing.assert_array_equal(line.get_xdata(), [0, 1, 2, 3])
    np.testing.assert_array_equal(line.get_ydata(), [5.0e4, 900.0, 900.0, 120.0])
    rejected = ax.lines[1]
    np.testing.assert_array_equal(rejected.get_xdata(), [2])
    np.testing.assert_array_equal(rejected.get_ydata(), [2.0e3])
    fig.canvas.draw()
    ticks = [t for t in ax.get_xticks() if ax.get_xlim()[0] <= t <= ax.get_xlim()[1]]
    assert len(ticks) >= 2 and all(float(t).is_integer() for t in ticks)
    assert ax.get_yscale() == "log"
    # A bare history with the start cost given gives the same curve.
    fig2, ax2 = plt.subplots()
    plot.convergence(ax2, Result.history, initial_cost=Result.initial_cost)
    np.testing.assert_array_equal(ax2.lines[0].get_xydata(), line.get_xydata())
    plt.close(fig)
    plt.close(fig2)


# --- model comparison figures -------------------------------------------------


def _comparison(errors: dict, rng):
    """A ModelComparison holding the given error-magnitude maps (x component) on a 30 x 40 grid."""
    from photax.compare import ModelComparison, ModelResult

    grid = ptx.Grid.from_bounds((1000.0, 2000.0, 1400.0, 2300.0), 10.0)
    assert grid.shape == (30, 40)
    gcp = np.column_stack([rng.uniform(1050, 1350, 8), rng.uniform(2050, 2250, 8), np.zeros(8)])
    check = np.column_stack([rng.uniform(1050, 1350, 5), rng.uniform(2050, 2250, 5), np.zeros(5)])
    models = [
        ModelResult(
            name,
            None,
            6,
            10,
            1.0,
            np.zeros((8, 2)),
            np.zeros((5, 2)),
            0.1,
            0.2,
            np.stack([e, np.zeros_like(e)], axis=-1),
        )
        for name, e in errors.items()
    ]
    return ModelComparison(models, None, None, None, grid, 10.0, gcp, np.zeros((8, 2)), check, np.zeros((5, 2)))


def test_error_maps_one_wild_model_does_not_black_out_the_others():
    rng = np.random.default_rng(1)
    good = {f"polynomial {k}": rng.uniform(0.0, 5.0, (30, 40)) for k in (1, 2, 3, 4)}
    wild = rng.uniform(0.0, 5.0, (30, 40))
    wild[:, :10] = 1000.0  # a quarter of the map: extrapolation outside the GCPs
    c = _comparison(
        {
            "collinearity": np.zeros((30, 40)),
            **good,
            "polynomial 5": wild,
            "projective": rng.uniform(0.0, 5.0, (30, 40)),
        },
        rng,
    )
    fig = c.plot_error_maps()
    panels = [ax for ax in fig.axes if ax.images and ax.get_title()]
    assert [ax.get_title().split("\n")[0] for ax in panels] == [*good, "polynomial 5", "projective"]
    # One scale for all panels (comparable colours) ...
    ((vmin, vmax),) = {ax.images[0].get_clim() for ax in panels}
    assert vmin == 0
    # ... on which every good map spans most of the colours, not the bottom 1 % of them.
    for ax in panels:
        data = np.asarray(ax.images[0].get_array())
        if "polynomial 5" not in ax.get_title():
            assert np.percentile(data, 99) >= 0.8 * vmax
    assert vmax < 10.0  # the wild model saturates, and says so:
    bar = panels[-1].images[0].colorbar
    assert bar.extend == "max" and bar.ax.get_ylabel() == "|collinearity+DEM - model| [px]"
    assert "max 1000 px" in panels[4].get_title()
    assert all(ax.get_xlabel().endswith("[km]") and ax.get_ylabel().endswith("[km]") for ax in panels)
    legend = panels[0].get_legend()
    assert [t.get_text() for t in legend.get_texts()] == ["GCP", "check point"]
    plt.close(fig)


def test_rectified_panels_in_colour_with_labels_and_a_legend():
    rng = np.random.default_rng(2)
    c = _comparison({"collinearity": np.zeros((30, 40))}, rng)
    rgb = rng.uniform(0.0, 1.0, (3, 30, 40))
    rgb[:, 0, 0] = np.nan  # no data
    grey = rng.integers(0, 256, (30, 40), dtype=np.uint8)
    fig = c.plot_rectified({"collinearity": rgb, "polynomial 1": grey}, c.grid)
    ax_rgb, ax_grey = [ax for ax in fig.axes if ax.images]
    shown = np.asarray(ax_rgb.images[0].get_array())
    assert shown.shape == (30, 40, 4)  # colour, not a colour map over one band
    np.testing.assert_allclose(shown[1:, :, :3], np.moveaxis(rgb, 0, -1)[1:])
    np.testing.assert_allclose(shown[1:, 1:, 3], 1.0)
    assert shown[0, 0, 3] == 0.0  # no data: transparent
    g = np.asarray(ax_grey.images[0].get_array())
    np.testing.assert_allclose(g[..., 0], grey / 255.0)
    np.testing.assert_array_equal(g[..., 0], g[..., 2])
    # Images sit on their ground coordinates; the marks are the surveyed points.
    np.testing.assert_allclose(ax_rgb.images[0].get_extent(), (1000.0, 1400.0, 2000.0, 2300.0))
    gcp_line = next(line for line in ax_rgb.lines if line.get_label() == "GCP")
    np.testing.assert_allclose(gcp_line.get_xydata(), c.gcp_ground[:, :2])
    check_line = next(line for line in ax_rgb.lines if line.get_label() == "check point")
    np.testing.assert_allclose(check_line.get_xydata(), c.check_ground[:, :2])
    for ax in (ax_rgb, ax_grey):
        assert ax.get_xlabel() == "easting [m]" and ax.get_ylabel() == "northing [m]"
    (legend,) = fig.legends
    assert [t.get_text() for t in legend.get_texts()] == ["GCP", "check point"]
    plt.close(fig)


def test_rmse_bars_are_the_models_rmse_and_the_method_draws_the_same():
    """``ModelComparison.plot_rmse`` is a thin wrapper of
    ``plot.comparison_rmse``: bars at each model's GCP and check RMSE."""
    rng = np.random.default_rng(3)
    c = _comparison({"collinearity": np.zeros((30, 40)), "polynomial 2": np.ones((30, 40))}, rng)
    figs = [plot.comparison_rmse(c), c.plot_rmse()]
    heights = []
    for fig in figs:
        (ax,) = fig.axes
        heights.append([p.get_height() for p in ax.patches])
        assert [t.get_text() for t in ax.get_xticklabels()] == ["collinearity", "poly 2"]
        plt.close(fig)
    assert heights[0] == heights[1] == [m.gcp_rmse for m in c.models] + [m.check_rmse for m in c.models]


def test_raster_rgba_rejects_other_shapes():
    import pytest

    with pytest.raises(ValueError, match="image must be"):
        plot.raster_rgba(np.zeros((2, 3, 4)))
    with pytest.raises(ValueError, match="value_range"):
        plot.raster_rgba(np.zeros((3, 4)), (1.0, 1.0))
