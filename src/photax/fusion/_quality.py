"""Quality of a pan-sharpened image: with a reference (Wald's protocol) and without (QNR).

Images are ``(bands, rows, cols)``; ``fused`` is compared with ``reference`` of the same shape.

* ERGAS (Wald 2002): ``100 / ratio * sqrt(mean_k (RMSE_k / mu_k)^2)``, ``mu_k`` the reference band's
  mean, ``ratio`` the PAN/MS pixel-size ratio (> 1); 0 is perfect.
* SAM: the mean over pixels of the angle between the spectral vectors, degrees; 0 is perfect (pixels
  where either vector is zero are left out).
* UIQI (Wang & Bovik 2002): ``Q = 4 s_xy mu_x mu_y / ((s_x^2 + s_y^2)(mu_x^2 + mu_y^2))`` on each
  ``block x block`` tile (non-overlapping; the whole image when smaller), averaged over the tiles and the
  bands; 1 is perfect.
* Q2n (Garzelli & Nencini 2009; Q4 for four bands): the bands of a pixel as one hypercomplex number of
  ``2^n`` components (Cayley-Dickson algebra; the bands padded with zero bands to ``2^n``),
  ``Q2n = |s_zz'| / (s_z s_z') * 2 s_z s_z' / (s_z^2 + s_z'^2) * 2 |mu_z| |mu_z'| / (|mu_z|^2 + |mu_z'|^2)``
  per tile, ``s_zz' = E[(z - mu_z) conj(z' - mu_z')]``, averaged over the tiles; 1 is perfect.
* SCC (Zhou et al. 1998): the correlation coefficient of the Laplacian-filtered fused and reference
  bands (``[[-1,-1,-1],[-1,8,-1],[-1,-1,-1]]``, interior pixels), averaged over the bands; 1 is perfect.
* QNR (Alparone et al. 2008): ``(1 - D_lambda) (1 - D_s)``, ``D_lambda = mean_{k != l} |Q(F_k, F_l) -
  Q(M_k, M_l)|``, ``D_s = mean_k |Q(F_k, P) - Q(M_k, P_L)|``, ``P_L`` the PAN degraded to the MS
  resolution, Q the UIQI on tiles of ``block`` pixels at the PAN resolution and ``block / ratio`` at the
  MS's; 1 is perfect.

Wald's protocol (Wald et al. 1997): degrade PAN and MS by the resolution ratio (a Gaussian matched to the
sensor's MTF, then decimation), fuse the degraded pair, and compare the result with the original MS.
"""

from __future__ import annotations

import numpy as np

BLOCK = 32  # tile of Q and Q2n (the pansharpening toolbox's)


def _pair(fused, reference):
    f = np.asarray(fused, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    if f.ndim == 2:
        f, r = f[None], r[None] if r.ndim == 2 else r
    if f.shape != r.shape or f.ndim != 3:
        raise ValueError(
            f"fused and reference must both be (bands, rows, cols) of one shape, got "
            f"{np.shape(fused)} and {np.shape(reference)}"
        )
    return f, r


def ergas(fused, reference, ratio: float) -> float:
    """ERGAS of ``fused`` against ``reference`` (the module docstring); ``ratio`` > 1.

    Examples:
        ERGAS is 0 for a perfect fusion and grows with the relative error of each band:

        >>> import numpy as np
        >>> from photax.fusion import ergas
        >>> rng = np.random.default_rng(0)
        >>> ref = rng.uniform(100, 200, (3, 32, 32))
        >>> print(f"{ergas(ref, ref, 4):.6f}", ergas(ref + 5.0, ref, 4) > 0)
        0.000000 True
    """
    f, r = _pair(fused, reference)
    rmse = np.sqrt(np.mean((f - r) ** 2, axis=(1, 2)))
    mu = r.mean(axis=(1, 2))
    if np.any(mu == 0):
        raise ValueError("ERGAS needs reference bands with a non-zero mean")
    return float(100.0 / ratio * np.sqrt(np.mean((rmse / mu) ** 2)))


def sam(fused, reference) -> float:
    """Mean spectral angle (degrees) between ``fused`` and ``reference``.

    Examples:
        The spectral angle between fused and reference pixels: 0 for the same spectra, even when
        scaled (a brightness change is no spectral distortion):

        >>> import numpy as np
        >>> from photax.fusion import sam
        >>> rng = np.random.default_rng(0)
        >>> ref = rng.uniform(10, 200, (4, 16, 16))
        >>> print(f"{sam(1.5 * ref, ref):.6f}")
        0.000000
    """
    f, r = _pair(fused, reference)
    dot = np.sum(f * r, axis=0)
    norm = np.sqrt(np.sum(f * f, axis=0) * np.sum(r * r, axis=0))
    ok = norm > 0
    if not ok.any():
        raise ValueError("SAM needs pixels whose spectral vectors are not zero")
    return float(np.degrees(np.mean(np.arccos(np.clip(dot[ok] / norm[ok], -1.0, 1.0)))))


def _tiles(a, block):
    """``(..., rows, cols)`` -> ``(..., tiles, block * block)``; the whole image when it is smaller."""
    h, w = a.shape[-2:]
    bh, bw = min(block, h), min(block, w)
    nh, nw = h // bh, w // bw
    a = a[..., : nh * bh, : nw * bw].reshape(a.shape[:-2] + (nh, bh, nw, bw))
    a = np.moveaxis(a, -3, -2)
    return a.reshape(a.shape[:-4] + (nh * nw, bh * bw))


def _q(x, y):
    """UIQI per tile of ``(..., tiles, pixels)`` arrays (a tile where both are constant: 1 if equal)."""
    mx, my = x.mean(-1), y.mean(-1)
    dx, dy = x - mx[..., None], y - my[..., None]
    sxy, sxx, syy = (dx * dy).mean(-1), (dx * dx).mean(-1), (dy * dy).mean(-1)
    num = 4 * sxy * mx * my
    den = (sxx + syy) * (mx * mx + my * my)
    flat = (sxx + syy) == 0
    mean_term = np.where(
        mx * mx + my * my > 0, 2 * mx * my / np.where(mx * mx + my * my > 0, mx * mx + my * my, 1), 1.0
    )
    return np.where(flat, mean_term, num / np.where(den == 0, 1, den))


def uiqi(fused, reference, block: int = BLOCK) -> float:
    """Wang and Bovik's universal image quality index, mean over tiles and bands.

    Examples:
        Wang and Bovik's universal image quality index: 1 for identical images:

        >>> import numpy as np
        >>> from photax.fusion import uiqi
        >>> rng = np.random.default_rng(0)
        >>> ref = rng.uniform(0, 255, (2, 64, 64))
        >>> print(f"{uiqi(ref, ref):.6f}")
        1.000000
    """
    f, r = _pair(fused, reference)
    return float(np.mean(_q(_tiles(f, block), _tiles(r, block))))


def _cd_conj(a):
    out = -a
    out[..., 0] = a[..., 0]
    return out


def _cd_mult(a, b):
    """Cayley-Dickson product of hypercomplex numbers on the last axis (length a power of 2):
    ``(p, q)(r, s) = (p r - conj(s) q, s p + q conj(r))``."""
    n = a.shape[-1]
    if n == 1:
        return a * b
    h = n // 2
    p, q, r, s = a[..., :h], a[..., h:], b[..., :h], b[..., h:]
    first = _cd_mult(p, r) - _cd_mult(_cd_conj(s), q)
    return np.concatenate([first, _cd_mult(s, p) + _cd_mult(q, _cd_conj(r))], axis=-1)


def q2n(fused, reference, block: int = BLOCK) -> float:
    """Q2n (Q4 for four bands): the hypercomplex UIQI of all bands at once (the module docstring).

    Examples:
        Q4 of four bands: 1 for a perfect fusion:

        >>> import numpy as np
        >>> from photax.fusion import q2n
        >>> ref = np.random.default_rng(0).uniform(0, 255, (4, 64, 64))
        >>> print(f"{q2n(ref, ref):.6f}")
        1.000000
    """
    f, r = _pair(fused, reference)
    n = 1 << max(0, int(np.ceil(np.log2(f.shape[0]))))
    pad = ((0, n - f.shape[0]), (0, 0), (0, 0))
    z = np.moveaxis(_tiles(np.pad(f, pad), block), 0, -1)  # (tiles, pixels, 2^n)
    y = np.moveaxis(_tiles(np.pad(r, pad), block), 0, -1)
    mz, my = z.mean(1), y.mean(1)
    dz, dy = z - mz[:, None], y - my[:, None]
    cov = _cd_mult(dz, _cd_conj(dy)).mean(1)
    vz, vy = (dz * dz).sum(-1).mean(1), (dy * dy).sum(-1).mean(1)
    amz, amy = np.sqrt((mz * mz).sum(-1)), np.sqrt((my * my).sum(-1))
    msum = amz**2 + amy**2
    mean_term = np.where(msum > 0, 2 * amz * amy / np.where(msum > 0, msum, 1), 1.0)
    var = vz + vy
    q = np.where(var > 0, 2 * np.sqrt((cov * cov).sum(-1)) / np.where(var > 0, var, 1), 1.0) * mean_term
    return float(q.mean())


def scc(fused, reference) -> float:
    """Spatial correlation coefficient: correlation of the Laplacian-filtered bands, mean over bands.

    Examples:
        The spatial correlation coefficient is 1 for identical images and drops when detail is lost:

        >>> import numpy as np
        >>> from scipy import ndimage
        >>> from photax.fusion import scc
        >>> ref = np.random.default_rng(0).uniform(0, 255, (3, 48, 48))
        >>> blurred = np.stack([ndimage.gaussian_filter(b, 2.0) for b in ref])
        >>> print(f"{scc(ref, ref):.6f}", scc(blurred, ref) < 0.9)
        1.000000 True
    """
    from scipy import ndimage

    f, r = _pair(fused, reference)
    if min(f.shape[1:]) < 3:
        raise ValueError("SCC needs images of at least 3 x 3 pixels")
    kernel = -np.ones((3, 3))
    kernel[1, 1] = 8
    out = []
    for a, b in zip(f, r):
        la = ndimage.correlate(a, kernel)[1:-1, 1:-1].ravel()
        lb = ndimage.correlate(b, kernel)[1:-1, 1:-1].ravel()
        la, lb = la - la.mean(), lb - lb.mean()
        den = np.sqrt((la * la).sum() * (lb * lb).sum())
        out.append((la * lb).sum() / den if den > 0 else float(np.allclose(la, lb)))
    return float(np.mean(out))


def qnr(fused, ms, pan, ratio: int, *, block: int = BLOCK, pan_low=None) -> dict:
    """QNR, D_lambda and D_s of ``fused`` (``(bands, R, C)``, on the PAN grid) from the ``ms``
    (``(bands, R / ratio, C / ratio)``) and the ``pan`` (``(R, C)``) it was made from, without reference.

    ``pan_low``: the PAN at the MS resolution (default: :func:`degrade` of ``pan``, gain 0.3).
    Returns ``{"QNR", "D_lambda", "D_s"}``.

    Examples:
        Bands that are the PAN times a constant, from MS bands that are its reduced copy times the
        same constants, distort nothing (QNR 1); noise added to them does:

        >>> import numpy as np
        >>> from photax.fusion import degrade, qnr
        >>> rng = np.random.default_rng(0)
        >>> pan = rng.uniform(50, 150, (64, 64))
        >>> fused = np.stack([k * pan for k in (0.8, 1.0, 1.2)])
        >>> ms = np.stack([k * degrade(pan[None], 4)[0] for k in (0.8, 1.0, 1.2)])  # (3, 16, 16)
        >>> {k: round(v, 6) for k, v in qnr(fused, ms, pan, 4).items()}
        {'QNR': 1.0, 'D_lambda': 0.0, 'D_s': 0.0}
        >>> bool(qnr(fused + rng.normal(0, 20, fused.shape), ms, pan, 4)["QNR"] < 0.8)
        True
    """
    f = np.asarray(fused, dtype=np.float64)
    m = np.asarray(ms, dtype=np.float64)
    p = np.asarray(pan, dtype=np.float64).reshape(f.shape[1:])
    ratio = int(ratio)
    if m.shape[0] != f.shape[0] or m.shape[1] * ratio != f.shape[1] or m.shape[2] * ratio != f.shape[2]:
        raise ValueError(f"ms {m.shape} must be fused {f.shape} reduced by ratio {ratio}")
    pl = degrade(p[None], ratio)[0] if pan_low is None else np.asarray(pan_low, dtype=np.float64)
    lb = max(block // ratio, 1)
    ft, mt = _tiles(f, block), _tiles(m, lb)
    bands = f.shape[0]
    if bands > 1:
        d_l = np.mean(
            [
                abs(np.mean(_q(ft[k], ft[j])) - np.mean(_q(mt[k], mt[j])))
                for k in range(bands)
                for j in range(bands)
                if j != k
            ]
        )
    else:
        d_l = 0.0
    pt, plt = _tiles(p, block), _tiles(pl, lb)
    d_s = np.mean([abs(np.mean(_q(ft[k], pt)) - np.mean(_q(mt[k], plt))) for k in range(bands)])
    return {"QNR": float((1 - d_l) * (1 - d_s)), "D_lambda": float(d_l), "D_s": float(d_s)}


def degrade(image, ratio: int, nyquist_gain: float = 0.3):
    """``(bands, rows, cols)`` reduced by the integer ``ratio``: a Gaussian matched to an MTF of gain
    ``nyquist_gain`` at the reduced grid's Nyquist frequency, then sampled (bilinear) at the centres of the
    ``ratio x ratio`` blocks: ``(bands, rows // ratio, cols // ratio)`` float32.

    Examples:
        Wald's protocol's reduction: the image at ``1 / ratio`` of its resolution (float32); a
        constant image stays constant:

        >>> import numpy as np
        >>> from photax.fusion import degrade
        >>> small = degrade(np.full((2, 40, 40), 7.0), 4)
        >>> small.shape, small.dtype.name, bool(np.allclose(small, 7.0))
        ((2, 10, 10), 'float32', True)
    """
    from ..kernels import resample_grid
    from ._sharpen import _gaussian, mtf_sigma

    a = np.asarray(image, dtype=np.float32)
    ratio = int(ratio)
    if ratio < 2:
        raise ValueError(f"ratio must be an integer >= 2, got {ratio}")
    h, w = a.shape[-2] // ratio, a.shape[-1] // ratio
    if h < 1 or w < 1:
        raise ValueError(f"an image of {a.shape[-2:]} pixels cannot be reduced by {ratio}")
    s = mtf_sigma(ratio, nyquist_gain)
    low = np.stack([_gaussian(b, s) for b in a])
    centre = (ratio - 1) / 2
    return resample_grid(low, np.arange(w) * ratio + centre, np.arange(h) * ratio + centre, "bilinear")


def wald_protocol(pan, ms, method: str = "gs", *, nyquist_gain=0.3, block: int = BLOCK, **kwargs) -> dict:
    """Reference-based quality of ``method`` at reduced resolution (Wald's protocol).

    ``pan`` ``(R, C)`` and ``ms`` ``(bands, r, c)`` cover the same bounds with an integer size ratio:
    both are reduced by it (:func:`degrade`), the reduced pair is fused (:func:`photax.fusion.pansharpen`
    with ``kwargs``) and compared with ``ms``.  Returns ``{"ERGAS", "SAM", "Q2n", "UIQI", "SCC"}`` and
    ``"fused"`` (the reduced-scale fusion, float32), ``"reference"`` (the ``ms`` it is compared with),
    ``"pan_low"`` and ``"ms_low"`` (the reduced pair, to fuse by other means).

    Examples:
        A smooth scene whose MS bands are the PAN's block means times a constant: fused at a quarter
        of the resolution, Gram-Schmidt keeps the spectra (SAM 0) and beats plain interpolation
        of the reduced MS (a lower ERGAS):

        >>> import numpy as np
        >>> from scipy import ndimage
        >>> from photax.fusion import assess, wald_protocol
        >>> pan = ndimage.gaussian_filter(np.random.default_rng(0).uniform(0, 200, (128, 128)), 1.5)
        >>> ms = np.stack([k * pan.reshape(32, 4, 32, 4).mean(axis=(1, 3)) for k in (0.8, 1.0, 1.2)])
        >>> q = wald_protocol(pan, ms, "gs")
        >>> q["pan_low"].shape, q["ms_low"].shape, round(q["SAM"], 3)  # float32 rounding apart
        ((32, 32), (3, 8, 8), 0.0)
        >>> interpolated = np.stack([ndimage.zoom(band, 4, order=1) for band in q["ms_low"]])
        >>> bool(q["ERGAS"] < assess(interpolated, q["reference"], 4)["ERGAS"])
        True
    """

    from ._sharpen import pansharpen

    pan = np.asarray(pan)
    pan = pan[0] if pan.ndim == 3 else pan
    ms = np.asarray(ms)
    rh, rw = pan.shape[0] / ms.shape[1], pan.shape[1] / ms.shape[2]
    ratio = round(rh)
    if abs(rh - ratio) > 1e-9 or abs(rw - ratio) > 1e-9 or ratio < 2:
        raise ValueError(f"Wald's protocol needs an integer PAN/MS size ratio >= 2, got {rh:g} x {rw:g}")
    h, w = ms.shape[1] // ratio * ratio, ms.shape[2] // ratio * ratio
    ref = ms[:, :h, :w].astype(np.float32)
    pan_low = degrade(pan[: h * ratio, : w * ratio][None], ratio, nyquist_gain)[0]
    ms_low = degrade(ref, ratio, nyquist_gain)
    fused = pansharpen(pan_low, ms_low, method, nyquist_gain=nyquist_gain, **kwargs).image
    return assess(fused, ref, ratio, block=block) | {
        "fused": fused,
        "reference": ref,
        "pan_low": pan_low,
        "ms_low": ms_low,
    }


def assess(fused, reference, ratio: float, *, block: int = BLOCK) -> dict:
    """ERGAS, SAM, Q2n, UIQI and SCC of ``fused`` against ``reference``, as a dict.

    Examples:
        All of Wald's indices at once; a perfect fusion scores ERGAS 0, SAM 0 and 1 for the others:

        >>> import numpy as np
        >>> from photax.fusion import assess
        >>> ref = np.random.default_rng(0).uniform(10, 250, (4, 64, 64))
        >>> {k: round(float(v), 6) for k, v in sorted(assess(ref, ref, 4).items()) if np.ndim(v) == 0}
        {'ERGAS': 0.0, 'Q2n': 1.0, 'SAM': 0.0, 'SCC': 1.0, 'UIQI': 1.0}
    """
    out = {
        "ERGAS": ergas(fused, reference, ratio),
        "SAM": np.nan,
        "Q2n": q2n(fused, reference, block),
        "UIQI": uiqi(fused, reference, block),
        "SCC": scc(fused, reference),
    }
    if np.shape(reference)[0] > 1:
        out["SAM"] = sam(fused, reference)
    return out
