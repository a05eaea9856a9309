"""Image-to-image co-registration (the notes' 影像配准, as AROSICS does): the transformation that maps a
target image (another date, another sensor) onto a reference image.

1. **Global shift**: phase correlation of the whole overlap (both images Hann-windowed, the normalised
   cross-power spectrum ``conj(F) G / |conj(F) G|`` transformed back), its integer peak refined by the
   upsampled DFT of Guizar-Sicairos et al. (2008) around it and a parabola through the finest samples.
2. **Local shifts** on a grid of windows, each measured by phase correlation (or least-squares matching,
   :func:`photax.measure.match_lsm`) between the reference window and the target *resampled onto the
   reference grid by the current model*, so that what is measured is a small residual; the model is
   refitted and the windows measured again until the model moves by less than ``tol`` px.
   A window with no data is **masked**: both windows are reduced to the pixels valid in both (each
   minus its mean over them, the others set to 0, so that neither the holes nor a fill value correlate),
   and its texture and SSIM are taken over those pixels only; a window without no data is measured as it
   is. A DSM with 10-20 % holes (its orthos blank there) still yields reliable windows: two orthos of
   the QuickBird scene over a DEM with 15 % of holes (15 and 29 % of their pixels), moved by (0.5, -0.3)
   px, are measured to 0.065 px (0.01 px without the holes; each window filled with its own mean
   instead: 0.18 px; tests/test_crops.py).
3. **Reliability** per window, each reason counted (:attr:`CoRegistration.counts`):

   * ``"no data"``: over ``max_nodata`` (default 40 %) of the window is outside either image or no
     data (NaN) in either (a DSM's holes in an ortho, clouds masked out);
   * ``"textureless"``: the standard deviation of either window is below ``min_texture`` x the image's;
   * ``"weak peak"``: the correlation peak is less than ``min_peak_ratio`` x the highest value outside
     its 3-px neighbourhood (no unique match), or the match lies over a quarter window away;
   * ``"dissimilar"``: after the shift, the two windows' SSIM (Wang et al. 2004, Gaussian sigma 1.5,
     each window standardised to mean 0 and variance 1 so that a change of gain or offset between dates
     does not count, ``L = 6``) is below ``min_ssim``: changed content;
   * ``"outlier"``: the normalised median test of PIV (Westerweel & Scarano 2005) on the residual shifts
     against the model of the previous pass (so from the second pass on; there are at least two): a
     window whose residual differs from the median of its 8 nearest reliable neighbours by more than
     ``median_threshold`` x (their median deviation + 0.1 px), per axis.
4. **Model** ``reference pixel -> target pixel`` fitted to the reliable windows: ``"affine"``,
   ``"polynomial"`` (order 1-5) or ``"tps"`` (:mod:`photax.polynomial`).  The target is then either
   resampled onto the reference grid (:meth:`CoRegistration.resample`) or, for the affine model, given a
   corrected georeference (:meth:`CoRegistration.corrected_transform`).

Pixels follow docs/conventions.md: ``(column, row)``, a raster cell's value at its integer position.
A shift ``d`` at a reference pixel ``p`` means ``target(p + d) = reference(p)`` (same grid); between
grids that differ, the georeferences give the start and shifts are relative to it, in target pixels.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import numpy as np

STATUSES = ("ok", "no data", "textureless", "weak peak", "dissimilar", "outlier")
MODELS = ("affine", "polynomial", "tps")


# -------------------------------------------------------------------------------------------------
# phase correlation


def _hann(h: int, w: int) -> np.ndarray:
    return np.outer(np.hanning(h), np.hanning(w))


def _upsampled_dft(spec: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``(b, len(rows), len(cols))`` inverse DFT of ``spec`` ``(b, H, W)`` at fractional positions (the
    matrix-multiply DFT of Guizar-Sicairos et al. 2008)."""
    from threadpoolctl import threadpool_limits

    h, w = spec.shape[-2:]
    fr, fc = np.fft.fftfreq(h), np.fft.fftfreq(w)
    er = np.exp(2j * np.pi * rows[..., :, None] * fr[None, :])  # (b, m, H)
    ec = np.exp(2j * np.pi * fc[:, None] * cols[..., None, :])  # (b, W, m)
    # small batched products: one BLAS thread (OpenBLAS' pool was 12x slower on a busy machine)
    with threadpool_limits(1, user_api="blas"):
        return np.real(er @ spec @ ec) / (h * w)


def _parabola(vm, v0, vp) -> np.ndarray:
    """Vertex offset of the parabola through three equally spaced samples (in sample steps, |.| <= 0.5)."""
    den = vm - 2 * v0 + vp
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(den < 0, 0.5 * (vm - vp) / den, 0.0)
    return np.clip(off, -0.5, 0.5)


def phase_correlation(reference, moving, *, upsample: int = 20, window: bool = True, bandwidth: float | None = 0.1):
    """Sub-pixel translation between two images (or ``(b, h, w)`` stacks of pairs) by phase correlation.

    Args:
        reference, moving: ``(h, w)`` or ``(b, h, w)`` float images of one shape, without NaN.
        upsample: refinement factor of the upsampled DFT around the integer peak (then a parabola through
            the finest samples).
        window: taper both images with a Hann window (no wrap-around edges).
        bandwidth: weight the normalised cross-power spectrum by ``exp(-|f|^2 / bandwidth^2)`` (``f`` in
            cycles/px); None: pure phase correlation.  The highest frequencies of a resampled image carry
            the interpolation kernel's errors, which pure phase correlation weighs like the signal: on
            smooth texture resampled by cubic convolution it was seen biased by 0.1 px; 0.1 removes that.

    Returns:
        ``(shift, peak_ratio)``: ``shift`` ``(..., 2)`` = ``(dx, dy)`` px with ``moving(p + d) =
        reference(p)``; ``peak_ratio`` ``(...)``: the correlation peak over the highest value outside its
        3-px neighbourhood (1 for noise, large for a clear match).

    Examples:
        The shift between an image and a copy moved by (3, -2) pixels (a circular shift, which
        phase correlation measures exactly):

        >>> import numpy as np
        >>> import photax as ptx
        >>> rng = np.random.default_rng(0)
        >>> ref = rng.normal(size=(64, 64))
        >>> moved = np.roll(ref, (-2, 3), axis=(0, 1))  # rows up by 2, columns right by 3
        >>> out = ptx.phase_correlation(ref, moved, window=False)
        >>> print(np.round(np.asarray(out[0]), 2) + 0.0)
        [ 3. -2.]
    """
    a = np.asarray(reference, dtype=float)
    b = np.asarray(moving, dtype=float)
    if a.shape != b.shape or a.ndim not in (2, 3) or min(a.shape[-2:]) < 8:
        raise ValueError(f"reference and moving must be (h, w) or (b, h, w) of one shape, h, w >= 8; got "
                         f"{a.shape} and {b.shape}")  # fmt: skip
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("reference and moving must be finite (fill no-data first)")
    single = a.ndim == 2
    a, b = (a[None], b[None]) if single else (a, b)
    h, w = a.shape[-2:]
    taper = _hann(h, w) if window else np.ones((h, w))
    fa = np.fft.fft2((a - a.mean(axis=(-2, -1), keepdims=True)) * taper)
    fb = np.fft.fft2((b - b.mean(axis=(-2, -1), keepdims=True)) * taper)
    cross = np.conj(fa) * fb
    mag = np.abs(cross)
    spec = np.where(mag > 1e-12 * mag.max(axis=(-2, -1), keepdims=True), cross / np.maximum(mag, 1e-300), 0)
    if bandwidth is not None:
        f2 = np.fft.fftfreq(h)[:, None] ** 2 + np.fft.fftfreq(w)[None, :] ** 2
        spec = spec * np.exp(-f2 / float(bandwidth) ** 2)
    surf = np.real(np.fft.ifft2(spec))
    n = len(surf)
    k = np.argmax(surf.reshape(n, -1), axis=1)
    r0, c0 = np.unravel_index(k, (h, w))
    peak = surf[np.arange(n), r0, c0]
    # peak ratio: against the highest value outside the peak's (wrapped) 3-px neighbourhood
    dr = np.minimum(np.abs(np.arange(h)[None, :] - r0[:, None]), h - np.abs(np.arange(h)[None, :] - r0[:, None]))
    dc = np.minimum(np.abs(np.arange(w)[None, :] - c0[:, None]), w - np.abs(np.arange(w)[None, :] - c0[:, None]))
    near = (dr[:, :, None] <= 3) & (dc[:, None, :] <= 3)
    second = np.max(np.where(near, -np.inf, surf).reshape(n, -1), axis=1)
    ratio = peak / np.maximum(second, 1e-12 * np.abs(peak) + 1e-300)
    ry = np.where(r0 > h // 2, r0 - h, r0).astype(float)
    cx = np.where(c0 > w // 2, c0 - w, c0).astype(float)
    # upsampled DFT within 1 px of the integer peak, then a parabola at the finest step
    up = int(upsample)
    if up > 1:
        offs = np.arange(-up, up + 1) / up
        vals = _upsampled_dft(spec, ry[:, None] + offs[None], cx[:, None] + offs[None])
        m = len(offs)
        j = np.argmax(vals.reshape(n, -1), axis=1)
        jr, jc = np.unravel_index(j, (m, m))
        jr, jc = np.clip(jr, 1, m - 2), np.clip(jc, 1, m - 2)
        i = np.arange(n)
        ry = ry + offs[jr] + _parabola(vals[i, jr - 1, jc], vals[i, jr, jc], vals[i, jr + 1, jc]) / up
        cx = cx + offs[jc] + _parabola(vals[i, jr, jc - 1], vals[i, jr, jc], vals[i, jr, jc + 1]) / up
    shift = np.stack([cx, ry], axis=-1)
    return (shift[0], float(ratio[0])) if single else (shift, ratio)


# -------------------------------------------------------------------------------------------------
# window tests


def _ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """``(b,)`` mean SSIM of window pairs ``(b, h, w)``, each window standardised (module docstring); with
    ``mask`` (``(b, h, w)``, True where both are valid) over those pixels only: standardised over them,
    the local Gaussian moments by normalised convolution (Knutsson & Westin 1993), averaged over them."""
    from scipy.ndimage import gaussian_filter

    m = np.ones(a.shape, bool) if mask is None else mask
    count = np.maximum(m.sum(axis=(-2, -1), keepdims=True), 1)

    def z(x):
        mean = np.where(m, x, 0.0).sum(axis=(-2, -1), keepdims=True) / count
        d = np.where(m, x - mean, 0.0)
        s = np.sqrt((d * d).sum(axis=(-2, -1), keepdims=True) / count)
        return d / np.where(s > 0, s, 1.0)

    a, b = z(a), z(b)
    g = lambda x: gaussian_filter(x, (0, 1.5, 1.5), truncate=3.5)  # noqa: E731
    w = g(m.astype(float))
    gm = lambda x: g(x) / np.maximum(w, 1e-12)  # noqa: E731 -- the mean over the valid neighbours
    ma, mb = gm(a), gm(b)
    va, vb, cov = gm(a * a) - ma * ma, gm(b * b) - mb * mb, gm(a * b) - ma * mb
    c1, c2 = (0.01 * 6) ** 2, (0.03 * 6) ** 2
    s = (2 * ma * mb + c1) * (2 * cov + c2) / ((ma * ma + mb * mb + c1) * (va + vb + c2))
    k = 4  # the Gaussian's border
    inner = m[:, k:-k, k:-k]
    return np.where(inner, s[:, k:-k, k:-k], 0.0).sum(axis=(-2, -1)) / np.maximum(inner.sum(axis=(-2, -1)), 1)


def _median_test(centres: np.ndarray, resid: np.ndarray, use: np.ndarray, threshold: float) -> np.ndarray:
    """``(n,)`` True where the normalised median test (Westerweel & Scarano 2005) flags a window: its
    residual against the median of its 8 nearest used neighbours, over their median deviation + 0.1 px."""
    from scipy.spatial import cKDTree

    idx = np.flatnonzero(use)
    bad = np.zeros(len(centres), bool)
    if len(idx) < 4:
        return bad
    k = min(9, len(idx))
    _, nb = cKDTree(centres[idx]).query(centres[idx], k=k)
    nb = idx[nb[:, 1:]]  # without the window itself
    u = resid[nb]  # (m, k-1, 2)
    med = np.median(u, axis=1)
    spread = np.median(np.abs(u - med[:, None]), axis=1)
    r = np.abs(resid[idx] - med) / (spread + 0.1)
    bad[idx] = (r > threshold).any(axis=1)
    return bad


# -------------------------------------------------------------------------------------------------
# the result


@dataclasses.dataclass(frozen=True)
class CoRegistration:
    """The outcome of :func:`coregister` (module docstring).

    Attributes:
        global_shift: ``(2,)`` the global translation ``(dx, dy)``, px, from phase correlation of the
            whole overlap (relative to the georeferences' start when both are given).
        global_peak_ratio: its correlation peak ratio.
        centres: ``(n, 2)`` window centres, reference pixels ``(column, row)``.
        matches: ``(n, 2)`` where each centre lies in the target, target pixels (NaN where not measured).
        shifts: ``(n, 2)`` ``matches`` minus the start's position (the centre itself for one grid).
        status: ``(n,)`` one of :data:`STATUSES` per window.
        peak_ratio, ssim: ``(n,)`` the reliability figures of the last pass (NaN where not measured).
        model: the fitted ``reference pixel -> target pixel`` map (``(..., 2) -> (..., 2)``).
        model_name: ``"affine"``, ``"polynomial N"`` or ``"tps"``.
        rmse: radial RMS of the reliable windows' residuals against the model, px (leave-one-out for the
            interpolating TPS).
        iterations: measure-and-fit passes.
        start: the ``reference pixel -> target pixel`` map the georeferences give (None: the identity).

    Examples:
        A 192 px image and a copy moved by a sub-pixel shift: 64 px windows side by side make a
        3 x 3 grid, each measured and tested, and the affine model through them:

        >>> import numpy as np
        >>> from scipy import ndimage
        >>> import photax as ptx
        >>> ref = ndimage.gaussian_filter(np.random.default_rng(0).normal(size=(192, 192)), 2.0)
        >>> co = ptx.coregister(ref, ndimage.shift(ref, (-1.5, 2.25), order=3, mode="nearest"), window=64)
        >>> co.centres.shape, sorted(set(co.status.tolist())), co.model_name
        ((9, 2), ['ok'], 'affine')
        >>> print(np.round(np.median(co.shifts, axis=0), 2), bool(co.rmse < 0.05))  # px
        [ 2.26 -1.5 ] True
    """

    global_shift: np.ndarray
    global_peak_ratio: float
    centres: np.ndarray
    matches: np.ndarray
    shifts: np.ndarray
    status: np.ndarray
    peak_ratio: np.ndarray
    ssim: np.ndarray
    model: object
    model_name: str
    rmse: float
    iterations: int
    start: np.ndarray | None = None

    @property
    def counts(self) -> dict:
        """Windows per status, every status listed."""
        return {s: int(np.sum(self.status == s)) for s in STATUSES}

    @property
    def reliable(self) -> np.ndarray:
        """``(n,)`` True for the windows the model was fitted to."""
        return self.status == "ok"

    def shift_at(self, xy) -> np.ndarray:
        """``(..., 2)`` the model's shift at reference pixels ``xy``: target position minus the start's."""
        p = np.asarray(xy, dtype=float)
        return _evaluate(self.model, p) - _apply(self.start, p)

    def resample(self, target, shape, resampling: str = "cubic", nodata=None):
        """The target (``(..., H, W)``, bands first) resampled onto the reference grid of ``shape``
        ``(rows, cols)``: ``out[..., r, c] = target(model(c, r))``."""
        from ..resampling import resample

        rows, cols = int(shape[0]), int(shape[1])
        out = []
        step = max(1, 2**20 // max(cols, 1))
        for r0 in range(0, rows, step):
            cc, rr = np.meshgrid(np.arange(cols, dtype=float), np.arange(r0, min(rows, r0 + step), dtype=float))
            q = _evaluate(self.model, np.stack([cc, rr], axis=-1))
            out.append(np.asarray(resample(target, q[..., 0], q[..., 1], resampling, nodata=nodata)))
        return np.concatenate(out, axis=-2)

    def corrected_transform(self, reference_transform) -> tuple:
        """The GDAL geotransform ``(a, b, xoff, d, e, yoff)`` that puts the target's own pixels where the
        reference says they are: ``reference_transform`` after the inverse of the affine model.  Only for
        ``model="affine"``; resample for the others."""
        if self.model_name != "affine":
            raise ValueError(f"a corrected georeference needs the affine model, not {self.model_name}; resample")
        ref = _gdal_matrix(reference_transform)
        # the model in raster coordinates (pixel centre at c + 0.5): q' = M p' with p' = p + 0.5
        lin = _affine_matrix(self.model)
        half = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
        m = half @ lin @ np.linalg.inv(half)
        out = ref @ np.linalg.inv(m)
        return tuple(float(v) for v in out[:2].ravel())


def _gdal_matrix(t) -> np.ndarray:
    a, b, c, d, e, f = (float(v) for v in tuple(t)[:6])
    return np.array([[a, b, c], [d, e, f], [0, 0, 1.0]])


def _affine_matrix(model) -> np.ndarray:
    """3 x 3 matrix of an affine map given as a callable, from three points."""
    p = np.array([[0.0, 0.0], [1000.0, 0.0], [0.0, 1000.0]])
    q = np.asarray(model(p))
    m = np.eye(3)
    m[:2, 2] = q[0]
    m[:2, 0] = (q[1] - q[0]) / 1000.0
    m[:2, 1] = (q[2] - q[0]) / 1000.0
    return m


def _apply(m: np.ndarray | None, p: np.ndarray) -> np.ndarray:
    return p if m is None else p @ m[:2, :2].T + m[:2, 2]


def _fit(name: str, order: int, smoothing: float, src: np.ndarray, dst: np.ndarray):
    from ..polynomial import fit_polynomial, fit_tps

    if name == "tps":
        model = fit_tps(src, dst, smoothing)
        v = np.asarray(model.loo_residuals)
    else:
        model = fit_polynomial(src, dst, 1 if name == "affine" else order)
        v = np.asarray(model.residuals)
    v2 = np.sum(v**2, axis=1)
    v2 = v2[np.isfinite(v2)]
    return model, float(np.sqrt(np.mean(v2))) if len(v2) else float("nan")


@eqx.filter_jit
def _evaluate_jit(model, p):
    return model(p)


def _evaluate(model, p) -> np.ndarray:
    """``model(p)`` as numpy, a fitted (jax) model in one compiled call instead of one per operation."""
    return np.asarray(_evaluate_jit(model, p) if isinstance(model, eqx.Module) else model(p))


class _Translation:
    """The start plus the global shift as a model: ``p -> start(p + s)``."""

    def __init__(self, start, shift):
        self.start, self.shift = start, np.asarray(shift, dtype=float)

    def __call__(self, p):
        return _apply(self.start, np.asarray(p, dtype=float) + self.shift)


# -------------------------------------------------------------------------------------------------
# the registration


def coregister(
    reference,
    target,
    *,
    reference_transform=None,
    target_transform=None,
    window: int = 64,
    spacing: int | None = None,
    model: str = "affine",
    order: int = 2,
    smoothing: float = 0.0,
    method: str = "phase",
    min_texture: float = 0.1,
    min_peak_ratio: float = 2.0,
    min_ssim: float = 0.5,
    median_threshold: float = 2.0,
    max_nodata: float = 0.4,
    max_iterations: int = 5,
    tol: float = 0.02,
    resampling: str = "cubic",
) -> CoRegistration:
    """Register ``target`` to ``reference`` (module docstring).

    Args:
        reference, target: ``(H, W)`` grey images (one band; NaN for no data).  They may differ in size.
        reference_transform, target_transform: their GDAL geotransforms, both or neither; with both (one
            CRS) the start maps reference pixels to target pixels through the map, so the grids may
            differ in resolution and extent; without, the start is the identity (one pixel grid).
        window: side of the square measuring windows, px (even, >= 16).
        spacing: step of the window grid, px (default ``window``: windows side by side).
        model: ``"affine"``, ``"polynomial"`` (of ``order`` 1-5) or ``"tps"`` (thin-plate spline through
            the reliable windows, ``smoothing`` as :func:`photax.fit_tps`).
        method: ``"phase"`` (phase correlation) or ``"lsm"`` (least-squares matching per window,
            :func:`photax.measure.match_lsm`, its affine window over the central half).
        min_texture, min_peak_ratio, min_ssim, median_threshold: the reliability tests (module docstring).
        max_nodata: the largest share of a window (0 .. 1) outside either image or no data in either; the
            rest is measured by masked correlation (module docstring). 0.4 keeps windows over a DSM with
            scattered holes; a window needs enough valid pixels to measure, so above about 0.6 the
            shifts of the windows left become noisy.
        max_iterations, tol: measure-and-fit passes at most; stop when the model moves no reliable
            window's centre by ``tol`` px or more.
        resampling: kernel that brings the target onto the reference grid (:func:`photax.resample`).

    Returns:
        :class:`CoRegistration`.

    Raises:
        ValueError: bad shapes or arguments; too few reliable windows for the model (the counts per
            reason are in the message): a failed registration never looks like a good one.

    Examples:
        A target moved by 2.25 columns and -1.5 rows: the fitted model maps each reference pixel
        there, to a hundredth of a pixel:

        >>> import numpy as np
        >>> from scipy import ndimage
        >>> import photax as ptx
        >>> ref = ndimage.gaussian_filter(np.random.default_rng(0).normal(size=(192, 192)), 2.0)
        >>> target = ndimage.shift(ref, (-1.5, 2.25), order=3, mode="nearest")  # (rows, columns)
        >>> co = ptx.coregister(ref, target, window=64)
        >>> moved = np.asarray(co.model(np.array([[96.0, 96.0]])))[0] - 96.0
        >>> bool(np.allclose(moved, [2.25, -1.5], atol=0.01))
        True

    """

    from ..resampling import resample

    ref = np.asarray(reference, dtype=float)
    tgt = np.asarray(target, dtype=float)
    if ref.ndim != 2 or tgt.ndim != 2:
        raise ValueError(f"reference and target must be (H, W) grey images, got {ref.shape} and {tgt.shape}")
    window = int(window)
    if window < 16 or window % 2:
        raise ValueError(f"window must be an even number of px >= 16, got {window}")
    spacing = window if spacing is None else int(spacing)
    if spacing < 1:
        raise ValueError(f"spacing must be >= 1 px, got {spacing}")
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    if model == "polynomial" and not (isinstance(order, (int, np.integer)) and 1 <= order <= 5):
        raise ValueError(f"order must be an integer from 1 to 5, got {order!r}")
    if not 0.0 <= float(max_nodata) < 1.0:
        raise ValueError(f"max_nodata must be a share in [0, 1), got {max_nodata!r}")
    if method not in ("phase", "lsm"):
        raise ValueError(f"method must be 'phase' or 'lsm', got {method!r}")
    if (reference_transform is None) != (target_transform is None):
        raise ValueError("give both reference_transform and target_transform, or neither")
    start = None
    if reference_transform is not None:
        half = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
        start = np.linalg.inv(half) @ np.linalg.inv(_gdal_matrix(target_transform)) @ _gdal_matrix(
            reference_transform
        ) @ half  # fmt: skip
    h, w = ref.shape
    if h < window or w < window:
        raise ValueError(f"the reference ({w} x {h} px) is smaller than one window ({window} px)")

    holes = tgt_filled = None
    if not np.isfinite(tgt).all():
        from scipy.ndimage import distance_transform_edt

        bad = ~np.isfinite(tgt)
        if bad.all():
            raise ValueError("the target has no data (all NaN)")
        nearest = distance_transform_edt(bad, return_distances=False, return_indices=True)
        tgt_filled = tgt[tuple(nearest)]
        holes = bad.astype(float)

    def warp(m):
        """The target resampled onto the reference grid through the model ``m``, which is evaluated every
        8 px and interpolated by cubic splines in between (a smooth map: ~1e-3 px)."""
        from scipy.ndimage import map_coordinates

        step = 8
        gy, gx = np.arange(0, h + step, step, dtype=float), np.arange(0, w + step, step, dtype=float)
        coarse = _evaluate(m, np.stack(np.meshgrid(gx, gy), axis=-1))
        rr, cc = np.mgrid[0:h, 0:w] / step
        q = [map_coordinates(coarse[..., k], [rr, cc], order=3, mode="nearest") for k in range(2)]
        if holes is None:
            return np.asarray(resample(tgt, q[0], q[1], resampling))
        # no data: the kernel runs over the target filled by its nearest valid pixel, and a position whose
        # bilinear weights lie on holes for half or more is no data: the holes keep their size (a cubic
        # kernel's 4 x 4 taps would widen each by 2 px, each resampling again: a DSM's scattered holes,
        # already widened in the orthos by the DEM's bilinear heights, would blank every window)
        out = np.asarray(resample(tgt_filled, q[0], q[1], resampling))
        on_holes = np.asarray(resample(holes, q[0], q[1], "bilinear"))
        return np.where(on_holes >= 0.5, np.nan, out)

    # 1. global shift on the overlap (no-data filled with each image's mean there)
    warped = warp(lambda p: _apply(start, p))
    valid = np.isfinite(ref) & np.isfinite(warped)
    if valid.mean() < 0.1:
        raise ValueError(f"the images overlap on {100 * valid.mean():.1f} % of the reference only")
    rv = np.where(valid, ref, np.nanmean(ref[valid]))
    tv = np.where(valid, warped, np.nanmean(warped[valid]))
    gshift, gratio = phase_correlation(rv, tv, upsample=10)  # the windows refine it
    current = _Translation(start, gshift)

    # 2. the window grid
    half_w = window // 2
    ys = np.arange(half_w, h - half_w + 1, spacing)
    xs = np.arange(half_w, w - half_w + 1, spacing)
    centres = np.array([(x - 0.5, y - 0.5) for y in ys for x in xs], dtype=float)  # between the window's 2 middle px
    n = len(centres)
    r0 = (centres[:, 1] + 0.5).astype(int) - half_w
    c0 = (centres[:, 0] + 0.5).astype(int) - half_w
    take = lambda img: np.stack([img[a : a + window, b : b + window] for a, b in zip(r0, c0)])  # noqa: E731
    ref_w = take(ref)
    ref_std = float(np.nanstd(ref))
    min_size = 3 if model != "polynomial" else (order + 1) * (order + 2) // 2
    fitted, rmse, it = None, float("nan"), 0
    status = np.full(n, "ok", dtype=object)
    matches = np.full((n, 2), np.nan)
    ratio, sim = np.full(n, np.nan), np.full(n, np.nan)
    for it in range(1, max_iterations + 1):  # noqa: B007 -- the passes made are kept
        warped = warp(current)
        tgt_w = take(warped)
        status = np.full(n, "ok", dtype=object)
        both = np.isfinite(ref_w) & np.isfinite(tgt_w)  # the pixels a window's correlation is taken over
        status[np.mean(~both, axis=(1, 2)) > max_nodata] = "no data"
        a, b = _masked(ref_w, both), _masked(tgt_w, both)
        tgt_std = float(np.nanstd(warped))
        count = np.maximum(both.sum(axis=(1, 2)), 1)
        sa, sb = (np.sqrt((x * x).sum(axis=(1, 2)) / count) for x in (a, b))  # over the valid pixels
        flat = (sa < min_texture * ref_std) | (sb < min_texture * tgt_std)
        status[(status == "ok") & flat] = "textureless"
        live = status == "ok"
        resid = np.full((n, 2), np.nan)
        ratio, sim = np.full(n, np.nan), np.full(n, np.nan)
        if live.any():
            s, pr = phase_correlation(a[live], b[live], upsample=20)
            ratio[live] = pr
            if method == "lsm":  # every window, one point count: one compilation for all passes
                start_all = np.zeros((n, 2))
                start_all[live] = s
                s = _lsm(ref, warped, centres, start_all, window)[live]
            resid[live] = s
        weak = live & ((ratio < min_peak_ratio) | ~np.all(np.abs(resid) <= window / 4, axis=1))
        status[weak] = "weak peak"
        live = status == "ok"
        if live.any():
            # the target window moved by the residual shift, against the reference window
            shifted = np.stack([_shift_window(b[i], resid[i]) for i in np.flatnonzero(live)])
            sim[live] = _ssim(a[live], shifted, both[live])
        status[live & (sim < min_ssim)] = "dissimilar"
        live = status == "ok"
        if it > 1:  # residuals against a fitted model (the first pass's are the whole local field)
            status[_median_test(centres, resid, live, median_threshold)] = "outlier"
        live = status == "ok"
        matches = np.full((n, 2), np.nan)
        measured = np.isfinite(resid).all(axis=1)
        matches[measured] = _evaluate(current, np.where(measured[:, None], centres + resid, centres))[measured]
        if live.sum() < min_size:
            counts = {k: int(np.sum(status == k)) for k in STATUSES}
            raise ValueError(
                f"only {int(live.sum())} reliable windows, the {model} model needs {min_size}: windows {counts}"
            )
        fitted, rmse = _fit(model, order, smoothing, centres[live], matches[live])
        moved = np.max(np.linalg.norm(_evaluate(fitted, centres) - _evaluate(current, centres), axis=1)[live])
        current = fitted
        if moved < tol and it > 1:
            break
    return CoRegistration(
        global_shift=np.asarray(gshift),
        global_peak_ratio=float(gratio),
        centres=centres,
        matches=matches,
        shifts=matches - _apply(start, centres),
        status=np.asarray(status, dtype=str),
        peak_ratio=ratio,
        ssim=sim,
        model=fitted,
        model_name=f"polynomial {order}" if model == "polynomial" else model,
        rmse=rmse,
        iterations=it,
        start=start,
    )


def _masked(windows: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``(n, h, w)`` windows reduced to ``mask`` (the pixels valid in both windows of a pair): minus their
    mean over it, 0 elsewhere (0 everywhere for an empty mask)."""
    mean = np.where(mask, windows, 0.0).sum(axis=(1, 2), keepdims=True) / np.maximum(
        mask.sum(axis=(1, 2), keepdims=True), 1
    )
    return np.where(mask, windows - mean, 0.0)


def _shift_window(b: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The window ``b`` sampled at ``p + d`` (Fourier shift: exact for a band-limited window, wraps at
    the edges, which the SSIM's border trim and the taper-free centre keep small)."""
    h, w = b.shape
    fy, fx = np.fft.fftfreq(h)[:, None], np.fft.fftfreq(w)[None, :]
    return np.real(np.fft.ifft2(np.fft.fft2(b) * np.exp(2j * np.pi * (fx * d[0] + fy * d[1]))))


def _lsm(ref, warped, centres, start, window):
    """Residual shifts by least-squares matching of the central half of each window, from ``start``."""
    from ..measure import match_lsm

    half = window // 4
    tpl = np.nan_to_num(ref, nan=float(np.nanmean(ref)))
    srch = np.nan_to_num(warped, nan=float(np.nanmean(warped)))
    xy = centres + 0.5  # an integer pixel for the template centre
    res = match_lsm(tpl, xy, srch, xy + start, window=half, margin=max(5, half // 2))
    out = np.asarray(res.xy) - xy
    return np.where(np.asarray(res.valid)[:, None], out, np.nan)  # a failed match: "weak peak"
