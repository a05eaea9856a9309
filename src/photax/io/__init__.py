"""Reading and writing photogrammetric files; one module per format."""

from .atomic import atomic_path as atomic_path, atomic_write as atomic_write
