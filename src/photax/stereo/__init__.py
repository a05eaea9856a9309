"""Dense stereo after matching: triangulation, point clouds and surface models.

The chain (``docs/stereo.md``): an epipolar pair (:func:`photax.epipolar_pair`: frame pairs by the
epipolar homographies, RPC / push-broom pairs by s2p's local affine rectification over a tile) ->
a disparity map (:func:`photax.disparity`) -> points (:func:`disparity_to_points`, each with its
intersection residual and height sigma; :func:`triangulate_pair` for any corresponding pixels) ->
a surface model on a grid chosen like the ortho's (:func:`rasterize_points`, small holes filled)
-> several pairs fused (:func:`fuse_dsms`) -> a Cloud-Optimized GeoTIFF (:func:`write_cog`); the points
themselves as PLY or LAS / LAZ (:meth:`PointCloud.write_ply`, :meth:`PointCloud.write_las`).
"""

from ._dsm import SurfaceModel as SurfaceModel
from ._dsm import fill_holes as fill_holes
from ._dsm import fuse_dsms as fuse_dsms
from ._dsm import rasterize_points as rasterize_points
from ._dsm import write_cog as write_cog
from ._pipeline import frame_disparity_range as frame_disparity_range
from ._pipeline import pair_points as pair_points
from ._pipeline import reduce as reduce
from ._points import PointCloud as PointCloud
from ._points import read_las as read_las
from ._points import read_ply as read_ply
from ._triangulate import SIGMA_DISPARITY as SIGMA_DISPARITY
from ._triangulate import disparity_to_points as disparity_to_points
from ._triangulate import height_per_disparity as height_per_disparity
from ._triangulate import triangulate_pair as triangulate_pair
