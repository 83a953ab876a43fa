"""wls warns when its estimates lie beyond what one linearisation handles."""

from __future__ import annotations

import numpy as np

from graphcal.data.calibration import Calibration, Observability
from graphcal.solvers.wls import LINEARISATION_LIMITS, beyond_one_linearisation


def _cal(offset_m: float, azimuth_rad: float) -> Calibration:
    labels = [("NORD", "range_offset"), ("NORD", "azimuth_bias")]
    return Calibration(method="wls", radar_ids=["NORD"], is_3d={"NORD": False}, labels=labels,
                       estimate=np.array([offset_m, azimuth_rad]),
                       covariance=np.diag([1.0, 1e-10]), n_plots={"NORD": 100},
                       observability=Observability(degree=0.1, rank=2, n_parameters=2))


def test_limits_are_1_km_and_10_mrad() -> None:
    assert LINEARISATION_LIMITS == {"range_offset_m": 1000.0, "azimuth_bias_mrad": 10.0,
                                    "elevation_bias_mrad": 10.0}


def test_large_biases_are_named_small_ones_not() -> None:
    assert beyond_one_linearisation(_cal(3030.3, 0.001)) == ["NORD range_offset_m 3,030"]
    assert beyond_one_linearisation(_cal(-50.0, -0.012)) == ["NORD azimuth_bias_mrad -12"]
    assert beyond_one_linearisation(_cal(999.0, 0.0099)) == []
