"""Resampling against independent references on the same coordinates.

Pixel convention everywhere: integer = pixel centre, column right, row down.
OpenCV's ``remap`` and scipy/scikit-image's ``map_coordinates`` use the same
convention, so their coordinates are passed unchanged; GDAL works with pixel
corners, which the translation test converts explicitly.
"""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import rasterio  # noqa: F401  (GDAL, for the Keys cubic and Lanczos references)
from rasterio.transform import Affine
from rasterio.warp import Resampling, reproject
from scipy import ndimage
from skimage.transform import warp

import photax
from photax.resampling import resample

RNG = np.random.default_rng(20240607)
IMG = RNG.random((37, 53))  # odd sizes catch row/column mix-ups


def _interior(n, h, w, margin, rng=RNG):
    """``n`` random (cols, rows) at least ``margin`` px inside the centres."""
    return rng.uniform(margin, w - 1 - margin, n), rng.uniform(margin, h - 1 - margin, n)


def _on_opencv_grid(v):
    """OpenCV's remap quantises positions to 1/32 px (INTER_BITS = 5) for the
    linear and cubic kernels; positions already on that grid are exact."""
    return np.round(v * 32) / 32


@pytest.mark.parametrize(
    "method, flag, a",
    [
        ("nearest", cv2.INTER_NEAREST, -0.5),
        ("bilinear", cv2.INTER_LINEAR, -0.5),
        # OpenCV's INTER_CUBIC is cubic convolution with a = -0.75, not Keys' -0.5.
        ("cubic", cv2.INTER_CUBIC, -0.75),
        # INTER_LANCZOS4: sinc(t) sinc(t/4) on 8 x 8 taps, normalised (imgwarp.cpp).
        ("lanczos4", cv2.INTER_LANCZOS4, -0.5),
    ],
)
def test_matches_opencv_remap(method, flag, a):
    """Same positions, same kernel, float32 image: equal to float32 round-off.

    Positions are on OpenCV's 1/32-px grid (see ``_on_opencv_grid``); for
    nearest they are random (OpenCV rounds half to even, photax
    ``floor(x + 0.5)``: a tie has probability zero).  Interior positions and
    a grid covering the borders (both replicate the edge pixels), the latter
    large enough to go through the multi-threaded path.
    """
    img = IMG.astype(np.float32)
    h, w = img.shape
    cols, rows = _interior(500, h, w, 2)
    gc, gr = np.meshgrid(np.linspace(-0.5, w - 0.5, 150), np.linspace(-0.5, h - 0.5, 130))
    for c, r in [(cols[None, :], rows[None, :]), (gc, gr)]:
        if method != "nearest":
            c, r = _on_opencv_grid(c), _on_opencv_grid(r)
        ours = np.asarray(resample(img, c, r, method, a=a))
        ref = cv2.remap(img, c.astype(np.float32), r.astype(np.float32), flag, borderMode=cv2.BORDER_REPLICATE)
        np.testing.assert_allclose(ours, ref, rtol=0, atol=2e-6)


@pytest.mark.parametrize("method, order", [("nearest", 0), ("bilinear", 1)])
def test_matches_skimage_warp(method, order):
    """scikit-image ``warp`` with a coordinate map (scipy ``map_coordinates``
    underneath; ``(row, col)`` order), ``mode="edge"`` = replicate."""
    h, w = IMG.shape
    cols, rows = _interior(400, h, w, 1)
    ref = warp(IMG, np.stack([rows, cols])[:, None, :], order=order, mode="edge", preserve_range=True)[0]
    np.testing.assert_allclose(np.asarray(resample(IMG, cols, rows, method)), ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("method, resampling", [("cubic", Resampling.cubic), ("lanczos", Resampling.lanczos)])
def test_matches_gdal_keys_cubic_and_lanczos(method, resampling):
    """GDAL's warper: cubic is Keys' a = -0.5, lanczos is Lanczos-3 with
    weights normalised to sum one (as ours).

    A pure sub-pixel translation: output pixel corner ``(c, r)`` is input
    raster point ``(c + dx, r + dy)``, so the output pixel *centre* is the
    input pixel-centre position ``(c + dx, r + dy)`` in photax's convention.
    Compared away from the borders (GDAL treats them differently).
    """
    h, w = IMG.shape
    dx, dy = 0.3, -0.45
    out = np.full_like(IMG, np.nan)
    origin = (500000.0, 4000000.0)  # UTM 33N, 1 m pixels, north up
    reproject(
        IMG,
        out,
        src_transform=Affine(1, 0, origin[0], 0, -1, origin[1]),
        src_crs="EPSG:32633",
        dst_transform=Affine(1, 0, origin[0] + dx, 0, -1, origin[1] - dy),
        dst_crs="EPSG:32633",
        resampling=resampling,
        dst_nodata=np.nan,
    )
    c, r = np.meshgrid(np.arange(w) + dx, np.arange(h) + dy)
    ours = np.asarray(resample(IMG, c, r, method))
    m = 4
    np.testing.assert_allclose(ours[m:-m, m:-m], out[m:-m, m:-m], rtol=0, atol=1e-8)


@pytest.mark.parametrize("a", [-0.5, -1.0])
def test_cubic_closed_form(a):
    """The 4 x 4 sum of DESIGN.md written out directly (distances to the 16
    neighbours, the piecewise kernel), for Keys' and the course text's a."""

    def kernel(t):
        t = np.abs(t)
        return np.where(
            t <= 1,
            (a + 2) * t**3 - (a + 3) * t**2 + 1,
            np.where(t <= 2, a * t**3 - 5 * a * t**2 + 8 * a * t - 4 * a, 0.0),
        )

    h, w = IMG.shape
    cols, rows = _interior(300, h, w, 1)
    ref = np.zeros_like(cols)
    for dr in range(-1, 3):
        for dc in range(-1, 3):
            nc, nr = np.floor(cols) + dc, np.floor(rows) + dr
            ref += IMG[nr.astype(int), nc.astype(int)] * kernel(cols - nc) * kernel(rows - nr)
    np.testing.assert_allclose(np.asarray(resample(IMG, cols, rows, "cubic", a=a)), ref, rtol=0, atol=1e-12)


def test_bspline_matches_scipy_everywhere():
    """Prefiltered cubic B-spline = ``map_coordinates(order=3, mode="nearest")``
    (scipy pads 12 replicated pixels and prefilters with a mirror boundary,
    as photax does), interior and borders; float64 image, float64 sums."""
    h, w = IMG.shape
    cols, rows = _interior(300, h, w, 0)
    gc, gr = np.meshgrid(np.linspace(-0.5, w - 0.5, 90), np.linspace(-0.5, h - 0.5, 70))
    for c, r in [(cols, rows), (gc, gr)]:
        ref = ndimage.map_coordinates(IMG, [r, c], order=3, mode="nearest")
        np.testing.assert_allclose(np.asarray(resample(IMG, c, r, "bspline")), ref, rtol=0, atol=1e-12)


def test_bspline_interpolates_at_pixel_centres():
    r, c = np.mgrid[0:37, 0:53].astype(float)
    np.testing.assert_allclose(np.asarray(resample(IMG, c, r, "bspline")), IMG, rtol=0, atol=1e-12)


def _poly_image(f, h=40, w=48):
    r, c = np.mgrid[0:h, 0:w].astype(float)
    return f(c, r)


@pytest.mark.parametrize(
    "method, kw, f, margin",
    [
        # bilinear: linear functions and the bilinear term x*y, exactly.
        ("bilinear", {}, lambda x, y: 3 + 0.7 * x - 1.3 * y + 0.05 * x * y, 0),
        # Keys' cubic (a = -0.5) reproduces quadratics (Keys 1981).
        ("cubic", {"a": -0.5}, lambda x, y: 2 + 0.3 * x - 0.2 * y + 0.02 * x * x - 0.03 * x * y + 0.01 * y * y, 1),
        # Lanczos with normalised weights reproduces constants.
        ("lanczos", {}, lambda x, y: 7.25 + 0 * x, 0),
    ],
)
def test_kernels_reproduce_their_polynomials(method, kw, f, margin):
    img = _poly_image(f)
    h, w = img.shape
    cols, rows = _interior(500, h, w, margin)
    np.testing.assert_allclose(np.asarray(resample(img, cols, rows, method, **kw)), f(cols, rows), rtol=0, atol=1e-10)


def test_bspline_reproduces_cubics_in_the_interior():
    """Away from the edges (the replicated border reaches ~z^d, z = 0.27)."""
    f = lambda x, y: 1 + 0.1 * x - 0.2 * y + 0.01 * x * y + 1e-3 * x**3 - 2e-3 * y**3 + 1e-3 * x * x * y  # noqa: E731
    img = _poly_image(f, 64, 64)
    cols, rows = _interior(500, 64, 64, 20)
    np.testing.assert_allclose(np.asarray(resample(img, cols, rows, "bspline")), f(cols, rows), rtol=0, atol=1e-6)


def test_course_cubic_does_not_reproduce_quadratics():
    """a = -1 is only first-order: a quadratic surface is visibly missed
    (this is why Keys' a = -0.5 is the default)."""
    f = lambda x, y: 0.05 * x * x + 0.04 * y * y  # noqa: E731
    img = _poly_image(f)
    cols, rows = _interior(500, *img.shape, 1)
    err = np.abs(np.asarray(resample(img, cols, rows, "cubic", a=-1.0)) - f(cols, rows)).max()
    assert err > 5e-3


@pytest.mark.parametrize("method", ["nearest", "bilinear", "cubic", "lanczos", "bspline"])
def test_multiband_equals_per_band(method):
    bands = np.stack([IMG, 2 * IMG[::-1], IMG**2])[:, None]  # (3, 1, H, W): any leading axes
    cols, rows = _interior(60, *IMG.shape, 0)
    cols, rows = cols.reshape(6, 10), rows.reshape(6, 10)
    out = np.asarray(resample(bands, cols, rows, method))
    assert out.shape == (3, 1, 6, 10)
    for b in range(3):
        np.testing.assert_allclose(out[b, 0], np.asarray(resample(bands[b, 0], cols, rows, method)), rtol=0, atol=1e-12)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int16])
def test_integer_images_are_rounded_and_clipped(dtype):
    """A sharp step makes the cubic kernel over- and undershoot; the integer
    result is the float result rounded and clipped to the dtype range."""
    info = np.iinfo(dtype)
    img = np.full((20, 30), info.min, dtype=dtype)
    img[:, 15:] = info.max
    img[5, 5] = (int(info.min) + int(info.max)) // 2
    cols, rows = _interior(400, 20, 30, 0)
    ours = np.asarray(resample(img, cols, rows, "cubic", a=-1.0))
    assert ours.dtype == dtype
    ref = np.clip(
        np.round(np.asarray(resample(img.astype(np.float64), cols, rows, "cubic", a=-1.0))), info.min, info.max
    )
    # float32 sums vs float64: a .5 tie may round either way
    assert np.abs(ours.astype(np.float64) - ref).max() <= 1
    assert (ours == info.max).any() and (ours == info.min).any()  # clipping happened


def test_uint8_bilinear_matches_opencv():
    """uint8 in, uint8 out, against OpenCV's fixed-point bilinear (1/32 px
    positions, 15-bit weights): equal within one grey level."""
    img = (RNG.random((50, 60)) * 255).astype(np.uint8)
    c, r = (_on_opencv_grid(v) for v in _interior(2000, 50, 60, 1))
    ref = cv2.remap(img, c.astype(np.float32)[None], r.astype(np.float32)[None], cv2.INTER_LINEAR)[0]
    ours = np.asarray(resample(img, c, r, "bilinear"))
    assert ours.dtype == np.uint8
    assert np.abs(ours.astype(int) - ref.astype(int)).max() <= 1


@pytest.mark.parametrize("method", ["nearest", "bilinear", "cubic", "lanczos", "bspline"])
def test_footprint_and_nodata(method):
    """Valid = inside ``[-0.5, W-0.5] x [-0.5, H-0.5]``; outside (and NaN
    positions) -> nodata: NaN for floats, 0 for integers, or as given."""
    h, w = IMG.shape
    cols = np.array([-0.5, w - 0.5, 3.0, -0.5001, w - 0.4999, 3.0, np.nan, 3.0])
    rows = np.array([-0.5, h - 0.5, -0.5, 2.0, 2.0, h - 0.4999, 2.0, np.nan])
    out = np.asarray(resample(IMG, cols, rows, method))
    assert np.isfinite(out[:3]).all() and np.isnan(out[3:]).all()
    out = np.asarray(resample(IMG, cols, rows, method, nodata=-9999.0))
    np.testing.assert_array_equal(out[3:], -9999.0)
    img8 = (IMG * 200 + 20).astype(np.uint8)
    out8 = np.asarray(resample(img8, cols, rows, method))
    assert (out8[:3] > 0).all() and (out8[3:] == 0).all()
    np.testing.assert_array_equal(np.asarray(resample(img8, cols, rows, method, nodata=255))[3:], 255)


@pytest.mark.parametrize("method", ["nearest", "bilinear"])
def test_edge_replicates_border_pixels(method):
    """On the footprint edge, beyond the outermost centres, nearest and
    bilinear return the edge pixels' values (neighbours clamped)."""
    h, w = IMG.shape
    rows = np.arange(h, dtype=float)
    np.testing.assert_allclose(np.asarray(resample(IMG, np.full(h, -0.5), rows, method)), IMG[:, 0], atol=1e-12)
    np.testing.assert_allclose(np.asarray(resample(IMG, np.full(h, w - 0.5), rows, method)), IMG[:, -1], atol=1e-12)


def test_works_under_jit_and_large_outputs_match_small():
    """Traced inputs take the single-thread path; concrete large inputs the
    multi-threaded one: same numbers, to the rounding of two different
    compiled programs (XLA may contract a multiply-add into an FMA in one and
    not the other: a few ulps of the image's values, 6.7e-16 measured with
    XLA:CPU's classic emitters, which the test session uses)."""
    h, w = IMG.shape
    gc, gr = np.meshgrid(np.linspace(-1, w, 160), np.linspace(-1, h, 120))
    direct = np.asarray(resample(IMG, gc, gr, "cubic"))
    jitted = np.asarray(jax.jit(lambda im, c, r: resample(im, c, r, "cubic"))(jnp.asarray(IMG), gc, gr))
    np.testing.assert_allclose(direct, jitted, rtol=0, atol=8 * np.finfo(float).eps * np.abs(IMG).max())


def test_function_and_module_have_different_names():
    """``photax.resample`` is the function, ``photax.resampling`` its module:
    importing the module does not replace the function on the package."""
    import importlib
    import types

    module = importlib.import_module("photax.resampling")
    assert isinstance(module, types.ModuleType) and photax.resampling is module
    assert photax.resample is resample is module.resample and callable(photax.resample)


@pytest.mark.parametrize("kernel", list(photax.Resampling))
def test_registry_taps_and_margin_match_the_kernel(kernel):
    """The registry's facts against what the kernel does: sampling a unit
    impulse at a fractional position, the pixels with nonzero weight span
    ``taps`` per axis (B-spline: ``taps`` coefficients, but the prefilter is
    recursive, so every pixel near enough weighs in: the margin must reach
    where the weights fall below 1e-7); ``margin`` covers the taps read plus
    one."""
    n = 16
    impulse = np.zeros((n, n))
    impulse[8, 8] = 1.0
    # The value at (8.3, 8.3) as a function of the image is linear: its
    # derivative w.r.t. the image gives the weight of every input pixel
    # (forward mode: reverse mode meets the NaN padding of the positions).
    grad = np.asarray(
        jax.jacfwd(lambda im: resample(im, jnp.array([8.3]), jnp.array([8.3]), kernel.value)[0])(jnp.asarray(impulse))
    )
    rows, cols = np.nonzero(np.abs(grad) > 1e-12)
    if kernel.prefilter:
        assert len(rows) > kernel.taps**2
        far = np.nonzero(np.abs(grad) > 1e-7)[1]
        assert kernel.margin >= max(8 - far.min(), far.max() - 8) + 1
    else:
        assert cols.max() - cols.min() + 1 == kernel.taps and rows.max() - rows.min() + 1 == kernel.taps
        first = 0 if kernel == "nearest" else kernel.taps // 2 - 1  # the module's tap convention
        assert kernel.margin >= max(first, kernel.taps - 1 - first) + 1
    assert photax.Resampling.check(kernel.value) is kernel and kernel == kernel.value


def test_cli_choices_are_the_registry():
    from photax.cli import build_parser

    parser = build_parser()
    for command in ("rectify", "ortho"):
        sub = parser._subparsers._group_actions[0].choices[command]
        action = next(a for a in sub._actions if a.dest == "resampling")
        assert tuple(action.choices) == tuple(k.value for k in photax.Resampling)


def test_bad_arguments():
    with pytest.raises(ValueError, match="resampling must be one of"):
        resample(IMG, [1.0], [1.0], "bicubic")
    with pytest.raises(ValueError, match=r"\(\.\.\., H, W\)"):
        resample(np.ones(5), [1.0], [1.0])
    with pytest.raises(ValueError, match="nodata"):
        resample(IMG.astype(np.uint8), [1.0], [1.0], nodata=np.nan)
    with pytest.raises(ValueError):
        resample(IMG, np.ones(3), np.ones(4))


def test_bspline_prefilter_numpy_equals_traced():
    """Concrete images are prefiltered by scipy's spline_filter1d, traced ones
    by the lax.scan recursion: the same filter, to float64 round-off."""
    h, w = IMG.shape
    gc, gr = np.meshgrid(np.linspace(-0.5, w - 0.5, 40), np.linspace(-0.5, h - 0.5, 30))
    direct = np.asarray(resample(IMG, gc, gr, "bspline"))
    jitted = np.asarray(jax.jit(lambda im: resample(im, gc, gr, "bspline"))(jnp.asarray(IMG)))
    np.testing.assert_allclose(direct, jitted, rtol=0, atol=1e-12)


def test_method_is_the_deprecated_name_of_resampling():
    """``resampling=`` as in rectify and the CLI; the old ``method=`` gives the same samples with a
    DeprecationWarning, and both at once is refused."""
    c, r = np.array([3.3, 7.8]), np.array([5.1, 2.6])
    new = np.asarray(resample(IMG, c, r, resampling="cubic"))
    np.testing.assert_allclose(new, np.asarray(resample(IMG, c, r, "cubic")), rtol=0, atol=0)
    assert not np.allclose(new, np.asarray(resample(IMG, c, r, "bilinear")))  # the kernel is honoured
    warning = r"resample\(method=\) is deprecated: use resample\(resampling=\)"
    with pytest.warns(DeprecationWarning, match=warning):
        old = np.asarray(resample(IMG, c, r, method="cubic"))
    np.testing.assert_array_equal(old, new)
    with pytest.raises(ValueError, match="give resampling= only"):
        resample(IMG, c, r, "nearest", method="cubic")


@pytest.mark.parametrize("method", photax.resampling.RESAMPLING)
@pytest.mark.parametrize("dtype", [np.float32, np.uint8])
def test_resample_grid_is_resample_on_a_lattice(method, dtype):
    """The separable numpy path (pan-sharpening's MS onto the PAN grid) against the JAX kernels on the
    same positions, footprint edges and outside included: equal to float32 rounding (integers exactly,
    but for a tie at .5 rounding either way)."""
    from photax.resampling import resample_grid

    rng = np.random.default_rng(3)
    img = (rng.random((2, 30, 40)) * 250).astype(dtype)
    cols, rows = np.linspace(-0.7, 39.8, 57), np.linspace(-0.5, 29.6, 23)
    ours = resample_grid(img, cols, rows, method)
    ref = np.asarray(resample(img, *np.meshgrid(cols, rows), method))
    assert ours.dtype == ref.dtype and ours.shape == ref.shape
    np.testing.assert_array_equal(np.isnan(ours.astype(float)), np.isnan(ref.astype(float)))
    np.testing.assert_allclose(
        ours.astype(float), ref.astype(float), atol=1 if dtype == np.uint8 else 5e-4
    )  # 2e-6 of the range
