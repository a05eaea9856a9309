"""Safe writing: no partial file on failure, never over an input."""

from __future__ import annotations

import contextlib
import os
import pathlib
import tempfile
from typing import IO, Iterable, Iterator


def _same_file(a: pathlib.Path, b: pathlib.Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_output_path(out, inputs: Iterable = ()) -> pathlib.Path:
    """Refuse an output path that is one of the inputs; return it as a Path."""
    out = pathlib.Path(out)
    for src in inputs:
        if src is not None and (_same_file(out, pathlib.Path(src)) or out.resolve() == pathlib.Path(src).resolve()):
            raise ValueError(f"refusing to write {out}: it is an input of this run")
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
