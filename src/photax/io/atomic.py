"""Safe writing: no partial file on failure, never over an input."""

from __future__ import annotations

import contextlib
import os
import pathlib
import tempfile
from typing import IO, Iterable, Iterator

from ._files import excerpt, inputs_read


def _same_file(a: pathlib.Path, b: pathlib.Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def sidecars(path) -> list[pathlib.Path]:
    """Files GDAL and friends read beside ``path``: they are inputs too.

    For ``dir/x.tif``: ``x.prj``, ``x.tif.aux.xml``, ``x.aux``, ``x.tif.ovr``,
    ``x.ovr``, ``x.tif.msk``, ``x.msk``, world files ``x.tfw``, ``x.tifw``,
    ``x.wld`` (for ``.jpg``: ``x.jgw``, ``x.jpgw``; ``.png``: ``x.pgw``...),
    ``x.imd``, ``x.rpb``, ``x_rpc.txt``.  Existing or not.
    """
    p = pathlib.Path(path)
    stem, name, ext = p.stem, p.name, p.suffix.lower().lstrip(".")
    names = [f"{stem}.prj", f"{name}.prj", f"{name}.aux.xml", f"{stem}.aux", f"{name}.aux",
             f"{name}.ovr", f"{stem}.ovr", f"{name}.msk", f"{stem}.msk", f"{stem}.wld", f"{name}.wld",
             f"{stem}.imd", f"{stem}.rpb", f"{stem}_rpc.txt"]
    if len(ext) >= 2:
        names += [f"{stem}.{ext[0]}{ext[-1]}w", f"{stem}.{ext}w"]
    return [p.with_name(n) for n in dict.fromkeys(names)]


def _same_place(a: pathlib.Path, b: pathlib.Path) -> bool:
    """Same file, or same folder and the same name up to case (GDAL tries .TFW and .tfw)."""
    if _same_file(a, b):
        return True
    return a.parent.resolve() == b.parent.resolve() and a.name.lower() == b.name.lower()


def check_output_path(out, inputs: Iterable = ()) -> pathlib.Path:
    """Refuse an output path that is one of the inputs; return it as a Path.

    Inputs are ``inputs`` and every file the readers opened in this command
    (:func:`photax.io._files.recording_inputs`: a block's camera files, a CSV's
    ``.prj``...), each with its sidecar files (:func:`sidecars`: ``.prj``,
    ``.aux.xml``, ``.ovr``, world files, ``.msk``...).  An existing folder
    is refused as an output file.

    Raises:
        ValueError: naming ``out`` and the input it would overwrite.
    """
    out = pathlib.Path(out)
    if out.is_dir():
        raise ValueError(f"refusing to write {out}: it is a folder")
    for src in [*inputs, *inputs_read()]:
        if src is None:
            continue
        src = pathlib.Path(src)
        if _same_file(out, src) or out.resolve() == src.resolve():
            raise ValueError(f"refusing to write {out}: it is an input of this run")
        if src.is_dir():  # a folder input lists the files it reads (e.g. a block's) as inputs too
            continue
        for side in sidecars(src):
            if _same_place(out, side):
                raise ValueError(f"refusing to write {out}: it is {side.name}, read with the input {src}")
    return out


@contextlib.contextmanager
def atomic_path(out, inputs: Iterable = ()) -> Iterator[pathlib.Path]:
    """Yield a temporary path beside ``out``; rename it onto ``out`` on success.

    On any exception the temporary file is removed and ``out`` is left as it
    was.  ``inputs`` are paths the run reads: ``out`` may not be one of them.
    """
    out = check_output_path(out, inputs)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".part", dir=out.parent)
    os.close(fd)
    # mkstemp makes the file private (0600); give it the permissions an
    # ordinary open() would have: 0666 less the umask.
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    tmp_path = pathlib.Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, out)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


@contextlib.contextmanager
def atomic_write(out, mode: str = "w", inputs: Iterable = (), **open_kwargs) -> Iterator[IO]:
    """``open()`` for writing, atomically (see :func:`atomic_path`)."""
    with atomic_path(out, inputs) as tmp, open(tmp, mode, **open_kwargs) as fh:
        yield fh


# Windows device names: a file called so (with any extension) is the device there.
_RESERVED = {"CON", "PRN", "AUX", "NUL", *(f"{p}{i}" for p in ("COM", "LPT") for i in range(1, 10))}


def output_name(name, what: str = "name") -> str:
    """``name`` (read from a file: a camera's, an image's) checked as one file
    name inside an output folder, never a path out of it.

    Raises:
        ValueError: an empty name, ``.`` or ``..``, a ``/``, ``\\``, NUL or
            other control character, leading or trailing blanks, a trailing
            dot, a Windows device name (``CON``, ``NUL``, ``COM1``...), or
            over 200 bytes.
    """
    text = str(name)
    bad = (not text.strip() or text in (".", "..") or any(c in text for c in "/\\") or text != text.strip()
           or any(ord(c) < 32 or ord(c) == 127 for c in text) or text.endswith(".")
           or text.split(".")[0].strip().upper() in _RESERVED or len(text.encode("utf-8", "replace")) > 200)
    if bad:
        raise ValueError(f"{what} {excerpt(text)} cannot be a file name (no '/', '\\', '..', control "
                         "characters, device names such as CON or NUL, or empty names); rename it")
    return text
