"""Tie points between overlapping images, guided by approximate orientations and a DEM.

:func:`match_ties` gives the observations of a :class:`photax.BundleProblem`
without hand measurement (seed 004, image matching):

1. interest points (Förstner) in every image, away from its border, spread
   over the part of the image that a later image sees;
2. each point is monoplotted onto the DEM by its image's sensor (a frame's
   approximate orientation, :func:`photax.image_to_ground`; an RPC's or a
   push-broom model's fixed point on the height: ``Sensor.on_dem``) and
   projected into every other image by its sensor (``Sensor.project``): the predicted position, i.e. the point of the epipolar line where the
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

import jax
import jax.numpy as jnp
import numpy as np

from ..camera import FrameCamera
from ..collinearity import stack_exteriors
from ..dem import DEM
from ..errors import CRSMismatchError
from ..geo import describe, same_crs
from ..sensor import FrameSensor, check_sensor_crs, is_sensor
from ._predict import (
    check_block,
    frame_pad,
    inside,
    match_sigma,
    match_warped,
    monoplot_sensors,
    padded,
    project_sensors,
    sensor_views,
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

    def as_rows(self) -> np.ndarray:
        """``(k, 4)`` rows ``point, image, column, row``: the observations as :func:`photax.adjust_rpc_block`
        takes its ties (which also takes the :class:`TiePoints` itself)."""
        return np.column_stack([self.obs_point, self.obs_image, self.obs_xy]).astype(float).reshape(-1, 4)

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


def _seen_by(xy: list, sensors, dem: DEM, size) -> tuple[list, np.ndarray]:
    """For each image's points ``xy[k] (n_k, 2)``, ``(n_k, m)``: whether image ``j`` sees its ground point
    (False for all ``j`` where the ray misses the DEM), and whether any ray of the image meets the DEM.
    ``size``: the images' ``(w, h)`` as ``(m, 1, 1)`` arrays (one per image ``j``)."""
    m = len(xy)
    n = max(max(len(p) for p in xy), 1)
    px = np.full((m, n, 2), np.nan)
    for k, p in enumerate(xy):
        px[k, : len(p)] = p
    ground = monoplot_sensors(px, sensors, dem)
    pred = project_sensors(ground.reshape(-1, 3), sensors).reshape(m, m, n, 2)
    seen = inside(pred, size, 0.0)  # [j, i, p]
    hits = np.all(np.isfinite(ground), axis=2).any(axis=1)
    return [seen[:, k, : len(p)].T for k, p in enumerate(xy)], hits


def _overlap(pred_grid: np.ndarray, size) -> np.ndarray:
    """``(m, m)`` predicted overlap: the share of image ``i``'s grid points whose ground point images
    inside ``j`` (``pred_grid[j, i]``; ``size`` as :func:`_seen_by`'s), averaged with the reverse share."""
    share = inside(pred_grid, size, 0.0).mean(axis=-1).T  # [i, j]
    return (share + share.T) / 2


def _frame_sensors(images, camera: FrameCamera, exterior) -> tuple[np.ndarray, list]:
    """The older frame form ``(images, camera, exterior)``: the stack and one :class:`photax.FrameSensor` each."""
    stack, eo = check_block(images, camera, exterior)
    return stack, [FrameSensor(jax.tree.map(lambda a, k=k: a[k], eo), camera) for k in range(len(stack))]


def _sensor_stack(images, sensors, dem) -> np.ndarray:
    """``m`` images of ``m`` sensors as one zero-filled ``(m, h_max, w_max)`` float64 stack, the
    sensors checked: photax sensors, one per image, of the image's size, in one CRS (a frame's the DEM's)."""
    sensors = list(sensors)
    imgs = [np.asarray(im, dtype=float) for im in images]
    if len(sensors) != len(imgs):
        raise ValueError(f"sensors: {len(sensors)} sensors for {len(imgs)} images (one per image)")
    for k, (s, im) in enumerate(zip(sensors, imgs)):
        if not is_sensor(s):
            raise ValueError(
                f"sensors[{k}]: expected a photax sensor (FrameSensor, GroundSensor: photax.sensor_of builds one), "
                f"got {type(s).__name__}"
            )
        if s.image_size is None:
            raise ValueError(f"sensors[{k}]: its camera has no image_size (the image's (width, height))")
        w, h = s.image_size
        if im.shape != (h, w):
            raise ValueError(f"images[{k}]: shape {im.shape}, but sensors[{k}].image_size is (w, h) = {(w, h)}")
    crs = [s.crs for s in sensors]
    for k, c in enumerate(crs):
        if (c is None) != (crs[0] is None) or (c is not None and not same_crs(c, crs[0])):
            name = lambda v: "no CRS" if v is None else describe(v)  # noqa: E731
            raise CRSMismatchError(
                f"sensors[{k}] is in {name(c)} but sensors[0] in {name(crs[0])}: tie matching predicts each "
                "image's points in the others through one ground frame (build the sensors for one CRS)"
            )
        if sensors[k].kind == "frame":  # a ground sensor samples a DEM in any CRS; a frame's rays are in the DEM's
            check_sensor_crs(sensors[k], dem.crs, "the DEM")
    hmax, wmax = max(im.shape[0] for im in imgs), max(im.shape[1] for im in imgs)
    stack = np.zeros((len(imgs), hmax, wmax))
    for k, im in enumerate(imgs):
        stack[k, : im.shape[0], : im.shape[1]] = im
    return stack


def match_ties(
    images,
    camera,
    exterior=None,
    dem: DEM | None = None,
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

    Two forms: ``match_ties(images, sensors, dem)``, one :class:`photax.Sensor` per image (frames,
    RPCs and push-broom models alike, in one CRS: :func:`photax.sensor_of`), and the frame form
    ``match_ties(images, camera, exterior, dem)`` (one :class:`photax.FrameCamera`, ``m``
    orientations), which is the first with a :class:`photax.FrameSensor` per orientation.  Every
    prediction goes through the sensors: a point is carried to the DEM by its sensor's ``on_dem``
    and into the others by their ``project`` (the predicted position, the local affine maps of its
    neighbours and the overlap grid alike), so an RPC pair is matched as a frame pair is.

    Args:
        images: ``m`` grey images ``(h, w)``.
        camera: ``m`` sensors (a list), or the frame form's one camera (``image_size`` required).
        exterior: the frame form's ``m`` approximate orientations (a list or a batched one); with
            sensors, the DEM may come here (``match_ties(images, sensors, dem)``).
        dem: terrain the rays are cut with (predictions, overlap, local affine maps); in the frames'
            CRS (a ground sensor's DEM may be in any CRS, as the products take it), heights
            ellipsoidal for an RPC or a push-broom model.
        max_points: interest points per image (strongest Förstner points,
            spread over the part of the image a later image sees).
        window: half-size of the matching window (``2 window + 1`` px square).
        search: NCC search radius around the prediction, px; must cover the
            prediction error of the approximate orientations (an RPC's bias).
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
        :class:`TiePoints` (tracks seen in >= 2 images); pixels of each image, ground in the
        sensors' CRS.  :meth:`TiePoints.as_rows` gives the rows :func:`photax.adjust_rpc_block` takes.

    Raises:
        ValueError: images / sensors (camera / orientations) that do not fit together.
        photax.errors.CRSMismatchError: sensors in different CRSs, or a frame's and the DEM's differ.

    Examples:
        Two frames 40 m apart over flat ground, rendered (:func:`photax.scene.render_image`); the
        frame form and the sensor form give the same ties, and each tie lands where the true
        orientations put the ground point of its first image's point:

        >>> import numpy as np, photax
        >>> from photax.scene import render_image
        >>> x0, y0 = 500_000.0, 4_000_000.0
        >>> dem = photax.DEM.flat(20.0, (x0 - 300, y0 - 300, x0 + 300, y0 + 300))
        >>> cam = photax.FrameCamera.from_pixels(300.0, (160, 120))
        >>> eos = [photax.ExteriorOrientation([x0 + dx, y0, 320.0], [0.0, 0.0, 0.0]) for dx in (0.0, 40.0)]
        >>> images = [render_image(cam, e, dem, origin=(x0, y0), supersample=2) for e in eos]
        >>> ties = photax.match_ties(images, cam, eos, dem, max_points=40)
        >>> sensors = [photax.FrameSensor(e, cam) for e in eos]
        >>> same = photax.match_ties(images, sensors, dem, max_points=40)
        >>> bool(np.array_equal(ties.obs_xy, same.obs_xy)), ties.pair_status[0, 1]
        (True, 'ok')
        >>> xy = [ties.obs_xy[ties.obs_image == k] for k in (0, 1)]  # one track per point, in order
        >>> ground, _ = sensors[0].localize(xy[0], 20.0)
        >>> float(np.abs(np.asarray(sensors[1].project(ground)) - xy[1]).max()) < 0.1
        True
    """
    # Over 80 lines: one pipeline (interest points, predictions, candidate pairs, batched
    # warped NCC/LSM, two-way check, guided outlier test, chained matches) whose arrays flow
    # from step to step.
    from ..measure import interest_points

    if isinstance(camera, FrameCamera):  # the frame form
        if dem is None:
            raise ValueError("dem: the frame form is match_ties(images, camera, exterior, dem)")
        stack, sensors = _frame_sensors(images, camera, exterior)
    else:
        if dem is None and isinstance(exterior, DEM):
            exterior, dem = None, exterior
        if exterior is not None or not isinstance(dem, DEM):
            raise ValueError("with sensors, give the DEM next: match_ties(images, sensors, dem)")
        if is_sensor(camera) or not isinstance(camera, (list, tuple)):
            raise ValueError(f"sensors: expected a list of one photax sensor per image, got {type(camera).__name__}")
        sensors = list(camera)
        stack = _sensor_stack(images, sensors, dem)
    m = len(stack)
    sizes = np.array([s.image_size for s in sensors], dtype=float)  # (m, 2) width, height
    per_view = (sizes[:, 0, None, None], sizes[:, 1, None, None])  # the size of image j of a [j, i, p] array
    # candidate interest points, monoplotted: an image keeps those a later image sees, spread over that area
    cand_xy = []
    for k in range(m):
        ip = interest_points(stack[k], "foerstner", window=5, min_distance=window // 2 + 2, max_points=20 * max_points)
        cand_xy.append(ip.xy[inside(ip.xy, sizes[k], window + 4)])
    seen_by, hits = _seen_by(cand_xy, sensors, dem, per_view)
    pts = [_spread(cand_xy[k][seen_by[k][:, k + 1 :].any(axis=1)], sizes[k], max_points) for k in range(m)]
    status = ["textureless" if not len(cand_xy[k]) else "ok" if hits[k] else "sees no DEM" for k in range(m)]
    n = max(max(len(p) for p in pts), 1)
    px = np.full((m, n, 2), np.nan)
    for k, p in enumerate(pts):
        px[k, : len(p)] = p
    # the points, their neighbours (local affine maps) and a grid (overlap) monoplotted and projected at once
    grid = np.stack(
        [np.stack([g.ravel() for g in np.meshgrid(np.linspace(0, w - 1, 16), np.linspace(0, h - 1, 16))], 1)
         for w, h in sizes]
    )  # fmt: skip
    ground, pred, affine, pred_grid = sensor_views(px, sensors, dem, step=window, extra=grid)  # pred [j, i, p]
    overlap = _overlap(pred_grid, per_view)
    affine = affine if warp else np.broadcast_to(np.eye(2), (m, m, n, 2, 2))
    usable = warpable(affine)
    reach = int(np.ceil(np.sqrt(2) * (window + 2)))
    ok_img = np.array([s == "ok" for s in status])
    cand = inside(pred, per_view, reach + 1) & usable & ok_img[:, None, None] & ok_img[None, :, None]  # [j, i, p]
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
            & inside(fxy, (sizes[bj, 0], sizes[bj, 1]), window + 1)
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
