"""Progress bars: one per command, named after it.

Long functions (:func:`photax.rectify`, :func:`photax.rectify_file`,
:func:`photax.bundle_adjust`, :meth:`photax.ModelComparison.rectify`,
:func:`photax.demo.run_demo`) take a ``progress`` argument:

* ``False`` (default): no bar, and tqdm is not even imported;
* ``True``: a bar labelled with the function's own name (``"rectify"``...);
* a string: a bar with that label (the command line passes the command's
  name: ``photax ortho`` shows one bar labelled ``ortho``);
* a bar made by :func:`progress_bar`: the function advances that bar and
  leaves it open, so a caller running several stages (``photax compare``
  rectifying with six models) shows one bar, not one per stage.  The caller
  sets its total.

Bars are ``tqdm.auto``'s choice (imported as it does, without its asyncio
mix-in): a widget in Jupyter (needs ``ipywidgets``, in the ``notebooks`` and
``test`` extras; without it tqdm falls back to text and warns with
``TqdmWarning``), text on stderr elsewhere.
"""

from __future__ import annotations

import contextlib

__all__ = ["progress_bar"]


class _NoBar:
    """What a disabled bar needs to answer."""

    total = 0

    def update(self, n=1):
        pass

    def set_postfix(self, *args, **kwargs):
        pass

    def set_postfix_str(self, *args, **kwargs):
        pass

    def close(self):
        pass


def _is_bar(obj) -> bool:
    return hasattr(obj, "update") and hasattr(obj, "set_postfix")


def progress_bar(progress, total: int | None, *, desc: str, unit: str = "it"):
    """A context manager giving the bar ``progress`` asks for (module docstring).

    Args:
        progress: ``False``/``None``, ``True``, a label, or an open bar.
        total: number of steps, or ``None`` where it is not known (the bar
            counts them); ignored when ``progress`` is an open bar.
        desc: the label when ``progress is True``.
        unit: what one step is ("tile", "it", "section").

    Raises:
        ValueError: ``progress`` is none of these.
    """
    if progress is None or progress is False:
        return contextlib.nullcontext(_NoBar())
    if _is_bar(progress):
        return contextlib.nullcontext(progress)  # the caller owns and closes it
    if progress is True:
        label = desc
    elif isinstance(progress, str) and progress:
        label = progress
    else:
        raise ValueError(f"progress must be a bool, a label or a progress bar, got {progress!r}")
    return _bar(total, label, unit)


@contextlib.contextmanager
def _bar(total, label: str, unit: str):
    """A tqdm bar kept on screen when its work is done, wiped when it fails: an error
    ends in its one-line message, not in a bar's fragment ("mosaic: 0step")."""
    import warnings

    from tqdm.std import TqdmExperimentalWarning

    with warnings.catch_warnings():  # tqdm.auto's own import: its choice of bar, without the asyncio
        warnings.simplefilter("ignore", TqdmExperimentalWarning)  # mix-in (importing asyncio: 36 ms a command)
        from tqdm.autonotebook import tqdm

    bar = tqdm(total=total, desc=label, unit=unit, dynamic_ncols=True)
    try:
        yield bar
    except BaseException:
        bar.leave = False
        raise
    finally:
        bar.close()
