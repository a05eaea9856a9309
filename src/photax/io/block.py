"""The block folder format of ``photax bundle --format block``.

A folder with ``block.json`` (cameras, images, angle convention),
``observations.csv`` (pixel measurements) and ``points.csv`` (tie, control
and check points).  See :func:`read_block` for the exact layout and
``data/block/`` for a sample.
"""

from __future__ import annotations

import csv
import json
import pathlib

import numpy as np

from ..bundle import INTRINSICS, ROLES, BundleProblem
from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from ..rotation import check_convention


def read_block(folder) -> BundleProblem:
    """Read a block folder: ``block.json``, ``observations.csv``, ``points.csv``.

    ``block.json``::

        {"convention": "omega-phi-kappa",          # or "phi-omega-kappa"
         "angle_unit": "degrees",                  # or "radians"
         "cameras": {"cam": {"focal_length_px": 3000, "image_size": [4000, 3000],
                             "principal_point_px": [1999.5, 1499.5],   # optional
                             "distortion": [0, 0, 0, 0, 0],           # optional, k1 k2 k3 p1 p2
                             "free": ["f", "k1"]}},                   # optional, self-calibration
         "images": [{"name": "IMG_1", "camera": "cam",
                     "position": [X, Y, Z], "angles": [a1, a2, a3],   # or null: resected
                     "fixed": false}]}

    ``observations.csv``: header ``image,point,col,row[,sigma_px]``, pixel
    coordinates (column right, row down, origin at the centre of the
    top-left pixel).  ``points.csv``: header ``name,X,Y,Z,role[,sigma]``
    with role ``tie``/``control``/``check``; X Y Z may be empty for tie
    points; ``sigma`` (ground unit) of control points, 0 = fixed.

    Raises:
        ValueError: naming the file and line of a malformed entry.
    """
    folder = pathlib.Path(folder)
    meta_path = folder / "block.json"
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{meta_path}:{exc.lineno}: invalid JSON: {exc.msg}") from None
    conv = check_convention(meta.get("convention", "omega-phi-kappa"))
    unit = meta.get("angle_unit", "degrees")
    if unit not in ("degrees", "radians"):
        raise ValueError(f"{meta_path}: angle_unit must be 'degrees' or 'radians', got {unit!r}")
    cam_names = list(meta.get("cameras", {}))
    if not cam_names or not meta.get("images"):
        raise ValueError(f"{meta_path}: needs non-empty 'cameras' and 'images'")
    cams, free = [], np.zeros((len(cam_names), 8), dtype=bool)
    for j, name in enumerate(cam_names):
        c = meta["cameras"][name]
        try:
            cams.append(FrameCamera.from_pixels(float(c["focal_length_px"]), tuple(c["image_size"]),
                                                c.get("principal_point_px"), c.get("distortion")))  # fmt: skip
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{meta_path}: camera {name!r}: needs focal_length_px and image_size ({exc})") from None
        bad = set(c.get("free", [])) - set(INTRINSICS)
        if bad:
            raise ValueError(f"{meta_path}: camera {name!r}: unknown free parameters {sorted(bad)}; use {INTRINSICS}")
        free[j, [INTRINSICS.index(n) for n in c.get("free", [])]] = True
    names, img_cam, pos, ang, fixed = [], [], [], [], []
    for i, im in enumerate(meta["images"]):
        if im.get("camera") not in cam_names:
            raise ValueError(f"{meta_path}: images[{i}]: camera {im.get('camera')!r} is not in 'cameras'")
        names.append(str(im.get("name", f"image {i}")))
        img_cam.append(cam_names.index(im["camera"]))
        pos.append(im.get("position") or [np.nan] * 3)
        a = np.asarray(im.get("angles") or [np.nan] * 3, dtype=float)
        ang.append(np.radians(a) if unit == "degrees" else a)
        fixed.append(bool(im.get("fixed", False)))

    def rows(path, required):
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            missing = set(required) - set(reader.fieldnames or [])
            if missing:
                raise ValueError(f"{path}:1: missing columns {sorted(missing)}")
            for line, row in enumerate(reader, start=2):
                yield line, {k: (v or "").strip() for k, v in row.items()}

    def num(path, line, row, key, default=None):
        text = row.get(key, "")
        if text == "" and default is not None:
            return default
        try:
            return float(text)
        except ValueError:
            raise ValueError(f"{path}:{line}: {key} = {text!r} is not a number") from None

    pnames, xyz, roles, psig = [], [], [], []
    ppath = folder / "points.csv"
    for line, row in rows(ppath, ("name", "X", "Y", "Z", "role")):
        if row["role"] not in ROLES:
            raise ValueError(f"{ppath}:{line}: role must be one of {ROLES}, got {row['role']!r}")
        pnames.append(row["name"])
        xyz.append([num(ppath, line, row, k, np.nan) for k in "XYZ"])
        roles.append(row["role"])
        psig.append(num(ppath, line, row, "sigma", 0.0))
    if len(set(pnames)) != len(pnames):
        raise ValueError(f"{ppath}: duplicate point names")
    pidx = {n: i for i, n in enumerate(pnames)}
    iidx = {n: i for i, n in enumerate(names)}
    oi, op, px, osig = [], [], [], []
    opath = folder / "observations.csv"
    for line, row in rows(opath, ("image", "point", "col", "row")):
        if row["image"] not in iidx or row["point"] not in pidx:
            raise ValueError(f"{opath}:{line}: unknown image {row['image']!r} or point {row['point']!r}")
        oi.append(iidx[row["image"]])
        op.append(pidx[row["point"]])
        px.append([num(opath, line, row, "col"), num(opath, line, row, "row")])
        osig.append(num(opath, line, row, "sigma_px", 1.0))
    oi, op, px, osig = np.array(oi), np.array(op), np.array(px, dtype=float).reshape(-1, 2), np.array(osig)
    cam_of_obs = np.array(img_cam)[oi]
    xy = np.empty_like(px)
    ps = np.empty(len(oi))
    for j, cam in enumerate(cams):
        sel = cam_of_obs == j
        xy[sel] = np.asarray(cam.pixel_to_image(px[sel]))
        ps[sel] = osig[sel] * float(np.mean(np.asarray(cam.pixel_size)))
    return BundleProblem(
        cams, ExteriorOrientation(np.array(pos, dtype=float), np.array(ang, dtype=float), conv), np.array(xyz, dtype=float),
        oi, op, xy, obs_sigma=ps, image_camera=np.array(img_cam), roles=roles, point_sigma=np.array(psig),
        free_intrinsics=free, fixed_exterior=np.array(fixed), image_names=names, point_names=pnames,
    )  # fmt: skip
