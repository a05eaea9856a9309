"""Space resection of the real ODM drone GCP list, against OpenCV's solvePnP."""

import cv2
import numpy as np
from conftest import shared_file

import photax as ptx

CAM = ptx.FrameCamera.from_pixels(2904.0, (4000, 3000))  # nominal focal length, centred principal point
K = np.array([[2904.0, 0.0, 1999.5], [0.0, 2904.0, 1499.5], [0.0, 0.0, 1.0]])  # pixel centre = integer


def _images(table):
    return [im for im in table.image_names if (table.images == im).sum() >= 6]


def _opencv_centre_and_rms(ground, pixel, origin):
    ok, rvec, tvec = cv2.solvePnP(ground - origin, pixel, K, None, flags=cv2.SOLVEPNP_ITERATIVE)
    assert ok
    r = cv2.Rodrigues(rvec)[0]
    proj, _ = cv2.projectPoints(ground - origin, rvec, tvec, K, None)
    rms = np.sqrt(np.mean(np.sum((proj[:, 0, :] - pixel) ** 2, axis=1)))
    return origin + (-r.T @ tvec).ravel(), rms


def test_real_gcp_list_resection_matches_opencv():
    table = ptx.read_gcps(shared_file("gcp_list_floatxy_raw.txt"))
    images = _images(table)
    assert len(images) >= 6
    for image in images:
        sub = table.select(image)
        res = ptx.resect(sub.image_plane(CAM), sub.ground, CAM, names=list(sub.names))
        print(
            f"{image}: {len(sub.names)} targets, rms {res.rmse:.2f} px, "
            f"outliers {[n for n, o in zip(sub.names, res.outliers) if o]}"
        )
        assert res.converged
        keep = ~res.outliers
        origin = sub.ground[keep].mean(0)
        ref, ref_rms = _opencv_centre_and_rms(sub.ground[keep], sub.pixel[keep], origin)
        # ~75 m flight height; both minimise the same reprojection error on the same
        # inliers, so photax's RMS (pixel units here) cannot be worse than OpenCV's
        np.testing.assert_allclose(np.asarray(res.exterior.position), ref, atol=1e-3)
        assert res.rmse <= ref_rms * (1 + 1e-6)
        assert 50 < float(res.exterior.Z) - sub.ground[:, 2].mean() < 120


def test_real_duplicate_target_is_a_blunder():
    # IMG_5352 has HV11 twice with different pixels: one of the two is wrong.
    table = ptx.read_gcps(shared_file("gcp_list_floatxy_raw.txt"))
    sub = table.select("IMG_5352.JPG")
    hv11 = np.flatnonzero(np.asarray(sub.names) == "HV11")
    assert len(hv11) == 2
    res = ptx.resect(sub.image_plane(CAM), sub.ground, CAM, names=list(sub.names))
    print(res.summary())
    flagged = [str(n) for n, o in zip(sub.names, res.outliers) if o]
    # one of the two HV11 measurements, and only one; the nominal camera (no distortion
    # model) leaves a few px of model error, so the tau test may flag another target too
    assert flagged.count("HV11") == 1, flagged
    assert "blunder: HV11" in res.summary()
    # the kept HV11 measurement fits, the flagged one does not
    d = np.hypot(*res.residuals[hv11].T)
    assert d.min() < 3 * res.rmse < d.max()
