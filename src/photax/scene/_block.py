"""A synthetic aerial block with known truth: strips of frames over smooth terrain.

The measurements and start values of :func:`photax.scene.synthetic_block`
(which packs them into a :class:`photax.BundleProblem`), used by the tests,
the bundle notebook, the demo and ``data/block/make_block.py``.  Nothing here
depends on the adjustment, so the bundle module can import it.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation


@dataclasses.dataclass(frozen=True)
class BlockScene:
    """Output of :func:`block_scene`.

    Attributes:
        camera: the one camera (pixel units, ``focal_px``).
        exterior: ``(n_images, 3)`` true orientations.
        points: ``(n_points, 3)`` true ground coordinates (UTM-like, metres).
        roles: ``(n_points,)`` "control", "check" or "tie".
        point_names, image_names: names ("CON000", "S1_1", ...).
        obs_image, obs_point: ``(k,)`` indices of each observation.
        obs_xy: ``(k, 2)`` measured image-plane coordinates (true + noise).
        obs_sigma: the measurements' sigma (``noise_px``, or 1 px for noise 0).
        start_exterior: start orientations (truth perturbed, or NaN).
        start_points: start points (control and check exact, ties perturbed or NaN).
    """

    camera: FrameCamera
    exterior: ExteriorOrientation
    points: np.ndarray
    roles: np.ndarray
    point_names: list[str]
    image_names: list[str]
    obs_image: np.ndarray
    obs_point: np.ndarray
    obs_xy: np.ndarray
    obs_sigma: float
    start_exterior: ExteriorOrientation
    start_points: np.ndarray


def block_scene(
    seed: int = 0,
    *,
    strips: int = 2,
    images_per_strip: int = 4,
    n_tie: int = 100,
    n_control: int = 6,
    n_check: int = 4,
    noise_px: float = 0.5,
    flying_height: float = 600.0,
    relief: float = 60.0,
    tilt_deg: float = 2.0,
    focal_px: float = 3000.0,
    distortion=(0.0, 0.0, 0.0, 0.0, 0.0),
    start_error: tuple[float, float, float] = (5.0, 0.01, 3.0),
    unknown_start: bool = False,
    convention: str = "omega-phi-kappa",
    forward_overlap: float = 0.6,
    side_overlap: float = 0.3,
) -> BlockScene:
    """An aerial block (strips of ``forward_overlap`` 60 % / ``side_overlap`` 30 %) with truth.

    4000 x 3000 px frames, ``focal_px`` principal distance, flown at
    ``flying_height`` m over terrain of heights ``0 .. relief`` m, each image
    tilted by up to ``tilt_deg``.  Ground coordinates are UTM-like (~5e5,
    4e6 m).  Control points sit on the block's border (``n_control``), check
    points inside, ties anywhere (the first ``n_tie`` seen on 2 images).
    Measurements are the true projections plus Gaussian noise of
    ``noise_px``.  Start values: the truth perturbed by ``start_error =
    (position m, angle rad, tie-point m)``, or NaN (``unknown_start=True``).
    """
    # One function on purpose (> 80 lines): every draw comes from this one generator in a
    # fixed order, and data/block and the tests' figures depend on that order.
    rng = np.random.default_rng(seed)
    w, h = 4000, 3000
    cam = FrameCamera.from_pixels(focal_px, (w, h), distortion=distortion)
    gsd = flying_height / focal_px
    if not (0.0 <= forward_overlap < 1.0 and 0.0 <= side_overlap < 1.0):
        raise ValueError(f"forward_overlap and side_overlap must be in [0, 1), got {forward_overlap}, {side_overlap}")
    base, spacing = (1.0 - forward_overlap) * w * gsd, (1.0 - side_overlap) * h * gsd
    origin = np.array([500_000.0, 4_000_000.0, 100.0])
    xs = np.arange(images_per_strip) * base
    ys = np.arange(strips) * spacing
    centres = np.array([[x, y, flying_height + relief / 2] for y in ys for x in xs]) + origin
    tilt = np.radians(tilt_deg)
    angles = np.column_stack([rng.uniform(-tilt, tilt, (len(centres), 2)), rng.uniform(-0.02, 0.02, len(centres))])
    truth_eo = ExteriorOrientation(centres, angles, "omega-phi-kappa").to_convention(convention)  # type: ignore[arg-type]
    lo = np.array([xs[0] - 0.3 * w * gsd, ys[0] - 0.3 * h * gsd])
    hi = np.array([xs[-1] + 0.3 * w * gsd, ys[-1] + 0.3 * h * gsd])

    def terrain(xy):
        u = (xy - lo) / (hi - lo)
        return relief * (0.5 + 0.25 * np.sin(5.0 * u[:, 0]) * np.cos(4.0 * u[:, 1]) + 0.25 * u[:, 0] * u[:, 1])

    # Control on a ring along the border, check points inside, ties anywhere.
    t = np.linspace(0, 1, n_control, endpoint=False) + 0.5 / max(n_control, 1)
    ring = np.column_stack([0.5 + 0.42 * np.cos(2 * np.pi * t), 0.5 + 0.42 * np.sin(2 * np.pi * t)])
    inner = 0.3 + 0.4 * rng.uniform(size=(n_check, 2))
    tie = rng.uniform(size=(4 * n_tie, 2))
    uv = np.concatenate([ring, inner, tie])
    xy = lo + uv * (hi - lo)
    xyz = np.column_stack([xy, terrain(xy)]) + origin
    roles = np.array(["control"] * n_control + ["check"] * n_check + ["tie"] * len(tie), dtype=object)

    # Which images see which points.  The images stand on a regular grid (columns xs, rows ys),
    # so a point can only be seen by those whose centre lies within `reach` of it in x and in y
    # (a generous superset of the footprint: relief, tilt); only those pairs are projected, in
    # fixed-size batches, and only for as many tie candidates as it takes to find n_tie seen twice.
    # Vectorised over points: a 10,000-image block in seconds.  The result does not depend on the
    # batching: the pairs inside the frame, ordered by image, then point.
    reach = (flying_height + relief) * (0.5 * np.hypot(w, h) / focal_px + np.tan(tilt) + 0.1)
    obs_i, obs_p, obs_xy = _visible(xyz, n_control + n_check, n_tie, xs + origin[0], ys + origin[1], reach,
                                    truth_eo, cam, 0.48 * w, 0.48 * h)  # fmt: skip
    counts = np.bincount(obs_p, minlength=len(xyz))
    keep = counts >= 2
    keep[:n_control] = counts[:n_control] >= 1
    tie_idx = np.flatnonzero(keep[n_control + n_check :])[:n_tie] + n_control + n_check
    keep[n_control + n_check :] = False
    keep[tie_idx] = True
    if not np.all(keep[: n_control + n_check]):
        raise ValueError("synthetic block: a control or check point is outside every image; change the layout")
    new_id = np.cumsum(keep) - 1
    sel = keep[obs_p]
    obs_i, obs_p, obs_xy = obs_i[sel], new_id[obs_p[sel]], obs_xy[sel]
    xyz, roles = xyz[keep], roles[keep]
    obs_xy = obs_xy + noise_px * rng.standard_normal(obs_xy.shape)
    names = [f"{r[:3].upper()}{i:03d}" for i, r in enumerate(roles)]
    e_pos, e_ang, e_pt = start_error
    if unknown_start:
        pos0 = np.full_like(centres, np.nan)
        ang0 = np.full_like(angles, np.nan)
        pts0 = np.where((roles == "tie")[:, None], np.nan, xyz)
    else:
        pos0 = np.asarray(truth_eo.position) + e_pos * rng.standard_normal(centres.shape)
        ang0 = np.asarray(truth_eo.angles) + e_ang * rng.standard_normal(angles.shape)
        pts0 = np.where((roles == "tie")[:, None], xyz + e_pt * rng.standard_normal(xyz.shape), xyz)
    return BlockScene(
        camera=cam, exterior=truth_eo, points=xyz, roles=roles, point_names=names,
        image_names=[f"S{i // images_per_strip + 1}_{i % images_per_strip + 1}" for i in range(len(centres))],
        obs_image=obs_i, obs_point=obs_p, obs_xy=obs_xy, obs_sigma=noise_px if noise_px > 0 else 1.0,
        start_exterior=ExteriorOrientation(pos0, ang0, convention),  # type: ignore[arg-type]
        start_points=pts0,
    )  # fmt: skip


#: Most image-point pairs projected per call in :func:`_visible`.
_PAIR_BATCH = 1 << 18


def _visible(xyz, n_fixed, n_tie, col_x, row_y, reach, eo, cam, half_w, half_h):
    """Observations ``(image, point, xy)`` of the points ``xyz`` inside the
    frames (``|x| < half_w``, ``|y| < half_h``) of images on the grid
    ``row_y x col_x`` (image ``r * len(col_x) + c``), ordered by image, then
    point.  All of the first ``n_fixed`` points are projected; of the rest
    (ties), the candidates in order until ``n_tie`` are seen on two images or
    more (the later ones cannot be kept: see :func:`block_scene`)."""
    n_col, n_row = len(col_x), len(row_y)
    step_x = col_x[1] - col_x[0] if n_col > 1 else 1.0
    step_y = row_y[1] - row_y[0] if n_row > 1 else 1.0
    wx = int(np.floor(2 * reach / step_x)) + 2 if n_col > 1 else 1  # window sizes (columns, rows)
    wy = int(np.floor(2 * reach / step_y)) + 2 if n_row > 1 else 1
    pos, rot = np.asarray(eo.position), np.asarray(eo.rotation)
    project_pairs = _pair_projector(cam)
    out_i, out_p, out_xy = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros((0, 2))]

    def pairs(first, last):
        p = xyz[first:last]
        c0 = (
            np.ceil((p[:, 0] - reach - col_x[0]) / step_x).astype(np.int64) if n_col > 1 else np.zeros(len(p), np.int64)
        )
        r0 = (
            np.ceil((p[:, 1] - reach - row_y[0]) / step_y).astype(np.int64) if n_row > 1 else np.zeros(len(p), np.int64)
        )
        c = c0[:, None, None] + np.arange(wx)[None, None, :]
        r = r0[:, None, None] + np.arange(wy)[None, :, None]
        ok = (c >= 0) & (c < n_col) & (r >= 0) & (r < n_row)
        ok &= np.abs(p[:, None, None, 0] - col_x[np.clip(c, 0, n_col - 1)]) <= reach
        ok &= np.abs(p[:, None, None, 1] - row_y[np.clip(r, 0, n_row - 1)]) <= reach
        pt, rr, cc = np.nonzero(ok)  # pt: first index, so ordered by point
        img = r[pt, rr, 0] * n_col + c[pt, 0, cc]
        pt = pt + first
        xy = np.empty((len(pt), 2))
        size = min(_PAIR_BATCH, 1 << max(len(pt) - 1, 1).bit_length())  # few shapes, few compiles
        for k in range(0, len(pt), size):
            sl = slice(k, k + size)
            n = len(pt[sl])
            pad = np.arange(size) % n
            xy[sl] = np.asarray(project_pairs(xyz[pt[sl][pad]], pos[img[sl][pad]], rot[img[sl][pad]]))[:n]
        inside = (np.abs(xy[:, 0]) < half_w) & (np.abs(xy[:, 1]) < half_h)
        out_i.append(img[inside])
        out_p.append(pt[inside])
        out_xy.append(xy[inside])
        return np.bincount(pt[inside] - first, minlength=last - first)

    if n_fixed:
        pairs(0, n_fixed)
    found, first = 0, n_fixed
    batch = max(1024, _PAIR_BATCH // (wx * wy))
    while found < n_tie and first < len(xyz):
        last = min(first + batch, len(xyz))
        found += int(np.sum(pairs(first, last) >= 2))
        first = last
    obs_i, obs_p = np.concatenate(out_i), np.concatenate(out_p)
    order = np.lexsort((obs_p, obs_i))
    return obs_i[order], obs_p[order], np.concatenate(out_xy).reshape(-1, 2)[order]


def _pair_projector(cam):
    """Jitted ``(points (n, 3), positions (n, 3), rotations (n, 3, 3)) ->
    (n, 2)``: each point through its own image, ``camera.project(R^T (X -
    Xs))`` as :func:`photax.collinearity.project` (the rotations computed
    once per image, not once per pair)."""
    return jax.jit(lambda p, position, rotation: cam.project(jnp.einsum("nij,ni->nj", rotation, p - position)))
