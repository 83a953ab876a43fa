"""Calibrating a recording while it is written: new part files fed to a Calibrator.

A recorder that writes a dataset folder as parts (``plots/`` and ``adsb/`` folders of
CSV or Parquet files, the contract extension v1.4; e.g. one file per radar and per
10 minutes, named so that name order is time order) can be calibrated while it
records.  :func:`follow_folder` looks for parts it has not read yet, validates them
as :func:`graphcal.io.folder.load_dataset` does (errors name the file, the row and
the field), and gives them to a :class:`graphcal.solvers.incremental.Calibrator`,
which closes each window once later data have arrived and updates the smoothed
chain with iSAM2.

A part is read once it has not changed for ``settle_s`` seconds (a file still being
written is left for the next look).  ASTERIX recordings are decoded to a dataset
first (``graphcal import-asterix``) and fed the same way, or given to
:meth:`Calibrator.add` directly.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pandas as pd

from graphcal.data.dataset import ADSB_COLUMNS, PLOT_COLUMNS, Dataset
from graphcal.io.folder import SITES_FILE, load_sites
from graphcal.io.table_checks import validate_adsb, validate_plots
from graphcal.io.table_files import read_rows
from graphcal.pipeline.windowed import summarise_associated
from graphcal.solvers.incremental import Calibrator
from graphcal.solvers.windows import WindowSummary

#: Suffixes of part files.
PART_SUFFIXES = (".csv", ".parquet")


def new_parts(folder: Path, seen: set[Path], settle_s: float = 2.0) -> list[Path]:
    """Part files of ``folder/plots`` and ``folder/adsb`` not in ``seen``, in name
    order, that have not changed for ``settle_s`` seconds."""
    now = time.time()
    found = []
    for stem in ("plots", "adsb"):
        parts = folder / stem
        if not parts.is_dir():
            continue
        for path in sorted(parts.iterdir()):
            if (path.suffix in PART_SUFFIXES and path not in seen
                    and now - path.stat().st_mtime >= settle_s):
                found.append(path)
    return sorted(found, key=lambda p: p.name)


def read_part(path: Path, sites) -> tuple[pd.DataFrame | None, pd.DataFrame | None]:
    """One part file, validated: ``(plots, None)`` or ``(None, adsb)``."""
    if path.parent.name == "plots":
        frames = [validate_plots(rows, sites) for rows in read_rows(path, PLOT_COLUMNS)]
        return pd.concat(frames, ignore_index=True), None
    frames = [validate_adsb(rows) for rows in read_rows(path, ADSB_COLUMNS)]
    return None, pd.concat(frames, ignore_index=True)


def follow_folder(
    folder: str | Path,
    calibrator: Calibrator | None = None,
    *,
    window_s: float = 1800.0,
    poll_s: float = 10.0,
    settle_s: float = 2.0,
    idle_stop_s: float | None = None,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[tuple[Calibrator, list[WindowSummary]]]:
    """Feed a folder's new parts to a Calibrator as they appear (module docstring).

    Yields ``(calibrator, windows closed)`` after each look that found parts.
    Stops after ``idle_stop_s`` seconds without a new part (``None``: never), then
    closes the last windows (:meth:`Calibrator.flush`) and yields once more.

    Parameters
    ----------
    folder : str or Path
        A dataset folder with ``sites.toml`` and ``plots/`` (and ``adsb/``) parts.
    calibrator : Calibrator, optional
        Default: a new one on the folder's sites with ``window_s``.
    poll_s, settle_s : float
        Seconds between looks, and how long a part must be unchanged to be read.
    """
    folder = Path(folder)
    sites = load_sites(folder / SITES_FILE)
    calibrator = calibrator or Calibrator(sites, window_s, summarise=summarise_associated)
    seen: set[Path] = set()
    idle = 0.0
    while True:
        parts = new_parts(folder, seen, settle_s)
        if parts:
            idle = 0.0
            plots, adsb = [], []
            for path in parts:
                p, a = read_part(path, sites)
                (plots if p is not None else adsb).append(p if p is not None else a)
                seen.add(path)
            if plots:
                data = Dataset(sites=sites, plots=pd.concat(plots, ignore_index=True),
                               adsb=pd.concat(adsb, ignore_index=True) if adsb else None,
                               path=folder)
                yield calibrator, calibrator.add(data)
            elif adsb:
                calibrator.add(Dataset(sites=sites, plots=pd.DataFrame(columns=PLOT_COLUMNS),
                                       adsb=pd.concat(adsb, ignore_index=True), path=folder))
            continue
        if idle_stop_s is not None and idle >= idle_stop_s:
            yield calibrator, calibrator.flush()
            return
        sleep(poll_s)
        idle += poll_s


__all__ = ["PART_SUFFIXES", "follow_folder", "new_parts", "read_part"]
