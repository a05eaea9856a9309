"""Transfer of ground control points into every image that sees them.

:func:`transfer_points`: a GCP measured in one image, or known only on the
ground (then found by matching a target template), is predicted in every
other image with the approximate orientations (collinearity, the point's
ground coordinates; a missing height is read from the DEM), then measured
there as tie points are (:mod:`photax.matching.ties`): the reference image's
window is resampled by the local affine map between the two views, predicted
from the orientations and the DEM (rotation, scale, shear: strips flown the
opposite way, rotated drone frames), then normalised cross-correlation within
``search`` px of the prediction and least-squares matching (Gruen 1985, with
gain and offset for the radiometric differences).  Each measurement gets the LSM shift's sigma ``sqrt(trace(Cov) / 2)`` (for a
transferred one combined in quadrature with its reference's, whose error it
inherits) and
each (point, image) item a status, so a GCP list can be written for
:func:`photax.resect`, :func:`photax.bundle_adjust` or OpenDroneMap.
"""

from __future__ import annotations

import dataclasses
import pathlib

import jax.numpy as jnp
import numpy as np

from ..camera import FrameCamera
from ..dem import DEM
from ..errors import OutsideValidityError, UnsupportedFormatError
from ._predict import check_block, frame_pad, inside, match_sigma, match_warped, padded, project_pixels, views, warpable

__all__ = ["Transfer", "transfer_points", "write_odm_gcps"]

STATUSES = (
    "ok",
    "reference",
    "not in image",
    "at image border",
    "behind camera",
    "outside DEM",
    "scale differs",
    "low correlation",
    "not matched",
    "no reference",
    "inconsistent",
    "not two-way",
)


@dataclasses.dataclass(frozen=True)
class Transfer:
    """Output of :func:`transfer_points`.

    Attributes:
        table: :class:`photax.io.GCPTable` of the successful measurements
            (reference and transferred), pixels, ``sigma`` in px.
        items: one dict per (point, image) pair: ``name``, ``image``,
            ``status`` (one of :data:`STATUSES`), ``predicted`` (px),
            ``xy`` (px, NaN unless measured), ``sigma`` (px), ``rho`` (NCC peak).
    """

    table: object
    items: list

    def status(self, name: str) -> dict:
        """``{image: status}`` of one point."""
        return {it["image"]: it["status"] for it in self.items if it["name"] == name}

    def write(self, path, *, format: str = "csv", crs: str | None = None) -> pathlib.Path:
        """Write the GCP list: ``"csv"`` (:func:`photax.io.write_gcps`) or ``"odm"`` (``gcp_list.txt``)."""
        from ..io import write_gcps

        if format == "csv":
            return write_gcps(path, self.table)
        if format == "odm":
            return write_odm_gcps(path, self.table, crs=crs)
        raise UnsupportedFormatError(f"format: expected 'csv' or 'odm', got {format!r}")


def write_odm_gcps(path, table, *, crs: str | None = None) -> pathlib.Path:
    """OpenDroneMap ``gcp_list.txt``: CRS line, then ``E N h col row image name`` per measurement.

    Pixel convention as :func:`photax.io.read_gcps` reads it (integer = pixel
    centre, kept as is).  ODM has no sigma or role column: they are not written.
    """
    from ..io.atomic import atomic_write

    crs = crs if crs is not None else table.crs
    if not crs or "\n" in crs:
        raise ValueError("crs: an ODM gcp_list.txt starts with the CRS (e.g. 'EPSG:32633'); give one")
    if table.pixel is None:
        raise ValueError("table: ODM lists need pixel coordinates")
    for v in (*table.names.tolist(), *table.images.tolist()):
        if not v or any(c.isspace() for c in v):
            raise ValueError(f"table: name {v!r} is empty or has whitespace (ODM columns are whitespace-separated)")
    with atomic_write(path, newline="") as fh:
        fh.write(f"{crs}\n")
        for k in range(len(table)):
            e, n, h = (repr(float(v)) for v in table.ground[k])
            c, r = (repr(float(v)) for v in table.pixel[k])
            fh.write(f"{e} {n} {h} {c} {r} {table.images[k]} {table.names[k]}\n")
    return pathlib.Path(path)


def transfer_points(
    images,
    camera: FrameCamera,
    exterior,
    dem: DEM | None,
    ground,
    *,
    names=None,
    image_names=None,
    reference_image=None,
    reference_xy=None,
    target_template=None,
    roles=None,
    window: int = 8,
    search: int = 12,
    min_rho: float = 0.7,
    min_rho_template: float = 0.6,
    back_tol: float = 0.3,
    crs: str | None = None,
) -> Transfer:
    """Measure ground control points in every image that sees them.

    Args:
        images: ``m`` grey images ``(h, w)`` of one camera.
        camera: their camera (``image_size`` required).
        exterior: ``m`` approximate orientations.
        dem: terrain for heights given as NaN and for the local affine maps
            between the views (None: all heights given; the maps are then
            predicted on a level plane through the points' mean height).
        ground: ``(n, 3)`` ground coordinates (E, N, h) of the points.
        names: ``n`` point names (default ``gcp1 ...``).
        image_names: ``m`` image names (default ``"0" ...``).
        reference_image: ``(n,)`` index of the image each point is measured
            in, ``-1`` for points known only on the ground; None: all ground-only.
        reference_xy: ``(n, 2)`` pixel (column, row) of those measurements.
        target_template: ``(th, tw)`` image of the survey target, centred on
            it (target centre at ``((tw - 1) / 2, (th - 1) / 2)``): ground-only
            points are found by matching it in the image where the prediction
            is closest to the centre.  Without it they get ``"no reference"``.
        roles: ``n`` ``"control"`` / ``"check"`` (default control).
        window: half-size of the matching window, px.
        search: NCC search radius around the prediction, px.
        min_rho: smallest accepted NCC peak between images.
        min_rho_template: the same for the target template (a drawn target
            never matches a photographed one as well as two photographs do).
        back_tol: two-way consistency of a transfer, px: the matched window,
            resampled in the reference image's geometry, is matched back
            into the reference image and must land within this of the
            reference measurement.
        crs: CRS text stored in the table.

    Returns:
        :class:`Transfer`.  Statuses: ``"reference"`` (the given or
        template-found measurement), ``"ok"``, ``"not in image"``
        (prediction outside the image: the views do not overlap there),
        ``"at image border"`` (inside, but the matching window would leave
        the image), ``"behind camera"``, ``"outside DEM"`` (a height to read
        off the DEM, or the reference window's rays, miss it),
        ``"scale differs"`` (the views' scales differ by more than 2x),
        ``"low correlation"`` (NCC peak below ``min_rho`` or on
        the search border), ``"not matched"`` (LSM failed), ``"not two-way"``
        (the match back missed the reference by more than ``back_tol``), ``"no reference"``
        (no measurement to match from), ``"inconsistent"`` (matched more than
        ``search`` px from where the point's other measurements put it).
    """
    from ..io import GCPTable

    stack, eo = check_block(images, camera, exterior)
    m = len(stack)
    g = np.array(ground, dtype=float)
    if g.ndim != 2 or g.shape[1] != 3 or len(g) == 0:
        raise ValueError(f"ground: expected (n, 3) ground coordinates, got shape {g.shape}")
    n = len(g)
    if np.any(~np.isfinite(g[:, :2])):
        raise ValueError("ground: E and N must be finite (a NaN height is read from the DEM)")
    if np.any(np.isnan(g[:, 2])):
        if dem is None:
            raise ValueError("ground: NaN heights need a dem")
        z = np.asarray(dem.height(jnp.asarray(g[:, 0]), jnp.asarray(g[:, 1])))
        g[:, 2] = np.where(np.isnan(g[:, 2]), z, g[:, 2])
    names = [f"gcp{k + 1}" for k in range(n)] if names is None else [str(s) for s in names]
    inames = [str(k) for k in range(m)] if image_names is None else [str(s) for s in image_names]
    roles = ["control"] * n if roles is None else [str(r) for r in roles]
    if len(names) != n or len(roles) != n or len(inames) != m:
        raise ValueError(f"names / roles need {n} entries and image_names {m}")
    ref_i = np.full(n, -1) if reference_image is None else np.asarray(reference_image, dtype=int).copy()
    ref_xy = np.full((n, 2), np.nan) if reference_xy is None else np.array(reference_xy, dtype=float)
    if ref_i.shape != (n,) or ref_xy.shape != (n, 2) or np.any(ref_i >= m) or np.any(ref_i < -1):
        raise ValueError(f"reference_image / reference_xy: expected (n,) indices in -1..{m - 1} and (n, 2) pixels")
    if np.any((ref_i >= 0) & ~np.all(np.isfinite(ref_xy), axis=1)):
        raise ValueError("reference_xy: a point with a reference image needs a finite pixel")
    outside = np.flatnonzero((ref_i >= 0) & ~inside(ref_xy, camera.image_size, 0.0))
    if len(outside):
        raise OutsideValidityError(f"reference_xy: points {outside.tolist()} lie outside their reference images")
    size = camera.image_size
    pad = frame_pad(window, search)
    pred = project_pixels(g, eo, camera)  # (m, n, 2)
    usable = inside(pred, size, window + 3)
    big = padded(stack, pad)
    status = np.full((m, n), "at image border", dtype=object)
    status[~inside(pred, size, 0.0)] = "not in image"
    status[~np.all(np.isfinite(pred), axis=2)] = "behind camera"
    status[:, np.isnan(g[:, 2])] = "outside DEM"  # no height: the point lies off the DEM
    out_xy = np.full((m, n, 2), np.nan)
    out_sig = np.full((m, n), np.nan)
    out_rho = np.full((m, n), np.nan)

    def measured(k, p, ncc_ok, rho, lsm_ok, xy, low):
        """The status of a match of point ``p`` in image ``k`` (its NCC peak kept)."""
        out_rho[k, p] = rho
        if not (ncc_ok and rho >= low):
            return "low correlation"
        if not (lsm_ok and inside(xy, size, window + 1)):
            return "not matched"
        return "ok"

    # 1. references of ground-only points: the template in the most central image that sees them
    centre = (np.asarray(size) - 1) / 2.0
    for p in np.flatnonzero(ref_i < 0):
        if not usable[:, p].any():
            continue
        if target_template is None:
            status[usable[:, p], p] = "no reference"
            continue
        d = np.where(usable[:, p], np.linalg.norm(pred[:, p] - centre, axis=1), np.inf)
        ref_i[p] = -2 - int(np.argmin(d))  # candidate, confirmed below
    cand = np.flatnonzero(ref_i <= -2)
    if len(cand):
        tpl = np.asarray(target_template, dtype=float)
        if tpl.ndim != 2:
            raise ValueError(f"target_template: expected a 2-D image, got shape {tpl.shape}")
        # the template drawn on a canvas of the images' (padded) shape, matched unwarped (a survey
        # target's drawing has no orientation to predict), by the one compiled matcher
        if np.any(np.array(tpl.shape) > np.array(stack.shape[1:])):
            raise ValueError(f"target_template: {tpl.shape} is too large for images of {size} px")
        canvas = np.zeros(big.shape[1:])
        canvas[pad : pad + tpl.shape[0], pad : pad + tpl.shape[1]] = tpl
        tc = np.broadcast_to((np.array(tpl.shape[::-1]) - 1) / 2.0 + pad, (len(cand), 2))
        k_img = -2 - ref_i[cand]
        ident = np.broadcast_to(np.eye(2), (len(cand), 2, 2))
        mt = match_warped(
            np.concatenate([big, canvas[None]]), np.full(len(cand), m), tc, k_img, pred[k_img, cand] + pad, ident,
            window=window, search=search, back=False,
        )  # fmt: skip
        lxy = mt.lsm_xy[:, 0] - pad
        sig = match_sigma(mt.lsm_cov[:, 0])
        for q, (k, p) in enumerate(zip(k_img, cand)):
            got = measured(
                k, p, bool(mt.ncc_valid[q, 0]), float(mt.rho[q, 0]), bool(mt.lsm_valid[q, 0]), lxy[q], min_rho_template
            )
            if got == "ok":
                ref_i[p], ref_xy[p], out_sig[k, p] = k, lxy[q], sig[q]
            else:
                status[usable[:, p], p] = "no reference"
                status[k, p] = got
                ref_i[p] = -1
    for p in np.flatnonzero(ref_i >= 0):
        k = ref_i[p]
        status[k, p] = "reference"
        out_xy[k, p] = ref_xy[p]  # a given measurement keeps sigma NaN: its precision is the user's

    # 2. transfer from the reference image into the others: the reference window warped by the local
    # affine map between the two views (predicted on the DEM, or on a level plane through the points),
    # then NCC within `search` px of the prediction and LSM, as tie matching does
    ki, pi = np.nonzero(usable & (ref_i[None] >= 0) & (np.arange(m)[:, None] != ref_i[None]))
    if len(ki):
        ri = ref_i[pi]
        px = np.full((m, n, 2), np.nan)
        px[ri, pi] = ref_xy[pi]
        _, _, affine, _ = views(px, eo, camera, dem if dem is not None else _level(g, eo), step=window)
        aff = affine[ki, ri, pi]
        ok = warpable(aff)
        status[ki[~ok], pi[~ok]] = np.where(np.all(np.isfinite(aff[~ok]), axis=(1, 2)), "scale differs", "outside DEM")
        ki, pi, ri, aff = ki[ok], pi[ok], ri[ok], aff[ok]
    if len(ki):
        mt = match_warped(
            big, ri, ref_xy[pi] + pad, ki, pred[ki, pi] + pad, aff, window=window, search=search, back=True
        )
        with np.errstate(invalid="ignore"):
            two_way = mt.back_valid[:, 0] & (np.linalg.norm(mt.back_xy[:, 0] - pad - ref_xy[pi], axis=1) <= back_tol)
        lxy = mt.lsm_xy[:, 0] - pad
        sig = match_sigma(mt.lsm_cov[:, 0])
        for q, (k, p) in enumerate(zip(ki, pi)):
            status[k, p] = measured(
                k, p, bool(mt.ncc_valid[q, 0]), float(mt.rho[q, 0]), bool(mt.lsm_valid[q, 0]), lxy[q], min_rho
            )
            if status[k, p] == "ok" and not two_way[q]:
                status[k, p] = "not two-way"
            if status[k, p] == "ok":
                out_xy[k, p] = lxy[q]
                # the reference's own error is in every transferred measurement of the point
                out_sig[k, p] = float(np.hypot(sig[q], np.nan_to_num(out_sig[ref_i[p], p])))
    # 3. consistency: offsets measured - predicted of one image are its orientation error, alike for its points
    for k in range(m):
        got = np.flatnonzero(np.isin(status[k], ("ok", "reference")))
        if len(got) >= 3:
            d = out_xy[k, got] - pred[k, got]
            bad = np.linalg.norm(d - np.median(d, axis=0), axis=1) > search
            for p in got[bad]:
                if status[k, p] == "ok":
                    status[k, p] = "inconsistent"
                    out_xy[k, p] = np.nan

    rows = [(k, p) for p in range(n) for k in range(m) if status[k, p] in ("ok", "reference")]
    items_out = [
        dict(
            name=names[p],
            image=inames[k],
            status=str(status[k, p]),
            predicted=pred[k, p],
            xy=out_xy[k, p],
            sigma=out_sig[k, p],
            rho=out_rho[k, p],
        )
        for p in range(n)
        for k in range(m)
    ]
    take = lambda f: np.array([f(k, p) for k, p in rows]) if rows else None  # noqa: E731
    table = GCPTable(
        names=np.array([names[p] for _, p in rows], dtype=str),
        images=np.array([inames[k] for k, _ in rows], dtype=str),
        ground=take(lambda k, p: g[p]) if rows else np.zeros((0, 3)),
        pixel=take(lambda k, p: out_xy[k, p]) if rows else np.zeros((0, 2)),
        image_xy=None,
        sigma=np.array([out_sig[k, p] for k, p in rows], dtype=float),
        role=np.array([roles[p] for _, p in rows], dtype=str),
        crs=crs,
        lines=np.zeros(len(rows), dtype=int),
    )
    return Transfer(table, items_out)


def _level(ground: np.ndarray, eo) -> DEM:
    """A level plane through the points' mean height, reaching as far from them as the cameras are:
    the surface the local affine maps are predicted on when no DEM is given."""
    pos = np.asarray(eo.position)
    reach = float(np.max(np.linalg.norm(pos[:, None] - ground[None], axis=-1)))
    lo, hi = ground[:, :2].min(axis=0) - reach, ground[:, :2].max(axis=0) + reach
    return DEM.flat(float(np.mean(ground[:, 2])), (lo[0], lo[1], hi[0], hi[1]))
