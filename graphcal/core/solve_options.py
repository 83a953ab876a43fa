"""The estimators' options: one table, read by the solvers, the pipeline and the command line.

:class:`SolveOptions` holds every option of every estimator with its default, and each
field's metadata says which command-line flag sets it and which estimators use it
(:func:`option_flag`, :func:`options_of`).  A new solver option is one field here and its
flag in ``graphcal calibrate``; the pipeline's per-method defaults
(:func:`method_defaults`), the command line's "this option is not for that method"
checks and the windows' options are derived from this table.

A leaf of the package (no numpy): the command line imports it before any data is read.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

#: Longest gap between two ADS-B reports that interpolation bridges [s] (every method).
DEFAULT_ADSB_MAX_GAP_S = 10.0

#: Estimators of the factor graph.
GRAPH = ("graph",)
#: Paper 001's cross-radar estimators.
WLS = ("wls", "wls-pruned")
#: Every estimator (:data:`graphcal.solvers.registry.METHODS`).
ALL_METHODS = ("graph", "ls", "fl", "fl-ls", "wls", "wls-pruned")


def _option(default: Any, flag: str | None, methods: tuple[str, ...], *,
            factory: Any = None, param: str | None = None, own_default: bool = False) -> Any:
    """A field of :class:`SolveOptions` with its flag, its estimators, the name of its
    ``graphcal calibrate`` parameter (when not the field's) and whether ``None`` means
    "the estimator's own default" (the option is then not passed)."""
    metadata = {"flag": flag, "methods": methods, "param": param, "own_default": own_default}
    if factory is not None:
        return field(default_factory=factory, metadata=metadata)
    return field(default=default, metadata=metadata)


@dataclass(frozen=True)
class SolveOptions:
    """Every estimator's options, with the command line's defaults.

    Attributes
    ----------
    cross : {"trajectory", "pairwise", "target-state", "none"}
        graph: how the radars are tied together (:data:`graphcal.model.factor_set.CROSS_MODES`).
    robust : {"huber", "cauchy", "none"}
        graph: the robust kernel of every measurement.
    robust_scale : float
        graph: multiple of the kernel's threshold.
    use_adsb : bool
        graph: use the ADS-B reports when the dataset has them.
    init : str
        graph: initial values, ``auto``, ``zero`` or a closed-form method.
    fixed : mapping
        graph: terms held at known values, ``{(radar_id, term): value SI}``.
    max_iterations : int
        graph: iteration limit.
    time_offset : bool or None
        graph: estimate the radars' time-stamping biases (``None``: where ADS-B determines
        them).
    iterations : int
        wls, wls-pruned: re-linearisations (1 = paper 001).
    linearise : {"plots", "neighbours"}
        wls, wls-pruned: where the Jacobians are evaluated.
    max_gap_s : float or None
        Every method: longest time gap bridged by interpolation [s]; None: each
        estimator's own (ADS-B :data:`DEFAULT_ADSB_MAX_GAP_S`, wls 2.5 scans).
    pair_max_gap_s : float or None
        graph, pairwise: longest gap between a radar's bracketing plots [s] (None: 2.5
        scans).  Not a command-line option.
    """

    cross: str = _option("trajectory", "--cross", GRAPH)
    robust: str = _option("huber", "--robust", GRAPH)
    robust_scale: float = _option(1.0, "--robust-scale", GRAPH)
    use_adsb: bool = _option(True, "--adsb/--no-adsb", GRAPH, param="adsb")
    init: str = _option("auto", "--init", GRAPH)
    fixed: Mapping[tuple[str, str], float] = _option(None, "--fix", GRAPH, factory=dict,
                                                     param="fix")
    max_iterations: int = _option(100, "--max-iterations", GRAPH)
    time_offset: bool | None = _option(None, "--time-offset", GRAPH)
    iterations: int = _option(1, "--iterations", WLS)
    linearise: str = _option("plots", "--linearise", WLS)
    max_gap_s: float | None = _option(None, "--max-gap-s", ALL_METHODS, own_default=True)
    pair_max_gap_s: float | None = _option(None, None, GRAPH, own_default=True)

    def for_method(self, method: str) -> dict[str, Any]:
        """The keyword arguments of estimator ``method``: the options it uses."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if method in f.metadata["methods"]
                and not (f.metadata["own_default"] and getattr(self, f.name) is None)}

    @property
    def adsb_max_gap_s(self) -> float:
        """The longest ADS-B gap bridged by interpolation [s]."""
        return DEFAULT_ADSB_MAX_GAP_S if self.max_gap_s is None else float(self.max_gap_s)

    def replace(self, **changes: Any) -> SolveOptions:
        """A copy with ``changes``."""
        return dataclasses.replace(self, **changes)


def options_of(methods: tuple[str, ...]) -> dict[str, str]:
    """Options used by ``methods`` and by no other: ``graphcal calibrate`` parameter -> flag.

    ``options_of(GRAPH)`` are graph's own options, ``options_of(WLS)`` those of paper
    001's estimators; options every method uses are in neither.
    """
    return {f.metadata["param"] or f.name: f.metadata["flag"]
            for f in dataclasses.fields(SolveOptions)
            if f.metadata["flag"] and tuple(f.metadata["methods"]) == methods}


def option_flag(name: str) -> str | None:
    """The command-line flag of option ``name`` (None: not on the command line)."""
    return {f.name: f.metadata["flag"] for f in dataclasses.fields(SolveOptions)}[name]


def option_methods(name: str) -> tuple[str, ...]:
    """The estimators that use option ``name``."""
    return {f.name: f.metadata["methods"] for f in dataclasses.fields(SolveOptions)}[name]


def method_defaults(method: str) -> dict[str, Any]:
    """The defaults of the options estimator ``method`` uses (command-line defaults)."""
    return SolveOptions().for_method(method)


__all__ = ["ALL_METHODS", "DEFAULT_ADSB_MAX_GAP_S", "GRAPH", "WLS", "SolveOptions",
           "method_defaults", "option_flag", "option_methods", "options_of"]
