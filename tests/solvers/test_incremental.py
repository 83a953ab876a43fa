"""The Calibrator: data given in blocks as they would arrive, windows closed as data beyond
them come, the chain kept by iSAM2.  Checked against the batch smoother on the same
summaries (the same linear problem, solved another way) and against the truth of a
simulated step."""

from __future__ import annotations

import tomllib
from dataclasses import replace

import numpy as np
import pytest

from graphcal.simulation.scenario import parse_scenario
from graphcal.simulation.simulate import simulate
from graphcal.solvers.incremental import Calibrator
from graphcal.solvers.windows import DEFAULT_RANDOM_WALK_PER_SQRT_S, smooth_windows
from tests.paths import SCENARIOS


@pytest.fixture(scope="module")
def fed():
    with open(SCENARIOS / "demo_network.toml", "rb") as f:
        doc = tomllib.load(f)
    doc["scenario"]["duration_s"] = 3600.0
    doc["traffic"]["start_time_s"] = [0.0, 1800.0]
    doc["radar"][1]["step"] = [{"time_s": 1850.0, "range_offset_m": 80.0}]
    sim = simulate(parse_scenario(doc), np.random.default_rng(7))
    ds = sim.dataset
    calibrator = Calibrator(ds.sites, 900.0)
    closed = []
    for start in np.arange(0.0, 3600.0, 600.0):  # ten-minute blocks
        keep = (ds.plots["time_s"] >= start) & (ds.plots["time_s"] < start + 600.0)
        near = (ds.adsb["time_s"] >= start) & (ds.adsb["time_s"] < start + 600.0)
        closed.append(len(calibrator.add(replace(ds, plots=ds.plots[keep],
                                                 adsb=ds.adsb[near]))))
    closed.append(len(calibrator.flush()))
    return ds, calibrator, closed


def test_windows_close_as_later_data_arrive(fed) -> None:
    _, calibrator, closed = fed
    # Blocks end at 600, 1200, ... s: 900-s windows close once plots beyond their end
    # (plus the 30-s ADS-B margin) have come; the last one at the flush.
    assert closed == [0, 1, 0, 1, 1, 0, 1]
    assert [s.t_start_s for s in calibrator.summaries] == [0.0, 900.0, 1800.0, 2700.0]


def test_isam2_gives_the_batch_smoother_solution(fed) -> None:
    ds, calibrator, _ = fed
    batch = smooth_windows(calibrator.summaries, ds.sites, 900.0,
                           random_walk_per_sqrt_s=DEFAULT_RANDOM_WALK_PER_SQRT_S,
                           breaks={e.radar_id: [e.time_s] for e in calibrator.events},
                           detect_steps=False)
    online = calibrator.series()
    for rid, windows in batch.series.items():
        for mine, theirs in zip(online[rid], windows, strict=True):
            for name in batch.terms[rid].free:
                sigma = np.sqrt(theirs.covariance[batch.terms[rid].free.index(name)] [
                    batch.terms[rid].free.index(name)])
                assert abs(mine.bias.value(name) - theirs.bias.value(name)) < 1e-6 * sigma
            for key, value in theirs.sigma.items():
                assert mine.sigma[key] == pytest.approx(value, rel=1e-6)


def test_the_step_is_found_when_its_window_arrives(fed) -> None:
    """SUD steps 80 m at 1850 s: the window 1800-2700 s jumps; no other event."""
    _, calibrator, _ = fed
    (event,) = calibrator.events
    assert event.radar_id == "SUD" and event.time_s == 1800.0
    assert event.parameters == ["range_offset_m"]
    assert abs(event.size["range_offset_m"] - 80.0 * (2700.0 - 1850.0) / 900.0) < (
        4 * event.sigma["range_offset_m"])
    current = calibrator.current()["SUD"]
    assert current.t_start_s == 2700.0


def test_late_data_are_refused(fed) -> None:
    ds, _, _ = fed
    calibrator = Calibrator(ds.sites, 900.0)
    calibrator.add(replace(ds, plots=ds.plots[ds.plots["time_s"] < 2000.0]))
    with pytest.raises(ValueError, match="time order"):
        calibrator.add(replace(ds, plots=ds.plots[ds.plots["time_s"] < 100.0]))
