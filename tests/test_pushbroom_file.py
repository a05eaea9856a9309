"""The push-broom camera file (:mod:`photax.io.pushbroom_file`) and the push-broom on the command line
(issue 23): the file reads back the very camera written (YAML and JSON), a malformed file is a
ValueError naming the file and the key's line (and the fuzzer's mutations of a real one are an error
or a sane camera), ``photax ortho IMAGE --camera pushbroom.yaml`` writes what
:func:`photax.orthorectify` computes on the command's grid, and ``photax rpc`` writes the RPC that
:func:`photax.fit_rpc` fits (read back by ``read_rpc``), whose ortho is the push-broom's to its fit
error."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from test_fuzz_readers import FUZZ, _expect_valueerror_or_sane, mutated

from photax.cli import main
from photax.dem import DEM
from photax.io.pushbroom_file import read_pushbroom, write_pushbroom
from photax.pushbroom import PushbroomCamera, fit_rpc
from photax.rectification import orthorectify
from photax.rpc import read_rpc
from photax.scene import pushbroom_scene
from photax.sensor import GroundSensor, utm_crs

rasterio = pytest.importorskip("rasterio")
HEIGHT = 700.0


@pytest.fixture(scope="module")
def scene():
    return pushbroom_scene(roll=12.0, pitch=-10.0, gsd=10.0, image_size=(96, 80), n_gcp=6, n_check=0)


def _same(a: PushbroomCamera, b: PushbroomCamera) -> bool:
    leaves = zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    return (
        a.image_size == b.image_size
        and a.convention == b.convention
        and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in leaves)
    )


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_round_trip_is_bit_for_bit(scene, tmp_path, suffix):
    cam = scene.camera
    cam = PushbroomCamera(cam.position, cam.angles, cam.reference, cam.focal_length, (1.25, -3.5),
                          image_size=cam.image_size, convention="omega-phi-kappa")  # fmt: skip
    path = write_pushbroom(cam, tmp_path / f"cam{suffix}", name="toy")
    assert _same(read_pushbroom(path), cam)
    with pytest.raises(ValueError, match="may not overwrite|is an input|input"):
        write_pushbroom(cam, path, inputs=[path])


def _seed(scene, tmp_path) -> bytes:
    return write_pushbroom(scene.camera, tmp_path / "seed.yaml").read_bytes()


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda t: t.replace("focal_length: ", "focal_length: -"), r"line 4: focal_length must be positive"),
        (lambda t: t.replace("type: pushbroom\n", "type: pushbroom\ncolour: red\n"), r"line 3: unknown key 'colour'"),
        (lambda t: t.replace("image_size: [96, 80]", "image_size: [96]"), r"line 3: image_size must be 2"),
        (lambda t: t.replace("- [-0.011", "- [2.0").replace("- [4796", "- [4796"), r"reference is not a rotation"),
        (lambda t: t[: t.index("angles:")], r"missing key 'angles'"),
        (lambda t: t.replace("position:\n- [", "position:\n- [nan, "), r"position must be rows of 3 finite"),
        (lambda t: t.replace("convention: phi-omega-kappa", "convention: kappa"), r"line 6: convention must be"),
        (lambda t: t.replace("image_size: [96, 80]", "image_size: [96, 80"), r"line \d+: not valid YAML"),
        (lambda t: t.replace("type: pushbroom", "type: frame"), r"not a photax push-broom camera file"),
    ],
)
def test_malformed_files_name_the_key_and_line(scene, tmp_path, edit, message):
    text = _seed(scene, tmp_path).decode()
    assert "focal_length: 64362" in text and "- [-0.011" in text  # the edits' anchors
    path = tmp_path / "bad.yaml"
    path.write_text(edit(text))
    with pytest.raises(ValueError, match=message) as exc:
        read_pushbroom(path)
    assert str(exc.value).startswith(str(path))


def _sane(cam) -> None:
    assert isinstance(cam, PushbroomCamera) and float(cam.focal_length) > 0 and min(cam.image_size) >= 1
    for a in (cam.position, cam.angles, cam.reference, cam.principal_point):
        assert np.all(np.isfinite(np.asarray(a)))


SEED = [
    b"type: pushbroom\nimage_size: [96, 80]\nfocal_length: 64362.9\nprincipal_point: [0.0, 0.0]\n"
    b"convention: phi-omega-kappa\nreference:\n- [1.0, 0.0, 0.0]\n- [0.0, 1.0, 0.0]\n- [0.0, 0.0, 1.0]\n"
    b"position:\n- [4796028.06, 727474.9, 5029304.6]\n- [315.2, -36.0, -295.4]\nangles:\n- [0.2, -0.17, 0.0]\n"
    b"- [3.0e-06, 6.2e-05, -2.0e-06]\nname: toy\n",
]


@FUZZ
@given(data=mutated(SEED))
def test_fuzz_read_pushbroom(work, data):
    path = work / "pushbroom.yaml"
    path.write_bytes(data)
    _expect_valueerror_or_sane(read_pushbroom, path, _sane)


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


# --- the command line ----------------------------------------------------------------------------


def _image(scene, path):
    """A smooth float32 test image of the camera's size (its values only need to vary)."""
    w, lines = scene.camera.image_size
    c, r = np.meshgrid(np.arange(w), np.arange(lines))
    image = (100 + 40 * np.sin(c / 7.0) * np.cos(r / 5.0) + r).astype(np.float32)
    with warnings.catch_warnings():  # a raw satellite image has no geotransform
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(path, "w", driver="GTiff", width=w, height=lines, count=1, dtype="float32") as dst:
            dst.write(image, 1)
    return image


def test_cli_pushbroom_ortho_equals_python_and_its_rpc(scene, tmp_path, capsys):
    cam_path = write_pushbroom(scene.camera, tmp_path / "scene.yaml")
    image = _image(scene, tmp_path / "scene.tif")
    cam = read_pushbroom(cam_path)
    w, lines = cam.image_size
    crs = utm_crs(*np.asarray(cam.to_ground(jnp.array([(w - 1) / 2, (lines - 1) / 2]), HEIGHT)))
    common = ["--height", str(HEIGHT), "--crs", crs, "--resolution", "15", "--no-progress"]
    out = tmp_path / "o.tif"
    assert main(["ortho", str(tmp_path / "scene.tif"), "--camera", str(cam_path), *common, "-o", str(out)]) == 0
    with rasterio.open(out) as src:
        got, transform, shape = src.read(1), src.transform, src.shape
    from photax.grid import Grid

    grid = Grid(transform, shape, crs)
    flat = DEM.flat(HEIGHT, GroundSensor(cam, crs).box())
    dem = DEM(flat.heights, flat.transform, crs=crs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ours, _ = orthorectify(image, None, cam, dem, grid)
    seen = np.isfinite(ours)
    assert seen.mean() > 0.5 and np.array_equal(np.isfinite(got), seen)
    np.testing.assert_allclose(got[seen], ours[seen], atol=1e-3)  # float32 tile positions

    # photax rpc: the fitted RPC written, read back equal to fit_rpc's; its ortho is the push-broom's
    rpc_path = tmp_path / "rpc_param.yaml"
    assert main(["rpc", str(cam_path), "--heights", "0", "1500", "-o", str(rpc_path)]) == 0
    printed = capsys.readouterr().out
    fit = fit_rpc(cam, (0.0, 1500.0))
    assert f"max {fit.check_max_error:.2e} px" in printed and "entry scene.tif" in printed
    rpc = read_rpc(rpc_path, "scene.tif")
    np.testing.assert_array_equal(np.asarray(rpc.coefficients), np.asarray(fit.camera.coefficients))
    assert rpc.image_size == cam.image_size
    out_rpc = tmp_path / "o_rpc.tif"
    assert main(["ortho", str(tmp_path / "scene.tif"), "--camera", str(rpc_path), *common, "-o", str(out_rpc)]) == 0
    with rasterio.open(out_rpc) as src:
        via_rpc = src.read(1)
    both = np.isfinite(via_rpc) & seen
    assert both.mean() > 0.5
    # the grey values' slope is at most ~ 40 / 5 + 1 per pixel: the fit error (<< 0.01 px) moves them by < 0.1
    assert np.abs(via_rpc[both] - got[both]).max() < 0.1


def test_cli_pushbroom_usage_errors(scene, tmp_path, capsys):
    cam_path = write_pushbroom(scene.camera, tmp_path / "scene.yaml")
    _image(scene, tmp_path / "a.tif")
    _image(scene, tmp_path / "b.tif")
    base = ["--height", "700", "--no-progress", "--camera", str(cam_path)]
    cases = [
        (["ortho", str(tmp_path / "a.tif"), *base, "--gcps", str(cam_path), "-o", str(tmp_path / "o.tif")],
         "resect_pushbroom"),
        (["ortho", str(tmp_path / "a.tif"), str(tmp_path / "b.tif"), *base, "--out-dir", str(tmp_path / "d")],
         "one push-broom camera for 2 images"),
        (["rpc", str(cam_path), "--heights", "0", "1500", "-o", str(tmp_path / "x.RPB")], "give a .yaml file"),
        (["rpc", str(cam_path), "--heights", "10", "10", "-o", str(tmp_path / "x.yaml")], "h_max > h_min"),
        (["rpc", str(cam_path), "--heights", "0", "1500", "-o", str(cam_path)], "input"),
    ]  # fmt: skip
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err
    assert read_pushbroom(cam_path).image_size == scene.camera.image_size  # the input is untouched
