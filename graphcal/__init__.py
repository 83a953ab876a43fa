"""graphcal: joint bias calibration of air-surveillance radar networks.

The public API, importable from the top level::

    import graphcal

    sim = graphcal.simulate("scenarios/demo_network.toml", seed=1)
    cal = graphcal.calibrate(sim.dataset)                 # the factor graph
    cal.value("NORD", "range_offset_m"), cal.sigma("NORD", "range_offset_m")
    cal.write_json("result.json")

    problem = graphcal.build_problem(sim.dataset, graphcal.SolveOptions(cross="pairwise"))
    cal = graphcal.solve(problem, "graph")                 # one estimator, the problem's options

Names are loaded on first use, so ``import graphcal`` stays light.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

#: Public name -> the module that defines it.
_EXPORTS: dict[str, str] = {
    "calibrate": "graphcal.pipeline.calibrate",
    "simulate": "graphcal.pipeline.simulate",
    "compare": "graphcal.pipeline.compare",
    "correct_folder": "graphcal.pipeline.correct",
    "correct_dataset": "graphcal.data.correct",
    "load_dataset": "graphcal.io.folder",
    "write_dataset": "graphcal.io.folder",
    "load_sites": "graphcal.io.folder",
    "load_scenario": "graphcal.simulation.scenario",
    "Calibration": "graphcal.data.calibration",
    "load_truth": "graphcal.data.truth",
    "compare_to_truth": "graphcal.data.truth",
    "Dataset": "graphcal.data.dataset",
    "Site": "graphcal.data.dataset",
    "RadarBias": "graphcal.data.bias",
    "SimulationResult": "graphcal.simulation.simulate",
    "GraphcalInputError": "graphcal.core.errors",
    "DatasetError": "graphcal.core.errors",
    "EstimationError": "graphcal.core.errors",
    "METHODS": "graphcal.solvers.registry",
    "solve": "graphcal.solvers.registry",
    "build_problem": "graphcal.model.problem",
    "Problem": "graphcal.model.problem",
    "SolveOptions": "graphcal.core.solve_options",
}

__all__ = [
    "__version__",
    "calibrate",
    "simulate",
    "compare",
    "correct_folder",
    "correct_dataset",
    "load_dataset",
    "write_dataset",
    "load_sites",
    "load_scenario",
    "Calibration",
    "load_truth",
    "compare_to_truth",
    "Dataset",
    "Site",
    "RadarBias",
    "SimulationResult",
    "GraphcalInputError",
    "DatasetError",
    "EstimationError",
    "METHODS",
    "solve",
    "build_problem",
    "Problem",
    "SolveOptions",
]

if TYPE_CHECKING:  # pragma: no cover - for type checkers and the API reference
    from graphcal.core.errors import DatasetError, EstimationError, GraphcalInputError
    from graphcal.core.solve_options import SolveOptions
    from graphcal.data.bias import RadarBias
    from graphcal.data.calibration import Calibration
    from graphcal.data.correct import correct_dataset
    from graphcal.data.dataset import Dataset, Site
    from graphcal.data.truth import compare_to_truth, load_truth
    from graphcal.io.folder import load_dataset, load_sites, write_dataset
    from graphcal.model.problem import Problem, build_problem
    from graphcal.pipeline.calibrate import calibrate
    from graphcal.pipeline.compare import compare
    from graphcal.pipeline.correct import correct_folder
    from graphcal.pipeline.simulate import simulate
    from graphcal.simulation.scenario import load_scenario
    from graphcal.simulation.simulate import SimulationResult
    from graphcal.solvers.registry import METHODS, solve


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'graphcal' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
