"""photax.coregister (issue 24, item 3): image-to-image registration, AROSICS-like.

The synthetic pairs are rendered analytically (a sum of Gaussian blobs evaluated where each target pixel
comes from), so the known shift field is exact -- no interpolation in the truth; references: that field,
the changed and flat cells put in by construction, and scikit-image's phase_cross_correlation.
"""

import numpy as np
import pytest

import photax as ptx
from photax.matching.coregister import phase_correlation


def _render(seed, n, size, x, y):
    rng = np.random.default_rng(seed)
    c = rng.uniform(-10, size + 10, (n, 2))
    s = rng.uniform(1.2, 3.0, n)
    a = rng.standard_normal(n)
    out = np.zeros(x.shape)
    for (cx, cy), sk, ak in zip(c, s, a):
        r = 4 * sk + 8
        x0, x1 = int(max(0, cx - r)), int(min(size, cx + r + 1))
        y0, y1 = int(max(0, cy - r)), int(min(size, cy + r + 1))
        if x0 < x1 and y0 < y1:
            xx, yy = x[y0:y1, x0:x1], y[y0:y1, x0:x1]
            out[y0:y1, x0:x1] += ak * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * sk * sk))
    return out


def _pair(size, window, shift, amp=0.0, changed=0.0, flat=0, seed=0, affine=None):
    """reference, target, truth(p) -> d with target(p + d) = reference(p), changed and flat cells (row, col).

    The shift field is ``d(q) = shift + amp * smooth(q)`` (+ ``affine @ (q - centre)``) taken at the target
    pixel ``q``: the target shows the texture at ``q - d(q)``."""
    n_blobs = int(0.15 * size * size)
    cells = np.random.default_rng(seed + 2).permutation((size // window) ** 2)
    ch = [divmod(int(k), size // window) for k in cells[: int(round(changed * len(cells)))]]
    fl = [divmod(int(k), size // window) for k in cells[len(ch) : len(ch) + flat]]

    def d_at(x, y):
        u, v = x / size, y / size
        dx = shift[0] + amp * np.sin(2 * np.pi * (0.6 * u + 0.2)) * np.cos(2 * np.pi * 0.4 * v)
        dy = shift[1] + amp * np.cos(2 * np.pi * (0.5 * v + 0.1)) * np.sin(2 * np.pi * (0.3 * u + 0.3))
        if affine is not None:
            dx = dx + affine[0, 0] * (x - size / 2) + affine[0, 1] * (y - size / 2)
            dy = dy + affine[1, 0] * (x - size / 2) + affine[1, 1] * (y - size / 2)
        return dx, dy

    yy, xx = np.mgrid[0:size, 0:size].astype(float)
    dx, dy = d_at(xx, yy)
    sx, sy = xx - dx, yy - dy
    ref = _render(seed, n_blobs, size, xx, yy)
    tgt = _render(seed, n_blobs, size, sx, sy)
    other = _render(seed + 1, n_blobs, size, sx, sy) if ch else None

    def cell(x, y, r, c, m=0):  # smooth (1 px logistic edges) indicator of a cell grown by m px
        lo = lambda t, e: 1 / (1 + np.exp(-(t - e)))  # noqa: E731
        w = window
        return (lo(x, c * w - m) - lo(x, (c + 1) * w + m)) * (lo(y, r * w - m) - lo(y, (r + 1) * w + m))

    for r, c in ch:  # changed content: the target shows another texture there
        m = cell(sx, sy, r, c)
        tgt = (1 - m) * tgt + m * other
    for r, c in fl:  # no texture in either, 6 px beyond the cell
        ref = ref * (1 - cell(xx, yy, r, c, 6))
        tgt = tgt * (1 - cell(sx, sy, r, c, 6))

    def truth(p):
        q = np.array(p, dtype=float)
        for _ in range(60):  # q = p + d(q) by fixed point (|grad d| << 1)
            q = p + np.stack(d_at(q[..., 0], q[..., 1]), axis=-1)
        return q - p

    return ref, tgt, truth, ch, fl


def _cells(reg, window):
    return [(int((c[1] + 0.5) // window), int((c[0] + 0.5) // window)) for c in reg.centres]


def _rms(v):
    return float(np.sqrt(np.mean(np.sum(v**2, axis=1))))


@pytest.fixture(scope="module")
def field_pair():
    return _pair(384, 64, (3.7, -2.3), amp=2.0, changed=0.3, flat=2)


def test_global_shift_by_phase_correlation_beside_scikit_image():
    """A global 3.7 / -2.3 px shift: photax within 0.01 px; scikit-image (no taper: the non-periodic
    edges) printed beside it and within 0.15 px."""
    from skimage.registration import phase_cross_correlation

    ref, tgt, truth, _, _ = _pair(256, 64, (3.7, -2.3))
    d, ratio = phase_correlation(ref, tgt, upsample=100)
    assert np.abs(d - [3.7, -2.3]).max() < 0.01 and ratio > 3
    sk = -phase_cross_correlation(ref, tgt, upsample_factor=100)[0][::-1]  # (row, col) to register moving
    print(f"global shift: photax {d}, scikit-image {sk}, truth (3.7, -2.3)")
    assert np.abs(sk - [3.7, -2.3]).max() < 0.15
    stack, ratios = phase_correlation(np.stack([ref, tgt]), np.stack([tgt, ref]), upsample=100)  # batched
    np.testing.assert_allclose(stack[0], d, atol=1e-9)
    np.testing.assert_allclose(stack[1], -d, atol=0.02)


def test_smooth_local_field_changed_and_textureless_windows(field_pair):
    """Global 3.7 px + a smooth +-2 px field, 30 % of the windows on changed content, 2 flat: the reliable
    windows' shifts within 0.05 px rms of the truth; every changed and flat window rejected, counted."""
    ref, tgt, truth, ch, fl = field_pair
    reg = ptx.coregister(ref, tgt, window=64, model="tps")
    ok = reg.reliable
    assert reg.counts["ok"] == ok.sum() >= 15 and sum(reg.counts.values()) == len(reg.centres) == 36
    err = _rms(reg.matches[ok] - reg.centres[ok] - truth(reg.centres[ok]))
    print(f"local shifts: rms error {err:.4f} px over {ok.sum()} windows; counts {reg.counts}")
    assert err <= 0.05
    np.testing.assert_allclose(reg.shifts[ok], reg.matches[ok] - reg.centres[ok])  # one grid: no start
    cells = _cells(reg, 64)
    changed = np.array([c in ch for c in cells])
    flat = np.array([c in fl for c in cells])
    assert changed.sum() == 11 and flat.sum() == 2
    assert not ok[changed].any() and not ok[flat].any()
    assert set(reg.status[changed]) <= {"weak peak", "dissimilar", "outlier", "no data"}
    assert reg.counts["textureless"] >= 1 and set(reg.status[flat]) <= {"textureless", "no data"}
    # the model between the windows: the shift field at the reliable centres and in the hull
    np.testing.assert_allclose(reg.shift_at(reg.centres[ok]), truth(reg.centres[ok]), atol=0.1)


def test_least_squares_matching_per_window(field_pair):
    ref, tgt, truth, ch, _ = field_pair
    reg = ptx.coregister(ref, tgt, window=64, model="tps", method="lsm")
    ok = reg.reliable
    err = _rms(reg.matches[ok] - reg.centres[ok] - truth(reg.centres[ok]))
    print(f"LSM windows: rms error {err:.4f} px over {ok.sum()} windows")
    assert ok.sum() >= 15 and err <= 0.05
    assert not ok[np.array([c in ch for c in _cells(reg, 64)])].any()


def test_affine_model_resampling_and_corrected_georeference():
    """An affine shift field (0.4 % scale, a small shear): the affine model equals it, the target resampled
    onto the reference grid equals the reference, and the corrected geotransform puts the target's pixels
    where the truth says."""
    a = np.array([[0.004, -0.003], [0.002, -0.004]])
    ref, tgt, truth, _, _ = _pair(256, 64, (1.3, 0.8), affine=a)
    reg = ptx.coregister(ref, tgt, window=64, model="affine")
    assert reg.model_name == "affine" and reg.counts["ok"] >= 9
    p = np.stack(np.meshgrid(np.linspace(20, 235, 7), np.linspace(20, 235, 7)), axis=-1).reshape(-1, 2)
    err = np.abs(reg.shift_at(p) - truth(p)).max()
    print(f"affine model: max error {err:.4f} px")
    assert err < 0.03
    back = reg.resample(tgt, ref.shape)
    inner = (slice(16, -16), slice(16, -16))
    assert np.nanmax(np.abs(back[inner] - ref[inner])) < 0.05 * np.ptp(ref)
    transform = (2.0, 0.0, 500000.0, 0.0, -2.0, 4000000.0)
    corrected = reg.corrected_transform(transform)
    q = p + truth(p)  # target pixels of the reference pixels p
    on_map = lambda t, c: np.c_[t[0] * (c[:, 0] + 0.5) + t[1] * (c[:, 1] + 0.5) + t[2],  # noqa: E731
                                 t[3] * (c[:, 0] + 0.5) + t[4] * (c[:, 1] + 0.5) + t[5]]  # fmt: skip
    np.testing.assert_allclose(on_map(corrected, q), on_map(transform, p), atol=2 * 0.03)  # 2 m px
    tps = ptx.coregister(ref, tgt, window=64, model="tps")
    with pytest.raises(ValueError, match="affine model"):
        tps.corrected_transform(transform)


def test_georeferences_give_the_start():
    """A target cut from another grid (offset by 21 / 13 px): with both geotransforms the shifts are what
    the georeference got wrong (0.6 / -0.4 px), not the offset."""
    ref, tgt, truth, _, _ = _pair(320, 64, (0.6, -0.4))
    t_ref = (1.0, 0.0, 1000.0, 0.0, -1.0, 2000.0)
    t_tgt = (1.0, 0.0, 1021.0, 0.0, -1.0, 1987.0)  # its pixel (0, 0) is the reference's (21, 13)
    part = tgt[13:, 21:]
    reg = ptx.coregister(ref, part, reference_transform=t_ref, target_transform=t_tgt, window=64)
    ok = reg.reliable
    assert ok.sum() >= 6
    np.testing.assert_allclose(reg.shifts[ok], truth(reg.centres[ok]), atol=0.03)
    np.testing.assert_allclose(reg.matches[ok], reg.centres[ok] + truth(reg.centres[ok]) - [21, 13], atol=0.03)


def test_bad_input():
    ref, tgt, _, _, _ = _pair(128, 64, (0.5, 0.5))
    with pytest.raises(ValueError, match="reliable windows"):
        ptx.coregister(np.zeros((128, 128)), np.zeros((128, 128)), window=32)
    with pytest.raises(ValueError, match="even number"):
        ptx.coregister(ref, tgt, window=33)
    with pytest.raises(ValueError, match="model must be"):
        ptx.coregister(ref, tgt, model="spline")
    with pytest.raises(ValueError, match="both reference_transform"):
        ptx.coregister(ref, tgt, reference_transform=(1, 0, 0, 0, -1, 0))
    with pytest.raises(ValueError, match="overlap"):
        far = (1.0, 0.0, 5000.0, 0.0, -1.0, 0.0)
        ptx.coregister(ref, tgt, reference_transform=(1, 0, 0, 0, -1, 0), target_transform=far)
    with pytest.raises(ValueError, match="finite"):
        phase_correlation(np.full((16, 16), np.nan), np.zeros((16, 16)))


def test_no_data_heavy_windows_are_counted_and_left_out():
    """A strip of no data (NaN) in the target: the windows it covers by more than ``max_nodata`` are
    "no data", the rest still fit the shift; those it covers less are measured on their valid pixels
    (masked correlation) as well as the whole ones."""
    ref, tgt, truth, _, _ = _pair(256, 64, (1.3, 0.8))
    tgt = tgt.copy()
    tgt[:, 100:140] = np.nan  # the second column of windows (64-127) is 56 % no data, the third 20 %
    reg = ptx.coregister(ref, tgt, window=64, max_nodata=0.05)
    cells = np.array(_cells(reg, 64))
    assert set(reg.status[cells[:, 1] == 1]) == {"no data"} and set(reg.status[cells[:, 1] == 2]) == {"no data"}
    assert reg.counts["no data"] == 8 and reg.counts["ok"] == 8
    ok = reg.reliable
    np.testing.assert_allclose(reg.shifts[ok], truth(reg.centres[ok]), atol=0.03)
    reg = ptx.coregister(ref, tgt, window=64)  # the default 40 %: the third column is measured
    cells = np.array(_cells(reg, 64))
    assert set(reg.status[cells[:, 1] == 1]) == {"no data"} and set(reg.status[cells[:, 1] == 2]) == {"ok"}
    third = cells[:, 1] == 2
    np.testing.assert_allclose(reg.shifts[third], truth(reg.centres[third]), atol=0.03)
    with pytest.raises(ValueError, match="max_nodata"):
        ptx.coregister(ref, tgt, max_nodata=1.0)


def test_a_window_without_any_data_is_no_data_not_a_warning():
    ref, tgt, _, _, _ = _pair(256, 64, (1.3, 0.8))
    tgt = tgt.copy()
    tgt[:70, :70] = np.nan
    reg = ptx.coregister(ref, tgt, window=64)  # warnings are errors in the tests
    assert reg.status[0] == "no data" and reg.counts["ok"] >= 10
