"""OpenDroneMap's own small files: ``cameras.json`` and the image geolocation file ``geo.txt``.

* ``cameras.json`` (ODM's ``--cameras``, and written by every run into the
  project folder) maps camera ids (``"dji fc6310r 5472 3648 brown 0.6666"``)
  to OpenSfM camera parameters: the ``cameras`` object of a
  ``reconstruction.json``, read by the same code
  (:func:`photax.io.opensfm.read_opensfm_cameras`' conventions: pixels,
  ``p1`` sign turned for photax's y-up image plane).
* ``geo.txt`` (ODM's ``--geo``; docs.opendronemap.org, "Image Geolocation
  Files"): a first line naming the CRS (``EPSG:4326``, a PROJ string, or
  ``WGS84 UTM <zone>[N|S]``), then ``image_name geo_x geo_y [geo_z] [yaw]
  [pitch] [roll] [horz_accuracy] [vert_accuracy] [extras...]``; for a
  geographic CRS ``geo_x`` is the longitude.  Positions are read (projected to
  the UTM zone of their mean, or ``crs=``; heights as given), with the
  accuracies where given; the angles are not: ODM uses them only for
  radiometric calibration and does not define their frame, so they do not
  make an exterior orientation.  :func:`write_odm_geo` writes positions back
  (names, x, y and the height where there is one).
"""

from __future__ import annotations

import math
import pathlib
import warnings

import numpy as np

from ..camera import FrameCamera
from .files import excerpt, file_error, head_text, load_json, read_text, split_lines
from .gcp import odm_crs_text


def read_odm_cameras(path) -> dict[str, FrameCamera]:
    """ODM's ``cameras.json``: ``{camera id: FrameCamera}`` in pixels.

    Raises:
        ValueError: naming the file: not a mapping of camera ids to OpenSfM
            camera parameters, or a camera model photax cannot represent.

    Examples:
        ODM's ``cameras.json`` (written here by :func:`write_odm_cameras`): ``{camera id: camera}``:

        >>> import pathlib, tempfile
        >>> import photax as ptx
        >>> from photax.io import read_odm_cameras, write_odm_cameras
        >>> path = write_odm_cameras(pathlib.Path(tempfile.mkdtemp()) / "cameras.json", ptx.FrameCamera.from_pixels(2904.0, (4000, 3000)))
        >>> {k: v.image_size for k, v in read_odm_cameras(path).items()}
        {'photax_camera': (4000, 3000)}
    """
    from .opensfm import _camera

    path = pathlib.Path(path)
    data = load_json(path, read_text(path, "camera file"))
    if not is_odm_cameras(data):
        raise file_error(
            path, None, "not an ODM cameras.json (an object of camera ids to objects with 'projection_type' expected)"
        )
    return {str(name): _camera(path, name, p) for name, p in data.items()}


def write_odm_cameras(path, cameras, *, inputs=()) -> pathlib.Path:
    """Write ``cameras`` (``{camera id: FrameCamera}``, or one camera, named
    ``"photax_camera"``) as ODM's ``cameras.json`` (``--cameras``);
    :func:`photax.io.read_odm_cameras` reads back the same cameras (in pixels).
    Written atomically; ``inputs`` may not be overwritten.

    Raises:
        ValueError: a camera OpenSfM cannot hold (:func:`photax.io.opensfm.camera_to_opensfm`).

    Examples:
        Cameras as ODM's ``cameras.json``, read back equal (in pixels):

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_odm_cameras, write_odm_cameras
        >>> cam = ptx.FrameCamera.from_pixels(2904.0, (4000, 3000), distortion=[-0.05, 0.01, 0.0, 0.0, 0.0])
        >>> path = write_odm_cameras(pathlib.Path(tempfile.mkdtemp()) / "cameras.json", {"dji": cam})
        >>> back = read_odm_cameras(path)["dji"]
        >>> bool(np.isclose(back.focal_length, 2904.0)), np.round(np.asarray(back.distortion), 6).tolist()[:2]
        (True, [-0.05, 0.01])
    """
    import json

    from .atomic import atomic_write
    from .opensfm import _opensfm_cameras

    data = _opensfm_cameras(cameras)
    with atomic_write(path, inputs=inputs) as fh:
        json.dump(data, fh, indent=4)
    return pathlib.Path(path)


def is_odm_cameras(data) -> bool:
    """Whether parsed JSON looks like ODM's ``cameras.json``."""
    return (
        isinstance(data, dict)
        and bool(data)
        and all(isinstance(v, dict) and "projection_type" in v for v in data.values())
    )


def read_odm_geo(path, crs=None) -> tuple[dict[str, np.ndarray], str | None, dict[str, tuple[float, float]]]:
    """ODM's ``geo.txt``: ``({image stem: (x, y, z)}, crs, {image stem: (horizontal,
    vertical accuracy)})``.

    Geographic coordinates (longitude, latitude) go to ``crs`` (a projected CRS)
    or, by default, the WGS84 UTM zone of their mean; projected ones stay in
    their CRS (moved to ``crs`` when given).  A missing ``geo_z`` is NaN (the
    position is 2-D: not for a GNSS-aided adjustment); accuracies are listed
    only for images that give both.  The positions can stand for the start
    positions and GNSS observations of ``photax bundle --position-sigma``.

    Raises:
        ValueError: naming the file and line: no CRS line, a CRS pyproj does not
            read, a line without a name and two numbers, a latitude out of
            range, a repeated image.

    Examples:
        Longitude, latitude and height, projected into the UTM zone of the points:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> from photax.io import read_odm_geo
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "geo.txt"
        >>> _ = path.write_text("EPSG:4326\\nIMG_1.JPG 15.0 37.0 450.0 0 0 0 2.5 5.0\\n")
        >>> positions, crs, accuracy = read_odm_geo(path)
        >>> crs, accuracy["IMG_1"]
        ('EPSG:32633', (2.5, 5.0))
        >>> from pyproj import Transformer  # the same point projected by PROJ
        >>> e, n = Transformer.from_crs("EPSG:4326", "EPSG:32633", always_xy=True).transform(15.0, 37.0)
        >>> bool(np.allclose(positions["IMG_1"], [e, n, 450.0]))
        True
    """
    from .gcp import _projected

    path = pathlib.Path(path)
    numbered = [(i + 1, t) for i, t in enumerate(split_lines(read_text(path, "ODM geo file")))]
    numbered = [(n, t) for n, t in numbered if t.strip() and not t.lstrip().startswith("#")]
    if not numbered:
        raise file_error(path, None, "empty: a CRS line, then 'image_name geo_x geo_y [geo_z] ...' lines expected")
    line0, crs_line = numbered[0]
    try:
        source = odm_crs_text(crs_line)
    except ValueError as exc:
        raise file_error(path, line0, str(exc)) from None
    names, xyz, lines, accuracy = [], [], [], {}
    for n, text in numbered[1:]:
        f = text.split()
        try:
            values = [float(v) for v in f[1:9]]
        except ValueError:
            bad = next(v for v in f[1:9] if not _is_float(v))
            if len(names) == 0 and len(f) < 3:
                raise file_error(path, n, "not an ODM geo.txt ('image_name geo_x geo_y [geo_z] ...' lines)") from None
            raise file_error(
                path, n, f"{excerpt(bad)} is not a number (columns: image_name geo_x geo_y [geo_z] ...)"
            ) from None
        if len(f) < 3:
            raise file_error(path, n, f"expected 'image_name geo_x geo_y [geo_z] ...', got {len(f)} column(s)")
        if not all(math.isfinite(v) for v in values):
            raise file_error(path, n, "a value is not finite")
        stem = pathlib.PurePath(f[0]).stem
        if not stem or stem in names:
            raise file_error(path, n, f"image {excerpt(f[0])} is empty or repeated")
        names.append(stem)
        xyz.append(values[:3] if len(values) >= 3 else [*values[:2], math.nan])
        lines.append(n)
        if len(values) >= 8:
            h, v = values[6], values[7]
            if not (h > 0 and v > 0):
                raise file_error(path, n, f"accuracies must be positive, got {h:g} and {v:g}")
            accuracy[stem] = (h, v)
    if not names:
        raise file_error(path, None, "no image positions after the CRS line")
    ground = np.asarray(xyz, dtype=float)
    try:
        out, crs_text = _projected(path, ground, source, crs, lines)
    except ValueError as exc:
        raise ValueError(str(exc) if str(path) in str(exc) else f"{path}: {exc}") from None
    if crs_text is not None and crs is None and _is_unreadable(crs_text):
        raise file_error(path, line0, f"{excerpt(crs_line)} is not a CRS (EPSG:4326, a PROJ string, WGS84 UTM 16N)")
    return dict(zip(names, out)), crs_text, accuracy


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _is_unreadable(text: str) -> bool:
    from .gcp import _parse_crs

    return _parse_crs(text) is None


def write_odm_geo(path, positions, crs, *, inputs=()) -> pathlib.Path:
    """Write ``positions`` (``{image name: (x, y[, z])}``, in ``crs``) as ODM's ``geo.txt``
    (``--geo``), atomically: the CRS line (``EPSG:<code>``, or the PROJ string of a CRS
    without one), then ``image_name geo_x geo_y [geo_z]``, 17 significant digits; for a
    geographic CRS ``x`` is the longitude.  A NaN height (a 2-D position, as
    :func:`read_odm_geo` reads one) is left out; angles and accuracies are not written
    (photax has no attitude of ODM's meaning, and no accuracy is invented).
    :func:`read_odm_geo` reads back the same positions (keyed by the names' stems;
    geographic ones projected to the UTM zone, or its ``crs=``).

    Raises:
        ValueError: no positions; a name that is empty, has spaces or repeats a
            stem; an x or y that is not finite, a height that is infinite; a CRS
            pyproj does not read, or one with neither an EPSG code nor a PROJ string.

    Examples:
        Positions in a projected CRS written as ODM's ``geo.txt`` and read back:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> from photax.io import read_odm_geo, write_odm_geo
        >>> positions = {"IMG_1": (512300.0, 4103800.0, 450.0), "IMG_2": (512400.5, 4103800.25, 451.0)}
        >>> path = write_odm_geo(pathlib.Path(tempfile.mkdtemp()) / "geo.txt", positions, "EPSG:32633")
        >>> back, crs, accuracy = read_odm_geo(path)
        >>> sorted(back), bool(np.allclose(back["IMG_2"], positions["IMG_2"])), accuracy
        (['IMG_1', 'IMG_2'], True, {})
    """
    from .atomic import atomic_write
    from .gcp import _parse_crs

    if not positions:
        raise ValueError("no positions to write")
    parsed = _parse_crs(str(crs)) if crs is not None else None
    if parsed is None:
        raise ValueError(f"crs {excerpt(crs)}: not a CRS pyproj reads (geo.txt's first line names it)")
    epsg = parsed.to_epsg()
    with warnings.catch_warnings():  # pyproj warns that PROJ strings lose some of a CRS: the line is all there is
        warnings.simplefilter("ignore")
        crs_line = f"EPSG:{epsg}" if epsg is not None else parsed.to_proj4()
    if not crs_line or "\n" in crs_line:
        raise ValueError(f"crs {excerpt(crs)}: has no EPSG code nor PROJ string for geo.txt's one line")
    lines, stems = [crs_line], set()
    for name, xyz in positions.items():
        name = str(name)
        stem = pathlib.PurePath(name).stem
        if not stem or any(c.isspace() for c in name) or name.startswith("#") or stem in stems:
            raise ValueError(f"image name {name!r}: empty, with spaces, starting with '#' or a repeated stem")
        stems.add(stem)
        v = np.asarray(xyz, dtype=float).ravel()
        if v.shape not in ((2,), (3,)) or not np.all(np.isfinite(v[:2])) or (len(v) == 3 and np.isinf(v[2])):
            raise ValueError(f"image {name!r}: position must be finite (x, y[, z]), got {v.tolist()}")
        keep = v[:2] if len(v) == 2 or np.isnan(v[2]) else v
        lines.append(" ".join([name, *(repr(float(c)) for c in keep)]))
    with atomic_write(path, inputs=inputs) as fh:
        fh.write("\n".join(lines) + "\n")
    return pathlib.Path(path)


def is_odm_geo(path) -> bool:
    """Whether ``path`` starts like ODM's ``geo.txt``: a CRS line, then ``image_name geo_x geo_y ...``
    (a name, not a number, first: ODM's ``gcp_list.txt`` starts its lines with coordinates)."""
    lines = [t for t in head_text(path, 4096).splitlines() if t.strip() and not t.lstrip().startswith("#")][:2]
    if len(lines) < 2:
        return False
    first, second = lines[0].strip(), lines[1].split()
    if not (first.upper().startswith(("EPSG:", "WGS84", "+PROJ")) and len(second) >= 3):
        return False
    return not _is_float(second[0]) and _is_float(second[1]) and _is_float(second[2])
