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
from ._edges import canny as canny, laplace as laplace, log as log, prewitt as prewitt, roberts as roberts
from ._edges import sobel as sobel
from ._filters import gradient as gradient
from ._hough import HoughCircles as HoughCircles, HoughLines as HoughLines
from ._hough import hough_circles as hough_circles, hough_lines as hough_lines
from ._interest import InterestPoints as InterestPoints, foerstner as foerstner, harris as harris
from ._interest import interest_points as interest_points, moravec as moravec
from ._interest import non_maximum_suppression as non_maximum_suppression
from ._matching import match_lsm as match_lsm, match_ncc as match_ncc
from ._result import LocateResult as LocateResult, Status as Status
from ._targets import ellipse_centre_offset as ellipse_centre_offset, locate_targets as locate_targets
from ._targets import target_homography as target_homography, target_kind as target_kind
