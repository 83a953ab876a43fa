"""Where the sensor models come from: GRAPHCAL_MODELS_DIR, the package's data, the source tree.

The installed wheel itself is tested in ``tests/test_installed_wheel.py``; here the order
of the lookup and the copy of a packaged folder that is not on disk (a zip import).
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest

from graphcal.core.errors import SensorModelError
from graphcal.data import sensor_models
from graphcal.data.sensor_models import MODELS_DIR_ENV, list_sensor_models, models_dir
from tests.paths import MODELS, ROOT


def _models_folder(folder: Path) -> Path:
    """A models folder with the NACp table and one radar model named ``own``."""
    folder.mkdir()
    (folder / "adsb-nacp.toml").write_bytes((MODELS / "adsb-nacp.toml").read_bytes())
    (folder / "own.toml").write_bytes((MODELS / "ssr-mode-s.toml").read_bytes())
    return folder


def test_the_source_tree_has_no_packaged_copy(monkeypatch: pytest.MonkeyPatch) -> None:
    """A checkout (editable install) reads the repository's models/ itself: no copy of it
    lies in the package folder, where it could go stale."""
    monkeypatch.delenv(MODELS_DIR_ENV, raising=False)
    assert not (ROOT / "graphcal" / "models").exists()
    assert sensor_models._packaged_models_dir() is None
    assert models_dir() == MODELS


def test_package_data_wins_over_the_source_tree(tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    packaged = _models_folder(tmp_path / "packaged")
    monkeypatch.delenv(MODELS_DIR_ENV, raising=False)
    monkeypatch.setattr(sensor_models, "_packaged_models_dir", lambda: packaged)
    assert models_dir() == packaged
    assert list_sensor_models() == ["own"]


def test_the_variable_wins_over_package_data(tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    packaged = _models_folder(tmp_path / "packaged")
    chosen = tmp_path / "chosen"
    chosen.mkdir()
    monkeypatch.setattr(sensor_models, "_packaged_models_dir", lambda: packaged)
    monkeypatch.setenv(MODELS_DIR_ENV, str(chosen))
    assert models_dir() == chosen
    assert list_sensor_models() == []
    monkeypatch.setenv(MODELS_DIR_ENV, "")  # empty: as if unset
    assert models_dir() == packaged


def test_no_models_anywhere_names_the_variable(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(MODELS_DIR_ENV, raising=False)
    monkeypatch.setattr(sensor_models, "_packaged_models_dir", lambda: None)
    monkeypatch.setattr(sensor_models, "_SOURCE_MODELS_DIR", tmp_path / "missing")
    with pytest.raises(SensorModelError, match="sensor model folder not found; set "
                       "GRAPHCAL_MODELS_DIR"):
        list_sensor_models()
    monkeypatch.setenv(MODELS_DIR_ENV, str(tmp_path / "also-missing"))
    with pytest.raises(SensorModelError, match="folder not found") as info:
        list_sensor_models()
    assert MODELS_DIR_ENV not in str(info.value)  # the user chose it: no hint to set it


def test_a_packaged_folder_inside_a_zip_is_copied_to_disk(tmp_path: Path) -> None:
    archive = tmp_path / "package.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        zf.writestr("graphcal/models/own.toml", b"kind = 'radar'\n")
        zf.writestr("graphcal/models/notes.txt", b"not a model")
    folder = zipfile.Path(archive, "graphcal/models/")
    copy = sensor_models._materialise(folder)
    assert copy.is_dir()
    assert {p.name: p.read_bytes() for p in copy.iterdir()} == {"own.toml": b"kind = 'radar'\n"}
