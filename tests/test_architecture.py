"""The package's architecture: layers (import-linter, ``make lint``) and private names.

import-linter checks that every subpackage imports only from the layers below
it (the contracts in pyproject.toml).  This test checks what it does not: that
no module imports another module's private (``_leading_underscore``) names, and
that every subpackage named in the layers contract exists.
"""

from __future__ import annotations

import ast
import tomllib

import pytest

from tests.paths import ROOT

PACKAGE = ROOT / "graphcal"


def _private_imports(path, root=ROOT) -> list[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if not node.module.startswith(("graphcal", "tests")):
                continue
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__"):
                    found.append(f"{path.relative_to(root)}:{node.lineno}: "
                                 f"from {node.module} import {alias.name}")
    return found


@pytest.mark.parametrize("folder", ["graphcal", "tests", "benchmarks"])
def test_no_module_imports_another_modules_private_names(folder: str) -> None:
    found = [line for path in sorted((ROOT / folder).rglob("*.py"))
             for line in _private_imports(path)]
    assert found == [], "\n".join(found)


def test_the_checker_finds_a_private_import(tmp_path) -> None:
    sample = tmp_path / "sample.py"
    sample.write_text("from graphcal.solvers.graph import _hidden, visible\nfrom os import _exit\n")
    assert _private_imports(sample, tmp_path) == [
        "sample.py:1: from graphcal.solvers.graph import _hidden"
    ]


def test_every_layer_of_the_contract_is_a_subpackage() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    contracts = config["tool"]["importlinter"]["contracts"]
    top = next(c for c in contracts if "containers" not in c)
    layers = [name.strip() for layer in top["layers"] for name in layer.split("|")]
    subpackages = {f"graphcal.{p.parent.name}" for p in PACKAGE.glob("*/__init__.py")}
    assert set(layers) == subpackages
