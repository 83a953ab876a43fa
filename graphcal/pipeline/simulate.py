"""Simulate a scenario for the Python API: a path or a scenario, a seed or a generator."""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from graphcal.simulation.scenario import Scenario, load_scenario
from graphcal.simulation.simulate import SimulationResult
from graphcal.simulation.simulate import simulate as simulate_scenario


def simulate(
    scenario: Scenario | str | os.PathLike[str],
    rng: np.random.Generator | None = None,
    *,
    seed: int | None = None,
    progress: Callable[..., None] | None = None,
) -> SimulationResult:
    """Simulate the radar plots and ADS-B reports of a scenario.

    Parameters
    ----------
    scenario : Scenario or path
        A scenario, or its TOML file (read with
        :func:`graphcal.simulation.scenario.load_scenario`).
    rng : numpy.random.Generator, optional
        The source of randomness.  Give either ``rng`` or ``seed``.
    seed : int, optional
        Seed of ``numpy.random.default_rng`` when no ``rng`` is given.
    progress : callable, optional
        ``progress(stage, done, total)``.

    Returns
    -------
    SimulationResult
        ``.dataset`` (a :class:`~graphcal.data.dataset.Dataset`) and ``.truth``
        (the true biases per radar), with the true positions behind every plot.

    Raises
    ------
    ValueError
        If both or neither of ``rng`` and ``seed`` are given, or ``seed`` is negative.
    """
    if (rng is None) == (seed is None):
        raise ValueError("give exactly one of rng (a numpy Generator) and seed (an int)")
    if rng is None:
        if not isinstance(seed, int | np.integer) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, not {seed!r}")
        rng = np.random.default_rng(seed)
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    return simulate_scenario(scenario, rng, progress=progress)
