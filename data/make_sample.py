"""Write the photax sample scene into this folder (run: ``python data/make_sample.py``).

The scene is synthetic and seeded (see :func:`photax.demo.sample_scene`):
sample_gcps.csv, sample_camera.yaml and sample_truth.json.  ``photax demo``
regenerates the same files in its own output folder.
"""

import pathlib

from photax.demo import write_sample

if __name__ == "__main__":
    for kind, path in write_sample(pathlib.Path(__file__).resolve().parent).items():
        print(f"{kind:7s} {path}")
