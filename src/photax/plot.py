"""Figures shared by the demo and the notebooks (matplotlib).

Every function draws on an ``Axes`` the caller made, except the
``comparison_*`` figures of a :class:`photax.ModelComparison` (grids of
panels sized to the models, behind its ``plot_*`` methods), which make their
own figure; none calls ``plt.show()``: the same code works in a notebook, a
script and the headless demo (Agg backend).
"""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib.patches
import numpy as np


def raster_rgba(image, value_range=None) -> np.ndarray:
    """An image as ``(rows, cols, 4)`` RGBA in 0..1 for ``imshow``.

    Args:
        image: ``(rows, cols)`` or ``(1, rows, cols)`` grey, ``(3, rows,
            cols)`` RGB or ``(4, rows, cols)`` RGBA (the fourth band is
            ignored; rasterio's band-first layout).
        value_range: ``(low, high)`` drawn as black..white (full colour);
            default ``(0, 255)`` for integer images, ``(0, 1)`` otherwise.

    Returns:
        float RGBA; alpha 0 where any band is NaN (no data).

    Raises:
        ValueError: another shape.
    """
    img = np.asarray(image)
    if value_range is None:
        value_range = (0.0, 255.0) if np.issubdtype(img.dtype, np.integer) else (0.0, 1.0)
    img = img.astype(float)
    if img.ndim == 3 and img.shape[0] in (3, 4):
        rgb = np.moveaxis(img[:3], 0, -1)
    elif img.ndim == 2 or (img.ndim == 3 and img.shape[0] == 1):
        grey = img.reshape(img.shape[-2:])
        rgb = np.repeat(grey[..., None], 3, axis=-1)
    else:
        raise ValueError(
            f"image must be (rows, cols), (1, rows, cols), (3, rows, cols) or (4, rows, cols), got {img.shape}"
        )
    lo, hi = (float(v) for v in value_range)
    if not hi > lo:
        raise ValueError(f"value_range must be (low, high) with high > low, got {value_range!r}")
    valid = np.all(np.isfinite(rgb), axis=-1)
    rgb = np.clip((np.nan_to_num(rgb, nan=lo) - lo) / (hi - lo), 0.0, 1.0)
    return np.concatenate([rgb, valid[..., None].astype(float)], axis=-1)


def residual_vectors(
    ax, pixel_xy, residuals, names=None, *, outliers=None, check=None, scale=None, image_size=None, title=None
):
    """Residual vectors drawn at the points on the image, exaggerated.

    Args:
        ax: a matplotlib ``Axes``.
        pixel_xy: ``(n, 2)`` point positions, pixel (column, row), row down.
        residuals: ``(n, 2)`` residuals, computed - observed
            (docs/conventions.md), in pixels along (column, row) (i.e.
            image-plane residuals divided by the pixel size, y flipped).
            The arrows show ``-residuals``, observed - computed: from where
            the model puts the point towards where it was measured (the
            figure photax has always drawn).
        names: ``(n,)`` labels, or ``None``.
        outliers: ``(n,)`` bool, drawn in red and named "blunder".
        check: ``(n,)`` bool, check points (drawn in blue, hollow).
        scale: arrow exaggeration; default so that the largest inlier vector
            is about 8 % of the image width.
        image_size: ``(width, height)``: draws the frame and fixes the limits.

    Returns:
        the exaggeration factor used (a key arrow shows its length).
    """
    xy = np.asarray(pixel_xy, dtype=float)
    v = -np.asarray(residuals, dtype=float)  # the arrow: observed - computed
    n = len(xy)
    outliers = np.zeros(n, bool) if outliers is None else np.asarray(outliers, bool)
    check = np.zeros(n, bool) if check is None else np.asarray(check, bool)
    width = image_size[0] if image_size is not None else np.ptp(xy[:, 0]) or 1.0
    length = np.hypot(v[:, 0], v[:, 1])
    inlier = ~outliers
    ref = np.max(length[inlier]) if inlier.any() and np.max(length[inlier]) > 0 else 1.0
    if scale is None:
        scale = 0.08 * width / ref
    control = ~check & ~outliers
    groups = ((control, "tab:green", "control"), (check, "tab:blue", "check"), (outliers, "tab:red", "blunder"))
    arrows = None
    for sel, colour, label in groups:
        if not sel.any():
            continue
        face = "none" if label == "check" else colour
        ax.scatter(xy[sel, 0], xy[sel, 1], s=25, facecolors=face, edgecolors=colour, label=label, zorder=3)
        arrows = ax.quiver(
            xy[sel, 0],
            xy[sel, 1],
            v[sel, 0] * scale,
            v[sel, 1] * scale,
            color=colour,
            angles="xy",
            scale_units="xy",
            scale=1.0,
            width=0.004,
            zorder=2,
        )
    if names is not None:
        for (c, r), name, bad in zip(xy, names, outliers):
            ax.annotate(
                str(name),
                (c, r),
                xytext=(4, 4),
                textcoords="offset points",
                fontsize=7,
                color="tab:red" if bad else "0.2",
            )
    # A key arrow: what a residual of "key" pixels looks like.
    key = float(f"{ref:.1g}")
    if arrows is not None:
        ax.quiverkey(
            arrows, 0.72, 1.03, key * scale, f"{key:g} px residual", labelpos="E", coordinates="axes", color="black"
        )
    if image_size is not None:
        w, h = image_size
        ax.add_patch(matplotlib.patches.Rectangle((-0.5, -0.5), w, h, fill=False, color="0.5", lw=1))
        ax.set_xlim(-0.05 * w, 1.05 * w)
        ax.set_ylim(1.05 * h, -0.05 * h)  # row down
    elif not ax.yaxis_inverted():
        ax.invert_yaxis()
    ax.set_aspect("equal")
    ax.set_xlabel("column [px]")
    ax.set_ylabel("row [px]")
    ax.legend(loc="lower right", fontsize=8)
    if title:
        ax.set_title(title, loc="left")
    return scale


def precision_rows(result, truth=None) -> list[dict]:
    """The parameters of a resection as rows: name, unit, value, std (and truth).

    Angles in degrees.  With ``truth`` (an ExteriorOrientation in any
    convention) each row also has ``true``, ``error`` = value - true and
    ``error/std``, which should mostly lie within +-2 when the precision
    estimate is honest.
    """
    e = result.exterior
    labels = ["X", "Y", "Z", *e.convention.split("-")]
    value = np.asarray(e.to_vector(), dtype=float)
    std = np.asarray(result.std, dtype=float)
    deg = np.array([1, 1, 1, 180 / np.pi, 180 / np.pi, 180 / np.pi])
    true = None if truth is None else np.asarray(truth.to_convention(e.convention).to_vector(), dtype=float)
    rows = []
    for k, label in enumerate(labels):
        row = {"parameter": label, "unit": "m" if k < 3 else "deg", "value": value[k] * deg[k], "std": std[k] * deg[k]}
        if true is not None:
            err = value[k] - true[k]
            if k >= 3:
                err = (err + np.pi) % (2 * np.pi) - np.pi
            row.update(true=true[k] * deg[k], error=err * deg[k], ratio=err / std[k] if std[k] > 0 else np.nan)
        rows.append(row)
    return rows


def precision_table(ax, result, truth=None, *, title=None):
    """Parameters +- std (and the truth, when known) as a table on ``ax``."""
    rows = precision_rows(result, truth)
    head = ["parameter", "value", "std"] + (["true", "error", "error/std"] if truth is not None else [])
    cells = []
    for r in rows:
        fmt = "{:.3f}" if r["unit"] == "m" else "{:.5f}"
        cell = [f"{r['parameter']} [{r['unit']}]", fmt.format(r["value"]), fmt.format(r["std"])]
        if truth is not None:
            cell += [fmt.format(r["true"]), fmt.format(r["error"]), f"{r['ratio']:+.2f}"]
        cells.append(cell)
    ax.axis("off")
    table = ax.table(cellText=cells, colLabels=head, loc="center", cellLoc="right")
    table.auto_set_font_size(False)
    table.set_fontsize(8)
    table.scale(1.0, 1.3)
    if title:
        ax.set_title(title)
    return table


def correlation_matrix(ax, correlation, labels, *, title="parameter correlations"):
    """A correlation matrix as a heat map with the values written in."""
    c = np.asarray(correlation, dtype=float)
    im = ax.imshow(c, vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(len(labels)), labels)
    ax.set_yticks(range(len(labels)), labels)
    for i in range(c.shape[0]):
        for j in range(c.shape[1]):
            ax.text(
                j,
                i,
                f"{c[i, j]:.2f}",
                ha="center",
                va="center",
                fontsize=7,
                color="white" if abs(c[i, j]) > 0.6 else "black",
            )
    if title:
        ax.set_title(title)
    return im


def convergence(ax, result, *, initial_cost=None, title="bundle adjustment: convergence"):
    """Cost per iteration of a bundle adjustment (log scale), from the start.

    Iteration 0 is the cost at the start values, before any step; iteration
    ``k`` the cost after the ``k``-th step (unchanged by a rejected one,
    whose candidate cost is marked with a cross).  Iterations are counted
    as :func:`photax.bundle_adjust` counts them, ticks at whole numbers.

    Args:
        ax: a matplotlib ``Axes``.
        result: a :class:`photax.BundleResult` (its ``history`` and
            ``initial_cost``), or a ``history`` list of dicts with
            ``iteration, cost, accepted, candidate_cost``.
        initial_cost: the cost at the start values, when ``result`` is a
            history list (else taken from the result).
    """
    from matplotlib.ticker import MaxNLocator

    history = getattr(result, "history", result)
    if initial_cost is None:
        initial_cost = getattr(result, "initial_cost", None)
    it = np.array([h["iteration"] for h in history], dtype=int)
    cost = np.array([h["cost"] for h in history], dtype=float)
    ok = np.array([h["accepted"] for h in history], dtype=bool)
    if initial_cost is not None:
        it, cost = np.concatenate([[0], it]), np.concatenate([[float(initial_cost)], cost])
    ax.semilogy(it, cost, "o-", ms=4, label="cost (0: start values)" if initial_cost is not None else "cost")
    if (~ok).any():
        cand = np.array([np.nan if h["candidate_cost"] is None else h["candidate_cost"] for h in history])[~ok]
        ax.semilogy(
            np.array([h["iteration"] for h in history])[~ok],
            cand,
            "x",
            color="tab:red",
            label="rejected step (its cost)",
        )
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("iteration")
    ax.set_ylabel("cost  ½ Σ ρ(|r/σ|²)  (r in sigmas)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    if title:
        ax.set_title(title)


def bundle_residuals(ax, result, *, title="image residuals by image"):
    """Normalised image residuals (residual / sigma) of a bundle adjustment,
    one column of points per image; down-weighted observations in red."""
    p = result.problem
    norm = np.linalg.norm(result.residuals / p.obs_sigma, axis=1)
    jitter = np.random.default_rng(0).uniform(-0.25, 0.25, len(norm))
    low = result.weights < 0.5
    ax.plot(p.obs_image[~low] + jitter[~low], norm[~low], ".", ms=3, alpha=0.6, label="|r| / sigma")
    if low.any():
        ax.plot(p.obs_image[low] + jitter[low], norm[low], "o", color="tab:red", ms=5, label="down-weighted")
    ax.set_xticks(range(p.n_images), p.image_names, rotation=45, fontsize=7)
    ax.set_ylabel("|residual| / sigma")
    ax.grid(True, alpha=0.3)
    ax.legend()
    if title:
        ax.set_title(title)


# --- model comparison (photax.compare) ---------------------------------------


def comparison_error_maps(comparison, names: Sequence[str] | None = None, *, vmax: float | None = None, ncols: int = 3):
    """Error maps of a :class:`photax.ModelComparison` side by side on one
    colour scale; GCPs ``+``, check points ``o``.

    One shared scale, so that a colour means the same error in every
    panel and models can be compared by eye.  Its top ``vmax`` defaults
    to the median over the panels of each panel's 99th percentile: a
    single model that extrapolates wildly (order 5 outside the GCPs'
    hull) saturates in its own panel (the colour bar's arrow; its title
    gives its map maximum) instead of stretching the scale until every
    other panel is black, as a percentile of all panels pooled does.

    Returns the matplotlib figure.
    """
    import matplotlib.pyplot as plt

    names = [n for n in comparison.names if n != "collinearity"] if names is None else list(names)
    if not names:
        raise ValueError("no model to plot")
    mags = [comparison[n].error_magnitude for n in names]
    if vmax is None:
        tops = [np.percentile(m[np.isfinite(m)], 99) for m in mags if np.isfinite(m).any()]
        vmax = float(np.median(tops)) if tops else 1.0
        vmax = vmax if vmax > 0 else 1.0
    ncols = min(ncols, len(names))
    nrows = -(-len(names) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(4.2 * ncols, 3.6 * nrows), squeeze=False, constrained_layout=True)
    x0, y0, x1, y1 = comparison.grid.bounds
    extent = (0.0, (x1 - x0) / 1000, 0.0, (y1 - y0) / 1000)
    to_km = lambda g: ((g[:, 0] - x0) / 1000, (g[:, 1] - y0) / 1000)  # noqa: E731
    for ax, name, mag in zip(axes.flat, names, mags):
        im = ax.imshow(mag, extent=extent, vmin=0, vmax=vmax, cmap="magma")
        ax.plot(*to_km(comparison.gcp_ground), "+", color="cyan", ms=7, mew=1.5, label="GCP")
        if len(comparison.check_ground):
            ax.plot(*to_km(comparison.check_ground), "o", mfc="none", color="lime", ms=4, label="check point")
        m = comparison[name]
        ax.set_title(
            f"{name}\ncheck RMSE {m.check_rmse:.2f} px, map RMSE {m.error_rmse:.1f} px, max {m.error_max:.0f} px",
            fontsize=9,
        )
        ax.set_xlabel(f"easting - {x0:.0f} m [km]")
        ax.set_ylabel(f"northing - {y0:.0f} m [km]")
    for ax in axes.flat[len(names) :]:
        ax.axis("off")
    axes.flat[0].legend(loc="lower left", fontsize=7)
    over = any(np.nanmax(m) > vmax for m in mags if np.isfinite(m).any())
    fig.colorbar(im, ax=axes, shrink=0.8, extend="max" if over else "neither", label="|collinearity+DEM - model| [px]")
    return fig


def comparison_rmse(comparison):
    """GCP and check-point RMSE per model of a :class:`photax.ModelComparison`,
    grouped bars (log scale).  Returns the matplotlib figure."""
    import matplotlib.pyplot as plt

    names = comparison.names
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(1.2 * len(names) + 2, 3.6), constrained_layout=True)
    ax.bar(x - 0.2, [comparison[n].gcp_rmse for n in names], 0.4, label="GCPs (fit)")
    ax.bar(x + 0.2, [comparison[n].check_rmse for n in names], 0.4, label="check points")
    ax.set_xticks(x, [n.replace("polynomial ", "poly ") for n in names], rotation=20)
    ax.set_yscale("log")
    # interpolating models (thin-plate spline, piecewise affine) fit the GCPs to rounding: keep the axis on
    # the other bars, not on 1e-13 px
    values = [v for n in names for v in (comparison[n].gcp_rmse, comparison[n].check_rmse) if v > 1e-6]
    if values:
        ax.set_ylim(bottom=0.5 * min(values))
    ax.set_ylabel("RMSE [px]")
    ax.legend()
    ax.grid(axis="y", alpha=0.3)
    return fig


def comparison_rectified(
    comparison,
    images: dict[str, np.ndarray],
    grid,
    *,
    reference: np.ndarray | None = None,
    reference_transform=None,
    ncols: int = 3,
    window=None,
    value_range=None,
):
    """Rectified images side by side (from :meth:`photax.ModelComparison.rectify`
    on the :class:`photax.Grid` ``grid``), optionally
    with a reference orthophoto; ``window=(xmin, ymin, xmax, ymax)`` zooms
    in (ground units).

    Images ``(rows, cols)`` are drawn in grey, ``(3 or 4, rows, cols)`` in
    colour (RGB, a fourth band ignored); ``value_range=(low, high)`` maps
    to black..white (default ``(0, 255)`` for integer images, else
    ``(0, 1)``); NaN (no data) is transparent.  The GCPs (``+``) and check
    points (``o``) are marked at their surveyed ground positions, where
    a correct rectification puts their image.
    """
    import matplotlib.pyplot as plt

    panels = list(images.items())
    extents = [grid.bounds] * len(panels)
    if reference is not None:
        a, _, xoff, _, e, yoff = tuple(reference_transform)[:6]
        rows, cols = reference.shape[-2:]
        panels.insert(0, ("truth (ground texture)", reference))
        extents.insert(0, (xoff, yoff + e * rows, xoff + a * cols, yoff))
    window = grid.bounds if window is None else window  # the reference may cover more ground
    ncols = min(ncols, len(panels))
    nrows = -(-len(panels) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(4.2 * ncols, 3.8 * nrows), squeeze=False, constrained_layout=True)
    for ax, (name, img), (xmin, ymin, xmax, ymax) in zip(axes.flat, panels, extents):
        ax.imshow(raster_rgba(img, value_range), extent=(xmin, xmax, ymin, ymax), interpolation="nearest")
        gcp, check = comparison.gcp_ground, comparison.check_ground
        ax.plot(gcp[:, 0], gcp[:, 1], "+", color="red", ms=7, mew=1.5, label="GCP")
        if len(check):
            ax.plot(check[:, 0], check[:, 1], "o", mfc="none", color="cyan", ms=4, label="check point")
        ax.set_title(name, fontsize=9)
        if window is not None:
            ax.set_xlim(window[0], window[2])
            ax.set_ylim(window[1], window[3])
        ax.ticklabel_format(useOffset=False, style="plain")
        ax.tick_params(labelsize=6)
        ax.set_xlabel("easting [m]", fontsize=8)
        ax.set_ylabel("northing [m]", fontsize=8)
    for ax in axes.flat[len(panels) :]:
        ax.axis("off")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=len(labels), fontsize=8)
    return fig
