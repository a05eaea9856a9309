"""Image measurement (seed 004): edge and interest operators, the Hough
transform, and sub-pixel locators.

Pixel convention (docs/conventions.md): positions are (column, row), the
centre of the top-left pixel at (0, 0).  Images are ``(h, w)`` or batches
``(b, h, w)`` of any integer or float dtype; results are float64.

Every locator takes many approximate positions at once and returns a
:class:`LocateResult` (``xy`` (n, 2) column/row, ``covariance`` (n, 2, 2),
``valid``, ``status``; failed points are NaN).
"""

from ._corners import locate_corners as locate_corners
from ._edges import canny as canny
from ._edges import laplace as laplace
from ._edges import log as log
from ._edges import prewitt as prewitt
from ._edges import roberts as roberts
from ._edges import sobel as sobel
from ._filters import gradient as gradient
from ._hough import HoughCircles as HoughCircles
from ._hough import HoughLines as HoughLines
from ._hough import hough_circles as hough_circles
from ._hough import hough_lines as hough_lines
from ._interest import InterestPoints as InterestPoints
from ._interest import foerstner as foerstner
from ._interest import harris as harris
from ._interest import interest_points as interest_points
from ._interest import moravec as moravec
from ._interest import non_maximum_suppression as non_maximum_suppression
from ._matching import match_lsm as match_lsm
from ._matching import match_ncc as match_ncc
from ._result import LocateResult as LocateResult
from ._result import Status as Status
from ._targets import ellipse_centre_offset as ellipse_centre_offset
from ._targets import locate_targets as locate_targets
from ._targets import target_homography as target_homography
from ._targets import target_kind as target_kind
