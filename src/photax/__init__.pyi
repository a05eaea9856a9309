"""photax's public names: the one list (read by photax._lazy at import time, and by type checkers)."""

from . import fusion as fusion, measure as measure
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
from .compare import ModelComparison as ModelComparison, compare_models as compare_models
from .dem import DEM as DEM
from .errors import RESULTS as RESULTS, ConvergenceError as ConvergenceError
from .fusion import pansharpen as pansharpen
from .grid import Grid as Grid
from .interior import (
    InteriorOrientation as InteriorOrientation,
    ScannedCamera as ScannedCamera,
    find_fiducials as find_fiducials,
    interior_orientation as interior_orientation,
)
from .intersection import intersect as intersect
from .io import (
    read_bal as read_bal,
    read_camera as read_camera,
    read_dem as read_dem,
    read_gcps as read_gcps,
    read_geotiff as read_geotiff,
    read_json as read_json,
    write_bal as write_bal,
    write_camera as write_camera,
    write_geotiff as write_geotiff,
    write_json as write_json,
)
from .io.lazy import to_raster as to_raster
from .matching import (
    EpipolarPair as EpipolarPair,
    Registration as Registration,
    TiePoints as TiePoints,
    Transfer as Transfer,
    epipolar_pair as epipolar_pair,
    match_ties as match_ties,
    register_to_ortho as register_to_ortho,
    transfer_points as transfer_points,
)
from .mosaicking import mosaic as mosaic
from .polynomial import (
    PolynomialModel as PolynomialModel,
    ProjectiveModel as ProjectiveModel,
    TPSModel as TPSModel,
    fit_polynomial as fit_polynomial,
    fit_projective as fit_projective,
    fit_tps as fit_tps,
)
from .rectification import (
    orthorectify as orthorectify,
    orthorectify_dask as orthorectify_dask,
    orthorectify_file as orthorectify_file,
    orthorectify_files as orthorectify_files,
    rectify as rectify,
    rectify_file as rectify_file,
)
from .resampling import Resampling as Resampling, resample as resample
from .resection import ResectionResult as ResectionResult, resect as resect, resect_batch as resect_batch
from .rotation import (
    angles_from_matrix as angles_from_matrix,
    axis_angle_to_matrix as axis_angle_to_matrix,
    convert_angles as convert_angles,
    matrix_to_axis_angle as matrix_to_axis_angle,
    rotation_matrix as rotation_matrix,
)
from .scene import Scene as Scene, relief_scene as relief_scene
from .uncertainty import OrthoUncertainty as OrthoUncertainty, ortho_uncertainty as ortho_uncertainty

__version__: str
