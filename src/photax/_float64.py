"""Float64 at the public entry points: coordinates that arrive as float32.

Private utility module: other photax units import its names directly
(``tests/test_imports.py`` lists the modules allowed that).

photax computes in float64 (``import photax`` turns on JAX's 64-bit mode).
Input that is already float32 -- a float32 numpy array, or a jax array made
before ``import photax``, when JAX still defaults to float32 -- is converted
to float64, but the digits it lost cannot come back: a UTM northing of
4.1e6 m is held to 0.25 m in float32 (24-bit mantissa), which moved a
resected camera centre by 6.5 cm in issue 27 (the same result as float64
arithmetic on the rounded values: the computation was float64 throughout;
the input was coarse).  :func:`as_float64` converts, and warns when the
rounding is coarse against the values' own spread (coarser than a
millionth of it, per column): image coordinates in mm or local ground
coordinates in float32 pass silently, world coordinates do not.
"""

from __future__ import annotations

import warnings

import numpy as np

_RELATIVE = 1e-6  # float32 spacing above this share of a column's spread: the rounding matters


class PrecisionWarning(UserWarning):
    """Coordinates were given in a floating type too coarse for their magnitude."""


def as_float64(value, name: str, *, resolution: float | None = None) -> np.ndarray:
    """``value`` as a float64 numpy array, with a :class:`PrecisionWarning`
    naming ``name`` when it came in a narrower float whose rounding is
    coarse for its values: coarser than a millionth of a column's spread
    (module docstring), or than ``resolution`` (in the values' unit) when
    given -- for a single position, which has no spread."""
    a = np.asarray(value)
    if a.dtype.kind == "f" and a.dtype.itemsize < 8 and a.size:
        cols = a.reshape(-1, a.shape[-1]) if a.ndim >= 2 else a.reshape(-1, 1)
        for k in range(cols.shape[1]):
            c = cols[:, k][np.isfinite(cols[:, k])]
            if not c.size:
                continue
            big, spread = np.abs(c).max(), float(c.max()) - float(c.min())
            step = float(np.spacing(big.astype(a.dtype)))
            limit = resolution if resolution is not None else _RELATIVE * max(spread, float(np.finfo(a.dtype).tiny))
            if step > limit:
                against = f"{resolution:.2g}" if resolution is not None else f"their spread of {spread:.3g}"
                warnings.warn(
                    f"{name} is {a.dtype}: values of magnitude {float(big):.3g} are held to {step:.2g}"
                    + (f" (column {k})" if a.ndim >= 2 else "")
                    + f", coarse for {against}; photax computes "
                    "in float64 but cannot restore the lost digits: pass float64 (numpy's default; jax "
                    "arrays made before `import photax` are float32)",
                    PrecisionWarning,
                    stacklevel=3,
                )
                break
    return np.asarray(a, dtype=np.float64)
