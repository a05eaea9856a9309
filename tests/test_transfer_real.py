"""photax.transfer_points on real images (issue 21): orthority's test corpus in ../shared/data/orthority
(skipped cleanly when absent), the fixtures of test_ties_real.

Points are measured in one frame (its strongest Förstner points, as a surveyor picks well-defined
points), their ground coordinates are where the survey's orientation puts them on the DEM, and they
are transferred into the other frames from orientations perturbed as in test_ties_real.  Truth: the
projection of the same ground points through the survey's orientations.  That truth is only as good
as the DEM along the epipolar line (the height of a ground point shifts its image along it, by
1 px per ~6.6 m of height on the NGI cross-strip pair), so the distance across the true epipolar
line (independent of the DEM) is checked on its own, tighter.

* NGI: from frame 05_0182 into 06_0253, the next strip flown the opposite way (kappa ~180 deg apart).
* ODM: from drone image 0142 (kappa 2 deg) into the images turned by 90, 176 and -94 deg in kappa
  (all 30 deg off nadir in four directions).
* Bad input: a point outside the other image, a ground point no image sees, a reference pixel
  outside its image.
"""

import numpy as np
import pytest
from test_ties_real import _perturbed, ngi, odm  # noqa: F401 (the fixtures)

from photax.collinearity import stack_exteriors
from photax.matching import monoplot_pixels, project_pixels, transfer_points
from photax.matching.transfer import STATUSES


def _points(image, exterior, camera, dem, seen_in, n):
    """The ``n`` strongest Förstner points of ``image`` whose ground point (``exterior`` on the DEM)
    images at least 30 px inside ``seen_in`` (a list of orientations): pixels and ground."""
    from photax.measure import interest_points

    xy = np.asarray(interest_points(image, "foerstner", window=5, min_distance=20, max_points=400).xy)
    g = monoplot_pixels(xy[None], stack_exteriors([exterior]), camera, dem)[0]
    w, h = camera.image_size
    px = project_pixels(g, stack_exteriors(seen_in), camera)
    ok = np.any(np.all((px >= 30) & (px <= [w - 31, h - 31]), axis=2), axis=0) & np.all(np.isfinite(g), axis=1)
    keep = np.flatnonzero(ok)[:n]
    return xy[keep], g[keep]


def _errors(tr, k, camera, ground, truth, ref):
    """Transferred minus true pixels in image ``k`` (``(q, 2)``) and their distance across the true
    epipolar line of the reference ray (``(q,)``), px."""
    items = [it for it in tr.items if it["image"] == str(k)]
    p = np.array([q for q, it in enumerate(items) if it["status"] == "ok"], dtype=int)
    eo = stack_exteriors(truth)
    centre = np.asarray(truth[ref].position)
    true = project_pixels(ground[p], eo, camera)[k]
    near = project_pixels(centre + 0.9 * (ground[p] - centre), eo, camera)[k]  # another point of the ray
    d = np.array([items[q]["xy"] for q in p]).reshape(-1, 2) - true
    u = (near - true) / np.linalg.norm(near - true, axis=1)[:, None]
    return d, u[:, 0] * d[:, 1] - u[:, 1] * d[:, 0]


def _rms(v):
    return float(np.sqrt(np.mean(np.sum(np.reshape(v, (len(v), -1)) ** 2, axis=1))))


def test_ngi_transfer_into_the_opposite_strip(ngi):  # noqa: F811
    """From 05_0182 into 06_0253 (kappa ~180 deg apart, base ~4.2 km at ~4 km above the terrain):
    >= 5 of 40 points measured, sub-pixel against the survey (2-D RMS < 1 px), <= 0.5 px RMS across
    the epipolar line; every other (point, image) item has a reason, and the points the survey
    predicts >= 20 px outside an image are "not in image" there."""
    camera, dem, truth = ngi["camera"], ngi["dem"], ngi["truth"]
    xy, ground = _points(ngi["images"][0], truth[0], camera, dem, [truth[3]], 40)
    start = _perturbed(truth, 15.0, 0.15, seed=21)
    tr = transfer_points(
        ngi["images"], camera, start, dem, ground, reference_image=np.zeros(len(ground), int), reference_xy=xy
    )
    assert all(it["status"] in STATUSES for it in tr.items)
    d, across = _errors(tr, 3, camera, ground, truth, 0)
    print(f"NGI 05_0182 -> 06_0253: {len(d)}/{len(ground)} transferred, RMS {_rms(d):.2f} px "
          f"(max {np.linalg.norm(d, axis=1).max():.2f}), across the epipolar line {_rms(across):.2f} px")  # fmt: skip
    assert len(d) >= 5
    assert _rms(d) < 1.0 and _rms(across) <= 0.5
    w, h = camera.image_size
    true = project_pixels(ground, stack_exteriors(truth), camera)
    far = np.any((true < -20) | (true > [w + 19, h + 19]), axis=2)  # (m, n)
    status = np.array([it["status"] for it in tr.items]).reshape(len(ground), -1).T
    assert far.any() and np.all(status[far] == "not in image")


def test_odm_transfer_into_rotated_drone_images(odm):  # noqa: F811
    """From image 0142 (kappa 2 deg) into the three others (kappa 90, 176, -94 deg; each 30 deg off
    nadir in its own direction) from OpenSfM's orientations moved by 0.5 m and 0.15 deg: every
    rotated image gets transfers, sub-pixel against OpenSfM's orientations on ODM's DSM (2-D RMS
    < 1 px), <= 0.5 px RMS across the epipolar line."""
    camera, dem, truth = odm["camera"], odm["dem"], odm["truth"]
    xy, ground = _points(odm["images"][3], truth[3], camera, dem, truth[:3], 60)
    start = _perturbed(truth, 0.5, 0.15, seed=21)
    tr = transfer_points(
        odm["images"], camera, start, dem, ground, reference_image=np.full(len(ground), 3), reference_xy=xy
    )
    all_d, all_across = [], []
    for k in range(3):
        d, across = _errors(tr, k, camera, ground, truth, 3)
        print(f"ODM 0142 -> image {k}: {len(d)}/{len(ground)} transferred, RMS {_rms(d):.2f} px, "
              f"across the epipolar line {_rms(across):.2f} px")  # fmt: skip
        assert len(d) >= 1, k
        all_d.append(d)
        all_across.append(across)
    assert _rms(np.concatenate(all_d)) < 1.0 and _rms(np.concatenate(all_across)) <= 0.5


def test_points_no_image_sees_and_references_outside_their_image(ngi):  # noqa: F811
    """A ground point 20 km from the block: "not in image" in every frame; one whose height is to be
    read off the DEM where there is none: "outside DEM"; a reference pixel outside its image: refused."""
    camera, dem, truth = ngi["camera"], ngi["dem"], ngi["truth"]
    e, n = np.asarray(truth[0].position)[:2]
    tr = transfer_points(
        ngi["images"][:2], camera, truth[:2], dem, [[e + 20_000.0, n, 1000.0], [e + 20_000.0, n, np.nan]]
    )
    assert [it["status"] for it in tr.items] == ["not in image"] * 2 + ["outside DEM"] * 2 and len(tr.table) == 0
    with pytest.raises(ValueError, match="outside their reference images"):
        transfer_points(
            ngi["images"][:2],
            camera,
            truth[:2],
            dem,
            [[e, n, 1000.0]],
            reference_image=[0],
            reference_xy=[[-5.0, 10.0]],
        )
