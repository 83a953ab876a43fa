"""Exceptions raised on bad user input.

Every message names the file, and where it applies the row and the field, so
that the command line can print it as one line and exit with status 2.
"""

from __future__ import annotations

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
