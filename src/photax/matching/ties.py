"""Tie points between overlapping images, guided by approximate orientations and a DEM.

:func:`match_ties` gives the observations of a :class:`photax.BundleProblem`
without hand measurement (seed 004, image matching):

1. interest points (Förstner) in every image, away from its border;
2. each point is monoplotted onto the DEM with its image's approximate
   orientation (:func:`photax.image_to_ground`) and projected into every other
   image: the predicted position, i.e. the point of the epipolar line where the
   ray meets the terrain.  A ground point is *owned* by the first image that
   sees it (so a point is one track, not one per image);
3. normalised cross-correlation within ``search`` px of the prediction (the
   prediction's error is the orientations' error, a few px), then
   least-squares matching (Gruen 1985) from the NCC peak;
4. two-way consistency: the matched window is matched back into the first
   image by LSM and must land within ``back_tol`` px of the interest point;
5. guided outlier test: in each pair, ``matched - predicted`` is a smooth
   function of position (the orientation errors), an affine one to first
   order; matches further than ``max(3 MAD, guide_tol)`` from a robust affine
   fit of it are rejected.

Each accepted match gives the track an observation; its sigma is the LSM
shift's ``sqrt(trace(Cov) / 2) / sqrt(2)``: LSM's ``sigma0`` holds the noise
of both windows, half of the variance of the difference is given to each
side (the first image's point gets the mean of its matches').

:func:`bundle_problem` joins tie tracks and transferred GCPs
(:func:`photax.transfer_points`) into a :class:`photax.BundleProblem`.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ..camera import FrameCamera
from ..collinearity import stack_exteriors
from ..dem import DEM
from ._predict import (
    POINTS,
    check_block,
    chunks_of,
    inside,
    match_chunks,
    match_sigma,
    monoplot_pixels,
    padded,
    project_pixels,
)

__all__ = ["TiePoints", "match_ties", "bundle_problem"]


def _robust_affine(xy, d, tol):
    """Inliers of ``d ~ A [x, y, 1]``: a median-translation cut, then affine fits with MAD cuts."""
    # a translation first (an affine fit on a narrow overlap band can absorb a false match), then the affine
    r0 = np.linalg.norm(d - np.median(d, axis=0), axis=1)
    ok = r0 <= max(3 * 1.4826 * np.median(r0), 3 * tol)
    if ok.sum() < 6:
        return ok & (r0 <= 3 * tol)
    a = np.column_stack([xy, np.ones(len(xy))])
    for _ in range(3):
        coef, *_ = np.linalg.lstsq(a[ok], d[ok], rcond=None)
        r = np.linalg.norm(d - a @ coef, axis=1)
        mad = 1.4826 * np.median(r[ok])
        ok = r <= max(3 * mad, tol)
    return ok


# --------------------------------------------------------------------------- tie points


@dataclasses.dataclass(frozen=True)
class TiePoints:
    """Output of :func:`match_ties`.

    Attributes:
        obs_image, obs_point: ``(k,)`` image and track index of each observation.
        obs_xy: ``(k, 2)`` pixel (column, row).
        obs_sigma: ``(k,)`` standard deviation of a pixel coordinate.
        ground: ``(n_tracks, 3)`` approximate ground points (monoplotted with the
            first image's approximate orientation).
        pair_counts: ``{(i, j): accepted matches}`` for every pair with candidates.
        pair_status: ``{(i, j): "ok" | "no overlap" | "too few matches" | "textureless"}``
            for every pair ``i < j``.
        image_status: ``(m,)`` ``"ok"``, ``"textureless"`` (no interest points)
            or ``"sees no DEM"`` (no point monoplots onto the DEM).
    """

    obs_image: np.ndarray
    obs_point: np.ndarray
    obs_xy: np.ndarray
    obs_sigma: np.ndarray
    ground: np.ndarray
    pair_counts: dict
    pair_status: dict
    image_status: list

    @property
    def n_tracks(self) -> int:
        return len(self.ground)

    def image_plane(self, camera: FrameCamera) -> tuple[np.ndarray, np.ndarray]:
        """Observations and sigmas in image-plane units (what :class:`photax.BundleProblem` takes)."""
        xy = np.asarray(camera.pixel_to_image(jnp.asarray(self.obs_xy))) if len(self.obs_xy) else np.zeros((0, 2))
        return xy, self.obs_sigma * _pixel_size(camera)


def _pixel_size(camera: FrameCamera) -> float:
    return float(np.mean(np.asarray(camera._pixel_grid()[1])))


def match_ties(
    images,
    camera: FrameCamera,
    exterior,
    dem: DEM,
    *,
    max_points: int = 150,
    window: int = 8,
    search: int = 12,
    min_rho: float = 0.7,
    back_tol: float = 0.3,
    guide_tol: float = 1.0,
    min_matches: int = 6,
) -> TiePoints:
    """Tie points between overlapping images, guided by approximate orientations and the DEM.

    Args:
        images: ``m`` grey images ``(h, w)`` of one camera.
        camera: their camera (``image_size`` required).
        exterior: ``m`` approximate orientations (a list or a batched one).
        dem: terrain the rays are cut with (predictions, overlap).
        max_points: interest points per image (strongest Förstner points).
        window: half-size of the matching window (``2 window + 1`` px square).
        search: NCC search radius around the prediction, px; must cover the
            prediction error of the approximate orientations.
        min_rho: smallest accepted NCC peak.
        back_tol: two-way consistency, px.
        guide_tol: smallest outlier threshold of the guided test, px.
        min_matches: pairs with fewer accepted matches are dropped (status
            ``"too few matches"``).

    Returns:
        :class:`TiePoints` (tracks seen in >= 2 images).

    Raises:
        ValueError: images / camera / orientations that do not fit together.
    """
    # Over 80 lines: one pipeline (interest points, owner rule, candidate pairs, batched
    # NCC/LSM, two-way check, guided outlier test) whose arrays flow from step to step.
    from ..measure import interest_points

    stack, eo = check_block(images, camera, exterior)
    m = len(stack)
    size = camera.image_size
    margin = window + search + 4
    pts, status = [], []
    for k in range(m):
        ip = interest_points(stack[k], "foerstner", window=5, min_distance=window // 2 + 2, max_points=4 * max_points)
        xy = ip.xy[inside(ip.xy, size, window + 4)][:max_points]
        pts.append(xy)
        status.append("ok" if len(xy) else "textureless")
    n = max(max(len(p) for p in pts), 1)
    px = np.full((m, n, 2), np.nan)
    for k, p in enumerate(pts):
        px[k, : len(p)] = p
    ground = monoplot_pixels(px, eo, camera, dem)  # (m, n, 3)
    for k in range(m):
        if status[k] == "ok" and not np.any(np.all(np.isfinite(ground[k]), axis=1)):
            status[k] = "sees no DEM"
    flat = ground.reshape(-1, 3)
    pred = project_pixels(flat, eo, camera).reshape(m, m, n, 2)  # [j, i, p]: point p of image i in image j
    seen = inside(pred, size, 0.0)
    # owner rule: point p of image i is kept when no earlier image sees it
    earlier = np.tril(np.ones((m, m), bool), -1).T  # earlier[j, i] = j < i
    owned = ~np.any(seen & earlier[:, :, None], axis=0)  # (i, p)
    # candidate matches (i < j)
    cand = inside(pred, size, window + 3) & owned[None] & earlier.T[:, :, None]  # [j, i]: j > i
    pairs = [(i, j) for i in range(m) for j in range(i + 1, m)]
    pair_status = {pr: "no overlap" for pr in pairs}
    items = [(i, j, p) for (i, j) in pairs if status[i] == status[j] == "ok" for p in np.flatnonzero(cand[j, i])]
    for i, j in pairs:
        if status[i] != "ok" or status[j] != "ok":
            pair_status[i, j] = "textureless" if "textureless" in (status[i], status[j]) else "sees no DEM"
    empty = TiePoints(
        np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), np.zeros((0, 3)), {}, pair_status, status
    )
    if not items:
        return empty
    it = np.array(items)
    # chunks of up to 16 points of one pair, matched BATCH pairs per compiled call (match_chunks)
    centre = (np.asarray(size) - 1) / 2.0 + margin
    groups = {}
    for i, j in sorted({(i, j) for i, j, _ in items}):
        sel = it[(it[:, 0] == i) & (it[:, 1] == j), 2]
        groups[i, j] = (sel, px[i, sel] + margin, pred[j, i, sel] + margin)
    chunks, txy, sxy = chunks_of(groups, centre)
    nc = len(chunks)
    bi = np.array([i for (i, _), _ in chunks])
    bj = np.array([j for (_, j), _ in chunks])
    valid = np.zeros((nc, POINTS), bool)
    pid = np.zeros((nc, POINTS), int)
    for b, (_, sel) in enumerate(chunks):
        valid[b, : len(sel)] = True
        pid[b, : len(sel)] = sel
    big = padded(stack, margin)
    mt = match_chunks(big, bi, bj, txy, sxy, window=window, search=search, back=True)
    txy, sxy = txy - margin, sxy - margin
    fxy = np.where(mt.lsm_valid[..., None], mt.lsm_xy - margin, sxy)
    ok = (
        valid
        & mt.ncc_valid
        & (np.nan_to_num(mt.rho) >= min_rho)
        & mt.lsm_valid
        & mt.back_valid
        & inside(fxy, size, window + 1)
    )
    with np.errstate(invalid="ignore"):
        ok &= np.linalg.norm(mt.back_xy - margin - txy, axis=-1) <= back_tol
    sig = match_sigma(mt.lsm_cov) / np.sqrt(2.0)
    obs = {}  # (i, p) -> list of (j, xy, sigma)
    counts = {}
    for i, j in sorted({(i, j) for i, j, _ in items}):
        mine = np.flatnonzero((bi == i) & (bj == j) & valid.any(axis=1))
        bq = [(b, q) for b in mine for q in np.flatnonzero(ok[b])]
        if bq:
            bb, qq = np.array(bq).T
            good = _robust_affine(txy[bb, qq], fxy[bb, qq] - sxy[bb, qq], guide_tol)
            bq = [x for x, g in zip(bq, good) if g]
        counts[i, j] = len(bq)
        if len(bq) < min_matches:
            pair_status[i, j] = "too few matches"
            continue
        pair_status[i, j] = "ok"
        for b, q in bq:
            obs.setdefault((i, int(pid[b, q])), []).append((j, fxy[b, q], sig[b, q]))
    oi, op, oxy, osig, gr = [], [], [], [], []
    for t, ((i, p), ms) in enumerate(sorted(obs.items())):
        oi.append(i)
        op.append(t)
        oxy.append(px[i, p])
        osig.append(float(np.mean([s for _, _, s in ms])))
        for j, xy, s in ms:
            oi.append(j)
            op.append(t)
            oxy.append(xy)
            osig.append(float(s))
        gr.append(ground[i, p])
    if not oi:
        return dataclasses.replace(empty, pair_counts=counts)
    return TiePoints(
        np.array(oi), np.array(op), np.array(oxy), np.array(osig), np.array(gr), counts, pair_status, status
    )


def bundle_problem(
    camera: FrameCamera,
    exterior,
    ties: TiePoints | None = None,
    gcps=None,
    *,
    image_names=None,
    point_sigma=0.0,
    sigma_floor: float = 0.0,
):
    """A :class:`photax.BundleProblem` from tie tracks and transferred GCPs.

    Args:
        camera: the one camera.
        exterior: ``m`` approximate orientations (start values).
        ties: :class:`TiePoints` from :func:`match_ties`, or None.
        gcps: a :class:`photax.io.GCPTable` in pixels (e.g.
            :attr:`photax.Transfer.table`) whose image names are in
            ``image_names``, or None.
        image_names: ``m`` names (default ``"0", "1", ...``, matching
            :func:`photax.transfer_points`' default).
        point_sigma: ground sigma of control points (0: fixed).
        sigma_floor: added in quadrature to every measurement sigma, px
            (model errors the matchers' precision does not see).

    Returns:
        :class:`photax.BundleProblem`; GCP roles as in the table, ties ``"tie"``
        with approximate (monoplotted) coordinates.  Tie and check points
        measured in fewer than two images are left out (they cannot be intersected).
    """
    from ..bundle import BundleProblem

    eo = stack_exteriors(exterior)
    m = eo.position.shape[0]
    names = [str(k) for k in range(m)] if image_names is None else [str(s) for s in image_names]
    if len(names) != m:
        raise ValueError(f"image_names: {len(names)} names for {m} images")
    index = {s: k for k, s in enumerate(names)}
    pts, roles, pnames, oi, op, oxy, osig = [], [], [], [], [], [], []
    if gcps is not None:
        if gcps.pixel is None:
            raise ValueError("gcps: the table must give pixels (column, row)")
        unknown = sorted(set(gcps.images.tolist()) - set(index))
        if unknown:
            raise ValueError(f"gcps: images {unknown} are not among image_names {names}")
        for nm in dict.fromkeys(gcps.names.tolist()):
            rows = np.flatnonzero(gcps.names == nm)
            t = len(pts)
            pts.append(gcps.ground[rows[0]])
            roles.append(str(gcps.role[rows[0]]))
            pnames.append(nm)
            for r in rows:
                oi.append(index[str(gcps.images[r])])
                op.append(t)
                oxy.append(gcps.pixel[r])
                s = float(gcps.sigma[r])
                osig.append(s if np.isfinite(s) else 1.0)
    if ties is not None:
        base = len(pts)
        for t in range(ties.n_tracks):
            pts.append(ties.ground[t])
            roles.append("tie")
            pnames.append(f"tie{t}")
        oi.extend(ties.obs_image.tolist())
        op.extend((ties.obs_point + base).tolist())
        oxy.extend(list(ties.obs_xy))
        osig.extend(ties.obs_sigma.tolist())
    if not oi:
        raise ValueError("nothing to adjust: no tie tracks and no GCP measurements")
    # tie and check points need two rays; control points keep their single ones
    seen = np.bincount(np.array(op), minlength=len(pts))
    keep_pt = (seen >= 2) | (np.array(roles) == "control")
    if not keep_pt.all():
        new_id = np.cumsum(keep_pt) - 1
        keep_ob = keep_pt[np.array(op)]
        oi, oxy, osig = ([v for v, kk in zip(a, keep_ob) if kk] for a in (oi, oxy, osig))
        op = list(new_id[np.array(op)[keep_ob]])
        pts = [v for v, kk in zip(pts, keep_pt) if kk]
        roles = [v for v, kk in zip(roles, keep_pt) if kk]
        pnames = [v for v, kk in zip(pnames, keep_pt) if kk]
    xy = np.asarray(camera.pixel_to_image(jnp.asarray(np.array(oxy, dtype=float))))
    sig = np.sqrt(np.array(osig) ** 2 + sigma_floor**2) * _pixel_size(camera)
    return BundleProblem(
        camera,
        eo,
        np.array(pts, dtype=float),
        np.array(oi),
        np.array(op),
        xy,
        obs_sigma=sig,
        roles=roles,
        point_sigma=point_sigma,
        image_names=names,
        point_names=pnames,
    )
