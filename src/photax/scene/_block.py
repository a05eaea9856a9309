"""A synthetic aerial block with known truth: strips of frames over smooth terrain.

The measurements and start values of :func:`photax.bundle.synthetic_block`
(which packs them into a :class:`photax.BundleProblem`), used by the tests,
the bundle notebook, the demo and ``data/block/make_block.py``.  Nothing here
depends on the adjustment, so the bundle module can import it.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from ..camera import FrameCamera
from ..collinearity import ExteriorOrientation, project


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

    # Each image projects only the points near its nadir (a generous superset of its footprint:
    # relief, tilt), so a block of 10,000 images costs seconds, not hours; same result as all points.
    reach = (flying_height + relief) * (0.5 * np.hypot(w, h) / focal_px + np.tan(tilt) + 0.1)
    by_x = np.argsort(xyz[:, 0], kind="stable")
    xs_sorted = xyz[by_x, 0]
    project_one = jax.jit(lambda pts, pos, ang: project(pts, ExteriorOrientation(pos, ang, convention), cam))
    obs_i, obs_p, obs_xy = [], [], []
    for i in range(len(centres)):
        lo_i, hi_i = np.searchsorted(xs_sorted, [centres[i, 0] - reach, centres[i, 0] + reach])
        near = np.sort(by_x[lo_i:hi_i])
        near = near[np.abs(xyz[near, 1] - centres[i, 1]) <= reach]
        padded = np.resize(near, 1 << max(len(near) - 1, 1).bit_length())  # few shapes, few compiles
        img = np.asarray(project_one(xyz[padded], truth_eo.position[i], truth_eo.angles[i]))[: len(near)]
        inside = (np.abs(img[:, 0]) < 0.48 * w) & (np.abs(img[:, 1]) < 0.48 * h)
        obs_i.append(np.full(int(inside.sum()), i))
        obs_p.append(near[inside])
        obs_xy.append(img[inside])
    obs_i, obs_p, obs_xy = np.concatenate(obs_i), np.concatenate(obs_p), np.concatenate(obs_xy).reshape(-1, 2)
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
