"""Tie points between overlapping images, guided by approximate orientations and a DEM.

:func:`match_ties` gives the observations of a :class:`photax.BundleProblem`
without hand measurement (seed 004, image matching):

1. interest points (Förstner) in every image, away from its border, spread
   over the part of the image that a later image sees;
2. each point is monoplotted onto the DEM with its image's approximate
   orientation (:func:`photax.image_to_ground`) and projected into every other
   image: the predicted position, i.e. the point of the epipolar line where the
   ray meets the terrain.  Four neighbours of the point (``window`` px away)
   go the same way: their projections give the *local affine map* from the
   image to the other (``A = d x_j / d x_i``: the rotation, scale and shear
   between the views and the terrain's slope);
3. the template is resampled by that map into the other image's geometry
   (``T(u) = I_i(x_i + A^-1 u)``), so that strips flown the opposite way,
   crossing strips and rotated or oblique images correlate like parallel
   ones; normalised cross-correlation within ``search`` px of the prediction
   (the prediction's error is the orientations' error, a few px), then
   least-squares matching (Gruen 1985; its affine and gain/offset parameters
   take up what the prediction missed and the radiometric differences);
4. two-way consistency: the matched window, resampled in the first image's
   geometry, is matched back into the first image by LSM and must land
   within ``back_tol`` px of the interest point;
5. guided outlier test: in each pair, ``matched - predicted`` is a smooth
   function of position (the orientation errors), an affine one to first
   order; matches further than ``max(3 MAD, guide_tol)`` from a robust affine
   fit of it are rejected;
6. chained matches: an image that sees a track's ground point but is not in
   it yet is matched from the track's image that overlaps it most (steps
   3-5; the affine maps compose), so a diagonal pair of a block is tied
   through its crossing neighbours' matches.  A track that meets an earlier
   track (an observation within 1 px of one of its observations) is the same
   ground point and is dropped.

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
    check_block,
    frame_pad,
    inside,
    match_sigma,
    match_warped,
    monoplot_pixels,
    padded,
    project_pixels,
    views,
    warpable,
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
        pair_counts: ``{(i, j): accepted matches}`` for every pair with candidates
            (points of ``i`` matched into ``j``; a point seen by an earlier image
            is that image's, see the owner rule).
        pair_status: ``{(i, j): "ok" | "no overlap" | "too few matches" | "textureless"
            | "sees no DEM"}`` for every pair ``i < j``: ``"ok"`` when at least
            ``min_matches`` tracks tie the two images (:attr:`pair_ties`).
        image_status: ``(m,)`` ``"ok"``, ``"textureless"`` (no interest points)
            or ``"sees no DEM"`` (no point monoplots onto the DEM).
        pair_overlap: ``{(i, j): predicted overlap}``, 0..1: the share of each
            image's area whose ground point (on the DEM, approximate
            orientations) images inside the other, the mean of both ways.
        pair_ties: ``{(i, j): tracks seen in both images}`` for every pair ``i < j``.

    Examples:
        One track seen in two images, its observations in pixels; :meth:`image_plane` gives them in
        the camera's unit, as :class:`photax.BundleProblem` takes them (the image centre is 0, 0):

        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.matching import TiePoints
        >>> ties = TiePoints(obs_image=np.array([0, 1]), obs_point=np.array([0, 0]),
        ...                  obs_xy=np.array([[499.5, 374.5], [399.5, 374.5]]), obs_sigma=np.array([0.5, 0.5]),
        ...                  ground=np.array([[0.0, 0.0, 0.0]]), pair_counts={(0, 1): 1},
        ...                  pair_status={(0, 1): "too few matches"}, image_status=["ok", "ok"])
        >>> xy, sigma = ties.image_plane(ptx.FrameCamera(8.8, pixel_size=0.0176, image_size=(1000, 750)))
        >>> print(np.round(xy, 9) + 0.0, np.round(sigma, 9))  # mm: 100 px * 0.0176 mm to the left
        [[ 0.    0.  ]
         [-1.76  0.  ]] [0.0088 0.0088]
        >>> ties.n_tracks
        1
    """

    obs_image: np.ndarray
    obs_point: np.ndarray
    obs_xy: np.ndarray
    obs_sigma: np.ndarray
    ground: np.ndarray
    pair_counts: dict
    pair_status: dict
    image_status: list
    pair_overlap: dict = dataclasses.field(default_factory=dict)
    pair_ties: dict = dataclasses.field(default_factory=dict)

    @property
    def n_tracks(self) -> int:
        return len(self.ground)

    def image_plane(self, camera: FrameCamera) -> tuple[np.ndarray, np.ndarray]:
        """Observations and sigmas in image-plane units (what :class:`photax.BundleProblem` takes)."""
        xy = np.asarray(camera.pixel_to_image(jnp.asarray(self.obs_xy))) if len(self.obs_xy) else np.zeros((0, 2))
        return xy, self.obs_sigma * _pixel_size(camera)


def _pixel_size(camera: FrameCamera) -> float:
    return float(np.mean(np.asarray(camera._pixel_grid()[1])))


def _spread(xy: np.ndarray, size, n: int) -> np.ndarray:
    """At most ``n`` of ``xy`` (strongest first) spread over the image: the strongest of each cell of a
    grid of about ``n`` cells first, then the strongest of the rest (so every overlap gets points)."""
    if len(xy) <= n:
        return xy
    w, h = size
    gx = max(int(round(np.sqrt(n * w / h))), 1)
    gy = max(int(round(n / gx)), 1)
    cell = np.minimum((xy[:, 0] * gx / w).astype(int), gx - 1) + gx * np.minimum(
        (xy[:, 1] * gy / h).astype(int), gy - 1
    )
    _, first = np.unique(cell, return_index=True)  # the strongest point of each occupied cell
    rest = np.setdiff1d(np.arange(len(xy)), first)
    order = np.concatenate([np.sort(first), rest])[:n]
    return xy[np.sort(order)]


def _seen_by(xy: list, eo, camera: FrameCamera, dem: DEM, size) -> tuple[list, np.ndarray]:
    """For each image's points ``xy[k] (n_k, 2)``, ``(n_k, m)``: whether image ``j`` sees its ground point
    (False for all ``j`` where the ray misses the DEM), and whether any ray of the image meets the DEM."""
    m = len(xy)
    n = max(max(len(p) for p in xy), 1)
    px = np.full((m, n, 2), np.nan)
    for k, p in enumerate(xy):
        px[k, : len(p)] = p
    ground = monoplot_pixels(px, eo, camera, dem)
    pred = project_pixels(ground.reshape(-1, 3), eo, camera).reshape(m, m, n, 2)
    seen = inside(pred, size, 0.0)  # [j, i, p]
    hits = np.all(np.isfinite(ground), axis=2).any(axis=1)
    return [seen[:, k, : len(p)].T for k, p in enumerate(xy)], hits


def _overlap(pred_grid: np.ndarray, size) -> np.ndarray:
    """``(m, m)`` predicted overlap: the share of image ``i``'s grid points whose ground point images
    inside ``j`` (``pred_grid[j, i]``), averaged with the reverse share."""
    share = inside(pred_grid, size, 0.0).mean(axis=-1).T  # [i, j]
    return (share + share.T) / 2


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
    warp: bool = True,
) -> TiePoints:
    """Tie points between overlapping images, guided by approximate orientations and the DEM.

    Args:
        images: ``m`` grey images ``(h, w)`` of one camera.
        camera: their camera (``image_size`` required).
        exterior: ``m`` approximate orientations (a list or a batched one).
        dem: terrain the rays are cut with (predictions, overlap, local affine maps).
        max_points: interest points per image (strongest Förstner points,
            spread over the part of the image a later image sees).
        window: half-size of the matching window (``2 window + 1`` px square).
        search: NCC search radius around the prediction, px; must cover the
            prediction error of the approximate orientations.
        min_rho: smallest accepted NCC peak.
        back_tol: two-way consistency, px.
        guide_tol: smallest outlier threshold of the guided test, px.
        min_matches: a pair's matches of one pass (direct or chained) are
            dropped when fewer than this many pass the guided test.
        warp: resample each template by the local affine map predicted from
            the orientations and the DEM (rotation, scale, shear between the
            views), so that opposite or crossing strips and rotated or oblique
            images match like parallel ones; False correlates unrotated
            windows (the views must then be nearly parallel).

    Returns:
        :class:`TiePoints` (tracks seen in >= 2 images).

    Raises:
        ValueError: images / camera / orientations that do not fit together.
    """
    # Over 80 lines: one pipeline (interest points, predictions, candidate pairs, batched
    # warped NCC/LSM, two-way check, guided outlier test, chained matches) whose arrays flow
    # from step to step.
    from ..measure import interest_points

    stack, eo = check_block(images, camera, exterior)
    m = len(stack)
    size = camera.image_size
    # candidate interest points, monoplotted: an image keeps those a later image sees, spread over that area
    cand_xy = []
    for k in range(m):
        ip = interest_points(stack[k], "foerstner", window=5, min_distance=window // 2 + 2, max_points=20 * max_points)
        cand_xy.append(ip.xy[inside(ip.xy, size, window + 4)])
    seen_by, hits = _seen_by(cand_xy, eo, camera, dem, size)
    pts = [_spread(cand_xy[k][seen_by[k][:, k + 1 :].any(axis=1)], size, max_points) for k in range(m)]
    status = ["textureless" if not len(cand_xy[k]) else "ok" if hits[k] else "sees no DEM" for k in range(m)]
    n = max(max(len(p) for p in pts), 1)
    px = np.full((m, n, 2), np.nan)
    for k, p in enumerate(pts):
        px[k, : len(p)] = p
    # the points, their neighbours (local affine maps) and a grid (overlap) monoplotted and projected at once
    w, h = size
    gx, gy = np.meshgrid(np.linspace(0, w - 1, 16), np.linspace(0, h - 1, 16))
    grid = np.broadcast_to(np.stack([gx.ravel(), gy.ravel()], axis=1), (m, 256, 2))
    ground, pred, affine, pred_grid = views(px, eo, camera, dem, step=window, extra=grid)  # pred [j, i, p]: i in j
    overlap = _overlap(pred_grid, size)
    affine = affine if warp else np.broadcast_to(np.eye(2), (m, m, n, 2, 2))
    usable = warpable(affine)
    reach = int(np.ceil(np.sqrt(2) * (window + 2)))
    ok_img = np.array([s == "ok" for s in status])
    cand = inside(pred, size, reach + 1) & usable & ok_img[:, None, None] & ok_img[None, :, None]  # [j, i, p]
    pairs = [(i, j) for i in range(m) for j in range(i + 1, m)]
    pair_overlap = {pr: float(overlap[pr]) for pr in pairs}
    pair_status = {pr: "no overlap" if overlap[pr] == 0 else "too few matches" for pr in pairs}
    for i, j in pairs:
        if status[i] != "ok" or status[j] != "ok":
            pair_status[i, j] = "textureless" if "textureless" in (status[i], status[j]) else "sees no DEM"
    pad = frame_pad(window, search)
    big = padded(stack, pad)
    counts = {}

    def accepted(bk, bj, txy, sxy, aff):
        """Rows matched and accepted (NCC, LSM, two-way, guided test per pair), their xy and sigma."""
        mt = match_warped(big, bk, txy + pad, bj, sxy + pad, aff, window=window, search=search, back=True)
        fxy = np.where(mt.lsm_valid[:, 0, None], mt.lsm_xy[:, 0] - pad, sxy)
        ok = (
            mt.ncc_valid[:, 0]
            & (np.nan_to_num(mt.rho[:, 0]) >= min_rho)
            & mt.lsm_valid[:, 0]
            & mt.back_valid[:, 0]
            & inside(fxy, size, window + 1)
        )
        with np.errstate(invalid="ignore"):
            ok &= np.linalg.norm(mt.back_xy[:, 0] - pad - txy, axis=-1) <= back_tol
        keep = []
        for k, j in sorted(set(zip(bk.tolist(), bj.tolist()))):
            rows = np.flatnonzero((bk == k) & (bj == j) & ok)
            if len(rows):
                rows = rows[_robust_affine(txy[rows], fxy[rows] - sxy[rows], guide_tol)]
            if len(rows) >= min_matches:
                keep.extend(rows.tolist())
                counts[min(k, j), max(k, j)] = counts.get((min(k, j), max(k, j)), 0) + len(rows)
        keep = np.array(sorted(keep), dtype=int)
        return keep, fxy[keep], match_sigma(mt.lsm_cov[keep, 0]) / np.sqrt(2.0)

    # direct matches: the points of each image into every later image that sees them
    it = np.array([(i, j, p) for i, j in pairs for p in np.flatnonzero(cand[j, i])]).reshape(-1, 3)
    if not len(it):
        return _assemble({}, px, ground, m, counts, pair_status, status, pair_overlap, min_matches)
    bi, bj, pid = it.T
    obs = {}  # (i, p) -> {j: (xy, sigma)}: the track of point p of image i
    rows, fxy, sig = accepted(bi, bj, px[bi, pid], pred[bj, bi, pid], affine[bj, bi, pid])
    for r, xy, sg in zip(rows, fxy, sig):
        obs.setdefault((int(bi[r]), int(pid[r])), {})[int(bj[r])] = (xy, sg)
    # chained matches: an image that sees a track's ground point but is not in it (an earlier image,
    # or a later one whose match failed) is matched from the track's image that overlaps it most
    # (a crossing pair often matches where a diagonal one does not); the affine maps compose,
    # A_jk = A_ji A_ki^-1, with A_ii = I
    chain = []
    for (i, p), ms in obs.items():
        for j in np.flatnonzero(cand[:, i, p]):
            if j != i and j not in ms:
                src = [k for k in ms if k != j] + ([i] if j < i else [])
                chain.append((max(src, key=lambda k: overlap[k, j]), j, i, p))
    if chain:
        ck, cj, ci, cp = np.array(chain).T
        xy_k = np.array([px[i, p] if k == i else obs[i, p][k][0] for k, _, i, p in chain])
        a_k = np.where((ck == ci)[:, None, None], np.eye(2), affine[ck, ci, cp])
        rows, fxy, sig = accepted(ck, cj, xy_k, pred[cj, ci, cp], affine[cj, ci, cp] @ np.linalg.inv(a_k))
        for r, xy, sg in zip(rows, fxy, sig):
            obs[int(ci[r]), int(cp[r])][int(cj[r])] = (xy, sg)
    return _assemble(obs, px, ground, m, counts, pair_status, status, pair_overlap, min_matches)


def _assemble(obs, px, ground, m, counts, pair_status, status, pair_overlap, min_matches) -> TiePoints:
    """:class:`TiePoints` from the tracks ``{(i, p): {j: (xy, sigma)}}`` of point ``p`` of image ``i``.

    A track with an observation within 1 px of an earlier track's observation in the same image
    is dropped: the two are one ground point (a point of image 1 that image 0's track reached)."""
    oi, op, oxy, osig, gr = [], [], [], [], []
    taken = [[] for _ in range(m)]
    for (i, p), ms in sorted(obs.items()):
        track = {i: (px[i, p], float(np.mean([s for _, s in ms.values()])))} | ms
        if any(
            taken[j] and np.min(np.linalg.norm(np.array(taken[j]) - xy, axis=1)) < 1.0 for j, (xy, _) in track.items()
        ):
            continue
        t = len(gr)
        for j, (xy, s) in sorted(track.items()):
            taken[j].append(xy)
            oi.append(j)
            op.append(t)
            oxy.append(xy)
            osig.append(float(s))
        gr.append(ground[i, p])
    # ties per pair: tracks seen in both images
    seen_in = np.zeros((len(gr), m), bool)
    seen_in[np.array(op, dtype=int), np.array(oi, dtype=int)] = True
    ties = {pr: int(np.sum(seen_in[:, pr[0]] & seen_in[:, pr[1]])) for pr in pair_status}
    pair_status = dict(pair_status)
    for pr in pair_status:
        if pair_status[pr] == "too few matches" and ties[pr] >= min_matches:
            pair_status[pr] = "ok"
    return TiePoints(
        np.array(oi, dtype=int), np.array(op, dtype=int), np.array(oxy, dtype=float).reshape(-1, 2),
        np.array(osig, dtype=float), np.array(gr, dtype=float).reshape(-1, 3), counts, pair_status, status,
        pair_overlap, ties,
    )  # fmt: skip


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
