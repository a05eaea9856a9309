"""What every reader shares: opening a file (regular files of a bounded size,
recorded as the command's inputs), decoding it, parsing YAML/JSON, and
reporting a bad file as one ``ValueError`` line naming the file and line.

The contract (``docs/architecture.md``): a reader returns a result or raises
``ValueError("<file>, line <n>: <what is wrong>")`` (``"<file>: ..."`` when
no line applies); a missing file is ``FileNotFoundError`` naming it.  No
parser's own exception (YAML, JSON, Unicode, csv) reaches the caller.  The
fuzz tests (``tests/test_fuzz_readers.py``) hold every reader to it.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import math
import os
import pathlib
import re
import stat

import yaml

from .._values import as_numbers, excerpt  # noqa: F401 -- io's names too; below io, for the models
from ..errors import UnreadableFileError


def where(path, line: int | None = None) -> str:
    """``"path, line n"``, or ``"path"`` when ``line`` is None."""
    return f"{path}" if line is None else f"{path}, line {line}"


def file_error(path, line: int | None, message: str) -> ValueError:
    """The reader error: ``ValueError("path, line n: message")``, on one line."""
    return ValueError(f"{where(path, line)}: {' '.join(str(message).split())}")


# --- Opening: regular files of a sane size, recorded as inputs -----------------------

#: The largest file each reader reads, by the ``what`` it names the file with
#: (``docs/architecture.md``).  Small files are configuration (a camera, a CRS);
#: tables (GCPs, orientations, blocks, results) may be large; BAL files larger.
MiB, GiB = 1 << 20, 1 << 30
MAX_BYTES = {
    "camera file": MiB,
    "orthority interior file": MiB,
    ".prj file": MiB,
    "fiducial file": MiB,
    "BAL file": 4 * GiB,
}
MAX_BYTES_DEFAULT = GiB

_INPUTS: contextvars.ContextVar[set | None] = contextvars.ContextVar("photax_inputs", default=None)


@contextlib.contextmanager
def recording_inputs():
    """Record, while open, every file the readers open (:func:`read_bytes`,
    :func:`photax.io.raster.open_raster`): one command's set of inputs, which
    :func:`photax.io.atomic.check_output_path` refuses to write over.  The CLI
    opens one per command; yields the set of paths."""
    token = _INPUTS.set(set())
    try:
        yield _INPUTS.get()
    finally:
        _INPUTS.reset(token)


def note_input(path) -> None:
    """Add ``path`` to the inputs being recorded (nothing when none are)."""
    seen = _INPUTS.get()
    if seen is not None:
        seen.add(pathlib.Path(path).absolute())


def inputs_read() -> tuple[pathlib.Path, ...]:
    """The inputs recorded so far (empty outside :func:`recording_inputs`)."""
    return tuple(_INPUTS.get() or ())


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def check_regular(path, what: str = "file", st: os.stat_result | None = None) -> os.stat_result:
    """``os.stat(path)`` after checking ``path`` is a regular file (symbolic links followed).

    Raises:
        FileNotFoundError: no such file.
        ValueError: a folder, a device, a FIFO or a socket, naming ``path``.
    """
    path = pathlib.Path(path)
    if st is None:
        try:
            st = path.stat()
        except FileNotFoundError:
            raise FileNotFoundError(f"{path}: no such {what}") from None
        except OSError as exc:
            raise UnreadableFileError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise UnreadableFileError(f"{path}: is a folder, expected a {what}")
    if not stat.S_ISREG(st.st_mode):
        raise UnreadableFileError(f"{path}: {_kind(st.st_mode)}, not a regular file; expected a {what}")
    return st


def _too_large(path, what: str, size: int, limit: int, over: bool = False) -> ValueError:
    def amount(n):
        return f"{n} bytes" if n < MiB else f"{n / MiB:.3g} MiB" if n < GiB else f"{n / GiB:.3g} GiB"

    return ValueError(
        f"{path}: {'over ' * over}{amount(size)}, too large for a {what} "
        f"(at most {amount(limit)}); is this the right file?"
    )


def read_bytes(path, what: str = "file") -> bytes:
    """The bytes of ``path``: a regular file of at most ``MAX_BYTES[what]``.

    The file is recorded as an input (:func:`recording_inputs`).

    Raises:
        FileNotFoundError: no such file.
        ValueError: ``path`` is a folder, a device, a FIFO or a socket, is
            larger than the limit, or cannot be read (permissions, I/O
            error), naming ``path``.
    """
    path = pathlib.Path(path)
    limit = MAX_BYTES.get(what, MAX_BYTES_DEFAULT)
    note_input(path)
    check_regular(path, what)  # before opening: opening a FIFO would block, a device may act
    try:
        # O_NONBLOCK: should the path have become a FIFO since the check, open() returns at once
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such {what}") from None
    except OSError as exc:  # PermissionError, EIO, ...
        raise UnreadableFileError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    with open(fd, "rb", closefd=True) as fh:
        st = check_regular(path, what, os.fstat(fd))
        if st.st_size > limit:
            raise _too_large(path, what, st.st_size, limit)
        try:
            raw = fh.read(limit + 1)  # a file growing while read is still bounded
        except OSError as exc:
            raise UnreadableFileError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    if len(raw) > limit:
        raise _too_large(path, what, limit, limit, over=True)
    return raw


# Parser messages quote the text they stopped at; of a file that did not parse
# only a character or a token name (``'\t'``, ``'<scalar>'``) is kept.
_QUOTED = re.compile(r"(['\"])(?!<)[^'\"]{5,}\1")


def _parser_problem(text) -> str:
    return _QUOTED.sub("(...)", " ".join(str(text).split()))


def decode(path, raw: bytes) -> str:
    """UTF-8 text (a byte-order mark is dropped); binary content is an error naming its line."""
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise file_error(path, line, f"not UTF-8 text (byte {raw[exc.start]:#04x}); is this the right file?") from None
    nul = text.find("\x00")
    if nul >= 0:
        raise file_error(path, text.count("\n", 0, nul) + 1, "a NUL byte: this is a binary file, not text")
    return text


def read_text(path, what: str = "file") -> str:
    """:func:`read_bytes` then :func:`decode`."""
    return decode(path, read_bytes(path, what))


def split_lines(text: str) -> list[str]:
    """Lines as an editor numbers them: split at ``\\n`` only, a trailing ``\\r``
    dropped (``str.splitlines`` also splits at form feeds, ``\\x1c``, U+2028, ...,
    which would make every line number after them wrong)."""
    return [ln[:-1] if ln.endswith("\r") else ln for ln in text.split("\n")]


def number(path, line: int | None, text, what: str) -> float:
    """A finite float from ``text``, else :func:`file_error` naming ``what``."""
    try:
        value = float(text)
    except (TypeError, ValueError, OverflowError):
        raise file_error(path, line, f"{what} is not a number: {excerpt(str(text))}") from None
    if not math.isfinite(value):
        raise file_error(path, line, f"{what} is not finite: {excerpt(str(text))}")
    return value


# --- The type of a value read from a YAML / JSON file ---------------------------------

#: The kinds of value :func:`expect` checks, as a file's author would name them.
_KINDS = {
    "text": (lambda v: isinstance(v, str), "text"),
    "mapping": (lambda v: isinstance(v, dict), "a mapping"),
    "list": (lambda v: isinstance(v, list), "a list"),
    "number": (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool), "a number"),
    "integer": (lambda v: isinstance(v, int) and not isinstance(v, bool), "a whole number"),
    "boolean": (lambda v: isinstance(v, bool), "true or false"),
    "null": (lambda v: v is None, "null"),
}


def kind_of(value) -> str:
    """What ``value`` is, in a file's terms: ``"null"``, ``"true or false"``, ``"a number"``,
    ``"text"``, ``"a list"``, ``"a mapping"`` (else its Python type's name)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true or false"
    if isinstance(value, (int, float)):
        return "a number"
    for name in ("text", "list", "mapping"):
        if _KINDS[name][0](value):
            return _KINDS[name][1]
    return type(value).__name__


def at_line(data, key, default: int | None = None) -> int | None:
    """The line of ``key`` in ``data`` (a :class:`Mapping` read from YAML), else ``default``."""
    line = data.line(key) if isinstance(data, Mapping) else None
    return default if line is None else line


def expect(value, kind: str | tuple[str, ...], key, path, line: int | None = None, what: str | None = None):
    """``value`` (read from ``path`` under ``key``) if it is of ``kind`` (one of
    ``"text"``, ``"mapping"``, ``"list"``, ``"number"``, ``"integer"``,
    ``"boolean"``, ``"null"``, or a tuple of them), else the reader's
    :func:`file_error` naming ``key`` (and ``line``; with a :class:`Mapping`
    ``line`` may be the mapping: the key's line is taken from it) and what
    was found instead: ``"path, line 3: type must be text, got a list: []"``.
    ``what`` prefixes the message (``"camera 'cam'"``).  The one check every
    reader makes before using a value as a key, text or number, so that a
    list, mapping, null or number where another kind is expected is the
    file's error, never ``TypeError`` (issue 38).

    >>> expect("pinhole", "text", "type", "int.yaml")
    'pinhole'
    >>> expect([], "text", "type", "int.yaml", 3)
    Traceback (most recent call last):
    ...
    ValueError: int.yaml, line 3: type must be text, got a list: []
    """
    kinds = (kind,) if isinstance(kind, str) else tuple(kind)
    if any(_KINDS[k][0](value) for k in kinds):
        return value
    if isinstance(line, Mapping):
        line = line.line(key)
    want = " or ".join(_KINDS[k][1] for k in kinds)
    got = kind_of(value)
    shown = "" if value is None or isinstance(value, bool) else f": {excerpt(value)}"
    prefix = f"{what}: " if what else ""
    raise file_error(
        path, line, f"{prefix}{excerpt(key) if not isinstance(key, str) else key} must be {want}, got {got}{shown}"
    )


# --- YAML and JSON ------------------------------------------------------------------


class Mapping(dict):
    """A YAML/JSON mapping that remembers the line of each key (``lines``; empty for JSON)."""

    lines: dict

    def __init__(self, *args, lines=None):
        super().__init__(*args)
        self.lines = dict(lines or {})

    def line(self, key) -> int | None:
        return self.lines.get(key)


#: Values a YAML file may expand to through its aliases (``*name``): a kilobyte of
#: nested aliases ("billion laughs") otherwise expands to billions.
MAX_YAML_ALIAS_VALUES = 100_000


class _Loader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys (the second silently won) and
    aliases expanding to over :data:`MAX_YAML_ALIAS_VALUES` values, and records
    each key's line."""

    def __init__(self, stream):
        super().__init__(stream)
        self._sizes: dict[int, int] = {}
        self._expanded = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            node = self.anchors.get(event.anchor)
            if node is not None:
                self._expanded += self._size(node)
                if self._expanded > MAX_YAML_ALIAS_VALUES:
                    raise yaml.composer.ComposerError(
                        None, None, f"its aliases expand to over {MAX_YAML_ALIAS_VALUES} values", event.start_mark
                    )
        return super().compose_node(parent, index)

    def _size(self, node) -> int:
        """Values in ``node``, aliases expanded (memoised: each anchor is counted once)."""
        if id(node) not in self._sizes:
            self._sizes[id(node)] = 1  # an alias to an ancestor counts once
            if isinstance(node, yaml.SequenceNode):
                self._sizes[id(node)] = 1 + sum(self._size(v) for v in node.value)
            elif isinstance(node, yaml.MappingNode):
                self._sizes[id(node)] = 1 + sum(self._size(k) + self._size(v) for k, v in node.value)
        return self._sizes[id(node)]

    def construct_mapping(self, node, deep=False):
        if not isinstance(node, yaml.MappingNode):
            return super().construct_mapping(node, deep)
        self.flatten_mapping(node)
        out, lines = {}, {}
        for key_node, value_node in node.value:
            key = self.construct_object(key_node, deep=deep)
            try:
                hash(key)
            except TypeError:
                raise yaml.constructor.ConstructorError(
                    None, None, f"a key must be a plain value, got {type(key).__name__}", key_node.start_mark
                ) from None
            if key in out:
                raise yaml.constructor.ConstructorError(
                    None, None, f"a key given twice (first on line {lines[key]})", key_node.start_mark
                )
            out[key] = self.construct_object(value_node, deep=deep)
            lines[key] = key_node.start_mark.line + 1
        return Mapping(out, lines=lines)


_Loader.add_constructor("tag:yaml.org,2002:map", lambda loader, node: loader.construct_mapping(node, deep=True))
# Dates stay text: a YAML timestamp is never a photax value, and an invalid
# one (2024-13-45) would otherwise raise a bare ValueError from datetime.
_Loader.add_constructor("tag:yaml.org,2002:timestamp", yaml.SafeLoader.construct_yaml_str)


def load_yaml(path, text: str):
    """Parse YAML safely; errors name the file and line."""
    try:
        return yaml.load(text, Loader=_Loader)  # noqa: S506 - _Loader is a SafeLoader
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = None if mark is None else mark.line + 1
        problem = _parser_problem(exc.problem or exc.context)
        raise file_error(path, line, f"not valid YAML: {problem}") from None
    except yaml.reader.ReaderError as exc:
        line = text.count("\n", 0, max(exc.position, 0)) + 1
        raise file_error(path, line, f"not valid YAML: {exc.reason} character {exc.character!r}") from None
    except yaml.YAMLError as exc:
        raise file_error(path, None, f"not valid YAML: {_parser_problem(exc)}") from None
    except RecursionError:
        raise file_error(path, None, "not valid YAML: nested too deeply") from None
    except (ValueError, OverflowError) as exc:  # a scalar constructor gave up
        raise file_error(path, None, f"not valid YAML: {exc}") from None


class _Bad(ValueError):
    """A value the JSON hooks refuse; ``token`` locates its line."""

    def __init__(self, message: str, token: str):
        super().__init__(message)
        self.token = token


def _no_constant(name):
    raise _Bad(f"{name} is not a JSON number (photax writes null for a missing value)", name)


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise _Bad(f"{text} is out of range for a float", text)
    return value


def load_json(path, text: str):
    """Parse strict JSON (no NaN/Infinity, no duplicate keys); errors name the file and line."""

    def pairs(items):
        out = {}
        for key, value in items:
            if key in out:
                raise _Bad("a key given twice", json.dumps(key))
            out[key] = value
        return Mapping(out)

    try:
        return json.loads(text, object_pairs_hook=pairs, parse_constant=_no_constant, parse_float=_finite_float)
    except json.JSONDecodeError as exc:
        raise file_error(path, exc.lineno, f"not valid JSON: {exc.msg}") from None
    except RecursionError:
        raise file_error(path, None, "not valid JSON: nested too deeply") from None
    except _Bad as exc:
        # The first occurrence of the token: its line for a constant or a
        # number, the first of the two lines for a duplicate key.
        at = text.find(exc.token)
        raise file_error(path, text.count("\n", 0, at) + 1 if at >= 0 else None, f"not valid JSON: {exc}") from None
    except ValueError as exc:  # an integer with too many digits
        raise file_error(path, None, f"not valid JSON: {exc}") from None


def opensfm_frame(path) -> tuple[str | None, object]:
    """``(frame, file)`` of ``grid:FILE`` or ``topocentric:FILE`` (a ``reconstruction.json``
    whose frame its ``gps_position`` do not tell: :func:`photax.io.read_opensfm_shots`),
    ``(None, path)`` for anything else (a file of that very name included)."""
    text = path if isinstance(path, str) else None
    if text is not None and not os.path.exists(text):
        for frame in ("grid", "topocentric"):
            if text.startswith(frame + ":") and os.path.isfile(text[len(frame) + 1 :]):
                return frame, text[len(frame) + 1 :]
    return None, path


def head_text(path, n: int) -> str:
    """The first ``n`` bytes of a regular file as text, a byte-order mark dropped ("" for anything
    else, or a file that cannot be opened: the reader reports it); for the formats' cheap sniffing
    tests (``is_*``), which never open a FIFO or device."""
    path = pathlib.Path(path)
    if not path.is_file():
        return ""
    try:
        with path.open("rb") as fh:
            return fh.read(n).decode("utf-8", "replace").lstrip("\ufeff")
    except OSError:
        return ""
