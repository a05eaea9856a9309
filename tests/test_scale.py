"""Inputs at scale (issue 27): data snooping that does not refit once per
blunder, GCP files of 10^5 lines, and no crash at exit after a large resection.

No timings here (benchmarks/bench_gcp_io.py and the commit messages have
them): what is tested is that the fast paths give the slow paths' answers.
"""

import numpy as np
import pytest
from conftest import scaled
from scipy import special

import photax as ptx
from photax.resection import _adjust

CAM = ptx.FrameCamera(0.15324)  # metres on the image plane
SIGMA = 5e-6  # 5 um image measurements
EO = ptx.ExteriorOrientation([512_000.0, 4_321_000.0, 1600.0], [0.02, -0.01, 0.6])


def _points(n, seed):
    """``n`` image points with N(0, SIGMA) noise and their ground points (UTM-scale, 40 m relief)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.09, 0.09, (n, 2))
    ground = np.asarray(ptx.image_to_ground(xy, EO, CAM, height=100.0 + rng.uniform(0.0, 40.0, n)))
    return xy + rng.normal(0.0, SIGMA, (n, 2)), ground


def _one_at_a_time(xy, ground, sigma, alpha=0.001):
    """Baarda's data snooping as the textbook writes it, through the public API:
    fit, exclude the point with the largest |w| above the critical value, fit again
    (without a sigma: Pope's tau, whose critical value the fit reports for its redundancy)."""
    c = np.sqrt(2.0) * special.erfinv(1.0 - alpha)  # two-sided normal quantile (3.29)
    out = np.zeros(len(xy), bool)
    while True:
        r = ptx.resect(xy, ground, CAM, sigma=sigma, check=out, robust=False)
        w = np.where(out, 0.0, np.max(np.nan_to_num(np.abs(np.asarray(r.normalised))), axis=1))
        if w.max() <= (c if sigma is not None else float(r.critical)):
            return out, r
        out[np.argmax(w)] = True


@pytest.mark.parametrize("sigma", [SIGMA, None])
@pytest.mark.parametrize("n, sizes", [(40, (60.0, 25.0, 9.0)), (400, (80.0, 30.0, 12.0, 8.0, 6.0, 5.0))])
def test_snooping_excludes_what_one_at_a_time_snooping_excludes(n, sizes, sigma):
    """Blunders of 5-80 sigma: the same points excluded and the same orientation
    as one exclusion per refit (several per round where the points are many)."""
    xy, ground = _points(n, seed=n)
    idx = np.random.default_rng(1).choice(n, len(sizes), replace=False)
    xy[idx, 0] += np.asarray(sizes) * SIGMA
    want, ref = _one_at_a_time(xy, ground, sigma)
    got = ptx.resect(xy, ground, CAM, sigma=sigma)
    assert set(np.flatnonzero(want)) >= set(idx)
    np.testing.assert_array_equal(np.asarray(got.outliers), want)
    np.testing.assert_allclose(np.asarray(got.exterior.position), np.asarray(ref.exterior.position), atol=1e-6)
    np.testing.assert_allclose(np.asarray(got.exterior.angles), np.asarray(ref.exterior.angles), atol=1e-10)


def _test_round(n, sizes, seed=0):
    """The points one round of the test excludes, for an adjustment of all ``n`` points."""
    from photax.resection._api import _bucket, _inputs, _options
    from photax.resection._checks import validate

    xy, ground = _points(n, seed)
    idx = np.random.default_rng(seed).choice(n, len(sizes), replace=False)
    xy[idx, 0] += np.asarray(sizes) * SIGMA
    prep = validate(xy, ground, CAM, SIGMA, None, None, None, "phi-omega-kappa", 0.001, batch=False)
    m = _bucket(n)
    opt = _options(prep, CAM, "phi-omega-kappa", True, 0.001, 50, m)
    inp = _inputs(prep, m)
    cheap = _adjust.solve_cheap(inp, opt)  # linear start, one adjustment of all points
    out = {k: getattr(cheap, k) for k in ("w", "sigma0", "redundancy", "result")}
    go, excluded, _, _ = _adjust.test(out, inp.ctrl, opt)
    return bool(go[0]), set(np.flatnonzero(np.asarray(excluded)[:n, 0])), set(idx)


def test_many_points_exclude_every_clear_blunder_in_one_round():
    go, excluded, blunders = _test_round(2000, (50.0, 20.0, 12.0, 9.0, 7.0))
    assert go and excluded >= blunders  # (and the odd chance point above 3.29 of 4,000 observations)


def test_few_points_exclude_only_the_worst_per_round():
    """12 points: a 40-sigma blunder pulls the others' residuals, so only it goes."""
    go, excluded, blunders = _test_round(12, (40.0, 15.0), seed=3)
    assert go and len(excluded) == 1 and excluded < blunders


# --- GCP files of 10^5 lines -----------------------------------------------------------------------


def _gcp_csv(path, n, seed=0, bad=None):
    """A GCP CSV of ``n`` measurements with every optional column in use (empty names and sigmas,
    roles in any case, spaces around fields, comments); ``bad``: ``(row, text)`` replaces one easting."""
    rng = np.random.default_rng(seed)
    half = n // 2  # every point measured in two images
    g = (rng.uniform(0.0, 1.0, (half, 3)) * [1e3, 1e3, 50.0] + [512_000.0, 4.1e6, 10.0]).tolist()
    px = (rng.uniform(0.0, 1.0, (n, 2)) * [4000.0, 3000.0]).tolist()
    lines = ["# crs: EPSG:32633", "name, image ,E,N,h,col,row,sigma,role"]
    for i in range(n):
        p = i % half
        name = "" if p % 7 == 3 else f"P{p}"
        e = repr(g[p][0]) if bad is None or bad[0] != i else bad[1].format(repr(g[p][0]))
        sigma = "" if i % 5 == 0 else f"{0.1 + i % 3 * 0.2:.1f}"
        role = (["check", " Check", "CHECK "] if p % 4 == 1 and name else ["control", "", "Control "])[i % 3]
        lines.append(f"{name},IMG_{i // half} ,{e}, {g[p][1]!r},{g[p][2]!r},{px[i][0]!r} ,{px[i][1]!r},{sigma},{role}")
        if i % 1000 == 10:
            lines += ["# a comment", ""]
    path.write_text("\n".join(lines) + "\n")
    return path


def _same_tables(a, b):
    for field in ("names", "images", "role", "lines", "ground", "pixel", "sigma"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    assert a.crs == b.crs and a.image_xy is None and b.image_xy is None


@pytest.mark.parametrize("fmt", ["csv", "odm"])
def test_whole_file_parsing_equals_the_line_by_line_parser(tmp_path, monkeypatch, fmt):
    from photax.io import gcp

    path = _gcp_csv(tmp_path / "g.csv", 3000)
    if fmt == "odm":  # the same measurements as an ODM list: E N h col row image [name]
        t = gcp.read_gcps(path)
        rows = [
            f"{e!r} {n!r} {h!r} {c!r} {r!r} {im}" + (f" Q{nm} extra" if k % 2 else "")
            for k, ((e, n, h), (c, r), im, nm) in enumerate(zip(t.ground.tolist(), t.pixel.tolist(), t.images, t.names))
        ]
        path = tmp_path / "gcp_list.txt"
        path.write_text("EPSG:32633\n" + "\n".join(rows) + "\n")
    calls = []
    fast_rows = gcp._fast_rows
    monkeypatch.setattr(gcp, "_fast_rows", lambda *a, **k: calls.append(1) or fast_rows(*a, **k))
    fast = gcp.read_gcps(path)
    assert calls and len(fast) == 3000  # the fast path was taken
    monkeypatch.setattr(gcp, "_fast_rows", lambda *a, **k: None)  # every line through the line parser
    _same_tables(fast, gcp.read_gcps(path))


@pytest.mark.parametrize(
    "bad, message",
    [
        ("5.12e5x", "E is not a number: '5.12e5x'"),
        ("inf", "E is not finite: 'inf'"),
        ("1,2", "expected 9 columns, got 10"),
        ('"{}"', None),  # its own value quoted: a valid CSV field, read by the line-by-line parser
    ],
)
def test_a_malformed_line_deep_in_a_big_file_is_named(tmp_path, bad, message):
    path = _gcp_csv(tmp_path / "g.csv", 100_000, bad=(87_654, bad))
    line = 2 + 87_654 + 1 + 2 * (87_654 // 1000 + 1)  # 2 lines of header, 2 per comment block above
    text = path.read_text().split("\n")[line - 1]
    if message is None:
        t = ptx.read_gcps(path)
        assert text.split(",")[2] == f'"{float(t.ground[87_654, 0])!r}"' and t.lines[87_654] == line
        return
    assert text.split(",")[2] == bad.split(",")[0]
    with pytest.raises(ValueError, match=f"g.csv, line {line}: {message}"):
        ptx.read_gcps(path)


@pytest.mark.parametrize("sigma_known", [True, False])
def test_critical_table_is_the_critical_value_per_point_count(sigma_known):
    from photax.resection._checks import _critical, _critical_table

    table = _critical_table(0.001, sigma_known, 300)
    np.testing.assert_array_equal(table, [_critical(0.001, sigma_known, 2.0 * k - 6.0) for k in range(301)])


def test_resect_of_3000_gcps_exits_cleanly(tmp_path):
    """``photax resect`` with 3,000 GCPs printed its result, then aborted (exit 134,
    "FATAL: exception not rethrown") while its background compilation was still
    running; noise-free points pass the blunder test, so that program is not waited for."""
    import json
    import pathlib
    import subprocess
    import sys

    data = pathlib.Path(__file__).resolve().parents[1] / "data"
    truth = json.loads((data / "sample_truth.json").read_text())
    cam = ptx.read_camera(data / "sample_camera.yaml")
    eo = ptx.ExteriorOrientation(truth["position"], truth["angles_rad"])
    rng = np.random.default_rng(5)
    g = np.column_stack(
        [np.asarray(truth["position"][:2]) + rng.uniform(-150.0, 150.0, (3000, 2)), rng.uniform(30.0, 70.0, 3000)]
    )
    px = np.asarray(cam.image_to_pixel(ptx.project(g, eo, cam)))
    assert np.all((px > 0) & (px < [999, 749]))
    path = tmp_path / "gcps.csv"
    path.write_text(
        "E,N,h,col,row\n"
        + "".join(f"{a!r},{b!r},{c!r},{d!r},{e!r}\n" for a, b, c, d, e in np.column_stack([g, px]).tolist())
    )
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from photax.cli import main; sys.exit(main())",
            "resect",
            str(path),
            "--camera",
            str(data / "sample_camera.yaml"),
        ],
        check=False,
        capture_output=True,
        text=True,
        timeout=scaled(600),
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "1 of 1 image solved" in proc.stdout and "terminate" not in proc.stderr
