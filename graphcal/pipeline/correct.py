"""Correct a dataset folder: read it and a result, write the plots with the biases removed."""

from __future__ import annotations

from pathlib import Path

from graphcal.core.errors import DatasetError, ResultError
from graphcal.data.calibration import read_biases
from graphcal.data.correct import correct_dataset
from graphcal.data.dataset import Dataset
from graphcal.io.folder import load_dataset, write_dataset


def _table_format(folder: Path | None) -> str:
    """``parquet`` when the source dataset's plots are Parquet, else ``csv``."""
    if folder is not None and (Path(folder) / "plots.parquet").exists():
        return "parquet"
    return "csv"


def correct_folder(
    dataset_dir: str | Path, result: str | Path, out: str | Path, *, overwrite: bool = False,
    force: bool = False,
) -> Dataset:
    """Read a dataset folder and a result JSON, write the corrected dataset to ``out``.

    ``result`` may be a calibration result or a simulation's ``truth.json``
    (read with :func:`graphcal.data.calibration.read_biases`).  The output keeps the
    table format of the input and is written atomically
    (:func:`graphcal.io.folder.write_dataset`); ``dataset_dir`` is only read.
    The dataset is read with its cleaning (:func:`graphcal.io.folder.load_dataset`):
    the rows it drops are not written, and the returned dataset's ``cleaning``
    reports them.  Radars the result has no biases for keep their plots as they are.
    ``force`` skips the unit and frame heuristics on reading it
    (:func:`graphcal.io.folder.load_dataset`).

    Raises
    ------
    DatasetError
        Bad input dataset, ``out`` is ``dataset_dir``, or ``out`` exists and is
        not empty without ``overwrite``.
    ResultError
        Bad result file, or one without biases for any of the dataset's radars.
    """
    dataset_dir, out = Path(dataset_dir), Path(out)
    if out.exists() and dataset_dir.exists() and out.resolve() == dataset_dir.resolve():
        raise DatasetError("the output folder must differ from the input dataset", path=out)
    dataset = load_dataset(dataset_dir, force=force)
    biases = read_biases(result)
    if not set(biases) & set(dataset.sites):
        known = ", ".join(sorted(biases)) or "none"
        raise ResultError(f"has biases for none of the radars of {dataset_dir} (it has: "
                          f"{known}; the dataset: {', '.join(sorted(dataset.sites))})",
                          path=result)
    corrected = correct_dataset(dataset, biases)
    write_dataset(corrected, out, fmt=_table_format(dataset_dir), overwrite=overwrite)
    corrected.path = out
    corrected.cleaning = dataset.cleaning
    return corrected
