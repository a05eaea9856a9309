"""photax: photogrammetry on JAX.

Importing photax turns on JAX's 64-bit mode: ground coordinates are large
(UTM ~1e6 m) and image measurements fine (0.1 px), so photax computes in
float64.  See ``docs/conventions.md`` for every frame, angle and unit.

The public names below are imported on first use (PEP 562 module
``__getattr__``): ``import photax`` itself loads neither JAX nor SciPy,
rasterio or matplotlib, so a command line (``photax --help``) or a script
that needs one function pays only for that function's modules.  When JAX
is not imported yet, 64-bit mode is requested through ``JAX_ENABLE_X64``,
which JAX reads when it is imported (child processes inherit it).
"""

from __future__ import annotations

import importlib
import os
import sys
from typing import TYPE_CHECKING

if "jax" in sys.modules:
    sys.modules["jax"].config.update("jax_enable_x64", True)
else:
    os.environ["JAX_ENABLE_X64"] = "1"  # read by jax/_src/config.py when jax is imported

# public name -> the module it lives in (relative to photax).  The
# TYPE_CHECKING block below names the same things for type checkers and
# IDEs; tests/test_imports.py checks the two agree and every name resolves.
_LAZY: dict[str, str] = {
    **dict.fromkeys(("BundleProblem", "BundleResult", "bundle_adjust", "initialize_block"), ".bundle"),
    "FrameCamera": ".camera",
    **dict.fromkeys(("ModelComparison", "compare_models"), ".compare"),
    **dict.fromkeys(("ExteriorOrientation", "depth", "image_to_ground", "look_at", "project"), ".collinearity"),
    "DEM": ".dem",
    **dict.fromkeys(("EpipolarPair", "epipolar_pair"), ".matching"),
    **dict.fromkeys(("InteriorOrientation", "ScannedCamera", "find_fiducials", "interior_orientation"), ".interior"),
    **dict.fromkeys(("Registration", "register_to_ortho"), ".matching"),
    **dict.fromkeys(("TiePoints", "match_ties"), ".matching"),
    **dict.fromkeys(("Transfer", "transfer_points"), ".matching"),
    **dict.fromkeys(("RESULTS", "ConvergenceError"), ".errors"),
    "intersect": ".intersection",
    # Dask/xarray/rioxarray (the optional dask extra) are imported inside these modules' functions only.
    "mosaic": ".mosaicking",
    "orthorectify_dask": ".rectification",
    "to_raster": ".io.lazy",
    **dict.fromkeys(("OrthoUncertainty", "ortho_uncertainty"), ".uncertainty"),
    **dict.fromkeys(("read_bal", "read_camera", "read_gcps", "read_json", "write_bal", "write_camera",
                     "write_json"), ".io"),
    **dict.fromkeys(("PolynomialModel", "ProjectiveModel", "fit_polynomial", "fit_projective"), ".polynomial"),
    **dict.fromkeys(("Resampling", "resample"), ".resampling"),
    **dict.fromkeys(("orthorectify", "orthorectify_file", "rectify", "rectify_file"), ".rectification"),
    "Grid": ".grid",
    **dict.fromkeys(("ResectionResult", "resect", "resect_batch"), ".resection"),
    **dict.fromkeys(("Scene", "relief_scene"), ".scene"),
    **dict.fromkeys(("angles_from_matrix", "axis_angle_to_matrix", "convert_angles", "matrix_to_axis_angle",
                     "rotation_matrix"), ".rotation"),
}
# Submodules reachable as attributes (``photax.measure.find_targets``)
# without importing them first, as the eager package allowed.
_SUBMODULES = frozenset({"measure"})

__all__ = sorted([*_LAZY, *_SUBMODULES, "__version__"])


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
    elif name in _SUBMODULES:
        value = importlib.import_module(f".{name}", __name__)
    elif name == "__version__":
        from importlib.metadata import version

        value = version("photax")
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # the same names, eagerly, for type checkers (never run)
    from . import measure as measure
    from .bundle import (
        BundleProblem as BundleProblem,
        BundleResult as BundleResult,
        bundle_adjust as bundle_adjust,
        initialize_block as initialize_block,
    )
    from .camera import FrameCamera as FrameCamera
    from .collinearity import (
        ExteriorOrientation as ExteriorOrientation,
        depth as depth,
        image_to_ground as image_to_ground,
        look_at as look_at,
        project as project,
    )
    from .compare import (
        ModelComparison as ModelComparison,
        compare_models as compare_models,
    )
    from .dem import DEM as DEM
    from .matching import EpipolarPair as EpipolarPair, epipolar_pair as epipolar_pair
    from .interior import (
        InteriorOrientation as InteriorOrientation,
        ScannedCamera as ScannedCamera,
        find_fiducials as find_fiducials,
        interior_orientation as interior_orientation,
    )
    from .errors import (
        RESULTS as RESULTS,
        ConvergenceError as ConvergenceError,
    )
    from .intersection import intersect as intersect
    from .mosaicking import mosaic as mosaic
    from .io.lazy import to_raster as to_raster
    from .rectification import orthorectify_dask as orthorectify_dask
    from .uncertainty import OrthoUncertainty as OrthoUncertainty, ortho_uncertainty as ortho_uncertainty
    from .io import (
        read_bal as read_bal,
        read_camera as read_camera,
        read_gcps as read_gcps,
        read_json as read_json,
        write_bal as write_bal,
        write_camera as write_camera,
        write_json as write_json,
    )
    from .matching import Registration as Registration, register_to_ortho as register_to_ortho
    from .matching import TiePoints as TiePoints, match_ties as match_ties
    from .matching import Transfer as Transfer, transfer_points as transfer_points
    from .polynomial import (
        PolynomialModel as PolynomialModel,
        ProjectiveModel as ProjectiveModel,
        fit_polynomial as fit_polynomial,
        fit_projective as fit_projective,
    )
    from .rectification import (
        Grid as Grid,
        orthorectify as orthorectify,
        orthorectify_file as orthorectify_file,
        rectify as rectify,
        rectify_file as rectify_file,
    )
    from .resampling import (
        Resampling as Resampling,
        resample as resample,
    )
    from .resection import (
        ResectionResult as ResectionResult,
        resect as resect,
        resect_batch as resect_batch,
    )
    from .rotation import (
        angles_from_matrix as angles_from_matrix,
        axis_angle_to_matrix as axis_angle_to_matrix,
        convert_angles as convert_angles,
        matrix_to_axis_angle as matrix_to_axis_angle,
        rotation_matrix as rotation_matrix,
    )
    from .scene import (
        Scene as Scene,
        relief_scene as relief_scene,
    )
