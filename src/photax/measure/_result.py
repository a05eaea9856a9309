"""The result of every sub-pixel locator: positions, covariances, a status per point.

Failed points policy (one rule for all locators): a point whose status is not
``Status.OK`` has ``valid = False`` and **NaN** in ``xy``, ``covariance`` and
``sigma0``, so a failed measurement can never be used as if it were one; the
reason is in ``status`` (see :meth:`LocateResult.messages`).
"""

from __future__ import annotations

import enum

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array


class Status(enum.IntEnum):
    """Per-point outcome of a locator (``LocateResult.status``).

    Examples:
        Each locator's per-point outcome; ``OK`` is 0:

        >>> from photax.measure import Status
        >>> int(Status.OK), Status(1).name
        (0, 'OUTSIDE')
    """

    OK = 0
    OUTSIDE = 1  # the measuring window (plus interpolation margin) is not inside the image
    TEXTURELESS = 2  # flat window: constant grey values (no gradient at all)
    NOT_CONVERGED = 3  # iterations ended before the update fell below the tolerance
    LEFT_WINDOW = 4  # the solution moved further from the approximation than the window allows
    ILL_CONDITIONED = 5  # gradients all in one direction (an edge, not a point: q below its threshold),
    # or a match (NCC, LSM) whose correlation or radiometric gain is not positive
    NO_TARGET = 6  # no blob above the background's noise or one touching the border; no quartered pattern
    NOT_FINITE = 7  # NaN/inf pixel values in the window


MESSAGES = {
    Status.OK: "ok",
    Status.OUTSIDE: "window not inside the image",
    Status.TEXTURELESS: "no texture in the window (constant grey values)",
    Status.NOT_CONVERGED: "did not converge",
    Status.LEFT_WINDOW: "moved out of the window",
    Status.ILL_CONDITIONED: "ill-conditioned (gradients in one direction only: an edge, not a point; "
    "or a match with no positive correlation)",
    Status.NO_TARGET: "no target found (no disc stands out of the background, no quartered pattern, "
    "or the disc touches the window border)",
    Status.NOT_FINITE: "non-finite pixel values in the window",
}


class LocateResult(eqx.Module):
    """Sub-pixel positions measured by a locator.

    Attributes:
        xy: ``(..., n, 2)`` float64 positions (column, row) in pixels, the
            centre of the top-left pixel at (0, 0) (docs/conventions.md).
            NaN where ``valid`` is False.
        covariance: ``(..., n, 2, 2)`` covariance of ``xy`` in px^2 from the
            locator's own adjustment (``sigma0^2 (A^T P A)^-1`` or the
            equivalent propagation, see each locator's docstring).
        status: ``(..., n)`` int32 :class:`Status` codes.
        sigma0: ``(..., n)`` a-posteriori standard deviation of unit weight
            of each point's adjustment (the locator's unit; NaN if failed).
        iterations: ``(..., n)`` iterations used (0 for direct methods).

    Examples:
        What every locator returns; a point that fails is NaN with its status, never a silent guess:

        >>> import numpy as np
        >>> from photax.measure import Status, locate_targets
        >>> r, c = np.mgrid[0:41, 0:41]
        >>> image = 20.0 + 200.0 * np.exp(-((c - 20.3) ** 2 + (r - 19.6) ** 2) / (2 * 2.5**2))
        >>> res = locate_targets(image, np.array([[21.0, 19.0], [100.0, 100.0]]), 6.0, method="centroid")
        >>> res.valid.tolist(), Status(int(res.status[1])).name, bool(np.isnan(res.xy[1]).all())
        ([True, False], 'OUTSIDE', True)
        >>> res.covariance.shape
        (2, 2, 2)
    """

    xy: Array
    covariance: Array
    status: Array
    sigma0: Array
    iterations: Array

    @property
    def valid(self) -> Array:
        """``(..., n)`` bool: True where the status is ``Status.OK``."""
        return self.status == Status.OK

    @property
    def sigma(self) -> Array:
        """``(..., n, 2)`` standard deviations of column and row, in pixels.

        Use as image-coordinate weights in :func:`photax.resect`, which wants
        image-plane units: ``resect(camera.pixel_to_image(r.xy[r.valid]),
        ground[r.valid], camera, sigma=r.image_sigma(camera)[r.valid])``.
        """
        return jnp.sqrt(jnp.diagonal(self.covariance, axis1=-2, axis2=-1))

    def image_sigma(self, camera) -> Array:
        """``(..., n, 2)`` sigma of (x, y) in image-plane units of ``camera``
        (pixel sigma times the pixel size; the y flip does not change a sigma)."""
        _, size = camera._pixel_grid()
        s = self.sigma
        size = jnp.broadcast_to(jnp.asarray(size, dtype=float), (2,))
        return s * size.reshape((1,) * (s.ndim - 1) + (2,))  # explicit rank: jax_numpy_rank_promotion="raise"

    def messages(self) -> list[str]:
        """One message per point (flattened over any batch axes)."""
        return [MESSAGES[Status(int(s))] for s in np.asarray(self.status).ravel()]

    def summary(self) -> str:
        """Counts per status, e.g. ``"98 ok, 2 window not inside the image"``."""
        codes, counts = np.unique(np.asarray(self.status), return_counts=True)
        return ", ".join(f"{c} {MESSAGES[Status(int(k))]}" for k, c in zip(codes, counts))


def finish(xy, cov, status, sigma0, iterations) -> LocateResult:
    """Apply the failed-points policy (NaN where status != OK) and build the result."""
    ok = status == Status.OK
    nan = jnp.nan
    return LocateResult(
        xy=jnp.where(ok[..., None], xy, nan),
        covariance=jnp.where(ok[..., None, None], cov, nan),
        status=status.astype(jnp.int32),
        sigma0=jnp.where(ok, sigma0, nan),
        iterations=iterations.astype(jnp.int32),
    )


# --------------------------------------------------------------------------- input handling shared by the locators


def as_images(image, name: str = "image", *, convert: bool = True) -> tuple[Array, bool]:
    """``image`` ``(h, w)`` or ``(b, h, w)``, any int/float dtype -> float64 ``(b, h, w)``
    and whether it was batched.  ``convert=False`` keeps the dtype (and a numpy
    image on the host) for callers that convert only the windows they read: a
    float64 copy of a 4-MPix image costs more than 1,000 corner windows."""
    arr = np.asarray(image) if not isinstance(image, jnp.ndarray) else image
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise ValueError(f"{name}: expected an integer or float image, got dtype {arr.dtype}")
    if arr.ndim not in (2, 3):
        raise ValueError(f"{name}: expected shape (h, w) or a batch (b, h, w), got {arr.shape}")
    # the batch axis is added before the transfer: on a numpy image a view, where on a
    # device array ``[None]`` copies the whole image (10 ms for 16 MiB)
    batch = arr if arr.ndim == 3 else arr[None]
    return (batch if not convert else jnp.asarray(batch, dtype=jnp.float64)), arr.ndim == 3


def as_points(approx_xy, batch: int, batched: bool, name: str = "approx_xy") -> Array:
    """``(n, 2)`` (or ``(b, n, 2)`` for a batch of images) -> float64 ``(b, n, 2)``."""
    xy = np.asarray(approx_xy, dtype=np.float64)
    if xy.ndim == 1 and xy.shape == (2,):
        raise ValueError(f"{name}: expected (n, 2) points (column, row), got one point of shape (2,); use [[c, r]]")
    if xy.ndim == 2 and xy.shape[1] == 2:
        xy = np.broadcast_to(xy, (batch, *xy.shape))
    elif not (batched and xy.ndim == 3 and xy.shape[0] == batch and xy.shape[2] == 2):
        want = "(n, 2) or (b, n, 2) with b images" if batched else "(n, 2)"
        raise ValueError(f"{name}: expected {want} (column, row), got {xy.shape}")
    return jnp.asarray(xy)


def check_window(size: int, shape, name: str = "window") -> None:
    """A window of ``size`` px (plus margin) must fit in the ``(h, w)`` image."""
    if size > min(shape):
        raise ValueError(
            f"{name}: the measuring window ({size} px with its margin) is larger than the image {tuple(shape)}"
        )


def patch(img: Array, centre_int: Array, half: int) -> tuple[Array, Array]:
    """The ``(2 half + 1)^2`` patch of ``img`` (h, w) centred on the integer
    pixel ``centre_int`` (col, row), and whether it lies inside the image
    (``dynamic_slice`` clamps; an outside patch is flagged, never read past the edge)."""
    size = 2 * half + 1
    start = centre_int[::-1] - half  # (row, col)
    h, w = img.shape
    inside = (start[0] >= 0) & (start[1] >= 0) & (start[0] + size <= h) & (start[1] + size <= w)
    return jax.lax.dynamic_slice(img, (start[0], start[1]), (size, size)), inside


def round_centre(xy: Array) -> Array:
    """Nearest integer pixel of ``xy`` (col, row) as int; non-finite -> a huge
    value so that the patch is flagged as outside."""
    ok = jnp.all(jnp.isfinite(xy))
    return jnp.where(ok, jnp.round(jnp.where(ok, xy, 0.0)), -(2**30)).astype(jnp.int32)
