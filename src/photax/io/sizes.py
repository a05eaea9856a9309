"""Output sizes checked before any work: an in-memory result against the memory available, a file
against the free space of its disk (photax's writers: rectification files, ``to_raster``)."""

from __future__ import annotations

import errno
import os
import pathlib
import shutil

import numpy as np

from .atomic import human_bytes as _human
from .atomic import not_written


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


# A compressed file is refused before the work only when even this ratio could not fit it; below that its
# size is not known, and the write itself reports a full disk (photax.io.atomic).
BEST_RATIO = 100


def check_output_size(shape, bands: int, dtype, *, path=None, hint=None, compressed: bool = False) -> None:
    """Refuse, before any work, an output that cannot fit: ``rows x cols x bands`` of ``dtype`` in the
    memory available (``path`` None: an in-memory result) or on the disk holding ``path``: uncompressed,
    or at :data:`BEST_RATIO` to 1 when ``compressed``.
    ``hint()`` (called only on failure) adds a sentence, e.g. the resolution the image supports."""
    rows, cols = (int(n) for n in shape)
    pixels = rows * cols
    nbytes = pixels * int(bands) * np.dtype(dtype).itemsize
    if path is None:
        room, where, fix = (
            _available_memory(),
            "of memory available",
            ("; a file output (rectify_file / orthorectify_file, streamed tile by tile) needs only disk space"),
        )
    else:
        folder = pathlib.Path(path).resolve().parent
        room, fix = shutil.disk_usage(folder).free, ""
        where = f"free on the disk of {folder} (" + (
            f"even at {BEST_RATIO}:1 compression)" if compressed else "uncompressed size)"
        )
    if (nbytes / BEST_RATIO if path is not None and compressed else nbytes) > room:
        more = f"; {hint()}" if hint is not None else ""
        if path is not None:  # an OSError naming the output, as every failed write (photax.io.atomic)
            raise not_written(
                pathlib.Path(path),
                errno.ENOSPC,
                f"the output grid of {rows:,} x {cols:,} = "
                f"{pixels:,} pixels x {bands} band(s) needs {_human(nbytes)}, more than the "
                f"{_human(room)} {where}{more}",
            )
        raise ValueError(
            f"the output grid of {rows:,} x {cols:,} = {pixels:,} pixels x {bands} band(s) "
            f"needs "
            f"{_human(nbytes)}, more than the {_human(room)} {where}{fix}{more}"
        )
