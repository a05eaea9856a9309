"""The ``photax`` command's vocabulary (issue 26, "what a new user hit"): one spelling of each option
across the subcommands, help text and an example in every ``--help``, ``--version``, errors in the
subcommand's own words, the extra to install when an optional dependency is missing, and
``photax ortho --height``.

References: argparse's own parsers (the option tables), pyproject.toml's extras, the notebooks'
import statements, and an ortho on a constant-height DEM file (for ``--height``).
"""

import importlib
import importlib.metadata
import json
import pathlib
import re
import sys
import tomllib

import numpy as np
import pytest
import rasterio
from conftest import ROOT

from photax.cli import SUBCOMMANDS, build_parser, main
from photax.io.raster import write_geotiff

DATA = ROOT / "data"
PARSERS = build_parser().subcommands


def _options(name):
    """The visible options of a subcommand: argparse actions with option strings, less --help."""
    return [a for a in PARSERS[name]._actions if a.option_strings and a.help != "==SUPPRESS==" and a.dest != "help"]


@pytest.mark.parametrize("name", SUBCOMMANDS)
def test_every_help_has_an_example_and_every_option_says_what_it_is(name):
    text = PARSERS[name].format_help()
    assert re.search(r"^examples?:\n  photax " + name + " ", text, re.MULTILINE), text
    missing = [a.option_strings[-1] for a in _options(name) if not (a.help or "").strip()]
    assert missing == [], f"photax {name}: options without help text"
    arguments = [a.dest for a in PARSERS[name]._actions if not a.option_strings and not (a.help or "").strip()]
    assert arguments == [], f"photax {name}: arguments without help text"


@pytest.mark.parametrize("name", SUBCOMMANDS)
def test_one_vocabulary_for_outputs_and_progress(name):
    opts = PARSERS[name]._option_string_actions
    # -o names the command's output, a file (--out) or a folder (--out-dir)
    assert "-o" in opts and opts["-o"].option_strings[-1] in ("--out", "--out-dir"), name
    assert (opts["-o"].option_strings[-1] == "--out-dir") == (opts["-o"].metavar == "DIR"), name
    # --no-progress wherever the command draws a bar (its runner passes progress= to the library)
    source = pathlib.Path(importlib.import_module(f"photax.cli.{name}").__file__).read_text()
    draws = "args.progress" in source
    assert ("--no-progress" in opts) == draws, name


def test_defaults_are_shown_and_old_spellings_still_parse():
    assert "default: bilinear" in " ".join(PARSERS["ortho"].format_help().split())
    assert "(default: affine)" in " ".join(PARSERS["fiducials"].format_help().split())
    parser = build_parser()
    old = {
        ("compare", "--out"): "out_dir",
        ("demo", "--out"): "out_dir",
        ("resect", "--json"): "out",
        ("bundle", "--json"): "out",
    }
    required = {
        "compare": ["G.csv", "--camera", "c", "--dem", "d"],
        "demo": [],
        "resect": ["G.csv", "--camera", "c"],
        "bundle": ["block"],
    }
    for (name, flag), dest in old.items():
        args = parser.parse_args([name, *required[name], flag, "x"])
        assert getattr(args, dest) == "x", (name, flag)
        assert re.search(rf"{flag}(?![\w-])", PARSERS[name].format_help()) is None  # hidden from the help
    assert parser.parse_args(["demo"]).out_dir == "photax-demo"


def test_version(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.strip() == f"photax {importlib.metadata.version('photax')}"


def test_a_mistyped_option_shows_the_subcommands_usage(capsys):
    argv = [
        "ortho",
        "image.tif",
        "--dem",
        "d.tif",
        "--camera",
        "c.yaml",
        "--exterior",
        "e.json",
        "-o",
        "o.tif",
        "--resolutoin",
        "2",
    ]
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: photax ortho "), err
    assert err.strip().endswith("photax ortho: error: unrecognized arguments: --resolutoin 2"), err


def test_a_missing_optional_dependency_names_the_extra(tmp_path, capsys, monkeypatch):
    """Without the dask extra ``photax mosaic`` of ortho files runs, ``--dsm`` included (NumPy and rasterio,
    no Dask: issue 21), and what needs the extra (orthos over the memory budget: the Dask way) is a usage
    error naming it (was "unexpected ModuleNotFoundError ... (PHOTAX_TRACEBACK=1 shows where)")."""
    import photax.mosaicking as mosaicking

    for module in ("dask", "xarray", "rioxarray", "distributed"):
        monkeypatch.setitem(sys.modules, module, None)  # "not installed": importing it raises
    for module in [m for m in sys.modules if m.startswith(("dask.", "xarray.", "rioxarray."))]:
        monkeypatch.delitem(sys.modules, module)
    field = np.random.default_rng(3).integers(1, 255, (60, 100)).astype(np.uint8)
    paths = []
    for name, c0 in (("a", 0), ("b", 40)):  # two orthos on one lattice, 20 columns of overlap
        paths.append(str(tmp_path / f"{name}.tif"))
        profile = dict(driver="GTiff", width=60, height=60, count=1, dtype="uint8", crs="EPSG:32633", nodata=0)
        transform = rasterio.transform.from_origin(500_000 + 2.0 * c0, 4_000_000, 2.0, 2.0)
        with rasterio.open(paths[-1], "w", transform=transform, **profile) as dst:
            dst.write(field[:, c0 : c0 + 60], 1)
    flat = dict(profile, width=100, dtype="float32", nodata=None)  # a flat DSM on the union grid
    with rasterio.open(tmp_path / "dsm.tif", "w", transform=rasterio.transform.from_origin(500_000, 4_000_000, 2.0, 2.0),
                       **flat) as dst:  # fmt: skip
        dst.write(np.zeros((60, 100), np.float32), 1)
    out = tmp_path / "m.tif"
    assert main(["mosaic", *paths, "--dsm", str(tmp_path / "dsm.tif"), "-o", str(out), "--no-progress"]) == 0
    with rasterio.open(out) as ds:
        assert ds.shape == (60, 100) and ds.dtypes[0] == "uint8"
    out.unlink()
    monkeypatch.setattr(mosaicking, "_PERSIST_BYTES", 0)
    assert main(["mosaic", *paths, "-o", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert re.fullmatch(r'photax mosaic: error: needs \w+, in the dask extra: pip install "photax\[dask\]"\n', err), err
    assert not out.exists()


def _requirement_names(reqs):
    return {re.match(r"[A-Za-z0-9_.-]+", r).group(0).lower().replace("_", "-") for r in reqs}


def test_the_notebooks_extra_brings_what_every_notebook_imports():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    have = _requirement_names(project["dependencies"] + extras["notebooks"])
    have |= {"ipython"}  # IPython comes with ipykernel (its kernel)
    dists = importlib.metadata.packages_distributions()
    for nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
        code = "\n".join("".join(c["source"]) for c in json.loads(nb.read_text())["cells"] if c["cell_type"] == "code")
        imported = {m.split(".")[0] for m in re.findall(r"^\s*(?:import|from)\s+([\w.]+)", code, re.MULTILINE)}
        third_party = {m for m in imported if m not in sys.stdlib_module_names and m != "photax"}
        needed = {d.lower() for m in third_party for d in dists.get(m, [m])}
        # photax's Dask-backed functions import the dask extra's packages themselves
        if re.search(r"\b(mosaic|orthorectify_dask|to_raster)\(|\.rio\.", code):
            needed |= _requirement_names(extras["dask"])
        assert needed <= have, f"{nb.name}: the notebooks extra lacks {sorted(needed - have)}"


def test_ortho_height_equals_an_ortho_on_a_constant_dem_file(tmp_path, capsys):
    """``--height H`` (no DEM): the same ortho, pixel for pixel, as ``--dem`` with a constant-H DEM file
    covering far more than the footprint."""
    truth = json.loads((DATA / "sample_truth.json").read_text())
    x, y = truth["position"][:2]
    h = 95.0
    flat = tmp_path / "flat.tif"
    write_geotiff(flat, np.full((50, 50), h), (200.0, 0.0, x - 5000.0, 0.0, -200.0, y + 5000.0))
    common = [
        str(DATA / "sample_image.tif"),
        "--camera",
        str(DATA / "sample_camera.yaml"),
        "--exterior",
        str(DATA / "sample_truth.json"),
        "--resolution",
        "2",
        "--no-progress",
    ]
    assert main(["ortho", *common, "--dem", str(flat), "-o", str(tmp_path / "dem.tif")]) == 0
    assert main(["ortho", *common, "--height", str(h), "-o", str(tmp_path / "height.tif")]) == 0
    capsys.readouterr()
    with rasterio.open(tmp_path / "dem.tif") as a, rasterio.open(tmp_path / "height.tif") as b:
        assert a.transform == b.transform and a.shape == b.shape
        np.testing.assert_allclose(b.read(), a.read(), rtol=0, atol=1e-6)
        assert (a.read() != 0).mean() > 0.3  # an ortho (a footprint turned 35 degrees), not nodata
    with pytest.raises(SystemExit):  # one of --dem and --height
        main(["ortho", *common, "--dem", str(flat), "--height", "1", "-o", str(tmp_path / "x.tif")])


@pytest.mark.parametrize("name", SUBCOMMANDS)
def test_a_run_builds_only_its_subcommand_as_the_full_parser_has_it(name):
    one = build_parser(name)
    assert list(one.subcommands) == [name]
    assert one.subcommands[name].format_help() == PARSERS[name].format_help()
    assert one.subcommands[name].format_usage() == PARSERS[name].format_usage()
