"""``graphcal methods`` and the estimator registry it reads without importing the estimators."""

from __future__ import annotations

import importlib
import inspect
import io

import pytest
from rich.console import Console
from typer.testing import CliRunner

from graphcal.cli import methods as methods_cli
from graphcal.cli.app import app
from graphcal.solvers.registry import (
    ESTIMATOR_LOADERS,
    ESTIMATOR_PATHS,
    METHOD_SUMMARIES,
    METHODS,
    LazyEstimators,
    describe,
    get_estimator,
)

runner = CliRunner()

NAMES = ["ls", "fl", "fl-ls", "wls", "wls-pruned", "graph"]


def _first_doc_line(function) -> str:
    return inspect.getdoc(function).splitlines()[0]


def test_every_estimator_has_a_path_and_a_summary() -> None:
    assert list(METHODS) == NAMES
    assert list(ESTIMATOR_PATHS) == NAMES
    assert list(ESTIMATOR_LOADERS) == NAMES
    assert list(METHOD_SUMMARIES) == NAMES


@pytest.mark.parametrize("name", NAMES)
def test_each_loader_imports_the_function_its_path_names(name: str) -> None:
    module, _, function = ESTIMATOR_PATHS[name].partition(":")
    assert ESTIMATOR_LOADERS[name]() is getattr(importlib.import_module(module), function)
    assert METHODS[name] is ESTIMATOR_LOADERS[name]()


@pytest.mark.parametrize("name", NAMES)
def test_summary_is_the_first_line_of_the_estimator_docstring(name: str) -> None:
    """The registry repeats these lines so that ``graphcal methods`` imports no estimator;
    when an estimator's docstring changes, change METHOD_SUMMARIES with it."""
    assert describe(name) == _first_doc_line(METHODS[name])


def test_methods_command_prints_one_line_per_estimator(monkeypatch: pytest.MonkeyPatch) -> None:
    # A wide terminal: one line each, unwrapped (at 80 columns the summaries wrap).
    monkeypatch.setattr(methods_cli, "console", Console(width=200, file=io.StringIO()))
    result = runner.invoke(app, ["methods"])
    result_output = methods_cli.console.file.getvalue()
    assert result.exit_code == 0
    assert result_output.splitlines() == [
        f"{name:12s} {_first_doc_line(function)}" for name, function in METHODS.items()
    ]


def test_lazy_mapping_reads_like_a_dict() -> None:
    methods = LazyEstimators({"ls": "graphcal.solvers.adsb_reference:ls"})
    assert "ls" in methods and "graph" not in methods and 3 not in methods
    assert len(methods) == 1 and list(methods) == ["ls"]
    assert methods["ls"] is get_estimator("ls")
    assert dict(methods.items()) == {"ls": METHODS["ls"]}
    assert methods.get("graph") is None
    with pytest.raises(KeyError):
        methods["graph"]


@pytest.mark.parametrize("lookup", [get_estimator, describe])
def test_unknown_method_names_the_available_ones(lookup) -> None:
    with pytest.raises(ValueError, match="unknown method 'magic'; use one of: ls, fl, fl-ls"):
        lookup("magic")
