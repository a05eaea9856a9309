"""photax.io's public names: the one list (read by photax._lazy at import time, and by type checkers)."""

from .atomic import atomic_path as atomic_path, atomic_write as atomic_write
from .bal import (
    BALData as BALData,
    read_bal as read_bal,
    read_bal_arrays as read_bal_arrays,
    write_bal as write_bal,
)
from .block import read_block as read_block, write_block as write_block
from .camera_file import read_camera as read_camera, write_camera as write_camera
from .gcp import GCPTable as GCPTable, read_gcps as read_gcps, write_gcps as write_gcps
from .orientation import (
    block_images as block_images,
    read_camera_unit as read_camera_unit,
    read_exterior as read_exterior,
    read_exteriors as read_exteriors,
    read_interior as read_interior,
)
from .opensfm import read_opensfm_cameras as read_opensfm_cameras, read_opensfm_shots as read_opensfm_shots
from .orthority import (
    read_orthority_crs as read_orthority_crs,
    read_orthority_exterior as read_orthority_exterior,
    read_orthority_exterior_crs as read_orthority_exterior_crs,
    read_orthority_geojson as read_orthority_geojson,
    read_orthority_interior as read_orthority_interior,
)
from .points import read_named_points as read_named_points, read_pixel_points as read_pixel_points
from .raster import (
    read_dem as read_dem,
    read_geotiff as read_geotiff,
    read_grey as read_grey,
    write_geotiff as write_geotiff,
)
from .results import read_json as read_json, write_json as write_json
