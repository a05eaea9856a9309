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

A scanned film photograph (:class:`photax.interior.ScannedCamera`, written by
``photax fiducials --camera-out``) adds a ``scan`` block: the fitted film ->
scan pixel transformation of its interior orientation
(:class:`photax.interior.PixelTransform`), so that pixels go through it::

    focal_length: 152.9            # from the calibration report, mm
    unit: mm
    principal_point: [0.0, 0.0]
    image_size: [2400, 2400]       # the scan's (width, height), required
    scan:
      model: affine                # similarity, affine, bilinear or projective
      film_centre: [0.3, -0.1]     # (cu, cv): centroid of the fiducials in (x, -y), unit
      film_scale: 149.8            # s: their rms distance from it, unit
      params: [1199.6, 1563.2, 1.1, 1200.2, -0.9, 1563.5]

``params`` map the normalised film coordinates ``u = (x - cu) / s``,
``v = (-y - cv) / s`` to the pixel (column, row): affine ``c = a0 + a1 u +
a2 v``, ``r = a3 + a4 u + a5 v`` (the other models: :mod:`photax.interior`).
``pixel_size`` may be left out (default: the transformation's mean scale);
``focal_length_px``, ``principal_point_px`` and ``unit: px`` do not go with a scan.

Missing distortion coefficients are zero; ``distortion`` may also be a list
``[k1, k2, k3, p1, p2]``.  Another distortion model
(:data:`photax.camera.DISTORTION_MODELS`) is named in the mapping, with its
coefficients (``convention: opencv`` negates ``p1``, ``s3`` and ``s4``)::

    distortion: {model: opencv, k1: -0.2, k4: 0.1, s1: 0.002}   # k1-k6, p1 p2, s1-s4
    distortion: {model: fisheye, k1: 0.04, k2: -0.01}         # Kannala-Brandt k1-k4
  ``name`` and ``description`` are free text.  Any
other key, a key given twice, a value that is not a finite number, and a
focal length, pixel size or image size that is not positive are a
``ValueError`` naming the file and (YAML) the line.  Frames and the distortion
equations: ``docs/conventions.md``.
"""

from __future__ import annotations

import json
import pathlib

import jax.numpy as jnp
import numpy as np
import yaml

from ..camera import DISTORTION_MODELS, FrameCamera
from ..errors import DegenerateGeometryError
from .atomic import atomic_write
from .files import Mapping, as_numbers, excerpt, file_error, load_json, load_yaml, read_text, where

_KEYS = {
    "focal_length",
    "unit",
    "principal_point",
    "principal_point_px",
    "pixel_size",
    "image_size",
    "distortion",
    "focal_length_px",
    "name",
    "description",
    "scan",
}
_SCAN_KEYS = ("model", "film_centre", "film_scale", "params")
_DIST = ("k1", "k2", "k3", "p1", "p2")
_Y_DOWN = ("p1", "s3", "s4")  # OpenCV's y is down: these are minus photax's (photax.camera)
_UNITS = ("mm", "m", "px")


def _load(path: pathlib.Path) -> dict:
    text = read_text(path, "camera file")
    data = load_json(path, text) if path.suffix.lower() == ".json" else load_yaml(path, text)
    if not isinstance(data, dict):
        got = "nothing" if data is None else f"a {type(data).__name__}"
        raise file_error(
            path, None, f"not a photax camera file (YAML mapping expected: focal_length: ..., unit: ...), got {got}"
        )
    if data and not set(data) & _KEYS:
        # No key is a camera key: some other file (a key of it may be a secret): quote none of it.
        raise file_error(
            path,
            None,
            "not a photax camera file (YAML mapping with focal_length or "
            f"focal_length_px expected; none of its {len(data)} keys is a camera key)",
        )
    return data


def _at(path, data, key) -> str:
    """``path, line n`` of ``key`` in ``data`` (YAML), or just ``path`` (JSON)."""
    return where(path, data.line(key) if isinstance(data, Mapping) else None)


def _vector(path, data, key, n, scalar_ok=False) -> np.ndarray:
    value = data[key]
    v = as_numbers(value)
    if v is None:
        raise ValueError(f"{_at(path, data, key)}: {key} must be numbers, got {excerpt(value)}") from None
    shapes = ((n,), ()) if scalar_ok else ((n,),)
    if v.shape not in shapes or not np.all(np.isfinite(v)):
        raise ValueError(
            f"{_at(path, data, key)}: {key} must be {n} finite number{'s' if n > 1 else ''}, got {excerpt(value)}"
        )
    return v


def _positive(path, data, key, v) -> np.ndarray:
    if not np.all(v > 0):
        raise ValueError(f"{_at(path, data, key)}: {key} must be positive, got {excerpt(data[key])}")
    return v


def _scalar(path, data, key) -> float:
    return float(_vector(path, data, key, 1, scalar_ok=True).reshape(-1)[0])


def _distortion(path, data) -> tuple[np.ndarray, str]:
    """The coefficients and the model name of ``data``'s ``distortion``."""
    value = data.get("distortion")
    if value is None:
        return np.zeros(5), "brown"
    if isinstance(value, (list, tuple)):
        if len(value) != 5:
            raise ValueError(f"{_at(path, data, 'distortion')}: distortion as a list must be [k1, k2, k3, p1, p2]")
        return _vector(path, data, "distortion", 5), "brown"
    if not isinstance(value, dict):
        raise ValueError(
            f"{_at(path, data, 'distortion')}: distortion must be a mapping {{k1: .., p1: ..}} or a list of 5"
        )
    convention = value.get("convention", "photax")
    model = value.get("model", "brown")
    if not isinstance(model, str) or model not in DISTORTION_MODELS:
        raise ValueError(
            f"{_at(path, value, 'model')}: distortion.model must be one of {', '.join(DISTORTION_MODELS)}, "
            f"got {excerpt(model)}"
        )
    names = DISTORTION_MODELS[model]
    unknown = sorted(set(value) - set(names) - {"convention", "model"}, key=str)
    if unknown:
        raise ValueError(
            f"{_at(path, value, unknown[0])}: unknown key distortion.{unknown[0]} for the {model} model; "
            f"accepted: {', '.join(names)}, model, convention"
        )
    if convention not in ("photax", "opencv"):
        raise ValueError(
            f"{_at(path, value, 'convention')}: distortion.convention must be 'photax' or 'opencv', "
            f"got {excerpt(convention)}"
        )
    d = np.array([_scalar(path, value, k) if k in value else 0.0 for k in names])
    if convention == "opencv":  # OpenCV's y is down, so its p1 (s3, s4) is minus ours
        d[[names.index(k) for k in _Y_DOWN if k in names]] *= -1.0
    return d, model


def read_camera(path) -> FrameCamera:
    """Read a camera file (format in the module docstring) into a :class:`FrameCamera`.

    Raises:
        ValueError: naming the file and the offending key (or line for a
            syntax error).

    Examples:
        A camera file in millimetres (``docs/conventions.md``), read into a :class:`FrameCamera`:

        >>> import pathlib, tempfile
        >>> import photax as ptx
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "camera.yaml"
        >>> _ = path.write_text(
        ...     "focal_length: 8.8\\nunit: mm\\nprincipal_point: [0.011, -0.0066]\\n"
        ...     "pixel_size: 0.0176\\nimage_size: [1000, 750]\\ndistortion: {k1: -0.02}\\n"
        ... )
        >>> cam = ptx.read_camera(path)
        >>> float(cam.focal_length), cam.image_size, cam.has_distortion
        (8.8, (1000, 750), True)
    """
    path = pathlib.Path(path)
    data = _load(path)
    unknown = sorted(set(data) - _KEYS, key=str)
    if unknown:
        raise ValueError(
            f"{_at(path, data, unknown[0])}: unknown key {excerpt(unknown[0])}; accepted: {', '.join(sorted(_KEYS))}"
        )
    distortion, model = _distortion(path, data)
    size = None
    if "image_size" in data:
        size = _vector(path, data, "image_size", 2)
        if np.any(size <= 0) or np.any(size != np.round(size)) or np.any(size > 2**31 - 1):
            raise ValueError(
                f"{_at(path, data, 'image_size')}: image_size must be [width, height] in whole "
                f"pixels, got {excerpt(data['image_size'])}"
            )
        size = (int(size[0]), int(size[1]))
    if "focal_length_px" in data:
        extra = sorted(set(data) & {"focal_length", "unit", "pixel_size", "principal_point", "scan"})
        if extra:
            raise ValueError(
                f"{_at(path, data, extra[0])}: focal_length_px is the pixel shorthand; "
                f"do not combine it with {extra[0]}"
            )
        if size is None:
            raise ValueError(f"{_at(path, data, 'focal_length_px')}: focal_length_px needs image_size")
        f = _positive(path, data, "focal_length_px", _scalar(path, data, "focal_length_px"))
        pp = data.get("principal_point_px")
        pp = None if pp is None else tuple(_vector(path, data, "principal_point_px", 2))
        return FrameCamera.from_pixels(f, size, pp, distortion, model=model)
    if "focal_length" not in data:
        raise ValueError(f"{path}: missing key 'focal_length' (or the shorthand 'focal_length_px')")
    unit = data.get("unit")
    if not isinstance(unit, str) or unit not in _UNITS:
        raise ValueError(
            f"{_at(path, data, 'unit') if 'unit' in data else path}: unit must be one of {_UNITS}, got {excerpt(unit)}"
        )
    f = _positive(path, data, "focal_length", _scalar(path, data, "focal_length"))
    pixel_size = None
    if "pixel_size" in data:
        pixel_size = _positive(path, data, "pixel_size", _vector(path, data, "pixel_size", 2, scalar_ok=True))
    if unit == "px":
        if pixel_size is not None and not np.all(pixel_size == 1):
            raise ValueError(
                f"{_at(path, data, 'pixel_size')}: with unit px the pixel_size is 1, got {excerpt(data['pixel_size'])}"
            )
        pixel_size = 1.0 if size is not None else None
    if "scan" in data:
        if model != "brown":
            raise ValueError(f"{_at(path, data, 'scan')}: a scanned camera has the brown distortion model")
        return _scanned(path, data, f, distortion, pixel_size, size, unit)
    if "principal_point" in data and "principal_point_px" in data:
        raise ValueError(
            f"{_at(path, data, 'principal_point_px')}: give principal_point or principal_point_px, not both"
        )
    pp = _vector(path, data, "principal_point", 2) if "principal_point" in data else np.zeros(2)
    if "principal_point_px" in data:
        if pixel_size is None or size is None:
            raise ValueError(
                f"{_at(path, data, 'principal_point_px')}: principal_point_px needs pixel_size and image_size"
            )
        c, r = _vector(path, data, "principal_point_px", 2)
        ps = np.broadcast_to(pixel_size, (2,))
        with np.errstate(over="ignore"):
            pp = np.array([(c - (size[0] - 1) / 2) * ps[0], -(r - (size[1] - 1) / 2) * ps[1]])
        if not np.all(np.isfinite(pp)):
            raise ValueError(f"{_at(path, data, 'principal_point_px')}: principal_point_px is out of range")
    return FrameCamera(f, pp, distortion, pixel_size=pixel_size, image_size=size, model=model)


def _scanned(path, data, f, distortion, pixel_size, size, unit):
    """The :class:`photax.interior.ScannedCamera` of a camera file with a ``scan`` block."""
    from ..interior import N_PARAMS, PixelTransform, ScannedCamera

    for key in ("principal_point_px",) + (("unit",) if unit == "px" else ()):
        if key in data:
            raise ValueError(
                f"{_at(path, data, key)}: a scanned camera (scan:) is in film units (mm or m): "
                f"{key}{': px' if key == 'unit' else ''} does not go with it"
            )
    if size is None:
        raise ValueError(f"{_at(path, data, 'scan')}: a scanned camera needs image_size (the scan's width, height)")
    scan = data["scan"]
    if not isinstance(scan, dict):
        raise ValueError(f"{_at(path, data, 'scan')}: scan must be a mapping with the keys {', '.join(_SCAN_KEYS)}")
    unknown = sorted(set(scan) - set(_SCAN_KEYS), key=str)
    missing = [k for k in _SCAN_KEYS if k not in scan]
    if unknown or missing:
        what = f"unknown key scan.{unknown[0]}" if unknown else f"missing key scan.{missing[0]}"
        raise ValueError(
            f"{_at(path, scan, unknown[0]) if unknown else _at(path, data, 'scan')}: {what}; "
            f"a scan block has {', '.join(_SCAN_KEYS)}"
        )
    model = scan["model"]
    if model not in N_PARAMS:
        raise ValueError(
            f"{_at(path, scan, 'model')}: scan.model must be one of {sorted(N_PARAMS)}, got {excerpt(model)}"
        )
    params = _vector(path, scan, "params", N_PARAMS[model])
    centre = _vector(path, scan, "film_centre", 2)
    scale = _positive(path, scan, "film_scale", _scalar(path, scan, "film_scale"))
    pp = _vector(path, data, "principal_point", 2) if "principal_point" in data else np.zeros(2)
    transform = PixelTransform(jnp.asarray(params), jnp.asarray(centre), jnp.asarray(scale), model)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean_scale = transform.scale()
    if not (np.isfinite(mean_scale) and mean_scale > 0):
        raise DegenerateGeometryError(f"{_at(path, scan, 'params')}: scan.params is a singular transformation")
    return ScannedCamera(
        f, pp, distortion, transform=transform, image_size=size, pixel_size=None if pixel_size is None else pixel_size
    )


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
    transform = getattr(camera, "transform", None)  # a photax.interior.ScannedCamera
    if transform is not None and unit == "px":
        raise ValueError("unit: a scanned camera is in film units, give 'mm' or 'm'")
    out: dict = {
        "focal_length": float(camera.focal_length),
        "unit": unit,
        "principal_point": np.asarray(camera.principal_point).tolist(),
    }
    if ps is not None and unit != "px" and not (transform is not None and ps == [transform.scale()] * 2):
        out["pixel_size"] = ps[0] if ps[0] == ps[1] else ps  # a scan's default (the transform's scale) is left out
    if camera.image_size is not None:
        out["image_size"] = list(camera.image_size)
    names = DISTORTION_MODELS[camera.model]
    out["distortion"] = ({} if camera.model == "brown" else {"model": camera.model}) | dict(
        zip(names, np.asarray(camera.distortion).tolist())
    )
    if transform is not None:
        out["scan"] = {
            "model": transform.model,
            "film_centre": np.asarray(transform.film_centre).tolist(),
            "film_scale": float(transform.film_scale),
            "params": np.asarray(transform.params).tolist(),
        }
    return out


def write_camera(camera: FrameCamera, path, *, unit: str | None = None, inputs=()) -> pathlib.Path:
    """Write ``camera`` as YAML (``.yaml``/``.yml``) or JSON (``.json``), atomically.

    ``unit`` as in :func:`camera_to_dict`.  Returns the path written.

    Examples:
        A camera written and read back equal (here in pixels):

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> cam = ptx.FrameCamera.from_pixels(2904.0, (4000, 3000))
        >>> path = ptx.write_camera(cam, pathlib.Path(tempfile.mkdtemp()) / "cam.yaml")
        >>> back = ptx.read_camera(path)
        >>> float(back.focal_length) == float(cam.focal_length), back.image_size
        (True, (4000, 3000))
        >>> bool(np.allclose(back.principal_point, cam.principal_point))
        True
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
