"""Gain/offset balancing of mosaics (photax.mosaicking._balance) at real overlap sizes, and the mosaic's
refusals of inputs it cannot join (issue 21).

Truth: n images of one scene with known gains and offsets, ``v_i = (t - o_i) / g_i``, so that
``g_i v_i + o_i = t`` in every overlap.  Each overlap is given by the moments ``_pair_moments`` sums, in
closed form from the scene's mean and variance there and its pixel count (10^4 to 10^7: no huge arrays).
A zero-residual solution is unique up to a common gain ``c`` and offset ``d``; the datum (mean gain 1,
mean offset 0) fixes them, so the recovered gains are ``g / mean(g)`` and offsets ``(o - mean(o)) / mean(g)``.
"""

import re

import numpy as np
import pytest
from conftest import needs

from photax.mosaicking import _balance


def _moments(n, count, rng, noise=0.0):
    """The pairs' moments ``{(i, j): [count, Sa, Sb, Saa, Sbb, Sab]}`` of a chain of n images plus random
    extra pairs, each image with independent noise of variance ``noise``; the true gains and offsets."""
    g = rng.uniform(0.6, 1.5, n)
    o = rng.uniform(-40, 40, n)
    pairs = {(i, i + 1) for i in range(n - 1)} | {tuple(sorted(rng.choice(n, 2, replace=False))) for _ in range(n)}
    out = {}
    for i, j in sorted(pairs):
        mt, vt = (
            rng.uniform(60, 200),
            rng.uniform(400, 2000),
        )  # the scene's mean and variance in the overlap
        ma, mb = (mt - o[i]) / g[i], (mt - o[j]) / g[j]
        vaa, vbb, vab = (
            vt / g[i] ** 2 + noise,
            vt / g[j] ** 2 + noise,
            vt / (g[i] * g[j]),
        )
        out[(i, j)] = [
            count,
            count * ma,
            count * mb,
            count * (vaa + ma * ma),
            count * (vbb + mb * mb),
            count * (vab + ma * mb),
        ]
    return out, g, o


@pytest.mark.parametrize("count", [10**4, 10**5, 4 * 10**5, 10**7])
@pytest.mark.parametrize("n", [2, 4, 17, 50])
def test_known_gains_and_offsets_recovered_at_any_overlap_size(n, count):
    """Before issue 21 the normal equations held raw sums (~1e10 at 1e5 px) beside the datum's ones and
    lstsq's cut-off dropped the datum: with any noise in the images every gain came out ~0 (a blank
    mosaic) from 1e5 overlap pixels up.  Noise of variance 0.25 (which the least squares does not model:
    it biases the gains by about its ratio to the scene's variance, <= 0.06 % here)."""
    rng = np.random.default_rng(n * 1000 + count % 997)
    moments, g, o = _moments(n, count, rng, noise=0.25)
    gains, offsets = _balance(n, moments)
    np.testing.assert_allclose(gains, g / g.mean(), rtol=2e-3)
    np.testing.assert_allclose(offsets, (o - o.mean()) / g.mean(), atol=0.5)
    exact, _ = _balance(n, _moments(n, count, np.random.default_rng(n * 1000 + count % 997))[0])
    np.testing.assert_allclose(exact, g / g.mean(), rtol=1e-8)  # without noise: exact
    assert gains.mean() == pytest.approx(1.0) and offsets.mean() == pytest.approx(0.0, abs=1e-9)


def test_unequal_overlap_sizes_and_noise():
    """Overlaps from 10^4 to 10^7 px in one block, each image with its own noise (variance 1 grey level^2,
    <= 0.4 % of the scene's; biases add up along the chains of overlaps): gains within 2 %, offsets within
    3 grey levels of the truth."""
    rng = np.random.default_rng(3)
    n = 12
    moments, g, o = _moments(n, 1, rng)
    for p, m in moments.items():
        cnt = float(10 ** rng.uniform(4, 7))
        ma, mb = m[1], m[2]
        vaa, vbb, vab = m[3] - ma * ma + 1.0, m[4] - mb * mb + 1.0, m[5] - ma * mb
        moments[p] = [
            cnt,
            cnt * ma,
            cnt * mb,
            cnt * (vaa + ma * ma),
            cnt * (vbb + mb * mb),
            cnt * (vab + ma * mb),
        ]
    gains, offsets = _balance(n, moments)
    np.testing.assert_allclose(gains, g / g.mean(), rtol=0.02)
    np.testing.assert_allclose(offsets, (o - o.mean()) / g.mean(), atol=3.0)


def test_undetermined_gain_is_refused():
    """Image 2 constant (50) in its only overlap: its gain and offset are one unknown; refused, not guessed."""
    moments, _, _ = _moments(2, 10**6, np.random.default_rng(1))
    moments[(1, 2)] = [
        1e6,
        1e8,
        5e7,
        1e10 + 1e9,
        2.5e9,
        5e9,
    ]  # a: mean 100, variance 1000; b == 50
    with pytest.raises(ValueError, match="do not determine the gain of ortho 2: it is constant"):
        _balance(3, moments)


# The mosaic's refusals, on small in-memory orthos.
pytestmark_dask = needs("dask", "rioxarray")


def _ortho(values, col0, res=2.0):
    from photax.grid import Grid
    from photax.io.lazy import dataarray

    grid = Grid(
        (res, 0, 500_000.0 + col0 * res, 0, -res, 4_000_000.0),
        values.shape,
        crs="EPSG:32633",
    )
    return dataarray(
        np.asarray(values, dtype=np.float32),
        grid,
        np.asarray(np.nan, dtype=np.float32),
        "o",
    )


@pytestmark_dask
def test_mosaic_refusals():
    from photax import mosaic

    rng = np.random.default_rng(0)
    scene = rng.uniform(20, 200, (40, 200))
    a, b = _ortho(scene[:, :80], 0), _ortho(scene[:, 50:130] * 1.2 + 5, 50)
    assert np.isfinite(mosaic([a, b]).values).all()  # fine
    with pytest.raises(ValueError, match=r"orthos\[1\] has no valid pixel"):
        mosaic([a, _ortho(np.full((40, 80), np.nan), 50)])
    # Two groups joined within, not between: said plainly.
    c, d = _ortho(scene[:, 140:170], 140), _ortho(scene[:, 160:200], 160)
    with pytest.raises(
        ValueError,
        match=r"do not all overlap.*orthos\[0\], orthos\[1\]\}.*orthos\[2\], orthos\[3\]",
    ):
        mosaic([a, b, c, d])
    # An inverted image (a negative) cannot be balanced by a positive gain: an error, not a blank mosaic.
    with pytest.raises(ValueError, match=r"orthos\[1\] a gain of .*<= 0"):
        mosaic([a, _ortho(255 - scene[:, 50:130], 50), _ortho(scene[:, 100:180], 100)])


@pytestmark_dask
def test_cli_refuses_an_empty_ortho_and_orthos_that_do_not_overlap(tmp_path, capsys):
    """Exit 2 with one line naming the file, never a blank mosaic with exit 0."""
    from photax.cli import main

    scene = np.random.default_rng(1).uniform(20, 200, (40, 200))
    paths = {}
    for name, o in (
        ("a", _ortho(scene[:, :80], 0)),
        ("b", _ortho(scene[:, 50:130], 50)),
        ("empty", _ortho(np.full((40, 80), np.nan), 50)),
        ("far", _ortho(scene[:, 150:200], 150)),
    ):
        o.rio.to_raster(tmp_path / f"{name}.tif")
        paths[name] = str(tmp_path / f"{name}.tif")
    out = tmp_path / "m.tif"
    for names, match in (
        (("a", "empty"), r"orthos\[1\] \(.*empty\.tif\) has no valid pixel"),
        (("a", "b", "far"), r"orthos\[2\] \(.*far\.tif\) overlaps no other ortho"),
    ):
        assert main(["mosaic", *(paths[n] for n in names), "-o", str(out), "--no-progress"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and re.search(match, err), err
        assert not out.exists()
