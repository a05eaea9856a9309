"""Space resection: the exterior orientation of one image (or many) from GCPs.

Model (``docs/conventions.md``): the collinearity equations
:func:`photax.collinearity.project`, parameters ``p = (Xs, Ys, Zs, a1, a2, a3)``
with the angles in the chosen convention's order.  Ground coordinates are
reduced to the centroid of the control points before anything is computed
(UTM eastings/northings are ~1e6 m) and the centroid is added back at the end.

1. **Cheap path, every image** (:mod:`._adjust`): one calibrated linear
   start from all control points (homography for planar GCPs, calibrated
   DLT for 3-D ones; :mod:`._linear`), Gauss-Newton with the closed-form
   collinearity Jacobian, precision, and the blunder test.
2. **Robust path, only where needed** (:mod:`._robust`), in compacted
   batches: data snooping (Baarda 1968; Pope 1976) - exclude the worst
   point, re-adjust, while the test fails and redundancy allows.  Images
   whose only fault is the failed test snoop from their cheap solution;
   images whose adjustment fails, whose start or solution puts control
   points behind the camera or is implausible (step 5) - and those the
   first kind leaves failed - start from a least-median-of-squares
   solution over 32 random subsets.
3. **Precision** at the solution, with ``A`` the Jacobian of the weighted
   model, ``r = 2 n - 6``::

       sigma0^2 = v^T P v / r,   C_pp = sigma0^2 (A^T P A)^-1,
       r_i = diag(I - A (A^T P A)^-1 A^T P)        (redundancy numbers)

   The test statistic is ``w_i = v_i / (sigma_i sqrt(r_i))`` (a-priori
   ``sigma`` given) or ``tau_i = w_i / sigma0_hat`` (not given), against
   ``3.29`` for ``alpha = 0.001`` or the tau distribution with ``r``
   degrees of freedom.
4. A single :func:`resect` whose Gauss-Newton fails retries with
   ``optimistix.LevenbergMarquardt`` (compiled only then).
5. **Plausibility** (:mod:`._checks`): a converged adjustment is still a
   failure (``converged=False``, ``result`` = ``RESULTS.implausible`` or
   ``behind_camera``, the reason in ``message``) when image and ground
   evidently do not belong together.  A mirror image (image or ground
   mirrored: a swap of axes) is told by the handedness of the image-ground
   correspondence, never by where the camera is (façades, oblique and
   upward-looking views are seen from below their points): a single
   :func:`resect` refuses a converged solution when the image reversed in
   x fits far better (GCPs with relief); the mirror of *planar* GCPs fits
   exactly, from the camera reflected through their plane, so there only
   the side they are seen from decides - known for level ones (the ground,
   seen from above), not for a planar façade.  When a single-image resection fails,
   the usual GCP-file mistakes are tried (image column/row swapped, row
   direction reversed, ground E/N swapped) and those that make it fit are
   named in the message.

Layout: :mod:`._types` (the pytrees: inputs, options, output), :mod:`._linear`,
:mod:`._adjust`, :mod:`._robust`, :mod:`._checks`, :mod:`._result`,
:mod:`._api` (:func:`resect`, :func:`resect_batch`).

References: Kraus, *Photogrammetry* vol. 1 (2007) sec. 4.3; Wolf & DeWitt,
*Elements of Photogrammetry* (2014) ch. 11 and app. B; Förstner & Wrobel,
*Photogrammetric Computer Vision* (2016) sec. 4.6.
"""

from ._api import resect as resect
from ._api import resect_batch as resect_batch
from ._result import ResectionResult as ResectionResult
