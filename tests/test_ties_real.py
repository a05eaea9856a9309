"""photax.match_ties on real images (issue 21, item 2): orthority's test corpus in ../shared/data/orthority
(skipped cleanly when absent).

* NGI: four aerial frames in two strips flown in opposite directions (kappa ~180 deg apart), from the
  survey's orientations (``io/ngi_xyz_opk.csv``) moved by 15 m and turned by 0.15 deg (seeded random
  directions).  Independent checks: the ties' count on every pair whose footprints overlap, and the
  tie residuals of a GNSS-aided bundle (positions = the survey's + N(0, 2 m), sigma 2 m, as
  benchmarks/gnss_ngi.py) started from the perturbed orientations.
* ODM: four drone images looking 30 deg off nadir in four directions (kappa 0, 90, 180, -94 deg), from
  OpenSfM's orientations moved by 0.5 m and 0.15 deg: 15 m, the aerial perturbation, is ~140 px at
  their ~0.1 m pixel, far beyond any search window (a test below says so per pair).
* Bad input: images whose footprints do not overlap, and a perturbation too large to match, get a
  status per pair with the predicted overlap.
"""

import numpy as np
import pytest
from conftest import SHARED_DATA

DATA = SHARED_DATA / "orthority"


def _grey(path):
    import warnings

    import rasterio

    with warnings.catch_warnings():  # the drone images are not georeferenced
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(path) as src:
            return src.read().astype(float).mean(axis=0)


def _perturbed(exteriors, metres, degrees, seed):
    import photax

    rng = np.random.default_rng(seed)
    out = []
    for e in exteriors:
        d, a = rng.normal(size=3), rng.normal(size=3)
        out.append(
            photax.ExteriorOrientation(
                np.asarray(e.position) + metres * d / np.linalg.norm(d),
                np.asarray(e.angles) + np.radians(degrees) * a / np.linalg.norm(a),
                e.convention,
            )
        )
    return out


@pytest.fixture(scope="module")
def ngi():
    if not (DATA / "ngi" / "dem.tif").is_file():
        pytest.skip("../shared/data/orthority is not present")
    from photax.io import read_dem, read_orthority_exterior, read_orthority_interior

    camera = next(iter(read_orthority_interior(DATA / "io" / "ngi_int_param.yaml").values()))
    survey = read_orthority_exterior(DATA / "io" / "ngi_xyz_opk.csv")
    names = sorted(p.stem for p in (DATA / "ngi").glob("*_RGB.tif"))
    images = [_grey(DATA / "ngi" / f"{n}.tif") for n in names]
    truth = [survey[n] for n in names]
    return dict(camera=camera, images=images, truth=truth, dem=read_dem(DATA / "ngi" / "dem.tif"), names=names)


@pytest.fixture(scope="module")
def ngi_ties(ngi):
    from photax.matching import match_ties

    start = _perturbed(ngi["truth"], 15.0, 0.15, seed=21)
    ties = match_ties(ngi["images"], ngi["camera"], start, ngi["dem"], max_points=300, min_rho=0.6)
    return ties, start


def test_ngi_ties_across_opposite_strips(ngi, ngi_ties):
    """Every pair of frames overlaps (12-38 %): the pairs of one strip, the pairs across the strips
    (flown the opposite way, kappa ~180 deg apart) and the two diagonal pairs (12-13 % overlap at a
    base of ~4.9 km over mountains; OpenCV SIFT finds 15 and 40 RANSAC inliers there) each get >= 20
    ties."""
    ties, _ = ngi_ties
    names = ngi["names"]
    assert len(ties.pair_overlap) == 6
    for (i, j), ov in ties.pair_overlap.items():
        assert ov > 0.1, (names[i], names[j], ov)
        assert ties.pair_ties[i, j] >= 20, (names[i], names[j], ties.pair_ties[i, j])
        assert ties.pair_status[i, j] == "ok"


def test_ngi_ties_fit_a_gnss_aided_bundle(ngi, ngi_ties):
    """Ties + GNSS positions (survey + N(0, 2 m), sigma 2 m), attitudes free from 0.15 deg off:
    the tie residuals after the adjustment <= 0.3 px RMS, and no tie over 1.5 px (no false match); the
    angles' sigma at the floor the GNSS alone sets (benchmarks/gnss_ngi.py)."""
    import photax
    from photax.matching import bundle_problem

    ties, start = ngi_ties
    camera = ngi["camera"]
    truth = np.array([np.asarray(e.position) for e in ngi["truth"]])
    gnss = truth + 2.0 * np.random.default_rng(2).standard_normal(truth.shape)
    problem = bundle_problem(camera, start, ties).replace(gnss_position=gnss, gnss_sigma=2.0)
    res = photax.bundle_adjust(problem, throw=False)
    pixel = float(np.mean(np.asarray(camera.pixel_size)))
    r = np.linalg.norm(res.residuals, axis=1) / pixel
    assert np.sqrt(np.mean(r**2)) <= 0.3, np.sqrt(np.mean(r**2))
    assert r.max() <= 1.5, r.max()
    # What the block can determine: its angles rest on the GNSS, which lets even a rigid block (perfect
    # ties) turn about its centroid by sigma^2 = 2 m^2 (sum |c|^2 I - c c^T)^-1 (c: the cameras from their
    # centroid; E, N, up = omega, phi, kappa at these near-nadir attitudes).  The ties' own share of the
    # reported (a-priori) angle sigma is small: within 25 % of that floor, never below it.
    c = truth - truth.mean(axis=0)
    floor = 2.0 * np.sqrt(np.diag(np.linalg.inv(np.sum(c**2) * np.eye(3) - c.T @ c)))
    ratio = np.asarray(res.exterior_std)[:, 3:] / res.sigma0 / floor
    assert np.all(ratio >= 0.99) and np.all(ratio <= 1.25), ratio


@pytest.fixture(scope="module")
def odm():
    path = DATA / "odm" / "opensfm" / "reconstruction.json"
    if not path.is_file():
        pytest.skip("../shared/data/orthority/odm is not present")
    from photax.io import read_dem, read_opensfm_cameras, read_opensfm_shots

    cameras = read_opensfm_cameras(path)
    shots, _, camera_of = read_opensfm_shots(path)
    names = sorted(shots)
    images = [_grey(DATA / "odm" / "images" / f"{n}.tif") for n in names]
    dem = read_dem(DATA / "odm" / "odm_dem" / "dsm.tif")
    return dict(camera=cameras[camera_of[names[0]]], images=images, truth=[shots[n] for n in names], dem=dem)


def test_odm_rotated_oblique_drone_images(odm):
    """Every pair whose footprints overlap by >= 20 % gets >= 20 ties, though the views differ by
    90 or 180 deg in kappa and look 30 deg off nadir in four directions; the ties fit a bundle with
    OpenSfM's positions as GNSS (sigma 0.1 m) to <= 0.3 px RMS, none over 1.5 px."""
    import photax
    from photax.matching import bundle_problem, match_ties

    start = _perturbed(odm["truth"], 0.5, 0.15, seed=21)
    camera = odm["camera"]
    ties = match_ties(odm["images"], camera, start, odm["dem"], max_points=450, min_rho=0.6)
    big = [pr for pr, ov in ties.pair_overlap.items() if ov >= 0.2]
    assert len(big) >= 4
    for pr in big:
        assert ties.pair_ties[pr] >= 20, (pr, ties.pair_ties[pr], ties.pair_overlap[pr])
    gnss = np.array([np.asarray(e.position) for e in odm["truth"]])
    res = photax.bundle_adjust(bundle_problem(camera, start, ties).replace(gnss_position=gnss, gnss_sigma=0.1))
    pixel = float(np.mean(np.asarray(camera.pixel_size)))
    r = np.linalg.norm(res.residuals, axis=1) / pixel
    assert np.sqrt(np.mean(r**2)) <= 0.3 and r.max() <= 1.5, (np.sqrt(np.mean(r**2)), r.max())


def test_no_overlap_and_too_large_a_perturbation_are_said_per_pair(ngi):
    """Frames 0184 and 0253 with 0253 moved 3 km south: no overlap predicted.  The survey's pair of one
    strip moved by 150 m and 1.5 deg: the predicted overlap stays but the matches fail."""
    import photax
    from photax.matching import match_ties

    (i, j) = (1, 3)
    e = ngi["truth"][j]
    away = photax.ExteriorOrientation(np.asarray(e.position) + [0.0, -3000.0, 0.0], e.angles, e.convention)
    ties = match_ties([ngi["images"][i], ngi["images"][j]], ngi["camera"], [ngi["truth"][i], away], ngi["dem"])
    assert ties.pair_status[0, 1] == "no overlap" and ties.pair_overlap[0, 1] == 0.0
    start = _perturbed(ngi["truth"][:2], 150.0, 1.5, seed=3)
    ties = match_ties(ngi["images"][:2], ngi["camera"], start, ngi["dem"])
    assert ties.pair_status[0, 1] == "too few matches" and ties.pair_overlap[0, 1] > 0.1
    assert ties.pair_ties[0, 1] < 6 and ties.n_tracks == 0
