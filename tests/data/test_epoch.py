"""The dataset's epoch, ``[dataset] epoch_utc`` (graphcal.data.epoch, contract v1.6)."""

from __future__ import annotations

from datetime import UTC, date, datetime, timedelta, timezone

import pytest

from graphcal.data.epoch import epoch_from_unix, format_epoch_utc, parse_epoch_utc, utc_at

OCT_7 = datetime(2021, 10, 7, tzinfo=UTC)


@pytest.mark.parametrize("value", [
    "2021-10-07T00:00:00Z", "2021-10-07T00:00:00+00:00", "2021-10-07 00:00:00Z",
    " 2021-10-07T00:00:00Z ", "20211007T000000Z",
    datetime(2021, 10, 7, tzinfo=UTC), datetime(2021, 10, 7, tzinfo=timezone(timedelta(0))),
])
def test_utc_times_are_read(value) -> None:
    epoch = parse_epoch_utc(value)
    assert epoch == OCT_7 and epoch.tzinfo == UTC


@pytest.mark.parametrize(("value", "words"), [
    ("2021-10-07T00:00:00", "has no UTC designator; end it with Z"),
    (datetime(2021, 10, 7), "2021-10-07T00:00:00 has no UTC designator"),
    ("2021-10-07T02:00:00+02:00", "is not in UTC (offset +02:00)"),
    ("2021-10-06T21:30:00-02:30", "is not in UTC (offset -02:30)"),
    ("2021-10-07", "is a date without a time"),
    (date(2021, 10, 7), "2021-10-07 is a date without a time"),
    ("yesterday", "'yesterday' is not an ISO 8601 date and time"),
    ("2021-13-07T00:00:00Z", "is not an ISO 8601 date and time"),
    (1633564800, "1633564800 is not a date and time"),
])
def test_other_values_are_refused_with_the_example(value, words: str) -> None:
    with pytest.raises(ValueError) as info:
        parse_epoch_utc(value)
    assert words in str(info.value) and '"2021-10-07T00:00:00Z"' in str(info.value)


def test_written_as_iso_with_z_and_read_back_exactly() -> None:
    assert format_epoch_utc(OCT_7) == "2021-10-07T00:00:00Z"
    fraction = OCT_7 + timedelta(hours=6, microseconds=250_000)
    assert format_epoch_utc(fraction) == "2021-10-07T06:00:00.25Z"
    assert parse_epoch_utc(format_epoch_utc(fraction)) == fraction
    assert epoch_from_unix(1633564800.0) == OCT_7  # tests/io: MIDNIGHT
    # 30 h after the epoch is the next day, 06:00 UTC
    assert utc_at(OCT_7, 30 * 3600.0) == datetime(2021, 10, 8, 6, tzinfo=UTC)
