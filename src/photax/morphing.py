"""Morphing (the notes' 变形): the in-between frames of two images related by control lines or points.

A frame at ``t`` in [0, 1] has its control features at ``(1 - t) a + t b`` (each endpoint or point
interpolated); each image is warped so that its features land there, and the two warps are cross-dissolved:
``frame = (1 - t) warp_a + t warp_b``.  ``t = 0`` returns image A, ``t = 1`` image B.

* **Control lines** ``(n, 2, 2)`` (segments ``P -> Q`` in pixel ``(column, row)``): the field morphing of
  Beier & Neely (1992).  For a frame pixel ``X`` and a frame line ``PQ``::

      u = (X - P).(Q - P) / |Q - P|^2,    v = (X - P).perp(Q - P) / |Q - P|^2
      X'_i = P' + u (Q' - P') + v perp(Q' - P')

  (``perp`` turns a vector by 90 degrees; ``P'Q'`` the line in the source image), and the source position
  is ``X + sum w_i (X'_i - X) / sum w_i`` with ``w_i = (length_i^p / (a + dist_i))^b``, ``dist_i`` the
  distance of ``X`` to the segment.  Here ``v`` is measured in line lengths, so each line carries a
  similarity (rotation, uniform scale, shift) and lines related by one similarity reproduce it everywhere;
  Beier & Neely's ``v`` in pixels (``keep_distance=True``) keeps the distance to the line instead, which
  only rigid motions reproduce.  Any affine map is reproduced *on* the lines (as ``a -> 0``), not
  between them.
* **Control points** ``(n, 2)``: a thin-plate spline (:func:`photax.fit_tps`) from the frame's points to
  each image's, through every point.

Images are ``(..., H, W)`` (bands first, as :func:`photax.resample`), float or integer, both of one shape;
samples outside an image are NaN (``fill`` replaces them).
"""

from __future__ import annotations

import pathlib

import numpy as np


def _features(lines_a, lines_b):
    a = np.asarray(lines_a, dtype=float)
    b = np.asarray(lines_b, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"lines_a and lines_b must have one shape, got {a.shape} and {b.shape}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("control lines / points must be finite")
    if a.ndim == 3 and a.shape[1:] == (2, 2):
        for name, x in (("lines_a", a), ("lines_b", b)):
            short = np.flatnonzero(np.linalg.norm(x[:, 1] - x[:, 0], axis=1) < 1e-9)
            if len(short):
                raise ValueError(f"{name} has lines of zero length at rows {short.tolist()}")
        if len(a) < 1:
            raise ValueError("give at least one control line")
        return a, b, "lines"
    if a.ndim == 2 and a.shape[1] == 2:
        if len(a) < 3:
            raise ValueError(f"a thin-plate warp needs at least 3 control points, got {len(a)}")
        return a, b, "points"
    raise ValueError(f"control features must be lines (n, 2, 2) or points (n, 2), got {a.shape}")


def field_warp(xy, lines_dst, lines_src, *, a: float = 1e-3, b: float = 2.0, p: float = 0.5, keep_distance=False):
    """Beier-Neely source positions ``(..., 2)`` of the points ``xy`` ``(..., 2)`` of an image whose lines
    are ``lines_dst`` ``(n, 2, 2)``, in the image whose lines are ``lines_src`` (module docstring)."""
    x = np.asarray(xy, dtype=float)
    dst = np.asarray(lines_dst, dtype=float)
    src = np.asarray(lines_src, dtype=float)
    flat = x.reshape(-1, 2)
    num = np.zeros_like(flat)
    den = np.zeros(len(flat))
    for (p0, q0), (p1, q1) in zip(dst, src):
        e, e1 = q0 - p0, q1 - p1
        length2 = e @ e
        perp, perp1 = np.array([-e[1], e[0]]), np.array([-e1[1], e1[0]])
        d = flat - p0
        u = d @ e / length2
        if keep_distance:
            v = d @ perp / np.sqrt(length2)
            moved = p1 + u[:, None] * e1 + v[:, None] * perp1 / np.linalg.norm(e1)
        else:
            v = d @ perp / length2
            moved = p1 + u[:, None] * e1 + v[:, None] * perp1
        beside = np.abs(d @ perp) / np.sqrt(length2)  # distance to the line, for 0 <= u <= 1
        dist = np.where(u < 0, np.linalg.norm(d, axis=1), np.where(u > 1, np.linalg.norm(flat - q0, axis=1), beside))
        w = (length2 ** (p / 2) / (a + dist)) ** b
        num += w[:, None] * (moved - flat)
        den += w
    return (flat + num / den[:, None]).reshape(x.shape)


def morph(
    image_a,
    image_b,
    lines_a,
    lines_b,
    t: float,
    *,
    a: float = 1e-3,
    b: float = 2.0,
    p: float = 0.5,
    keep_distance: bool = False,
    resampling: str = "bilinear",
    fill=None,
):
    """The morph frame at ``t`` between ``image_a`` and ``image_b`` (module docstring).

    Args:
        image_a, image_b: ``(..., H, W)`` images of one shape.
        lines_a, lines_b: control lines ``(n, 2, 2)`` (``[[x0, y0], [x1, y1]]`` each, pixels) or control
            points ``(n, 2)``, corresponding row by row.
        t: in [0, 1]: 0 gives image A, 1 image B.
        a, b, p: Beier-Neely's weight ``(length^p / (a + dist))^b``: ``a`` small pins the pixels on a
            line to it, ``b`` how fast a line's influence falls off, ``p`` how much longer lines count.
        keep_distance: Beier-Neely's original ``v`` in pixels (module docstring).
        resampling: kernel of :func:`photax.resample`.
        fill: value for samples outside an image (default NaN; the other image's where it has one).

    Returns:
        ``(..., H, W)`` float frame.

    Raises:
        ValueError: ``t`` outside [0, 1], images of different shapes, lines of zero length, fewer than 3
            points, or features of different shapes.

    Examples:
        At ``t = 0`` the frame is image A, at ``t = 1`` image B (here with three control points that
        do not move, so the warp is the identity and only the cross-dissolve is left):

        >>> import numpy as np
        >>> import photax as ptx
        >>> a, b = np.zeros((20, 30)), np.full((20, 30), 100.0)
        >>> pts = np.array([[5.0, 5.0], [25.0, 15.0], [5.0, 15.0]])
        >>> [float(np.asarray(ptx.morph(a, b, pts, pts, t))[10, 15]) for t in (0.0, 0.25, 1.0)]
        [0.0, 25.0, 100.0]
    """
    from .resampling import resample

    if not (np.isscalar(t) and 0.0 <= float(t) <= 1.0):
        raise ValueError(f"t must be a number in [0, 1], got {t!r}")
    t = float(t)
    ia = np.asarray(image_a)
    ib = np.asarray(image_b)
    if ia.shape != ib.shape or ia.ndim < 2:
        raise ValueError(f"image_a and image_b must be (..., H, W) of one shape, got {ia.shape} and {ib.shape}")
    fa, fb, kind = _features(lines_a, lines_b)
    ft = (1 - t) * fa + t * fb
    h, w = ia.shape[-2:]
    grid = np.stack(np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float)), axis=-1)
    if kind == "lines":
        to_a = field_warp(grid, ft, fa, a=a, b=b, p=p, keep_distance=keep_distance)
        to_b = field_warp(grid, ft, fb, a=a, b=b, p=p, keep_distance=keep_distance)
    else:
        from .polynomial import fit_tps

        to_a = np.asarray(fit_tps(ft, fa)(grid))
        to_b = np.asarray(fit_tps(ft, fb)(grid))
    wa = np.asarray(resample(ia.astype(float), to_a[..., 0], to_a[..., 1], resampling))
    wb = np.asarray(resample(ib.astype(float), to_b[..., 0], to_b[..., 1], resampling))
    # where one warp falls outside its image, the other image alone (NaN where both do)
    out = np.where(np.isnan(wa), wb, np.where(np.isnan(wb), wa, (1 - t) * wa + t * wb))
    return out if fill is None else np.where(np.isnan(out), fill, out)


def morph_sequence(image_a, image_b, lines_a, lines_b, frames: int = 10, **kwargs) -> np.ndarray:
    """``(frames, ..., H, W)``: :func:`morph` at ``t = 0, 1/(frames-1), ..., 1`` (``frames >= 2``).

    Examples:
        Five frames from black to grey 100 (control points that stay put: a pure cross-dissolve),
        ``t`` in steps of 1/4:

        >>> import numpy as np
        >>> import photax as ptx
        >>> a, b = np.zeros((20, 30)), np.full((20, 30), 100.0)
        >>> pts = np.array([[5.0, 5.0], [25.0, 15.0], [5.0, 15.0]])
        >>> frames = ptx.morph_sequence(a, b, pts, pts, frames=5)
        >>> frames.shape, frames[:, 10, 15].tolist()
        ((5, 20, 30), [0.0, 25.0, 50.0, 75.0, 100.0])
    """
    if int(frames) < 2:
        raise ValueError(f"frames must be >= 2, got {frames}")
    return np.stack([morph(image_a, image_b, lines_a, lines_b, t, **kwargs) for t in np.linspace(0, 1, int(frames))])


def write_sequence(frames, out, *, duration: float = 0.1, loop: bool = True, inputs=()) -> pathlib.Path:
    """Write a morph sequence ``(n, H, W)`` or ``(n, 3, H, W)`` (bands first) as an animated GIF (``out``
    ends in ``.gif``) or as PNG frames ``frame_000.png``, ... in the folder ``out``, atomically (Pillow).

    Values are scaled to 0-255 by the sequence's common minimum and maximum (uint8 as it is); NaN is black.
    ``duration``: seconds per GIF frame.

    Examples:
        Frames written as an animated GIF (or a folder of PNGs), read back by Pillow:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> from PIL import Image
        >>> import photax as ptx
        >>> frames = [np.full((16, 16), v, np.uint8) for v in (0, 128, 255)]
        >>> path = ptx.write_sequence(frames, pathlib.Path(tempfile.mkdtemp()) / "morph.gif")
        >>> with Image.open(path) as gif:
        ...     print(gif.n_frames, gif.size)
        3 (16, 16)
    """
    from PIL import Image

    from .io.atomic import atomic_path

    f = np.asarray(frames)
    if f.ndim not in (3, 4) or (f.ndim == 4 and f.shape[1] not in (1, 3)):
        raise ValueError(f"frames must be (n, H, W) or (n, 3, H, W), got {f.shape}")
    if f.dtype != np.uint8:
        lo, hi = np.nanmin(f), np.nanmax(f)
        f = np.nan_to_num((f - lo) / (hi - lo if hi > lo else 1.0) * 255.0, nan=0.0)
        f = np.clip(np.round(f), 0, 255).astype(np.uint8)
    if f.ndim == 4:
        f = np.moveaxis(f, 1, -1)
        f = f[..., 0] if f.shape[-1] == 1 else f
    images = [Image.fromarray(x) for x in f]
    out = pathlib.Path(out)
    if out.suffix.lower() == ".gif":
        with atomic_path(out, inputs) as tmp:
            images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                           duration=int(round(1000 * duration)), loop=0 if loop else 1)  # fmt: skip
        return out
    if out.exists():
        raise FileExistsError(f"{out} exists: give a new folder for the frames")
    with atomic_path(out, inputs, folder=True) as tmp:
        for i, im in enumerate(images):
            im.save(tmp / f"frame_{i:03d}.png")
    return out
