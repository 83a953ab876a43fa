"""Display units and number formats of the HTML report.

The result JSON speaks contract units (m, fraction, mrad, s); an engineer reads
a range gain in ppm and a time offset in ms.  :data:`DISPLAY` maps each
contract key to a readable name, a display unit and the factor from the
contract unit; :func:`value_text` writes a value with as many decimals as its
sigma warrants (two significant digits of the sigma); :func:`clock_text`
writes a dataset time as a UTC time of day, and :func:`span_text` a time span, with
its UTC date when the dataset's epoch is known (:mod:`graphcal.data.epoch`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime

from graphcal.data.epoch import utc_at


@dataclass(frozen=True)
class DisplayUnit:
    """How one parameter is shown.

    Attributes
    ----------
    name : str
        Readable name, e.g. ``"range gain"``.
    unit : str
        Display unit, e.g. ``"ppm"``.
    factor : float
        Display value = contract value x ``factor``.
    short : str
        Short name for matrix labels, e.g. ``"gain"``.
    """

    name: str
    unit: str
    factor: float
    short: str


#: Contract key -> how it is displayed.
DISPLAY: dict[str, DisplayUnit] = {
    "range_offset_m": DisplayUnit("range offset", "m", 1.0, "Δr"),
    "range_gain": DisplayUnit("range gain", "ppm", 1e6, "gain"),
    "azimuth_bias_mrad": DisplayUnit("azimuth bias", "mrad", 1.0, "az"),
    "elevation_bias_mrad": DisplayUnit("elevation bias", "mrad", 1.0, "el"),
    "time_offset_s": DisplayUnit("time offset", "ms", 1e3, "Δt"),
    "azimuth_sin_mrad": DisplayUnit("azimuth eccentricity, sin term", "mrad", 1.0, "az sin"),
    "azimuth_cos_mrad": DisplayUnit("azimuth eccentricity, cos term", "mrad", 1.0, "az cos"),
    "height_offset_m": DisplayUnit("height offset", "m", 1.0, "Δh"),
    "height_scale": DisplayUnit("height scale", "ppm", 1e6, "h scale"),
}

#: |z| (error over sigma against the truth) beyond which an estimate is flagged.
Z_FLAG = 3.0


def display_unit(key: str) -> DisplayUnit:
    """The :class:`DisplayUnit` of a contract key (the key itself, factor 1, if unknown)."""
    return DISPLAY.get(key, DisplayUnit(key, "", 1.0, key))


def decimals_for(sigma: float | None, default: int = 3) -> int:
    """Decimals that show two significant digits of ``sigma`` (0 to 6)."""
    if sigma is None or not math.isfinite(sigma) or sigma <= 0.0:
        return default
    return int(min(6, max(0, 1 - math.floor(math.log10(sigma)))))


def value_text(value: float | None, decimals: int) -> str:
    """``value`` with fixed ``decimals`` (no exponent); an en dash when missing."""
    if value is None:
        return "–"
    if not math.isfinite(value):
        return str(value)
    text = f"{value:,.{decimals}f}"
    if text.startswith("-") and float(text.replace(",", "")) == 0.0:
        text = text[1:]  # no "-0.00"
    return text.replace(",", "\u2009")  # a thin space between thousands


def clock_text(time_s: float, epoch_utc: datetime | None = None) -> str:
    """A dataset time as ``HH:MM:SS`` UTC, with ``+Nd`` beyond the first day.

    The contract's ``time_s`` is seconds on the ADS-B time base.  With the dataset's
    epoch (the UTC time of 0 s, ``[dataset] epoch_utc``) the time is the epoch plus
    ``time_s`` (``+Nd``: days after the epoch's date); without it, the time is read as
    counted from 00:00 UTC of the first day, as recordings imported from ASTERIX count it.
    """
    if not math.isfinite(time_s):
        return "–"
    if epoch_utc is not None:
        when = utc_at(epoch_utc, round(time_s))
        day = (when.date() - epoch_utc.astimezone(when.tzinfo).date()).days
        text = when.strftime("%H:%M:%S")
        return text if day == 0 else f"{text} {day:+d}d"
    day, rest = divmod(round(time_s), 86400)
    hours, rest = divmod(rest, 3600)
    minutes, seconds = divmod(rest, 60)
    text = f"{hours:02d}:{minutes:02d}:{seconds:02d}"
    return text if day == 0 else f"{text} {day:+d}d"


def span_text(t0_s: float, t1_s: float, epoch_utc: datetime | None = None) -> str:
    """A time span of the dataset in UTC, e.g. ``2021-10-07 08:00:00 – 10:30:00``.

    With the dataset's epoch (the UTC time of 0 s) the first time has its date, and
    the last one too when it falls on another day; without it, both are times of day
    read as counted from 00:00 UTC of the first day (:func:`clock_text`).
    """
    if epoch_utc is None or not (math.isfinite(t0_s) and math.isfinite(t1_s)):
        return f"{clock_text(t0_s)} – {clock_text(t1_s)}"
    first, last = utc_at(epoch_utc, round(t0_s)), utc_at(epoch_utc, round(t1_s))
    end = (last.strftime("%H:%M:%S") if last.date() == first.date()
           else last.strftime("%Y-%m-%d %H:%M:%S"))
    return f"{first.strftime('%Y-%m-%d %H:%M:%S')} – {end}"


def duration_text(seconds: float) -> str:
    """A duration as ``1 h 05 min``, ``12 min 30 s`` or ``45 s``."""
    seconds = max(0.0, float(seconds))
    if seconds >= 3600:
        hours, rest = divmod(round(seconds / 60), 60)
        return f"{hours} h {rest:02d} min"
    if seconds >= 60:
        minutes, rest = divmod(round(seconds), 60)
        return f"{minutes} min {rest:02d} s"
    return f"{seconds:.0f} s"


__all__ = ["DISPLAY", "Z_FLAG", "DisplayUnit", "clock_text", "decimals_for", "display_unit",
           "span_text",
           "duration_text", "value_text"]
