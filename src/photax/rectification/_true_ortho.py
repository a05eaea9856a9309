"""The true orthophoto of a block (:func:`true_ortho`): each cell from the most nadir image that
sees it (:mod:`._occlusion`'s z-buffer)."""

from __future__ import annotations

from typing import Literal

import numpy as np

from ..dem import DEM
from ..grid import Grid
from ._occlusion import _centres, ground_lean
from ._ortho import OrthoModel, occlusion_mask, orthorectify
from ._tiling import _fill_value


def true_ortho(
    images,
    exteriors,
    cameras,
    dsm: DEM,
    grid: Grid,
    *,
    occlusion: Literal["fill", "mark"] = "fill",
    resampling="bilinear",
    nodata=None,
    supersample: int = 2,
    tolerance: float | None = None,
    info: dict | None = None,
) -> np.ndarray:
    """The true orthophoto of a block on a DSM: each image's ortho (:func:`photax.orthorectify`)
    with its hidden cells (:func:`occlusion_mask`) removed, and every cell from the most nadir image
    that sees it (the smallest ground lean, ``tan`` of the off-nadir angle, at the cell).

    Args:
        images: a sequence of ``(..., H, W)`` images (one band layout for all).
        exteriors, cameras: per image, as in :func:`photax.orthorectify` (a single camera is used
            for all); ``exteriors`` ``None`` (or a list of ``None``) for RPC / push-broom cameras.
        dsm: the surface model; grid: the output grid.
        occlusion: ``"fill"`` (the block's true ortho) or ``"mark"`` (only the first image, its
            hidden cells ``nodata``).
        resampling, nodata: as in :func:`photax.orthorectify`; supersample, tolerance: as in
            :func:`occlusion_mask`.
        info: a dict to receive ``source`` (``(rows, cols)`` int, the image each cell comes from,
            ``-1`` for none) and ``occluded`` (``(n, rows, cols)`` bool, each image's mask).

    Returns:
        ``(..., rows, cols)`` array in the images' dtype, ``nodata`` where no image sees the cell.

    Examples:
        :func:`occlusion_mask`'s 20 m block, seen by the nadir image (grey 1) and by one 80 m west
        (grey 2): along y = -0.5 the cells from x = -39.5 m take the nadir image, the ground the
        block hides from it (out to -37.5 m) the western one, the block's top the nadir one again:

        >>> import numpy as np
        >>> import photax as ptx
        >>> camera = ptx.FrameCamera.from_pixels(100.0, (100, 100))
        >>> heights = np.zeros((200, 200))
        >>> heights[90:110, 120:130] = 20.0  # 1 m cells from (-150, 100): y 10 .. -10, x -30 .. -20
        >>> dsm = ptx.DEM(heights, (1.0, 0.0, -150.0, 0.0, -1.0, 100.0))
        >>> exteriors = [ptx.ExteriorOrientation([x, 0.0, 100.0], [0.0, 0.0, 0.0]) for x in (0.0, -80.0)]
        >>> info = {}
        >>> out = ptx.true_ortho([np.full((100, 100), 1.0), np.full((100, 100), 2.0)], exteriors, camera, dsm,
        ...                      ptx.Grid.from_bounds((-50.0, -50.0, 50.0, 50.0), 1.0), info=info)
        >>> out[50, 10:23].tolist()  # x = -39.5 .. -27.5 m
        [1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0, 1.0, 1.0, 1.0]
        >>> bool(np.array_equal(info["source"][50, 10:23] + 1, out[50, 10:23]))
        True
    """

    images = list(images) if not hasattr(images, "shape") else [images]
    n = len(images)
    if n == 0:
        raise ValueError("true_ortho needs at least one image")
    if occlusion not in ("fill", "mark"):
        raise ValueError(f"occlusion must be 'fill' or 'mark', got {occlusion!r}")
    exteriors = [exteriors] * n if exteriors is None or not isinstance(exteriors, (list, tuple)) else list(exteriors)
    cameras = list(cameras) if isinstance(cameras, (list, tuple)) else [cameras] * n
    if len(exteriors) != n or len(cameras) != n:
        raise ValueError(f"{n} images but {len(exteriors)} exteriors and {len(cameras)} cameras")
    if occlusion == "mark":
        n = 1
    xy = _centres(grid, np.arange(grid.shape[0]), np.arange(grid.shape[1])).reshape(-1, 2)
    best = np.full(grid.shape, np.inf)
    source = np.full(grid.shape, -1, dtype=np.int64)
    out, masks = None, []
    for i in range(n):
        ortho, _ = orthorectify(
            images[i], exteriors[i], cameras[i], dsm, grid, resampling=resampling, nodata=nodata, approx=0.125
        )
        hidden = occlusion_mask(exteriors[i], cameras[i], dsm, grid, supersample=supersample, tolerance=tolerance)
        masks.append(hidden)
        if out is None:
            fill = _fill_value(ortho.dtype, nodata)
            out = np.full(ortho.shape, fill, dtype=ortho.dtype)
        valid = ~hidden & _has_data(ortho, fill)
        lean = ground_lean(OrthoModel(exteriors[i], cameras[i], dsm, grid.crs), xy).reshape(grid.shape)
        take = valid & (lean < best)
        best = np.where(take, lean, best)
        source = np.where(take, i, source)
        out[..., take] = ortho[..., take]
    if info is not None:
        info["source"] = source
        info["occluded"] = np.stack(masks)
    return out


def _has_data(ortho: np.ndarray, fill) -> np.ndarray:
    lead = tuple(range(ortho.ndim - 2))
    if np.isnan(fill):
        return np.all(np.isfinite(ortho), axis=lead) if lead else np.isfinite(ortho)
    return np.all(ortho != fill, axis=lead) if lead else ortho != fill
