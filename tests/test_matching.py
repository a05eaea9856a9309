"""GCP transfer, tie points and the bundle adjustment they feed, on a rendered 3 x 3 block.

Truth: the orientations the images were rendered with (photax.scene.render_image)
and the DEM.  The start orientations are the truth moved by 5 m and turned by
1 degree (random directions).  GCPs are known only on the ground and found by
a drawn target template; nothing is measured by hand.  Independent checks:
every tie observation against the truth (first observation monoplotted with
the true orientation, projected with the true one), the adjusted orientations
against the truth within 3 x their reported std, check points against their
surveyed coordinates, the ODM list read back by photax.io.read_gcps.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

import photax
from photax.collinearity import stack_exteriors
from photax.io import read_gcps
from photax.matching import bundle_problem, match_ties, monoplot_pixels, project_pixels, transfer_points
from photax.scene import render_image

X0, Y0 = 500_000.0, 4_000_000.0
W, H = 300, 200
CAM = photax.FrameCamera.from_pixels(300.0, (W, H))
FLY = 320.0
GSD = (FLY - 25.0) / 300.0  # m/px at the mean terrain height
SEARCH = 15  # px: covers the prediction error of 5 m / 1 degree at this scale


def _dem():
    n, cell = 330, 2.0
    c = -330 + cell * (np.arange(n) + 0.5)
    xx, yy = c[None, :], c[:, None]
    h = 20 + 15 * np.exp(-((xx - 40) ** 2 + (yy + 30) ** 2) / (2 * 90.0**2)) + 0.02 * xx
    return photax.DEM(h, (cell, 0.0, X0 - 330, 0.0, -cell, Y0 + 330))


def _unit(v):
    return v / np.linalg.norm(v)


@pytest.fixture(scope="module")
def block():
    dem = _dem()
    base, side = 0.4 * W * GSD, 0.7 * H * GSD  # 60 % forward, 30 % side overlap
    rng = np.random.default_rng(3)
    truth = [
        photax.ExteriorOrientation(
            [X0 + (c - 1) * base, Y0 + (1 - r) * side, FLY + rng.uniform(-3, 3)], np.radians(rng.uniform(-1, 1, 3))
        )
        for r in range(3)
        for c in range(3)
    ]
    gx = X0 + np.array([-1.0, 0.1, 1.0, -0.9, 0.0, 1.1]) * base
    gy = Y0 + np.array([0.6, 0.5, 0.65, -0.6, -0.55, -0.5]) * side
    gcp = np.column_stack([gx, gy, np.asarray(dem.height(jnp.asarray(gx), jnp.asarray(gy)))])
    images = [
        render_image(
            CAM, e, dem, origin=(X0, Y0), targets=gcp, target_radius=5.0, supersample=3, blur=0.5, noise=0.005, seed=k
        )
        for k, e in enumerate(truth)
    ]
    start = [
        photax.ExteriorOrientation(
            np.asarray(e.position) + 5.0 * _unit(rng.normal(size=3)),
            np.asarray(e.angles) + np.radians(1.0) * _unit(rng.normal(size=3)),
        )
        for e in truth
    ]
    # the target as drawn on a survey sheet: a quartered disc of 5 m, at the GSD, north up
    k = np.arange(-10, 11) * GSD
    xx, yy = np.meshgrid(k, -k)
    template = np.where(np.hypot(xx, yy) < 5.0, 0.5 + 0.45 * np.tanh(xx / 0.4) * np.tanh(yy / 0.4), 0.5)
    roles = ["control"] * 4 + ["check"] * 2
    transfer = transfer_points(
        images, CAM, start, dem, gcp, target_template=template, roles=roles, search=SEARCH, crs="EPSG:32633"
    )
    ties = match_ties(images, CAM, start, dem, search=SEARCH)
    return dem, truth, start, images, gcp, transfer, ties


def test_transferred_gcps_and_ties_match_the_truth(block):
    dem, truth, _, _, gcp, transfer, ties = block
    eo = stack_exteriors(truth)
    true_px = project_pixels(gcp, eo, CAM)
    t = transfer.table
    assert len(set(t.names.tolist())) >= 5 and len(t) >= 15, [it["status"] for it in transfer.items]
    k = t.images.astype(int)
    p = np.array([int(n[3:]) - 1 for n in t.names])
    err = t.pixel - true_px[k, p]
    assert np.sqrt(np.mean(err**2)) <= 0.15, err  # px: template reference ~0.1 px, transfers ~0.01 px on top
    assert np.all(np.abs(err) <= 4 * t.sigma[:, None] + 0.05)
    # ties: the first observation of each track carried to the ground and into the others with the truth
    assert ties.n_tracks >= 200 and sum(v == "ok" for v in ties.pair_status.values()) >= 12, ties.pair_status
    first = np.array([np.flatnonzero(ties.obs_point == q)[0] for q in range(ties.n_tracks)])
    g = monoplot_pixels(np.broadcast_to(ties.obs_xy[first], (9, len(first), 2)), eo, CAM, dem)
    g = g[ties.obs_image[first], np.arange(len(first))]
    other = np.setdiff1d(np.arange(len(ties.obs_image)), first)
    pred = project_pixels(g, eo, CAM)[ties.obs_image[other], ties.obs_point[other]]
    e = ties.obs_xy[other] - pred
    assert np.max(np.abs(e)) <= 0.2 and np.sqrt(np.mean(e**2)) <= 0.03, (np.abs(e).max(), np.sqrt(np.mean(e**2)))


def test_the_sensor_form_gives_the_frame_forms_ties(block):
    # match_ties(images, sensors, dem) with one FrameSensor per start orientation is the frame form
    # match_ties(images, camera, exterior, dem): the same tracks, pixels, sigmas and statuses
    dem, _, start, images, _, _, ties = block
    sensors = [photax.FrameSensor(e, CAM, "EPSG:32633") for e in start]
    new = match_ties(images, sensors, dem, search=SEARCH)
    for f in dataclasses.fields(ties):
        a, b = getattr(ties, f.name), getattr(new, f.name)
        assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b, f.name


def test_bundle_recovers_the_rendering_orientations(block):
    _, truth, start, _, gcp, transfer, ties = block
    problem = bundle_problem(CAM, start, ties, transfer.table)
    res = photax.bundle_adjust(problem)
    assert res.converged, res.message
    eo = stack_exteriors(truth)
    d = np.concatenate(
        [
            np.asarray(res.exterior.position) - np.asarray(eo.position),
            np.asarray(res.exterior.angles) - np.asarray(eo.angles),
        ],
        axis=1,
    )
    assert np.all(np.abs(d) <= 3 * res.exterior_std), np.round(np.abs(d) / res.exterior_std, 1)
    # check points: RMSE per coordinate against GSD x their image-measurement sigma (a posteriori)
    check = transfer.table.role == "check"
    assert len(res.check_residuals) == 2, [it["status"] for it in transfer.items if it["name"] in ("gcp5", "gcp6")]
    sigma_img = res.sigma0 * np.sqrt(np.mean(transfer.table.sigma[check] ** 2))
    rmse = np.sqrt(np.mean(res.check_residuals**2))
    assert rmse <= 1.5 * GSD * sigma_img, (rmse, GSD * sigma_img)


def test_gcp_list_files_read_back(block, tmp_path):
    transfer = block[5]
    t = transfer.table
    for fmt, name in (("csv", "gcps.csv"), ("odm", "gcp_list.txt")):
        back = read_gcps(transfer.write(tmp_path / name, format=fmt))
        np.testing.assert_array_equal(back.names, t.names)
        np.testing.assert_array_equal(back.images, t.images)
        np.testing.assert_allclose(back.pixel, t.pixel, rtol=0, atol=0)
        np.testing.assert_allclose(back.ground, t.ground, rtol=0, atol=0)
        assert back.crs == "EPSG:32633"


def test_bad_input_gets_a_status(block):
    dem, _, start, images, gcp, _, _ = block
    # a textureless image and an orientation 10 km away that sees nothing of the DEM
    far = photax.ExteriorOrientation(np.asarray(start[1].position) + [10_000.0, 0.0, 0.0], start[1].angles)
    ties = match_ties([images[0], np.full((H, W), 0.4), images[1]], CAM, [start[0], start[4], far], dem, search=SEARCH)
    assert block[6].pair_status[0, 8] == "no overlap"  # the block's opposite corners
    assert ties.image_status == ["ok", "textureless", "sees no DEM"]
    assert ties.pair_status[0, 1] == "textureless" and ties.pair_status[0, 2] == "sees no DEM"
    assert ties.n_tracks == 0
    tr = transfer_points([images[0]], CAM, [start[0]], dem, gcp[:1] + [5000.0, 0.0, 0.0])
    assert [it["status"] for it in tr.items] == ["not in image"] and len(tr.table) == 0
    # a GCP measured in image 4 (the library's measurement) transferred into a textureless image and image 3
    t = block[5].table
    row = np.flatnonzero((t.images == "4") & (t.names == "gcp5"))[0]
    tr = transfer_points(
        [images[4], np.full((H, W), 0.4), images[3]],
        CAM,
        [start[4], start[4], start[3]],
        dem,
        gcp[4:5],
        reference_image=[0],
        reference_xy=t.pixel[row : row + 1],
        search=SEARCH,
    )
    assert [it["status"] for it in tr.items] == ["reference", "low correlation", "ok"], tr.items
    with pytest.raises(ValueError, match="exterior"):
        match_ties(images[:2], CAM, start[:1], dem)
    with pytest.raises(ValueError, match="images"):
        match_ties([images[0][:-1]], CAM, start[:1], dem)


def test_cli_transfer_and_ties(block, tmp_path):
    """photax transfer and photax ties in process on the middle strip (images 3, 4, 5): the shapes
    test_bad_input_gets_a_status compiled (match_chunks' batches, 3 orientations), so the commands
    add reading, matching and writing.  ``photax ties --points 50``: the command is under test here, not
    the density of ties (the library test above matches 150 per image); fewer points, less matching."""
    pytest.importorskip("rasterio")
    from photax.cli import main
    from photax.io import write_geotiff

    dem, _, start, images, gcp, transfer, _ = block
    paths, orient = [], {}
    for k in (3, 4, 5):
        p = tmp_path / f"img{k}.tif"
        write_geotiff(p, images[k], (0.5, 0.0, 500000.0, 0.0, -0.5, 4100000.0), compress=None)  # not used
        paths.append(str(p))
        e = start[k]
        orient[f"img{k}"] = {"exterior": {"position": e.position, "angles_rad": e.angles, "convention": e.convention}}
    photax.write_json({"images": orient}, tmp_path / "ext.json")
    photax.write_camera(CAM, tmp_path / "cam.yaml")
    write_geotiff(
        tmp_path / "dem.tif",
        np.asarray(dem.heights),
        np.asarray(dem.transform).tolist(),
        crs="EPSG:32633",
        compress=None,
    )
    # the GCPs the library measured in image 4 (renamed to its file) are transferred to the others
    t = transfer.table.subset(transfer.table.images == "4")
    assert len(t) >= 3
    photax.io.write_gcps(tmp_path / "in.csv", dataclasses.replace(t, images=np.full(len(t), "img4")))
    common = [
        "--camera",
        str(tmp_path / "cam.yaml"),
        "--exterior",
        str(tmp_path / "ext.json"),
        "--dem",
        str(tmp_path / "dem.tif"),
        "--search",
        str(SEARCH),
    ]
    assert main(["transfer", *paths, *common, "--gcps", str(tmp_path / "in.csv"), "-o", str(tmp_path / "out.csv")]) == 0
    out = read_gcps(tmp_path / "out.csv")
    assert set(out.names.tolist()) == set(t.names.tolist()) and len(out) > len(t)
    # each transferred measurement against the truth (the rendering orientation), as the library's are checked
    eo = stack_exteriors(block[1])
    true_px = project_pixels(gcp, eo, CAM)
    k = np.array([int(s[3:]) for s in out.images])
    p = np.array([int(n[3:]) - 1 for n in out.names])
    assert np.sqrt(np.mean((out.pixel - true_px[k, p]) ** 2)) <= 0.15
    assert (
        main(
            [
                "ties",
                *paths,
                *common,
                "--points",
                "50",
                "--gcps",
                str(tmp_path / "out.csv"),
                "-o",
                str(tmp_path / "blk"),
            ]
        )
        == 0
    )
    prob = photax.io.read_block(tmp_path / "blk")  # a block folder: the GCPs stay control points
    assert prob.n_images == 3 and prob.n_observations >= 100 and prob.image_names == ("img3", "img4", "img5")
    ctrl = {n for n, r in zip(prob.point_names, prob.roles) if r != "tie"}
    assert ctrl == set(out.names.tolist()), (ctrl, out.names)
    cam = prob.cameras[0]
    assert cam.focal_length == CAM.focal_length and cam.image_size == CAM.image_size


def test_ties_between_a_frame_and_one_turned_by_180_degrees(block):
    """Image 4 turned by 180 deg in the plane (kappa + pi: the same view, pixel (c, r) at
    (W - 1 - c, H - 1 - r)) still ties to image 3, at the pixels of the unturned pair: the templates
    are warped by the predicted affine map."""
    dem, truth, start, images, _, _, _ = block
    e = start[4]
    turned = photax.ExteriorOrientation(e.position, np.asarray(e.angles) + [0.0, 0.0, np.pi], e.convention)
    g = monoplot_pixels(np.array([[[40.0, 30.0], [250.0, 170.0]]]), stack_exteriors([truth[4]]), CAM, dem)[0]
    xy = project_pixels(g, stack_exteriors([e, turned]), CAM)
    np.testing.assert_allclose(xy[1], [W - 1, H - 1] - xy[0], atol=1e-9)  # kappa + pi is the 180 deg turn
    flipped = images[4][::-1, ::-1]
    plain = match_ties([images[3], images[4]], CAM, [start[3], e], dem, search=SEARCH)
    ties = match_ties([images[3], flipped], CAM, [start[3], turned], dem, search=SEARCH)
    assert ties.pair_ties[0, 1] >= 0.9 * plain.pair_ties[0, 1] >= 20, (ties.pair_ties, plain.pair_ties)
    # the turned image's observations, turned back, are the unturned pair's where both hold a track
    a = {tuple(np.round(plain.obs_xy[k], 6)): plain.obs_point[k] for k in np.flatnonzero(plain.obs_image == 0)}
    pairs = []
    for k in np.flatnonzero(ties.obs_image == 0):
        q = a.get(tuple(np.round(ties.obs_xy[k], 6)))
        if q is not None:
            mine = ties.obs_xy[(ties.obs_point == ties.obs_point[k]) & (ties.obs_image == 1)][0]
            theirs = plain.obs_xy[(plain.obs_point == q) & (plain.obs_image == 1)][0]
            pairs.append([W - 1, H - 1] - mine - theirs)
    d = np.array(pairs)
    assert len(d) >= 0.8 * plain.pair_ties[0, 1] and np.max(np.abs(d)) <= 0.05, (len(d), np.abs(d).max())


def test_transfer_into_a_frame_turned_by_180_degrees(block):
    """GCPs measured in image 3 (their true pixels) transferred into image 4 turned by 180 deg in the plane
    (kappa + pi: pixel (c, r) at (W - 1 - c, H - 1 - r)) from the start orientations: the reference
    window is warped by the predicted affine map (here a half turn), so every GCP that images 3 and
    4 see is measured at its true pixel (the truth turned with the image) to the 0.15 px of the
    unturned transfers above, with the DEM or without one. (The drawn targets look alike after a
    half turn, so an unwarped match would find them too: the real-data test, test_transfer_real, has
    no such luck.)"""
    dem, truth, start, images, gcp, _, _ = block
    turn = lambda e: photax.ExteriorOrientation(e.position, np.asarray(e.angles) + [0.0, 0.0, np.pi], e.convention)  # noqa: E731
    true_px = project_pixels(gcp, stack_exteriors([truth[3], turn(truth[4])]), CAM)
    seen = np.flatnonzero(np.all((true_px > 12) & (true_px < [W - 13, H - 13]), axis=(0, 2)))
    assert len(seen) >= 2
    args = dict(reference_image=np.zeros(len(seen), int), reference_xy=true_px[0, seen], search=SEARCH)
    flipped = images[4][::-1, ::-1]
    tr = transfer_points([images[3], flipped], CAM, [start[3], turn(start[4])], dem, gcp[seen], **args)
    assert [it["status"] for it in tr.items] == ["reference", "ok"] * len(seen), tr.items
    got = np.array([it["xy"] for it in tr.items if it["image"] == "1"])
    err = np.linalg.norm(got - true_px[1, seen], axis=1)
    assert err.max() <= 0.15, err  # px: as the unturned transfers above
    # without a DEM (the heights given) the affine maps come from a level plane through the points
    flat = transfer_points([images[3], flipped], CAM, [start[3], turn(start[4])], None, gcp[seen], **args)
    assert [it["status"] for it in flat.items] == ["reference", "ok"] * len(seen), flat.items
    got = np.array([it["xy"] for it in flat.items if it["image"] == "1"])
    assert np.linalg.norm(got - true_px[1, seen], axis=1).max() <= 0.15
