"""Reading and writing photogrammetric files; one module per format.

Every reader keeps one contract: it returns a sane result (finite numbers,
positive focal lengths, pixel and image sizes, unique names where names must
be unique) or raises ``ValueError("<file>, line <n>: <what is wrong>")``
(``"<file>: ..."`` where no line applies, e.g. a missing key in JSON); a
folder, a FIFO or device, a file over its size limit or an unreadable file is
a ``ValueError`` naming the path, a missing file a ``FileNotFoundError``; no
content of a file that is not of the reader's format is quoted.  The shared pieces (opening, decoding, strict
YAML/JSON with key lines) are in :mod:`photax.io._files`;
``tests/test_fuzz_readers.py`` holds every reader to the contract.
"""

# Public names -> their module, imported on first use (PEP 562): reading an
# orientation file must not import the bundle adjustment (``bal`` and
# ``block`` need it) nor rasterio.  The TYPE_CHECKING block names the same
# things for type checkers.
import importlib
from typing import TYPE_CHECKING

_LAZY = {
    **dict.fromkeys(("atomic_path", "atomic_write"), ".atomic"),
    **dict.fromkeys(("BALData", "read_bal", "read_bal_arrays", "write_bal"), ".bal"),
    **dict.fromkeys(("read_block", "write_block"), ".block"),
    **dict.fromkeys(("read_camera", "write_camera"), ".camera_file"),
    **dict.fromkeys(("GCPTable", "read_gcps", "write_gcps"), ".gcp"),
    **dict.fromkeys(("read_orthority_crs", "read_orthority_exterior", "read_orthority_interior"), ".orthority"),
    **dict.fromkeys(("read_camera_unit", "read_exterior", "read_interior"), ".orientation"),
    **dict.fromkeys(("read_dem", "read_geotiff", "write_geotiff"), ".raster"),
    **dict.fromkeys(("read_json", "write_json"), ".results"),
}
__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name], __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:
    from .atomic import atomic_path as atomic_path, atomic_write as atomic_write
    from .bal import BALData as BALData, read_bal as read_bal, read_bal_arrays as read_bal_arrays, write_bal as write_bal
    from .block import read_block as read_block, write_block as write_block
    from .camera_file import read_camera as read_camera, write_camera as write_camera
    from .gcp import GCPTable as GCPTable, read_gcps as read_gcps, write_gcps as write_gcps
    from .orthority import (
        read_orthority_crs as read_orthority_crs,
        read_orthority_exterior as read_orthority_exterior,
        read_orthority_interior as read_orthority_interior,
    )
    from .orientation import (
        read_camera_unit as read_camera_unit,
        read_exterior as read_exterior,
        read_interior as read_interior,
    )
    from .raster import read_dem as read_dem, read_geotiff as read_geotiff, write_geotiff as write_geotiff
    from .results import read_json as read_json, write_json as write_json
