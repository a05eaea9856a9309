"""photax.coregister on real data (issue 24, item 3): two orthos of the NGI frame, one from its
orientation and one from a perturbed copy; the shift field between them is known from the geometry
(each reference ortho pixel's ground point projected with the true orientation, the image point
monoplotted on the DEM with the perturbed one), and the registration must find it to 0.1 px."""

import numpy as np
from conftest import shared_file

import photax as ptx
from photax.collinearity import stack_exteriors
from photax.io import read_dem, read_geotiff, read_orthority_exterior, read_orthority_interior
from photax.matching import monoplot_pixels, project_pixels
from photax.rectification import ortho_grid

IMAGE = "3324c_2015_1004_05_0182_RGB"


def test_shift_field_between_orthos_of_a_true_and_a_perturbed_orientation():
    image = read_geotiff(shared_file(f"{IMAGE}.tif"))[0].astype(float).mean(axis=0)
    camera = read_orthority_interior(shared_file("ngi_int_param.yaml"))["Integraph DMC"]
    exterior = read_orthority_exterior(shared_file("ngi_xyz_opk.csv"))[IMAGE]
    dem = read_dem(shared_file("dem.tif"))
    full = ortho_grid(exterior, camera, dem, resolution=5.0)
    a, b, c, d, e, f = tuple(full.transform)[:6]
    r0, c0, n = full.shape[0] // 2 - 192, full.shape[1] // 2 - 192, 384
    grid = ptx.Grid((a, b, c + a * c0, d, e, f + e * r0), (n, n), crs=full.crs)  # the frame's centre, 5 m px
    perturbed = ptx.ExteriorOrientation(
        np.asarray(exterior.position) + [4.0, -3.0, 2.0],
        np.asarray(exterior.angles) + np.radians([0.01, -0.008, 0.015]),
        exterior.convention,
    )
    ref, _ = ptx.orthorectify(image, exterior, camera, dem, grid, resampling="cubic", approx=0)
    tgt, _ = ptx.orthorectify(image, perturbed, camera, dem, grid, resampling="cubic", approx=0)

    def truth(p):
        x = grid.transform[2] + a * (p[:, 0] + 0.5)
        y = grid.transform[5] + e * (p[:, 1] + 0.5)
        ground = np.c_[x, y, np.asarray(dem.height(x, y))]
        px = project_pixels(ground, stack_exteriors([exterior]), camera)
        g = monoplot_pixels(px, stack_exteriors([perturbed]), camera, dem)[0]
        return np.c_[(g[:, 0] - grid.transform[2]) / a - 0.5, (g[:, 1] - grid.transform[5]) / e - 0.5] - p

    reg = ptx.coregister(ref, tgt, model="tps")
    ok = reg.reliable
    assert ok.sum() >= 30
    expected = truth(reg.centres[ok])
    assert np.ptp(expected, axis=0).max() > 0.2  # a field, not one shift
    err = reg.matches[ok] - reg.centres[ok] - expected
    rms = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    print(f"NGI orthos: shifts {expected.min(0)} .. {expected.max(0)} px, error rms {rms:.3f} px, counts {reg.counts}")
    assert rms <= 0.1
