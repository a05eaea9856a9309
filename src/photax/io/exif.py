"""A drone image's own position and attitude: EXIF GPS and DJI's XMP tags.

Read through rasterio (GDAL: its JPEG and GTiff drivers expose EXIF as
``EXIF_*`` metadata and XMP in the ``xml:XMP`` domain, as orthority reads them),
so no further dependency: Pillow's ``getxmp`` fails on the XMP packets GDAL
writes into TIFFs (``xml:XMP=<?xpacket ...``), and ``exifread`` would add a
package for what GDAL already decodes.

Tags read (:class:`DroneTags`): EXIF ``GPSLatitude``/``GPSLongitude``/
``GPSAltitude`` (+ refs), ``FocalLength``, ``FocalLengthIn35mmFilm``, ``Make``,
``Model``; DJI XMP (``drone-dji:``) ``GpsLatitude``, ``GpsLongtitude`` (sic; or
``GpsLongitude``), ``AbsoluteAltitude``, ``RelativeAltitude``,
``GimbalRoll/Pitch/YawDegree``, ``FlightRoll/Pitch/YawDegree``, ``RtkFlag``,
``RtkStdLon/Lat/Hgt``, ``CalibratedFocalLength``,
``CalibratedOpticalCenterX/Y``.

**Attitudes are named, never guessed** (:func:`exterior_from_tags`):

* ``"gimbal"``: DJI's gimbal angles, the camera's own attitude in the local
  north-east-down frame (yaw from true north; pitch -90 looks straight down;
  roll about the optical axis).  Used as the rotation of the gimbal frame
  (x along the optical axis, y right, z down in the image), not as a body
  attitude with 90 degrees added to the pitch (orthority's way, the same
  when the roll is 0): a nadir frame tagged roll +-180 (gimbal lock at pitch
  -90) stays a nadir frame (orthority #36: it looked up).
* ``"flight"``: the airframe's attitude, for a camera fixed to it looking down
  with its top to the front (a fixed-wing camera; on a gimbal the flight
  angles say nothing about the camera: ODM #1406, #1974).

Positions: WGS84 latitude, longitude into a projected CRS (the UTM zone of
the images by default), with the meridian convergence
(:func:`photax.io.orthority.lla_rpy_to_xyz_opk`).  Heights are taken as tagged
(``AbsoluteAltitude``, else EXIF ``GPSAltitude``): EXIF defines the latter
above sea level, DJI does not document the former's datum; neither is the
ellipsoidal height a GNSS solution gives, so they are not moved into a DEM's
vertical datum (:func:`photax.io.crs.heights_from_ellipsoid` does that for
ellipsoidal heights): check them against the DEM.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import re

import numpy as np

from ..collinearity import ExteriorOrientation
from ..errors import UnsupportedFormatError
from .files import check_regular

_DJI = "{http://www.dji.com/drone-dji/1.0/}"
ATTITUDES = ("gimbal", "flight")

#: Rotation from the camera frame (x right, y up, z back) to DJI's gimbal frame
#: (x along the optical axis, y right, z down in the image).
GIMBAL_FROM_CAMERA = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclasses.dataclass(frozen=True)
class DroneTags:
    """What an image says of where it was taken (None: not tagged).

    Attributes:
        path: the image.
        image_size: ``(width, height)`` of the raster, pixels.
        make, model: EXIF camera make and model.
        latitude, longitude: WGS84 degrees (DJI XMP, else EXIF GPS).
        altitude: metres, as tagged (XMP ``AbsoluteAltitude``, else EXIF
            ``GPSAltitude``, above sea level by EXIF's definition).
        relative_altitude: DJI's height above the take-off point, metres.
        gimbal_rpy, flight_rpy: roll, pitch, yaw in degrees (DJI's gimbal and
            airframe attitudes, north-east-down).
        rtk_flag: DJI's ``RtkFlag`` (50: RTK fixed, 34: float, 16: single
            point, 0: none), rtk_std: its ``(lon, lat, height)`` standard
            deviations in metres.
        focal_length_mm, focal_length_35mm: EXIF focal length and 35 mm
            equivalent.
        calibrated_focal_px, calibrated_centre_px: DJI's
            ``CalibratedFocalLength`` and ``CalibratedOpticalCenterX/Y``, pixels.
        dewarp: DJI's ``DewarpData`` (fx, fy, cx, cy offsets from the centre, in
            pixels of the tagged size, then k1, k2, p1, p2, k3).
        tag_image_size: EXIF ``PixelXDimension``, ``PixelYDimension`` (the size
            the camera wrote; the raster may be a reduced copy).
        sensor_size_mm: from EXIF ``FocalPlaneX/YResolution`` and its unit.

    Examples:
        Tags as :func:`read_drone_tags` returns them, or made by hand to try the orientation and
        camera they give:

        >>> import pathlib
        >>> from photax.io import DroneTags
        >>> tags = DroneTags(pathlib.Path("DJI_0001.JPG"), (4000, 3000), make="DJI", latitude=45.0, longitude=9.0,
        ...                  altitude=250.0, gimbal_rpy=(0.0, -90.0, 0.0))
        >>> tags.path.stem, tags.gimbal_rpy[1], tags.flight_rpy  # pitch -90: the gimbal looks straight down
        ('DJI_0001', -90.0, None)
    """

    path: pathlib.Path
    image_size: tuple[int, int]
    make: str | None = None
    model: str | None = None
    latitude: float | None = None
    longitude: float | None = None
    altitude: float | None = None
    relative_altitude: float | None = None
    gimbal_rpy: tuple[float, float, float] | None = None
    flight_rpy: tuple[float, float, float] | None = None
    rtk_flag: int | None = None
    rtk_std: tuple[float, float, float] | None = None
    focal_length_mm: float | None = None
    focal_length_35mm: float | None = None
    calibrated_focal_px: float | None = None
    calibrated_centre_px: tuple[float, float] | None = None
    dewarp: tuple[float, ...] | None = None
    tag_image_size: tuple[int, int] | None = None
    sensor_size_mm: tuple[float, float] | None = None


def _numbers(text) -> list[float] | None:
    """GDAL's EXIF rationals ``"(24) (40) (49.0009)"`` or a plain number."""
    if text is None:
        return None
    try:
        values = [float(v) for v in re.findall(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", str(text))]
    except ValueError:
        return None
    return values if values and all(math.isfinite(v) for v in values) else None


def _xmp(path, packet: str) -> dict[str, str]:
    """The DJI XMP attributes and elements of ``packet``: ``{name: text}``."""
    from xml.etree import ElementTree

    start, end = packet.find("<x:xmpmeta"), packet.rfind("</x:xmpmeta>")
    if start < 0 or end < 0:
        return {}
    try:
        root = ElementTree.fromstring(packet[start : end + len("</x:xmpmeta>")])
    except ElementTree.ParseError as exc:
        raise ValueError(f"{path}: its XMP packet is not well-formed XML ({exc})") from None
    out = {}
    for element in root.iter():
        for key, value in element.attrib.items():
            if key.startswith(_DJI):
                out[key[len(_DJI) :]] = value
        if element.tag.startswith(_DJI) and element.text is not None:
            out[element.tag[len(_DJI) :]] = element.text
    return out


def read_drone_tags(path) -> DroneTags:
    """:class:`DroneTags` of a JPEG or TIFF (any raster GDAL reads).

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file: not a raster, or a tag present but
            malformed (a latitude out of range, an XMP packet that is not XML,
            an angle that is not a number).

    Examples:
        A small GeoTIFF given EXIF GPS tags (45 deg 30 min N, 9 deg E, 250 m) and a 35 mm
        equivalent focal length, as GDAL names them:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import rasterio
        >>> from photax.io import read_drone_tags
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "IMG_1.tif"
        >>> with rasterio.open(path, "w", driver="GTiff", width=40, height=30, count=1, dtype="uint8",
        ...                    transform=rasterio.Affine(1.0, 0.0, 0.0, 0.0, -1.0, 30.0)) as ds:
        ...     ds.write(np.zeros((1, 30, 40), np.uint8))
        ...     ds.update_tags(EXIF_GPSLatitude="(45) (30) (0)", EXIF_GPSLatitudeRef="N",
        ...                    EXIF_GPSLongitude="(9) (0) (0)", EXIF_GPSLongitudeRef="E",
        ...                    EXIF_GPSAltitude="(250)", EXIF_FocalLengthIn35mmFilm="(24)")
        >>> tags = read_drone_tags(path)
        >>> tags.image_size, tags.latitude, tags.longitude, tags.altitude, tags.focal_length_35mm, tags.gimbal_rpy
        ((40, 30), 45.5, 9.0, 250.0, 24.0, None)
    """
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioIOError

    path = pathlib.Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no such image: {path}")
    check_regular(path, "image")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                exif = dict(ds.tags()) or dict(ds.tags(ns="EXIF"))
                xmp_text = ds.tags(ns="xml:XMP").get("xml:XMP", "")
                size = (int(ds.width), int(ds.height))
    except RasterioIOError as exc:
        raise UnsupportedFormatError(f"{path}: not an image GDAL reads ({' '.join(str(exc).split())[:120]})") from None
    xmp = _xmp(path, xmp_text) if xmp_text else {}

    def one(value, key, lo=-math.inf, hi=math.inf):
        if value is None:
            return None
        v = _numbers(value)
        if v is None or len(v) != 1 or not lo <= v[0] <= hi:
            raise ValueError(f"{path}: tag {key} = {str(value)[:40]!r} is not a number in [{lo}, {hi}]")
        return v[0]

    def triple(prefix, suffix):
        keys = [f"{prefix}{a}{suffix}" for a in ("Roll", "Pitch", "Yaw")]
        if not all(k in xmp for k in keys):
            return None
        return tuple(one(xmp[k], k, -360.0, 360.0) for k in keys)

    lat = one(xmp.get("GpsLatitude"), "GpsLatitude", -90, 90)
    lon_key = "GpsLongtitude" if "GpsLongtitude" in xmp else "GpsLongitude"  # DJI spells it both ways
    lon = one(xmp.get(lon_key), lon_key, -180, 360)
    alt = one(xmp.get("AbsoluteAltitude"), "AbsoluteAltitude", -1e5, 1e5)
    if lat is None or lon is None:
        lat, lon = _exif_degrees(path, exif, "Latitude", "NS", 90), _exif_degrees(path, exif, "Longitude", "EW", 180)
    if alt is None and "EXIF_GPSAltitude" in exif:
        alt = one(exif["EXIF_GPSAltitude"], "GPSAltitude", 0, 1e5)
        ref = str(exif.get("EXIF_GPSAltitudeRef", "0")).strip()
        try:
            below = int(ref, 0) == 1  # GDAL writes the byte as "0x01"
        except ValueError:
            raise ValueError(f"{path}: EXIF GPSAltitudeRef {ref[:20]!r} is not 0 or 1") from None
        alt = -alt if below else alt
    std = [one(xmp.get(f"RtkStd{k}"), f"RtkStd{k}", 0, 1e6) for k in ("Lon", "Lat", "Hgt")]
    centre = [one(xmp.get(f"CalibratedOpticalCenter{k}"), k, -1e6, 1e6) for k in "XY"]
    rtk = one(xmp.get("RtkFlag"), "RtkFlag", 0, 1e6)
    tw = one(exif.get("EXIF_PixelXDimension"), "PixelXDimension", 1, 2**31 - 1)
    th = one(exif.get("EXIF_PixelYDimension"), "PixelYDimension", 1, 2**31 - 1)
    tag_size = (int(tw), int(th)) if tw is not None and th is not None else None
    return DroneTags(
        path=path,
        image_size=size,
        make=exif.get("EXIF_Make") or None,
        model=exif.get("EXIF_Model") or None,
        latitude=lat,
        longitude=lon,
        altitude=alt,
        relative_altitude=one(xmp.get("RelativeAltitude"), "RelativeAltitude", -1e5, 1e5),
        gimbal_rpy=triple("Gimbal", "Degree"),
        flight_rpy=triple("Flight", "Degree"),
        rtk_flag=None if rtk is None else int(rtk),
        rtk_std=tuple(std) if None not in std else None,
        focal_length_mm=one(exif.get("EXIF_FocalLength"), "FocalLength", 0, 1e5),
        focal_length_35mm=one(exif.get("EXIF_FocalLengthIn35mmFilm"), "FocalLengthIn35mmFilm", 0, 1e5),
        calibrated_focal_px=one(xmp.get("CalibratedFocalLength"), "CalibratedFocalLength", 0, 1e7),
        calibrated_centre_px=tuple(centre) if None not in centre else None,
        dewarp=_dewarp(xmp.get("DewarpData")),
        tag_image_size=tag_size,
        sensor_size_mm=_sensor_size(exif, tag_size),
    )


def _dewarp(text) -> tuple[float, ...] | None:
    if text is None:
        return None
    values = _numbers(str(text).split(";")[-1])
    if values is None or len(values) != 9 or not any(values) or not (values[0] > 0 and values[1] > 0):
        return None  # as orthority: uninterpretable dewarp data is not used
    return tuple(values)


def _sensor_size(exif, tag_size) -> tuple[float, float] | None:
    unit = _numbers(exif.get("EXIF_FocalPlaneResolutionUnit"))
    mm = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}.get(int(unit[0]) if unit and abs(unit[0]) < 10 else 0)
    res = [_numbers(exif.get(f"EXIF_FocalPlane{a}Resolution")) for a in "XY"]
    if mm is None or tag_size is None or None in res or not all(len(r) == 1 and r[0] > 0 for r in res):
        return None
    return (mm * tag_size[0] / res[0][0], mm * tag_size[1] / res[1][0])


def _exif_degrees(path, exif, what, refs, limit) -> float | None:
    value, ref = exif.get(f"EXIF_GPS{what}"), exif.get(f"EXIF_GPS{what}Ref")
    if value is None or ref is None:
        return None
    dms = _numbers(value)
    ref = str(ref).strip().upper()[:1]
    if dms is None or not 1 <= len(dms) <= 3 or ref not in refs:
        raise ValueError(f"{path}: EXIF GPS{what} {str(value)[:40]!r} {ref!r} is not degrees, minutes, seconds")
    degrees = sum(v / 60.0**k for k, v in enumerate(dms)) * (1 if ref == refs[0] else -1)
    if abs(degrees) > limit:
        raise ValueError(f"{path}: EXIF GPS{what} {degrees:g} is out of range")
    return degrees


def exterior_from_tags(tags, attitude: str = "gimbal", crs=None) -> tuple[dict[str, ExteriorOrientation], str]:
    """``({image stem: ExteriorOrientation}, crs)`` of one or several images' tags.

    Args:
        tags: a :class:`DroneTags` or a list of them.
        attitude: ``"gimbal"`` (the camera's own angles) or ``"flight"`` (a
            camera fixed to the airframe looking down, top to the front): see
            the module docstring.  An image without the named angles is
            refused: the other is never used in its place.
        crs: the projected CRS of the positions (of a compound CRS its
            horizontal part); default the WGS84 UTM zone of the mean position.

    Raises:
        ValueError: naming the image: no position or no such attitude tagged.

    Examples:
        A nadir image (gimbal pitch -90 deg, yaw 0: north up) at 9 E, 45 N, 250 m: in its UTM zone
        (32, whose central meridian is 9 E) at E 500 000, looking straight down:

        >>> import pathlib
        >>> import numpy as np
        >>> from photax.io import DroneTags, exterior_from_tags
        >>> tags = DroneTags(pathlib.Path("DJI_0001.JPG"), (4000, 3000), latitude=45.0, longitude=9.0, altitude=250.0,
        ...                  gimbal_rpy=(0.0, -90.0, 0.0))
        >>> exteriors, crs = exterior_from_tags(tags)
        >>> crs, np.round(np.asarray(exteriors["DJI_0001"].position), 2).tolist()
        ('EPSG:32632', [500000.0, 4982950.4, 250.0])
        >>> bool(np.allclose(exteriors["DJI_0001"].angles, 0.0, atol=1e-9))
        True
    """
    from ..geo import utm_crs
    from ._geo import projected_crs
    from .orthority import BODY_FROM_CAMERA, lla_rpy_to_xyz_opk

    if attitude not in ATTITUDES:
        raise ValueError(f"attitude must be one of {ATTITUDES} (named, never guessed), got {attitude!r}")
    tags = [tags] if isinstance(tags, DroneTags) else list(tags)
    if not tags:
        raise ValueError("no images")
    lla, rpy = [], []
    for t in tags:
        if t.latitude is None or t.longitude is None or t.altitude is None:
            raise ValueError(f"{t.path}: no GPS latitude, longitude and altitude tags (EXIF or DJI XMP)")
        angles = t.gimbal_rpy if attitude == "gimbal" else t.flight_rpy
        if angles is None:
            other = "flight" if attitude == "gimbal" else "gimbal"
            has = (t.flight_rpy if attitude == "gimbal" else t.gimbal_rpy) is not None
            raise ValueError(
                f"{t.path}: no DJI {attitude} roll/pitch/yaw tags"
                + (f" (it has {other} angles: name them if they are the camera's)" if has else "")
            )
        lla.append((t.latitude, t.longitude, t.altitude))
        rpy.append(angles)
    lla, rpy = np.asarray(lla, dtype=float), np.radians(np.asarray(rpy, dtype=float))
    target = (
        projected_crs(crs) if crs is not None else projected_crs(utm_crs(lon=lla[:, 1].mean(), lat=lla[:, 0].mean()))
    )
    mount = GIMBAL_FROM_CAMERA if attitude == "gimbal" else BODY_FROM_CAMERA
    try:
        xyz, opk = lla_rpy_to_xyz_opk(lla, rpy, target, body_from_camera=mount)
    except ValueError as exc:
        raise ValueError(
            f"{', '.join(str(t.path) for t in tags[:3])}{' ...' if len(tags) > 3 else ''}: {exc}"
        ) from None
    names = [t.path.stem for t in tags]
    if len(set(names)) != len(names):
        raise ValueError(f"images of the same name: {sorted(n for n in names if names.count(n) > 1)}")
    code = target.to_epsg()
    crs_text = f"EPSG:{code}" if code is not None else target.to_wkt()
    return {n: ExteriorOrientation(p, a, "omega-phi-kappa") for n, p, a in zip(names, xyz, opk)}, crs_text


def read_exif_exteriors(images, attitude: str = "gimbal", crs=None) -> tuple[dict[str, ExteriorOrientation], str]:
    """:func:`exterior_from_tags` of the images' own tags (:func:`read_drone_tags`)."""
    images = [images] if isinstance(images, (str, pathlib.PurePath)) else list(images)
    return exterior_from_tags([read_drone_tags(p) for p in images], attitude, crs)


def camera_from_tags(tags: DroneTags):
    """A :class:`photax.FrameCamera` from an image's tags, as orthority builds it: DJI's
    ``DewarpData`` as a ``brown`` camera (focal lengths and principal point offsets in
    pixels of the tagged size, scaled to the raster's), else a ``pinhole`` from EXIF
    ``FocalLength`` and the sensor size, else from the 35 mm equivalent (36 mm across
    the larger side).  In the focal length's unit (pixels of the tagged size for
    DewarpData).  A first camera to look with: a calibration does better.

    Raises:
        ValueError: naming the image: none of these tags, or values that make no camera.

    Examples:
        An 8.8 mm lens on a 13.2 mm wide sensor of 4000 px: pixels of 13.2 / 4000 = 0.0033 mm; or
        from the 35 mm equivalent alone, ``24 / 36`` of the larger side, in pixels:

        >>> import pathlib
        >>> from photax.io import DroneTags, camera_from_tags
        >>> tags = DroneTags(pathlib.Path("a.jpg"), (4000, 3000), focal_length_mm=8.8, sensor_size_mm=(13.2, 9.9))
        >>> c = camera_from_tags(tags)
        >>> float(c.focal_length), [round(float(p), 9) for p in c.pixel_size], c.image_size
        (8.8, [0.0033, 0.0033], (4000, 3000))
        >>> equivalent = DroneTags(pathlib.Path("b.jpg"), (4000, 3000), focal_length_35mm=24.0)
        >>> round(float(camera_from_tags(equivalent).focal_length), 6)
        2666.666667
    """

    from .orthority import _camera_from_params

    w, h = tags.image_size
    if tags.dewarp is not None and tags.tag_image_size is not None:
        d, (tw, th) = tags.dewarp, tags.tag_image_size
        p = dict(type="brown", im_size=[w, h], focal_len=list(d[:2]), sensor_size=[float(tw), float(th)])
        p.update(cx=d[2] / max(tw, th), cy=d[3] / max(tw, th), k1=d[4], k2=d[5], p1=d[6], p2=d[7], k3=d[8])
    elif tags.focal_length_mm and tags.sensor_size_mm:
        p = dict(type="pinhole", im_size=[w, h], focal_len=tags.focal_length_mm, sensor_size=list(tags.sensor_size_mm))
    elif tags.focal_length_35mm:
        p = dict(type="pinhole", im_size=[w, h], focal_len=tags.focal_length_35mm / 36.0)
        if tags.sensor_size_mm:
            p.update(focal_len=max(tags.sensor_size_mm) * tags.focal_length_35mm / 36.0)
            p.update(sensor_size=list(tags.sensor_size_mm))
    else:
        raise ValueError(
            f"{tags.path}: no DJI DewarpData, EXIF focal length and sensor size, or 35 mm equivalent focal length"
        )
    try:
        return _camera_from_params(tags.path, None, p)
    except ValueError as exc:
        raise ValueError(f"{tags.path}: the tags make no camera ({exc})") from None
