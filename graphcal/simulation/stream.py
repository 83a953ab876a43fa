"""Long scenarios written as they are simulated: one chunk of time in memory, not the recording.

:func:`simulate_to_folder` simulates a scenario chunk after chunk
(:class:`graphcal.simulation.simulate.ChunkedSimulation`, an hour by default) and
appends each chunk's plots and ADS-B reports to the dataset folder's tables as it
goes (:class:`graphcal.io.folder.DatasetWriter`: Parquet row groups, or CSV rows),
so a day of a large network (tens of millions of plots) is written in the memory
of an hour.  Neither the plots' truth nor the trajectories' samples are kept, but
for a scenario some of whose plots carry no address (contract v3: a radar whose
``identity`` is not ``"mode_s"``, or clutter): each plot's ``truth_target_id`` is
kept (one reference per plot) for the ``plot_truth`` block of ``truth.json``.

The folder is the one :func:`graphcal.simulation.simulate.write_simulation` writes
for ``simulate(scenario, rng, chunk_s=chunk_s)`` with the same seed: the same
``sites.toml``, the same rows in the same order (a CSV file byte for byte) and the
same ``truth.json``.  It is written atomically (a temporary folder renamed into
place, ``truth.json`` included).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from graphcal.io.folder import DatasetWriter
from graphcal.simulation.scenario import Scenario
from graphcal.simulation.simulate import ChunkedSimulation, ProgressCallback, scenario_truth

#: Default chunk of simulated time [s].
DEFAULT_CHUNK_S = 3600.0


@dataclass
class StreamedSimulation:
    """What :func:`simulate_to_folder` wrote.

    Attributes
    ----------
    path : Path
        The dataset folder.
    n_plots : dict of str to int
        Plots per radar.
    n_adsb : int
        ADS-B reports (0: no ADS-B table).
    n_chunks : int
        Chunks simulated.
    n_candidates : dict of str to int
        Per radar, the beam hits in coverage before the detection draw.
    antenna_phase_rad : dict of str to float
        Beam azimuth at time 0 of each radar [rad].
    adsb_equipped : tuple of str
        Addresses of the aircraft that broadcast ADS-B.
    n_clutter : dict of str to int
        Per radar, the false plots among its plots.
    """

    path: Path
    n_plots: dict[str, int]
    n_adsb: int
    n_chunks: int
    n_candidates: dict[str, int] = field(default_factory=dict)
    antenna_phase_rad: dict[str, float] = field(default_factory=dict)
    adsb_equipped: tuple[str, ...] = ()
    n_clutter: dict[str, int] = field(default_factory=dict)

    @property
    def total_plots(self) -> int:
        """Plots of all radars."""
        return sum(self.n_plots.values())


def simulate_to_folder(
    scenario: Scenario,
    rng: np.random.Generator,
    out_dir: str | Path,
    *,
    fmt: str = "parquet",
    chunk_s: float = DEFAULT_CHUNK_S,
    overwrite: bool = False,
    progress: ProgressCallback | None = None,
) -> StreamedSimulation:
    """Simulate a scenario into a dataset folder chunk by chunk (module docstring).

    Parameters
    ----------
    scenario : Scenario
        From :func:`graphcal.simulation.scenario.load_scenario`.
    rng : numpy.random.Generator
        The only source of randomness (``numpy.random.default_rng(seed)``).
    out_dir : str or Path
        Destination folder (refused when it exists and is not empty, unless
        ``overwrite``).
    fmt : {"parquet", "csv"}, optional
        Table format; Parquet gets one row group per chunk (or more, of at most
        :data:`graphcal.io.table_writer.DEFAULT_ROW_GROUP_ROWS` rows each).
    chunk_s : float, optional
        Chunk of reported time [s] (:mod:`graphcal.simulation.chunks`).
    overwrite : bool, optional
        Replace an existing non-empty folder.
    progress : callable, optional
        ``progress(stage, done, total)`` after the traffic and after each radar
        and the ADS-B of each chunk.

    Returns
    -------
    StreamedSimulation
        The folder and its counts.

    Raises
    ------
    ScenarioError
        If an ``[opensky]`` table is missing or unreadable.
    DatasetError
        If ``out_dir`` is a file, or a non-empty folder without ``overwrite``.
    ValueError
        If ``fmt`` or ``chunk_s`` is invalid.
    """
    sites = {radar.id: radar.site() for radar in scenario.radars}
    with DatasetWriter(sites, out_dir, fmt=fmt, overwrite=overwrite,
                       plot_altitude=scenario.plot_altitude,
                       epoch_utc=scenario.epoch_utc) as writer:
        run = ChunkedSimulation(scenario, rng, chunk_s=chunk_s, progress=progress)
        n_plots = dict.fromkeys(sites, 0)
        candidates = dict.fromkeys(sites, 0)
        n_clutter = dict.fromkeys(sites, 0)
        targets: list[np.ndarray] | None = None if scenario.addressed else []
        n_adsb = 0
        for chunk in run.chunks():
            writer.write_plots(chunk.plots)
            for radar_id, count in chunk.plots["radar_id"].value_counts().items():
                n_plots[str(radar_id)] += int(count)
            for radar_id, count in chunk.n_candidates.items():
                candidates[radar_id] += count
            for radar_id, count in chunk.n_clutter.items():
                n_clutter[radar_id] += count
            if targets is not None:
                targets.append(chunk.plot_truth["truth_target_id"].to_numpy(dtype=object))
            if chunk.adsb is not None and len(chunk.adsb):
                writer.write_adsb(chunk.adsb)
                n_adsb += len(chunk.adsb)
        plot_targets = None if targets is None else np.concatenate(
            [np.empty(0, dtype=object), *targets])
        document = scenario_truth(scenario, n_plots, plot_targets, n_clutter)
        writer.write_text("truth.json", json.dumps(document, indent=2) + "\n")
    return StreamedSimulation(Path(out_dir), n_plots, n_adsb, run.n_chunks, candidates,
                              run.antenna_phase_rad, run.adsb_equipped, n_clutter)


__all__ = ["DEFAULT_CHUNK_S", "StreamedSimulation", "simulate_to_folder"]
