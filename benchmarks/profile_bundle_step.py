"""Where one Levenberg–Marquardt iteration of photax's bundle adjustment spends its time.

Run:  python benchmarks/profile_bundle_step.py [--grid 30] [--repeat 5]

On a generated BAL block of ``g x g`` images (:func:`bench_bundle.synthetic_bal`,
the block of ``bench_bundle.py --grid``), each phase of one iteration is
jitted on its own and timed warm (median of ``--repeat`` runs, CPU seconds
of the process, all threads, and wall seconds), one BLAS thread as in the
solver: the trial step of the banded solver (``_trial``, with the
linearisation at its candidate as in the least-squares loop) and its parts:
the per-observation Jacobians, the Schur pass (reduced right-hand side and
the pair products), the scatter into the band, the banded Cholesky and
solve, the back-substitution for the points.  The parts overlap (each is a
separate program; XLA fuses differently inside the whole), so they do not
add up to the trial exactly.
"""

from __future__ import annotations

import argparse
import functools
import os
import pathlib
import resource
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from bench_bundle import synthetic_bal  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from photax.bundle import _linearise as li  # noqa: E402
from photax.bundle import _schur as sc  # noqa: E402
from photax.bundle import _solver as so  # noqa: E402
from photax.bundle import _sparse as sp  # noqa: E402
from photax.io.bal import bal_problem  # noqa: E402


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=int, default=30)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    print(f"reproduce with: python benchmarks/profile_bundle_step.py --grid {args.grid} --repeat {args.repeat}")
    d = synthetic_bal(args.grid, 0)
    p = bal_problem(d)
    s, n_c, _, origin = p.analyse("damped")
    state = so._start_state(p, origin)
    none, one, lam = jnp.asarray(0), jnp.asarray(1.0), jnp.asarray(1e-4)
    lin = li._linearise(state, s, none, one, n_c)
    damp = lam * lin.d_c * s.mask_c + (1.0 - s.mask_c)
    band = jax.jit(sc._reduced_band, static_argnames="n_c")
    m, rhs, vinv = band(lin, s, lam, n_c, damp)
    f = jax.jit(sp.band_cholesky)(m)

    def backsub(lin, x, vinv):
        dce = x[s.image_ext]
        wdc = jax.ops.segment_sum(sc._jt_dot(lin.jp, sc._jc_dot(lin.jc, dce[s.obs_image])), s.obs_point,
                                  num_segments=state.xyz.shape[0])  # fmt: skip
        return -jnp.sum(vinv * (lin.g_p + wdc)[:, None, :], axis=2) * s.mask_p

    phases = {
        "trial step (whole, with the linearisation at its candidate)": (functools.partial(
            sc._trial, n_c=n_c, solver="band", relinearise=True), (state, lin, s, lam, none, one)),
        "  linearisation (Jacobians, V, g, diag U)": (li._linearise, (state, s, none, one, n_c)),
        "    of which per-observation Jacobians and gradients": (jax.jit(li._observation_terms), (state, s, none, one)),
        "  Schur pass (rhs, pair products W V^-1 W^T and U)": (jax.jit(sc._schur_blocks, static_argnames="n_c"), (lin, s, lam, n_c)),
        "    of which V^-1 and the reduced rhs": (jax.jit(lambda lin: sc._reduced_rhs(lin, s, sc._damped_vinv(lin, s, lam), n_c)), (lin,)),
        "  Schur pass + scatter into the band": (band, (lin, s, lam, n_c, damp)),
        "  band Cholesky": (jax.jit(sp.band_cholesky), (m,)),
        "  band solve": (jax.jit(sp.band_solve), (f, jnp.append(rhs, 0.0)[s.band_perm], rhs[s.band_border])),
        "  back-substitution of the points": (jax.jit(backsub), (lin, rhs, vinv)),
        "cost alone (one projection pass)": (li._cost, (state, s, none, one)),
    }  # fmt: skip
    res: dict = {}
    with threadpool_limits(1, user_api="blas"):
        for fn, a in phases.values():
            jax.block_until_ready(fn(*a))
        for _ in range(args.repeat):
            for k, (fn, a) in phases.items():
                c0, w0 = _cpu(), time.perf_counter()
                jax.block_until_ready(fn(*a))
                res.setdefault(k, []).append((_cpu() - c0, time.perf_counter() - w0))
    print(f"{len(d.cameras)} images, {len(d.points)} points, {len(d.observations)} observations; band "
          f"{tuple(s.band_perm.shape)} (chunks x width), border {s.band_border.shape[0]}")  # fmt: skip
    print(f"{'phase':62s} {'CPU s':>7s} {'wall s':>7s}")
    for k in phases:
        c, w = np.median(res[k], axis=0)
        print(f"{k:62s} {c:7.3f} {w:7.3f}")
    print(f"load average {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
