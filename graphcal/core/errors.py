"""Exceptions raised on bad user input.

Every message names the file, and where it applies the row and the field, so
that the command line can print it as one line and exit with status 2.
"""

from __future__ import annotations

import os
from pathlib import Path


class GraphcalInputError(ValueError):
    """Bad user input: a file, row or field that cannot be used."""

    def __init__(
        self,
        message: str,
        *,
        path: str | Path | None = None,
        row: int | None = None,
        field: str | None = None,
    ) -> None:
        self.path = None if path is None else Path(path)
        self.row = row
        self.field = field
        self.detail = message
        where = []
        if path is not None:
            where.append(str(path))
        if row is not None:
            where.append(f"row {row}")
        if field is not None:
            where.append(f"field '{field}'")
        prefix = ", ".join(where)
        super().__init__(f"{prefix}: {message}" if prefix else message)


class DatasetError(GraphcalInputError):
    """A dataset folder (sites.toml, plots, adsb) is missing or invalid."""


class RowsOutOfOrderError(DatasetError):
    """A table read in one pass as if in time order has a row earlier than the reader's
    tolerance (:class:`~graphcal.io.table_stream.TableSource`): a caller that took the
    order for granted reads the table again, sorting it first."""


class ScenarioError(GraphcalInputError):
    """A scenario file is invalid."""


class SensorModelError(GraphcalInputError):
    """A sensor model file is missing or invalid."""


class ResultError(GraphcalInputError):
    """A result JSON (``calibrate --out``) is missing or invalid."""


class EstimationError(RuntimeError):
    """An estimator cannot run on the given data (no usable observations, ...)."""


class ImplausibleDataError(DatasetError):
    """A valid dataset whose values look like a unit or frame mistake (exit 2, ``--force``).

    ``findings`` holds every field that looks wrong
    (:class:`graphcal.data.plausibility.Finding`), the first named by the message.
    """

    def __init__(self, message: str, *, path: str | Path | None = None,
                 row: int | None = None, field: str | None = None,
                 findings: list | None = None) -> None:
        super().__init__(message, path=path, row=row, field=field)
        self.findings = list(findings or [])


class OutputExistsError(GraphcalInputError):
    """An output file or folder appeared (written by another process) between the check
    before the work and the final rename, and replacing it was not asked for."""

    def __init__(self, path: str | Path) -> None:
        super().__init__("exists (written by another process meanwhile); pass --overwrite",
                         path=path)


#: Causes of operating-system errors in words, by ``errno`` name.
_CAUSES = {
    "ENOSPC": "disk full",
    "EDQUOT": "disk quota exceeded",
    "EFBIG": "file too large",
    "EROFS": "read-only file system",
    "EACCES": "permission denied",
    "EPERM": "permission denied",
    "EISDIR": "is a folder",
    "ENOTDIR": "not a folder (a part of the path is a file)",
    "ENOENT": "no such file or folder",
    "EEXIST": "exists",
    "ENOTEMPTY": "folder is not empty",
    "ENAMETOOLONG": "name too long",
    "ELOOP": "too many levels of symbolic links",
    "EIO": "input/output error",
    "EMFILE": "too many open files",
    "ENFILE": "too many open files",
    "EBUSY": "busy (in use, or a mount point)",
    "EXDEV": "on another file system",
    "ETXTBSY": "busy (in use)",
    "ENOMEM": "out of memory",
    "EINVAL": "invalid argument",
}


def fill_errno(exc: OSError) -> bool:
    """Set ``errno`` and ``strerror`` of ``exc`` (in place) when only its message names
    them (:func:`os_error_errno`); whether it is an error of the system at all."""
    if exc.errno is None:
        code = os_error_errno(exc)
        if code is not None:
            exc.errno, exc.strerror = code, os.strerror(code)
    return exc.errno is not None


def os_error_errno(exc: BaseException) -> int | None:
    """The ``errno`` of an operating-system error, also when a library (pyarrow) only
    names it in the message (``[errno 28] No space left on device``)."""
    import errno as errno_module
    import re

    code = getattr(exc, "errno", None)
    if isinstance(code, int) and code > 0:
        return code
    text = str(exc)
    found = re.search(r"\[errno (\d+)\]", text, flags=re.IGNORECASE)
    if found:
        return int(found.group(1))
    for code_, words in ((errno_module.ENOSPC, "no space left on device"),
                         (errno_module.EFBIG, "file too large"),
                         (errno_module.EROFS, "read-only file system")):
        if words in text.lower():
            return code_
    return None


def os_error_cause(exc: BaseException) -> str:
    """The cause of an operating-system error in words: ``"disk full"``,
    ``"file too large"``, ``"read-only file system"``, ``"permission denied"``, ..."""
    import errno as errno_module

    code = os_error_errno(exc)
    name = errno_module.errorcode.get(code) if code is not None else None
    if name in _CAUSES:
        return _CAUSES[name]
    strerror = getattr(exc, "strerror", None)
    if strerror:
        return str(strerror).lower()
    if code is not None:
        return os.strerror(code).lower()
    return str(exc) or type(exc).__name__


def os_error_message(exc: BaseException, path: str | Path | None = None) -> str:
    """``"<path>: <cause>"`` for an operating-system error: the path of the error
    (``filename``, and ``filename2`` for a rename), else ``path``."""
    cause = os_error_cause(exc)
    name = getattr(exc, "filename", None)
    name2 = getattr(exc, "filename2", None)
    where = name if isinstance(name, str | bytes | os.PathLike) else path
    if where is None:
        return cause
    if isinstance(name2, str | bytes | os.PathLike):
        return f"{os.fsdecode(where)} -> {os.fsdecode(name2)}: {cause}"
    return f"{os.fsdecode(where)}: {cause}"
