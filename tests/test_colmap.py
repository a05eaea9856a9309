"""COLMAP sparse models (photax.io.colmap): text and binary round trips, and pycolmap as the reference
reader and projector of the same files."""

from __future__ import annotations

import numpy as np
import pytest

import photax as ptx
from photax.io import colmap as C
from photax.scene import synthetic_block

pycolmap = pytest.importorskip("pycolmap")

ORIGIN = np.array([500_000.0, 4_000_000.0, 100.0])


def _project_all(problem) -> np.ndarray:
    """photax's image-plane projection of every observation of ``problem``."""
    out = np.zeros((problem.n_observations, 2))
    eo = problem.exterior
    for i in range(problem.n_images):
        sel = problem.obs_image == i
        e = ptx.ExteriorOrientation(np.asarray(eo.position)[i], np.asarray(eo.angles)[i], eo.convention)
        cam = problem.cameras[problem.image_camera[i]]
        out[sel] = np.asarray(ptx.project(problem.points[problem.obs_point[sel]], e, cam))
    return out


def _pixels(problem, xy) -> np.ndarray:
    """Image plane -> photax pixels of each observation."""
    out = np.zeros_like(xy)
    for j, cam in enumerate(problem.cameras):
        sel = problem.image_camera[problem.obs_image] == j
        out[sel] = np.asarray(cam.image_to_pixel(xy[sel]))
    return out


@pytest.fixture(scope="module")
def block():
    """The synthetic block's truth in a local frame (COLMAP models are), with an OPENCV camera,
    exact observations, tie points seen on 2+ images only."""
    prob, truth = synthetic_block(0, noise_px=0.0)
    cam = ptx.FrameCamera(3000.0, (2.5, -1.5), (-0.05, 0.01, 0.0, 0.001, -0.0005), pixel_size=(1.0, 1.002),
                          image_size=(4000, 3000))  # fmt: skip
    keep = np.bincount(prob.obs_point, minlength=prob.n_points) >= 2
    sel = keep[prob.obs_point]
    new_index = np.cumsum(keep) - 1
    p = prob.replace(
        cameras=cam, exterior=ptx.ExteriorOrientation(np.asarray(truth.exterior.position) - ORIGIN,
                                                      truth.exterior.angles, truth.exterior.convention),
        points=truth.points[keep] - ORIGIN, obs_image=prob.obs_image[sel], obs_point=new_index[prob.obs_point[sel]],
        obs_xy=prob.obs_xy[sel], obs_sigma=1.0, roles=None, point_sigma=0.0,
        point_names=[str(10 + k) for k in range(int(keep.sum()))],
    )  # fmt: skip
    return p.replace(obs_xy=_project_all(p))


def _by_link(problem) -> np.ndarray:
    """The observations' order by (image, point)."""
    return np.lexsort((problem.obs_point, problem.obs_image))


def _assert_models_equal(a: C.ColmapModel, b: C.ColmapModel) -> None:
    assert a.cameras.keys() == b.cameras.keys() and a.images.keys() == b.images.keys()
    assert a.points.keys() == b.points.keys()
    for k, c in a.cameras.items():
        d = b.cameras[k]
        assert (c.model, c.width, c.height) == (d.model, d.width, d.height)
        np.testing.assert_array_equal(c.params, d.params)
    for k, im in a.images.items():
        jm = b.images[k]
        assert (im.name, im.camera_id) == (jm.name, jm.camera_id)
        for f in ("qvec", "tvec", "xy", "point3d_ids"):
            np.testing.assert_array_equal(getattr(im, f), getattr(jm, f))
    for k, p in a.points.items():
        q = b.points[k]
        assert p.error == q.error
        for f in ("xyz", "rgb", "image_ids", "point2d_idx"):
            np.testing.assert_array_equal(getattr(p, f), getattr(q, f))


def _pycolmap_residuals(folder) -> float:
    """Largest difference between pycolmap's projection of each 3-D point and the keypoint stored for it."""
    rec = pycolmap.Reconstruction(str(folder))
    worst = 0.0
    for im in rec.images.values():
        for p2 in im.points2D:
            if p2.has_point3D():
                worst = max(worst, float(np.abs(im.project_point(rec.points3D[p2.point3D_id].xyz) - p2.xy).max()))
    return worst


def test_round_trip_text_binary_photax_and_pycolmap(block, tmp_path):
    C.write_colmap(block, tmp_path / "text")
    C.write_colmap(block, tmp_path / "bin", binary=True)
    text, binary = C.read_colmap_model(tmp_path / "text"), C.read_colmap_model(tmp_path / "bin")
    _assert_models_equal(text, binary)  # text and binary hold the same numbers, exactly
    assert text.cameras[1].model == "OPENCV"
    # photax -> COLMAP -> photax: the same block
    back = C.read_colmap(tmp_path / "bin")
    assert back.image_names == block.image_names and back.point_names == block.point_names
    a, b = _by_link(back), _by_link(block)  # observations come point by point (the tracks) from COLMAP
    np.testing.assert_array_equal(back.obs_image[a], block.obs_image[b])
    np.testing.assert_array_equal(back.obs_point[a], block.obs_point[b])
    np.testing.assert_allclose(_pixels(back, back.obs_xy)[a], _pixels(block, block.obs_xy)[b], rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.exterior.position, block.exterior.position, rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.exterior.rotation, block.exterior.rotation, rtol=0, atol=1e-14)
    np.testing.assert_allclose(back.points, block.points, rtol=0, atol=0)
    cam, orig = back.cameras[0], block.cameras[0]
    for f in ("focal_length", "principal_point", "distortion", "pixel_size"):
        np.testing.assert_allclose(getattr(cam, f), getattr(orig, f), rtol=1e-15, atol=1e-12)
    # pycolmap reads the same files and projects every point onto its keypoint (photax's projection)
    for folder in ("text", "bin"):
        assert _pycolmap_residuals(tmp_path / folder) < 1e-9
    # and photax's projections of the model it read equal pycolmap's
    rec = pycolmap.Reconstruction(str(tmp_path / "text"))
    ours = _pixels(back, _project_all(back)) + 0.5  # COLMAP's pixel corner
    name_to_id = {im.name: k for k, im in rec.images.items()}
    for o in range(0, back.n_observations, 7):
        im = rec.images[name_to_id[back.image_names[back.obs_image[o]]]]
        theirs = im.project_point(rec.points3D[int(back.point_names[back.obs_point[o]])].xyz)
        np.testing.assert_allclose(ours[o], theirs, rtol=0, atol=1e-9)


def test_model_written_by_pycolmap_is_read(block, tmp_path):
    """pycolmap 4 writes rigs and frames too (ignored); text and binary give one photax problem."""
    C.write_colmap(block, tmp_path / "ours")
    rec = pycolmap.Reconstruction(str(tmp_path / "ours"))
    (tmp_path / "t").mkdir()
    rec.write_text(str(tmp_path / "t"))
    (tmp_path / "b").mkdir()
    rec.write_binary(str(tmp_path / "b"))
    assert (tmp_path / "b" / "frames.bin").is_file()
    a, b = C.read_colmap(tmp_path / "t"), C.read_colmap(tmp_path / "b")
    _assert_models_equal(C.read_colmap_model(tmp_path / "t"), C.read_colmap_model(tmp_path / "b"))
    np.testing.assert_allclose(_pixels(a, _project_all(a)), _pixels(a, a.obs_xy), rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.exterior.position, block.exterior.position, rtol=0, atol=1e-9)


CAMERAS = [
    ("SIMPLE_PINHOLE", [510.0, 321.3, 239.1]),
    ("PINHOLE", [500.0, 512.0, 318.0, 243.5]),
    ("SIMPLE_RADIAL", [505.0, 320.0, 240.0, -0.08]),
    ("RADIAL", [505.0, 322.0, 238.0, -0.08, 0.012]),
    ("OPENCV", [500.0, 507.0, 321.0, 241.0, -0.1, 0.02, 0.0015, -0.0008]),
    ("FULL_OPENCV", [500.0, 507.0, 321.0, 241.0, -0.1, 0.02, 0.0015, -0.0008, 0.003, 0.0, 0.0, 0.0]),
    ("FULL_OPENCV", [500.0, 507.0, 321.0, 241.0, -0.1, 0.02, 0.0015, -0.0008, 0.003, 0.04, -0.01, 0.002]),
    ("OPENCV_FISHEYE", [500.0, 507.0, 321.0, 241.0, 0.05, -0.01, 0.003, -0.0004]),
]


@pytest.mark.parametrize(("model", "params"), CAMERAS)
def test_each_camera_model_projects_as_pycolmap(model, params):
    theirs = pycolmap.Camera(model=model, width=640, height=480, params=params)
    ours = C.colmap_camera_to_photax(C.ColmapCamera(model, 640, 480, np.array(params)))
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-0.6, 0.6, (50, 2)), np.ones(50)]) * rng.uniform(1, 9, (50, 1))
    expected = theirs.img_from_cam(pts)  # COLMAP's camera frame: y down, z forward
    got = np.asarray(ours.image_to_pixel(ours.project(pts * [1, -1, -1]))) + 0.5
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    # written back: the simplest model holding it, with the same parameters
    back = C.photax_camera_to_colmap(ours)
    expect_model = "OPENCV" if model == "FULL_OPENCV" and params[8] == 0 else model
    assert back.model == expect_model
    np.testing.assert_allclose(back.params, params, rtol=1e-15, atol=1e-15)


@pytest.mark.parametrize(
    ("model", "params", "words"),
    [
        ("FOV", [500, 500, 320, 240, 0.9], "FOV has no photax camera"),
    ],
)
def test_models_photax_cannot_hold_are_refused_by_name(tmp_path, model, params, words):
    (tmp_path / "cameras.txt").write_text(f"1 {model} 640 480 {' '.join(map(str, params))}\n")
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 5 1 a.jpg\n10 20 1\n2 1 0 0 0 1 0 5 1 b.jpg\n11 20 1\n")
    (tmp_path / "points3D.txt").write_text("1 0 0 0 1 2 3 -1 1 0 2 0\n")
    model_read = C.read_colmap_model(tmp_path)  # read as stored, every model
    assert model_read.cameras[1].model == model
    with pytest.raises(ValueError, match=words) as err:
        C.read_colmap(tmp_path)
    assert str(tmp_path) in str(err.value)


@pytest.mark.parametrize(
    ("file", "text", "words"),
    [
        ("cameras.txt", "1 PINHOLE 640 480 500 500 320\n", r"cameras.txt, line 1: .*PINHOLE camera has 4 parameters"),
        ("cameras.txt", "# c\n1 NOPE 640 480 500\n", r"cameras.txt, line 2: .*unknown COLMAP camera model 'NOPE'"),
        ("images.txt", "1 1 0 0 0 0 0 5 2 a.jpg\n\n", r"images.txt, line 1: image 1: camera 2 is not"),
        ("images.txt", "1 1 0 0 0 0 0 5 1 a.jpg\n10 20\n", r"images.txt, line 2: .*triples"),
        ("images.txt", "1 1 0 0 0 0 0 nan 1 a.jpg\n\n", r"images.txt, line 1: .*finite"),
        ("points3D.txt", "1 0 0 0 1 2 3 -1 1 5 2 0\n", r"points3D.txt, line 1: point 1: image 1 has no keypoint 5"),
        ("points3D.txt", "1 0 0 0 1 2 3 -1 1 0 3 0\n", r"points3D.txt, line 1: .*image 3, which is not"),
    ],
)
def test_malformed_text_names_file_and_line(tmp_path, file, text, words):
    files = {
        "cameras.txt": "1 PINHOLE 640 480 500 500 320 240\n",
        "images.txt": "1 1 0 0 0 0 0 5 1 a.jpg\n10 20 1\n2 1 0 0 0 1 0 5 1 b.jpg\n11 20 1\n",
        "points3D.txt": "1 0 0 0 1 2 3 -1 1 0 2 0\n",
    }
    files[file] = text
    for k, v in files.items():
        (tmp_path / k).write_text(v)
    with pytest.raises(ValueError, match=words):
        C.read_colmap_model(tmp_path)


def test_truncated_binary_names_the_file(block, tmp_path):
    C.write_colmap(block, tmp_path / "m", binary=True)
    raw = (tmp_path / "m" / "images.bin").read_bytes()
    (tmp_path / "m" / "images.bin").write_bytes(raw[:-5])
    with pytest.raises(ValueError, match=r"images.bin: .*(truncated|more than the file holds)"):
        C.read_colmap_model(tmp_path / "m")


def test_writer_refuses_a_non_empty_folder(block, tmp_path):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "keep.txt").write_text("mine")
    with pytest.raises(ValueError, match="not an empty folder"):
        C.write_colmap(block, tmp_path / "x")


def test_quaternions_round_trip():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    np.testing.assert_allclose(C.matrix_to_quaternion(C.quaternion_to_matrix(q)), q, atol=1e-14)
    r = C.quaternion_to_matrix(q)
    np.testing.assert_allclose(r @ np.swapaxes(r, 1, 2), np.broadcast_to(np.eye(3), r.shape), atol=1e-14)
    # pycolmap's convention: Rotation3d takes (x, y, z, w)
    for k in range(3):
        theirs = pycolmap.Rotation3d(np.r_[q[k, 1:], q[k, 0]]).matrix()
        np.testing.assert_allclose(r[k], theirs, atol=1e-15)


def test_point_ids_kept_and_new_points_numbered_after_them():
    assert C._point_ids(["10", "3", "CON1", "07", "7", "x"]) == [10, 3, 11, 7, 12, 13]
