"""Registration of a rendered image to the scene's exact orthophoto (photax.matching.registration).

Truth: the rendering orientation; the reference orthophoto is the ground
texture sampled on a ground grid (what a perfect orthophoto shows).  The
check is the reprojection error of ground points between the refined and
the true orientation, in pixels.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import photax
from photax.matching.registration import register_to_ortho
from photax.scene import detailed_texture, render_image

X0, Y0 = 500_000.0, 4_000_000.0
CAM = photax.FrameCamera.from_pixels(300.0, (200, 160))
TRUE = photax.ExteriorOrientation([X0 - 30, Y0, 320.0], np.radians([0.5, -0.3, 1.0]))


@pytest.fixture(scope="module")
def scene():
    n, cell = 300, 2.0
    c = -300 + cell * (np.arange(n) + 0.5)
    h = 20 + 15 * np.exp(-((c[None, :] - 40) ** 2 + (c[:, None] + 30) ** 2) / (2 * 90.0**2)) + 0.02 * c[None, :]
    dem = photax.DEM(h, (cell, 0.0, X0 - 300, 0.0, -cell, Y0 + 300))
    image = render_image(CAM, TRUE, dem, origin=(X0, Y0), supersample=3, blur=0.5, noise=0.005, seed=1)
    k = 160  # a 160 m ortho at 1 m inside the footprint
    ox = -110 + (np.arange(k) + 0.5)
    oy = 80 - (np.arange(k) + 0.5)
    ortho = np.asarray(detailed_texture(jnp.asarray(ox)[None, :], jnp.asarray(oy)[:, None]))
    transform = (1.0, 0.0, X0 - 110, 0.0, -1.0, Y0 + 80)
    rng = np.random.default_rng(0)
    g = np.column_stack([rng.uniform(X0 - 100, X0 + 40, 100), rng.uniform(Y0 - 70, Y0 + 70, 100)])
    g = np.column_stack([g, np.asarray(dem.height(jnp.asarray(g[:, 0]), jnp.asarray(g[:, 1])))])
    return dem, image, ortho, transform, g


def _px(e, g):
    return np.asarray(CAM.image_to_pixel(photax.project(g, e, CAM)))


def test_from_5_m_and_0_2_degrees_to_a_tenth_of_a_pixel(scene):
    dem, image, ortho, transform, g = scene
    start = photax.ExteriorOrientation(
        np.asarray(TRUE.position) + [4.0, -3.0, 0.0], np.asarray(TRUE.angles) + np.radians([0.2, -0.15, 0.1])
    )
    before = np.sqrt(np.mean(np.sum((_px(start, g) - _px(TRUE, g)) ** 2, 1)))
    assert before > 4.0  # px: a real starting error
    res = register_to_ortho(image, CAM, start, ortho, transform, dem, levels=(4, 2, 1))
    assert res.converged and res.result == photax.RESULTS.successful, res.message
    # rmse per level, the finest the history's last (its last step moved < 1e-3 px); rms is its old
    # name, kept with a DeprecationWarning
    assert len(res.rmse) == 3 and res.rmse[-1] == pytest.approx(res.history[-1]["rmse"], rel=1e-3)
    with pytest.warns(DeprecationWarning, match="Registration.rms is deprecated"):
        assert res.rms == res.rmse
    after = np.sqrt(np.mean(np.sum((_px(res.exterior, g) - _px(TRUE, g)) ** 2, 1)))
    assert after <= 0.1, after
    # the history: one entry per step, levels coarse to fine, the last step below the tolerance
    assert len(res.history) == sum(res.steps) and [h["level"] for h in res.history] == sorted(
        (h["level"] for h in res.history), reverse=True
    )
    assert res.history[-1]["shift_px"] < 1e-3 < res.history[0]["shift_px"]


def test_too_far_off_raises_or_is_reported(scene):
    """One estimate: a failure raises ConvergenceError by default (docs/architecture.md, "Outcomes and
    throw"); with throw=False it comes back with its RESULTS code and the code's words."""
    dem, image, ortho, transform, _ = scene
    start = photax.ExteriorOrientation(np.asarray(TRUE.position) + [60.0, 40.0, 0.0], TRUE.angles)
    with pytest.raises(photax.ConvergenceError, match="registration failed"):
        register_to_ortho(image, CAM, start, ortho, transform, dem, levels=(4, 2, 1), max_steps=8)
    res = register_to_ortho(image, CAM, start, ortho, transform, dem, levels=(4, 2, 1), max_steps=8, throw=False)
    assert not res.converged and res.result != photax.RESULTS.successful
    assert res.message.startswith(res.result.text) and np.all(np.isfinite(res.exterior.position))
    # an orientation 10 km away sees nothing of the reference: said so, not a wrong orientation
    far = photax.ExteriorOrientation(np.asarray(TRUE.position) + [10_000.0, 0.0, 0.0], TRUE.angles)
    res = register_to_ortho(image, CAM, far, ortho, transform, dem, levels=(4, 2, 1), max_steps=8, throw=False)
    assert not res.converged and "sees (almost) nothing" in res.message, res.message
    assert res.result == photax.RESULTS.implausible
    # method= is the old name of resampling=: the same answer, with a DeprecationWarning
    with pytest.warns(DeprecationWarning, match=r"register_to_ortho\(method=\) is deprecated"):
        old = register_to_ortho(
            image, CAM, far, ortho, transform, dem, levels=(4, 2, 1), max_steps=8, throw=False, method="nearest"
        )
    new = register_to_ortho(
        image, CAM, far, ortho, transform, dem, levels=(4, 2, 1), max_steps=8, throw=False, resampling="nearest"
    )
    np.testing.assert_array_equal(old.exterior.position, new.exterior.position)
    with pytest.raises(ValueError, match="give resampling= only"):
        register_to_ortho(image, CAM, far, ortho, transform, dem, method="nearest", resampling="cubic")


def test_cli_register(scene, tmp_path):
    """``photax register`` in process on the same scene and shapes: exit 0 and the refined orientation
    written (checked against the truth like the library's), exit 1 with status "not converged" from
    too far off (the JSON still written), exit 2 for bad input."""
    pytest.importorskip("rasterio")
    from photax.cli import main
    from photax.io import read_exterior, write_geotiff

    dem, image, ortho, transform, g = scene
    paths = {k: tmp_path / f"{k}.tif" for k in ("image", "ortho", "dem")}
    write_geotiff(paths["image"], image, (0.5, 0.0, 0.0, 0.0, -0.5, 100.0), compress=None)  # not used
    write_geotiff(paths["ortho"], ortho, transform, crs="EPSG:32633", compress=None)
    write_geotiff(
        paths["dem"], np.asarray(dem.heights), np.asarray(dem.transform).tolist(), crs="EPSG:32633", compress=None
    )
    photax.write_camera(CAM, tmp_path / "cam.yaml")
    common = [
        str(paths["image"]),
        "--camera",
        str(tmp_path / "cam.yaml"),
        "--ortho",
        str(paths["ortho"]),
        "--dem",
        str(paths["dem"]),
        "--levels",
        "4,2,1",
    ]
    for name, offset, max_steps, code in (
        ("near", ([4.0, -3.0, 0.0], [0.2, -0.15, 0.1]), 15, 0),
        ("far", ([60.0, 40.0, 0.0], [0.0, 0.0, 0.0]), 8, 1),
    ):
        start = photax.ExteriorOrientation(
            np.asarray(TRUE.position) + offset[0], np.asarray(TRUE.angles) + np.radians(offset[1])
        )
        photax.write_json(
            {"exterior": {"position": start.position, "angles_rad": start.angles, "convention": start.convention}},
            tmp_path / f"{name}.json",
        )
        out = tmp_path / f"{name}_out.json"
        assert (
            main(
                [
                    "register",
                    *common,
                    "--exterior",
                    str(tmp_path / f"{name}.json"),
                    "--max-steps",
                    str(max_steps),
                    "-o",
                    str(out),
                ]
            )
            == code
        )
        data = photax.read_json(out)
        assert data["status"] == ("solved" if code == 0 else "not converged") and data["message"]
        assert (data["result"] == "successful") == (code == 0) and len(data["rmse"]) == len(data["steps"])
        if code == 0:
            refined, _ = read_exterior(out, paths["image"])  # the output is an --exterior input of other commands
            after = np.sqrt(np.mean(np.sum((_px(refined, g) - _px(TRUE, g)) ** 2, 1)))
            assert after <= 0.1, after
    # bad input: the output over an input, a missing file, nonsense levels
    assert main(["register", *common, "--exterior", str(tmp_path / "near.json"), "-o", str(paths["ortho"])]) == 2
    assert main(["register", *common, "--exterior", str(tmp_path / "none.json"), "-o", str(tmp_path / "x.json")]) == 2
    assert (
        main(
            ["register", *common[:-1], "4,x", "--exterior", str(tmp_path / "near.json"), "-o", str(tmp_path / "x.json")]
        )
        == 2
    )
    assert not (tmp_path / "x.json").exists()
