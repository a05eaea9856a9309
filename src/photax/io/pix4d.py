"""Pix4D's internal camera parameters, ``*_pix4d_calibrated_internal_camera_parameters.cam``
(PIX4Dmapper's ``1_initial/params`` folder)::

    Pix4D camera calibration file 0
    #Focal Length mm assuming a sensor width of 17.49998592x13.12498944mm
    F 15.01175404934517487732
    #Principal Point mm
    Px 8.48210511970419922534
    Py 6.33434629978042273990
    #Symmetrical Lens Distortion Coeffs
    K1 0.03833474118270804865
    K2 -0.01750917966495743258
    K3 0.02049798716391852335
    #Tangential Lens Distortion Coeffs
    T1 0.00240851666319534747
    T2 0.00292562392135245920

The model is Pix4D's perspective lens ("How are the Internal and External
Camera Parameters defined?", support article 202559089, section 2.1.2), in
the frame of the ``calibrated_camera_parameters.txt`` it is exported with
(``m = K [R | -R t] X``: camera x right, y down, z forward; pixels from the
top-left)::

    xh = X / Z, yh = Y / Z,  r^2 = xh^2 + yh^2
    xhd = xh (1 + K1 r^2 + K2 r^4 + K3 r^6) + 2 T1 xh yh + T2 (r^2 + 2 xh^2)
    yhd = yh (1 + K1 r^2 + K2 r^4 + K3 r^6) + 2 T2 xh yh + T1 (r^2 + 2 yh^2)
    u = f xhd + cx,  v = f yhd + cy        f, cx, cy = F, Px, Py in pixels

``F``, ``Px`` and ``Py`` are in mm on a sensor of the header's width x
height, measured from its top-left corner: one pixel is ``width_mm / W``.
So ``T1, T2`` are OpenCV's ``p1, p2`` (photax's, y up: ``p1 = -T1``,
``p2 = T2``) and photax's principal point is ``(Px - width/2, height/2 - Py)``
mm.  Pinned by two independent sources: (1) a real PIX4Dmapper run's pair of
files (the ``maize`` project quoted in EasyIDP's ``pix4d.py``) -- its ``.cam``
gives ``F, Px, Py`` times ``W / width_mm`` equal to its
``calibrated_camera_parameters.txt``'s ``K`` (3952.812, 2233.461,
1667.925 px for 4608 x 3456) and the same ``K1..T2`` as that file's radial and
tangential terms, whose ``R`` is right-handed with z toward the ground for a
nadir image (so y is down and ``cy`` counts from the top); (2) EasyIDP's
projection, which applies the equations above to ``K``'s pixels, and openMVG's
``Pinhole_Intrinsic_Brown_T2`` (``T1``, ``T2`` in those roles).  The origin at
the sensor's *corner* (not the first pixel's centre) is what a mm coordinate
on a ``width_mm`` sensor means; no source found states it in words: if
Pix4D's origin were the first pixel's centre, photax's principal point would
be off by half a pixel.

The file does not hold the image's pixel count: give ``image_size`` (or keep
the ``calibrated_camera_parameters.txt`` of the same run beside the ``.cam``:
:func:`photax.io.read_interior` takes the size from it).  Pix4D's fisheye
``.cam`` (its ``C D E F`` affine and ``p`` polynomial) is refused by name.
"""

from __future__ import annotations

import math
import pathlib
import re

import numpy as np

from ..camera import FrameCamera
from .files import excerpt, file_error, head_text, number, read_text, split_lines

MAGIC = "Pix4D camera calibration file"
_KEYS = ("F", "Px", "Py", "K1", "K2", "K3", "T1", "T2")
_SENSOR = re.compile(r"#\s*Focal Length.*sensor width of\s+(\S+?)\s*x\s*(\S+?)\s*mm\s*$", re.IGNORECASE)


def is_pix4d_cam(path) -> bool:
    """Whether ``path`` starts like a Pix4D ``.cam`` (its first line, cheaply)."""
    return head_text(path, 256).lstrip().startswith(MAGIC)


def read_pix4d_cam(path, image_size: tuple[int, int] | None = None) -> FrameCamera:
    """A Pix4D ``*_pix4d_calibrated_internal_camera_parameters.cam`` as a
    :class:`photax.FrameCamera` in mm (module docstring): with ``image_size``
    ``(width, height)`` in pixels it has its pixel grid (pixel size ``width_mm /
    width``, ``height_mm / height``), without it none.

    Raises:
        ValueError: naming the file and line: not a Pix4D camera file, a
            fisheye camera, an unknown or repeated key, a value that is not a
            finite number, a missing term, a sensor or focal length that is
            not positive; an ``image_size`` that is not two positive integers.

    Examples:
        Pix4D's ``.cam`` file (mm on the sensor; written here by :func:`write_pix4d_cam`), with the
        image's pixel count:

        >>> import pathlib, tempfile
        >>> import photax as ptx
        >>> from photax.io import read_pix4d_cam, write_pix4d_cam
        >>> cam = ptx.FrameCamera(8.8, pixel_size=0.0176, image_size=(1000, 750))
        >>> path = write_pix4d_cam(cam, pathlib.Path(tempfile.mkdtemp()) / "p_pix4d_calibrated_internal_camera_parameters.cam")
        >>> back = read_pix4d_cam(path, (1000, 750))
        >>> round(float(back.focal_length / back.pixel_size[0]), 6), back.image_size
        (500.0, (1000, 750))
    """
    path = pathlib.Path(path)
    lines = split_lines(read_text(path, "camera file"))
    first = next((n for n, t in enumerate(lines, start=1) if t.strip()), None)
    if first is None or not lines[first - 1].strip().lstrip("\ufeff").startswith(MAGIC):
        raise file_error(path, first, f"not a Pix4D camera file (its first line is '{MAGIC} 0')")
    values: dict[str, float] = {}
    sensor = None
    for n, text in enumerate(lines[first:], start=first + 1):
        s = text.strip()
        if not s:
            continue
        if s.startswith("#"):
            m = _SENSOR.match(s)
            if m is not None:
                if sensor is not None:
                    raise file_error(path, n, "the sensor size is given twice")
                sensor = (number(path, n, m.group(1), "the sensor width"), number(path, n, m.group(2), "height"))
                if not (0 < sensor[0] < 1e6 and 0 < sensor[1] < 1e6):
                    raise file_error(path, n, f"the sensor size must be positive mm, got {sensor[0]:g} x {sensor[1]:g}")
            elif "fisheye" in s.lower():
                raise file_error(path, n, "a Pix4D fisheye camera: photax reads Pix4D's perspective .cam only")
            continue
        fields = s.split()
        key = fields[0]
        if key not in _KEYS:
            raise file_error(
                path, n, f"unknown term {excerpt(key)}: photax reads Pix4D's perspective lens (F, Px, Py, K1-K3, "
                "T1, T2) only; a fisheye's C D E F and polynomial are not converted"
            )  # fmt: skip
        if len(fields) != 2:
            raise file_error(path, n, f"expected '{key} <number>', got {len(fields)} fields")
        if key in values:
            raise file_error(path, n, f"{key} is given twice")
        values[key] = number(path, n, fields[1], key)
    missing = [k for k in _KEYS if k not in values]
    if missing:
        raise file_error(path, None, f"no {', '.join(missing)} (a Pix4D .cam has F, Px, Py, K1-K3, T1, T2)")
    if sensor is None:
        raise file_error(path, None, "no '#Focal Length mm assuming a sensor width of WxHmm' line: the sensor size")
    w_mm, h_mm = sensor
    f = values["F"]
    if not 0 < f < 1e6:
        raise file_error(path, None, f"F (focal length, mm) must be positive, got {f:g}")
    if not (abs(values["Px"]) < 1e6 and abs(values["Py"]) < 1e6):
        raise file_error(path, None, "Px or Py (principal point, mm) is out of range")
    pp = (values["Px"] - w_mm / 2.0, h_mm / 2.0 - values["Py"])
    dist = (values["K1"], values["K2"], values["K3"], 0.0 - values["T1"], values["T2"])
    if image_size is None:
        return FrameCamera(f, pp, dist)
    try:
        w, h = (int(v) for v in image_size)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: image_size must be (width, height) in pixels, got {image_size!r}") from None
    if not (w >= 1 and h >= 1 and (w, h) == tuple(image_size)):
        raise ValueError(f"{path}: image_size must be two positive whole numbers, got {image_size!r}")
    return FrameCamera(f, pp, dist, pixel_size=(w_mm / w, h_mm / h), image_size=(w, h))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def write_pix4d_cam(camera: FrameCamera, path, *, inputs=()) -> pathlib.Path:
    """Write ``camera`` as a Pix4D ``.cam``, atomically: ``F``, ``Px``, ``Py`` in the
    camera's length unit on a sensor of ``image_size * pixel_size`` (a camera in
    mm gives mm; one in pixels writes pixels where Pix4D says mm: the geometry is
    the same), ``T1 = -p1``, ``T2 = p2``, each to 17 significant digits.
    :func:`read_pix4d_cam` with the camera's ``image_size`` reads back the same
    projection.

    Raises:
        ValueError: not a Brown-Conrady :class:`photax.FrameCamera` with a pixel
            grid; non-square pixels (Pix4D has one focal length); a value that
            is not finite.

    Examples:
        A camera as Pix4D's ``.cam`` file (mm on the sensor), read back with its pixel count:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_pix4d_cam, write_pix4d_cam
        >>> cam = ptx.FrameCamera(8.8, principal_point=(0.011, -0.0066), pixel_size=0.0176, image_size=(1000, 750))
        >>> path = write_pix4d_cam(cam, pathlib.Path(tempfile.mkdtemp()) / "p_pix4d_calibrated_internal_camera_parameters.cam")
        >>> back = read_pix4d_cam(path, (1000, 750))
        >>> bool(np.allclose(np.asarray(back.image_to_pixel(np.array([[0.1, 0.2]]))), np.asarray(cam.image_to_pixel(np.array([[0.1, 0.2]])))))
        True
    """
    from .atomic import atomic_write

    if type(camera) is not FrameCamera or camera.pixel_size is None or camera.image_size is None:
        raise ValueError("a Pix4D .cam needs a FrameCamera with pixel_size and image_size (not a scan)")
    if camera.model != "brown":
        raise ValueError(f"a Pix4D .cam holds the Brown-Conrady model (K1-K3, T1, T2), not {camera.model!r}")
    sx, sy = (float(v) for v in np.asarray(camera.pixel_size))
    w, h = camera.image_size
    x0, y0 = (float(v) for v in np.asarray(camera.principal_point))
    k1, k2, k3, p1, p2 = (float(v) for v in np.asarray(camera.distortion))
    f = float(camera.focal_length)
    numbers = (f, sx, sy, x0, y0, k1, k2, k3, p1, p2)
    if not all(math.isfinite(v) for v in numbers):
        raise ValueError("a camera value is not finite (nan or inf): not written")
    if not math.isclose(sx, sy, rel_tol=1e-12):
        raise ValueError(f"a Pix4D .cam has square pixels (one focal length); this camera's are {sx:g} x {sy:g}")
    w_mm, h_mm = w * sx, h * sy
    terms = {"F": f, "Px": x0 + w_mm / 2.0, "Py": h_mm / 2.0 - y0, "K1": k1, "K2": k2, "K3": k3,
             "T1": 0.0 - p1, "T2": p2}  # fmt: skip
    v = {k: repr(x) for k, x in terms.items()}  # 17 significant digits: the value read back is the same
    text = (
        f"{MAGIC} 0\n#Focal Length mm assuming a sensor width of {w_mm!r}x{h_mm!r}mm\nF {v['F']}\n"
        f"#Principal Point mm\nPx {v['Px']}\nPy {v['Py']}\n#Symmetrical Lens Distortion Coeffs\n"
        f"K1 {v['K1']}\nK2 {v['K2']}\nK3 {v['K3']}\n#Tangential Lens Distortion Coeffs\nT1 {v['T1']}\nT2 {v['T2']}\n"
    )
    with atomic_write(path, inputs=inputs) as fh:
        fh.write(text)
    return pathlib.Path(path)


def image_size_beside(path) -> tuple[int, int] | None:
    """The image size (pixels) of a ``.cam`` from the ``calibrated_camera_parameters.txt`` of the
    same run beside it (its image lines, ``name width height``: a first field that is not a number) (``<project>_calibrated_camera_parameters.txt`` for
    ``<project>_pix4d_calibrated_internal_camera_parameters.cam``), None when there is none.

    Raises:
        ValueError: naming that file: no image line (``name width height``), or
            images of different sizes (more than one camera: give the size).
    """
    path = pathlib.Path(path)
    suffix = "_pix4d_calibrated_internal_camera_parameters.cam"
    if not path.name.endswith(suffix):
        return None
    other = path.with_name(path.name[: -len(suffix)] + "_calibrated_camera_parameters.txt")
    if not other.is_file():
        return None
    sizes = {}
    for n, text in enumerate(split_lines(read_text(other, "Pix4D camera parameters file")), start=1):
        f = text.split()
        if len(f) == 3 and f[0] != "fileName" and not _is_number(f[0]) and f[1].isdigit() and f[2].isdigit():
            size = (int(f[1]), int(f[2]))
            if not (1 <= size[0] < 2**31 and 1 <= size[1] < 2**31):
                raise file_error(other, n, f"image size {size[0]} x {size[1]} is not positive")
            sizes.setdefault(size, n)
    if not sizes:
        raise file_error(other, None, "no 'fileName imageWidth imageHeight' line: not Pix4D's camera parameters")
    if len(sizes) > 1:
        raise file_error(other, None, f"images of {len(sizes)} sizes: read the .cam with its image_size")
    return next(iter(sizes))
