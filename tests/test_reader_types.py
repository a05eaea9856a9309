"""Every value of every structured (YAML / JSON) file photax reads, replaced by
a value of each other type: the reader's own error or a sane result, never a
``TypeError``, ``KeyError``, ``AttributeError`` or an unhashable-type crash
(issue 38: orthority's interior ``type: []`` raised ``TypeError: unhashable
type: 'list'``).

Where the random fuzzing of ``test_fuzz_readers.py`` draws some of these
substitutions on some runs, this test makes every one of them, for every key
of each seed file (the first two items of a long list), so it finds the same
class of crash on every run.  The errors are checked as the fuzz tests check
them: one line naming the file.  For a YAML seed, which photax reads with
each key's line, a substituted value's error that names a line names one
inside the file.
"""

from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest
import yaml
from conftest import SHARED_DATA
from test_fuzz_readers import (
    CAMERA,
    CAMERA_JSON,
    DATA,
    EXTERIORS_JSON,
    GCP_GEOJSON,
    OPENSFM,
    ORTHO_GEOJSON,
    ORTHO_INT,
    _check_message,
    _finite,
    _sane_block,
    _sane_camera,
    _sane_cameras,
    _sane_gcps,
)

# One value of each kind a YAML or JSON file can hold, and a few edge cases of each.
SUBSTITUTES = [None, True, False, 0, -1, 1.5, 10**400, "", "x", "1.5", [], [1, 2], ["a", "b"], [[1]], {}, {"a": 1}]
# One of each type, for the readers whose every call is dear (a CRS transformation per file).
TYPES = [None, True, 1.5, "x", [], [1, 2], {}]


def _paths(node, prefix=()):
    """Every path to a value in ``node`` (dict keys, list indices; the first two items of a list)."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield (*prefix, k)
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node[:2]):
            yield (*prefix, i)
            yield from _paths(v, (*prefix, i))


def _replaced(doc, path, value):
    doc = json.loads(json.dumps(doc))  # a deep copy
    node = doc
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return doc


# YAML keys need not be text: each key of a YAML seed is also replaced by one of these.
KEY_SUBSTITUTES = [None, True, 0, 1.5]


def _renamed(doc, path, new_key):
    doc = json.loads(json.dumps(doc))
    node = doc
    for key in path[:-1]:
        node = node[key]
    if not isinstance(node, dict):
        return None
    node[new_key] = node.pop(path[-1])
    return doc


def _cases(seed: bytes, yaml_seed: bool, where=None, substitutes=SUBSTITUTES):
    """``(path, value, document)`` for each value of ``seed`` (at a path ``where`` accepts) replaced
    by each of ``substitutes``, and, in YAML, each key by each of :data:`KEY_SUBSTITUTES`."""
    doc = yaml.safe_load(seed) if yaml_seed else json.loads(seed)
    for path in _paths(doc):
        if where is not None and not where(path):
            continue
        for value in substitutes:
            yield path, value, _replaced(doc, path, value)
        if yaml_seed:
            for key in KEY_SUBSTITUTES:
                renamed = _renamed(doc, path, key)
                if renamed is not None:
                    yield (*path, "<key>"), key, renamed


def _dump(doc, yaml_seed: bool) -> str:
    if yaml_seed:
        return yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)
    return json.dumps(doc, indent=1, allow_nan=False)


def _sane_pair(result):
    eos, crs = result
    assert eos and (crs is None or isinstance(crs, str))
    for eo in eos.values():
        _finite(eo.position, eo.angles)


def _sane_shots(result):
    eos, crs, names = result
    assert eos and isinstance(crs, str) and set(names) == set(eos)
    for eo in eos.values():
        _finite(eo.position, eo.angles)


def _sane_rpc(cam):
    assert cam.image_size is None or min(cam.image_size) >= 1
    _finite(*[np.asarray(v) for v in vars(cam).values() if isinstance(v, (float, np.ndarray))])


def _readers():
    from photax.io import read_exteriors
    from photax.io.camera_file import read_camera
    from photax.io.gcp import read_gcps
    from photax.io.odm import read_odm_cameras
    from photax.io.opensfm import read_opensfm_cameras, read_opensfm_shots
    from photax.io.orthority import read_orthority_geojson, read_orthority_interior
    from photax.io.pushbroom_file import read_pushbroom

    odm = json.dumps({"c": {"projection_type": "brown", "width": 640, "height": 480, "focal_x": 0.66,
                            "focal_y": 0.67, "c_x": -0.001, "c_y": 0.004, "k1": -0.26, "k2": 0.1, "p1": 0.0007,
                            "p2": 0.0002, "k3": -0.02}}).encode()  # fmt: skip
    pushbroom = (
        b"type: pushbroom\nname: toy\nimage_size: [96, 80]\nfocal_length: 1000.0\nprincipal_point: [0.0, 0.0]\n"
        b"convention: omega-phi-kappa\nreference: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]\n"
        b"position: [[0.0, 0.0, 7000.0], [10.0, 0.0, 0.0]]\nangles: [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]\n"
    )
    rows = [
        # (name, reader, file name, seeds (bytes), YAML?, sane)
        ("camera_yaml", read_camera, "camera.yaml", CAMERA, True, _sane_camera),
        ("camera_json", read_camera, "camera.json", CAMERA_JSON, False, _sane_camera),
        ("orthority_interior", read_orthority_interior, "int_param.yaml", ORTHO_INT[:2], True, _sane_cameras),
        ("orthority_geojson", read_orthority_geojson, "ext.geojson", ORTHO_GEOJSON[:1], False, _sane_pair),
        ("opensfm_cameras", read_opensfm_cameras, "reconstruction.json", OPENSFM, False, _sane_cameras),
        # the shots' reader: everything but the cameras (read_opensfm_cameras' above), one value of each type
        (
            "opensfm_shots",
            read_opensfm_shots,
            "reconstruction.json",
            OPENSFM,
            False,
            _sane_shots,
            lambda path: len(path) < 2 or path[1] != "cameras",
            TYPES,
        ),
        ("gcps_geojson", lambda p: read_gcps(p, format="geojson"), "gcps.geojson", GCP_GEOJSON[:1], False, _sane_gcps),
        ("exteriors_json", read_exteriors, "block.json", EXTERIORS_JSON, False, _sane_pair),
        ("odm_cameras", read_odm_cameras, "cameras.json", [odm], False, _sane_cameras),
        ("pushbroom_yaml", read_pushbroom, "pushbroom.yaml", [pushbroom], True, lambda c: None),
    ]
    rpc = SHARED_DATA / "orthority" / "rpc" / "rpc_param.yaml"
    if rpc.is_file():
        from photax.rpc import read_rpc

        # an RPCCamera of JAX arrays per read: one value of each type
        rows.append(
            ("rpc_orthority_yaml", read_rpc, "rpc_param.yaml", [rpc.read_bytes()], True, _sane_rpc, None, TYPES)
        )
    return rows


READERS = {row[0]: (*row[1:], None, SUBSTITUTES)[:7] for row in _readers()}


def _check(read, path: pathlib.Path, text: str, sane) -> str:
    """The reader's error naming the file (and a line inside it, if any), or a sane result."""
    path.write_text(text)
    try:
        result = read(path)
    except ValueError as exc:
        _check_message(str(exc), path, None, None)
        msg = str(exc)
        if f"{path}, line " in msg:
            line = int(msg.split(f"{path}, line ", 1)[1].split(":", 1)[0])
            assert 1 <= line <= text.count("\n") + 1, msg
        return "error"
    sane(result)
    return "read"


@pytest.mark.parametrize("name", list(READERS))
def test_every_value_of_every_type(tmp_path, name):
    read, file_name, seeds, yaml_seed, sane, where, substitutes = READERS[name]
    path = tmp_path / file_name
    for seed in seeds:  # the seeds are read
        assert _check(read, path, seed.decode(), sane) == "read", seed[:80]
    outcomes = {"error": 0, "read": 0}
    for seed in seeds:
        for key, value, doc in _cases(seed, yaml_seed, where, substitutes):
            try:
                outcomes[_check(read, path, _dump(doc, yaml_seed), sane)] += 1
            except Exception as exc:  # name the substitution that crashed
                raise AssertionError(f"{name}: {'/'.join(map(str, key))} = {value!r}: {exc!r}") from exc
    # A reader that accepted every substitution would not be checking anything.
    assert outcomes["error"] > 0, outcomes


def test_block_json_every_value_of_every_type(tmp_path):
    """The block folder's ``block.json`` (its CSVs are text, checked by the fuzz tests)."""
    import shutil

    from photax.io.block import read_block

    for f in ("observations.csv", "points.csv"):
        shutil.copy(DATA / "block" / f, tmp_path / f)
    seed = (DATA / "block" / "block.json").read_bytes()
    errors = 0
    for key, value, doc in _cases(seed, False):
        (tmp_path / "block.json").write_text(_dump(doc, False))
        try:
            _sane_block(read_block(tmp_path))
        except ValueError as exc:
            _check_message(str(exc), tmp_path, None, None)
            errors += 1
        except Exception as exc:
            raise AssertionError(f"block.json: {'/'.join(map(str, key))} = {value!r}: {exc!r}") from exc
    assert errors > 0
