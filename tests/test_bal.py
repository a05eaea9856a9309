"""BAL files: parsing, the BAL -> photax camera mapping, errors, writing.

References: the file text itself, the BAL projection written out in numpy
(with SciPy's Rodrigues), the SciPy Cookbook's published initial cost of
problem-49-7776, and GTSAM's check on dubrovnik-3-7.
"""

import bz2

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import shared_file
from scipy.spatial.transform import Rotation

import photax
from photax.io.bal import (
    BALData,
    bal_to_photax,
    photax_to_bal,
    read_bal,
    read_bal_arrays,
    write_bal,
    write_bal_arrays,
)


def bal_project(cameras, points, cam_idx, pt_idx):
    """BAL's projection, straight from the format's description."""
    c = cameras[cam_idx]
    P = Rotation.from_rotvec(c[:, :3]).apply(points[pt_idx]) + c[:, 3:6]
    p = -P[:, :2] / P[:, 2:3]
    r2 = np.sum(p * p, axis=1)
    return (c[:, 6] * (1.0 + c[:, 7] * r2 + c[:, 8] * r2 * r2))[:, None] * p


@jax.jit
def _project_each(xyz, exterior, camera):
    return jax.vmap(lambda x, eo, cam: photax.project(x[None, :], eo, cam)[0])(xyz, exterior, camera)


def photax_project(problem):
    """Observation-wise photax.project through the converted cameras and orientations."""
    cams = jax.tree.map(lambda *a: jnp.stack(a), *problem.cameras)
    per_obs = lambda tree, idx: jax.tree.map(lambda a: a[idx], tree)  # noqa: E731
    cam = per_obs(cams, jnp.asarray(problem.image_camera[problem.obs_image]))
    eo = per_obs(problem.exterior, jnp.asarray(problem.obs_image))
    return np.asarray(_project_each(jnp.asarray(problem.points[problem.obs_point]), eo, cam))


def test_dubrovnik_parse():
    path = shared_file("dubrovnik-3-7-pre.txt")
    d = read_bal_arrays(path)
    assert d.cameras.shape == (3, 9) and d.points.shape == (7, 3) and d.observations.shape == (19, 2)
    # First and last observation lines and the first camera, as in the file.
    assert (d.camera_index[0], d.point_index[0]) == (0, 0)
    np.testing.assert_array_equal(d.observations[0], [-3.859900e02, 3.871200e02])
    assert (d.camera_index[-1], d.point_index[-1]) == (2, 6)
    np.testing.assert_array_equal(d.observations[-1], [-5.841998e01, 1.108300e02])
    np.testing.assert_array_equal(
        d.cameras[0, :3], [-1.6943983532198115e-02, 1.1171804676513932e-02, 2.4643508831711991e-03]
    )
    assert d.cameras[0, 6] == 1.4300319432711681e03
    assert d.camera_index.dtype.kind == "i" and d.point_index.dtype.kind == "i"


def test_dubrovnik_gtsam_check():
    # GTSAM testSfmData.cpp: camera 0 projects track 0 within 12 px of its measurement.
    problem = read_bal(shared_file("dubrovnik-3-7-pre.txt"))
    sel = (problem.obs_image == 0) & (problem.obs_point == 0)
    xy = photax_project(problem)[sel]
    assert np.linalg.norm(xy - problem.obs_xy[sel]) < 12.0


def test_problem_49_counts_and_published_initial_cost():
    problem = read_bal(shared_file("problem-49-7776-pre.txt"))
    assert (problem.n_images, problem.n_points, problem.n_observations) == (49, 7776, 31843)
    assert problem.n_cameras == 49
    np.testing.assert_array_equal(problem.image_camera, np.arange(49))
    # Self-calibration as in BAL: f, k1, k2 free; x0, y0, k3, p1, p2 fixed.
    np.testing.assert_array_equal(problem.free_intrinsics[0], [1, 0, 0, 1, 1, 0, 0, 0])
    r = photax_project(problem) - problem.obs_xy
    cost = 0.5 * np.sum(r * r)
    # SciPy Cookbook, "Large-scale bundle adjustment in scipy": 8.5091e+05.
    assert abs(cost - 8.5091e05) <= 5.0


def test_projection_matches_bal_formula():
    path = shared_file("problem-49-7776-pre.txt")
    d = read_bal_arrays(path)
    problem = read_bal(path)
    ref = bal_project(d.cameras, d.points, d.camera_index, d.point_index)
    ours = photax_project(problem)
    assert np.max(np.abs(ours - ref)) < 1e-9 * max(1.0, np.max(np.abs(ref)))
    # Centres: C = -R^T t, written out with SciPy.
    centres = -Rotation.from_rotvec(d.cameras[:, :3]).inv().apply(d.cameras[:, 3:6])
    np.testing.assert_allclose(np.asarray(problem.exterior.position), centres, rtol=0, atol=1e-12)


def test_camera_round_trip():
    d = read_bal_arrays(shared_file("problem-49-7776-pre.txt"))
    cams, eo = bal_to_photax(d.cameras)
    back = photax_to_bal(cams, eo.rotation, eo.position)
    np.testing.assert_allclose(back, d.cameras, rtol=1e-12, atol=1e-13)


def _write(tmp_path, text, name="bad.txt"):
    path = tmp_path / name
    path.write_text(text)
    return path


GOOD = "2 2 3\n0 0 1.0 2.0\n1 0 3.0 4.0\n1 1 5.0 6.0\n" + "0.1\n" * 18 + "1 2 3\n4 5 -6\n"


@pytest.mark.parametrize(
    "text, line, words",
    [
        ("2 2\n", 1, "header"),
        ("2 x 3\n", 1, "header"),
        ("2 2 3\n0 0 1.0 2.0\n1 0 3.0\n1 1 5.0 6.0\n" + "0.1\n" * 18 + "1 2 3\n4 5 -6 7\n", 3, "4 fields"),
        (GOOD.replace("1 0 3.0 4.0", "1 0 3.0 abc"), 3, "'abc'"),
        (GOOD.replace("1 1 5.0 6.0", "2 1 5.0 6.0"), 4, "camera index"),
        (GOOD.replace("1 1 5.0 6.0", "1 -1 5.0 6.0"), 4, "point index"),
        (GOOD.replace("1 1 5.0 6.0", "1 0.5 5.0 6.0"), 4, "integer"),
        (GOOD.replace("4 5 -6\n", "4 5\n"), 24, "truncated"),
        (GOOD.replace("4 5 -6\n", "4 5 -6 7\n"), 24, "extra"),
        (GOOD.replace("1 2 3\n", "1 nan 3\n"), 23, "'nan'"),
        (GOOD.replace("0.1\n" * 18, "0.1\n" * 6 + "-5\n" + "0.1\n" * 11), 11, "focal length"),
        ("2 2 3\n0 0 1.0 2.0\n", 2, "truncated"),
    ],
)
def test_malformed_files_name_file_and_line(tmp_path, text, line, words):
    path = _write(tmp_path, text)
    with pytest.raises(ValueError) as err:
        read_bal_arrays(path)
    msg = str(err.value)
    assert f"{path}, line {line}:" in msg, msg
    assert words in msg, msg


def test_good_tiny_file_and_blank_lines(tmp_path):
    d = read_bal_arrays(_write(tmp_path, GOOD.replace("\n0 0", "\n\n0 0", 1) + "\n\n"))
    np.testing.assert_array_equal(d.points, [[1, 2, 3], [4, 5, -6]])
    np.testing.assert_array_equal(d.camera_index, [0, 1, 1])
    np.testing.assert_array_equal(d.observations[2], [5.0, 6.0])
    with pytest.raises(ValueError, match="empty"):
        read_bal_arrays(_write(tmp_path, "\n\n", "empty.txt"))


def test_bz2(tmp_path):
    src = shared_file("dubrovnik-3-7-pre.txt")
    packed = tmp_path / "dubrovnik.txt.bz2"
    packed.write_bytes(bz2.compress(src.read_bytes()))
    a, b = read_bal_arrays(src), read_bal_arrays(packed)
    for name in ("cameras", "points", "camera_index", "point_index", "observations"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_write_read_round_trip(tmp_path):
    src = shared_file("dubrovnik-3-7-pre.txt")
    d = read_bal_arrays(src)
    out = write_bal_arrays(d, tmp_path / "copy.txt")
    e = read_bal_arrays(out)
    for name in ("cameras", "points", "camera_index", "point_index", "observations"):
        np.testing.assert_array_equal(getattr(d, name), getattr(e, name))
    # Through a BundleProblem: exact observations and points, cameras to rounding.
    problem = read_bal(src)
    f = read_bal_arrays(write_bal(problem, tmp_path / "problem.txt"))
    np.testing.assert_array_equal(f.observations, d.observations)
    np.testing.assert_array_equal(f.points, d.points)
    np.testing.assert_allclose(f.cameras, d.cameras, rtol=1e-12, atol=1e-14)
    with pytest.raises(ValueError, match="refusing"):
        write_bal(problem, src, inputs=[src])


def test_write_refuses_what_bal_cannot_hold(tmp_path):
    problem = read_bal(shared_file("dubrovnik-3-7-pre.txt"))
    cams = list(problem.cameras)
    cams[1] = photax.FrameCamera(cams[1].focal_length, (1.0, 0.0), cams[1].distortion)
    with pytest.raises(ValueError, match=r"cameras\[1\]"):
        write_bal(problem.replace(cameras=cams), tmp_path / "x.txt")
    shared = problem.replace(
        cameras=problem.cameras[:1],
        image_camera=np.zeros(3, dtype=np.int64),
        free_intrinsics=problem.free_intrinsics[:1],
    )
    with pytest.raises(ValueError, match="one camera per image"):
        write_bal(shared, tmp_path / "x.txt")
    with pytest.raises(ValueError, match="BundleProblem or BundleResult"):
        write_bal(BALData(*(np.zeros((1, 1)),) * 5), tmp_path / "x.txt")
    assert not (tmp_path / "x.txt").exists()


def test_write_result_holds_the_adjusted_block(tmp_path):
    # An adjusted block written to BAL reproduces the solver's residuals when
    # projected with BAL's own formula: the written cameras are the adjusted ones.
    problem = read_bal(shared_file("dubrovnik-3-7-pre.txt"))
    result = photax.bundle_adjust(problem, gauge="damped", precision=False, throw=False)
    assert result.cost < result.initial_cost
    d = read_bal_arrays(write_bal(result, tmp_path / "adjusted.txt"))
    r = bal_project(d.cameras, d.points, d.camera_index, d.point_index) - d.observations
    np.testing.assert_allclose(r, result.residuals, rtol=0, atol=1e-8)
    np.testing.assert_allclose(0.5 * np.sum(r * r), result.cost, rtol=1e-10)
