"""Write docs/_static/sample_ortho.png, the README's and the site's picture, with photax from the
bundled sample (``data/``): the raw image with its GCPs (P07, the planted blunder, in red) and its
orthophoto from the resected orientation.  Run from the repository root:

    python docs/make_figure.py
"""

import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import photax as ptx  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT / "data"


def main(out=ROOT / "docs" / "_static" / "sample_ortho.png"):
    gcps = ptx.read_gcps(DATA / "sample_gcps.csv")
    camera = ptx.read_camera(DATA / "sample_camera.yaml")
    res = ptx.resect(gcps.image_plane(camera), gcps.ground, camera, sigma=gcps.image_plane_sigma(camera),
                     check=gcps.check, names=gcps.names)  # fmt: skip
    image = ptx.read_geotiff(DATA / "sample_image.tif")[0][0]
    dem = ptx.read_dem(DATA / "sample_dem.tif")
    ortho, grid = ptx.orthorectify(image, res.exterior, camera, dem, resolution=1.0, nodata=0)
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6), dpi=80)
    a.imshow(image, cmap="gray")
    bad = np.asarray(res.outliers)
    a.scatter(*gcps.pixel[~bad].T, s=40, facecolors="none", edgecolors="tab:cyan", label="GCP")
    a.scatter(*gcps.pixel[bad].T, s=60, marker="x", color="tab:red", label="blunder (flagged)")
    a.set_title("sample image and its GCPs")
    a.legend(loc="lower right", fontsize=8)
    x0, x1, y0, y1 = grid.bounds[0], grid.bounds[2], grid.bounds[1], grid.bounds[3]
    b.imshow(np.ma.masked_equal(ortho, 0), cmap="gray", extent=(x0, x1, y0, y1))
    b.set_title("photax orthophoto (1 m, on the DEM)")
    b.set_xlabel("E [m]")
    b.set_ylabel("N [m]")
    b.ticklabel_format(useOffset=False, style="plain")
    b.tick_params(labelsize=7)
    a.set_xticks([])
    a.set_yticks([])
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    print("wrote", out)


if __name__ == "__main__":
    main()
