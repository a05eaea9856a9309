"""DEM-aided bundle adjustment: each tie point's height as an observation of a
DEM at its planimetric position, ``Z - DEM(X, Y) = 0`` with a sigma (Ames Stereo
Pipeline's ``bundle_adjust --heights-from-dem``).  The Schur step against a
dense solve with the DEM rows differentiated independently here, a GNSS block
over known terrain with and without the DEM against its truth, points off the
DEM, bad input, the CLI and the real NGI block."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from bundle_steps import LAMBDA, apply, one_step

import photax as ptx
from photax.bundle._linearise import _residuals
from photax.cli import main
from photax.io.block import write_block
from photax.scene import synthetic_block

H, RELIEF, F_PX, W, HT = 600.0, 150.0, 3000.0, 4000, 3000
ORIGIN = np.array([500_000.0, 4_000_000.0, 100.0])


def _terrain(x, y, strips=2, per_strip=4):
    """The terrain of :func:`photax.scene.block_scene` (its default layout and
    ``relief=RELIEF``), written out here: heights at ground ``x, y``."""
    gsd = H / F_PX
    xs, ys = np.arange(per_strip) * 0.4 * W * gsd, np.arange(strips) * 0.7 * HT * gsd
    lo = np.array([xs[0] - 0.3 * W * gsd, ys[0] - 0.3 * HT * gsd])
    hi = np.array([xs[-1] + 0.3 * W * gsd, ys[-1] + 0.3 * HT * gsd])
    x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
    u = (x - ORIGIN[0] - lo[0]) / (hi[0] - lo[0])
    v = (y - ORIGIN[1] - lo[1]) / (hi[1] - lo[1])
    return RELIEF * (0.5 + 0.25 * np.sin(5.0 * u) * np.cos(4.0 * v) + 0.25 * u * v) + ORIGIN[2]


def _dem(post=10.0, noise=1.0, seed=7, crs=None):
    """The terrain sampled every ``post`` m, plus N(0, noise) per post, over
    the block and 100 m around it."""
    gsd = H / F_PX
    x0, x1 = ORIGIN[0] - 0.3 * W * gsd - 100, ORIGIN[0] + 3 * 0.4 * W * gsd + 0.3 * W * gsd + 100
    y0, y1 = ORIGIN[1] - 0.3 * HT * gsd - 100, ORIGIN[1] + 0.7 * HT * gsd + 0.3 * HT * gsd + 100
    gx, gy = np.arange(x0, x1, post), np.arange(y1, y0, -post)
    z = _terrain(gx[None, :], gy[:, None]) + noise * np.random.default_rng(seed).standard_normal((len(gy), len(gx)))
    return ptx.DEM(z, (post, 0, gx[0] - post / 2, 0, -post, gy[0] + post / 2), crs)


#: The height error of a bilinear DEM whose posts carry independent N(0, 1 m)
#: noise, at a uniformly random point: sqrt(E sum w^2) = sqrt((2/3)^2) m.
DEM_SIGMA = 2.0 / 3.0


def _gnss(truth, sigma, seed):
    rng = np.random.default_rng(seed)
    return np.asarray(truth.exterior.position) + sigma * rng.standard_normal((len(truth.exterior.position), 3))


@pytest.fixture(scope="module")
def terrain_block():
    """2 strips x 4 images over 150 m of relief (600 m flying height), 150
    ties, no control, 0.5 px noise; GNSS positions of sigma 2 m."""
    problem, truth = synthetic_block(0, n_control=0, n_check=0, n_tie=150, relief=RELIEF)
    assert np.allclose(_terrain(truth.points[:, 0], truth.points[:, 1]), truth.points[:, 2], atol=1e-6)
    return problem.replace(gnss_position=_gnss(truth, 2.0, 1), gnss_sigma=2.0), truth


def test_the_bilinear_dem_sigma_is_what_the_test_dem_gives():
    """The sigma the tests give the DEM (2/3 of its posts' noise) is the RMS
    of its heights' errors at random points: measured, not assumed."""
    dem = _dem()
    rng = np.random.default_rng(3)
    x = rng.uniform(ORIGIN[0], ORIGIN[0] + 1200, 4000)
    y = rng.uniform(ORIGIN[1], ORIGIN[1] + 700, 4000)
    err = np.asarray(dem.height(x, y)) - _terrain(x, y)
    assert np.sqrt(np.mean(err**2)) == pytest.approx(DEM_SIGMA, rel=0.1)


@pytest.mark.parametrize("solver", ["dense", "band", "cg"])
def test_schur_step_with_dem_equals_dense_normal_equations(terrain_block, solver):
    """One damped step with GNSS and DEM heights (some points off the DEM)
    equals the dense solve of the whole normal matrix, the DEM rows
    ``(Z - DEM(X, Y)) / sigma`` differentiated here by JAX through
    :meth:`photax.DEM.height` as a function of every unknown."""
    problem, _ = terrain_block
    dem = _dem()
    n_img, n_pts = problem.n_images, problem.n_points
    sig = np.random.default_rng(4).uniform(0.5, 2.0, n_pts)
    pts = problem.points.copy()
    pts[:5, 0] -= 5000.0  # off the DEM: no observation (and moved back by the ties alone)
    problem = problem.replace(points=pts, dem=dem, dem_sigma=sig)
    s, n_c, origin, state, lin, new = one_step(problem, solver)
    assert np.count_nonzero(np.asarray(s.dem_w)) == n_pts - 5

    seen = np.ones(n_pts, bool)
    seen[:5] = False
    g_local = jnp.asarray(problem.gnss_position - origin[None, :])

    def residual(x):
        st = apply(state, x, n_img, n_c)
        world = st.xyz + jnp.asarray(origin)[None, :]  # the problem's DEM itself, in world coordinates
        r_dem = ((world[:, 2] - dem.height(world[:, 0], world[:, 1])) / sig)[seen]
        r_g = (st.centre - g_local) / 2.0
        return jnp.concatenate([_residuals(st, s).ravel(), r_g.ravel(), r_dem])

    x0 = jnp.zeros(n_c + 3 * n_pts)
    J = np.asarray(jax.jit(jax.jacfwd(residual))(x0))
    r = np.asarray(jax.jit(residual)(x0))
    assert float(lin.cost) == pytest.approx(0.5 * float(r @ r), rel=1e-10)
    h = J.T @ J
    dx = np.linalg.solve(h + LAMBDA * np.diag(np.clip(np.diag(h), 1e-6, 1e32)), -J.T @ r)
    ref = apply(state, jnp.asarray(dx), n_img, n_c)
    tol = (
        {"centre": 1e-6, "rot": 1e-10, "xyz": 1e-6} if solver != "cg" else {"centre": 2e-3, "rot": 1e-6, "xyz": 2e-3}
    )  # CG: its own tolerance
    np.testing.assert_allclose(new.centre, ref.centre, atol=tol["centre"])
    np.testing.assert_allclose(new.rot, ref.rot, atol=tol["rot"])
    np.testing.assert_allclose(new.xyz, ref.xyz, atol=tol["xyz"])


def test_dem_heights_hold_a_gnss_block_over_relief(terrain_block):
    """GNSS of sigma 2 m alone lets the block turn by ~0.1-0.2 deg; with the
    DEM (posts 10 m, noise 1 m, sigma its measured 2/3 m) every angle's and
    position's sigma is lower, the largest angle error is lower, all agree
    with the truth within 3 sigma, sigma0 ~ 1, and the redundancy, report
    and JSON count the DEM heights."""
    problem, truth = terrain_block
    plain = ptx.bundle_adjust(problem)
    res = ptx.bundle_adjust(problem.replace(dem=_dem(), dem_sigma=DEM_SIGMA))
    assert plain.converged and res.converged
    true_ang = np.asarray(truth.exterior.angles)
    errs = {}
    for name, r in (("plain", plain), ("dem", res)):
        errs[name] = (
            np.abs(np.degrees(np.asarray(r.exterior.angles) - true_ang)),
            np.abs(np.asarray(r.exterior.position) - np.asarray(truth.exterior.position)),
        )
        ang, pos = errs[name]
        assert np.all(ang < 3 * np.degrees(r.exterior_std[:, 3:])), (name, ang, np.degrees(r.exterior_std[:, 3:]))
        assert np.all(pos < 3 * r.exterior_std[:, :3]), (name, pos, r.exterior_std[:, :3])
    assert np.all(res.exterior_std < plain.exterior_std)
    assert np.median(res.exterior_std[:, 3:]) < 0.5 * np.median(plain.exterior_std[:, 3:])
    assert errs["dem"][0].max() < 0.6 * errs["plain"][0].max()
    pt_err = np.abs(res.points - truth.points)
    assert np.all(pt_err < 4 * res.point_std), np.max(pt_err / res.point_std, axis=0)  # 450 values
    assert 0.8 < res.sigma0 < 1.2
    assert res.redundancy == plain.redundancy + problem.n_points
    assert np.sqrt(np.nanmean(res.dem_residuals**2)) == pytest.approx(DEM_SIGMA, rel=0.3)
    report = res.report(unit="m")
    assert f"DEM heights ({problem.n_points} of {problem.n_points} tie points; 0 off the DEM" in report
    assert res.to_dict()["dem_heights"]["observed"] == problem.n_points
    assert plain.dem_residuals is None and "DEM" not in plain.report()
    # the robust path (its point pass) counts the DEM heights too: the same answer at a wide loss scale
    rob = ptx.bundle_adjust(problem.replace(dem=_dem(), dem_sigma=DEM_SIGMA), loss="huber", loss_scale=10.0)
    np.testing.assert_allclose(rob.exterior.position, res.exterior.position, atol=1e-4)


def test_points_off_the_dem_or_on_nodata_get_no_observation(terrain_block):
    """A DEM with a nodata hole and covering only part of the block: the ties
    there (at the start values) get no height observation, are counted in the
    report, have NaN residuals, and the block still converges."""
    problem, _ = terrain_block
    dem = _dem()
    z = np.asarray(dem.heights).copy()
    z[:, : z.shape[1] // 3] = np.nan  # the western third: nodata
    cut = ptx.DEM(z[: z.shape[0] * 2 // 3], np.asarray(dem.transform))  # the southern third: off the grid
    res = ptx.bundle_adjust(problem.replace(dem=cut, dem_sigma=DEM_SIGMA))
    assert res.converged
    h = np.asarray(cut.height(problem.points[:, 0], problem.points[:, 1]))
    on = np.isfinite(h)
    assert 20 < on.sum() < problem.n_points - 20
    np.testing.assert_array_equal(np.isfinite(res.dem_residuals), on)
    assert f"({int(on.sum())} of {problem.n_points} tie points; {int((~on).sum())} off the DEM" in res.report()


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"dem_sigma": 0.0}, "dem_sigma must be positive"),
        ({"dem_sigma": -1.0}, "dem_sigma must be positive"),
        ({"dem_sigma": np.nan}, "dem_sigma must be positive"),
        ({"dem_sigma": np.ones(3)}, "dem_sigma must be a scalar or"),
        ({"dem_sigma": None}, "dem needs dem_sigma"),
        ({"dem": None, "dem_sigma": 1.0}, "dem_sigma is given without dem"),
        ({"dem": np.zeros((3, 3)), "dem_sigma": 1.0}, "dem must be a photax.DEM"),
        ({"dem": _dem(crs="EPSG:32632"), "dem_sigma": 1.0, "crs": "EPSG:32633"}, "but the DEM in"),
    ],
)
def test_bad_dem_input_is_refused(terrain_block, kw, match):
    problem, _ = terrain_block
    with pytest.raises(ValueError, match=match):
        problem.replace(**{"dem": _dem(), **kw})


def test_dem_crs_compared_by_its_horizontal_part(terrain_block):
    """A compound DEM CRS (projected + EGM2008 heights, as the NGI DEM's)
    matches the block's projected CRS; heights are the user's business."""
    problem, _ = terrain_block
    ok = problem.replace(dem=_dem(crs="EPSG:32632+3855"), dem_sigma=1.0, crs="EPSG:32632")
    assert ok.dem is not None and ok.crs == "EPSG:32632"


def test_a_dem_beside_the_block_is_refused(terrain_block):
    problem, _ = terrain_block
    dem = _dem()
    far = ptx.DEM(np.asarray(dem.heights), np.asarray(dem.transform) + np.array([0, 0, 1e5, 0, 0, 0]))
    with pytest.raises(ValueError, match="no tie point of the block lies on the DEM"):
        ptx.bundle_adjust(problem.replace(dem=far, dem_sigma=1.0))


def test_cli_dem_option(terrain_block, tmp_path, capsys):
    """``photax bundle BLOCK --position-sigma 2 --dem DEM --dem-sigma S``
    reports the DEM heights and writes them to the JSON; bad input exits 2."""
    from photax.io import write_geotiff

    problem, truth = terrain_block
    block = tmp_path / "block"
    write_block(problem.replace(exterior=ptx.ExteriorOrientation(problem.gnss_position,
                                                                  np.asarray(problem.exterior.angles),
                                                                  problem.exterior.convention)), block)  # fmt: skip
    dem = _dem()
    tif = write_geotiff(tmp_path / "dem.tif", np.asarray(dem.heights), tuple(np.asarray(dem.transform)))
    out = tmp_path / "res.json"
    code = main(["bundle", str(block), "--position-sigma", "2", "--dem", str(tif), "--dem-sigma", f"{DEM_SIGMA}",
                 "--quiet", "--no-progress", "-o", str(out)])  # fmt: skip
    text = capsys.readouterr().out
    assert code == 0, text
    assert f"DEM heights ({problem.n_points} of {problem.n_points} tie points" in text
    assert json.loads(out.read_text())["dem_heights"]["observed"] == problem.n_points
    for args, msg in (
        (["--dem-sigma", "1"], "--dem-sigma needs --dem"),
        (["--dem", str(tif)], "--dem needs --dem-sigma"),
        (["--dem", str(tif), "--dem-sigma", "0"], "--dem-sigma must be a positive number"),
        (["--dem", str(tmp_path / "none.tif"), "--dem-sigma", "1"], "none.tif"),
    ):
        assert main(["bundle", str(block), "--position-sigma", "2", "--quiet", "--no-progress", *args]) == 2
        assert msg in capsys.readouterr().err


def test_replace_keeps_one_dem_sigma_when_points_change(terrain_block):
    """A DEM sigma given once for all points stays so when points are added
    (e.g. georeference's GCPs) or dropped."""
    problem, _ = terrain_block
    p = problem.replace(dem=_dem(), dem_sigma=2.0)
    keep = p.obs_point < p.n_points - 1
    fewer = p.replace(points=p.points[:-1], obs_point=p.obs_point[keep], obs_image=p.obs_image[keep],
                      obs_xy=p.obs_xy[keep], obs_sigma=p.obs_sigma[keep], roles=p.roles[:-1],
                      point_sigma=p.point_sigma[:-1], point_names=p.point_names[:-1])  # fmt: skip
    assert fewer.dem_sigma.shape == (p.n_points - 1,) and np.all(fewer.dem_sigma == 2.0)


def test_ngi_block_with_gnss_and_its_dem():
    """The real NGI block (four frames, two strips flown opposite ways):
    ties from photax.match_ties (100 points per image, start orientations =
    GNSS + attitudes 0.15 deg off), GNSS = camera_pos_ori.txt + N(0, 2 m),
    sigma 2 m, and NGI's DEM at sigma 3 m (the RMS of Z - DEM measured for
    ties intersected with the survey's orientations, benchmarks/gnss_ngi.py).
    Every tie lies on the DEM; the DEM lowers each image's omega and phi
    sigma at least 2x (kappa's less: the slopes alone hold it); every angle is within 0.05 deg and every position within 4 m
    of camera_pos_ori.txt; the DEM residuals' RMS is about its sigma.  A block
    CRS other than the DEM's (geographic WGS 84) is refused."""
    import cv2
    from conftest import shared_file

    from photax.io import read_dem
    from photax.io.orthority import read_orthority_interior
    from photax.matching import bundle_problem

    ngi = shared_file("orthority/ngi/camera_pos_ori.txt").parent
    rows = [ln.split() for ln in (ngi / "camera_pos_ori.txt").read_text().splitlines() if ln.strip()]
    names = [r[0] for r in rows]
    pos = np.array([[float(v) for v in r[1:4]] for r in rows])
    ang = np.radians(np.array([[float(v) for v in r[4:7]] for r in rows]))
    cam = next(iter(read_orthority_interior(shared_file("orthority/io/ngi_int_param.yaml")).values()))
    images = [cv2.imread(str(shared_file(f"orthority/ngi/{n}.tif")), cv2.IMREAD_GRAYSCALE).astype(float) for n in names]
    dem = read_dem(shared_file("orthority/ngi/dem.tif"))
    rng = np.random.default_rng(0)
    gnss = pos + 2.0 * rng.standard_normal(pos.shape)
    start_ang = ang + np.radians(0.15) * rng.standard_normal(ang.shape)
    start = ptx.ExteriorOrientation(gnss, start_ang, "omega-phi-kappa")
    starts = [ptx.ExteriorOrientation(g, a, "omega-phi-kappa") for g, a in zip(gnss, start_ang)]
    ties = ptx.match_ties(images, cam, starts, dem, max_points=100, min_rho=0.6)
    problem = bundle_problem(cam, start, ties, image_names=names).replace(gnss_position=gnss, gnss_sigma=2.0)
    plain = ptx.bundle_adjust(problem, initialize=True)
    res = ptx.bundle_adjust(problem.replace(dem=dem, dem_sigma=3.0), initialize=True)
    assert res.converged and 0.8 < res.sigma0 < 1.2
    assert np.all(np.isfinite(res.dem_residuals))
    # the tilts (omega, phi) at least 2x; kappa, held by the slopes alone, less
    assert np.all(res.exterior_std[:, 3:5] < 0.5 * plain.exterior_std[:, 3:5])
    assert np.all(res.exterior_std[:, 5] < 0.75 * plain.exterior_std[:, 5])
    dang = np.degrees(np.asarray(res.exterior.angles) - ang)
    assert np.abs(dang).max() < 0.05, dang
    assert np.abs(np.asarray(res.exterior.position) - pos).max() < 4.0
    assert 1.5 < np.sqrt(np.mean(res.dem_residuals**2)) < 4.5
    with pytest.raises(ValueError, match="but the DEM in"):
        problem.replace(dem=dem, dem_sigma=3.0, crs="EPSG:4326")


@pytest.mark.parametrize("given", [DEM_SIGMA, 3.0 * DEM_SIGMA])
def test_the_dem_sigma_estimate_finds_the_dem_error(terrain_block, given):
    """The variance component of the DEM heights estimates the DEM's true
    error at the ties (2/3 m: posts with 1 m noise, bilinear) whether the
    sigma given is right or 3x too large; the report prints it."""
    problem, _ = terrain_block
    res = ptx.bundle_adjust(problem.replace(dem=_dem(), dem_sigma=given))
    assert res.dem_sigma_estimate == pytest.approx(DEM_SIGMA, rel=0.25)
    assert f"estimated {res.dem_sigma_estimate:.3g}" in res.report()


def test_cli_refuses_a_dem_in_another_crs(terrain_block, tmp_path, capsys):
    """A block folder whose block.json names its CRS (kept by write_block /
    read_block) and a DEM in another: exit 2, both CRSs named."""
    from photax.io import write_geotiff
    from photax.io.block import read_block

    problem, _ = terrain_block
    block = tmp_path / "block"
    write_block(problem.replace(gnss_position=None, gnss_sigma=None, crs="EPSG:32632"), block)
    assert read_block(block).crs == "EPSG:32632"
    dem = _dem()
    tif = write_geotiff(
        tmp_path / "dem.tif", np.asarray(dem.heights), tuple(np.asarray(dem.transform)), crs="EPSG:32633"
    )
    args = ["bundle", str(block), "--position-sigma", "2", "--dem", str(tif), "--dem-sigma", "1", "--quiet"]
    assert main([*args, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "the block is in EPSG:32632 but the DEM in EPSG:32633" in err
