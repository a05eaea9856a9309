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

from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from .files import Mapping, as_numbers, excerpt, file_error, load_yaml, read_text, split_lines, where


def _camera_from_params(path, name, p: dict, line: int | None = None) -> FrameCamera:
    # Messages point at the key's line, or at the camera's for a missing key.
    at = lambda key: where(path, p.line(key) if isinstance(p, Mapping) and key in p else line)  # noqa: E731
    kind = p.get("type")
    if not isinstance(kind, str) or kind.lower() != "pinhole":
        raise ValueError(
            f"{at('type')}: camera {excerpt(name)} has type {excerpt(kind)}; "
            "photax reads orthority 'pinhole' "
            "cameras only (brown/opencv/fisheye distortion models are not converted)"
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
            raise ValueError(f"{at(key)}: camera {excerpt(name)}: {key} must be {n} finite number"
                             f"{'s' if n > 1 else ''}, got {excerpt(value)}")
        return v

    im_size = numbers("im_size", 2)
    if np.any(im_size < 1) or np.any(im_size != np.round(im_size)) or np.any(im_size > 2**31 - 1):
        raise ValueError(f"{at('im_size')}: camera {excerpt(name)}: im_size must be [width, height] "
                         "in whole pixels, "
                         f"got {excerpt(p['im_size'])}")
    w, h = (int(v) for v in im_size)
    focal = np.broadcast_to(numbers("focal_len", 2, scalar_ok=True), (2,))
    if not np.all(focal > 0):
        raise ValueError(f"{at('focal_len')}: camera {excerpt(name)}: focal_len must be positive, "
                         f"got {excerpt(p['focal_len'])}")
    sensor = numbers("sensor_size", 2) if p.get("sensor_size") is not None else None
    if sensor is not None and not np.all(sensor > 0):
        raise ValueError(f"{at('sensor_size')}: camera {excerpt(name)}: sensor_size must be positive, "
                         f"got {excerpt(p['sensor_size'])}")
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
    if not (np.isfinite(f) and f > 0 and np.all(np.isfinite(size)) and np.all(size > 0)
            and np.all(np.isfinite(principal_point))):
        raise ValueError(f"{at('focal_len')}: camera {excerpt(name)}: "
                         "focal_len, sensor_size, cx, cy give a camera "
                         f"out of range (f = {f:g}, pixel size = {size.tolist()})")
    return FrameCamera(f, principal_point, pixel_size=size, image_size=(w, h))


def read_orthority_interior(path) -> dict[str, FrameCamera]:
    """Read orthority's interior-parameter YAML: ``{camera name: FrameCamera}``.

    Each entry has ``type: pinhole``, ``im_size: [w, h]``, ``focal_len``
    (scalar or ``[fx, fy]``), ``sensor_size: [w, h]`` in the focal length's
    unit, and ``cx``, ``cy`` (see the module docstring).  The photax camera
    works in the focal length's unit (e.g. mm).
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


def read_orthority_exterior(csv_path, prj=None) -> dict[str, ExteriorOrientation]:
    """Read orthority's exterior CSV: ``{file stem: ExteriorOrientation}``.

    Columns ``filename, x, y, z, omega, phi, kappa`` (with or without that
    header line; comma, tab, semicolon or space separated; an optional
    ``camera`` column is ignored).  Positions are in the CRS of the ``.prj``
    beside the file (see :func:`read_orthority_crs`); angles are degrees in
    orthority's omega-phi-kappa, which is photax's ``"omega-phi-kappa"``
    convention unchanged (module docstring).  Keys are file names without
    extension, as orthority matches them.
    """
    path = pathlib.Path(csv_path)
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
            rows.extend((n, [c.strip() for c in row]) for row in csv.reader([ln], dialect))
        except csv.Error as exc:
            raise file_error(path, n, f"not a CSV line ({exc})") from None
    if not rows:
        raise file_error(path, None, "no exterior orientations")
    header = [c.lower() for c in rows[0][1]]
    if "filename" in header:
        rows = rows[1:]
        missing = [c for c in _COLUMNS if c not in header]
        if missing:
            raise ValueError(f"{path}, line {lines[0][0]}: header lacks the columns {missing}")
        index = [header.index(c) for c in _COLUMNS]
    else:
        index = list(range(7))
    out: dict[str, ExteriorOrientation] = {}
    for k, (n, row) in enumerate(rows):
        try:
            name, *vals = (row[i] for i in index)
            x, y, z, omega, phi, kappa = (float(v) for v in vals)
        except (IndexError, ValueError):
            if k == 0 and "filename" not in header:  # some other file: none of it quoted
                raise file_error(path, n, "not an orthority exterior file (a CSV with a header filename, x, "
                                 "y, z, omega, phi, kappa, or rows of those 7 values, expected)") from None
            got = excerpt(row, 80)
            raise ValueError(f"{path}, line {n}: expected {', '.join(_COLUMNS)}, got {got}") from None
        if not all(math.isfinite(v) for v in (x, y, z, omega, phi, kappa)):
            raise ValueError(f"{path}, line {n}: non-finite value in {excerpt(row, 80)}")
        key = pathlib.PurePath(name).stem
        if not key:
            raise file_error(path, n, f"empty file name in {row}")
        if key in out:
            raise ValueError(f"{path}, line {n}: duplicate file name {excerpt(key)}")
        out[key] = ExteriorOrientation((x, y, z), np.radians([omega, phi, kappa]), "omega-phi-kappa")
    if not out:
        raise file_error(path, None, "no exterior orientations")
    if prj is not None and not pathlib.Path(prj).is_file():
        raise FileNotFoundError(f"no such .prj file: {prj}")
    return out


def read_orthority_crs(csv_path, prj=None) -> str | None:
    """The CRS text of an exterior CSV: ``prj`` or the ``.prj`` beside it, else None."""
    prj = pathlib.Path(prj) if prj is not None else pathlib.Path(csv_path).with_suffix(".prj")
    if not prj.is_file():
        return None
    text = read_text(prj, ".prj file").strip()
    if not text:
        raise ValueError(f"{prj}: empty CRS file")
    return text
