"""photax.fusion: pan-sharpening and its quality indices (issue 24, items 1-2).

References: the indices' closed forms on synthetic images (angles, biases, affine maps of a band), a scene
whose MS is the box average of a known high-resolution truth (the PAN a known mix of it), GDAL's warper
(rasterio.warp.reproject) for the MS mapped onto the PAN grid across CRSs, and orthority's Gram-Schmidt
(``oty sharpen``) on the real pan/MS pair.
"""

import numpy as np
import pytest
import rasterio
from conftest import SHARED_DATA
from rasterio import Affine
from scipy import ndimage

from photax.cli import main
from photax.fusion import (
    METHODS,
    assess,
    ergas,
    pansharpen,
    q2n,
    qnr,
    sam,
    scc,
    uiqi,
    wald_protocol,
)
from photax.io.raster import read_geotiff, write_geotiff

PAIR = SHARED_DATA / "orthority" / "pan_sharp"


def _texture(shape, seed, sigma=2.0):
    rng = np.random.default_rng(seed)
    return ndimage.gaussian_filter(rng.normal(size=shape), sigma, mode="wrap")


def _scene(r=4, size=64, bands=3, weights=(0.5, 0.3, 0.2)):
    """A high-resolution truth (bands, size, size), its PAN (a known mix) and its MS (box averages)."""
    truth = np.stack(
        [100 + 20 * _texture((size, size), k) + 10 * _texture((size, size), 10, 1.0) for k in range(bands)]
    )
    pan = np.tensordot(np.asarray(weights[:bands]), truth, 1)
    ms = truth.reshape(bands, size // r, r, size // r, r).mean(axis=(2, 4))
    return truth, pan, ms


# ---- the indices against their closed forms


def test_sam_of_known_angles_and_of_a_band_permutation():
    ref = np.zeros((3, 2, 4))
    fused = np.zeros((3, 2, 4))
    ref[0, 0], fused[1, 0] = 5.0, 2.0  # row 0: (1,0,0) vs (0,1,0): 90 degrees
    ref[0, 1], ref[1, 1] = 1.0, 1.0  # row 1: (1,1,0) vs (1,0,1): 60 degrees
    fused[0, 1], fused[2, 1] = 3.0, 3.0
    assert sam(fused, ref) == pytest.approx(75.0, abs=1e-9)
    a, b, c = 3.0, 5.0, 7.0
    v = np.broadcast_to(np.array([a, b, c])[:, None, None], (3, 4, 4))
    perm = v[[1, 2, 0]]
    expected = np.degrees(np.arccos((a * b + b * c + c * a) / (a * a + b * b + c * c)))
    assert sam(perm, v) == pytest.approx(expected, abs=1e-9)
    assert sam(2.5 * v, v) == pytest.approx(0.0, abs=1e-6)  # a scaled spectrum has no angle


def test_ergas_of_a_known_bias():
    ref = np.stack([50 + 10 * _texture((32, 32), k) for k in range(3)])
    ref -= ref.mean(axis=(1, 2), keepdims=True) - np.array([50.0, 80.0, 120.0])[:, None, None]  # means exact
    bias = np.array([2.0, -4.0, 6.0])
    expected = 100 / 4 * np.sqrt(np.mean((bias / np.array([50.0, 80.0, 120.0])) ** 2))
    assert ergas(ref + bias[:, None, None], ref, 4) == pytest.approx(expected, rel=1e-12)


def test_uiqi_and_q2n_of_affine_maps():
    x = 100 + 10 * _texture((1, 32, 32), 3)
    assert uiqi(x, x) == pytest.approx(1.0)
    a, b = 0.7, 12.0
    y = a * x + b
    mx = x.mean()
    expected = 2 * a / (1 + a * a) * 2 * mx * (a * mx + b) / (mx * mx + (a * mx + b) ** 2)
    assert uiqi(y, x, block=32) == pytest.approx(expected, rel=1e-10)
    assert q2n(y, x, block=32) == pytest.approx(expected, rel=1e-10)  # one band: Q2n is UIQI
    # Four bands scaled alike, z' = a z: |s_zz'| = a s_z^2, so Q4 = (2a / (1 + a^2))^2
    z = np.stack([100 + 10 * _texture((32, 32), k) for k in range(4)])
    assert q2n(z, z) == pytest.approx(1.0)
    assert q2n(a * z, z, block=32) == pytest.approx((2 * a / (1 + a * a)) ** 2, rel=1e-10)
    # three bands are padded to four with a zero band: the same closed form
    assert q2n(a * z[:3], z[:3], block=32) == pytest.approx((2 * a / (1 + a * a)) ** 2, rel=1e-10)


def test_scc_ignores_what_the_laplacian_cannot_see():
    x = 100 + 10 * _texture((2, 40, 40), 5, 1.0)
    rows, cols = np.mgrid[0:40, 0:40]
    assert scc(x, x) == pytest.approx(1.0)
    assert scc(x + 0.3 * rows + 0.2 * cols + 7, x) == pytest.approx(1.0)  # a plane added
    assert scc(-x, x) == pytest.approx(-1.0)


def test_qnr_of_a_fusion_that_adds_nothing_is_one():
    """Nearest-neighbour replication by the ratio: every tile's Q at the PAN scale is the Q of its
    tile at the MS scale, so D_lambda = D_s = 0 and QNR = 1."""
    ms = 100 + 10 * _texture((3, 16, 16), 7)
    pan_low = ms.mean(axis=0) + 5 * _texture((16, 16), 8)
    up = ms.repeat(4, 1).repeat(4, 2)
    pan = pan_low.repeat(4, 0).repeat(4, 1)
    out = qnr(up, ms, pan, 4, pan_low=pan_low)
    assert out["D_lambda"] == pytest.approx(0, abs=1e-12)
    assert out["D_s"] == pytest.approx(0, abs=1e-12)
    assert out["QNR"] == pytest.approx(1.0)
    # a fusion whose bands all carry the PAN's detail changes the bands' mutual Q: D_lambda > 0
    detail = 5 * _texture((64, 64), 9, 0.7)[None] * np.array([1, -1, 0.5])[:, None, None]
    assert qnr(up + detail, ms, pan, 4, pan_low=pan_low)["D_lambda"] > 0.01


# ---- pan-sharpening


def test_estimated_weights_are_the_true_mix():
    _, pan, ms = _scene()
    out = pansharpen(pan, ms, "gs")
    np.testing.assert_allclose(out.weights, [0.5, 0.3, 0.2], atol=1e-6)


def test_negative_weights_are_refitted_without_those_bands():
    """The PAN a mix with a negative weight: the weights are the non-negative least squares fit of the
    averaged PAN on the MS bands (scipy.optimize.nnls on the centred data), normalised."""
    from scipy.optimize import nnls

    truth, _, ms = _scene()
    pan = np.tensordot([0.7, 0.5, -0.2], truth, 1) + 3 * _texture((64, 64), 20, 0.7)
    out = pansharpen(pan, ms, "gs")
    pd = pan.reshape(16, 4, 16, 4).mean(axis=(1, 3)).ravel()
    design = ms.reshape(3, -1).T
    w = nnls(design - design.mean(0), pd - pd.mean())[0]
    assert w[2] == 0 and np.all(out.weights >= 0)
    np.testing.assert_allclose(out.weights, w / w.sum(), atol=1e-6)


@pytest.mark.parametrize("method", ["brovey", "ihs", "pca", "gs", "gsa"])
def test_a_spectrally_flat_scene_gives_back_the_pan(method):
    """Every MS band the PAN averaged over the MS pixel: component substitution returns the PAN."""
    _, pan, _ = _scene()
    flat = pan.reshape(16, 4, 16, 4).mean(axis=(1, 3))
    ms = np.stack([flat] * 3)
    out = pansharpen(pan, ms, method)
    assert out.image.dtype == np.float64
    np.testing.assert_allclose(out.image, np.broadcast_to(pan, out.image.shape), atol=2e-3)


@pytest.mark.parametrize("method", METHODS)
def test_every_method_recovers_detail_the_interpolation_lost(method):
    """Against the known truth: closer (ERGAS, SCC) than the MS interpolated alone."""
    truth, pan, ms = _scene()
    out = pansharpen(pan, ms, method).image
    from photax.fusion._geometry import positions
    from photax.resampling import resample

    cols, rows = positions(pan.shape, None, None, ms.shape[1:], None, None)
    exp = np.asarray(resample(ms.astype(np.float32), cols, rows, "cubic"))
    assert ergas(out, truth, 4) < 0.8 * ergas(exp, truth, 4)
    assert scc(out, truth) > scc(exp, truth) + 0.1


def test_integer_output_is_the_float_result_rounded_and_clipped():
    _, pan, ms = _scene()
    ms8 = np.round((ms - ms.min()) / np.ptp(ms) * 255).astype(np.uint8)  # the full range: it overshoots
    f = pansharpen(pan, ms8.astype(np.float32), "mtf_glp")
    i = pansharpen(pan, ms8, "mtf_glp")
    assert i.image.dtype == np.uint8
    expected = np.clip(np.round(f.image), 0, 255)
    assert np.abs(i.image - expected).max() <= 1  # float32 ties at .5 may round either way
    assert i.clipped == np.count_nonzero((np.round(f.image) < 0) | (np.round(f.image) > 255)) > 0


def test_ms_mapped_onto_the_pan_grid_across_crss_like_gdal():
    """The MS in UTM, the PAN in Web Mercator: the MS positions of the PAN pixels (through both
    transforms and PROJ) and photax's bilinear kernel give GDAL's warp of the MS onto the PAN grid."""
    from rasterio.warp import Resampling, reproject, transform_bounds

    from photax.fusion._geometry import positions
    from photax.resampling import resample

    ms = (100 + 30 * _texture((1, 60, 60), 11, 3.0)).astype(np.float32)
    ms_t = Affine(8.0, 0, 500000.0, 0, -8.0, 4000480.0)
    left, bottom, right, top = transform_bounds("EPSG:32633", "EPSG:3857", 500000, 4000000, 500480, 4000480)
    pan_t = Affine(2.0, 0, left + 40, 0, -2.0, top - 40)
    shape = (int((top - bottom - 80) / 2), int((right - left - 80) / 2))
    ours = np.asarray(
        resample(ms, *positions(shape, pan_t, "EPSG:3857", ms.shape[1:], ms_t, "EPSG:32633"), "bilinear")
    )[0]
    gdal = np.full(shape, np.nan, np.float32)
    reproject(
        ms,
        gdal,
        src_transform=ms_t,
        src_crs="EPSG:32633",
        dst_transform=pan_t,
        dst_crs="EPSG:3857",
        resampling=Resampling.bilinear,
        src_nodata=np.nan,
        dst_nodata=np.nan,
    )
    both = np.isfinite(ours) & np.isfinite(gdal)
    assert both.mean() > 0.9
    assert np.abs(ours - gdal)[both].max() < 0.05 * np.ptp(ms)
    assert np.abs(ours - gdal)[both].mean() < 0.002 * np.ptp(ms)


def test_the_output_is_the_pan_window_the_ms_covers():
    _, pan, ms = _scene()
    pan_t = Affine(1.0, 0, 1000.0, 0, -1.0, 2000.0)
    ms_t = Affine(4.0, 0, 1000.0 + 32, 0, -4.0, 2000.0)  # the MS starts 32 PAN columns in
    out = pansharpen(pan, ms, "gs", pan_transform=pan_t, ms_transform=ms_t, pan_crs="EPSG:32633", ms_crs="EPSG:32633")
    assert out.window == (0, 32)
    assert out.image.shape == (3, 64, 32)
    assert out.transform.almost_equals(Affine(1.0, 0, 1032.0, 0, -1.0, 2000.0))


# ---- bad input


def test_bad_input_is_refused_with_its_reason():
    _, pan, ms = _scene()
    t = Affine(1.0, 0, 0.0, 0, -1.0, 0.0)
    far = Affine(4.0, 0, 1e5, 0, -4.0, 0.0)
    with pytest.raises(ValueError, match="do not overlap"):
        pansharpen(pan, ms, pan_transform=t, ms_transform=far, pan_crs="EPSG:32633", ms_crs="EPSG:32633")
    with pytest.raises(ValueError, match="one band"):
        pansharpen(pan, ms[:1], "gs")
    assert pansharpen(pan, ms[:1], "mtf_glp").image.shape == (1, 64, 64)  # MRA sharpens one band
    with pytest.raises(ValueError, match="larger than the PAN"):
        pansharpen(ms[0], np.stack([pan] * 3), "gs")
    with pytest.raises(ValueError, match="method must be one of"):
        pansharpen(pan, ms, "wavelet")
    with pytest.raises(ValueError, match="one value per MS band"):
        pansharpen(pan, ms, "gs", weights=[1, 2])


def test_nodata_pixels_stay_nodata_and_a_nodata_heavy_pair_is_refused():
    _, pan, ms = _scene()
    ms8 = np.clip(ms, 1, 255).astype(np.uint8)
    holed = ms8.copy()
    holed[:, :4, :] = 0  # the top quarter of the MS is nodata
    out = pansharpen(pan, holed, "gs", ms_nodata=0)
    assert out.nodata == 0
    assert not out.valid[:16].any() and out.valid[18:].all()
    assert (out.image[:, ~out.valid] == 0).all()
    full = pansharpen(pan, ms8, "gs")
    # the same away from the hole, but for statistics taken from 3/4 of the pixels
    assert np.corrcoef(full.image[:, 20:].ravel(), out.image[:, 20:].ravel())[0, 1] > 0.99
    mostly = ms8.copy()
    mostly[:, 2:, :] = 0  # 2 of 16 MS rows left
    mostly[:, :, 3:] = 0
    with pytest.raises(ValueError, match="too few MS pixels"):
        pansharpen(pan, mostly, "gs", ms_nodata=0)


# ---- the real pair and orthority


def _pair():
    if not PAIR.is_dir():
        pytest.skip(f"{PAIR} not present")
    pan, _ = read_geotiff(PAIR / "pan.tif")
    ms, _ = read_geotiff(PAIR / "ms.tif")
    return pan, ms


def _orthority(pan_path, ms_path, out, **kw):
    import warnings

    from orthority.pan_sharp import PanSharpen

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "not georeferenced: assuming matching bounds"
        PanSharpen(str(pan_path), str(ms_path)).process(str(out), compress="deflate", build_ovw=False, **kw)
    with rasterio.open(out) as f:
        return f.read()


def test_gram_schmidt_equals_orthority_on_the_real_pair(tmp_path):
    pytest.importorskip("orthority")
    pan, ms = _pair()
    theirs = _orthority(PAIR / "pan.tif", PAIR / "ms.tif", tmp_path / "oty.tif")
    ours = pansharpen(pan, ms, "gs").image
    assert ours.shape == theirs.shape and ours.dtype == theirs.dtype
    for a, b in zip(ours.astype(float), theirs.astype(float)):
        assert np.corrcoef(a.ravel(), b.ravel())[0, 1] >= 0.995
        assert np.abs(a - b).mean() <= 0.01 * np.ptp(b)


def test_wald_protocol_on_the_real_pair_beats_orthority(tmp_path):
    """GSA (lanczos) against orthority's Gram-Schmidt on the same reduced pair: lower ERGAS and SAM;
    every index better than the reduced MS interpolated alone."""
    pytest.importorskip("orthority")
    pan, ms = _pair()
    ours = wald_protocol(pan, ms, "gsa", resampling="lanczos")
    write_geotiff(tmp_path / "p.tif", ours["pan_low"], None)
    write_geotiff(tmp_path / "m.tif", ours["ms_low"], None)
    theirs = assess(
        _orthority(tmp_path / "p.tif", tmp_path / "m.tif", tmp_path / "o.tif", dtype="float32"), ours["reference"], 4
    )
    assert ours["ERGAS"] < theirs["ERGAS"] and ours["SAM"] < theirs["SAM"]
    exp = wald_protocol(pan, ms, "gs", weights=[1, 1, 1])  # only its reduced pair
    plain = assess(exp["ms_low"].repeat(4, 1).repeat(4, 2), ours["reference"], 4)
    assert ours["ERGAS"] < plain["ERGAS"] and ours["Q2n"] > plain["Q2n"] and ours["SCC"] > plain["SCC"]


# ---- the command


def test_photax_sharpen_writes_the_pan_grid_and_prints_the_table(tmp_path, capsys):
    _, pan, ms = _scene()
    t = Affine(1.0, 0, 500000.0, 0, -1.0, 4000000.0)
    write_geotiff(tmp_path / "pan.tif", pan.astype(np.float32), t, crs="EPSG:32633")
    write_geotiff(tmp_path / "ms.tif", ms.astype(np.float32), t * Affine.scale(4), crs="EPSG:32633")
    out = tmp_path / "sharp.tif"
    assert (
        main(
            [
                "sharpen",
                str(tmp_path / "pan.tif"),
                str(tmp_path / "ms.tif"),
                "-o",
                str(out),
                "--method",
                "mtf_glp",
                "--assess",
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "ERGAS" in text and "QNR" in text
    data, profile = read_geotiff(out)
    assert data.shape == (3, 64, 64) and profile["transform"].almost_equals(t)
    far = tmp_path / "far.tif"
    write_geotiff(far, ms.astype(np.float32), Affine(4.0, 0, 0.0, 0, -4.0, 0.0), crs="EPSG:32633")
    assert main(["sharpen", str(tmp_path / "pan.tif"), str(far), "-o", str(tmp_path / "x.tif")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "photax sharpen: error: the PAN and MS images do not overlap", err
    assert not (tmp_path / "x.tif").exists()


def test_the_command_lists_the_library_methods():
    from photax.cli import sharpen

    assert sharpen.METHODS == METHODS


def test_an_ms_in_another_crs_is_sharpened_on_the_pan_grid():
    """The truth on a Web Mercator PAN grid, the MS its average on a UTM grid of 4x larger pixels (GDAL):
    sharpened through both CRSs (the JAX resampler: the positions are not a separable lattice), the
    result is closer to the truth than the MS interpolated alone."""
    from rasterio.warp import Resampling, reproject, transform_bounds

    from photax.fusion._geometry import positions
    from photax.resampling import resample

    left, bottom, right, top = transform_bounds("EPSG:32633", "EPSG:3857", 500000, 4000000, 500512, 4000512)
    pan_t = Affine(2.0, 0, left, 0, -2.0, top)
    shape = (int((top - bottom) / 2), int((right - left) / 2))
    truth = np.stack([100 + 20 * _texture(shape, k) + 10 * _texture(shape, 10, 1.0) for k in range(3)])
    pan = np.tensordot([0.5, 0.3, 0.2], truth, 1)
    ms_t = Affine(8.0, 0, 500000.0, 0, -8.0, 4000512.0)
    ms = np.full((3, 64, 64), np.nan)
    reproject(
        truth,
        ms,
        src_transform=pan_t,
        src_crs="EPSG:3857",
        dst_transform=ms_t,
        dst_crs="EPSG:32633",
        resampling=Resampling.average,
        src_nodata=np.nan,
        dst_nodata=np.nan,
    )
    out = pansharpen(pan, ms, "gs", pan_transform=pan_t, ms_transform=ms_t, pan_crs="EPSG:3857", ms_crs="EPSG:32633")
    r0, c0 = out.window
    rows, cols = out.image.shape[1:]
    inner = np.zeros((rows, cols), bool)
    inner[8:-8, 8:-8] = True
    ok = out.valid & inner
    assert ok.mean() > 0.5
    ref = truth[:, r0 : r0 + rows, c0 : c0 + cols]
    cp, rp = positions(pan.shape, pan_t, "EPSG:3857", ms.shape[1:], ms_t, "EPSG:32633")
    plain = np.asarray(resample(ms, cp, rp, "cubic"))[:, r0 : r0 + rows, c0 : c0 + cols]
    assert ergas(out.image[:, ok][..., None], ref[:, ok][..., None], 4) < 0.6 * ergas(
        plain[:, ok][..., None], ref[:, ok][..., None], 4
    )  # measured 0.30 against 0.67
