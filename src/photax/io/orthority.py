"""Orthority's camera files (interior YAML, exterior CSV + .prj).

These are the formats of the NGI aerial test data (orthority's tests) and of
``orthority`` itself.  Their conventions, read from orthority 0.7's source
(``camera.py``, ``param_io.py``), map onto photax's exactly:

* **Exterior angles**: orthority's ``(omega, phi, kappa)`` build
  ``R = Rx(omega) Ry(phi) Rz(kappa)`` rotating from its "PATB" camera frame
  (x right, y up, z backwards) to the world: that is photax's
  ``"omega-phi-kappa"`` ``world_from_camera`` in the same camera frame
  (``docs/conventions.md``), so the angles are taken over unchanged (degrees
  -> radians).  orthority flips y and z afterwards only to use OpenCV's
  intrinsic matrix.
* **Interior**: focal length in pixels ``f * im_size / sensor_size`` per
  axis, so photax's ``pixel_size = sensor_size / im_size``.  The principal
  point in pixels is ``(im_size - 1)/2 + max(im_size) * (cx, cy)`` (row
  down): ``cx, cy`` are offsets from the image centre normalised by the
  larger image dimension, ``cy`` positive downwards.
* **Pixels**: integer coordinates at pixel centres, origin at the top-left
  pixel centre, as photax.  No half-pixel shift is needed.
"""

from __future__ import annotations

import csv
import math
import pathlib

import numpy as np

from ..camera import DISTORTION_MODELS, FrameCamera
from ..collinearity import ExteriorOrientation
from .files import (
    Mapping,
    as_numbers,
    at_line,
    excerpt,
    expect,
    file_error,
    load_json,
    load_yaml,
    read_text,
    split_lines,
    where,
)

#: orthority's camera types -> photax's distortion model and its coefficients read from the file
#: (photax.camera.DISTORTION_MODELS; pinhole: none, brown).
_TYPES = {"pinhole": "brown", "brown": "brown", "opencv": "opencv", "fisheye": "fisheye"}
_Y_DOWN = ("p1", "s3", "s4")  # OpenCV's y is down: these are minus photax's (photax.camera)
_TILT = ("tx", "ty")  # OpenCV's tilted sensor: not in photax's models


def _camera_from_params(path, name, p: dict, line: int | None = None) -> FrameCamera:
    # Messages point at the key's line, or at the camera's for a missing key.
    at = lambda key: where(path, p.line(key) if isinstance(p, Mapping) and key in p else line)  # noqa: E731
    if "type" in p:
        expect(p["type"], "text", "type", path, at_line(p, "type", line), f"camera {excerpt(name)}")
    kind = p.get("type")
    kind = kind.lower() if isinstance(kind, str) else kind
    if kind not in _TYPES:
        raise ValueError(
            f"{at('type')}: camera {excerpt(name)} has type {excerpt(kind)}; "
            "photax reads orthority 'pinhole', 'brown', 'opencv' and 'fisheye' cameras"
        )
    if kind == "opencv":  # the tilt of OpenCV's 14-term model has no photax camera
        values = {k: as_numbers(p[k]) for k in _TILT if k in p}
        extra = [k for k, v in values.items() if v is None or v.shape != () or float(v) != 0.0]
        if extra:
            raise ValueError(
                f"{at(extra[0])}: camera {excerpt(name)}: the opencv parameters {extra} are not "
                "zero; photax's opencv model has k1-k6, p1, p2, s1-s4 (the tilted sensor's tx, ty "
                "is not converted)"
            )

    def numbers(key, n, default=None, scalar_ok=False):
        if key not in p:
            if default is None:
                raise ValueError(f"{at(key)}: camera {excerpt(name)}: missing parameter {excerpt(key)}")
            return np.asarray(default, dtype=float)
        value = p[key]
        v = as_numbers(value)
        ok_shapes = ((n,), ()) if scalar_ok else ((n,),)
        if v is None or v.shape not in ok_shapes or not np.all(np.isfinite(v)):
            raise ValueError(
                f"{at(key)}: camera {excerpt(name)}: {key} must be {n} finite number"
                f"{'s' if n > 1 else ''}, got {excerpt(value)}"
            )
        return v

    im_size = numbers("im_size", 2)
    if np.any(im_size < 1) or np.any(im_size != np.round(im_size)) or np.any(im_size > 2**31 - 1):
        raise ValueError(
            f"{at('im_size')}: camera {excerpt(name)}: im_size must be [width, height] "
            "in whole pixels, "
            f"got {excerpt(p['im_size'])}"
        )
    w, h = (int(v) for v in im_size)
    focal = np.broadcast_to(numbers("focal_len", 2, scalar_ok=True), (2,))
    if not np.all(focal > 0):
        raise ValueError(
            f"{at('focal_len')}: camera {excerpt(name)}: focal_len must be positive, got {excerpt(p['focal_len'])}"
        )
    sensor = numbers("sensor_size", 2) if p.get("sensor_size") is not None else None
    if sensor is not None and not np.all(sensor > 0):
        raise ValueError(
            f"{at('sensor_size')}: camera {excerpt(name)}: sensor_size must be positive, "
            f"got {excerpt(p['sensor_size'])}"
        )
    cx, cy = float(numbers("cx", 1, 0.0, scalar_ok=True)), float(numbers("cy", 1, 0.0, scalar_ok=True))
    with np.errstate(over="ignore", under="ignore"):
        if sensor is None:
            # orthority: focal_len normalised by the image width, square pixels.
            fx, fy = focal * w
            size = np.array([1.0, fx / fy])
            f = fx
        else:
            sw, sh = sensor
            # Focal lengths in pixels fx = f_x w / sw, fy = f_y h / sh; photax keeps one
            # principal distance, f_x, and puts any difference into the pixel height.
            f = focal[0]
            size = np.array([sw / w, sh / h * focal[0] / focal[1]])
        m = max(w, h)
        principal_point = np.array([cx * m * size[0], -cy * m * size[1]])  # y up in photax
    if not (
        np.isfinite(f)
        and f > 0
        and np.all(np.isfinite(size))
        and np.all(size > 0)
        and np.all(np.isfinite(principal_point))
    ):
        raise ValueError(
            f"{at('focal_len')}: camera {excerpt(name)}: "
            "focal_len, sensor_size, cx, cy give a camera "
            f"out of range (f = {f:g}, pixel size = {size.tolist()})"
        )
    model = _TYPES[kind]
    dist = [
        (-1.0 if k in _Y_DOWN else 1.0) * float(numbers(k, 1, 0.0, scalar_ok=True)) if kind != "pinhole" else 0.0
        for k in DISTORTION_MODELS[model]
    ]  # OpenCV's p1, s3, s4 are for y down; photax's image plane has y up (photax.camera)
    return FrameCamera(f, principal_point, dist, pixel_size=size, image_size=(w, h), model=model)


def camera_to_orthority(camera: FrameCamera) -> dict:
    """The orthority interior parameters of ``camera`` (the inverse of
    :func:`read_orthority_interior` for one camera): ``type`` (``brown``,
    ``opencv`` or ``fisheye`` after the camera's model), ``im_size``,
    ``focal_len`` and ``sensor_size`` in the camera's unit, ``cx``, ``cy``
    (module docstring) and the distortion coefficients in OpenCV's sense.

    Raises:
        ValueError: a camera without a pixel grid, or a scanned one (its
            pixels go through a fitted transformation orthority has no
            place for).

    Examples:
        The orthority parameters of a camera (pixels become orthority's sensor size):

        >>> import photax as ptx
        >>> from photax.io import camera_to_orthority
        >>> params = camera_to_orthority(ptx.FrameCamera(8.8, pixel_size=0.0176, image_size=(1000, 750)))
        >>> params["type"], params["im_size"], [round(v, 6) for v in params["sensor_size"]]
        ('brown', [1000, 750], [17.6, 13.2])
    """
    if camera.pixel_size is None or camera.image_size is None or getattr(camera, "transform", None) is not None:
        raise ValueError("an orthority camera needs a pixel grid (pixel_size and image_size) and no scan transform")
    (w, h), (sx, sy) = camera.image_size, (float(v) for v in np.asarray(camera.pixel_size))
    x0, y0 = (float(v) for v in np.asarray(camera.principal_point))
    m = max(w, h)
    names = DISTORTION_MODELS[camera.model]
    dist = {k: (-v if k in _Y_DOWN else v) + 0.0 for k, v in zip(names, np.asarray(camera.distortion).tolist())}
    return {
        "type": camera.model,
        "im_size": [w, h],
        "focal_len": float(camera.focal_length),
        "sensor_size": [sx * w, sy * h],
        "cx": x0 / (m * sx),
        "cy": -y0 / (m * sy),
        **dist,
    }


def read_orthority_interior(path) -> dict[str, FrameCamera]:
    """Read orthority's interior-parameter YAML: ``{camera name: FrameCamera}``.

    Each entry has ``type`` (``pinhole``, ``brown``, ``opencv`` or
    ``fisheye``), ``im_size: [w, h]``, ``focal_len`` (scalar or ``[fx,
    fy]``), ``sensor_size: [w, h]`` in the focal length's unit, ``cx``, ``cy``
    (see the module docstring) and the type's distortion coefficients:
    ``brown`` k1, k2, k3, p1, p2 (photax's ``"brown"``), ``opencv`` those and
    k4, k5, k6, s1 ... s4 (``"opencv"``; a tilt ``tx``, ``ty`` other than 0
    is refused), ``fisheye`` k1 ... k4 (``"fisheye"``).  The photax camera
    works in the focal length's unit (e.g. mm).

    Examples:
        orthority's interior parameter file: ``{camera name: FrameCamera}``:

        >>> import pathlib, tempfile
        >>> from photax.io import read_orthority_interior
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "int_param.yaml"
        >>> _ = path.write_text("cam:\\n  type: pinhole\\n  im_size: [1000, 750]\\n  focal_len: 8.8\\n  sensor_size: [17.6, 13.2]\\n")
        >>> cam = read_orthority_interior(path)["cam"]
        >>> cam.image_size, round(float(cam.focal_length / cam.pixel_size[0]), 6)  # f in pixels: 8.8 / 0.0176
        ((1000, 750), 500.0)
    """
    path = pathlib.Path(path)
    data = load_yaml(path, read_text(path, "orthority interior file"))
    if isinstance(data, dict) and "type" in data and not isinstance(data["type"], dict):
        data = {None: data}  # a single, unnamed camera
    if not isinstance(data, dict) or not data or not all(isinstance(v, dict) for v in data.values()):
        raise ValueError(f"{path}: expected a mapping of camera names to parameter mappings")
    lines = data.lines if isinstance(data, Mapping) else {}
    return {name: _camera_from_params(path, name, p, lines.get(name)) for name, p in data.items()}


_COLUMNS = ["filename", "x", "y", "z", "omega", "phi", "kappa"]
_LLA_RPY = ["filename", "latitude", "longitude", "altitude", "roll", "pitch", "yaw"]


def read_orthority_exterior(csv_path, prj=None) -> dict[str, ExteriorOrientation]:
    """Read orthority's exterior CSV: ``{file stem: ExteriorOrientation}``.

    Columns ``filename, x, y, z, omega, phi, kappa`` (with or without that
    header line; comma, tab, semicolon or space separated; an optional
    ``camera`` column is ignored), or, with a header,
    ``filename, latitude, longitude, altitude, roll, pitch, yaw`` (a drone's
    GNSS and attitude: see :func:`read_orthority_exterior_crs`, which also
    gives the CRS).  Positions are in the CRS of the ``.prj`` beside the file
    (see :func:`read_orthority_crs`); angles are degrees in orthority's
    omega-phi-kappa, which is photax's ``"omega-phi-kappa"`` convention
    unchanged (module docstring).  Keys are file names without extension, as
    orthority matches them.

    Examples:
        orthority's ``filename x y z omega phi kappa`` CSV (angles in degrees): ``{stem: orientation}``:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> from photax.io import read_orthority_exterior
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "ext.csv"
        >>> _ = path.write_text("filename,x,y,z,omega,phi,kappa\\nIMG_1.tif,512300.0,4103800.0,450.0,1.0,-2.0,30.0\\n")
        >>> eo = read_orthority_exterior(path)["IMG_1"]
        >>> eo.convention, np.asarray(eo.position).tolist(), np.round(np.degrees(np.asarray(eo.angles)), 6).tolist()
        ('omega-phi-kappa', [512300.0, 4103800.0, 450.0], [1.0, -2.0, 30.0])
    """
    table, _ = _read_csv(pathlib.Path(csv_path))
    if prj is not None and not pathlib.Path(prj).is_file():
        raise FileNotFoundError(f"no such .prj file: {prj}")
    return table


def read_orthority_exterior_crs(csv_path, crs=None) -> tuple[dict[str, ExteriorOrientation], str | None]:
    """:func:`read_orthority_exterior` with the CRS of its positions: the ``.prj``
    beside an ``x y z omega phi kappa`` file (None without one); for a
    ``latitude longitude altitude roll pitch yaw`` file the WGS84 UTM zone of
    the mean position, into which positions are projected and roll, pitch,
    yaw (degrees; body x forward, y right, z down, the camera's x along the
    body's y: the usual drone geometry) turned into omega, phi, kappa at each
    camera with the meridian convergence, as orthority (and Pix4D) do, or
    into ``crs`` (a projected CRS) when given; ``crs`` is not used for an
    ``x y z`` file, whose CRS is its ``.prj``'s.  Heights stay as given
    (ellipsoidal for GNSS).

    Examples:
        orthority's drone CSV (latitude, longitude, altitude, roll, pitch, yaw) projected into the
        UTM zone of its mean position:

        >>> import pathlib, tempfile
        >>> from photax.io import read_orthority_exterior_crs
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "lla_rpy.csv"
        >>> _ = path.write_text("filename,latitude,longitude,altitude,roll,pitch,yaw\\nDJI_1.JPG,37.0,15.0,500.0,0,0,0\\n")
        >>> table, crs = read_orthority_exterior_crs(path)
        >>> crs, [round(float(v), 1) for v in table["DJI_1"].position][::2]  # on the zone's central meridian: E 500000
        ('EPSG:32633', [500000.0, 500.0])
    """
    return _read_csv(pathlib.Path(csv_path), crs)


def _read_csv(path: pathlib.Path, crs=None):
    text = read_text(path, "orthority exterior file")
    lines = [(i + 1, ln) for i, ln in enumerate(split_lines(text)) if ln.strip() and not ln.startswith("#")]
    if not lines:
        raise ValueError(f"{path}: no exterior orientations")
    try:
        dialect = csv.Sniffer().sniff(lines[0][1], delimiters=",;\t ")
    except csv.Error:
        dialect = csv.excel
    rows = []
    for n, ln in lines:
        try:
            rows.extend(
                (
                    n,
                    [c.strip().strip("'") for c in row if c.strip()]
                    if dialect.delimiter == " "
                    else [c.strip().strip("'") for c in row],
                )
                for row in csv.reader([ln], dialect)
            )
        except csv.Error as exc:
            raise file_error(path, n, f"not a CSV line ({exc})") from None
    if not rows:
        raise file_error(path, None, "no exterior orientations")
    header = [c.lower() for c in rows[0][1]]
    columns = _COLUMNS
    if "filename" in header:
        rows = rows[1:]
        if all(c in header for c in _LLA_RPY[1:]) and not all(c in header for c in _COLUMNS):
            columns = _LLA_RPY
        missing = [c for c in columns if c not in header]
        if missing:
            raise ValueError(
                f"{path}, line {lines[0][0]}: header lacks the columns {missing} (photax reads "
                "x, y, z, omega, phi, kappa or latitude, longitude, altitude, roll, pitch, yaw)"
            )
        index = [header.index(c) for c in columns]
    else:
        index = list(range(7))
    names, values, at = [], [], []
    for k, (n, row) in enumerate(rows):
        try:
            name, *vals = (row[i] for i in index)
            vals = [float(v) for v in vals]
        except (IndexError, ValueError):
            if k == 0 and "filename" not in header:  # some other file: none of it quoted
                raise file_error(
                    path,
                    n,
                    "not an orthority exterior file (a CSV with a header filename, x, "
                    "y, z, omega, phi, kappa, or rows of those 7 values, expected)",
                ) from None
            got = excerpt(row, 80)
            raise ValueError(f"{path}, line {n}: expected {', '.join(columns)}, got {got}") from None
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"{path}, line {n}: non-finite value in {excerpt(row, 80)}")
        if columns is _LLA_RPY and not (abs(vals[0]) <= 90 and abs(vals[1]) <= 360 and abs(vals[2]) < 1e7):
            raise ValueError(f"{path}, line {n}: latitude, longitude or altitude out of range")
        key = pathlib.PurePath(name).stem
        if not key:
            raise file_error(path, n, f"empty file name in {row}")
        if key in names:
            raise ValueError(f"{path}, line {n}: duplicate file name {excerpt(key)}")
        names.append(key)
        values.append(vals)
        at.append(n)
    if not names:
        raise file_error(path, None, "no exterior orientations")
    values = np.asarray(values, dtype=float)
    if columns is _COLUMNS:
        return {
            k: ExteriorOrientation(v[:3], np.radians(v[3:]), "omega-phi-kappa") for k, v in zip(names, values)
        }, read_orthority_crs(path)
    from ..geo import utm_crs
    from ._geo import projected_crs

    lat, lon = values[:, 0], values[:, 1]
    target = projected_crs(crs) if crs is not None else projected_crs(utm_crs(lon=lon.mean(), lat=lat.mean()))
    try:
        xyz, opk = lla_rpy_to_xyz_opk(values[:, :3], np.radians(values[:, 3:]), target)
    except ValueError as exc:
        raise file_error(path, None, str(exc)) from None
    return {k: ExteriorOrientation(p, a, "omega-phi-kappa") for k, p, a in zip(names, xyz, opk)}, target.to_string()


#: Rotation from the camera frame (x right, y up, z back) to a drone's body frame
#: (x forward, y right, z down) of a camera looking down with its top to the front
#: (orthority's and Pix4D's default ``C_bB``).
BODY_FROM_CAMERA = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def lla_rpy_to_xyz_opk(lla, rpy, crs, body_from_camera=BODY_FROM_CAMERA) -> tuple[np.ndarray, np.ndarray]:
    """WGS84 ``(lat, lon, h)`` (degrees, ``(n, 3)``) and roll, pitch, yaw (radians,
    ``(n, 3)``: body -> north-east-down, ``R = Rz(yaw) Ry(pitch) Rx(roll)``) ->
    positions in the projected ``crs`` and omega, phi, kappa (radians, photax's
    ``"omega-phi-kappa"`` world_from_camera) there, the Pix4D way orthority
    follows: ``world_from_camera = grid_from_ned C_nb C_bB``, ``grid_from_ned``
    from grid north at the camera (meridian convergence) and the vertical.
    """
    from ..rotation import angles_from_matrix, rotation_matrix
    from ._geo import grid_from_enu, project_lla

    lla, rpy = np.asarray(lla, dtype=float), np.asarray(rpy, dtype=float)
    xyz = project_lla(lla[:, 0], lla[:, 1], lla[:, 2], crs)
    r, p, y = rpy[:, 0], rpy[:, 1], rpy[:, 2]
    # Rz(yaw) Ry(pitch) Rx(roll) is photax's "omega-phi-kappa" matrix Rx Ry Rz transposed with negated angles.
    c_nb = np.swapaxes(np.asarray(rotation_matrix(np.stack([-r, -p, -y], -1), "omega-phi-kappa")), -1, -2)
    enu_from_ned = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    grid = grid_from_enu(lla[:, 0], lla[:, 1], crs, delta=1e-7) @ enu_from_ned
    opk = np.asarray(angles_from_matrix(grid @ c_nb @ np.asarray(body_from_camera), "omega-phi-kappa"))
    return xyz, opk


def read_orthority_geojson(path) -> tuple[dict[str, ExteriorOrientation], str]:
    """orthority's exterior GeoJSON (``--export-params``): ``({file stem:
    ExteriorOrientation}, crs)``; each feature's ``properties`` hold
    ``filename``, ``xyz`` (in ``world_crs``) and ``opk`` (radians, orthority's
    omega-phi-kappa = photax's); the point geometry (lon, lat) is not used.

    Examples:
        orthority's exterior GeoJSON (written here by :func:`write_orthority_geojson`):
        ``({stem: orientation}, crs)``:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_orthority_geojson, write_orthority_geojson
        >>> eo = ptx.ExteriorOrientation([512300.0, 4103800.0, 450.0], np.radians([1.0, -2.0, 30.0]), "omega-phi-kappa")
        >>> path = write_orthority_geojson(pathlib.Path(tempfile.mkdtemp()) / "ext.geojson", {"IMG_1.tif": eo}, "EPSG:32633")
        >>> table, crs = read_orthority_geojson(path)
        >>> list(table), table["IMG_1"].convention
        (['IMG_1'], 'omega-phi-kappa')
    """
    path = pathlib.Path(path)
    data = load_json(path, read_text(path, "orthority exterior file"))
    if (
        not isinstance(data, dict)
        or data.get("type") != "FeatureCollection"
        or not isinstance(data.get("features"), list)
    ):
        raise file_error(
            path,
            None,
            "not an orthority exterior GeoJSON (a FeatureCollection with "
            "'world_crs' and features of filename, xyz, opk expected)",
        )
    crs = data.get("world_crs")
    if not isinstance(crs, str) or not crs.strip():
        raise file_error(path, None, "'world_crs' must be the CRS of the positions (WKT, EPSG or PROJ text)")
    out: dict[str, ExteriorOrientation] = {}
    for k, feature in enumerate(data["features"]):
        props = feature.get("properties") if isinstance(feature, dict) else None
        name = props.get("filename") if isinstance(props, dict) else None
        xyz = as_numbers(props.get("xyz")) if isinstance(props, dict) else None
        opk = as_numbers(props.get("opk")) if isinstance(props, dict) else None
        if (
            not isinstance(name, str)
            or xyz is None
            or opk is None
            or xyz.shape != (3,)
            or opk.shape != (3,)
            or not np.all(np.isfinite(xyz) & np.isfinite(opk))
        ):
            raise file_error(
                path, None, f"feature {k}: properties need a filename, and xyz and opk of 3 finite numbers each"
            )
        key = pathlib.PurePath(name).stem
        if not key or key in out:
            raise file_error(path, None, f"feature {k}: an empty or repeated filename {excerpt(name)}")
        out[key] = ExteriorOrientation(xyz, opk, "omega-phi-kappa")
    if not out:
        raise file_error(path, None, "no exterior orientations")
    return out, crs


def read_orthority_crs(csv_path, prj=None) -> str | None:
    """The CRS text of an exterior CSV: ``prj`` or the ``.prj`` beside it, else None.

    Examples:
        The CRS of an exterior CSV: the ``.prj`` beside it, or None:

        >>> import pathlib, tempfile
        >>> from pyproj import CRS
        >>> from photax.io import read_orthority_crs
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> _ = (folder / "ext.csv").write_text("A.tif 100 200 300 0 0 0\\n")
        >>> read_orthority_crs(folder / "ext.csv") is None
        True
        >>> _ = (folder / "ext.prj").write_text(CRS.from_epsg(32633).to_wkt())
        >>> CRS.from_user_input(read_orthority_crs(folder / "ext.csv")).to_epsg()
        32633
    """
    prj = pathlib.Path(prj) if prj is not None else pathlib.Path(csv_path).with_suffix(".prj")
    if not prj.is_file():
        return None
    text = read_text(prj, ".prj file").strip()
    if not text:
        raise ValueError(f"{prj}: empty CRS file")
    return text


# --- writers (photax ortho --export-params) -------------------------------------------------


def _interior_params(name, camera: FrameCamera) -> dict:
    """orthority's parameters of ``camera`` (:func:`camera_to_orthority`), ``pinhole`` when
    it has no distortion; the camera named in the error."""
    try:
        p = camera_to_orthority(camera)
    except ValueError as exc:
        raise ValueError(f"camera {excerpt(name)}: {exc}") from None
    bad = [k for k, v in p.items() if not isinstance(v, str) and not np.all(np.isfinite(np.asarray(v, dtype=float)))]
    if bad:
        raise ValueError(f"camera {excerpt(name)}: {', '.join(bad)} is not finite (nan or inf): not written")
    if not np.any(np.asarray(camera.distortion) != 0):
        p = {k: v for k, v in p.items() if k in ("im_size", "focal_len", "sensor_size", "cx", "cy")}
        p = {"type": "pinhole", **p}
    return p


def write_orthority_interior(path, cameras, *, inputs=()) -> pathlib.Path:
    """Write ``cameras`` (``{name: FrameCamera}``, or one camera, named ``"photax_camera"``)
    as orthority's interior YAML: ``pinhole`` without distortion, else the
    camera's model (``brown``, ``opencv`` or ``fisheye``); ``focal_len`` and ``sensor_size``
    in the camera's length unit, ``cx``, ``cy`` normalised (module docstring).
    :func:`read_orthority_interior` reads back the same cameras (to rounding).
    Written atomically; ``inputs`` may not be overwritten.

    Raises:
        ValueError: a camera without a pixel grid, a scanned camera, or a camera named
            ``camera`` (orthority's legacy key).

    Examples:
        A camera as orthority's interior YAML, read back equal:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_orthority_interior, write_orthority_interior
        >>> cam = ptx.FrameCamera.from_pixels(2904.0, (4000, 3000))
        >>> path = write_orthority_interior(pathlib.Path(tempfile.mkdtemp()) / "int_param.yaml", {"drone": cam})
        >>> back = read_orthority_interior(path)["drone"]
        >>> back.image_size, bool(np.isclose(back.focal_length / back.pixel_size[0], 2904.0))
        ((4000, 3000), True)
    """
    import yaml

    from .atomic import atomic_write

    if isinstance(cameras, FrameCamera):
        cameras = {"photax_camera": cameras}
    if not cameras:
        raise ValueError("no cameras to write")
    if "camera" in map(str, cameras):
        raise ValueError(
            "a camera named 'camera': orthority reads a top-level 'camera' key as its legacy "
            "config.yaml, not as a camera name; name it otherwise"
        )
    data = {str(name): _interior_params(name, cam) for name, cam in cameras.items()}
    with atomic_write(path, inputs=inputs) as fh:
        yaml.safe_dump(data, fh, sort_keys=False, default_flow_style=None)
    return pathlib.Path(path)


def _opk_degrees(name, eo: ExteriorOrientation) -> list[float]:
    from ..rotation import convert_angles

    pos, ang = np.asarray(eo.position, dtype=float), np.asarray(eo.angles, dtype=float)
    if pos.shape != (3,) or ang.shape != (3,) or not (np.all(np.isfinite(pos)) and np.all(np.isfinite(ang))):
        raise ValueError(f"image {excerpt(name)}: the orientation must be one finite position and attitude")
    return np.degrees(np.asarray(convert_angles(ang, eo.convention, "omega-phi-kappa"), dtype=float)).tolist()


def write_orthority_exterior(path, table, crs=None, *, inputs=()) -> pathlib.Path:
    """Write ``table`` (``{image name: ExteriorOrientation}``, any angle convention)
    as orthority's exterior CSV: a header ``filename x y z omega phi kappa``,
    angles in degrees (orthority's omega-phi-kappa = photax's), full precision;
    with ``crs``, its WKT in the ``.prj`` beside the file (both written
    atomically).  :func:`read_orthority_exterior_crs` reads back the same.

    Examples:
        Orientations as orthority's exterior CSV (with its ``.prj``), read back equal:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_orthority_exterior, write_orthority_exterior
        >>> eo = ptx.ExteriorOrientation([512300.0, 4103800.0, 450.0], np.radians([1.0, -2.0, 30.0]), "omega-phi-kappa")
        >>> path = write_orthority_exterior(pathlib.Path(tempfile.mkdtemp()) / "ext.csv", {"IMG_1": eo}, "EPSG:32633")
        >>> back = read_orthority_exterior(path)["IMG_1"]
        >>> bool(np.allclose(back.position, eo.position) and np.allclose(back.rotation, eo.rotation))
        True
    """
    import pyproj

    from .atomic import atomic_write

    path = pathlib.Path(path)
    if not table:
        raise ValueError("no orientations to write")
    rows = []
    for name, eo in table.items():
        key = pathlib.PurePath(str(name)).stem
        if not key or any(c in key for c in ",\n\r\"'") or key != key.strip():
            raise ValueError(f"image name {excerpt(name)} cannot be written in a CSV column")
        rows.append([key, *np.asarray(eo.position, dtype=float).tolist(), *_opk_degrees(name, eo)])
    wkt = pyproj.CRS.from_user_input(crs).to_wkt() if crs is not None else None
    with atomic_write(path, inputs=inputs, newline="") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(_COLUMNS)
        writer.writerows([r[0], *(repr(float(v)) for v in r[1:])] for r in rows)
    if wkt is not None:
        with atomic_write(path.with_suffix(".prj"), inputs=inputs) as fh:
            fh.write(wkt + "\n")
    return path


def write_orthority_geojson(path, table, crs, camera=None, *, inputs=()) -> pathlib.Path:
    """Write ``table`` (``{image name: ExteriorOrientation}``) as orthority's exterior
    GeoJSON (what orthority's ``--export-params`` writes): ``world_crs`` (``crs``, a
    projected CRS), each feature's ``filename``, ``camera`` (the camera name in the
    interior file, or null), ``xyz`` and ``opk`` (radians) and a WGS84 point
    (lon, lat, h).  :func:`read_orthority_geojson` reads back the same.

    Examples:
        Orientations as orthority's exterior GeoJSON, read back equal with their CRS:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_orthority_geojson, write_orthority_geojson
        >>> eo = ptx.ExteriorOrientation([512300.0, 4103800.0, 450.0], np.radians([1.0, -2.0, 30.0]), "omega-phi-kappa")
        >>> path = write_orthority_geojson(pathlib.Path(tempfile.mkdtemp()) / "ext.geojson", {"IMG_1": eo}, "EPSG:32633")
        >>> table, crs = read_orthority_geojson(path)
        >>> bool(np.allclose(table["IMG_1"].position, eo.position) and np.allclose(table["IMG_1"].rotation, eo.rotation))
        True
    """
    import json

    import pyproj

    from ._geo import projected_crs
    from .atomic import atomic_write

    if not table:
        raise ValueError("no orientations to write")
    target = projected_crs(crs, "the exterior GeoJSON's CRS")
    code = target.to_epsg()
    world = f"EPSG:{code}" if code is not None else target.to_wkt()
    to_lla = pyproj.Transformer.from_crs(target, "EPSG:4979", always_xy=True)
    features = []
    for name, eo in table.items():
        opk = np.radians(_opk_degrees(name, eo)).tolist()
        xyz = np.asarray(eo.position, dtype=float).tolist()
        lon, lat, h = to_lla.transform(*xyz)
        props = {"filename": str(name), "camera": camera, "xyz": xyz, "opk": opk}
        geometry = {"type": "Point", "coordinates": [float(lon), float(lat), float(h)]}
        features.append({"type": "Feature", "properties": props, "geometry": geometry})
    data = {"type": "FeatureCollection", "world_crs": world, "features": features}
    with atomic_write(path, inputs=inputs) as fh:
        json.dump(data, fh, indent=2, allow_nan=False)
        fh.write("\n")
    return pathlib.Path(path)


def write_orthority_rpc(path, cameras, *, inputs=()) -> pathlib.Path:
    """Write RPCs (:class:`photax.rpc.RPCCamera`, ``{image file name: camera}``) as orthority's
    ``rpc_param.yaml`` (each entry ``im_size`` and ``rpc`` with GDAL's keys), atomically:
    ``oty rpc --rpc-file`` and :func:`photax.rpc.read_rpc` read it back (a refined RPC's image-space
    correction is not part of the format: refused).

    Examples:
        RPCs as orthority's ``rpc_param.yaml``, read back by :func:`photax.read_rpc`:

        >>> import numpy as np
        >>> import photax as ptx
        >>> t = np.eye(20)  # terms 1, L, P of the 20: column = 500 + 500 L, row = 500 - 500 P
        >>> rpc = ptx.RPCCamera([-t[2], t[0], t[1], t[0]], [10.0, 45.0, 0.0, 500.0, 500.0],
        ...                     [0.01, 0.01, 500.0, 500.0, 500.0], image_size=(1000, 1000))
        >>> import pathlib, tempfile
        >>> from photax.io import write_orthority_rpc
        >>> path = write_orthority_rpc(pathlib.Path(tempfile.mkdtemp()) / "rpc_param.yaml", {"scene.tif": rpc})
        >>> back = ptx.read_rpc(path)
        >>> print(np.asarray(back(np.array([[10.005, 45.005, 100.0]]))), back.image_size)
        [[750. 250.]] (1000, 1000)
    """
    import yaml

    from .atomic import atomic_write

    if not cameras:
        raise ValueError("no RPCs to write")
    doc = {}
    for name, camera in cameras.items():
        if np.any(np.asarray(camera.correction) != 0):
            raise ValueError(f"{name}: a refined RPC's correction has no place in rpc_param.yaml")
        entry = {} if camera.image_size is None else {"im_size": [int(v) for v in camera.image_size]}
        doc[str(name)] = {**entry, "rpc": camera.to_dict()}
    with atomic_write(path, inputs=inputs) as fh:
        yaml.safe_dump(doc, fh, sort_keys=False, default_flow_style=None)
    return pathlib.Path(path)
