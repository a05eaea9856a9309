"""LAS 1.4 / LAZ files of point clouds, through laspy (the ``las`` extra: ``pip install "photax[las]"``).

The layout (what :meth:`photax.stereo.PointCloud.write_las` writes and :func:`photax.stereo.read_las`
reads; ASPRS LAS 1.4 R15):

* point data record format 7 (x y z, GPS time, RGB) for a coloured cloud, 6 without colour;
* x, y, z as 32-bit integers ``X = round((x - offset) / scale)``: scale 1/1000 of the CRS's unit
  (1 mm in metres; a geographic CRS: 1e-8 degree, about 1.1 mm) and 0.001 for z; offset the
  cloud's minimum rounded down to a whole unit (a multiple of the scale), so a decoded coordinate is
  within half a scale step of the point's (:data:`SCALE`);
* the CRS as an OGC coordinate system WKT VLR (``LASF_Projection`` 2112, the header's WKT bit set):
  WKT1 (OGC 01-009, what the specification names; GDAL's flavour), WKT2 2019 for a CRS that WKT1
  cannot express (a 3-D geographic CRS);
* RGB as 16 bits, ``c * 257`` (255 -> 65535, the full scale the specification asks; ``>> 8``
  gives the 8-bit value back);
* the photax extras as extra bytes dimensions (float32, named, described):
  :data:`EXTRA_DIMS`.

``.laz`` is compressed (laspy's LAZ backend, lazrs), any other suffix uncompressed.
"""

from __future__ import annotations

import math
import pathlib

import numpy as np

#: ``(x/y scale in a projected CRS's unit, x/y scale in degrees, z scale)``.
SCALE = (1e-3, 1e-8, 1e-3)
#: The extra bytes dimensions: ``(name, description)`` (float32; descriptions at most 32 bytes).
EXTRA_DIMS = (
    ("residual", "intersection residual, RMS (px)"),
    ("sigma_z", "height standard deviation (m)"),
)
_INT32 = 2**31 - 1


def laspy():
    """laspy, or ``ModuleNotFoundError`` naming the extra to install."""
    try:
        import laspy
    except ModuleNotFoundError as exc:
        raise ModuleNotFoundError(
            'LAS / LAZ point clouds need laspy (and lazrs for .laz), in the las extra: pip install "photax[las]"',
            name="laspy",
        ) from exc
    return laspy


def _laz_backend(lp):
    backends = lp.LazBackend.detect_available()
    if not backends:
        raise ModuleNotFoundError(
            'LAZ (compressed) point clouds need lazrs, in the las extra: pip install "photax[las]"', name="lazrs"
        )
    return backends[0]


def _pyproj_crs(crs):
    import pyproj

    from ..errors import CRSMismatchError

    try:
        return pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError as exc:
        raise CRSMismatchError(f"the point cloud's CRS {crs!r} is not one pyproj reads ({exc})") from exc


def _wkt(crs) -> str:
    """OGC WKT1 (GDAL's), or WKT2 2019 where WKT1 cannot express the CRS."""
    import pyproj

    try:
        wkt = crs.to_wkt("WKT1_GDAL")
    except pyproj.exceptions.CRSError:
        wkt = None
    return wkt or crs.to_wkt("WKT2_2019")


def scales_offsets(xyz: np.ndarray, crs) -> tuple[np.ndarray, np.ndarray]:
    """The LAS scales and offsets of ``(n, 3)`` points in ``crs`` (module docstring's rule)."""
    geographic = crs is not None and _pyproj_crs(crs).is_geographic
    scale = np.array([SCALE[1] if geographic else SCALE[0]] * 2 + [SCALE[2]])
    offset = np.floor(xyz.min(axis=0))
    span = (xyz.max(axis=0) - offset) / scale
    if np.any(span > _INT32):
        axis = "xyz"[int(np.argmax(span > _INT32))]
        extent = float(xyz[:, "xyz".index(axis)].max() - xyz[:, "xyz".index(axis)].min())
        raise ValueError(
            f"the points span {extent:.6g} units in {axis}: more than LAS's 32-bit integers hold at a scale of "
            f"{scale['xyz'.index(axis)]:g} (write a part of the cloud, or a PLY)"
        )
    return scale, offset


def write_las(path, xyz, residual, sigma_z, colour, crs, inputs=()) -> pathlib.Path:
    """Write the arrays of a point cloud as LAS 1.4 (``.laz``: LAZ), atomically."""
    from ..io.atomic import atomic_write

    path = pathlib.Path(path)
    n = len(xyz)
    if n == 0:
        raise ValueError(f"refusing to write {path}: the point cloud has no points")
    lp = laspy()
    compress = path.suffix.lower() == ".laz"
    backend = _laz_backend(lp) if compress else None
    bad = ~np.isfinite(xyz).all(axis=1)
    if bad.any():
        raise ValueError(f"refusing to write {path}: {int(bad.sum())} of {n} points have a coordinate not finite")
    header = lp.LasHeader(point_format=6 if colour is None else 7, version="1.4")
    header.scales, header.offsets = scales_offsets(xyz, crs)
    header.generating_software = "photax"
    header.system_identifier = "EXTRACTION"  # the specification's word for points not from a lidar
    header.add_extra_dims([lp.ExtraBytesParams(name, np.float32, description=d) for name, d in EXTRA_DIMS])
    if crs is not None:
        header.vlrs.append(lp.vlrs.known.WktCoordinateSystemVlr(_wkt(_pyproj_crs(crs))))
        header.global_encoding.wkt = True
    las = lp.LasData(header)
    las.x, las.y, las.z = xyz.T  # laspy stores round((x - offset) / scale)
    if colour is not None:
        rgb = np.asarray(colour, dtype=np.uint16) * np.uint16(257)
        las.red, las.green, las.blue = rgb.T
    las.residual, las.sigma_z = np.float32(residual), np.float32(sigma_z)
    with atomic_write(path, "wb", inputs) as f:
        las.write(f, do_compress=compress, laz_backend=backend)
    return path


def read_las(path) -> dict:
    """``{"xyz", "residual", "sigma_z", "colour", "crs"}`` of a LAS / LAZ file (any writer's: extras
    missing are NaN, colour None without RGB, crs None without a CRS VLR)."""
    from ..errors import MalformedFileError, UnreadableFileError

    lp = laspy()
    path = pathlib.Path(path)
    try:
        las = lp.read(path)
    except FileNotFoundError as exc:
        raise UnreadableFileError(f"{path}: no such file") from exc
    except lp.errors.LaspyException as exc:
        raise MalformedFileError(f"{path}: not a LAS / LAZ file laspy reads ({exc})") from exc
    n = len(las.points)
    xyz = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)]).astype(np.float64)
    names = set(las.point_format.dimension_names)
    extras = {
        name: np.asarray(las[name], dtype=np.float64) if name in names else np.full(n, math.nan)
        for name, _ in EXTRA_DIMS
    }
    colour = None
    if {"red", "green", "blue"} <= names:
        colour = (np.column_stack([las.red, las.green, las.blue]) >> 8).astype(np.uint8)
    crs = None
    try:
        parsed = las.header.parse_crs()
    except Exception as exc:  # pyproj's CRSError of a WKT it cannot read
        raise MalformedFileError(f"{path}: its CRS VLR cannot be read ({exc})") from exc
    if parsed is not None:
        epsg = parsed.to_epsg()
        crs = f"EPSG:{epsg}" if epsg and _pyproj_crs(f"EPSG:{epsg}").equals(parsed) else parsed.to_wkt()
    return {"xyz": xyz, **extras, "colour": colour, "crs": crs}
