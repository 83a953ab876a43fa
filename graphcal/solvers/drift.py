"""How a radar's biases move from window to window: random-walk rates and steps.

The windows' *independent* estimates ``y_k`` of one bias term (each from its own
window's data, variance ``R_k``) are modelled as a random walk seen through noise::

    x_k = x_{k-1} + w_k,   w_k ~ N(0, q^2 (t_k - t_{k-1})),   y_k = x_k + v_k,  v_k ~ N(0, R_k)

with ``t_k`` the windows' middles and ``q`` the term's rate [unit per sqrt(s)].  A
Kalman filter over the chain gives the innovations ``nu_k`` (variance ``S_k``) and
the log-likelihood ``log L(q) = -1/2 sum (log S_k + nu_k^2 / S_k)``; the first
window of a chain (or of a segment after a step) starts the filter and adds no
term (a diffuse start).

* **Rates.**  ``q`` maximises the likelihood (a grid over ``log q``), 0 when the
  windows agree within their noise.
* **Steps.**  A step between windows ``j`` and ``j + 1`` cuts the chain there into
  two segments that share ``q``; the step's size, profiled out, explains window
  ``j + 1``'s innovation (which leaves its ``1/2 log S``) and the second segment
  restarts from that window.  A step inside window ``j`` isolates it (cuts on both
  sides; its mean lies between its neighbours').  The likelihood ratio of a
  candidate, ``2 (log L_step - log L)`` at the rate that fits best with the step
  (the rate the rest of the chain shows: a random walk free to take any rate
  explains any one jump), is about chi-square with 1 (a cut) or 2 (an isolated
  window) degrees of freedom, term by term.  The most significant candidate over
  the terms and links is a step when its p-value is below ``false_alarm`` split
  over the candidates (Bonferroni: the chance of one false step per radar and
  recording is at most ``false_alarm``); then the segments are searched again
  (binary segmentation).

Every log-likelihood is computed for all grid rates at once, and the cut at each
link from a forward and a backward pass over its segment (the likelihood of a
segment is the same in either direction), so one search costs ``O(n_windows)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy import special

FloatArray = NDArray[np.float64]

#: Chance of one false step per radar and recording (before the Bonferroni split over links).
DEFAULT_STEP_FALSE_ALARM = 1e-3

#: Points of the rate grid (log-spaced).
RATE_GRID_POINTS = 80


def _cumulative_nll(t: FloatArray, y: FloatArray, r: FloatArray, q2: FloatArray
                    ) -> tuple[FloatArray, FloatArray]:
    """Negative log-likelihood of ``y[0..k]`` for every ``k`` and every grid ``q^2``.

    Returns two arrays ``(len(y), len(q2))``: the cumulative values (row 0 is 0,
    the diffuse start) and ``1/2 log S_k`` of each step's innovation (row 0: 0).
    """
    n = len(y)
    out = np.zeros((n, len(q2)))
    half_log_s = np.zeros((n, len(q2)))
    x = np.full(len(q2), y[0])
    p = np.full(len(q2), r[0])
    for k in range(1, n):
        p_pred = p + q2 * abs(t[k] - t[k - 1])
        s = p_pred + r[k]
        nu = y[k] - x
        half_log_s[k] = 0.5 * np.log(s)
        out[k] = out[k - 1] + half_log_s[k] + 0.5 * nu * nu / s
        gain = p_pred / s
        x = x + gain * nu
        p = (1.0 - gain) * p_pred
    return out, half_log_s


@dataclass
class _Segment:
    """One term's windows between two cuts, with their cumulative likelihoods."""

    rows: NDArray[np.int64]  # window numbers (the term's finite windows only)
    forward: FloatArray  # (len(rows), Q): nll of the first i + 1 entries
    backward: FloatArray  # (len(rows), Q): nll of the entries from i on
    half_log_s: FloatArray  # (len(rows), Q): 1/2 log S of entry i's forward innovation

    @property
    def total(self) -> FloatArray:
        return self.forward[-1]


def _segment(t: FloatArray, y: FloatArray, r: FloatArray, q2: FloatArray,
             rows: NDArray[np.int64]) -> _Segment:
    forward, half_log_s = _cumulative_nll(t[rows], y[rows], r[rows], q2)
    back = rows[::-1]
    backward = _cumulative_nll(t[back], y[back], r[back], q2)[0][::-1]
    return _Segment(rows, forward, backward, half_log_s)


def rate_grid(t: FloatArray, y: FloatArray, r: FloatArray) -> FloatArray:
    """Grid of rates ``q`` [unit per sqrt(s)]: 0, then from far below the noise to
    far above the spread of the estimates (log-spaced)."""
    dt = np.diff(t)
    dt = dt[dt > 0]
    if len(dt) == 0:
        return np.zeros(1)
    scale = np.sqrt(np.median(r) / np.median(dt))
    spread = np.sqrt(np.max(np.diff(y) ** 2 / np.maximum(np.diff(t), 1e-9))
                     + np.median(r) / np.median(dt))
    return np.concatenate([[0.0], np.geomspace(1e-4 * scale, 10.0 * max(spread, scale),
                                               RATE_GRID_POINTS - 1)])


@dataclass
class ChainAnalysis:
    """One radar's chain: rates per term, and the links cut by steps.

    Attributes
    ----------
    rates : ndarray
        Random-walk rate of each term [SI unit per sqrt(s)] (given or estimated).
    cuts : list of int
        Links ``j`` (between windows ``j`` and ``j + 1``) where a step was found
        or declared, in increasing order.
    statistics : dict
        The likelihood-ratio statistic of each cut found (declared cuts: absent).
    threshold : float
        The p-value a step had to be below (the false-alarm rate split over the
        candidates).
    """

    rates: FloatArray
    cuts: list[int] = field(default_factory=list)
    statistics: dict[int, float] = field(default_factory=dict)
    threshold: float = np.inf


def _ratio(without: FloatArray, with_step: FloatArray) -> float:
    """``2 (nll without - nll with the step)`` at the rate that fits best with the step.

    Not profiled separately under each hypothesis: a random walk with a rate large
    enough can explain any one jump, so the rate is the one the rest of the chain
    shows, and the jump is judged against it.
    """
    best = int(np.argmin(with_step))
    return float(2.0 * (without[best] - with_step[best]))


def _chi2_sf(statistic: float, dof: int) -> float:
    """``P(chi2_dof > statistic)``; 1 for a statistic at or below zero (a ratio of
    likelihoods that rounding made slightly negative).  ``scipy.special.chdtrc``, not
    scipy.stats, whose import costs a second."""
    return float(special.chdtrc(dof, max(float(statistic), 0.0)))


def _best_step(segments_of, t: FloatArray, r: FloatArray, grids: list[FloatArray], m: int,
               n: int, cuts: list[int]) -> tuple[float, list[int], float] | None:
    """The most significant step candidate: ``(p-value, links to cut, statistic)``.

    For each term and each segment, a cut after entry ``i`` (1 degree of freedom:
    the step's size) and, for an interior entry, the entry isolated by cuts on
    both sides (2 degrees of freedom: a step inside that window, whose mean then
    lies between its neighbours').
    """
    best: tuple[float, list[int], float] | None = None
    for term in range(m):
        segs = segments_of(term, cuts)
        if not segs:
            continue
        q2 = grids[term] ** 2
        totals = np.sum([s.total for s in segs], axis=0)
        for seg in segs:
            others = totals - seg.total
            rows = seg.rows
            for i in range(len(rows) - 1):
                # The step profiled out: entry i + 1's innovation is explained by it,
                # which leaves its 1/2 log S; the rest restarts from that entry.
                cut = others + seg.forward[i] + seg.half_log_s[i + 1] + seg.backward[i + 1]
                statistic = _ratio(totals, cut)
                candidate = (_chi2_sf(statistic, 1), [int(rows[i])], statistic)
                if best is None or candidate[0] < best[0]:
                    best = candidate
                if i == 0:
                    continue
                # Entry i isolated: its own innovation and the next one's (predicted
                # from entry i alone) explained by the step.
                a, k, b = rows[i - 1], rows[i], rows[i + 1]
                next_s = r[k, term] + q2 * (t[b] - t[k]) + r[b, term]
                alone = (others + seg.forward[i - 1] + seg.half_log_s[i]
                         + 0.5 * np.log(next_s) + seg.backward[i + 1])
                statistic = _ratio(totals, alone)
                candidate = (_chi2_sf(statistic, 2), [int(a), int(k)], statistic)
                if candidate[0] < best[0]:
                    best = candidate
    return best


def _finite_chain(y: FloatArray, r: FloatArray) -> NDArray[np.bool_]:
    return np.isfinite(y) & np.isfinite(r) & (r > 0)


def analyse_chain(
    time_s: FloatArray,
    estimates: FloatArray,
    variances: FloatArray,
    *,
    given_rates: FloatArray | None = None,
    declared_cuts: list[int] | tuple[int, ...] = (),
    detect_steps: bool = True,
    false_alarm: float = DEFAULT_STEP_FALSE_ALARM,
) -> ChainAnalysis:
    """Rates and steps of one radar's chain of window estimates (module docstring).

    Parameters
    ----------
    time_s : ndarray, shape (n,)
        Middle of each window [s], increasing.
    estimates, variances : ndarray, shape (n, m)
        Each window's independent estimate of each of the radar's ``m`` terms and its
        variance (SI).  A term a window does not determine has a non-finite value or
        variance and is left out of that term's chain.
    given_rates : ndarray, shape (m,), optional
        Rates to use instead of estimating them (``nan`` = estimate that term's).
    declared_cuts : sequence of int
        Links known to be cut (a declared maintenance time).
    detect_steps : bool
        Search for steps beyond the random walk.
    false_alarm : float
        Chance of one false step per radar and recording.

    Returns
    -------
    ChainAnalysis
    """
    t = np.asarray(time_s, dtype=float)
    y = np.atleast_2d(np.asarray(estimates, dtype=float).T).T
    r = np.atleast_2d(np.asarray(variances, dtype=float).T).T
    n, m = y.shape
    given = np.full(m, np.nan) if given_rates is None else np.asarray(given_rates, float)
    grids = []
    for j in range(m):
        ok = _finite_chain(y[:, j], r[:, j])
        if np.isfinite(given[j]):
            grids.append(np.array([given[j]]))
        elif ok.sum() >= 3:
            grids.append(rate_grid(t[ok], y[ok, j], r[ok, j]))
        else:
            grids.append(np.zeros(1))
    cuts = sorted({int(c) for c in declared_cuts if 0 <= c < n - 1})
    analysis = ChainAnalysis(np.zeros(m), list(cuts))
    n_links = max(n - 1, 1)
    # Candidates: a cut at each link, and a window isolated (a step inside it); each
    # tested term by term.  ``threshold`` is the p-value a step must beat.
    analysis.threshold = false_alarm / (m * (2 * n_links - 1))

    def segments_of(term: int, boundaries: list[int]) -> list[_Segment]:
        """The term's segments (its finite windows) between the cuts."""
        ok = _finite_chain(y[:, term], r[:, term])
        edges = [0, *[c + 1 for c in boundaries], n]
        return [_segment(t, y[:, term], r[:, term], grids[term] ** 2, rows)
                for a, b in zip(edges, edges[1:], strict=False)
                if len(rows := np.flatnonzero(ok[a:b]) + a)]

    while detect_steps and n >= 3:
        found = _best_step(segments_of, t, r, grids, m, n, analysis.cuts)
        if found is None or found[0] > analysis.threshold:
            break
        _, new_cuts, statistic = found
        analysis.cuts = sorted({*analysis.cuts, *new_cuts})
        for c in new_cuts:
            analysis.statistics[c] = statistic
    for term in range(m):
        segs = segments_of(term, analysis.cuts)
        if not segs:
            continue
        totals = np.sum([s.total for s in segs], axis=0)
        analysis.rates[term] = float(grids[term][int(np.argmin(totals))])
    return analysis


def random_walk_rate(time_s: FloatArray, estimate: FloatArray, variance: FloatArray) -> float:
    """Maximum-likelihood random-walk rate ``q`` [unit per sqrt(s)] of one term's chain.

    The windows' independent estimates and their variances; 0 when the windows agree
    within their noise (a constant bias).  See the module docstring.
    """
    found = analyse_chain(time_s, np.asarray(estimate, float)[:, None],
                          np.asarray(variance, float)[:, None], detect_steps=False)
    return float(found.rates[0])


__all__ = ["DEFAULT_STEP_FALSE_ALARM", "ChainAnalysis", "analyse_chain", "random_walk_rate",
           "rate_grid"]
