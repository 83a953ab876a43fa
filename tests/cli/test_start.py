"""The command line starts light: importing it, ``--help`` and ``methods`` load no heavy module.

Every command imports what it needs (numpy, pandas, the estimators and their gtsam, scipy,
cvxpy, matplotlib, the ASTERIX decoder) inside its function, so that ``graphcal --help`` and
``graphcal methods`` answer at once. These tests fail when a module-level import brings one
back; they check which modules are loaded, not how long it takes.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

#: Modules that must not be loaded before a command needs them (a name covers its submodules).
HEAVY = [
    "gtsam",
    "cvxpy",
    "matplotlib",
    "scipy.stats",
    "asterix",
    "graphcal.io.asterix",
    "numpy",
    "pandas",
    "scipy",
    "graphcal.solvers.graph",
    "graphcal.solvers.wls",
    "graphcal.solvers.adsb_reference",
]


def _loaded_after(code: str) -> set[str]:
    """The modules loaded by running ``code`` in a fresh interpreter."""
    script = (
        "import json, sys\n"
        f"{code}\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True,
                          text=True, check=True)
    return set(json.loads(done.stdout.splitlines()[-1]))


def _heavy(modules: set[str]) -> list[str]:
    """The entries of HEAVY of which ``modules`` holds the module or a submodule."""
    return [heavy for heavy in HEAVY
            if any(m == heavy or m.startswith(heavy + ".") for m in modules)]


def test_importing_the_app_loads_no_heavy_module() -> None:
    modules = _loaded_after("import graphcal.cli.app")
    assert "graphcal.cli.app" in modules
    assert _heavy(modules) == []


@pytest.mark.parametrize("args", [["--help"], ["methods"]])
def test_help_and_methods_load_no_heavy_module(args: list[str]) -> None:
    modules = _loaded_after(
        "from graphcal.cli.app import app\n"
        f"app({args!r}, standalone_mode=False)"
    )
    assert "graphcal.solvers.registry" in modules or args == ["--help"]
    assert _heavy(modules) == []


def test_heavy_modules_are_found_when_loaded() -> None:
    """The check itself works: a command's own imports do show up."""
    modules = _loaded_after("from graphcal.solvers.registry import METHODS\nMETHODS['graph']")
    assert {"gtsam", "graphcal.solvers.graph"} <= set(_heavy(modules))
