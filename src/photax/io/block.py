"""The block folder format of ``photax bundle --format block``.

A folder with ``block.json`` (cameras, images, angle convention),
``observations.csv`` (pixel measurements) and ``points.csv`` (tie, control
and check points).  See :func:`read_block` for the exact layout and
``data/block/`` for a sample.
"""

from __future__ import annotations

import csv
import pathlib

import numpy as np

from ..bundle import INTRINSICS, ROLES, BundleProblem
from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from ..rotation import check_convention
from .files import (
    as_numbers,
    excerpt,
    load_json,
    number,
    read_text,
    split_lines,
    where,
)


def read_block(folder) -> BundleProblem:
    """Read a block folder: ``block.json``, ``observations.csv``, ``points.csv``.

    ``block.json``::

        {"convention": "omega-phi-kappa",          # or "phi-omega-kappa"
         "angle_unit": "degrees",                  # or "radians"
         "cameras": {"cam": {"focal_length_px": 3000, "image_size": [4000, 3000],
                             "principal_point_px": [1999.5, 1499.5],   # optional
                             "distortion": [0, 0, 0, 0, 0],           # optional, k1 k2 k3 p1 p2
                             "free": ["f", "k1"]},                    # optional, self-calibration
                     "scan": {"file": "scan_camera.yaml", "free": ["f"]}},  # or a camera file
                     # (photax.io.camera_file, path relative to the folder; e.g. a scanned camera
                     # written by photax fiducials --camera-out, whose pixels go through its scan block)
         "crs": "EPSG:32632",                      # optional: the ground CRS (checked against a DEM's)
         "images": [{"name": "IMG_1", "camera": "cam",
                     "position": [X, Y, Z], "angles": [a1, a2, a3],   # or null: resected
                     "fixed": false}]}

    ``observations.csv``: header ``image,point,col,row[,sigma_px]``, pixel
    coordinates (column right, row down, origin at the centre of the
    top-left pixel).  ``points.csv``: header ``name,X,Y,Z,role[,sigma]``
    with role ``tie``/``control``/``check``; X Y Z may be empty for tie
    points; ``sigma`` (ground unit) of control points, 0 = fixed.

    Image and point names are unique, a point is measured at most once per
    image, X Y Z are all given or all empty (tie points only), sigmas are
    finite (``sigma_px > 0``, ``sigma >= 0``), ``block.json`` is strict JSON
    without duplicate keys.

    Raises:
        ValueError: naming the file (and the line, for the CSV files) of a
            malformed entry; ``folder`` not a folder, or a file in it a
            folder or unreadable, naming the path.
        FileNotFoundError: no such folder or file.

    Examples:
        A block written by :func:`write_block` and read back: the same images, points, roles and
        observations (pixels in the files, image-plane units in the problem):

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> from photax.io import read_block, write_block
        >>> from photax.scene import synthetic_block
        >>> problem, _ = synthetic_block(0)
        >>> back = read_block(write_block(problem, pathlib.Path(tempfile.mkdtemp()) / "block"))
        >>> back
        BundleProblem(8 images, 1 cameras, 110 points (6 control, 4 check), 286 observations)
        >>> bool(np.allclose(back.obs_xy, problem.obs_xy, atol=1e-9)), list(back.roles) == list(problem.roles)
        (True, True)
        >>> bool(np.array_equal(back.exterior.position, problem.exterior.position))
        True
    """
    folder = pathlib.Path(folder)
    if not folder.is_dir():
        if folder.exists():
            raise ValueError(f"{folder}: a block is a folder (block.json, observations.csv, points.csv), not a file")
        raise FileNotFoundError(f"{folder}: no such block folder")
    meta_path = folder / "block.json"
    meta = load_json(meta_path, read_text(meta_path, "block file"))
    if not isinstance(meta, dict):
        raise ValueError(f'{meta_path}: expected an object {{"cameras": ..., "images": ...}}')
    meta_file = _Meta(meta_path)
    conv = meta.get("convention", "omega-phi-kappa")
    try:
        conv = check_convention(conv)
    except ValueError as exc:
        raise meta_file.bad(str(exc)) from None
    unit = meta.get("angle_unit", "degrees")
    if unit not in ("degrees", "radians"):
        raise meta_file.bad(f"angle_unit must be 'degrees' or 'radians', got {excerpt(unit)}")
    cameras, images = meta.get("cameras"), meta.get("images")
    if not isinstance(cameras, dict) or not cameras or not isinstance(images, list) or not images:
        raise meta_file.bad("needs a non-empty object 'cameras' and a non-empty list 'images'")
    crs = meta.get("crs")
    if crs is not None and not (isinstance(crs, str) and crs.strip()):
        raise meta_file.bad(f"'crs' must be a CRS as text (EPSG code, WKT, PROJ), got {crs!r}")
    cam_names = list(cameras)
    cams, free = _read_cameras(meta_file, cameras)
    names, img_cam, pos, ang, fixed = _read_images(meta_file, images, cam_names, unit)
    pnames, xyz, roles, psig = _read_points(folder / "points.csv")
    oi, op, px, osig = _read_observations(folder / "observations.csv", names, pnames)
    xy, ps = _pixels_to_image(px, osig, cams, np.array(img_cam)[oi])
    try:
        return BundleProblem(
            cams, ExteriorOrientation(np.array(pos, dtype=float), np.array(ang, dtype=float), conv),
            np.array(xyz, dtype=float), oi, op, xy, obs_sigma=ps, image_camera=np.array(img_cam), roles=roles,
            point_sigma=np.array(psig), free_intrinsics=free, fixed_exterior=np.array(fixed), image_names=names,
            point_names=pnames, crs=crs,
        )  # fmt: skip
    except ValueError as exc:  # e.g. a tie point seen in one image only
        raise ValueError(f"{folder}: {exc}") from None


class _Meta:
    """Errors naming ``block.json``, and its checked number vectors."""

    def __init__(self, path: pathlib.Path):
        self.path = path

    def bad(self, what: str) -> ValueError:
        return ValueError(f"{self.path}: {what}")

    def vector(self, where_, value, n, what):
        v = as_numbers(value)
        if v is None or v.shape != ((n,) if n else ()) or not np.all(np.isfinite(v)):
            raise self.bad(
                f"{where_}: {what} must be {n or 1} finite number{'s' if n > 1 else ''}, got {excerpt(value)}"
            )
        return v


def _read_cameras(meta: _Meta, cameras: dict) -> tuple[list[FrameCamera], np.ndarray]:
    """``block.json``'s cameras and their free intrinsics ``(n_cameras, n_intrinsics)``
    (the cameras' ``intrinsic_names``; all of one model, else the problem says so)."""
    cams, free = [], []
    for name in cameras:
        c, at = cameras[name], f"camera {excerpt(name)}"
        if isinstance(c, dict) and "file" in c:
            cams.append(_camera_file(meta, at, c))
            free.append(_free(meta, at, c, cams[-1].intrinsic_names))
            continue
        if not isinstance(c, dict) or "focal_length_px" not in c or "image_size" not in c:
            raise meta.bad(f"{at}: needs focal_length_px and image_size")
        unknown = sorted(set(c) - {"focal_length_px", "image_size", "principal_point_px", "distortion", "free"})
        if unknown:
            raise meta.bad(f"{at}: unknown key {excerpt(unknown[0])}")
        f = float(meta.vector(at, c["focal_length_px"], 0, "focal_length_px"))
        size = meta.vector(at, c["image_size"], 2, "image_size")
        if not f > 0 or np.any(size < 1) or np.any(size != np.round(size)) or np.any(size > 2**31 - 1):
            raise meta.bad(
                f"{at}: focal_length_px must be positive and image_size whole pixels >= 1, "
                f"got {excerpt(c['focal_length_px'])} and {excerpt(c['image_size'])}"
            )
        pp = c.get("principal_point_px")
        pp = None if pp is None else tuple(meta.vector(at, pp, 2, "principal_point_px"))
        dist = c.get("distortion")
        dist = None if dist is None else meta.vector(at, dist, 5, "distortion")
        cams.append(FrameCamera.from_pixels(f, (int(size[0]), int(size[1])), pp, dist))
        free.append(_free(meta, at, c, INTRINSICS))
    if len({len(f) for f in free}) > 1:
        raise meta.bad(f"the cameras must share one distortion model, got {sorted({c.model for c in cams})}")
    return cams, np.array(free, dtype=bool).reshape(len(cameras), -1)


def _free(meta: _Meta, at: str, c: dict, names: tuple[str, ...]) -> np.ndarray:
    """``(len(names),)`` the camera entry's free intrinsics, of its ``names``."""
    names_free = c.get("free", [])
    if not isinstance(names_free, list) or not all(isinstance(n, str) for n in names_free):
        raise meta.bad(f"{at}: free must be a list of names from {names}, got {excerpt(names_free)}")
    unknown = set(names_free) - set(names)
    if unknown:
        raise meta.bad(f"{at}: unknown free parameters {sorted(unknown)}; use {names}")
    out = np.zeros(len(names), dtype=bool)
    out[[names.index(n) for n in names_free]] = True
    return out


def _camera_file(meta: _Meta, at: str, c: dict) -> FrameCamera:
    """A camera entry ``{"file": ..., "free": [...]}``: the photax camera file it names."""
    from .camera_file import read_camera

    unknown = sorted(set(c) - {"file", "free"})
    if unknown:
        raise meta.bad(f"{at}: unknown key {excerpt(unknown[0])} (a camera given by file has only file and free)")
    if not isinstance(c["file"], str) or not c["file"].strip():
        raise meta.bad(f"{at}: file must be the path of a camera file, got {excerpt(c['file'])}")
    cam = read_camera(meta.path.parent / c["file"])
    if cam.image_size is None or cam.pixel_size is None:
        raise meta.bad(f"{at}: the camera file {c['file']} needs image_size and a pixel size (pixels are observed)")
    return cam


def _read_images(meta: _Meta, images: list, cam_names: list[str], unit: str):
    """``block.json``'s images: ``(names, camera index, positions, angles
    in radians, fixed)``, NaN for orientations to be resected."""
    names, img_cam, pos, ang, fixed = [], [], [], [], []
    for i, im in enumerate(images):
        at = f"images[{i}]"
        if not isinstance(im, dict):
            raise meta.bad(f"{at}: expected an object with name, camera, position, angles")
        if not isinstance(im.get("camera"), str) or im["camera"] not in cam_names:
            raise meta.bad(f"{at}: camera {excerpt(im.get('camera'))} is not in 'cameras'")
        name = im.get("name", f"image {i}")
        if not isinstance(name, str) or not name.strip() or name in names:
            raise meta.bad(f"{at}: image names must be distinct, non-empty text, got {excerpt(name)}")
        names.append(name)
        img_cam.append(cam_names.index(im["camera"]))
        p, a = im.get("position"), im.get("angles")
        pos.append([np.nan] * 3 if p is None else meta.vector(at, p, 3, "position"))
        a = [np.nan] * 3 if a is None else meta.vector(at, a, 3, "angles")
        ang.append(np.radians(a) if unit == "degrees" else np.asarray(a, dtype=float))
        if not isinstance(im.get("fixed", False), bool):
            raise meta.bad(f"{at}: fixed must be true or false, got {excerpt(im['fixed'])}")
        fixed.append(im.get("fixed", False))
    return names, img_cam, pos, ang, fixed


def _rows(path: pathlib.Path, required, optional=()):
    """``(line number, {column: text})`` of a block CSV file, header checked."""
    lines = split_lines(read_text(path, "block file"))
    reader = csv.reader(lines)
    try:
        header = [h.strip() for h in next(reader, [])]
        missing = sorted(set(required) - set(header))
        unknown = sorted(set(header) - set(required) - set(optional))
        if missing or unknown or len(set(header)) != len(header):
            # a header naming none of the columns: some other file, none of it quoted
            got = f"got {excerpt(header, 80)}" if set(header) & set(required) else "got none of them"
            raise ValueError(
                f"{where(path, 1)}: the header must name the columns {list(required)} "
                f"(and optionally {list(optional)}) once each, {got}"
            )
        for row in reader:
            line = reader.line_num
            if not row or not "".join(row).strip():
                continue
            if len(row) != len(header):
                raise ValueError(f"{where(path, line)}: expected {len(header)} columns, got {len(row)}")
            yield line, {k: v.strip() for k, v in zip(header, row)}
    except csv.Error as exc:
        raise ValueError(f"{where(path, reader.line_num)}: not a CSV line ({exc})") from None


def _read_points(ppath: pathlib.Path):
    """``points.csv``: ``(names, XYZ (NaN for unknown tie points), roles, sigmas)``."""
    pnames, xyz, roles, psig = [], [], [], []
    plines: dict[str, int] = {}
    for line, row in _rows(ppath, ("name", "X", "Y", "Z", "role"), ("sigma",)):
        if row["role"] not in ROLES:
            raise ValueError(f"{where(ppath, line)}: role must be one of {ROLES}, got {excerpt(row['role'])}")
        name = row["name"]
        if not name:
            raise ValueError(f"{where(ppath, line)}: empty point name")
        if name in plines:
            raise ValueError(f"{where(ppath, line)}: point {excerpt(name)} again (first on line {plines[name]})")
        plines[name] = line
        given = [row[k] != "" for k in "XYZ"]
        if any(given) and not all(given) or (row["role"] == "control" and not all(given)):
            raise ValueError(f"{where(ppath, line)}: X, Y, Z must all be given (or all empty for a tie point)")
        pnames.append(name)
        xyz.append([number(ppath, line, row[k], k) if row[k] else np.nan for k in "XYZ"])
        roles.append(row["role"])
        s = number(ppath, line, row["sigma"], "sigma") if row.get("sigma") else 0.0
        if s < 0:
            raise ValueError(
                f"{where(ppath, line)}: sigma must be >= 0 (0 fixes the point), got {excerpt(row['sigma'])}"
            )
        psig.append(s)
    if not pnames:
        raise ValueError(f"{ppath}: no points")
    return pnames, xyz, roles, psig


def _read_observations(opath: pathlib.Path, names: list[str], pnames: list[str]):
    """``observations.csv``: image and point indices ``(k,)``, pixels ``(k, 2)``, sigmas ``(k,)``."""
    pidx = {n: i for i, n in enumerate(pnames)}
    iidx = {n: i for i, n in enumerate(names)}
    oi, op, px, osig = [], [], [], []
    seen: dict[tuple[str, str], int] = {}
    for line, row in _rows(opath, ("image", "point", "col", "row"), ("sigma_px",)):
        if row["image"] not in iidx or row["point"] not in pidx:
            raise ValueError(
                f"{where(opath, line)}: unknown image {excerpt(row['image'])} or point {excerpt(row['point'])}"
            )
        pair = (row["image"], row["point"])
        if pair in seen:
            raise ValueError(
                f"{where(opath, line)}: point {excerpt(pair[1])} measured again "
                f"in image {excerpt(pair[0])} "
                f"(first on line {seen[pair]})"
            )
        seen[pair] = line
        oi.append(iidx[row["image"]])
        op.append(pidx[row["point"]])
        px.append([number(opath, line, row["col"], "col"), number(opath, line, row["row"], "row")])
        s = number(opath, line, row["sigma_px"], "sigma_px") if row.get("sigma_px") else 1.0
        if not s > 0:
            raise ValueError(f"{where(opath, line)}: sigma_px must be positive, got {excerpt(row['sigma_px'])}")
        osig.append(s)
    if not oi:
        raise ValueError(f"{opath}: no observations")
    return np.array(oi), np.array(op), np.array(px, dtype=float).reshape(-1, 2), np.array(osig)


def _pixels_to_image(px: np.ndarray, osig: np.ndarray, cams: list[FrameCamera], cam_of_obs: np.ndarray):
    """Pixels and pixel sigmas -> image-plane coordinates and sigmas (camera unit)."""
    xy = np.empty_like(px)
    ps = np.empty(len(px))
    for j, cam in enumerate(cams):
        # FrameCamera.pixel_to_image in numpy: eager JAX would compile its ops
        # again for every new number of observations.
        sel = cam_of_obs == j
        if type(cam) is not FrameCamera:  # e.g. a scanned camera: pixels through its own transformation
            xy[sel] = np.asarray(cam.pixel_to_image(px[sel]))
            ps[sel] = osig[sel] * float(np.mean(np.asarray(cam.pixel_size)))
            continue
        centre = (np.asarray(cam.image_size, dtype=float) - 1) / 2
        size = np.asarray(cam.pixel_size, dtype=float)
        xy[sel] = (px[sel] - centre) * size * [1.0, -1.0]
        ps[sel] = osig[sel] * float(np.mean(size))
    return xy, ps


def write_block(problem: BundleProblem, folder, *, units=None, inputs=()) -> pathlib.Path:
    """Write ``problem`` as a block folder that :func:`read_block` reads back.

    ``block.json`` (angles in radians, the problem's convention), one camera
    file per camera (``cameras/NAME.yaml``, so a scanned camera keeps its
    film transformation; :func:`photax.io.write_camera`), ``points.csv``
    with every point's role and sigma, ``observations.csv`` in pixels.
    Numbers are written with 17 significant digits: the round trip is
    exact to rounding.

    Args:
        problem: the block; camera names are ``cam`` (one camera) or
            ``cam1``, ``cam2``...
        folder: a new or empty folder (written beside it, then renamed: a
            failure leaves nothing).
        units: the cameras' length unit (``"mm"``, ``"m"``, ``"px"``), one
            string or one per camera; default ``"px"``, which needs pixel
            size 1 (:func:`photax.io.camera_file.camera_to_dict`).
        inputs: paths this run read: ``folder`` may not be one of them.

    Raises:
        ValueError: what the format cannot hold (different x / y sigmas
            of an observation, per-axis point sigmas, some but not all
            exterior parameters of an image fixed), a camera without
            ``image_size``, or a non-empty ``folder``.

    Examples:
        The files of a block folder, and the first lines of its tables:

        >>> import pathlib, tempfile
        >>> from photax.io import write_block
        >>> from photax.scene import synthetic_block
        >>> problem, _ = synthetic_block(0)
        >>> folder = write_block(problem, pathlib.Path(tempfile.mkdtemp()) / "block")
        >>> sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))
        ['block.json', 'cameras', 'cameras/cam.yaml', 'observations.csv', 'points.csv']
        >>> (folder / "points.csv").read_text().splitlines()[0], (folder / "observations.csv").read_text()[:28]
        ('name,X,Y,Z,role,sigma', 'image,point,col,row,sigma_px')
    """

    import json

    from .atomic import atomic_path
    from .camera_file import write_camera

    folder = check_block_output(folder, inputs)
    p = problem
    if np.any(p.obs_sigma[:, 0] != p.obs_sigma[:, 1]):
        raise ValueError("the block format has one sigma per observation: x and y sigmas differ")
    if np.any(p.point_sigma.min(axis=1) != p.point_sigma.max(axis=1)):
        raise ValueError("the block format has one sigma per point: per-axis point sigmas differ")
    fixed = p.fixed_exterior.all(axis=1)
    if np.any(p.fixed_exterior.any(axis=1) & ~fixed):
        raise ValueError(
            "the block format fixes whole images: some exterior parameters of an image are fixed, others not"
        )
    n_cam = len(p.cameras)
    units = [units] * n_cam if units is None or isinstance(units, str) else list(units)
    cam_names = ["cam"] if n_cam == 1 else [f"cam{j + 1}" for j in range(n_cam)]
    with atomic_path(folder.resolve(), folder=True) as tmp:  # renamed onto ``folder`` (empty) at the end
        cameras = {}
        for j, (name, cam) in enumerate(zip(cam_names, p.cameras)):
            if cam.image_size is None:
                raise ValueError(f"camera {j}: the block format observes pixels, the camera needs image_size")
            write_camera(cam, tmp / "cameras" / f"{name}.yaml", unit=units[j])
            free = [n for n, f in zip(p.intrinsic_names, p.free_intrinsics[j]) if f]
            cameras[name] = {"file": f"cameras/{name}.yaml", **({"free": free} if free else {})}
        eo = p.exterior
        images = [
            {
                "name": n,
                "camera": cam_names[c],
                "position": np.asarray(eo.position[i]).tolist(),
                "angles": np.asarray(eo.angles[i]).tolist(),
                **({"fixed": True} if fixed[i] else {}),
            }
            for i, (n, c) in enumerate(zip(p.image_names, p.image_camera))
        ]
        meta = {"convention": eo.convention, "angle_unit": "radians", "cameras": cameras, "images": images}
        if p.crs is not None:
            meta["crs"] = p.crs
        (tmp / "block.json").write_text(json.dumps(meta, indent=1) + "\n")
        g = lambda v: "" if np.isnan(v) else repr(float(v))  # noqa: E731 - repr: 17 digits, exact round trip
        rows = ["name,X,Y,Z,role,sigma"] + [
            ",".join([_csv_name(n), *map(g, xyz), r, repr(float(s))])
            for n, xyz, r, s in zip(p.point_names, p.points, p.roles, p.point_sigma[:, 0])
        ]
        (tmp / "points.csv").write_text("\n".join(rows) + "\n")
        px, spx = _image_to_pixels(np.asarray(p.obs_xy), p.obs_sigma[:, 0], p.cameras, p.image_camera[p.obs_image])
        rows = ["image,point,col,row,sigma_px"] + [
            f"{_csv_name(p.image_names[i])},{_csv_name(p.point_names[k])},{c!r},{r!r},{s!r}"
            for i, k, (c, r), s in zip(p.obs_image.tolist(), p.obs_point.tolist(), px.tolist(), spx.tolist())
        ]
        (tmp / "observations.csv").write_text("\n".join(rows) + "\n")
    return folder


def check_block_output(folder, inputs=()) -> pathlib.Path:
    """Refuse a block output that exists and is not an empty folder, or that
    would overwrite an input; return it as a Path (call it before the work)."""
    from .atomic import check_output_path

    folder = pathlib.Path(folder)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise ValueError(f"refusing to write the block {folder}: it exists and is not an empty folder")
    check_output_path(folder / "block.json", inputs)
    return folder


def _csv_name(name: str) -> str:
    """A name as one CSV field (quoted when it holds a comma or a quote)."""
    name = str(name)
    return '"' + name.replace('"', '""') + '"' if any(c in name for c in ',"\n') else name


def _image_to_pixels(xy: np.ndarray, sig: np.ndarray, cams, cam_of_obs: np.ndarray):
    """The inverse of :func:`_pixels_to_image`: pixels and pixel sigmas."""
    px = np.empty_like(xy)
    ps = np.empty(len(xy))
    for j, cam in enumerate(cams):
        sel = cam_of_obs == j
        size = np.asarray(cam.pixel_size, dtype=float)
        if type(cam) is not FrameCamera:
            px[sel] = np.asarray(cam.image_to_pixel(xy[sel]))
        else:
            centre = (np.asarray(cam.image_size, dtype=float) - 1) / 2
            px[sel] = xy[sel] * [1.0, -1.0] / size + centre
        ps[sel] = sig[sel] / float(np.mean(size))
    return px, ps
