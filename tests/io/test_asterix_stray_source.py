"""A data source identifier corrupted in a few records is not a radar to ask a position
for: its handful of plots are left out and counted."""

from __future__ import annotations

from graphcal.io.asterix.tables import (
    STRAY_MAX_PLOTS,
    STRAY_MAX_SHARE,
    RadarInventory,
    stray_sources,
)


def _radar(sic: int, plots: int) -> RadarInventory:
    return RadarInventory(sac=25, sic=sic, radar_id=f"R{sic}", plots=plots,
                          polar_reports=plots, height_reports=0, cat034=None)


def test_a_handful_of_plots_is_a_stray_source() -> None:
    radars = [_radar(10, 70_000), _radar(11, 71_000), _radar(99, 1), _radar(98, STRAY_MAX_PLOTS)]
    stray = stray_sources(radars[2:], radars)
    assert [r.sic for r in stray] == [99, 98]


def test_a_small_recording_keeps_asking() -> None:
    # 15 plots of 200 are 7.5 %: a radar seen briefly, not a corrupted byte
    radars = [_radar(10, 185), _radar(11, 15)]
    assert 15 > STRAY_MAX_SHARE * 200
    assert stray_sources(radars[1:], radars) == []


def test_more_than_the_limit_is_a_radar() -> None:
    radars = [_radar(10, 1_000_000), _radar(11, STRAY_MAX_PLOTS + 1)]
    assert stray_sources(radars[1:], radars) == []
