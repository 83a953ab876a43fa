"""Fixtures shared by several test modules: the demo network simulated once per session.

Tests must not change these in place (copy a table before editing it); a module that
needs another dataset defines its own fixture of the same name, which wins.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import graphcal
from graphcal.io.folder import write_dataset
from tests.paths import SCENARIOS


@pytest.fixture(scope="session")
def demo() -> graphcal.Dataset:
    """``scenarios/demo_network.toml`` simulated with seed 1 (5 radars, ADS-B)."""
    return graphcal.simulate(SCENARIOS / "demo_network.toml", seed=1).dataset


@pytest.fixture(scope="session")
def demo_dir(demo, tmp_path_factory) -> Path:
    """:func:`demo` written as a dataset folder (read-only for the tests)."""
    folder = tmp_path_factory.mktemp("demo") / "demo"
    write_dataset(demo, folder)
    return folder
