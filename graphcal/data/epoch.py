"""The epoch of a dataset: the UTC time of 0 s on its time base (contract extension v1.6).

``time_s`` in the plots and ADS-B tables counts seconds on a time base the contract
leaves open (ASTERIX recordings count from 00:00 UTC of their first day, a simulation
from its start).  ``sites.toml`` may say which UTC time its 0 s is::

    [dataset]
    epoch_utc = "2021-10-07T00:00:00Z"

An ISO 8601 date and time with a UTC designator (``Z`` or ``+00:00``), as a string
or a TOML offset date-time; fractions of a second are allowed.  A time without a
designator, with another offset, or a date alone is refused: the key names UTC, and a
local time read as UTC would shift every date by hours.

:func:`parse_epoch_utc` validates a value, :func:`format_epoch_utc` writes one and
:func:`utc_at` turns a dataset time into a UTC date and time.
"""

from __future__ import annotations

from datetime import UTC, date, datetime, timedelta
from typing import Any

#: The example the messages give.
EPOCH_EXAMPLE = "2021-10-07T00:00:00Z"


def parse_epoch_utc(value: Any) -> datetime:
    """A ``[dataset] epoch_utc`` value as an aware UTC :class:`~datetime.datetime`.

    Parameters
    ----------
    value : str or datetime
        ISO 8601 text with a UTC designator, or an aware datetime at UTC (TOML
        offset date-times are read as such).

    Raises
    ------
    ValueError
        Naming what is wrong, with the example ``2021-10-07T00:00:00Z``.
    """
    shown = value.isoformat() if isinstance(value, date) else repr(value)
    if isinstance(value, date) and not isinstance(value, datetime):
        raise ValueError(f"{shown} is a date without a time; give the UTC time of 0 s, "
                         f"e.g. \"{EPOCH_EXAMPLE}\"")
    if isinstance(value, str):
        text = value.strip()
        try:
            parsed = datetime.fromisoformat(text)
        except ValueError:
            raise ValueError(f"{shown} is not an ISO 8601 date and time; e.g. "
                             f"\"{EPOCH_EXAMPLE}\"") from None
        if len(text) <= len("2021-10-07"):
            raise ValueError(f"{shown} is a date without a time; give the UTC time of 0 s, "
                             f"e.g. \"{EPOCH_EXAMPLE}\"")
    elif isinstance(value, datetime):
        parsed = value
    else:
        raise ValueError(f"{shown} is not a date and time; give a string such as "
                         f"\"{EPOCH_EXAMPLE}\"")
    offset = parsed.utcoffset()
    if offset is None:
        raise ValueError(f"{shown} has no UTC designator; end it with Z, e.g. "
                         f"\"{EPOCH_EXAMPLE}\"")
    if offset != timedelta(0):
        raise ValueError(f"{shown} is not in UTC (offset {_offset_text(offset)}); give the "
                         f"UTC time with Z, e.g. \"{EPOCH_EXAMPLE}\"")
    return parsed.astimezone(UTC)


def _offset_text(offset: timedelta) -> str:
    minutes = round(offset.total_seconds() / 60)
    sign = "+" if minutes >= 0 else "-"
    return f"{sign}{abs(minutes) // 60:02d}:{abs(minutes) % 60:02d}"


def format_epoch_utc(epoch: datetime) -> str:
    """``2021-10-07T00:00:00Z`` (fractions of a second when there are any)."""
    epoch = epoch.astimezone(UTC)
    text = epoch.strftime("%Y-%m-%dT%H:%M:%S")
    if epoch.microsecond:
        text += f".{epoch.microsecond:06d}".rstrip("0")
    return text + "Z"


def epoch_from_unix(unix_s: float) -> datetime:
    """The epoch at unix time ``unix_s`` [s] (as an ASTERIX or OpenSky reader knows it)."""
    return datetime(1970, 1, 1, tzinfo=UTC) + timedelta(seconds=float(unix_s))


def utc_at(epoch: datetime, time_s: float) -> datetime:
    """The UTC date and time of ``time_s`` [s] on a time base whose 0 s is ``epoch``."""
    return epoch.astimezone(UTC) + timedelta(seconds=float(time_s))


__all__ = ["EPOCH_EXAMPLE", "epoch_from_unix", "format_epoch_utc", "parse_epoch_utc", "utc_at"]
