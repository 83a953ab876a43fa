"""``graphcal calibrate``: options checked against each other before any data is read.

An option the chosen method (or the absence of ``--select``, ``--window``, ``--report``)
leaves unused is refused with exit status 2 and a line saying why, instead of being
ignored: ``--method ls --no-adsb`` (ls estimates against ADS-B), ``--budget`` without
``--select``, ``--robust`` with ``wls``, ...  A value outside an option's choices is
refused the same way.  An option counts as given when it is on the command line (or in
the environment), even at its default value.

A leaf beside :mod:`graphcal.cli.common`: no numpy, so that ``graphcal --help`` stays quick;
the choices are repeated here from the modules that own them (a test keeps them equal).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import typer

from graphcal.cli.common import EXIT_BAD_INPUT, check_choice, check_count, check_positive, fail
from graphcal.core.solve_options import GRAPH, WLS, options_of

#: Estimators (:data:`graphcal.solvers.registry.METHODS`).
METHOD_CHOICES: tuple[str, ...] = ("graph", "ls", "fl", "fl-ls", "wls", "wls-pruned")
#: Methods that estimate each radar against ADS-B and need it.
ADSB_METHODS: tuple[str, ...] = ("ls", "fl", "fl-ls")
#: Methods that use the radars' common observations only.
CROSS_RADAR_METHODS: tuple[str, ...] = ("wls", "wls-pruned")
#: ``--cross`` (:data:`graphcal.model.factor_set.CROSS_MODES`).
CROSS_CHOICES: tuple[str, ...] = ("trajectory", "pairwise", "target-state", "none")
#: ``--robust`` (:data:`graphcal.model.robust.KERNELS`).
ROBUST_CHOICES: tuple[str, ...] = ("huber", "cauchy", "none")
#: ``--init``: automatic, zero, or a closed-form method.
INIT_CHOICES: tuple[str, ...] = ("auto", "zero", "ls", "fl", "fl-ls", "wls", "wls-pruned")
#: ``--time-offset`` (:data:`graphcal.pipeline.calibrate.TIME_OFFSET_CHOICES`).
TIME_OFFSET_CHOICES: tuple[str, ...] = ("auto", "on", "off")
#: ``--linearise`` (:data:`graphcal.model.cross_radar.LINEARISE_CHOICES`).
LINEARISE_CHOICES: tuple[str, ...] = ("plots", "neighbours")
#: ``--select`` (:data:`graphcal.analysis.selection.SELECTION_METHODS`).
SELECT_CHOICES: tuple[str, ...] = ("greedy", "e-optimal", "d-optimal", "random")
#: ``--select-unit`` (:data:`graphcal.analysis.selection.SELECTION_UNITS`).
SELECT_UNIT_CHOICES: tuple[str, ...] = ("observation", "segment", "track")

#: Options of the graph method only: parameter name -> option (from the one option table,
#: :class:`graphcal.core.solve_options.SolveOptions`).  ``--adsb/--no-adsb`` is checked on
#: its own (:func:`_check_adsb`), with what each method does with ADS-B.
GRAPH_OPTIONS: dict[str, str] = {name: flag for name, flag in options_of(GRAPH).items()
                                 if name != "adsb"}
#: Options of wls and wls-pruned only.
WLS_OPTIONS: dict[str, str] = options_of(WLS)
#: Options of ``--select`` only.
SELECT_OPTIONS: dict[str, str] = {
    "budget": "--budget", "select_unit": "--select-unit", "segment_s": "--segment-s",
    "select_seed": "--select-seed",
}
#: Options of ``--window`` only.
WINDOW_OPTIONS: dict[str, str] = {
    "drift": "--drift", "breaks": "--break", "steps": "--steps/--no-steps",
    "scheduler": "--scheduler",
}


def _given(ctx: typer.Context, name: str) -> bool:
    """The user gave parameter ``name`` (command line or environment), even at its default."""
    source = ctx.get_parameter_source(name)
    return getattr(source, "name", None) in ("COMMANDLINE", "ENVIRONMENT")


def check_calibrate_options(ctx: typer.Context) -> None:
    """Refuse (exit 2) an option value outside its choices or an option left unused.

    Parameters
    ----------
    ctx : typer.Context
        The ``calibrate`` command's context: its parameter values and where each came from.
    """
    params: Mapping[str, Any] = ctx.params
    method = params.get("method") or "graph"
    if method not in METHOD_CHOICES:
        check_choice(method, "--method", METHOD_CHOICES, "method")
    for name, option, choices, what in (
        ("cross", "--cross", CROSS_CHOICES, "cross-radar mode"),
        ("robust", "--robust", ROBUST_CHOICES, "robust kernel"),
        ("init", "--init", INIT_CHOICES, "initialisation"),
        ("linearise", "--linearise", LINEARISE_CHOICES, "choice"),
        ("select", "--select", SELECT_CHOICES, "selection method"),
        ("select_unit", "--select-unit", SELECT_UNIT_CHOICES, "selection unit"),
    ):
        check_choice(params.get(name), option, choices, what)
    if params.get("time_offset") not in TIME_OFFSET_CHOICES:
        fail(f"--time-offset must be auto, on or off, not '{params.get('time_offset')}'",
             EXIT_BAD_INPUT)
    check_numbers(params)
    _check_adsb(ctx, method)
    _check_method_options(ctx, method)
    _check_selection(ctx, method)
    _check_window(ctx, method)
    if (params.get("robust") == "none" and _given(ctx, "robust_scale")
            and method == "graph"):
        fail("--robust-scale scales a robust kernel's threshold; with --robust none there "
             "is none", EXIT_BAD_INPUT)
    if (_given(ctx, "truth") and params.get("out") is not None
            and params.get("report") is None):
        fail("--truth is compared in the printed table and in --report; with --out alone "
             "it is not used", EXIT_BAD_INPUT)


#: Numeric options that must be a positive, finite number: parameter -> (option, what).
POSITIVE_OPTIONS: dict[str, tuple[str, str]] = {
    "max_gap_s": ("--max-gap-s", "a positive number of seconds"),
    "segment_s": ("--segment-s", "a positive number of seconds"),
    "robust_scale": ("--robust-scale", "a positive, finite factor"),
}
#: Integer options that must be at least 1: parameter -> option.
COUNT_OPTIONS: dict[str, str] = {
    "iterations": "--iterations", "max_iterations": "--max-iterations", "budget": "--budget",
}


def check_numbers(params: Mapping[str, Any]) -> None:
    """Refuse (exit 2) numeric options out of their domain (:data:`POSITIVE_OPTIONS`,
    :data:`COUNT_OPTIONS`), whether or not the method uses them."""
    for name, (option, what) in POSITIVE_OPTIONS.items():
        check_positive(params.get(name), option, what)
    for name, option in COUNT_OPTIONS.items():
        check_count(params.get(name), option, "at least 1")


def _check_adsb(ctx: typer.Context, method: str) -> None:
    if not _given(ctx, "adsb"):
        return
    if not ctx.params.get("adsb") and method in ADSB_METHODS:
        fail(f"--no-adsb: {method} estimates each radar against ADS-B and needs it; for "
             "the radars' common observations only use --method graph or wls",
             EXIT_BAD_INPUT)
    if method in CROSS_RADAR_METHODS:
        flag = "--adsb" if ctx.params.get("adsb") else "--no-adsb"
        fail(f"{flag}: {method} uses only the radars' common observations, never ADS-B; "
             "drop the option, or use --method graph to choose", EXIT_BAD_INPUT)


def _check_method_options(ctx: typer.Context, method: str) -> None:
    for names, owners in ((GRAPH_OPTIONS, ("graph",)), (WLS_OPTIONS, CROSS_RADAR_METHODS)):
        if method in owners:
            continue
        for name, option in names.items():
            if _given(ctx, name):
                fail(f"{option} applies to {' and '.join(owners)}; {method} does not use it",
                     EXIT_BAD_INPUT)


def _check_selection(ctx: typer.Context, method: str) -> None:
    select = ctx.params.get("select")
    if select is None:
        for name, option in SELECT_OPTIONS.items():
            if _given(ctx, name):
                fail(f"{option} applies to a selection: give --select "
                     f"{'|'.join(SELECT_CHOICES)} as well", EXIT_BAD_INPUT)
        return
    if method == "wls-pruned":
        fail("--select with wls-pruned would prune twice; use --method wls", EXIT_BAD_INPUT)
    if ctx.params.get("window") is not None:
        fail("--select is not available with --window: each window uses all its data",
             EXIT_BAD_INPUT)
    if select != "random" and _given(ctx, "select_seed"):
        fail(f"--select-seed seeds --select random; --select {select} draws nothing",
             EXIT_BAD_INPUT)
    if ctx.params.get("select_unit") != "segment" and _given(ctx, "segment_s"):
        fail(f"--segment-s applies to --select-unit segment, not "
             f"{ctx.params.get('select_unit')}", EXIT_BAD_INPUT)


def _check_window(ctx: typer.Context, method: str) -> None:
    if ctx.params.get("window") is None:
        for name, option in WINDOW_OPTIONS.items():
            if _given(ctx, name):
                fail(f"{option} applies to calibrations over time: give --window as well",
                     EXIT_BAD_INPUT)
        return
    if method != "graph":
        fail(f"--window calibrates with the graph method, not {method}", EXIT_BAD_INPUT)
    if ctx.params.get("report") is not None:
        fail("--report draws one batch of plots; with --window, write the result (--out) "
             "and run 'graphcal report' on it", EXIT_BAD_INPUT)
    for name, option, why in (
        ("init", "--init", "each window starts from its own closed-form estimate"),
        ("time_offset", "--time-offset", "time offsets are estimated in every window with "
         "ADS-B"),
        ("model_checks", "--model-checks", "the model checks are not run per window"),
    ):
        if _given(ctx, name) and not (name == "model_checks" and not ctx.params[name]):
            fail(f"{option} does not apply with --window: {why}", EXIT_BAD_INPUT)


__all__ = [
    "ADSB_METHODS",
    "CROSS_CHOICES",
    "CROSS_RADAR_METHODS",
    "GRAPH_OPTIONS",
    "INIT_CHOICES",
    "LINEARISE_CHOICES",
    "METHOD_CHOICES",
    "ROBUST_CHOICES",
    "SELECT_CHOICES",
    "SELECT_OPTIONS",
    "SELECT_UNIT_CHOICES",
    "TIME_OFFSET_CHOICES",
    "WINDOW_OPTIONS",
    "WLS_OPTIONS",
    "check_calibrate_options",
    "check_numbers",
]
