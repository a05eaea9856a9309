"""Old public names kept as aliases that warn (``docs/conventions.md``, "Words").

Private utility module, imported across photax's units as ``_linalg`` is:
the one way an old attribute or keyword name is kept working while it says
what replaced it.
"""

from __future__ import annotations

import warnings


def warn_renamed(old: str, new: str, *, stacklevel: int = 3) -> None:
    """A :class:`DeprecationWarning`: ``old`` is now called ``new``."""
    warnings.warn(
        f"{old} is deprecated: use {new} (the same value; docs/conventions.md)",
        DeprecationWarning,
        stacklevel=stacklevel,
    )


def alias(new: str) -> property:
    """A read-only attribute that returns ``self.<new>`` with a :class:`DeprecationWarning`;
    its old name is the one it is assigned to in the class body."""

    class _Alias(property):
        def __set_name__(self, owner, name):
            self.old = name

    def get(self):
        warn_renamed(f"{type(self).__name__}.{prop.old}", f"{type(self).__name__}.{new}")
        return getattr(self, new)

    prop = _Alias(get, doc=f"Deprecated alias of :attr:`{new}`.")
    return prop


def renamed_argument(function: str, old: str, old_value, new: str, new_value, default):
    """The value of keyword ``new`` when the caller may still pass ``old`` (None when not passed):
    ``old``'s value with a :class:`DeprecationWarning`; both given is a ``ValueError``."""
    if old_value is None:
        return new_value
    if new_value != default:
        raise ValueError(f"{function}: give {new}= only ({old}= is its deprecated old name)")
    warn_renamed(f"{function}({old}=)", f"{function}({new}=)", stacklevel=4)
    return old_value
