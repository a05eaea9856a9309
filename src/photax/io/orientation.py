"""Orientation files whatever their format: the format is detected here.

* :func:`read_interior`: a photax camera file (:mod:`photax.io.camera_file`)
  or an orthority interior YAML (:mod:`photax.io.orthority`) -- an orthority
  file has a ``type`` key, or maps camera names to mappings that each have one;
* :func:`read_exterior`: a ``photax resect --json`` result (``.json``) or an
  orthority exterior CSV (+ ``.prj`` beside it);
* :func:`read_camera_unit`: the length unit a photax camera file is written in.

The readers' contract holds (:mod:`photax.io`): a malformed file is a
``ValueError`` naming the file (and line where one applies).
"""

from __future__ import annotations

import pathlib

from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from ._files import excerpt, file_error, load_yaml, read_text
from .camera_file import _load as _load_camera_mapping
from .camera_file import read_camera
from .orthority import read_orthority_crs, read_orthority_exterior, read_orthority_interior
from .results import read_json


def _is_orthority_interior(path: pathlib.Path) -> bool:
    try:
        data = load_yaml(path, read_text(path, "camera file"))
    except ValueError:  # not YAML: let read_camera report what is wrong
        return False
    if not isinstance(data, dict) or not data:
        return False
    # orthority's single-camera form has "type" at the top; a photax camera file never does.
    return "type" in data or all(isinstance(v, dict) and "type" in v for v in data.values())


def read_interior(path, name: str | None = None) -> FrameCamera:
    """A :class:`photax.FrameCamera` from a photax camera file or an orthority interior YAML.

    Args:
        path: the file.
        name: the camera of a multi-camera orthority file (not needed when
            it holds one camera; ignored for a photax camera file).

    Raises:
        ValueError: a malformed file (naming file and line), or ``name``
            missing or unknown for a multi-camera file (listing the names).
    """
    path = pathlib.Path(path)
    if not _is_orthority_interior(path):
        return read_camera(path)
    cameras = read_orthority_interior(path)
    if name is None and len(cameras) == 1:
        return next(iter(cameras.values()))
    if name not in cameras:
        raise file_error(path, None, f"holds {len(cameras)} cameras: name one (--camera-name), one of {sorted(map(str, cameras))}")
    return cameras[name]


def _pick_image(path, images, image) -> dict:
    """The entry of a ``photax resect --json`` ``images`` mapping (or of a
    ``photax bundle --json`` ``images`` list, each entry named) for ``image``."""
    if isinstance(images, list):  # bundle: entries carry their name; a batch result: no names to match
        images = {str(v["name"]) if isinstance(v, dict) and "name" in v else str(k): v for k, v in enumerate(images)}
    if not isinstance(images, dict) or not images:
        raise ValueError(f"{path}: 'images' holds no image results")
    if len(images) == 1:
        name, entry = next(iter(images.items()))
    else:
        p = pathlib.Path(image)
        matches = [n for n in images if n in (p.name, p.stem) or pathlib.Path(n).stem == p.stem]
        if len(matches) != 1:
            raise ValueError(f"{path}: holds {len(images)} images {excerpt(sorted(images), 80)}, "
                             "none named like "
                             f"{p.name!r}; rename the image or keep only its result")
        name, entry = matches[0], images[matches[0]]
    if not isinstance(entry, dict):
        raise ValueError(f"{path}: the result of image {excerpt(name)} is not an object")
    status = entry.get("status", "solved" if entry.get("converged", True) else "not converged")
    if status != "solved" or "skipped" in entry:
        why = entry.get("message") or entry.get("skipped") or status
        raise ValueError(f"{path}: image {excerpt(name)} was not solved ({why}); no orientation to use")
    return entry


def read_exterior(path, image) -> tuple[ExteriorOrientation, str | None]:
    """``(ExteriorOrientation, crs or None)`` of ``image`` from a JSON or CSV file.

    A ``photax resect --json`` file (``.json``) holds ``images`` keyed by
    image name, a ``photax bundle --json`` file a list of named images with
    the angle convention beside it: with one image it is used whatever its
    name; with several, the one named like ``image`` (file name or stem); an
    image that was not solved, or any image of an adjustment that did not
    converge, is refused.  Any other file is read as an orthority exterior
    CSV and ``image``'s stem looked up in it.

    Args:
        path: the orientation file.
        image: the image's path or name.

    Raises:
        ValueError: naming the file: malformed, no (solved) orientation for
            ``image``, or several candidates.
    """
    path = pathlib.Path(path)
    if path.suffix.lower() == ".json":
        return exterior_from_result(path, read_json(path), image)
    table = read_orthority_exterior(path)
    stem = pathlib.Path(image).stem
    if stem not in table:
        raise ValueError(f"{path}: no orientation for image {stem!r}")
    return table[stem], read_orthority_crs(path)


def exterior_from_result(path, data, image) -> tuple[ExteriorOrientation, str | None]:
    """:func:`read_exterior` of the already parsed JSON ``data`` of ``path`` (a
    caller reading many images of one file parses it once)."""
    crs = data.get("crs") if isinstance(data, dict) else None
    convention = data.get("convention") if isinstance(data, dict) else None  # a bundle's, for all its images
    if isinstance(data, dict) and data.get("converged") is False:  # a bundle adjustment's own status
        why = data.get("message") or "not converged"
        raise ValueError(f"{path}: the adjustment did not converge ({why}); no orientation to use")
    if isinstance(data, dict) and "images" in data:
        data = _pick_image(path, data["images"], image)
    data = data.get("exterior", data) if isinstance(data, dict) else data
    try:
        convention = data.get("convention", convention)
        if convention is None:
            raise KeyError("convention")
        return ExteriorOrientation(data["position"], data["angles_rad"], convention), crs
    except (KeyError, TypeError, AttributeError):
        raise ValueError(f"{path}: expected 'position', 'angles_rad' and 'convention' (photax resect --json)") from None


def read_camera_unit(path) -> str | None:
    """The length unit of a photax camera file: its ``unit:`` (``"mm"``, ``"m"``,
    ``"px"``), ``"px"`` for the ``focal_length_px`` shorthand, None if not given."""
    data = _load_camera_mapping(pathlib.Path(path))
    return "px" if "focal_length_px" in data else data.get("unit")
