"""Interior orientation from fiducial marks, on rendered scans with known geometry.

References: the scans' true film -> pixel mappings (written here, independent
of photax.interior), OpenCV's ``findHomography`` (least squares + LM on the
reprojection error) and scikit-image's affine / similarity estimates, and
the least-squares theory (sigma0^2 and the parameter covariance over seeded
noise trials).
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

import photax
from photax.interior import ScannedCamera, find_fiducials, interior_orientation
from photax.scene import fiducial_scan

# 8 marks of a 230 mm aerial frame: corners and mid-sides (film mm, y up).
FID = np.array([[-106, 106], [0, 110], [106, 106], [110, 0], [106, -106], [0, -110], [-106, -106], [-110, 0]], float)
PS = 0.5  # mm per scan pixel: a small scan keeps the test cheap
SIZE = (520, 500)
MARK = dict(mark_size=4.0, line_width=0.8)


def _affine(f):
    u, v = f[:, 0], -f[:, 1]
    th = np.radians(0.8)
    c = 257.0 + 1.002 * (np.cos(th) * u - np.sin(th) * v) / PS
    r = 246.0 + (np.sin(th) * u + np.cos(th) * v + 0.003 * u) / PS
    return np.column_stack([c, r])


def _bilinear(f):  # ~2.5 px of u v term at the corners
    u, v = f[:, 0], -f[:, 1]
    return _affine(f) + np.column_stack([2.5 * u * v / 110**2, -1.8 * u * v / 110**2])


def _projective(f):  # ~3 px of perspective at the corners
    u, v = f[:, 0], -f[:, 1]
    c0 = np.array([257.0, 246.0])
    return c0 + (_affine(f) - c0) / (1.0 + 1.2e-4 * u - 0.8e-4 * v)[:, None]


TRUTH = {"affine": _affine, "bilinear": _bilinear, "projective": _projective}


@pytest.fixture(scope="module")
def scans():
    """One clean scan per model, and one with mark 3 painted 5 px off."""
    out = {}
    for name, fn in TRUTH.items():
        out[name] = fiducial_scan(FID, fn, SIZE, **MARK, seed=1)
        out[name + "-displaced"] = fiducial_scan(FID, fn, SIZE, **MARK, seed=2, displaced={3: (3.0, -4.0)})
    return out


@pytest.mark.parametrize("model", ["affine", "bilinear", "projective"])
def test_marks_found_to_a_tenth_of_a_pixel(scans, model):
    img, truth = scans[model]
    res = find_fiducials(img, FID, pixel_size=PS, model=model, **MARK)
    assert not res.flagged.any(), res.messages
    err = res.xy - truth
    assert np.sqrt(np.mean(err**2)) <= 0.1
    # the fitted transformation reproduces the true geometry at the marks and between them
    assert np.sqrt(np.mean((res.orientation.pixel_from_film(FID) - truth) ** 2)) <= 0.1
    inner = np.array([[50.0, -30.0], [-70.0, 80.0], [0.0, 0.0]])
    assert np.max(np.abs(res.orientation.pixel_from_film(inner) - TRUTH[model](inner))) <= 0.15
    assert res.rmse < 0.1  # residuals of the fit, px (sigma0 is relative to the a-priori 0.1 px)


@pytest.mark.parametrize("model", ["affine", "bilinear", "projective"])
def test_displaced_mark_is_flagged_in_the_scan(scans, model):
    img, truth = scans[model + "-displaced"]
    res = find_fiducials(img, FID, pixel_size=PS, model=model, **MARK)
    assert np.flatnonzero(res.flagged).tolist() == [3]
    assert "calibrated pattern" in res.messages[3]
    ok = ~res.flagged
    assert np.sqrt(np.mean((res.xy[ok] - truth[ok]) ** 2)) <= 0.1


@pytest.mark.parametrize("model", ["similarity", "affine", "bilinear", "projective"])
def test_five_pixel_blunder_always_flagged(model):
    """Every mark, displaced by 5 px in 8 directions, on top of 0.02 px noise: flagged, and only it."""
    rng = np.random.default_rng(5)
    truth = TRUTH.get(model, _affine)(FID) if model != "similarity" else _similarity_truth(FID)
    for k in range(len(FID)):
        for a in np.radians(np.arange(0, 360, 45) + 10):
            px = truth + rng.normal(0, 0.02, truth.shape)
            px[k] += 5.0 * np.array([np.cos(a), np.sin(a)])
            io = interior_orientation(px, FID, model)
            assert np.flatnonzero(io.outliers).tolist() == [k], (k, np.degrees(a), io.message)


def _similarity_truth(f):
    th = np.radians(-1.3)
    u, v = f[:, 0], -f[:, 1]
    return np.column_stack([260 + (np.cos(th) * u - np.sin(th) * v) / PS, 250 + (np.sin(th) * u + np.cos(th) * v) / PS])


def test_fits_agree_with_opencv_and_scikit_image():
    cv2 = pytest.importorskip("cv2")
    transform = pytest.importorskip("skimage.transform")
    rng = np.random.default_rng(0)
    src = np.column_stack([FID[:, 0], -FID[:, 1]])  # (u, v): film with y down, like rows
    from scipy.optimize import least_squares

    def polish(apply, q0):  # the least-squares minimum of the reprojection error, from a peer's estimate
        return apply(least_squares(lambda q: (apply(q) - px).ravel(), q0, xtol=1e-15, ftol=1e-15, gtol=1e-15).x)

    hom = np.column_stack([src, np.ones(len(src))])
    for model, truth in [("similarity", _similarity_truth), ("affine", _affine), ("projective", _projective)]:
        px = truth(FID) + rng.normal(0, 0.3, FID.shape)
        fit = interior_orientation(px, FID, model, robust=False)
        ours = fit.pixel_from_film(FID)
        np.testing.assert_allclose(fit.residuals, ours - px, atol=1e-9)  # computed - observed, as everywhere
        if model == "projective":
            # OpenCV: linear + LM on the reprojection error (it stops at ~1e-4 px: polished by scipy)
            h, _ = cv2.findHomography(src, px, 0)

            def apply(q):  # numpy: cv2.perspectiveTransform rounds to float32 (~3e-5 px here)
                x = hom @ np.append(q, 1.0).reshape(3, 3).T
                return x[:, :2] / x[:, 2:]

            ref = polish(apply, (h / h[2, 2]).ravel()[:8])
        elif model == "affine":
            # scikit-image's affine estimate is a total-least-squares one (~1e-4 px off the minimum): polished
            est = transform.AffineTransform.from_estimate(src, px)
            assert est
            ref = polish(lambda q: hom @ q.reshape(2, 3).T, est.params[:2].ravel())
        else:  # Umeyama: the least-squares similarity, closed form
            est = transform.SimilarityTransform.from_estimate(src, px)
            assert est
            ref = est(src)
        np.testing.assert_allclose(ours, ref, atol=1e-7)


@pytest.mark.parametrize("model", ["affine", "projective"])
def test_sigma0_and_covariance_match_the_noise(model):
    """Seeded trials: E[sigma0^2] = sigma^2, and the spread of the parameters is the reported covariance."""
    rng = np.random.default_rng(11)
    truth = TRUTH[model](FID)
    s = 0.05
    runs = [interior_orientation(truth + rng.normal(0, s, truth.shape), FID, model, robust=False) for _ in range(200)]
    s02 = np.mean([r.sigma0**2 for r in runs])
    assert abs(s02 / s**2 - 1) < 0.15  # 200 x 10 (or 8) degrees of freedom: ~5 % standard error
    params = np.array([np.asarray(r.transform.params) for r in runs])
    cov = np.mean([r.covariance for r in runs], axis=0)
    emp = np.cov(params.T)
    d = np.sqrt(np.diag(cov))
    np.testing.assert_allclose(emp / np.outer(d, d), cov / np.outer(d, d), atol=0.2)
    np.testing.assert_allclose(np.sqrt(np.diag(emp)) / d, 1.0, atol=0.15)


def test_scanned_camera_in_resection_and_orthorectification():
    """Ground -> film (collinearity, mm camera) -> scan pixels (bilinear scanner): resect recovers the
    orientation through ScannedCamera, and the orthophoto's mapping lands on the true scan pixels."""
    from photax.rectification import OrthoModel

    rng = np.random.default_rng(3)
    film_cam = photax.FrameCamera(153.0, (0.01, -0.02))
    ext = photax.ExteriorOrientation([1000.0, 2000.0, 1500.0], np.radians([1.0, -2.0, 30.0]))
    ground = np.column_stack([rng.uniform(200, 1800, 12), rng.uniform(1200, 2800, 12), np.full(12, 40.0)])
    ground[:6, 2] += rng.uniform(0, 80, 6)
    io = interior_orientation(_bilinear(FID), FID, "bilinear")
    cam = io.camera(153.0, (0.01, -0.02), image_size=SIZE)
    assert isinstance(cam, ScannedCamera) and isinstance(cam, photax.FrameCamera)
    dem = photax.DEM(np.full((4, 4), 40.0), (1000.0, 0.0, -1000.0, 0.0, -1000.0, 4000.0))

    @jax.jit  # one compilation instead of one per eager operation
    def run(cam, ext, dem):
        film = photax.project(ground, ext, film_cam)
        pix = cam.image_to_pixel(film)
        return film, pix, cam.pixel_to_image(pix), OrthoModel(ext, cam, dem)(ground[6:, :2])

    film, pix, back, ortho = (np.asarray(a) for a in run(cam, ext, dem))
    np.testing.assert_allclose(pix, _bilinear(film), atol=1e-9)  # image_to_pixel is the fitted (exact) model
    np.testing.assert_allclose(back, film, atol=1e-9)  # pixel_to_image inverts it (Newton)
    np.testing.assert_allclose(ortho, _bilinear(film[6:]), atol=1e-9)  # the orthophoto reads the scan's pixels
    res = photax.resect(cam.pixel_to_image(_bilinear(film)), ground, cam)
    np.testing.assert_allclose(np.asarray(res.exterior.position), np.asarray(ext.position), atol=1e-5)


def test_bad_input():
    with pytest.raises(ValueError, match="model"):
        interior_orientation(_affine(FID), FID, "quadratic")
    with pytest.raises(ValueError, match="fiducial_xy"):
        interior_orientation(_affine(FID), FID[:5])
    with pytest.raises(ValueError, match="needs at least 4 marks"):
        interior_orientation(np.where(np.arange(8)[:, None] < 5, np.nan, _affine(FID)), FID, "projective")
    with pytest.raises(ValueError, match="pixel_size"):
        find_fiducials(np.zeros((50, 50)), FID)
    io = interior_orientation(_affine(FID[:4]), FID[:4], "projective")
    assert io.redundancy == 0 and "no redundancy" in io.message and not io.outliers.any()


def test_cli_fiducials(scans, tmp_path):
    pytest.importorskip("rasterio")
    import rasterio.transform

    from photax.cli import main

    img, truth = scans["affine-displaced"]
    tif = tmp_path / "scan.tif"
    with rasterio.open(
        tif,
        "w",
        driver="GTiff",
        width=img.shape[1],
        height=img.shape[0],
        count=1,
        dtype="float32",
        transform=rasterio.transform.from_origin(500000.0, 4100000.0, 0.5, 0.5),
    ) as dst:
        dst.write(img.astype(np.float32), 1)
    fid = tmp_path / "fiducials.csv"
    fid.write_text("name,x,y\n" + "".join(f"F{i + 1},{x},{y}\n" for i, (x, y) in enumerate(FID)))
    out, table = tmp_path / "io.json", tmp_path / "marks.csv"
    cal, cam_file = tmp_path / "calibrated.yaml", tmp_path / "scan_camera.yaml"
    cal.write_text("focal_length: 153.0\nunit: mm\nprincipal_point: [0.01, -0.02]\n")  # the calibration report
    code = main(
        [
            "fiducials",
            str(tif),
            "--fiducials",
            str(fid),
            "--pixel-size",
            str(PS),
            "--mark-size",
            "4",
            "--line-width",
            "0.8",
            "-o",
            str(out),
            "--csv",
            str(table),
            "--camera",
            str(cal),
            "--camera-out",
            str(cam_file),
        ]
    )
    assert code == 1  # a mark flagged
    data = photax.read_json(out)
    marks = {m["name"]: m for m in data["marks"]}
    assert not marks["F4"]["used"] and "calibrated pattern" in marks["F4"]["status"]
    got = np.array([[marks[f"F{i + 1}"]["col"], marks[f"F{i + 1}"]["row"]] for i in range(8) if i != 3])
    assert np.sqrt(np.mean((got - np.delete(truth, 3, axis=0)) ** 2)) <= 0.1
    assert table.read_text().count("\n") == 9
    # The scanned camera file: the same camera as find_fiducials' in memory, and photax resect through
    # it gives what photax.resect gives with the in-memory ScannedCamera (ground -> film with a 153 mm
    # camera -> scan pixels with the scanner's true mapping _affine).
    mem = find_fiducials(img.astype(np.float32), FID, pixel_size=PS, **MARK).orientation
    mem_cam = mem.camera(153.0, (0.01, -0.02), image_size=SIZE)
    file_cam = photax.read_camera(cam_file)
    assert isinstance(file_cam, ScannedCamera) and file_cam.image_size == SIZE
    np.testing.assert_array_equal(np.asarray(file_cam.transform.params), np.asarray(mem_cam.transform.params))
    rng = np.random.default_rng(3)
    ext = photax.ExteriorOrientation([1000.0, 2000.0, 1500.0], np.radians([1.0, -2.0, 30.0]))
    ground = np.column_stack([rng.uniform(200, 1800, 12), rng.uniform(1200, 2800, 12), rng.uniform(40, 120, 12)])
    pix = _affine(np.asarray(photax.project(ground, ext, photax.FrameCamera(153.0, (0.01, -0.02)))))
    gcps = tmp_path / "gcps.csv"
    gcps.write_text(
        "name,image,E,N,h,col,row,role\n"
        + "".join(
            f"P{i},scan,{','.join(map(repr, [*g.tolist(), *p.tolist()]))},control\n"
            for i, (g, p) in enumerate(zip(ground, pix))
        )
    )
    assert main(["resect", str(gcps), "--camera", str(cam_file), "--json", str(tmp_path / "r.json")]) == 0
    via_file = photax.read_json(tmp_path / "r.json")["images"]["scan"]
    ref = photax.resect(mem_cam.pixel_to_image(pix), ground, mem_cam)
    np.testing.assert_allclose(via_file["position"], np.asarray(ref.exterior.position), rtol=0, atol=1e-6)
    np.testing.assert_allclose(via_file["angles_rad"], np.asarray(ref.exterior.angles), rtol=0, atol=1e-9)
    np.testing.assert_allclose(via_file["position"], np.asarray(ext.position), atol=0.5)  # m: marks to ~0.01 px
    bad = tmp_path / "bad.csv"
    bad.write_text("name,x\nF1,3\n")
    assert (
        main(["fiducials", str(tif), "--fiducials", str(bad), "--pixel-size", "0.5", "-o", str(tmp_path / "x.json")])
        == 2
    )
    assert (
        main(
            [
                "fiducials",
                str(tif),
                "--fiducials",
                str(fid),
                "--pixel-size",
                "0.5",
                "-o",
                str(tmp_path / "x.json"),
                "--camera-out",
                str(tmp_path / "c.yaml"),
            ]
        )
        == 2
    )  # without --camera


def test_scanned_camera_file_round_trip(tmp_path):
    """A ScannedCamera written as a camera file (its 'scan' block) reads back as the same camera, to the bit."""
    from photax.io import read_camera, write_camera

    for model, fn in TRUTH.items():
        io = interior_orientation(fn(FID), FID, model)
        cam = io.camera(153.0, (0.01, -0.02), (-1e-5, 0.0, 0.0, 2e-6, 0.0), image_size=SIZE)
        path = write_camera(cam, tmp_path / f"{model}.yaml", unit="mm")
        assert "scan:" in path.read_text() and "pixel_size" not in path.read_text()  # derived from the scan
        back = read_camera(path)
        assert isinstance(back, ScannedCamera) and back.transform.model == model and back.image_size == SIZE
        for a, b in (
            (back.transform.params, cam.transform.params),
            (back.transform.film_centre, cam.transform.film_centre),
            (back.transform.film_scale, cam.transform.film_scale),
            (back.pixel_size, cam.pixel_size),
            (back.focal_length, cam.focal_length),
            (back.principal_point, cam.principal_point),
            (back.distortion, cam.distortion),
        ):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        # and the file's transformation is the scanner's (the fit is exact on noise-free marks)
        np.testing.assert_allclose(np.asarray(back.image_to_pixel(FID)), fn(FID), atol=1e-8)
    text = (tmp_path / "affine.yaml").read_text()
    for old, new, match in (
        ("unit: mm", "unit: px", "film units"),
        ("model: affine", "model: conformal", "scan.model"),
        ("scan:", "scan:\n  order: 2", "unknown key scan.order"),
        ("image_size:", "image_sizes:", "unknown key|image_size"),
    ):
        bad = tmp_path / "bad.yaml"
        bad.write_text(text.replace(old, new, 1))
        with pytest.raises(ValueError, match=match):
            read_camera(bad)


def test_bundle_self_calibration_keeps_the_scan_transform():
    """Self-calibration adjusts the camera inside the film and keeps the scanner's transformation.
    The block and start camera are test_bundle's self-calibration test's (same compiled shapes)."""
    from photax.scene import synthetic_block

    kw = dict(noise_px=0.0, relief=250.0, tilt_deg=8.0, distortion=(-0.04, 0.0, 0.0, 0.0, 0.0), n_control=8, n_tie=80)
    problem, truth = synthetic_block(5, **kw)
    io = interior_orientation(_affine(FID), FID, "affine")  # any transformation: the block is in image-plane units
    start = ScannedCamera(2950.0, transform=io.transform, image_size=(4000, 3000))
    res = photax.bundle_adjust(problem.replace(cameras=[start], free_intrinsics=("f", "k1")))
    cam = res.cameras[0]
    assert res.converged and isinstance(cam, ScannedCamera)
    assert cam.transform.model == "affine" and cam.image_size == start.image_size
    for a, b in (
        (cam.transform.params, io.transform.params),
        (cam.transform.film_centre, io.transform.film_centre),
        (cam.transform.film_scale, io.transform.film_scale),
        (cam.pixel_size, start.pixel_size),
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert abs(float(cam.focal_length) - float(truth.camera.focal_length)) < 1e-5
    assert abs(float(cam.distortion[0]) + 0.04) < 1e-9


def test_marks_not_found_get_a_status(scans):
    """A mark missing from the scan (painted over) is "not found" and left out; a blank scan is an error."""
    img, truth = scans["affine"]
    img = img.copy()
    c, r = np.round(truth[5]).astype(int)
    img[r - 14 : r + 15, c - 14 : c + 15] = np.median(img)  # mark 6 gone: film base only
    res = find_fiducials(img, FID, pixel_size=PS, **MARK)
    assert res.flagged.tolist() == [k == 5 for k in range(8)] and res.messages[5].startswith("not found"), res.messages
    assert np.sqrt(np.mean((res.xy[~res.flagged] - truth[~res.flagged]) ** 2)) <= 0.1
    with pytest.raises(ValueError, match="only 0 of 8 found"):
        find_fiducials(np.full_like(img, 0.15), FID, pixel_size=PS, **MARK)


def test_block_folder_reads_a_scanned_camera_file(tmp_path):
    """A block folder's camera given as {"file": ...}: its pixels go through the scan transformation
    (the observations equal ScannedCamera.pixel_to_image of the pixels, i.e. the scanner's film points)."""
    import json
    import shutil

    from photax.io import read_block, write_camera

    folder = tmp_path / "block"
    from conftest import ROOT

    shutil.copytree(ROOT / "data" / "block", folder, ignore=shutil.ignore_patterns("*.py"))
    io = interior_orientation(_affine(FID), FID, "affine")
    cam = io.camera(153.0, (0.01, -0.02), image_size=SIZE)
    write_camera(cam, folder / "scan.yaml", unit="mm")
    meta = json.loads((folder / "block.json").read_text())
    meta["cameras"] = {"cam": {"file": "scan.yaml", "free": ["f"]}}
    (folder / "block.json").write_text(json.dumps(meta))
    problem = read_block(folder)
    assert isinstance(problem.cameras[0], ScannedCamera) and problem.free_intrinsics[0].tolist()[:2] == [True, False]
    obs = np.loadtxt(folder / "observations.csv", delimiter=",", skiprows=1, usecols=(2, 3))
    back = _affine(np.asarray(problem.obs_xy))  # the scanner's true mapping takes them back to the pixels
    order = lambda a: a[np.lexsort(a.T)]  # noqa: E731
    np.testing.assert_allclose(order(back), order(obs), atol=1e-6)
    meta["cameras"] = {"cam": {"file": "scan.yaml", "focal_length_px": 3.0}}
    (folder / "block.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="unknown key 'focal_length_px'"):
        read_block(folder)
