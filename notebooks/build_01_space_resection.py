"""Write notebooks/01_space_resection.ipynb (without outputs).

Run: ``python notebooks/build_01_space_resection.py``.  The notebook is
committed without outputs; tests/test_notebooks.py executes it.
"""

from _build import FIND_SHARED, write_notebook

CELLS = [
    (
        "md",
        """# Space resection of one image

Estimate the exterior orientation (projection centre and attitude) of one image from ground
control points (GCPs) with `photax.resect`, and look at what the result says about itself:
precision, correlations, residuals and blunders.

Data: the OpenDroneMap GCP list of a real drone survey (19 painted targets measured with
geodetic GPS, sub-pixel image coordinates; `../../shared/data/gcp_list_floatxy_raw.txt`) when
it is available, otherwise photax's synthetic sample (`../data/`).""",
    ),
    (
        "code",
        """import pathlib
import tempfile

import matplotlib.pyplot as plt
import numpy as np

import photax as ptx
from photax import plot


"""
        + FIND_SHARED
        + """

odm = find_shared("gcp_list_floatxy_raw.txt")
if odm is not None:
    gcps = ptx.read_gcps(odm)
    # Canon PowerShot SX260 HS: f = 4.5 mm, about 2904 px on the 4000 x 3000 images
    # (the survey's README); no calibration is published, so no distortion.
    camera = ptx.FrameCamera.from_pixels(2904.0, (4000, 3000))
    image = "IMG_5357.JPG"
else:
    data = pathlib.Path.cwd().parent / "data"
    if not (data / "sample_gcps.csv").is_file():  # photax installed without the repository
        from photax.demo import write_sample
        data = pathlib.Path(tempfile.mkdtemp())
        write_sample(data)
    gcps = ptx.read_gcps(data / "sample_gcps.csv")
    camera = ptx.read_camera(data / "sample_camera.yaml")
    image = "IMG_0001"
print(gcps.source, "| CRS:", gcps.crs)
print({name: int((gcps.images == name).sum()) for name in gcps.image_names})
for note in gcps.duplicates():
    print("note:", note)""",
    ),
    (
        "md",
        """The file holds pixels (column, row; integer = pixel centre, row down). `resect` wants
image-plane coordinates (x right, y up, in the camera's unit), so the table converts them
with the camera: `table.image_plane(camera)`.""",
    ),
    (
        "code",
        """pts = gcps.select(image)
pixel_size = float(np.asarray(camera.pixel_size)[0])
result = ptx.resect(pts.image_plane(camera), pts.ground, camera, check=pts.check, names=pts.names)
print(result.summary())""",
    ),
    (
        "md",
        """## Residuals on the image

Arrows go from where the model puts a point to where it was measured (observed minus computed, i.e. minus the residuals photax reports, docs/conventions.md), exaggerated; the key gives their scale.
Systematic patterns (all arrows pointing outwards, say) hint at an unmodelled lens
distortion rather than at bad measurements. With the ODM survey the camera has no published
calibration, so the residuals of a few pixels are mostly that; the synthetic sample's known
camera leaves only its 0.3 px noise (and a planted blunder on P07).""",
    ),
    (
        "code",
        """res_px = result.residuals / pixel_size * np.array([1.0, -1.0])  # image plane (y up) -> (column, row)
fig, ax = plt.subplots(figsize=(8, 6))
plot.residual_vectors(ax, pts.pixel, res_px, pts.names, outliers=result.outliers, check=result.check,
                      image_size=camera.image_size, title=f"{image}: residuals")
plt.show()""",
    ),
    (
        "md",
        """## Precision

`sigma0` scales the cofactor matrix to the covariance of the six parameters. The projection
centre's height and the tilts are typically strongly correlated with the horizontal position
for a near-vertical image: the heat map shows by how much.""",
    ),
    (
        "code",
        """fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4), gridspec_kw={"width_ratios": [1.3, 1]})
plot.precision_table(ax1, result, title=f"sigma0 = {result.sigma0:.3g}")
plot.correlation_matrix(ax2, result.correlation, ["X", "Y", "Z", "phi", "omega", "kappa"])
plt.show()""",
    ),
    (
        "md",
        """## Blunders

Data snooping tests each residual against its own standard deviation and excludes the worst
point while a test fails. Plant a 20 px error on one point and see whether it is found, and
what it would have done to the orientation without the test (`robust=False`).""",
    ),
    (
        "code",
        """k = len(pts) // 2
bad_xy = np.array(pts.image_plane(camera))
bad_xy[k, 0] += 20 * pixel_size
found = ptx.resect(bad_xy, pts.ground, camera, check=pts.check, names=pts.names)
plain = ptx.resect(bad_xy, pts.ground, camera, check=pts.check, names=pts.names, robust=False)
print("planted on:", pts.names[k], "| flagged:", [str(n) for n in np.asarray(found.names)[found.outliers]])
for label, r in (("with data snooping", found), ("plain least squares", plain)):
    shift = np.linalg.norm(np.asarray(r.exterior.position) - np.asarray(result.exterior.position))
    print(f"{label:>20}: centre moved {shift:.3f} m, sigma0 = {r.sigma0:.3g}")""",
    ),
    (
        "md",
        """## Angle conventions

photax's default is phi-omega-kappa (primary axis Y, the Chinese and German textbooks);
most Western software and aerial-triangulation exports use omega-phi-kappa (primary axis X).
The angles differ, the rotation is the same. Never mix them up: name the convention.""",
    ),
    (
        "code",
        """opk = ptx.resect(pts.image_plane(camera), pts.ground, camera, check=pts.check, names=pts.names,
             convention="omega-phi-kappa")
for label, e in (("phi-omega-kappa", result.exterior), ("omega-phi-kappa", opk.exterior),
                 ("pok converted to opk", result.exterior.to_convention("omega-phi-kappa"))):
    print(f"{label:>20} [deg]:", np.degrees(np.asarray(e.angles)).round(5))
print("max |R_pok - R_opk| =", float(np.abs(np.asarray(result.exterior.rotation) - np.asarray(opk.exterior.rotation)).max()))""",
    ),
]


if __name__ == "__main__":
    write_notebook(CELLS, "01_space_resection.ipynb")
