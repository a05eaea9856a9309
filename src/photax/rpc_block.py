"""Block adjustment of several RPC images with tie points (Grodecki & Dial 2003).

Each image ``i`` keeps its RPC and gains the image-space correction of :func:`photax.refine_rpc`
(``shift``, ``shift-drift`` or ``affine``: ``dc = a0 + a1 c + a2 r``, ``dr = b0 + b1 c + b2 r`` on the
RPC's own column, row); the unknowns are these corrections of every image and the ground coordinates
of every tie point (lon, lat, ellipsoidal h, adjusted as east, north, up metres about their start).
The observations are the measured image positions of tie points and GCPs (standard deviation
``pixel_sigma``), the GCPs' ground coordinates (fixed, or weighted with ``gcp_sigma`` metres, when they
are unknowns too) and, when given, a prior ``correction_sigma`` on the corrections (centred on zero).
Gauss-Newton on the dense normal equations (a few hundred tie points; no reduction of the points
yet), the Jacobians of the RPC by ``jax.jacfwd``; reported like
:func:`photax.refine_rpc`: sigma0, the corrections' covariance, residuals, standardized residuals for
data snooping, and check points (GCPs marked ``check``, left out of the adjustment).

Without GCPs the block has no datum: ties fix the images relative to one another, not on the ground
(a common shift of all images moves every tie point with it). :func:`adjust_rpc_block` refuses such a
block unless ``correction_sigma`` is given, and refuses any block whose normal equations are singular.

Reference: Grodecki & Dial, "Block adjustment of high-resolution satellite images described by rational
polynomials", PE&RS 69 (2003).
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._float64 import as_float64
from .earth import radii_of_curvature
from .errors import ConvergenceError
from .rpc import RPCCamera, check_gcps
from .sensor import is_sensor

_TERMS = {"shift": (0,), "shift-drift": (0, 2), "affine": (0, 1, 2)}  # as refine_rpc's models


@eqx.filter_jit
def _linearise_jit(camera: RPCCamera, ground):
    return camera(ground), jax.vmap(jax.jacfwd(camera))(ground), camera.uncorrected(ground)


def _linearise(camera: RPCCamera, ground):
    """Corrected pixel ``(n, 2)``, its Jacobian by lon, lat, h ``(n, 2, 3)`` and the RPC's own pixel
    (the points padded to a power of two, so that few shapes are compiled)."""
    ground = np.asarray(ground)
    n = len(ground)
    padded = np.concatenate([ground, np.repeat(ground[:1], (1 << max(n - 1, 0).bit_length()) - n, 0)])
    return tuple(np.asarray(v)[:n] for v in _linearise_jit(camera, jnp.asarray(padded)))


def _metres_per_degree(lat):
    m, n = radii_of_curvature(lat)
    return np.column_stack([np.deg2rad(n * np.cos(np.deg2rad(lat))), np.deg2rad(m), np.ones_like(lat)])


def _observations(obs, name: str, n_images: int) -> np.ndarray:
    obs = as_float64(obs, name)
    if obs.ndim != 2 or obs.shape[1] != 4:
        raise ValueError(f"{name}: expected shape (k, 4) rows of point, image, column, row, got {obs.shape}")
    if not np.all(np.isfinite(obs)):
        raise ValueError(f"{name}: non-finite values in rows {np.flatnonzero(~np.all(np.isfinite(obs), 1)).tolist()}")
    img = obs[:, 1]
    if np.any(img != np.round(img)) or np.any((img < 0) | (img >= n_images)):
        raise ValueError(f"{name}: image indices must be integers in [0, {n_images})")
    if np.any(obs[:, 0] != np.round(obs[:, 0])):
        raise ValueError(f"{name}: point ids must be integers")
    return obs


@dataclasses.dataclass(frozen=True)
class RPCBlock:
    """Outcome of :func:`adjust_rpc_block`.

    Attributes:
        cameras: the refined :class:`photax.RPCCamera` of each image (its ``correction`` set): usable
            wherever one is, as :attr:`photax.RPCRefinement.camera` is.
        model: the correction (``"shift"``, ``"shift-drift"``, ``"affine"``).
        corrections: ``(m, 2, 3)`` each image's ``[[a0, a1, a2], [b0, b1, b2]]`` (px, px/px).
        correction_sigmas: ``(m, 2, 3)`` their standard deviations (0 for terms the model leaves out).
        covariance: ``(p, p)`` covariance of the adjusted correction parameters, image by image, column
            axis then row axis, the model's terms in order (sigma0^2 Q).
        tie_ids: ``(t,)`` the tie points' ids; tie_ground ``(t, 3)`` their adjusted lon, lat, h;
            tie_sigmas ``(t, 3)`` their standard deviations east, north, up (m).
        point, image: ``(k,)`` the point id and image of each image observation (ties, then GCPs);
            is_gcp ``(k,)`` which are GCP observations.
        residuals: ``(k, 2)`` adjusted minus observed image position (px; computed - observed,
            ``docs/conventions.md``).
        standardized: ``(k, 2)`` residuals over their a posteriori standard deviation
            ``v / (sigma0 sqrt(q_vv))`` (Pope's tau); the largest beyond about 3 or 4 marks a blunder
            (data snooping). NaN without redundancy.
        gcp_residuals: ``(g, 3)`` adjusted minus given east, north, up of the GCPs (m; 0 when fixed,
            NaN for check points).
        check_residuals: ``(c, 2)`` refined projection of the check points' known ground minus observed
            (px), one row per check observation (``check_point``, ``check_image`` say which).
        check_ground_residuals: ``(g, 3)`` intersected minus known east, north, up of the check points
            seen in at least two images with the refined cameras (m; NaN elsewhere).
        sigma0: a posteriori standard deviation of unit weight (NaN without redundancy).
        redundancy: observations (including priors and weighted GCPs) minus unknowns.
        iterations: Gauss-Newton iterations.

    Examples:
        Two toy RPCs, the second looking obliquely (its column grows with height), three tie points
        measured without error and no GCPs (the corrections' prior is the datum): the ties are
        intersected at their true lon, lat, h, and nothing is left to correct:

        >>> import numpy as np
        >>> import photax as ptx
        >>> t = np.eye(20)  # terms 1, L, P, H of the 20: column = 500 + 500 (L + k H), row = 500 - 500 P
        >>> off, scale = [10.0, 45.0, 0.0, 500.0, 500.0], [0.01, 0.01, 500.0, 500.0, 500.0]
        >>> cams = [ptx.RPCCamera([-t[2], t[0], t[1] + k * t[3], t[0]], off, scale, image_size=(1000, 1000))
        ...         for k in (0.0, 0.2)]
        >>> truth = np.array([[10.004, 45.003, 300.0], [9.998, 44.998, 200.0], [10.001, 44.995, 50.0]])
        >>> ties = np.array([[k, i, *np.asarray(c(truth))[k]] for k in range(3) for i, c in enumerate(cams)])
        >>> block = ptx.adjust_rpc_block(cams, ties, correction_sigma=1.0)
        >>> block.tie_ids.tolist(), bool(np.allclose(block.tie_ground, truth, rtol=0, atol=1e-6))
        ([0, 1, 2], True)
        >>> bool(np.abs(block.corrections).max() < 1e-9), block.residuals.shape, block.redundancy
        (True, (6, 2), 3)
    """

    cameras: list
    model: str
    corrections: np.ndarray
    correction_sigmas: np.ndarray
    covariance: np.ndarray
    tie_ids: np.ndarray
    tie_ground: np.ndarray
    tie_sigmas: np.ndarray
    point: np.ndarray
    image: np.ndarray
    is_gcp: np.ndarray
    residuals: np.ndarray
    standardized: np.ndarray
    gcp_residuals: np.ndarray
    check_point: np.ndarray
    check_image: np.ndarray
    check_residuals: np.ndarray
    check_ground_residuals: np.ndarray
    sigma0: float
    redundancy: int
    iterations: int

    @property
    def rmse(self) -> float:
        """Root mean square length of the image residuals (px)."""
        return float(np.sqrt(np.mean(np.sum(self.residuals**2, axis=1))))

    def correction_covariance(self, image: int) -> np.ndarray:
        """``(6, 6)`` covariance of image ``image``'s correction ``(a0, a1, a2, b0, b1, b2)`` (zero rows for
        the terms the model leaves out), as :func:`photax.ortho_uncertainty` takes it beside
        ``cameras[image]``."""
        terms = _TERMS[self.model]
        nt = len(terms)
        idx = [(image * 2 + axis) * nt + k for axis in range(2) for k in range(nt)]
        at = [axis * 3 + t for axis in range(2) for t in terms]
        out = np.zeros((6, 6))
        out[np.ix_(at, at)] = self.covariance[np.ix_(idx, idx)]
        return out

    @property
    def check_rmse(self) -> float:
        """The same for the check observations (px; NaN without check points)."""
        if len(self.check_residuals) == 0:
            return math.nan
        return float(np.sqrt(np.mean(np.sum(self.check_residuals**2, axis=1))))


def _start_ground(cameras, obs, ids) -> np.ndarray:
    """``(len(ids), 3)`` lon, lat, h of points ``ids`` from their rays in ``obs`` (rows point, image,
    column, row): each ray's ground point at the RPCs' mean height offset, averaged per point (the
    adjustment then finds the height)."""
    h = float(np.mean([float(c.offsets[2]) for c in cameras]))
    ll = np.full((len(obs), 2), np.nan)
    for i, cam in enumerate(cameras):
        sel = obs[:, 1] == i
        if np.any(sel):
            ll[sel] = np.asarray(cam.to_ground(jnp.asarray(obs[sel, 2:]), h))
    row = np.searchsorted(ids, obs[:, 0].astype(int))
    ok = np.all(np.isfinite(ll), 1)
    total, count = np.zeros((len(ids), 2)), np.zeros(len(ids))
    np.add.at(total, row[ok], ll[ok])
    np.add.at(count, row[ok], 1)
    if np.any(count == 0):
        bad = ids[count == 0].tolist()
        raise ValueError(f"points {bad}: no ray reaches the ground (are they inside the images?)")
    return np.column_stack([total / count[:, None], np.full(len(ids), h)])


def _intersect(cameras, obs, start, steps: int = 10) -> np.ndarray:
    """Least-squares intersection of one point's rays with fixed cameras (lon, lat, h)."""
    x = start.copy()
    for _ in range(steps):
        a, b = [], []
        for o in obs:
            pix, jac, _ = _linearise(cameras[int(o[1])], x[None])
            a.append(np.asarray(jac)[0] / _metres_per_degree(np.array([x[1]]))[0])
            b.append(o[2:] - np.asarray(pix)[0])
        d = np.linalg.lstsq(np.concatenate(a), np.concatenate(b), rcond=None)[0]
        x = x + d / _metres_per_degree(np.array([x[1]]))[0]
        if np.max(np.abs(d)) < 1e-6:
            break
    return x


def adjust_rpc_block(
    cameras,
    ties,
    gcps=None,
    *,
    model: str = "shift",
    check=None,
    pixel_sigma: float = 1.0,
    gcp_sigma=None,
    correction_sigma=None,
    max_iterations: int = 20,
) -> RPCBlock:
    """Adjust the image-space corrections of several RPC images together, on tie points and GCPs
    (module docstring; Grodecki & Dial 2003).

    Args:
        cameras: the images' :class:`photax.RPCCamera` (an existing ``correction`` is replaced), or
            their :class:`photax.GroundSensor` s (those :func:`photax.match_ties` took).
        ties: ``(k, 4)`` rows ``point, image, column, row``: tie point ``point`` (an integer id) measured
            at ``(column, row)`` in ``cameras[image]``; each tie point in two images at least.  Or the
            :class:`photax.TiePoints` of :func:`photax.match_ties` on these images (its
            :meth:`~photax.TiePoints.as_rows`); its sigmas are not used (``pixel_sigma`` weighs all).
        gcps: ``(ground, observations)``: ``(g, 3)`` lon, lat, ellipsoidal h and ``(k, 4)`` rows
            ``gcp, image, column, row`` (``gcp`` indexes ``ground``), or None; checked against each
            image's RPC as :func:`photax.refine_rpc` checks them (:func:`photax.rpc.check_gcps`: its
            validity volume and the image given, so a crop's RPC, :meth:`photax.RPCCamera.crop`, takes
            the GCPs measured on the crop).
        model: ``"shift"``, ``"shift-drift"`` or ``"affine"``, for every image.
        check: ``(g,)`` booleans: GCPs kept out of the adjustment as check points.
        pixel_sigma: a-priori standard deviation of an image measurement (px).
        gcp_sigma: None (GCPs fixed) or their standard deviation east, north, up (m; a scalar or 3).
        correction_sigma: None or a prior standard deviation of each correction term about zero (px for
            a0/b0, px/px for the others; a scalar or one per term of the model): the datum of a block
            without GCPs.

    Raises:
        ValueError: bad input; a block without GCPs and without ``correction_sigma`` (no datum); a
            block whose normal equations are singular (say what is missing).
        ConvergenceError: Gauss-Newton did not settle in ``max_iterations``.

    Examples:
        Two toy RPCs (the second oblique: its column grows with height) whose measurements are off by
        2 columns in the first image and -1 row in the second; four GCPs and two tie points find the
        two shifts, and the ties' true positions (ties from images: :func:`photax.match_ties` on their
        :class:`photax.GroundSensor` s, passed as they come):

        >>> import numpy as np
        >>> import photax as ptx
        >>> t = np.eye(20)  # terms 1, L, P, H of the 20: column = 500 + 500 (L + k H), row = 500 - 500 P
        >>> off, scale = [10.0, 45.0, 0.0, 500.0, 500.0], [0.01, 0.01, 500.0, 500.0, 500.0]
        >>> cams = [ptx.RPCCamera([-t[2], t[0], t[1] + k * t[3], t[0]], off, scale, image_size=(1000, 1000))
        ...         for k in (0.0, 0.2)]
        >>> bias = np.array([[2.0, 0.0], [0.0, -1.0]])
        >>> measure = lambda points: np.array([[k, i, *(np.asarray(c(points))[k] + bias[i])]
        ...                                    for k in range(len(points)) for i, c in enumerate(cams)])
        >>> gcps = np.array([[10.002, 45.001, 50.0], [10.007, 44.996, 80.0], [9.995, 45.004, 20.0],
        ...                  [9.993, 44.994, 120.0]])
        >>> tie_truth = np.array([[10.004, 45.003, 300.0], [9.998, 44.998, 200.0]])
        >>> block = ptx.adjust_rpc_block(cams, measure(tie_truth), (gcps, measure(gcps)), model="shift")
        >>> print(np.round(block.corrections[:, :, 0], 6) + 0.0)  # a0, b0 of each image (px)
        [[ 2.  0.]
         [ 0. -1.]]
        >>> bool(np.allclose(block.tie_ground, tie_truth, rtol=0, atol=1e-6))
        True
    """

    if model not in _TERMS:
        raise ValueError(f"model: expected one of {', '.join(_TERMS)}, got {model!r}")
    cameras = [c.camera if is_sensor(c) else c for c in cameras]  # a GroundSensor's RPC
    if not cameras or not all(isinstance(c, RPCCamera) for c in cameras):
        kinds = sorted({type(c).__name__ for c in cameras if not isinstance(c, RPCCamera)})
        raise ValueError(
            f"cameras: expected a non-empty sequence of RPCCamera (or their GroundSensors), got {', '.join(kinds)}"
            " (a push-broom model: photax.fit_rpc gives its RPC)"
        )
    m, terms = len(cameras), _TERMS[model]
    nt = len(terms)
    raw_cams = [RPCCamera(c.coefficients, c.offsets, c.scales, image_size=c.image_size) for c in cameras]
    rows = getattr(ties, "as_rows", None)  # a photax.TiePoints
    ties = _observations(rows() if callable(rows) else ties, "ties", m)
    if gcps is None:
        g_ground, g_obs = np.zeros((0, 3)), np.zeros((0, 4))
    else:
        g_ground = as_float64(gcps[0], "gcps ground")
        if g_ground.ndim != 2 or g_ground.shape[1] != 3 or not np.all(np.isfinite(g_ground)):
            raise ValueError(f"gcps: ground must be finite (g, 3) lon, lat, h, got shape {g_ground.shape}")
        g_obs = _observations(gcps[1], "gcps observations", m)
        if np.any((g_obs[:, 0] < 0) | (g_obs[:, 0] >= len(g_ground))):
            raise ValueError(f"gcps: observation gcp indices must be in [0, {len(g_ground)})")
        for i, cam in enumerate(cameras):  # as refine_rpc: the RPC's validity volume and the image given
            sel = g_obs[:, 1] == i
            if np.any(sel):
                idx = g_obs[sel, 0].astype(int)
                check_gcps(
                    cam, g_ground[idx], g_obs[sel, 2:], [f"GCP {k}" for k in idx], who=f"gcps in image {i}", warn=False
                )
    check = np.zeros(len(g_ground), bool) if check is None else np.asarray(check, bool)
    if check.shape != (len(g_ground),):
        raise ValueError(f"check: expected {len(g_ground)} booleans (one per GCP), got shape {check.shape}")
    if pixel_sigma <= 0:
        raise ValueError("pixel_sigma must be positive")
    g_sigma = None
    if gcp_sigma is not None:
        g_sigma = np.broadcast_to(as_float64(gcp_sigma, "gcp_sigma"), (3,)).copy()
        if np.any(g_sigma <= 0):
            raise ValueError("gcp_sigma must be positive (None: fixed GCPs)")
    c_sigma = None
    if correction_sigma is not None:
        c_sigma = np.broadcast_to(as_float64(correction_sigma, "correction_sigma"), (nt,)).copy()
        if np.any(c_sigma <= 0):
            raise ValueError("correction_sigma must be positive")
    control = g_obs[~check[g_obs[:, 0].astype(int)]] if len(g_obs) else g_obs
    if len(control) == 0 and c_sigma is None:
        raise ValueError(
            "adjust_rpc_block: the block has no datum -- tie points fix the images relative to one another, "
            "not on the ground; give GCPs (not all check points) or a prior correction_sigma"
        )

    # points: tie points, then the GCPs in the adjustment (unknowns when weighted, fixed otherwise)
    tie_ids = np.unique(ties[:, 0]).astype(int)
    for pid in tie_ids:
        imgs = np.unique(ties[ties[:, 0] == pid, 1])
        if len(imgs) < 2:
            raise ValueError(f"ties: point {pid} is measured in {len(imgs)} image(s); a tie needs two at least")
    control_ids = np.unique(control[:, 0]).astype(int) if len(control) else np.zeros(0, int)
    n_tie, free_gcp = len(tie_ids), control_ids if g_sigma is not None else np.zeros(0, int)
    pt_index = {("t", int(p)): k for k, p in enumerate(tie_ids)}
    pt_index.update({("g", int(p)): n_tie + k for k, p in enumerate(free_gcp)})
    ground = np.concatenate(
        [_start_ground(raw_cams, ties, tie_ids),
         g_ground[free_gcp].reshape(-1, 3)]
    )  # fmt: skip
    obs = np.concatenate([ties, control])
    kind = np.array(["t"] * len(ties) + ["g"] * len(control))
    n_obs = len(obs)
    # each observation: a free point (index into ground) or a fixed GCP
    free = np.array([(k, int(o[0])) in pt_index for k, o in zip(kind, obs, strict=True)], bool)
    pidx = np.array([pt_index.get((k, int(o[0])), -1) for k, o in zip(kind, obs, strict=True)])
    img = obs[:, 1].astype(int)
    n_corr, n_pts = m * 2 * nt, len(ground)
    u = n_corr + 3 * n_pts
    ground0 = ground.copy()

    corr = np.zeros((m, 2, 3))
    x_pts = np.zeros((n_pts, 3))  # east, north, up from ground0 (m)
    scale0 = _metres_per_degree(ground0[:, 1]) if n_pts else np.zeros((0, 3))

    def current_cameras():
        return [RPCCamera(c.coefficients, c.offsets, c.scales, corr[i], c.image_size) for i, c in enumerate(raw_cams)]

    def linearise():
        cams = current_cameras()
        pts = ground0 + x_pts / np.where(scale0 == 0, 1.0, scale0) if n_pts else ground0
        xyz = np.zeros((n_obs, 3))
        xyz[free] = pts[pidx[free]]
        xyz[~free] = g_ground[obs[~free, 0].astype(int)]
        a = np.zeros((2 * n_obs, u))
        f = np.zeros((n_obs, 2))
        for i in range(m):
            sel = np.flatnonzero(img == i)
            if len(sel) == 0:
                continue
            pix, jac, rawpix = _linearise(cams[i], xyz[sel])
            f[sel] = pix
            basis = np.column_stack([np.ones(len(sel)), rawpix])[:, terms]  # d(dc)/d(a_terms)
            for axis in range(2):
                cols = (i * 2 + axis) * nt + np.arange(nt)
                a[np.ix_(2 * sel + axis, cols)] = basis
            fr = sel[free[sel]]
            if len(fr):
                jm = jac[free[sel]] / scale0[pidx[fr]][:, None, :]  # per metre east, north, up
                for axis in range(2):
                    for c in range(3):
                        a[2 * fr + axis, n_corr + 3 * pidx[fr] + c] = jm[:, axis, c]
        return f, a

    # pseudo-observations: corrections ~ 0 (c_sigma), free GCPs' offsets ~ 0 (g_sigma)
    prior_w = np.zeros(u)
    if c_sigma is not None:
        prior_w[:n_corr] = np.tile(1.0 / c_sigma**2, 2 * m)
    if g_sigma is not None and len(free_gcp):
        prior_w[n_corr + 3 * n_tie :] = np.tile(1.0 / g_sigma**2, len(free_gcp))
    w = 1.0 / pixel_sigma**2

    def state():
        return np.concatenate([corr[:, :, list(terms)].reshape(-1), x_pts.reshape(-1)])

    iterations = 0
    converged = False
    for iterations in range(1, max_iterations + 1):  # noqa: B007
        f, a = linearise()
        v = (obs[:, 2:] - f).reshape(-1)
        x = state()
        normal = w * a.T @ a + np.diag(prior_w)
        rhs = w * a.T @ v - prior_w * x
        d = np.sqrt(np.maximum(np.diag(normal), 1e-300))
        scaled = normal / np.outer(d, d)
        ev = np.linalg.eigvalsh(scaled) if iterations == 1 else None  # the rank is the block's structure
        if ev is not None and ev[0] < 1e-12 * ev[-1]:
            raise ValueError(
                "adjust_rpc_block: the normal equations are singular -- the GCPs and ties do not determine "
                f"every image's {model!r} correction and every tie point (add GCPs or ties, a lower model, "
                "or correction_sigma)"
            )
        dx = np.linalg.solve(scaled, rhs / d) / d
        x = x + dx
        corr[:, :, list(terms)] = x[:n_corr].reshape(m, 2, nt)
        x_pts = x[n_corr:].reshape(n_pts, 3)
        if np.max(np.abs(dx[:n_corr])) < 1e-9 and (n_pts == 0 or np.max(np.abs(dx[n_corr:])) < 1e-6):
            converged = True
            break
    if not converged:
        raise ConvergenceError(f"adjust_rpc_block: Gauss-Newton did not settle in {max_iterations} iterations")

    f, a = linearise()
    v = obs[:, 2:] - f
    x = state()
    normal = w * a.T @ a + np.diag(prior_w)
    q = np.linalg.inv(normal)
    n_prior = int(np.count_nonzero(prior_w))
    r = 2 * n_obs + n_prior - u
    vpv = w * np.sum(v**2) + np.sum(prior_w * x**2)
    sigma0 = float(np.sqrt(vpv / r)) if r > 0 else math.nan
    cov = q * (sigma0**2 if r > 0 else math.nan)
    qvv = 1.0 / w - np.sum((a @ q) * a, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        standardized = v / (sigma0 * np.sqrt(np.where(qvv > 1e-12 / w, qvv, np.nan))).reshape(-1, 2)
    sig = np.sqrt(np.diag(cov))
    corr_sig = np.zeros((m, 2, 3))
    corr_sig[:, :, list(terms)] = sig[:n_corr].reshape(m, 2, nt)
    pts = ground0 + x_pts / np.where(scale0 == 0, 1.0, scale0) if n_pts else ground0
    pt_sig = sig[n_corr:].reshape(n_pts, 3)
    gcp_res = np.full((len(g_ground), 3), np.nan)
    gcp_res[control_ids] = 0.0
    if len(free_gcp):
        gcp_res[free_gcp] = x_pts[n_tie:]
    cams = current_cameras()

    # check points: image residuals of their known ground, and their intersection when seen twice
    chk_obs = g_obs[check[g_obs[:, 0].astype(int)]] if len(g_obs) else g_obs
    chk_res = np.zeros((len(chk_obs), 2))
    for k, o in enumerate(chk_obs):
        chk_res[k] = np.asarray(cams[int(o[1])](jnp.asarray(g_ground[int(o[0])]))) - o[2:]
    chk_ground = np.full((len(g_ground), 3), np.nan)
    for p in np.unique(chk_obs[:, 0]).astype(int) if len(chk_obs) else []:
        po = chk_obs[chk_obs[:, 0] == p]
        if len(np.unique(po[:, 1])) >= 2:
            xi = _intersect(cams, po, _start_ground(cams, po, np.array([p]))[0])
            chk_ground[p] = (xi - g_ground[p]) * _metres_per_degree(np.array([g_ground[p, 1]]))[0]

    point_ids = np.concatenate([ties[:, 0], control[:, 0]]).astype(int)
    return RPCBlock(
        cameras=cams,
        model=model,
        corrections=corr.copy(),
        correction_sigmas=corr_sig,
        covariance=cov[:n_corr, :n_corr],
        tie_ids=tie_ids,
        tie_ground=pts[:n_tie],
        tie_sigmas=pt_sig[:n_tie],
        point=point_ids,
        image=img,
        is_gcp=kind == "g",
        residuals=-v,  # computed - observed (v above is the solver's observed - computed)
        standardized=-standardized,
        gcp_residuals=gcp_res,
        check_point=chk_obs[:, 0].astype(int),
        check_image=chk_obs[:, 1].astype(int),
        check_residuals=chk_res,
        check_ground_residuals=chk_ground,
        sigma0=sigma0,
        redundancy=r,
        iterations=iterations,
    )
