"""``rasterio.open`` for reading, without rasterio's NotGeoreferencedWarning, under one lock.

``warnings.catch_warnings`` swaps the process-wide filters: two threads (Dask workers reading
windows) interleaving it could restore each other's filters mid-open, so every quiet open of
photax goes through the one lock here.  The raster readers (photax.io) and the output grid's
``Grid.like`` (a lower stage than the readers) both use it.

Private utility module: other photax units import its names directly
(``tests/test_imports.py`` lists the modules allowed that).
"""

from __future__ import annotations

import threading
import warnings

_LOCK = threading.Lock()


def open_quietly(path):
    """``rasterio.open(path)``: an image without georeference (a raw photo) opens without
    NotGeoreferencedWarning.  rasterio's own errors are the caller's to translate."""
    import rasterio

    with _LOCK, warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        return rasterio.open(path)
