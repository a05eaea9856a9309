"""Checks of values read from files or passed to constructors, below every stage (the models use them
as the readers do): :func:`excerpt` quotes a value in an error message, :func:`as_numbers` takes
numbers (nested lists, numpy arrays, numeric text) and nothing else.

Private utility module: io.files re-exports both for the readers."""

from __future__ import annotations

import numpy as np


def excerpt(value, n: int = 40) -> str:
    """A short printable quotation of ``value`` for an error message: ``repr``
    of its text with control and other unprintable characters escaped, cut
    after ``n`` characters (``'abc…'``).  Quote file content only through this,
    and only from a file that is of the expected format."""
    if not isinstance(value, str):  # a number, a list: its repr (which escapes what it quotes), cut
        text = repr(value)
        return text if len(text) <= n else text[:n] + "…"
    body = repr(value[:n])
    return body if len(value) <= n else body[:-1] + "…" + body[-1]


def as_numbers(value):
    """``value`` (a number or nested lists of numbers) as float64, or None if
    it is not one.  Text that reads as a number counts (PyYAML follows YAML
    1.1, where ``1e-5`` without a dot is a string); booleans and nulls do not
    (``true`` is not 1)."""

    def conv(v):
        if isinstance(v, (list, tuple)):
            return [conv(x) for x in v]
        if isinstance(v, np.ndarray) and v.dtype.kind in "fiu":  # numbers already (an API caller's)
            return v.astype(float)
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, str, np.integer, np.floating)):
            raise TypeError
        return float(v) if isinstance(v, str) else v

    try:
        return np.asarray(conv(value), dtype=float)
    except (TypeError, ValueError, OverflowError, RecursionError):
        return None
