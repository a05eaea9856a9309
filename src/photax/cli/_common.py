"""Helpers shared by the subcommands: input checks, units, plurals."""

from __future__ import annotations

import os
import pathlib

# Choices of --convention and --resampling, written out here so that building
# the parser (``photax --help``) imports neither JAX nor numpy; they must equal
# photax.rotation.CONVENTIONS and photax.resampling.RESAMPLING (a test checks).
CONVENTIONS = ("phi-omega-kappa", "omega-phi-kappa")
RESAMPLING = ("nearest", "bilinear", "cubic", "lanczos", "lanczos4", "bspline")


def input_file(path, what: str) -> pathlib.Path:
    """``path`` as a Path after checking it is a readable file.

    Raises:
        ValueError: one line naming ``what`` (e.g. "GCP file") and the path:
            missing, a folder where a file is expected, or not readable.
    """
    p = pathlib.Path(path)
    if not p.exists():
        raise ValueError(f"{what} {p}: no such file")
    if p.is_dir():
        raise ValueError(f"{what} {p}: is a folder, expected a file")
    try:
        with open(p, "rb"):
            pass
    except PermissionError:
        raise ValueError(f"{what} {p}: permission denied (cannot read it)") from None
    except OSError as exc:
        raise ValueError(f"{what} {p}: cannot read it ({exc.strerror or exc})") from None
    return p


def input_folder(path, what: str) -> pathlib.Path:
    """``path`` as a Path after checking it is a readable folder."""
    p = pathlib.Path(path)
    if not p.exists():
        raise ValueError(f"{what} {p}: no such folder")
    if not p.is_dir():
        raise ValueError(f"{what} {p}: is a file, expected a folder")
    if not os.access(p, os.R_OK | os.X_OK):
        raise ValueError(f"{what} {p}: permission denied (cannot read it)")
    return p


def plural(n: int, word: str, words: str | None = None) -> str:
    """``"1 camera"``, ``"2 cameras"``, ``"0 cameras"``."""
    return f"{n} {word if n == 1 else (words or word + 's')}"


def ground_unit(crs, default: str = "ground units") -> str:
    """The CRS's unit symbol (``"m"``, ``"ft"``...) or ``default`` when unknown."""
    from ..io.raster import crs_unit

    return crs_unit(crs) or default
