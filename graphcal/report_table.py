"""Readable tables of calibration results (``value ± sigma``) for the terminal."""

from __future__ import annotations

from typing import Any

from rich.table import Table

from graphcal.bias import CONTRACT_KEYS, PARAMETER_NAMES
from graphcal.calibration import Calibration

#: Display precision per contract key.
_FORMATS = {
    "range_offset_m": "{:.2f}",
    "range_gain": "{:.3e}",
    "azimuth_bias_mrad": "{:.3f}",
    "elevation_bias_mrad": "{:.3f}",
    "time_offset_s": "{:.3f}",
}


def format_value(key: str, value: float | None, sigma: float | None = None) -> str:
    """``value ± sigma`` in the key's precision; '-' when not estimated."""
    if value is None:
        return "-"
    fmt = _FORMATS.get(key, "{:.4g}")
    text = fmt.format(value)
    if sigma is None:
        return text
    if sigma != sigma or sigma == float("inf"):
        return f"{text} ± undetermined"
    return f"{text} ± {fmt.format(sigma)}"


def calibration_table(cal: Calibration, truth: dict[str, Any] | None = None) -> Table:
    """A table: one row per radar and parameter, estimate ± 1 sigma, truth if given."""
    table = Table(title=f"graphcal calibration, method {cal.method}")
    table.add_column("radar")
    table.add_column("parameter", no_wrap=True)
    table.add_column("estimate ± 1σ", justify="right", no_wrap=True)
    if truth is not None:
        table.add_column("truth", justify="right")
        table.add_column("error/σ", justify="right")
    table.add_column("plots", justify="right")
    for rid in cal.radar_ids:
        first = True
        for name in PARAMETER_NAMES:
            key = CONTRACT_KEYS[name][0]
            value, sigma = cal.value(rid, key), cal.sigma(rid, key)
            if value is None:
                continue
            row = [rid if first else "", key, format_value(key, value, sigma)]
            if truth is not None:
                true = truth.get("radars", {}).get(rid, {}).get(key)
                row.append(format_value(key, true))
                if true is not None and sigma and sigma == sigma and sigma != float("inf"):
                    row.append(f"{(value - true) / sigma:+.1f}")
                else:
                    row.append("")
            row.append(str(cal.n_plots.get(rid, "")) if first else "")
            table.add_row(*row)
            first = False
    return table
