"""Atomic writes: a reader sees either the old file or the complete new one.

Every output of graphcal goes through these functions: the content is written
to a temporary file in the destination folder and renamed into place
(``os.replace``), so an error or an interruption leaves any previous file
untouched and no temporary file behind.

No-replace mode (``replace=False``): the complete temporary file is published
with ``os.link(temporary, path)``, which fails when ``path`` appeared meanwhile
(another process wrote it after the command checked that it was free); then
:class:`~graphcal.core.errors.OutputExistsError` is raised and ``path`` is left as
the other process wrote it.  On a file system without hard links, ``renameat2``
with ``RENAME_NOREPLACE`` (Linux) does the same; where neither exists, the file is
checked just before an ``os.replace``.

``replace=None`` (the default) replaces, unless the path was registered with
:func:`protect` (what the command line does for an output whose existence it
refused without ``--overwrite``): writers of any module then publish such a path
without replacing, without an option of their own.

An operating-system error while writing (a full disk, a file-size limit, a
read-only file system) is raised with the destination as its ``filename``, so the
message names the file the user asked for, not the temporary one.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from graphcal.core.errors import OutputExistsError, fill_errno

if TYPE_CHECKING:
    import pandas as pd

_protected: set[str] = set()
_protected_lock = threading.Lock()


def _key(path: str | Path) -> str:
    return os.path.normcase(os.path.abspath(os.fspath(path)))


def protect(path: str | Path) -> None:
    """Publish ``path`` without replacing (no-replace mode) until it is written once or
    :func:`unprotect`/:func:`clear_protected` is called."""
    with _protected_lock:
        _protected.add(_key(path))


def unprotect(path: str | Path) -> None:
    """Undo :func:`protect` for ``path``."""
    with _protected_lock:
        _protected.discard(_key(path))


def clear_protected() -> None:
    """Forget every :func:`protect` (the start of a command)."""
    with _protected_lock:
        _protected.clear()


def is_protected(path: str | Path) -> bool:
    """Whether ``path`` is published without replacing (:func:`protect`)."""
    with _protected_lock:
        return _key(path) in _protected


def _replaces(path: Path, replace: bool | None) -> bool:
    return not is_protected(path) if replace is None else replace


#: ``link`` errors of file systems without hard links.
_NO_LINKS = {errno.EPERM, errno.EMLINK, errno.ENOSYS, errno.EXDEV,
             getattr(errno, "EOPNOTSUPP", -1), getattr(errno, "ENOTSUP", -1)}


def _renameat2_noreplace(source: str, target: str) -> bool:
    """``renameat2(source, target, RENAME_NOREPLACE)``; False where not available.

    Raises FileExistsError when ``target`` exists, OSError on another error.
    """
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        function = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_noreplace = -100, 1
    status = function(at_fdcwd, os.fsencode(source), at_fdcwd, os.fsencode(target),
                      rename_noreplace)
    if status == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, getattr(errno, "EOPNOTSUPP", -1)):
        return False
    raise OSError(code, os.strerror(code), target)


def rename_no_replace(source: str | Path, target: str | Path) -> None:
    """Rename ``source`` (a file or a folder) to ``target`` unless ``target`` exists.

    Raises
    ------
    FileExistsError
        If ``target`` exists (an empty folder counts as existing for ``renameat2``;
        the fallback ``os.rename`` replaces an empty folder, which holds nothing).
    """
    source, target = os.fspath(source), os.fspath(target)
    if _renameat2_noreplace(source, target):
        return
    if os.path.lexists(target) and not (os.path.isdir(target) and not os.listdir(target)):
        raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), target)
    try:
        os.rename(source, target)
    except OSError as exc:
        if exc.errno in (errno.ENOTEMPTY, errno.EEXIST):
            raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), target) from exc
        raise


def publish(temporary: str | Path, path: str | Path, *, replace: bool = True) -> None:
    """Move the complete file ``temporary`` to ``path`` (same folder).

    ``replace``: ``os.replace``.  Otherwise ``os.link`` then unlink the temporary (or
    :func:`rename_no_replace` on a file system without hard links); raises
    :class:`OutputExistsError` when ``path`` exists.
    """
    temporary, path = os.fspath(temporary), os.fspath(path)
    if replace:
        os.replace(temporary, path)
        return
    try:
        try:
            os.link(temporary, path)
        except FileExistsError:
            raise
        except OSError as exc:
            if exc.errno not in _NO_LINKS:
                raise
            rename_no_replace(temporary, path)
            return
    except FileExistsError as exc:
        raise OutputExistsError(path) from exc
    os.unlink(temporary)


def _name_error(exc: OSError, path: Path, temporary: str | None) -> None:
    """Give an operating-system error the destination as its file (in place)."""
    if not fill_errno(exc):  # not an error of the system: its message stands
        return
    name = exc.filename
    if name is None or (temporary is not None and os.fspath(name) == os.fspath(temporary)) \
            or _temporary_of(name, path):
        exc.filename = str(path)
        exc.filename2 = None


def _temporary_of(name: object, path: Path) -> bool:
    """Whether ``name`` is a temporary file of ``path`` (``.<stem>.*`` beside it)."""
    if not isinstance(name, str | bytes | os.PathLike):
        return False
    candidate = Path(os.fsdecode(name))
    return (os.path.abspath(candidate.parent) == os.path.abspath(path.parent)
            and candidate.name.startswith(f".{path.stem}."))


@contextlib.contextmanager
def _published(path: Path, replace: bool | None, prefix: str, suffix: str) -> Iterator[str]:
    """A temporary file beside ``path`` to fill inside the block; then synced to disk and
    published (:func:`publish`, never replacing a protected or ``replace=False`` path).
    On any error the temporary is removed and an :class:`OSError` names ``path``."""
    no_replace = not _replaces(path, replace)
    temporary: str | None = None
    try:
        handle, temporary = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=path.parent)
        os.close(handle)
        yield temporary
        with open(temporary, "rb+") as stream:
            os.fsync(stream.fileno())
        os.chmod(temporary, 0o644)
        publish(temporary, path, replace=not no_replace)
    except BaseException as exc:
        if temporary is not None:
            with contextlib.suppress(OSError):
                os.unlink(temporary)
        if isinstance(exc, OSError):
            _name_error(exc, path, temporary)
        raise
    if no_replace:
        unprotect(path)


def atomic_write_stream(path: str | Path, write: Callable[[Any], None], *,
                        replace: bool | None = None) -> None:
    """Write a file atomically through ``write(stream)`` (a binary stream).

    ``write`` fills a temporary file in the same folder, which then replaces
    ``path`` (``os.replace``), so a reader never sees a half-written file and an
    error leaves any previous file untouched.

    Parameters
    ----------
    path : str or Path
        Destination file; its folder must exist.
    write : callable
        Called once with the open binary stream.
    replace : bool or None, optional
        False: never replace a ``path`` that exists when the file is published
        (:class:`~graphcal.core.errors.OutputExistsError`).  None: replace unless
        ``path`` is :func:`protect`-ed.

    Raises
    ------
    OSError
        With ``filename`` the destination (a full disk, a file-size limit, ...).
    """
    path = Path(path)
    with _published(path, replace, f".{path.name}.", ".tmp") as temporary, \
            open(temporary, "wb") as stream:
        write(stream)


def atomic_write_text(path: str | Path, text: str, *, encoding: str = "utf-8",
                      replace: bool | None = None) -> None:
    """Write a text file atomically (:func:`atomic_write_stream`).

    Parameters
    ----------
    path : str or Path
        Destination file; its folder must exist.
    text : str
        Content.
    encoding : str, optional
        Text encoding, UTF-8 by default.
    replace : bool or None, optional
        As :func:`atomic_write_stream`.
    """
    data = text.encode(encoding)
    atomic_write_stream(path, lambda stream: stream.write(data), replace=replace)


def atomic_write_table(frame: pd.DataFrame, path: str | Path, *,
                       replace: bool | None = None) -> None:
    """Write one table atomically, CSV or Parquet by the suffix of ``path``.

    ``replace`` as :func:`atomic_write_stream`.

    Raises
    ------
    ValueError
        If the suffix is neither ``.csv`` nor ``.parquet``.
    """
    path = Path(path)
    if path.suffix not in (".csv", ".parquet"):
        raise ValueError(f"{path}: the table format comes from the suffix: .csv or .parquet")
    with _published(path, replace, f".{path.stem}.", path.suffix) as temporary:
        write_table(frame, Path(temporary))


def write_table(frame: pd.DataFrame, path: Path) -> None:
    """Write one table as CSV (empty cells for NaN) or Parquet, by suffix."""
    if path.suffix == ".csv":
        frame.to_csv(path, index=False, na_rep="")
    else:
        frame.to_parquet(path, index=False)
