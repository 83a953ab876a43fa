"""An indeterminate system at the solution is an estimation failure naming the radar
(exit 3), not a GTSAM traceback."""

from __future__ import annotations

import numpy as np
import pytest

from graphcal.core.errors import EstimationError
from graphcal.solvers import graph as graph_module
from graphcal.solvers.gtsam_adapter import FactorGraph, IndeterminateSystemError, symbol


def test_an_unconstrained_direction_raises_with_its_key() -> None:
    a, b = symbol("b", 0), symbol("b", 1)
    fg = FactorGraph()
    fg.add_variable(a, np.zeros(2))
    fg.add_variable(b, np.zeros(1))
    fg.add_prior(b, np.zeros(1), np.ones(1))
    # a's second component appears in no factor: its information is singular
    fg.add_linear([a], [np.array([[1.0, 0.0]])], np.zeros(1))
    result = fg.optimize()  # Levenberg-Marquardt's damping solves it; the marginals cannot
    with pytest.raises(IndeterminateSystemError) as caught:
        fg.joint_covariance(result.values, [a, b])
    assert caught.value.key == a
    assert isinstance(caught.value, EstimationError)


def test_graph_names_the_radar() -> None:
    class Stub:
        def joint_covariance(self, values, keys):
            raise IndeterminateSystemError("indeterminate", symbol("b", 1))

    with pytest.raises(EstimationError, match="near SUD's biases"):
        graph_module.named_joint_covariance(Stub(), None, [symbol("b", 0), symbol("b", 1)],
                                       {"NORD": symbol("b", 0), "SUD": symbol("b", 1)})
