"""Output sizes checked before any work: an in-memory result against the memory available, a file
against the free space of its disk (photax's writers: rectification files, ``to_raster``)."""

from __future__ import annotations

import os
import pathlib
import shutil

import numpy as np


def _human(nbytes: float) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB", "PB"):
        if nbytes < 1000 or unit == "PB":
            return f"{nbytes:.3g} {unit}"
        nbytes /= 1000
    return ""  # unreachable


def _available_memory() -> int:
    """Bytes of memory available to a new allocation (``MemAvailable``; the physical memory elsewhere)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def check_output_size(shape, bands: int, dtype, *, path=None, hint=None) -> None:
    """Refuse, before any work, an output that cannot fit: ``rows x cols x bands`` of ``dtype`` in the
    memory available (``path`` None: an in-memory result) or, uncompressed, on the disk holding ``path``.
    ``hint()`` (called only on failure) adds a sentence, e.g. the resolution the image supports."""
    rows, cols = (int(n) for n in shape)
    pixels = rows * cols
    nbytes = pixels * int(bands) * np.dtype(dtype).itemsize
    if path is None:
        room, where, fix = _available_memory(), "of memory available", (
            "; a file output (rectify_file / orthorectify_file, streamed tile by tile) needs only disk space")
    else:
        folder = pathlib.Path(path).resolve().parent
        room, fix = shutil.disk_usage(folder).free, ""
        where = f"free on the disk of {folder} (uncompressed size)"
    if nbytes > room:
        more = f"; {hint()}" if hint is not None else ""
        raise ValueError(f"the output grid of {rows:,} x {cols:,} = {pixels:,} pixels x {bands} band(s) "
                         f"needs "
                         f"{_human(nbytes)}, more than the {_human(room)} {where}{fix}{more}")
