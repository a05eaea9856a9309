"""Georeferencing a free network (a COLMAP or BAL model, any block in its own frame).

Two steps, as a photogrammetrist would do it by hand:

1. a **7-parameter similarity** ``X_ground = s R X_model + t`` (Umeyama 1991;
   Horn 1987), fitted by least squares to control points intersected in the
   model from their image measurements and/or to the images' projection
   centres paired with their GNSS positions, and applied to the whole block
   (centres, attitudes, points);
2. a **bundle adjustment** with the control points as weighted (or fixed)
   observations, the GNSS positions as observations, and the check points
   adjusted as tie points and compared with their surveyed coordinates
   afterwards (:attr:`BundleResult.check_residuals`, with their standard
   deviations in :attr:`BundleResult.point_std`): the check-point report.

The similarity alone cannot remove the model's own deformation (COLMAP's
drift, a wrong focal length); the bundle does, within what the control
constrains.
"""

from __future__ import annotations

import collections
import dataclasses
import pathlib

import numpy as np

from .bundle import BundleProblem, BundleResult, bundle_adjust
from .camera import FrameCamera
from .collinearity import ExteriorOrientation
from .intersection import intersect
from .rotation import angles_from_matrix


@dataclasses.dataclass(frozen=True)
class Similarity:
    """``X_target = scale * rotation @ X_source + translation`` and its fit.

    Attributes:
        scale: ``s > 0``.
        rotation: ``(3, 3)`` proper rotation.
        translation: ``(3,)``.
        residuals: ``(n, 3)`` fitted minus target of the pairs it was fitted to.

    Examples:
        What :func:`similarity_transform` returns: ``apply`` maps points, ``rms`` the fit's residual:

        >>> import numpy as np
        >>> import photax as ptx
        >>> source = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 10.0]])
        >>> sim = ptx.similarity_transform(source, 2.0 * source + [100.0, 200.0, 300.0])
        >>> print(np.round(np.asarray(sim.apply(np.array([[1.0, 1.0, 1.0]]))), 6), f"{sim.rms:.6f}")
        [[102. 202. 302.]] 0.000000
    """

    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    residuals: np.ndarray

    def apply(self, points) -> np.ndarray:
        """``(..., 3)`` source points -> target points."""
        return self.scale * np.asarray(points, dtype=float) @ self.rotation.T + self.translation

    @property
    def rms(self) -> float:
        """RMS of the 3-D residual lengths of the fit."""
        return float(np.sqrt(np.mean(np.sum(self.residuals**2, axis=1)))) if len(self.residuals) else 0.0


def similarity_transform(source, target) -> Similarity:
    """The least-squares similarity mapping ``source`` onto ``target`` (Umeyama 1991).

    With ``mu``, ``sigma^2`` the mean and variance of the source,
    ``Sigma = (T - mu_T)^T (S - mu_S) / n = U D V^T``, ``E = diag(1, 1,
    det(U V^T))``: ``R = U E V^T``, ``s = tr(D E) / sigma^2``,
    ``t = mu_T - s R mu_S``.  Computed about the means, so large (UTM)
    coordinates lose no digits.

    Args:
        source, target: ``(n, 3)`` corresponding points, ``n >= 3``, finite.

    Raises:
        ValueError: fewer than 3 pairs, or source points on one line (the
            rotation about it is then undetermined).

    Examples:
        A 7-parameter (Helmert) similarity found back from points it moved:

        >>> import numpy as np
        >>> import photax as ptx
        >>> rng = np.random.default_rng(1)
        >>> source = rng.uniform(-100, 100, (6, 3))
        >>> R = np.asarray(ptx.rotation_matrix(np.radians([1.0, 2.0, 30.0])))
        >>> target = 1.5 * source @ R.T + [500000.0, 4100000.0, 200.0]
        >>> sim = ptx.similarity_transform(source, target)
        >>> print(f"{sim.scale:.6f}", bool(np.allclose(sim.rotation, R)), bool(np.allclose(sim.residuals, 0, atol=1e-6)))
        1.500000 True True
    """
    s, t = np.asarray(source, dtype=float), np.asarray(target, dtype=float)
    if s.shape != t.shape or s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f"source and target must both be (n, 3), got {s.shape} and {t.shape}")
    if len(s) < 3 or not (np.all(np.isfinite(s)) and np.all(np.isfinite(t))):
        raise ValueError(f"a similarity needs at least 3 finite point pairs, got {len(s)}")
    ms, mt = s.mean(axis=0), t.mean(axis=0)
    ds, dt = s - ms, t - mt
    sv = np.linalg.svd(ds, compute_uv=False)
    if not sv[1] > 1e-9 * sv[0]:
        raise ValueError("the points for the similarity lie on one line (or coincide): the rotation is undetermined")
    u, d, vt = np.linalg.svd(dt.T @ ds / len(s))
    e = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    r = u @ e @ vt
    scale = float(np.trace(np.diag(d) @ e) / np.mean(np.sum(ds**2, axis=1)))
    trans = mt - scale * r @ ms
    return Similarity(scale, r, trans, scale * s @ r.T + trans - t)


def transform_problem(problem: BundleProblem, sim: Similarity) -> BundleProblem:
    """``problem`` moved by ``sim``: centres and points ``s R X + t``, attitudes
    ``R @ world_from_camera`` (same angle convention); the cameras are unchanged."""
    eo = problem.exterior
    rot = sim.rotation @ np.asarray(eo.rotation)
    angles = np.asarray(angles_from_matrix(rot, eo.convention))
    return problem.replace(
        exterior=ExteriorOrientation(sim.apply(np.asarray(eo.position)), angles, eo.convention),
        points=sim.apply(problem.points),
    )


@dataclasses.dataclass(frozen=True)
class Georeferenced:
    """What :func:`georeference` did.

    Attributes:
        similarity: model -> ground.
        problem: the block in the ground frame with the control and check
            points (named as in the GCP file) and GNSS observations added.
        result: the adjustment of ``problem`` (None with ``adjust=False``).
        notes: what was left out and why (GCP rows of images not in the model,
            check points seen in fewer than two images, ...).

    Examples:
        A block whose GNSS positions are its own centres moved 100 m east and 200 m north: the
        similarity is that shift (scale 1), and the report says so:

        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.scene import synthetic_block
        >>> problem, _ = synthetic_block(0, n_control=0, n_check=0)
        >>> centres = np.asarray(problem.exterior.position)
        >>> gnss = {name: c + [100.0, 200.0, 0.0] for name, c in zip(problem.image_names, centres)}
        >>> geo = ptx.georeference(problem, gnss=gnss, gnss_sigma=0.05, adjust=False)
        >>> print(np.round(geo.similarity.translation, 6) + 0.0, geo.result, geo.notes)
        [100. 200.   0.] None ()
        >>> print(geo.report().split(";")[0])
        similarity model -> ground: scale 1, rotation ... deg, translation [ 1.00e+02,  2.00e+02, ...]
    """

    similarity: Similarity
    problem: BundleProblem
    result: BundleResult | None
    notes: tuple[str, ...] = ()

    def report(self, unit: str = "m") -> str:
        """The similarity, the adjustment's report and every check point's residual and std."""
        s = self.similarity
        angle = np.degrees(np.arccos(np.clip((np.trace(s.rotation) - 1) / 2, -1.0, 1.0)))
        lines = [
            f"similarity model -> ground: scale {s.scale:.9g}, rotation {angle:.6g} deg, "
            f"translation {np.array2string(s.translation, precision=3, separator=', ')}; "
            f"fit RMS {s.rms:.4g} {unit} on {len(s.residuals)} points",
            *(f"  note: {n}" for n in self.notes),
        ]
        if self.result is None:
            return "\n".join(lines)
        res = self.result
        lines.append(res.report(unit))
        check = self.problem.roles == "check"
        if check.any():
            lines.append(f"  check point residuals (adjusted - surveyed) and their std, {unit}:")
            std = res.point_std[check] if res.point_std is not None else np.full((int(check.sum()), 3), np.nan)
            for name, r, sd in zip(res.check_names, res.check_residuals, std):
                lines.append(
                    f"    {name}: dX {r[0]:+.4g} dY {r[1]:+.4g} dZ {r[2]:+.4g}   (std {sd[0]:.3g} {sd[1]:.3g} {sd[2]:.3g})"
                )
        return "\n".join(lines)


def _image_index(names: tuple[str, ...]):
    """A function: a GCP file's image name -> the problem's image index, or None.

    Exact name first, then the file name, then the stem (each only when unique):
    COLMAP names images by their path under its image folder, GCP lists by file name."""
    keys = [
        {n: i for i, n in enumerate(names)},
        _unique({pathlib.PurePath(n).name: i for i, n in enumerate(names)}, [pathlib.PurePath(n).name for n in names]),
        _unique({pathlib.PurePath(n).stem: i for i, n in enumerate(names)}, [pathlib.PurePath(n).stem for n in names]),
    ]

    def find(image: str):
        p = pathlib.PurePath(image)
        for table, key in zip(keys, (image, p.name, p.stem)):
            if key in table:
                return table[key]
        return None

    return find


def _unique(table: dict, keys: list) -> dict:
    counts = collections.Counter(keys)
    return {k: v for k, v in table.items() if counts[k] == 1}


def georeference(
    problem: BundleProblem,
    gcps=None,
    *,
    gnss: dict | None = None,
    gnss_sigma=None,
    gcp_sigma: float = 0.0,
    pixel_sigma: float = 1.0,
    adjust: bool = True,
    **bundle_options,
) -> Georeferenced:
    """Put a block in its own frame (a COLMAP model: :func:`photax.io.read_colmap`) into a ground CRS.

    Args:
        problem: the block (tie points; any frame).
        gcps: a :class:`photax.io.GCPTable` (:func:`photax.io.read_gcps`):
            ground coordinates and image measurements of control and check
            points; images matched to the problem's by name, file name or
            stem.  Rows of images not in the block are left out (noted).
        gnss: ``{image name: (X, Y, Z)}`` GNSS positions of projection
            centres in the ground CRS (names matched as for ``gcps``).
        gnss_sigma: their standard deviation (ground unit, > 0), needed with ``gnss``.
        gcp_sigma: standard deviation of the control points' surveyed
            coordinates (ground unit); 0 (default) holds them fixed.
        pixel_sigma: standard deviation of a GCP measurement where the file
            gives none, in pixels.
        adjust: run the bundle adjustment (else only the similarity).
        bundle_options: passed to :func:`photax.bundle_adjust` (``loss``,
            ``max_steps``, ``verbose``, ...); ``throw`` defaults to False.

    The similarity is fitted to every control point seen in two or more
    images (intersected in the model) and every image with a GNSS position,
    together; it needs three such points not on one line.

    Raises:
        ValueError: too few points for the similarity, a GCP named like a tie
            point, GNSS positions without ``gnss_sigma``, an unknown image
            for every GCP row.

    Examples:
        A block at 1 : 100 in its own frame (a photograph does not know its scale: the same image
        coordinates) put back on its images' GNSS positions; ``adjust=False`` stops after the
        similarity:

        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.scene import synthetic_block
        >>> problem, _ = synthetic_block(0, n_control=0, n_check=0)
        >>> e = problem.exterior
        >>> small = ptx.ExteriorOrientation(np.asarray(e.position) / 100, e.angles, e.convention)
        >>> model = problem.replace(exterior=small, points=problem.points / 100)
        >>> gnss = dict(zip(problem.image_names, np.asarray(e.position)))
        >>> geo = ptx.georeference(model, gnss=gnss, gnss_sigma=0.05, adjust=False)
        >>> back = bool(np.allclose(geo.problem.points, problem.points, rtol=0, atol=1e-6))
        >>> print(f"{geo.similarity.scale:.6f}", back)
        100.000000 True
    """

    if gcps is None and not gnss:
        raise ValueError("georeference needs GCPs (gcps=) or GNSS positions of the images (gnss=)")
    find = _image_index(problem.image_names)
    notes: list[str] = []
    src, dst = [], []
    cams_of_image = [problem.cameras[c] for c in problem.image_camera]
    new_points = None
    if gcps is not None:
        new_points = _gcp_points(problem, gcps, find, pixel_sigma, notes, cams_of_image)
        names, ground, roles, oi, op, xy, sig = new_points
        ctrl = [k for k, r in enumerate(roles) if r == "control"]
        rays = np.bincount(op, minlength=len(names))
        usable = [k for k in ctrl if rays[k] >= 2]
        if usable:
            sel = np.isin(op, usable)
            model_xyz = intersect(
                xy[sel], problem.exterior, cams_of_image, obs_image=oi[sel], obs_point=op[sel], n_points=len(names)
            )
            ok = [k for k in usable if np.all(np.isfinite(model_xyz[k]))]
            src += [model_xyz[k] for k in ok]
            dst += [ground[k] for k in ok]
    gnss_rows = None
    if gnss:
        if gnss_sigma is None:
            raise ValueError("gnss needs gnss_sigma (the positions' standard deviation, ground unit)")
        gnss_rows = np.full((problem.n_images, 3), np.nan)
        missing = []
        for name, xyz in gnss.items():
            i = find(str(name))
            if i is None:
                missing.append(str(name))
                continue
            gnss_rows[i] = np.asarray(xyz, dtype=float)
        if missing:
            notes.append(f"{len(missing)} GNSS position(s) of images not in the block left out, e.g. {missing[0]!r}")
        seen = np.all(np.isfinite(gnss_rows), axis=1)
        src += list(np.asarray(problem.exterior.position)[seen])
        dst += list(gnss_rows[seen])
    if len(src) < 3:
        raise ValueError(
            f"the similarity needs 3 points: control points seen in 2+ images of the block or images with a GNSS "
            f"position; got {len(src)}"
        )
    sim = similarity_transform(np.array(src), np.array(dst))
    moved = transform_problem(problem, sim)
    changes: dict = {}
    if new_points is not None:
        names, ground, roles, oi, op, xy, sig = new_points
        clash = set(names) & set(problem.point_names)
        if clash:
            raise ValueError(f"GCP {sorted(clash)[0]!r} has the name of a tie point of the block: rename it")
        n0 = problem.n_points
        k = len(names)
        changes.update(
            points=np.vstack([moved.points, ground]),
            obs_image=np.concatenate([problem.obs_image, oi]),
            obs_point=np.concatenate([problem.obs_point, op + n0]),
            obs_xy=np.vstack([problem.obs_xy, xy]),
            obs_sigma=np.vstack([problem.obs_sigma, np.column_stack([sig, sig])]),
            roles=[*problem.roles.tolist(), *roles],
            point_sigma=np.vstack([problem.point_sigma, np.full((k, 3), float(gcp_sigma))]),
            point_names=[*problem.point_names, *names],
        )
    if gnss_rows is not None:
        changes.update(gnss_position=gnss_rows, gnss_sigma=gnss_sigma)
    out = moved.replace(**changes) if changes else moved
    result = None
    if adjust:
        bundle_options.setdefault("throw", False)
        result = bundle_adjust(out, **bundle_options)
    return Georeferenced(sim, out, result, tuple(notes))


def _gcp_points(problem, gcps, find, pixel_sigma, notes, cams_of_image):
    """The GCP table as new points: ``(names, ground (k, 3), roles, obs_image, obs_point, xy, sigma)``
    with observations on the image plane of each image's camera; check points seen in fewer than
    two images and rows of unknown images are left out (noted)."""
    rows_image = [find(str(n)) for n in gcps.images.tolist()]
    unknown = sorted({str(n) for n, i in zip(gcps.images.tolist(), rows_image) if i is None})
    if unknown:
        notes.append(f"GCP measurements in {len(unknown)} image(s) not in the block left out, e.g. {unknown[0]!r}")
    if all(i is None for i in rows_image):
        raise ValueError(
            f"no GCP measurement is in an image of the block (its images are e.g. {problem.image_names[0]!r})"
        )
    names = list(dict.fromkeys(str(n) for n, i in zip(gcps.names.tolist(), rows_image) if i is not None))
    index = {n: k for k, n in enumerate(names)}
    ground = np.zeros((len(names), 3))
    roles = ["control"] * len(names)
    oi, op, xy, sig = [], [], [], []
    for r, i in enumerate(rows_image):
        if i is None:
            continue
        k = index[str(gcps.names[r])]
        ground[k] = gcps.ground[r]
        roles[k] = str(gcps.role[r])
        cam: FrameCamera = cams_of_image[i]
        one = gcps.subset(np.array([r]))
        xy.append(np.asarray(one.image_plane(cam))[0])
        s = float(one.image_plane_sigma(cam)[0])
        if not np.isfinite(s):
            s = pixel_sigma * (float(np.mean(np.asarray(cam.pixel_size))) if cam.pixel_size is not None else 1.0)
        sig.append(s)
        oi.append(i)
        op.append(k)
    oi, op = np.array(oi, dtype=np.int64), np.array(op, dtype=np.int64)
    xy, sig = np.array(xy, dtype=float).reshape(-1, 2), np.array(sig)
    if not np.all(np.isfinite(ground)):
        raise ValueError("GCPs need X, Y and Z (a 2-D GCP file cannot georeference a block in 3-D)")
    rays = np.bincount(op, minlength=len(names))
    drop = [k for k in range(len(names)) if roles[k] == "check" and rays[k] < 2]
    if drop:
        notes.append(
            f"{len(drop)} check point(s) seen in fewer than 2 images left out (cannot be intersected), "
            f"e.g. {names[drop[0]]!r}"
        )
        keep = np.setdiff1d(np.arange(len(names)), drop)
        remap = -np.ones(len(names), dtype=np.int64)
        remap[keep] = np.arange(len(keep))
        sel = remap[op] >= 0
        names, ground, roles = [names[k] for k in keep], ground[keep], [roles[k] for k in keep]
        oi, op, xy, sig = oi[sel], remap[op[sel]], xy[sel], sig[sel]
    return names, ground, roles, oi, op, xy, sig
