"""Image measurement (seed 004): sub-pixel locators.

Every locator takes many approximate positions at once and returns a
:class:`LocateResult` (``xy`` (n, 2) column/row, ``covariance`` (n, 2, 2),
``valid``, ``status``; failed points are NaN).  Pixel convention:
docs/conventions.md.
"""

from ._corners import locate_corners as locate_corners
from ._matching import match_lsm as match_lsm, match_ncc as match_ncc
from ._result import LocateResult as LocateResult, Status as Status
from ._targets import ellipse_centre_offset as ellipse_centre_offset, locate_targets as locate_targets
