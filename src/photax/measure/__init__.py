"""Image measurement (seed 004): sub-pixel locators.

Every locator takes many approximate positions at once and returns a
:class:`LocateResult` (``xy`` (n, 2) column/row, ``covariance`` (n, 2, 2),
``valid``, ``status``).  Pixel convention: docs/conventions.md.
"""

from ._corners import locate_corners as locate_corners
from ._result import LocateResult as LocateResult, Status as Status
