"""photax: photogrammetry on JAX.

Importing photax turns on JAX's 64-bit mode: ground coordinates are large
(UTM ~1e6 m) and image measurements fine (0.1 px), so photax computes in
float64.  See ``docs/conventions.md`` for every frame, angle and unit.
"""

import importlib.metadata

import jax

jax.config.update("jax_enable_x64", True)

from .bundle import (
    BundleProblem as BundleProblem,
    BundleResult as BundleResult,
    bundle_adjust as bundle_adjust,
    initialize_block as initialize_block,
)
from .camera import FrameCamera as FrameCamera
from .compare import ModelComparison as ModelComparison, compare_models as compare_models
from .collinearity import (
    ExteriorOrientation as ExteriorOrientation,
    depth as depth,
    image_to_ground as image_to_ground,
    look_at as look_at,
    project as project,
)
from .dem import DEM as DEM
from .errors import RESULTS as RESULTS, ConvergenceError as ConvergenceError
from .intersection import intersect as intersect
from .io import (
    read_bal as read_bal,
    read_camera as read_camera,
    read_gcps as read_gcps,
    read_json as read_json,
    write_bal as write_bal,
    write_camera as write_camera,
    write_json as write_json,
)
from . import measure as measure
from .polynomial import (
    PolynomialModel as PolynomialModel,
    ProjectiveModel as ProjectiveModel,
    fit_polynomial as fit_polynomial,
    fit_projective as fit_projective,
)
from .resampling import Resampling as Resampling, resample as resample
from .rectification import (
    Grid as Grid,
    orthorectify as orthorectify,
    orthorectify_file as orthorectify_file,
    rectify as rectify,
    rectify_file as rectify_file,
)
from .resection import (
    ResectionResult as ResectionResult,
    resect as resect,
    resect_batch as resect_batch,
)
from .scene import Scene as Scene, relief_scene as relief_scene
# Dask/xarray/rioxarray (the optional dask extra) are imported inside these functions only.
from .mosaic import mosaic as mosaic
from .tiled import orthorectify_dask as orthorectify_dask, to_raster as to_raster
from .uncertainty import OrthoUncertainty as OrthoUncertainty, ortho_uncertainty as ortho_uncertainty
from .rotation import (
    angles_from_matrix as angles_from_matrix,
    axis_angle_to_matrix as axis_angle_to_matrix,
    convert_angles as convert_angles,
    matrix_to_axis_angle as matrix_to_axis_angle,
    rotation_matrix as rotation_matrix,
)

__version__ = importlib.metadata.version("photax")
