"""Satellite RPC files, every vendor's family in one format table, recognised by content.

A vendor's RPC comes under many names (``*_RPC.TXT``, ``po_*_rpc.txt``, ``RPC_*.XML``, ``*.XML``,
``*.RPB``, the GeoTIFF itself); :data:`FORMATS` says, for each family, how its content is recognised
(magic bytes, the XML root, the keys of the first lines), how it is read and, where photax writes
it, how it is written.  :func:`rpc_format` names a file's family, :func:`read_rpc` reads any of them
(``photax.read_rpc``), :func:`write_rpc` writes ``_RPC.TXT`` text, ``.RPB`` and GeoTIFF RPC tags, and
:func:`read_sensor` gives the sensor of a file (``photax.read_sensor``).  The families
(``docs/formats.md``):

- ``dimap``: Airbus DIMAP v2/v3 XML (a DIMAP v1 file, SPOT 1-5, has no RPC: refused saying so) (Pleiades, SPOT 6/7: ``Inverse_Model`` and ``Direct_Model``;
  Pleiades Neo: ``GroundtoImage_Values`` and ``ImagetoGround_Values``); both models are kept (the
  direct one localizes by default, :class:`photax.RPCCamera`).  DIMAP counts pixels from (1, 1)
  (v2; v3 says where it starts in ``ImagetoGround_Validity_Domain/FIRST_COL``), photax from
  (0, 0): the line and sample offsets are shifted as GDAL's DIMAP reader does.  A main
  ``DIM_*.XML`` without the model is followed to the RPC file it names.
- ``maxar-xml``: DigitalGlobe/Maxar ISD XML (WorldView-1/2/3/4, GeoEye-1, QuickBird): ``<isd>``'s
  ``<RPB><IMAGE>`` block.
- ``rpc-txt``: the ``KEY: value [unit]`` text of IKONOS, Planet, SkySat and GDAL's ``_RPC.TXT``
  (``LINE_OFF: +005124.00 pixels``, ``LINE_NUM_COEFF_1: ...``), whatever the file's name; the
  "extended IKONOS" ``LON_NUM_COEFF_n`` ... ``LAT_DEN_COEFF_n`` lines are a direct model.
- ``rpb``: DigitalGlobe's ``.RPB`` text (``lineOffset = ...;``, ``lineNumCoef = ( ... );``).
- ``orthority``: orthority's ``rpc_param.yaml`` (one entry per image; ``image=`` picks one).
- ``rpcm-json``: rpcm's ``RPCModel.__dict__`` as JSON (``row_offset``, ``col_num``, ...; also with
  GDAL's upper-case keys), or s2p's ``config.json`` (``images: [{img, rpc}]``; ``image=`` picks one).
- ``raster``: an image GDAL reads with RPC metadata (GeoTIFF RPC tags, NITF RPC00B, JPEG 2000, or
  the ``.RPB`` / ``_RPC.TXT`` beside it), or a GDAL VRT with an ``RPC`` metadata domain, through
  rasterio.

None of these families holds one model per band; ``band=`` is accepted for the day one does and
refused (a typed error) for a file of one model but ``band`` 1.

Errors (:mod:`photax.errors`): a file of no family is :class:`~photax.errors.UnsupportedFormatError`
naming the families looked for; a file of a family with a bad or missing value is
:class:`~photax.errors.MalformedFileError` naming the file and the line (text) or the key (XML,
JSON); neither quotes more than a short excerpt, and no parser's own exception (XML, YAML, JSON,
rasterio) reaches the caller.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import re
import warnings
from collections.abc import Callable

import numpy as np

from ..errors import MalformedFileError, UnsupportedFormatError
from ..rpc import COEFFICIENT_KEYS, DIRECT_KEYS, OFFSET_KEYS, SCALE_KEYS, RPCCamera
from . import files

WHAT = "RPC file"
_HEAD = 65536  # bytes looked at to recognise a file


# --- the format table ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Head:
    """What the sniffers look at: a file's first bytes, and as text (lenient UTF-8, BOM dropped)."""

    raw: bytes
    text: str

    @property
    def xml_root(self) -> str | None:
        """The name of the root element of an XML document (namespace prefix dropped), or None."""
        m = _XML_ROOT.match(self.text)
        return m.group(1).rpartition(":")[2] if m else None


# the first element after the prolog, comments, processing instructions and a DOCTYPE
_XML_ROOT = re.compile(
    r"\s*(?:(?:<\?.*?\?>|<!--.*?-->|<!DOCTYPE[^\[>]*(?:\[.*?\])?\s*>)\s*)*<([A-Za-z_][\w.:-]*)", re.S
)


@dataclasses.dataclass(frozen=True)
class RPCFormat:
    """One family of RPC files (module docstring).

    Attributes:
        name: the family's short name (what :func:`rpc_format` returns, ``write_rpc``'s ``format``).
        description: its vendors and files, for messages and ``docs/formats.md``.
        sniff: ``Head -> bool``: whether a file's first bytes are of this family (content only).
        read: ``(path, image, band) -> RPCCamera``.
        write: ``(rpc, path) -> None`` or None where photax does not write the family.
        entries: ``path -> tuple of image names`` for a family holding one RPC per image, else None.
    """

    name: str
    description: str
    sniff: Callable[[Head], bool]
    read: Callable
    write: Callable | None = None
    entries: Callable | None = None


def _head(path: pathlib.Path) -> Head:
    files.check_regular(path, WHAT)
    try:
        with path.open("rb") as fh:
            raw = fh.read(_HEAD)
    except OSError as exc:
        raise MalformedFileError(f"{path}: cannot read the {WHAT} ({exc.strerror or exc})") from None
    return Head(raw, raw.decode("utf-8", "replace").lstrip("\ufeff"))


def _path(path) -> pathlib.Path:
    p = pathlib.Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file")
    return p


def rpc_format(path) -> str:
    """The name of the RPC family of the file at ``path`` (:data:`FORMATS`), read from its content.

    Raises:
        UnsupportedFormatError: of no family photax reads (the message lists them).
        FileNotFoundError: no such file.

    Examples:
        >>> import pathlib, tempfile
        >>> import photax as ptx
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "notes.txt"
        >>> _ = path.write_text("LINE_OFF: 12.5 pixels")  # the key family, even if incomplete
        >>> ptx.rpc_format(path)
        'rpc-txt'
        >>> _ = path.write_text("hello")
        >>> ptx.rpc_format(path)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        photax.errors.UnsupportedFormatError: ...notes.txt: not an RPC file photax reads; it reads ...
    """
    return _format_of(_path(path)).name


def _format_of(path: pathlib.Path) -> RPCFormat:
    head = _head(path)
    for fmt in FORMATS:
        if fmt.sniff(head):
            return fmt
    raise UnsupportedFormatError(f"{path}: not an RPC file photax reads; it reads {families()}")


def families() -> str:
    """The families photax reads, in words (for messages).

    Examples:
        >>> from photax.io.satellite import families
        >>> "DIMAP v2/v3 XML" in families() and "KEY: value RPC text" in families()
        True
    """
    return "; ".join(f.description for f in FORMATS)


def rpc_images(path) -> tuple[str, ...] | None:
    """The image names of a file holding one RPC per image (orthority's ``rpc_param.yaml``, s2p's
    ``config.json``), or None for a file of one RPC.

    Examples:
        >>> import json, pathlib, tempfile
        >>> from photax.io.satellite import rpc_images
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "config.json"
        >>> _ = path.write_text(json.dumps({"images": [{"img": "in/a.tif", "rpc": {}}, {"img": "b.tif", "rpc": {}}]}))
        >>> rpc_images(path)
        ('a.tif', 'b.tif')
    """
    path = _path(path)
    fmt = _format_of(path)
    return None if fmt.entries is None else fmt.entries(path)


def read_rpc(path, image: str | None = None, *, band: int | None = None) -> RPCCamera:
    """The :class:`photax.RPCCamera` of any RPC file photax reads (module docstring), its family
    recognised by content, not by name.

    Args:
        path: the file: a vendor's RPC file, or an image with RPC metadata.
        image: the entry of a file with one RPC per image (orthority's YAML, s2p's ``config.json``);
            needed when it holds several.
        band: the band whose model to read, for a family with one model per band (none yet: a file
            of one model accepts None or 1).

    Raises:
        UnsupportedFormatError: a file of no family (the message lists them).
        MalformedFileError: a file of a family with a bad or missing value (naming the line or key).
        FileNotFoundError: no such file.

    Examples:
        An RPC (column ~ longitude, row ~ -latitude) written as GDAL's ``_RPC.TXT`` text under a name
        that says nothing, and read back by its content:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> c = np.zeros((4, 20)); c[[1, 3], 0] = 1.0; c[0, 2] = -1.0; c[2, 1] = 1.0
        >>> rpc = ptx.RPCCamera(c, [2.35, 48.85, 100.0, 5000.0, 5000.0], [0.05, 0.05, 500.0, 5000.0, 5000.0])
        >>> path = ptx.write_rpc(rpc, pathlib.Path(tempfile.mkdtemp()) / "scene metadata")
        >>> ptx.rpc_format(path)
        'rpc-txt'
        >>> [round(float(v), 6) for v in ptx.read_rpc(path)([2.375, 48.85, 100.0])]  # column, row (px)
        [7500.0, 5000.0]
    """
    path = _path(path)
    fmt = _format_of(path)
    if band is not None and band != 1:
        raise MalformedFileError(f"{path}: holds one model for all bands ({fmt.name}); band={band!r} is not in it")
    return fmt.read(path, image, band)


def read_sensor(path, crs=None, *, image: str | None = None):
    """The sensor of a file, recognised by content: an RPC file of any family :func:`read_rpc` reads
    (a :class:`photax.sensor.GroundSensor` of its :class:`~photax.RPCCamera`), or a photax push-broom
    camera file (:func:`photax.io.read_pushbroom`).

    Args:
        path: the file.
        crs: the map CRS the sensor's ground points are in (default: the UTM zone of its scene centre).
        image: the entry of a file with one RPC per image.

    Raises:
        UnsupportedFormatError: neither (the message lists the families looked for).

    Examples:
        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> c = np.zeros((4, 20)); c[[1, 3], 0] = 1.0; c[0, 2] = -1.0; c[2, 1] = 1.0
        >>> rpc = ptx.RPCCamera(c, [2.35, 48.85, 100.0, 5000.0, 5000.0], [0.05, 0.05, 500.0, 5000.0, 5000.0])
        >>> sensor = ptx.read_sensor(ptx.write_rpc(rpc, pathlib.Path(tempfile.mkdtemp()) / "x.RPB", "rpb"))
        >>> type(sensor).__name__, sensor.camera.image_size
        ('GroundSensor', None)
    """
    from ..sensor import GroundSensor, utm_crs
    from .pushbroom_file import is_pushbroom_file, read_pushbroom

    path = _path(path)
    if is_pushbroom_file(path):
        camera = read_pushbroom(path)
    else:
        try:
            camera = read_rpc(path, image)
        except UnsupportedFormatError:
            raise UnsupportedFormatError(
                f"{path}: not a sensor file photax reads; it reads a photax push-broom camera file and the RPC "
                f"families {families()}"
            ) from None
    if crs is None:
        crs = utm_crs(*(float(v) for v in camera.ground_box()[0]))
    return GroundSensor(camera, crs)


def write_rpc(rpc: RPCCamera, path, format: str = "rpc-txt") -> pathlib.Path:
    """Write ``rpc`` as ``format``: ``"rpc-txt"`` (GDAL's ``_RPC.TXT`` ``KEY: value`` text, with the
    direct model as the extended IKONOS keys when there is one), ``"rpb"`` (DigitalGlobe's ``.RPB``) or
    ``"geotiff"`` (the RPC tags of the existing GeoTIFF ``path``, rewritten; GDAL, QGIS and rasterio then
    use them).

    A refined RPC's image-space correction (:func:`photax.refine_rpc`) is folded into the written
    RPC, as no file holds it apart: a shift and a scale per axis exactly (into the line and sample
    offsets and scales); a correction that mixes the axes (shift-drift, affine) by refitting the RPC
    to the corrected model (:func:`photax.fit_rpc`, which needs ``rpc.image_size``), refused if the
    refit misses by more than 1e-3 px.  Text files are written atomically; ``"geotiff"`` writes a
    copy of the image and renames it over the original.

    Returns:
        the path written.

    Examples:
        A shift refined on GCPs, folded into the offsets of the ``.RPB`` written:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> c = np.zeros((4, 20)); c[[1, 3], 0] = 1.0; c[0, 2] = -1.0; c[2, 1] = 1.0
        >>> rpc = ptx.RPCCamera(c, [2.35, 48.85, 100.0, 5000.0, 5000.0], [0.05, 0.05, 500.0, 5000.0, 5000.0])
        >>> refined = rpc.replace(correction=[[2.5, 0.0, 0.0], [-1.0, 0.0, 0.0]])
        >>> back = ptx.read_rpc(ptx.write_rpc(refined, pathlib.Path(tempfile.mkdtemp()) / "x.RPB", "rpb"))
        >>> [float(v) for v in back.offsets[3:]], [float(v) for v in back([2.35, 48.85, 100.0])]
        ([5002.5, 4999.0], [5002.5, 4999.0])
    """
    if format not in WRITE_FORMATS:
        raise ValueError(f"format: expected one of {', '.join(WRITE_FORMATS)}, got {format!r}")
    family = next(f for f in FORMATS if f.name == WRITE_FORMATS[format])
    path = pathlib.Path(path)
    family.write(folded(rpc), path)
    return path


def folded(rpc: RPCCamera) -> RPCCamera:
    """``rpc`` with its image-space correction folded into the RPC itself (:func:`write_rpc`).

    Examples:
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io.satellite import folded
        >>> c = np.zeros((4, 20)); c[[1, 3], 0] = 1.0; c[0, 2] = -1.0; c[2, 1] = 1.0
        >>> rpc = ptx.RPCCamera(c, [2.35, 48.85, 100.0, 5000.0, 5000.0], [0.05, 0.05, 500.0, 5000.0, 5000.0])
        >>> plain = folded(rpc.replace(correction=[[1.0, 0.01, 0.0], [0.0, 0.0, 0.0]]))
        >>> [float(v) for v in plain.offsets[3:]], [float(v) for v in plain.scales[3:]], float(np.abs(plain.correction).max())
        ([5051.0, 5000.0], [5050.0, 5000.0], 0.0)
    """
    k = np.asarray(rpc.correction)
    if not np.any(k):
        return rpc
    o, s = np.asarray(rpc.offsets).copy(), np.asarray(rpc.scales).copy()
    if k[0, 2] == 0 and k[1, 1] == 0:  # column from column, row from row: offsets and scales
        for axis, gain in ((3, 1 + k[0, 1]), (4, 1 + k[1, 2])):
            if not gain > 0:
                raise ValueError(f"RPC correction: a gain of {gain} on the {'sample' if axis == 3 else 'line'} axis")
        o[3], s[3] = (1 + k[0, 1]) * o[3] + k[0, 0], (1 + k[0, 1]) * s[3]
        o[4], s[4] = (1 + k[1, 2]) * o[4] + k[1, 0], (1 + k[1, 2]) * s[4]
        return rpc.replace(offsets=o, scales=s, correction=np.zeros((2, 3)))
    if rpc.image_size is None:
        raise ValueError(
            "RPC correction mixes the image axes (shift-drift or affine): writing it needs a refit over the "
            "image, and the RPC has no image_size"
        )
    from ..pushbroom import fit_rpc

    fit = fit_rpc(rpc, rpc.height_range)
    if not fit.check_max_error < 1e-3:
        raise ValueError(f"RPC correction: the refit RPC misses the refined one by {fit.check_max_error:.2g} px")
    return fit.camera.replace(image_size=rpc.image_size, localization=rpc.localization)


# --- shared pieces ------------------------------------------------------------------------------


def _bad(path, line: int | None, message: str) -> MalformedFileError:
    return MalformedFileError(str(files.file_error(path, line, message)))


def _num(path, line, text, what: str) -> float:
    try:
        return files.number(path, line, text, what)
    except ValueError as exc:
        raise MalformedFileError(str(exc)) from None


def _camera(path, parts: dict, where: Callable[[str], str], image_size=None) -> RPCCamera:
    """An RPCCamera from GDAL-keyed ``parts`` (coefficient rows as lists of 20); a missing key is named
    with ``where(key)`` (the file's spelling and place)."""
    keys = (*COEFFICIENT_KEYS, *OFFSET_KEYS, *SCALE_KEYS)
    missing = [where(k) for k in keys if parts.get(k) is None]
    if missing:
        raise MalformedFileError(f"{path}: missing {', '.join(missing)}")
    for k in (*COEFFICIENT_KEYS, *DIRECT_KEYS):
        if parts.get(k) is not None and len(parts[k]) != 20:
            raise MalformedFileError(f"{path}: {where(k)} has {len(parts[k])} coefficients, expected 20")
    have = [k for k in DIRECT_KEYS if parts.get(k) is not None]
    if have and len(have) < 4:
        missing = [where(k) for k in DIRECT_KEYS if parts.get(k) is None]
        raise MalformedFileError(f"{path}: a direct model without {', '.join(missing)}")
    direct = np.array([parts[k] for k in DIRECT_KEYS]) if have else None
    scales = [parts[k] for k in SCALE_KEYS]
    zero = [where(k) for k, v in zip(SCALE_KEYS, scales, strict=True) if v == 0]
    if zero:
        raise MalformedFileError(f"{path}: zero scale {', '.join(zero)}")
    for rows in (np.array([parts[k] for k in COEFFICIENT_KEYS]), direct):
        if rows is not None and np.any(np.all(rows[[1, 3]] == 0, axis=1)):
            raise MalformedFileError(f"{path}: a denominator with every coefficient zero")
    try:
        return RPCCamera(
            np.array([parts[k] for k in COEFFICIENT_KEYS]),
            [parts[k] for k in OFFSET_KEYS],
            scales,
            image_size=image_size,
            direct=direct,
        )
    except ValueError as exc:
        raise MalformedFileError(f"{path}: {exc}") from None


def _text(path) -> str:
    try:
        return files.read_text(path, WHAT)
    except MalformedFileError:
        raise
    except ValueError as exc:
        raise MalformedFileError(str(exc)) from None


def _no_entries(path, image, kind: str) -> None:
    if image is not None:
        raise MalformedFileError(f"{path}: a {kind} file holds one RPC; image={image!r} names none")


# --- KEY: value text (IKONOS, Planet, SkySat, GDAL _RPC.TXT) ---------------------------------------

_TXT_SNIFF = re.compile(
    r"^[ \t]*(LINE_OFF|SAMP_OFF|LAT_OFF|LONG_OFF|HEIGHT_OFF|LINE_SCALE|LINE_NUM_COEFF_1)[ \t]*:", re.M
)
_TXT_DIRECT = {"lon_num_coeff": "LON_NUM_COEFF", "lon_den_coeff": "LON_DEN_COEFF",
               "lat_num_coeff": "LAT_NUM_COEFF", "lat_den_coeff": "LAT_DEN_COEFF"}  # fmt: skip


def _sniff_txt(head: Head) -> bool:
    return head.xml_root is None and bool(_TXT_SNIFF.search(head.text))


def _read_txt(path, image=None, band=None) -> RPCCamera:
    _no_entries(path, image, "KEY: value text")
    text = _text(path)
    fields: dict[str, tuple[int, str]] = {}
    for n, line in enumerate(files.split_lines(text), 1):
        key, sep, value = line.partition(":")
        key = key.strip().upper()
        if not sep or not re.fullmatch(r"[A-Z][A-Z0-9_]*", key):
            continue  # a title, a comment
        if key in fields:
            raise _bad(path, n, f"{key} given twice (first on line {fields[key][0]})")
        fields[key] = (n, value.split()[0] if value.split() else "")
    spelled = {k: k.upper() for k in (*OFFSET_KEYS, *SCALE_KEYS)}
    parts: dict = {}
    for k, name in spelled.items():
        if name in fields:
            n, v = fields[name]
            parts[k] = _num(path, n, v, name)
    for k, name in [*((k, k.upper()) for k in COEFFICIENT_KEYS), *_TXT_DIRECT.items()]:
        names = [f"{name}_{i}" for i in range(1, 21)]
        present = [x for x in names if x in fields]
        if not present:
            continue
        absent = [x for x in names if x not in fields]
        if absent:
            raise _bad(path, None, f"missing {', '.join(absent)}")
        parts[k] = [_num(path, fields[x][0], fields[x][1], x) for x in names]

    def where(k):
        name = spelled.get(k) or _TXT_DIRECT.get(k) or k.upper()
        return name if k in spelled else f"{name}_1 .. _20"

    return _camera(path, parts, where)


def _fmt(v: float) -> str:
    return repr(float(v))  # the shortest text that reads back the same float64


def _write_txt(rpc: RPCCamera, path: pathlib.Path) -> None:
    from .atomic import atomic_write

    o, s = np.asarray(rpc.offsets), np.asarray(rpc.scales)
    units = ("degrees", "degrees", "meters", "pixels", "pixels")
    order = (4, 3, 1, 0, 2)  # GDAL's order: LINE, SAMP, LAT, LONG, HEIGHT
    lines = [f"{OFFSET_KEYS[i].upper()}: {_fmt(o[i])} {units[i]}" for i in order]
    lines += [f"{SCALE_KEYS[i].upper()}: {_fmt(s[i])} {units[i]}" for i in order]
    rows = [(k.upper(), c) for k, c in zip(COEFFICIENT_KEYS, np.asarray(rpc.coefficients), strict=True)]
    if rpc.direct is not None:
        rows += [(_TXT_DIRECT[k], c) for k, c in zip(DIRECT_KEYS, np.asarray(rpc.direct), strict=True)]
    for name, row in rows:
        lines += [f"{name}_{i}: {_fmt(c)}" for i, c in enumerate(row, 1)]
    with atomic_write(path) as fh:
        fh.write("\n".join(lines) + "\n")


# --- .RPB (DigitalGlobe) -------------------------------------------------------------------------

_RPB_KEYS = {
    "lineOffset": "line_off", "sampOffset": "samp_off", "latOffset": "lat_off", "longOffset": "long_off",
    "heightOffset": "height_off", "lineScale": "line_scale", "sampScale": "samp_scale",
    "latScale": "lat_scale", "longScale": "long_scale", "heightScale": "height_scale",
    "lineNumCoef": "line_num_coeff", "lineDenCoef": "line_den_coeff",
    "sampNumCoef": "samp_num_coeff", "sampDenCoef": "samp_den_coeff",
}  # fmt: skip
_RPB_SNIFF = re.compile(r"^[ \t]*(satId|bandId|SpecId|BEGIN_GROUP|lineOffset|sampOffset)[ \t]*=", re.M)


def _sniff_rpb(head: Head) -> bool:
    return head.xml_root is None and bool(_RPB_SNIFF.search(head.text))


_RPB_STATEMENT = re.compile(r"(\w+)[ \t]*=[ \t]*(\([^)]*\)|[^;\n]*);")  # a list may span lines, a value not


def _read_rpb(path, image=None, band=None) -> RPCCamera:
    _no_entries(path, image, ".RPB")
    text = _text(path)
    parts: dict = {}
    seen: dict[str, int] = {}
    for m in _RPB_STATEMENT.finditer(text):
        key, value = m.group(1), m.group(2).strip()
        if key not in _RPB_KEYS:
            continue
        line = text.count("\n", 0, m.start(1)) + 1
        if key in seen:
            raise _bad(path, line, f"{key} given twice (first on line {seen[key]})")
        seen[key] = line
        if value.startswith("("):
            parts[_RPB_KEYS[key]] = [_num(path, line, v, key) for v in value[1:-1].split(",") if v.strip()]
        else:
            parts[_RPB_KEYS[key]] = _num(path, line, value, key)
    names = {v: k for k, v in _RPB_KEYS.items()}
    return _camera(path, parts, lambda k: names[k])


def _write_rpb(rpc: RPCCamera, path: pathlib.Path) -> None:
    from .atomic import atomic_write

    o, s = np.asarray(rpc.offsets), np.asarray(rpc.scales)
    names = {v: k for k, v in _RPB_KEYS.items()}
    lines = ['satId = "UNKNOWN";', 'bandId = "UNKNOWN";', 'SpecId = "RPC00B";', "BEGIN_GROUP = IMAGE"]
    for i in (4, 3, 1, 0, 2):
        lines.append(f"\t{names[OFFSET_KEYS[i]]} = {_fmt(o[i])};")
    for i in (4, 3, 1, 0, 2):
        lines.append(f"\t{names[SCALE_KEYS[i]]} = {_fmt(s[i])};")
    for k, row in zip(COEFFICIENT_KEYS, np.asarray(rpc.coefficients), strict=True):
        body = ",\n".join(f"\t\t\t{_fmt(c)}" for c in row)
        lines.append(f"\t{names[k]} = (\n{body});")
    lines += ["END_GROUP = IMAGE", "END;"]
    with atomic_write(path) as fh:
        fh.write("\n".join(lines) + "\n")


# --- XML (DIMAP, Maxar ISD) ----------------------------------------------------------------------


def _xml(path) -> tuple[str, object]:
    from xml.etree import ElementTree

    text = _text(path)
    if re.search(r"<!ENTITY", text[:_HEAD]):  # no entity expansion (billion laughs), no external entities
        raise _bad(path, text.count("\n", 0, text.find("<!ENTITY")) + 1, "an XML entity declaration: not read")
    try:
        return text, ElementTree.fromstring(text)
    except ElementTree.ParseError as exc:
        line = exc.position[0] if getattr(exc, "position", None) else None
        raise _bad(path, line, "not well-formed XML") from None


def _local(tag: str) -> str:
    return tag.rpartition("}")[2]


def _child(node, name: str):
    for c in node:
        if _local(c.tag) == name:
            return c
    return None


def _find(node, *names):
    """The first descendant along ``names`` (local names, any depth for the first)."""
    for start in node.iter():
        if _local(start.tag) != names[0]:
            continue
        cur = start
        for n in names[1:]:
            cur = _child(cur, n)
            if cur is None:
                break
        if cur is not None:
            return cur
    return None


def _xml_line(text: str, tag: str, within: str = "") -> int | None:
    """The line of the first ``<tag>`` after the first ``<within>`` (the element's section)."""
    start = max(text.find(f"<{within}"), 0) if within else 0
    i = text.find(f"<{tag}>", start)
    if i < 0:
        i = text.find(f"<{tag}", start)
    return None if i < 0 else text.count("\n", 0, i) + 1


def _xml_value(path, text, node, tag: str, where: str) -> float | None:
    el = _child(node, tag) if node is not None else None
    if el is None:
        return None
    return _num(path, _xml_line(text, tag, where.split("/")[-1]), (el.text or "").strip(), f"{where}/{tag}")


def _sniff_dimap(head: Head) -> bool:
    return head.xml_root == "Dimap_Document"


def _read_dimap(path, image=None, band=None, *, _followed: bool = False) -> RPCCamera:
    _no_entries(path, image, "DIMAP")
    text, root = _xml(path)
    rfm = _find(root, "Rational_Function_Model")
    grfm = _find(rfm, "Global_RFM") if rfm is not None else None
    grfm = grfm if grfm is not None else rfm
    models = None
    if grfm is not None:
        for inverse, direct, lon, lat in (("Inverse_Model", "Direct_Model", "SAMP", "LINE"),
                                          ("GroundtoImage_Values", "ImagetoGround_Values", "LON", "LAT")):  # fmt: skip
            if _child(grfm, inverse) is not None:
                models = (_child(grfm, inverse), _child(grfm, direct), lon, lat, inverse, direct)
                break
    if models is None:
        # a main DIM_*.XML: the RPC is in the file its Rational_Function_Model / Geoposition names
        if not _followed:
            for el in root.iter():
                href = el.get("href", "")
                if _local(el.tag) == "COMPONENT_PATH" and "RPC" in pathlib.Path(href).name.upper():
                    target = path.parent / href
                    if target.is_file():
                        return _read_dimap(target, None, band, _followed=True)
                    raise MalformedFileError(f"{path}: names its RPC file {files.excerpt(href)}, which is not there")
        fmt = _find(root, "METADATA_FORMAT")
        v1 = fmt is not None and str(fmt.get("version", "")).startswith("1")
        raise _bad(
            path,
            None,
            "a DIMAP document without a Rational_Function_Model (Inverse_Model or GroundtoImage_Values)"
            + ("; DIMAP v1 (SPOT 1-5, Formosat) carries a physical sensor model, not an RPC" if v1 else ""),
        )
    inv, dire, lon_prefix, lat_prefix, inv_name, dir_name = models
    parts: dict = {}

    def row(node, prefix, where):
        values = []
        for i in range(1, 21):
            v = _xml_value(path, text, node, f"{prefix}_{i}", where)
            if v is None:
                raise _bad(path, None, f"missing {where}/{prefix}_{i}")
            values.append(v)
        return values

    for k in COEFFICIENT_KEYS:
        parts[k] = row(inv, k.upper(), inv_name)
    if dire is not None:
        # v2's Direct_Model names lon's ratio SAMP_* and lat's LINE_*, v3's LON_* and LAT_*
        for k, prefix in zip(DIRECT_KEYS, (f"{lon_prefix}_NUM_COEFF", f"{lon_prefix}_DEN_COEFF",
                                           f"{lat_prefix}_NUM_COEFF", f"{lat_prefix}_DEN_COEFF"), strict=True):  # fmt: skip
            parts[k] = row(dire, prefix, dir_name)
    validity = _child(grfm, "RFM_Validity")
    names = {k: k.upper() for k in (*OFFSET_KEYS, *SCALE_KEYS)}
    for k, tag in names.items():
        parts[k] = _xml_value(path, text, validity, tag, "RFM_Validity")
    # DIMAP v2 counts pixels from (1, 1); v3 says where (GDAL's DIMAP reader does the same)
    first = 1.0
    domain = _find(root, "ImagetoGround_Validity_Domain")
    if domain is not None:
        v = _xml_value(path, text, domain, "FIRST_COL", "ImagetoGround_Validity_Domain")
        first = 1.0 if v is None else v
    for k in ("line_off", "samp_off"):
        if parts[k] is not None:
            parts[k] -= first
    return _camera(path, parts, lambda k: f"RFM_Validity/{names[k]}" if k in names else f"{inv_name}/{k.upper()}_n")


def _sniff_maxar(head: Head) -> bool:
    return head.xml_root == "isd"


_ISD_KEYS = {"line_off": "LINEOFFSET", "samp_off": "SAMPOFFSET", "lat_off": "LATOFFSET",
             "long_off": "LONGOFFSET", "height_off": "HEIGHTOFFSET", "line_scale": "LINESCALE",
             "samp_scale": "SAMPSCALE", "lat_scale": "LATSCALE", "long_scale": "LONGSCALE",
             "height_scale": "HEIGHTSCALE"}  # fmt: skip
_ISD_COEFFS = {"line_num_coeff": "LINENUMCOEF", "line_den_coeff": "LINEDENCOEF",
               "samp_num_coeff": "SAMPNUMCOEF", "samp_den_coeff": "SAMPDENCOEF"}  # fmt: skip


def _read_maxar(path, image=None, band=None) -> RPCCamera:
    _no_entries(path, image, "Maxar ISD")
    text, root = _xml(path)
    block = _find(root, "RPB", "IMAGE")
    if block is None:
        raise _bad(path, None, "an ISD document without an RPB/IMAGE block (the RPC)")
    parts: dict = {k: _xml_value(path, text, block, tag, "RPB/IMAGE") for k, tag in _ISD_KEYS.items()}
    for k, tag in _ISD_COEFFS.items():
        lst = _child(block, tag + "List")
        el = _child(lst, tag) if lst is not None else None
        if el is None:
            continue
        line = _xml_line(text, tag, "RPB")
        parts[k] = [_num(path, line, v, f"RPB/IMAGE/{tag}List/{tag}") for v in (el.text or "").split()]
    where = {**_ISD_KEYS, **{k: f"{v}List/{v}" for k, v in _ISD_COEFFS.items()}}
    return _camera(path, parts, lambda k: "RPB/IMAGE/" + where[k])


# --- orthority YAML, rpcm / s2p JSON ---------------------------------------------------------------

_YAML_SNIFF = re.compile(r"^[ \t]+rpc[ \t]*:", re.M)


def _sniff_orthority(head: Head) -> bool:
    return head.xml_root is None and not head.text.lstrip().startswith("{") and bool(_YAML_SNIFF.search(head.text))


def _load(path, loader):
    text = _text(path)
    try:
        return loader(path, text)
    except MalformedFileError:
        raise
    except ValueError as exc:
        raise MalformedFileError(str(exc)) from None


def _pick(path, doc: dict, image, what: str):
    if image is None:
        if len(doc) > 1:
            names = ", ".join(files.excerpt(str(k), 30) for k in list(doc)[:8])
            raise MalformedFileError(
                f"{path}: holds {len(doc)} images ({names}{', ...' if len(doc) > 8 else ''}): pass image="
            )
        image = next(iter(doc))
    if image not in doc:
        from ..errors import NoEntryError

        raise NoEntryError(f"{path}: no entry {files.excerpt(str(image))} ({what})")
    return image, doc[image]


def _orthority_doc(path) -> dict:
    doc = _load(path, files.load_yaml)
    if not isinstance(doc, dict) or not doc:
        raise _bad(path, None, "not an orthority RPC file (expected a mapping of image names)")
    return doc


def _read_orthority(path, image=None, band=None) -> RPCCamera:
    doc = _orthority_doc(path)
    image, entry = _pick(path, doc, image, f"it has {len(doc)}")
    line = doc.line(image) if isinstance(doc, files.Mapping) else None
    if not isinstance(entry, dict) or not isinstance(entry.get("rpc"), dict):
        raise _bad(path, line, f"entry {files.excerpt(str(image))} has no 'rpc' mapping")
    rpc = entry["rpc"]
    parts: dict = {}
    for k in (*OFFSET_KEYS, *SCALE_KEYS):
        if rpc.get(k) is not None:
            parts[k] = _num(path, rpc.line(k) if isinstance(rpc, files.Mapping) else line, rpc[k], k)
    for k in COEFFICIENT_KEYS:
        if rpc.get(k) is not None:
            values = files.as_numbers(rpc[k])
            n = rpc.line(k) if isinstance(rpc, files.Mapping) else line
            if values is None or values.ndim != 1 or not np.all(np.isfinite(values)):
                raise _bad(path, n, f"{k}: expected a list of 20 finite numbers")
            parts[k] = values.tolist()
    size = entry.get("im_size")
    size_arr = files.as_numbers(size) if size is not None else None
    if size is not None and (
        size_arr is None or size_arr.shape != (2,) or not np.all(size_arr >= 1) or not np.all(size_arr < 2**31)
        or not np.all(size_arr == np.round(size_arr))
    ):  # fmt: skip
        raise _bad(path, line, f"entry {files.excerpt(str(image))}: im_size must be two positive integers")
    try:
        return _camera(path, parts, lambda k: f"rpc.{k}", None if size is None else size_arr.astype(int))
    except MalformedFileError as exc:
        raise MalformedFileError(str(exc).replace(f"{path}: ", f"{path} [{image}]: ", 1)) from None


def _orthority_entries(path) -> tuple[str, ...]:
    return tuple(str(k) for k in _orthority_doc(path))


_RPCM_KEYS = {"line_off": "row_offset", "samp_off": "col_offset", "lat_off": "lat_offset",
              "long_off": "lon_offset", "height_off": "alt_offset", "line_scale": "row_scale",
              "samp_scale": "col_scale", "lat_scale": "lat_scale", "long_scale": "lon_scale",
              "height_scale": "alt_scale", "line_num_coeff": "row_num", "line_den_coeff": "row_den",
              "samp_num_coeff": "col_num", "samp_den_coeff": "col_den", "lon_num_coeff": "lon_num",
              "lon_den_coeff": "lon_den", "lat_num_coeff": "lat_num", "lat_den_coeff": "lat_den"}  # fmt: skip


def _sniff_json(head: Head) -> bool:
    t = head.text.lstrip()
    return t.startswith("{") and bool(re.search(r'"(row_num|col_offset|LINE_NUM_COEFF|LINE_OFF|rpc)"', t))


def _json_doc(path):
    doc = _load(path, files.load_json)
    if not isinstance(doc, dict):
        raise _bad(path, None, "not an rpcm / s2p RPC file (expected a JSON object)")
    return doc


def _s2p_images(path, doc) -> dict | None:
    images = doc.get("images")
    if not isinstance(images, list):
        return None
    out = {}
    for i, entry in enumerate(images):
        if isinstance(entry, dict) and isinstance(entry.get("rpc"), dict):
            name = pathlib.Path(str(entry.get("img", f"image {i + 1}"))).name
            out.setdefault(name, entry["rpc"])
    return out


def _read_json(path, image=None, band=None) -> RPCCamera:
    doc = _json_doc(path)
    entries = _s2p_images(path, doc)
    label = ""
    if entries is not None:
        if not entries:
            raise _bad(path, None, "an s2p config whose images carry no 'rpc'")
        image, doc = _pick(path, entries, image, f"its images are {', '.join(list(entries)[:8])}")
        label = f"images[{image}].rpc."
    else:
        _no_entries(path, image, "rpcm JSON")
    upper = "LINE_OFF" in doc or "LINE_NUM_COEFF" in doc
    parts: dict = {}
    for k, rk in _RPCM_KEYS.items():
        key = k.upper() if upper else rk
        if upper and k in DIRECT_KEYS:
            key = _TXT_DIRECT[k]
        v = doc.get(key)
        if v is None:
            continue
        if k in (*COEFFICIENT_KEYS, *DIRECT_KEYS):
            values = files.as_numbers(v.split() if isinstance(v, str) else v)
            if values is None or values.ndim != 1 or not np.all(np.isfinite(values)):
                raise _bad(path, None, f"{label}{key}: expected 20 finite numbers")
            parts[k] = values.tolist()
        else:
            parts[k] = _num(path, None, v if not isinstance(v, bool) else "bool", label + key)

    def where(k):
        key = k.upper() if upper else _RPCM_KEYS[k]
        return label + (_TXT_DIRECT.get(k, key) if upper else key)

    return _camera(path, parts, where)


def _json_entries(path) -> tuple[str, ...] | None:
    entries = _s2p_images(path, _json_doc(path))
    return None if entries is None else tuple(entries)


# --- rasters through rasterio (GeoTIFF, NITF, JPEG 2000, VRT) ------------------------------------

_MAGIC = (
    b"II*\x00",
    b"MM\x00*",
    b"II+\x00",
    b"MM\x00+",
    b"NITF",
    b"NSIF",
    b"\x00\x00\x00\x0cjP  ",
    b"\xff\x4f\xff\x51",
)


def _sniff_raster(head: Head) -> bool:
    return head.raw.startswith(_MAGIC) or head.xml_root == "VRTDataset"


def _read_raster(path, image=None, band=None) -> RPCCamera:
    _no_entries(path, image, "raster")
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioError

    try:
        with warnings.catch_warnings():  # an image without RPCs is an error below, not a warning here
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            src = rasterio.open(path)
        with src:
            rpcs, size = src.rpcs, (src.width, src.height)
    except (RasterioError, OSError) as exc:
        raise MalformedFileError(
            f"{path}: GDAL cannot read it ({files.excerpt(str(exc).splitlines()[0], 80)})"
        ) from None
    if rpcs is None:
        raise MalformedFileError(
            f"{path}: has no RPC metadata (GDAL found none in it nor in a .RPB / _RPC.TXT beside it)"
        )
    d = rpcs.to_dict()
    parts = {k: (None if d.get(k) is None else (list(d[k]) if k in COEFFICIENT_KEYS else float(d[k]))) for k in d}
    for k in (*OFFSET_KEYS, *SCALE_KEYS):
        if parts.get(k) is not None and not math.isfinite(parts[k]):
            raise MalformedFileError(f"{path}: RPC metadata {k.upper()} is not finite")
    return _camera(path, parts, lambda k: f"RPC metadata {k.upper()}", size)


def _write_geotiff(rpc: RPCCamera, path: pathlib.Path) -> None:
    import shutil

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioError
    from rasterio.rpc import RPC

    from .atomic import atomic_path

    if not path.is_file() or not _head(path).raw.startswith(_MAGIC[:4]):
        raise ValueError(f"{path}: write_rpc(format='geotiff') rewrites the RPC tags of an existing GeoTIFF")
    try:
        with atomic_path(path) as tmp:
            shutil.copyfile(path, tmp)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                with rasterio.open(tmp, "r+") as dst:
                    dst.rpcs = RPC(**rpc.to_dict())
    except RasterioError as exc:
        raise MalformedFileError(f"{path}: GDAL cannot write its RPC tags ({files.excerpt(str(exc), 80)})") from None


# The one table: each family's sniffer, reader and writer, in the order they are tried.
FORMATS: tuple[RPCFormat, ...] = (
    RPCFormat("raster", "an image with RPC metadata GDAL reads (GeoTIFF RPC tags, NITF, JPEG 2000, a GDAL VRT)",
              _sniff_raster, _read_raster, _write_geotiff),
    RPCFormat("dimap", "DIMAP v2/v3 XML (Pleiades, SPOT 6/7, Pleiades Neo)", _sniff_dimap, _read_dimap),
    RPCFormat("maxar-xml", "DigitalGlobe/Maxar ISD XML (WorldView, GeoEye, QuickBird <RPB>)", _sniff_maxar,
              _read_maxar),
    RPCFormat("rpcm-json", "rpcm / s2p JSON", _sniff_json, _read_json, entries=_json_entries),
    RPCFormat("orthority", "orthority rpc_param.yaml", _sniff_orthority, _read_orthority,
              entries=_orthority_entries),
    RPCFormat("rpb", "DigitalGlobe .RPB text", _sniff_rpb, _read_rpb, _write_rpb),
    RPCFormat("rpc-txt", "KEY: value RPC text (IKONOS, Planet, SkySat, GDAL _RPC.TXT)", _sniff_txt, _read_txt,
              _write_txt),
)  # fmt: skip
# write_rpc's format names -> the family that writes it (GeoTIFF tags: the raster family)
WRITE_FORMATS = {"rpc-txt": "rpc-txt", "rpb": "rpb", "geotiff": "raster"}
