"""Safe writing: no partial file on failure, never over an input.

Every output is written to a temporary file beside it (``.NAME.XXXXXXXX.part``),
synced to disk and only then renamed onto its name (:func:`atomic_path`): a
failed write (a full disk, a file size limit, an I/O error), an exception or
a signal leaves the previous file as it was and no temporary behind.
"""

from __future__ import annotations

import contextlib
import errno
import os
import pathlib
import re
import shutil
import stat
import tempfile
import threading
import time
import unicodedata
from collections.abc import Iterable, Iterator
from typing import IO

# Temporaries being written by this process (absolute paths): what
# cleanup_temporaries() removes.  A set, not guarded by a lock: add/discard
# are atomic under the GIL and a signal handler must not wait on a lock.
_LIVE: set[str] = set()
# The temporaries' names: tempfile's 8 random characters; with a suffix, the COG
# writer's intermediate GeoTIFF (photax.io.lazy), a previous file kept by all_or_nothing().
_PART = re.compile(r"\..+\.[a-z0-9_]{8}\.part(\.gtiff|\.old)?")
STALE_AFTER = 24 * 3600  # seconds: a temporary untouched this long is a leftover
# Outputs renamed into place in the all_or_nothing() block in effect, as
# (output, the previous file kept as a hard link or None, whether it existed).
_RUN: list | None = None


# Set by the command line's Ctrl-C handler (photax.cli): from then on no output is committed,
# even where a dependency swallowed the KeyboardInterrupt (it was raised inside an import or a
# callback that ignores it) and the run went on to its end.
interrupted = threading.Event()


def commit(tmp, out) -> None:
    """Rename ``tmp`` onto ``out``; ``KeyboardInterrupt`` instead after a Ctrl-C (:data:`interrupted`)."""
    if interrupted.is_set():
        raise KeyboardInterrupt
    os.replace(tmp, out)


def sidecars(path) -> list[pathlib.Path]:
    """Files GDAL and friends read beside ``path``: they are inputs too.

    For ``dir/x.tif``: ``x.prj``, ``x.tif.aux.xml``, ``x.aux``, ``x.tif.ovr``,
    ``x.ovr``, ``x.tif.msk``, ``x.msk``, world files ``x.tfw``, ``x.tifw``,
    ``x.wld`` (for ``.jpg``: ``x.jgw``, ``x.jpgw``; ``.png``: ``x.pgw``...),
    ``x.imd``, ``x.rpb``, ``x_rpc.txt``.  Existing or not.
    """
    p = pathlib.Path(path)
    return [p.with_name(n) for n in _sidecar_names(p)]


def _sidecar_names(p: pathlib.Path) -> list[str]:
    """The file names of :func:`sidecars` (strings: no path is made for a name that is not a candidate)."""
    stem, name, ext = p.stem, p.name, p.suffix.lower().lstrip(".")
    names = [
        f"{stem}.prj",
        f"{name}.prj",
        f"{name}.aux.xml",
        f"{stem}.aux",
        f"{name}.aux",
        f"{name}.ovr",
        f"{stem}.ovr",
        f"{name}.msk",
        f"{stem}.msk",
        f"{stem}.wld",
        f"{name}.wld",
        f"{stem}.imd",
        f"{stem}.rpb",
        f"{stem}_rpc.txt",
    ]
    if len(ext) >= 2:
        names += [f"{stem}.{ext[0]}{ext[-1]}w", f"{stem}.{ext}w"]
    return list(dict.fromkeys(names))


def _stat(p) -> os.stat_result | None:
    """``os.stat`` (symbolic links followed), None where it fails."""
    try:
        return os.stat(p)
    except (OSError, ValueError):
        return None


def _name_key(name: str) -> str:
    """A file name as a case-insensitive (and, on macOS, normalising) file system may match it."""
    return name.lower() if name.isascii() else unicodedata.normalize("NFC", name).casefold()


def _listing(listings: dict, folder: str) -> set | None:
    """The names in ``folder`` (:func:`_name_key`), listed once per check and kept in ``listings``;
    None where it cannot be listed.  Spares one ``stat`` per sidecar that is not there: the 16 names
    of each input, for each output of a block."""
    if folder not in listings:
        try:
            with os.scandir(folder) as entries:
                listings[folder] = {_name_key(e.name) for e in entries}
        except OSError:
            listings[folder] = None
    return listings[folder]


def check_output_path(out, inputs: Iterable = ()) -> pathlib.Path:
    """Refuse an output path that is one of the inputs; return it as a Path.

    Inputs are ``inputs`` and every file the readers opened in this command
    (:func:`photax.io.files.recording_inputs`: a block's camera files, a CSV's
    ``.prj``...), each with its sidecar files (:func:`sidecars`: ``.prj``,
    ``.aux.xml``, ``.ovr``, world files, ``.msk``...).  An existing folder
    is refused as an output file.

    Raises:
        ValueError: naming ``out`` and the input it would overwrite.
    """
    out = pathlib.Path(out)
    if out.is_dir():
        raise ValueError(f"refusing to write {out}: it is a folder")
    from .files import inputs_read  # here: the CLI imports this module before numpy

    # ``out``'s side of each comparison is made once, each input's sidecars are compared by name
    # before any file system call: a block of n images checks n outputs against n images' sidecars
    # (16 each), and re-resolving ``out`` for each of them was most of the block's per-image time.
    out_stat, name, folder = _stat(out), out.name.lower(), None
    listings: dict = {}  # an input's folder -> the names in it (_name_key), None where it cannot be listed
    for src in [*inputs, *inputs_read()]:
        if src is None:
            continue
        src = pathlib.Path(src)
        src_stat = _stat(src)
        # Both existing: one file, whatever the paths (links); an input not there: compare the paths.
        if src_stat is None:
            same = out.resolve() == src.resolve()
        else:
            same = out_stat is not None and os.path.samestat(out_stat, src_stat)
        if same:
            raise ValueError(f"refusing to write {out}: it is an input of this run")
        if src_stat is not None and stat.S_ISDIR(src_stat.st_mode):
            continue  # a folder input lists the files it reads (e.g. a block's) as inputs too
        parent = src.parent
        here = _listing(listings, str(parent)) if out_stat is not None else None
        for side in _sidecar_names(src):
            # Same folder and the same name up to case (GDAL tries .TFW and .tfw), or the same file.
            same = False
            if side.lower() == name:
                folder = out.parent.resolve() if folder is None else folder
                same = parent.resolve() == folder
            if not same and out_stat is not None and (here is None or _name_key(side) in here):
                st = _stat(src.with_name(side))
                same = st is not None and os.path.samestat(out_stat, st)
            if same:
                raise ValueError(f"refusing to write {out}: it is {side}, read with the input {src}")
    return out


@contextlib.contextmanager
def atomic_path(out, inputs: Iterable = (), *, size: int | None = None, folder: bool = False) -> Iterator[pathlib.Path]:
    """Yield a temporary path beside ``out``; rename it onto ``out`` on success.

    The temporary (``.NAME.XXXXXXXX.part``) is synced to disk (``fsync``)
    before the rename: a write error the operating system reports late (a
    full disk, a network file system) fails here, not after exit.  On any
    exception the temporary is removed and ``out`` is left as it was; it is
    also removed by :func:`cleanup_temporaries` (the CLI's handlers of
    SIGTERM, SIGINT and SIGHUP).  Stale temporaries of this naming older
    than a day in the folder are removed first.

    Args:
        out: the output.
        inputs: paths the run reads: ``out`` may not be one of them.
        size: bytes the output needs, where known before writing: refused
            at once (nothing written) when the folder's file system has less
            free space, or the process's file size limit is lower.
        folder: the output is a folder (a new or empty one): the temporary
            is a folder, renamed onto ``out`` as a whole.

    Raises:
        OSError: ``errno.ENOSPC``, ``EFBIG``, ``EDQUOT`` or ``EIO`` with
            ``filename`` ``out`` and a message saying what was needed and
            what is free, when the output could not be written.

    Examples:
        A temporary path to write to (by any library), renamed onto the target on success:

        >>> import pathlib, tempfile
        >>> from photax.io import atomic_path
        >>> out = pathlib.Path(tempfile.mkdtemp()) / "data.bin"
        >>> with atomic_path(out) as tmp:
        ...     _ = tmp.write_bytes(b"\\x00\\x01")
        ...     print(out.exists(), tmp.name.endswith(".part"))
        False True
        >>> out.read_bytes()
        b'\\x00\\x01'
    """
    out = pathlib.Path(out) if folder else check_output_path(out, inputs)
    parent = out.parent
    parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(parent)
    if size is not None:
        check_space(out, size)
    if folder:
        tmp = pathlib.Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".part", dir=parent))
    else:
        fd, name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".part", dir=parent)
        os.close(fd)
        tmp = pathlib.Path(name)
    _LIVE.add(os.path.abspath(tmp))
    try:
        # mkstemp / mkdtemp make it private (0600 / 0700); give it the permissions an
        # ordinary open() / mkdir() would have: 0666 / 0777 less the umask.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, (0o777 if folder else 0o666) & ~umask)
        yield tmp
        _fsync(tmp)
        _keep_previous(out, tmp)
        commit(tmp, out)
        _fsync_folder(parent)
    except BaseException as exc:
        failure = _write_failure(out, tmp, exc, size)
        if failure is None:
            raise
        raise failure from exc
    finally:
        _remove(tmp)
        _LIVE.discard(os.path.abspath(tmp))


@contextlib.contextmanager
def atomic_write(
    out, mode: str = "w", inputs: Iterable = (), *, size: int | None = None, **open_kwargs
) -> Iterator[IO]:
    """``open()`` for writing, atomically (see :func:`atomic_path`); a failing
    write or close raises (``OSError``) and leaves ``out`` as it was.

    Examples:
        ``open()`` whose file appears only when the block ends without error:

        >>> import pathlib, tempfile
        >>> from photax.io import atomic_write
        >>> out = pathlib.Path(tempfile.mkdtemp()) / "report.txt"
        >>> with atomic_write(out) as f:
        ...     _ = f.write("sigma0 1.02\\n")
        >>> out.read_text()
        'sigma0 1.02\\n'
        >>> try:
        ...     with atomic_write(out) as f:
        ...         _ = f.write("half a report")
        ...         raise RuntimeError("interrupted")
        ... except RuntimeError:
        ...     pass
        >>> out.read_text(), sorted(p.name for p in out.parent.iterdir())  # the old file kept, no temporary left
        ('sigma0 1.02\\n', ['report.txt'])
    """
    with atomic_path(out, inputs, size=size) as tmp, open(tmp, mode, **open_kwargs) as fh:
        yield fh


@contextlib.contextmanager
def temporary(path) -> Iterator[pathlib.Path]:
    """A further temporary file of a write (e.g. an intermediate copy),
    removed at the end of the block and by :func:`cleanup_temporaries`."""
    path = pathlib.Path(path)
    _LIVE.add(os.path.abspath(path))
    try:
        yield path
    finally:
        _remove(path)
        _LIVE.discard(os.path.abspath(path))


@contextlib.contextmanager
def all_or_nothing() -> Iterator[None]:
    """A run that writes all its outputs or none: when the block raises, the
    outputs :func:`atomic_path` renamed into place in it are taken back (the
    previous files restored, new ones removed).  The CLI runs each command
    in one: a command that fails writes nothing, even after some of its
    outputs were complete.  The previous files are kept meanwhile as hard
    links (no copy); where the file system has none, a replaced file stays."""
    global _RUN
    outer, _RUN = _RUN, []
    try:
        yield
    except BaseException:
        _take_back()
        raise
    finally:
        for _, previous, _ in _RUN or ():
            if previous is not None:
                _remove(previous)
                _LIVE.discard(os.path.abspath(previous))
        _RUN = outer


def _keep_previous(out: pathlib.Path, tmp: pathlib.Path) -> None:
    """In an :func:`all_or_nothing` block: note ``out`` as renamed into place,
    keeping the file it replaces (a hard link ``TMP.old``)."""
    if _RUN is None:
        return
    previous = None
    if out.is_file() and not out.is_symlink():
        with contextlib.suppress(OSError):
            os.link(out, f"{tmp}.old")
            previous = f"{tmp}.old"
            _LIVE.add(os.path.abspath(previous))
    _RUN.append((out, previous, out.exists()))


def _take_back() -> None:
    """Undo the renames of the :func:`all_or_nothing` block in effect, last first."""
    while _RUN:
        out, previous, existed = _RUN.pop()
        if previous is not None:
            with contextlib.suppress(OSError):
                os.replace(previous, out)
        elif not existed or out.is_dir():  # a new file, or a block written into an empty folder
            _remove(out)
            if existed:
                out.mkdir()


def cleanup_temporaries() -> None:
    """Remove every temporary this process is writing (:func:`atomic_path`),
    after taking back the outputs of the :func:`all_or_nothing` block in
    effect.

    For signal handlers (the CLI calls it on SIGTERM, SIGINT and SIGHUP):
    the outputs are then left as they were before the run.
    """
    _take_back()
    for path in list(_LIVE):
        _remove(path)
        _LIVE.discard(path)


def remove_stale_temporaries(folder, max_age: float = STALE_AFTER) -> None:
    """Remove photax's temporaries (``.NAME.XXXXXXXX.part``) in ``folder``
    untouched for ``max_age`` seconds: leftovers of a killed process."""
    now = time.time()
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return
    for entry in entries:
        if not _PART.fullmatch(entry.name) or os.path.abspath(entry.path) in _LIVE:
            continue
        with contextlib.suppress(OSError):
            st = entry.stat(follow_symlinks=False)
            # a previous file kept as a link (.old) has its old mtime: its ctime is the link's
            if now - (st.st_ctime if entry.name.endswith(".old") else st.st_mtime) > max_age:
                _remove(entry.path)


def check_space(out, size: int) -> None:
    """Refuse to write ``size`` bytes to ``out`` when its folder's file system
    has less free space, or the file size limit (``ulimit -f``) is lower.

    Raises:
        OSError: ``ENOSPC`` or ``EFBIG``, ``filename`` ``out``, with what is
            needed and what is free.
    """
    out = pathlib.Path(out)
    free = _free(out.parent)
    if free is not None and size > free:
        raise not_written(out, errno.ENOSPC, f"{human_bytes(size)} needed, {human_bytes(free)} free")
    limit = _file_size_limit()
    if limit is not None and size > limit:
        raise not_written(
            out, errno.EFBIG, f"{human_bytes(size)} needed, the file size limit (ulimit -f) is {human_bytes(limit)}"
        )


def not_written(out: pathlib.Path, no: int, detail: str) -> OSError:
    """The error of an output not written: ``OUT: not written: CAUSE: DETAIL`` in the CLI."""
    kept = " (the existing file is kept)" if out.exists() else ""
    return OSError(no, f"not written{kept}: {_FULL[no]}: {detail}", str(out))


def human_bytes(n: float) -> str:
    """Bytes for a reader: ``"812 kB"``, ``"2.1 MB"``, ``"3.4 GB"`` (powers of 1000)."""
    n = int(n)
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}" if n < 100 * scale else f"{n / scale:.0f} {unit}"
    return f"{n} bytes"


def _free(folder) -> int | None:
    try:
        return shutil.disk_usage(folder).free
    except OSError:
        return None


def _file_size_limit() -> int | None:
    try:
        import resource  # POSIX only
    except ImportError:
        return None
    soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    return None if soft == resource.RLIM_INFINITY else soft


def _size(path) -> int:
    """Bytes of a file, or of the files in a folder (0 when absent)."""
    path = pathlib.Path(path)
    with contextlib.suppress(OSError):
        if path.is_dir():
            return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
        return path.stat().st_size
    return 0


def _remove(path) -> None:
    """Remove a file or a folder (not following a link); absent is fine."""
    with contextlib.suppress(OSError):
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path, ignore_errors=True)
        else:
            os.unlink(path)


def _fsync(path: pathlib.Path) -> None:
    """Sync a file (or a folder's files and the folder) to disk: a late write
    error (a full disk on a network file system...) raises here."""
    files = [p for p in path.rglob("*") if p.is_file()] if path.is_dir() else [path]
    for p in files:
        fd = os.open(p, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    if path.is_dir():
        _fsync_folder(path)


def _fsync_folder(folder) -> None:
    """Sync a folder's entries (the rename); not possible everywhere (Windows)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


# What a write failure says, by errno: the disk or the quota is full, or the
# file is over the file size limit; EIO is any other failure of the device.
_FULL = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large",
    errno.EIO: "input/output error",
}


def _failed_errno(exc: BaseException) -> int | None:
    """The errno of a failed write: of ``exc`` or the exceptions it came
    from, or read from their text (GDAL reports "No space left on device")."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in _FULL:
            return exc.errno
        text = str(exc)
        for no in _FULL:
            if os.strerror(no) in text:
                return no
        exc = exc.__cause__ or exc.__context__
    return None


def _write_failure(out: pathlib.Path, tmp: pathlib.Path, exc: BaseException, size: int | None) -> OSError | None:
    """``exc`` raised while writing ``tmp`` as an OSError naming ``out`` and the
    cause, or None when it is not a failure to write (a bug, an interrupt...).

    A failure whose cause is not given (rasterio's "Write failed") is read
    from the disk: its free space nearly nil, or the temporary at the file
    size limit."""
    if isinstance(exc, OSError) and exc.filename == str(out):
        return None  # said already (check_space)
    no = _failed_errno(exc)
    written = _size(tmp)
    if no in (None, errno.EIO) and isinstance(exc, OSError) and exc.errno in (None, errno.EIO):
        limit, free = _file_size_limit(), _free(tmp.parent)
        if free is not None and free < (1 << 20):
            no = errno.ENOSPC
        elif limit is not None and written >= limit - (1 << 16):
            no = errno.EFBIG
    if no is None:
        return None
    _remove(tmp)
    needed = human_bytes(size) if size else f"more than {human_bytes(written)}"
    limit, free = _file_size_limit(), _free(out.parent)
    if no == errno.EFBIG and limit is not None:
        return not_written(out, no, f"{needed} needed, the file size limit (ulimit -f) is {human_bytes(limit)}")
    if no == errno.EIO:
        return not_written(out, no, " ".join(str(exc).split())[:200])
    return not_written(out, no, f"{needed} needed, {human_bytes(free) if free is not None else 'unknown'} free")


# Windows device names: a file called so (with any extension) is the device there.
_RESERVED = {"CON", "PRN", "AUX", "NUL", *(f"{p}{i}" for p in ("COM", "LPT") for i in range(1, 10))}


def output_name(name, what: str = "name") -> str:
    """``name`` (read from a file: a camera's, an image's) checked as one file
    name inside an output folder, never a path out of it.

    Raises:
        ValueError: an empty name, ``.`` or ``..``, a ``/``, ``\\``, NUL or
            other control character, leading or trailing blanks, a trailing
            dot, a Windows device name (``CON``, ``NUL``, ``COM1``...), or
            over 200 bytes.
    """
    from .files import excerpt

    text = str(name)
    bad = (
        not text.strip()
        or text in (".", "..")
        or any(c in text for c in "/\\")
        or text != text.strip()
        or any(ord(c) < 32 or ord(c) == 127 for c in text)
        or text.endswith(".")
        or text.split(".")[0].strip().upper() in _RESERVED
        or len(text.encode("utf-8", "replace")) > 200
    )
    if bad:
        raise ValueError(
            f"{what} {excerpt(text)} cannot be a file name (no '/', '\\', '..', control "
            "characters, device names such as CON or NUL, or empty names); rename it"
        )
    return text
