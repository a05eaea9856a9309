"""Orthorectification of the real NGI aerial frame, against orthority.

orthority (an independent orthorectifier, test-only dependency) and photax
get the same image, DEM, interior and exterior orientation, the same output
grid (orthority's, passed to photax) and the same kernels (bilinear DEM
heights, nearest/bilinear grey values).

The DEM's CRS is compound (horizontal + EGM2008 heights) while the
orientation's .prj is horizontal only; orthority would then shift the DEM
heights to the ellipsoid through PROJ's geoid grid, which needs the network.
Both tools are given a copy of the DEM (in tmp_path) tagged with the .prj CRS
instead, i.e. the heights as stored, which is what photax uses.
"""

import numpy as np
import pytest
import rasterio
from conftest import shared_file

import photax
from photax.cli import main
from photax.io import read_dem, read_geotiff, read_orthority_exterior, read_orthority_interior
from photax.rectification import Grid

IMAGE = "3324c_2015_1004_05_0182_RGB"


@pytest.fixture(scope="module")
def ngi(tmp_path_factory):
    image = shared_file(f"{IMAGE}.tif")
    csv = shared_file("ngi_xyz_opk.csv")
    prj = shared_file("ngi_xyz_opk.prj").read_text()
    interior = shared_file("ngi_int_param.yaml")
    tmp = tmp_path_factory.mktemp("ngi")
    with rasterio.open(shared_file("dem.tif")) as src:
        profile, heights = src.profile, src.read()
    profile.update(crs=rasterio.CRS.from_string(prj))
    dem = tmp / "dem.tif"
    with rasterio.open(dem, "w", **profile) as dst:
        dst.write(heights)
    return dict(image=image, csv=csv, prj=prj, interior=interior, dem=dem, tmp=tmp)


def _orthority_camera(ngi, cx=0.0, cy=0.0):
    from orthority.camera import PinholeCamera

    with open(ngi["csv"]) as fh:
        row = next(ln.split(",") for ln in fh if ln.startswith(IMAGE))
    x, y, z, omega, phi, kappa = (float(v) for v in row[1:7])
    return PinholeCamera(
        (640, 1152), 120.0, (92.16, 165.888), cx, cy, xyz=(x, y, z), opk=tuple(np.radians([omega, phi, kappa]))
    )


def test_orthority_conventions_project_identically(ngi, tmp_path):
    """Orthority's own camera model and photax's, read from the same files,
    put ground points on the same pixels: its omega-phi-kappa and camera frame
    are photax's "omega-phi-kappa" world_from_camera, and both put integer
    pixel coordinates at pixel centres, so no half-pixel shift is needed."""
    exterior = read_orthority_exterior(ngi["csv"])[IMAGE]
    rng = np.random.default_rng(0)
    ground = np.column_stack(
        [rng.uniform(-57000, -53000, 200), rng.uniform(-3730500, -3724500, 200), rng.uniform(0, 900, 200)]
    )
    # The file's camera, and one with a principal point offset (cx, cy) to
    # pin down orthority's normalisation and sign of cy.
    yaml = tmp_path / "int.yaml"
    yaml.write_text(
        "offset cam:\n  type: pinhole\n  im_size: [640, 1152]\n  focal_len: 120.0\n"
        "  sensor_size: [92.16, 165.888]\n  cx: 0.013\n  cy: -0.021\n"
    )
    for path, name, cx, cy in [(ngi["interior"], "Integraph DMC", 0.0, 0.0), (yaml, "offset cam", 0.013, -0.021)]:
        camera = read_orthority_interior(path)[name]
        ref = _orthority_camera(ngi, cx, cy).world_to_pixel(ground.T).T
        ours = np.asarray(camera.image_to_pixel(photax.project(ground, exterior, camera)))
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-6)
        assert np.ptp(ref[:, 0]) > 300  # the points spread over the image


def test_orthority_reader_errors(tmp_path):
    bad = tmp_path / "ext.csv"
    bad.write_text("filename,x,y,z,omega,phi,kappa\nimg1,1,2,3,0.1,0.2\n")
    with pytest.raises(ValueError, match="line 2"):
        read_orthority_exterior(bad)
    cam = tmp_path / "int.yaml"
    cam.write_text("c:\n  type: rpc\n  im_size: [10, 10]\n  focal_len: 1.0\n")  # fisheye is read (issue 22)
    with pytest.raises(ValueError, match="pinhole"):
        read_orthority_interior(cam)


@pytest.mark.parametrize("resampling, max_mad", [("nearest", 0.05), ("bilinear", 0.5)])
def test_ngi_ortho_agrees_with_orthority(ngi, resampling, max_mad):
    from orthority.ortho import Ortho

    out = ngi["tmp"] / f"orthority_{resampling}.tif"
    Ortho(ngi["image"], ngi["dem"], _orthority_camera(ngi), crs=ngi["prj"]).process(
        out,
        resolution=(6.0, 6.0),
        interp=resampling,
        dem_interp="bilinear",
        compress="deflate",
        write_mask=False,
        overwrite=True,
    )
    with rasterio.open(out) as ds:
        ref, grid = ds.read(), Grid(ds.transform, ds.shape, ds.crs)
    image, _ = read_geotiff(ngi["image"])
    camera = read_orthority_interior(ngi["interior"])["Integraph DMC"]
    exterior = read_orthority_exterior(ngi["csv"])[IMAGE]
    # orthority maps every pixel exactly: so does photax with approx=0.
    ours, g = photax.orthorectify(image, exterior, camera, read_dem(ngi["dem"]), grid, resampling=resampling, approx=0)
    assert g is grid and ours.shape == ref.shape == (3, 1166, 653)
    valid_ours, valid_ref = ours[0] != 0, ref[0] != 0
    both = valid_ours & valid_ref
    # Same footprint, up to a rim: OpenCV's BORDER_TRANSPARENT drops samples
    # within half a pixel of the image edge, photax keeps them.
    assert (valid_ours ^ valid_ref).sum() < 0.005 * both.sum()
    diff = np.abs(ours.astype(float) - ref)[:, both]
    # Measured: nearest MAD 0.0004 grey levels (a handful of x.5 rounding
    # ties), bilinear 0.12 (OpenCV rounds the fractions to 1/32 pixel and
    # the weights to 1/1024; photax interpolates in float32).
    assert diff.mean() < max_mad
    assert np.percentile(diff, 99) <= (0 if resampling == "nearest" else 1)


def test_cli_ortho_on_ngi(ngi, tmp_path):
    out = tmp_path / "ortho.tif"
    rc = main(
        [
            "ortho",
            str(ngi["image"]),
            "--dem",
            str(ngi["dem"]),
            "--interior",
            str(ngi["interior"]),
            "--exterior",
            str(ngi["csv"]),
            "--out",
            str(out),
            "--resolution",
            "12",
            "--no-progress",
        ]
    )
    assert rc == 0
    with rasterio.open(out) as ds:
        assert ds.res == (12.0, 12.0) and ds.count == 3
        assert ds.crs == rasterio.CRS.from_string(ngi["prj"])
        data = ds.read()
    assert 0.8 < np.mean(data[0] != 0) <= 1.0  # the footprint fills the grid
    # Refuses to overwrite an input.
    assert (
        main(
            [
                "ortho",
                str(ngi["image"]),
                "--dem",
                str(ngi["dem"]),
                "--interior",
                str(ngi["interior"]),
                "--exterior",
                str(ngi["csv"]),
                "--out",
                str(ngi["dem"]),
                "--no-progress",
            ]
        )
        == 2
    )
