"""Every ``measure.Status`` reason is true: each test builds an input that truly has the condition
and checks that the locator reports it (and that no other input gets it). Issue 26, item 2: the README's
``photax measure`` on the sample found 0 of 16 quartered targets and called windows of grey-value
sigma 92-97 "no texture".
"""

import json
import pathlib

import numpy as np

from photax.measure import Status, locate_corners, locate_targets, match_lsm, target_kind
from photax.scene import patterns as R

DATA = pathlib.Path(__file__).resolve().parents[1] / "data"
RADIUS = 6.0


def _disc_image(centre=(30.3, 29.6), shape=(60, 60), noise=0.01, seed=0):
    return R.render(
        R.disc(centre, RADIUS), shape, blur=0.7, noise=noise, low=20.0, high=220.0, rng=np.random.default_rng(seed)
    )


def _noise_texture(shape=(60, 60), seed=1):
    return np.random.default_rng(seed).uniform(0.0, 255.0, shape)  # grey-value sigma ~74: textured, no target


def _sample():
    from photax.io import read_gcps
    from photax.io.raster import read_geotiff

    image = read_geotiff(DATA / "sample_image.tif")[0][0]
    table = read_gcps(DATA / "sample_gcps.csv")
    truth = json.loads((DATA / "sample_truth.json").read_text())
    pixel_true = np.asarray([truth["pixel_true"][name] for name in table.names], dtype=float)
    return image, table, pixel_true, truth["blunder"]["name"]


def test_ok_quartered_targets_on_the_sample():
    """The README's example: 15 of the 16 quartered targets at the rendering's truth; the 16th approximation
    is the sample's blunder (15 px off, on the ground texture): no target there, truly."""
    image, table, truth, blunder = _sample()
    assert target_kind(image, table.pixel, RADIUS) == "quartered"
    res = locate_targets(image, table.pixel, RADIUS, method="auto")
    st = np.asarray(res.status)
    bad = table.names == blunder
    assert np.all(st[~bad] == Status.OK) and np.all(st[bad] == Status.NO_TARGET)
    err = np.asarray(res.xy)[~bad] - truth[~bad]
    assert np.sqrt(np.mean(np.sum(err**2, axis=1))) < 0.05  # px
    # the disc locators do not find a blob there; what they say is "no target", never "no texture"
    for method in ("ellipse", "centroid", "wong-trinder"):
        st = np.asarray(locate_targets(image, table.pixel, RADIUS, method=method).status)
        assert not np.any(st == Status.TEXTURELESS), method


def test_disc_image_is_not_quartered_and_auto_takes_the_ellipse():
    img = _disc_image()
    assert target_kind(img, [[30.0, 30.0]], RADIUS) == "disc"
    auto = locate_targets(img, [[30.0, 30.0]], RADIUS, method="auto")
    ell = locate_targets(img, [[30.0, 30.0]], RADIUS, method="ellipse")
    assert int(auto.status[0]) == Status.OK and np.allclose(auto.xy, ell.xy)
    assert np.allclose(np.asarray(auto.xy)[0], [30.3, 29.6], atol=0.05)


def test_outside():
    img = _disc_image()
    for res in (
        locate_targets(img, [[3.0, 30.0]], RADIUS),
        locate_corners(img, [[58.0, 3.0]]),
        locate_targets(img, [[3.0, 30.0]], RADIUS, method="quartered"),
    ):
        assert int(res.status[0]) == Status.OUTSIDE


def test_textureless_only_for_constant_windows():
    flat = np.full((60, 60), 87.0)
    assert int(locate_targets(flat, [[30.0, 30.0]], RADIUS).status[0]) == Status.TEXTURELESS
    assert int(locate_corners(flat, [[30.0, 30.0]]).status[0]) == Status.TEXTURELESS
    tex = _noise_texture()
    for method in ("ellipse", "centroid", "wong-trinder", "quartered"):
        st = int(locate_targets(tex, [[30.0, 30.0]], RADIUS, method=method).status[0])
        assert st != Status.TEXTURELESS, method


def test_no_target_in_texture_or_touching_the_border():
    tex = _noise_texture()
    for method in ("ellipse", "centroid", "quartered"):
        assert int(locate_targets(tex, [[30.0, 30.0]], RADIUS, method=method).status[0]) == Status.NO_TARGET
    # a disc cut by the window's border (window half-size 8 < offset 5 + radius 6)
    img = _disc_image()
    res = locate_targets(img, [[25.3, 29.6]], RADIUS, window=8, method="centroid")
    assert int(res.status[0]) == Status.NO_TARGET


def test_left_window():
    # the disc lies wholly inside a large window but 8 px (> radius) from the approximation
    img = _disc_image()
    res = locate_targets(img, [[38.3, 29.6]], RADIUS, window=20)
    assert int(res.status[0]) == Status.LEFT_WINDOW


def test_not_converged():
    img = R.render(R.corner((22.2, 20.7), 0.3, 1.6), (45, 45), blur=1.2)
    assert int(locate_corners(img, [[24.0, 23.0]], iterations=1).status[0]) == Status.NOT_CONVERGED
    assert int(locate_corners(img, [[24.0, 23.0]], iterations=30).status[0]) == Status.OK


def test_ill_conditioned_on_a_straight_edge():
    edge = R.render(lambda x, y: (x > 22.3) * 1.0 + 0 * y, (45, 45), blur=0.7)
    assert int(locate_corners(edge, [[22.0, 22.0]]).status[0]) == Status.ILL_CONDITIONED
    # LSM: a template matched against its own negative has no positive gain
    tpl = R.render(R.corner((22.2, 20.7), 0.3, 1.6), (45, 45), blur=0.7)
    res = match_lsm(tpl, [[22.0, 21.0]], 1.0 - tpl, [[22.0, 21.0]])
    assert int(res.status[0]) == Status.ILL_CONDITIONED


def test_not_finite():
    img = _disc_image()
    img[30, 31] = np.nan
    for res in (locate_targets(img, [[30.0, 30.0]], RADIUS), locate_corners(img, [[30.0, 30.0]])):
        assert int(res.status[0]) == Status.NOT_FINITE


def test_cli_readme_example(tmp_path, capsys):
    """README: ``photax measure data/sample_image.tif --targets data/sample_gcps.csv --radius 6
    -o measured.csv --gcp-out gcps.csv``: 15 targets measured (the blunder reported as no target), a GCP
    file resect reads."""
    from photax.cli import main
    from photax.io import read_gcps

    out, gcps = tmp_path / "measured.csv", tmp_path / "gcps.csv"
    code = main(
        [
            "measure",
            str(DATA / "sample_image.tif"),
            "--targets",
            str(DATA / "sample_gcps.csv"),
            "--radius",
            "6",
            "-o",
            str(out),
            "--gcp-out",
            str(gcps),
        ]
    )
    text = capsys.readouterr().out
    assert code == 1 and "15 ok, 1 no target found" in text and "no texture" not in text
    assert len(read_gcps(gcps).names) == 15
