"""Pan-sharpening: a multispectral (MS) image brought to the resolution of a panchromatic (PAN) one.

Every method writes the fused band ``k`` as the MS band interpolated onto the PAN grid, ``M~_k``, plus
detail taken from the PAN (Vivone et al. 2015, "A critical comparison among pansharpening algorithms",
IEEE TGRS 53(5), eqs. 1-2):

* **component substitution** (CS): ``F_k = M~_k + g_k (P' - I)``, ``I = sum_i w_i M~_i`` an intensity
  the MS bands synthesise, ``P'`` the PAN matched to ``I``'s mean and standard deviation:

  - ``"brovey"``: ``F_k = M~_k P' / I`` (multiplicative; Gillespie et al. 1987);
  - ``"ihs"``: generalised IHS (fast IHS of Tu et al. 2001), ``g_k = 1``;
  - ``"pca"``: ``I`` the first principal component of the MS bands, ``g`` its eigenvector;
  - ``"gs"``: Gram-Schmidt (Laben & Brower 2000, US patent 6,011,875; the recipe of Maurer 2013):
    ``g_k = cov(M_k, I) / var(I)``, which is what the forward transform, the substitution of the first
    component and the inverse transform amount to;
  - ``"gsa"``: adaptive GS (Aiazzi et al. 2007): the weights (and an offset) fitted by least squares of
    the PAN low-passed by the MTF-matched Gaussian below on the MS bands, no sign constraint;

* **multiresolution analysis** (MRA): ``F_k = M~_k + (s_k / s_P) (P - P_L,k)``, or the modulation
  ``F_k = M~_k P'_k / P'_L,k``, ``P_L`` a low-pass PAN and ``s`` standard deviations at MS resolution:

  - ``"hpf"``: ``P_L`` a box filter of the ratio's odd size (Chavez et al. 1991);
  - ``"sfim"``: the same box filter, modulation (Liu 2000);
  - ``"mtf_glp"``: ``P_L`` the PAN filtered by a Gaussian matched to the MS sensor's modulation transfer
    function, decimated onto the MS grid and interpolated back with the MS's own kernel (generalised
    Laplacian pyramid, Aiazzi et al. 2006); the Gaussian's gain at the MS Nyquist frequency ``1 / (2 r)``
    cycles per PAN pixel is ``nyquist_gain``: ``sigma = r sqrt(-2 ln G) / pi`` PAN pixels;
  - ``"mtf_glp_hpm"``: the same low-pass, modulation (high-pass modulation, Vivone et al. 2013).

Statistics (weights, gains, the matching of the PAN) are computed at the MS resolution over the pixels
where both images are valid: the PAN averaged over each MS pixel (the PAN pixels whose centres fall in
it) against the MS pixel, as orthority does.  Weights ``None`` are estimated from the data: least
squares of that averaged PAN on the MS bands, the bands with a negative weight refitted without them
(non-negative least squares), normalised to sum to one -- orthority's policy (Maurer 2013, eq. 6).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import _geometry

METHODS = ("brovey", "ihs", "pca", "gs", "gsa", "hpf", "sfim", "mtf_glp", "mtf_glp_hpm")
_CS = ("brovey", "ihs", "pca", "gs", "gsa")
_WEIGHTED = ("brovey", "ihs", "gs")


@dataclasses.dataclass(frozen=True)
class Sharpened:
    """A pan-sharpened image on the PAN grid (cropped to the pixels the MS covers).

    Attributes:
        image: ``(bands, rows, cols)`` in the MS dtype; integer dtypes rounded to nearest and clipped to
            the dtype's range (``clipped`` says how many values were), invalid pixels ``nodata``.
        valid: ``(rows, cols)`` bool, where PAN and MS were both valid.
        window: ``(row0, col0)`` of the image's top-left pixel in the PAN image.
        transform: the image's affine georeference (the PAN's, shifted to ``window``), or None.
        nodata: the value of the invalid pixels (None when every pixel is valid).
        method: the method's name.
        weights: ``(bands,)`` the intensity's band weights (CS methods; None for MRA).
        gains: ``(bands,)`` the injection gains ``g_k`` (additive methods) or ``s_k / s_P`` (MRA).
        ratio: the PAN/MS pixel-size ratio (> 1).
        clipped: how many output values fell outside the dtype's range and were clipped.

    Examples:
        What :func:`photax.pansharpen` returns besides the image: the method, the size ratio,
        where the output lies in the PAN and is valid, and the intensity's band weights (estimated,
        or as given, normalised to sum to 1):

        >>> import numpy as np
        >>> import photax as ptx
        >>> pan = np.random.default_rng(0).uniform(50, 150, (64, 64))
        >>> ms = np.stack([k * pan.reshape(16, 4, 16, 4).mean(axis=(1, 3)) for k in (0.8, 1.0, 1.2)])
        >>> out = ptx.pansharpen(pan, ms, "gs")
        >>> out.method, out.ratio, out.window, bool(out.valid.all()), out.clipped
        ('gs', 4.0, (0, 0), True, 0)
        >>> print(f"{out.weights.sum():.6f}", ptx.pansharpen(pan, ms, "gs", weights=[1, 2, 1]).weights.tolist())
        1.000000 [0.25, 0.5, 0.25]

    """

    image: np.ndarray
    valid: np.ndarray
    window: tuple[int, int]
    transform: object
    nodata: float | None
    method: str
    weights: np.ndarray | None
    gains: np.ndarray
    ratio: float
    clipped: int


def mtf_sigma(ratio: float, nyquist_gain: float) -> float:
    """The standard deviation (PAN pixels) of the Gaussian whose frequency response
    ``exp(-2 pi^2 sigma^2 f^2)`` equals ``nyquist_gain`` at the MS Nyquist frequency ``f = 1 / (2 ratio)``.

    Examples:
        The Gaussian's sigma by hand: ``exp(-2 pi^2 sigma^2 f^2) = g`` at ``f = 1 / (2 ratio)``:

        >>> import numpy as np
        >>> from photax.fusion import mtf_sigma
        >>> ratio, gain = 4, 0.3
        >>> by_hand = np.sqrt(-np.log(gain) / (2 * np.pi**2)) * 2 * ratio
        >>> print(f"{mtf_sigma(ratio, gain):.6f} {by_hand:.6f}")
        1.975757 1.975757
    """
    if not 0 < nyquist_gain < 1:
        raise ValueError(f"nyquist_gain must be in (0, 1), got {nyquist_gain}")
    return float(ratio * np.sqrt(-2.0 * np.log(nyquist_gain)) / np.pi)


def _gaussian(image, sigma):
    from scipy import ndimage

    return ndimage.gaussian_filter(image, sigma, mode="nearest", truncate=4.0)


def _nnls_weights(cov_mm, cov_pm):
    """Least squares weights of the PAN on the MS bands from their covariances; bands that come out
    negative are dropped and the rest refitted (non-negative least squares); normalised to sum to 1."""
    w = np.linalg.lstsq(cov_mm, cov_pm, rcond=None)[0]
    if np.any(w < 0):
        from scipy.optimize import nnls  # 1.4 s to import: only when needed

        # min ||P - w.M||^2 = w'Cw - 2 w'c + const = ||L'w - L^-1 c||^2 with C = L L'
        vals, vecs = np.linalg.eigh(cov_mm)
        root = vecs * np.sqrt(np.clip(vals, 0, None))  # root root' = C
        rhs = np.linalg.lstsq(root, cov_pm, rcond=None)[0]
        w = nnls(root.T, rhs)[0]
    if not np.any(w > 0):
        raise ValueError("the PAN is not positively related to any MS band: give weights")
    return w / w.sum()


def _check_weights(weights, bands):
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (bands,):
        raise ValueError(f"weights must have one value per MS band ({bands}), got shape {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0) or not w.sum() > 0:
        raise ValueError("weights must be finite, >= 0 and not all zero")
    return w / w.sum()


def _ratio_or_one(num, den, floor):
    """``num / den`` where ``den > floor``, else 1 (no detail where the low-pass vanishes)."""
    ok = den > floor
    return np.where(ok, num / np.where(ok, den, 1), 1).astype(np.float32)


def pansharpen(
    pan,
    ms,
    method: str = "gs",
    *,
    pan_transform=None,
    ms_transform=None,
    pan_crs=None,
    ms_crs=None,
    weights=None,
    resampling: str = "cubic",
    nyquist_gain=0.3,
    pan_nodata=None,
    ms_nodata=None,
) -> Sharpened:
    """Pan-sharpen ``ms`` with ``pan`` (the methods and their formulas: the module docstring).

    Args:
        pan: ``(rows, cols)`` or ``(1, rows, cols)`` panchromatic image, any real dtype.
        ms: ``(bands, rows, cols)`` multispectral image, any real dtype; its pixels are larger.
        method: one of :data:`METHODS`.
        pan_transform, ms_transform: affine georeferences (GDAL order, pixel corners), or None for an
            image without georeference: it is taken to cover the other's bounds exactly.  The output is on
            the PAN grid; the MS is mapped onto it through both transforms (and the two CRSs, which may
            differ), cropped to the PAN pixels it covers.
        pan_crs, ms_crs: the CRSs (anything rasterio accepts), both or neither.
        weights: ``(bands,)`` band weights of the intensity (``"brovey"``, ``"ihs"``, ``"gs"``), or
            ``"equal"``, or None: estimated from the data (the module docstring).
        resampling: photax's kernel interpolating the MS onto the PAN grid (:class:`photax.Resampling`).
        nyquist_gain: the MS sensor's MTF at its Nyquist frequency, one value or one per band
            (``"gsa"``, ``"mtf_glp"``, ``"mtf_glp_hpm"``); 0.3 is typical of satellite MS sensors.
        pan_nodata, ms_nodata: values marking invalid pixels (NaN is always invalid in float images).

    Returns:
        :class:`Sharpened`.  The arithmetic is float32 pixels and float64 statistics.  For scenes larger
        than memory: :func:`pansharpen_dask`, the same code block by block.

    Raises:
        ValueError: the images do not overlap, the MS has one band with a component-substitution method
            (it would return the PAN rescaled), its pixels are not larger than the PAN's, too few pixels
            are valid in both to estimate the statistics, or a bad argument.

    Examples:
        A PAN image at 4x the MS resolution whose detail the MS lacks: the sharpened bands take the
        PAN's detail and keep each band's mean (component substitution, Gram-Schmidt):

        >>> import numpy as np
        >>> import photax as ptx
        >>> rng = np.random.default_rng(0)
        >>> pan = rng.uniform(50, 150, (64, 64))
        >>> ms = np.stack([k * pan.reshape(16, 4, 16, 4).mean(axis=(1, 3)) for k in (0.8, 1.0, 1.2)])  # (3, 16, 16)
        >>> out = ptx.pansharpen(pan, ms, "gs")
        >>> out.image.shape
        (3, 64, 64)
        >>> bool(np.corrcoef(np.asarray(out.image[1]).ravel(), pan.ravel())[0, 1] > 0.9)
        True
    """
    pan = np.asarray(pan)
    if pan.ndim == 3 and pan.shape[0] == 1:
        pan = pan[0]
    ms = np.asarray(ms)
    plan = make_plan(
        pan.shape,
        pan.dtype,
        ms.shape,
        ms.dtype,
        method,
        pan_transform=pan_transform,
        ms_transform=ms_transform,
        pan_crs=pan_crs,
        ms_crs=ms_crs,
        weights=weights,
        resampling=resampling,
        nyquist_gain=nyquist_gain,
        pan_nodata=pan_nodata,
        ms_nodata=ms_nodata,
    )
    # The three passes of pansharpen_dask, each over one block: the whole PAN.
    whole = (0, 0, *pan.shape)
    sums = [pan_sums(plan, pan, whole)]
    fill = pan_fill(sums)
    lows = [lowpass_at_ms(plan, fill, pan, whole, whole, *ms_points(plan))] if plan.sigmas else []
    stats = statistics(plan, ms, fill, sums, lows)
    r0, r1, c0, c1 = plan.window
    fused, valid = fuse(plan, stats, pan, whole, (r0, c0, r1 - r0, c1 - c0))
    image, nodata, clipped = _to_dtype(fused, valid, ms.dtype, ms_nodata)
    return Sharpened(
        image,
        valid,
        (r0, c0),
        plan.out_transform,
        nodata,
        method,
        stats.weights,
        np.asarray(stats.gains),
        plan.ratio,
        clipped,
    )


@dataclasses.dataclass(frozen=True, eq=False)
class Plan:
    """What pan-sharpening a pair does, known before any pixel is read: the geometry (the PAN window the
    MS covers, the pixel-size ratio), the options checked, and the filters' footprints."""

    method: str
    pan_shape: tuple[int, int]
    ms_shape: tuple[int, int, int]
    ms_dtype: np.dtype
    pan_transform: object
    ms_transform: object
    pan_crs: object
    ms_crs: object
    window: tuple[int, int, int, int]  # (r0, r1, c0, c1) of the PAN pixels the MS covers
    ratio: float
    resampling: str
    weights: object
    nyquist: np.ndarray
    pan_nodata: object
    ms_nodata: object

    def positions(self, window):
        """MS ``(cols, rows)`` of the PAN pixels of ``window`` ``(r0, c0, h, w)``."""
        return _geometry.positions(
            self.pan_shape,
            self.pan_transform,
            self.pan_crs,
            self.ms_shape[1:],
            self.ms_transform,
            self.ms_crs,
            window,
        )

    @property
    def sigmas(self) -> tuple[float, ...]:
        """The MTF-matched Gaussians' standard deviations (PAN pixels) the method low-passes the PAN by."""
        if self.method == "gsa":
            return (float(np.mean([mtf_sigma(self.ratio, g) for g in self.nyquist])),)
        if self.method in ("mtf_glp", "mtf_glp_hpm"):
            return tuple(dict.fromkeys(mtf_sigma(self.ratio, g) for g in self.nyquist))
        return ()

    @property
    def box(self) -> int:
        """The box filter's odd size (HPF, SFIM)."""
        return 2 * int(np.floor(self.ratio / 2)) + 1

    @property
    def halo(self) -> int:
        """PAN pixels around an output block its fusion reads (the box filter's radius)."""
        return self.box // 2 if self.method in ("hpf", "sfim") else 0

    @property
    def lowpass_halo(self) -> int:
        """PAN pixels around a block its Gaussians (truncated at 4 sigma) and their bilinear sampling read."""
        return int(4.0 * max(self.sigmas) + 0.5) + 2 if self.sigmas else 0

    @property
    def out_transform(self):
        if self.pan_transform is None:
            return None
        r0, _, c0, _ = self.window
        return _geometry._affine(self.pan_transform) * _geometry._affine((1, 0, c0, 0, 1, r0))


def make_plan(pan_shape, pan_dtype, ms_shape, ms_dtype, method, **options) -> Plan:
    """Check a pan-sharpening's arguments (those of :func:`pansharpen`) and find its geometry."""
    from ..kernels import Resampling

    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    resampling = Resampling.check(options["resampling"]).value
    if len(pan_shape) != 2:
        raise ValueError(f"pan must be (rows, cols) or (1, rows, cols), got shape {tuple(pan_shape)}")
    if len(ms_shape) != 3:
        raise ValueError(f"ms must be (bands, rows, cols), got shape {tuple(ms_shape)}")
    for name, dt in (("pan", np.dtype(pan_dtype)), ("ms", np.dtype(ms_dtype))):
        if not (np.issubdtype(dt, np.integer) or np.issubdtype(dt, np.floating)) or dt == np.bool_:
            raise ValueError(f"{name} must have an integer or float dtype, got {dt}")
    bands = ms_shape[0]
    if bands == 1 and method in _CS:
        raise ValueError(
            f"the MS image has one band: {method!r} (component substitution) would return the "
            "PAN rescaled to it; use an MRA method (hpf, sfim, mtf_glp, mtf_glp_hpm)"
        )
    weights = options["weights"]
    if weights is not None and method not in _WEIGHTED:
        raise ValueError(f"weights apply to {_WEIGHTED}, not {method!r}")
    if isinstance(weights, str):
        if weights != "equal":
            raise ValueError(f"weights must be values, 'equal' or None, got {weights!r}")
        weights = np.full(bands, 1.0 / bands)
    elif weights is not None:
        weights = _check_weights(weights, bands)
    gain = options["nyquist_gain"]
    nyquist = np.asarray(gain, dtype=np.float64)
    nyquist = np.broadcast_to(nyquist, (bands,)).copy() if nyquist.ndim == 0 else nyquist
    if nyquist.shape != (bands,):
        raise ValueError(f"nyquist_gain must be one value or one per MS band ({bands})")
    georef = {k: options[k] for k in ("pan_transform", "ms_transform", "pan_crs", "ms_crs")}
    window, ratio = _geometry.footprint(
        tuple(pan_shape),
        georef["pan_transform"],
        georef["pan_crs"],
        tuple(ms_shape[1:]),
        georef["ms_transform"],
        georef["ms_crs"],
    )
    if window is None:
        raise ValueError("the PAN and MS images do not overlap")
    if not ratio > 1.0 + 1e-9:
        raise ValueError(f"the MS pixels must be larger than the PAN's (size ratio {ratio:.3g})")
    plan = Plan(
        method,
        tuple(pan_shape),
        tuple(ms_shape),
        np.dtype(ms_dtype),
        window=window,
        ratio=ratio,
        resampling=resampling,
        weights=weights,
        nyquist=nyquist,
        pan_nodata=options["pan_nodata"],
        ms_nodata=options["ms_nodata"],
        **georef,
    )
    plan.sigmas  # noqa: B018  (nyquist_gain checked: mtf_sigma raises outside (0, 1))
    return plan


def _inner(block, origin, window):
    """The part of ``block`` (whose top-left pixel is ``origin`` ``(r, c, ...)``) under ``window``
    ``(r0, c0, h, w)``."""
    r, c = origin[:2]
    r0, c0, h, w = window
    return block[..., r0 - r : r0 - r + h, c0 - c : c0 - c + w]


def pan_sums(plan: Plan, block, window):
    """The statistics pass over one PAN block ``window`` ``(r0, c0, h, w)`` (``block`` its pixels): the sum
    and count of its valid pixels, and over the box of MS pixels its pixels fall in (its top-left MS pixel
    ``(row, col)``, then per MS pixel): how many of them, how many valid, and their sum (the PAN averaged
    over each MS pixel, once added up)."""
    block = np.asarray(block)
    ok = _valid(block, plan.pan_nodata)
    total, n = float(block[ok].sum(dtype=np.float64)), int(ok.sum())
    r0, r1, c0, c1 = plan.window
    br, bc, bh, bw = window
    a0, a1, b0, b1 = max(br, r0), min(br + bh, r1), max(bc, c0), min(bc + bw, c1)
    if a1 <= a0 or b1 <= b0:
        return total, n, None
    part = (a0, b0, a1 - a0, b1 - b0)
    cols, rows = plan.positions(part)
    covered = _geometry.inside(cols, rows, plan.ms_shape[1:])
    if not covered.any():
        return total, n, None
    h, w = plan.ms_shape[1:]
    ci = np.clip(np.floor(cols[covered] + 0.5).astype(np.int64), 0, w - 1)
    ri = np.clip(np.floor(rows[covered] + 0.5).astype(np.int64), 0, h - 1)
    top, left = int(ri.min()), int(ci.min())
    bh, bw = int(ri.max()) + 1 - top, int(ci.max()) + 1 - left
    flat = (ri - top) * bw + (ci - left)
    okc = _inner(ok, window, part)[covered]
    vals = np.where(okc, _inner(block, window, part)[covered].astype(np.float32), np.float32(0))
    sums = [np.bincount(flat, weights=x, minlength=bh * bw).reshape(bh, bw) for x in (None, okc, vals)]
    return total, n, (top, left, *sums)


def pan_fill(sums) -> np.float32:
    """The value invalid PAN pixels are filled with (so that they do not smear through the kernels): the
    mean of the valid ones."""
    total, n = sum(s[0] for s in sums), sum(s[1] for s in sums)
    if n == 0:
        raise ValueError("the PAN image has no valid pixel")
    return np.float32(total / n)


def _filled(plan: Plan, block, fill):
    block = np.asarray(block)
    ok = _valid(block, plan.pan_nodata)
    p = block.astype(np.float32)
    p[~ok] = fill
    return p, ok


def ms_points(plan: Plan):
    """The PAN ``(cols, rows)`` of every MS pixel centre (MS-resolution arrays)."""
    return _geometry.positions(
        plan.ms_shape[1:], plan.ms_transform, plan.ms_crs, plan.pan_shape, plan.pan_transform, plan.pan_crs
    )


def lowpass_at_ms(plan: Plan, fill, block, window, core, cols, rows, index=None):
    """The low-pass pass over one PAN block: ``block`` the pixels of ``window`` ``(r0, c0, h, w)``, ``core``
    the part it answers for (``window`` is ``core`` plus :attr:`Plan.lowpass_halo`, clipped to the PAN).
    Per Gaussian of :attr:`Plan.sigmas`: the sum of the filtered PAN over ``core`` (its mean, once added
    up) and its bilinear samples at the PAN positions ``(cols, rows)`` of the MS pixels ``index`` (flat;
    None: all) whose centres fall in ``core`` (NaN outside the PAN)."""
    p, _ = _filled(plan, block, fill)
    out = []
    for s in plan.sigmas:
        g = _gaussian(p, s)
        out.append(
            (float(_inner(g, window, core).sum(dtype=np.float64)), _bilinear(g, window, plan.pan_shape, cols, rows))
        )
    return index, out


def _bilinear(block, window, shape, cols, rows):
    """``block`` (the pixels of ``window`` of an image of ``shape``) at the image's positions ``(cols,
    rows)``: :func:`photax.kernels.resample_grid`'s bilinear kernel (edges replicated, NaN outside the
    image's footprint), at scattered points; the block holds every tap of the points inside the image."""
    r, c, h, w = window
    cols, rows = np.asarray(cols, np.float64), np.asarray(rows, np.float64)
    ok = _geometry.inside(cols, rows, shape)
    x0, y0 = np.floor(np.where(ok, cols, 0)), np.floor(np.where(ok, rows, 0))
    wx, wy = (np.where(ok, cols, 0) - x0).astype(np.float32), (np.where(ok, rows, 0) - y0).astype(np.float32)
    xa = np.clip(x0.astype(np.int64), 0, shape[1] - 1) - c
    xb = np.clip(x0.astype(np.int64) + 1, 0, shape[1] - 1) - c
    ya = np.clip(y0.astype(np.int64), 0, shape[0] - 1) - r
    yb = np.clip(y0.astype(np.int64) + 1, 0, shape[0] - 1) - r
    if ok.any() and (
        min(xa[ok].min(), ya[ok].min()) < 0 or xb[ok].max() >= w or yb[ok].max() >= h
    ):  # pragma: no cover  (the halo covers every tap)
        raise RuntimeError("photax: a low-pass block misses the taps of its MS pixels; please report this")
    xa, xb, ya, yb = (np.where(ok, v, 0) for v in (xa, xb, ya, yb))
    top = block[ya, xa] * (1 - wx) + block[ya, xb] * wx
    bottom = block[yb, xa] * (1 - wx) + block[yb, xb] * wx
    return np.where(ok, top * (1 - wy) + bottom * wy, np.float32(np.nan)).astype(np.float32)


@dataclasses.dataclass(frozen=True, eq=False)
class Statistics:
    """The global statistics of a pan-sharpening (at MS resolution, float64), and the MS-resolution
    arrays every block samples: the MS with its invalid pixels filled, and the decimated low-passes."""

    fill: np.float32  # the PAN's invalid pixels
    m: np.ndarray  # (bands, h, w) float32 MS, invalid pixels filled with the band's valid mean
    ms_ok: np.ndarray  # (h, w) bool
    mu_p: float
    s_p: float
    mu_m: np.ndarray
    s_m: np.ndarray
    weights: np.ndarray | None  # intensity weights (CS), the first eigenvector (PCA)
    offset: float
    gains: np.ndarray
    mu_i: float  # the intensity's mean and std the PAN is matched to (CS)
    s_i: float
    decimated: dict  # sigma -> (h, w) float32 low-passed PAN at the MS pixel centres (GSA, MTF-GLP)


def statistics(plan: Plan, ms, fill, sums, lows) -> Statistics:
    """The statistics of the pair from the passes' results (:func:`pan_sums` per PAN block, and
    :func:`lowpass_at_ms` per block for the methods that low-pass the PAN by a Gaussian): whatever the
    blocks, the same sums as over the whole image at once."""
    ms = np.asarray(ms)
    bands, h, w = ms.shape
    ms_ok = np.all([_valid(b, plan.ms_nodata) for b in ms], axis=0)
    if not ms_ok.any():
        raise ValueError("the MS image has no valid pixel")
    m = ms.astype(np.float32)
    for b in m:
        b[~ms_ok] = b[ms_ok].mean(dtype=np.float64)
    count, good, p_sum = np.zeros((h, w)), np.zeros((h, w)), np.zeros((h, w))
    for s in sums:
        if s[2] is not None:
            top, left, c, g, v = s[2]
            box = np.s_[top : top + c.shape[0], left : left + c.shape[1]]
            count[box] += c
            good[box] += g
            p_sum[box] += v
    p_avg = p_sum / np.maximum(count, 1)
    lo = ms_ok & (count >= 0.5 * plan.ratio**2) & (good == count)
    n = int(lo.sum())
    if n < max(16, 2 * bands + 2):
        raise ValueError(
            f"too few MS pixels where both images are valid to estimate the statistics: {n} "
            f"(at least {max(16, 2 * bands + 2)} needed)"
        )
    stack = np.concatenate([p_avg[lo][None], m[:, lo]]).astype(np.float64)
    mean = stack.mean(axis=1)
    cov = np.cov(stack)
    mu_p, s_p, mu_m, c_mm = mean[0], np.sqrt(cov[0, 0]), mean[1:], cov[1:, 1:]
    if not s_p > 0:
        raise ValueError("the PAN is constant where both images are valid: no detail to inject")
    decimated = {}
    if plan.sigmas:
        total = {s: 0.0 for s in plan.sigmas}
        dec = {s: np.full(h * w, np.nan, np.float32) for s in plan.sigmas}
        for index, per_sigma in lows:
            for s, (sub, samples) in zip(plan.sigmas, per_sigma):
                total[s] += sub
                if index is None:
                    dec[s][:] = samples.ravel()
                else:
                    dec[s][index] = samples
        npix = plan.pan_shape[0] * plan.pan_shape[1]
        for s in plan.sigmas:  # outside the PAN: the low-pass's mean
            d = dec[s].reshape(h, w)
            decimated[s] = np.where(np.isfinite(d), d, np.float32(total[s] / npix))
    method, wts, offset, mu_i, s_i = plan.method, None, 0.0, np.nan, np.nan
    if method == "pca":
        vals, vecs = np.linalg.eigh(c_mm)
        wts = vecs[:, -1] * np.sign(vecs[:, -1].sum() or 1.0)
        gains, s_i = wts, float(np.sqrt(vals[-1]))
    elif method in _CS:
        if method == "gsa":
            design = np.concatenate([m[:, lo].T, np.ones((n, 1), np.float32)], axis=1).astype(np.float64)
            coef = np.linalg.lstsq(design, decimated[plan.sigmas[0]][lo].astype(np.float64), rcond=None)[0]
            wts, offset = coef[:-1], float(coef[-1])
        else:
            wts = _nnls_weights(c_mm, cov[0, 1:]) if plan.weights is None else plan.weights
        mu_i, s_i = float(wts @ mu_m + offset), float(np.sqrt(wts @ c_mm @ wts))
        if not s_i > 0:
            raise ValueError("the weighted MS intensity is constant: nothing to match the PAN to")
        gains = np.ones(bands) if method in ("brovey", "ihs") else (c_mm @ wts) / s_i**2  # gs, gsa
    else:
        gains = np.sqrt(np.diag(c_mm)) / s_p
    return Statistics(
        fill, m, ms_ok, mu_p, s_p, mu_m, np.sqrt(np.diag(c_mm)), wts, offset, np.asarray(gains), mu_i, s_i, decimated
    )


def fuse(plan: Plan, st: Statistics, block, window, tile):
    """The fused ``(bands, h, w)`` float32 pixels of the output ``tile`` ``(r0, c0, h, w)`` (PAN pixels,
    inside :attr:`Plan.window`) and where they are valid, from the PAN ``block`` over ``window`` (``tile``
    plus :attr:`Plan.halo`, clipped to the PAN)."""
    cols, rows = plan.positions(tile)
    p, pan_ok = _filled(plan, block, st.fill)
    pc = _inner(p, window, tile)
    m_up = _sample_near(st.m, cols, rows, plan.resampling)
    valid = _geometry.inside(cols, rows, plan.ms_shape[1:]) & _inner(pan_ok, window, tile)
    if not st.ms_ok.all():  # a PAN pixel is valid where the four nearest MS pixels are
        valid &= _sample_near(st.ms_ok.astype(np.float32)[None], cols, rows, "bilinear")[0] > 1 - 1e-6

    def matched(x, mu, s):  # the PAN (or its low-pass) with the mean and std of a target
        return ((x - st.mu_p) * np.float32(s / st.s_p) + np.float32(mu)).astype(np.float32)

    method, bands, gains = plan.method, plan.ms_shape[0], st.gains
    if method == "pca":
        v = st.weights
        inten = np.tensordot(v.astype(np.float32), m_up - st.mu_m[:, None, None].astype(np.float32), 1)
        fused = m_up + gains[:, None, None].astype(np.float32) * (matched(pc, 0.0, st.s_i) - inten)
    elif method in _CS:
        inten = np.tensordot(st.weights.astype(np.float32), m_up, 1) + np.float32(st.offset)
        p_i = matched(pc, st.mu_i, st.s_i)
        if method == "brovey":
            fused = m_up * _ratio_or_one(p_i, inten, 1e-3 * abs(st.mu_i))[None]
        elif method == "ihs":
            fused = m_up + (p_i - inten)[None]
        else:  # gs, gsa: g_k = cov(M_k, I) / var(I)
            fused = m_up + gains[:, None, None].astype(np.float32) * (p_i - inten)[None]
    else:
        fused = np.empty_like(m_up)
        if method in ("hpf", "sfim"):
            from scipy import ndimage  # 0.5 s to import: only when needed

            lows = [_inner(ndimage.uniform_filter(p, plan.box, mode="nearest"), window, tile)] * bands
        else:
            cache = {s: _sample_near(st.decimated[s][None], cols, rows, plan.resampling)[0] for s in plan.sigmas}
            lows = [cache[mtf_sigma(plan.ratio, g)] for g in plan.nyquist]
        for k in range(bands):
            if method in ("hpf", "mtf_glp"):
                fused[k] = m_up[k] + np.float32(gains[k]) * (pc - lows[k])
            else:
                num, den = matched(pc, st.mu_m[k], st.s_m[k]), matched(lows[k], st.mu_m[k], st.s_m[k])
                fused[k] = m_up[k] * _ratio_or_one(num, den, 1e-3 * abs(st.mu_m[k]))
    return fused, valid


def _sample(image, cols, rows, resampling):
    """``(B, h, w)`` ``image`` at the positions ``(cols, rows)`` (each ``(H, W)``) with photax's kernel: on a
    separable lattice (axis-aligned grids, the usual case) by :func:`photax.kernels.resample_grid`, which
    traces and compiles nothing, else by :func:`photax.resample`."""
    from ..kernels import resample_grid

    if np.abs(cols - cols[:1]).max() <= 1e-9 and np.abs(rows - rows[:, :1]).max() <= 1e-9:
        return resample_grid(image, cols[0], rows[:, 0], resampling)
    from ..resampling import (
        resample,  # JAX: imported only for grids that are not axis-aligned
    )

    return np.asarray(resample(image, cols, rows, resampling))


def _sample_near(image, cols, rows, resampling):
    """:func:`_sample` on the part of ``image`` the kernel reads at ``(cols, rows)``, the same values (the
    positions shifted by whole pixels, which is exact in float64): a block of the PAN grid samples its own
    neighbourhood of the MS, not a copy of all of it.  A B-spline's prefilter spans the whole image."""
    from ..kernels import Resampling

    kernel = Resampling(resampling)
    ok = np.isfinite(cols) & np.isfinite(rows)
    if kernel.prefilter or not ok.any():
        return _sample(image, cols, rows, resampling)
    h, w = image.shape[-2:]
    m = kernel.taps + 1
    c0 = int(np.clip(np.floor(cols[ok].min()) - m, 0, w - 1))
    c1 = int(np.clip(np.ceil(cols[ok].max()) + m + 1, c0 + 1, w))
    r0 = int(np.clip(np.floor(rows[ok].min()) - m, 0, h - 1))
    r1 = int(np.clip(np.ceil(rows[ok].max()) + m + 1, r0 + 1, h))
    return _sample(image[..., r0:r1, c0:c1], cols - c0, rows - r0, resampling)


def _valid(a, nodata):
    ok = np.isfinite(a) if np.issubdtype(a.dtype, np.floating) else np.ones(a.shape, bool)
    if nodata is not None and not np.isnan(nodata):
        ok &= a != nodata
    return ok


def _to_dtype(fused, valid, dtype, nodata):
    """Float pixels to ``dtype``: integers rounded to nearest and clipped to the dtype's range."""
    clipped = 0
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        r = np.round(fused)
        clipped = int(np.count_nonzero(((r < info.min) | (r > info.max)) & valid[None]))
        out = np.clip(r, info.min, info.max).astype(dtype)
        fill = 0 if nodata is None else nodata
    else:
        out = fused.astype(dtype)
        fill = np.nan if nodata is None else nodata
    if valid.all():
        return out, nodata, clipped
    out[:, ~valid] = fill
    return out, fill, clipped
