"""Results as JSON: estimates, precision and residuals in a file any tool reads."""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import numpy as np

from .atomic import atomic_write
from .files import load_json, read_text


def to_jsonable(obj):
    """``obj`` as plain JSON types.

    Objects with ``.to_dict()`` use it; dataclasses (and equinox modules) become
    dicts of their fields; numpy/JAX arrays become (nested) lists; paths
    become strings.  Non-finite floats become ``null``: JSON has no NaN, and a
    NaN written as ``NaN`` is unreadable by strict parsers.
    """
    if hasattr(obj, "to_dict") and callable(obj.to_dict):
        return to_jsonable(obj.to_dict())
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, (str, bool)) or obj is None:
        return obj
    if isinstance(obj, pathlib.PurePath):
        return str(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if hasattr(obj, "__array__"):  # numpy and JAX arrays
        arr = np.asarray(obj)
        return to_jsonable(arr.item() if arr.ndim == 0 else arr.tolist())
    raise TypeError(f"cannot write a {type(obj).__name__} as JSON")


def write_json(obj, path, *, inputs=()) -> pathlib.Path:
    """Write ``obj`` (a dict, or anything with ``.to_dict()``) as JSON, atomically.

    Args:
        obj: the result; converted with :func:`to_jsonable`.
        path: output file.
        inputs: the files this run read; ``path`` may not be one of them.

    Returns:
        the path written.

    Examples:
        Results as JSON (NumPy and JAX arrays become lists), read back by :func:`read_json`:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> path = ptx.write_json({"sigma0": np.float64(1.25), "xyz": np.array([1.0, 2.0])}, pathlib.Path(tempfile.mkdtemp()) / "r.json")
        >>> ptx.read_json(path)
        {'sigma0': 1.25, 'xyz': [1.0, 2.0]}
    """
    text = json.dumps(to_jsonable(obj), indent=2, allow_nan=False) + "\n"
    data = text.encode("utf-8")  # its size known: refused at once when the disk cannot hold it
    with atomic_write(path, "wb", inputs=inputs, size=len(data)) as fh:
        fh.write(data)
    return pathlib.Path(path)


def read_json(path):
    """Read a JSON file as photax writes it: strict JSON (no ``NaN``/``Infinity``,
    which :func:`write_json` writes as ``null``), no duplicate keys.

    Raises:
        ValueError: naming the file (and line, for a syntax error); a folder
            or an unreadable file is a ValueError naming the path too.
        FileNotFoundError: no such file.

    Examples:
        The inverse of :func:`write_json`:

        >>> import pathlib, tempfile
        >>> import photax as ptx
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "r.json"
        >>> _ = path.write_text('{"images": {"IMG_1": {"sigma0": 0.9}}}')
        >>> ptx.read_json(path)["images"]["IMG_1"]["sigma0"]
        0.9
    """
    path = pathlib.Path(path)
    return load_json(path, read_text(path, "JSON file"))
