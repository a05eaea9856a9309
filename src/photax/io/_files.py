"""What every reader shares: opening a file, decoding it, parsing YAML/JSON,
and reporting a bad file as one ``ValueError`` line naming the file and line.

The contract (``docs/architecture.md``): a reader returns a result or raises
``ValueError("<file>, line <n>: <what is wrong>")`` (``"<file>: ..."`` when
no line applies); a missing file is ``FileNotFoundError`` naming it.  No
parser's own exception (YAML, JSON, Unicode, csv) reaches the caller.  The
fuzz tests (``tests/test_fuzz_readers.py``) hold every reader to it.
"""

from __future__ import annotations

import json
import math
import pathlib

import numpy as np
import yaml


def where(path, line: int | None = None) -> str:
    """``"path, line n"``, or ``"path"`` when ``line`` is None."""
    return f"{path}" if line is None else f"{path}, line {line}"


def file_error(path, line: int | None, message: str) -> ValueError:
    """The reader error: ``ValueError("path, line n: message")``, on one line."""
    return ValueError(f"{where(path, line)}: {' '.join(str(message).split())}")


def read_bytes(path, what: str = "file") -> bytes:
    """The bytes of ``path``.

    Raises:
        FileNotFoundError: no such file.
        ValueError: ``path`` is a folder, or cannot be read (permissions,
            I/O error), naming ``path``.
    """
    path = pathlib.Path(path)
    if path.is_dir():
        raise ValueError(f"{path}: is a folder, expected a {what}")
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such {what}") from None
    except OSError as exc:  # PermissionError, EIO, ...
        raise ValueError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None


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


def as_numbers(value):
    """``value`` (a number or nested lists of numbers) as float64, or None if
    it is not one.  Text that reads as a number counts (PyYAML follows YAML
    1.1, where ``1e-5`` without a dot is a string); booleans and nulls do not
    (``true`` is not 1)."""

    def conv(v):
        if isinstance(v, (list, tuple)):
            return [conv(x) for x in v]
        if isinstance(v, bool) or not isinstance(v, (int, float, str)):
            raise TypeError
        return float(v) if isinstance(v, str) else v

    try:
        return np.asarray(conv(value), dtype=float)
    except (TypeError, ValueError, OverflowError, RecursionError):
        return None


def number(path, line: int | None, text, what: str) -> float:
    """A finite float from ``text``, else :func:`file_error` naming ``what``."""
    try:
        value = float(text)
    except (TypeError, ValueError, OverflowError):
        raise file_error(path, line, f"{what} is not a number: {str(text)!r}") from None
    if not math.isfinite(value):
        raise file_error(path, line, f"{what} is not finite: {str(text)!r}")
    return value


# --- YAML and JSON ------------------------------------------------------------------


class Mapping(dict):
    """A YAML/JSON mapping that remembers the line of each key (``lines``; empty for JSON)."""

    lines: dict

    def __init__(self, *args, lines=None):
        super().__init__(*args)
        self.lines = dict(lines or {})

    def line(self, key) -> int | None:
        return self.lines.get(key)


class _Loader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys (the second silently won) and
    records each key's line."""

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
                    None, None, f"duplicate key {key!r} (first on line {lines[key]})", key_node.start_mark
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
        raise file_error(path, line, f"not valid YAML: {exc.problem or exc.context}") from None
    except yaml.reader.ReaderError as exc:
        line = text.count("\n", 0, max(exc.position, 0)) + 1
        raise file_error(path, line, f"not valid YAML: {exc.reason} character {exc.character!r}") from None
    except yaml.YAMLError as exc:
        raise file_error(path, None, f"not valid YAML: {exc}") from None
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
                raise _Bad(f"duplicate key {key!r}", json.dumps(key))
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
