"""photax.io's public names: the one list (read by photax._lazy at import time, and by type checkers)."""

from .atomic import atomic_path as atomic_path
from .atomic import atomic_write as atomic_write
from .bal import (
    BALData as BALData,
)
from .bal import (
    read_bal as read_bal,
)
from .bal import (
    read_bal_arrays as read_bal_arrays,
)
from .bal import (
    write_bal as write_bal,
)
from .block import read_block as read_block
from .block import write_block as write_block
from .camera_file import read_camera as read_camera
from .camera_file import write_camera as write_camera
from .colmap import ColmapModel as ColmapModel
from .colmap import read_colmap as read_colmap
from .colmap import read_colmap_model as read_colmap_model
from .colmap import write_colmap as write_colmap
from .colmap import write_colmap_model as write_colmap_model
from .exif import DroneTags as DroneTags
from .exif import camera_from_tags as camera_from_tags
from .exif import exterior_from_tags as exterior_from_tags
from .exif import read_drone_tags as read_drone_tags
from .exif import read_exif_exteriors as read_exif_exteriors
from .gcp import GCPTable as GCPTable
from .gcp import read_gcps as read_gcps
from .gcp import write_gcps as write_gcps
from .metashape import read_metashape_calibration as read_metashape_calibration
from .metashape import read_opk_export as read_opk_export
from .metashape import write_metashape_calibration as write_metashape_calibration
from .metashape import write_opk_export as write_opk_export
from .odm import read_odm_cameras as read_odm_cameras
from .odm import read_odm_geo as read_odm_geo
from .odm import write_odm_cameras as write_odm_cameras
from .odm import write_odm_geo as write_odm_geo
from .opensfm import camera_to_opensfm as camera_to_opensfm
from .opensfm import read_opensfm_cameras as read_opensfm_cameras
from .opensfm import read_opensfm_shots as read_opensfm_shots
from .opensfm import write_opensfm_reconstruction as write_opensfm_reconstruction
from .orientation import (
    block_images as block_images,
)
from .orientation import (
    read_camera_unit as read_camera_unit,
)
from .orientation import (
    read_exterior as read_exterior,
)
from .orientation import (
    read_exteriors as read_exteriors,
)
from .orientation import (
    read_interior as read_interior,
)
from .orthority import camera_to_orthority as camera_to_orthority
from .orthority import (
    read_orthority_crs as read_orthority_crs,
)
from .orthority import (
    read_orthority_exterior as read_orthority_exterior,
)
from .orthority import (
    read_orthority_exterior_crs as read_orthority_exterior_crs,
)
from .orthority import (
    read_orthority_geojson as read_orthority_geojson,
)
from .orthority import (
    read_orthority_interior as read_orthority_interior,
)
from .orthority import write_orthority_exterior as write_orthority_exterior
from .orthority import write_orthority_geojson as write_orthority_geojson
from .orthority import write_orthority_interior as write_orthority_interior
from .orthority import write_orthority_rpc as write_orthority_rpc
from .pix4d import read_pix4d_cam as read_pix4d_cam
from .pix4d import write_pix4d_cam as write_pix4d_cam
from .points import read_named_points as read_named_points
from .points import read_pixel_points as read_pixel_points
from .pushbroom_file import read_pushbroom as read_pushbroom
from .pushbroom_file import write_pushbroom as write_pushbroom
from .raster import (
    read_dem as read_dem,
)
from .raster import (
    read_geotiff as read_geotiff,
)
from .raster import (
    read_grey as read_grey,
)
from .raster import (
    write_geotiff as write_geotiff,
)
from .results import read_json as read_json
from .results import write_json as write_json
from .satellite import read_rpc as read_rpc
from .satellite import read_sensor as read_sensor
from .satellite import rpc_format as rpc_format
from .satellite import rpc_images as rpc_images
from .satellite import write_rpc as write_rpc
