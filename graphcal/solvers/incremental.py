"""Calibrating while the data arrive: windows added one by one, the chain kept by iSAM2.

:class:`Calibrator` takes data as they come (a file appearing in a folder, a decoded
ASTERIX recording, a live feed cut into blocks), closes each time window once data
beyond its end have arrived, reduces it to its summary
(:func:`graphcal.solvers.windows.summarise_window`) and adds that summary to a chain
solved incrementally by GTSAM's ``ISAM2``: the same factors as the batch
:func:`graphcal.solvers.windows.smooth_windows` (summaries, random walks between a
radar's consecutive windows, a weak prior where a chain starts), but each new window
updates the smoothed estimate of every earlier one without solving again from the
start.

Differences from the batch, because the future is not known yet:

* the random-walk rates are the ones given, else
  :data:`graphcal.solvers.windows.DEFAULT_RANDOM_WALK_PER_SQRT_S` (the batch
  estimates them from the whole chain);
* a step is tested when its window arrives: each term's innovation (the window's
  own estimate against the chain's prediction from the windows before it) against
  chi-square with 1 degree of freedom at :data:`ONLINE_STEP_FALSE_ALARM_PER_WINDOW`
  per radar and window, term by term (Bonferroni).  A step found cuts the chain
  before the window and is reported at the window's start.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np
import pandas as pd
from scipy import special

from graphcal.data.bias import CONTRACT_KEYS
from graphcal.data.dataset import Dataset, Site
from graphcal.data.windows import DEFAULT_ADSB_MARGIN_S, Window, split_windows
from graphcal.model.parameters import TERM_NAMES, RadarTerms, prior_sigmas, radar_terms
from graphcal.solvers.gtsam_adapter import IncrementalGraph, symbol
from graphcal.solvers.windows import (
    DEFAULT_RANDOM_WALK_PER_SQRT_S,
    BiasEvent,
    WindowEstimate,
    WindowOptions,
    WindowSummary,
    chain_scale,
    embed_summary,
    random_walk_block,
    summarise_window,
    window_estimate,
)

FloatArray = np.ndarray

#: Chance of a false step per radar and window (0.1 % per radar over 50 windows).
ONLINE_STEP_FALSE_ALARM_PER_WINDOW = 2e-5


class _RadarChain:
    """One radar's variables in the incremental graph."""

    def __init__(self, radar_id: str, names: tuple[str, ...], prior: FloatArray,
                 rates: FloatArray, scale: FloatArray) -> None:
        self.radar_id = radar_id
        self.names = names
        self.prior = prior
        self.rates = rates
        self.scale = scale  # the variables are bias / scale (windows.chain_scale)
        self.keys: list[int] = []
        self.windows: list[WindowSummary] = []
        self.estimated: set[str] = set()


class Calibrator:
    """Windows as they arrive, the smoothed chain updated by iSAM2 (module docstring).

    Parameters
    ----------
    sites : mapping
        The radars' sites (every radar that may appear).
    window_s : float
        Window length [s]; windows are aligned on multiples of it.
    options : WindowOptions, optional
        How each window is calibrated.
    random_walk_per_sqrt_s : mapping, optional
        Rate per term name [SI per sqrt(s)]; the others are the defaults.
    detect_steps : bool
        Test each new window for a step.
    adsb_margin_s : float
        ADS-B kept beyond a window's ends; a window is closed once plots later than
        its end plus this margin have arrived.
    summarise : callable, optional
        ``(window, options) -> WindowSummary or None``, each window's calibration
        (default :func:`graphcal.solvers.windows.summarise_window`).  Plots without an
        address (contract v3) are used only by
        :func:`graphcal.pipeline.windowed.summarise_associated`, which associates them
        first; with the default they are left out, and :attr:`unaddressed_plots` counts
        them.

    Examples
    --------
    >>> calibrator = Calibrator(dataset.sites, 1800.0)          # doctest: +SKIP
    >>> for block in blocks:                                     # doctest: +SKIP
    ...     calibrator.add(block)
    ...     print(calibrator.current()["NORD"].bias)
    >>> calibrator.flush()                                       # doctest: +SKIP
    """

    def __init__(
        self,
        sites: Mapping[str, Site],
        window_s: float,
        *,
        options: WindowOptions | None = None,
        random_walk_per_sqrt_s: Mapping[str, float] | None = None,
        detect_steps: bool = True,
        adsb_margin_s: float = DEFAULT_ADSB_MARGIN_S,
        summarise: Callable[[Window, WindowOptions], WindowSummary | None] | None = None,
    ) -> None:
        if not (np.isfinite(window_s) and window_s > 0):
            raise ValueError(f"the window must be a positive duration, not {window_s} s")
        self.sites = dict(sites)
        self.window_s = float(window_s)
        self.options = options or WindowOptions()
        self.detect_steps = detect_steps
        self.adsb_margin_s = float(adsb_margin_s)
        self._summarise = summarise or summarise_window
        #: Plots without an address taken while windows are summarised by the default,
        #: which leaves them out (``summarise``).
        self.unaddressed_plots = 0
        self._rates = {**DEFAULT_RANDOM_WALK_PER_SQRT_S, **dict(random_walk_per_sqrt_s or {})}
        self._graph = IncrementalGraph()
        self._chains: dict[str, _RadarChain] = {}
        self._pending: Dataset | None = None
        self._closed_until_s = -np.inf
        self._counter = 0
        self.summaries: list[WindowSummary] = []
        self.events: list[BiasEvent] = []

    # ------------------------------------------------------------------ data in
    def add(self, data: Dataset) -> list[WindowSummary]:
        """Take new plots and ADS-B; summarise and add every window they close.

        Plots of a window already closed are refused (``ValueError``): data must
        arrive in time order, to within ``adsb_margin_s``.
        """
        plots = data.plots
        if self._summarise is summarise_window and "target_id" in plots:
            target = plots["target_id"]
            self.unaddressed_plots += int((target.isna() | target.astype(str).str.strip()
                                           .isin(["", "nan"])).sum())
        late = plots["time_s"].to_numpy(float) < self._closed_until_s
        if late.any():
            raise ValueError(
                f"{int(late.sum())} plots before {self._closed_until_s:.0f} s arrived after "
                "their window was closed; give the data in time order")
        if self._pending is None:
            self._pending = replace(data, cleaning=None)
        else:
            self._pending = replace(
                self._pending,
                plots=pd.concat([self._pending.plots, plots], ignore_index=True),
                adsb=_concat(self._pending.adsb, data.adsb))
        latest = float(self._pending.plots["time_s"].max())
        close_before = np.floor((latest - self.adsb_margin_s) / self.window_s) * self.window_s
        return self._close(close_before)

    def flush(self) -> list[WindowSummary]:
        """Summarise and add every window still open (at the end of the data)."""
        return self._close(np.inf)

    def _close(self, before_s: float) -> list[WindowSummary]:
        if self._pending is None or before_s <= self._closed_until_s:
            return []
        pending = self._pending
        times = pending.plots["time_s"].to_numpy(float)
        ready = times < before_s
        if not ready.any():
            return []
        closing = replace(pending, plots=pending.plots.loc[ready])
        added = []
        for window in split_windows(closing, self.window_s, self.adsb_margin_s):
            summary = self._summarise(window, self.options)
            if summary is not None:
                self.add_summary(summary)
                added.append(summary)
        self._closed_until_s = before_s
        keep_adsb = None
        if pending.adsb is not None:
            adsb_time = pending.adsb["time_s"].to_numpy(float)
            keep_adsb = pending.adsb.loc[adsb_time >= before_s - self.adsb_margin_s]
        self._pending = replace(pending, plots=pending.plots.loc[~ready], adsb=keep_adsb)
        return added

    # ------------------------------------------------------------------ the chain
    def _chain(self, radar_id: str, first: WindowSummary) -> _RadarChain:
        chain = self._chains.get(radar_id)
        if chain is None:
            site = self.sites[radar_id]
            fixed = dict(self.options.fixed)
            terms = radar_terms(site, fixed, time_offset=self.options.use_adsb)
            names = tuple(n for n in TERM_NAMES if n in terms.free)
            prior = prior_sigmas(site, RadarTerms(radar_id, names, {}))
            rates = np.array([self._rates[n] for n in names])
            chain = self._chains[radar_id] = _RadarChain(
                radar_id, names, prior, rates, chain_scale(first, radar_id, names, prior))
        return chain

    def add_summary(self, summary: WindowSummary) -> None:
        """Add one window's summary (computed here or anywhere) to the chain.

        Windows must come in time order.
        """
        radars = list(dict.fromkeys(rid for rid, _ in summary.labels))
        where = {label: i for i, label in enumerate(summary.labels)}
        chains = {rid: self._chain(rid, summary) for rid in radars}
        radars, information, vector, points = embed_summary(
            summary, {rid: chains[rid].names for rid in radars},
            {rid: chains[rid].scale for rid in radars})
        keys = []
        for rid, point in zip(radars, points, strict=True):
            chain = chains[rid]
            positions = [where.get((rid, name)) for name in chain.names]
            key = symbol("i", self._counter)
            self._counter += 1
            self._graph.add_variable(key, point)
            cut = self.detect_steps and chain.keys and self._step(chain, summary, positions)
            if not chain.keys or cut:
                self._graph.add_prior(key, np.zeros(len(chain.names)), chain.prior / chain.scale)
            else:
                dt = summary.middle_s - chain.windows[-1].middle_s
                block = random_walk_block(chain.rates, dt, chain.scale)
                self._graph.add_linear([chain.keys[-1], key], [-block, block],
                                       np.zeros(len(chain.names)))
            chain.estimated.update(n for n, p in zip(chain.names, positions, strict=True)
                                   if p is not None)
            chain.keys.append(key)
            chain.windows.append(summary)
            keys.append(key)
        if summary.labels:
            self._graph.add_gaussian(keys, information, vector, points)
        self._graph.update()
        self.summaries.append(summary)

    def _step(self, chain: _RadarChain, summary: WindowSummary,
              positions: Sequence[int | None]) -> bool:
        """Whether the new window's own estimate jumps beyond the random walk."""
        previous = chain.keys[-1]
        mean = chain.scale * self._graph.vector(previous)
        covariance = self._graph.covariance(previous) * np.outer(chain.scale, chain.scale)
        dt = summary.middle_s - chain.windows[-1].middle_s
        predicted = np.diag(covariance) + chain.rates**2 * dt
        sizes, sigmas, worst = {}, {}, 1.0
        threshold = ONLINE_STEP_FALSE_ALARM_PER_WINDOW / len(chain.names)
        for col, pos in enumerate(positions):
            if pos is None:
                continue
            innovation = summary.estimate[pos] - mean[col]
            s = predicted[col] + summary.covariance[pos, pos]
            p = float(special.chdtrc(1, innovation**2 / s))
            worst = min(worst, p)
            if p < threshold:
                key, factor = CONTRACT_KEYS[chain.names[col]]
                sizes[key] = float(innovation) * factor
                sigmas[key] = float(np.sqrt(s)) * factor
        if not sizes:
            return False
        self.events.append(BiasEvent(chain.radar_id, summary.t_start_s, "step", list(sizes),
                                     sizes, sigmas, float(special.chdtri(1, worst))))
        return True

    # ------------------------------------------------------------------ estimates out
    def _estimate(self, chain: _RadarChain, key: int, summary: WindowSummary
                  ) -> WindowEstimate:
        return window_estimate(summary, chain.radar_id,
                               RadarTerms(chain.radar_id, chain.names, {}),
                               chain.scale * self._graph.vector(key),
                               self._graph.covariance(key) * np.outer(chain.scale, chain.scale),
                               reported=chain.estimated)

    def current(self) -> dict[str, WindowEstimate]:
        """Each radar's latest window, smoothed with everything so far: the correction
        to apply now."""
        return {rid: self._estimate(chain, chain.keys[-1], chain.windows[-1])
                for rid, chain in self._chains.items() if chain.keys}

    def series(self) -> dict[str, list[WindowEstimate]]:
        """Every window of every radar, smoothed with everything so far."""
        return {rid: [self._estimate(chain, key, summary)
                      for key, summary in zip(chain.keys, chain.windows, strict=True)]
                for rid, chain in self._chains.items()}


def _concat(a: pd.DataFrame | None, b: pd.DataFrame | None) -> pd.DataFrame | None:
    if a is None:
        return b
    if b is None:
        return a
    return pd.concat([a, b], ignore_index=True)


__all__ = ["ONLINE_STEP_FALSE_ALARM_PER_WINDOW", "Calibrator"]
