"""Figures shared by the demo and the notebooks (matplotlib).

Every function draws on an ``Axes`` the caller made, and never calls
``plt.show()``: the same code works in a notebook, a script and the
headless demo (Agg backend).
"""

from __future__ import annotations

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
        raise ValueError(f"image must be (rows, cols), (1, rows, cols), (3, rows, cols) or (4, rows, cols), "
                         f"got {img.shape}")
    lo, hi = (float(v) for v in value_range)
    if not hi > lo:
        raise ValueError(f"value_range must be (low, high) with high > low, got {value_range!r}")
    valid = np.all(np.isfinite(rgb), axis=-1)
    rgb = np.clip((np.nan_to_num(rgb, nan=lo) - lo) / (hi - lo), 0.0, 1.0)
    return np.concatenate([rgb, valid[..., None].astype(float)], axis=-1)


def residual_vectors(ax, pixel_xy, residuals, names=None, *, outliers=None, check=None,
                     scale=None, image_size=None, title=None):
    """Residual vectors drawn at the points on the image, exaggerated.

    Args:
        ax: a matplotlib ``Axes``.
        pixel_xy: ``(n, 2)`` point positions, pixel (column, row), row down.
        residuals: ``(n, 2)`` residuals in pixels along (column, row) (i.e.
            image-plane residuals divided by the pixel size, y flipped).
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
    v = np.asarray(residuals, dtype=float)
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
        arrows = ax.quiver(xy[sel, 0], xy[sel, 1], v[sel, 0] * scale, v[sel, 1] * scale, color=colour,
                  angles="xy", scale_units="xy", scale=1.0, width=0.004, zorder=2)
    if names is not None:
        for (c, r), name, bad in zip(xy, names, outliers):
            ax.annotate(str(name), (c, r), xytext=(4, 4), textcoords="offset points", fontsize=7,
                        color="tab:red" if bad else "0.2")
    # A key arrow: what a residual of "key" pixels looks like.
    key = float(f"{ref:.1g}")
    if arrows is not None:
        ax.quiverkey(arrows, 0.72, 1.03, key * scale, f"{key:g} px residual", labelpos="E",
                     coordinates="axes", color="black")
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
            ax.text(j, i, f"{c[i, j]:.2f}", ha="center", va="center", fontsize=7,
                    color="white" if abs(c[i, j]) > 0.6 else "black")
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
        ax.semilogy(np.array([h["iteration"] for h in history])[~ok], cand, "x", color="tab:red",
                    label="rejected step (its cost)")
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
