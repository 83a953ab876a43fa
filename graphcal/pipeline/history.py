"""The calibration history: every run's biases over time in one SQLite database.

A history is a single SQLite file (Python's standard :mod:`sqlite3`) that grows by one
*run* per calibration.  A run records its provenance (graphcal version, method,
dataset, options, the time span of the data, when it ran) and its biases: the
windows of the result's ``series`` (contract v2, ``calibrate --window``), or, for a
run without windows, the ``radars`` estimates as one window spanning the run's time
span.  Reading it back gives each radar's biases over time with their sigmas, the
detected events, and which windows lie outside a tolerance.

Writing a run
-------------
``calibrate --history calib.db`` appends its run with::

    from graphcal.pipeline.history import append_run

    run_id = append_run("calib.db", result, provenance={
        "dataset": str(dataset_dir),           # required
        "options": {"window": "30min"},        # the command's options (JSON-able)
        "t_start_s": 32400.0,                  # time span of the data, dataset time base
        "t_end_s": 41400.0,
        "sensor_models": {"NORD": "ssr-mode-s"},   # site -> its sites.toml model
    })

``result`` is the result JSON document as a dict, exactly as ``calibrate --out``
writes it (:meth:`graphcal.data.calibration.Calibration.to_dict`, plus ``series``
and ``events`` when windows were used).  The run is written in one transaction: it
is stored completely or not at all.  The file is created when missing.

Schema (version :data:`SCHEMA_VERSION`)
---------------------------------------
The file is marked as a graphcal history by ``PRAGMA application_id`` =
:data:`APPLICATION_ID` and carries its schema version in ``PRAGMA user_version``;
a file with another application id, or written by a newer graphcal, is refused.

- ``runs``: ``run_id``, ``run_time_utc`` (ISO 8601), ``graphcal_version``,
  ``method``, ``dataset``, ``options_json``, ``t_start_s``, ``t_end_s``,
  ``epoch_utc`` (UTC time of 0 s on the dataset's time base, when known),
  ``window_s`` (NULL for a run without windows).
- ``run_radars``: ``run_id``, ``radar_id``, ``sensor_model``.
- ``estimates`` (a long table: one row per run, radar, window and bias):
  ``run_id``, ``radar_id``, ``t_start_s``, ``t_end_s``, ``n_plots``, ``key`` (the
  contract key, e.g. ``range_offset_m``), ``value`` and ``sigma`` (1-sigma), in the
  key's contract unit.
- ``events``: ``event_id``, ``run_id``, ``radar_id``, ``time_s``, ``kind``; and
  ``event_parameters``: ``event_id``, ``key``, ``size``, ``sigma``.

Every numeric key of a radar's entry is stored, whatever its name (the four bias
keys, ``time_offset_s``, the eccentricity terms and any later key); ``null``
values (not estimated) and the values a run held fixed are not.

Tolerances
----------
:func:`flag_tolerances` compares each window with a tolerance on its bias (the
bias itself, "measured minus true", before any correction: how far the radar is
from its nominal registration), using the window's 2-sigma band:

- ``outside``: ``|value| - 2 sigma > tolerance``, the whole band lies beyond the
  tolerance: the data show the bias outside it;
- ``possibly``: ``|value| > tolerance`` but the band reaches back inside (or the
  sigma is unknown): the estimate is outside, not beyond its uncertainty;
- ``within``: ``|value| <= tolerance``;
- ``unchecked``: no tolerance for that key.

The default tolerance of a bias is twice its ``typical_bias`` in the radar's sensor
model (``models/*.toml``, the spread of that bias over installations of the type,
one sigma): a bias beyond it is larger than about 95 % of installations of that
type show.  Radars without a known model, and keys the model does not give, use
:data:`FALLBACK_TOLERANCES`.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from graphcal.core.errors import GraphcalInputError, SensorModelError
from graphcal.data.bias import CONTRACT_KEYS
from graphcal.data.sensor_models import load_sensor_model

#: Version of the database layout, kept in ``PRAGMA user_version``.
SCHEMA_VERSION = 1
#: ``PRAGMA application_id`` of a graphcal history (the bytes ``GCHD``).
APPLICATION_ID = 0x47434844

#: Contract keys in display order; other stored keys follow, alphabetically.
KEY_ORDER: tuple[str, ...] = tuple(key for key, _ in CONTRACT_KEYS.values())

#: Entries of a radar (or window) that are not bias values.
STRUCTURE_KEYS: frozenset[str] = frozenset(
    {"t_start_s", "t_end_s", "n_plots", "sigma", "fixed", "residuals"}
)

#: The default tolerance is this multiple of the sensor model's ``typical_bias``.
TOLERANCE_PER_TYPICAL_BIAS = 2.0

#: Tolerances [contract units] for radars without a known sensor model: twice the
#: ``typical_bias`` of the bundled ``ssr-mode-s`` model (the most common radar;
#: range offset 50 m, gain 2e-4, azimuth 1.5 mrad, time 0.05 s) and, for elevation,
#: of ``air-defence-3d`` (3 mrad).  The eccentricity terms share the azimuth bias's
#: tolerance: each adds up to its size to the azimuth error.
FALLBACK_TOLERANCES: dict[str, float] = {
    "range_offset_m": 100.0,
    "range_gain": 4e-4,
    "azimuth_bias_mrad": 3.0,
    "elevation_bias_mrad": 6.0,
    "time_offset_s": 0.1,
    "azimuth_sin_mrad": 3.0,
    "azimuth_cos_mrad": 3.0,
}

#: ``status`` values of :func:`flag_tolerances`, from worst to best.
STATUSES: tuple[str, ...] = ("outside", "possibly", "within", "unchecked")

#: Keys a provenance may hold.
PROVENANCE_KEYS: tuple[str, ...] = (
    "dataset", "method", "options", "t_start_s", "t_end_s", "epoch_utc", "graphcal_version",
    "run_time_utc", "sensor_models",
)

_SCHEMA: tuple[str, ...] = (
    """CREATE TABLE runs (
        run_id INTEGER PRIMARY KEY,
        run_time_utc TEXT NOT NULL,
        graphcal_version TEXT NOT NULL,
        method TEXT,
        dataset TEXT NOT NULL,
        options_json TEXT NOT NULL,
        t_start_s REAL NOT NULL,
        t_end_s REAL NOT NULL,
        epoch_utc TEXT,
        window_s REAL,
        CHECK (t_end_s >= t_start_s)
    )""",
    """CREATE TABLE run_radars (
        run_id INTEGER NOT NULL REFERENCES runs (run_id),
        radar_id TEXT NOT NULL,
        sensor_model TEXT,
        PRIMARY KEY (run_id, radar_id)
    )""",
    """CREATE TABLE estimates (
        run_id INTEGER NOT NULL,
        radar_id TEXT NOT NULL,
        t_start_s REAL NOT NULL,
        t_end_s REAL NOT NULL,
        n_plots INTEGER,
        key TEXT NOT NULL,
        value REAL NOT NULL,
        sigma REAL,
        PRIMARY KEY (run_id, radar_id, t_start_s, key),
        FOREIGN KEY (run_id, radar_id) REFERENCES run_radars (run_id, radar_id),
        CHECK (t_end_s >= t_start_s)
    )""",
    "CREATE INDEX estimates_by_radar ON estimates (radar_id, t_end_s)",
    """CREATE TABLE events (
        event_id INTEGER PRIMARY KEY,
        run_id INTEGER NOT NULL,
        radar_id TEXT NOT NULL,
        time_s REAL NOT NULL,
        kind TEXT NOT NULL,
        FOREIGN KEY (run_id, radar_id) REFERENCES run_radars (run_id, radar_id)
    )""",
    """CREATE TABLE event_parameters (
        event_id INTEGER NOT NULL REFERENCES events (event_id),
        key TEXT NOT NULL,
        size REAL,
        sigma REAL,
        PRIMARY KEY (event_id, key)
    )""",
)


class HistoryError(GraphcalInputError):
    """A history database, or a run to append to it, that cannot be used."""


# --------------------------------------------------------------------------- units


def key_unit(key: str) -> str:
    """The unit of a contract key, from its suffix: ``m``, ``mrad``, ``s``, ``deg``.

    ``range_gain`` (and any key without a unit suffix) is a plain fraction:
    ``"fraction"`` for ``range_gain``, ``""`` otherwise.
    """
    for suffix in ("mrad", "deg", "m", "s"):
        if key.endswith(f"_{suffix}"):
            return suffix
    return "fraction" if key == "range_gain" else ""


def key_rank(key: str) -> tuple[int, str]:
    """Sort key of a bias key: contract order (:data:`KEY_ORDER`), then alphabetical."""
    return (KEY_ORDER.index(key), "") if key in KEY_ORDER else (len(KEY_ORDER), key)


# --------------------------------------------------------------------------- parsing a run


@dataclass(frozen=True)
class _Window:
    radar_id: str
    t_start_s: float
    t_end_s: float
    n_plots: int | None
    values: tuple[tuple[str, float, float | None], ...]  # key, value, sigma


@dataclass(frozen=True)
class _Event:
    radar_id: str
    time_s: float
    kind: str
    parameters: tuple[tuple[str, float | None, float | None], ...]  # key, size, sigma


@dataclass(frozen=True)
class _Run:
    run_time_utc: str
    graphcal_version: str
    method: str | None
    dataset: str
    options_json: str
    t_start_s: float
    t_end_s: float
    epoch_utc: str | None
    window_s: float | None
    sensor_models: dict[str, str | None]
    windows: tuple[_Window, ...]
    events: tuple[_Event, ...]


def _number(value: Any, where: str, *, optional: bool = False) -> float | None:
    """A finite number (``None`` allowed when ``optional``)."""
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise HistoryError(f"{value!r} is not a finite number", field=where)
    return float(value)


def _mapping(value: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise HistoryError("must be an object", field=where)
    return value


def _bias_values(entry: Mapping[str, Any], where: str) -> tuple[tuple[str, float, float | None],
                                                                 ...]:
    """``(key, value, sigma)`` of every numeric bias key of a radar or window entry."""
    sigmas = _mapping(entry.get("sigma") or {}, f"{where}.sigma")
    values = []
    for key, value in entry.items():
        if key in STRUCTURE_KEYS or value is None:
            continue
        if key not in KEY_ORDER and isinstance(value, Mapping | list | str | bool):
            continue  # not a bias value (e.g. a later structured extension)
        number = _number(value, f"{where}.{key}")
        sigma = _number(sigmas.get(key), f"{where}.sigma.{key}", optional=True)
        if sigma is not None and sigma < 0.0:
            raise HistoryError(f"negative sigma {sigma!r}", field=f"{where}.sigma.{key}")
        values.append((str(key), number, sigma))
    return tuple(sorted(values, key=lambda item: key_rank(item[0])))


def _n_plots(entry: Mapping[str, Any], where: str) -> int | None:
    value = entry.get("n_plots")
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise HistoryError(f"{value!r} is not a count", field=f"{where}.n_plots")
    return value


def _series_windows(series: Mapping[str, Any]) -> tuple[float, list[_Window]]:
    """``window_s`` and the windows of a result's ``series`` block."""
    window_s = _number(series.get("window_s"), "series.window_s")
    radars = _mapping(series.get("radars"), "series.radars")
    windows = []
    for rid, entries in radars.items():
        if not isinstance(entries, list):
            raise HistoryError("must be a list of windows", field=f"series.radars.{rid}")
        for i, entry in enumerate(entries):
            where = f"series.radars.{rid}[{i}]"
            entry = _mapping(entry, where)
            start = _number(entry.get("t_start_s"), f"{where}.t_start_s")
            end = _number(entry.get("t_end_s"), f"{where}.t_end_s")
            if end < start:
                raise HistoryError(f"ends ({end}) before it starts ({start})", field=where)
            windows.append(_Window(str(rid), start, end, _n_plots(entry, where),
                                   _bias_values(entry, where)))
    return window_s, windows


def _single_windows(radars: Mapping[str, Any], start: float, end: float) -> list[_Window]:
    """A run without windows: each radar's estimate as one window over the run's span."""
    windows = []
    for rid, entry in radars.items():
        where = f"radars.{rid}"
        entry = _mapping(entry, where)
        windows.append(_Window(str(rid), start, end, _n_plots(entry, where),
                               _bias_values(entry, where)))
    return windows


def _events(events: Any) -> list[_Event]:
    if events is None:
        return []
    if not isinstance(events, list):
        raise HistoryError("must be a list", field="events")
    out = []
    for i, event in enumerate(events):
        where = f"events[{i}]"
        event = _mapping(event, where)
        rid, kind = event.get("radar_id"), event.get("kind", "step")
        if not isinstance(rid, str) or not rid:
            raise HistoryError("must be a radar id", field=f"{where}.radar_id")
        if not isinstance(kind, str):
            raise HistoryError("must be a string", field=f"{where}.kind")
        keys = event.get("parameters") or []
        if not isinstance(keys, list) or not all(isinstance(k, str) for k in keys):
            raise HistoryError("must be a list of keys", field=f"{where}.parameters")
        size = _mapping(event.get("size") or {}, f"{where}.size")
        sigma = _mapping(event.get("sigma") or {}, f"{where}.sigma")
        parameters = tuple(
            (key, _number(size.get(key), f"{where}.size.{key}", optional=True),
             _number(sigma.get(key), f"{where}.sigma.{key}", optional=True))
            for key in dict.fromkeys(keys)
        )
        out.append(_Event(rid, _number(event.get("time_s"), f"{where}.time_s"), kind,
                          parameters))
    return out


def _utc_text(value: Any, where: str) -> str:
    """An ISO 8601 UTC time ``YYYY-MM-DDTHH:MM:SS[.ffffff]Z``; a naive time is taken as UTC."""
    if isinstance(value, str):
        try:
            value = datetime.fromisoformat(value)
        except ValueError:
            raise HistoryError(f"{value!r} is not an ISO 8601 time", field=where) from None
    if not isinstance(value, datetime):
        raise HistoryError(f"{value!r} is not a time", field=where)
    if value.tzinfo is None:
        value = value.replace(tzinfo=UTC)
    return value.astimezone(UTC).isoformat().replace("+00:00", "Z")


def _json_default(value: Any) -> Any:
    """Paths as text, numpy scalars and arrays as Python values, in the stored options."""
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} {value!r} cannot be stored as JSON")


def _options_json(options: Any) -> str:
    if options is None:
        options = {}
    if not isinstance(options, Mapping):
        raise HistoryError("must be an object (a dict of options)", field="provenance.options")
    try:
        return json.dumps(dict(options), sort_keys=True, allow_nan=False, default=_json_default)
    except (TypeError, ValueError) as exc:
        raise HistoryError(str(exc), field="provenance.options") from None


def _graphcal_version() -> str:
    from graphcal import __version__

    return __version__


def _sensor_models(value: Any, radar_ids: Sequence[str]) -> dict[str, str | None]:
    models = _mapping(value or {}, "provenance.sensor_models")
    out: dict[str, str | None] = {}
    for rid in radar_ids:
        model = models.get(rid)
        if model is not None and not isinstance(model, str):
            raise HistoryError(f"{model!r} is not a model name",
                               field=f"provenance.sensor_models.{rid}")
        out[rid] = model or None
    return out


def _time_span(provenance: Mapping[str, Any], windows: list[_Window]) -> tuple[float, float]:
    """The run's time span: the provenance's, else the extent of its series windows."""
    start = _number(provenance.get("t_start_s"), "provenance.t_start_s", optional=True)
    end = _number(provenance.get("t_end_s"), "provenance.t_end_s", optional=True)
    if (start is None or end is None) and not windows:
        raise HistoryError("a run without series windows needs its time span: give "
                           "t_start_s and t_end_s", field="provenance")
    start = min(w.t_start_s for w in windows) if start is None else start
    end = max(w.t_end_s for w in windows) if end is None else end
    if end < start:
        raise HistoryError(f"t_end_s ({end}) before t_start_s ({start})", field="provenance")
    return start, end


def _parse_run(result: Mapping[str, Any], provenance: Mapping[str, Any]) -> _Run:
    """Check a result document and its provenance; everything to store, or HistoryError."""
    result = _mapping(result, "result")
    provenance = _mapping(provenance, "provenance")
    unknown = sorted(set(provenance) - set(PROVENANCE_KEYS))
    if unknown:
        raise HistoryError(f"unknown key(s) {', '.join(unknown)}; known: "
                           f"{', '.join(PROVENANCE_KEYS)}", field="provenance")
    dataset = provenance.get("dataset")
    if not isinstance(dataset, str | os.PathLike) or not os.fspath(dataset):
        raise HistoryError("must name the dataset (a path)", field="provenance.dataset")
    radars = _mapping(result.get("radars"), "radars")
    series = result.get("series")
    if series is not None:
        window_s, windows = _series_windows(_mapping(series, "series"))
    else:
        window_s, windows = None, []
    start, end = _time_span(provenance, windows)
    if series is None:
        windows = _single_windows(radars, start, end)
    events = _events(result.get("events"))
    radar_ids = list(dict.fromkeys([*radars, *(w.radar_id for w in windows),
                                    *(e.radar_id for e in events)]))
    method = provenance.get("method", result.get("method"))
    version = provenance.get("graphcal_version") or _graphcal_version()
    epoch = provenance.get("epoch_utc")
    return _Run(
        run_time_utc=_utc_text(provenance.get("run_time_utc") or datetime.now(UTC),
                               "provenance.run_time_utc"),
        graphcal_version=str(version),
        method=None if method is None else str(method),
        dataset=os.fspath(dataset),
        options_json=_options_json(provenance.get("options")),
        t_start_s=start,
        t_end_s=end,
        epoch_utc=None if epoch is None else _utc_text(epoch, "provenance.epoch_utc"),
        window_s=window_s,
        sensor_models=_sensor_models(provenance.get("sensor_models"), [str(r) for r in radar_ids]),
        windows=tuple(windows),
        events=tuple(events),
    )


# --------------------------------------------------------------------------- the file


#: SQLite's errors in words (the start of its message -> the cause).
_SQLITE_CAUSES = (
    ("database or disk is full", "disk full"),
    ("attempt to write a readonly database", "read-only (no permission to write it, or a "
                                             "read-only file system)"),
    ("database is locked", "busy: another process is writing it; try again"),
    ("file is not a database", "not a graphcal history database (not an SQLite file)"),
    ("database disk image is malformed", "damaged (database disk image is malformed)"),
    ("disk i/o error", "input/output error"),
    ("unable to open database file", "cannot open (permission denied, or not a file)"),
)


def _io_cause(path: Path | None) -> str | None:
    """Why a write to ``path`` failed with an input/output error, when the file system
    says it: ``"disk full"`` (no free space in its folder) or ``"file too large"`` (the
    process's file-size limit reached); SQLite names neither."""
    if path is None:
        return None
    with suppress(OSError):
        stat = os.statvfs(path.parent)
        if stat.f_bavail * stat.f_frsize < 256 * 1024:
            return "disk full"
    with suppress(ImportError, OSError, ValueError):
        import resource

        limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        if limit != resource.RLIM_INFINITY:
            sizes = [p.stat().st_size for p in (path, *_leftovers(path)) if p.exists()]
            if sizes and max(sizes) + 64 * 1024 >= limit:
                return "file too large"
    return None


def _sqlite_cause(exc: sqlite3.Error, path: Path | None = None) -> str:
    """An SQLite error in words: ``"disk full"``, ``"read-only ..."``, ..."""
    text = str(exc).lower()
    if "disk i/o error" in text or "database or disk is full" in text:
        found = _io_cause(path)
        if found is not None:
            return found
    for start, cause in _SQLITE_CAUSES:
        if start in text:
            return cause
    return str(exc)


def _leftovers(path: Path) -> list[Path]:
    """The journal or write-ahead log an interrupted write left beside ``path``."""
    return [p for p in (path.with_name(path.name + "-journal"),
                        path.with_name(path.name + "-wal")) if p.exists()]


def _recover(path: Path) -> bool:
    """Roll back what an interrupted write left (a hot journal), as any SQLite writer does
    when it opens the file; a read-only connection cannot.  False when not possible."""
    if not _leftovers(path) or not os.access(path, os.W_OK) \
            or not os.access(path.parent, os.W_OK | os.X_OK):
        return False
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=rw", uri=True,
                              isolation_level=None)
    except sqlite3.Error:
        return False
    try:
        con.execute("PRAGMA application_id").fetchone()  # reading rolls the journal back
    except sqlite3.Error:
        return False
    finally:
        con.close()
    return True


def _check_file(con: sqlite3.Connection, path: Path, *, empty_ok: bool) -> bool:
    """Whether ``con`` is a graphcal history (False: an empty database, if ``empty_ok``)."""
    try:
        app_id = con.execute("PRAGMA application_id").fetchone()[0]
        version = con.execute("PRAGMA user_version").fetchone()[0]
        n_tables = con.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
    except sqlite3.DatabaseError as exc:
        cause = _sqlite_cause(exc, path)
        if "read-only" in cause and _leftovers(path):
            cause = (f"an interrupted write left {_leftovers(path)[0].name}, which needs "
                     "write access to be rolled back")
        raise HistoryError(cause, path=path) from None
    if app_id == 0 and n_tables == 0 and empty_ok:
        return False
    if app_id == 0 and n_tables == 0:
        raise HistoryError("holds no runs yet (an empty database)", path=path)
    if app_id != APPLICATION_ID:
        raise HistoryError("not a graphcal history database (an SQLite file of another "
                           "application)", path=path)
    if version > SCHEMA_VERSION:
        raise HistoryError(f"written by a newer graphcal (schema version {version}; this "
                           f"one reads up to {SCHEMA_VERSION})", path=path)
    if version < 1:
        raise HistoryError(f"unknown schema version {version}", path=path)
    return True


@contextmanager
def _connect(path: Path, *, write: bool) -> Iterator[sqlite3.Connection]:
    """An open connection (read-only unless ``write``), closed afterwards.

    A read-only connection first rolls back a hot journal that a killed writer left
    (:func:`_recover`), which a read-only connection cannot do itself.
    """
    if not write and not path.is_file():
        raise HistoryError("no such file" if not path.exists()
                           else "is a folder, not a file" if path.is_dir()
                           else "not a file", path=path)
    if write and not path.parent.is_dir():
        raise HistoryError(f"folder {path.parent} does not exist", path=path)
    if write and path.is_dir():
        raise HistoryError("is a folder, not a file", path=path)
    if not write and _leftovers(path):
        _recover(path)
    uri = f"{path.resolve().as_uri()}?mode={'rwc' if write else 'ro'}"
    try:
        con = sqlite3.connect(uri, uri=True, isolation_level=None)
    except sqlite3.Error as exc:
        raise HistoryError(_sqlite_cause(exc, path), path=path) from None
    try:
        con.execute("PRAGMA foreign_keys = ON")
        yield con
    finally:
        con.close()


def _create_schema(con: sqlite3.Connection) -> None:
    for statement in _SCHEMA:
        con.execute(statement)
    con.execute(f"PRAGMA application_id = {APPLICATION_ID}")
    con.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")


def _insert_run(con: sqlite3.Connection, run: _Run) -> int:
    cursor = con.execute(
        "INSERT INTO runs (run_time_utc, graphcal_version, method, dataset, options_json, "
        "t_start_s, t_end_s, epoch_utc, window_s) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
        (run.run_time_utc, run.graphcal_version, run.method, run.dataset, run.options_json,
         run.t_start_s, run.t_end_s, run.epoch_utc, run.window_s),
    )
    run_id = int(cursor.lastrowid)
    con.executemany("INSERT INTO run_radars VALUES (?, ?, ?)",
                    [(run_id, rid, model) for rid, model in run.sensor_models.items()])
    for window in run.windows:
        try:
            con.executemany(
                "INSERT INTO estimates VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                [(run_id, window.radar_id, window.t_start_s, window.t_end_s, window.n_plots,
                  key, value, sigma) for key, value, sigma in window.values],
            )
        except sqlite3.IntegrityError:
            raise HistoryError(f"two windows of radar {window.radar_id} start at "
                               f"{window.t_start_s} s", field="series") from None
    for event in run.events:
        event_id = con.execute(
            "INSERT INTO events (run_id, radar_id, time_s, kind) VALUES (?, ?, ?, ?)",
            (run_id, event.radar_id, event.time_s, event.kind),
        ).lastrowid
        con.executemany("INSERT INTO event_parameters VALUES (?, ?, ?, ?)",
                        [(event_id, *parameter) for parameter in event.parameters])
    return run_id


def append_run(
    db_path: str | os.PathLike[str],
    result: Mapping[str, Any],
    *,
    provenance: Mapping[str, Any],
) -> int:
    """Append one calibration run to a history database, in one transaction.

    Parameters
    ----------
    db_path : str or path
        The history file; created (with its schema) when missing.  Its folder
        must exist.
    result : mapping
        The result JSON document as a dict (``calibrate --out``): ``radars``
        (``{id: {range_offset_m: ..., ..., sigma: {...}, n_plots: N}}``), and
        optionally ``series`` (``{window_s, radars: {id: [{t_start_s, t_end_s,
        n_plots, <keys>, sigma: {...}}]}}``) and ``events`` (a list of
        ``{radar_id, time_s, kind, parameters, size, sigma}``).  With ``series``
        its windows are stored (``radars`` then repeats the last window); without
        it, each radar's ``radars`` entry is stored as one window over the time
        span of the run.  Values and sigmas in contract units (sigmas 1-sigma).
    provenance : mapping
        ``dataset`` (str or path, required): the dataset the run calibrated;
        ``options`` (dict, JSON-able; paths are stored as text): the run's options;
        ``t_start_s``, ``t_end_s`` (float [s], dataset time base): the time span of
        the data, required without ``series`` (default: the windows' extent);
        ``epoch_utc`` (ISO 8601 text or datetime, optional): the UTC time of 0 s on
        the dataset's time base; ``sensor_models`` (dict radar id -> model name,
        optional): each site's ``model``, for the default tolerances;
        ``method`` (default: the result's), ``graphcal_version`` (default: this
        one) and ``run_time_utc`` (default: now).  A naive time is taken as UTC.

    Returns
    -------
    int
        The new run's id (1, 2, ... in order of appending).

    Raises
    ------
    HistoryError
        The file is not a graphcal history or is from a newer graphcal, its
        folder is missing, or the result or provenance is malformed (the
        message names the field).  Nothing is written then; a file this call
        created is removed.
    """
    path = Path(db_path)
    run = _parse_run(result, provenance)
    existed = path.exists()
    try:
        with _connect(path, write=True) as con:
            _check_file(con, path, empty_ok=True)  # a clear message before taking the lock
            con.execute("BEGIN IMMEDIATE")
            try:
                if not _check_file(con, path, empty_ok=True):
                    _create_schema(con)
                run_id = _insert_run(con, run)
                con.execute("COMMIT")
            except BaseException:
                # SQLite has rolled back by itself after some errors (a full disk):
                # a second rollback would hide the cause.
                if con.in_transaction:
                    with suppress(sqlite3.Error):
                        con.execute("ROLLBACK")
                raise
    except sqlite3.Error as exc:
        cause = _sqlite_cause(exc, path)  # before removing what it looks at
        _remove_new(path, existed)
        raise HistoryError(cause, path=path) from None
    except BaseException:
        _remove_new(path, existed)
        raise
    return run_id


def _remove_new(path: Path, existed: bool) -> None:
    """Remove a file that a failed append created."""
    if not existed:
        for leftover in (path, path.with_name(path.name + "-journal")):
            leftover.unlink(missing_ok=True)


# --------------------------------------------------------------------------- reading


def _read_frame(db_path: str | os.PathLike[str], sql: str,
                params: Sequence[Any] = ()) -> pd.DataFrame:
    path = Path(db_path)
    with _connect(path, write=False) as con:
        _check_file(con, path, empty_ok=False)
        return pd.read_sql_query(sql, con, params=list(params))


def _utc_column(values: pd.Series, db_path: str | os.PathLike[str] | None = None,
                field: str = "epoch_utc") -> pd.Series:
    """UTC timestamps of ISO 8601 texts (NaT for none); a bad text is a HistoryError
    naming the file and the field (a database edited or damaged by another tool)."""
    try:
        return pd.to_datetime(values, utc=True, format="ISO8601")
    except (ValueError, TypeError) as exc:
        raise HistoryError(f"a value that is not an ISO 8601 time ({exc}); the database "
                           "was changed outside graphcal", path=db_path, field=field) from None


def _checked_numbers(frame: pd.DataFrame, db_path: str | os.PathLike[str], table: str,
                     columns: Mapping[str, str]) -> None:
    """Coerce ``columns`` of ``frame`` to floats in place and refuse what graphcal never
    writes: text, or infinite values (``columns``: name -> ``"required"``, ``"optional"``
    or ``"sigma"``, an optional value that must not be negative).

    Raises
    ------
    HistoryError
        Naming the file, the table, the first bad row's run and the column.
    """
    for column, kind in columns.items():
        raw = frame[column]
        values = pd.to_numeric(raw, errors="coerce").astype(float)
        given = raw.notna().to_numpy()
        finite = np.isfinite(values.to_numpy())
        bad = given & ~finite
        if kind == "required":
            bad |= ~given
        if kind == "sigma":
            bad |= finite & (values.to_numpy() < 0)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            run = frame["run_id"].iloc[i] if "run_id" in frame else None
            raise HistoryError(
                f"{raw.iloc[i]!r} in table {table}" + (f", run {run}" if run is not None else "")
                + " is not a valid number; the database was changed outside graphcal",
                path=db_path, field=column)
        frame[column] = values


def read_runs(db_path: str | os.PathLike[str]) -> pd.DataFrame:
    """Every run of a history, in order.

    Returns
    -------
    DataFrame
        ``run_id``, ``run_time_utc`` (UTC timestamp), ``graphcal_version``,
        ``method``, ``dataset``, ``options`` (dict), ``t_start_s``, ``t_end_s``
        [s, dataset time base], ``epoch_utc`` (UTC timestamp or NaT),
        ``window_s`` [s] (NaN for a run without windows), ``n_radars``.

    Raises
    ------
    HistoryError
        Missing file, not a graphcal history, or from a newer graphcal.
    """
    frame = _read_frame(
        db_path,
        "SELECT r.*, (SELECT count(*) FROM run_radars a WHERE a.run_id = r.run_id) AS n_radars "
        "FROM runs r ORDER BY r.run_id",
    )
    frame["run_time_utc"] = _utc_column(frame["run_time_utc"], db_path, "run_time_utc")
    frame["epoch_utc"] = _utc_column(frame["epoch_utc"], db_path, "epoch_utc")
    _checked_numbers(frame, db_path, "runs",
                     {"t_start_s": "required", "t_end_s": "required", "window_s": "sigma"})
    options = []
    for run, text in zip(frame["run_id"], frame.pop("options_json"), strict=True):
        try:
            options.append(json.loads(text))
        except (TypeError, ValueError):
            raise HistoryError(f"run {run}: not JSON; the database was changed outside "
                               "graphcal", path=db_path, field="options_json") from None
    frame.insert(5, "options", options)
    return frame


def radar_ids(db_path: str | os.PathLike[str]) -> list[str]:
    """The radars of every run of a history, sorted."""
    frame = _read_frame(db_path, "SELECT DISTINCT radar_id FROM run_radars ORDER BY radar_id")
    return frame["radar_id"].tolist()


def _check_radar(db_path: str | os.PathLike[str], radar: str | None) -> None:
    if radar is None:
        return
    known = radar_ids(db_path)
    if radar not in known:
        raise HistoryError(f"no radar '{radar}'; known: {', '.join(known) or 'none'}",
                           path=Path(db_path))


def _utc_name(column: str) -> str:
    """``t_start_s`` -> ``t_start_utc``."""
    return f"{column.removesuffix('_s')}_utc"


def _since(frame: pd.DataFrame, column: str, since: float | datetime | None) -> pd.DataFrame:
    """Rows whose ``column`` [s] (or its UTC time, for a datetime ``since``) is after ``since``."""
    if since is None:
        return frame
    if isinstance(since, datetime):
        since = since if since.tzinfo is not None else since.replace(tzinfo=UTC)
        return frame[frame[_utc_name(column)] > pd.Timestamp(since)]
    return frame[frame[column] > float(since)]


def _add_utc(frame: pd.DataFrame, epochs: pd.Series, columns: Sequence[str]) -> None:
    """``<time>_utc`` beside each ``<time>_s`` column: the run's epoch plus the seconds."""
    epoch = _utc_column(epochs)
    for column in columns:
        frame[_utc_name(column)] = epoch + pd.to_timedelta(frame[column], unit="s")


def read_series(
    db_path: str | os.PathLike[str],
    radar: str | None = None,
    since: float | datetime | None = None,
) -> pd.DataFrame:
    """Every stored window's biases: one row per run, radar, window and key.

    Parameters
    ----------
    db_path : str or path
        The history file.
    radar : str, optional
        Only this radar.
    since : float or datetime, optional
        Only the windows that end after this time: seconds on the datasets' time
        base, or a UTC time (a naive datetime is taken as UTC), which keeps only
        runs with a known ``epoch_utc``.

    Returns
    -------
    DataFrame
        ``run_id``, ``radar_id``, ``sensor_model``, ``t_start_s``, ``t_end_s``
        [s], ``n_plots`` (nullable integer), ``key`` (contract key), ``value`` and
        ``sigma`` (1-sigma; NaN when unknown) in the key's unit, and ``t_start_utc``,
        ``t_end_utc`` (NaT without an epoch).  Sorted by radar, window start, run
        and key (contract order).

    Raises
    ------
    HistoryError
        Missing file, not a graphcal history, newer schema, or an unknown radar.
    """
    _check_radar(db_path, radar)
    sql = ("SELECT e.run_id, e.radar_id, a.sensor_model, e.t_start_s, e.t_end_s, e.n_plots, "
           "e.key, e.value, e.sigma, r.epoch_utc FROM estimates e "
           "JOIN runs r USING (run_id) JOIN run_radars a USING (run_id, radar_id)")
    params: list[Any] = []
    if radar is not None:
        sql += " WHERE e.radar_id = ?"
        params.append(radar)
    frame = _read_frame(db_path, sql, params)
    _checked_numbers(frame, db_path, "estimates",
                     {"t_start_s": "required", "t_end_s": "required", "value": "required",
                      "sigma": "sigma", "n_plots": "sigma"})
    frame["n_plots"] = frame["n_plots"].round().astype("Int64")
    _add_utc(frame, _utc_column(frame.pop("epoch_utc"), db_path), ("t_start_s", "t_end_s"))
    frame = _since(frame, "t_end_s", since)
    rank = frame["key"].map(key_rank)
    order = frame.assign(_rank=rank).sort_values(["radar_id", "t_start_s", "run_id", "_rank"],
                                                 kind="stable")
    return order.drop(columns="_rank").reset_index(drop=True)


def read_events(
    db_path: str | os.PathLike[str],
    radar: str | None = None,
    since: float | datetime | None = None,
) -> pd.DataFrame:
    """Every stored event (detected step): one row per event and parameter.

    Parameters are as for :func:`read_series` (``since`` keeps events after it).

    Returns
    -------
    DataFrame
        ``event_id``, ``run_id``, ``radar_id``, ``time_s`` [s], ``kind``, ``key``,
        ``size`` and ``sigma`` (1-sigma) in the key's unit, ``time_utc``.  An event
        without parameters has one row with ``key`` None.  Sorted by radar and time.
    """
    _check_radar(db_path, radar)
    sql = ("SELECT v.event_id, v.run_id, v.radar_id, v.time_s, v.kind, p.key, p.size, "
           "p.sigma, r.epoch_utc FROM events v JOIN runs r USING (run_id) "
           "LEFT JOIN event_parameters p USING (event_id)")
    params: list[Any] = []
    if radar is not None:
        sql += " WHERE v.radar_id = ?"
        params.append(radar)
    frame = _read_frame(db_path, sql + " ORDER BY v.radar_id, v.time_s, v.event_id", params)
    _checked_numbers(frame, db_path, "events",
                     {"time_s": "required", "size": "optional", "sigma": "sigma"})
    _add_utc(frame, _utc_column(frame.pop("epoch_utc"), db_path), ("time_s",))
    return _since(frame, "time_s", since).reset_index(drop=True)


# --------------------------------------------------------------------------- tolerances


def model_tolerances(sensor_model: str) -> dict[str, float]:
    """The tolerances a sensor model gives: :data:`TOLERANCE_PER_TYPICAL_BIAS` times each
    of its non-zero ``typical_bias`` values [contract units].

    Raises
    ------
    SensorModelError
        The model does not exist or is invalid.
    """
    typical = load_sensor_model(sensor_model).typical_bias
    return {key: TOLERANCE_PER_TYPICAL_BIAS * value for key, value in typical.items()
            if value > 0.0}


def default_tolerances(sensor_model: str | None = None) -> dict[str, float]:
    """Default tolerance of each bias key [contract units] for a radar of a sensor model.

    Parameters
    ----------
    sensor_model : str, optional
        A sensor model name (``models/*.toml``).  Its :func:`model_tolerances`
        replace the :data:`FALLBACK_TOLERANCES` of the keys it gives.

    Raises
    ------
    SensorModelError
        The model does not exist or is invalid.
    """
    return {**FALLBACK_TOLERANCES, **(model_tolerances(sensor_model) if sensor_model else {})}


def _checked_tolerances(tolerances: Mapping[str, float] | None) -> dict[str, float]:
    out = {}
    for key, value in (tolerances or {}).items():
        number = _number(value, f"tolerance.{key}")
        if number <= 0.0:
            raise HistoryError(f"must be positive, got {value!r}", field=f"tolerance.{key}")
        out[str(key)] = number
    return out


def _model_tolerances(models: Sequence[Any]) -> dict[Any, dict[str, tuple[float, str]]]:
    """Per sensor model name (or None): each key's default tolerance and its source (the
    model's name, or ``default`` for :data:`FALLBACK_TOLERANCES`)."""
    out: dict[Any, dict[str, tuple[float, str]]] = {}
    for model in models:
        table = {key: (value, "default") for key, value in FALLBACK_TOLERANCES.items()}
        try:
            given = model_tolerances(model) if model else {}
        except SensorModelError:
            given = {}  # a model unknown here (the history was written elsewhere)
        table.update({key: (value, model) for key, value in given.items()})
        out[model] = table
    return out


def flag_tolerances(
    series: pd.DataFrame,
    tolerances: Mapping[str, float] | None = None,
    *,
    defaults: bool = True,
) -> pd.DataFrame:
    """Each window's bias against its tolerance, with its 2-sigma band.

    Parameters
    ----------
    series : DataFrame
        Rows of :func:`read_series` (``key``, ``value``, ``sigma``, and
        ``sensor_model`` for the defaults).
    tolerances : mapping of str to float, optional
        Tolerance per key [contract units, > 0], for every radar; it overrides the
        defaults for that key.
    defaults : bool
        Check the keys ``tolerances`` does not name against the defaults
        (:func:`default_tolerances` of each row's sensor model; an unknown model
        gives :data:`FALLBACK_TOLERANCES`).  False: check only the named keys.

    Returns
    -------
    DataFrame
        ``series`` with ``tolerance`` (NaN: unchecked), ``tolerance_source`` (the
        sensor model, ``default`` or ``given``) and ``status``: ``outside``
        (``|value| - 2 sigma > tolerance``), ``possibly`` (``|value| > tolerance``,
        not beyond 2 sigma, or sigma unknown), ``within`` (``|value| <= tolerance``)
        or ``unchecked``.

    Raises
    ------
    HistoryError
        A tolerance that is not a positive finite number.
    """
    given = _checked_tolerances(tolerances)
    out = series.copy()
    column = out["sensor_model"].tolist() if "sensor_model" in out else [None] * len(out)
    models = [m if isinstance(m, str) and m else None for m in column]  # NaN, "" -> None
    per_model = _model_tolerances(list(dict.fromkeys(models))) if defaults else {}
    limits, sources = [], []
    for model, key in zip(models, out["key"].tolist(), strict=True):
        if key in given:
            limits.append(given[key])
            sources.append("given")
            continue
        limit, source = per_model.get(model, {}).get(key, (math.nan, ""))
        limits.append(limit)
        sources.append(source)
    out["tolerance"] = pd.Series(limits, index=out.index, dtype=float)
    out["tolerance_source"] = sources
    out["status"] = _status(out["value"], out["sigma"], out["tolerance"])
    return out


def _status(value: pd.Series, sigma: pd.Series, tolerance: pd.Series) -> list[str]:
    magnitude = value.abs().to_numpy(dtype=float)
    band = 2.0 * sigma.to_numpy(dtype=float)
    limit = tolerance.to_numpy(dtype=float)
    statuses = []
    for m, b, t in zip(magnitude, band, limit, strict=True):
        if not math.isfinite(t):
            statuses.append("unchecked")
        elif m - b > t:  # False for an unknown (NaN) sigma
            statuses.append("outside")
        elif m > t:
            statuses.append("possibly")
        else:
            statuses.append("within")
    return statuses


def outside_tolerance(
    series: pd.DataFrame,
    tolerances: Mapping[str, float] | None = None,
    *,
    defaults: bool = True,
) -> pd.DataFrame:
    """The windows whose bias is outside its tolerance (status ``outside`` or ``possibly``).

    Same arguments and columns as :func:`flag_tolerances`, keeping only those rows.
    """
    flagged = flag_tolerances(series, tolerances, defaults=defaults)
    return flagged[flagged["status"].isin(("outside", "possibly"))].reset_index(drop=True)


__all__ = [
    "APPLICATION_ID",
    "FALLBACK_TOLERANCES",
    "KEY_ORDER",
    "PROVENANCE_KEYS",
    "SCHEMA_VERSION",
    "STATUSES",
    "STRUCTURE_KEYS",
    "TOLERANCE_PER_TYPICAL_BIAS",
    "HistoryError",
    "append_run",
    "default_tolerances",
    "flag_tolerances",
    "key_rank",
    "key_unit",
    "model_tolerances",
    "outside_tolerance",
    "radar_ids",
    "read_events",
    "read_runs",
    "read_series",
]
