"""The real-data tier (issue 21 item 6): orthority's test corpus in ``../shared/data/orthority``
(skipped cleanly when absent).

* The real-block chain of docs/cli.md (ties -> GNSS-aided bundle with the DEM's heights -> orthos of the
  block in one process -> mosaic with seamlines and source index) runs as written, from a folder
  beside ``shared/``.
* photax's orthos of the four NGI frames and of the four drone images against orthority's
  (``oty frame``, ``oty odm``: an independent orthorectifier), same inputs, resolution and kernels:
  mean absolute difference <= 0.3 grey levels, grey-level bias < 0.05 and geometric offset
  <= 0.05 px.  The offset is the least-squares shift between the two orthos (their difference
  against the mean image gradient), itself checked here on a known sub-pixel shift.
"""

import glob
import json
import os
import pathlib
import re
import shlex
import shutil
import subprocess
import sys

import numpy as np
import pytest
import rasterio
from conftest import ROOT, SHARED_DATA

from photax.cli import build_parser, main

ORTHORITY = SHARED_DATA / "orthority"
NGI, IO, ODM = ORTHORITY / "ngi", ORTHORITY / "io", ORTHORITY / "odm"
NGI_NAMES = [f"3324c_2015_1004_{n}_RGB" for n in ("05_0182", "05_0184", "06_0251", "06_0253")]


def _need(path: pathlib.Path) -> pathlib.Path:
    if not path.exists():
        pytest.skip(f"{path} is not present (../shared/data/orthority)")
    return path


def _oty() -> str:
    oty = shutil.which("oty", path=str(pathlib.Path(sys.executable).parent)) or shutil.which("oty")
    if oty is None:
        pytest.skip("orthority's oty command is not installed (the test extra)")
    return oty


# --- the README's chain ------------------------------------------------------------------------


def readme_chain() -> list[str]:
    """The indented ``photax`` commands that follow the "real-block chain" paragraph of the CLI page
    (docs/cli.md; it was the README's)."""
    text = (ROOT / "docs" / "cli.md").read_text()
    block = re.search(r"real-block chain.*?\n\n((?:    photax [^\n]*\n)+)", text, flags=re.S)
    assert block, "docs/cli.md: no real-block chain"
    return [ln.strip() for ln in block.group(1).splitlines()]


def test_readme_real_block_chain_runs_as_written(tmp_path, monkeypatch, capsys):
    _need(NGI / "dem.tif")
    cmds = readme_chain()
    assert [c.split()[1] for c in cmds] == ["ties", "bundle", "ortho", "mosaic"]
    # A clone beside shared/: ../shared/data/orthority resolves as in a worktree.
    (tmp_path / "shared").symlink_to(SHARED_DATA.parent, target_is_directory=True)
    (tmp_path / "clone").mkdir()
    monkeypatch.chdir(tmp_path / "clone")
    monkeypatch.setenv("DATA", "../shared/data")  # the page's $DATA: the public data sets, beside the clone
    draws_bar = {k for k, p in build_parser().subcommands.items() if "--no-progress" in p._option_string_actions}
    for cmd in cmds:
        argv = []
        for arg in map(os.path.expandvars, shlex.split(cmd)[1:]):  # the shell's $DATA and glob expansion
            argv += sorted(glob.glob(arg)) or [arg] if "*" in arg else [arg]
        assert main(argv + ["--no-progress"] * (argv[0] in draws_bar)) == 0, cmd
    out = pathlib.Path("out")
    result = json.loads((out / "ngi-bundle.json").read_text())
    assert result["converged"]
    images = {img["name"]: img for img in result["images"]}
    assert sorted(images) == NGI_NAMES
    # The adjusted positions stay within 3 sigma (2 m per axis) of the GNSS ones, the survey's.
    lines = (NGI / "camera_pos_ori.txt").read_text().split("\n")
    survey = {ln.split()[0]: np.array(ln.split()[1:4], float) for ln in lines if ln.strip()}
    for name, img in images.items():
        assert np.all(np.abs(np.asarray(img["position"]) - survey[name]) < 3 * 2.0), name
    # The DEM's heights: every tie lies on the DEM, and the adjusted heights lie within the DEM's own
    # error at the ties (3 m RMS, measured independently: the ties intersected with the survey's
    # orientations, benchmarks/gnss_ngi.py) -- a DEM in another height system or a wrong DEM term
    # leaves them tens of metres off.
    dem = result["dem_heights"]
    n_ties = (out / "ngi-block" / "points.csv").read_text().count(",tie,")
    assert dem["observed"] == n_ties > 0 and dem["not_observed"] == 0, dem
    assert dem["rms"] < 3.0, dem
    # ... and they hold the block's angles tighter than the GNSS alone: the same bundle without them.
    (bundle,) = [shlex.split(c)[1:] for c in cmds if c.split()[1] == "bundle"]  # options: one value each
    alone = {a: v for a, v in zip(bundle[2::2], bundle[3::2]) if a not in ("--dem", "--dem-sigma")}
    alone |= {"-o": "out/ngi-bundle-gnss.json"}
    assert main(bundle[:2] + [x for kv in alone.items() for x in kv] + ["--no-progress"]) == 0
    gnss_only = {img["name"]: img for img in json.loads((out / "ngi-bundle-gnss.json").read_text())["images"]}
    for name, img in images.items():
        assert np.all(np.asarray(img["std"][3:]) < np.asarray(gnss_only[name]["std"][3:])), name
    assert sorted(p.name for p in (out / "ngi-orthos").iterdir()) == [f"{n}_ortho.tif" for n in NGI_NAMES]
    with rasterio.open(out / "ngi-mosaic.tif") as ds, rasterio.open(out / "ngi-source.tif") as src:
        mosaic, index = ds.read(1), src.read(1)
        assert ds.shape == src.shape and ds.transform == src.transform
    seams = json.loads((out / "ngi-seams.geojson").read_text())
    assert len(seams["features"]) == 4
    assert set(np.unique(index[index >= 0])) >= {0, 1, 2, 3}  # every ortho gives part of the mosaic
    assert mosaic[index >= 0].std() > 10  # an image, not a blank
    assert not list(out.rglob("*.part"))
    printed = capsys.readouterr().out
    assert "wrote out/ngi-bundle.json" in printed


# --- photax's orthos against orthority's --------------------------------------------------------


def shift_px(ours: np.ndarray, ref: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The (column, row) shift s with ours(x) ~ ref(x + s), in pixels: least squares of the
    difference on the mean gradient of the two images (bands stacked), over valid pixels whose
    3 x 3 neighbourhood is valid."""
    a, b = ours.astype(float), ref.astype(float)
    m = (a + b) / 2
    gy, gx = np.gradient(m, axis=(1, 2))
    inner = valid.copy()
    for ax in (0, 1):
        for s in (1, -1):
            inner &= np.roll(valid, s, axis=ax)
    inner[[0, -1], :] = inner[:, [0, -1]] = False
    g = np.stack([gx[:, inner].ravel(), gy[:, inner].ravel()], axis=1)
    d = (a - b)[:, inner].ravel()
    return np.linalg.lstsq(g, d, rcond=None)[0]


def test_shift_estimator_finds_a_known_sub_pixel_shift():
    from scipy.ndimage import gaussian_filter, shift

    rng = np.random.default_rng(3)
    img = gaussian_filter(rng.uniform(0, 255, (3, 200, 240)), (0, 2.0, 2.0))
    true = np.array([0.07, -0.04])  # columns, rows
    moved = shift(img, (0, -true[1], -true[0]), order=3, mode="nearest")  # moved(x) = img(x + s)
    valid = np.ones(img.shape[1:], bool)
    np.testing.assert_allclose(shift_px(moved, img, valid), true, atol=0.005)
    np.testing.assert_allclose(shift_px(img, img, valid), 0.0, atol=1e-12)


def _common_windows(a, b):
    from rasterio.windows import from_bounds

    left, top = max(a.bounds.left, b.bounds.left), min(a.bounds.top, b.bounds.top)
    right, bottom = min(a.bounds.right, b.bounds.right), max(a.bounds.bottom, b.bounds.bottom)
    wa = from_bounds(left, bottom, right, top, a.transform).round_offsets().round_lengths()
    wb = from_bounds(left, bottom, right, top, b.transform).round_offsets().round_lengths()
    assert (wa.height, wa.width) == (wb.height, wb.width)  # both grids on multiples of the resolution
    return wa, wb


def _agree(ours_path, ref_path, label):
    """MAD, bias and geometric offset of two orthos over the pixels both cover."""
    with rasterio.open(ours_path) as a, rasterio.open(ref_path) as b:
        assert a.crs == b.crs and a.res == b.res, label
        wa, wb = _common_windows(a, b)
        x, y = a.read(window=wa).astype(float), b.read(window=wb).astype(float)
    both = (x != 0).any(0) & (y != 0).any(0)
    assert both.sum() > 0.8 * min((x != 0).any(0).sum(), (y != 0).any(0).sum()), label
    d = (x - y)[:, both]
    mad, bias, offset = np.abs(d).mean(), d.mean(), shift_px(x, y, both)
    print(f"{label}: mean abs diff {mad:.3f}, bias {bias:+.3f} grey levels, offset {offset.round(4)} px")
    assert mad <= 0.3, (label, mad)
    assert abs(bias) < 0.05, (label, bias)
    assert np.all(np.abs(offset) <= 0.05), (label, offset)
    return mad, offset


def test_ngi_block_orthos_match_oty_frame(tmp_path):
    """``photax ortho`` of the four NGI frames in one process against ``oty frame`` of the four:
    5 m, bilinear grey values and DEM heights, lossless output."""
    _need(NGI / "dem.tif")
    oty = _oty()
    # The DEM tagged with the orientation's horizontal CRS (its heights as stored): orthority would
    # otherwise shift EGM2008 heights to the ellipsoid through PROJ's network grid (test_ortho_real).
    with rasterio.open(NGI / "dem.tif") as src:
        profile, heights = src.profile, src.read()
    profile.update(crs=rasterio.CRS.from_string((IO / "ngi_xyz_opk.prj").read_text()))
    dem = tmp_path / "dem.tif"
    with rasterio.open(dem, "w", **profile) as dst:
        dst.write(heights)
    images = [str(NGI / f"{n}.tif") for n in NGI_NAMES]
    interior, exterior = str(IO / "ngi_int_param.yaml"), str(IO / "ngi_xyz_opk.csv")
    common = ["--dem", str(dem), "--out-dir"]
    (tmp_path / "oty").mkdir()
    subprocess.run(
        [oty, "frame", *images, *common, str(tmp_path / "oty"), "--int-param", interior, "--ext-param", exterior]
        + "--res 5 --aligned-pixels --interp bilinear --dem-interp bilinear --compress deflate --no-write-mask --no-build-ovw".split(),
        check=True,
        capture_output=True,
    )
    argv = ["ortho", *images, *common, str(tmp_path / "photax"), "--camera", interior, "--exterior", exterior]
    assert main(argv + ["--resolution", "5", "--resampling", "bilinear", "--no-progress"]) == 0
    for n in NGI_NAMES:
        _agree(tmp_path / "photax" / f"{n}_ortho.tif", tmp_path / "oty" / f"{n}_ORTHO.tif", n)


def test_drone_orthos_match_oty_odm(tmp_path):
    """``photax ortho IMAGE --camera reconstruction.json --exterior reconstruction.json --dem
    dsm.tif`` of the four drone images (one process) against ``oty odm`` (bilinear, 0.4 m)."""
    rec = _need(ODM / "opensfm" / "reconstruction.json")
    oty = _oty()
    (tmp_path / "oty").mkdir()
    subprocess.run(
        [oty, "odm", "-dd", str(ODM), "-od", str(tmp_path / "oty"), "-r", "0.4", "-ap"]
        + "-i bilinear -di bilinear -cm deflate -nwm -o".split(),
        check=True,
        capture_output=True,
    )
    images = sorted((ODM / "images").glob("*.tif"))
    assert len(images) == 4
    argv = ["ortho", *map(str, images), "--camera", str(rec), "--exterior", str(rec)]
    argv += ["--dem", str(ODM / "odm_dem" / "dsm.tif"), "--resolution", "0.4", "--out-dir", str(tmp_path / "photax")]
    assert main(argv + ["--no-progress"]) == 0
    for image in images:
        _agree(
            tmp_path / "photax" / f"{image.stem}_ortho.tif", tmp_path / "oty" / f"{image.stem}_ORTHO.tif", image.stem
        )
