"""The calibration problem: built once, immutable, and the one place the plots are aligned
with ADS-B for every stage of a calibration."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import graphcal.model.problem as problem_module
from graphcal.core.solve_options import SolveOptions
from graphcal.data.align import align_adsb
from graphcal.model.problem import Problem, as_problem, build_problem
from graphcal.pipeline.calibrate import calibrate
from graphcal.solvers.adsb_reference import ls
from graphcal.solvers.registry import solve
from graphcal.solvers.wls import wls


@pytest.fixture(scope="module")
def short(demo):
    """The demo network's first 20 minutes."""
    plots = demo.plots[demo.plots["time_s"] < demo.plots["time_s"].min() + 1200.0]
    return dataclasses.replace(demo, plots=plots.reset_index(drop=True))


def test_a_problem_is_immutable_and_its_arrays_are_made_once(short) -> None:
    problem = build_problem(short, SolveOptions(max_gap_s=8.0))
    with pytest.raises(dataclasses.FrozenInstanceError):
        problem.options = SolveOptions()  # type: ignore[misc]
    assert problem.plots("NORD") is problem.plots("NORD")
    al = problem.alignment("NORD")
    assert al is problem.alignment("NORD", 8.0)  # the options' gap
    assert problem.alignment("NORD", 10.0) is not al
    # Against aligning afresh: the same arrays.
    afresh = align_adsb(short, "NORD", 8.0)
    np.testing.assert_array_equal(al.reference_ecef_m, afresh.reference_ecef_m)
    np.testing.assert_array_equal(al.plots.index, afresh.plots.index)
    # At a time offset: made afresh each time, as the offset moves the reference.
    assert problem.alignment("NORD", time_offset_s=0.5) is not problem.alignment(
        "NORD", time_offset_s=0.5)
    assert as_problem(problem) is problem
    assert isinstance(as_problem(short), Problem)


def test_solve_runs_the_estimator_with_the_problems_options(short) -> None:
    problem = build_problem(short, SolveOptions(max_gap_s=8.0, iterations=2))
    by_problem = solve(problem, "ls")
    by_dataset = ls(short, max_gap_s=8.0)
    np.testing.assert_array_equal(by_problem.estimate, by_dataset.estimate)
    np.testing.assert_array_equal(by_problem.covariance, by_dataset.covariance)
    assert by_problem.info["max_gap_s"] == 8.0
    by_problem = solve(problem, "wls")
    by_dataset = wls(short, iterations=2, max_gap_s=8.0)
    np.testing.assert_array_equal(by_problem.estimate, by_dataset.estimate)
    assert by_problem.info["iterations"] == 2


def test_one_calibration_aligns_each_radar_with_adsb_once(short, monkeypatch) -> None:
    """The estimate, its initial values, the Cramér-Rao bound, the model checks and the fit
    verdict share the problem's alignments: each radar is aligned at zero time offset
    once (the model checks align again at each radar's estimated time offset)."""
    calls: list[tuple[str, float]] = []

    def counted(dataset, radar_id, max_gap_s, time_offset_s=0.0, **kwargs):
        calls.append((radar_id, time_offset_s))
        return align_adsb(dataset, radar_id, max_gap_s, time_offset_s, **kwargs)

    monkeypatch.setattr(problem_module, "align_adsb", counted)
    cal = calibrate(short, bound=True)
    assert "crlb_sigma" in cal.info and "model_checks" in cal.info
    at_zero = [rid for rid, tau in calls if tau == 0.0]
    assert sorted(at_zero) == sorted(short.radar_ids)
