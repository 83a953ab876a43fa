"""The true biases of a simulated dataset (``truth.json``) and an estimate compared with them.

A simulation writes ``truth.json`` beside its dataset, in the result schema
(``radars.RADAR.<contract key>``, contract units; ``null`` for a term the radar
does not have, which is zero).  :func:`load_truth` reads it, checked;
:func:`compare_to_truth` sets a :class:`~graphcal.data.calibration.Calibration`
against it, term by term::

    import graphcal

    cal = graphcal.calibrate("demo-out")
    table = graphcal.compare_to_truth(cal, graphcal.load_truth("demo-out/truth.json"))
    print(table[table["z"].abs() > 3])      # estimates more than 3 sigma off
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from graphcal.core.errors import ResultError
from graphcal.data.bias import CONTRACT_KEYS, NAME_FROM_KEY, contract_unit
from graphcal.data.calibration import Calibration

#: Columns of :func:`compare_to_truth`'s table, in order.
COMPARISON_COLUMNS: tuple[str, ...] = (
    "radar", "parameter", "unit", "estimate", "truth", "error", "sigma", "z",
)


@dataclass(frozen=True)
class Truth:
    """True biases per radar, contract units (``truth.json``).

    Attributes
    ----------
    radars : dict of str to dict of str to float
        Per radar, the values the file gives by contract key (``null`` ones as 0).
    scenario : str or None
        The scenario's name, when the file says it.
    path : Path or None
        The file read.
    raw : dict
        The whole parsed file (e.g. ``series`` of a scenario whose biases change).
    """

    radars: dict[str, dict[str, float]]
    scenario: str | None = None
    path: Path | None = None
    raw: dict[str, Any] = field(default_factory=dict, repr=False)

    def value(self, radar_id: str, key: str) -> float:
        """The true value of a contract key [contract unit]; 0 where the file has none
        (a term the simulation did not give the radar); NaN for a radar it lacks."""
        if radar_id not in self.radars:
            return math.nan
        return self.radars[radar_id].get(key, 0.0)


def load_truth(path: str | Path) -> Truth:
    """Read and check a ``truth.json`` (or any result JSON: its values are taken as true).

    Raises
    ------
    ResultError
        Missing or unreadable file, not JSON, no ``radars`` object, or a value that
        is not a number; the message names the file and the field.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ResultError("no such file", path=path) from None
    except IsADirectoryError:
        raise ResultError("is a folder, not a truth JSON file", path=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ResultError(f"cannot read: {exc}", path=path) from None
    except json.JSONDecodeError as exc:
        raise ResultError(f"not valid JSON (line {exc.lineno}, column {exc.colno}: "
                          f"{exc.msg})", path=path) from None
    radars = data.get("radars") if isinstance(data, Mapping) else None
    if not isinstance(radars, Mapping):
        raise ResultError("missing or not an object", path=path, field="radars")
    out: dict[str, dict[str, float]] = {}
    for rid, entry in radars.items():
        if not isinstance(entry, Mapping):
            raise ResultError("not an object", path=path, field=f"radars.{rid}")
        values: dict[str, float] = {}
        fixed = entry.get("fixed") if isinstance(entry.get("fixed"), Mapping) else {}
        for key, value in [*fixed.items(), *entry.items()]:
            if key not in NAME_FROM_KEY:
                continue
            if value is None:
                values[key] = 0.0
                continue
            if isinstance(value, bool) or not isinstance(value, int | float) or not \
                    math.isfinite(value):
                raise ResultError(f"{value!r} is not a finite number", path=path,
                                  field=f"radars.{rid}.{key}")
            values[key] = float(value)
        out[str(rid)] = values
    scenario = data.get("scenario")
    return Truth(out, scenario if isinstance(scenario, str) else None, path, dict(data))


def compare_to_truth(calibration: Calibration, truth: Truth | str | Path) -> pd.DataFrame:
    """Each estimated term of ``calibration`` against the truth.

    Parameters
    ----------
    calibration : Calibration
        The estimate.
    truth : Truth, str or Path
        A :class:`Truth` or the path of a ``truth.json`` (:func:`load_truth`).

    Returns
    -------
    pandas.DataFrame
        One row per radar and estimated term (:data:`COMPARISON_COLUMNS`), contract
        units: ``estimate``, ``truth`` (NaN for a radar the truth lacks),
        ``error = estimate - truth``, ``sigma`` (the estimate's 1-sigma) and
        ``z = error / sigma`` (how many sigmas off; about standard normal for an
        honest estimate).  Fixed terms are not compared.
    """
    if not isinstance(truth, Truth):
        truth = load_truth(truth)
    rows = []
    for rid, name in calibration.labels:
        key = CONTRACT_KEYS[name][0]
        estimate = calibration.value(rid, key)
        sigma = calibration.sigma(rid, key)
        true = truth.value(rid, key)
        error = estimate - true
        rows.append({"radar": rid, "parameter": key, "unit": contract_unit(key),
                     "estimate": estimate, "truth": true, "error": error,
                     "sigma": np.nan if sigma is None else sigma,
                     "z": error / sigma if sigma else np.nan})
    return pd.DataFrame(rows, columns=list(COMPARISON_COLUMNS))


__all__ = ["COMPARISON_COLUMNS", "Truth", "compare_to_truth", "load_truth"]
