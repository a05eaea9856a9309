"""Bundle adjustment: the problem, a Schur-complement Levenberg–Marquardt
solver, robust losses, self-calibration and precision.

The model is the collinearity equations (``docs/conventions.md``) of
:func:`photax.project`: observation ``o`` of point ``X_p`` on image ``i``
(camera ``c = image_camera[i]``) has the residual::

    r_o = (project(X_p; R_i, C_i, camera_c) - xy_o) / sigma_o       (2,)

and the solver minimises (Ceres' convention, 0.5 times the sum of squares)::

    cost = 0.5 sum_o rho(|r_o|^2) + 0.5 sum_{control p} |(X_p - X_p^survey) / sigma_p|^2
           + 0.5 sum_{GNSS i} |(C_i + R_i l - G_i) / sigma_i|^2 + 0.5 sum_{INS i} |M_i Log(A_i^T R_i)|^2

(the last two: an image's GNSS antenna position ``G_i`` with lever arm ``l``
and its INS attitude ``A_i``, ``M_i`` mapping the rotation vector to angle
differences over their sigmas; :func:`photax.bundle._linearise._camera_prior`)

with ``rho(s) = s`` (no loss), Huber ``rho(s) = s`` for ``s <= d^2`` else
``2 d sqrt(s) - d^2``, or Cauchy ``rho(s) = d^2 log(1 + s / d^2)``
(``d = loss_scale``, in units of the observation's sigma).  Robust losses
enter each linearisation through Ceres' corrector (Triggs et al. 2000, sec.
4.3; ``corrector.cc``; see :func:`photax.bundle._robust._corrector`): for Huber and Cauchy
(``rho'' <= 0``) that is reweighting, ``J~ = sqrt(rho') J``, a model that
majorises the loss along each residual.  After each trial step a *point
pass* moves every point, with the trial cameras fixed, to the best of a few
multiples of its own reweighted Gauss–Newton step (:data:`POINT_STEPS`);
its decrease counts in the trust region's gain ratio as Conn, Gould &
Toint's "magical steps".  It takes care of what the reweighted model gets
wrong, points sliding along directions where the loss is flat (see
:mod:`photax.bundle._solver` for why this converges, and how fast).  A step
whose cost or norm is not finite is rejected (more damping), never taken.

Parameters (analysed once on the numpy side, then solved by jitted steps):

* per image: the projection centre ``C`` (ground unit) and the attitude
  ``R`` (world_from_camera), updated on the manifold ``R <- R Exp(dr)``
  with ``dr`` a rotation vector about the camera axes, so any orientation
  works (BAL cameras look everywhere); the centre step turns with the
  camera, ``C <- C + R' R^T dC`` with ``R'`` the new attitude (see
  :mod:`photax.bundle._solver` for why);
* per camera (shared by its images): ``f, x0, y0, k1, k2, k3, p1, p2``,
  each free or fixed (self-calibration);
* per point: ``X, Y, Z``.  Tie and check points are free; control points
  are free with a prior ``sigma`` (pseudo-observations), or fixed when
  their sigma is 0.  Check points are adjusted as tie points and compared
  with their surveyed coordinates afterwards.

Each LM step solves ``(J^T J + lambda D) dx = -J^T r`` with
``D = diag(J^T J)`` clamped to ``[1e-6, 1e32]`` (Ceres; with a robust loss
``J~^T J~``, ``J~^T r~`` and ``D = diag(J~^T J~)``).  Ordering camera
unknowns ``c`` before points ``p``::

    [U  W] [dc]   [-g_c]                  S  = U - W V^-1 W^T
    [W' V] [dp] = [-g_p]      ->          S dc = -g_c + W V^-1 g_p
                                          dp = -V^-1 (g_p + W^T dc)

``V`` is block diagonal (3x3 per point), so ``V^-1`` is a batch of 3x3
inverses and ``S`` (the reduced camera system) is accumulated from
per-observation blocks: block ``(i, j)`` sums ``W_a V^-1 W_b^T`` over the
pairs of observations ``a`` (image ``i``), ``b`` (image ``j``) of one point,
grouped on the numpy side into fixed-size chunks of one block each so that
the sum is a batch of small GEMMs (see :func:`photax.bundle._schur._reduced_system`).  Jacobians
are closed-form (:func:`photax.bundle._linearise._project_obs`, built on
:func:`photax.collinearity.collinearity_rows` and
:func:`photax.camera.intrinsics_jacobian`).  ``S`` is solved by a dense
Cholesky (49 BAL images x 9 = 441 unknowns, on one BLAS thread), or for a
block of strips by a banded block-Cholesky in a bandwidth-reducing image
order, or matrix-free by Schur-Jacobi preconditioned CG; the choice is by
estimated cost (:mod:`photax.bundle._sparse`, :func:`~photax.bundle._sparse.choose_solver`).  A rejected step re-solves with the same
linearisation (only the damping changes).  References: Triggs et al.,
"Bundle adjustment — a modern synthesis" (2000); Agarwal et al., "Bundle
adjustment in the large" (ECCV 2010); Ceres Solver's trust-region minimiser.
"""

from ._problem import (
    EXTERIOR as EXTERIOR,
)
from ._problem import (
    INTRINSICS as INTRINSICS,
)
from ._problem import (
    ROLES as ROLES,
)
from ._problem import (
    BundleProblem as BundleProblem,
)
from ._problem import (
    Gauge as Gauge,
)
from ._problem import (
    Loss as Loss,
)
from ._result import BundleResult as BundleResult
from ._solver import (
    POINT_STEPS as POINT_STEPS,
)
from ._solver import (
    StoppingRule as StoppingRule,
)
from ._solver import (
    bundle_adjust as bundle_adjust,
)
from ._start import initialize_block as initialize_block
