"""photax.errors: one typed hierarchy; the library raises its types; the CLI decides by type, not by words.

References: the README's exit-status contract (0 / 1 / 2 / 130); Python's
exception hierarchy (a typed error is still the built-in photax raised before).
"""

from __future__ import annotations

import ast
import pathlib

import numpy as np
import pytest
from conftest import ROOT

import photax
import photax.cli._common as common
from photax import errors
from photax.cli import main

DATA = ROOT / "data"
SRC = pathlib.Path(photax.__file__).resolve().parent

BUILTIN = {
    errors.UnreadableFileError: (OSError, ValueError),
    errors.UnsupportedFormatError: (ValueError,),
    errors.NoEntryError: (ValueError, LookupError),
    errors.CRSMismatchError: (ValueError,),
    errors.OutsideValidityError: (ValueError,),
    errors.DegenerateGeometryError: (ValueError,),
    errors.NotConvergedError: (ValueError,),
    errors.ConvergenceError: (ValueError, RuntimeError),
}


@pytest.mark.parametrize("kind", list(BUILTIN), ids=lambda k: k.__name__)
def test_each_type_is_a_photax_error_and_the_builtin_it_was(kind):
    exc = kind("x.tif: what went wrong")
    assert isinstance(exc, errors.PhotaxError)
    for base in BUILTIN[kind]:
        assert isinstance(exc, base)
    assert str(exc) == "x.tif: what went wrong"  # OSError's (errno, strerror) do not garble it
    assert getattr(photax, kind.__name__) is kind  # public at the top level


# --- the library raises its types ---------------------------------------------


def test_a_folder_or_a_text_file_as_a_raster(tmp_path):
    from photax.io.files import read_bytes

    with pytest.raises(errors.UnreadableFileError, match="is a folder"):
        read_bytes(tmp_path, "image")
    text = tmp_path / "notes.tif"
    text.write_text("not a raster\n")
    with pytest.raises(errors.UnsupportedFormatError, match="not a raster"):
        photax.read_geotiff(text)


def test_no_entry_of_that_name(tmp_path):
    path = tmp_path / "rpc_param.yaml"
    path.write_text("a.tif:\n  rpc: {}\nb.tif:\n  rpc: {}\n")
    with pytest.raises(errors.NoEntryError, match="no entry 'zz.tif'"):
        photax.read_rpc(path, "zz.tif")


def test_crs_mismatch_degenerate_and_outside():
    from photax.grid import Grid
    from photax.io.crs import require_same

    with pytest.raises(errors.CRSMismatchError):
        require_same("EPSG:32633", "the DEM", "EPSG:32634", "the GCPs")
    with pytest.raises(errors.DegenerateGeometryError, match="singular"):
        Grid((1.0, 2.0, 0.0, 2.0, 4.0, 0.0), (10, 10))  # a*e - b*d = 0
    src = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])  # all on one line
    with pytest.raises(errors.DegenerateGeometryError, match="collinear"):
        photax.fit_projective(src, src + 1.0)
    import pyproj

    from photax.io._geo import project_lla

    with pytest.raises(errors.OutsideValidityError, match="outside the area"):  # the antipode of LAEA's centre
        project_lla(-52.0, -170.0, 0.0, pyproj.CRS("EPSG:3035"))


# --- the CLI: exit status from the type ----------------------------------------


def _run(monkeypatch, capsys, exc, tmp_path):
    """``photax rectify`` whose first input check raises ``exc``: (status, stderr)."""

    def fail(path, what):
        raise exc

    monkeypatch.setattr(common, "input_file", fail)
    out = tmp_path / "out.tif"
    status = main(
        ["rectify", str(DATA / "sample_image.tif"), "--gcps", str(DATA / "sample_gcps.csv"), "--out", str(out)]
    )
    err = capsys.readouterr().err
    assert not out.exists()
    return status, err


@pytest.mark.parametrize(
    "kind, status",
    [
        (errors.UnreadableFileError, 2),
        (errors.UnsupportedFormatError, 2),
        (errors.NoEntryError, 2),
        (errors.CRSMismatchError, 2),
        (errors.OutsideValidityError, 2),
        (errors.DegenerateGeometryError, 2),
        (errors.NotConvergedError, 1),
        (errors.ConvergenceError, 1),
        (ValueError, 2),
    ],
    ids=lambda k: getattr(k, "__name__", str(k)),
)
def test_cli_exit_status_is_the_types(monkeypatch, capsys, tmp_path, kind, status):
    # One message for every type: only the type can choose the status.
    got, err = _run(monkeypatch, capsys, kind("the same words: did not converge"), tmp_path)
    assert got == status
    assert err == "photax rectify: error: the same words: did not converge\n"


def test_words_do_not_choose_the_status(monkeypatch, capsys, tmp_path):
    # a ValueError that says "did not converge" is an input error; a NotConvergedError saying anything is 1
    assert _run(monkeypatch, capsys, ValueError("did not converge"), tmp_path)[0] == 2
    assert _run(monkeypatch, capsys, errors.NotConvergedError("input looks fine"), tmp_path)[0] == 1


def test_cli_real_failure_modes(tmp_path, capsys):
    out = str(tmp_path / "out.tif")
    gcps = str(DATA / "sample_gcps.csv")
    assert main(["rectify", str(tmp_path), "--gcps", gcps, "--out", out]) == 2  # a folder as the image
    assert "folder" in capsys.readouterr().err
    text = tmp_path / "notes.tif"
    text.write_text("not a raster\n")
    assert main(["rectify", str(text), "--gcps", gcps, "--out", out]) == 2
    assert "not a raster" in capsys.readouterr().err


# --- no decision on the words of an exception -----------------------------------


def _text_matching(source: str) -> list[int]:
    """Lines that test the words of an exception or a message: ``... in str(exc)``, ``str(e).startswith``,
    ``"x" in res.message``, ``exc.args[0] == ...``, ``re.search(..., str(exc))``."""

    def is_text(node) -> bool:
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "str" and node.args:
            return isinstance(node.args[0], ast.Name) and node.args[0].id not in ("path", "p", "name")
        if isinstance(node, ast.Attribute) and node.attr in ("message", "args", "strerror"):
            return True
        if isinstance(node, ast.Subscript):
            return is_text(node.value)
        return False

    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare) and any(is_text(n) for n in [node.left, *node.comparators]):
            if not any(isinstance(op, (ast.Is, ast.IsNot)) for op in node.ops):
                lines.append(node.lineno)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            f = node.func
            if f.attr in ("startswith", "endswith", "find", "index", "count") and is_text(f.value):
                lines.append(node.lineno)
            if f.attr in ("search", "match", "fullmatch", "findall") and any(is_text(a) for a in node.args):
                lines.append(node.lineno)
    return sorted(lines)


def test_the_matching_finder_finds_planted_cases():
    planted = (
        "try:\n    f()\nexcept ValueError as exc:\n    if 'no entry' not in str(exc):\n        raise\n"
        "if res.message.startswith('wrong'):\n    pass\n"
        "if 'units' in res.message:\n    pass\n"
        "import re\nre.search('x', str(err))\n"
        "ok = 'rpc' in v and str(path).endswith('.tif') and res.message is None\n"
    )
    assert _text_matching(planted) == [4, 6, 8, 11]


def test_no_cli_file_decides_on_exception_text():
    files = sorted((SRC / "cli").glob("*.py")) + [SRC / "resection" / "_api.py"]
    found = {str(p.relative_to(SRC)): _text_matching(p.read_text()) for p in files}
    assert {k: v for k, v in found.items() if v} == {}
