"""Image matching guided by approximate orientations: the stage between image
measurement (:mod:`photax.measure`'s operators) and bundle adjustment.

* :mod:`._predict` -- what both share: ground points predicted in the images
  with the approximate orientations (:func:`project_pixels`), image points
  monoplotted on the DEM (:func:`monoplot_pixels`), chunked NCC + LSM;
* :mod:`.ties` -- tie points between overlapping images (:func:`match_ties`), and
  :func:`bundle_problem`, which joins ties and transferred GCPs into a
  :class:`photax.BundleProblem`;
* :mod:`.transfer` -- GCP transfer into every image that sees the point
  (:func:`transfer_points`);
* :mod:`.registration` -- an image matched to a reference orthophoto refines
  its exterior orientation (:func:`register_to_ortho`);
* :mod:`.epipolar` -- epipolar (normalised) image pairs, where stereo
  correspondences lie on rows, and points from x-parallax (:func:`epipolar_pair`);
* :mod:`.epipolar_affine` -- the same for two RPC / push-broom images over a tile: s2p's local affine
  rectification, with its residual vertical disparity (:class:`AffineEpipolarPair`);
* :mod:`.coregister` -- image-to-image registration: global and local shifts by phase correlation,
  reliability tests, an affine / polynomial / TPS model (:func:`coregister`);
* :mod:`.sgm` -- dense disparity maps of epipolar pairs by semi-global matching (:func:`disparity`).
"""

from ._predict import monoplot_pixels as monoplot_pixels
from ._predict import project_pixels as project_pixels
from .coregister import CoRegistration as CoRegistration
from .coregister import coregister as coregister
from .coregister import phase_correlation as phase_correlation
from .epipolar import EpipolarPair as EpipolarPair
from .epipolar import epipolar_pair as epipolar_pair
from .epipolar_affine import AffineEpipolarPair as AffineEpipolarPair
from .registration import Registration as Registration
from .registration import register_to_ortho as register_to_ortho
from .sgm import disparity as disparity
from .sgm import disparity_range_from_ties as disparity_range_from_ties
from .ties import TiePoints as TiePoints
from .ties import bundle_problem as bundle_problem
from .ties import match_ties as match_ties
from .transfer import Transfer as Transfer
from .transfer import transfer_points as transfer_points
