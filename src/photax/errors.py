"""Exceptions photax raises besides ValueError, and the outcome codes of its solvers.

Outcomes and ``throw`` (docs/architecture.md): every solver result carries
``result`` (a :class:`RESULTS` code) next to ``converged`` and ``message``.
With ``throw=True`` a failure raises :class:`ConvergenceError` with the same
message; with ``throw=False`` the result comes back flagged, values finite.
"""

from __future__ import annotations

import enum


class ConvergenceError(RuntimeError):
    """An estimate did not converge; the message says why.

    Raised only with ``throw=True``; with ``throw=False`` the result carries
    ``converged=False`` and the same message instead.

    Examples:
        Raised by an estimate that did not converge when ``throw=True``:

        >>> import photax as ptx
        >>> issubclass(ptx.ConvergenceError, RuntimeError)
        True
    """


_SINGULAR = "the normal equations became singular (the control points do not determine the orientation from there)"


class RESULTS(enum.IntEnum):
    """Outcome of a photax solver, as optimistix's ``RESULTS`` but in photax's words.

    Integer-valued, so compiled code returns them as ``int`` arrays (one per
    image of a batch) and ``RESULTS(code)`` names them.  ``successful`` is 0;
    :attr:`text` is the reason shown in messages.

    Examples:
        Solver outcomes as codes, each with its message:

        >>> import photax as ptx
        >>> ptx.RESULTS(0) is ptx.RESULTS.successful, int(ptx.RESULTS.max_steps_reached) > 0
        (True, True)
    """

    successful = 0
    max_steps_reached = 1
    singular = 2
    nonfinite = 3
    diverged = 4
    solver_failed = 5  # an optimistix outcome photax has no words for
    behind_camera = 6  # converged, but points lie behind the camera
    implausible = 7  # converged, but image and ground evidently do not belong together

    @property
    def text(self) -> str:
        return _TEXTS[self]


_TEXTS = {
    RESULTS.successful: "converged",
    RESULTS.max_steps_reached: "the iteration limit was reached",
    RESULTS.singular: _SINGULAR,
    RESULTS.nonfinite: "the estimate became non-finite (NaN or inf)",
    RESULTS.diverged: "the iterations diverged",
    RESULTS.solver_failed: "the solver failed",
    RESULTS.behind_camera: "the solution puts control points behind the camera",
    RESULTS.implausible: "the solution is implausible",
}


def from_optimistix(result):
    """optimistix's outcome (``Solution.result``, traced or not) -> a
    :class:`RESULTS` code (an int array), through optimistix's public
    ``optx.RESULTS`` items, never its private tables; an item this
    optimistix version lacks is skipped, an outcome photax has no words for
    is ``solver_failed``."""
    import jax.numpy as jnp
    import optimistix as optx

    words = [("successful", RESULTS.successful), ("max_steps_reached", RESULTS.max_steps_reached),
             ("nonlinear_max_steps_reached", RESULTS.max_steps_reached), ("singular", RESULTS.singular),
             ("breakdown", RESULTS.singular), ("stagnation", RESULTS.singular), ("conlim", RESULTS.singular),
             ("nonfinite_input", RESULTS.nonfinite), ("nonfinite", RESULTS.nonfinite),
             ("nonlinear_divergence", RESULTS.diverged)]  # fmt: skip
    code = jnp.array(RESULTS.solver_failed)
    for name, ours in reversed(words):
        item = getattr(optx.RESULTS, name, None)
        if item is not None:
            code = jnp.where(result == item, ours, code)
    return code
