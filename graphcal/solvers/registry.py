"""Estimators: every one takes a :class:`~graphcal.data.dataset.Dataset` and returns a
:class:`~graphcal.data.calibration.Calibration`, so comparisons are a loop over names.

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

from collections.abc import Callable
from typing import Any

from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset
from graphcal.solvers.adsb_reference import fl, fl_ls, ls
from graphcal.solvers.graph import graph
from graphcal.solvers.wls import wls, wls_pruned

Estimator = Callable[..., Calibration]

#: Registered estimators by their command-line name.
METHODS: dict[str, Estimator] = {
    "ls": ls,
    "fl": fl,
    "fl-ls": fl_ls,
    "wls": wls,
    "wls-pruned": wls_pruned,
    "graph": graph,
}

#: Methods of the contract that are planned but not available in this version.
PLANNED_METHODS: tuple[str, ...] = ()


def get_estimator(method: str) -> Estimator:
    """The estimator registered as ``method``.

    Raises
    ------
    ValueError
        For an unknown or not yet available method, listing the available ones.
    """
    if method in METHODS:
        return METHODS[method]
    available = ", ".join(METHODS)
    if method in PLANNED_METHODS:
        raise ValueError(
            f"method '{method}' is not available in this version; use one of: {available}"
        )
    raise ValueError(f"unknown method '{method}'; use one of: {available}")


def calibrate(dataset: Dataset, method: str, **options: Any) -> Calibration:
    """Run the estimator ``method`` on ``dataset``."""
    return get_estimator(method)(dataset, **options)
