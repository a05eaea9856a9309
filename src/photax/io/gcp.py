"""Ground control point files: a CSV with a header, OpenDroneMap's ``gcp_list.txt``,
QGIS ``.points``, GeoJSON.

Each gives, per measurement, a point name, the image it is measured in, its
ground coordinates and its image coordinates.  They are read into a
:class:`GCPTable`; ``table.select(image).image_plane(camera)`` gives what
:func:`photax.resect` wants.

**CSV** (comma-separated, one header line; blank lines and lines starting with
``#`` are skipped, except that a comment ``# crs: EPSG:32633`` gives the CRS).  Columns are found by name, case-insensitively:

=============== ================================================================
column          accepted names
=============== ================================================================
point name      ``name`` (optional: default ``gcp1, gcp2, ...`` by ground point)
image           ``image`` (optional: ``""`` for a single-image file)
ground          ``E``/``easting``/``X``, ``N``/``northing``/``Y``, ``h``/``height``/``Z``
pixel           ``col``/``column`` and ``row`` (photax pixels, see below)
image plane     ``x`` and ``y`` (or ``image_x``, ``image_y``), camera units, y up
a-priori sigma  ``sigma`` (optional; same unit as the image measurements)
role            ``role`` (optional): ``control`` (default) or ``check``
=============== ================================================================

``x``/``y`` are ambiguous: when both ``X`` and ``x`` are present the upper-case
one is the ground coordinate; a lone ``x`` is the ground easting unless the
file names its easting ``E``/``easting``, in which case it is image-plane.
A file gives pixels *or* image-plane coordinates, not both.  Unknown columns
are an error (a misspelt ``sigma`` must not be silently ignored).

**OpenDroneMap** ``gcp_list.txt``: the first line is the CRS (``EPSG:32722``
or a PROJ string), then one measurement per line, whitespace-separated::

    E N h col row image [name] [extra ...]

ODM's pixel coordinates are OpenSfM's, whose ``normalized_image_coordinates``
adds 0.5 to them: integer values are pixel *centres*, row down, exactly the
photax pixel convention (``docs/conventions.md``), so the numbers are kept as
they are.  Extra columns after the name are ignored, as ODM does.

Malformed lines (wrong number of columns, non-numeric or non-finite values,
an unknown role) raise ``ValueError`` naming the file and the line number.
**QGIS Georeferencer** ``.points``: an optional ``#CRS: <WKT>`` line (QGIS 3.26+),
then the header ``mapX,mapY,sourceX,sourceY,enable[,dX,dY,residual]``.  QGIS gives
a pixel position of an ungeoreferenced raster as ``(column, -row)`` with the
origin at the *corner* of the first pixel (GDAL's pixel/line convention), so
``col = sourceX - 0.5`` and ``row = -sourceY - 0.5`` in photax's centre
convention; a positive ``sourceY`` (a georeferenced source raster, map units) is
refused.  The points are 2-D: heights are NaN (enough for ``photax rectify``,
not for a resection).  ``enable = 0`` (a point left out of QGIS's fit) reads as
a check point; there are no names (``gcp1, gcp2, ...``) and one image (``""``).

**GeoJSON** as orthority writes it: a ``FeatureCollection`` of ``Point``
features, ``coordinates`` = longitude, latitude, height (WGS84, RFC 7946),
``properties``: ``ji`` = pixel ``[column, row]`` (orthority's pixels are
photax's: integer = centre), ``id`` (the name), ``filename`` (the image).

**Geographic coordinates** (an ODM list whose first line is ``WGS84``,
``EPSG:4326`` or ``+proj=longlat ...``, a CSV ``# crs:`` of a geographic CRS, a
GeoJSON file): ``x`` is the longitude, ``y`` the latitude; the points are
projected through pyproj to ``crs=`` or, by default, to the WGS84 UTM zone of
their mean position, as ODM does.  Degrees are never taken for metres.  Heights
are kept as the file gives them (no vertical datum is converted).  Given
``crs=``, a file in another projected CRS is reprojected to it too.

A name is one point: the same name with other ground coordinates or another
role is an error naming both lines.  A point measured twice in one image is kept (real lists have such slips: the
ODM sample measures HV11 twice in IMG_5352) and reported by
:meth:`GCPTable.duplicates`; a robust resection then flags the wrong one.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import pathlib
import re
from typing import Literal

import numpy as np

from ..errors import CRSMismatchError, OutsideValidityError, UnsupportedFormatError
from .files import as_numbers, excerpt, file_error, number, read_text, split_lines

_ROLES = ("control", "check")


@dataclasses.dataclass(frozen=True, eq=False)
class GCPTable:
    """Ground control measurements, one row per (point, image) pair.

    Attributes:
        names: ``(n,)`` point names.
        images: ``(n,)`` image names (``""`` when the file has no image column).
        ground: ``(n, 3)`` ground ``(X, Y, Z)`` (easting, northing, height), float64;
            heights NaN for a 2-D file (QGIS ``.points``).
        pixel: ``(n, 2)`` pixel ``(column, row)``, integer = pixel centre,
            row down; or ``None`` when the file gives image-plane coordinates.
        image_xy: ``(n, 2)`` image-plane ``(x, y)`` (y up, camera units), or
            ``None`` when the file gives pixels.
        sigma: ``(n,)`` a-priori standard deviation of an image coordinate, in
            the unit of the measurements (pixels or image-plane); NaN when
            not given.
        role: ``(n,)`` ``"control"`` or ``"check"``.
        crs: the ground CRS as text (EPSG code or PROJ string), or ``None``.
        lines: ``(n,)`` line numbers in the source file (0 when built in memory).
        source: the file it was read from, if any (for messages).

    Examples:
        Built in memory, or read by :func:`photax.read_gcps`; ``image_plane`` converts its pixels
        with a camera:

        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import GCPTable
        >>> table = GCPTable(names=np.array(["A"]), images=np.array(["IMG"]), ground=np.array([[100.0, 200.0, 10.0]]),
        ...                  pixel=np.array([[499.5, 374.5]]), image_xy=None, sigma=np.array([0.3]),
        ...                  role=np.array(["control"]))
        >>> cam = ptx.FrameCamera(8.8, pixel_size=0.0176, image_size=(1000, 750))
        >>> print(np.round(np.asarray(table.image_plane(cam)), 9) + 0.0)  # the image centre
        [[0. 0.]]
    """

    names: np.ndarray
    images: np.ndarray
    ground: np.ndarray
    pixel: np.ndarray | None
    image_xy: np.ndarray | None
    sigma: np.ndarray
    role: np.ndarray
    crs: str | None = None
    lines: np.ndarray | None = None
    source: str | None = None

    def __len__(self) -> int:
        return len(self.names)

    @property
    def image_names(self) -> list[str]:
        """The distinct image names, in file order."""
        return list(dict.fromkeys(self.images.tolist()))

    @property
    def check(self) -> np.ndarray:
        """``(n,)`` bool, True for check points."""
        return self.role == "check"

    def select(self, image: str) -> GCPTable:
        """The measurements in one image."""
        keep = self.images == image
        if not keep.any():
            raise ValueError(f"image {image!r} is not in {self.source or 'the GCP table'}; it has {self.image_names}")
        return self.subset(keep)

    def subset(self, keep) -> GCPTable:
        """The rows where the boolean (or index) array ``keep`` selects."""
        take = lambda a: None if a is None else a[keep]  # noqa: E731
        return dataclasses.replace(
            self,
            names=self.names[keep],
            images=self.images[keep],
            ground=self.ground[keep],
            pixel=take(self.pixel),
            image_xy=take(self.image_xy),
            sigma=self.sigma[keep],
            role=self.role[keep],
            lines=take(self.lines),
        )

    def duplicates(self) -> list[str]:
        """Messages for points measured more than once in the same image."""
        lines = self.lines if self.lines is not None else np.zeros(len(self), dtype=int)
        first: dict[tuple[str, str], int] = {}
        out = []
        for name, image, line in zip(self.names.tolist(), self.images.tolist(), lines.tolist()):
            if (name, image) in first:
                where = f" in image {image!r}" if image else ""
                out.append(f"point {name!r} measured twice{where} (lines {first[name, image]} and {line})")
            first.setdefault((name, image), line)
        return out

    def image_plane(self, camera) -> np.ndarray:
        """``(n, 2)`` image-plane coordinates: as given, or ``camera.pixel_to_image(pixel)``."""
        if self.image_xy is not None:
            return self.image_xy
        return np.asarray(camera.pixel_to_image(self.pixel))

    def image_plane_sigma(self, camera) -> np.ndarray:
        """``(n,)`` a-priori sigma in image-plane units (pixels times the mean pixel size)."""
        if self.image_xy is not None:
            return self.sigma
        return self.sigma * float(np.mean(np.asarray(camera._pixel_grid()[1])))


_UTM = re.compile(r"^\s*WGS\s*84\s+UTM\s+(\d{1,2})\s*([NS])\s*$", re.IGNORECASE)


def odm_crs_text(text: str) -> str:
    """ODM's CRS line as pyproj reads it: ``WGS84 UTM 16N`` -> ``EPSG:32616``; other text as it is."""
    m = _UTM.match(text)
    if m is None:
        return text.strip()
    zone = int(m.group(1))
    if not 1 <= zone <= 60:
        raise ValueError(f"UTM zone {zone} is not 1 to 60")
    return f"EPSG:{(32600 if m.group(2).upper() == 'N' else 32700) + zone}"


_FORMATS = ("auto", "csv", "odm", "qgis", "geojson")


def read_gcps(path, *, format: Literal["auto", "csv", "odm", "qgis", "geojson"] = "auto", crs=None) -> GCPTable:
    """Read a GCP file (CSV with header, OpenDroneMap ``gcp_list.txt``, QGIS
    Georeferencer ``.points``, or orthority's GeoJSON).

    Args:
        path: the file.
        format: ``"csv"``, ``"odm"``, ``"qgis"``, ``"geojson"``, or ``"auto"``:
            GeoJSON when the file starts with ``{``, QGIS when its header is
            ``mapX,mapY,...``, CSV when the first non-blank line contains a
            comma, else ODM.
        crs: the projected CRS to give the ground coordinates in (EPSG code,
            PROJ string, WKT); by default geographic coordinates go to the UTM
            zone of the points and projected ones stay as they are.

    Returns:
        a :class:`GCPTable`.

    Raises:
        ValueError: naming the file and line of the first malformed line.

    Examples:
        A CSV with a header (name, image, ground E N h, pixel column row, sigma, role); lines starting
        with ``#`` are comments, and ``# crs:`` names the ground CRS:

        >>> import pathlib, tempfile
        >>> import photax as ptx
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "gcps.csv"
        >>> _ = path.write_text(
        ...     "# crs: EPSG:32633\\n"
        ...     "name,image,E,N,h,col,row,sigma,role\\n"
        ...     "P1,IMG_1,511890.627,4103806.525,48.276,81.112,44.633,0.3,control\\n"
        ...     "P2,IMG_1,512075.985,4103928.086,57.478,355.060,44.955,0.3,check\\n"
        ... )
        >>> gcps = ptx.read_gcps(path)
        >>> gcps.names.tolist(), gcps.role.tolist(), gcps.crs
        (['P1', 'P2'], ['control', 'check'], 'EPSG:32633')
        >>> gcps.ground[1].tolist(), gcps.pixel[0].tolist()
        ([512075.985, 4103928.086, 57.478], [81.112, 44.633])
    """
    path = pathlib.Path(path)
    text = read_text(path, "GCP file")
    lines = split_lines(text)
    numbered = [(i + 1, s) for i, s in enumerate(lines) if s.strip() and not s.lstrip().startswith("#")]
    if format not in _FORMATS:
        raise UnsupportedFormatError(f"format must be one of {', '.join(map(repr, _FORMATS))}, got {format!r}")
    if format == "auto" and text.lstrip().startswith("{"):
        format = "geojson"
    if format == "geojson":
        rows, source_crs = _parse_geojson(path, text)
    elif not numbered:
        raise ValueError(f"{path}: empty GCP file")
    else:
        if format == "auto":
            first = numbered[0][1].replace(" ", "").lower()
            format = "qgis" if first.startswith("mapx,") else "csv" if "," in first else "odm"
        if format == "csv":
            rows = _parse_csv(path, numbered)
            tags = [ln.lstrip()[1:].strip() for ln in lines if ln.lstrip().startswith("#")]
            source_crs = next((t.split(":", 1)[1].strip() for t in tags if t.lower().startswith("crs:")), None)
        elif format == "qgis":
            rows, source_crs = _parse_qgis(path, lines, numbered)
        else:
            source_crs = numbered[0][1].strip()
            if _looks_like_measurement(source_crs):
                raise ValueError(
                    f"{path}, line {numbered[0][0]}: an ODM GCP list starts with its CRS "
                    f"(e.g. EPSG:32633 or a PROJ string), got a measurement: {excerpt(source_crs)}"
                )
            rows = _parse_odm(path, numbered[1:])
            try:  # ODM's own "WGS84 UTM 16N" as an EPSG code; anything else as written
                source_crs = odm_crs_text(source_crs)
            except ValueError as exc:
                raise ValueError(f"{path}, line {numbered[0][0]}: {exc}") from None
    if not len(rows["names"]):
        raise ValueError(f"{path}: no GCP measurements")
    _auto_names(rows)
    try:
        _check_points(path, rows)
    except ValueError as exc:  # GeoJSON has features, not lines
        message = str(exc).replace(", line ", ", feature ") if format == "geojson" else str(exc)
        raise ValueError(message) from None
    if format == "qgis":  # 2-D points: no height (zero until the checks, which compare positions)
        rows["ground"][:, 2] = math.nan
    unit = "feature" if format == "geojson" else "line"
    ground, out_crs = _projected(path, rows["ground"], source_crs, crs, rows["lines"], unit)
    return GCPTable(
        names=np.asarray(rows["names"], dtype=str),
        images=np.asarray(rows["images"], dtype=str),
        ground=ground,
        pixel=rows["pixel"],
        image_xy=rows["image_xy"],
        sigma=rows["sigma"],
        role=np.asarray(rows["role"], dtype=str),
        crs=out_crs,
        lines=rows["lines"],
        source=str(path),
    )


def _parse_crs(text):
    """A ``pyproj.CRS`` (its horizontal part) from the file's CRS text, or None when pyproj cannot read it."""
    import pyproj

    try:
        crs = pyproj.CRS.from_user_input(text)
    except Exception:  # noqa: BLE001 - pyproj raises CRSError, and others on odd text: not a CRS either way
        return None
    return crs.sub_crs_list[0] if crs.is_compound else crs


def _projected(path, ground, source_text, target_text, lines, unit="line") -> tuple[np.ndarray, str | None]:
    """``ground`` in ``target_text`` (or, for geographic coordinates, the UTM zone of
    their mean position) and the CRS text; heights unchanged."""
    import pyproj

    from ..geo import utm_crs
    from ._geo import projected_crs

    target = None if target_text is None else projected_crs(target_text, "crs")
    source = None if source_text is None else _parse_crs(source_text)
    if source is None:
        if source_text is not None and target is not None:
            raise CRSMismatchError(
                f"{path}: its CRS {excerpt(source_text)} is not one pyproj reads; cannot reproject it"
            )
        if source_text is None and target is not None:  # the caller says what the coordinates are
            return ground, str(target_text)
        return ground, source_text
    if not (source.is_geographic or source.is_projected):
        raise CRSMismatchError(f"{path}: CRS {source.name!r} is neither geographic nor projected")
    if source.is_geographic:
        lon, lat = ground[:, 0], ground[:, 1]
        bad = ~((np.abs(lat) <= 90) & (np.abs(lon) <= 360))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"{path}, {unit} {lines[i]}: the CRS {source.name!r} is geographic, "
                f"but x {lon[i]:g}, y {lat[i]:g} is not a longitude, latitude in degrees"
            )
        if target is None:
            target = projected_crs(utm_crs(lon=np.mean(lon), lat=np.mean(lat)))
    elif target is None or target == source:
        return ground, source_text
    t = pyproj.Transformer.from_crs(source, target, always_xy=True)
    x, y = t.transform(ground[:, 0], ground[:, 1])
    out = np.column_stack([x, y, ground[:, 2]]).astype(float)
    bad = ~np.all(np.isfinite(out[:, :2]), axis=1)
    if bad.any():
        where = lines[int(np.flatnonzero(bad)[0])]
        raise OutsideValidityError(f"{path}, {unit} {where}: outside the area of {target.name!r}")
    epsg = target.to_epsg()
    return out, (f"EPSG:{epsg}" if epsg is not None else target.to_wkt())


_QGIS_HEADER = ["mapx", "mapy", "sourcex", "sourcey", "enable"]


def _parse_qgis(path, lines, numbered) -> tuple[dict, str | None]:
    crs = None
    for ln in lines:
        s = ln.strip()
        if s.upper().replace(" ", "").startswith("#CRS:"):
            crs = s.split(":", 1)[1].strip() or None
            break
        if s and not s.startswith("#"):
            break
    parsed = None if crs is None else _parse_crs(crs)
    if parsed is not None and parsed.to_epsg(min_confidence=100) is not None:  # QGIS's WKT as its EPSG code
        crs = f"EPSG:{parsed.to_epsg(min_confidence=100)}"
    (hline, head), body = numbered[0], numbered[1:]
    header = [h.strip().lower() for h in _split_csv(path, hline, head)]
    if header[:5] != _QGIS_HEADER or len(header) > 8:
        raise file_error(path, hline, "not a QGIS .points file (header mapX,mapY,sourceX,sourceY,enable,... expected)")
    rows = _empty_rows()
    for line, text in body:
        f = [s.strip() for s in _split_csv(path, line, text)]
        if len(f) != len(header):
            raise file_error(path, line, f"expected {len(header)} columns, got {len(f)}")
        x, y, sx, sy = (_number(path, line, f[k], w) for k, w in enumerate(("mapX", "mapY", "sourceX", "sourceY")))
        if f[4] not in ("0", "1"):
            raise file_error(path, line, f"enable must be 0 or 1, got {excerpt(f[4])}")
        if sy > 0:
            raise file_error(
                path,
                line,
                f"sourceY {sy:g} is positive: QGIS writes pixel rows as -row, so the source raster was "
                "georeferenced (map units, not pixels); georeference the raw image in QGIS",
            )
        rows["ground"].append([x, y, 0.0])
        rows["pixel"].append([sx - 0.5, -sy - 0.5])
        rows["images"].append("")
        rows["names"].append(None)
        rows["sigma"].append(math.nan)
        rows["role"].append("control" if f[4] == "1" else "check")
        rows["lines"].append(line)
    return _as_arrays(rows), crs


def _parse_geojson(path, text) -> tuple[dict, str]:
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError, too many digits, too deep
        where = f", line {exc.lineno}" if isinstance(exc, json.JSONDecodeError) else ""
        raise ValueError(f"{path}{where}: not JSON ({getattr(exc, 'msg', type(exc).__name__)})") from None
    if not (isinstance(doc, dict) and doc.get("type") == "FeatureCollection" and isinstance(doc.get("features"), list)):
        raise ValueError(f"{path}: a GeoJSON GCP file is a FeatureCollection of Point features")
    crs = "EPSG:4326"  # RFC 7946; the old "crs" member when a file names one
    named = doc.get("crs")
    if named is not None:
        props = named.get("properties") if isinstance(named, dict) else None
        name = props.get("name") if isinstance(props, dict) else None
        if not isinstance(name, str):
            raise ValueError(f"{path}: the 'crs' member has no properties.name")
        crs = name
    rows = _empty_rows()
    for k, feat in enumerate(doc["features"], start=1):
        geom = feat.get("geometry") if isinstance(feat, dict) else None
        props = feat.get("properties") if isinstance(feat, dict) else None
        if not (isinstance(geom, dict) and geom.get("type") == "Point" and isinstance(props, dict)):
            raise ValueError(f"{path}, feature {k}: expected a Point feature with properties")
        xyz, ji = as_numbers(geom.get("coordinates")), as_numbers(props.get("ji"))
        if xyz is None or xyz.shape != (3,) or not np.all(np.isfinite(xyz)):
            raise ValueError(f"{path}, feature {k}: coordinates must be 3 finite numbers (longitude, latitude, height)")
        if ji is None or ji.shape != (2,) or not np.all(np.isfinite(ji)):
            raise ValueError(f"{path}, feature {k}: properties.ji must be 2 finite numbers (pixel column, row)")
        name, image = props.get("id"), props.get("filename", "")
        if name is not None and not isinstance(name, (str, int)) or isinstance(name, bool):
            raise ValueError(f"{path}, feature {k}: properties.id must be a text, got {excerpt(name)}")
        if not isinstance(image, str):
            raise ValueError(f"{path}, feature {k}: properties.filename must be a text, got {excerpt(image)}")
        name = None if name is None else str(name).strip() or None
        rows["ground"].append(xyz.tolist())
        rows["pixel"].append(ji.tolist())
        rows["images"].append(image.strip())
        rows["names"].append(name)
        rows["sigma"].append(math.nan)
        rows["role"].append("control")
        rows["lines"].append(k)
    return _as_arrays(rows), crs


_number = number


def _check_points(path, rows) -> None:
    """One point, one ground position and one role: a name reused for another
    position (a typo, or two lists merged) would silently pull the solution."""
    names, ground, role, lines = rows["names"], rows["ground"], rows["role"], rows["lines"]
    _, first, inverse = np.unique(names.astype(str), return_index=True, return_inverse=True)
    j_of = first[inverse.reshape(-1)]  # each row's first row of the same name
    bad = np.any(ground != ground[j_of], axis=1) | (role != role[j_of])
    if not bad.any():
        return
    i = int(np.flatnonzero(bad)[0])
    j, name = int(j_of[i]), names[i]
    if np.any(ground[i] != ground[j]):
        raise file_error(
            path,
            lines[i],
            f"point {excerpt(str(name))} has ground coordinates {ground[i].tolist()}, "
            f"but {ground[j].tolist()} on line {lines[j]}; one name, one point",
        )
    raise file_error(
        path, lines[i], f"point {excerpt(str(name))} is a {role[i]} point here but a {role[j]} point on line {lines[j]}"
    )


def _empty_rows() -> dict[str, list]:
    return {k: [] for k in ("names", "images", "ground", "pixel", "image_xy", "sigma", "role", "lines")}


def _as_arrays(rows: dict[str, list]) -> dict:
    """The line-by-line parsers' lists as the arrays :func:`_fast_rows` makes."""
    n = len(rows["names"])
    arr = lambda k, shape: np.asarray(rows[k], dtype=float).reshape(shape) if rows[k] else None  # noqa: E731
    names = np.empty(n, dtype=object)
    names[:] = rows["names"]
    return dict(
        names=names,
        images=rows["images"],
        ground=arr("ground", (n, 3)),
        pixel=arr("pixel", (n, 2)),
        image_xy=arr("image_xy", (n, 2)),
        sigma=np.asarray(rows["sigma"], dtype=float),
        role=np.asarray(rows["role"], dtype=str),
        lines=np.asarray(rows["lines"], dtype=int),
    )


def _auto_names(rows) -> None:
    """Name unnamed points ``gcp1, gcp2, ...`` by distinct ground coordinates, in file order."""
    unnamed = np.flatnonzero(np.equal(rows["names"], None))
    if not unnamed.size:
        return
    _, first, inverse = np.unique(rows["ground"][unnamed], axis=0, return_index=True, return_inverse=True)
    rank = np.empty(first.size, int)
    rank[np.argsort(first)] = np.arange(1, first.size + 1)  # numbered by first appearance
    names = rows["names"].copy()
    names[unnamed] = [f"gcp{k}" for k in rank[inverse.reshape(-1)].tolist()]
    rows["names"] = names


def _is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def _looks_like_measurement(text: str) -> bool:
    f = text.split()
    try:
        return len(f) >= 6 and all(math.isfinite(float(v)) for v in f[:5])
    except ValueError:
        return False


def _parse_odm(path, numbered) -> dict:
    split = [text.split() for _, text in numbered]
    if all(len(f) >= 6 for f in split):
        col = lambda k: [f[k] for f in split]  # noqa: E731
        fast = _fast_rows(
            numbered,
            dict(
                e=col(0),
                n=col(1),
                h=col(2),
                u=col(3),
                v=col(4),
                image=col(5),
                name=[f[6] if len(f) > 6 else "" for f in split],
            ),
            pixel=True,
        )
        if fast is not None:
            return fast
    rows = _empty_rows()
    for i, (line, text) in enumerate(numbered):
        f = text.split()
        try:
            if len(f) < 6:
                raise file_error(
                    path, line, f"expected 'E N h col row image [name]', got {len(f)} columns: {excerpt(text.strip())}"
                )
            values = [_number(path, line, f[k], w) for k, w in enumerate(("E", "N", "h", "col", "row"))]
        except ValueError as exc:
            if i == 0 and sum(_is_number(v) for v in f[:5]) < 3:  # some other file: none of it quoted
                raise file_error(
                    path,
                    line,
                    "not a GCP file (a CSV with a header, or an OpenDroneMap list: "
                    "a CRS line, then lines 'E N h col row image [name]', expected)",
                ) from None
            raise ValueError(f"{exc} (columns are 'E N h col row image [name]')") from None
        rows["ground"].append(values[:3])
        rows["pixel"].append(values[3:])
        rows["images"].append(f[5])
        rows["names"].append(f[6] if len(f) > 6 else None)
        rows["sigma"].append(math.nan)
        rows["role"].append("control")
        rows["lines"].append(line)
    return _as_arrays(rows)


_GROUND = {"e": ("easting", "e", "x"), "n": ("northing", "n", "y"), "h": ("height", "h", "z")}
_OTHER = {"name", "image", "col", "column", "row", "sigma", "role", "image_x", "image_y"}


def _csv_columns(path, header: list[str], hline: int = 1) -> dict[str, int]:
    """Map our field names to column indices (see the module docstring)."""
    low = [h.strip().lower() for h in header]
    raw = [h.strip() for h in header]
    cols: dict[str, int] = {}
    # a coordinate column: the file is meant as a GCP file, and its header may be quoted
    coordinates = {"image_x", "image_y", "col", "column", "row", *(n for g in _GROUND.values() for n in g)}
    known = bool(coordinates & set(low))
    both_case = {"X", "x"} <= set(raw)
    named_en = bool({"easting", "e"} & set(low))
    for i, (r, lo) in enumerate(zip(raw, low)):
        if lo in ("x", "y"):
            ground = r.isupper() if both_case else not named_en
            key = ({"x": "e", "y": "n"}[lo]) if ground else lo
        elif lo in ("image_x", "image_y"):
            key = lo[-1]
        elif lo in ("col", "column"):
            key = "col"
        else:
            key = next((k for k, names in _GROUND.items() if lo in names), lo if lo in _OTHER else None)
        if key is None and not known:  # no column photax knows: some other file, none of it quoted
            raise file_error(path, hline, "not a GCP file (a CSV header naming E, N, h and col, row or x, y expected)")
        if key is None:
            raise ValueError(
                f"{path}, line {hline}: unknown column {excerpt(r)}; accepted: name, image, "
                "E/easting/X, N/northing/Y, h/height/Z, col/column, row, x, y, sigma, role"
            )
        if key in cols:
            raise ValueError(
                f"{path}, line {hline}: two columns mean the same thing: {excerpt(raw[cols[key]])} and {excerpt(r)}"
            )
        cols[key] = i
    missing = [w for w, k in (("easting", "e"), ("northing", "n"), ("height", "h")) if k not in cols]
    if missing:
        raise ValueError(f"{path}, line {hline}: no {'/'.join(missing)} column in {excerpt(raw, 80)}")
    has_px, has_xy = {"col", "row"} <= cols.keys(), {"x", "y"} <= cols.keys()
    if has_px == has_xy:
        raise ValueError(
            f"{path}, line {hline}: give pixel columns (col, row) or image-plane columns "
            f"(x, y), exactly one pair; header is {excerpt(raw, 80)}"
        )
    return cols


def _split_csv(path, line: int, text: str) -> list[str]:
    try:
        return next(csv.reader([text]), [])
    except csv.Error as exc:
        raise file_error(path, line, f"not a CSV line ({exc})") from None


def _parse_csv(path, numbered) -> dict:
    (_, head), body = numbered[0], numbered[1:]
    header = _split_csv(path, numbered[0][0], head)
    cols = _csv_columns(path, header, numbered[0][0])
    pix = "col" in cols
    k = len(header)
    texts = [text for _, text in body]
    joined = "\n".join(texts)
    # Plain CSV (no quotes, no carriage return, every line the header's number of fields): one split of
    # the whole body, as csv.reader would split each line.
    if not any(c in head or c in joined for c in '"\r') and all(t.count(",") == k - 1 for t in texts):
        flat = joined.replace("\n", ",").split(",")
        col = lambda key: flat[cols[key] :: k] if key in cols else [""] * len(texts)  # noqa: E731
        fast = _fast_rows(
            body,
            dict(
                e=col("e"),
                n=col("n"),
                h=col("h"),
                u=col("col" if pix else "x"),
                v=col("row" if pix else "y"),
                image=col("image"),
                name=col("name"),
                sigma=col("sigma"),
                role=col("role"),
            ),
            pixel=pix,
        )
        if fast is not None:
            return fast
    rows = _empty_rows()
    for line, text in body:
        f = [s.strip() for s in _split_csv(path, line, text)]
        if len(f) != len(header):
            raise ValueError(f"{path}, line {line}: expected {len(header)} columns, got {len(f)}")
        num = lambda k: _number(path, line, f[cols[k]], header[cols[k]].strip())  # noqa: E731
        rows["ground"].append([num("e"), num("n"), num("h")])
        rows["pixel" if pix else "image_xy"].append([num("col"), num("row")] if pix else [num("x"), num("y")])
        rows["images"].append(f[cols["image"]] if "image" in cols else "")
        rows["names"].append(f[cols["name"]] or None if "name" in cols else None)
        sigma = num("sigma") if "sigma" in cols and f[cols["sigma"]] else math.nan
        if not sigma > 0 and not math.isnan(sigma):
            raise ValueError(f"{path}, line {line}: sigma must be positive, got {sigma}")
        rows["sigma"].append(sigma)
        role = f[cols["role"]].lower() if "role" in cols and f[cols["role"]] else "control"
        if role not in _ROLES:
            raise ValueError(f"{path}, line {line}: role must be 'control' or 'check', got {excerpt(role)}")
        rows["role"].append(role)
        rows["lines"].append(line)
    return _as_arrays(rows)


def _fast_rows(body, fields: dict[str, list[str]], pixel: bool) -> dict | None:
    """The rows of a whole file at once from each column's texts (one per
    line of ``body``), as :func:`_as_arrays` gives them; None when a value is
    not plain (not a finite number, a bad sigma or role): the line-by-line
    parser then names the line.  10^6 lines in a few seconds, where the
    line-by-line parser took 16 s and 1 GB (issue 27)."""
    try:
        num = [np.fromiter(map(float, fields[key]), float, len(body)) for key in ("e", "n", "h", "u", "v")]
    except ValueError:
        return None
    n = len(body)
    # Columns of few distinct texts (sigma, role, image): each distinct text converted once.
    sig_map = {t: t.strip() for t in set(fields.get("sigma", [""]))}
    sig_text = [sig_map[t] for t in fields["sigma"]] if "sigma" in fields else [""] * n
    given = np.fromiter(map(bool, sig_text), bool, n)
    try:
        sigma = np.fromiter((float(t) if t else math.nan for t in sig_text), float, n)
    except ValueError:
        return None
    role_map = {t: t.strip().lower() or "control" for t in set(fields.get("role", [""]))}
    role = np.asarray([role_map[t] for t in fields["role"]] if "role" in fields else ["control"] * n, dtype=str)
    ground, coords = np.stack(num[:3], axis=1), np.stack(num[3:], axis=1)
    if not (
        np.all(np.isfinite(ground))
        and np.all(np.isfinite(coords))
        and np.all(np.isin(role, _ROLES))
        and np.all(np.isfinite(sigma[given]) & (sigma[given] > 0))
    ):
        return None
    names = np.empty(n, dtype=object)
    names[:] = [t.strip() or None for t in fields["name"]]
    image_map = {t: t.strip() for t in set(fields["image"])}
    return dict(
        names=names,
        images=[image_map[t] for t in fields["image"]],
        ground=ground,
        pixel=coords if pixel else None,
        image_xy=None if pixel else coords,
        sigma=sigma,
        role=role,
        lines=np.fromiter((line for line, _ in body), int, n),
    )


def _fmt(v: float) -> str:
    """Shortest text that reads back as the same float (``repr``); NaN as an empty field."""
    return "" if math.isnan(v) else repr(float(v))


def write_gcps(path, table: GCPTable, *, format: str = "auto", inputs=()) -> pathlib.Path:
    """Write ``table`` as a GCP file that :func:`read_gcps` reads back.

    ``format``: ``"csv"``, ``"qgis"`` (QGIS Georeferencer ``.points``),
    ``"geojson"`` (orthority's GCP file), or ``"auto"``: by the suffix
    (``.points``, ``.geojson``/``.json``), else CSV.

    **CSV**: columns ``name,image,E,N,h,col,row`` (or ``x,y`` for image-plane
    coordinates), ``sigma`` (empty where NaN) and ``role``, after a
    ``# crs: ...`` comment when the table has a CRS.  Numbers are written with
    ``repr`` (the shortest decimal that converts back to the same float64), so
    ``read_gcps(write_gcps(p, t))`` has the same names, images, coordinates,
    sigmas, roles and CRS as ``t``.

    **QGIS** ``.points``: one image, pixels; names, heights and sigmas are not
    kept (the format has none), check points are written disabled
    (``enable = 0``), residual columns as 0, the CRS as a ``#CRS:`` WKT line.

    **GeoJSON**: pixels and heights needed, the table's CRS converted to WGS84
    longitude, latitude (heights as they are); roles and sigmas not kept.

    The file is written atomically (:mod:`photax.io.atomic`) and may not be one
    of ``inputs``.

    Measured points (``photax.measure``) become GCPs with ``pixel = r.xy`` and
    ``sigma`` one number per point in pixels, e.g. ``sqrt((s_col^2 + s_row^2) / 2)``
    of ``r.sigma`` (``read_gcps`` and :func:`photax.resect` take one sigma per point).

    Returns the path written.

    Examples:
        What :func:`photax.read_gcps` reads back equal:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> from photax.io import GCPTable, read_gcps, write_gcps
        >>> table = GCPTable(names=np.array(["A", "B"]), images=np.array(["IMG", "IMG"]),
        ...                  ground=np.array([[100.0, 200.0, 10.0], [150.0, 260.0, 12.5]]),
        ...                  pixel=np.array([[10.5, 20.25], [300.0, 400.0]]), image_xy=None,
        ...                  sigma=np.array([0.5, 0.5]), role=np.array(["control", "check"]), crs="EPSG:32633")
        >>> path = write_gcps(pathlib.Path(tempfile.mkdtemp()) / "gcps.csv", table)
        >>> back = read_gcps(path)
        >>> bool(np.array_equal(back.ground, table.ground) and np.array_equal(back.pixel, table.pixel))
        True
        >>> back.role.tolist(), back.crs
        (['control', 'check'], 'EPSG:32633')
    """
    from .atomic import atomic_write

    if format == "auto":
        suffix = pathlib.Path(path).suffix.lower()
        format = {".points": "qgis", ".geojson": "geojson", ".json": "geojson"}.get(suffix, "csv")
    if format not in ("csv", "qgis", "geojson"):
        raise UnsupportedFormatError(f"format must be 'auto', 'csv', 'qgis' or 'geojson', got {format!r}")
    if not isinstance(table, GCPTable):
        raise ValueError(f"table: expected a GCPTable, got {type(table).__name__}")
    pix = table.pixel is not None
    coords = table.pixel if pix else table.image_xy
    if coords is None:
        raise ValueError("table: has neither pixel nor image-plane coordinates")
    if format != "csv" and not pix:
        raise ValueError(f"table: a {format} GCP file gives pixels; this table has image-plane coordinates")
    ground = table.ground[:, :2] if format == "qgis" else table.ground
    for what, arr in (("ground", ground), ("pixel" if pix else "image_xy", coords)):
        if not np.all(np.isfinite(arr)):
            bad = table.names[~np.all(np.isfinite(arr), axis=1)][:5]
            raise ValueError(f"table: non-finite {what} coordinates for {', '.join(bad)}; drop the failed points first")
    if format == "qgis":
        return _write_qgis(path, table, inputs)
    if format == "geojson":
        return _write_geojson(path, table, inputs)
    sigma = np.asarray(table.sigma, dtype=float)
    if np.any(~np.isnan(sigma) & ~(sigma > 0)):
        raise ValueError("table: sigma must be positive (or NaN for none)")
    for what, values in (("names", table.names), ("images", table.images)):
        for v in values.tolist():
            if v != v.strip() or "\n" in v or v.startswith("#") or (what == "names" and not v):
                raise ValueError(
                    f"table: {what[:-1]} {v!r} would not read back (empty name, surrounding spaces, newline or '#')"
                )
    if table.crs is not None and "\n" in table.crs:
        raise ValueError(f"table: crs {table.crs!r} spans lines")
    header = ["name", "image", "E", "N", "h", *(("col", "row") if pix else ("x", "y")), "sigma", "role"]
    with atomic_write(path, inputs=inputs, newline="") as fh:
        if table.crs is not None:
            fh.write(f"# crs: {table.crs}\n")
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(header)
        for i in range(len(table)):
            writer.writerow(
                [
                    table.names[i],
                    table.images[i],
                    *map(_fmt, table.ground[i]),
                    *map(_fmt, coords[i]),
                    _fmt(sigma[i]),
                    table.role[i],
                ]
            )
    return pathlib.Path(path)


def _write_qgis(path, table: GCPTable, inputs) -> pathlib.Path:
    from .atomic import atomic_write

    if len(table.image_names) > 1:
        raise ValueError(f"table: a QGIS .points file is one image's; select one of {table.image_names}")
    wkt = None
    if table.crs is not None:
        crs = _parse_crs(table.crs)
        if crs is None:
            raise ValueError(f"table: crs {excerpt(table.crs)} is not one pyproj reads (QGIS needs its WKT)")
        wkt = crs.to_wkt()
    with atomic_write(path, inputs=inputs, newline="") as fh:
        if wkt is not None:
            fh.write(f"#CRS: {wkt}\n")
        fh.write("mapX,mapY,sourceX,sourceY,enable,dX,dY,residual\n")
        for (x, y, _), (col, row), role in zip(table.ground, table.pixel, table.role.tolist()):
            enable = "0" if role == "check" else "1"
            fh.write(f"{_fmt(x)},{_fmt(y)},{_fmt(col + 0.5)},{_fmt(-(row + 0.5))},{enable},0,0,0\n")
    return pathlib.Path(path)


def _write_geojson(path, table: GCPTable, inputs) -> pathlib.Path:
    import pyproj

    from .atomic import atomic_write

    crs = None if table.crs is None else _parse_crs(table.crs)
    if crs is None:
        raise ValueError("table: a GeoJSON GCP file is in WGS84; the table needs a CRS pyproj reads to convert it")
    lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(
        table.ground[:, 0], table.ground[:, 1]
    )
    features = [
        {
            "type": "Feature",
            "properties": {"ji": [float(c), float(r)], "filename": str(image), "id": str(name), "info": str(name)},
            "geometry": {"type": "Point", "coordinates": [float(a), float(b), float(h)]},
        }
        for (c, r), image, name, a, b, h in zip(
            table.pixel, table.images, table.names, np.atleast_1d(lon), np.atleast_1d(lat), table.ground[:, 2]
        )
    ]
    with atomic_write(path, inputs=inputs) as fh:
        json.dump({"type": "FeatureCollection", "features": features}, fh, indent=1)
        fh.write("\n")
    return pathlib.Path(path)
