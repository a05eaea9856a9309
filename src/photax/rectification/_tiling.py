"""Tiles of the output grid, the thread pool that runs them, progress, and
the argument checks every rectification entry point shares.

A tile's kernel shape is a multiple of the lattice step ``_STEP`` (the
approximate mapping's lattice, :mod:`._approx`), split into chunks of
``_STEP`` rows x at most ``_CHUNK_COLS`` columns.
"""

from __future__ import annotations

import math

import numpy as np

from ..io.atomic import interrupted
from ..resampling import Resampling

_STEP = 16  # lattice spacing in output pixels (cost of the lattice: ~2/256 of exact)
_CHUNK_COLS = 1024  # columns per chunk at most: 16 x 1024 samples (measured 25 % faster than 16 x 256)


_BUCKET = 64  # kernel tile sides above this are rounded up to its multiples


def _bucket(n: int) -> int:
    """``n`` rounded up to the kernel side it runs at: a power of two from _STEP to _BUCKET, then a
    multiple of _BUCKET (at most 1/16 more pixels from about 1000 up).  64 rather than 128: a
    4097-pixel grid's tiles of 832 px ran at 896 (20 % more pixels computed than kept, against 3 %),
    and the NGI block's frames (704 x 784, 704 x 800, 688 x 784) still share one shape."""
    if n <= _BUCKET:
        return max(_STEP, 1 << (int(n) - 1).bit_length())
    return -(-n // _BUCKET) * _BUCKET


def _layout(rows: int, cols: int) -> tuple[tuple[int, int], int, int]:
    """Kernel tile shape, step and chunk width for a ``rows x cols`` tile (edge tiles are computed
    at this shape and cropped).  The shape is bucketed (:func:`_bucket`), so images of different
    sizes share a few compiled programs: each new shape costs a process its lowering and the read
    of the executable from the compilation cache, about 0.2-0.7 s CPU for the ortho kernels
    (measured on the NGI block, 4 images of 3 different tile shapes), more than computing the
    extra pixels."""
    s = _STEP
    tr, tc = _bucket(rows), _bucket(cols)
    q = max(d for d in range(1, _CHUNK_COLS // s + 1) if (tc // s) % d == 0)
    return (tr, tc), s, q * s


def tile_windows(shape: tuple[int, int], tile: int):
    """``(r0, c0, h, w)`` of the tiles covering ``shape``, row by row: about
    ``tile`` pixels square, balanced (a 4097-row grid gets five 832-row
    tiles, not four of 1024 and one of 1) and multiples of the lattice step
    except the last, so the approximate mapping's lattice does not depend
    on the tiling."""
    if int(tile) < 1:
        raise ValueError(f"tile must be a positive number of pixels, got {tile!r}")

    def up(a, b):  # ceil(a / b)
        return -(-a // b)

    sizes = [up(up(n, up(n, int(tile))), _STEP) * _STEP for n in shape]
    for r0 in range(0, shape[0], sizes[0]):
        for c0 in range(0, shape[1], sizes[1]):
            yield r0, c0, min(sizes[0], shape[0] - r0), min(sizes[1], shape[1] - c0)


def _run_tiles(fn, tiles, progress, desc: str, info: dict | None, approx: float, chunks: int, sink):
    """``sink(tile, block)`` for ``block, err, n_exact = fn(tile)`` over the
    tiles, in order; ``fn`` runs on a thread pool (XLA:CPU runs each tile's
    loop on one thread and releases the GIL), at most two tiles per thread
    in flight.  Shows a progress bar and fills ``info`` (see :func:`rectify`)."""
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    from ..resampling import THREADS

    worst, exact = 0.0, 0
    threads = max(1, min(THREADS, len(tiles)))
    pool = ThreadPoolExecutor(threads)
    try:
        with _progress(len(tiles), progress, desc) as bar:
            running = deque()
            for i in range(len(tiles) + 1):
                if interrupted.is_set():  # a Ctrl-C a dependency swallowed: stop between tiles
                    raise KeyboardInterrupt
                if i < len(tiles):
                    running.append((tiles[i], pool.submit(fn, tiles[i])))
                while running and (len(running) >= 2 * threads or i == len(tiles)):
                    t, future = running.popleft()
                    block, err, n_exact = future.result()
                    sink(t, block)
                    worst, exact = max(worst, float(err)), exact + int(n_exact)
                    if approx:
                        bar.set_postfix(max_err=f"{worst:.3f}px", refresh=False)
                    bar.update()
    except BaseException:
        # A Ctrl-C, a signal or an error: the tiles queued are dropped, only those computing are
        # waited for (they read the source dataset, closed after), so that the command stops in
        # about one tile's time, not after every tile in flight (issue 38: up to 7 s under load).
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
    if info is not None:
        info.update(approx=approx, approx_error=worst, exact_fraction=exact / max(chunks * len(tiles), 1))


def _progress(total: int, progress, desc: str):
    from ..progress import progress_bar

    return progress_bar(progress, total, desc=desc, unit="tile")


def _check_resampling(resampling) -> str:
    return Resampling.check(resampling).value


def _check_model(model):
    if not callable(model):
        raise ValueError(f"model must be a callable (..., 2) map -> (..., 2) pixel, got {type(model).__name__}")


def _check_approx(approx) -> float:
    a = 0.0 if approx is None else float(approx)
    if not (math.isfinite(a) and a >= 0):
        raise ValueError(f"approx must be None or a maximum position error >= 0 in pixels, got {approx!r}")
    return a


def _approx_arg(approx: float):
    """The kernels' ``approx``: None for exact, else a traced threshold (no
    recompilation per value).  A numpy scalar, not a jax one: making a jax
    array dispatches an XLA conversion, which waits behind the tile already
    computing and so stalls the pipeline of tiles."""
    return np.asarray(approx, dtype=float) if approx > 0 else None


def _fill_value(dtype: np.dtype, nodata) -> np.ndarray:
    """The nodata value as a 0-d array of ``dtype`` (default NaN, or 0 for integers)."""
    dtype = np.dtype(dtype)
    if nodata is None:
        nodata = np.nan if np.issubdtype(dtype, np.floating) else 0
    if np.isnan(nodata) and not np.issubdtype(dtype, np.floating):
        raise ValueError(f"nodata=NaN needs a floating-point image, got {dtype}")
    value = np.asarray(nodata, dtype=dtype)
    if not np.isnan(nodata) and float(value) != float(nodata):
        raise ValueError(f"nodata={nodata!r} is not representable in the image dtype {dtype}")
    return value
