"""photax: photogrammetry on JAX.

Importing photax turns on JAX's 64-bit mode: ground coordinates are large
(UTM ~1e6 m) and image measurements fine (0.1 px), so photax computes in
float64.  See ``docs/conventions.md`` for every frame, angle and unit.

The public names are listed once, in ``__init__.pyi`` (what type checkers
read); :mod:`photax._lazy` imports each on first use (PEP 562 module
``__getattr__``): ``import photax`` itself loads neither JAX nor SciPy,
rasterio or matplotlib, so a command line (``photax --help``) or a script
that needs one function pays only for that function's modules.  When JAX
is not imported yet, 64-bit mode is requested through ``JAX_ENABLE_X64``,
which JAX reads when it is imported (child processes inherit it).
"""

import os as _os
import sys as _sys

if "jax" in _sys.modules:
    _sys.modules["jax"].config.update("jax_enable_x64", True)
else:
    _os.environ["JAX_ENABLE_X64"] = "1"  # read by jax/_src/config.py when jax is imported

from ._lazy import attach_stub as _attach_stub  # noqa: E402  (64-bit mode first)

__getattr__, __dir__, __all__ = _attach_stub(__name__, __file__)
