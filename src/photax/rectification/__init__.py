"""Whole-image rectification and orthorectification.

**Indirect mapping** (output -> input; the default, docs/maths.md): for every
output pixel centre take its map/ground coordinate from the output
:class:`Grid`, find its position in the input image with a *model*
``(..., 2) map (X, Y) -> (..., 2) input pixel (column, row)``, and
interpolate the grey value there (:func:`photax.resampling.resample`).  Every
output pixel gets a value, so there are no holes.

**Direct mapping** (input -> output), kept for comparison: every input pixel
centre is sent forward with the *inverse* model and its value dropped into
the nearest output pixel.  When the output is finer than the input (or the
map stretches the image) some output pixels are never hit: holes.

**Orthorectification** is indirect mapping with the collinearity model: a
ground point ``(X, Y)`` of the output grid gets its height ``Z`` from the DEM
(bilinear), and ``(X, Y, Z)`` is projected into the image with the
collinearity equations (:func:`photax.collinearity.project`) and converted
to pixels (:meth:`photax.FrameCamera.image_to_pixel`).  This removes relief
displacement, which no plane-to-plane polynomial can.  Occlusion is **not**
handled: a ground point hidden behind a hill still receives the grey value
of whatever the camera saw along that ray (a "ghost"), as in orthority and
most DEM (non-true) orthophoto software.

The output is processed in tiles of about ``tile x tile`` pixels, so memory
stays bounded; each tile's mapping (grid -> ground -> pixel) and resampling
are one jitted function (no full-size coordinate maps), and tiles run on a
thread pool.  By default the mapping is *approximate*, as GDAL's warper
does it: the exact model on a 16-pixel lattice, bilinear interpolation in
between where checks show the position error is at most ``approx``
(0.125 px), exact evaluation elsewhere (see :func:`rectify`).  The
``*_file`` variants stream through rasterio windows: per output tile they
read only the input window it needs (plus the kernel's margin,
:class:`photax.Resampling`), so images far larger than memory can be
processed.

Frames and conventions: ``docs/conventions.md`` (pixel centres at integer
pixel coordinates; raster georeference at pixel corners).
"""

# Re-exports only; three entry points (rectify in memory, rectify_file file to
# file, orthorectify_dask on Dask) over one kernel set.  The modules, in
# pipeline order: _tiling (tiles, thread pool, progress, checks), _approx
# (input positions: lattice, checks, exact fallback), _indirect (rectify),
# _direct (direct mapping), _ortho (OrthoModel, orthorectify), _files
# (rectify_file, orthorectify_file, orthorectify_block: windowed reads),
# _dask (orthorectify_dask: one Dask task per chunk), _occlusion (z-buffer visibility),
# _true_ortho (true_ortho: a block's true ortho).  The output grid (Grid,
# ortho_grid) lives in photax.grid (re-exported here), the resampling kernels
# in photax.resampling.

from ..grid import Grid as Grid
from ..grid import check_resolution as check_resolution
from ..grid import dem_coverage as dem_coverage
from ..grid import ground_sampling_distance as ground_sampling_distance
from ..grid import ortho_grid as ortho_grid
from ..resampling import Resampling as Resampling
from ._dask import orthorectify_dask as orthorectify_dask
from ._files import (
    orthorectify_block as orthorectify_block,
)
from ._files import (
    orthorectify_file as orthorectify_file,
)
from ._files import (
    orthorectify_files as orthorectify_files,
)
from ._files import (
    rectify_file as rectify_file,
)
from ._indirect import rectify as rectify
from ._ortho import OrthoModel as OrthoModel
from ._ortho import occlusion_mask as occlusion_mask
from ._ortho import orthorectify as orthorectify
from ._tiling import tile_windows as tile_windows
from ._true_ortho import true_ortho as true_ortho
