"""Point lists in image or film coordinates: ``name,a,b`` CSVs and the approximate positions
``photax measure`` and ``photax fiducials`` start from.

* :func:`read_named_points`: ``name,<a>,<b>`` rows under a header naming the columns
  (fiducial marks ``name,x,y`` in film mm, approximate positions ``name,col,row``);
* :func:`read_pixel_points`: a GCP file (:func:`photax.io.read_gcps`, its pixels) or a plain
  ``name,col,row`` CSV.

The readers' contract holds (:mod:`photax.io`): a malformed file is a ``ValueError`` naming
the file (and line where one applies).
"""

from __future__ import annotations

import csv
import math
import pathlib

import numpy as np

from .files import excerpt, file_error, read_text, split_lines
from .gcp import read_gcps


def read_named_points(path, columns: tuple[str, str], what: str) -> tuple[list[str], np.ndarray]:
    """``name,a,b`` rows of a CSV with a header naming those columns (file and line in errors).

    Examples:
        A ``name,x,y`` list (fiducial marks in mm, say):

        >>> import pathlib, tempfile
        >>> from photax.io import read_named_points
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "fiducials.csv"
        >>> _ = path.write_text("name,x,y\\nF1,-106.0,-106.0\\nF2,106.0,106.0\\n")
        >>> names, xy = read_named_points(path, ("x", "y"), "fiducial")
        >>> names, xy.tolist()
        (['F1', 'F2'], [[-106.0, -106.0], [106.0, 106.0]])
    """
    rows = []
    for k, line in enumerate(split_lines(read_text(path, what)), start=1):
        try:
            r = next(csv.reader([line]), [])
        except csv.Error as exc:
            raise file_error(path, k, f"not a CSV line ({exc})") from None
        if r and any(c.strip() for c in r):
            rows.append((k, r))
    if not rows:
        raise file_error(path, None, f"empty {what}")
    head = [c.strip().lower() for c in rows[0][1]]
    want = ("name", *columns)
    if not all(c in head for c in want):
        got = excerpt(", ".join(head), 80) if set(head) & set(want) else "none of them"  # else some other file
        raise file_error(path, rows[0][0], f"expected a header with the columns {', '.join(want)}, got {got}")
    idx = [head.index(c) for c in want]
    names, vals = [], []
    for k, r in rows[1:]:
        try:
            names.append(r[idx[0]].strip())
            vals.append([float(r[idx[1]]), float(r[idx[2]])])
            if not (math.isfinite(vals[-1][0]) and math.isfinite(vals[-1][1])):
                raise ValueError
        except (ValueError, IndexError):
            raise file_error(
                path, k, f"expected name,{columns[0]},{columns[1]} with finite numbers, got {','.join(r)}"
            ) from None
    if not names:
        raise file_error(path, None, f"no points in the {what}")
    if len(set(names)) != len(names):
        raise file_error(path, None, "duplicated mark names")
    return names, np.asarray(vals, dtype=float)


def read_pixel_points(path, image_name: str | None = None):
    """``(names, approx (n, 2), table)`` from a GCP file or a ``name,col,row`` CSV
    (``table`` is the GCP table, or None for a plain list).

    Examples:
        Approximate image positions as ``name,col,row`` (or any GCP file):

        >>> import pathlib, tempfile
        >>> from photax.io import read_pixel_points
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "approx.csv"
        >>> _ = path.write_text("name,col,row\\nT1,100.5,200.0\\nT2,310.0,45.25\\n")
        >>> names, xy, table = read_pixel_points(path)
        >>> names.tolist(), xy.tolist(), table is None
        (['T1', 'T2'], [[100.5, 200.0], [310.0, 45.25]], True)
    """
    path = pathlib.Path(path)
    lines = [
        (i + 1, s)
        for i, s in enumerate(split_lines(read_text(path, "point file")))
        if s.strip() and not s.lstrip().startswith("#")
    ]
    if not lines:
        raise ValueError(f"{path}: no points")
    header = [h.strip().lower() for h in next(csv.reader([lines[0][1]]))]
    if header in (["name", "col", "row"], ["name", "column", "row"]):
        names, xy = [], []
        for line, text in lines[1:]:
            f = [s.strip() for s in next(csv.reader([text]))]
            if len(f) != 3:
                raise ValueError(f"{path}, line {line}: expected 3 columns name,col,row, got {len(f)}")
            try:
                c, r = float(f[1]), float(f[2])
            except ValueError:
                got = f"{excerpt(f[1])}, {excerpt(f[2])}"
                raise ValueError(f"{path}, line {line}: col and row must be numbers, got {got}") from None
            if not (math.isfinite(c) and math.isfinite(r)):
                raise ValueError(f"{path}, line {line}: col and row must be finite")
            names.append(f[0] or f"p{len(names) + 1}")
            xy.append((c, r))
        if not names:
            raise ValueError(f"{path}: no points")
        return np.asarray(names), np.asarray(xy, dtype=float), None
    table = read_gcps(path, format="csv")
    if table.pixel is None:
        raise ValueError(f"{path}: the GCPs give image-plane x, y; measuring needs approximate pixels (col, row)")
    if image_name is not None:
        table = table.select(image_name)
    elif len(table.image_names) > 1:
        raise ValueError(f"{path}: points of several images {table.image_names}; choose one with --image-name")
    return table.names, table.pixel, table
