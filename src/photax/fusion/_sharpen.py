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
    ``exp(-2 pi^2 sigma^2 f^2)`` equals ``nyquist_gain`` at the MS Nyquist frequency ``f = 1 / (2 ratio)``."""
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
        :class:`Sharpened`.  The arithmetic is float32 pixels and float64 statistics.

    Raises:
        ValueError: the images do not overlap, the MS has one band with a component-substitution method
            (it would return the PAN rescaled), its pixels are not larger than the PAN's, too few pixels
            are valid in both to estimate the statistics, or a bad argument.
    """
    from ..kernels import Resampling

    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    resampling = Resampling.check(resampling).value
    pan = np.asarray(pan)
    if pan.ndim == 3 and pan.shape[0] == 1:
        pan = pan[0]
    ms = np.asarray(ms)
    if pan.ndim != 2:
        raise ValueError(f"pan must be (rows, cols) or (1, rows, cols), got shape {pan.shape}")
    if ms.ndim != 3:
        raise ValueError(f"ms must be (bands, rows, cols), got shape {ms.shape}")
    for name, a in (("pan", pan), ("ms", ms)):
        if not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)) or a.dtype == bool:
            raise ValueError(f"{name} must have an integer or float dtype, got {a.dtype}")
    bands = ms.shape[0]
    if bands == 1 and method in _CS:
        raise ValueError(
            f"the MS image has one band: {method!r} (component substitution) would return the "
            "PAN rescaled to it; use an MRA method (hpf, sfim, mtf_glp, mtf_glp_hpm)"
        )
    if weights is not None and method not in _WEIGHTED:
        raise ValueError(f"weights apply to {_WEIGHTED}, not {method!r}")
    gains_nyq = (
        np.broadcast_to(np.asarray(nyquist_gain, dtype=np.float64), (bands,)).copy()
        if np.ndim(nyquist_gain) == 0
        else np.asarray(nyquist_gain, dtype=np.float64)
    )
    if gains_nyq.shape != (bands,):
        raise ValueError(f"nyquist_gain must be one value or one per MS band ({bands})")

    # --- geometry: the MS position of every PAN pixel, the PAN position of every MS pixel
    cols, rows = _geometry.positions(pan.shape, pan_transform, pan_crs, ms.shape[1:], ms_transform, ms_crs)
    covered = _geometry.inside(cols, rows, ms.shape[1:])
    if not covered.any():
        raise ValueError("the PAN and MS images do not overlap")
    rr, cc = np.nonzero(covered.any(axis=1))[0], np.nonzero(covered.any(axis=0))[0]
    r0, r1, c0, c1 = rr[0], rr[-1] + 1, cc[0], cc[-1] + 1
    cols, rows, covered = cols[r0:r1, c0:c1], rows[r0:r1, c0:c1], covered[r0:r1, c0:c1]
    ratio = _geometry.pixel_ratio(cols, rows) if min(cols.shape) > 1 else np.nan
    if not ratio > 1.0 + 1e-9:
        raise ValueError(f"the MS pixels must be larger than the PAN's (size ratio {ratio:.3g})")

    # --- validity, and the invalid values filled so that they do not smear through the kernels
    pan_ok = _valid(pan, pan_nodata)
    ms_ok = np.all([_valid(b, ms_nodata) for b in ms], axis=0)
    if not ms_ok.any() or not pan_ok.any():
        raise ValueError(f"the {'MS' if not ms_ok.any() else 'PAN'} image has no valid pixel")
    p = pan.astype(np.float32)
    p[~pan_ok] = p[pan_ok].mean()
    m = ms.astype(np.float32)
    for b in m:
        b[~ms_ok] = b[ms_ok].mean()

    # --- the PAN averaged over each MS pixel (statistics at MS resolution)
    ci = np.floor(cols + 0.5).astype(np.int64)
    ri = np.floor(rows + 0.5).astype(np.int64)
    h, w = ms.shape[1:]
    flat = (np.clip(ri, 0, h - 1) * w + np.clip(ci, 0, w - 1))[covered]
    pan_c = pan_ok[r0:r1, c0:c1][covered]
    count = np.bincount(flat, minlength=h * w).reshape(h, w)
    good = np.bincount(flat, weights=pan_c, minlength=h * w).reshape(h, w)
    p_avg = np.bincount(flat, weights=p[r0:r1, c0:c1][covered], minlength=h * w).reshape(h, w)
    p_avg = p_avg / np.maximum(count, 1)
    lo = ms_ok & (count >= 0.5 * ratio**2) & (good == count)
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

    # --- the MS on the PAN grid with photax's kernel
    m_up = _sample(m, cols, rows, resampling)
    valid = covered & pan_ok[r0:r1, c0:c1]
    if not ms_ok.all():  # a PAN pixel is valid where the four nearest MS pixels are
        valid &= _sample(ms_ok.astype(np.float32)[None], cols, rows, "bilinear")[0] > 1 - 1e-6
    pc = p[r0:r1, c0:c1]

    def matched(x, mu, s):  # the PAN (or its low-pass) with the mean and std of a target
        return ((x - mu_p) * np.float32(s / s_p) + np.float32(mu)).astype(np.float32)

    w_out = None
    if method in _CS:
        if method == "pca":
            vals, vecs = np.linalg.eigh(c_mm)
            v = vecs[:, -1] * np.sign(vecs[:, -1].sum() or 1.0)
            inten = np.tensordot(v.astype(np.float32), m_up - mu_m[:, None, None].astype(np.float32), 1)
            gains, w_out = v, v
            p_pc = matched(pc, 0.0, np.sqrt(vals[-1]))  # the PAN matched to the first component
            fused = m_up + gains[:, None, None].astype(np.float32) * (p_pc - inten)
        else:
            if method == "gsa":
                sig = float(np.mean([mtf_sigma(ratio, g) for g in gains_nyq]))
                p_mtf = _at_ms(_gaussian(p, sig), pan_transform, pan_crs, ms_transform, ms_crs, pan.shape, ms.shape)
                design = np.concatenate([m[:, lo].T, np.ones((n, 1), np.float32)], axis=1).astype(np.float64)
                coef = np.linalg.lstsq(design, p_mtf[lo].astype(np.float64), rcond=None)[0]
                wts, offset = coef[:-1], coef[-1]
            else:
                if isinstance(weights, str):
                    if weights != "equal":
                        raise ValueError(f"weights must be values, 'equal' or None, got {weights!r}")
                    wts = np.full(bands, 1.0 / bands)
                elif weights is None:
                    wts = _nnls_weights(c_mm, cov[0, 1:])
                else:
                    wts = _check_weights(weights, bands)
                offset = 0.0
            w_out = wts
            mu_i, s_i = float(wts @ mu_m + offset), float(np.sqrt(wts @ c_mm @ wts))
            if not s_i > 0:
                raise ValueError("the weighted MS intensity is constant: nothing to match the PAN to")
            inten = np.tensordot(wts.astype(np.float32), m_up, 1) + np.float32(offset)
            p_i = matched(pc, mu_i, s_i)
            if method == "brovey":
                gains = np.ones(bands)
                fused = m_up * _ratio_or_one(p_i, inten, 1e-3 * abs(mu_i))[None]
            elif method == "ihs":
                gains = np.ones(bands)
                fused = m_up + (p_i - inten)[None]
            else:  # gs, gsa: g_k = cov(M_k, I) / var(I)
                gains = (c_mm @ wts) / s_i**2
                fused = m_up + gains[:, None, None].astype(np.float32) * (p_i - inten)[None]
    else:
        s_m = np.sqrt(np.diag(c_mm))
        gains = s_m / s_p
        fused = np.empty_like(m_up)
        if method in ("hpf", "sfim"):
            from scipy import ndimage

            size = 2 * int(np.floor(ratio / 2)) + 1
            lows = [ndimage.uniform_filter(p, size, mode="nearest")[r0:r1, c0:c1]] * bands
        else:
            sigmas = [mtf_sigma(ratio, g) for g in gains_nyq]
            cache = {}
            for s in sigmas:
                if s not in cache:
                    dec = _at_ms(_gaussian(p, s), pan_transform, pan_crs, ms_transform, ms_crs, pan.shape, ms.shape)
                    cache[s] = _sample(dec[None], cols, rows, resampling)[0]
            lows = [cache[s] for s in sigmas]
        for k in range(bands):
            if method in ("hpf", "mtf_glp"):
                fused[k] = m_up[k] + np.float32(gains[k]) * (pc - lows[k])
            else:
                num, den = matched(pc, mu_m[k], s_m[k]), matched(lows[k], mu_m[k], s_m[k])
                fused[k] = m_up[k] * _ratio_or_one(num, den, 1e-3 * abs(mu_m[k]))
    image, nodata, clipped = _to_dtype(fused, valid, ms.dtype, ms_nodata)
    transform = None
    if pan_transform is not None:
        transform = _geometry._affine(pan_transform) * _geometry._affine((1, 0, c0, 0, 1, r0))
    return Sharpened(
        image, valid, (int(r0), int(c0)), transform, nodata, method, w_out, np.asarray(gains), float(ratio), clipped
    )


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


def _valid(a, nodata):
    ok = np.isfinite(a) if np.issubdtype(a.dtype, np.floating) else np.ones(a.shape, bool)
    if nodata is not None and not np.isnan(nodata):
        ok &= a != nodata
    return ok


def _at_ms(image, pan_transform, pan_crs, ms_transform, ms_crs, pan_shape, ms_shape):
    """A PAN-grid ``image`` sampled (bilinear) at the MS pixel centres; outside the PAN: its mean."""
    cols, rows = _geometry.positions(ms_shape[1:], ms_transform, ms_crs, pan_shape, pan_transform, pan_crs)
    out = _sample(image.astype(np.float32)[None], cols, rows, "bilinear")[0]
    return np.where(np.isfinite(out), out, np.float32(image.mean()))


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
