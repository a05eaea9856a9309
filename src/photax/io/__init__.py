"""Reading and writing photogrammetric files; one module per format.

Every reader keeps one contract: it returns a sane result (finite numbers,
positive focal lengths, pixel and image sizes, unique names where names must
be unique) or raises ``ValueError("<file>, line <n>: <what is wrong>")``
(``"<file>: ..."`` where no line applies, e.g. a missing key in JSON); a
folder, a FIFO or device, a file over its size limit or an unreadable file is
a ``ValueError`` naming the path, a missing file a ``FileNotFoundError``; no
content of a file that is not of the reader's format is quoted.  The shared pieces (opening, decoding, strict
YAML/JSON with key lines) are in :mod:`photax.io.files`;
``tests/test_fuzz_readers.py`` holds every reader to the contract.  Every
writer writes atomically what its reader reads back equal, and refuses a
value that is not finite (a ``ValueError`` naming it; never a file holding
``nan``): ``tests/test_writer_fuzz.py``.
"""

# Public names: the one list is __init__.pyi, each imported on first use (PEP 562,
# photax._lazy): reading an orientation file must not import the bundle adjustment
# (``bal`` and ``block`` need it) nor rasterio.
from .._lazy import attach_stub as _attach_stub

__getattr__, __dir__, __all__ = _attach_stub(__name__, __file__)
