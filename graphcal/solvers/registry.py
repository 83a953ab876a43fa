"""Estimators: every one takes a calibration problem (:class:`~graphcal.model.problem.Problem`,
or a :class:`~graphcal.data.dataset.Dataset` made into one) and returns a
:class:`~graphcal.data.calibration.Calibration`, so comparisons are a loop over names:
``solve(problem, method)`` with the problem's options (:func:`solve`).

=============  ==========================================================  ========
name           what                                                         needs
=============  ==========================================================  ========
``ls``         paper 003 eq. 11-19, per radar against ADS-B                 ADS-B
``fl``         paper 003 eq. 8-10, line-fit azimuth                         ADS-B
``fl-ls``      paper 003: FL compensation, then LS                          ADS-B
``wls``        paper 001 eq. 8-11, cross-radar weighted least squares       2 radars
``wls-pruned`` paper 001 eq. 12 greedy pruning, then WLS                    2 radars
``graph``      GTSAM factor graph: ADS-B and cross-radar factors, robust    either
=============  ==========================================================  ========
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator, Mapping
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover - the estimators' types, without importing them
    from graphcal.core.solve_options import SolveOptions
    from graphcal.data.calibration import Calibration
    from graphcal.data.dataset import Dataset
    from graphcal.model.problem import Problem

Estimator = Callable[..., "Calibration"]

#: Where each estimator lives, ``"module:function"``; imported on first use.
ESTIMATOR_PATHS: dict[str, str] = {
    "ls": "graphcal.solvers.adsb_reference:ls",
    "fl": "graphcal.solvers.adsb_reference:fl",
    "fl-ls": "graphcal.solvers.adsb_reference:fl_ls",
    "wls": "graphcal.solvers.wls:wls",
    "wls-pruned": "graphcal.solvers.wls:wls_pruned",
    "graph": "graphcal.solvers.graph:graph",
}

# Each estimator's loader: an import a reader (or a static analysis) can follow, done on
# first use so that naming or listing the methods imports none of them.
def _load_ls() -> Estimator:
    from graphcal.solvers.adsb_reference import ls

    return ls


def _load_fl() -> Estimator:
    from graphcal.solvers.adsb_reference import fl

    return fl


def _load_fl_ls() -> Estimator:
    from graphcal.solvers.adsb_reference import fl_ls

    return fl_ls


def _load_wls() -> Estimator:
    from graphcal.solvers.wls import wls

    return wls


def _load_wls_pruned() -> Estimator:
    from graphcal.solvers.wls import wls_pruned

    return wls_pruned


def _load_graph() -> Estimator:
    from graphcal.solvers.graph import graph

    return graph


#: Each estimator's loader (the same functions as :data:`ESTIMATOR_PATHS` names; a test
#: keeps the two equal).
ESTIMATOR_LOADERS: dict[str, Callable[[], Estimator]] = {
    "ls": _load_ls,
    "fl": _load_fl,
    "fl-ls": _load_fl_ls,
    "wls": _load_wls,
    "wls-pruned": _load_wls_pruned,
    "graph": _load_graph,
}

#: One line on each estimator: the first line of its docstring, repeated here so that
#: ``graphcal methods`` can list them without importing them (a test keeps the two equal).
METHOD_SUMMARIES: dict[str, str] = {
    "ls": "Paper 003 LS (eq. 11-19) against ADS-B, every radar on its own.",
    "fl": "Paper 003 FL: line-fit azimuth bias, mean range (and elevation) difference.",
    "fl-ls": "Paper 003 FL-LS: FL azimuth compensation (eq. 10, sign corrected), then LS.",
    "wls": "Paper 001 WLS (eq. 8-11) over all radar pairs, no ADS-B needed.",
    "wls-pruned": "Paper 001 greedy pruning (eq. 12), then WLS (eq. 10) on the kept "
    "observations.",
    "graph": "Joint calibration of every radar with a GTSAM factor graph.",
}


class LazyEstimators(Mapping[str, Estimator]):
    """Estimators by name, each imported when first looked up: from its loader (a
    function that imports it) or its ``"module:function"`` path.

    Names, ``in``, ``len`` and iteration over the names import nothing; ``[name]``,
    ``.get``, ``.values()`` and ``.items()`` import the estimators they return (once).
    """

    def __init__(self, paths: Mapping[str, str | Callable[[], Estimator]]) -> None:
        self._paths = dict(paths)
        self._loaded: dict[str, Estimator] = {}

    def __getitem__(self, name: str) -> Estimator:
        try:
            return self._loaded[name]
        except KeyError:
            pass
        where = self._paths[name]
        if callable(where):
            estimator = where()
        else:
            module, _, function = where.partition(":")
            estimator = getattr(importlib.import_module(module), function)
        self._loaded[name] = estimator
        return estimator

    def __contains__(self, name: object) -> bool:
        return name in self._paths

    def __iter__(self) -> Iterator[str]:
        return iter(self._paths)

    def __len__(self) -> int:
        return len(self._paths)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self._paths!r})"


#: Registered estimators by their command-line name.
METHODS: Mapping[str, Estimator] = LazyEstimators(ESTIMATOR_LOADERS)

#: Methods of the contract that are planned but not available in this version.
PLANNED_METHODS: tuple[str, ...] = ()


def _unavailable(method: str) -> ValueError:
    available = ", ".join(METHODS)
    if method in PLANNED_METHODS:
        return ValueError(
            f"method '{method}' is not available in this version; use one of: {available}"
        )
    return ValueError(f"unknown method '{method}'; use one of: {available}")


def get_estimator(method: str) -> Estimator:
    """The estimator registered as ``method`` (imported now if it was not yet).

    Raises
    ------
    ValueError
        For an unknown or not yet available method, listing the available ones.
    """
    if method in METHODS:
        return METHODS[method]
    raise _unavailable(method)


def describe(method: str) -> str:
    """One line on the estimator ``method``, without importing it.

    Raises
    ------
    ValueError
        For an unknown or not yet available method, listing the available ones.
    """
    if method in METHOD_SUMMARIES:
        return METHOD_SUMMARIES[method]
    raise _unavailable(method)


def solve(problem: Problem, method: str = "graph", options: SolveOptions | None = None,
          **run: Any) -> Calibration:
    """Solve ``problem`` with the estimator ``method``.

    Parameters
    ----------
    problem : Problem
        :func:`graphcal.model.problem.build_problem`'s result.
    method : str
        A name of :data:`METHODS`.
    options : SolveOptions, optional
        The estimator's options (those it uses, :meth:`SolveOptions.for_method`);
        default: the problem's.
    **run
        How to run it, not what to estimate: ``progress`` (graph, wls), ``bound``
        (graph).
    """
    options = problem.options if options is None else options
    return get_estimator(method)(problem, **options.for_method(method), **run)


def calibrate(dataset: Dataset, method: str, **options: Any) -> Calibration:
    """Run the estimator ``method`` on ``dataset``."""
    return get_estimator(method)(dataset, **options)


__all__ = ["ESTIMATOR_LOADERS", "ESTIMATOR_PATHS", "METHODS", "METHOD_SUMMARIES",
           "PLANNED_METHODS", "Estimator", "LazyEstimators", "calibrate", "describe",
           "get_estimator", "solve"]
