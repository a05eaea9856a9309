"""The pytrees the compiled resection passes around: inputs, options, output.

Each is an ``equinox.Module`` (a frozen dataclass that is a pytree), as
optimistix passes its ``Solution`` and solver states: adding an option or an
output means adding a field here and setting it where the module is built
(:func:`photax.resection._api._options`, the solver that fills it).

Inside the compiled code every array carries the batch of images as its
last axis (lanes, :mod:`._lanes`); options are shared by the batch.
``m`` is the point count padded (16, 32, ... for one image; a multiple of 4 for a batch).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..camera import FrameCamera


class Inputs(eqx.Module):
    """A batch of ``B`` images' data, the images on the last axis (lanes,
    :mod:`._lanes`), ground reduced to the control points' centroid."""

    xy: Array  # (2, m, B) image-plane coordinates (padding: 0)
    ground: Array  # (3, m, B) ground minus origin, metres
    weight: Array  # (2, m, B) 1 / sigma^2 (padding: 1)
    ctrl: Array  # (m, B) bool: a control point (not a check point, not padding)
    basis: Array  # (3, 3, B) principal axes of the control points (columns), last = plane normal
    init: Array  # (6, B) the user's start (C - origin, angles), or zeros
    use_init: Array  # (B,) bool: start from ``init`` instead of the linear start

    def per_image(self) -> Inputs:
        """The image axis first, each image in its natural layout (``xy`` ``(B, m, 2)``,
        ``basis`` ``(B, 3, 3)``, ...): for per-image code under ``vmap``."""
        t = functools.partial(jnp.transpose, axes=(2, 1, 0))
        return Inputs(
            xy=t(self.xy),
            ground=t(self.ground),
            weight=t(self.weight),
            ctrl=self.ctrl.T,
            basis=jnp.transpose(self.basis, (2, 0, 1)),
            init=self.init.T,
            use_init=self.use_init,
        )

    def take(self, idx) -> Inputs:
        """The lanes ``idx`` (numpy or JAX)."""
        return jax.tree_util.tree_map(lambda a: a[..., idx], self)


class Options(eqx.Module):
    """Settings shared by every image of a call; no static fields, so that
    one compilation serves every setting (``camera`` carries only its
    interior orientation, no pixel grid: see ``_api._options``)."""

    critical: Array  # (m + 1,) critical value of the test with k control points in use
    snoop: Array  # () bool: robust=True, test for blunders (and exclude them on the robust path)
    scale_stat: Array  # () bool: divide w by sigma0 (Pope's tau: no a-priori sigma)
    exact: Array  # () sigma0 below this: rounding-level residuals, no test
    min_points: Array  # () int: never exclude below this many control points
    min_redundancy: Array  # () never exclude below this redundancy
    dlt_ok: Array  # () bool: 6 or more control points, the DLT start is allowed
    pok: Array  # () bool: phi-omega-kappa (else omega-phi-kappa)
    subsets: Array  # (k, 6) int: indices of the random subsets of the robust start
    camera: FrameCamera
    max_steps: Array  # () int: Gauss-Newton iterations per adjustment


class Output(eqx.Module):
    """What the compiled solver returns for each image (local coordinates):
    the shapes below per image, with the lanes last inside the compiled code
    (``params`` ``(6, B)``) and the images first once :func:`pack`-ed and
    :func:`unpack`-ed (``params`` ``(B, 6)``)."""

    params: Array  # (6,) (C - origin, angles), angles wrapped to (-pi, pi]
    start: Array  # (6,) the start the adjustment ran from
    sigma0: Array  # () a-posteriori sigma0 (NaN at zero redundancy)
    qxx: Array  # (6, 6) cofactor matrix (A^T P A)^-1
    residuals: Array  # (m, 2) computed - observed, all points
    redundancy: Array  # (m, 2) redundancy numbers (0 where not used)
    w: Array  # (m, 2) v / sqrt(r) (weighted; divide by sigma0 for tau)
    depth: Array  # (m,) distance in front of the camera
    axis: Array  # (3,) viewing direction in the world
    result: Array  # () int photax.RESULTS code of the adjustment
    steps: Array  # () int iterations of the final adjustment
    used: Array  # (m,) bool: control points in the final adjustment
    stat_at: Array  # (m, 2) the statistic with which a point was excluded (NaN otherwise)
    critical: Array  # () the critical value of the final test
    retry: Array  # () int: the cheap path asks for the robust one: 0 no, 1 only the test failed, 2 everything

    @classmethod
    def blank(cls, m: int) -> Output:
        """Zeros of every field's shape and dtype (a new field adds its line here)."""
        z = jnp.zeros
        return cls(
            params=z(6),
            start=z(6),
            sigma0=z(()),
            qxx=z((6, 6)),
            residuals=z((m, 2)),
            redundancy=z((m, 2)),
            w=z((m, 2)),
            depth=z(m),
            axis=z(3),
            result=z((), int),
            steps=z((), int),
            used=z(m, bool),
            stat_at=z((m, 2)),
            critical=z(()),
            retry=z((), int),
        )


def pack(out: Output) -> Array:
    """All leaves as one float64 ``(L, B)`` array, the lanes still last: one
    device-to-host copy instead of 15.  The host transposes it (``.T``: the
    images first, as :func:`unpack` reads it): transposed inside the program,
    XLA fused the computation of each output into a strided transposing copy,
    twice where two outputs read it (measured: ~1 us per image)."""
    leaves = jax.tree_util.tree_leaves(out)
    b = leaves[0].shape[-1]
    return jnp.concatenate([x.reshape(-1, b).astype(float) for x in leaves], axis=0)


class HostOutput(NamedTuple):
    """:class:`Output` on the host, the images first (numpy leaves): a plain
    tuple, whose attributes cost nothing to read (an ``equinox.Module``'s
    cost a microsecond each, and a single resection reads about forty).
    Its fields are :class:`Output`'s, in the same order."""

    params: np.ndarray
    start: np.ndarray
    sigma0: np.ndarray
    qxx: np.ndarray
    residuals: np.ndarray
    redundancy: np.ndarray
    w: np.ndarray
    depth: np.ndarray
    axis: np.ndarray
    result: np.ndarray
    steps: np.ndarray
    used: np.ndarray
    stat_at: np.ndarray
    critical: np.ndarray
    retry: np.ndarray


@functools.lru_cache(maxsize=32)
def _layout(m: int):
    blank = Output.blank(m)
    names = [f.name for f in dataclasses.fields(Output)]
    assert tuple(names) == HostOutput._fields, "HostOutput must list Output's fields in order"
    layout, i = [], 0
    for name in names:
        x = getattr(blank, name)
        size = int(np.prod(x.shape))
        layout.append((slice(i, i + size), x.shape, x.dtype))
        i += size
    return layout


def unpack(flat: np.ndarray, m: int) -> HostOutput:
    """Inverse of :func:`pack` (transposed: ``flat`` ``(..., L)``, the images first) for any
    leading batch axes; numpy leaves."""
    leaves = []
    for where, shape, dtype in _layout(m):
        v = flat[..., where].reshape(flat.shape[:-1] + shape)
        leaves.append(v > 0.5 if np.issubdtype(dtype, np.bool_) else (v.astype(dtype) if dtype != v.dtype else v))
    return HostOutput(*leaves)
