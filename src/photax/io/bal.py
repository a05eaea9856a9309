"""Bundle Adjustment in the Large (BAL) files.

The BAL format (Agarwal, Snavely, Seitz, Szeliski, "Bundle Adjustment in the
Large", ECCV 2010; grail.cs.washington.edu/projects/bal) is plain text::

    n_cameras n_points n_observations
    camera_index point_index x y          (n_observations lines)
    9 values per camera                   (rx ry rz tx ty tz f k1 k2)
    3 values per point                    (X Y Z)

Values of the parameter blocks may be one per line or several per line;
blank lines are ignored.  ``.bz2`` files (as the BAL site ships them) are
read directly.  Each camera projects a point ``X`` by::

    P   = R(r) X + t             # R: Rodrigues, camera_from_world
    p   = -P[:2] / P[2]          # the camera looks along -z
    pix = f (1 + k1 |p|^2 + k2 |p|^4) p

with the origin at the image centre and y up, in pixels.

This is exactly photax's frame camera (``docs/conventions.md``): camera
``FrameCamera(f, (0, 0), (k1, k2, 0, 0, 0))`` on an image plane in pixels,
exterior orientation with ``world_from_camera = R^T`` and projection centre
``C = -R^T t``.  :func:`bal_to_photax` and :func:`photax_to_bal` convert.
"""

from __future__ import annotations

import bz2
import dataclasses
import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from ..bundle import BundleProblem, BundleResult
from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation
from ..errors import UnreadableFileError
from ..rotation import angles_from_matrix, axis_angle_to_matrix, matrix_to_axis_angle
from .atomic import atomic_write
from .files import MAX_BYTES, excerpt, read_bytes, where


@dataclasses.dataclass(frozen=True)
class BALData:
    """The arrays of a BAL file, as stored (no conversion).

    Attributes:
        cameras: ``(m, 9)`` ``(rx, ry, rz, tx, ty, tz, f, k1, k2)``; ``r`` is
            the Rodrigues vector of ``camera_from_world`` (radians), ``t`` in
            the world unit, ``f`` in pixels, ``k1 k2`` dimensionless.
        points: ``(n, 3)`` world points.
        camera_index: ``(k,)`` int, camera of each observation.
        point_index: ``(k,)`` int, point of each observation.
        observations: ``(k, 2)`` pixels, origin at the image centre, y up.

    Examples:
        BAL's arrays in memory, the second camera turned by ``r = (0, 0, pi/2)`` (camera_from_world),
        which sees point ``(1, 2, 0)`` at ``R X + t = (-2, 1, -10)``, pixel ``100 (-0.2, 0.1)``; as a
        block (:func:`photax.io.bal.bal_problem`) the turn is photax's world_from_camera kappa of -90 deg:

        >>> import numpy as np
        >>> from photax.io import BALData
        >>> from photax.io.bal import bal_problem
        >>> data = BALData(cameras=np.array([[0, 0, 0, 0, 0, -10, 100, 0, 0], [0, 0, np.pi / 2, 0, 0, -10, 100, 0, 0]]),
        ...                points=np.array([[1.0, 2.0, 0.0], [0.0, 0.0, 0.0]]),
        ...                camera_index=np.array([0, 1, 0, 1]), point_index=np.array([0, 0, 1, 1]),
        ...                observations=np.array([[10.0, 20.0], [-20.0, 10.0], [0.0, 0.0], [0.0, 0.0]]))

        >>> problem = bal_problem(data)
        >>> print(np.round(np.degrees(np.asarray(problem.exterior.angles)), 6) + 0.0, problem.exterior.convention)
        [[  0.   0.   0.]
         [  0.   0. -90.]] omega-phi-kappa

    """

    cameras: np.ndarray
    points: np.ndarray
    camera_index: np.ndarray
    point_index: np.ndarray
    observations: np.ndarray


class _TooLarge(Exception):
    """The decompressed BAL file passed ``MAX_BYTES["BAL file"]``."""


def _read_bytes(path: pathlib.Path) -> bytes:
    raw = read_bytes(path, "BAL file")
    if path.suffix == ".bz2":
        limit, out, size = MAX_BYTES["BAL file"], [], 0
        try:
            while raw:  # stream after stream, as bz2.decompress, but never past the limit (a bzip2 bomb)
                unpack = bz2.BZ2Decompressor()
                out.append(unpack.decompress(raw, max_length=limit + 1 - size))
                size += len(out[-1])
                if size > limit or not unpack.eof and not unpack.needs_input:
                    raise _TooLarge
                if not unpack.eof:
                    raise EOFError("Compressed file ended before the end-of-stream marker was reached")
                raw = unpack.unused_data
        except _TooLarge:
            raise ValueError(
                f"{path}: decompresses to over {limit / 2**30:.3g} GiB, too large for a BAL file"
            ) from None
        except (OSError, ValueError, EOFError) as exc:
            raise UnreadableFileError(f"{path}: not a readable bzip2 file ({exc})") from None
        return b"".join(out)
    return raw


def _tokens(raw: bytes) -> tuple[list[bytes], np.ndarray]:
    """Whitespace-separated fields and the 1-based line number of each.

    Vectorised over the bytes so a 30 000-observation file takes tens of ms.
    """
    tokens = raw.split()  # splits on ASCII whitespace, as ``ws`` below
    b = np.frombuffer(raw, dtype=np.uint8)
    ws = (b == 32) | ((b >= 9) & (b <= 13))
    first = ~ws & np.concatenate([[True], ws[:-1]])
    lines = np.searchsorted(np.flatnonzero(b == 10), np.flatnonzero(first)) + 1
    return tokens, lines


def _floats(tokens: list[bytes], lines: np.ndarray, path, what: str) -> np.ndarray:
    """Tokens -> float64; a bad token raises naming its line."""
    try:
        values = np.array(tokens, dtype=float)
        if np.all(np.isfinite(values)):
            return values
    except ValueError:
        pass
    for tok, line in zip(tokens, lines.tolist()):
        try:
            ok = np.isfinite(float(tok))
        except ValueError:
            ok = False
        if not ok:
            shown = excerpt(tok.decode(errors="replace"))
            raise ValueError(f"{where(path, line)}: {what}: {shown} is not a finite number")
    raise AssertionError("unreachable")


def read_bal_arrays(path) -> BALData:
    """Read a BAL file into its arrays.

    Args:
        path: a ``.txt`` BAL file (or ``.txt.bz2``).

    Returns:
        :class:`BALData`.

    Raises:
        ValueError: naming the file and line for a wrong header, an
            observation line without 4 fields, an index out of range, a value
            that is not a finite number, a non-positive focal length, or too
            few / too many values.

    Examples:
        Header, four observations, two cameras of 9 values (no rotation, ``t``, ``f = 100``, no
        distortion), two points; camera 0 sees point ``(1, 2, 0)`` at ``100 (1, 2) / 10 = (10, 20)``:

        >>> import pathlib, tempfile
        >>> from photax.io import read_bal_arrays
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "problem.txt"
        >>> _ = path.write_text("2 2 4\\n0 0 10 20\\n1 0 0 20\\n0 1 0 0\\n1 1 -10 0\\n"
        ...                     "0 0 0 0 0 -10 100 0 0\\n0 0 0 -1 0 -10 100 0 0\\n1 2 0\\n0 0 0\\n")
        >>> data = read_bal_arrays(path)
        >>> data.cameras.shape, data.points.tolist(), data.observations[0].tolist()
        ((2, 9), [[1.0, 2.0, 0.0], [0.0, 0.0, 0.0]], [10.0, 20.0])
    """
    path = pathlib.Path(path)
    tokens, lines = _tokens(_read_bytes(path))
    if not tokens:
        raise ValueError(f"{path}: empty file, expected a BAL header 'n_cameras n_points n_observations'")
    per_line = np.bincount(lines)
    head = tokens[: int(per_line[lines[0]])]
    try:
        m, n, k = (int(v) for v in head)
    except ValueError:  # not a BAL file: none of its content is quoted
        raise ValueError(
            f"{where(path, lines[0])}: not a BAL file (a header 'n_cameras n_points n_observations' of three "
            "whole numbers expected)"
        ) from None
    if min(m, n, k) < 1:
        raise ValueError(f"{where(path, lines[0])}: header counts must be positive, got {m} {n} {k}")
    need = 3 + 4 * k + 9 * m + 3 * n
    if len(tokens) < need:
        raise ValueError(
            f"{where(path, lines[-1])}: truncated: the header announces {k} observations, {m} cameras and "
            f"{n} points ({need} values), the file has {len(tokens)}"
        )
    if len(tokens) > need:
        raise ValueError(
            f"{where(path, lines[need])}: unexpected extra values after the last point ({need} values expected)"
        )

    # Observation lines hold exactly 4 fields each: 'camera point x y'.
    obs_lines = lines[3 : 3 + 4 * k]
    wrong = per_line[obs_lines] != 4
    if wrong.any():
        line = int(obs_lines[np.argmax(wrong)])
        raise ValueError(
            f"{where(path, line)}: an observation line needs 4 fields 'camera point x y', got {per_line[line]}"
        )
    table = _floats(tokens[3 : 3 + 4 * k], obs_lines, path, "observation").reshape(k, 4)
    index = table[:, :2]
    bad = (index != np.round(index)) | (index < 0) | (index >= np.array([[m, n]], dtype=float))
    if bad.any():
        i = int(np.argmax(bad.any(axis=1)))
        raise ValueError(
            f"{where(path, obs_lines[4 * i])}: camera index must be an integer in [0, {m}) and point index "
            f"in [0, {n}), got {table[i, 0]:g} {table[i, 1]:g}"
        )
    param_lines = lines[3 + 4 * k :]
    values = _floats(tokens[3 + 4 * k :], param_lines, path, "parameter")
    cameras = values[: 9 * m].reshape(m, 9)
    if not np.all(cameras[:, 6] > 0):
        i = int(np.argmin(cameras[:, 6] > 0))
        raise ValueError(f"{where(path, param_lines[9 * i + 6])}: focal length of camera {i} must be positive")
    return BALData(
        cameras=cameras,
        points=values[9 * m :].reshape(n, 3),
        camera_index=index[:, 0].astype(np.int64),
        point_index=index[:, 1].astype(np.int64),
        observations=table[:, 2:].copy(),
    )


def write_bal_arrays(data: BALData, path, inputs=()) -> pathlib.Path:
    """Write :class:`BALData` as a BAL text file (atomically).

    Numbers are written with 17 significant digits, so reading the file back
    gives the same float64 values.  ``inputs`` are files the caller read:
    the output may not overwrite one of them.
    """
    cameras = np.asarray(data.cameras, dtype=float)
    points = np.asarray(data.points, dtype=float)
    obs = np.asarray(data.observations, dtype=float)
    ci = np.asarray(data.camera_index)
    pi = np.asarray(data.point_index)
    m, n, k = len(cameras), len(points), len(obs)
    with atomic_write(path, inputs=inputs) as fh:
        fh.write(f"{m} {n} {k}\n")
        fh.writelines(f"{c} {p} {x:.17g} {y:.17g}\n" for c, p, x, y in zip(ci.tolist(), pi.tolist(), *obs.T.tolist()))
        fh.writelines(f"{v:.17g}\n" for v in np.concatenate([cameras.ravel(), points.ravel()]).tolist())
    return pathlib.Path(path)


@jax.jit
def _exterior_from_bal(rt):
    # One compiled function rather than a dozen eagerly dispatched ops.
    r_cw = axis_angle_to_matrix(rt[:, :3])  # camera_from_world
    centres = -jnp.einsum("mji,mj->mi", r_cw, rt[:, 3:6])
    return centres, angles_from_matrix(jnp.swapaxes(r_cw, -1, -2), "omega-phi-kappa")


@jax.jit
def _bal_from_exterior(r_wc, centres):
    r_cw = jnp.swapaxes(r_wc, -1, -2)
    return matrix_to_axis_angle(r_cw), -jnp.einsum("mij,mj->mi", r_cw, centres)


def bal_to_photax(cameras_bal) -> tuple[list[FrameCamera], ExteriorOrientation]:
    """BAL camera rows -> photax interior and exterior orientations.

    Args:
        cameras_bal: ``(m, 9)`` BAL camera rows.

    Returns:
        ``(cameras, exterior)``: ``m`` :class:`FrameCamera` (image plane in
        pixels, principal point ``(0, 0)``, distortion ``(k1, k2, 0, 0, 0)``)
        and one batched :class:`ExteriorOrientation` of shape ``(m,)`` in the
        omega-phi-kappa convention, with ``world_from_camera = R^T`` and
        ``C = -R^T t``.
    """
    c = np.asarray(cameras_bal, dtype=float)
    if c.ndim != 2 or c.shape[1] != 9:
        raise ValueError(f"cameras_bal must have shape (m, 9), got {c.shape}")
    centres, angles = _exterior_from_bal(jnp.asarray(c[:, :6]))
    exterior = ExteriorOrientation(centres, angles, "omega-phi-kappa")
    zeros = np.zeros(len(c))
    dist = np.stack([c[:, 7], c[:, 8], zeros, zeros, zeros], axis=1)
    return [FrameCamera(f, (0.0, 0.0), d) for f, d in zip(c[:, 6].tolist(), dist)], exterior


def photax_to_bal(cameras, rotation, centres) -> np.ndarray:
    """The inverse of :func:`bal_to_photax`: ``(m, 9)`` BAL camera rows.

    Args:
        cameras: ``m`` :class:`FrameCamera`.
        rotation: ``(m, 3, 3)`` world_from_camera matrices.
        centres: ``(m, 3)`` projection centres.

    Raises ValueError for a camera BAL cannot hold: principal point off the
    centre or distortion beyond ``k1, k2``.
    """
    r_wc = np.asarray(rotation, dtype=float).reshape(-1, 3, 3)
    centres = np.asarray(centres, dtype=float).reshape(-1, 3)
    if len(cameras) != len(r_wc):
        raise ValueError(f"{len(cameras)} cameras for {len(r_wc)} images: BAL needs one camera per image")
    other = [i for i, c in enumerate(cameras) if c.model != "brown"]
    if other:
        raise ValueError(
            f"cameras[{other[0]}]: BAL holds the Brown model's f, k1, k2, not a {cameras[other[0]].model} camera"
        )
    intr = np.array(
        [[float(c.focal_length), *np.asarray(c.principal_point), *np.asarray(c.distortion)] for c in cameras]
    )
    bad = np.any(intr[:, [1, 2, 5, 6, 7]] != 0, axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(
            f"cameras[{i}]: BAL holds only f, k1, k2 with the principal point at the image centre; got "
            f"principal_point {intr[i, 1:3].tolist()} and (k3, p1, p2) {intr[i, 5:].tolist()}"
        )
    rotvec, t = _bal_from_exterior(jnp.asarray(r_wc), jnp.asarray(centres))
    return np.concatenate([np.asarray(rotvec), np.asarray(t), intr[:, [0, 3, 4]]], axis=1)


def read_bal(path) -> BundleProblem:
    """Read a BAL file as a :class:`photax.BundleProblem`.

    One camera per image (``image_camera = arange``), with ``f, k1, k2``
    free and the principal point, ``k3, p1, p2`` fixed at 0, as in the BAL
    problems.  Observations are image-plane pixels (y up), sigma 1, so the
    cost is BAL's ``0.5 sum |r|^2`` in pixels^2.  BAL has no control points:
    adjust with ``photax.bundle_adjust(problem, gauge="damped")`` (the LM
    damping handles the 7-parameter datum defect, as Ceres does).

    Examples:
        Two cameras at ``t = (0, 0, -10)`` and ``(-1, 0, -10)``, no rotation: photax's projection
        centres are ``C = -R^T t``, the cameras ``f = 100`` px with ``f, k1, k2`` free:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "problem.txt"
        >>> _ = path.write_text("2 2 4\\n0 0 10 20\\n1 0 0 20\\n0 1 0 0\\n1 1 -10 0\\n"
        ...                     "0 0 0 0 0 -10 100 0 0\\n0 0 0 -1 0 -10 100 0 0\\n1 2 0\\n0 0 0\\n")
        >>> problem = ptx.read_bal(path)
        >>> problem.n_images, problem.n_points, problem.n_observations
        (2, 2, 4)
        >>> print(np.asarray(problem.exterior.position) + 0.0, float(problem.cameras[1].focal_length))
        [[ 0.  0. 10.]
         [ 1.  0. 10.]] 100.0
        >>> problem.free_intrinsics[0].tolist()  # f x0 y0 k1 k2 k3 p1 p2
        [True, False, False, True, True, False, False, False]
    """
    data = read_bal_arrays(path)
    try:
        problem = bal_problem(data)
    except ValueError as exc:  # e.g. a point seen by one camera only
        raise ValueError(f"{path}: {exc}") from None
    bad = ~(
        np.isfinite(np.asarray(problem.exterior.position)).all(1)
        & np.isfinite(np.asarray(problem.exterior.angles)).all(1)
    )
    if bad.any():
        raise ValueError(f"{path}: camera {int(np.argmax(bad))}: rotation or translation out of range")
    return problem


def bal_problem(data: BALData) -> BundleProblem:
    """:class:`BALData` -> :class:`photax.BundleProblem` (see :func:`read_bal`)."""
    cameras, exterior = bal_to_photax(data.cameras)
    return BundleProblem(
        cameras, exterior, data.points, data.camera_index, data.point_index, data.observations,
        free_intrinsics=("f", "k1", "k2"),
    )  # fmt: skip


def block_state(problem_or_result):
    """``(problem, cameras, rotations world_from_camera, centres, points)`` of a
    :class:`photax.BundleProblem` (its start) or a :class:`photax.BundleResult` (adjusted): what the
    block writers (BAL, COLMAP) write."""
    if isinstance(problem_or_result, BundleResult):
        res = problem_or_result
        return res.problem, res.cameras, res.rotation, res.exterior.position, res.points
    if isinstance(problem_or_result, BundleProblem):
        prob = problem_or_result
        return prob, prob.cameras, prob.exterior.rotation, prob.exterior.position, prob.points
    raise ValueError(f"expected a BundleProblem or BundleResult, got {type(problem_or_result).__name__}")


def write_bal(problem_or_result, path, inputs=()) -> pathlib.Path:
    """Write a :class:`photax.BundleProblem` or an adjusted
    :class:`photax.BundleResult` as a BAL file (atomically), e.g. to hand an
    adjusted block back to BAL tools.

    The problem needs one camera per image with only ``f, k1, k2`` (BAL's
    camera); a result writes its adjusted cameras, orientations and points.
    ``inputs``: files the output may not overwrite.

    Examples:
        A round trip: the problem read from a BAL file writes the same cameras back (photax's
        ``C, R`` converted to BAL's ``r, t``):

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import read_bal_arrays
        >>> folder = pathlib.Path(tempfile.mkdtemp())
        >>> _ = (folder / "in.txt").write_text("2 2 4\\n0 0 10 20\\n1 0 0 20\\n0 1 0 0\\n1 1 -10 0\\n"
        ...                                    "0 0 0.1 0 0 -10 100 0 0\\n0 0 0 -1 0 -10 100 0 0\\n1 2 0\\n0 0 0\\n")
        >>> out = ptx.write_bal(ptx.read_bal(folder / "in.txt"), folder / "out.txt")
        >>> a, b = read_bal_arrays(folder / "in.txt"), read_bal_arrays(out)
        >>> bool(np.allclose(a.cameras, b.cameras, atol=1e-12)), bool(np.array_equal(a.observations, b.observations))
        (True, True)
    """

    prob, cams, rot, centres, points = block_state(problem_or_result)
    if not np.array_equal(prob.image_camera, np.arange(prob.n_images)):
        raise ValueError("BAL needs one camera per image (image_camera = arange(n_images))")
    data = BALData(
        cameras=photax_to_bal(cams, rot, centres), points=np.asarray(points, dtype=float),
        camera_index=prob.obs_image, point_index=prob.obs_point, observations=prob.obs_xy,
    )  # fmt: skip
    return write_bal_arrays(data, path, inputs=inputs)
