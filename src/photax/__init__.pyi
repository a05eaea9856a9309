"""photax's public names: the one list (read by photax._lazy at import time, and by type checkers)."""

from . import fusion as fusion
from . import measure as measure
from . import stereo as stereo
from .bundle import (
    BundleProblem as BundleProblem,
)
from .bundle import (
    BundleResult as BundleResult,
)
from .bundle import (
    bundle_adjust as bundle_adjust,
)
from .bundle import (
    initialize_block as initialize_block,
)
from .camera import FrameCamera as FrameCamera
from .collinearity import (
    ExteriorOrientation as ExteriorOrientation,
)
from .collinearity import (
    depth as depth,
)
from .collinearity import (
    image_to_ground as image_to_ground,
)
from .collinearity import (
    look_at as look_at,
)
from .collinearity import (
    project as project,
)
from .compare import ModelComparison as ModelComparison
from .compare import compare_models as compare_models
from .dem import DEM as DEM
from .earth import ImageCorrections as ImageCorrections
from .earth import LocalFrame as LocalFrame
from .earth import correct_image as correct_image
from .earth import refraction_coefficient as refraction_coefficient
from .errors import RESULTS as RESULTS
from .errors import ConvergenceError as ConvergenceError
from .errors import CRSMismatchError as CRSMismatchError
from .errors import DegenerateGeometryError as DegenerateGeometryError
from .errors import MalformedFileError as MalformedFileError
from .errors import NoEntryError as NoEntryError
from .errors import NotConvergedError as NotConvergedError
from .errors import OutputCRSError as OutputCRSError
from .errors import OutsideValidityError as OutsideValidityError
from .errors import PartialDEMWarning as PartialDEMWarning
from .errors import PhotaxError as PhotaxError
from .errors import UnreadableFileError as UnreadableFileError
from .errors import UnsupportedFormatError as UnsupportedFormatError
from .fusion import pansharpen as pansharpen
from .fusion import pansharpen_dask as pansharpen_dask
from .geo import utm_crs as utm_crs
from .grid import Grid as Grid
from .grid import GridSpec as GridSpec
from .grid import dem_coverage as dem_coverage
from .interior import (
    InteriorOrientation as InteriorOrientation,
)
from .interior import (
    ScannedCamera as ScannedCamera,
)
from .interior import (
    find_fiducials as find_fiducials,
)
from .interior import (
    interior_orientation as interior_orientation,
)
from .intersection import intersect as intersect
from .io import (
    read_bal as read_bal,
)
from .io import (
    read_camera as read_camera,
)
from .io import (
    read_dem as read_dem,
)
from .io import (
    read_gcps as read_gcps,
)
from .io import (
    read_geotiff as read_geotiff,
)
from .io import (
    read_json as read_json,
)
from .io import (
    write_bal as write_bal,
)
from .io import (
    write_camera as write_camera,
)
from .io import (
    write_geotiff as write_geotiff,
)
from .io import (
    write_json as write_json,
)
from .io.lazy import to_raster as to_raster
from .io.satellite import read_rpc as read_rpc
from .io.satellite import read_sensor as read_sensor
from .io.satellite import rpc_format as rpc_format
from .io.satellite import write_rpc as write_rpc
from .matching import AffineEpipolarPair as AffineEpipolarPair
from .matching import CoRegistration as CoRegistration
from .matching import (
    EpipolarPair as EpipolarPair,
)
from .matching import (
    Registration as Registration,
)
from .matching import (
    TiePoints as TiePoints,
)
from .matching import (
    Transfer as Transfer,
)
from .matching import coregister as coregister
from .matching import disparity as disparity
from .matching import disparity_range_from_ties as disparity_range_from_ties
from .matching import (
    epipolar_pair as epipolar_pair,
)
from .matching import (
    match_ties as match_ties,
)
from .matching import phase_correlation as phase_correlation
from .matching import (
    register_to_ortho as register_to_ortho,
)
from .matching import (
    transfer_points as transfer_points,
)
from .morphing import morph as morph
from .morphing import morph_sequence as morph_sequence
from .morphing import write_sequence as write_sequence
from .mosaicking import mosaic as mosaic
from .mosaicking import mosaic_to_raster as mosaic_to_raster
from .polynomial import (
    PiecewiseAffineModel as PiecewiseAffineModel,
)
from .polynomial import (
    PolynomialModel as PolynomialModel,
)
from .polynomial import (
    ProjectiveModel as ProjectiveModel,
)
from .polynomial import (
    TPSModel as TPSModel,
)
from .polynomial import (
    fit_piecewise_affine as fit_piecewise_affine,
)
from .polynomial import (
    fit_polynomial as fit_polynomial,
)
from .polynomial import (
    fit_projective as fit_projective,
)
from .polynomial import (
    fit_tps as fit_tps,
)
from .pushbroom import PushbroomCamera as PushbroomCamera
from .pushbroom import PushbroomResection as PushbroomResection
from .pushbroom import RPCFit as RPCFit
from .pushbroom import fit_rpc as fit_rpc
from .pushbroom import resect_pushbroom as resect_pushbroom
from .rectification import (
    occlusion_mask as occlusion_mask,
)
from .rectification import (
    orthorectify as orthorectify,
)
from .rectification import (
    orthorectify_dask as orthorectify_dask,
)
from .rectification import (
    orthorectify_file as orthorectify_file,
)
from .rectification import (
    orthorectify_files as orthorectify_files,
)
from .rectification import (
    rectify as rectify,
)
from .rectification import (
    rectify_file as rectify_file,
)
from .rectification import (
    true_ortho as true_ortho,
)
from .resampling import Resampling as Resampling
from .resampling import resample as resample
from .resection import ResectionResult as ResectionResult
from .resection import resect as resect
from .resection import resect_batch as resect_batch
from .rotation import (
    angles_from_matrix as angles_from_matrix,
)
from .rotation import (
    axis_angle_to_matrix as axis_angle_to_matrix,
)
from .rotation import (
    convert_angles as convert_angles,
)
from .rotation import (
    matrix_to_axis_angle as matrix_to_axis_angle,
)
from .rotation import (
    rotation_matrix as rotation_matrix,
)
from .rpc import RPCCamera as RPCCamera
from .rpc import RPCRefinement as RPCRefinement
from .rpc import refine_rpc as refine_rpc
from .scene import PushbroomScene as PushbroomScene
from .scene import Scene as Scene
from .scene import pushbroom_scene as pushbroom_scene
from .scene import relief_scene as relief_scene
from .sensor import FrameSensor as FrameSensor
from .sensor import GroundCamera as GroundCamera
from .sensor import GroundSensor as GroundSensor
from .sensor import Sensor as Sensor
from .sensor import Validity as Validity
from .uncertainty import OrthoUncertainty as OrthoUncertainty
from .uncertainty import ortho_uncertainty as ortho_uncertainty

__version__: str
from .georeferencing import Georeferenced as Georeferenced
from .georeferencing import Similarity as Similarity
from .georeferencing import georeference as georeference
from .georeferencing import similarity_transform as similarity_transform
from .io import read_pushbroom as read_pushbroom
from .io import write_pushbroom as write_pushbroom
from .rpc_block import RPCBlock as RPCBlock
from .rpc_block import adjust_rpc_block as adjust_rpc_block
