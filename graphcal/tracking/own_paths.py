"""Paths of their own for aircraft that no reference covers, seen by two radars without
identity.

An aircraft without ADS-B, outside every Mode S radar's cover, leaves plots only at radars
that report no address (primary radars, Mode A/C SSRs).  None of them can be matched to a
known aircraft (:mod:`graphcal.tracking.association`), but when two such radars see it, the
pair still measures their relative biases, as any common observation does.  This module
finds such aircraft and gives their plots an address of their own:

1. **Tracks.**  Each radar's plots left out by the association are formed into tracks
   (:func:`graphcal.tracking.track_formation.form_tracks`); clutter forms none.
2. **References.**  The tracks that can be placed in space (3-D radars; 2-D radars with
   Mode C altitudes), corrected with their radar's current biases, are reference
   trajectories (:class:`~graphcal.tracking.gating.References`) named ``RADAR#k``.  A
   reference position's sigma is its plot's largest position sigma (range, range times the
   azimuth and elevation sigmas; for a Mode C height at least :data:`MODE_C_SIGMA_M`).
3. **Votes.**  Every tracked plot of a radar is gated against the other radars' tracks in
   its own coordinates (:func:`~graphcal.tracking.gating.gated_pairs`, with its bias
   covariance and Mode 3/A codes), and votes, at each other radar, for the track it fits
   best, unless a second fits within :data:`AMBIGUITY_CHI2_MARGIN`.  A track is linked with
   the track of another radar that has at least :data:`MIN_MATCHED_PLOTS` of its votes and
   :data:`VOTE_DOMINANCE` times the votes of any other track of that radar.
4. **Aircraft.**  Linked tracks form aircraft (connected components).  Where two tracks of one
   radar overlap in time by up to :data:`MAX_SPLIT_OVERLAP_S`, the radar split its track and
   the shorter is left out; an aircraft with a longer overlap is dropped (two aircraft were
   joined).  One seen by two radars or more is kept, named ``~`` and the first of its
   tracks' names.  A plot is given that name when it fits one of the aircraft's other
   radars' tracks (its vote), or when its radar's track was linked only by the votes of
   others.

An aircraft seen by one radar alone is left out: without a reference it tells nothing of
that radar's biases.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.data.align import adsb_track_table
from graphcal.data.bias import RadarBias
from graphcal.data.dataset import Site
from graphcal.tracking.gating import References, gated_pairs, plot_positions
from graphcal.tracking.track_formation import form_tracks

FloatArray = NDArray[np.float64]

#: A plot whose second-best track fits within this chi-square of its best does not vote.
AMBIGUITY_CHI2_MARGIN = 4.0
#: Fewest votes that link two tracks.
MIN_MATCHED_PLOTS = 4
#: The best-voted track needs this many times the votes of the runner-up.
VOTE_DOMINANCE = 5.0
#: The sigma of a position placed at a Mode C (pressure) altitude [m].
MODE_C_SIGMA_M = 300.0
#: Two tracks of one radar in one aircraft that overlap by at most this [s] are a split track
#: (the shorter is left out); longer, two aircraft were joined (the aircraft is dropped).
MAX_SPLIT_OVERLAP_S = 60.0
#: An aircraft's name starts with this (no ICAO address does).
OWN_PATH_PREFIX = "~"


@dataclass
class Leftover:
    """One radar's plots that the association left out.

    ``plots``: their arrays; ``rows``: their rows among the radar's plots without an
    address; ``codes``, ``track_number``: their Mode 3/A codes and track numbers (or
    ``None``); ``bias``, ``covariance``: the radar's current estimate and its (4, 4)
    covariance over (range offset m, range gain, azimuth rad, elevation rad), or ``None``.
    """

    plots: Any
    rows: NDArray[np.int64]
    codes: NDArray[np.object_] | None
    track_number: NDArray | None
    bias: RadarBias
    covariance: FloatArray | None


def own_paths(sites: Mapping[str, Site], leftovers: Mapping[str, Leftover]
              ) -> dict[str, NDArray[np.object_]]:
    """Each leftover plot's own-path aircraft name, "" where none (module docstring)."""
    radars = sorted(leftovers)  # the answer does not depend on the radars' order
    labels = {rid: form_tracks(sites[rid], leftovers[rid].plots, leftovers[rid].track_number,
                               leftovers[rid].codes) for rid in radars}
    table, codes = _track_references(sites, leftovers, labels, radars)
    votes = {rid: _votes(sites[rid], leftovers[rid], labels[rid], rid, table, codes)
             for rid in radars}
    names = _aircraft(_components(_links(pd.concat(votes.values(), ignore_index=True))),
                      _spans(leftovers, labels, radars))
    out: dict[str, NDArray[np.object_]] = {}
    for rid in radars:
        label, vote = labels[rid], votes[rid]
        ids = np.full(len(label), "", dtype=object)
        node = pd.Series(np.char.add(f"{rid}#", label.astype(str)), dtype=object)
        name = node.map(names).where(label >= 0)
        # A plot fits a track of its aircraft at another radar, or its track was linked by
        # the others' votes alone.
        vote_name = vote["other"].map(names)
        fits = vote.loc[vote_name.notna().to_numpy() & (vote_name.to_numpy()
                                                         == name.to_numpy()[vote["row"]]), "row"]
        accepted = np.zeros(len(label), dtype=bool)
        accepted[fits.to_numpy(dtype=np.int64)] = True
        accepted |= name.notna().to_numpy() & ~node.isin(set(vote["node"])).to_numpy()
        accepted &= name.notna().to_numpy()
        ids[accepted] = name.to_numpy()[accepted]
        out[rid] = ids
    return out


def _track_references(sites: Mapping[str, Site], leftovers: Mapping[str, Leftover],
                      labels: Mapping[str, NDArray[np.int64]], radars: list[str]
                      ) -> tuple[pd.DataFrame, dict[str, set[str]]]:
    """The tracks as reference positions (module docstring, step 2) and their codes."""
    parts = []
    codes: dict[str, set[str]] = {}
    for rid in radars:
        site, left, label = sites[rid], leftovers[rid], labels[rid]
        keep = label >= 0
        if not site.is_3d:
            keep &= np.isfinite(left.plots.altitude_m)
        if not np.any(keep):
            continue
        sub = left.plots.subset(keep)
        ecef = plot_positions(site, sub, left.bias)
        lat, lon, h = frames.ecef_to_geodetic(ecef)
        sigmas = site.measurement_sigmas()
        angular = max(sigmas[1], sigmas[2]) if site.is_3d else sigmas[1]
        sigma = np.maximum(sigmas[0], sub.range_m * angular)
        if not site.is_3d:
            sigma = np.maximum(sigma, MODE_C_SIGMA_M)
        node = np.char.add(f"{rid}#", label[keep].astype(str)).astype(object)
        parts.append(pd.DataFrame({
            "time_s": sub.time_s - left.bias.time_offset_s, "target_id": node,
            "lat_deg": np.rad2deg(lat), "lon_deg": np.rad2deg(lon), "alt_m": h,
            "sigma_m": sigma}))
        if left.codes is not None:
            for n, c in zip(node, np.asarray(left.codes, dtype=object)[keep], strict=True):
                if c:
                    codes.setdefault(n, set()).add(str(c))
    if not parts:
        return pd.DataFrame(columns=["time_s", "target_id", "lat_deg", "lon_deg", "alt_m",
                                     "sigma_m"]), codes
    return pd.concat(parts, ignore_index=True), codes


def _votes(site: Site, left: Leftover, label: NDArray[np.int64], rid: str,
           table: pd.DataFrame, codes: dict[str, set[str]]) -> pd.DataFrame:
    """The plots' votes: per tracked plot and other radar, the track of that radar it fits
    best, unless a second fits within :data:`AMBIGUITY_CHI2_MARGIN` (``row``: the plot,
    ``node``: its track, ``other``: the track it fits)."""
    empty = pd.DataFrame({"row": pd.Series(dtype=np.int64), "node": pd.Series(dtype=object),
                          "other": pd.Series(dtype=object)})
    others = table[~table["target_id"].astype(str).str.startswith(f"{rid}#")]
    tracked = np.flatnonzero(label >= 0)
    if len(others) == 0 or len(tracked) == 0:
        return empty
    refs = References(adsb_track_table(others), codes)
    plot_codes = None if left.codes is None else np.asarray(left.codes, dtype=object)[tracked]
    keep = np.zeros(len(label), dtype=bool)
    keep[tracked] = True
    pairs = gated_pairs(site, refs, left.plots.subset(keep), left.bias, left.covariance, None,
                        plot_codes)
    if len(pairs.plot) == 0:
        return empty
    names = np.asarray(refs.tracks.targets, dtype=object)[pairs.aircraft]
    radar = np.asarray(refs.tracks.targets.str.split("#").str[0], dtype=object)
    frame = pd.DataFrame({"plot": pairs.plot, "other": names, "chi2": pairs.chi2,
                          "radar": radar[pairs.aircraft]})
    frame = frame.sort_values(["plot", "radar", "chi2"], kind="stable")
    rank = frame.groupby(["plot", "radar"], sort=False).cumcount().to_numpy()
    first = frame[rank == 0]
    second = frame[rank == 1].set_index(["plot", "radar"])["chi2"]
    runner_up = second.reindex(pd.MultiIndex.from_frame(first[["plot", "radar"]])).to_numpy()
    first = first[~(runner_up - first["chi2"].to_numpy() < AMBIGUITY_CHI2_MARGIN)]
    rows = tracked[first["plot"].to_numpy()]
    node = np.char.add(f"{rid}#", label[rows].astype(str)).astype(object)
    return pd.DataFrame({"row": rows, "node": node, "other": first["other"].to_numpy()})


def _links(votes: pd.DataFrame) -> list[tuple[str, str]]:
    """Pairs of tracks linked by their votes (module docstring, step 3): per track and
    other radar, the track of that radar with most votes, when they are enough and dominant."""
    if len(votes) == 0:
        return []
    counts = votes.groupby(["node", "other"], sort=True).size().rename("n").reset_index()
    counts["radar"] = counts["other"].str.split("#").str[0]
    counts = counts.sort_values(["node", "radar", "n"], ascending=[True, True, False],
                                kind="stable")
    edges = []
    for (node, _), group in counts.groupby(["node", "radar"], sort=True):
        n = group["n"].to_numpy()
        runner_up = n[1] if len(n) > 1 else 0
        if n[0] >= MIN_MATCHED_PLOTS and n[0] >= VOTE_DOMINANCE * runner_up:
            edges.append((str(node), str(group["other"].iloc[0])))
    return edges


def _components(edges: list[tuple[str, str]]) -> dict[str, str]:
    """Each linked track's component, named by its smallest member (union-find)."""
    parent: dict[str, str] = {}

    def root(x: str) -> str:
        parent.setdefault(x, x)
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a, b in edges:
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    return {node: root(node) for node in parent}


def _spans(leftovers: Mapping[str, Leftover], labels: Mapping[str, NDArray[np.int64]],
           radars: list[str]) -> dict[str, tuple[float, float]]:
    """Each track's first and last plot time [s]."""
    spans = {}
    for rid in radars:
        label, time_s = labels[rid], leftovers[rid].plots.time_s
        keep = label >= 0
        if not keep.any():
            continue
        span = pd.DataFrame({"k": label[keep], "t": time_s[keep]}).groupby("k")["t"].agg(
            ["min", "max"])
        for k, lo, hi in span.itertuples():
            spans[f"{rid}#{k}"] = (float(lo), float(hi))
    return spans


def _aircraft(component: dict[str, str], spans: dict[str, tuple[float, float]]
              ) -> dict[str, str]:
    """Each kept track's aircraft name (module docstring, step 4)."""
    members: dict[str, list[str]] = {}
    for node, head in component.items():
        members.setdefault(head, []).append(node)
    names = {}
    for head, nodes in members.items():
        by_radar: dict[str, list[str]] = {}
        for node in nodes:
            by_radar.setdefault(node.split("#")[0], []).append(node)
        if len(by_radar) < 2:
            continue
        kept = [_without_splits(tracks, spans) for tracks in by_radar.values()]
        if any(k is None for k in kept):
            continue
        for tracks in kept:
            for node in tracks or ():
                names[node] = OWN_PATH_PREFIX + head
    return names


def _without_splits(tracks: list[str], spans: dict[str, tuple[float, float]]
                    ) -> list[str] | None:
    """One radar's tracks of one aircraft, the shorter of two that overlap by at most
    :data:`MAX_SPLIT_OVERLAP_S` left out (the radar split its track); ``None`` when two
    overlap longer (two aircraft were joined)."""
    by_length = sorted(tracks, key=lambda n: (-(spans[n][1] - spans[n][0]), n))
    kept: list[str] = []
    for node in by_length:
        lo, hi = spans[node]
        overlap = max((min(hi, spans[k][1]) - max(lo, spans[k][0]) for k in kept), default=-1.0)
        if overlap > MAX_SPLIT_OVERLAP_S:
            return None
        if overlap < 0.0:
            kept.append(node)
    return kept


__all__ = ["Leftover", "OWN_PATH_PREFIX", "own_paths"]
