"""One progress bar per command, named after it (stderr of ``photax.cli.main``).

A tqdm bar redraws itself on one line (``\\r``) and ends it with a newline
when it closes: the last state on each line of stderr is one bar.
"""

import json
import re

import numpy as np
import pytest
from conftest import ROOT

import photax
import photax.demo
from photax.cli import main
from photax.io.camera_file import write_camera
from photax.io.raster import write_geotiff

BAR = re.compile(r"([A-Za-z][\w ]*): +(?:\d+%\||\d+\w* \[)")  # "ortho:  40%|####  | 2/5 [...]", "bundle: 3it [..."


def bars(err: str) -> list[str]:
    """Labels of the bars in ``err``, one per bar, in order."""
    closed = [m.group(1) for line in err.split("\n") if (m := BAR.match(line.split("\r")[-1]))]
    assert {m.group(1) for m in BAR.finditer(err)} <= set(closed)  # no other bar drawn and wiped
    return closed


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A 96 x 64 px RGB frame looking down on a gentle slope, 16 GCPs and 6 check points, as files."""
    d = tmp_path_factory.mktemp("scene")
    camera = photax.FrameCamera.from_pixels(120.0, (96, 64))
    exterior = photax.look_at([500.0, 300.0, 400.0], [505.0, 302.0, 0.0])
    heights = 10.0 + 0.02 * np.arange(60)[None, :] + np.zeros((60, 60))
    transform = (20.0, 0.0, -100.0, 0.0, -20.0, 900.0)  # 1200 m square around the footprint
    rng = np.random.default_rng(3)
    pixel = np.column_stack([rng.uniform(5, 90, 22), rng.uniform(5, 58, 22)])
    rays = np.asarray(camera.ray(camera.pixel_to_image(pixel))) @ np.asarray(exterior.rotation).T
    c = np.asarray(exterior.position)
    slope = lambda x: 10.0 + 0.02 * ((x + 100.0) / 20.0 - 0.5)  # noqa: E731  the DEM, bilinear = exact
    z = np.full(22, 15.0)
    for _ in range(30):  # cut each ray with the slope
        g = c + ((z - c[2]) / rays[:, 2])[:, None] * rays
        z = slope(g[:, 0])
    ground = np.column_stack([g[:, :2], z])
    pixel = np.asarray(camera.image_to_pixel(photax.project(ground, exterior, camera)))
    rows = ["name,E,N,h,col,row,role"] + [
        f"p{k},{x:.17g},{y:.17g},{h:.17g},{u:.17g},{v:.17g},{'check' if k >= 16 else 'control'}"
        for k, ((x, y, h), (u, v)) in enumerate(zip(ground, pixel))
    ]
    (d / "gcps.csv").write_text("\n".join(rows) + "\n")
    write_camera(camera, d / "camera.yaml")
    write_geotiff(d / "dem.tif", heights, transform)
    write_geotiff(d / "image.tif", rng.integers(1, 256, (3, 64, 96), dtype=np.uint8), None)
    (d / "exterior.json").write_text(
        json.dumps(
            {
                "position": list(map(float, exterior.position)),
                "angles_rad": list(map(float, exterior.angles)),
                "convention": exterior.convention,
            }
        )
    )
    return d


def commands(d, out):
    files = {
        k: str(d / f)
        for k, f in [
            ("gcps", "gcps.csv"),
            ("camera", "camera.yaml"),
            ("dem", "dem.tif"),
            ("image", "image.tif"),
            ("exterior", "exterior.json"),
        ]
    }
    return {
        "rectify": [
            "rectify",
            files["image"],
            "--gcps",
            files["gcps"],
            "--order",
            "1",
            "--resolution",
            "10",
            "--tile",
            "16",
            "--out",
            str(out / "rect.tif"),
        ],
        "ortho": [
            "ortho",
            files["image"],
            "--dem",
            files["dem"],
            "--interior",
            files["camera"],
            "--exterior",
            files["exterior"],
            "--resolution",
            "10",
            "--tile",
            "16",
            "--out",
            str(out / "o.tif"),
        ],
        "compare": [
            "compare",
            files["gcps"],
            "--camera",
            files["camera"],
            "--dem",
            files["dem"],
            "--image",
            files["image"],
            "--orders",
            "1",
            "--out",
            str(out / "cmp"),
        ],
        "bundle": ["bundle", str(ROOT / "data" / "block"), "--quiet", "--max-iterations", "3"],
        "resect": ["resect", files["gcps"], "--camera", files["camera"]],
    }


@pytest.mark.parametrize("command", ["rectify", "ortho", "compare", "bundle", "resect"])
def test_one_bar_per_command_named_after_it(scene, tmp_path, capsys, command):
    args = commands(scene, tmp_path)[command]
    assert main(args) in (0, 1)  # bundle stopped after 3 iterations: 1, not converged
    captured = capsys.readouterr()
    assert bars(captured.err) == [command], captured.err
    if command == "bundle":
        assert "bundle:" not in captured.out  # the bar is on stderr, the report on stdout
        # iterations and cost, no total: max_iterations is a limit, so a percentage or an ETA would lie
        last = captured.err.split("\n")[0].split("\r")[-1]
        assert re.match(r"bundle: 3it \[[\d:]+, .*cost=", last) and "%" not in captured.err, last
    if command == "resect":  # a bar over the images (issue 27: a 10^6-point file takes seconds), then the report
        assert "resect:" not in captured.out and "1 of 1 image solved" in captured.out
        assert "1/1" in captured.err
    if command in ("rectify", "bundle", "resect"):  # the cheap ones
        assert main([*args, "--no-progress"]) in (0, 1)
        assert bars(capsys.readouterr().err) == []


def test_demo_shows_one_bar_over_its_sections(tmp_path, capsys, monkeypatch):
    # Three cheap stand-in sections: the framework's bar, not the sections' work.
    monkeypatch.setattr(photax.demo, "SECTIONS", [lambda out: "a", lambda out: "b", lambda out: "c"])
    assert main(["demo", "--out", str(tmp_path / "demo")]) == 0
    err = capsys.readouterr().err
    assert bars(err) == ["demo"]
    assert "3/3" in err


def test_compare_advances_one_bar_over_all_models():
    """A bar passed in is advanced, not closed, and no bar of its own is opened."""

    class Bar:
        def __init__(self):
            self.n, self.closed = 0, False

        def update(self, n=1):
            self.n += n

        def set_postfix(self, *a, **k):
            pass

        def close(self):
            self.closed = True

    bar = Bar()
    grid = photax.Grid.from_bounds((0.0, 0.0, 40.0, 30.0), 1.0)
    image = np.arange(20.0 * 30).reshape(20, 30)
    for _ in range(3):
        photax.rectify(image, lambda xy: xy * 0.5, grid, tile=16, progress=bar)
    assert bar.n == 3 * 6 and not bar.closed  # 40 x 30 px in 16-px tiles: 3 x 2 tiles per call
    from photax.progress import progress_bar

    with pytest.raises(ValueError, match="progress"):
        with progress_bar(3.5, 1, desc="x"):
            pass


def _screen(err: str) -> list[str]:
    """What a terminal shows of ``err``: each ``\\r`` returns to the line's start and overwrites."""
    lines = []
    for line in err.split("\n"):
        shown = ""
        for part in line.split("\r"):
            shown = part + shown[len(part) :]
        lines.append(shown.rstrip())
    return [s for s in lines if s]


def test_an_error_leaves_its_message_not_a_bar(scene, tmp_path, capsys, monkeypatch):
    """An error while a bar is open ends in the one-line message alone (was: "rectify: 0%|..." above it)."""
    import photax.rectification._files

    def broken(*a, **k):
        raise ValueError("a tile went wrong")

    monkeypatch.setattr(photax.rectification._files, "_resample_tile", broken)
    assert main(commands(scene, tmp_path)["rectify"]) == 2
    assert _screen(capsys.readouterr().err) == ["photax rectify: error: a tile went wrong"]
    assert list(tmp_path.iterdir()) == []
