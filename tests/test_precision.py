"""Precision by construction (issue 27): float32 coordinates at the public entry points.

photax computes in float64; float32 input is converted, and a
:class:`photax._float64.PrecisionWarning` says when its rounding was
coarse (world coordinates), since no computation can restore the digits.
The 6.5 cm of the issue came from that rounding, not from float32
arithmetic: the result equals the float64 one on the rounded values.
"""

import pathlib
import subprocess
import sys
import warnings

import numpy as np
import pytest
from conftest import scaled

import photax as ptx
from photax._float64 import PrecisionWarning

DATA = pathlib.Path(__file__).resolve().parents[1] / "data"


def _sample():
    t = ptx.read_gcps(DATA / "sample_gcps.csv")
    cam = ptx.read_camera(DATA / "sample_camera.yaml")
    return t.image_plane(cam), t.ground, cam, dict(names=t.names, check=t.check)


def test_float32_world_coordinates_warn_and_are_computed_in_float64():
    xy, ground, cam, kw = _sample()
    with pytest.warns(PrecisionWarning, match=r"ground_xyz is float32: .* held to 0\.031"):
        r32 = ptx.resect(xy, ground.astype(np.float32), cam, **kw)
    # the reference: float64 arithmetic on the values float32 kept
    ref = ptx.resect(xy, ground.astype(np.float32).astype(np.float64), cam, **kw)
    np.testing.assert_allclose(np.asarray(r32.exterior.position), np.asarray(ref.exterior.position), atol=1e-9)
    np.testing.assert_allclose(np.asarray(r32.exterior.angles), np.asarray(ref.exterior.angles), atol=1e-12)
    # and the rounding is what moves the centre (the centimetres)
    full = ptx.resect(xy, ground, cam, **kw)
    assert np.abs(np.asarray(full.exterior.position) - np.asarray(ref.exterior.position)).max() > 1e-3


def test_float32_image_coordinates_are_fine_as_they_are():
    xy, ground, cam, kw = _sample()
    with warnings.catch_warnings():
        warnings.simplefilter("error", PrecisionWarning)  # mm on the image: float32 keeps 1e-8 mm
        r = ptx.resect(xy.astype(np.float32), ground, cam, **kw)
        ptx.fit_polynomial(xy.astype(np.float32), xy.astype(np.float32) * 2.0, 1)
    ref = ptx.resect(xy.astype(np.float32).astype(np.float64), ground, cam, **kw)
    np.testing.assert_allclose(np.asarray(r.exterior.position), np.asarray(ref.exterior.position), atol=1e-9)


@pytest.mark.parametrize("call", ["orientation", "bundle"])
def test_other_entry_points_warn_on_float32_world_coordinates(call):
    """An orientation's position (what orthorectify, intersect, project take) and a bundle's points."""
    xy, ground, cam, kw = _sample()
    eo = ptx.resect(xy, ground, cam, **kw).exterior
    with pytest.warns(PrecisionWarning, match="position is float32" if call == "orientation" else "points is"):
        if call == "orientation":
            ptx.ExteriorOrientation(np.asarray(eo.position, np.float32), eo.angles)
        else:
            ptx.BundleProblem(
                cam,
                [eo],
                ground.astype(np.float32),
                np.zeros(len(xy), int),
                np.arange(len(xy)),
                xy,
                roles=["control"] * len(xy),
            )


def test_jax_arrays_made_before_import_photax():
    """Made while JAX still defaulted to float32: the same warning, and the float64 result of the rounded values."""
    script = f"""
import warnings, numpy as np, jax.numpy as jnp
t = np.loadtxt({str(DATA / "sample_gcps.csv")!r}, delimiter=",", skiprows=3, usecols=(2, 3, 4, 5, 6))
ground = jnp.asarray(t[:, :3])
assert ground.dtype == jnp.float32
import photax as ptx
cam = ptx.read_camera({str(DATA / "sample_camera.yaml")!r})
xy = np.asarray(cam.pixel_to_image(t[:, 3:]))
with warnings.catch_warnings(record=True) as w:
    warnings.simplefilter("always")
    r = ptx.resect(xy, ground, cam)
ref = ptx.resect(xy, np.asarray(ground, np.float64), cam)
assert any(issubclass(x.category, ptx._float64.PrecisionWarning) for x in w), [str(x.message) for x in w]
assert np.abs(np.asarray(r.exterior.position) - np.asarray(ref.exterior.position)).max() < 1e-9
"""
    proc = subprocess.run(
        [sys.executable, "-c", script], check=False, capture_output=True, text=True, timeout=scaled(300)
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
