"""Random-walk rates and steps of a chain of window estimates (graphcal.solvers.drift),
on synthetic chains whose truth is known: rates recovered, steps found where they are,
and no step on constant or linearly drifting chains."""

from __future__ import annotations

import numpy as np
import pytest

from graphcal.solvers.drift import analyse_chain

#: Per-window noise of four terms (range offset m, gain, azimuth rad, elevation rad).
NOISE = np.array([2.0, 1e-5, 1e-4, 1e-4])


@pytest.mark.parametrize("q_true", [0.5, 2.0])
def test_random_walk_rate_recovers_the_simulated_rate(q_true) -> None:
    """Chains of 40 windows: a random walk of rate q seen through noise of 10 units; the
    median over 40 chains of the maximum-likelihood rate is within 15 % of q."""
    from graphcal.solvers.drift import random_walk_rate

    rng = np.random.default_rng(0)
    t = np.arange(40) * 900.0
    rates = []
    for _ in range(40):
        x = np.cumsum(np.r_[0.0, rng.normal(0.0, q_true * np.sqrt(900.0), 39)])
        rates.append(random_walk_rate(t, x + rng.normal(0.0, 10.0, 40), np.full(40, 100.0)))
    assert np.median(rates) == pytest.approx(q_true, rel=0.15)


def test_random_walk_rate_of_a_constant_is_mostly_zero() -> None:
    from graphcal.solvers.drift import random_walk_rate

    rng = np.random.default_rng(1)
    t = np.arange(40) * 900.0
    rates = [random_walk_rate(t, rng.normal(5.0, 10.0, 40), np.full(40, 100.0))
             for _ in range(40)]
    assert np.mean(np.array(rates) == 0.0) > 0.5
    assert np.max(rates) < 0.2  # far below what 10 units of noise per window could hide


def _chain(rng, n, window_s=1800.0):
    t = np.arange(n) * window_s + window_s / 2
    return t, rng.normal(0.0, 1.0, (n, 4)) * NOISE, np.tile(NOISE**2, (n, 1))


def test_no_step_on_constant_or_linearly_drifting_chains() -> None:
    """200 constant chains and 100 drifting 1 mrad/h, 48 windows each: no step (the stated
    false-alarm rate is 0.1 % per chain, so one would be surprising)."""
    rng = np.random.default_rng(2)
    found = 0
    for k in range(300):
        t, y, v = _chain(rng, 48)
        if k >= 200:
            y[:, 2] += t / 3600.0 * 1e-3
        found += bool(analyse_chain(t, y, v).cuts)
    assert found == 0


def test_a_step_is_found_within_one_window_of_its_time() -> None:
    """A 20 m range step (10 sigma of one window) at a random time in 16 windows of 30 min;
    the window holding it has the mean of before and after in proportion.  In every one of
    60 chains it is found, and placed within one window of its time (a cut at one link
    places it on that boundary; two cuts isolating a window place it inside it)."""
    rng = np.random.default_rng(1)
    starts = np.arange(16) * 1800.0
    for _ in range(60):
        t, y, v = _chain(rng, 16)
        when = rng.uniform(3 * 1800.0, 13 * 1800.0)
        y[:, 0] += 20.0 * np.clip((starts + 1800.0 - when) / 1800.0, 0.0, 1.0)
        found = analyse_chain(t, y, v)
        assert found.cuts, when
        earliest, latest = 1800.0 * (min(found.cuts) + 1), 1800.0 * (max(found.cuts) + 1)
        assert earliest - 1800.0 <= when <= latest + 1800.0, (when, found.cuts)
        assert max(found.cuts) - min(found.cuts) <= 1


def test_declared_cuts_are_kept_and_rates_given_are_used() -> None:
    rng = np.random.default_rng(3)
    t, y, v = _chain(rng, 12)
    found = analyse_chain(t, y, v, declared_cuts=[5], given_rates=np.array([1.0, np.nan,
                                                                           np.nan, np.nan]))
    assert found.cuts == [5] and found.statistics == {}
    assert found.rates[0] == 1.0
