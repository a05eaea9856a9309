"""Image-to-image registration: ``photax.coregister`` beside scikit-image's ``phase_cross_correlation`` on
the synthetic pairs of tests/test_coregister.py (rendered analytically: the shift field is exact).

    python benchmarks/bench_coregister.py [--repeat N]

1. Global shift (3.7, -2.3) px on a 512 px pair: error and median time of ``photax.phase_correlation``
   (Hann taper, low-pass weighted, upsampled DFT) and of ``skimage.registration.phase_cross_correlation``
   (``upsample_factor=100``), same process, interleaved.
2. Local field (3.7 px + a smooth +-2 px field, 30 % of the windows on changed content, 2 flat) on a
   384 px pair: ``photax.coregister(model="tps")`` against scikit-image run on each 64 px window (no
   taper, no iteration, no reliability test; and again on Hann-tapered windows): rms error over the
   windows photax keeps, and how many of the changed windows each would have used.  AROSICS (the tool this follows) is not installed here: it
   needs GDAL's Python bindings.
Writes ``benchmarks/results/bench_coregister.json``.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np
from _common import add_threads_option, apply_threads, median_times, record, start

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from test_coregister import _cells, _pair  # noqa: E402 -- the tests' exact synthetic pairs

import photax as ptx  # noqa: E402
from photax.matching.coregister import phase_correlation  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="runs per function (median)")
    add_threads_option(parser)
    args = parser.parse_args()
    apply_threads(args)
    from skimage.registration import phase_cross_correlation

    start("bench_coregister")
    ref, tgt, _, _, _ = _pair(512, 64, (3.7, -2.3))
    ours = phase_correlation(ref, tgt, upsample=100)[0]
    sk = -phase_cross_correlation(ref, tgt, upsample_factor=100)[0][::-1]
    t = median_times(
        {
            "photax": lambda: phase_correlation(ref, tgt, upsample=100),
            "skimage": lambda: phase_cross_correlation(ref, tgt, upsample_factor=100),
        },
        repeat=args.repeat,
    )
    e_ours, e_sk = np.abs(ours - [3.7, -2.3]).max(), np.abs(sk - [3.7, -2.3]).max()
    print(f"global shift, 512 px: photax {ours} (max error {e_ours:.4f} px, {t['photax'] * 1e3:.0f} ms); "
          f"scikit-image {sk} (max error {e_sk:.4f} px, {t['skimage'] * 1e3:.0f} ms)")  # fmt: skip
    record("global_shift_512", photax_error_px=float(e_ours), skimage_error_px=float(e_sk),
           photax_s=t["photax"], skimage_s=t["skimage"], ratio=t["photax"] / t["skimage"])  # fmt: skip

    ref, tgt, truth, ch, _ = _pair(384, 64, (3.7, -2.3), amp=2.0, changed=0.3, flat=2)
    reg = ptx.coregister(ref, tgt, window=64, model="tps")
    ok = reg.reliable
    err = reg.matches[ok] - reg.centres[ok] - truth(reg.centres[ok])
    windows = []
    for cx, cy in reg.centres:
        r0, c0 = int(cy + 0.5) - 32, int(cx + 0.5) - 32
        s = phase_cross_correlation(
            ref[r0 : r0 + 64, c0 : c0 + 64], tgt[r0 : r0 + 64, c0 : c0 + 64], upsample_factor=100
        )
        windows.append(-s[0][::-1])
    windows = np.array(windows)
    err_sk = windows[ok] - truth(reg.centres[ok])
    hann = np.outer(np.hanning(64), np.hanning(64))
    tapered = []  # scikit-image given photax's taper: the windows' edges no longer wrap around
    for cx, cy in reg.centres[ok]:
        r0, c0 = int(cy + 0.5) - 32, int(cx + 0.5) - 32
        a, b = ref[r0 : r0 + 64, c0 : c0 + 64], tgt[r0 : r0 + 64, c0 : c0 + 64]
        s = phase_cross_correlation((a - a.mean()) * hann, (b - b.mean()) * hann, upsample_factor=100)
        tapered.append(-s[0][::-1])
    err_tap = np.array(tapered) - truth(reg.centres[ok])
    changed = np.array([c in ch for c in _cells(reg, 64)])
    t = median_times(
        {
            "photax": lambda: ptx.coregister(ref, tgt, window=64, model="tps"),
            "skimage": lambda: [
                phase_cross_correlation(
                    ref[int(y + 0.5) - 32 : int(y + 0.5) + 32, int(x + 0.5) - 32 : int(x + 0.5) + 32],
                    tgt[int(y + 0.5) - 32 : int(y + 0.5) + 32, int(x + 0.5) - 32 : int(x + 0.5) + 32],
                    upsample_factor=100,
                )
                for x, y in reg.centres
            ],  # fmt: skip
        },
        repeat=max(3, args.repeat // 2),
    )
    rms = lambda v: float(np.sqrt(np.mean(np.sum(v**2, axis=1))))  # noqa: E731
    print(f"local field, 384 px, {ok.sum()} reliable of {len(ok)} windows: photax rms {rms(err):.4f} px "
          f"({t['photax']:.2f} s, changed windows used: {int((ok & changed).sum())} of {changed.sum()}); "
          f"scikit-image per window rms {rms(err_sk):.4f} px on the same windows ({t['skimage']:.2f} s, "
          f"no test: all {changed.sum()} changed windows used); scikit-image on Hann-tapered windows "
          f"rms {rms(err_tap):.4f} px")  # fmt: skip
    record("local_field_384", photax_rms_px=rms(err), skimage_rms_px=rms(err_sk), skimage_tapered_rms_px=rms(err_tap),
           photax_s=t["photax"],
           skimage_s=t["skimage"], reliable=int(ok.sum()), windows=len(ok), changed=int(changed.sum()),
           changed_used_by_photax=int((ok & changed).sum()))  # fmt: skip


if __name__ == "__main__":
    main()
