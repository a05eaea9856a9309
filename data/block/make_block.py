"""Write the synthetic block sample of this folder (``photax bundle data/block``).

Two strips of four 4000 x 3000 px frames (f = 3000 px) flown 630 m over
terrain of 0..60 m, 6 control points (fixed), 4 check points, ~100 tie
points measured with 0.5 px noise.  Start orientations are the truth
perturbed by ~5 m and ~0.6 degrees; tie points have no coordinates (they are
intersected).  The truth is written to ``truth.json`` for comparison.

Run from the repository root: ``python data/block/make_block.py``.
"""

import csv
import json
import pathlib

import numpy as np

from photax.scene import synthetic_block

HERE = pathlib.Path(__file__).resolve().parent


def main() -> None:
    problem, truth = synthetic_block(0, noise_px=0.5)
    cam = problem.cameras[0]
    eo = problem.exterior
    meta = {
        "convention": eo.convention,
        "angle_unit": "degrees",
        "cameras": {"cam": {"focal_length_px": float(cam.focal_length), "image_size": list(cam.image_size)}},
        "images": [
            {"name": n, "camera": "cam", "position": np.round(np.asarray(eo.position[i]), 3).tolist(),
             "angles": np.round(np.degrees(np.asarray(eo.angles[i])), 5).tolist()}
            for i, n in enumerate(problem.image_names)
        ],
    }  # fmt: skip
    (HERE / "block.json").write_text(json.dumps(meta, indent=1) + "\n")
    px = np.asarray(cam.image_to_pixel(problem.obs_xy))
    with open(HERE / "observations.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["image", "point", "col", "row", "sigma_px"])
        for i, p, (c, r) in zip(problem.obs_image, problem.obs_point, px):
            w.writerow([problem.image_names[i], problem.point_names[p], f"{c:.3f}", f"{r:.3f}", 0.5])
    with open(HERE / "points.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["name", "X", "Y", "Z", "role", "sigma"])
        for n, role, xyz in zip(problem.point_names, problem.roles, problem.points):
            coords = ["", "", ""] if role == "tie" else [f"{v:.3f}" for v in xyz]
            w.writerow([n, *coords, role, 0 if role == "control" else ""])
    (HERE / "truth.json").write_text(json.dumps({
        "convention": truth.exterior.convention,
        "images": {n: {"position": np.asarray(truth.exterior.position[i]).tolist(),
                       "angles_deg": np.degrees(np.asarray(truth.exterior.angles[i])).tolist()}
                   for i, n in enumerate(problem.image_names)},
        "points": {n: p.tolist() for n, p in zip(problem.point_names, truth.points)},
    }, indent=1) + "\n")  # fmt: skip


if __name__ == "__main__":
    main()
