"""``photax ortho IMAGE... --out-dir DIR``: a block of images in one process (issue 21, item 4).

On orthority's NGI frames (``../shared/data/orthority``; skipped when absent), at 20 m to stay
quick: the block command writes, for every image, the very file ``photax ortho IMAGE -o OUT``
writes for it alone (bit for bit), and an image that fails is named and exits 1 with the others
written.  Timing beside ``oty frame``: ``benchmarks/bench_ortho_block.py``.
"""

import filecmp
import pathlib
import shutil

import pytest
from conftest import SHARED_DATA

from photax.cli import main

NGI, IO = SHARED_DATA / "orthority" / "ngi", SHARED_DATA / "orthority" / "io"
NAMES = ["3324c_2015_1004_05_0182_RGB", "3324c_2015_1004_05_0184_RGB", "3324c_2015_1004_06_0251_RGB"]


@pytest.fixture
def images(tmp_path):
    if not (NGI / "dem.tif").is_file():
        pytest.skip("../shared/data/orthority/ngi is not present")
    folder = tmp_path / "in"
    folder.mkdir()
    for n in NAMES:
        shutil.copy(NGI / f"{n}.tif", folder / f"{n}.tif")
    return [folder / f"{n}.tif" for n in NAMES]


def _common():
    return [
        "--dem",
        str(NGI / "dem.tif"),
        "--camera",
        str(IO / "ngi_int_param.yaml"),
        "--exterior",
        str(IO / "ngi_xyz_opk.csv"),
        "--resolution",
        "20",
        "--resampling",
        "cubic",
        "--no-progress",
    ]


def _singles(images, folder):
    folder.mkdir()
    for image in images:
        assert main(["ortho", str(image), "-o", str(folder / f"{image.stem}.tif"), *_common()]) == 0
    return {image.stem: folder / f"{image.stem}.tif" for image in images}


def test_block_writes_what_single_runs_write_bit_for_bit(images, tmp_path, capsys):
    assert main(["ortho", *map(str, images), "--out-dir", str(tmp_path / "block"), *_common()]) == 0
    assert capsys.readouterr().out.count("wrote ") == len(images)
    singles = _singles(images, tmp_path / "single")
    for image in images:
        assert filecmp.cmp(tmp_path / "block" / f"{image.stem}_ortho.tif", singles[image.stem], shallow=False)


def test_a_bad_image_exits_1_and_the_others_are_written(images, tmp_path, capsys):
    broken = images[1]
    broken.write_bytes(b"II*\x00" + b"\x17" * 500)  # a TIFF header and garbage
    stranger = images[0].with_name("stranger.tif")  # an image the exterior file does not know
    shutil.copy(images[0], stranger)
    todo = [images[0], broken, stranger, images[2]]
    rc = main(["ortho", *map(str, todo), "--out-dir", str(tmp_path / "block"), *_common()])
    err = capsys.readouterr().err
    assert rc == 1
    assert f"{broken} failed" in err and f"{stranger} failed" in err and "2 of 4 images failed" in err
    assert not (tmp_path / "block" / f"{broken.stem}_ortho.tif").exists()
    assert not (tmp_path / "block" / "stranger_ortho.tif").exists()
    singles = _singles([images[0], images[2]], tmp_path / "single")
    for image in (images[0], images[2]):
        assert filecmp.cmp(tmp_path / "block" / f"{image.stem}_ortho.tif", singles[image.stem], shallow=False)
    assert not list((tmp_path / "block").glob(".*part"))  # no temporary left


def test_an_image_failing_mid_ortho_exits_1_and_the_others_are_written(images, tmp_path, capsys):
    # Its header reads (its grid is made) but its pixels do not: it fails while the next image is
    # already being computed (two images in flight), and only it is missing.
    broken = images[1]
    broken.write_bytes(broken.read_bytes()[: broken.stat().st_size // 2])
    rc = main(["ortho", *map(str, images), "--out-dir", str(tmp_path / "block"), *_common()])
    captured = capsys.readouterr()
    assert rc == 1
    assert f"{broken} failed" in captured.err and "1 of 3 images failed" in captured.err
    assert [line.split(":")[0] for line in captured.out.splitlines()] == [
        f"wrote {tmp_path / 'block' / (image.stem + '_ortho.tif')}" for image in (images[0], images[2])
    ]
    assert sorted(p.name for p in (tmp_path / "block").iterdir()) == sorted(
        f"{image.stem}_ortho.tif" for image in (images[0], images[2])
    )  # no temporary left, nothing of the broken image
    singles = _singles([images[0], images[2]], tmp_path / "single")
    for image in (images[0], images[2]):
        assert filecmp.cmp(tmp_path / "block" / f"{image.stem}_ortho.tif", singles[image.stem], shallow=False)


def test_ctrl_c_while_two_images_are_in_flight_leaves_no_file(images, tmp_path, capsys, monkeypatch):
    import photax.rectification._files as files

    real, calls = files._resample_tile, []

    def interrupted(*args, **kwargs):  # Ctrl-C in the second image's tiles
        calls.append(1)
        if len(calls) >= 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(files, "_resample_tile", interrupted)
    assert main(["ortho", *map(str, images), "--out-dir", str(tmp_path / "block"), *_common()]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert not (tmp_path / "block").exists() or not any((tmp_path / "block").iterdir())  # no ortho, no .part


def test_each_images_write_is_checked_against_every_input_of_the_command(images, tmp_path, monkeypatch):
    # The images run on threads: the record of the command's inputs (a context variable) goes with
    # them, so each output's last check (in atomic_path, on that thread) still sees every input read.
    import photax.io.atomic as atomic
    from photax.io.files import inputs_read

    real, seen = atomic.check_output_path, []

    def check(out, inputs=()):
        seen.append({pathlib.Path(p).absolute() for p in (*inputs, *inputs_read()) if p is not None})
        return real(out, inputs)

    monkeypatch.setattr(atomic, "check_output_path", check)
    assert main(["ortho", *map(str, images), "--out-dir", str(tmp_path / "block"), *_common()]) == 0
    read = {p.absolute() for p in (*images, NGI / "dem.tif", IO / "ngi_int_param.yaml", IO / "ngi_xyz_opk.csv")}
    assert len(seen) == 2 * len(images)  # before any work, then at each write
    assert all(read <= s for s in seen), [read - s for s in seen]


def test_block_usage_errors_exit_2(images, tmp_path, capsys):
    assert main(["ortho", *map(str, images[:2]), "-o", str(tmp_path / "x.tif"), *_common()]) == 2
    assert "--out-dir" in capsys.readouterr().err
    twin = tmp_path / "twin"
    twin.mkdir()
    shutil.copy(images[0], twin / images[0].name)
    assert (
        main(["ortho", str(images[0]), str(twin / images[0].name), "--out-dir", str(tmp_path / "o"), *_common()]) == 2
    )
    assert "same name" in capsys.readouterr().err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())
