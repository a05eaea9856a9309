"""Reading and writing photogrammetric files; one module per format."""

from .atomic import atomic_path as atomic_path, atomic_write as atomic_write
from .block import read_block as read_block
from .camera_file import read_camera as read_camera, write_camera as write_camera
from .gcp import GCPTable as GCPTable, read_gcps as read_gcps
from .results import read_json as read_json, write_json as write_json
