"""Write notebooks/09_fusion_and_registration.ipynb (without outputs).

Run: ``python notebooks/build_09_fusion_and_registration.py``.  The notebook is
committed without outputs; tests/test_notebooks.py executes it.
"""

from _build import FIND_SHARED, write_notebook

CELLS = [
    (
        "md",
        """# Fusion, image-to-image registration, and morphing

Three of the remote-sensing notes' applications of geometric transformation:

1. **data fusion** (数据融合): a panchromatic and a multispectral image pan-sharpened by each of
   `photax.fusion`'s methods, side by side, with their quality on Wald's protocol;
2. **registration** (影像配准): a target image registered to a reference by `photax.coregister`
   (phase correlation, windows tested for reliability, a thin-plate-spline model), its shift field
   before and after, and where a thin-plate spline beats a polynomial;
3. **morphing** (变形): `photax.morph`, the in-between frames of two images related by control lines.

The pan/MS pair is orthority's test pair (`../../shared/data/orthority/pan_sharp/`, see SOURCES.md);
without it the notebook makes a small synthetic pair instead.""",
    ),
    (
        "code",
        """import pathlib
import tempfile
import time

import matplotlib.pyplot as plt
import numpy as np
from scipy.ndimage import gaussian_filter

import photax as ptx
from photax import fusion


"""
        + FIND_SHARED
        + """

pan_path, ms_path = find_shared("orthority/pan_sharp/pan.tif"), find_shared("orthority/pan_sharp/ms.tif")
if pan_path and ms_path:
    import warnings

    with warnings.catch_warnings():  # the pair has no georeference: rasterio says so
        warnings.simplefilter("ignore")
        pan = ptx.read_geotiff(pan_path)[0][0]
        ms = ptx.read_geotiff(ms_path)[0]
    print(f"orthority's pair: PAN {pan.shape}, MS {ms.shape} ({pan.dtype})")
else:  # a synthetic pair: a smooth colour scene, the PAN its band mean at 4x the MS resolution
    rng = np.random.default_rng(0)
    scene = np.stack([gaussian_filter(rng.random((512, 768)), s) for s in (3, 4, 5)])
    scene = (40 + 180 * (scene - scene.min()) / np.ptp(scene)).astype(np.float32)
    pan = scene.mean(axis=0).astype(np.uint8)
    ms = fusion.degrade(scene, 4).astype(np.uint8)
    print("orthority's pan/MS pair not available: a synthetic pair", pan.shape, ms.shape)
ratio = pan.shape[0] // ms.shape[1]""",
    ),
    (
        "md",
        """## 1. Pan-sharpening, every method

Component substitution (Brovey, IHS, PCA, Gram-Schmidt, GSA) injects the PAN's detail through one
intensity component; multiresolution analysis (HPF, SFIM, MTF-GLP, MTF-GLP-HPM) adds the PAN's high
frequencies per band. The table is Wald's protocol: the pair reduced by the resolution ratio, fused,
and compared with the original MS (ERGAS and SAM: lower is better; Q2n, UIQI, SCC: 1 is ideal), and
QNR of the full-resolution product (1 is ideal). A crop is shown.""",
    ),
    (
        "code",
        """rows = []
fused = {}
for method in fusion.METHODS:
    t0 = time.perf_counter()
    out = ptx.pansharpen(pan, ms, method)
    seconds = time.perf_counter() - t0
    fused[method] = out.image
    wald = fusion.wald_protocol(pan, ms, method)
    q = fusion.qnr(out.image.astype(np.float64), ms.astype(np.float64), pan, ratio)
    rows.append((method, wald["ERGAS"], wald["SAM"], wald["Q2n"], wald["UIQI"], wald["SCC"], q["QNR"], seconds))

print(f"{'method':12s} {'ERGAS':>7s} {'SAM':>7s} {'Q2n':>7s} {'UIQI':>7s} {'SCC':>7s} {'QNR':>7s} {'s':>6s}")
for r in sorted(rows, key=lambda r: r[1]):
    print(f"{r[0]:12s} " + " ".join(f"{v:7.4f}" for v in r[1:7]) + f" {r[7]:6.2f}")

r0, c0, size = pan.shape[0] // 2 - 96, pan.shape[1] // 2 - 128, 192
crop = (slice(r0, r0 + size), slice(c0, c0 + size))


def rgb(img):
    x = np.moveaxis(np.asarray(img, dtype=float)[:3], 0, -1)
    lo, hi = np.percentile(x, [1, 99])
    return np.clip((x - lo) / (hi - lo), 0, 1)


upsampled = ms.repeat(ratio, axis=1).repeat(ratio, axis=2)
panels = [("PAN", pan[crop]), ("MS (pixels repeated)", rgb(upsampled[(slice(None), *crop)]))]
panels += [(m, rgb(fused[m][(slice(None), *crop)])) for m in fusion.METHODS]
fig, axes = plt.subplots(2, 6, figsize=(16, 6))
for ax, (name, img) in zip(axes.flat, panels):
    ax.imshow(img, cmap="gray" if img.ndim == 2 else None)
    ax.set_title(name, fontsize=10)
for ax in axes.flat:
    ax.set_axis_off()
fig.tight_layout()""",
    ),
    (
        "md",
        """## 2. Co-registration: a target registered to a reference

The reference is a 512 x 512 px part of the PAN image; the target is the same ground seen with a
global shift of (3.7, -2.3) px plus a smooth +-2 px distortion, with one part of the scene changed
(a block replaced by other content) and one flat (no texture). `photax.coregister` measures the global
shift, then a grid of 64 px windows, rejects the windows that fail a reliability test (each reason
counted), and fits a thin-plate spline to the rest. The arrows are the windows' shifts (x 20) before
the correction and after it (the corrected target registered again).""",
    ),
    (
        "code",
        """ref = pan[:512, :512].astype(float) if pan.shape[0] >= 512 and pan.shape[1] >= 512 else pan.astype(float)
size = ref.shape[0]


def field(x, y):
    u, v = x / size, y / size
    return (3.7 + 2 * np.sin(2 * np.pi * (0.6 * u + 0.2)) * np.cos(2 * np.pi * 0.4 * v),
            -2.3 + 2 * np.cos(2 * np.pi * (0.5 * v + 0.1)) * np.sin(2 * np.pi * (0.3 * u + 0.3)))


yy, xx = np.mgrid[0:size, 0:ref.shape[1]].astype(float)
dx, dy = field(xx, yy)
# the target shows the reference's ground at q - d(q): target(p + d) = reference(p)
target = np.array(ptx.resample(ref, xx - dx, yy - dy, "bspline"))
target[64:192, 320:448] = np.flipud(np.fliplr(target[64:192, 320:448]))  # changed content
target[384:448, 64:128] = np.nanmean(target)  # a flat field (new tarmac)
ref_n = np.nan_to_num(ref, nan=float(np.nanmean(ref)))

t0 = time.perf_counter()
reg = ptx.coregister(ref_n, target, model="tps")
print(f"coregister: {time.perf_counter() - t0:.1f} s, global shift {reg.global_shift.round(3)} px, "
      f"{reg.iterations} passes; windows {reg.counts}")


def truth(p):  # the shift at reference pixels p: q = p + d(q), by fixed point
    q = np.array(p, dtype=float)
    for _ in range(50):
        q = p + np.stack(field(q[..., 0], q[..., 1]), axis=-1)
    return q - p


ok = reg.reliable
err = reg.matches[ok] - reg.centres[ok] - truth(reg.centres[ok])
print(f"reliable windows' shifts against the truth: rms {np.sqrt(np.mean(np.sum(err**2, 1))):.3f} px")

corrected = reg.resample(target, ref.shape)
after = ptx.coregister(ref_n, np.nan_to_num(corrected, nan=float(np.nanmean(corrected))), model="affine")
colours = {"ok": "tab:green", "no data": "0.6", "textureless": "tab:blue", "weak peak": "tab:red",
           "dissimilar": "tab:orange", "outlier": "tab:purple"}
fig, axes = plt.subplots(1, 2, figsize=(13, 6.2))
for ax, r, title in ((axes[0], reg, "before: target against reference"),
                     (axes[1], after, "after: corrected target against reference")):
    ax.imshow(ref_n, cmap="gray")
    m = r.reliable
    ax.quiver(r.centres[m, 0], r.centres[m, 1], r.shifts[m, 0], r.shifts[m, 1], color=colours["ok"], angles="xy",
              scale_units="xy", scale=1 / 20, width=0.004, label=f"ok ({m.sum()})")
    for status, colour in list(colours.items())[1:]:  # the rejected windows: where, and why
        m = r.status == status
        if m.any():
            ax.plot(r.centres[m, 0], r.centres[m, 1], "X", color=colour, ms=9, label=f"{status} ({m.sum()})")
    rms = np.sqrt(np.mean(np.sum(r.shifts[r.reliable] ** 2, 1)))
    ax.set_title(f"{title}\\n(arrows x 20; rms shift {rms:.3f} px)")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_axis_off()
fig.tight_layout()""",
    ),
    (
        "md",
        """### Thin-plate spline or polynomial?

The same reliable windows fitted by a 2nd-order polynomial and by the thin-plate spline; each map is the
model's shift minus the true one over the reference. The polynomial cannot follow the +-2 px waves; the
spline goes through every window and is off only between windows and outside them.""",
    ),
    (
        "code",
        """grid = np.stack(np.meshgrid(np.arange(0, ref.shape[1], 4.0), np.arange(0, size, 4.0)), axis=-1)
true_shift = truth(grid)
poly = ptx.fit_polynomial(reg.centres[ok], reg.matches[ok], 2)
maps = {"polynomial 2": np.asarray(poly(grid)) - grid - true_shift,
        "thin-plate spline": np.asarray(reg.model(grid)) - grid - true_shift}
fig, axes = plt.subplots(1, 2, figsize=(12, 5))
for ax, (name, e) in zip(axes, maps.items()):
    mag = np.hypot(e[..., 0], e[..., 1])
    im = ax.imshow(mag, cmap="magma", vmin=0, vmax=1.0, extent=(0, ref.shape[1], size, 0))
    ax.plot(reg.centres[ok, 0], reg.centres[ok, 1], "c.", ms=4)
    ax.set_title(f"{name}: rms {np.sqrt(np.mean(mag**2)):.3f} px")
    ax.set_axis_off()
fig.colorbar(im, ax=axes, label="|model - truth| (px)", shrink=0.8);""",
    ),
    (
        "md",
        """## 3. Morphing

Image A is a crop of the Gram-Schmidt product; image B is the same crop turned by 20 degrees about its
centre and shifted. Three control lines in A and their images in B drive Beier and Neely's field
morphing; every frame warps both images to the interpolated lines and cross-dissolves them.""",
    ),
    (
        "code",
        """a_img = fused["gs"][(slice(None), *crop)].astype(float)
h, w = a_img.shape[1:]
ang = np.deg2rad(20.0)
rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
centre, move = np.array([w / 2, h / 2]), np.array([8.0, -5.0])
to_b = lambda p: (p - centre) @ rot.T + centre + move  # noqa: E731
yy, xx = np.mgrid[0:h, 0:w].astype(float)
src = (np.stack([xx, yy], -1) - centre - move) @ rot + centre  # B(x) = A(to_b^-1(x))
b_img = np.asarray(ptx.resample(a_img, src[..., 0], src[..., 1], "cubic"))
b_img = b_img[[2, 0, 1]]  # and other colours: B's bands in another order
lines_a = np.array([[[40.0, 40.0], [150.0, 50.0]], [[50.0, 150.0], [140.0, 120.0]], [[100.0, 70.0], [100.0, 110.0]]])
lines_b = to_b(lines_a)
frames = ptx.morph_sequence(a_img, b_img, lines_a, lines_b, frames=5)
fig, axes = plt.subplots(1, 5, figsize=(16, 3.6))
for ax, f, t in zip(axes, frames, np.linspace(0, 1, 5)):
    ax.imshow(rgb(np.nan_to_num(f)))
    lt = (1 - t) * lines_a + t * lines_b
    for ln in lt:
        ax.plot(ln[:, 0], ln[:, 1], "y-", lw=2)
    ax.set_title(f"t = {t:.2f}")
    ax.set_axis_off()
fig.tight_layout()
gif = ptx.write_sequence(frames, pathlib.Path(tempfile.mkdtemp()) / "morph.gif", duration=0.2)
print("animated GIF:", gif, f"{gif.stat().st_size / 1e3:.0f} kB")""",
    ),
]

if __name__ == "__main__":
    write_notebook(CELLS, "09_fusion_and_registration.ipynb")
