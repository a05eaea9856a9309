"""Rational polynomial (RPC) sensor model of satellite images, and its refinement on GCPs.

Forward model (RPC00B; NITF STDI-0002 / GDAL / orthority)::

    L = (lon - LONG_OFF) / LONG_SCALE,  P = (lat - LAT_OFF) / LAT_SCALE,  H = (h - HEIGHT_OFF) / HEIGHT_SCALE
    column = SAMP_OFF + SAMP_SCALE * num_s(L, P, H) / den_s(L, P, H)
    row    = LINE_OFF + LINE_SCALE * num_l(L, P, H) / den_l(L, P, H)

each polynomial a cubic with its 20 terms in the RPC00B order::

    1, L, P, H, L P, L H, P H, L^2, P^2, H^2, P L H, L^3, L P^2, L H^2, L^2 P, P^3, P H^2, L^2 H, P^2 H, H^3

lon, lat in degrees (WGS84), h ellipsoidal height in metres (a DEM on a geoid must be converted
first), pixel coordinates (column, row) with the centre of the top-left pixel at (0, 0), photax's
convention everywhere -- GDAL's RPC transformer counts from the pixel's corner (0.5 more).

Inverse (:meth:`RPCCamera.to_ground`, image -> ground at a given height): the vendor's *direct*
model where the file carries one (DIMAP's ``Direct_Model`` / ``ImagetoGround_Values``, the "extended
IKONOS" ``LON_NUM_COEFF_n`` ...), the same cubic ratios with the roles swapped::

    C = (column - SAMP_OFF) / SAMP_SCALE,  R = (row - LINE_OFF) / LINE_SCALE,  H as above
    lon = LONG_OFF + LONG_SCALE * num_lon(C, R, H) / den_lon(C, R, H)
    lat = LAT_OFF  + LAT_SCALE  * num_lat(C, R, H) / den_lat(C, R, H)

(terms in the RPC00B order with C in L's place and R in P's, as rpcm and GDAL's DIMAP reader take
them); otherwise, or with ``localization="newton"``, Newton's method on (lon, lat) inverting the
ground -> image model, the 2 x 2 Jacobian by ``jax.jacfwd``.  The two differ by the vendor's fit
(1 mm on the shared Pleiades file, ``tests/test_rpc_formats.py``).

Refinement (:func:`refine_rpc`, Grodecki & Dial 2003; Hanley & Fraser 2004): an image-space
correction added to the RPC's pixel position, of increasing order::

    shift:        dc = a0,                 dr = b0
    shift-drift:  dc = a0 + a2 r,          dr = b0 + b2 r        (drift along the line time)
    affine:       dc = a0 + a1 c + a2 r,   dr = b0 + b1 c + b2 r

(c, r the RPC's own pixel position), adjusted by linear least squares on GCPs, with sigma0,
covariance and leave-one-out residuals.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ._aot import disk_cached
from ._float64 import as_float64
from ._linalg import solve2
from ._pytree import Module, field, filter_jit
from .errors import OutsideValidityError

# An RPC is evaluated within its validity volume (offsets +- scales) widened by this factor; beyond,
# a rational polynomial can fold far-away ground back into the image, so those points are NaN.
RPC_MARGIN = 1.1

# Coefficient rows of RPCCamera.coefficients, and the keys GDAL / rasterio / orthority give them.
COEFFICIENT_KEYS = ("line_num_coeff", "line_den_coeff", "samp_num_coeff", "samp_den_coeff")
# Rows of RPCCamera.direct (the image -> ground model), and their keys (rpcm's, lower case).
DIRECT_KEYS = ("lon_num_coeff", "lon_den_coeff", "lat_num_coeff", "lat_den_coeff")
Localization = Literal["direct", "newton"]
# Entries of RPCCamera.offsets / .scales, and their keys.
OFFSET_KEYS = ("long_off", "lat_off", "height_off", "samp_off", "line_off")
SCALE_KEYS = ("long_scale", "lat_scale", "height_scale", "samp_scale", "line_scale")

Refinement = Literal["shift", "shift-drift", "affine"]
# Which of (a0, a1, a2) -- constant, column, row -- each refinement adjusts, per axis.
_REFINE_TERMS = {"shift": (0,), "shift-drift": (0, 2), "affine": (0, 1, 2)}


def _monomials(lph: Array) -> Array:
    """``(..., 20)`` RPC00B terms of normalised ``(..., 3)`` (L, P, H)."""
    L, P, H = lph[..., 0], lph[..., 1], lph[..., 2]
    one = jnp.ones_like(L)
    return jnp.stack(
        [one, L, P, H, L * P, L * H, P * H, L * L, P * P, H * H,
         P * L * H, L**3, L * P * P, L * H * H, L * L * P, P**3, P * H * H, L * L * H, P * P * H, H**3],
        axis=-1,
    )  # fmt: skip


class RPCCamera(Module):
    """An RPC sensor model (module docstring: the equations and conventions).

    Attributes:
        coefficients: ``(4, 20)`` rows line numerator, line denominator, sample numerator,
            sample denominator (:data:`COEFFICIENT_KEYS`), terms in the RPC00B order
            (module docstring).
        offsets: ``(5,)`` lon (deg), lat (deg), height (m), sample (px), line (px) (:data:`OFFSET_KEYS`).
        scales: ``(5,)`` the same five scales (:data:`SCALE_KEYS`).
        correction: ``(2, 3)`` image-space correction ``[[a0, a1, a2], [b0, b1, b2]]`` added to the
            RPC's (column, row): ``dc = a0 + a1 c + a2 r``, ``dr = b0 + b1 c + b2 r`` (zero unless refined,
            :func:`refine_rpc`).
        image_size: ``(width, height)`` in pixels, or None when unknown.
        direct: ``(4, 20)`` the vendor's image -> ground model, rows lon numerator, lon denominator,
            lat numerator, lat denominator (:data:`DIRECT_KEYS`), on the same offsets and scales
            (module docstring), or None when the file has none.
        localization: ``"direct"`` (image -> ground by ``direct`` where there is one, else Newton) or
            ``"newton"`` (always Newton's inverse of the ground -> image model); :meth:`with_localization`.

    Examples:
        A toy RPC by hand: column and row linear in longitude and latitude (``col = samp_off +
        samp_scale L``, ``L = (lon - long_off) / long_scale``; rows grow southward), and back:

        >>> import numpy as np
        >>> import photax as ptx
        >>> one, lon, lat = np.eye(20)[0], np.eye(20)[1], -np.eye(20)[2]  # 1, L, -P of the 20 terms
        >>> rpc = ptx.RPCCamera.from_dict(dict(
        ...     samp_num_coeff=lon, samp_den_coeff=one, line_num_coeff=lat, line_den_coeff=one,
        ...     long_off=10.0, lat_off=45.0, height_off=0.0, samp_off=500.0, line_off=500.0,
        ...     long_scale=0.01, lat_scale=0.01, height_scale=500.0, samp_scale=500.0, line_scale=500.0,
        ... ), image_size=(1000, 1000))
        >>> print(np.asarray(rpc(np.array([[10.005, 45.005, 100.0]]))))  # lon, lat, h -> column, row
        [[750. 250.]]
        >>> print(np.round(np.asarray(rpc.to_ground(np.array([[750.0, 250.0]]), 100.0)), 9))
        [[10.005 45.005]]
    """

    coefficients: Array
    offsets: Array
    scales: Array
    correction: Array
    image_size: tuple[int, int] | None = field(static=True, default=None)
    direct: Array | None = None
    localization: str = field(static=True, default="direct")

    def __init__(
        self, coefficients, offsets, scales, correction=None, image_size=None, *, direct=None, localization="direct"
    ):
        c = as_float64(coefficients, "coefficients")
        o = as_float64(offsets, "offsets")
        s = as_float64(scales, "scales")
        if c.shape != (4, 20):
            raise ValueError(f"coefficients: expected shape (4, 20), got {c.shape}")
        for name, a in (("offsets", o), ("scales", s)):
            if a.shape != (5,):
                raise ValueError(f"{name}: expected shape (5,), got {a.shape}")
        bad = [f"{COEFFICIENT_KEYS[i]}[{j}]" for i, j in zip(*np.nonzero(~np.isfinite(c)), strict=True)]
        bad += [OFFSET_KEYS[i] for i in np.flatnonzero(~np.isfinite(o))]
        bad += [SCALE_KEYS[i] for i in np.flatnonzero(~np.isfinite(s))]
        if bad:
            raise ValueError(f"RPC: non-finite values in {', '.join(bad)}")
        if np.any(s == 0):
            raise ValueError(f"RPC: zero scale in {', '.join(SCALE_KEYS[i] for i in np.flatnonzero(s == 0))}")
        k = np.zeros((2, 3)) if correction is None else as_float64(correction, "correction")
        if k.shape != (2, 3):
            raise ValueError(f"correction: expected shape (2, 3), got {k.shape}")
        # with a dtype: transfers, not eager programs (each lowered and looked up in every process)
        self.coefficients = jnp.asarray(c, dtype=float)
        self.offsets = jnp.asarray(o, dtype=float)
        self.scales = jnp.asarray(s, dtype=float)
        self.correction = jnp.asarray(k, dtype=float)
        self.image_size = None if image_size is None else (int(image_size[0]), int(image_size[1]))
        if direct is not None:
            d = as_float64(direct, "direct")
            if d.shape != (4, 20):
                raise ValueError(f"direct: expected shape (4, 20), got {d.shape}")
            bad = [f"{DIRECT_KEYS[i]}[{j}]" for i, j in zip(*np.nonzero(~np.isfinite(d)), strict=True)]
            if bad:
                raise ValueError(f"RPC: non-finite values in {', '.join(bad)}")
            direct = jnp.asarray(d, dtype=float)
        self.direct = direct
        if localization not in ("direct", "newton"):
            raise ValueError(f"localization: expected 'direct' or 'newton', got {localization!r}")
        self.localization = localization

    def replace(self, **changes) -> RPCCamera:
        """A copy with some fields changed (``correction=``, ``image_size=``, ``offsets=``, ...), every other
        field, the direct model included, kept."""
        names = ("coefficients", "offsets", "scales", "correction", "image_size", "direct", "localization")
        unknown = sorted(set(changes) - set(names))
        if unknown:
            raise ValueError(f"replace: no field {', '.join(unknown)} (fields: {', '.join(names)})")
        kw = {n: changes.get(n, getattr(self, n)) for n in names}
        return RPCCamera(
            kw["coefficients"], kw["offsets"], kw["scales"], kw["correction"], kw["image_size"],
            direct=kw["direct"], localization=kw["localization"],
        )  # fmt: skip

    def with_localization(self, localization: Localization) -> RPCCamera:
        """The same RPC localizing (image -> ground) by ``"direct"`` (the vendor's direct model, where
        there is one) or ``"newton"`` (Newton's inverse of the ground -> image model)."""
        return self.replace(localization=localization)

    @property
    def localizes_directly(self) -> bool:
        """Whether image -> ground uses the vendor's direct model (one is present and not declined)."""
        return self.direct is not None and self.localization == "direct"

    # --- construction ---------------------------------------------------------------------------

    @classmethod
    def from_dict(cls, rpc: dict, image_size=None) -> RPCCamera:
        """From a mapping with GDAL's / rasterio's / orthority's lower-case keys
        (``line_num_coeff``, ..., ``long_off``, ..., ``samp_scale``); missing keys are named."""
        keys = (*COEFFICIENT_KEYS, *OFFSET_KEYS, *SCALE_KEYS)
        missing = [k for k in keys if rpc.get(k) is None]
        if missing:
            raise ValueError(f"RPC: missing {', '.join(missing)}")
        from ._values import as_numbers, excerpt

        def numbers(key, value, what):  # a list, mapping, text or null is the RPC's error, not numpy's
            v = as_numbers(value)
            if v is None:
                raise ValueError(f"RPC: {key} must be {what}, got {excerpt(value)}")
            return v

        coeffs = []
        for k in COEFFICIENT_KEYS:
            row = numbers(k, rpc[k], "20 numbers").ravel()
            if row.shape != (20,):
                raise ValueError(f"RPC: {k} has {row.size} coefficients, expected 20")
            coeffs.append(row)
        scalars = {k: numbers(k, rpc[k], "a number") for k in (*OFFSET_KEYS, *SCALE_KEYS)}
        bad = [k for k, v in scalars.items() if v.shape != ()]
        if bad:
            raise ValueError(f"RPC: {bad[0]} must be a number, got {excerpt(rpc[bad[0]])}")
        if image_size is not None:
            size = as_numbers(image_size)
            if (
                size is None
                or size.shape != (2,)
                or not np.all(np.isfinite(size))
                or np.any(size < 1)
                or np.any(size != np.round(size))
                or np.any(size > 2**31 - 1)
            ):
                raise ValueError(
                    f"RPC: the image size must be [width, height] in whole pixels, got {excerpt(image_size)}"
                )
            image_size = (int(size[0]), int(size[1]))
        return cls(
            np.stack(coeffs),
            [float(scalars[k]) for k in OFFSET_KEYS],
            [float(scalars[k]) for k in SCALE_KEYS],
            image_size=image_size,
        )

    @classmethod
    def from_rasterio(cls, rpcs, image_size=None) -> RPCCamera:
        """From a :class:`rasterio.rpc.RPC` (``src.rpcs`` of an opened image)."""
        return cls.from_dict(rpcs.to_dict(), image_size)

    def to_dict(self) -> dict:
        """The RPC with GDAL's lower-case keys, as :class:`rasterio.rpc.RPC` takes them
        (the refinement's ``correction`` is not part of an RPC and is left out)."""
        d = {k: np.asarray(row).tolist() for k, row in zip(COEFFICIENT_KEYS, self.coefficients, strict=True)}
        d.update({k: float(v) for k, v in zip(OFFSET_KEYS, self.offsets, strict=True)})
        d.update({k: float(v) for k, v in zip(SCALE_KEYS, self.scales, strict=True)})
        return d

    def crop(self, col_off, row_off, width: int, height: int) -> RPCCamera:
        """The RPC of a crop of this image: the window of ``width x height`` pixels whose top-left pixel is
        ``(col_off, row_off)`` of this one (a :class:`rasterio.windows.Window`'s ``col_off, row_off,
        width, height``), with its pixel coordinates counted from the crop's corner, as vendors and GDAL
        (``gdal_translate -srcwin``) write a cut scene's RPC: ``SAMP_OFF - col_off``, ``LINE_OFF - row_off``,
        the scales, coefficients and ground offsets unchanged (a crop's offsets can lie far outside it,
        tens of its own sizes: the full scene's centre). A refinement's correction ``dc = a0 + a1 c +
        a2 r`` is carried over to the crop's pixels (``a0 += a1 col_off + a2 row_off``, likewise ``b0``),
        so the crop images every ground point where the whole image did, shifted by the origin.

        Raises:
            ValueError: a non-finite origin, a size not a positive integer, or (with ``image_size``) a
                window not inside the image.
        """
        c0, r0 = float(col_off), float(row_off)
        if not (math.isfinite(c0) and math.isfinite(r0)):
            raise ValueError(f"crop: col_off, row_off must be finite, got {col_off}, {row_off}")
        if int(width) != width or int(height) != height or width < 1 or height < 1:
            raise ValueError(f"crop: width, height must be positive integers, got {width}, {height}")
        if self.image_size is not None:
            w, h = self.image_size
            if c0 < 0 or r0 < 0 or c0 + width > w or r0 + height > h:
                raise OutsideValidityError(
                    f"crop: the window at ({c0:g}, {r0:g}) of {int(width)} x {int(height)} pixels is not inside "
                    f"the {w} x {h} pixel image"
                )
        offsets = np.asarray(self.offsets).copy()
        offsets[3:] -= (c0, r0)
        k = np.asarray(self.correction).copy()
        k[:, 0] += k[:, 1] * c0 + k[:, 2] * r0
        return RPCCamera(self.coefficients, offsets, self.scales, k, (int(width), int(height)))

    # --- projection -----------------------------------------------------------------------------

    def uncorrected(self, ground: Array) -> Array:
        """``(..., 3)`` lon, lat, h -> ``(..., 2)`` column, row of the RPC alone (no correction)."""
        ground = jnp.asarray(ground, dtype=jnp.float64)
        lead = (1,) * (ground.ndim - 1)  # explicit broadcasting (rank promotion is an error in the tests)
        lph = (ground - self.offsets[:3].reshape(*lead, 3)) / self.scales[:3].reshape(*lead, 3)
        m = _monomials(lph)
        p = jnp.einsum("...t,kt->...k", m, self.coefficients)
        row_n, col_n = p[..., 0] / p[..., 1], p[..., 2] / p[..., 3]
        scale, offset = self.scales[3:].reshape(*lead, 2), self.offsets[3:].reshape(*lead, 2)
        return jnp.stack([col_n, row_n], axis=-1) * scale + offset

    def __call__(self, ground: Array) -> Array:
        """``(..., 3)`` lon (deg), lat (deg), ellipsoidal h (m) -> ``(..., 2)`` column, row (px)."""
        cr = self.uncorrected(ground)
        return cr + cr @ self.correction[:, 1:].T + self.correction[:, 0].reshape(*(1,) * (cr.ndim - 1), 2)

    project = __call__

    # the ground-camera protocol of photax.sensor (shared with photax.PushbroomCamera)

    def ground_box(self):
        """``((lon, lat), (dlon, dlat))``: the validity box's centre and half-sides (deg): offsets +- scales."""
        return np.asarray(self.offsets)[:2], np.asarray(self.scales)[:2]  # sliced in numpy: no eager program

    @property
    def height_range(self) -> tuple[float, float]:
        """The heights the RPC was fitted for (m): height offset +- scale."""
        off, scale = float(np.asarray(self.offsets)[2]), float(np.asarray(self.scales)[2])
        return off - scale, off + scale

    def invert(self, pixel: Array, h: Array):
        """``(n, 2)`` pixels at ``(n,)`` heights -> ``((n, 2)`` lon, lat, ``(n,)`` converged); jittable
        (the direct model where :attr:`localizes_directly`, else Newton)."""
        return localize_inverse(self, pixel, h)

    def to_ground(
        self, pixel: Array, height, *, max_steps: int = 20, tol: float = 1e-12, method: Localization | None = None
    ):
        """``(..., 2)`` column, row and ellipsoidal height(s) ``(...)`` -> ``(..., 2)`` lon, lat (deg).

        The vendor's direct model where the RPC has one (the image-space correction undone first),
        unless ``method="newton"`` or the camera's :attr:`localization` is ``"newton"``; otherwise
        Newton's method on (lon, lat) from the scene centre, the Jacobian by ``jax.jacfwd``,
        stopping after the step is below ``tol`` degrees (1e-12 deg ~ 0.1 um) or ``max_steps``.
        Points that did not converge come back NaN (:meth:`to_ground_status` gives the flags).
        """
        lonlat, ok = self.to_ground_status(pixel, height, max_steps=max_steps, tol=tol, method=method)
        return jnp.where(ok[..., None], lonlat, jnp.nan)

    localize = to_ground

    def to_ground_status(
        self, pixel: Array, height, *, max_steps: int = 20, tol: float = 1e-12, method: Localization | None = None
    ):
        """As :meth:`to_ground`, returning ``(lonlat, converged)`` with the unconverged values kept."""
        if method is not None and method != self.localization:
            return self.with_localization(method).to_ground_status(pixel, height, max_steps=max_steps, tol=tol)
        pixel = jnp.asarray(as_float64(pixel, "pixel"))
        if pixel.shape[-1:] != (2,):
            raise ValueError(f"pixel: expected shape (..., 2), got {pixel.shape}")
        h = jnp.broadcast_to(jnp.asarray(as_float64(height, "height")), pixel.shape[:-1])
        flat_p, flat_h = pixel.reshape(-1, 2), h.reshape(-1)
        lonlat, ok = localize_inverse(self, flat_p, flat_h, max_steps, tol)
        return lonlat.reshape(pixel.shape), ok.reshape(pixel.shape[:-1])

    def to_ground_dem(self, pixel, dem, *, max_steps: int = 50, tol: float = 1e-6, method=None) -> np.ndarray:
        """``(..., 2)`` column, row -> ``(..., 3)`` lon, lat, h on a :class:`photax.DEM` (GDAL's ``RPC_DEM``).

        Fixed-point iteration: the ground point at height ``h`` (:meth:`to_ground`), then ``h`` from
        the DEM there, from the RPC's height offset until ``h`` moves less than ``tol`` metres.  The
        DEM's heights must be ellipsoidal (WGS84), as the RPC's; a DEM on a geoid must be converted
        first.  Its CRS (None: lon, lat) is reached through pyproj.  NaN where the ground point leaves
        the DEM or the iteration does not settle in ``max_steps`` (it converges while the terrain's slope
        times the view's tangent stays below 1); :meth:`to_ground_dem_status` says which.
        """
        return self.to_ground_dem_status(pixel, dem, max_steps=max_steps, tol=tol, method=method)[0]

    def to_ground_dem_status(self, pixel, dem, *, max_steps: int = 50, tol: float = 1e-6, method=None):
        """As :meth:`to_ground_dem`, returning ``(lon_lat_h, status)``: ``status`` ``(...)`` per point,
        one of :data:`GROUND_STATUS` (0 converged, 1 off the DEM, 2 Newton's inverse did not converge,
        3 the height iteration did not settle); ``method`` as :meth:`to_ground`'s."""
        import pyproj

        if method is not None and method != self.localization:
            return self.with_localization(method).to_ground_dem_status(pixel, dem, max_steps=max_steps, tol=tol)
        pixel = as_float64(pixel, "pixel")
        if pixel.shape[-1:] != (2,):
            raise ValueError(f"pixel: expected shape (..., 2), got {pixel.shape}")
        flat = jnp.asarray(pixel.reshape(-1, 2))
        to_dem = None
        if dem.crs is not None:
            to_dem = pyproj.Transformer.from_crs("EPSG:4326", dem.crs, always_xy=True)
        h = np.full(len(flat), float(self.offsets[2]))
        done = np.zeros(len(flat), bool)
        failed = np.zeros(len(flat), bool)  # Newton's inverse did not converge at some height
        for _ in range(max_steps):
            lonlat, ok = (np.asarray(v) for v in _to_ground_cached(self, flat, jnp.asarray(h), 20, 1e-12))
            failed |= ~ok & np.isfinite(h)
            x, y = to_dem.transform(lonlat[:, 0], lonlat[:, 1]) if to_dem else lonlat.T
            new = np.asarray(dem.height(jnp.asarray(x, dtype=jnp.float64), jnp.asarray(y, dtype=jnp.float64)))
            new = np.where(ok, new, np.nan)
            done = np.abs(new - h) < tol
            h = new
            if np.all(done | ~np.isfinite(h)):
                break
        lonlat, ok = (np.asarray(v) for v in _to_ground_cached(self, flat, jnp.asarray(h), 20, 1e-12))  # last height
        failed |= ~ok & np.isfinite(h)
        status = np.where(failed, 2, np.where(~np.isfinite(h), 1, np.where(done & ok, 0, 3)))
        out = np.column_stack([lonlat, h])
        out[status != 0] = np.nan
        return out.reshape(*pixel.shape[:-1], 3), status.reshape(pixel.shape[:-1])


# The status codes of RPCCamera.to_ground_dem_status.
GROUND_STATUS = ("converged", "off the DEM", "no convergence (inverse)", "no convergence (height)")


@filter_jit
def newton_inverse(camera: RPCCamera, pixel: Array, h: Array, max_steps: int = 20, tol: float = 1e-12):
    """``(n, 2)`` pixels at ``(n,)`` heights -> ``((n, 2)`` lon, lat, ``(n,)`` converged): Newton's method
    from the scene centre, jittable (:meth:`RPCCamera.to_ground_status` is its checked entry point)."""

    def f(ll, hh):
        return camera(jnp.concatenate([ll, hh[None]]))

    jac = jax.jacfwd(f)

    def one(p, hh):
        def body(state):
            ll, step, i = state
            d = solve2(jac(ll, hh), p - f(ll, hh))
            return ll + d, jnp.max(jnp.abs(d)), i + 1

        def cond(state):
            _, step, i = state
            return (step > tol) & (i < max_steps) & jnp.isfinite(step)

        start = (camera.offsets[:2], jnp.asarray(1.0), 0)  # a first "step" of 1 deg (> tol): it starts
        ll, step, _ = jax.lax.while_loop(cond, body, start)
        return ll, step <= tol

    return jax.vmap(one)(pixel, h)


@filter_jit
def direct_inverse(camera: RPCCamera, pixel: Array, h: Array):
    """``(n, 2)`` pixels at ``(n,)`` heights -> ``((n, 2)`` lon, lat, ``(n,)`` finite) by the camera's direct
    (image -> ground) model (module docstring), its image-space correction undone first; jittable."""
    a = camera.correction[:, 1:] + jnp.eye(2)
    det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    inv = jnp.stack([jnp.stack([a[1, 1], -a[0, 1]]), jnp.stack([-a[1, 0], a[0, 0]])]) / det
    cr = (pixel - camera.correction[:, 0].reshape(1, 2)) @ inv.T  # the RPC's own position
    o, s = camera.offsets, camera.scales
    crh = jnp.stack([(cr[:, 0] - o[3]) / s[3], (cr[:, 1] - o[4]) / s[4], (h - o[2]) / s[2]], axis=-1)
    p = jnp.einsum("nt,kt->nk", _monomials(crh), camera.direct)
    lonlat = jnp.stack([p[:, 0] / p[:, 1], p[:, 2] / p[:, 3]], axis=-1) * s[:2].reshape(1, 2) + o[:2].reshape(1, 2)
    return lonlat, jnp.all(jnp.isfinite(lonlat), axis=-1)


def localize_inverse(camera: RPCCamera, pixel: Array, h: Array, max_steps: int = 20, tol: float = 1e-12):
    """Image -> ground at heights: :func:`direct_inverse` where ``camera.localizes_directly``, else
    :func:`newton_inverse` (``max_steps``, ``tol`` are Newton's); jittable (the choice is static)."""
    if camera.localizes_directly:
        return direct_inverse(camera, pixel, h)
    return newton_inverse(camera, pixel, h, max_steps, tol)


_to_ground_cached = disk_cached(
    filter_jit(localize_inverse), "rpc_to_ground"
)  # traced once per machine, not per process


_forward = disk_cached(filter_jit(RPCCamera.__call__), "rpc_forward")  # one program, not op by op


# --- readers ---------------------------------------------------------------------------------


def __getattr__(name):
    """``photax.rpc.read_rpc``: the readers moved to :mod:`photax.io.satellite` (every vendor's family, by
    content; ``photax.read_rpc``); the old name still reaches them."""
    if name == "read_rpc":
        import photax

        return photax.read_rpc
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# --- refinement ---------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class RPCRefinement:
    """Outcome of :func:`refine_rpc`.

    Attributes:
        camera: the refined :class:`RPCCamera` (its ``correction`` set).
        model: the refinement (``"shift"``, ``"shift-drift"``, ``"affine"``).
        correction: ``(2, 3)`` the adjusted ``[[a0, a1, a2], [b0, b1, b2]]`` (px, px/px).
        covariance: ``(u, u)`` covariance of the adjusted parameters, column axis first (sigma0^2 Q).
        residuals: ``(n, 2)`` refined minus observed pixel position of each GCP (px; computed -
            observed, ``docs/conventions.md``).
        raw_residuals: ``(n, 2)`` the same for the unrefined RPC (px).
        loo_residuals: ``(n, 2)`` each GCP's residual from a refinement without it (leave-one-out;
            NaN where the others are too few).
        sigma0: a posteriori standard deviation of unit weight (px), ``sqrt(v'v / (2n - u))``; NaN when
            there is no redundancy.
        redundancy: ``2n - u``.
        standardized: ``(n, 2)`` residuals over their own a posteriori standard deviation,
            ``v_i / (sigma0 sqrt(1 - h_ii))`` with ``h_ii`` the GCP's leverage (Pope's tau statistic);
            the largest beyond about 3 marks a blunder (data snooping, Baarda 1968). NaN without
            redundancy or where a GCP alone determines a parameter (``h_ii = 1``).

    Examples:
        What :func:`refine_rpc` returns: the refined camera and the fit before and after, per GCP
        and with each left out:

        >>> import numpy as np
        >>> import photax as ptx
        >>> t = np.eye(20)  # terms 1, L, P of the 20: column = 500 + 500 L, row = 500 - 500 P
        >>> rpc = ptx.RPCCamera([-t[2], t[0], t[1], t[0]], [10.0, 45.0, 0.0, 500.0, 500.0],
        ...                     [0.01, 0.01, 500.0, 500.0, 500.0], image_size=(1000, 1000))
        >>> ground = np.array([[10.002, 45.001, 50.0], [10.007, 44.996, 80.0], [9.995, 45.004, 20.0]])
        >>> ref = ptx.refine_rpc(rpc, ground, np.asarray(rpc(ground)) + [1.0, 0.0], names=["A", "B", "C"])
        >>> list(ref.names), f"{ref.raw_rmse:.3f}", f"{ref.rmse:.6f}", f"{ref.loo_rmse:.6f}"
        (['A', 'B', 'C'], '1.000', '0.000000', '0.000000')
    """

    camera: RPCCamera
    model: str
    correction: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    raw_residuals: np.ndarray
    loo_residuals: np.ndarray
    sigma0: float
    redundancy: int
    standardized: np.ndarray
    names: tuple[str, ...] | None = None

    def report(self) -> str:
        """A text report: the fit's figures, the correction and each GCP's residuals (px)."""
        a, b = self.correction
        lines = [
            f"RPC refinement ({self.model}) on {len(self.residuals)} GCPs: RMSE {self.raw_rmse:.3f} px unrefined, "
            f"{self.rmse:.3f} px refined, {self.loo_rmse:.3f} px leave-one-out; sigma0 {self.sigma0:.3f} px, "
            f"redundancy {self.redundancy}",
            f"  column += {a[0]:+.3f} {a[1]:+.3e} c {a[2]:+.3e} r;  row += {b[0]:+.3f} {b[1]:+.3e} c {b[2]:+.3e} r",
            f"  {'GCP':<24} {'raw dc':>8} {'raw dr':>8} {'dc':>8} {'dr':>8} {'loo dc':>8} {'loo dr':>8} {'|w|':>6}"
            "   (residuals: computed - observed, px)",
        ]
        names = self.names or tuple(str(i + 1) for i in range(len(self.residuals)))
        w = np.max(np.abs(self.standardized), axis=1)
        for k, name in enumerate(names):
            r, v, lo = self.raw_residuals[k], self.residuals[k], self.loo_residuals[k]
            lines.append(
                f"  {name[:24]:<24} {r[0]:8.3f} {r[1]:8.3f} {v[0]:8.3f} {v[1]:8.3f} {lo[0]:8.3f} {lo[1]:8.3f} "
                f"{w[k]:6.2f}" + ("  <- blunder?" if w[k] > 3 else "")
            )
        return "\n".join(lines)

    @property
    def rmse(self) -> float:
        """Root mean square of the residuals' lengths (px)."""
        return float(np.sqrt(np.mean(np.sum(self.residuals**2, axis=1))))

    @property
    def raw_rmse(self) -> float:
        """The same for the unrefined RPC (px)."""
        return float(np.sqrt(np.mean(np.sum(self.raw_residuals**2, axis=1))))

    @property
    def loo_rmse(self) -> float:
        """The same for the leave-one-out residuals (px)."""
        return float(np.sqrt(np.nanmean(np.sum(self.loo_residuals**2, axis=1))))


def _fit_correction(cr: np.ndarray, obs: np.ndarray, terms: tuple[int, ...]):
    """Least-squares ``(2, 3)`` correction (zeros outside ``terms``) and the cofactor per axis."""
    design = np.column_stack([np.ones(len(cr)), cr])[:, terms]
    k = np.zeros((2, 3))
    for axis in range(2):
        k[axis, list(terms)] = np.linalg.lstsq(design, obs[:, axis] - cr[:, axis], rcond=None)[0]
    return k, design


def _apply(k: np.ndarray, cr: np.ndarray) -> np.ndarray:
    return cr + cr @ k[:, 1:].T + k[:, 0]


def check_gcps(
    camera: RPCCamera, ground, pixel, names=None, *, who: str = "GCPs", warn: bool = True, stacklevel: int = 2
) -> None:
    """Refuse GCPs that cannot belong to ``camera``'s image, warn of those just outside it.

    * The ground ``(n, 3)`` lon, lat, h must lie in the RPC's validity volume, its ground offsets
      +- :data:`RPC_MARGIN` scales (beyond, the polynomial is extrapolated and may fold):
      a ValueError naming them.
    * With ``camera.image_size`` (``w x h``): a pixel ``(n, 2)`` more than the image's own size beyond
      its edges is a blunder or another image's measurement (a ValueError); one outside the image but
      nearer is used, with a warning unless ``warn=False`` (measured on the full scene this file is
      cut from: orthority's QuickBird sample has two). The image is the one given, not the RPC's offsets: a crop's RPC
      (:meth:`RPCCamera.crop`) keeps the full scene's scales, its offsets lie tens of scales away.
    * Without ``image_size``: the RPC's own pixel box, its line and sample offsets +- 1.5 scales.
    """

    label = (lambda i: names[i]) if names else (lambda i: f"GCP {i}")

    def listing(idx, what):
        return ", ".join(f"{label(i)} at ({what[i, 0]:.1f}, {what[i, 1]:.1f})" for i in idx)

    off, scale = np.asarray(camera.offsets), np.asarray(camera.scales)
    far = np.abs(ground - off[:3]) > RPC_MARGIN * np.abs(scale[:3])
    out = np.flatnonzero(far.any(axis=1))
    if out.size:
        lo, hi = off[:3] - RPC_MARGIN * np.abs(scale[:3]), off[:3] + RPC_MARGIN * np.abs(scale[:3])
        which = ", ".join(f"{label(i)} at ({ground[i, 0]:.6f}, {ground[i, 1]:.6f}, {ground[i, 2]:.1f} m)" for i in out)
        raise OutsideValidityError(
            f"{who}: {out.size} GCP(s) outside the RPC's validity volume (lon {lo[0]:.6f} .. {hi[0]:.6f}, lat "
            f"{lo[1]:.6f} .. {hi[1]:.6f}, h {lo[2]:.1f} .. {hi[2]:.1f} m: its offsets +- {RPC_MARGIN} scales): "
            f"{which}; another scene's GCPs, or lon and lat swapped?"
        )
    if camera.image_size is None:
        box_off, box = off[3:], 1.5 * np.abs(scale[3:])
        out = np.flatnonzero(np.any(np.abs(pixel - box_off) > box, axis=1))
        if out.size:  # not an image of this RPC: a blunder or another image's measurement
            raise OutsideValidityError(
                f"{who}: {out.size} GCP(s) outside the RPC's image (columns {box_off[0] - box[0]:.0f} .. "
                f"{box_off[0] + box[0]:.0f}, rows {box_off[1] - box[1]:.0f} .. {box_off[1] + box[1]:.0f}): "
                f"{listing(out, pixel)}"
            )
        return
    w, h = camera.image_size
    size = np.array([w, h], dtype=float)
    out = np.flatnonzero(np.any((pixel < -0.5 - size) | (pixel > size - 0.5 + size), axis=1))
    if out.size:
        raise OutsideValidityError(
            f"{who}: {out.size} GCP(s) outside the {w} x {h} pixel image by more than its size (a blunder or "
            f"another image's measurement?): {listing(out, pixel)}"
        )
    out = np.flatnonzero(np.any((pixel < -0.5) | (pixel > size - 0.5), axis=1))
    if out.size and warn:  # inside the RPC's volume: measured on the full scene this file is cut from
        import warnings

        warnings.warn(
            f"{out.size} GCP(s) outside the {w} x {h} pixel image, inside the RPC's validity volume: "
            f"{listing(out, pixel)}; used (measured on the full scene?)",
            stacklevel=stacklevel,
        )


def refine_rpc(camera: RPCCamera, ground, pixel, model: Refinement = "shift", *, names=None) -> RPCRefinement:
    """Refine ``camera`` on GCPs by an image-space correction (module docstring; Grodecki & Dial 2003).

    Args:
        camera: the RPC to refine (an existing ``correction`` is replaced, not added to).
        ground: ``(n, 3)`` lon (deg), lat (deg), ellipsoidal height (m) of the GCPs.
        pixel: ``(n, 2)`` their measured column, row (px).
        model: ``"shift"`` (1 GCP at least), ``"shift-drift"`` (2), ``"affine"`` (3).
        names: the GCPs' names, for the messages and :meth:`RPCRefinement.report`.

    GCPs are checked by :func:`check_gcps`: outside the RPC's validity volume (ground offsets +- 1.1
    scales) or far outside the image (beyond ``camera.image_size`` by more than its size) they are
    refused, naming them; just outside the image (a file cut from the scene the GCPs were measured on:
    orthority's QuickBird sample has two) they are used, with a warning naming them. A crop's RPC
    (:meth:`RPCCamera.crop`) is refined in its own pixels and stays a crop's RPC (its offsets and
    ``image_size`` kept).

    Equal weights; the normal equations of the two axes are separate (the correction of each axis
    is linear in its own parameters), so each is an ordinary least-squares fit of the RPC's misfit.

    Examples:
        GCPs measured 2.5 columns and -1.25 rows away from where the RPC puts them: the ``shift``
        refinement finds the bias, and the refined camera fits them to rounding:

        >>> import numpy as np
        >>> import photax as ptx
        >>> t = np.eye(20)  # terms 1, L, P of the 20: column = 500 + 500 L, row = 500 - 500 P
        >>> rpc = ptx.RPCCamera([-t[2], t[0], t[1], t[0]], [10.0, 45.0, 0.0, 500.0, 500.0],
        ...                     [0.01, 0.01, 500.0, 500.0, 500.0], image_size=(1000, 1000))
        >>> ground = np.array([[10.002, 45.001, 50.0], [10.007, 44.996, 80.0], [9.995, 45.004, 20.0]])
        >>> pixel = np.asarray(rpc(ground)) + [2.5, -1.25]
        >>> ref = ptx.refine_rpc(rpc, ground, pixel, "shift")
        >>> print(f"{ref.raw_rmse:.3f} -> {ref.rmse:.6f} px")
        2.795 -> 0.000000 px
    """
    if model not in _REFINE_TERMS:
        raise ValueError(f"model: expected one of {', '.join(_REFINE_TERMS)}, got {model!r}")
    ground = as_float64(ground, "ground")
    pixel = as_float64(pixel, "pixel")
    if ground.ndim != 2 or ground.shape[1] != 3:
        raise ValueError(f"ground: expected shape (n, 3) lon, lat, h, got {ground.shape}")
    if pixel.shape != (len(ground), 2):
        raise ValueError(f"pixel: expected shape ({len(ground)}, 2) to match ground, got {pixel.shape}")
    if not (np.all(np.isfinite(ground)) and np.all(np.isfinite(pixel))):
        raise ValueError("ground / pixel: non-finite GCP coordinates")
    names = None if names is None else tuple(str(v) for v in names)
    if names is not None and len(names) != len(ground):
        raise ValueError(f"names: {len(names)} for {len(ground)} GCPs")
    check_gcps(camera, ground, pixel, names, who="refine_rpc", stacklevel=3)
    terms = _REFINE_TERMS[model]
    n, u = len(ground), 2 * len(terms)
    if n < len(terms):
        raise ValueError(f"refine_rpc: {model!r} needs at least {len(terms)} GCPs, got {n}")
    raw = RPCCamera(camera.coefficients, camera.offsets, camera.scales, image_size=camera.image_size)
    cr = np.asarray(_forward(raw, jnp.asarray(ground)))
    k, design = _fit_correction(cr, pixel, terms)
    residuals = _apply(k, cr) - pixel  # computed - observed
    r = 2 * n - u
    sigma0 = float(np.sqrt(np.sum(residuals**2) / r)) if r > 0 else math.nan
    q = np.linalg.pinv(design.T @ design)
    leverage = np.einsum("ij,jk,ik->i", design, q, design)  # the same design on both axes
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = sigma0 * np.sqrt(np.where(leverage < 1 - 1e-12, 1 - leverage, np.nan))
        standardized = residuals / spread[:, None]
    cov = np.kron(np.eye(2), q) * (sigma0**2 if r > 0 else math.nan)
    loo = np.full((n, 2), np.nan)
    if n > len(terms):
        for i in range(n):
            keep = np.arange(n) != i
            ki, _ = _fit_correction(cr[keep], pixel[keep], terms)
            loo[i] = _apply(ki, cr[i : i + 1])[0] - pixel[i]
    refined = camera.replace(correction=k)  # the direct model, if any, kept
    return RPCRefinement(refined, model, k, cov, residuals, cr - pixel, loo, sigma0, r, standardized, names)


def rpc_terms(lph) -> Array:
    """``(..., 20)`` the RPC00B terms of normalised ``(..., 3)`` (L, P, H), in the module docstring's order:
    the design matrix of an RPC fit (:func:`photax.fit_rpc`)."""
    return _monomials(jnp.asarray(lph, dtype=jnp.float64))
