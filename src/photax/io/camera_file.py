"""photax's own camera file (interior orientation), YAML or JSON.

Full form (lengths in ``unit``; ``mm``, ``m`` or ``px``)::

    focal_length: 8.8              # principal distance f
    unit: mm                       # unit of focal_length, principal_point, pixel_size
    principal_point: [0.0, 0.0]    # (x0, y0) on the image plane, y up, from the image centre
    pixel_size: 0.0044             # one value, or [along columns, along rows]
    image_size: [4000, 3000]       # (width, height) in pixels
    distortion:                    # Brown-Conrady on normalised coordinates
      k1: -0.05
      k2: 0.0
      k3: 0.0
      p1: 0.0                      # photax's y-up sense ...
      p2: 0.0
      convention: photax           # ... or "opencv": p1 is then OpenCV's (= -photax's)

Instead of ``principal_point`` the principal point may be given in pixels,
``principal_point_px: [column, row]`` (needs ``pixel_size`` and ``image_size``).
With ``unit: px`` the pixel size is 1 and may be left out.  Shorthand for a
camera in pixel units (:meth:`photax.FrameCamera.from_pixels`)::

    focal_length_px: 2904.0
    image_size: [4000, 3000]
    principal_point_px: [1999.5, 1499.5]   # optional, default the image centre
    distortion: {k1: -0.05}

Missing distortion coefficients are zero; ``distortion`` may also be a list
``[k1, k2, k3, p1, p2]``.  ``name`` and ``description`` are free text.  Any
other key, a key given twice, a value that is not a finite number, and a
focal length, pixel size or image size that is not positive are a
``ValueError`` naming the file and (YAML) the line.  Frames and the distortion
equations: ``docs/conventions.md``.
"""

from __future__ import annotations

import json
import pathlib

import numpy as np
import yaml

from ..camera import FrameCamera
from ._files import Mapping, as_numbers, file_error, load_json, load_yaml, read_text, where
from .atomic import atomic_write

_KEYS = {"focal_length", "unit", "principal_point", "principal_point_px", "pixel_size",
         "image_size", "distortion", "focal_length_px", "name", "description"}
_DIST = ("k1", "k2", "k3", "p1", "p2")
_UNITS = ("mm", "m", "px")


def _load(path: pathlib.Path) -> dict:
    text = read_text(path, "camera file")
    data = load_json(path, text) if path.suffix.lower() == ".json" else load_yaml(path, text)
    if not isinstance(data, dict):
        raise file_error(path, None, "a camera file must be a mapping of keys to values "
                                     f"(focal_length: ..., unit: ...), got {type(data).__name__}")
    return data


def _at(path, data, key) -> str:
    """``path, line n`` of ``key`` in ``data`` (YAML), or just ``path`` (JSON)."""
    return where(path, data.line(key) if isinstance(data, Mapping) else None)


def _vector(path, data, key, n, scalar_ok=False) -> np.ndarray:
    value = data[key]
    v = as_numbers(value)
    if v is None:
        raise ValueError(f"{_at(path, data, key)}: {key} must be numbers, got {value!r}") from None
    shapes = ((n,), ()) if scalar_ok else ((n,),)
    if v.shape not in shapes or not np.all(np.isfinite(v)):
        raise ValueError(f"{_at(path, data, key)}: {key} must be {n} finite number{'s' if n > 1 else ''}, got {value!r}")
    return v


def _positive(path, data, key, v) -> np.ndarray:
    if not np.all(v > 0):
        raise ValueError(f"{_at(path, data, key)}: {key} must be positive, got {data[key]!r}")
    return v


def _scalar(path, data, key) -> float:
    return float(_vector(path, data, key, 1, scalar_ok=True).reshape(-1)[0])


def _distortion(path, data) -> np.ndarray:
    value = data.get("distortion")
    if value is None:
        return np.zeros(5)
    if isinstance(value, (list, tuple)):
        if len(value) != 5:
            raise ValueError(f"{_at(path, data, 'distortion')}: distortion as a list must be [k1, k2, k3, p1, p2]")
        return _vector(path, data, "distortion", 5)
    if not isinstance(value, dict):
        raise ValueError(f"{_at(path, data, 'distortion')}: distortion must be a mapping {{k1: .., p1: ..}} or a list of 5")
    convention = value.get("convention", "photax")
    unknown = sorted(set(value) - set(_DIST) - {"convention"}, key=str)
    if unknown:
        raise ValueError(f"{_at(path, value, unknown[0])}: unknown key distortion.{unknown[0]}; "
                         f"accepted: {', '.join(_DIST)}, convention")
    if convention not in ("photax", "opencv"):
        raise ValueError(f"{_at(path, value, 'convention')}: distortion.convention must be 'photax' or 'opencv', "
                         f"got {convention!r}")
    d = np.array([_scalar(path, value, k) if k in value else 0.0 for k in _DIST])
    if convention == "opencv":
        d[3] = -d[3]  # OpenCV's y is down, so its p1 is minus ours
    return d


def read_camera(path) -> FrameCamera:
    """Read a camera file (format in the module docstring) into a :class:`FrameCamera`.

    Raises:
        ValueError: naming the file and the offending key (or line for a
            syntax error).
    """
    path = pathlib.Path(path)
    data = _load(path)
    unknown = sorted(set(data) - _KEYS, key=str)
    if unknown:
        raise ValueError(f"{_at(path, data, unknown[0])}: unknown key {unknown[0]!r}; "
                         f"accepted: {', '.join(sorted(_KEYS))}")
    distortion = _distortion(path, data)
    size = None
    if "image_size" in data:
        size = _vector(path, data, "image_size", 2)
        if np.any(size <= 0) or np.any(size != np.round(size)) or np.any(size > 2**31 - 1):
            raise ValueError(f"{_at(path, data, 'image_size')}: image_size must be [width, height] in whole "
                             f"pixels, got {data['image_size']!r}")
        size = (int(size[0]), int(size[1]))
    if "focal_length_px" in data:
        extra = sorted(set(data) & {"focal_length", "unit", "pixel_size", "principal_point"})
        if extra:
            raise ValueError(f"{_at(path, data, extra[0])}: focal_length_px is the pixel shorthand; "
                             f"do not combine it with {extra[0]}")
        if size is None:
            raise ValueError(f"{_at(path, data, 'focal_length_px')}: focal_length_px needs image_size")
        f = _positive(path, data, "focal_length_px", _scalar(path, data, "focal_length_px"))
        pp = data.get("principal_point_px")
        pp = None if pp is None else tuple(_vector(path, data, "principal_point_px", 2))
        return FrameCamera.from_pixels(f, size, pp, distortion)
    if "focal_length" not in data:
        raise ValueError(f"{path}: missing key 'focal_length' (or the shorthand 'focal_length_px')")
    unit = data.get("unit")
    if not isinstance(unit, str) or unit not in _UNITS:
        raise ValueError(f"{_at(path, data, 'unit') if 'unit' in data else path}: unit must be one of "
                         f"{_UNITS}, got {unit!r}")
    f = _positive(path, data, "focal_length", _scalar(path, data, "focal_length"))
    pixel_size = None
    if "pixel_size" in data:
        pixel_size = _positive(path, data, "pixel_size", _vector(path, data, "pixel_size", 2, scalar_ok=True))
    if unit == "px":
        if pixel_size is not None and not np.all(pixel_size == 1):
            raise ValueError(f"{_at(path, data, 'pixel_size')}: with unit px the pixel_size is 1, "
                             f"got {data['pixel_size']!r}")
        pixel_size = 1.0 if size is not None else None
    if "principal_point" in data and "principal_point_px" in data:
        raise ValueError(f"{_at(path, data, 'principal_point_px')}: give principal_point or "
                         "principal_point_px, not both")
    pp = _vector(path, data, "principal_point", 2) if "principal_point" in data else np.zeros(2)
    if "principal_point_px" in data:
        if pixel_size is None or size is None:
            raise ValueError(f"{_at(path, data, 'principal_point_px')}: principal_point_px needs "
                             "pixel_size and image_size")
        c, r = _vector(path, data, "principal_point_px", 2)
        ps = np.broadcast_to(pixel_size, (2,))
        with np.errstate(over="ignore"):
            pp = np.array([(c - (size[0] - 1) / 2) * ps[0], -(r - (size[1] - 1) / 2) * ps[1]])
        if not np.all(np.isfinite(pp)):
            raise ValueError(f"{_at(path, data, 'principal_point_px')}: principal_point_px is out of range")
    return FrameCamera(f, pp, distortion, pixel_size=pixel_size, image_size=size)


def camera_to_dict(camera: FrameCamera, unit: str | None = None) -> dict:
    """The file form of ``camera`` (full form; see the module docstring).

    ``unit`` labels the camera's length unit; default ``"px"`` when the pixel
    size is 1, else it must be given (photax does not guess units).
    """
    ps = None if camera.pixel_size is None else np.asarray(camera.pixel_size).tolist()
    if unit is None:
        if ps is None or ps != [1.0, 1.0]:
            raise ValueError("unit is required ('mm' or 'm') for a camera whose pixel size is not 1")
        unit = "px"
    if unit not in _UNITS:
        raise ValueError(f"unit must be one of {_UNITS}, got {unit!r}")
    out: dict = {"focal_length": float(camera.focal_length), "unit": unit,
                 "principal_point": np.asarray(camera.principal_point).tolist()}
    if ps is not None and unit != "px":
        out["pixel_size"] = ps[0] if ps[0] == ps[1] else ps
    if camera.image_size is not None:
        out["image_size"] = list(camera.image_size)
    out["distortion"] = dict(zip(_DIST, np.asarray(camera.distortion).tolist()))
    return out


def write_camera(camera: FrameCamera, path, *, unit: str | None = None, inputs=()) -> pathlib.Path:
    """Write ``camera`` as YAML (``.yaml``/``.yml``) or JSON (``.json``), atomically.

    ``unit`` as in :func:`camera_to_dict`.  Returns the path written.
    """
    path = pathlib.Path(path)
    data = camera_to_dict(camera, unit)
    with atomic_write(path, inputs=inputs) as fh:
        if path.suffix.lower() == ".json":
            json.dump(data, fh, indent=2)
            fh.write("\n")
        else:
            yaml.safe_dump(data, fh, sort_keys=False)
    return path
