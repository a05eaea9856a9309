"""Resection inputs that do not fit together must fail, in photax's words.

Synthetic scenes with known truth, and the sample of ``data/`` (12 control
points, one 15 px blunder), corrupted the way users corrupt GCP files:
swapped columns, mirrored axes, wrong units, GCPs of another image.
All cameras here have the 4000 x 3000 pixel grid of the scene in
``test_resection._pixel_scene`` and 12 or 16 points, so they share its
compiled solver (resection compiles once per camera grid and point bucket).
"""

import pathlib
import re

import numpy as np
import pytest

import photax as ptx
from photax import resection
from photax.io.camera_file import read_camera
from photax.io.gcp import read_gcps

ROOT = pathlib.Path(__file__).resolve().parents[1]
ORIGIN = np.array([512_000.0, 4_321_000.0, 0.0])
# Texts of the dependencies' own messages: never shown to a photax user.
DEPENDENCY_WORDS = ("lineax", "well_posed", "optimistix", "equinox", "AutoLinearSolver", "max_steps`", "operator")


def _scene(seed, relief=30.0, n=12):
    """A 3000 px camera 900 m above ground, 12 GCPs with 0.5 px noise: (camera, truth, ground, image)."""
    rng = np.random.default_rng(seed)
    cam = ptx.FrameCamera.from_pixels(3000.0, (4000, 3000))
    eo = ptx.ExteriorOrientation(ORIGIN + [30.0, -40.0, 900.0], [0.05, -0.04, 2.2])
    px = np.column_stack([rng.uniform(200, 3800, n), rng.uniform(200, 2800, n)])
    ground = np.asarray(ptx.image_to_ground(cam.pixel_to_image(px), eo, cam, height=100.0 + rng.uniform(0, relief, n)))
    xy = np.asarray(ptx.project(ground, eo, cam)) + rng.normal(0.0, 0.5, (n, 2))
    return cam, eo, ground, xy


def _no_dependency_text(text):
    assert not any(w.lower() in str(text).lower() for w in DEPENDENCY_WORDS), text


def _fails(res, *words):
    assert not res.converged, res.message
    for w in words:
        assert w in res.message, (w, res.message)
    _no_dependency_text(res.message)
    values = np.concatenate([np.ravel(res.exterior.position), np.ravel(res.exterior.angles), np.ravel(res.residuals)])
    assert np.all(np.isfinite(values))  # flagged, not NaN


@pytest.fixture(scope="module")
def sample():
    table = read_gcps(ROOT / "data" / "sample_gcps.csv")
    camera = read_camera(ROOT / "data" / "sample_camera.yaml")
    return table, camera


def _resect_sample(table, camera, pixel=None, ground=None, throw=False):
    pixel = table.pixel if pixel is None else pixel
    ground = table.ground if ground is None else ground
    return ptx.resect(
        np.asarray(camera.pixel_to_image(pixel)),
        ground,
        camera,
        sigma=table.image_plane_sigma(camera),
        check=table.check,
        names=table.names,
        throw=throw,
    )


@pytest.fixture(scope="module")
def sample_result(sample):
    return _resect_sample(*sample)


def test_sample_still_succeeds_with_its_blunder(sample_result):
    res = sample_result
    assert res.converged, res.message
    assert [str(n) for n in np.asarray(res.names)[res.outliers]] == ["P07"]  # the sample's one 15 px blunder
    assert res.rmse / res.pixel_size < 1.0


def test_sample_with_column_and_row_swapped_fails(sample):
    # before: "converged", camera 320 m below the ground, 8 of 12 control points excluded
    table, camera = sample
    res = _resect_sample(table, camera, pixel=table.pixel[:, ::-1])
    _fails(res, "column and row", "fit if the image column and row are swapped (then rmse 0.")
    with pytest.raises(ptx.ConvergenceError, match="column and row") as info:
        _resect_sample(table, camera, pixel=table.pixel[:, ::-1], throw=True)
    _no_dependency_text(info.value)


def test_sample_with_east_and_north_swapped_fails_in_photax_words(sample):
    # before: lineax's advice about AutoLinearSolver(well_posed=False)
    table, camera = sample
    ground = table.ground[:, [1, 0, 2]]
    res = _resect_sample(table, camera, ground=ground)
    # near-nadir: an image y reversal is the same as a ground reflection, so both fit; the swap is named
    _fails(res, "swapped or mirrored axes", "fit if", "the ground E and N (X and Y) are swapped (then rmse 0.")
    with pytest.raises(ptx.ConvergenceError) as info:
        _resect_sample(table, camera, ground=ground, throw=True)
    _no_dependency_text(info.value)
    assert "NOT CONVERGED" in res.summary()


@pytest.mark.parametrize("mirror", ["east-north", "image x-y", "image x"])
def test_mirrored_planar_scene_is_not_an_answer(mirror):
    # A mirrored planar scene is fitted exactly by the mirrored camera below the
    # ground looking up: a perfect fit, but not the camera that took the image.
    cam, eo, ground, xy = _scene(31, relief=0.0)
    if mirror == "east-north":
        ground = ground[:, [1, 0, 2]]
    elif mirror == "image x-y":
        xy = xy[:, ::-1]
    else:
        xy = xy * [-1.0, 1.0]
    res = ptx.resect(xy, ground, cam, throw=False)
    _fails(res, "mirror image")
    assert np.asarray(res.exterior.position)[2] < ground[:, 2].min()  # what made it wrong: below the ground


def test_more_than_a_third_excluded_is_a_failure():
    cam, eo, ground, xy = _scene(32)
    bad = xy.copy()
    rng = np.random.default_rng(5)
    bad[:5] += rng.choice([-1.0, 1.0], (5, 2)) * rng.uniform(60.0, 200.0, (5, 2))  # 5 of 12 gross blunders
    res = ptx.resect(bad, ground, cam, sigma=0.5, throw=False)
    _fails(res, "had to be excluded")
    # 3 of 12 is still a result, the blunders named
    ok = xy.copy()
    ok[:3] = bad[:3]
    res = ptx.resect(ok, ground, cam, sigma=0.5, throw=False)
    assert res.converged and res.outliers.tolist() == [k < 3 for k in range(12)], res.message


def test_control_points_of_another_image_fail():
    cam, eo, ground, xy = _scene(33)
    _, _, _, other = _scene(34)  # the same camera, another image's measurements
    res = ptx.resect(other, ground, cam, throw=False)
    _fails(res)
    assert any(w in res.message for w in ("do not fit together", "did not converge")), res.message


def test_wrong_units_mm_camera_with_metre_coordinates():
    cam, eo, ground, xy = _scene(35)
    mm = ptx.FrameCamera(3000 * 0.0044, pixel_size=0.0044, image_size=(4000, 3000))  # the same camera in mm
    xy_mm = xy * 0.0044
    res = ptx.resect(xy_mm, ground, mm, throw=False)
    assert res.converged, res.message  # correct units: fine
    np.testing.assert_allclose(np.asarray(res.exterior.position), np.asarray(eo.position), atol=5.0)
    _fails(ptx.resect(xy_mm / 1000.0, ground, mm, throw=False), "wrong units")  # metres
    _fails(ptx.resect(xy, ground, mm, throw=False), "wrong units")  # pixels


def test_wrong_units_without_a_frame():
    # a camera in metres without a pixel grid, image coordinates in mm
    cam, eo, ground, xy = _scene(36)
    metres = ptx.FrameCamera(3000 * 4.4e-6)
    assert ptx.resect(xy * 4.4e-6, ground, metres, throw=False).converged
    _fails(ptx.resect(xy * 4.4e-3, ground, metres, throw=False), "wrong units")


def test_batch_gives_each_image_its_status():
    cam, eo, ground, xy = _scene(37)
    g = np.stack([ground] * 4)
    _, _, _, other = _scene(38)
    rng = np.random.default_rng(6)
    bad = xy.copy()
    bad[:5] += rng.choice([-1.0, 1.0], (5, 2)) * rng.uniform(60.0, 200.0, (5, 2))
    images = np.stack([xy, other, xy * [-1.0, 1.0], bad])
    res = ptx.resect_batch(images, g, cam, sigma=0.5)
    assert res.converged.tolist() == [True, False, False, False], res.message
    for i in range(1, 4):
        _fails(res[i])
    np.testing.assert_allclose(np.asarray(res[0].exterior.position), np.asarray(eo.position), atol=5.0)
    with pytest.raises(ptx.ConvergenceError, match="3 of 4 images") as info:
        ptx.resect_batch(images, g, cam, sigma=0.5, throw=True)
    _no_dependency_text(info.value)


def test_errors_inside_the_solver_are_reported_in_photax_words(monkeypatch):
    cam, eo, ground, xy = _scene(39)
    inner = RuntimeError("lineax: pass `solver=AutoLinearSolver(well_posed=False)` (equinox check failed)")

    def broken(*args, **kwargs):
        raise inner

    broken.prefetch = lambda *args: None  # the compiled solvers' interface (photax._aot.disk_cached)
    monkeypatch.setattr(resection._api, "_solve_cheap", broken)
    monkeypatch.setattr(resection._api, "_solve_robust", broken)
    monkeypatch.setattr(resection._api, "_solve_robust_batch", broken)
    for call in (
        lambda: ptx.resect(xy, ground, cam, throw=False),
        lambda: ptx.resect_batch(xy[None], ground[None], cam),
    ):
        with pytest.raises(ptx.ConvergenceError) as info:
            call()
        _no_dependency_text(info.value)
        assert info.value.__cause__ is inner


def test_optimistix_result_codes_all_have_photax_words():
    import optimistix as optx

    from photax.resection import _adjust, _api

    # every optimistix outcome (enumerated here through its private table: the code under test reads only
    # the public items) maps to a photax code with photax's words
    for name, item in optx.RESULTS._name_to_item.items():
        code = ptx.RESULTS(int(_adjust.from_optimistix(item)))
        assert (code == ptx.RESULTS.successful) == (name == "successful"), name
        converged, text = _api._message(int(code), 7, "gn")
        assert converged == (name == "successful")
        _no_dependency_text(text)
        assert "Gauss-Newton" in text and "7 steps" in text


def test_result_codes_next_to_messages(sample_result):
    assert sample_result.result == ptx.RESULTS.successful and sample_result.to_dict()["result"] == "successful"
    cam, eo, ground, xy = _scene(31, relief=0.0)
    mirrored = ptx.resect(xy * [-1.0, 1.0], ground, cam, throw=False)
    assert mirrored.result == ptx.RESULTS.implausible and not mirrored.converged
    batch = ptx.resect_batch(np.stack([xy, xy * [-1.0, 1.0]]), np.stack([ground] * 2), cam)
    assert batch.result.tolist() == [ptx.RESULTS.successful, ptx.RESULTS.implausible]
    assert batch[1].result == ptx.RESULTS.implausible


# ----------------------------------------------------------------------------- units in the report


def _row(text, start):
    return next(line for line in text.splitlines() if line.strip().startswith(start))


def test_summary_has_units_on_every_number(sample_result):
    res = sample_result  # mm camera with a pixel size, sigma given (Baarda's w: sigma0 unitless)
    text = res.summary(crs="EPSG:32633", camera_unit="mm")
    ps = float(np.mean(np.asarray(read_camera(ROOT / "data" / "sample_camera.yaml").pixel_size)))
    assert res.pixel_size == pytest.approx(ps)
    assert f"rmse = {res.rmse / ps:.3f} px ({res.rmse:.4g} mm)" in text
    assert f"check points: rmse = {res.check_rmse / ps:.3f} px ({res.check_rmse:.4g} mm)" in text
    x = _row(text, "X [m]").split()
    assert float(x[2]) == pytest.approx(float(res.exterior.X), abs=1e-4) and x[-1] == "m"
    assert float(x[3]) == pytest.approx(res.std[0], abs=1e-4)
    kappa = _row(text, "kappa [deg]").split()
    assert float(kappa[2]) == pytest.approx(np.degrees(float(res.exterior.kappa)), abs=1e-6)
    assert float(kappa[3]) == pytest.approx(np.degrees(res.std[5]) * 3600.0, abs=0.01) and kappa[-1] == '"'
    assert "vx [px]" in text and "vy [mm]" in text and "unitless" in text
    p07 = _row(text, "P07").split()  # residuals in pixels, then mm
    k = list(res.names).index("P07")
    np.testing.assert_allclose([float(v) for v in p07[2:4]], res.residuals[k] / ps, atol=1e-3)
    np.testing.assert_allclose([float(v) for v in p07[4:6]], res.residuals[k], rtol=1e-3)
    # the CRS's unit replaces metres when it is known
    feet = res.summary(crs="EPSG:2263")
    assert "X [US ft]" in feet and "mm" not in feet and "image-plane units" in feet
    assert "X [ft]" in res.summary(ground_unit="ft")


def test_summary_residual_table_columns_are_separated_and_aligned(sample_result):
    """Issue 26: without camera_unit the header read ``vy [px]vx [image-plane units]vy ...``. Every header
    cell stands apart (two spaces at least) and ends where its column's values end (right-aligned), or
    starts where they start (name and role)."""
    text = sample_result.summary()  # no camera_unit: the longest heads, "vx [image-plane units]"
    lines = text.splitlines()
    head = next(i for i, line in enumerate(lines) if line.strip().startswith("point"))
    heads = ["point", "role", "vx [px]", "vy [px]", "vx [image-plane units]", "vy [image-plane units]", "w_x", "w_y"]
    cells = [(m.start(), m.end()) for m in re.finditer(r"\S+(?: \S+)*", lines[head])]
    assert [lines[head][a:b] for a, b in cells] == heads
    rows = lines[head + 1 : head + 1 + len(sample_result.names)]
    for row, name in zip(rows, sample_result.names):
        spans = [(m.start(), m.end()) for m in re.finditer(r"\S+", row)]
        assert row[slice(*spans[0])] == name and len(spans) == len(heads)
        assert spans[0][0] == cells[0][0] and spans[1][0] == cells[1][0]  # left-aligned: same start
        assert [e for _, e in spans[2:]] == [e for _, e in cells[2:]]  # right-aligned: same end
    # the values are the residuals: the check that the columns hold what their heads say
    k = list(sample_result.names).index("P07")
    p07 = rows[k].split()
    np.testing.assert_allclose([float(v) for v in p07[4:6]], sample_result.residuals[k], rtol=1e-3)


def test_old_result_names_warn_and_give_the_new_values(sample_result):
    """rms, check_rms and normalized are the old names of rmse, check_rmse and normalised
    (docs/conventions.md, "Words"): still there, each with a DeprecationWarning."""
    res = sample_result
    assert res.rmse > 0 and res.check_rmse > 0
    for old, new in (("rms", "rmse"), ("check_rms", "check_rmse"), ("normalized", "normalised")):
        warning = f"ResectionResult.{old} is deprecated: use ResectionResult.{new}"
        with pytest.warns(DeprecationWarning, match=warning):
            value = getattr(res, old)
        np.testing.assert_array_equal(value, getattr(res, new))
    assert {"rmse", "check_rmse"} <= res.to_dict().keys() and "normalised" in res.to_dict()["points"][0]


def test_summary_units_pixels_and_no_grid():
    cam, eo, ground, xy = _scene(40)
    res = ptx.resect(xy, ground, cam)  # pixel camera, no sigma: Pope's tau, sigma0 in pixels
    text = res.summary()
    assert f"sigma0 = {res.sigma0:.3f} px" in text and f"rmse = {res.rmse:.3f} px" in text
    assert "vx [px]" in text and "X [m]" in text and "image-plane units" not in text
    metres = ptx.FrameCamera(3000 * 4.4e-6)  # no pixel grid: the camera's unit only
    res = ptx.resect(xy * 4.4e-6, ground, metres)
    text = res.summary(camera_unit="m")
    assert res.pixel_size is None and f"rmse = {res.rmse:.4g} m" in text
    assert "vx [m]" in text and "px" not in text


def test_residuals_are_computed_minus_observed(sample, sample_result):
    """docs/conventions.md: residual = computed - observed (here: the
    collinearity projection at the adjusted orientation minus the measurement)."""
    table, camera = sample
    res = sample_result
    computed = np.asarray(ptx.project(table.ground, res.exterior, camera))
    observed = np.asarray(camera.pixel_to_image(table.pixel))
    np.testing.assert_allclose(res.residuals, computed - observed, rtol=0, atol=1e-9 * float(camera.focal_length))
