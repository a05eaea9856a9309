"""COLMAP sparse models: ``cameras``, ``images``, ``points3D`` as text (``.txt``) or binary (``.bin``).

The layout is COLMAP's (``src/colmap/scene/reconstruction_io.cc``,
``scripts/python/read_write_model.py``; colmap.github.io/format.html):

* ``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS...``;
* ``images.txt``: two lines per image, ``IMAGE_ID QW QX QY QZ TX TY TZ
  CAMERA_ID NAME`` then ``X Y POINT3D_ID`` triples (``-1``: no 3-D point; the
  line may be empty);
* ``points3D.txt``: ``POINT3D_ID X Y Z R G B ERROR`` then ``IMAGE_ID
  POINT2D_IDX`` pairs (the track);
* the ``.bin`` files hold the same, little-endian: counts ``uint64``, ids of
  cameras and images ``uint32``, of points ``uint64``, model ids ``int32``,
  sizes ``uint64``, numbers ``float64``, names NUL-terminated.

COLMAP 3.12+ also writes ``rigs`` and ``frames``; they are not read (the
images' poses are complete without them) nor written (COLMAP reads a model
without them as one rig per camera).  A folder is read as binary when its
three ``.bin`` files are there, else as text, as COLMAP does.

Conventions, and how they map onto photax (``docs/conventions.md``):

* **Poses**: ``(QW, QX, QY, QZ)`` is the unit quaternion of the
  world -> camera rotation ``R`` in COLMAP's camera frame (x right, y down,
  z forward, OpenCV's) and ``x_cam = R X + t``: the projection centre is
  ``C = -R^T t`` and photax's ``world_from_camera`` is ``R^T diag(1, -1, -1)``
  (:func:`photax.camera.from_opencv_extrinsics`).  A quaternion is normalised
  on reading, as COLMAP does.
* **Pixels**: COLMAP's image coordinates have the *corner* of the top-left
  pixel at ``(0, 0)`` and its centre at ``(0.5, 0.5)``; photax's have the
  centre at ``(0, 0)``: ``col = x - 0.5``, ``row = y - 0.5``.
* **Cameras** (in pixels; ``fx != fy`` becomes photax's pixel aspect
  ``pixel_size = (1, fx / fy)``, as for OpenSfM): ``SIMPLE_PINHOLE`` (f, cx,
  cy), ``PINHOLE`` (fx, fy, cx, cy), ``SIMPLE_RADIAL`` (f, cx, cy, k),
  ``RADIAL`` (f, cx, cy, k1, k2), ``OPENCV`` (fx, fy, cx, cy, k1, k2, p1, p2)
  (photax's ``brown`` model), ``FULL_OPENCV`` (k1, k2, p1, p2, k3, k4, k5,
  k6: photax's ``opencv`` model, or ``brown`` when k4 = k5 = k6 = 0) and
  ``OPENCV_FISHEYE`` (k1-k4: photax's ``fisheye``).  The distortion is
  OpenCV's on normalised coordinates with y down, so ``p1`` changes sign
  (:mod:`photax.camera`).  The principal point
  ``(x0, y0) = (cx - w/2, (h/2 - cy) fx/fy)`` from the image centre, y up.
  Every other model (``FOV``, ``THIN_PRISM_FISHEYE``, the radial fisheyes, the division models,
  ``EUCM``, ``EQUIRECTANGULAR``, ...) is read into :class:`ColmapModel` and
  written back unchanged, but refused by name when converted to photax
  cameras.
* Written back, a camera takes the simplest of those models that holds it
  exactly (``SIMPLE_PINHOLE`` for square pixels without distortion, ...).

:func:`read_colmap` gives a :class:`photax.BundleProblem` (one image per
registered COLMAP image, every 3-D point a tie point, observations from the
tracks); :func:`write_colmap` writes a problem or an adjusted result back.
:func:`photax.georeference` puts a model into a ground CRS.
"""

from __future__ import annotations

import dataclasses
import pathlib
import struct
import warnings

import numpy as np

from ..camera import FrameCamera
from .files import excerpt, file_error, head_text, read_bytes, read_text, split_lines

#: COLMAP's camera models: ``name -> (model id, parameter names)``
#: (``src/colmap/sensor/models.h``, COLMAP 4).
MODELS: dict[str, tuple[int, tuple[str, ...]]] = {
    "SIMPLE_PINHOLE": (0, ("f", "cx", "cy")),
    "PINHOLE": (1, ("fx", "fy", "cx", "cy")),
    "SIMPLE_RADIAL": (2, ("f", "cx", "cy", "k")),
    "RADIAL": (3, ("f", "cx", "cy", "k1", "k2")),
    "OPENCV": (4, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")),
    "OPENCV_FISHEYE": (5, ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")),
    "FULL_OPENCV": (6, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")),
    "FOV": (7, ("fx", "fy", "cx", "cy", "omega")),
    "SIMPLE_RADIAL_FISHEYE": (8, ("f", "cx", "cy", "k")),
    "RADIAL_FISHEYE": (9, ("f", "cx", "cy", "k1", "k2")),
    "THIN_PRISM_FISHEYE": (10, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "sx1", "sy1")),
    "RAD_TAN_THIN_PRISM_FISHEYE": (
        11,
        ("fx", "fy", "cx", "cy", "k0", "k1", "k2", "k3", "k4", "k5", "p0", "p1", "s0", "s1", "s2", "s3"),
    ),
    "SIMPLE_DIVISION": (12, ("f", "cx", "cy", "k")),
    "DIVISION": (13, ("fx", "fy", "cx", "cy", "k")),
    "SIMPLE_FISHEYE": (14, ("f", "cx", "cy")),
    "FISHEYE": (15, ("fx", "fy", "cx", "cy")),
    "EUCM": (16, ("fx", "fy", "cx", "cy", "alpha", "beta")),
    "EQUIRECTANGULAR": (17, ("w", "h")),
}
_BY_ID = {mid: name for name, (mid, _) in MODELS.items()}

#: The models photax converts, and the photax distortion model each becomes.
PHOTAX_MODELS = {
    "SIMPLE_PINHOLE": "brown",
    "PINHOLE": "brown",
    "SIMPLE_RADIAL": "brown",
    "RADIAL": "brown",
    "OPENCV": "brown",
    "FULL_OPENCV": "opencv",
    "OPENCV_FISHEYE": "fisheye",
}
_NO_ID = 2**64 - 1  # COLMAP's kInvalidPoint3DId, written as -1 in text


@dataclasses.dataclass(frozen=True)
class ColmapCamera:
    """A COLMAP camera as stored: ``model`` name, ``width``, ``height`` and ``params`` (``MODELS[model][1]``)."""

    model: str
    width: int
    height: int
    params: np.ndarray


@dataclasses.dataclass(frozen=True)
class ColmapImage:
    """A registered COLMAP image as stored.

    Attributes:
        qvec: ``(4,)`` unit quaternion ``(w, x, y, z)`` of camera_from_world (COLMAP's camera frame).
        tvec: ``(3,)`` translation: ``x_cam = R X + t``.
        camera_id: its camera.
        name: the image file name (relative to COLMAP's image folder).
        xy: ``(n, 2)`` keypoints in COLMAP pixels (top-left corner at ``(0, 0)``).
        point3d_ids: ``(n,)`` int64 point of each keypoint, -1 for none.
    """

    qvec: np.ndarray
    tvec: np.ndarray
    camera_id: int
    name: str
    xy: np.ndarray
    point3d_ids: np.ndarray


@dataclasses.dataclass(frozen=True)
class ColmapPoint:
    """A COLMAP 3-D point: ``xyz``, ``rgb`` (3 ints 0-255), reprojection ``error`` (px, -1 unknown)
    and its track: ``image_ids`` and ``point2d_idx`` ``(m,)`` int64, each a keypoint of an image."""

    xyz: np.ndarray
    rgb: np.ndarray
    error: float
    image_ids: np.ndarray
    point2d_idx: np.ndarray


@dataclasses.dataclass(frozen=True)
class ColmapModel:
    """A COLMAP sparse model: ``{id: ColmapCamera}``, ``{id: ColmapImage}``, ``{id: ColmapPoint}``.

    Examples:
        A model by hand: one pinhole camera (f = 100 px), two unrotated images with ``t = (0, 0, 10)``
        and ``(-1, 0, 10)``, one point at the origin seen by both; read as a block, the images'
        projection centres are COLMAP's ``-R^T t``:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> from photax.io import ColmapModel, read_colmap, write_colmap_model
        >>> from photax.io.colmap import ColmapCamera, ColmapImage, ColmapPoint
        >>> q, track = np.array([1.0, 0.0, 0.0, 0.0]), np.array([7])
        >>> model = ColmapModel(
        ...     {1: ColmapCamera("SIMPLE_PINHOLE", 100, 100, np.array([100.0, 50.0, 50.0]))},
        ...     {1: ColmapImage(q, np.array([0.0, 0.0, 10.0]), 1, "a.jpg", np.array([[50.0, 50.0]]), track),
        ...      2: ColmapImage(q, np.array([-1.0, 0.0, 10.0]), 1, "b.jpg", np.array([[40.0, 50.0]]), track)},
        ...     {7: ColmapPoint(np.zeros(3), np.array([128, 128, 128]), -1.0, np.array([1, 2]), np.array([0, 0]))})
        >>> problem = read_colmap(write_colmap_model(model, pathlib.Path(tempfile.mkdtemp()) / "sparse"))
        >>> problem.image_names, problem.point_names
        (('a.jpg', 'b.jpg'), ('7',))
        >>> print(np.asarray(problem.exterior.position) + 0.0)
        [[  0.   0. -10.]
         [  1.   0. -10.]]
    """

    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    points: dict[int, ColmapPoint]


# --------------------------------------------------------------------------
# Quaternions (w, x, y, z), numpy
# --------------------------------------------------------------------------


def quaternion_to_matrix(q) -> np.ndarray:
    """``(..., 4)`` quaternions ``(w, x, y, z)`` (normalised here) -> ``(..., 3, 3)`` rotation matrices."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def matrix_to_quaternion(r) -> np.ndarray:
    """``(..., 3, 3)`` rotation matrices -> ``(..., 4)`` unit quaternions ``(w, x, y, z)``, ``w >= 0``
    (Shepperd's method: the best conditioned of four candidates)."""
    r = np.asarray(r, dtype=float)
    tr = np.trace(r, axis1=-2, axis2=-1)
    d = np.stack([tr, r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]], axis=-1)
    k = np.argmax(d, axis=-1)
    cands = np.stack(
        [
            np.stack(
                [1 + tr, r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1
            ),
            np.stack(
                [
                    r[..., 2, 1] - r[..., 1, 2],
                    1 + 2 * r[..., 0, 0] - tr,
                    r[..., 0, 1] + r[..., 1, 0],
                    r[..., 0, 2] + r[..., 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    r[..., 0, 2] - r[..., 2, 0],
                    r[..., 0, 1] + r[..., 1, 0],
                    1 + 2 * r[..., 1, 1] - tr,
                    r[..., 1, 2] + r[..., 2, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    r[..., 1, 0] - r[..., 0, 1],
                    r[..., 0, 2] + r[..., 2, 0],
                    r[..., 1, 2] + r[..., 2, 1],
                    1 + 2 * r[..., 2, 2] - tr,
                ],
                -1,
            ),
        ],
        axis=-2,
    )
    q = np.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


# --------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------


def _files(folder: pathlib.Path) -> tuple[str, dict[str, pathlib.Path]]:
    names = ("cameras", "images", "points3D")
    for ext in (".bin", ".txt"):
        paths = {n: folder / f"{n}{ext}" for n in names}
        if all(p.is_file() for p in paths.values()):
            return ext, paths
    if not folder.is_dir():
        if folder.exists():
            raise ValueError(f"{folder}: a COLMAP model is a folder (cameras, images, points3D .txt or .bin)")
        raise FileNotFoundError(f"{folder}: no such COLMAP model folder")
    raise ValueError(
        f"{folder}: not a COLMAP model folder: cameras, images and points3D, all .bin or all .txt, expected"
    )


def read_colmap_model(folder) -> ColmapModel:
    """Read a COLMAP sparse model folder (binary when ``cameras.bin``,
    ``images.bin`` and ``points3D.bin`` are there, else text).

    Every camera model of :data:`MODELS` is read (its parameter count is
    checked); nothing is converted.

    Raises:
        ValueError: naming the file (and line, for text) of a malformed
            entry: a wrong field count, a value that is not a finite number,
            an id given twice, an image of an unknown camera, a track
            element of an unknown image or keypoint, or a keypoint that
            names another 3-D point than the track does.
        FileNotFoundError: no such folder.

    Examples:
        A text model of one camera, and no images or points yet:

        >>> import pathlib, tempfile
        >>> from photax.io import read_colmap_model
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> _ = (folder / "cameras.txt").write_text("# CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]\\n"
        ...                                         "1 PINHOLE 640 480 500 510 320 240\\n")
        >>> _ = (folder / "images.txt").write_text(""), (folder / "points3D.txt").write_text("")
        >>> model = read_colmap_model(folder)
        >>> model.cameras[1].model, model.cameras[1].params.tolist(), model.images, model.points
        ('PINHOLE', [500.0, 510.0, 320.0, 240.0], {}, {})
    """
    folder = pathlib.Path(folder)
    ext, paths = _files(folder)
    if ext == ".txt":
        cameras = _read_cameras_text(paths["cameras"])
        images = _read_images_text(paths["images"], cameras)
        points = _read_points_text(paths["points3D"], images)
    else:
        cameras = _read_cameras_bin(paths["cameras"])
        images = _read_images_bin(paths["images"], cameras)
        points = _read_points_bin(paths["points3D"], images)
    return ColmapModel(cameras, images, points)


def _data_lines(path):
    """``(line number, fields, line)`` of the non-comment lines of a text file (blank lines kept)."""
    for n, line in enumerate(split_lines(read_text(path, "COLMAP model file")), start=1):
        if not line.lstrip().startswith("#"):
            yield n, line.split(), line


def _int(path, line, text, what, lo=0, hi=2**63 - 1) -> int:
    try:
        v = int(text)
    except ValueError:
        raise file_error(path, line, f"{what} must be a whole number, got {excerpt(text)}") from None
    if not lo <= v <= hi:
        raise file_error(path, line, f"{what} must be in [{lo}, {hi}], got {v}")
    return v


def _floats(path, line, fields, what) -> np.ndarray:
    try:
        v = np.array([float(f) for f in fields], dtype=float)
    except ValueError:
        raise file_error(path, line, f"{what} must be numbers, got {excerpt(' '.join(fields), 60)}") from None
    if not np.all(np.isfinite(v)):
        raise file_error(path, line, f"{what} must be finite numbers, got {excerpt(' '.join(fields), 60)}")
    return v


def _camera(path, line, cid, model, width, height, params) -> ColmapCamera:
    if model not in MODELS:
        raise file_error(
            path, line, f"camera {cid}: unknown COLMAP camera model {excerpt(model)} (known: {', '.join(MODELS)})"
        )
    names = MODELS[model][1]
    if len(params) != len(names):
        raise file_error(
            path, line, f"camera {cid}: a {model} camera has {len(names)} parameters ({', '.join(names)}), "
            f"got {len(params)}"
        )  # fmt: skip
    if not (1 <= width < 2**31 and 1 <= height < 2**31):
        raise file_error(path, line, f"camera {cid}: width and height must be whole pixels >= 1")
    if names[0] in ("f", "fx") and not np.all(params[: 2 if names[1] == "fy" else 1] > 0):
        raise file_error(path, line, f"camera {cid}: the focal length must be positive")
    return ColmapCamera(model, int(width), int(height), np.asarray(params, dtype=float))


def _read_cameras_text(path) -> dict[int, ColmapCamera]:
    cameras: dict[int, ColmapCamera] = {}
    for n, f, _ in _data_lines(path):
        if not f:
            continue
        if len(f) < 4:
            raise file_error(path, n, f"expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS..., got {len(f)} fields")
        cid = _int(path, n, f[0], "CAMERA_ID", 0, 2**32 - 1)
        if cid in cameras:
            raise file_error(path, n, f"camera {cid} again")
        w, h = (_int(path, n, v, what, 1, 2**31 - 1) for v, what in ((f[2], "WIDTH"), (f[3], "HEIGHT")))
        cameras[cid] = _camera(path, n, cid, f[1], w, h, _floats(path, n, f[4:], "camera parameters"))
    if not cameras:
        raise file_error(path, None, "no cameras")
    return cameras


def _image(path, line, iid, q, t, cid, name, xy, ids, cameras, names) -> ColmapImage:
    if cid not in cameras:
        raise file_error(path, line, f"image {iid}: camera {cid} is not in the cameras file")
    norm = float(np.linalg.norm(q))
    if not 0.5 < norm < 2.0 or not np.all(np.abs(t) < 1e12):
        raise file_error(path, line, f"image {iid}: the quaternion must have norm 1 and t be finite")
    if not name or name in names or any(c in name for c in "\n\r\x00"):
        raise file_error(path, line, f"image {iid}: an empty or repeated NAME {excerpt(name)}")
    if not np.all(np.abs(xy) < 1e9):
        raise file_error(path, line, f"image {iid}: keypoint coordinates out of range")
    return ColmapImage(q / norm, t, cid, name, xy, ids)


def _read_images_text(path, cameras) -> dict[int, ColmapImage]:
    images: dict[int, ColmapImage] = {}
    names: set[str] = set()
    lines = list(_data_lines(path))
    k = 0
    while k < len(lines):
        n, f, line = lines[k]
        k += 1
        if not f:
            continue
        if len(f) < 10:
            raise file_error(path, n, f"expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got {len(f)} fields")
        iid = _int(path, n, f[0], "IMAGE_ID", 0, 2**32 - 1)
        if iid in images:
            raise file_error(path, n, f"image {iid} again")
        pose = _floats(path, n, f[1:8], "QW QX QY QZ TX TY TZ")
        cid = _int(path, n, f[8], "CAMERA_ID", 0, 2**32 - 1)
        name = line.split(None, 9)[9].strip()  # a name may hold spaces
        if k >= len(lines):
            raise file_error(path, n, f"image {iid}: the POINTS2D line is missing")
        n2, p, _ = lines[k]
        k += 1
        if len(p) % 3:
            raise file_error(path, n2, f"image {iid}: POINTS2D must be X Y POINT3D_ID triples, got {len(p)} fields")
        xy = _floats(path, n2, p[0::3] + p[1::3], "keypoint X Y").reshape(2, -1).T.copy()
        ids = np.array([_int(path, n2, v, "POINT3D_ID", -1) for v in p[2::3]], dtype=np.int64)
        images[iid] = _image(path, n, iid, pose[:4], pose[4:], cid, name, xy, ids, cameras, names)
        names.add(name)
    return images


def _point(path, line, pid, xyz, rgb, error, track, images) -> ColmapPoint:
    if not np.all(np.abs(xyz) < 1e12):
        raise file_error(path, line, f"point {pid}: X Y Z out of range")
    iids, idx = track[:, 0], track[:, 1]
    for i, j in zip(iids.tolist(), idx.tolist()):
        im = images.get(i)
        if im is None:
            raise file_error(path, line, f"point {pid}: its track names image {i}, which is not in the images file")
        if not 0 <= j < len(im.point3d_ids):
            raise file_error(path, line, f"point {pid}: image {i} has no keypoint {j} (it has {len(im.point3d_ids)})")
        if im.point3d_ids[j] != pid:
            raise file_error(
                path, line, f"point {pid}: keypoint {j} of image {i} belongs to point {int(im.point3d_ids[j])}"
            )
    return ColmapPoint(xyz, rgb, error, iids, idx)


def _read_points_text(path, images) -> dict[int, ColmapPoint]:
    points: dict[int, ColmapPoint] = {}
    for n, f, _ in _data_lines(path):
        if not f:
            continue
        if len(f) < 8 or (len(f) - 8) % 2:
            raise file_error(
                path, n, f"expected POINT3D_ID X Y Z R G B ERROR and IMAGE_ID POINT2D_IDX pairs, got {len(f)} fields"
            )
        pid = _int(path, n, f[0], "POINT3D_ID", 0, 2**63 - 1)
        if pid in points:
            raise file_error(path, n, f"point {pid} again")
        xyz = _floats(path, n, f[1:4], "X Y Z")
        rgb = np.array([_int(path, n, v, "R G B", 0, 255) for v in f[4:7]], dtype=np.uint8)
        error = float(_floats(path, n, f[7:8], "ERROR")[0])
        track = np.array([_int(path, n, v, "track", 0, 2**31 - 1) for v in f[8:]], dtype=np.int64).reshape(-1, 2)
        points[pid] = _point(path, n, pid, xyz, rgb, error, track, images)
    return points


class _Bytes:
    """A cursor over a binary file; a short read is an error naming the file and offset."""

    def __init__(self, path):
        self.path = path
        self.raw = read_bytes(path, "COLMAP model file")
        self.at = 0

    def take(self, fmt: str):
        size = struct.calcsize(fmt)
        if self.at + size > len(self.raw):
            raise file_error(self.path, None, f"truncated at byte {self.at} (not a COLMAP .bin file, or cut short)")
        out = struct.unpack_from(fmt, self.raw, self.at)
        self.at += size
        return out

    def array(self, dtype, n: int, width: int) -> np.ndarray:
        dt = np.dtype(dtype)
        size = dt.itemsize * n * width
        if n < 0 or self.at + size > len(self.raw):
            raise file_error(self.path, None, f"truncated at byte {self.at} (a count of {n} runs past the end)")
        out = np.frombuffer(self.raw, dtype=dt, count=n * width, offset=self.at).reshape(n, width)
        self.at += size
        return out

    def name(self) -> str:
        end = self.raw.find(b"\x00", self.at)
        if end < 0:
            raise file_error(self.path, None, f"truncated at byte {self.at}: an image name without its NUL")
        raw, self.at = self.raw[self.at : end], end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise file_error(self.path, None, f"an image name that is not UTF-8 at byte {self.at}") from None

    def count(self, what: str, per_item: int) -> int:
        (n,) = self.take("<Q")
        if n * per_item > len(self.raw) - self.at:  # each item takes at least per_item bytes
            raise file_error(self.path, None, f"{n} {what} announced at byte {self.at - 8}, more than the file holds")
        return n

    def end(self) -> None:
        if self.at != len(self.raw):
            raise file_error(self.path, None, f"{len(self.raw) - self.at} unexpected bytes after the last entry")


def _read_cameras_bin(path) -> dict[int, ColmapCamera]:
    b = _Bytes(path)
    cameras: dict[int, ColmapCamera] = {}
    for _ in range(b.count("cameras", 24)):
        cid, mid, w, h = b.take("<IiQQ")
        model = _BY_ID.get(mid)
        if model is None:
            raise file_error(path, None, f"camera {cid}: unknown COLMAP camera model id {mid}")
        if cid in cameras:
            raise file_error(path, None, f"camera {cid} again")
        params = b.array("<f8", len(MODELS[model][1]), 1)[:, 0]
        if not np.all(np.isfinite(params)):
            raise file_error(path, None, f"camera {cid}: parameters must be finite numbers")
        cameras[cid] = _camera(path, None, cid, model, w, h, params.copy())
    b.end()
    if not cameras:
        raise file_error(path, None, "no cameras")
    return cameras


def _read_images_bin(path, cameras) -> dict[int, ColmapImage]:
    b = _Bytes(path)
    images: dict[int, ColmapImage] = {}
    names: set[str] = set()
    for _ in range(b.count("images", 73)):
        iid, *pose, cid = b.take("<I7dI")
        name = b.name()
        if iid in images:
            raise file_error(path, None, f"image {iid} again")
        pose = np.array(pose)
        if not np.all(np.isfinite(pose)):
            raise file_error(path, None, f"image {iid}: quaternion and translation must be finite")
        n = b.count("keypoints", 24)
        rows = np.frombuffer(b.array("<u1", n, 24).tobytes(), dtype=[("xy", "<f8", 2), ("id", "<u8")])
        xy = rows["xy"].astype(float).reshape(n, 2)
        ids = rows["id"].astype(np.uint64)
        if not np.all(np.isfinite(xy)):
            raise file_error(path, None, f"image {iid}: keypoint coordinates must be finite")
        ids = np.where(ids == _NO_ID, -1, ids.astype(np.int64)).astype(np.int64)
        if np.any(ids < -1):
            raise file_error(path, None, f"image {iid}: a POINT3D_ID out of range")
        images[iid] = _image(path, None, iid, pose[:4], pose[4:], cid, name, xy, ids, cameras, names)
        names.add(name)
    b.end()
    return images


def _read_points_bin(path, images) -> dict[int, ColmapPoint]:
    b = _Bytes(path)
    points: dict[int, ColmapPoint] = {}
    for _ in range(b.count("points", 51)):
        pid, x, y, z, r, g, bl, error = b.take("<Q3d3Bd")
        if pid in points or pid >= 2**63:
            raise file_error(path, None, f"point {pid} again, or out of range")
        xyz = np.array([x, y, z])
        if not np.all(np.isfinite(xyz)) or not np.isfinite(error):
            raise file_error(path, None, f"point {pid}: X Y Z and ERROR must be finite")
        n = b.count("track elements", 8)
        track = b.array("<i4", n, 2).astype(np.int64)
        if np.any(track < 0):
            raise file_error(path, None, f"point {pid}: a negative image id or keypoint index in its track")
        points[pid] = _point(path, None, pid, xyz, np.array([r, g, bl], dtype=np.uint8), float(error), track, images)
    b.end()
    return points


# --------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------


def _g(v) -> str:
    return repr(float(v))  # 17 significant digits: exact round trip


def write_colmap_model(model: ColmapModel, folder, *, binary: bool = False, inputs=()) -> pathlib.Path:
    """Write ``model`` as a COLMAP sparse model folder (text, or binary with ``binary=True``).

    ``folder`` must be new or empty; it is written beside and renamed, so a
    failure leaves nothing.  Numbers are written exactly (17 digits in
    text).  ``inputs``: paths the output may not overwrite.

    Examples:
        The same model as text and as binary files reads back the same, to the last digit:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> from photax.io import ColmapModel, read_colmap_model, write_colmap_model
        >>> from photax.io.colmap import ColmapCamera
        >>> camera = ColmapCamera("SIMPLE_RADIAL", 640, 480, np.array([500.1, 320.0, 240.0, -0.0217]))
        >>> model = ColmapModel({1: camera}, {}, {})  # a camera, no images or points yet

        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> text = write_colmap_model(model, folder / "text")
        >>> binary = write_colmap_model(model, folder / "bin", binary=True)
        >>> print((text / "cameras.txt").read_text().splitlines()[-1])
        1 SIMPLE_RADIAL 640 480 500.1 320.0 240.0 -0.0217
        >>> [read_colmap_model(f).cameras[1].params.tolist() for f in (text, binary)]
        [[500.1, 320.0, 240.0, -0.0217], [500.1, 320.0, 240.0, -0.0217]]
    """

    from .atomic import atomic_path, check_output_path

    folder = pathlib.Path(folder)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise ValueError(f"refusing to write the COLMAP model {folder}: it exists and is not an empty folder")
    check_output_path(folder / "cameras.txt", inputs)
    for im in model.images.values():
        if not im.name or any(c in im.name for c in "\n\r\x00") or im.name != im.name.strip():
            raise ValueError(f"image {im.name!r}: a COLMAP image name must be one line without surrounding spaces")
    numbers = [*((f"camera {k}", c.params) for k, c in model.cameras.items()),
               *((f"image {im.name!r}", np.concatenate([im.qvec, im.tvec, np.ravel(im.xy)])) for im in model.images.values()),
               *((f"point {k}", np.append(p.xyz, p.error)) for k, p in model.points.items())]  # fmt: skip
    for what, values in numbers:
        if not np.all(np.isfinite(np.asarray(values, dtype=float))):
            raise ValueError(f"{what}: a value is not finite (nan or inf): not written")
    with atomic_path(folder.resolve(), folder=True) as tmp:
        if binary:
            _write_bin(model, tmp)
        else:
            _write_text(model, tmp)
    return folder


def _write_text(model: ColmapModel, out: pathlib.Path) -> None:
    lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    lines += [f"{i} {c.model} {c.width} {c.height} {' '.join(map(_g, c.params))}" for i, c in model.cameras.items()]
    (out / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = [
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "#   POINTS2D[] as (X, Y, POINT3D_ID)",
    ]
    for i, im in model.images.items():
        lines.append(f"{i} {' '.join(map(_g, [*im.qvec, *im.tvec]))} {im.camera_id} {im.name}")
        lines.append(" ".join(f"{_g(x)} {_g(y)} {p}" for (x, y), p in zip(im.xy.tolist(), im.point3d_ids.tolist())))
    (out / "images.txt").write_text("\n".join(lines) + "\n")
    lines = [
        "# 3D point list with one line of data per point:",
        "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
    ]
    for i, p in model.points.items():
        track = " ".join(f"{a} {b}" for a, b in zip(p.image_ids.tolist(), p.point2d_idx.tolist()))
        lines.append(f"{i} {' '.join(map(_g, p.xyz))} {' '.join(map(str, p.rgb.tolist()))} {_g(p.error)} {track}")
    (out / "points3D.txt").write_text("\n".join(lines) + "\n")


def _write_bin(model: ColmapModel, out: pathlib.Path) -> None:
    parts = [struct.pack("<Q", len(model.cameras))]
    for i, c in model.cameras.items():
        parts.append(struct.pack("<IiQQ", i, MODELS[c.model][0], c.width, c.height))
        parts.append(np.asarray(c.params, dtype="<f8").tobytes())
    (out / "cameras.bin").write_bytes(b"".join(parts))
    parts = [struct.pack("<Q", len(model.images))]
    for i, im in model.images.items():
        parts.append(struct.pack("<I7dI", i, *im.qvec, *im.tvec, im.camera_id))
        parts.append(im.name.encode("utf-8") + b"\x00")
        rows = np.zeros(len(im.xy), dtype=[("xy", "<f8", 2), ("id", "<u8")])
        rows["xy"] = im.xy
        rows["id"] = np.where(im.point3d_ids < 0, _NO_ID, im.point3d_ids.astype(np.uint64))
        parts.append(struct.pack("<Q", len(rows)) + rows.tobytes())
    (out / "images.bin").write_bytes(b"".join(parts))
    parts = [struct.pack("<Q", len(model.points))]
    for i, p in model.points.items():
        parts.append(struct.pack("<Q3d3Bd", i, *p.xyz, *p.rgb.tolist(), p.error))
        track = np.stack([p.image_ids, p.point2d_idx], axis=1).astype("<i4")
        parts.append(struct.pack("<Q", len(track)) + track.tobytes())
    (out / "points3D.bin").write_bytes(b"".join(parts))


# --------------------------------------------------------------------------
# COLMAP <-> photax
# --------------------------------------------------------------------------


def colmap_camera_to_photax(camera: ColmapCamera) -> FrameCamera:
    """A COLMAP camera as a :class:`photax.FrameCamera` in pixels (module docstring).

    Raises:
        ValueError: a model photax has no camera for, named (with the ones
            it reads).
    """
    model = camera.model
    if model not in PHOTAX_MODELS:
        raise ValueError(f"COLMAP camera model {model} has no photax camera (photax reads {', '.join(PHOTAX_MODELS)})")
    p = dict(zip(MODELS[model][1], np.asarray(camera.params, dtype=float).tolist()))
    fx = p.get("fx", p.get("f"))
    fy = p.get("fy", fx)
    k1, k2, k3 = p.get("k1", p.get("k", 0.0)), p.get("k2", 0.0), p.get("k3", 0.0)
    p1, p2 = p.get("p1", 0.0), p.get("p2", 0.0)
    k4, k5, k6 = p.get("k4", 0.0), p.get("k5", 0.0), p.get("k6", 0.0)
    w, h = camera.width, camera.height
    aspect = fx / fy
    pp = (p["cx"] - w / 2.0, (h / 2.0 - p["cy"]) * aspect)
    kind = PHOTAX_MODELS[model]
    if kind == "fisheye":
        distortion = (k1, k2, k3, k4)
    elif kind == "opencv" and (k4 != 0 or k5 != 0 or k6 != 0):
        distortion = (k1, k2, k3, 0.0 - p1, p2, k4, k5, k6, 0.0, 0.0, 0.0, 0.0)
    else:
        kind, distortion = "brown", (k1, k2, k3, 0.0 - p1, p2)
    return FrameCamera(fx, pp, distortion, pixel_size=(1.0, aspect), image_size=(w, h), model=kind)


def photax_camera_to_colmap(camera: FrameCamera) -> ColmapCamera:
    """A :class:`photax.FrameCamera` (with a pixel grid) as the simplest COLMAP camera that holds it exactly.

    Raises:
        ValueError: no pixel grid, a camera that is not a plain frame camera
            (a scan), or an ``opencv`` camera with thin-prism terms (COLMAP's
            FULL_OPENCV has none).
    """
    if type(camera) is not FrameCamera or camera.pixel_size is None or camera.image_size is None:
        raise ValueError("a COLMAP camera needs a FrameCamera with pixel_size and image_size (not a scan)")
    sx, sy = (float(v) for v in np.asarray(camera.pixel_size))
    f = float(camera.focal_length)
    x0, y0 = (float(v) for v in np.asarray(camera.principal_point))
    w, h = camera.image_size
    fx, fy = f / sx, f / sy
    cx, cy = w / 2.0 + x0 / sx, h / 2.0 - y0 / sy
    d = [float(v) for v in np.asarray(camera.distortion)]
    if camera.model == "fisheye":
        return ColmapCamera("OPENCV_FISHEYE", w, h, np.array([fx, fy, cx, cy, *d]))
    k1, k2, k3, p1, p2 = d[:5]
    p1 = 0.0 - p1  # OpenCV's sense (y down)
    k4, k5, k6 = d[5:8] if camera.model == "opencv" else (0.0, 0.0, 0.0)
    if camera.model == "opencv" and any(v != 0 for v in d[8:]):
        raise ValueError("COLMAP has no camera model with thin-prism terms (s1-s4) besides a fisheye: not written")
    square = fx == fy
    if k3 != 0 or k4 != 0 or k5 != 0 or k6 != 0:
        return ColmapCamera("FULL_OPENCV", w, h, np.array([fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6]))
    if p1 != 0 or p2 != 0 or (not square and (k1 != 0 or k2 != 0)):
        return ColmapCamera("OPENCV", w, h, np.array([fx, fy, cx, cy, k1, k2, p1, p2]))
    if not square:
        return ColmapCamera("PINHOLE", w, h, np.array([fx, fy, cx, cy]))
    if k2 != 0:
        return ColmapCamera("RADIAL", w, h, np.array([fx, cx, cy, k1, k2]))
    if k1 != 0:
        return ColmapCamera("SIMPLE_RADIAL", w, h, np.array([fx, cx, cy, k1]))
    return ColmapCamera("SIMPLE_PINHOLE", w, h, np.array([fx, cx, cy]))


def _pixels_to_plane(colrow: np.ndarray, camera: FrameCamera) -> np.ndarray:
    """photax pixels -> image plane of a plain frame camera, in numpy."""
    centre = (np.asarray(camera.image_size, dtype=float) - 1) / 2
    return (colrow - centre) * np.asarray(camera.pixel_size, dtype=float) * [1.0, -1.0]


def _plane_to_pixels(xy: np.ndarray, camera: FrameCamera) -> np.ndarray:
    centre = (np.asarray(camera.image_size, dtype=float) - 1) / 2
    return xy * [1.0, -1.0] / np.asarray(camera.pixel_size, dtype=float) + centre


def colmap_problem(model: ColmapModel, *, free_intrinsics=(), source=None):
    """:class:`ColmapModel` -> :class:`photax.BundleProblem` (see :func:`read_colmap`)."""
    from ..bundle import BundleProblem
    from ..camera import from_opencv_extrinsics
    from ..collinearity import ExteriorOrientation
    from ..rotation import angles_from_matrix

    at = f"{source}: " if source is not None else ""
    cam_ids = sorted(model.cameras)
    cams = []
    for cid in cam_ids:
        try:
            cams.append(colmap_camera_to_photax(model.cameras[cid]))
        except ValueError as exc:
            raise ValueError(f"{at}camera {cid}: {exc}") from None
    image_ids = sorted(model.images)
    if not image_ids or not model.points:
        raise ValueError(f"{at}the model has no registered images or no 3-D points")
    row = {iid: i for i, iid in enumerate(image_ids)}
    ims = [model.images[i] for i in image_ids]
    r_cv = quaternion_to_matrix(np.array([im.qvec for im in ims]))
    r_wc, centres = from_opencv_extrinsics(r_cv, np.array([im.tvec for im in ims]))
    angles = np.asarray(angles_from_matrix(r_wc, "omega-phi-kappa"))
    exterior = ExteriorOrientation(centres, angles, "omega-phi-kappa")
    image_camera = np.array([cam_ids.index(im.camera_id) for im in ims], dtype=np.int64)
    point_ids = sorted(model.points)
    single = [i for i in point_ids if len(set(model.points[i].image_ids.tolist())) < 2]
    if single:  # COLMAP's own models have none; a model written from a block with single-ray GCPs has
        warnings.warn(
            f"{at}{len(single)} 3-D point(s) seen in fewer than 2 images left out (a tie point needs 2), "
            f"e.g. point {single[0]}",
            stacklevel=3,
        )
        point_ids = sorted(set(point_ids) - set(single))
    oi, op, px = [], [], []
    for k, pid in enumerate(point_ids):
        p = model.points[pid]
        for iid, j in zip(p.image_ids.tolist(), p.point2d_idx.tolist()):
            oi.append(row[iid])
            op.append(k)
            px.append(model.images[iid].xy[j])
    oi, op = np.array(oi, dtype=np.int64), np.array(op, dtype=np.int64)
    px = np.array(px, dtype=float).reshape(-1, 2) - 0.5  # COLMAP's pixel corner -> photax's pixel centre
    xy, sigma = np.empty_like(px), np.empty(len(px))
    for j, cam in enumerate(cams):
        sel = image_camera[oi] == j
        xy[sel] = _pixels_to_plane(px[sel], cam)
        sigma[sel] = float(np.mean(np.asarray(cam.pixel_size)))
    try:
        return BundleProblem(
            cams, exterior, np.array([model.points[i].xyz for i in point_ids]), oi, op, xy, obs_sigma=sigma,
            image_camera=image_camera, free_intrinsics=free_intrinsics, image_names=[im.name for im in ims],
            point_names=[str(i) for i in point_ids],
        )  # fmt: skip
    except ValueError as exc:  # e.g. a point seen in one image only
        raise ValueError(f"{at}{exc}") from None


def read_colmap(folder, *, free_intrinsics=()):
    """Read a COLMAP sparse model folder as a :class:`photax.BundleProblem`.

    One photax camera per COLMAP camera (in pixels), one image per
    registered image (named by COLMAP's NAME, in image-id order), one tie
    point per 3-D point (named by its POINT3D_ID), one observation per track
    element (sigma 1 pixel).  Keypoints without a 3-D point are not kept;
    3-D points seen in fewer than two images (COLMAP leaves none; a model
    written from a block with single-ray control points has them) are left
    out with a warning.
    The model has no datum of its own: georeference it (:func:`photax.georeference`)
    or adjust with ``gauge="damped"``.

    Args:
        folder: the model (``cameras``, ``images``, ``points3D``, ``.bin`` or ``.txt``).
        free_intrinsics: as :class:`photax.BundleProblem`'s; default fixed.

    Raises:
        ValueError: as :func:`read_colmap_model`, and a camera model photax
            cannot represent (named), naming the file or folder.

    Examples:

        A block written by :func:`write_colmap` and read back: orientations and points as they were
        (each observation kept, listed point by point as COLMAP's tracks are):

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> from photax.io import read_colmap, write_colmap
        >>> from photax.scene import synthetic_block
        >>> problem, _ = synthetic_block(0, n_control=0, n_check=0)  # ties only: each seen twice or more
        >>> back = read_colmap(write_colmap(problem, pathlib.Path(tempfile.mkdtemp()) / "sparse"))
        >>> back
        BundleProblem(8 images, 1 cameras, 100 points (0 control, 0 check), 258 observations)
        >>> gap = np.asarray(back.exterior.position) - np.asarray(problem.exterior.position)
        >>> bool(np.abs(gap).max() < 1e-6), bool(np.array_equal(back.points, problem.points))
        (True, True)
    """
    folder = pathlib.Path(folder)
    model = read_colmap_model(folder)
    return colmap_problem(model, free_intrinsics=free_intrinsics, source=folder)


def colmap_model_from_problem(problem_or_result) -> ColmapModel:
    """A :class:`photax.BundleProblem` or adjusted :class:`photax.BundleResult` as a :class:`ColmapModel`.

    Cameras and images are numbered from 1 in the problem's order; a point
    whose name is a positive whole number keeps it as its id (a model read by
    :func:`read_colmap` keeps its ids), the others are numbered after the
    largest; each image's keypoints are its observations, each point's
    track their image and index.  Colours are grey 128 and errors -1
    (unknown).
    """
    from .bal import block_state

    prob, cams, rot, centres, points = block_state(problem_or_result)
    from ..camera import opencv_extrinsics

    cameras = {j + 1: photax_camera_to_colmap(c) for j, c in enumerate(cams)}
    r_cv, t = opencv_extrinsics(np.asarray(rot, dtype=float), np.asarray(centres, dtype=float))
    q = matrix_to_quaternion(r_cv)
    points = np.asarray(points, dtype=float)
    if not np.all(np.isfinite(points)):
        raise ValueError("every point needs finite coordinates to be written to COLMAP")
    pids = _point_ids(prob.point_names)
    images = {}
    oi, op = prob.obs_image, prob.obs_point
    pid_of_obs = np.asarray(pids, dtype=np.int64)[op]
    by_image = np.argsort(oi, kind="stable")  # each image's observations, in order: its keypoints
    starts = np.searchsorted(oi[by_image], np.arange(prob.n_images + 1))
    keypoint = np.empty(len(oi), dtype=np.int64)
    keypoint[by_image] = np.arange(len(oi)) - np.repeat(starts[:-1], np.diff(starts))
    for i in range(prob.n_images):
        sel = by_image[starts[i] : starts[i + 1]]
        cam = cams[prob.image_camera[i]]
        xy = _plane_to_pixels(np.asarray(prob.obs_xy[sel]), cam) + 0.5
        images[i + 1] = ColmapImage(q[i], t[i], int(prob.image_camera[i]) + 1, prob.image_names[i], xy, pid_of_obs[sel])
    by_point = np.argsort(op, kind="stable")
    pstarts = np.searchsorted(op[by_point], np.arange(len(pids) + 1))
    pts = {}
    for k, pid in enumerate(pids):
        sel = by_point[pstarts[k] : pstarts[k + 1]]
        pts[pid] = ColmapPoint(points[k], np.full(3, 128, dtype=np.uint8), -1.0, oi[sel] + 1, keypoint[sel])
    return ColmapModel(cameras, images, pts)


def _point_ids(names) -> list[int]:
    """COLMAP ids for points: a name that is a positive whole number (``read_colmap``'s) keeps it,
    the others (e.g. GCPs) are numbered after the largest."""
    kept = [int(n) if n.isascii() and n.isdigit() and 0 < int(n) < 2**63 else None for n in map(str, names)]
    seen: set[int] = set()
    for k, v in enumerate(kept):
        if v in seen:
            kept[k] = None  # "7" and "07": one keeps 7
        elif v is not None:
            seen.add(v)
    nxt = max(seen, default=0) + 1
    out = []
    for v in kept:
        if v is None:
            v, nxt = nxt, nxt + 1
        out.append(v)
    return out


def write_colmap(problem_or_result, folder, *, binary: bool = False, inputs=()) -> pathlib.Path:
    """Write a :class:`photax.BundleProblem` or :class:`photax.BundleResult` as a COLMAP model folder
    (:func:`colmap_model_from_problem`, :func:`write_colmap_model`).

    Examples:
        A synthetic block's 4000 x 3000 px camera of f = 3000 px becomes a ``SIMPLE_PINHOLE`` with the
        principal point at the centre, in binary files here:

        >>> import pathlib, tempfile
        >>> from photax.io import read_colmap_model, write_colmap
        >>> from photax.scene import synthetic_block
        >>> problem, _ = synthetic_block(0, n_control=0, n_check=0)
        >>> folder = write_colmap(problem, pathlib.Path(tempfile.mkdtemp()) / "sparse", binary=True)
        >>> sorted(p.name for p in folder.iterdir())
        ['cameras.bin', 'images.bin', 'points3D.bin']
        >>> model = read_colmap_model(folder)
        >>> camera = model.cameras[1]
        >>> camera.model, camera.width, camera.height, camera.params.tolist()
        ('SIMPLE_PINHOLE', 4000, 3000, [3000.0, 2000.0, 1500.0])
        >>> len(model.images), len(model.points), model.images[1].name
        (8, 100, 'S1_1')
    """
    return write_colmap_model(colmap_model_from_problem(problem_or_result), folder, binary=binary, inputs=inputs)


# --------------------------------------------------------------------------
# One file of a model, for --camera / --exterior
# --------------------------------------------------------------------------


def is_colmap_file(path, kind: str) -> bool:
    """Whether ``path`` is a COLMAP ``cameras`` or ``images`` file (``kind``): ``cameras.bin`` /
    ``images.bin`` by name, a ``.txt`` by its first data line (``1 PINHOLE 640 480 ...``,
    ``1 QW QX QY QZ TX TY TZ 1 NAME``)."""
    path = pathlib.Path(path)
    if path.name == f"{kind}.bin":
        return path.is_file()
    if path.suffix.lower() != ".txt" or not path.is_file():
        return False
    first = next(
        (ln.split() for ln in head_text(path, 4096).splitlines() if ln.strip() and not ln.lstrip().startswith("#")), []
    )
    if kind == "cameras":
        return len(first) >= 4 and first[0].isdigit() and first[1] in MODELS and first[2].isdigit()
    try:
        return len(first) >= 10 and first[0].isdigit() and first[8].isdigit() and bool([float(v) for v in first[1:8]])
    except ValueError:
        return False


def read_colmap_cameras(path) -> dict[str, FrameCamera]:
    """The cameras of a COLMAP ``cameras.txt`` / ``cameras.bin``: ``{camera id as text: FrameCamera}``
    in pixels; a model photax cannot represent is refused by name (naming the file)."""
    path = pathlib.Path(path)
    cams = _read_cameras_bin(path) if path.suffix == ".bin" else _read_cameras_text(path)
    out = {}
    for cid, c in cams.items():
        try:
            out[str(cid)] = colmap_camera_to_photax(c)
        except ValueError as exc:
            raise file_error(path, None, f"camera {cid}: {exc}") from None
    return out


def read_colmap_exteriors(path) -> dict:
    """The poses of a COLMAP ``images.txt`` / ``images.bin`` (the cameras file of the same kind
    beside it is read to check the camera ids): ``{image stem: ExteriorOrientation
    ("omega-phi-kappa")}`` in the model's frame -- a ground CRS only for a georeferenced model
    (``photax bundle --colmap-out``)."""
    from ..camera import from_opencv_extrinsics
    from ..collinearity import ExteriorOrientation
    from ..rotation import angles_from_matrix

    path = pathlib.Path(path)
    cam_path = path.with_name("cameras" + path.suffix)
    if not cam_path.is_file():
        raise file_error(path, None, f"no {cam_path.name} beside it (COLMAP's images need their cameras file)")
    if path.suffix == ".bin":
        images = _read_images_bin(path, _read_cameras_bin(cam_path))
    else:
        images = _read_images_text(path, _read_cameras_text(cam_path))
    if not images:
        raise file_error(path, None, "no images")
    ims = list(images.values())
    r_wc, centres = from_opencv_extrinsics(
        quaternion_to_matrix(np.array([im.qvec for im in ims])), np.array([im.tvec for im in ims])
    )
    angles = np.asarray(angles_from_matrix(r_wc, "omega-phi-kappa"))
    out = {}
    for im, c, a in zip(ims, centres, angles):
        stem = pathlib.PurePath(im.name).stem
        if stem in out:
            raise file_error(path, None, f"two images named {excerpt(stem)} (in different folders): rename one")
        out[stem] = ExteriorOrientation(c, a, "omega-phi-kappa")
    return out
