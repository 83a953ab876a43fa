"""Durations written as people write them: ``15min``, ``1h``, ``900s``, ``1.5h``, ``2d``.

Used by ``calibrate --window`` (contract v2) and the drift rates.  A bare number is in
seconds.  Units: ``s``, ``min``, ``h``, ``d`` (also ``sec``, ``m`` for minutes, ``hr``,
``day``).
"""

from __future__ import annotations

import math
import re

#: Unit -> seconds.
UNITS_S: dict[str, float] = {
    "": 1.0, "s": 1.0, "sec": 1.0,
    "m": 60.0, "min": 60.0,
    "h": 3600.0, "hr": 3600.0,
    "d": 86400.0, "day": 86400.0,
}

_PATTERN = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([a-zA-Z]*)\s*$")


def parse_duration(text: str | float) -> float:
    """A duration in seconds from ``"15min"``, ``"1h"``, ``"900s"``, ``"1.5h"`` or ``900``.

    Raises
    ------
    ValueError
        Naming the text and the units understood, for anything else, and for a
        duration that is not positive and finite.
    """
    if isinstance(text, int | float) and not isinstance(text, bool):
        seconds = float(text)
    else:
        match = _PATTERN.match(str(text))
        unit = match.group(2).lower() if match else None
        if match is None or unit not in UNITS_S:
            raise ValueError(
                f"not a duration: {text!r} (write e.g. 900s, 15min, 1h or 1.5h; "
                f"units {', '.join(u for u in UNITS_S if u)})")
        seconds = float(match.group(1)) * UNITS_S[unit]
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"a duration must be positive: {text!r}")
    return seconds


def format_duration(seconds: float) -> str:
    """The shortest of ``"1h"``, ``"15min"`` or ``"900s"`` that is exact."""
    for unit, factor in (("d", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= factor and (seconds / factor).is_integer():
            return f"{int(seconds / factor)}{unit}"
    return f"{seconds:g}s"


__all__ = ["UNITS_S", "format_duration", "parse_duration"]
