"""Frozen dataclasses registered as JAX pytrees: what photax's types on the orthorectification path
(cameras, orientations, DEMs, sensors) ask of ``equinox.Module``, without importing equinox.

``import equinox`` costs 0.2 s of CPU (its neural-network layers, jaxtyping, unittest.mock...): a
tenth of a warm ``photax ortho`` process, which runs only programs photax._aot loads from disk.
:class:`Module` is a dataclass whose fields are the pytree's children, except those declared
``field(static=True)`` (or ``equinox.field(static=True)``: the same metadata), which are its
auxiliary data, as in equinox; a class may define its own ``__init__`` (setting its fields), and
is frozen once it returns.  ``equinox`` functions (``filter_jit``, ``tree_at``, ``partition``)
work on these as on any pytree, and ``==`` is equinox's ``tree_equal`` (equinox imported then).
Unlike ``equinox.Module``: methods are plain Python methods (not pytrees themselves).  :func:`filter_jit` is
``equinox.filter_jit`` made at the first call.

Private utility module: other photax units import its names directly
(``tests/test_imports.py`` lists the modules allowed that).
"""

from __future__ import annotations

import dataclasses
import functools

import jax


def field(*, static: bool = False, **kwargs):
    """A dataclass field; ``static=True``: part of the pytree structure, not a leaf."""
    return dataclasses.field(metadata={"static": static}, **kwargs)


class Module:
    """Base of a frozen dataclass registered as a pytree (module docstring)."""

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        # the dataclass's own __init__ only where neither the class nor a parent module defines one
        written = any("__init__" in k.__dict__ for k in cls.__mro__ if k not in (Module, object))
        dataclasses.dataclass(cls, init=not written, repr=False, eq=False)
        init = cls.__init__

        @functools.wraps(init)
        def __init__(self, *args, **kw):
            depth = self.__dict__.get("_initialising", 0)  # a subclass's __init__ calling its parent's
            object.__setattr__(self, "_initialising", depth + 1)
            try:
                init(self, *args, **kw)
            finally:
                if depth:
                    object.__setattr__(self, "_initialising", depth)
                else:
                    object.__delattr__(self, "_initialising")

        cls.__init__ = __init__
        fields = dataclasses.fields(cls)
        children = tuple(f.name for f in fields if not f.metadata.get("static", False))
        static = tuple(f.name for f in fields if f.metadata.get("static", False))

        def flatten_with_keys(obj):
            return [(jax.tree_util.GetAttrKey(n), getattr(obj, n)) for n in children], tuple(
                getattr(obj, n) for n in static
            )

        def flatten(obj):
            return [getattr(obj, n) for n in children], tuple(getattr(obj, n) for n in static)

        def unflatten(aux, leaves):
            obj = object.__new__(cls)
            for n, v in zip(children, leaves):
                object.__setattr__(obj, n, v)
            for n, v in zip(static, aux):
                object.__setattr__(obj, n, v)
            return obj

        jax.tree_util.register_pytree_with_keys(cls, flatten_with_keys, unflatten, flatten)

    def __setattr__(self, name, value):
        if "_initialising" not in self.__dict__:
            raise dataclasses.FrozenInstanceError(f"cannot assign to field {name!r} of a {type(self).__name__}")
        object.__setattr__(self, name, value)

    def __eq__(self, other):
        import equinox as eqx  # here: == is not on the ortho path

        return eqx.tree_equal(self, other)  # equinox.Module's: same structure, equal leaves

    def __hash__(self):
        return hash(tuple(jax.tree_util.tree_leaves(self)))  # equinox.Module's

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(f'{f.name}={getattr(self, f.name, None)!r}' for f in dataclasses.fields(self))})"


def filter_jit(fn):
    """``equinox.filter_jit(fn)``, made at the first call: equinox is imported then, not when the
    module defining ``fn`` is (a warm run loads its programs from disk and never calls it)."""
    jitted = None

    @functools.wraps(fn)
    def call(*args, **kwargs):
        nonlocal jitted
        if jitted is None:
            import equinox as eqx

            jitted = eqx.filter_jit(fn)
        return jitted(*args, **kwargs)

    return call


def is_array(x) -> bool:
    """``equinox.is_array``: a JAX or NumPy array (or NumPy scalar)."""
    import numpy as np

    return isinstance(x, (jax.Array, np.ndarray, np.generic))
