"""Exceptions photax raises besides ValueError."""


class ConvergenceError(RuntimeError):
    """An estimate did not converge; the message says why.

    Raised only with ``throw=True``; with ``throw=False`` the result carries
    ``converged=False`` and the same message instead.
    """
