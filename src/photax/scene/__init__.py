"""Synthetic scenes with known truth -- the one generator of test, demo and example data.

* :func:`relief_scene` (:mod:`._relief`): one aerial frame over hills or flat
  land, rendered image, DEM, control and check points (tests, the rectification
  notebook, the demo's comparison);
* :func:`sample_points` and :func:`render_sample_image` (:mod:`._sample`): the
  sample image and GCPs that ``data/make_sample.py`` and ``photax demo`` write;
* :func:`block_scene` (:mod:`._block`): a block of strips for bundle adjustment
  and :func:`synthetic_block` (:mod:`._bundle`), which packs it into a
  :class:`photax.BundleProblem`;
* :func:`texture` (:mod:`._texture`): the ground texture all of them are painted with;
* :mod:`.patterns`: analytic patterns (corners, discs, rings, textures)
  area-sampled into small images, for the image-measurement tests and notebook;
* :func:`render_image` (:mod:`._render`): the image a frame camera takes of a
  textured DEM with survey targets, area-sampled, blurred and noised;
* :func:`fiducial_scan` (:mod:`._fiducials`): a scanned film frame's fiducial
  marks under a known film -> pixel geometry (interior-orientation tests).

Everything is seeded; ground coordinates are UTM-like so code that forgets to
reduce them to a local origin shows it.  Frames and units: ``docs/conventions.md``.
"""

from ._fiducials import fiducial_scan as fiducial_scan
from ._render import render_image as render_image
from ._block import BlockScene as BlockScene, block_scene as block_scene
from ._bundle import SyntheticBlock as SyntheticBlock, synthetic_block as synthetic_block
from ._relief import Scene as Scene, relief_scene as relief_scene
from ._sample import (
    SAMPLE_BLUNDER as SAMPLE_BLUNDER,
    SAMPLE_CHECK as SAMPLE_CHECK,
    SAMPLE_CRS as SAMPLE_CRS,
    SAMPLE_DEM_CELL as SAMPLE_DEM_CELL,
    SAMPLE_DEM_HALF as SAMPLE_DEM_HALF,
    SAMPLE_IMAGE as SAMPLE_IMAGE,
    SAMPLE_NOISE_PX as SAMPLE_NOISE_PX,
    SAMPLE_ORIGIN as SAMPLE_ORIGIN,
    SAMPLE_SEED as SAMPLE_SEED,
    SAMPLE_TARGET_RADIUS as SAMPLE_TARGET_RADIUS,
    render_sample_image as render_sample_image,
    sample_dem as sample_dem,
    sample_points as sample_points,
)
from ._texture import detailed_texture as detailed_texture, texture as texture
