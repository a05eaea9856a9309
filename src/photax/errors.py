"""photax's exception types, and the outcome codes of its solvers.

The exceptions form one small hierarchy under :class:`PhotaxError`, so that a
caller (the CLI among them) decides on the *type* of a failure, never on its
words::

    PhotaxError
    ├── UnreadableFileError      (also OSError and ValueError)
    ├── UnsupportedFormatError   (ValueError)
    │   └── NoEntryError         (a file of several entries has none of that name; also LookupError)
    ├── MalformedFileError       (ValueError; a file of a format photax reads, a bad value: names line or key)
    ├── CRSMismatchError         (ValueError)
    │   └── OutputCRSError       (an output CRS the sensor model cannot give: a frame ortho's is its orientation's)
    ├── OutsideValidityError     (ValueError)
    ├── DegenerateGeometryError  (ValueError)
    └── NotConvergedError        (ValueError)
        └── ConvergenceError     (also RuntimeError; a solver's ``throw=True``)

and one warning, :class:`PartialDEMWarning` (a ``UserWarning``: the DEM covers part of an image, its
``coverage`` the share).

Each is a subclass of the built-in exception photax raised for it before, so
``except ValueError`` (and ``pytest.raises(ValueError)``) still catches it.
Plain ``ValueError`` remains the error of a malformed argument (a wrong shape,
an unknown option name), naming the argument.

Outcomes and ``throw`` (docs/architecture.md): every solver result carries
``result`` (a :class:`RESULTS` code) next to ``converged`` and ``message``.
With ``throw=True`` a failure raises :class:`ConvergenceError` with the same
message; with ``throw=False`` the result comes back flagged, values finite.

Examples
--------
>>> from photax.errors import PhotaxError, UnreadableFileError
>>> try:
...     raise UnreadableFileError("x.tif: cannot read the image (permission denied)")
... except ValueError as exc:  # what photax raised before, still caught
...     isinstance(exc, (PhotaxError, OSError))
True
"""

from __future__ import annotations

import enum


class PhotaxError(Exception):
    """Base of every error photax raises on purpose: the input, not a bug, is at fault.

    Examples:
        One ``except`` for every input photax refuses; the type tells what was wrong:

        >>> import photax as ptx
        >>> try:
        ...     ptx.utm_crs(lon=0.0, lat=88.0)
        ... except ptx.PhotaxError as exc:
        ...     print(type(exc).__name__, "-", exc)
        OutsideValidityError - no UTM zone at lon 0.0, lat 88.0 (UTM covers lat 80 S to 84 N)
    """


class UnreadableFileError(PhotaxError, OSError, ValueError):
    """A file that cannot be read: missing, not a regular file, no permission, damaged.

    ``str(exc)`` is photax's whole message (``OSError``'s ``errno`` /
    ``strerror`` are not set: the message already names the file and why).

    Examples:
        A folder where a file was expected:

        >>> import tempfile
        >>> import photax as ptx
        >>> ptx.read_gcps(tempfile.mkdtemp())
        Traceback (most recent call last):
        ...
        photax.errors.UnreadableFileError: ...: is a folder, expected a GCP file
    """

    def __init__(self, *args):
        Exception.__init__(self, *args)  # not OSError's (errno, strerror) signature

    def __str__(self) -> str:
        return Exception.__str__(self)


class UnsupportedFormatError(PhotaxError, ValueError):
    """A file (or a ``format=``) photax does not read: the message names the file and what was looked for
    (``photax.io.satellite.FORMATS`` for RPC files).

    Examples:
        A text file that is no RPC file of any family photax reads (the message lists them):

        >>> import pathlib, tempfile
        >>> import photax as ptx
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "notes.txt"
        >>> _ = path.write_text("hello\\n")
        >>> ptx.read_rpc(path)
        Traceback (most recent call last):
        ...
        photax.errors.UnsupportedFormatError: ...notes.txt: not an RPC file photax reads; it reads ...
    """


class NoEntryError(UnsupportedFormatError, LookupError):
    """A file of several entries (an orthority ``rpc_param.yaml``, a camera file) has none of the name asked for.

    Examples:
        An orthority ``rpc_param.yaml`` with one image, asked for another:

        >>> import pathlib, tempfile
        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.io import write_orthority_rpc
        >>> t = np.eye(20)  # terms 1, L, P of the 20: column = 500 + 500 L, row = 500 - 500 P
        >>> rpc = ptx.RPCCamera([-t[2], t[0], t[1], t[0]], [10.0, 45.0, 0.0, 500.0, 500.0],
        ...                     [0.01, 0.01, 500.0, 500.0, 500.0], image_size=(1000, 1000))
        >>> path = write_orthority_rpc(pathlib.Path(tempfile.mkdtemp()) / "rpc_param.yaml", {"scene.tif": rpc})
        >>> ptx.read_rpc(path, "other.tif")
        Traceback (most recent call last):
        ...
        photax.errors.NoEntryError: ...rpc_param.yaml: no entry 'other.tif' (it has 1)
    """


class CRSMismatchError(PhotaxError, ValueError):
    """Inputs in different (or missing, or unusable) coordinate reference systems.

    Examples:
        photax does not reproject between two CRSs it is handed; it names both:

        >>> from photax.geo import require_same
        >>> require_same("EPSG:32632", "the DEM", "EPSG:32633", "the GCPs")
        Traceback (most recent call last):
        ...
        photax.errors.CRSMismatchError: the DEM is in EPSG:32632 but the GCPs in EPSG:32633; ...
    """


class OutsideValidityError(PhotaxError, ValueError):
    """Points outside where a model holds: a sensor's height range or ground box, a CRS's or a grid's area.

    Examples:
        UTM stops at 84 N:

        >>> import photax as ptx
        >>> ptx.utm_crs(lon=10.0, lat=85.0)
        Traceback (most recent call last):
        ...
        photax.errors.OutsideValidityError: no UTM zone at lon 10.0, lat 85.0 (UTM covers lat 80 S to 84 N)
    """


class DegenerateGeometryError(PhotaxError, ValueError):
    """A configuration that does not determine the answer: collinear points, a singular transform.

    Examples:
        Four points on one line do not fix a projective transform:

        >>> import numpy as np
        >>> import photax as ptx
        >>> line = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])
        >>> ptx.fit_projective(line, np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]))
        Traceback (most recent call last):
        ...
        photax.errors.DegenerateGeometryError: degenerate configuration for a projective transform: ...
    """


class NotConvergedError(PhotaxError, ValueError):
    """An iteration (an estimate, an RPC's inverse) did not converge; the message says why."""


class ConvergenceError(NotConvergedError, RuntimeError):
    """An estimate did not converge; the message says why.

    Raised only with ``throw=True``; with ``throw=False`` the result carries
    ``converged=False`` and the same message instead.

    Examples:
        Raised by an estimate that did not converge when ``throw=True``:

        >>> import photax as ptx
        >>> issubclass(ptx.ConvergenceError, RuntimeError)
        True
    """


class MalformedFileError(PhotaxError, ValueError):
    """A file of a format photax reads, with a bad or missing value; the message names the file and the
    line (text) or key (XML, JSON).

    Examples:
        A ``KEY: value`` RPC text without its coefficients:

        >>> import pathlib, tempfile
        >>> import photax as ptx
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "scene_RPC.TXT"
        >>> _ = path.write_text("LINE_OFF: 500\\nSAMP_OFF: 500\\n")
        >>> ptx.read_rpc(path)
        Traceback (most recent call last):
        ...
        photax.errors.MalformedFileError: ...scene_RPC.TXT: missing LINE_NUM_COEFF_1 .. _20, ...
    """


class OutputCRSError(CRSMismatchError):
    """The output CRS asked for is not one this sensor model can give the output in (a frame
    image's ortho is in its orientation's CRS); the message names both CRSs.

    Examples:
        A frame image oriented in UTM 33N asked for an ortho grid in longitude and latitude:

        >>> import numpy as np
        >>> import photax as ptx
        >>> from photax.grid import ortho_grid
        >>> camera = ptx.FrameCamera.from_pixels(100.0, (100, 100))
        >>> exterior = ptx.ExteriorOrientation([500000.0, 4000000.0, 100.0], [0.0, 0.0, 0.0])
        >>> dem = ptx.DEM(np.zeros((101, 101)), (1.0, 0.0, 499950.0, 0.0, -1.0, 4000050.0), crs="EPSG:32633")
        >>> ortho_grid(exterior, camera, dem, spec=ptx.GridSpec(crs="EPSG:4326"))
        Traceback (most recent call last):
        ...
        photax.errors.OutputCRSError: the output CRS (EPSG:4326) is not the frame orientation's (EPSG:32633): ...
    """


class PartialDEMWarning(UserWarning):
    """The DEM covers only part of an image's footprint (:func:`photax.dem_coverage` below
    :data:`photax.grid.PARTIAL_DEM`): the ortho is nodata where the DEM has no height.

    Attributes:
        coverage: the covered share of the image, 0 .. 1.

    Examples:
        A nadir image 100 m on a side orthorectified on a DEM of its western half only
        (:func:`photax.dem_coverage`'s example): the ortho comes with a warning of the share:

        >>> import warnings
        >>> import numpy as np
        >>> import photax as ptx
        >>> camera = ptx.FrameCamera.from_pixels(100.0, (100, 100))
        >>> exterior = ptx.ExteriorOrientation([0.0, 0.0, 100.0], [0.0, 0.0, 0.0])
        >>> west = ptx.DEM(np.zeros((101, 51)), (1.0, 0.0, -50.0, 0.0, -1.0, 50.0))  # x from -50 to 1 m
        >>> with warnings.catch_warnings(record=True) as caught:
        ...     warnings.simplefilter("always")
        ...     _ = ptx.orthorectify(np.ones((100, 100)), exterior, camera, west)
        >>> [(type(w.message).__name__, w.message.coverage) for w in caught]
        [('PartialDEMWarning', 0.5)]
    """

    def __init__(self, message: str, coverage: float):
        super().__init__(message)
        self.coverage = float(coverage)


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
