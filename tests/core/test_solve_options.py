"""The one option table: every estimator takes the options it is given, with the same
defaults, and the command line's flags are the table's."""

from __future__ import annotations

import dataclasses
import inspect

import pytest
import typer

from graphcal.cli.app import app
from graphcal.core.solve_options import (
    ALL_METHODS,
    GRAPH,
    WLS,
    SolveOptions,
    option_flag,
    options_of,
)
from graphcal.solvers.registry import METHODS

FIELDS = [f.name for f in dataclasses.fields(SolveOptions)]


@pytest.mark.parametrize("method", ALL_METHODS)
def test_every_estimator_takes_its_options_with_the_tables_defaults(method: str) -> None:
    parameters = inspect.signature(METHODS[method]).parameters
    for name, value in SolveOptions().for_method(method).items():
        assert name in parameters, (method, name)
        default = parameters[name].default
        if name == "fixed":  # None in the signature: no term fixed
            assert default is None and value == {}
        else:
            assert default == value, (method, name)


def test_options_given_to_an_estimator_are_its_own() -> None:
    options = SolveOptions(cross="pairwise", iterations=3, max_gap_s=5.0)
    assert options.for_method("wls") == {"iterations": 3, "linearise": "plots",
                                         "max_gap_s": 5.0}
    assert options.for_method("ls") == {"max_gap_s": 5.0}
    graph = options.for_method("graph")
    assert graph["cross"] == "pairwise" and "iterations" not in graph
    # None means the estimator's own default: not passed.
    assert "max_gap_s" not in SolveOptions().for_method("ls")
    assert SolveOptions().adsb_max_gap_s == 10.0


def test_the_command_lines_flags_are_the_tables() -> None:
    command = typer.main.get_command(app).commands["calibrate"]
    flags = {opt for p in command.params for opt in (*p.opts, *p.secondary_opts)}
    params = {p.name for p in command.params}
    for name in FIELDS:
        flag = option_flag(name)
        if flag is None:
            continue
        for one in flag.split("/"):
            assert one in flags, (name, one)
    for table in (options_of(GRAPH), options_of(WLS)):
        assert set(table) <= params
    assert options_of(WLS) == {"iterations": "--iterations", "linearise": "--linearise"}
