"""Durations for ``--window`` (graphcal.core.durations)."""

from __future__ import annotations

import pytest

from graphcal.core.durations import format_duration, parse_duration


@pytest.mark.parametrize(("text", "seconds"), [
    ("900s", 900.0), ("15min", 900.0), ("15m", 900.0), ("1h", 3600.0), ("1.5h", 5400.0),
    ("2d", 172800.0), (" 30 min ", 1800.0), ("900", 900.0), (900, 900.0), ("1e3s", 1000.0),
    ("1H", 3600.0),
])
def test_durations_are_read_in_seconds(text, seconds) -> None:
    assert parse_duration(text) == seconds


@pytest.mark.parametrize("text", ["", "h", "15 minutes", "1h30", "-5min", "0s", "nan", "1 w",
                                  True])
def test_bad_durations_are_refused_with_the_text(text) -> None:
    with pytest.raises(ValueError, match="duration"):
        parse_duration(text)


@pytest.mark.parametrize(("seconds", "text"), [(3600.0, "1h"), (900.0, "15min"),
                                               (90.0, "90s"), (5400.0, "90min"),
                                               (86400.0, "1d"), (0.5, "0.5s")])
def test_format_is_exact_and_parses_back(seconds, text) -> None:
    assert format_duration(seconds) == text
    assert parse_duration(text) == seconds
