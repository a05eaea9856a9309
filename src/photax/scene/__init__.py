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
  marks under a known film -> pixel geometry (interior-orientation tests);
* :func:`pushbroom_scene` (:mod:`._pushbroom`): a push-broom satellite image
  from orbit (off nadir, along-track views), its GCPs and the orbit and
  attitude errors of its start.

Everything is seeded; ground coordinates are UTM-like so code that forgets to
reduce them to a local origin shows it.  Frames and units: ``docs/conventions.md``.
"""

from ._block import BlockScene as BlockScene
from ._block import block_scene as block_scene
from ._bundle import SyntheticBlock as SyntheticBlock
from ._bundle import synthetic_block as synthetic_block
from ._fiducials import fiducial_scan as fiducial_scan
from ._pushbroom import PushbroomScene as PushbroomScene
from ._pushbroom import pushbroom_scene as pushbroom_scene
from ._relief import Scene as Scene
from ._relief import relief_scene as relief_scene
from ._render import render_image as render_image
from ._sample import (
    SAMPLE_BLUNDER as SAMPLE_BLUNDER,
)
from ._sample import (
    SAMPLE_CHECK as SAMPLE_CHECK,
)
from ._sample import (
    SAMPLE_CRS as SAMPLE_CRS,
)
from ._sample import (
    SAMPLE_DEM_CELL as SAMPLE_DEM_CELL,
)
from ._sample import (
    SAMPLE_DEM_HALF as SAMPLE_DEM_HALF,
)
from ._sample import (
    SAMPLE_IMAGE as SAMPLE_IMAGE,
)
from ._sample import (
    SAMPLE_NOISE_PX as SAMPLE_NOISE_PX,
)
from ._sample import (
    SAMPLE_ORIGIN as SAMPLE_ORIGIN,
)
from ._sample import (
    SAMPLE_SEED as SAMPLE_SEED,
)
from ._sample import (
    SAMPLE_TARGET_RADIUS as SAMPLE_TARGET_RADIUS,
)
from ._sample import (
    render_sample_image as render_sample_image,
)
from ._sample import (
    sample_dem as sample_dem,
)
from ._sample import (
    sample_points as sample_points,
)
from ._texture import detailed_texture as detailed_texture
from ._texture import texture as texture
