"""Agisoft Metashape's (and PhotoScan's) camera calibration XML and "Omega Phi Kappa" camera export,
and Pix4D's ``calibrated_external_camera_parameters.txt``.

**Calibration XML** (Tools > Camera Calibration > Export, ``<calibration>``;
also every ``<calibration>`` of an *Export Cameras* ``cameras.xml``, named by
its ``<sensor label>``, the ``class="adjusted"`` one where both are there).
The frame model (Metashape Professional manual, Appendix C "Camera models")::

    x = X / Z, y = Y / Z          camera frame x right, y down, z forward
    r^2 = x^2 + y^2
    x' = x (1 + K1 r^2 + K2 r^4 + K3 r^6 + K4 r^8) + (P1 (r^2 + 2 x^2) + 2 P2 x y) (1 + P3 r^2 + P4 r^4)
    y' = y (1 + K1 r^2 + K2 r^4 + K3 r^6 + K4 r^8) + (P2 (r^2 + 2 y^2) + 2 P1 x y) (1 + P3 r^2 + P4 r^4)
    u = w / 2 + cx + x' (f + B1) + y' B2
    v = h / 2 + cy + y' f

``cx, cy`` are offsets of the principal point from the image centre, and the
image centre is ``(w/2, h/2)``: the origin is the top-left *corner*, so photax's
pixel is ``(u - 0.5, v - 0.5)``.  Metashape's ``P1, P2`` are OpenCV's ``p2,
p1`` (their roles swap), so photax's (y up) are ``p1 = -P2``, ``p2 = P1``.
``B1`` (affinity) becomes photax's pixel aspect: ``f_x = f + B1``,
``pixel_size = (1, (f + B1) / f)``, exactly.  **Not converted**: ``K4``,
``P3``, ``P4`` and ``B2`` (skew) have no photax term: a file where one is not
zero is refused, naming it (never dropped).  Projections other than ``frame``
(``fisheye``, ``spherical``, ...) are refused by name; so is PhotoScan 1.x's
older layout (``fx``, ``fy``).

**Omega Phi Kappa export** (File > Export > Export Cameras, "Omega Phi Kappa
(*.txt)"): ``# Cameras (n)``, ``# PhotoID, X, Y, Z, Omega, Phi, Kappa, r11,
r12, r13, r21, r22, r23, r31, r32, r33``, then one tab-separated line per
camera.  The angles are degrees in the photogrammetric omega-phi-kappa
(photax's ``"omega-phi-kappa"``, as orthority and Pix4D's PATB); the matrix,
row by row, is the world -> camera rotation of the same angles in the
photogrammetric camera frame (x right, y up, z back): ``r = R^T`` with ``R =
Rx(omega) Ry(phi) Rz(kappa)`` photax's world_from_camera, i.e. the classical
collinearity matrix ``M`` (``m11 = cos(phi) cos(kappa)``, ``m31 = sin(phi)``,
``m33 = cos(omega) cos(phi)``).  Metashape's manual does not define
``r11..r33`` (none found); this layout is the one two independent programs
that use real Metashape exports read: the Camera Projection Painter add-on
(its ``MS_PIDXYZOPK`` reader and writer: camera-to-world ``= r^T`` in
Blender's y-up, z-back camera frame, while its Metashape XML reader flips
that XML's y-down frame) and a photomontage tool's ``readOPKFile`` +
``colinearite`` (``r (X - S)``, then ``u = w/2 + cx - f x``, ``v = h/2 + cy +
f y``: a y-up, z-back frame).  Each line's matrix is checked against its
angles (to 1e-4), so a file whose angles mean another rotation -- or whose
matrix is in Metashape's own y-down camera frame, ``diag(1, -1, -1) R^T``,
the same camera looking up -- is refused, not misread.  Positions are in
the chunk's CRS, which the file does not name.

**Pix4D** ``*_calibrated_external_camera_parameters.txt``: a header
``imageName X Y Z Omega Phi Kappa`` then one space-separated line per image;
angles in degrees, PATB omega-phi-kappa (Pix4D, "How are the Internal and
External Camera Parameters defined"): photax's ``"omega-phi-kappa"``
unchanged.  Positions in the project's output CRS (not named in the file).
Pix4D's ``.cam`` internal parameters: :mod:`photax.io.pix4d`.
"""

from __future__ import annotations

import math
import pathlib
import xml.etree.ElementTree as ET

import numpy as np

from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from ..errors import UnsupportedFormatError
from .files import excerpt, file_error, head_text, number, read_text, split_lines

_TERMS = ("f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2", "p3", "p4")
_NOT_CONVERTED = ("k4", "p3", "p4", "b2")


def _parse_xml(path: pathlib.Path) -> ET.Element:
    text = read_text(path, "camera file")
    if "<!DOCTYPE" in text or "<!ENTITY" in text:
        raise file_error(path, None, "an XML document type or entity declaration: not a Metashape calibration")
    try:
        return ET.fromstring(text)
    except ET.ParseError as exc:
        line = exc.position[0] if getattr(exc, "position", None) else None
        raise file_error(path, line, "not well-formed XML") from None


def is_metashape_xml(path) -> bool:
    """Whether ``path`` looks like a Metashape calibration or cameras XML (by its start, cheaply)."""
    path = pathlib.Path(path)
    if path.suffix.lower() != ".xml":
        return False
    head = head_text(path, 4096)
    return "<calibration" in head or "<document" in head


def _calibration(path, name, cal: ET.Element) -> FrameCamera:
    at = f"calibration {excerpt(name)}: " if name is not None else ""
    kind = cal.get("type") or (cal.findtext("projection") or "").strip()
    if kind != "frame":
        raise file_error(
            path, None, f"{at}projection {excerpt(kind or None)}: photax reads Metashape 'frame' cameras only "
            "(fisheye, spherical, cylindrical and RPC have no photax camera)"
        )  # fmt: skip
    tags = {child.tag for child in cal}
    if "fx" in tags or "fy" in tags:
        raise file_error(path, None, f"{at}PhotoScan 1.x's layout (fx, fy): export it again from Metashape (f, b1)")
    values = {}
    for key in _TERMS:
        text = cal.findtext(key)
        if text is None:
            values[key] = None if key == "f" else 0.0
            continue
        values[key] = number(path, None, text.strip(), f"{at}<{key}>")
    res = cal.find("resolution")
    size = []
    for key in ("width", "height"):
        text = res.get(key) if res is not None else cal.findtext(key)
        try:
            n = int(str(text).strip())
        except ValueError:
            raise file_error(path, None, f"{at}{key} must be a whole number of pixels, got {excerpt(text)}") from None
        if not 1 <= n < 2**31:
            raise file_error(path, None, f"{at}{key} must be >= 1 pixel, got {n}")
        size.append(n)
    if values["f"] is None:
        raise file_error(path, None, f"{at}no <f> (focal length in pixels)")
    lost = [k for k in _NOT_CONVERTED if values[k] != 0.0]
    if lost:
        raise file_error(
            path, None, f"{at}{', '.join(f'{k} = {values[k]:g}' for k in lost)}: photax's camera has no "
            "k4 (r^8), p3, p4 or b2 (skew) term; recalibrate in Metashape with them fixed at 0"
        )  # fmt: skip
    f, b1 = values["f"], values["b1"]
    fx = f + b1
    if not (f > 0 and fx > 0):
        raise file_error(path, None, f"{at}the focal length must be positive (f = {f:g}, b1 = {b1:g})")
    aspect = fx / f
    w, h = size
    pp = (values["cx"], -values["cy"] * aspect)  # y up; the image centre is photax's too
    dist = (values["k1"], values["k2"], values["k3"], 0.0 - values["p2"], values["p1"])
    return FrameCamera(fx, pp, dist, pixel_size=(1.0, aspect), image_size=(w, h))


def read_metashape_calibration(path) -> dict[str | None, FrameCamera]:
    """The frame cameras of a Metashape calibration XML or cameras XML (module docstring):
    ``{sensor label (None for a lone <calibration>): FrameCamera}`` in pixels.

    Raises:
        ValueError: naming the file: not XML, no calibration, a projection
            other than frame, a term photax cannot hold (named), a value
            that is not a finite number.

    Examples:
        A Metashape calibration XML (written here by :func:`write_metashape_calibration`):
        ``{sensor label or None: FrameCamera}`` in pixels:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_metashape_calibration, write_metashape_calibration
        >>> cam = ptx.FrameCamera.from_pixels(3000.0, (4000, 3000), principal_point_px=(2010.0, 1490.0))
        >>> path = write_metashape_calibration(cam, pathlib.Path(tempfile.mkdtemp()) / "calibration.xml")
        >>> (back,) = read_metashape_calibration(path).values()
        >>> print(np.round(np.asarray(back.principal_point), 6))  # from the image centre, x right, y up (px)
        [10.5  9.5]
    """
    path = pathlib.Path(path)
    root = _parse_xml(path)
    if root.tag == "calibration":
        return {None: _calibration(path, None, root)}
    out: dict[str | None, FrameCamera] = {}
    for k, sensor in enumerate(root.iter("sensor")):
        cals = sensor.findall("calibration")
        if not cals:
            continue
        cal = next((c for c in cals if c.get("class") == "adjusted"), cals[0])
        name = sensor.get("label") or sensor.get("id") or f"sensor {k}"
        if name in out:
            raise file_error(path, None, f"sensor {excerpt(name)} twice")
        out[name] = _calibration(path, name, cal)
    if not out:
        raise file_error(path, None, "no <calibration> element: not a Metashape calibration or cameras XML")
    return out


# --------------------------------------------------------------------------
# Omega-phi-kappa text exports (Metashape, Pix4D)
# --------------------------------------------------------------------------


def is_opk_export(path) -> bool:
    """Whether ``path`` starts like a Metashape OPK export or a Pix4D external-parameters file."""
    head = head_text(path, 2048)
    first = next((ln.strip() for ln in head.splitlines() if ln.strip()), "")
    return first.startswith("# Cameras (") or first.startswith("# PhotoID") or first.lower().startswith("imagename")


def read_opk_export(path) -> dict[str, ExteriorOrientation]:
    """A Metashape "Omega Phi Kappa" export or a Pix4D ``calibrated_external_camera_parameters.txt``:
    ``{image stem: ExteriorOrientation ("omega-phi-kappa")}`` (module docstring).

    Raises:
        ValueError: naming the file and line: a wrong number of values, a
            value that is not a finite number, a name twice, a Metashape
            matrix that disagrees with its angles.

    Examples:
        A Metashape *Omega Phi Kappa* export (written here by :func:`write_opk_export`) read back:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_opk_export, write_opk_export
        >>> eo = ptx.ExteriorOrientation([512300.0, 4103800.0, 450.0], np.radians([1.0, -2.0, 30.0]), "omega-phi-kappa")
        >>> path = write_opk_export({"IMG_1": eo}, pathlib.Path(tempfile.mkdtemp()) / "cameras_opk.txt", format="pix4d")
        >>> back = read_opk_export(path)
        >>> list(back), np.round(np.degrees(np.asarray(back["IMG_1"].angles)), 6).tolist()
        (['IMG_1'], [1.0, -2.0, 30.0])
    """
    path = pathlib.Path(path)
    lines = split_lines(read_text(path, "orientation file"))
    out: dict[str, ExteriorOrientation] = {}
    pix4d = None
    for n, line in enumerate(lines, start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            if s.startswith("# PhotoID") or s.startswith("# Cameras"):
                pix4d = False
            continue
        if pix4d is None:
            if s.lower().split()[:7] != ["imagename", "x", "y", "z", "omega", "phi", "kappa"]:
                raise file_error(
                    path, n, "not a Metashape OPK export ('# PhotoID, X, Y, Z, Omega, Phi, Kappa, r11 ...') nor "
                    "a Pix4D external parameters file ('imageName X Y Z Omega Phi Kappa')"
                )  # fmt: skip
            pix4d = True
            continue
        fields = s.split("\t") if "\t" in s else s.split()
        fields = [f.strip() for f in fields]
        want = (7,) if pix4d else (7, 16)
        if len(fields) not in want:
            expected = " or ".join(map(str, want))
            raise file_error(path, n, f"expected {expected} values (name, X, Y, Z, omega, phi, kappa[, r11..r33]), "
                             f"got {len(fields)}")  # fmt: skip
        try:
            v = np.array([float(x) for x in fields[1:]])
        except ValueError:
            raise file_error(path, n, f"not a number in {excerpt(' '.join(fields[1:]), 60)}") from None
        if not np.all(np.isfinite(v)) or not np.all(np.abs(v[:3]) < 1e12):
            raise file_error(path, n, "a value is not finite or out of range")
        stem = pathlib.PurePath(fields[0]).stem
        if not stem or stem in out:
            raise file_error(path, n, f"an empty or repeated image name {excerpt(fields[0])}")
        eo = ExteriorOrientation(v[:3], np.radians(v[3:6]), "omega-phi-kappa")
        if len(v) == 15:
            r = v[6:].reshape(3, 3)
            expected = np.asarray(eo.rotation).T
            if not np.allclose(r, expected, rtol=0, atol=1e-4):  # the file rounds both (6 decimals usual)
                raise file_error(
                    path, n, "the rotation matrix r11..r33 does not match omega, phi, kappa in Metashape's "
                    "convention (photogrammetric omega-phi-kappa; r = world -> camera, camera y up, z back): "
                    "not a Metashape export?"
                )  # fmt: skip
        out[stem] = eo
    if not out:
        raise file_error(path, None, "no camera orientations")
    return out


# --------------------------------------------------------------------------
# Writers
# --------------------------------------------------------------------------


def write_metashape_calibration(camera: FrameCamera, path, *, inputs=()) -> pathlib.Path:
    """Write ``camera`` as a Metashape calibration XML (``<calibration>``, frame), atomically,
    in pixels: ``f = f_y``, ``b1 = f_x - f_y``, ``cx, cy`` from the image centre (y down),
    ``k1-k3``, ``P1 = p2``, ``P2 = -p1`` (photax's y-up p1); :func:`read_metashape_calibration`
    reads it back to the same projection.

    Raises:
        ValueError: a camera without a pixel grid (``pixel_size``, ``image_size``) or a scan.

    Examples:
        A camera as a Metashape calibration XML, read back (``{sensor name or None: camera}``):

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_metashape_calibration, write_metashape_calibration
        >>> cam = ptx.FrameCamera.from_pixels(3000.0, (4000, 3000), distortion=[-0.05, 0.0, 0.0, 0.0, 0.0])  # k1 k2 k3 p1 p2
        >>> path = write_metashape_calibration(cam, pathlib.Path(tempfile.mkdtemp()) / "calibration.xml")
        >>> (back,) = read_metashape_calibration(path).values()
        >>> back.image_size, bool(np.isclose(back.focal_length, cam.focal_length)), float(back.distortion[0])
        ((4000, 3000), True, -0.05)
    """
    from .atomic import atomic_write

    if type(camera) is not FrameCamera or camera.pixel_size is None or camera.image_size is None:
        raise ValueError("a Metashape calibration needs a FrameCamera with pixel_size and image_size (not a scan)")
    sx, sy = (float(v) for v in np.asarray(camera.pixel_size))
    f = float(camera.focal_length)
    x0, y0 = (float(v) for v in np.asarray(camera.principal_point))
    k1, k2, k3, p1, p2 = (float(v) for v in np.asarray(camera.distortion))
    fx, fy = f / sx, f / sy
    terms = {"f": fy, "cx": x0 / sx, "cy": -y0 / sy, "b1": fx - fy, "k1": k1, "k2": k2, "k3": k3,
             "p1": p2, "p2": 0.0 - p1}  # fmt: skip
    bad = [k for k, v in terms.items() if not math.isfinite(v)]
    if bad:
        raise ValueError(f"the camera's {', '.join(bad)} is not finite (nan or inf): not written")
    w, h = camera.image_size
    body = "".join(f"  <{k}>{v!r}</{k}>\n" for k, v in terms.items())
    with atomic_write(path, inputs=inputs) as fh:
        fh.write(
            '<?xml version="1.0" encoding="UTF-8"?>\n<calibration>\n  <projection>frame</projection>\n'
            f"  <width>{w}</width>\n  <height>{h}</height>\n{body}</calibration>\n"
        )
    return pathlib.Path(path)


def write_opk_export(table: dict, path, *, format: str = "metashape", inputs=()) -> pathlib.Path:
    """Write ``{image name: ExteriorOrientation}`` as a Metashape "Omega Phi Kappa" export
    (``format="metashape"``: tab-separated, with r11..r33) or a Pix4D external parameters file
    (``"pix4d"``), atomically; angles in degrees, omega-phi-kappa, 17 significant digits.
    :func:`read_opk_export` reads either back.

    Examples:
        Orientations as a Metashape *Omega Phi Kappa* export (or Pix4D's), read back equal:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_opk_export, write_opk_export
        >>> eo = ptx.ExteriorOrientation([512300.0, 4103800.0, 450.0], np.radians([1.0, -2.0, 30.0]), "omega-phi-kappa")
        >>> path = write_opk_export({"IMG_1": eo}, pathlib.Path(tempfile.mkdtemp()) / "cameras_opk.txt")
        >>> back = read_opk_export(path)["IMG_1"]
        >>> bool(np.allclose(back.position, eo.position) and np.allclose(back.rotation, eo.rotation))
        True
    """
    from .atomic import atomic_write

    if format not in ("metashape", "pix4d"):
        raise UnsupportedFormatError(f"format must be 'metashape' or 'pix4d', got {format!r}")
    if not table:
        raise ValueError("no orientations to write")
    lines = []
    for name, eo in table.items():
        name = str(name)
        if not name or any(c.isspace() for c in name):
            raise ValueError(f"image name {name!r}: an OPK file's names have no spaces")
        e = eo.to_convention("omega-phi-kappa")
        values = [*np.asarray(e.position, dtype=float).tolist(), *np.degrees(np.asarray(e.angles)).tolist()]
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"image {name!r}: a position or angle is not finite (nan or inf): not written")
        if format == "metashape":
            values += np.asarray(e.rotation).T.ravel().tolist()
        lines.append(("\t" if format == "metashape" else " ").join([name, *(repr(float(v)) for v in values)]))
    if format == "metashape":
        head = [f"# Cameras ({len(lines)})", "# PhotoID, X, Y, Z, Omega, Phi, Kappa, r11, r12, r13, r21, r22, r23, "
                "r31, r32, r33"]  # fmt: skip
    else:
        head = ["imageName X Y Z Omega Phi Kappa"]
    with atomic_write(path, inputs=inputs) as fh:
        fh.write("\n".join(head + lines) + "\n")
    return pathlib.Path(path)
