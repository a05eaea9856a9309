"""Model comparison: relief displacement against its closed form d = r h / H.

The synthetic scene's truth (DEM, exterior orientation, noise-free pixels) is
the reference.  For a vertical image the collinearity equations give, for a
point at height h imaged at radial distance r from the nadir (the principal
point), a radial displacement of exactly d = r h / H against the same (X, Y)
on the datum Z = 0 (Wolf & DeWitt, Elements of Photogrammetry, eq. 6-11).
At Z = 0 a vertical, north-up image is an affine (scale + shift) image of the
ground, so an order-1 polynomial fitted to noise-free GCPs must leave exactly
the part of d that an affine least-squares fit to d cannot absorb.
"""

import json

import numpy as np
import pytest

from photax.compare import compare_models
from photax.scene import relief_scene, texture

NOISE = 0.3  # px, per coordinate


@pytest.fixture(scope="module")
def hills():
    return relief_scene(300.0, tilt_deg=0.0, noise_px=NOISE, seed=0)


@pytest.fixture(scope="module")
def hills_cmp(hills):
    s = hills
    return compare_models(
        s.gcp_ground, s.gcp_pixel, s.camera, s.dem, check_ground=s.check_ground, check_pixel=s.check_pixel
    )


@pytest.fixture(scope="module")
def flat():
    return relief_scene(0.0, tilt_deg=2.0, noise_px=NOISE, seed=1)


def _nadir(scene):
    w, h = scene.camera.image_size
    return np.array([(w - 1) / 2, (h - 1) / 2])  # principal point = nadir for a vertical image


def test_scene_truth_is_consistent(hills, flat):
    s = hills
    # control points lie on the DEM, and the measured pixels carry the stated noise
    z = np.asarray(s.dem.height(s.gcp_ground[:, 0], s.gcp_ground[:, 1]))
    np.testing.assert_allclose(z, s.gcp_ground[:, 2], atol=1e-3)
    noise = np.concatenate([s.gcp_pixel - s.gcp_pixel_true, s.check_pixel - s.check_pixel_true]).ravel()
    assert 0.7 * NOISE < noise.std() < 1.3 * NOISE
    assert float(np.ptp(np.asarray(s.dem.heights))) == pytest.approx(300.0)
    assert float(np.ptp(np.asarray(flat.dem.heights))) == 0.0
    # the image shows the ground texture where each GCP's ray meets the ground
    px = np.rint(s.gcp_pixel_true).astype(int)
    grey = s.image[px[:, 1], px[:, 0]]
    # the GCPs are not at integer pixels: compare with the texture at the
    # rounded pixel's own ground point, i.e. allow for ~0.5 px of texture slope
    truth = np.asarray(texture(s.gcp_ground[:, 0] - 500_000.0, s.gcp_ground[:, 1] - 4_000_000.0))
    assert np.median(np.abs(grey - truth)) < 0.05


def test_relief_displacement_is_r_h_over_H(hills):
    """Collinearity with the DEM minus collinearity on the datum = r h / H, radially outwards."""
    s = hills
    c = compare_models(
        s.gcp_ground, s.gcp_pixel_true, s.camera, s.dem, exterior=s.exterior, orders=(1,), projective=False
    )
    d = c.relief_displacement(datum=0.0)
    xy = c.grid.xy()
    h = np.asarray(s.dem.height(xy[..., 0], xy[..., 1]))
    p = np.asarray(c["collinearity"].model(xy))  # displaced image position
    radial = p - _nadir(s)[None, None, :]
    r = np.linalg.norm(radial, axis=-1)
    inside = np.isfinite(c["collinearity"].error[..., 0])
    assert inside.mean() > 0.9
    expected = r * h / s.flying_height
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1)[inside], expected[inside], atol=1e-8)
    # direction: away from the nadir for points above the datum
    cos = np.sum(d * radial, axis=-1) / np.maximum(np.linalg.norm(d, axis=-1) * r, 1e-12)
    assert np.all(cos[inside & (expected > 0.5)] > 1 - 1e-9)
    assert expected[inside].max() > 40  # strong relief: tens of pixels


def test_affine_error_is_the_unabsorbed_relief_displacement(hills):
    """Order-1 check residuals = d(check) - (affine LS fit of d at the GCPs)(check), exactly."""
    s = hills
    c = compare_models(
        s.gcp_ground,
        s.gcp_pixel_true,
        s.camera,
        s.dem,
        exterior=s.exterior,
        check_ground=s.check_ground,
        check_pixel=s.check_pixel_true,
        orders=(1,),
        projective=False,
    )
    H, nadir = s.flying_height, _nadir(s)
    d_gcp = (s.gcp_pixel_true - nadir) * s.gcp_ground[:, 2:3] / H
    d_chk = (s.check_pixel_true - nadir) * s.check_ground[:, 2:3] / H
    design = lambda g: np.column_stack([np.ones(len(g)), g[:, :2] - s.gcp_ground[:, :2].mean(0)])  # noqa: E731
    coef, *_ = np.linalg.lstsq(design(s.gcp_ground), d_gcp, rcond=None)
    expected = d_chk - design(s.check_ground) @ coef
    np.testing.assert_allclose(c["polynomial 1"].check_residuals, -expected, atol=1e-6)  # computed - observed
    np.testing.assert_allclose(c["collinearity"].check_residuals, 0.0, atol=1e-6)
    assert np.sqrt(np.mean(np.sum(expected**2, 1))) > 3  # several pixels


def test_polynomials_cannot_follow_relief(hills, hills_cmp):
    c = hills_cmp
    coll = c["collinearity"]
    # collinearity: residuals are the measurement noise (radial RMS sqrt(2) sigma)
    assert coll.gcp_rmse < 1.5 * np.sqrt(2) * NOISE
    assert coll.check_rmse < 1.5 * np.sqrt(2) * NOISE
    np.testing.assert_allclose(c.exterior.position, hills.exterior.position, atol=5.0)
    polys = [c[f"polynomial {k}"] for k in range(1, 6)]
    gcp = np.array([m.gcp_rmse for m in polys])
    chk = np.array([m.check_rmse for m in polys])
    # nested least squares: more terms never fit the GCPs worse ...
    assert np.all(np.diff(gcp) < 0)
    # ... but the check points stay several pixels off at every order
    assert chk.min() > 10 * coll.check_rmse and chk.min() > 3.0
    # and the highest order overfits: GCPs fit best, check points get worse
    assert chk[4] > chk.min() * 1.3 and chk[4] > 3 * gcp[4]
    # the error maps are of the size of the relief displacement (r h / H, up to ~50 px here)
    d = np.linalg.norm(c.relief_displacement(), axis=-1)
    d_rms = np.sqrt(np.nanmean(d[np.isfinite(coll.error[..., 0])] ** 2))
    for m in polys:
        assert 0.1 * d_rms < m.error_rmse < 1.5 * d_rms
    # error_rms is the old name of error_rmse (docs/conventions.md, "Words"): kept, with a warning
    warning = "ModelResult.error_rms is deprecated: use ModelResult.error_rmse"
    with pytest.warns(DeprecationWarning, match=warning):
        assert polys[0].error_rms == polys[0].error_rmse
    # mean GSD = (H - mean terrain height) / f
    assert c.gsd == pytest.approx((hills.flying_height - float(np.mean(hills.dem.heights))) / 1000, rel=0.03)


def test_flat_terrain_models_agree(flat):
    s = flat
    c = compare_models(
        s.gcp_ground,
        s.gcp_pixel,
        s.camera,
        s.dem,
        check_ground=s.check_ground,
        check_pixel=s.check_pixel,
        orders=(1, 2, 3),
    )
    coll = c["collinearity"].check_rmse
    assert coll < 1.5 * np.sqrt(2) * NOISE
    # a plane maps projectively: the projective model is collinearity here
    assert c["projective"].check_rmse == pytest.approx(coll, abs=0.1)
    assert c["projective"].error_rmse < 0.5
    # a 2-degree tilt is nearly affine; order 2 absorbs what is left
    for k in (2, 3):
        assert c[f"polynomial {k}"].check_rmse == pytest.approx(coll, abs=0.15)
    assert c["polynomial 1"].check_rmse > c["polynomial 2"].check_rmse


def test_report_and_dict(hills_cmp):
    c = hills_cmp
    text = c.table()
    for name in ["collinearity", "polynomial 1", "polynomial 5", "projective"]:
        assert f"| {name} |" in text
    d = json.loads(json.dumps(c.to_dict()))
    assert [m["name"] for m in d["models"]] == c.names
    poly5 = d["models"][c.names.index("polynomial 5")]
    used = 30 - int(c.resection.outliers.sum())  # the resection's rejected points are in no fit
    assert poly5["n_params"] == 42 and poly5["redundancy"] == 2 * used - 42
    assert d["excluded"] == np.flatnonzero(c.resection.outliers).tolist()


def test_a_blunder_rejected_by_the_resection_is_in_no_fit(hills):
    """A 25 px blunder on one GCP: the resection rejects it, and every polynomial is then the one
    fitted without that point (so the models compare on the same points); its GCP RMSE leaves it out."""
    from photax.polynomial import fit_polynomial

    s = hills
    px = s.gcp_pixel.copy()
    px[7] += [25.0, -10.0]
    c = compare_models(
        s.gcp_ground, px, s.camera, s.dem, orders=(2,), projective=False, gcp_names=[f"G{k}" for k in range(len(px))]
    )
    assert c.excluded[7] and c.excluded.tolist() == np.asarray(c.resection.outliers).tolist()
    keep = ~c.excluded
    ref = fit_polynomial(s.gcp_ground[keep, :2], px[keep], 2)
    p2 = c["polynomial 2"]
    np.testing.assert_allclose(
        np.asarray(p2.model(s.gcp_ground[:, :2])), np.asarray(ref(s.gcp_ground[:, :2])), atol=1e-9
    )
    np.testing.assert_allclose(p2.gcp_rmse, np.sqrt(np.mean(np.sum(p2.gcp_residuals[keep] ** 2, axis=1))))
    assert np.linalg.norm(p2.gcp_residuals[7]) > 15  # the blunder shows in its residual
    note = [line for line in c.table("text").splitlines() if "left out of every fit" in line]
    assert c["collinearity"].gcp_rmse < 3 * NOISE and len(note) == 1 and " G7" in note[0].replace(",", " ")


def test_figures(hills, hills_cmp):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = hills_cmp
    fig = c.plot_error_maps()
    panels = [ax.get_title().split("\n")[0] for ax in fig.axes if ax.images and ax.get_title()]
    assert panels == [n for n in c.names if n != "collinearity"]  # eight maps (and one shared colour bar)
    plt.close(fig)
    plt.close(c.plot_rmse())
    images, grid = c.rectify(hills.image, ["collinearity", "polynomial 1"])
    # the orthophoto reproduces the ground texture; the polynomial one does not
    xy = grid.xy()
    truth = np.asarray(texture(xy[..., 0] - 500_000.0, xy[..., 1] - 4_000_000.0))
    err = {k: np.nanmean(np.abs(v - truth)) for k, v in images.items()}
    assert err["collinearity"] < 0.5 * err["polynomial 1"]
    plt.close(c.plot_rectified(images, grid, reference=hills.ortho, reference_transform=hills.ortho_transform))


def test_thin_plate_spline_and_piecewise_affine_beside_the_polynomials(hills_cmp):
    """Their rows in the table, and their check-point errors equal to peers' fits on the same GCPs:
    scipy's thin-plate RBF (degree 1) and scikit-image's PiecewiseAffineTransform."""
    from scipy.interpolate import RBFInterpolator
    from scipy.spatial import Delaunay

    c = hills_cmp
    assert c.names[-2:] == ["thin-plate spline", "piecewise affine"]
    used = ~c.excluded
    gg, gp = c.gcp_ground[used, :2], c.gcp_pixel[used]
    origin = gg.mean(0)
    cg, cp = c.check_ground[:, :2] - origin, c.check_pixel
    tps = RBFInterpolator(gg - origin, gp, kernel="thin_plate_spline", degree=1)(cg) - cp
    np.testing.assert_allclose(c["thin-plate spline"].check_residuals, tps, atol=1e-6)
    assert c["thin-plate spline"].check_rmse == pytest.approx(np.sqrt(np.mean(np.sum(tps**2, 1))), abs=1e-6)
    skt = pytest.importorskip("skimage.transform")
    pwa = skt.PiecewiseAffineTransform.from_estimate(gg - origin, gp)
    inside = Delaunay(gg - origin).find_simplex(cg) >= 0  # outside the hull scikit-image gives no value
    assert inside.sum() >= 0.5 * len(cg)
    got = c["piecewise affine"].check_residuals[inside]
    np.testing.assert_allclose(got, pwa(cg[inside]) - cp[inside], atol=1e-9)
    for name in ("thin-plate spline", "piecewise affine"):
        m = c[name]
        assert m.gcp_rmse < 1e-6 and m.redundancy == 0 and m.n_params == 2 * used.sum()
        assert f"| {name} | {m.n_params} | 0 |" in c.table() and f"{m.check_rmse:.3f}" in c.table()
        assert name in [d["name"] for d in c.to_dict()["models"]]


def test_skips_orders_without_enough_gcps(hills):
    s = hills
    c = compare_models(
        s.gcp_ground[:12], s.gcp_pixel[:12], s.camera, s.dem, exterior=s.exterior, orders=(1, 4, 5), projective=False
    )
    assert c.names == ["collinearity", "polynomial 1", "thin-plate spline", "piecewise affine"]
    assert "needs at least 15 GCPs, have 12" in c.skipped["polynomial 4"]
    assert "polynomial 5" in c.table()


def test_bad_input_is_rejected(hills):
    s = hills
    args = (s.gcp_ground, s.gcp_pixel, s.camera, s.dem)
    with pytest.raises(ValueError, match="gcp_pixel"):
        compare_models(s.gcp_ground, s.gcp_pixel[:-1], s.camera, s.dem)
    with pytest.raises(ValueError, match="gcp_ground"):
        compare_models(s.gcp_ground[:, :2], s.gcp_pixel, s.camera, s.dem)
    with pytest.raises(ValueError, match="check_pixel"):
        compare_models(*args, check_ground=s.check_ground)
    with pytest.raises(ValueError, match="orders"):
        compare_models(*args, orders=(6,))
    bad = s.gcp_pixel.copy()
    bad[3, 0] = np.nan
    with pytest.raises(ValueError, match="rows \\[3\\]"):
        compare_models(s.gcp_ground, bad, s.camera, s.dem)
    import photax as ptx

    with pytest.raises(ValueError, match="image_size"):
        compare_models(*args[:2], ptx.FrameCamera(1000.0), s.dem)
    with pytest.raises(ValueError, match="relief"):
        relief_scene(-1.0)


def test_cli_compare(hills, tmp_path, capsys):
    from photax.cli import main
    from photax.io.camera_file import write_camera
    from photax.io.raster import write_geotiff

    s = hills
    rows = ["name,E,N,h,col,row,role"]
    for role, g, p in (("control", s.gcp_ground, s.gcp_pixel), ("check", s.check_ground, s.check_pixel)):
        rows += [
            f"{role[:2]}{k},{x:.17g},{y:.17g},{z:.17g},{c:.17g},{r:.17g},{role}"
            for k, ((x, y, z), (c, r)) in enumerate(zip(g, p))
        ]
    (tmp_path / "gcps.csv").write_text("\n".join(rows) + "\n")
    write_camera(s.camera, tmp_path / "camera.yaml")
    write_geotiff(tmp_path / "dem.tif", np.asarray(s.dem.heights), tuple(np.asarray(s.dem.transform)))
    write_geotiff(tmp_path / "image.tif", (s.image * 255).astype(np.uint8), None)
    out = tmp_path / "out"
    files = [str(tmp_path / "gcps.csv"), "--camera", str(tmp_path / "camera.yaml"), "--dem", str(tmp_path / "dem.tif")]
    assert (
        main(
            [
                "compare",
                *files,
                "--image",
                str(tmp_path / "image.tif"),
                "--orders",
                "1-2",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "polynomial 2" in printed and "polynomial 3" not in printed
    for name in ["comparison.md", "comparison.json", "error_maps.png", "rmse.png", "rectified.png"]:
        assert (out / name).stat().st_size > 0
    d = json.loads((out / "comparison.json").read_text())
    assert d["n_gcp"] == 30 and d["n_check"] == 60
    assert d["models"][0]["check_rmse_px"] < 1.0
    with pytest.raises(SystemExit):
        main(["compare", *files, "--orders", "0-7"])
    assert "orders must lie in 1..5" in capsys.readouterr().err
    assert main(["compare", *files, "--out", str(tmp_path / "dem.tif")]) == 2  # a file, not a folder


def test_demo_section(tmp_path):
    from photax.demo import SECTIONS, rectification_section

    assert rectification_section in SECTIONS
    md = rectification_section(tmp_path)
    assert "| polynomial 5 |" in md and "overfitting" in md
    for name in ["comparison.json", "comparison_error_maps.png", "comparison_rmse.png", "comparison_rectified.png"]:
        assert (tmp_path / name).stat().st_size > 0
        assert f"({name})" in md or name.endswith(".json")
