"""photax's push-broom camera file (a :class:`photax.PushbroomCamera`), YAML or JSON.

All of the model's fields, in its own units (``docs/conventions.md``, "Push-broom camera file")::

    type: pushbroom                  # required: says what the file holds
    image_size: [2000, 2000]         # (width: pixels along the array, lines)
    focal_length: 310000.0           # principal distance, pixels
    principal_point: [0.0, 0.0]      # (x0, y0) px: right of the array's centre, above the array (optional)
    convention: phi-omega-kappa      # the attitude angles' convention (optional, this default)
    reference:                       # world(ECEF)_from_reference rotation, 3 rows
      - [0.1, -0.9, 0.4]
      - ...
    position:                        # projection centre, ECEF metres: polynomial coefficients in the
      - [4.5e6, 8.1e5, 4.9e6]        # normalised line time tau, lowest order first: order 0 (tau = 0,
      - [-1.3e3, 2.0e2, 1.1e3]       # the middle line), order 1 (metres per unit tau), ...
    angles:                          # attitude angles (rad, in the convention's order) relative to
      - [0.0, 0.21, 0.0]             # ``reference``, polynomial coefficients in tau likewise
      - [1.0e-6, 0.0, 0.0]
    name: my scene                   # free text (optional)

``tau = (row - (L - 1) / 2) / ((L - 1) / 2)`` for ``L = image_size[1]`` lines: ``-1`` at the first
line's centre, ``+1`` at the last's.  Any other key, a key given twice, a missing one, a value that
is not a finite number or of the wrong shape, a reference that is not a rotation, and a focal length
or image size that is not positive are a ``ValueError`` naming the file and (YAML) the key's line.
:func:`write_pushbroom` writes every float as Python's ``repr``: a file read back is the same camera,
bit for bit.
"""

from __future__ import annotations

import json
import pathlib

import numpy as np
import yaml

from .atomic import atomic_write
from .files import Mapping, as_numbers, excerpt, file_error, load_json, load_yaml, read_text, where

_REQUIRED = ("type", "image_size", "focal_length", "reference", "position", "angles")
_KEYS = frozenset(_REQUIRED) | {"principal_point", "convention", "name"}


def _at(path, data, key) -> str:
    return where(path, data.line(key) if isinstance(data, Mapping) else None)


def _array(path, data, key, shape: tuple) -> np.ndarray:
    """``data[key]`` as finite numbers of ``shape`` (``-1``: any length >= 1)."""
    value = data[key]
    v = as_numbers(value)
    ok = v is not None and v.ndim == len(shape) and all(s == -1 or n == s for n, s in zip(v.shape, shape))
    if not ok or v.size == 0 or not np.all(np.isfinite(v)):
        want = {(): "a finite number", (2,): "2 finite numbers", (3, 3): "3 rows of 3 finite numbers",
                (-1, 3): "rows of 3 finite numbers (one per polynomial order)"}[shape]  # fmt: skip
        raise ValueError(f"{_at(path, data, key)}: {key} must be {want}, got {excerpt(value)}")
    return v


def is_pushbroom_file(path) -> bool:
    """Whether ``path`` is a YAML/JSON file whose top-level ``type`` is ``pushbroom`` (a quick test for
    the command line; :func:`read_pushbroom` says what else is wrong with it)."""
    path = pathlib.Path(path)
    if path.suffix.lower() not in (".yaml", ".yml", ".json") or not path.is_file():
        return False
    try:
        text = path.read_text()
        doc = json.loads(text) if path.suffix.lower() == ".json" else yaml.safe_load(text)
    except (OSError, UnicodeDecodeError, ValueError, yaml.YAMLError):
        return False
    return isinstance(doc, dict) and doc.get("type") == "pushbroom"


def read_pushbroom(path):
    """Read a push-broom camera file (format in the module docstring) into a :class:`photax.PushbroomCamera`.

    Raises:
        ValueError: naming the file and the offending key (YAML: its line; a syntax error's line).

    Examples:
        A camera file by hand: an array 1000 px wide, 100 lines, 620 km above the equator at 0 E
        looking down (the reference turns the camera's -z onto -X, its y onto north), flying north
        3 km from the first line to the middle one:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "scene.yaml"
        >>> _ = path.write_text("type: pushbroom\\nimage_size: [1000, 100]\\nfocal_length: 310000.0\\n"
        ...                     "reference: [[0, 0, 1], [1, 0, 0], [0, 1, 0]]\\n"
        ...                     "position: [[6998137.0, 0.0, 0.0], [0.0, 0.0, 3000.0]]\\nangles: [[0.0, 0.0, 0.0]]\\n")

        >>> camera = ptx.read_pushbroom(path)
        >>> camera.image_size, float(camera.focal_length)
        ((1000, 100), 310000.0)
        >>> print(np.round(np.asarray(camera(np.array([[0.0, 0.0, 0.0]]))), 6) + 0.0)  # the nadir point
        [[499.5  49.5]]
    """
    from ..pushbroom import PushbroomCamera
    from ..rotation import CONVENTIONS

    path = pathlib.Path(path)
    text = read_text(path, "push-broom camera file")
    data = load_json(path, text) if path.suffix.lower() == ".json" else load_yaml(path, text)
    if not isinstance(data, dict) or data.get("type") != "pushbroom":
        raise file_error(path, None, "not a photax push-broom camera file (a mapping with 'type: pushbroom' expected)")
    unknown = sorted((k for k in data if k not in _KEYS), key=str)
    if unknown:
        raise ValueError(
            f"{_at(path, data, unknown[0])}: unknown key {excerpt(unknown[0])}; accepted: {', '.join(sorted(_KEYS))}"
        )
    missing = [k for k in _REQUIRED if k not in data]
    if missing:
        raise file_error(path, None, f"missing key {', '.join(repr(k) for k in missing)}")
    size = _array(path, data, "image_size", (2,))
    if np.any(size != np.round(size)) or size[0] < 1 or size[1] < 2 or np.any(size > 2**31 - 1):
        raise ValueError(
            f"{_at(path, data, 'image_size')}: image_size must be [width >= 1, lines >= 2] in whole pixels, "
            f"got {excerpt(data['image_size'])}"
        )
    focal = float(_array(path, data, "focal_length", ()))
    if not focal > 0:
        raise ValueError(f"{_at(path, data, 'focal_length')}: focal_length must be positive, got {focal}")
    pp = _array(path, data, "principal_point", (2,)) if "principal_point" in data else np.zeros(2)
    convention = data.get("convention", "phi-omega-kappa")
    if convention not in CONVENTIONS:
        raise ValueError(
            f"{_at(path, data, 'convention')}: convention must be one of {', '.join(CONVENTIONS)}, "
            f"got {excerpt(convention)}"
        )
    if "name" in data and not isinstance(data["name"], str):
        raise ValueError(f"{_at(path, data, 'name')}: name must be text, got {excerpt(data['name'])}")
    reference = _array(path, data, "reference", (3, 3))
    if not (np.allclose(reference.T @ reference, np.eye(3), atol=1e-9) and np.linalg.det(reference) > 0):
        raise ValueError(f"{_at(path, data, 'reference')}: reference is not a rotation (orthonormal, determinant +1)")
    position = _array(path, data, "position", (-1, 3))
    angles = _array(path, data, "angles", (-1, 3))
    try:
        return PushbroomCamera(position, angles, reference, focal, pp, image_size=(int(size[0]), int(size[1])),
                               convention=convention)  # fmt: skip
    except ValueError as exc:
        raise file_error(path, None, str(exc)) from None


def pushbroom_to_dict(camera, name: str | None = None) -> dict:
    """The file's mapping of ``camera`` (plain Python numbers)."""
    data = {
        "type": "pushbroom",
        "image_size": [int(v) for v in camera.image_size],
        "focal_length": float(camera.focal_length),
        "principal_point": [float(v) for v in np.asarray(camera.principal_point)],
        "convention": camera.convention,
        "reference": np.asarray(camera.reference, dtype=float).tolist(),
        "position": np.asarray(camera.position, dtype=float).tolist(),
        "angles": np.asarray(camera.angles, dtype=float).tolist(),
    }
    if name is not None:
        data["name"] = str(name)
    return data


def write_pushbroom(camera, path, *, name: str | None = None, inputs=()) -> pathlib.Path:
    """Write ``camera`` (a :class:`photax.PushbroomCamera`) as YAML (``.yaml``/``.yml``) or JSON
    (``.json``), atomically; ``inputs``: paths it may not overwrite.  Returns the path written.

    Examples:
        Written and read back, as YAML or JSON: the same camera, bit for bit:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> camera = ptx.pushbroom_scene(image_size=(2000, 2000)).camera
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> backs = [ptx.read_pushbroom(ptx.write_pushbroom(camera, folder / name)) for name in ("c.yaml", "c.json")]
        >>> same = lambda b: bool(np.array_equal(b.position, camera.position) and np.array_equal(b.angles, camera.angles))
        >>> [same(b) for b in backs]
        [True, True]
        >>> (folder / "c.yaml").read_text().splitlines()[1]
        'type: pushbroom'
    """
    path = pathlib.Path(path)
    data = pushbroom_to_dict(camera, name)
    with atomic_write(path, inputs=inputs) as fh:
        if path.suffix.lower() == ".json":
            json.dump(data, fh, indent=2)
            fh.write("\n")
        else:
            fh.write("# photax push-broom camera (docs/conventions.md): tau = (row - (L-1)/2) / ((L-1)/2)\n")
            yaml.safe_dump(data, fh, sort_keys=False, default_flow_style=None)
    return path
