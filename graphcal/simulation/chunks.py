"""Chunks of simulated time: the spans a long scenario is simulated in, one after the other.

A scenario of ``duration_s`` is cut at multiples of ``chunk_s`` of the *reported*
time (the time written in the tables): chunk ``k`` holds the plots and ADS-B reports
whose reported time lies in ``[edges[k], edges[k + 1])``, the first chunk open to the
left and the last to the right.  A radar with a time-stamping bias ``d`` reports a
plot of true time ``t`` at ``t + d``, so its true times in chunk ``k`` are
``[edges[k] - d, edges[k + 1] - d)``, always within the scenario's ``[0, duration_s]``
(closed at the end).  The chunks thus partition the plots and reports of the whole
scenario, and tables written chunk after chunk are in time order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class TimeSpan:
    """True times [s] ``[t0_s, t1_s)``, or ``[t0_s, t1_s]`` when ``closed``."""

    t0_s: float
    t1_s: float
    closed: bool

    def keep(self, time_s: NDArray[np.float64]) -> NDArray[np.float64]:
        """The times of ``time_s`` (all within ``[t0_s, t1_s]``) that belong to the span."""
        return time_s if self.closed else time_s[time_s < self.t1_s]


def chunk_edges(duration_s: float, chunk_s: float | None) -> list[float]:
    """Edges of the chunks in reported time [s] (module docstring).

    Parameters
    ----------
    duration_s : float
        The scenario's duration [s].
    chunk_s : float or None
        Chunk length [s]; ``None``: one chunk, the whole scenario.

    Returns
    -------
    list of float
        ``[-inf, chunk_s, 2 chunk_s, ..., inf]``: ``ceil(duration_s / chunk_s)``
        chunks (at least one).

    Raises
    ------
    ValueError
        If ``chunk_s`` is not a positive finite number.
    """
    if chunk_s is None:
        return [-math.inf, math.inf]
    if not (math.isfinite(chunk_s) and chunk_s > 0):
        raise ValueError(f"the chunk must be a positive duration, not {chunk_s} s")
    n = max(1, math.ceil(duration_s / chunk_s))
    return [-math.inf, *(k * chunk_s for k in range(1, n)), math.inf]


def true_span(edges: list[float], k: int, duration_s: float,
              time_offset_s: float = 0.0) -> TimeSpan:
    """The true times [s] of chunk ``k`` for a sensor whose clock is ``time_offset_s`` ahead."""
    lo, hi = edges[k] - time_offset_s, edges[k + 1] - time_offset_s
    return TimeSpan(max(0.0, lo), min(duration_s, hi), hi >= duration_s)


__all__ = ["TimeSpan", "chunk_edges", "true_span"]
