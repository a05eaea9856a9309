"""Fuzzing every file reader with hypothesis.

Contract (docs/architecture.md): a reader either returns a sane result or
raises ``ValueError`` naming the file (and the line, for line-oriented
formats).  Nothing else escapes: no KeyError, TypeError, IndexError, YAML or
JSON errors, UnicodeDecodeError, numpy errors, OverflowError.

Inputs are random bytes, truncations of valid files and valid files with a
few mutations: a field replaced by a hostile value (``nan``, ``-1``, ``0``,
``1e999``, a huge integer, a YAML tag, ...), bytes inserted or deleted,
lines duplicated or dropped.  The seeds are the repository's own valid files
(``data/``) and small files written here, so the tests need nothing outside
the repository.  The checks on a returned result are independent of the
readers: finite numbers, positive focal lengths, pixel sizes and image
sizes, unique names where names must be unique.

Fixed seed (``derandomize=True``), 300 examples per reader (the block
folder: 100 per file; ``read_bal`` building the JAX problem: 40 more;
the raster readers, whose examples are dearer: 150).
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import re
import shutil
import warnings

import numpy as np
import pytest
from conftest import SHARED_DATA, fuzz_budget
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from photax.io.bal import BALData, read_bal, read_bal_arrays, write_bal_arrays
from photax.io.block import read_block
from photax.io.camera_file import read_camera
from photax.io.gcp import read_gcps
from photax.io.opensfm import read_opensfm_cameras, read_opensfm_shots
from photax.io.orthority import (
    read_orthority_exterior,
    read_orthority_exterior_crs,
    read_orthority_geojson,
    read_orthority_interior,
)
from photax.io.results import read_json

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT / "data"

# The seed and the budget come from the hypothesis profile (tests/conftest.py, docs/testing.md):
# "ci" (the default) a fixed seed and these counts, "deep" a random seed and 10 times as many.
FUZZ = settings(
    max_examples=fuzz_budget(300),
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

# Values that broke or could break a parser, as whole fields.
HOSTILE = [
    b"",
    b"0",
    b"-0",
    b"-1",
    b"-1e-9",
    b"1e999",
    b"-1e999",
    b"nan",
    b"NaN",
    b"inf",
    b"-inf",
    b"Infinity",
    b"1e-400",
    b"9" * 400,
    b"99999999999999999999",
    b"0x10",
    b"1_000",
    b"1.5",
    b"2.5e3",
    b"true",
    b"null",
    b"~",
    b"[]",
    b"{}",
    b"[1, 2]",
    b"[1, 2, 3]",
    b"[0, 0]",
    b"[-1, 5]",
    b"[1.5, 2]",
    b'"x"',
    b"'",
    b'"',
    b"!!python/object:os.system",
    b"!!binary AAAA",
    b"&a",
    b"*a",
    b"2024-01-01",
    b"a,b",
    b"a;b",
    b"#",
    b"control",
    b"check",
    b"tie",
    b"pinhole",
    b"brown",
    b"\xff\xfe",
    b"\x00",
    b"\xc3\xa9",
    b"\xe2\x80\xa8",
    b"\t",
    b" ",
    b"\n",
    b"\r\n",
    b"\r",
    b"---",
    b"...",
    b"- ",
    b": ",
    b"P01",
    b"IMG_0001",
    b"cam",
    b"S1_1",
]
SEPARATORS = [b",", b";", b"\t", b" ", b"\n", b":", b"-", b"[", b"]", b"{", b"}", b'"', b"#", b"\xff"]
FIELD = re.compile(rb"[^\s,;:\[\]{}\"']+")


@st.composite
def mutated(draw, seeds: list[bytes]) -> bytes:
    """A seed file, truncated, mutated field by field or byte by byte, or random bytes."""
    kind = draw(st.sampled_from(["fields", "fields", "fields", "bytes", "lines", "truncate", "random"]))
    if kind == "random":
        return draw(st.one_of(st.binary(max_size=300), st.text(max_size=300).map(str.encode)))
    data = draw(st.sampled_from(seeds))
    if kind == "truncate":
        return data[: draw(st.integers(0, len(data)))]
    for _ in range(draw(st.integers(1, 3))):
        if kind == "fields":
            fields = list(FIELD.finditer(data))
            if not fields:
                break
            m = draw(st.sampled_from(fields))
            new = draw(st.one_of(st.sampled_from(HOSTILE), st.sampled_from(HOSTILE).map(lambda h: m.group() + h)))
            data = data[: m.start()] + new + data[m.end() :]
        elif kind == "bytes":
            i = draw(st.integers(0, len(data)))
            j = draw(st.integers(i, min(len(data), i + 8)))
            data = data[:i] + draw(st.sampled_from(SEPARATORS + HOSTILE)) + data[j:]
        else:  # lines: drop, duplicate or swap one
            lines = data.split(b"\n")
            i, j = draw(st.integers(0, len(lines) - 1)), draw(st.integers(0, len(lines) - 1))
            op = draw(st.sampled_from(["drop", "dup", "swap"]))
            if op == "drop":
                del lines[i]
            elif op == "dup":
                lines.insert(j, lines[i])
            else:
                lines[i], lines[j] = lines[j], lines[i]
            data = b"\n".join(lines)
    return data


def _check_message(msg: str, path, n_lines: int | None, whole_file: str | None) -> None:
    """One line naming ``path``; for a line-oriented format (``n_lines`` given)
    also a line number within the file, unless the problem is the whole file's
    (``whole_file``: a regex of such messages)."""
    assert str(path) in msg, f"error does not name the file: {msg!r}"
    assert "\n" not in msg.strip(), f"error is not one line: {msg!r}"
    if n_lines is None:
        return
    m = re.search(r", line (\d+): ", msg)
    if m is None:
        assert whole_file and re.search(whole_file, msg), f"error does not name the line: {msg!r}"
    else:
        assert 1 <= int(m.group(1)) <= n_lines + 1, f"line out of range ({n_lines} lines): {msg!r}"


def _expect_valueerror_or_sane(read, path: pathlib.Path, sane, whole_file: str | None = None, lines=False) -> None:
    """``read(path)`` returns a result ``sane`` accepts, or raises a ValueError
    naming the file (and with ``lines``, the line)."""
    n_lines = path.read_bytes().count(b"\n") + 1 if lines else None
    try:
        result = read(path)
    except ValueError as exc:
        _check_message(str(exc), path, n_lines, whole_file)
        return
    sane(result)


def _finite(*arrays) -> None:
    for a in arrays:
        if a is not None:
            assert np.all(np.isfinite(np.asarray(a, dtype=float))), a


def _sane_camera(cam) -> None:
    assert float(cam.focal_length) > 0
    _finite(cam.focal_length, cam.principal_point, cam.distortion, cam.pixel_size)
    if cam.pixel_size is not None:
        assert np.all(np.asarray(cam.pixel_size) > 0)
    if cam.image_size is not None:
        assert min(cam.image_size) > 0


def _sane_cameras(cams) -> None:
    """A non-empty mapping of sane cameras."""
    assert cams
    for cam in cams.values():
        _sane_camera(cam)


def _sane_orientations(eos) -> None:
    """A non-empty mapping of orientations with finite positions and angles."""
    assert eos
    for eo in eos.values():
        _finite(eo.position, eo.angles)


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def _shared_seed(name: str) -> list[bytes]:
    """A real file of ../shared/data as an extra seed when present (never required)."""
    p = SHARED_DATA / name
    return [p.read_bytes()[:4000]] if p.is_file() else []


# --- GCP files ---------------------------------------------------------------------

GCP_CSV = [
    (DATA / "sample_gcps.csv").read_bytes(),
    b"name,image,X,Y,Z,x,y\nA,i,1,2,3,0.1,0.2\nB,i,4,5,6,-0.1,0.3\n",
]
GCP_ODM = [
    b"EPSG:32633\n500000 4000000 100 10 20 a.jpg P1\n500010 4000010 101 30 40 a.jpg P2\n"
    b"500010 4000010 101 31 41 b.jpg P2 extra\n",
    *_shared_seed("gcp_list_floatxy_raw.txt"),
    b"WGS84\n-48.4 -25.6 890.6 2460.6 233.9 IMG_5349.JPG HV01\n-48.401 -25.601 890.1 1855.8 602.3 IMG_5352.JPG HV02\n",
    b"+proj=longlat +datum=WGS84 +no_defs\n15 40 10 1 2 a.jpg A\n15.001 40.001 12 3 4 a.jpg B\n",
]
GCP_QGIS = [
    b"#CRS: EPSG:32633\nmapX,mapY,sourceX,sourceY,enable,dX,dY,residual\n"
    b"511890.627,4103806.525,81.612,-45.133,1,0,0,0\n512075.985,4103928.086,355.56,-45.455,0,0.1,-0.2,0.3\n",
    b"mapX,mapY,sourceX,sourceY,enable\n15.0,40.0,10.5,-20.5,1\n",
]
GCP_GEOJSON = [
    b'{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"ji": [821.3, 62.3], '
    b'"filename": "a.tif", "id": "p1", "info": "p1"}, "geometry": {"type": "Point", "coordinates": '
    b'[24.419, -33.654, 214.7]}}, {"type": "Feature", '
    b'"properties": {"ji": [-185.1, 11.3], "filename": "a.tif", '
    b'"id": 7}, "geometry": {"type": "Point", "coordinates": [24.347, -33.649, 463.6]}}], '
    b'"crs": {"type": "name", "properties": {"name": "EPSG:4326"}}}\n',
    *_shared_seed("orthority/rpc/gcps.geojson"),
]


def _sane_gcps(t) -> None:
    n = len(t)
    assert n > 0
    assert t.ground.shape == (n, 3)
    _finite(t.ground, t.pixel, t.image_xy)
    assert (t.pixel is None) != (t.image_xy is None)
    assert np.all(np.isnan(t.sigma) | (t.sigma > 0))
    assert set(t.role.tolist()) <= {"control", "check"}
    assert all(isinstance(s, str) and s for s in t.names.tolist())


@FUZZ
@given(data=mutated(GCP_CSV + GCP_ODM))
def test_fuzz_read_gcps(work, data):
    path = work / "gcps.csv"
    path.write_bytes(data)
    _expect_valueerror_or_sane(read_gcps, path, _sane_gcps, r": (empty GCP file|no GCP measurements)$", lines=True)


def _sane_2d_gcps(t) -> None:
    """A QGIS table: heights NaN (2-D points), the rest as any GCP table."""
    assert np.all(np.isnan(t.ground[:, 2]))
    _sane_gcps(dataclasses.replace(t, ground=np.nan_to_num(t.ground, nan=0.0)))


@FUZZ
@given(data=mutated(GCP_QGIS))
def test_fuzz_read_gcps_qgis(work, data):
    path = work / "gcps.points"
    path.write_bytes(data)
    whole = r": (empty GCP file|no GCP measurements)$"
    _expect_valueerror_or_sane(lambda p: read_gcps(p, format="qgis"), path, _sane_2d_gcps, whole, lines=True)


@FUZZ
@given(data=mutated(GCP_GEOJSON))
# Crash found (issue 38): a null crs.properties (AttributeError).
@example(
    data=GCP_GEOJSON[0].replace(
        b'"crs": {"type": "name", "properties": {', b'"crs": {"type": "name", "properties": null, "x": {'
    )
)
def test_fuzz_read_gcps_geojson(work, data):
    path = work / "gcps.geojson"
    path.write_bytes(data)
    _expect_valueerror_or_sane(lambda p: read_gcps(p, format="geojson"), path, _sane_gcps)


# --- camera files ------------------------------------------------------------------

CAMERA = [
    (DATA / "sample_camera.yaml").read_bytes(),
    b"focal_length_px: 2904.0\nimage_size: [4000, 3000]\nprincipal_point_px: [1999.5, 1499.5]\n"
    b"distortion: {k1: -0.05, p1: 0.001, convention: opencv}\n",
    b"focal_length: 0.035\nunit: m\nprincipal_point_px: [10, 20]\npixel_size: [1e-5, 1.1e-5]\n"
    b"image_size: [40, 30]\ndistortion: [0.1, 0, 0, 0, 0]\nname: cam\n",
]
CAMERA_JSON = [
    b'{"focal_length": 8.8, "unit": "mm", "principal_point": [0.01, -0.02], "pixel_size": 0.0044,\n'
    b' "image_size": [4000, 3000], "distortion": {"k1": -0.02, "k2": 0.004}}\n',
]


@FUZZ
@given(data=mutated(CAMERA), suffix=st.sampled_from([".yaml", ".yml"]))
def test_fuzz_read_camera_yaml(work, data, suffix):
    path = work / f"camera{suffix}"
    path.write_bytes(data)
    _expect_valueerror_or_sane(read_camera, path, _sane_camera)


@FUZZ
@given(data=mutated(CAMERA_JSON + CAMERA[:1]))
def test_fuzz_read_camera_json(work, data):
    path = work / "camera.json"
    path.write_bytes(data)
    _expect_valueerror_or_sane(read_camera, path, _sane_camera)


# --- orthority ---------------------------------------------------------------------

ORTHO_INT = [
    b"Integraph DMC:\n    type: pinhole\n    im_size: [640, 1152]\n    focal_len: 120.0\n"
    b"    sensor_size: [92.16, 165.888]\n    cx: 0.0\n    cy: 0.0\n"
    b"other:\n    type: pinhole\n    im_size: [400, 300]\n    focal_len: [0.8, 0.81]\n",
    b"type: pinhole\nim_size: [400, 300]\nfocal_len: 0.8\ncx: -0.01\ncy: 0.02\n",
    *_shared_seed("ngi_int_param.yaml"),
]
ORTHO_EXT = [
    b"filename,x,y,z,omega,phi,kappa\nimg_1.tif,-55094.5,-3727407.0,5258.3,-0.349,0.298,-179.087\n"
    b"img_2,-57710.4,-3727433.9,5256.8,0.27,-0.282,-179.028\n",
    b"img_1 1 2 3 0.1 0.2 0.3\nimg_2 4 5 6 0.1 0.2 0.3\n",
    *_shared_seed("ngi_xyz_opk.csv"),
]


@FUZZ
@given(data=mutated(ORTHO_INT))
# Crashes found (issue 38): a list as the type, named or unnamed (TypeError: unhashable type: 'list').
@example(data=b"type: []\nim_size: [400, 300]\nfocal_len: 0.8\n")
@example(data=b"cam:\n    type: [1, 2]\n    im_size: [400, 300]\n    focal_len: 0.8\n")
@example(data=b"cam:\n    type: {}\n    im_size: [400, 300]\n    focal_len: 0.8\n")
def test_fuzz_read_orthority_interior(work, data):
    path = work / "int_param.yaml"
    path.write_bytes(data)

    _expect_valueerror_or_sane(read_orthority_interior, path, _sane_cameras)


@FUZZ
@given(data=mutated(ORTHO_EXT))
def test_fuzz_read_orthority_exterior(work, data):
    path = work / "xyz_opk.csv"
    path.write_bytes(data)

    _expect_valueerror_or_sane(
        read_orthority_exterior, path, _sane_orientations, r": no exterior orientations$", lines=True
    )


ORTHO_LLA = [
    b"filename latitude longitude altitude roll pitch yaw camera\n"
    b'a.tif 24.68027804 120.9517016 186.57 0.0 30.0 92.9 "cam 1"\n'
    b'b.tif 24.68014678 120.95166508 186.65 0.0 30.0 -175.8 "cam 1"\n',
    *_shared_seed("orthority/io/odm_lla_rpy.csv"),
]


@FUZZ
@given(data=mutated(ORTHO_LLA))
def test_fuzz_read_orthority_lla_rpy(work, data):
    path = work / "lla_rpy.csv"
    path.write_bytes(data)

    def sane(result):
        eos, crs = result
        assert eos
        for eo in eos.values():
            _finite(eo.position, eo.angles)

    whole_file = r": no exterior orientations$|: positions outside|latitude/longitude out of range"
    _expect_valueerror_or_sane(read_orthority_exterior_crs, path, sane, whole_file, lines=True)


ORTHO_GEOJSON = [
    json.dumps(
        {
            "type": "FeatureCollection",
            "world_crs": "EPSG:32735",
            "features": [
                {
                    "type": "Feature",
                    "properties": {
                        "filename": "a.tif",
                        "camera": "c",
                        "xyz": [1.0, 2.0, 3.0],
                        "opk": [0.01, -0.02, 3.1],
                    },
                    "geometry": {"type": "Point", "coordinates": [24.4, -33.6, 3.0]},
                }
            ],
        }
    ).encode(),
    *_shared_seed("orthority/io/ngi_ext_param.geojson"),
]


@FUZZ
@given(data=mutated(ORTHO_GEOJSON))
def test_fuzz_read_orthority_geojson(work, data):
    path = work / "ext.geojson"
    path.write_bytes(data)

    def sane(result):
        eos, crs = result
        assert eos and isinstance(crs, str) and crs.strip()
        for eo in eos.values():
            _finite(eo.position, eo.angles)

    _expect_valueerror_or_sane(read_orthority_geojson, path, sane)


OPENSFM = [  # gps_position: the shots' centres (-R^T t) to a mm, so the frame is told (topocentric)
    json.dumps(
        [
            {
                "cameras": {
                    "v2 cam": {
                        "projection_type": "brown",
                        "width": 100,
                        "height": 80,
                        "focal_x": 0.7,
                        "focal_y": 0.71,
                        "c_x": 0.01,
                        "c_y": -0.02,
                        "k1": -0.1,
                        "k2": 0.01,
                        "k3": 0.0,
                        "p1": 0.001,
                        "p2": 0.0,
                    }
                },
                "shots": {
                    "a.JPG": {
                        "rotation": [2.6, 0.05, -0.01],
                        "translation": [-74.0, -17.7, 222.6],
                        "camera": "v2 cam",
                        "gps_position": [78.338, -126.974, 181.882],
                    },
                    "b.JPG": {
                        "rotation": [1.9, -2.0, 0.55],
                        "translation": [-71.8, 195.5, 100.9],
                        "camera": "v2 cam",
                        "gps_position": [117.125, -73.682, 185.497],
                    },
                },
                "reference_lla": {"latitude": 24.68, "longitude": 120.95, "altitude": 0.0},
            }
        ]
    ).encode(),
    json.dumps(
        [
            {
                "cameras": {
                    "c": {
                        "projection_type": "perspective",
                        "width": 64,
                        "height": 48,
                        "focal": 0.9,
                        "k1": 0.0,
                        "k2": 0.0,
                    }
                },
                "shots": {
                    "x": {
                        "rotation": [3.1, 0.0, 0.0],
                        "translation": [0.0, 0.0, 50.0],
                        "camera": "c",
                        "gps_position": [0.0, -2.079, 49.957],
                    }
                },
                "reference_lla": {"latitude": -33.6, "longitude": 24.4, "altitude": 10.0},
            }
        ]
    ).encode(),
]


@FUZZ
@given(data=mutated(OPENSFM))
# Crash found (issue 38): a list as the projection type (TypeError: unhashable type: 'list').
@example(data=OPENSFM[1].replace(b'"perspective"', b"[]"))
def test_fuzz_read_opensfm(work, data):
    path = work / "reconstruction.json"
    path.write_bytes(data)

    def sane_cameras(cams):
        assert cams
        for cam in cams.values():
            _sane_camera(cam)

    def sane_shots(result):
        eos, crs, names = result
        assert eos and isinstance(crs, str) and set(names) == set(eos)
        for eo in eos.values():
            _finite(eo.position, eo.angles)

    _expect_valueerror_or_sane(read_opensfm_cameras, path, sane_cameras)
    _expect_valueerror_or_sane(read_opensfm_shots, path, sane_shots)


# --- BAL ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bal_seed(tmp_path_factory) -> bytes:
    """A 2-camera, 3-point BAL file written by photax's own writer."""
    rng = np.random.default_rng(7)
    cams = np.c_[rng.normal(0, 0.1, (2, 3)), rng.normal(0, 1, (2, 3)), [500.0, 520.0], [[-0.1, 0.01], [0.02, 0.0]]]
    data = BALData(cams, rng.normal(0, 1, (3, 3)) - [0, 0, 10], np.array([0, 0, 1, 1, 0]), np.array([0, 1, 1, 2, 2]),
                   rng.normal(0, 100, (5, 2)))  # fmt: skip
    return write_bal_arrays(data, tmp_path_factory.mktemp("bal") / "seed.txt").read_bytes()


def _sane_bal(d) -> None:
    _finite(d.cameras, d.points, d.observations)
    assert np.all(d.cameras[:, 6] > 0)
    assert np.all((d.camera_index >= 0) & (d.camera_index < len(d.cameras)))
    assert np.all((d.point_index >= 0) & (d.point_index < len(d.points)))


@FUZZ
@given(data=st.data())
def test_fuzz_read_bal(work, bal_seed, data):
    raw = data.draw(mutated([bal_seed]))
    path = work / "problem.txt"
    path.write_bytes(raw)
    _expect_valueerror_or_sane(read_bal_arrays, path, _sane_bal, r": empty file", lines=True)


def test_fuzz_read_bal_problem(work, bal_seed):
    """``read_bal`` (which builds the JAX problem) on a few mutations: the same contract."""

    @settings(FUZZ, max_examples=fuzz_budget(40))
    @given(raw=mutated([bal_seed]))
    def run(raw):
        path = work / "problem2.txt"
        path.write_bytes(raw)

        def sane(problem):
            _finite(problem.points, problem.obs_xy, problem.exterior.position, problem.exterior.angles)
            assert all(float(c.focal_length) > 0 for c in problem.cameras)

        _expect_valueerror_or_sane(read_bal, path, sane)

    run()


# --- block folder --------------------------------------------------------------------

BLOCK_FILES = ("block.json", "observations.csv", "points.csv")


def _sane_block(problem) -> None:
    assert len(set(problem.point_names)) == problem.n_points
    assert len(set(problem.image_names)) == problem.n_images
    _finite(problem.obs_xy, problem.obs_sigma, problem.point_sigma)
    for cam in problem.cameras:
        _sane_camera(cam)
    pos = np.asarray(problem.exterior.position)
    ang = np.asarray(problem.exterior.angles)
    # Orientations are either given (finite) or left to the solver (all NaN).
    for p, a in zip(pos, ang):
        assert np.all(np.isfinite(p)) or np.all(np.isnan(p)), p
        assert np.all(np.isfinite(a)) or np.all(np.isnan(a)), a
    pts = problem.points
    assert np.all(np.isfinite(pts) | np.isnan(pts))


@pytest.mark.parametrize("name", BLOCK_FILES)
def test_fuzz_read_block(tmp_path_factory, name):
    folder = tmp_path_factory.mktemp("block")
    for f in BLOCK_FILES:
        shutil.copy(DATA / "block" / f, folder / f)
    seed = (DATA / "block" / name).read_bytes()

    # 100 per file: 300 for the reader, as for the others.
    @settings(FUZZ, max_examples=fuzz_budget(100))
    @given(raw=mutated([seed]))
    def run(raw):
        (folder / name).write_bytes(raw)

        def read(_):
            return read_block(folder)

        try:
            problem = read(folder)
        except ValueError as exc:
            msg = str(exc)
            if name == "block.json" or not msg.startswith(str(folder / name)):
                _check_message(msg, folder, None, None)  # JSON: keys, not lines
            else:  # the fuzzed CSV: its line, unless the whole file is empty
                _check_message(msg, folder / name, raw.count(b"\n") + 1, r": no (points|observations)$")
            return
        _sane_block(problem)

    run()


# --- result JSON ---------------------------------------------------------------------

RESULT = [
    json.dumps({"images": {"IMG_1": {"position": [1.0, 2.0, 3.0], "angles_rad": [0.1, 0.2, 0.3],
                                     "convention": "omega-phi-kappa", "converged": True}}}, indent=2).encode(),
    (DATA / "sample_truth.json").read_bytes()[:3000],
]  # fmt: skip


@FUZZ
@given(data=mutated(RESULT))
def test_fuzz_read_json(work, data):
    path = work / "result.json"
    path.write_bytes(data)

    def sane(obj):
        # Strict JSON: no NaN/Infinity constants (photax writes null for them).
        json.dumps(obj, allow_nan=False)

    _expect_valueerror_or_sane(read_json, path, sane)


# --- rasters (GDAL through rasterio) ------------------------------------------------


@pytest.fixture(scope="module")
def tif_seeds(tmp_path_factory) -> list[bytes]:
    from photax.io.raster import write_geotiff

    folder = tmp_path_factory.mktemp("tif")
    z = np.arange(48, dtype=np.float32).reshape(6, 8)
    return [
        write_geotiff(
            folder / f"{c}.tif", z, (1, 0, 500, 0, -1, 1000), crs="EPSG:32633", nodata=-9999, compress=c
        ).read_bytes()
        for c in (None, "deflate")
    ]


def test_fuzz_read_raster(work, tif_seeds):
    """GeoTIFF and DEM readers: random bytes, truncated and corrupted GeoTIFFs."""
    from photax.io.raster import read_dem, read_geotiff, write_geotiff

    # Crash found by the deep profile (issue 38): pixels of 3e231 m, whose area overflowed
    # (RuntimeWarning: overflow encountered in scalar multiply, in DEM).
    huge = write_geotiff(work / "huge.tif", np.zeros((6, 8), np.float32), (-3.1e231, 0, 0, 0, -3.1e231, 0)).read_bytes()

    @settings(FUZZ, max_examples=fuzz_budget(150))
    @given(raw=mutated(tif_seeds), dem=st.booleans())
    @example(raw=huge, dem=True)
    def run(raw, dem):
        path = work / "raster.tif"
        path.write_bytes(raw)

        def sane(result):
            if dem:
                assert np.all(np.isfinite(np.asarray(result.transform)))
                h = np.asarray(result.heights)
                assert np.all(np.isfinite(h) | np.isnan(h))
            else:
                array, profile = result
                assert array.ndim == 3 and array.shape[0] == profile["count"]

        _expect_valueerror_or_sane(read_dem if dem else read_geotiff, path, sane)

    run()


def test_seeds_are_valid(work, bal_seed, tif_seeds):
    """The fuzzing starts from files the readers accept (else it would only
    exercise the error paths)."""
    from photax.io.raster import read_dem

    cases = [(read_gcps, "s.csv", GCP_CSV + GCP_ODM, _sane_gcps),
             (read_gcps, "s.points", GCP_QGIS, _sane_2d_gcps),
             (read_gcps, "s.geojson", GCP_GEOJSON, _sane_gcps), (read_camera, "s.yaml", CAMERA, _sane_camera),
             (read_camera, "s.json", CAMERA_JSON, _sane_camera),
             (read_orthority_interior, "s_int.yaml", ORTHO_INT, lambda c: [_sane_camera(v) for v in c.values()]),
             (read_orthority_exterior, "s_ext.csv", ORTHO_EXT, lambda e: len(e) >= 2 or None),
             (read_orthority_exterior_crs, "s_lla.csv", ORTHO_LLA[:1], lambda e: len(e[0]) == 2 or None),
             (read_orthority_geojson, "s.geojson", ORTHO_GEOJSON[:1], lambda e: len(e[0]) == 1 or None),
             (read_opensfm_cameras, "s_rec.json", OPENSFM, lambda c: [_sane_camera(v) for v in c.values()]),
             (read_opensfm_shots, "s_rec.json", OPENSFM, lambda e: len(e[0]) >= 1 or None),
             (read_bal_arrays, "s.txt", [bal_seed], _sane_bal), (read_json, "s.json", RESULT, lambda o: None),
             (read_dem, "s.tif", tif_seeds, lambda d: None)]  # fmt: skip
    for read, name, seeds, sane in cases:
        for raw in seeds:
            path = work / name
            path.write_bytes(raw)
            sane(read(path))
    _sane_block(read_block(DATA / "block"))


# --- many orientations from one file, point lists ----------------------------------

EXTERIORS_JSON = [
    json.dumps(
        {
            "converged": True,
            "convention": "phi-omega-kappa",
            "crs": "EPSG:32633",
            "images": [
                {"name": "img0", "position": [500000.0, 4000000.0, 300.0], "angles_rad": [0.01, 0.0, 0.1]},
                {"name": "img1", "position": [500100.0, 4000000.0, 300.0], "angles_rad": [0.0, 0.02, 0.1]},
            ],
        }
    ).encode(),
    json.dumps(
        {
            "images": {
                "a.tif": {
                    "status": "solved",
                    "position": [1.0, 2.0, 3.0],
                    "angles_rad": [0.0, 0.0, 0.0],
                    "convention": "omega-phi-kappa",
                }
            }
        }
    ).encode(),
]


@FUZZ
@given(data=mutated(EXTERIORS_JSON))
# Found: a crs of true returned as the CRS (issue 38); a huge integer position (OverflowError, 30c628a).
@example(data=EXTERIORS_JSON[0].replace(b'"crs": "EPSG:32633"', b'"crs": true'))
@example(data=EXTERIORS_JSON[0].replace(b"500000.0", b"9" * 400))
def test_fuzz_read_exteriors(work, data):
    from photax.io import read_exteriors

    path = work / "block.json"
    path.write_bytes(data)

    def sane(result):
        table, crs = result
        assert table and (crs is None or isinstance(crs, str))
        for eo in table.values():
            _finite(eo.position, eo.angles)

    _expect_valueerror_or_sane(read_exteriors, path, sane)


NAMED = [
    b"name,x,y\nF1,-106.0,-106.0\nF2,106.0,106.0\nF3,-106.0,106.0\n",
    b"name,col,row\nF1,10.5,20.25\nF2,3000,4000\n",
]


@FUZZ
@given(data=mutated(NAMED))
# Crash found (30c628a): a carriage return inside a line (csv.Error).
@example(data=b"name,x,y\nF1,-106.0,\r-106.0\nF2,106.0,106.0\n")
def test_fuzz_read_named_points(work, data):
    from photax.io.points import read_named_points

    path = work / "marks.csv"
    path.write_bytes(data)

    def sane(result):
        names, xy = result
        assert len(names) == len(set(names)) == len(xy) and xy.shape[1:] == (2,)
        _finite(xy)

    _expect_valueerror_or_sane(
        lambda p: read_named_points(p, ("x", "y"), "fiducial file"),
        path,
        sane,
        r": (empty fiducial file|no points in the fiducial file|duplicated mark names)$",
        lines=True,
    )


# --- COLMAP sparse models -------------------------------------------------------------

COLMAP_TEXT = {
    "cameras.txt": b"# Camera list\n1 OPENCV 640 480 500 510 320 240 -0.1 0.01 0.001 -0.002\n2 SIMPLE_PINHOLE 64 48 50 32 24\n",
    "images.txt": b"# Image list\n1 1 0 0 0 0 0 5 1 im 0.jpg\n10 20 1 11 20 2 5 5 -1\n"
    b"2 0.99995 0 0 0.01 0.1 0 5 2 b.jpg\n11 21 1 12 21 2\n",
    "points3D.txt": b"# 3D points\n1 0.1 -0.1 0.6 1 2 3 -1 1 0 2 0\n2 0.2 0.3 0.4 255 0 9 0.5 1 1 2 1\n",
}


def _sane_colmap(model) -> None:
    assert model.cameras
    for c in model.cameras.values():
        _finite(c.params)
        assert c.width >= 1 and c.height >= 1
    names = [im.name for im in model.images.values()]
    assert len(set(names)) == len(names) and all(names)
    for im in model.images.values():
        _finite(im.qvec, im.tvec, im.xy)
        assert abs(np.linalg.norm(im.qvec) - 1) < 1e-12 and im.camera_id in model.cameras
    for p in model.points.values():
        _finite(p.xyz, p.error)
        for i, j in zip(p.image_ids.tolist(), p.point2d_idx.tolist()):
            assert model.images[i].point3d_ids[j] >= 0


@pytest.mark.parametrize("name", [*COLMAP_TEXT, "cameras.bin", "images.bin", "points3D.bin"])
def test_fuzz_read_colmap(tmp_path_factory, name):
    """Text files: 100 examples each, errors naming the file and line; binary: 60 each, naming the file."""
    from photax.io.colmap import (
        read_colmap,
        read_colmap_cameras,
        read_colmap_exteriors,
        read_colmap_model,
        write_colmap_model,
    )

    folder = tmp_path_factory.mktemp("colmap")
    for f, raw in COLMAP_TEXT.items():
        (folder / f).write_bytes(raw)
    if name.endswith(".bin"):
        model = read_colmap_model(folder)
        for f in COLMAP_TEXT:
            (folder / f).unlink()
        write_colmap_model(model, folder / "bin", binary=True)
        folder = folder / "bin"
    seed = (folder / name).read_bytes()

    @settings(FUZZ, max_examples=fuzz_budget(60 if name.endswith(".bin") else 100))
    @given(raw=mutated([seed]))
    def run(raw):
        (folder / name).write_bytes(raw)
        try:
            model = read_colmap_model(folder)
        except ValueError as exc:
            msg = str(exc)
            if name.endswith(".bin") or not msg.startswith(str(folder / name)):
                _check_message(msg, folder, None, None)
            else:
                _check_message(msg, folder / name, raw.count(b"\n") + 1, r": no cameras$")
            return
        _sane_colmap(model)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # points seen in one image, left out
                problem = read_colmap(folder)
        except ValueError as exc:
            _check_message(str(exc), folder, None, None)
            return
        _finite(problem.points, problem.obs_xy, problem.exterior.position, problem.exterior.angles)
        # the one-file readers of --camera / --exterior
        ext = ".bin" if name.endswith(".bin") else ".txt"
        try:
            cams, eos = read_colmap_cameras(folder / f"cameras{ext}"), read_colmap_exteriors(folder / f"images{ext}")
        except ValueError as exc:
            _check_message(str(exc), folder, None, None)
            return
        for cam in cams.values():
            _sane_camera(cam)
        for eo in eos.values():
            _finite(eo.position, eo.angles)

    run()


# --- Metashape calibration XML, Metashape / Pix4D omega-phi-kappa exports ---------------

METASHAPE_XML = [
    b'<?xml version="1.0" encoding="UTF-8"?>\n<calibration>\n  <projection>frame</projection>\n  <width>5472</width>\n'
    b"  <height>3648</height>\n  <f>3664.2</f>\n  <cx>-12.7</cx>\n  <cy>21.3</cy>\n  <b1>-1.9</b1>\n  <k1>-0.0123</k1>\n"
    b"  <k2>0.0081</k2>\n  <p1>0.00031</p1>\n  <p2>-0.00054</p2>\n</calibration>\n",
    b'<document><chunk><sensors><sensor id="0" label="cam" type="frame"><calibration type="frame" class="adjusted">'
    b'<resolution width="640" height="480"/><f>500</f><k1>0.01</k1></calibration></sensor></sensors></chunk></document>',
]
OPK_EXPORTS = [
    b"# Cameras (1)\n# PhotoID, X, Y, Z, Omega, Phi, Kappa, r11, r12, r13, r21, r22, r23, r31, r32, r33\n"
    b"a.JPG\t1.0\t2.0\t3.0\t0.000000\t0.000000\t0.000000\t1\t0\t0\t0\t1\t0\t0\t0\t1\n"
    b"b.JPG\t4.0\t5.0\t6.0\t0.0\t0.0\t0.0\n",
    b"imageName X Y Z Omega Phi Kappa\nIMG_1.JPG 12.5 -3.25 101.0 0.5 -1.25 92.0\nIMG_2.JPG 2.5 -3 10 0 0 0\n",
]


@FUZZ
@given(data=mutated(METASHAPE_XML))
def test_fuzz_read_metashape_calibration(work, data):
    from photax.io.metashape import read_metashape_calibration

    path = work / "calib.xml"
    path.write_bytes(data)

    _expect_valueerror_or_sane(read_metashape_calibration, path, _sane_cameras)


@FUZZ
@given(data=mutated(OPK_EXPORTS))
def test_fuzz_read_opk_export(work, data):
    from photax.io.metashape import read_opk_export

    path = work / "opk.txt"
    path.write_bytes(data)

    _expect_valueerror_or_sane(read_opk_export, path, _sane_orientations, r": no camera orientations$", lines=True)


PIX4D_CAMS = [
    b"Pix4D camera calibration file 0\n#Focal Length mm assuming a sensor width of 17.49998592x13.12498944mm\n"
    b"F 15.01175404934517487732\n#Principal Point mm\nPx 8.48210511970419922534\nPy 6.33434629978042273990\n"
    b"#Symmetrical Lens Distortion Coeffs\nK1 0.0383\nK2 -0.0175\nK3 0.0205\n#Tangential Lens Distortion Coeffs\n"
    b"T1 0.0024\nT2 0.0029\n",
]


@FUZZ
@given(data=mutated(PIX4D_CAMS))
def test_fuzz_read_pix4d_cam(work, data):
    from photax.io.pix4d import read_pix4d_cam

    path = work / "p_pix4d_calibrated_internal_camera_parameters.cam"
    path.write_bytes(data)
    whole = r": (no .*|not a Pix4D camera file .*|F \(focal length, mm\) must be positive.*|Px or Py .* out of range)$"
    _expect_valueerror_or_sane(lambda p: read_pix4d_cam(p, (4608, 3456)), path, _sane_camera, whole, lines=True)


PIX4D_CCP = [
    b"fileName imageWidth imageHeight\ncamera matrix K [3x3]\nradial distortion [3x1]\ntangential distortion [2x1]\n"
    b"camera position t [3x1]\ncamera rotation R [3x3]\ncamera model m = K [R|-Rt] X\n\nDJI_0954.JPG 4608 3456\n"
    b"3952.8 0 2233.4\n0 3952.8 1667.9\n0 0 1\n0.038 -0.017 0.020\n0.0024 0.0029\n21.5 -29.5 30.8\n"
    b"0.78 -0.62 -0.019\n-0.62 -0.78 -0.033\n0.0058 0.038 -0.99\nDJI_0955.JPG 4608 3456\n",
]


@FUZZ
@given(data=mutated(PIX4D_CCP))
def test_fuzz_pix4d_image_size_beside(work, data):
    from photax.io.pix4d import image_size_beside

    cam = work / "q_pix4d_calibrated_internal_camera_parameters.cam"
    cam.write_bytes(PIX4D_CAMS[0])
    path = work / "q_calibrated_camera_parameters.txt"
    path.write_bytes(data)

    def sane(size):
        assert size is None or (len(size) == 2 and min(size) >= 1)

    whole = r": (no 'fileName imageWidth imageHeight' line.*|images of \d+ sizes.*)$"
    _expect_valueerror_or_sane(lambda p: image_size_beside(cam), path, sane, whole, lines=True)


# --- satellite RPC files (photax.io.satellite: every family, by content) -----------------------


def _rpc_seeds(folder) -> dict[str, list[bytes]]:
    """Valid files of the text and XML families, made from a synthetic RPC (nothing outside the
    repository needed), plus the real IKONOS and Pleiades files of ../shared/data when present."""
    from photax.io.satellite import write_rpc
    from photax.rpc import RPCCamera

    rng = np.random.default_rng(1)
    coeffs = rng.normal(0, 1e-4, (4, 20))
    coeffs[0, :4] += [0.0, 0.03, -1.04, 0.01]
    coeffs[2, :4] += [0.0, 1.02, 0.0, 0.013]
    coeffs[[1, 3], 0] = 1.0
    cam = RPCCamera(coeffs, [24.4, -33.7, 700.0, 640.0, 400.0], [0.1, 0.07, 500.0, 1400.0, 1200.0], direct=coeffs)
    txt = write_rpc(cam, folder / "seed_RPC.TXT").read_bytes()
    rpb = write_rpc(cam, folder / "seed.RPB", "rpb").read_bytes()
    o, s = np.asarray(cam.offsets), np.asarray(cam.scales)
    body = "".join(f"<{t}>{v!r}</{t}>\n" for t, v in zip(("LONGOFFSET", "LATOFFSET", "HEIGHTOFFSET", "SAMPOFFSET",
                                                           "LINEOFFSET"), o.tolist(), strict=True))  # fmt: skip
    body += "".join(f"<{t}>{v!r}</{t}>\n" for t, v in zip(("LONGSCALE", "LATSCALE", "HEIGHTSCALE", "SAMPSCALE",
                                                           "LINESCALE"), s.tolist(), strict=True))  # fmt: skip
    for tag, row in zip(("LINENUMCOEF", "LINEDENCOEF", "SAMPNUMCOEF", "SAMPDENCOEF"), coeffs, strict=True):
        body += f"<{tag}List><{tag}>{' '.join(repr(float(c)) for c in row)}</{tag}></{tag}List>\n"
    isd = f'<?xml version="1.0"?>\n<isd>\n<RPB>\n<IMAGE>\n{body}</IMAGE>\n</RPB>\n</isd>\n'.encode()
    text = [txt]
    if (SHARED_DATA / "satellite/rpc_IKONOS.txt").is_file():
        text.append((SHARED_DATA / "satellite/rpc_IKONOS.txt").read_bytes())
    xml = [isd]
    if (SHARED_DATA / "satellite/rpc_PLEIADES.xml").is_file():
        xml.append((SHARED_DATA / "satellite/rpc_PLEIADES.xml").read_bytes())
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        profile = dict(
            driver="GTiff", width=4, height=3, count=1, dtype="uint8", rpcs=rasterio.rpc.RPC(**cam.to_dict())
        )
        with rasterio.open(folder / "seed.tif", "w", **profile) as dst:
            dst.write(np.zeros((1, 3, 4), np.uint8))
    return {"text": text, "rpb": [rpb], "xml": xml, "raster": [(folder / "seed.tif").read_bytes()]}


@pytest.fixture(scope="module")
def rpc_seeds(tmp_path_factory):
    return _rpc_seeds(tmp_path_factory.mktemp("rpc_seeds"))


def _expect_photax_error_or_sane_rpc(path) -> None:
    """``read_rpc(path)``: a sane RPC (finite numbers, non-zero scales) or one of photax's two file
    errors, naming the file on one line; nothing else (no XML, YAML, JSON, rasterio, numpy error)."""
    from photax.errors import MalformedFileError, UnsupportedFormatError
    from photax.io.satellite import read_rpc

    try:
        cam = read_rpc(path)
    except (MalformedFileError, UnsupportedFormatError) as exc:
        _check_message(str(exc), path, None, None)
        return
    _finite(cam.coefficients, cam.offsets, cam.scales, cam.direct)
    assert np.all(np.asarray(cam.scales) != 0)


@pytest.mark.parametrize("family, examples", [("text", 300), ("rpb", 150), ("xml", 150), ("raster", 100)])
def test_fuzz_read_rpc(work, rpc_seeds, family, examples):
    """The satellite RPC readers on mutated KEY: value text (IKONOS, GDAL _RPC.TXT), .RPB and XML
    (Maxar ISD, DIMAP): only photax's typed errors escape, whatever the content sniffs as."""

    @settings(FUZZ, max_examples=fuzz_budget(examples))
    @given(data=mutated(rpc_seeds[family]))
    def run(data):
        path = work / "rpc_file"  # no suffix: the family is the content's
        path.write_bytes(data)
        _expect_photax_error_or_sane_rpc(path)

    run()


def test_rpc_seeds_are_valid(work, rpc_seeds):
    from photax.io.satellite import read_rpc, rpc_format

    expected = {"text": "rpc-txt", "rpb": "rpb", "xml": ("maxar-xml", "dimap"), "raster": "raster"}
    for family, seeds in rpc_seeds.items():
        for raw in seeds:
            path = work / f"seed_{family}"
            path.write_bytes(raw)
            assert rpc_format(path) in expected[family]
            read_rpc(path)


def test_fuzz_profile():
    """The fuzz tests take their seed and budget from the hypothesis profile (conftest.py):
    "ci" (the default) draws the same examples every run; "deep" ten times as many, at random."""
    name = settings.get_current_profile_name()
    if name == "ci":
        assert FUZZ.derandomize and FUZZ.max_examples == 300 and FUZZ.database is None
    elif name == "deep":
        assert not FUZZ.derandomize and FUZZ.max_examples == 3000
