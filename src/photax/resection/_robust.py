"""The robust path, for the few images the cheap one hands over.

**Start**: an image whose cheap adjustment only failed the blunder test
starts from that least-squares solution (``use_init``); any other by
least median of squares (Rousseeuw 1984: no threshold, tolerant of up to
half the points being blunders): the linear candidates from all
control points and from 32 seeded random subsets of 6 (:func:`subsets`;
homography on their first 4), the one with the smallest median squared
reprojection error wins; candidates that put points behind the camera lose.

**Data snooping** (Baarda 1968; Pope 1976 tau test): while the largest
standardised residual exceeds the critical value and redundancy allows,
the worst point (both coordinates) is excluded - with every other point
whose test fails even after the flagged points' pull on it is taken away
(:func:`._adjust.test`: a large set is not refitted once per blunder) -
and the adjustment repeated from the start - inside the compiled function, a ``lax.while_loop``
with one adjustment in its body (traced once).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from . import _adjust, _lanes, _linear
from ._types import Inputs, Options, Output

N_SUBSETS = 32  # random subsets for the robust start: P(all 32 contain a blunder) < 1e-4 at 20 % blunders
SEED = 20240601  # fixed: the same input gives the same answer


@functools.lru_cache(maxsize=128)
def subsets(n_ctrl: int) -> np.ndarray:
    """``(32, 6)`` seeded random subsets of ``range(n_ctrl)`` (distinct points when there are 6)."""
    rng = np.random.default_rng(SEED + n_ctrl)
    return rng.random((N_SUBSETS, n_ctrl)).argsort(axis=1)[:, np.arange(6) % n_ctrl]


def lmeds_start(uv, ground, ctrl, basis, subset_idx, dlt_ok, pok):
    """The least-median-of-squares start, a 6-vector."""
    r_all, c_all, is_dlt, err = _linear.candidates(uv, ground, ctrl, basis, subset_idx)
    n_ctrl = jnp.sum(ctrl.astype(int))
    median = jnp.take(jnp.sort(err, axis=1), (n_ctrl - 1) // 2, axis=1)
    score = jnp.where(jnp.asarray(is_dlt) & ~dlt_ok, jnp.inf, median)
    best = jnp.argmin(jnp.where(jnp.isnan(score), jnp.inf, score))
    return _linear.to_parameters(r_all[best], c_all[best], pok)


def starts(inp: Inputs, opt: Options):
    """Starts ``(6, B)`` for a chunk of lanes: ``inp.init`` where
    ``inp.use_init``, else the LMedS start.  A chunk whose images all have a
    start (the user's, or the cheap path's solution for images that only
    failed the test) skips the LMedS candidates: a ``cond`` on the whole
    chunk, so it is not computed and thrown away (they were three quarters
    of the robust path's time)."""

    def lmeds(i: Inputs):
        uv = _linear.opencv_uv(i.xy, opt.camera)
        return lmeds_start(uv, i.ground, i.ctrl, i.basis, opt.subsets, opt.dlt_ok, opt.pok)

    return jax.lax.cond(
        jnp.all(inp.use_init),
        lambda: inp.init,
        lambda: _lanes.sel(inp.use_init, inp.init, jax.vmap(lmeds)(inp.per_image()).T),
    )


def solve_robust(inp: Inputs, opt: Options, start) -> Output:
    """From ``start`` ``(6, B)`` (:func:`starts`): adjust - test - exclude the
    worst point, until the test passes; each lane snoops on its own (a lane
    whose test passed is left as it is while the others go on)."""
    m, b = inp.ctrl.shape

    def body(carry):  # adjust; test; exclude the worst point if the test fails
        out, used, stat_at, go, c = carry
        new = _adjust.adjust(start, inp, used, opt, active=go)
        exclude, worst, stat, c_new = _adjust.test(new, used, opt)
        out = jax.tree_util.tree_map(lambda x, y: _lanes.sel(go, x, y), new, out)
        hit = worst & (go & exclude)[None]  # (m, B): the points excluded now
        return (out, used & ~hit, jnp.where(hit[:, None, :], stat, stat_at), go & exclude, jnp.where(go, c_new, c))

    blank = Output.blank(m)
    first = {
        k: jnp.zeros(getattr(blank, k).shape + (b,), getattr(blank, k).dtype)
        for k in ("params", "sigma0", "qxx", "residuals", "redundancy", "w", "depth", "axis", "result", "steps")
    }
    carry = (first, inp.ctrl, jnp.full((m, 2, b), jnp.nan), jnp.ones(b, bool), jnp.zeros(b))
    out, used, stat_at, _, c = jax.lax.while_loop(lambda s: jnp.any(s[3]), body, carry)
    return Output(**out, start=start, used=used, stat_at=stat_at, critical=c, retry=jnp.zeros(b, int))
