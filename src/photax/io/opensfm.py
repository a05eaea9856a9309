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
  under which the shots land on their GNSS positions, when the residuals
  tell it (the fit of the residuals to the two frames' difference lies near
  one frame, with a standard error under 1/6 of the way between them); else,
  where the frames' headings differ (the meridian convergence: a one-shot or
  compact reconstruction lands both ways on its GNSS positions, yet one way
  is turned by up to a degree or so), an error asking for the frame, never a
  guess.

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
* **Writing** (:func:`write_opensfm_reconstruction`, ODM's ``cameras.json``:
  :func:`photax.io.odm.write_odm_cameras`) is the inverse: a ``brown`` (or ``opencv``
  without its extra terms) camera as ``brown``, a ``fisheye`` one as OpenSfM's
  ``fisheye`` where it has one focal length, a centred principal point and
  ``k3 = k4 = 0`` (the one fisheye orthority reads), else ``fisheye_opencv``;
  shots in the frame named (``"topocentric"`` or ``"grid"``), each with a
  ``gps_position``: the camera's own position in the topocentric frame (what
  ODM's hold), so that a reader deciding the frame by it (photax's) finds the
  frame written.  ``points`` is empty.
"""

from __future__ import annotations

import math
import pathlib

import numpy as np

from ..camera import DISTORTION_MODELS, FrameCamera, from_opencv_extrinsics, opencv_extrinsics
from ..collinearity import ExteriorOrientation
from ..errors import OutsideValidityError
from ..geo import utm_crs
from ..rotation import angles_from_matrix, axis_angle_to_matrix, matrix_to_axis_angle
from ._geo import (
    project_lla,
    projected_crs,
    projected_to_topocentric,
    reproject,
    topocentric_to_projected,
)
from .files import as_numbers, excerpt, expect, file_error, load_json, read_text

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
    if "projection_type" in p:
        expect(kind, "text", "projection_type", path, None, f"camera {excerpt(name)}")
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

    Examples:
        OpenSfM's focal length is a share of the larger image side: 0.75 of 4000 px is 3000 px:

        >>> import json, pathlib, tempfile
        >>> from photax.io import read_opensfm_cameras
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "reconstruction.json"
        >>> camera = {"projection_type": "perspective", "width": 4000, "height": 3000, "focal": 0.75, "k1": -0.01}
        >>> _ = path.write_text(json.dumps([{"cameras": {"v2 dji 4000 3000 perspective 0.75": camera}, "shots": {},
        ...                                  "reference_lla": {"latitude": 45.0, "longitude": 9.0, "altitude": 0.0}}]))
        >>> cameras = read_opensfm_cameras(path)  # names without OpenSfM's "v2 "
        >>> {name: (float(c.focal_length), c.image_size, float(c.distortion[0])) for name, c in cameras.items()}
        {'dji 4000 3000 perspective 0.75': (3000.0, (4000, 3000), -0.01)}
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

    Examples:
        One nadir shot (OpenSfM turns its camera by 180 deg about x to look down) 100 m above the
        reference point 9 E 45 N at 120 m: in UTM zone 32 that is on the central meridian, E 500 000:

        >>> import json, pathlib, tempfile
        >>> import numpy as np
        >>> from photax.io import read_opensfm_shots
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "reconstruction.json"
        >>> camera = {"projection_type": "perspective", "width": 4000, "height": 3000, "focal": 0.75}
        >>> shot = {"camera": "v2 cam", "rotation": [np.pi, 0.0, 0.0], "translation": [0.0, 0.0, 100.0]}
        >>> _ = path.write_text(json.dumps([{"cameras": {"v2 cam": camera}, "shots": {"IMG_1.JPG": shot},
        ...                                  "reference_lla": {"latitude": 45.0, "longitude": 9.0, "altitude": 120}}]))

        >>> shots, crs, cameras = read_opensfm_shots(path)
        >>> crs, cameras, np.round(np.asarray(shots["IMG_1"].position), 2).tolist()
        ('EPSG:32632', {'IMG_1': 'cam'}, [500000.0, 4982950.4, 220.0])
        >>> bool(np.allclose(shots["IMG_1"].angles, 0.0, atol=1e-12))  # photax's nadir: no rotation
        True
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
            target = projected_crs(crs, "crs") if crs is not None else projected_crs(utm_crs(lon=lla[1], lat=lla[0]))
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
    utm = projected_crs(utm_crs(lon=lla[1], lat=lla[0]))  # ODM's grid-aligned frame is its UTM zone's
    xyz_t, grid_from_topo = topocentric_to_projected(centre, lla, utm)
    xyz_g = project_lla(*lla, utm) + centre
    if frame is None:
        has = np.all(np.isfinite(gps), axis=-1)
        spread = float(np.max(np.linalg.norm(xyz_t - xyz_g, axis=-1)))
        # the frames' headings differ by the meridian convergence: same positions are not same rotations
        turn = float(np.max(np.arccos(np.clip((np.trace(grid_from_topo, axis1=-2, axis2=-1) - 1) / 2, -1, 1))))
        if has.any():
            # the GNSS residuals under the grid frame, e, against the frames' difference, d: e = alpha d + noise,
            # alpha 0 for the grid frame, 1 for the topocentric one; decided when alpha is near one of them
            # and its standard error (from the residuals of that fit) is under 1/6 of their distance
            truth = topocentric_to_projected(gps[has], lla, utm)[0]
            e, d = truth - xyz_g[has], (xyz_t - xyz_g)[has]
            dd = float(np.sum(d * d))
            alpha = float(np.sum(e * d)) / dd if dd > 1e-6 else math.nan
            near = 1.0 if alpha > 0.5 else 0.0
            sigma = math.sqrt(float(np.sum((e - near * d) ** 2)) / max(e.size - 1, 1))
            if dd > 1e-6 and abs(alpha - near) < 0.25 and sigma < math.sqrt(dd) / 6:  # frames a mm apart or more
                frame = "topocentric" if near else "grid"
        if frame is None and turn < 1e-9:  # the two frames are one here: either will do
            frame = "topocentric"
        if frame is None:
            if not has.any():
                why = "no shot has a gps_position"
            else:
                fit = (
                    f"fit {alpha:.2f} of the way from grid to topocentric"
                    if dd > 1e-6
                    else "both frames put them there"
                )
                why = (
                    f"the shots' gps_position (residual {sigma:.3g} m) do not tell OpenSfM's topocentric frame "
                    f"from ODM's grid-aligned one ({fit})"
                )
            raise ValueError(
                f"{why}: the frames' positions differ by up to {spread:.3g} m and headings "
                f"by {np.degrees(turn):.3g} degrees here: name the frame (--exterior grid:FILE or topocentric:FILE; frame=)"
            )
    if frame == "topocentric":
        xyz, rotation = xyz_t, grid_from_topo @ r_frame
    else:
        xyz, rotation = xyz_g, r_frame
    if crs == utm:
        return xyz, rotation
    xyz, turn = reproject(xyz, utm, crs)
    return xyz, turn @ rotation


def camera_to_opensfm(camera: FrameCamera) -> dict:
    """The OpenSfM camera entry of ``camera`` (the inverse of the reader's, module
    docstring): normalised focal lengths and principal point, OpenCV's ``p1``.

    Raises:
        ValueError: a camera without a pixel grid, a scanned one, or an
            ``opencv`` camera with terms beyond OpenSfM's ``brown`` (k4-k6, s1-s4).

    Examples:
        OpenSfM's camera entry: focal length and principal point normalised by the larger image side:

        >>> import photax as ptx
        >>> from photax.io import camera_to_opensfm
        >>> entry = camera_to_opensfm(ptx.FrameCamera.from_pixels(3000.0, (4000, 3000)))
        >>> entry["projection_type"], entry["width"], entry["height"], round(entry["focal_x"], 6)
        ('brown', 4000, 3000, 0.75)
    """
    if camera.pixel_size is None or camera.image_size is None or getattr(camera, "transform", None) is not None:
        raise ValueError("an OpenSfM camera needs a pixel grid (pixel_size and image_size) and no scan transform")
    (w, h), (sx, sy) = camera.image_size, (float(v) for v in np.asarray(camera.pixel_size))
    x0, y0 = (float(v) for v in np.asarray(camera.principal_point))
    f, m = float(camera.focal_length), max(w, h)
    dist = dict(zip(DISTORTION_MODELS[camera.model], np.asarray(camera.distortion, dtype=float).tolist()))
    if camera.model == "opencv" and any(dist[k] != 0 for k in ("k4", "k5", "k6", "s1", "s2", "s3", "s4")):
        raise ValueError(
            "OpenSfM has no camera for OpenCV's k4-k6 and s1-s4 terms: this camera has them "
            "(an 'opencv' camera without them is written as 'brown')"
        )
    out = {"projection_type": "brown", "width": int(w), "height": int(h)}
    focal = {"focal_x": f / sx / m, "focal_y": f / sy / m}
    centre = {"c_x": x0 / (sx * m), "c_y": -y0 / (sy * m)}
    if camera.model == "fisheye":
        if sx == sy and x0 == 0 and y0 == 0 and dist["k3"] == 0 and dist["k4"] == 0:
            return {**out, "projection_type": "fisheye", "focal": focal["focal_x"], "k1": dist["k1"], "k2": dist["k2"]}
        return {
            **out,
            "projection_type": "fisheye_opencv",
            **focal,
            **centre,
            **{f"k{i}": dist[f"k{i}"] for i in range(1, 5)},
        }
    brown = {k: dist[k] for k in ("k1", "k2", "k3", "p2")}
    return {**out, **focal, **centre, **brown, "p1": 0.0 - dist["p1"]}


def _opensfm_cameras(cameras) -> dict[str, dict]:
    if isinstance(cameras, FrameCamera):
        cameras = {"photax_camera": cameras}
    if not cameras:
        raise ValueError("no cameras to write")
    out = {}
    for name, cam in cameras.items():
        try:
            out[str(name)] = camera_to_opensfm(cam)
        except ValueError as exc:
            raise ValueError(f"camera {excerpt(name)}: {exc}") from None
        bad = [k for k, v in out[str(name)].items() if not isinstance(v, str) and not math.isfinite(v)]
        if bad:
            raise ValueError(f"camera {excerpt(name)}: {', '.join(bad)} is not finite (nan or inf): not written")
    return out


def write_opensfm_reconstruction(
    path,
    cameras,
    exteriors,
    crs,
    reference_lla=None,
    frame: str = "topocentric",
    image_cameras=None,
    *,
    inputs=(),
) -> pathlib.Path:
    """Write cameras and orientations as an OpenSfM/ODM ``reconstruction.json``: a
    list of one reconstruction with ``cameras``, ``shots``, ``reference_lla`` and
    no ``points`` (module docstring).  :func:`read_opensfm_cameras` and
    :func:`read_opensfm_shots` read back the same cameras (in pixels) and
    orientations; orthority reads it too (``frame="grid"`` is the frame it assumes).

    Args:
        path: the file (written atomically; ``inputs`` may not be overwritten).
        cameras: ``{camera name: FrameCamera}``, or one camera (named ``"photax_camera"``).
        exteriors: ``{image name: ExteriorOrientation}`` (any convention) in ``crs``.
        crs: the projected CRS of the positions.
        reference_lla: ``(latitude, longitude, altitude)`` (WGS84, degrees, ellipsoidal
            metres) of the reconstruction's origin; default the geodetic position of
            the cameras' mean.
        frame: ``"topocentric"`` (OpenSfM's) or ``"grid"`` (ODM's and orthority's:
            the UTM grid of ``reference_lla``, offsets from it).
        image_cameras: ``{image name: camera name}``; may be left out with one camera.

    Raises:
        ValueError: no orientations, a camera OpenSfM cannot hold, an image without a
            camera, two images of one name, a CRS that is not projected, a bad frame.

    Examples:
        Cameras and orientations as an OpenSfM/ODM ``reconstruction.json``, read back (the shots in
        the projected CRS; here ODM's grid frame, parallel to the UTM grid):

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_opensfm_cameras, read_opensfm_shots, write_opensfm_reconstruction
        >>> cam = ptx.FrameCamera.from_pixels(3000.0, (4000, 3000))
        >>> eo = ptx.ExteriorOrientation([500100.0, 4096000.0, 400.0], np.radians([1.0, -2.0, 30.0]), "omega-phi-kappa")
        >>> path = write_opensfm_reconstruction(pathlib.Path(tempfile.mkdtemp()) / "reconstruction.json",
        ...                                     {"cam": cam}, {"IMG_1.JPG": eo}, "EPSG:32633", frame="grid")
        >>> (back_cam,) = read_opensfm_cameras(path).values()
        >>> shots, crs, _ = read_opensfm_shots(path, crs="EPSG:32633", frame="grid")
        >>> bool(np.isclose(back_cam.focal_length, 3000.0)), bool(np.allclose(shots["IMG_1"].position, eo.position, atol=1e-6))
        (True, True)
        >>> bool(np.allclose(shots["IMG_1"].rotation, eo.rotation, atol=1e-9))
        True
    """
    import json

    from .atomic import atomic_write

    if frame not in ("topocentric", "grid"):
        raise ValueError(f"frame must be 'topocentric' or 'grid', got {frame!r}")
    osfm_cameras = _opensfm_cameras(cameras)
    if not exteriors:
        raise ValueError("no orientations to write")
    names = [str(n) for n in exteriors]
    stems = [pathlib.PurePath(n).stem for n in names]
    if len(set(stems)) != len(stems) or not all(stems):
        raise ValueError("image names must be non-empty and differ without their extensions (read back by stem)")
    if image_cameras is None:
        if len(osfm_cameras) != 1:
            raise ValueError(f"{len(osfm_cameras)} cameras: image_cameras must say which image uses which")
        image_cameras = dict.fromkeys(names, next(iter(osfm_cameras)))
    shot_cameras = {}
    for name in exteriors:
        cam = image_cameras.get(name)
        if cam is None or str(cam) not in osfm_cameras:
            raise ValueError(f"image {excerpt(name)}: camera {excerpt(cam)} is not among the cameras written")
        shot_cameras[str(name)] = str(cam)
    target = projected_crs(crs, "crs")
    xyz = np.asarray([np.asarray(eo.position, dtype=float) for eo in exteriors.values()])
    rotation = np.asarray([np.asarray(eo.rotation, dtype=float) for eo in exteriors.values()])
    if xyz.shape != (len(names), 3) or not (np.all(np.isfinite(xyz)) and np.all(np.isfinite(rotation))):
        raise ValueError("every orientation must be one finite position and attitude")
    if reference_lla is None:
        lon, lat, h = _to_lla(xyz.mean(axis=0), target)
        reference_lla = (lat, lon, h)
    lla = np.asarray(reference_lla, dtype=float)
    if lla.shape != (3,) or not np.all(np.isfinite(lla)) or abs(lla[0]) > 90 or abs(lla[1]) > 180:
        raise ValueError(f"reference_lla must be a latitude, longitude and altitude, got {reference_lla!r}")
    centre, r_frame, gps = _from_grid(xyz, rotation, lla, target, frame)
    r_cv, t = opencv_extrinsics(r_frame, centre)
    rvec = np.asarray(matrix_to_axis_angle(r_cv), dtype=float)
    shots = {
        name: {
            "rotation": rvec[j].tolist(),
            "translation": t[j].tolist(),
            "camera": shot_cameras[name],
            "gps_position": gps[j].tolist(),
        }
        for j, name in enumerate(names)
    }
    ref = dict(zip(("latitude", "longitude", "altitude"), lla.tolist()))
    data = [{"cameras": osfm_cameras, "shots": shots, "reference_lla": ref, "points": {}}]
    with atomic_write(path, inputs=inputs) as fh:
        json.dump(data, fh, indent=4)
    return pathlib.Path(path)


def _to_lla(xyz, crs) -> tuple[float, float, float]:
    import pyproj

    t = pyproj.Transformer.from_crs(crs, "EPSG:4979", always_xy=True)
    lon, lat, h = (float(v) for v in t.transform(*xyz))
    if not all(np.isfinite((lon, lat, h))):
        raise OutsideValidityError(f"positions outside the area of {crs.name!r}")
    return lon, lat, h


def _from_grid(xyz, rotation, lla, crs, frame):
    """Projected positions and world_from_camera rotations in ``crs`` -> shot centres,
    rotations and topocentric GNSS positions in the reconstruction's ``frame``: the
    inverse of :func:`_to_grid`."""
    utm = projected_crs(utm_crs(lon=lla[1], lat=lla[0]))
    if crs != utm:
        xyz, turn = reproject(xyz, crs, utm)
        rotation = turn @ rotation
    topo = projected_to_topocentric(xyz, lla, utm)
    if frame == "grid":
        return xyz - project_lla(*lla, utm), rotation, topo
    grid_from_topo = topocentric_to_projected(topo, lla, utm)[1]
    return topo, np.swapaxes(grid_from_topo, -1, -2) @ rotation, topo
