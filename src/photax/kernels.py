"""The interpolation kernels: their list, their weights and their edges, in numpy (no JAX).

:mod:`photax.resampling` (JAX, any positions) and :func:`resample_grid` (numpy, the positions of a
separable lattice: one axis-aligned grid onto another) evaluate the same weights; the formulas, the
footprint and the edge rule are in :mod:`photax.resampling`'s docstring.
"""

from __future__ import annotations

import enum

import numpy as np


class Resampling(str, enum.Enum):  # noqa: UP042 -- str() of a member stays "Resampling.NAME"
    """The interpolation kernels, and what each needs: the one list of them.

    A member is its name (a ``str``: ``Resampling.cubic == "cubic"``), so
    every function taking ``resampling``/``method`` accepts either; the CLI's
    ``--resampling`` choices are :data:`RESAMPLING`.

    Attributes:
        taps: neighbours per axis the kernel weights; the first is at
            ``floor(x) - (taps // 2 - 1)`` (nearest: at ``floor(x + 0.5)``).
        margin: input pixels around a sample position that the kernel reads,
            plus one: the margin a windowed read
            (:func:`photax.rectify_file`) needs to give the same result as
            the whole image.  The B-spline prefilter is recursive (pole
            0.268), so its influence decays by 1e-14 over 24 pixels but never
            quite ends: file and memory agree to ~1e-7 (the window edge, not
            the image's, is padded before the prefilter).
        prefilter: the kernel works on prefiltered coefficients (B-spline),
            not on the grey values themselves.

    Examples:
        The kernels by name; functions take the name or the member:

        >>> import photax as ptx
        >>> ptx.Resampling("cubic") is ptx.Resampling.cubic, [k.value for k in ptx.Resampling]
        (True, ['nearest', 'bilinear', 'cubic', 'lanczos', 'lanczos4', 'bspline'])
    """

    def __new__(cls, name: str, taps: int, margin: int, prefilter: bool):
        member = str.__new__(cls, name)
        member._value_ = name
        member.taps, member.margin, member.prefilter = taps, margin, prefilter
        return member

    nearest = ("nearest", 1, 2, False)
    bilinear = ("bilinear", 2, 2, False)
    cubic = ("cubic", 4, 3, False)
    lanczos = ("lanczos", 6, 4, False)
    lanczos4 = ("lanczos4", 8, 5, False)
    bspline = ("bspline", 4, 24, True)

    def __str__(self) -> str:
        return self.value

    @classmethod
    def check(cls, value, argument: str = "resampling") -> Resampling:
        """``value`` (a name or member) as a member; a ValueError naming
        ``argument`` otherwise."""
        try:
            return cls(value)
        except ValueError:
            raise ValueError(f"{argument} must be one of {RESAMPLING}, got {value!r}") from None


RESAMPLING: tuple[str, ...] = tuple(k.value for k in Resampling)  # the kernel names, in order
BSPLINE_PAD = 12  # scipy's npad for mode="nearest"


def _cubic_weights(t, a: float) -> list:
    """Keys' cubic-convolution weights of the 4 taps at offsets -1, 0, 1, 2
    from ``floor(x)``; ``t = x - floor(x)`` in ``[0, 1)``."""

    def near(s):  # |s| <= 1
        return ((a + 2) * s - (a + 3)) * s * s + 1

    def far(s):  # 1 < |s| <= 2
        return ((a * s - 5 * a) * s + 8 * a) * s - 4 * a

    return [far(1 + t), near(t), near(1 - t), far(2 - t)]


def _bspline_weights(t) -> list:
    """Cubic B-spline weights of the taps at -1, 0, 1, 2 from ``floor(x)``."""
    u = 1 - t
    return [u * u * u / 6, (4 - 6 * t * t + 3 * t * t * t) / 6, (4 - 6 * u * u + 3 * u * u * u) / 6, t * t * t / 6]


def _lanczos_weights(t, a: int = 3, xp=np) -> list:
    """Lanczos-``a`` weights of the ``2a`` taps at ``-(a-1) .. a`` from
    ``floor(x)``, normalised to sum to one.

    Tap ``i`` is at distance ``d = t + k``, ``k = a-1-i``, and
    ``sinc(d) sinc(d/a) = a sin(pi d) sin(pi d/a) / (pi d)^2`` with
    ``sin(pi d) = (-1)^k sin(pi t)`` and ``sin(pi d/a)`` by the angle sum
    from ``sin, cos(pi t/a)``: three sines per axis instead of ``4a``
    (OpenCV's ``interpolateLanczos4`` does the same).  The constant factor
    cancels in the normalisation; at ``d = 0`` the limit ``pi^2/a`` of
    ``sin(pi d) sin(pi d/a) / d^2``.
    """
    s = xp.sin(xp.pi * t)
    sa, ca = xp.sin(xp.pi / a * t), xp.cos(xp.pi / a * t)
    w = []
    for i in range(2 * a):
        k = a - 1 - i
        d = t + k
        num = (s if k % 2 == 0 else -s) * (sa * float(np.cos(np.pi * k / a)) + ca * float(np.sin(np.pi * k / a)))
        w.append(xp.where(xp.abs(d) < 1e-8, float(np.pi**2 / a), num / xp.where(d == 0, 1, d * d)))
    total = sum(w)
    return [wi / total for wi in w]


def kernel_weights(method: str, t, a: float = -0.5, xp=np) -> list:
    """The weights of a kernel's taps (first at ``floor(x) - (taps // 2 - 1)``; nearest: the one tap at
    ``floor(x + 0.5)``) for fractions ``t = x - floor(x)`` (nearest: ``x - floor(x + 0.5)``), one array per
    tap, in the array module ``xp`` (numpy, or jax.numpy inside traced code)."""
    if method == "nearest":
        return [xp.ones_like(t)]
    if method == "bilinear":
        return [1 - t, t]
    if method == "cubic":
        return _cubic_weights(t, a)
    if method == "lanczos":
        return _lanczos_weights(t, 3, xp)
    if method == "lanczos4":
        return _lanczos_weights(t, 4, xp)
    return _bspline_weights(t)


def pad_width(method: str) -> int:
    """Replicated border so that every tap of a valid sample is in bounds:
    valid samples have ``floor(x)`` in [-1, W-1] (nearest: [0, W])."""
    kernel = Resampling(method)
    return BSPLINE_PAD if kernel.prefilter else max(kernel.taps // 2, 1)


def resample_grid(
    image, cols, rows, resampling: Resampling | str = "bilinear", *, nodata=None, a: float = -0.5
) -> np.ndarray:
    """:func:`photax.resample` on a separable lattice, in numpy: ``out[..., i, j]`` is ``image`` at
    ``(cols[j], rows[i])``.

    The same kernels, edges, footprint and rounding as :func:`photax.resample` (equal to float rounding), for
    the positions of an axis-aligned grid (a north-up raster onto another of the same CRS): each axis is
    one gather per tap, so nothing is traced or compiled.

    Args:
        image: ``(..., H, W)`` grey values, any integer or float dtype.
        cols: ``(W_out,)`` fractional columns; rows: ``(H_out,)`` fractional rows.
        resampling, nodata, a: as for :func:`photax.resample`.

    Returns:
        ``(..., H_out, W_out)`` array of ``image``'s dtype.
    """
    method = Resampling.check(resampling, "resampling").value
    image = np.asarray(image)
    if image.ndim < 2 or min(image.shape[-2:]) < 1:
        raise ValueError(f"image must have shape (..., H, W) with H, W >= 1, got {image.shape}")
    dtype = image.dtype
    if dtype == np.bool_ or not (np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating)):
        raise ValueError(f"image must have an integer or float dtype (not boolean), got {dtype}")
    is_int = np.issubdtype(dtype, np.integer)
    nodata = (0 if is_int else np.nan) if nodata is None else nodata
    compute = np.float64 if dtype == np.float64 else np.float32
    lead, (h, w) = image.shape[:-2], image.shape[-2:]
    pad = pad_width(method)
    src = np.pad(image.reshape((-1, h, w)), ((0, 0), (pad, pad), (pad, pad)), mode="edge").astype(compute)
    if method == "bspline":  # photax.resampling.bspline_coefficients, in numpy
        from scipy import ndimage

        for axis in (1, 2):
            src = ndimage.spline_filter1d(src, 3, axis=axis, mode="mirror", output=np.float64)
        src = src.astype(compute)
    taps = Resampling(method).taps
    first = 0 if method == "nearest" else taps // 2 - 1

    def axis(x, n):
        """The first tap's index in the padded axis, the taps' weights and the footprint test."""
        x = np.asarray(x, dtype=np.float64).ravel()
        valid = (x >= -0.5) & (x <= n - 0.5)
        x0 = np.where(valid, np.floor(x + 0.5) if method == "nearest" else np.floor(x), 0)
        wts = [np.asarray(v, dtype=compute) for v in kernel_weights(method, (x - x0).astype(compute), a)]
        base = np.clip(x0.astype(np.int64), first - pad, n + pad - taps + first) + pad - first
        return base, wts, valid

    br, wr, vr = axis(rows, h)
    bc, wc, vc = axis(cols, w)
    # One gather per tap and axis (columns, then rows), as resample's taps: no scipy.sparse to import.
    tmp = sum(src[:, :, bc + k] * wc[k] for k in range(taps))  # (B, Hp, W_out)
    out = sum(tmp[:, br + k, :] * wr[k][:, None] for k in range(taps))  # (B, H_out, W_out)
    if is_int:
        info = np.iinfo(dtype)
        out = np.clip(np.round(out), info.min, info.max)
    out = out.astype(dtype)
    out[:, ~(vr[:, None] & vc[None, :])] = nodata
    return out.reshape(lead + out.shape[1:])
