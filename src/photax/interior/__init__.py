"""Interior orientation of scanned film from fiducial marks.

A scanned photograph's pixels are not the camera's image plane: the film sits
in the scanner shifted, rotated, perhaps stretched.  The calibration report
gives the fiducial marks' positions on the film (image-plane ``x`` right,
``y`` up, mm, origin at the fiducial centre: ``docs/conventions.md``);
measuring them in the scan fixes the transformation between the two.

The model is fitted in the direction of the measurement, **film -> pixel**::

    (u, v) = (x, -y)                                  (film with y down, like rows)
    similarity   c = a0 + p u - q v,          r = b0 + q u + p v          (4)
    affine       c = a0 + a1 u + a2 v,        r = b0 + b1 u + b2 v        (6)
    bilinear     c = a0 + a1 u + a2 v + a3 u v, r = b0 + b1 u + b2 v + b3 u v   (8)
    projective   c = (h11 u + h12 v + h13) / (h31 u + h32 v + 1), r likewise   (8)

so that the measured pixels are the observations and the calibrated film
coordinates error-free (a Gauss-Markov model, Kraus 2007 sec. 3.3.2; Wolf &
DeWitt 2014 app. C): residuals are in pixels and ``sigma0`` is the marks'
measuring precision.  Film coordinates are centred and scaled to unit rms
inside the model (Hartley normalisation: ``STYLE.md`` item 7); the parameters
and their covariance refer to the normalised film coordinates.

Blunders: data snooping as in the resection (:mod:`photax.resection`, Baarda
1968; Pope 1976), but one test per *mark* (both coordinates together): with
``Q_vv = I - A (A^T P A)^-1 A^T P`` and ``v_i`` the mark's two weighted
residuals, ``T_i = v_i^T (Q_vv,ii)^-1 v_i`` (a-priori ``sigma``: ``T_i ~
chi^2(2)``) or ``T_i / sigma0^2`` (``/ r ~ Beta(1, (r-2)/2)``); the worst mark
is excluded and the fit repeated while its test fails and the redundancy
allows.  The resection's per-coordinate test missed a (3, -4) px blunder on
an affine 8-mark scan (tau 2.53 < 2.68 for each coordinate): a displacement
split over both coordinates is what a wrong mark looks like.

:class:`ScannedCamera` is a :class:`photax.FrameCamera` whose pixel <->
image-plane conversion goes through the fitted transformation, so
:func:`photax.resect` (via ``camera.pixel_to_image``), :func:`photax.orthorectify`
and the bundle adjustment take scanned images as they are.

Modules: ``_transform`` (the film -> pixel models, :class:`PixelTransform`,
:class:`ScannedCamera`), ``_fit`` (:func:`interior_orientation`: the
adjustment and the per-mark test), ``_fiducials`` (mark templates and
:func:`find_fiducials`).
"""

from ._fiducials import Fiducials as Fiducials
from ._fiducials import find_fiducials as find_fiducials
from ._fiducials import mark_coverage as mark_coverage
from ._fiducials import mark_template as mark_template
from ._fit import InteriorOrientation as InteriorOrientation
from ._fit import interior_orientation as interior_orientation
from ._transform import N_PARAMS as N_PARAMS
from ._transform import Model as Model
from ._transform import PixelTransform as PixelTransform
from ._transform import ScannedCamera as ScannedCamera
