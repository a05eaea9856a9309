"""Orientation files whatever their format: the format is detected here.

* :func:`read_interior`: a photax camera file (:mod:`photax.io.camera_file`),
  an orthority interior YAML (:mod:`photax.io.orthority`) -- an orthority
  file has a ``type`` key, or maps camera names to mappings that each have one --
  or an OpenSfM/ODM ``reconstruction.json`` (:mod:`photax.io.opensfm`: a JSON list
  of objects with ``shots``), or ODM's ``cameras.json`` (:mod:`photax.io.odm`), or
  Pix4D's ``.cam`` (:mod:`photax.io.pix4d`: its pixel count from the
  ``calibrated_camera_parameters.txt`` beside it);
* :func:`read_exterior`: a ``photax resect --json`` result (``.json``), a
  ``reconstruction.json``, an orthority GeoJSON (``.geojson``) or an orthority
  exterior CSV (+ ``.prj`` beside it; or latitude, longitude, altitude, roll,
  pitch, yaw), or the word ``exif`` (``exif:gimbal``, ``exif:flight``: each image's
  own GPS and attitude tags, :mod:`photax.io.exif`), or ``grid:`` / ``topocentric:``
  before a ``reconstruction.json`` to name its frame (:func:`opensfm_frame`); :func:`read_exteriors` reads
  many images' orientations from one such file, parsing it once, and
  :func:`block_images` pairs them with the image files of a folder;
* :func:`read_camera_unit`: the length unit a photax camera file is written in.

The readers' contract holds (:mod:`photax.io`): a malformed file is a
``ValueError`` naming the file (and line where one applies).
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from .camera_file import _load as _load_camera_mapping
from .camera_file import read_camera
from .exif import read_exif_exteriors
from .files import MAX_BYTES, check_regular, excerpt, expect, file_error, load_json, load_yaml, opensfm_frame, read_text
from .odm import is_odm_cameras, read_odm_cameras
from .opensfm import is_reconstruction, read_opensfm_cameras, read_opensfm_shots
from .orthority import read_orthority_exterior_crs, read_orthority_geojson, read_orthority_interior
from .results import read_json


def _table(path: pathlib.Path, data=None, crs=None, frame=None) -> tuple[dict[str, ExteriorOrientation], str | None]:
    """``({stem: orientation}, crs)`` of a file holding a table of orientations: an
    OpenSfM/ODM ``reconstruction.json`` (its parsed JSON ``data``), an orthority
    GeoJSON or an orthority exterior CSV (any column layout); ``crs``: the
    projected CRS wanted of the formats whose positions are geographic or
    topocentric (reconstruction, latitude/longitude CSV), default their UTM zone."""
    if data is not None:  # JSON already parsed: a reconstruction
        table, out, _ = read_opensfm_shots(path, crs, frame)
        return _into_vertical_datum(table, out, crs)
    if frame is not None:
        raise ValueError(f"{frame}:{path}: '{frame}:' names the frame of a reconstruction.json, not of this file")
    if path.suffix.lower() == ".geojson":
        return read_orthority_geojson(path)
    from .metashape import is_opk_export, read_opk_export

    if is_opk_export(path):  # Metashape's Omega Phi Kappa export, Pix4D's external parameters: no CRS named
        return read_opk_export(path), None
    from .odm import is_odm_geo

    if is_odm_geo(path):
        raise file_error(
            path, None, "an ODM geo.txt holds positions, no attitude: not an exterior orientation "
            "(photax bundle --gnss takes it; photax.io.read_odm_geo reads it)"
        )  # fmt: skip
    from .colmap import is_colmap_file, read_colmap_exteriors

    if is_colmap_file(path, "images"):  # a (georeferenced) COLMAP model's poses: no CRS named
        return read_colmap_exteriors(path), None
    table, out = read_orthority_exterior_crs(path, crs)
    return _into_vertical_datum(table, out, crs) if _is_lla_csv(path) else (table, out)


def _is_lla_csv(path: pathlib.Path) -> bool:
    """An orthority CSV of latitude, longitude, altitude (ellipsoidal heights)."""
    for line in read_text(path, "orthority exterior file").splitlines():
        if line.strip() and not line.startswith("#"):
            return "latitude" in line.lower()
    return False


def _into_vertical_datum(table, table_crs, crs):
    """Positions whose heights are WGS84 ellipsoidal (GNSS, OpenSfM, drone tags), now in
    the horizontal ``table_crs``, with their heights moved into the vertical datum of
    ``crs`` when it has one (a DEM in ``EPSG:32735+5773``: :mod:`photax.io.crs`)."""
    from .crs import heights_from_ellipsoid, vertical_crs

    if crs is None or vertical_crs(crs) is None or not table:
        return table, table_crs
    import pyproj

    names = list(table)
    xyz = np.stack([np.asarray(table[n].position, dtype=float) for n in names])
    lon, lat = pyproj.Transformer.from_crs(table_crs, "EPSG:4326", always_xy=True).transform(xyz[:, 0], xyz[:, 1])
    xyz[:, 2] = heights_from_ellipsoid(lat, lon, xyz[:, 2], crs)
    out = {n: ExteriorOrientation(p, table[n].angles, table[n].convention) for n, p in zip(names, xyz)}
    return out, table_crs


def _is_orthority_interior(path: pathlib.Path) -> bool:
    try:
        data = load_yaml(path, read_text(path, "camera file"))
    except ValueError:  # not YAML: let read_camera report what is wrong
        return False
    if not isinstance(data, dict) or not data:
        return False
    # orthority's single-camera form has "type" at the top; a photax camera file never does.
    return "type" in data or all(isinstance(v, dict) and "type" in v for v in data.values())


def _is_reconstruction_file(path: pathlib.Path) -> bool:
    """An OpenSfM ``reconstruction.json`` given as a camera file: a JSON list, or a
    ``.json`` too large for a camera file (then read, and checked, as a reconstruction)."""
    if path.suffix.lower() != ".json":
        return False
    if check_regular(path, "camera file").st_size > MAX_BYTES["camera file"]:
        return True
    return is_reconstruction(read_json(path))


def _is_odm_cameras_file(path: pathlib.Path) -> bool:
    """ODM's ``cameras.json``: camera ids mapped to OpenSfM camera parameters."""
    if path.suffix.lower() != ".json":
        return False
    try:
        data = load_json(path, read_text(path, "camera file"))
    except ValueError:  # let read_camera report what is wrong
        return False
    return is_odm_cameras(data)


def read_interior(path, name: str | None = None) -> FrameCamera:
    """A :class:`photax.FrameCamera` from a photax camera file or an orthority interior YAML.

    Args:
        path: the file.
        name: the camera of a multi-camera orthority file (not needed when
            it holds one camera; ignored for a photax camera file).

    Raises:
        ValueError: a malformed file (naming file and line), or ``name``
            missing or unknown for a multi-camera file (listing the names).

    Examples:
        A camera from a photax camera file or an orthority interior file, told apart by content:

        >>> import pathlib, tempfile
        >>> from photax.io import read_interior
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> _ = (folder / "photax.yaml").write_text("focal_length_px: 500.0\\nimage_size: [1000, 750]\\n")
        >>> _ = (folder / "int_param.yaml").write_text(
        ...     "cam:\\n  type: pinhole\\n  im_size: [1000, 750]\\n  focal_len: 8.8\\n  sensor_size: [17.6, 13.2]\\n")
        >>> [read_interior(folder / f).image_size for f in ("photax.yaml", "int_param.yaml")]
        [(1000, 750), (1000, 750)]
    """
    path = pathlib.Path(path)
    from .colmap import is_colmap_file, read_colmap_cameras
    from .metashape import is_metashape_xml, read_metashape_calibration
    from .pix4d import image_size_beside, is_pix4d_cam, read_pix4d_cam

    if is_metashape_xml(path):
        cameras = read_metashape_calibration(path)
    elif is_pix4d_cam(path):
        size = image_size_beside(path)
        if size is None:
            raise file_error(
                path, None, "a Pix4D .cam does not give the image's size in pixels: keep the same run's "
                "<project>_calibrated_camera_parameters.txt beside it, or read it with "
                "photax.io.read_pix4d_cam(path, image_size)"
            )  # fmt: skip
        return read_pix4d_cam(path, size)
    elif is_colmap_file(path, "cameras"):
        cameras = read_colmap_cameras(path)
    elif _is_reconstruction_file(path):
        cameras = read_opensfm_cameras(path)
    elif _is_odm_cameras_file(path):
        cameras = read_odm_cameras(path)
    elif not _is_orthority_interior(path):
        return read_camera(path)
    else:
        cameras = read_orthority_interior(path)
    if name is None and len(cameras) == 1:
        return next(iter(cameras.values()))
    if name not in cameras:
        raise file_error(
            path, None, f"holds {len(cameras)} cameras: name one (--camera-name), one of {sorted(map(str, cameras))}"
        )
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
            raise ValueError(
                f"{path}: holds {len(images)} images {excerpt(sorted(images), 80)}, "
                "none named like "
                f"{p.name!r}; rename the image or keep only its result"
            )
        name, entry = matches[0], images[matches[0]]
    if not isinstance(entry, dict):
        raise ValueError(f"{path}: the result of image {excerpt(name)} is not an object")
    status = entry.get("status", "solved" if entry.get("converged", True) else "not converged")
    if status != "solved" or "skipped" in entry:
        why = entry.get("message") or entry.get("skipped") or status
        raise ValueError(f"{path}: image {excerpt(name)} was not solved ({why}); no orientation to use")
    return entry


def read_exterior(path, image, crs=None) -> tuple[ExteriorOrientation, str | None]:
    """``(ExteriorOrientation, crs or None)`` of ``image`` from a JSON or CSV file.

    A ``photax resect --json`` file (``.json``) holds ``images`` keyed by
    image name, a ``photax bundle --json`` file a list of named images with
    the angle convention beside it: with one image it is used whatever its
    name; with several, the one named like ``image`` (file name or stem); an
    image that was not solved, or any image of an adjustment that did not
    converge, is refused.  A ``reconstruction.json`` (a JSON list), a
    ``.geojson`` and any other file (an orthority exterior CSV) are read as
    tables of orientations and ``image``'s stem looked up in them.

    Args:
        path: the orientation file.
        image: the image's path or name.
        crs: the projected CRS (EPSG code, WKT, PROJ string; of a compound
            CRS its horizontal part) into which a reconstruction's or a
            latitude/longitude CSV's positions are converted (e.g. the DEM's);
            default their UTM zone.  Other formats name their own CRS.

    Raises:
        ValueError: naming the file: malformed, no (solved) orientation for
            ``image``, or several candidates.

    Examples:
        One image's orientation from a ``photax resect``/``bundle`` JSON result or an orthority file;
        here a JSON orientation as ``data/sample_truth.json`` holds it:

        >>> import json, pathlib, tempfile
        >>> import numpy as np
        >>> from photax.io import read_exterior
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "truth.json"
        >>> _ = path.write_text(json.dumps({"convention": "phi-omega-kappa", "position": [512308.0, 4103788.0, 450.0],
        ...                                 "angles_rad": [0.02, -0.01, 0.61], "crs": "EPSG:32633"}))
        >>> eo, crs = read_exterior(path, "IMG_0001.tif")
        >>> np.asarray(eo.position).tolist(), eo.convention
        ([512308.0, 4103788.0, 450.0], 'phi-omega-kappa')
    """
    if exif_attitude(path) is not None:  # the image's own GPS and attitude tags
        # heights as tagged: not moved into a vertical datum (their own datum is not known)
        table, out = read_exif_exteriors(image, exif_attitude(path), crs)
        return next(iter(table.values())), out
    frame, path = opensfm_frame(path)
    path = pathlib.Path(path)
    data = read_json(path) if path.suffix.lower() == ".json" else None
    if data is not None and not is_reconstruction(data):
        if frame is not None:
            raise ValueError(f"{frame}:{path}: '{frame}:' names the frame of a reconstruction.json, not of a result")
        return exterior_from_result(path, data, image)
    table, crs = _table(path, data, crs, frame)
    stem = pathlib.Path(image).stem
    if stem not in table:
        raise ValueError(f"{path}: no orientation for image {stem!r}")
    return table[stem], crs


def read_exteriors(path, names=None, crs=None) -> tuple[dict[str, ExteriorOrientation], str | None]:
    """``({name: ExteriorOrientation}, crs or None)`` from one orientation file, parsed once.

    Args:
        path: a ``photax resect --json`` or ``photax bundle --json`` result, or
            an orthority exterior CSV (the formats of :func:`read_exterior`).
        names: the images wanted (paths or names), each found as
            :func:`read_exterior` finds one; keys are the names as given, in
            their order.  ``None``: every image of the file, keyed by its
            name's stem.
        crs: as :func:`read_exterior`'s.

    Raises:
        ValueError: naming the file: malformed, no images, or no (solved)
            orientation for one of ``names``.

    Examples:
        Every image of an orientation file, parsed once (here orthority's CSV with a ``.prj``):

        >>> import pathlib, tempfile
        >>> from photax.io import read_exteriors
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> _ = (folder / "ext.csv").write_text("A.tif 100 200 300 0 0 0\\nB.tif 150 200 300 0 0 90\\n")
        >>> table, crs = read_exteriors(folder / "ext.csv")
        >>> sorted(table), crs
        (['A', 'B'], None)
    """
    if exif_attitude(path) is not None:  # each image's own tags, into one CRS
        if names is None:
            raise ValueError("--exterior exif reads the images' own tags: name the images")
        table, out = read_exif_exteriors(names, exif_attitude(path), crs)  # heights as tagged
        return dict(zip(names, table.values())), out
    frame, path = opensfm_frame(path)
    path = pathlib.Path(path)
    data = read_json(path) if path.suffix.lower() == ".json" else None
    if data is not None and not is_reconstruction(data):
        if frame is not None:
            raise ValueError(f"{frame}:{path}: '{frame}:' names the frame of a reconstruction.json, not of a result")
        if names is None:
            images = data.get("images") if isinstance(data, dict) else None
            if not isinstance(images, (list, dict)) or not images:
                raise ValueError(f"{path}: no 'images' (expected a photax bundle or resect --json result)")
            if isinstance(images, list):
                names = [e.get("name") if isinstance(e, dict) else None for e in images]
            else:
                names = list(images)
            if not all(isinstance(n, str) for n in names):
                raise ValueError(f"{path}: every image needs a 'name' (photax bundle --json)")
            table = {pathlib.Path(n).stem: exterior_from_result(path, data, n)[0] for n in names}
        else:
            table = {n: exterior_from_result(path, data, n)[0] for n in names}
        return table, _result_crs(path, data)
    rows, crs = _table(path, data, crs, frame)
    if names is None:
        if not rows:
            raise ValueError(f"{path}: no image orientations")
        return dict(rows), crs
    table = {}
    for n in names:
        stem = pathlib.Path(n).stem
        if stem not in rows:
            raise ValueError(f"{path}: no orientation for image {stem!r}")
        table[n] = rows[stem]
    return table, crs


def exif_attitude(path) -> str | None:
    """``"gimbal"`` or ``"flight"`` when ``path`` is the word ``exif`` (the camera's own,
    gimbal, angles), ``exif:gimbal`` or ``exif:flight``: the orientation is read from each
    image's tags (:mod:`photax.io.exif`); None for a file (``./exif`` for a file of that name)."""
    text = str(path) if isinstance(path, str) else None
    return {"exif": "gimbal", "exif:gimbal": "gimbal", "exif:flight": "flight"}.get(text)


def block_images(path, folder, crs=None) -> tuple[list[pathlib.Path], list[ExteriorOrientation], str | None]:
    """``(image files, exterior orientations, crs or None)`` of a block: every
    orientation of ``path`` (:func:`read_exteriors`) with the file of
    ``folder`` of the same stem; ``crs`` as :func:`read_exterior`'s.

    Raises:
        ValueError: naming the file: no orientations, or an image missing
            from ``folder``.

    Examples:
        Two orientations (a Metashape export) and a folder of images: each orientation gets the
        file of its stem, in the export's order; other files are ignored:

        >>> import pathlib, tempfile
        >>> import photax as ptx
        >>> from photax.io import block_images, write_opk_export
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> for name in ("IMG_2.tif", "IMG_1.tif", "notes.txt"):
        ...     _ = (folder / name).write_bytes(b"")
        >>> eo = {n: ptx.ExteriorOrientation([512300.0 + x, 4103800.0, 450.0], [0.0, 0.0, 0.0], "omega-phi-kappa")
        ...       for n, x in (("IMG_1", 0.0), ("IMG_2", 100.0))}
        >>> files, exteriors, crs = block_images(write_opk_export(eo, folder / "opk.txt"), folder)
        >>> [f.name for f in files], [float(e.position[0]) for e in exteriors], crs
        (['IMG_1.tif', 'IMG_2.tif'], [512300.0, 512400.0], None)
    """
    table, crs = read_exteriors(path, crs=crs)

    files = {p.stem: p for p in sorted(pathlib.Path(folder).iterdir()) if p.is_file()}
    missing = [n for n in table if n not in files]
    if missing:
        raise ValueError(f"{path}: no image in {folder} for {sorted(missing)}")
    return [files[n] for n in table], list(table.values()), crs


def _result_crs(path, data) -> str | None:
    """The ``crs`` of a photax result (text, or None when absent or null)."""
    crs = data.get("crs") if isinstance(data, dict) else None
    return expect(crs, ("text", "null"), "crs", path)


def exterior_from_result(path, data, image) -> tuple[ExteriorOrientation, str | None]:
    """:func:`read_exterior` of the already parsed JSON ``data`` of ``path`` (a
    caller reading many images of one file parses it once)."""
    crs = _result_crs(path, data)
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
        position, angles = (np.asarray(data[k], dtype=float) for k in ("position", "angles_rad"))
    except (KeyError, TypeError, AttributeError, ValueError, OverflowError):
        raise ValueError(f"{path}: expected 'position', 'angles_rad' and 'convention' (photax resect --json)") from None
    finite = np.isfinite(position).all() and np.isfinite(angles).all()
    if position.shape != (3,) or angles.shape != (3,) or not finite:
        raise ValueError(f"{path}: 'position' and 'angles_rad' must be 3 finite numbers each")
    try:
        return ExteriorOrientation(position, angles, convention), crs
    except ValueError as exc:  # an unknown convention
        raise ValueError(f"{path}: {exc}") from None


def read_camera_unit(path) -> str | None:
    """The length unit of a photax camera file: its ``unit:`` (``"mm"``, ``"m"``,
    ``"px"``), ``"px"`` for the ``focal_length_px`` shorthand and for an
    OpenSfM/ODM ``reconstruction.json`` (read in pixels); None if not given, as
    for an orthority interior file (its focal length and sensor size share a
    unit it does not name: :func:`camera_in_pixels`); ``"mm"`` for a Pix4D ``.cam``.

    Examples:
        The unit a camera file's lengths are in:

        >>> import pathlib, tempfile
        >>> from photax.io import read_camera_unit
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> _ = (folder / "mm.yaml").write_text("focal_length: 8.8\\nunit: mm\\npixel_size: 0.0176\\nimage_size: [1000, 750]\\n")
        >>> _ = (folder / "px.yaml").write_text("focal_length_px: 500.0\\nimage_size: [1000, 750]\\n")
        >>> read_camera_unit(folder / "mm.yaml"), read_camera_unit(folder / "px.yaml")
        ('mm', 'px')
    """
    path = pathlib.Path(path)
    from .colmap import is_colmap_file
    from .metashape import is_metashape_xml
    from .pix4d import is_pix4d_cam

    if is_pix4d_cam(path):  # F, Px, Py in mm
        return "mm"
    if (
        _is_reconstruction_file(path)
        or _is_odm_cameras_file(path)
        or is_metashape_xml(path)
        or is_colmap_file(path, "cameras")
    ):
        return "px"
    if _is_orthority_interior(path):
        return None
    data = _load_camera_mapping(path)
    return "px" if "focal_length_px" in data else data.get("unit")


def camera_in_pixels(camera: FrameCamera) -> FrameCamera:
    """``camera`` with the pixel as its length unit (focal length, principal point
    divided by the pixel size): the same geometry, for a file that must name its
    unit (a block) when the source names none (orthority's interior files).

    Raises:
        ValueError: no pixel grid, non-square pixels, or a scanned camera.
    """
    scanned = getattr(camera, "transform", None) is not None
    if camera.pixel_size is None or camera.image_size is None or scanned:
        raise ValueError("the camera has no pixel grid (or is a scan): give a photax camera file with a unit")
    sx, sy = (float(v) for v in np.asarray(camera.pixel_size))
    if not np.isclose(sx, sy, rtol=1e-12, atol=0):
        raise ValueError(
            f"the camera's pixels are not square ({sx:g} x {sy:g}): a block camera in pixels "
            "needs square pixels; give a photax camera file with unit mm or m"
        )
    return FrameCamera(
        camera.focal_length / sx,
        camera.principal_point / sx,
        camera.distortion,
        pixel_size=1.0,
        image_size=camera.image_size,
        model=camera.model,
    )
