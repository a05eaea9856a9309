"""OpenSfM's (and OpenDroneMap's) ``reconstruction.json``: cameras and shots.

The conventions, from OpenSfM's ``types.py``/``geo.py`` and checked against
orthority 0.7's reader of the same file:

* **Cameras** (``projection_type``, OpenSfM's ``camera_from_json``):
  ``perspective`` (``focal``, ``k1``, ``k2``), ``simple_radial`` and
  ``radial`` (``focal_x``, ``focal_y``, ``c_x``, ``c_y``, ``k1`` [, ``k2``])
  and ``brown`` (those and ``k3``, ``p1``, ``p2``) are photax's ``"brown"``
  model; ``fisheye`` (``focal``, ``k1``, ``k2``) and ``fisheye_opencv``
  (``focal_x``, ``focal_y``, ``c_x``, ``c_y``, ``k1`` ... ``k4``) its
  ``"fisheye"`` (Kannala-Brandt, ``k3 = k4 = 0`` for ``fisheye``).  Lengths
  are normalised by ``max(width, height)`` and ``c_x, c_y`` are the principal
  point's offset from the image centre (``c_y`` down).  Distortion is
  OpenCV's on normalised coordinates, so ``p1`` changes sign for photax's
  y-up image plane (:mod:`photax.camera`).  The photax camera is in pixels
  (``unit: px``).  ``spherical``/``equirectangular``, ``dual``,
  ``fisheye62``, ``fisheye624`` are refused by name: photax has no model for
  them.
* **Shots**: ``rotation`` is the angle-axis (Rodrigues) vector of the
  world -> camera rotation in OpenCV's camera frame (x right, y down, z
  forward) and ``x_cam = R X + translation``, so the projection centre is
  ``C = -R^T t``.  The world is the topocentric east-north-up frame at
  ``reference_lla`` (WGS84 latitude, longitude, ellipsoidal height).
* **Into a projected CRS** (default the UTM zone of ``reference_lla``, as
  ODM and orthority choose it).  Which frame the shots are in is not written
  in the file: OpenSfM's is the topocentric frame at ``reference_lla``, but
  ODM's reconstructions (the test data's among them) are aligned in a frame
  parallel to the UTM grid (their ``gps_position`` entries, true topocentric,
  sit ~2 m from the shots, turned by the meridian convergence).  ``frame=``
  names it; by default it is decided by the shots' ``gps_position``: the frame
  under which the shots land nearer their GNSS positions (an error when no
  shot has one and the two frames differ).

  - ``"topocentric"``: positions exactly, through geocentric coordinates;
    each rotation turned into the grid frame at the camera (its own
    vertical, then the meridian convergence: ``photax.io._geo``);
  - ``"grid"``: positions are offsets from ``reference_lla``'s position in
    its UTM zone and rotations are already in that grid's frame (what
    orthority assumes of every reconstruction).

  Into another projected CRS (``crs=``, e.g. the DEM's) the UTM positions are
  moved by PROJ and the rotations turned by the two grids' convergence.

  The grid's scale factor (1 +- 4e-4 within a UTM zone) is not applied to
  the camera.
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..camera import FrameCamera, from_opencv_extrinsics
from ..collinearity import ExteriorOrientation
from ..rotation import angles_from_matrix, axis_angle_to_matrix
from ._geo import project_lla, projected_crs, reproject, topocentric_to_projected, utm_crs
from .files import as_numbers, excerpt, file_error, load_json, read_text

_WHAT = "OpenSfM reconstruction"
_KEYS = {
    "perspective": ("focal", "k1", "k2"),
    "simple_radial": ("focal_x", "focal_y", "c_x", "c_y", "k1"),
    "radial": ("focal_x", "focal_y", "c_x", "c_y", "k1", "k2"),
    "brown": ("focal_x", "focal_y", "c_x", "c_y", "k1", "k2", "k3", "p1", "p2"),
    "fisheye": ("focal", "k1", "k2"),
    "fisheye_opencv": ("focal_x", "focal_y", "c_x", "c_y", "k1", "k2", "k3", "k4"),
}
#: Keys of a camera entry that carry no geometry photax needs.
_IGNORED = {"projection_type", "width", "height"}


def is_reconstruction(data) -> bool:
    """Whether parsed JSON looks like a ``reconstruction.json`` (a list of objects with ``shots``)."""
    return isinstance(data, list) and bool(data) and isinstance(data[0], dict) and "shots" in data[0]


def _load(path) -> list:
    path = pathlib.Path(path)
    data = load_json(path, read_text(path, _WHAT))
    if not is_reconstruction(data):
        raise file_error(
            path,
            None,
            "not an OpenSfM reconstruction.json (a list of reconstructions, each "
            "with 'cameras', 'shots' and 'reference_lla', expected)",
        )
    for k, rec in enumerate(data):
        if (
            not isinstance(rec, dict)
            or not isinstance(rec.get("cameras"), dict)
            or not isinstance(rec.get("shots"), dict)
        ):
            raise file_error(path, None, f"reconstruction {k} has no 'cameras' and 'shots' objects")
    return data


def _camera_name(name: str) -> str:
    return name.removeprefix("v2 ")  # OpenSfM's versioned camera ids


def _camera(path, name, p) -> FrameCamera:
    if not isinstance(p, dict):
        raise file_error(path, None, f"camera {excerpt(name)} is not an object")
    kind = p.get("projection_type")
    if kind not in _KEYS:
        raise file_error(
            path,
            None,
            f"camera {excerpt(name)} has projection_type {excerpt(kind)}: "
            f"photax reads {', '.join(repr(k) for k in _KEYS)} cameras only "
            "(spherical, dual, fisheye62 and fisheye624 have no photax camera)",
        )
    unknown = sorted(set(p) - _IGNORED - set(_KEYS[kind]))
    if unknown:
        raise file_error(
            path,
            None,
            f"camera {excerpt(name)}: parameters {excerpt(unknown, 80)} are not part of OpenSfM's {kind} model",
        )
    size = as_numbers([p.get("width"), p.get("height")])
    if size is None or not np.all((size >= 1) & (size <= 2**31 - 1) & (size == np.round(size))):
        raise file_error(path, None, f"camera {excerpt(name)}: width and height must be whole pixels")
    values = {}
    for key in _KEYS[kind]:
        default = None if key.startswith("focal") else 0.0
        v = as_numbers(p.get(key, default))
        if v is None or v.shape != () or not np.isfinite(v):
            raise file_error(
                path, None, f"camera {excerpt(name)}: {key} must be a finite number, got {excerpt(p.get(key))}"
            )
        values[key] = float(v)
    if "focal" in values:
        values.update(focal_x=values["focal"], focal_y=values["focal"])
    w, h = (int(v) for v in size)
    m = max(w, h)
    fx, fy = values["focal_x"] * m, values["focal_y"] * m
    if not (fx > 0 and fy > 0 and np.isfinite(fx * fy)):
        raise file_error(path, None, f"camera {excerpt(name)}: the focal length must be positive")
    aspect = fx / fy  # photax: one principal distance, the pixel height carries fx / fy
    pp = (values.get("c_x", 0.0) * m, -values.get("c_y", 0.0) * m * aspect)
    if kind.startswith("fisheye"):
        dist, model = [values.get(k, 0.0) for k in ("k1", "k2", "k3", "k4")], "fisheye"
    else:
        k1, k2, k3, p1, p2 = (values.get(k, 0.0) for k in ("k1", "k2", "k3", "p1", "p2"))
        dist, model = [k1, k2, k3, 0.0 - p1, p2], "brown"
    return FrameCamera(fx, pp, dist, pixel_size=(1.0, aspect), image_size=(w, h), model=model)


def read_opensfm_cameras(path) -> dict[str, FrameCamera]:
    """The cameras of a ``reconstruction.json``: ``{name: FrameCamera}`` in pixels
    (names without OpenSfM's ``"v2 "`` prefix).

    Raises:
        ValueError: naming the file: not a reconstruction, or a camera model
            photax cannot represent (named).
    """
    path = pathlib.Path(path)
    out: dict[str, FrameCamera] = {}
    for rec in _load(path):
        for name, p in rec["cameras"].items():
            out[_camera_name(str(name))] = _camera(path, name, p)
    if not out:
        raise file_error(path, None, "no cameras")
    return out


def read_opensfm_shots(
    path, crs=None, frame: str | None = None
) -> tuple[dict[str, ExteriorOrientation], str, dict[str, str]]:
    """The shots of a ``reconstruction.json`` in a projected CRS.

    Args:
        path: the file.
        crs: the projected CRS wanted (EPSG code, WKT, PROJ string); default
            the WGS84 UTM zone of the (first) reconstruction's ``reference_lla``.
        frame: ``"topocentric"`` (OpenSfM's), ``"grid"`` (ODM's) or None:
            decided by the shots' ``gps_position`` (module docstring).

    Returns:
        ``({image stem: ExteriorOrientation ("omega-phi-kappa")}, crs, {image stem: camera name})``;
        ``crs`` as text (``"EPSG:32651"`` where it has a code).

    Raises:
        ValueError: naming the file: malformed, no shots, a shot name twice,
            or a frame that cannot be decided.
    """
    if frame not in (None, "topocentric", "grid"):
        raise ValueError(f"frame must be 'topocentric', 'grid' or None, got {frame!r}")
    path = pathlib.Path(path)
    data = _load(path)
    exteriors: dict[str, ExteriorOrientation] = {}
    cameras: dict[str, str] = {}
    target = None
    for k, rec in enumerate(data):
        ref = rec.get("reference_lla")
        lla = as_numbers([ref.get(c) for c in ("latitude", "longitude", "altitude")]) if isinstance(ref, dict) else None
        if lla is None or lla.shape != (3,) or not np.all(np.isfinite(lla)) or abs(lla[0]) > 90 or abs(lla[1]) > 360:
            raise file_error(
                path, None, f"reconstruction {k}: 'reference_lla' must hold a latitude, longitude and altitude"
            )
        if target is None:
            target = projected_crs(crs, "crs") if crs is not None else utm_crs(lla[0], lla[1])
        names, rvecs, tvecs, gps = [], [], [], []
        for name, shot in rec["shots"].items():
            stem = pathlib.PurePath(str(name)).stem
            if not stem or stem in exteriors or stem in names:
                raise file_error(path, None, f"shot {excerpt(name)}: an empty or repeated image name")
            r = as_numbers(shot.get("rotation")) if isinstance(shot, dict) else None
            t = as_numbers(shot.get("translation")) if isinstance(shot, dict) else None
            if (
                r is None
                or t is None
                or r.shape != (3,)
                or t.shape != (3,)
                or not np.all(np.isfinite(r) & np.isfinite(t) & (np.abs(t) < 1e8))
            ):
                raise file_error(
                    path, None, f"shot {excerpt(name)}: 'rotation' and 'translation' must be 3 finite numbers each"
                )
            g = as_numbers(shot.get("gps_position"))
            ok = g is not None and g.shape == (3,) and np.all(np.isfinite(g) & (np.abs(g) < 1e8))
            gps.append(g if ok else np.full(3, np.nan))
            names.append(stem)
            rvecs.append(r)
            tvecs.append(t)
            cameras[stem] = _camera_name(str(shot.get("camera", "")))
        if not names:
            continue
        r_cv = np.asarray(axis_angle_to_matrix(np.asarray(rvecs)))
        r_topo, centre = from_opencv_extrinsics(r_cv, np.asarray(tvecs))
        try:
            xyz, rotation = _to_grid(centre, r_topo, np.asarray(gps), lla, target, frame)
        except ValueError as exc:
            raise file_error(path, None, f"reconstruction {k}: {exc}") from None
        angles = np.asarray(angles_from_matrix(rotation, "omega-phi-kappa"))
        for j, stem in enumerate(names):
            exteriors[stem] = ExteriorOrientation(xyz[j], angles[j], "omega-phi-kappa")
    if not exteriors:
        raise file_error(path, None, "no shots")
    return exteriors, target.to_string(), cameras


def _to_grid(centre, r_frame, gps, lla, crs, frame):
    """Shot centres and world_from_camera rotations in the reconstruction's frame ->
    projected positions and rotations in ``crs`` (module docstring)."""
    utm = utm_crs(lla[0], lla[1])  # ODM's grid-aligned frame is its UTM zone's
    xyz_t, grid_from_topo = topocentric_to_projected(centre, lla, utm)
    xyz_g = project_lla(*lla, utm) + centre
    if frame is None:
        has = np.all(np.isfinite(gps), axis=-1)
        spread = float(np.max(np.linalg.norm(xyz_t - xyz_g, axis=-1)))
        if has.any():
            truth = topocentric_to_projected(gps[has], lla, utm)[0]
            err_t = np.linalg.norm(xyz_t[has] - truth, axis=-1).mean()
            err_g = np.linalg.norm(xyz_g[has] - truth, axis=-1).mean()
            frame = "topocentric" if err_t <= err_g else "grid"
        elif spread < 1e-3:  # the two frames agree to a millimetre: either will do
            frame = "topocentric"
        else:
            raise ValueError(
                f"no shot has a gps_position to tell OpenSfM's topocentric frame from ODM's "
                f"grid-aligned one (they differ by up to {spread:.3g} m here): name the frame"
            )
    if frame == "topocentric":
        xyz, rotation = xyz_t, grid_from_topo @ r_frame
    else:
        xyz, rotation = xyz_g, r_frame
    if crs == utm:
        return xyz, rotation
    xyz, turn = reproject(xyz, utm, crs)
    return xyz, turn @ rotation
