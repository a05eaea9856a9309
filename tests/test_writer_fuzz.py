"""Every writer of photax.io, property-style: random valid inputs (seeded numpy) written and read
back equal what was written (to the tolerance of the format), and a value that is not finite is
refused with a ValueError naming it, never written as 'nan' (issue 22, item 4).

One helper (``_round_trip``) runs each format; the references are the inputs themselves: the
cameras' projections of fixed points (pixels), the orientations' positions and rotation matrices,
the GCP tables' coordinates.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib

import numpy as np
import pyproj
import pytest

import photax as ptx
from photax.io import colmap as C
from photax.io.gcp import GCPTable, read_gcps, write_gcps
from photax.io.metashape import (
    read_metashape_calibration,
    read_opk_export,
    write_metashape_calibration,
    write_opk_export,
)
from photax.io.odm import read_odm_cameras, read_odm_geo, write_odm_cameras, write_odm_geo
from photax.io.opensfm import read_opensfm_cameras, read_opensfm_shots, write_opensfm_reconstruction
from photax.io.orthority import (
    read_orthority_exterior_crs,
    read_orthority_geojson,
    read_orthority_interior,
    write_orthority_exterior,
    write_orthority_geojson,
    write_orthority_interior,
    write_orthority_rpc,
)
from photax.io.pix4d import read_pix4d_cam, write_pix4d_cam

CASES = 12  # random inputs per format (small: every case writes and reads a file)
CRS = "EPSG:32633"
POINTS = np.column_stack([np.random.default_rng(99).uniform(-0.5, 0.5, (30, 2)), -np.ones(30)]) * 20.0


def _round_trip(tmp_path, name, make, write, read, check, cases=CASES):
    """``cases`` random valid inputs ``make(rng)``: ``check(input, read(write(input, path)))``."""
    rng = np.random.default_rng(sum(map(ord, name)))  # fixed per format
    for k in range(cases):
        obj = make(rng)
        path = write(obj, tmp_path / f"{name}_{k}")
        try:
            check(obj, read(path))
        except AssertionError as exc:
            raise AssertionError(f"{name}, case {k}: {exc}") from None


def _refuses_non_finite(tmp_path, name, make, write, poisons):
    """Each ``poison(obj, value)`` of a valid input, for NaN and +-inf, is a ValueError and no file."""
    obj = make(np.random.default_rng(1))
    for k, poison in enumerate(poisons):
        for value in (math.nan, math.inf, -math.inf):
            path = tmp_path / f"{name}_bad_{k}"
            try:
                bad = poison(obj, value)
            except ValueError:
                continue  # the object itself refuses it (e.g. a camera's focal length)
            with pytest.raises(ValueError, match=r"(?i)finite|nan|inf"):
                write(bad, path)
            assert not path.exists() or not any(path.iterdir() if path.is_dir() else [path])


# --- random valid inputs ----------------------------------------------------------------------


def _camera(rng, square=True, pixels=False):
    w, h = int(rng.integers(200, 6000)), int(rng.integers(150, 4500))
    ps = 1.0 if pixels else rng.uniform(0.001, 0.01)
    size = (ps, ps) if square else (ps, ps * rng.uniform(0.98, 1.02))
    f = rng.uniform(0.6, 1.6) * w * ps
    pp = rng.uniform(-0.03, 0.03, 2) * np.array([w * ps, h * ps])
    dist = rng.uniform(-1, 1, 5) * [0.1, 0.02, 0.005, 0.001, 0.001]
    return ptx.FrameCamera(f, pp, dist, pixel_size=size, image_size=(w, h))


def _pixels(cam):
    return np.asarray(cam.image_to_pixel(cam.project(POINTS)))


def _same_projection(a, b, atol=1e-9):
    assert a.image_size == b.image_size, (a.image_size, b.image_size)
    np.testing.assert_allclose(_pixels(b), _pixels(a), rtol=0, atol=atol)


def _exteriors(rng, n=None):
    n = n or int(rng.integers(1, 6))
    conv = ["omega-phi-kappa", "phi-omega-kappa"][int(rng.integers(2))]
    return {
        f"IMG_{k:04d}.JPG": ptx.ExteriorOrientation(
            [rng.uniform(4.5e5, 5.5e5), rng.uniform(4.0e6, 4.1e6), rng.uniform(50, 900)],
            rng.uniform(-0.3, 0.3, 3) + [0, 0, rng.uniform(-np.pi, np.pi)],
            conv,
        )
        for k in range(n)
    }


def _same_orientations(a, b, pos_atol=0.0, rot_atol=1e-12):
    stems = {pathlib.PurePath(k).stem: v for k, v in a.items()}
    assert set(b) == set(stems), (sorted(b), sorted(stems))
    for k, eo in stems.items():
        np.testing.assert_allclose(np.asarray(b[k].position), np.asarray(eo.position), rtol=0, atol=pos_atol)
        np.testing.assert_allclose(np.asarray(b[k].rotation), np.asarray(eo.rotation), rtol=0, atol=rot_atol)


def _gcps(rng, three_d=True, check_roles=True):
    n = int(rng.integers(1, 8))
    ground = np.column_stack([rng.uniform(4.9e5, 5.1e5, n), rng.uniform(4.0e6, 4.01e6, n), rng.uniform(0, 500, n)])
    if not three_d:
        ground[:, 2] = np.nan
    roles = rng.choice(["control", "check"], n) if check_roles else np.array(["control"] * n)
    return GCPTable(
        names=np.array([f"P{k}" for k in range(n)]),
        images=np.array(["IMG_1.tif"] * n),
        ground=ground,
        pixel=rng.uniform(0, 3000, (n, 2)),
        image_xy=None,
        sigma=np.full(n, np.nan),
        role=roles,
        crs=CRS,
    )


# --- the formats ------------------------------------------------------------------------------


def test_camera_writers_round_trip(tmp_path):
    def metashape_check(cam, back):
        _same_projection(cam, next(iter(back.values())))

    _round_trip(
        tmp_path, "metashape", lambda r: _camera(r, square=False),
        lambda c, p: write_metashape_calibration(c, p.with_suffix(".xml")), read_metashape_calibration, metashape_check,
    )  # fmt: skip
    _round_trip(
        tmp_path, "pix4d", _camera,
        lambda c, p: (write_pix4d_cam(c, p.with_suffix(".cam")), c.image_size),
        lambda pc: read_pix4d_cam(*pc), _same_projection,
    )  # fmt: skip
    _round_trip(
        tmp_path, "orthority", lambda r: _camera(r, square=False),
        lambda c, p: write_orthority_interior(p.with_suffix(".yaml"), {"cam": c}), read_orthority_interior,
        lambda c, back: _same_projection(c, back["cam"]),
    )  # fmt: skip
    _round_trip(
        tmp_path, "odm_cameras", _camera,
        lambda c, p: write_odm_cameras(p.with_suffix(".json"), {"c": c}), read_odm_cameras,
        lambda c, back: _same_projection(c, back["c"]),
    )  # fmt: skip


def test_orientation_writers_round_trip(tmp_path):
    for fmt in ("metashape", "pix4d"):
        _round_trip(
            tmp_path, f"opk_{fmt}", _exteriors,
            lambda t, p, fmt=fmt: write_opk_export(t, p.with_suffix(".txt"), format=fmt), read_opk_export,
            _same_orientations,
        )  # fmt: skip
    _round_trip(
        tmp_path, "orthority_csv", _exteriors,
        lambda t, p: write_orthority_exterior(p.with_suffix(".csv"), t, CRS), read_orthority_exterior_crs,
        lambda t, back: (_same_orientations(t, back[0]), pyproj.CRS(back[1]) == pyproj.CRS(CRS)) and None,
    )  # fmt: skip
    _round_trip(
        tmp_path, "orthority_geojson", _exteriors,
        lambda t, p: write_orthority_geojson(p.with_suffix(".geojson"), t, CRS), read_orthority_geojson,
        lambda t, back: _same_orientations(t, back[0]),
    )  # fmt: skip


def test_reconstruction_writer_round_trips(tmp_path):
    def make(rng):
        return _camera(rng), _exteriors(rng), ["topocentric", "grid"][int(rng.integers(2))]

    def write(obj, p):
        cam, table, frame = obj
        return write_opensfm_reconstruction(p.with_suffix(".json"), cam, table, CRS, frame=frame)

    def check(obj, path):
        cam, table, frame = obj
        _same_projection(cam, next(iter(read_opensfm_cameras(path).values())))
        # several shots: the frame is told by their gps_position; one: it must be named (both fit it)
        shots, crs, _ = read_opensfm_shots(path, CRS, None if len(table) > 1 else frame)
        _same_orientations(table, shots, pos_atol=1e-6, rot_atol=1e-9)  # through geodetic frames
        if len(table) == 1:
            with pytest.raises(ValueError, match="do not tell OpenSfM.s topocentric frame.*name the frame"):
                read_opensfm_shots(path, CRS)

    _round_trip(tmp_path, "opensfm", make, write, lambda p: p, check, cases=6)


def test_geo_txt_writer_round_trips(tmp_path):
    def make(rng):
        n = int(rng.integers(1, 6))
        xyz = np.column_stack([rng.uniform(4.5e5, 5.5e5, n), rng.uniform(4.0e6, 4.1e6, n), rng.uniform(0, 900, n)])
        xyz[rng.random(n) < 0.3, 2] = np.nan  # 2-D positions
        return {f"IMG_{k}.JPG": v for k, v in enumerate(xyz)}

    def check(pos, back):
        table, crs, _ = back
        assert crs == CRS
        for k, v in pos.items():
            np.testing.assert_array_equal(table[k.split(".")[0]], v)

    _round_trip(tmp_path, "geo", make, lambda t, p: write_odm_geo(p.with_suffix(".txt"), t, CRS), read_odm_geo, check)


def test_rpc_writer_round_trips(tmp_path):
    """orthority's rpc_param.yaml: every coefficient, offset and scale read back exactly (repr floats)."""

    def make(rng):
        coef = rng.normal(0, 1, (4, 20)) * np.logspace(0, -6, 20)
        coef[[1, 3], 0] = 1.0  # the denominators' constant term
        offsets = [rng.uniform(-180, 180), rng.uniform(-80, 80), rng.uniform(0, 2000), 3000.0, 4000.0]
        scales = [rng.uniform(0.01, 0.2), rng.uniform(0.01, 0.2), rng.uniform(200, 900), 3000.0, 4000.0]
        size = (int(rng.integers(100, 30000)), int(rng.integers(100, 30000)))
        return {f"scene_{k}.tif": ptx.RPCCamera(coef * (k + 1), offsets, scales, image_size=size) for k in range(2)}

    def check(cams, path):
        for name, cam in cams.items():
            back = ptx.read_rpc(path, image=name)
            for field in ("coefficients", "offsets", "scales"):
                np.testing.assert_array_equal(np.asarray(getattr(back, field)), np.asarray(getattr(cam, field)))
            assert back.image_size == cam.image_size

    def write(cams, p):
        return write_orthority_rpc(p.with_suffix(".yaml"), cams)

    _round_trip(tmp_path, "rpc", make, write, lambda p: p, check)


def test_gcp_writers_round_trip(tmp_path):
    def check_csv(t, back):
        assert back.names.tolist() == t.names.tolist() and back.role.tolist() == t.role.tolist()
        np.testing.assert_array_equal(back.ground, t.ground)
        np.testing.assert_array_equal(back.pixel, t.pixel)

    def check_qgis(t, back):  # 2-D, checks disabled -> check points
        np.testing.assert_array_equal(back.ground[:, :2], t.ground[:, :2])
        np.testing.assert_allclose(back.pixel, t.pixel, rtol=0, atol=1e-9)
        assert back.role.tolist() == t.role.tolist()

    def check_geojson(t, back):  # through WGS84 longitude, latitude
        np.testing.assert_allclose(back.ground, t.ground, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(back.pixel, t.pixel)

    for suffix, check in ((".csv", check_csv), (".points", check_qgis), (".geojson", check_geojson)):
        _round_trip(
            tmp_path, f"gcp{suffix}", _gcps, lambda t, p, s=suffix: write_gcps(p.with_suffix(s), t),
            lambda p: read_gcps(p, crs=CRS), check,
        )  # fmt: skip


def _colmap_model(rng):
    n_points, n_images = int(rng.integers(1, 6)), int(rng.integers(1, 4))
    cam = _camera(rng, pixels=True)
    k1, k2, _, p1, p2 = np.asarray(cam.distortion)
    (w, h), f = cam.image_size, float(cam.focal_length)
    cx, cy = np.asarray(cam.principal_point) * [1, -1] + [w / 2, h / 2]
    cameras = {1: C.ColmapCamera("OPENCV", w, h, np.array([f, f, cx, cy, k1, k2, -p1, p2]))}
    images, tracks = {}, {p: ([], []) for p in range(1, n_points + 1)}
    for i in range(1, n_images + 1):
        q = rng.normal(size=4)
        q = q / np.linalg.norm(q) * np.sign(q[0])
        ids = np.arange(1, n_points + 1, dtype=np.int64)
        for j, p in enumerate(ids):
            tracks[int(p)][0].append(i)
            tracks[int(p)][1].append(j)
        images[i] = C.ColmapImage(
            q, rng.normal(size=3) * 10, 1, f"im_{i}.jpg", rng.uniform(0, 1000, (n_points, 2)), ids
        )
    points = {
        p: C.ColmapPoint(rng.normal(size=3) * 50, rng.integers(0, 256, 3), float(rng.uniform(0, 2)),
                         np.array(t[0], dtype=np.int64), np.array(t[1], dtype=np.int64))
        for p, t in tracks.items()
    }  # fmt: skip
    return C.ColmapModel(cameras, images, points)


def _same_colmap(a, b):
    assert a.cameras.keys() == b.cameras.keys() and a.images.keys() == b.images.keys()
    for k, c in a.cameras.items():
        assert (c.model, c.width, c.height) == (b.cameras[k].model, b.cameras[k].width, b.cameras[k].height)
        np.testing.assert_array_equal(b.cameras[k].params, c.params)
    for k, im in a.images.items():
        np.testing.assert_allclose(b.images[k].qvec, im.qvec, rtol=0, atol=1e-15)  # read back normalised
        for f in ("tvec", "xy", "point3d_ids"):
            np.testing.assert_array_equal(getattr(b.images[k], f), getattr(im, f))
    for k, p in a.points.items():
        for f in ("xyz", "rgb", "image_ids", "point2d_idx"):
            np.testing.assert_array_equal(getattr(b.points[k], f), getattr(p, f))


def test_colmap_writer_round_trips(tmp_path):
    for binary in (False, True):
        _round_trip(
            tmp_path, f"colmap_{binary}", _colmap_model,
            lambda m, p, b=binary: C.write_colmap_model(m, p, binary=b), C.read_colmap_model, _same_colmap, cases=6,
        )  # fmt: skip


# --- non-finite values are refused ------------------------------------------------------------


def _with_camera(cam, **change):
    return ptx.FrameCamera(
        change.get("f", cam.focal_length), change.get("pp", cam.principal_point), change.get("d", cam.distortion),
        pixel_size=cam.pixel_size, image_size=cam.image_size,
    )  # fmt: skip


CAMERA_POISONS = [
    lambda c, v: _with_camera(c, pp=[v, 0.0]),
    lambda c, v: _with_camera(c, d=[0.01, v, 0.0, 0.0, 0.0]),
    lambda c, v: _with_camera(c, d=[0.01, 0.0, 0.0, 0.0, v]),
]


def _poison_eo(table, v, where):
    name, eo = next(iter(table.items()))
    pos, ang = np.array(eo.position, dtype=float), np.array(eo.angles, dtype=float)
    (pos if where == "pos" else ang)[1] = v
    return {**table, name: ptx.ExteriorOrientation(pos, ang, eo.convention)}


EXTERIOR_POISONS = [lambda t, v: _poison_eo(t, v, "pos"), lambda t, v: _poison_eo(t, v, "ang")]


def test_camera_writers_refuse_non_finite(tmp_path):
    writers = {
        "metashape": lambda c, p: write_metashape_calibration(c, p),
        "pix4d": lambda c, p: write_pix4d_cam(c, p),
        "orthority": lambda c, p: write_orthority_interior(p, {"cam": c}),
        "odm_cameras": lambda c, p: write_odm_cameras(p, {"c": c}),
        "opensfm": lambda c, p: write_opensfm_reconstruction(p, c, _exteriors(np.random.default_rng(2)), CRS),
    }
    for name, write in writers.items():
        _refuses_non_finite(tmp_path, name, _camera, write, CAMERA_POISONS)


def test_orientation_writers_refuse_non_finite(tmp_path):
    cam = _camera(np.random.default_rng(3))
    writers = {
        "opk_metashape": lambda t, p: write_opk_export(t, p, format="metashape"),
        "opk_pix4d": lambda t, p: write_opk_export(t, p, format="pix4d"),
        "orthority_csv": lambda t, p: write_orthority_exterior(p, t, CRS),
        "orthority_geojson": lambda t, p: write_orthority_geojson(p, t, CRS),
        "opensfm": lambda t, p: write_opensfm_reconstruction(p, cam, t, CRS),
        "geo": lambda t, p: write_odm_geo(p, {k: np.asarray(e.position) for k, e in t.items()}, CRS),
    }
    for name, write in writers.items():
        poisons = EXTERIOR_POISONS[:1] if name == "geo" else EXTERIOR_POISONS
        _refuses_non_finite(tmp_path, name, _exteriors, write, poisons)


def test_gcp_and_colmap_writers_refuse_non_finite(tmp_path):
    def poison_gcp(field, j):
        def poison(t, v):
            arr = np.array(getattr(t, field), dtype=float)
            arr[0, j] = v
            return dataclasses.replace(t, **{field: arr})

        return poison

    gcp_poisons = [poison_gcp("ground", 0), poison_gcp("ground", 2), poison_gcp("pixel", 1)]
    for suffix in (".csv", ".points", ".geojson"):
        poisons = gcp_poisons[::2] if suffix == ".points" else gcp_poisons  # .points holds no height
        _refuses_non_finite(tmp_path, f"gcp{suffix}", _gcps, lambda t, p, s=suffix: write_gcps(p.with_suffix(s), t),
                            poisons)  # fmt: skip

    def poison_colmap(part):
        def poison(m, v):
            if part == "camera":
                c = m.cameras[1]
                params = c.params.copy()
                params[4] = v
                return dataclasses.replace(m, cameras={1: dataclasses.replace(c, params=params)})
            if part == "image":
                im = m.images[1]
                tvec = im.tvec.copy()
                tvec[0] = v
                return dataclasses.replace(m, images={**m.images, 1: dataclasses.replace(im, tvec=tvec)})
            p = next(iter(m.points))
            xyz = m.points[p].xyz.copy()
            xyz[2] = v
            return dataclasses.replace(m, points={**m.points, p: dataclasses.replace(m.points[p], xyz=xyz)})

        return poison

    for binary in (False, True):
        _refuses_non_finite(
            tmp_path, f"colmap_{binary}", _colmap_model, lambda m, p, b=binary: C.write_colmap_model(m, p, binary=b),
            [poison_colmap("camera"), poison_colmap("image"), poison_colmap("point")],
        )  # fmt: skip


def test_reconstruction_frame_told_by_noisy_gnss_or_refused(tmp_path):
    """A grid-frame reconstruction whose gps_position carry GNSS noise (sigma 0.5 m): over a wide
    block (3 km: the frames up to ~6 m apart) the reader still finds the grid frame (headings to
    1e-9); over a compact one (20 m: frames centimetres apart, within the noise) it asks for the
    frame, whose headings differ by the meridian convergence, instead of guessing."""
    import json

    rng = np.random.default_rng(7)
    cam = _camera(rng)
    for extent, decided in ((3000.0, True), (20.0, False)):
        table = {
            f"IMG_{k}.JPG": ptx.ExteriorOrientation(
                [5.3e5 + rng.uniform(0, extent), 4.05e6 + rng.uniform(0, extent), 120.0],
                rng.uniform(-0.1, 0.1, 3),
                "omega-phi-kappa",
            )
            for k in range(12)
        }
        path = write_opensfm_reconstruction(tmp_path / f"r{extent}.json", cam, table, CRS, frame="grid")
        data = json.loads(path.read_text())
        for shot in data[0]["shots"].values():
            shot["gps_position"] = (np.asarray(shot["gps_position"]) + rng.normal(0, 0.5, 3)).tolist()
        path.write_text(json.dumps(data))
        if decided:
            _same_orientations(table, read_opensfm_shots(path, CRS)[0], pos_atol=1e-6, rot_atol=1e-9)
        else:
            with pytest.raises(ValueError, match=r"do not tell .* headings by 0\.\d+ degrees here: name the frame"):
                read_opensfm_shots(path, CRS)
            _same_orientations(table, read_opensfm_shots(path, CRS, "grid")[0], pos_atol=1e-6, rot_atol=1e-9)
            # from the command line: --exterior grid:FILE (checked as FILE, read in that frame)
            from photax.cli._common import input_file
            from photax.io.orientation import read_exteriors

            assert input_file(f"grid:{path}", "exterior file") == path
            _same_orientations(table, read_exteriors(f"grid:{path}", crs=CRS)[0], pos_atol=1e-6, rot_atol=1e-9)
            with pytest.raises(ValueError, match="names the frame of a reconstruction.json"):
                write_orthority_exterior(tmp_path / "x.csv", table, CRS)
                read_exteriors(f"grid:{tmp_path / 'x.csv'}")
