"""photax._pytree.Module: the core types as JAX pytrees without equinox, checked against what
equinox.Module does with the same class (leaves, static fields, tree_at, filter_jit, frozen)."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from photax import DEM, ExteriorOrientation, FrameCamera
from photax._pytree import Module, field


class Mine(Module):
    a: jax.Array
    b: jax.Array
    name: str = field(static=True, default="x")


class Theirs(eqx.Module):
    a: jax.Array
    b: jax.Array
    name: str = eqx.field(static=True, default="x")


class Checked(Module):
    """A class with its own __init__, and a subclass that calls it."""

    value: jax.Array
    size: tuple = eqx.field(static=True)  # equinox's field: the same metadata

    def __init__(self, value, size=(1, 2)):
        self.value = jnp.asarray(value, dtype=float)
        self.size = tuple(size)


class Child(Checked):
    extra: jax.Array

    def __init__(self, value, extra):
        super().__init__(value, size=(3, 4))
        self.extra = jnp.asarray(extra)


def test_leaves_structure_and_tree_at_as_equinox():
    mine, theirs = Mine(jnp.ones(2), jnp.zeros(3), "n"), Theirs(jnp.ones(2), jnp.zeros(3), "n")
    for a, b in zip(jax.tree_util.tree_leaves(mine), jax.tree_util.tree_leaves(theirs), strict=True):
        np.testing.assert_array_equal(a, b)
    paths = [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_flatten_with_path(mine)[0]]
    assert paths == [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_flatten_with_path(theirs)[0]]
    moved = eqx.tree_at(lambda m: m.b, mine, jnp.full(3, 5.0))
    assert type(moved) is Mine and moved.name == "n" and float(moved.b[0]) == 5.0 and float(mine.b[0]) == 0.0
    doubled = jax.tree_util.tree_map(lambda x: 2 * x, mine)
    np.testing.assert_array_equal(doubled.a, 2 * np.ones(2))


def test_static_fields_are_compile_time_values_and_arrays_are_traced():
    traces = []

    @eqx.filter_jit
    def f(m):
        traces.append(m.name)  # only while tracing
        return m.a.sum() + m.b.sum()

    assert float(f(Mine(jnp.ones(2), jnp.ones(3)))) == 5.0
    assert float(f(Mine(jnp.asarray(np.full(2, 2.0)), jnp.ones(3)))) == 7.0  # new values, same program
    assert float(f(Mine(jnp.ones(2), jnp.ones(3), "other"))) == 5.0  # a new static value: traced again
    assert traces == ["x", "other"]


def test_own_init_subclass_and_frozen():
    c = Child([1.0, 2.0], 3.0)
    assert c.size == (3, 4) and float(c.extra) == 3.0
    assert [np.asarray(x).tolist() for x in jax.tree_util.tree_leaves(c)] == [[1.0, 2.0], 3.0]
    rebuilt = jax.tree_util.tree_map(lambda x: x + 1, c)  # no __init__ run on unflattening
    assert type(rebuilt) is Child and rebuilt.size == (3, 4) and float(rebuilt.extra) == 4.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.extra = jnp.zeros(())
    with pytest.raises(dataclasses.FrozenInstanceError):
        Mine(jnp.ones(1), jnp.ones(1)).a = jnp.zeros(1)


def test_photax_types_keep_their_static_fields_out_of_the_leaves():
    cam = FrameCamera.from_pixels(1000.0, (640, 480))
    ext = ExteriorOrientation([1.0, 2.0, 3.0], [0.1, 0.2, 0.3], "omega-phi-kappa")
    dem = DEM(np.zeros((3, 3)), (1, 0, 0, 0, -1, 3), crs="EPSG:32735")
    assert all(isinstance(x, jax.Array) for x in jax.tree_util.tree_leaves((cam, ext, dem)))
    assert len(jax.tree_util.tree_leaves(cam)) == 4  # focal length, principal point, distortion, pixel size
    again = jax.tree_util.tree_map(lambda x: x, (cam, ext, dem))
    assert again[0].image_size == (640, 480) and again[1].convention == "omega-phi-kappa"
    assert again[2].crs == "EPSG:32735"
    np.testing.assert_allclose(again[0].image_to_pixel(jnp.zeros(2)), cam.image_to_pixel(jnp.zeros(2)))


def test_equality_is_equinox_tree_equal():
    a, b = Mine(jnp.ones(2), jnp.zeros(3), "n"), Theirs(jnp.ones(2), jnp.zeros(3), "n")
    assert a == Mine(jnp.ones(2), jnp.zeros(3), "n") and b == Theirs(jnp.ones(2), jnp.zeros(3), "n")
    assert a != Mine(jnp.ones(2), jnp.ones(3), "n") and b != Theirs(jnp.ones(2), jnp.ones(3), "n")
    assert a != Mine(jnp.ones(2), jnp.zeros(3), "m") and b != Theirs(jnp.ones(2), jnp.zeros(3), "m")
    cam = FrameCamera.from_pixels(1000.0, (640, 480))
    assert cam == FrameCamera.from_pixels(1000.0, (640, 480)) and cam != FrameCamera.from_pixels(999.0, (640, 480))
