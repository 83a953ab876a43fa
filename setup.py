"""Build hook: ship the sensor models of ``models/`` inside the built package.

All metadata lives in ``pyproject.toml``; this file only adds a ``build_py`` step.
``models/*.toml`` at the top of the repository is where the sensor models are
edited (the single copy in git).  A built package (wheel, non-editable install)
must carry them, so ``build_py`` copies them into ``graphcal/models/`` of the build
folder, where :mod:`graphcal.data.sensor_models` reads them with
:mod:`importlib.resources`.  Nothing is written into the source tree, and an
editable install copies nothing: it reads the repository's ``models/`` itself.
The source distribution carries ``models/`` through ``MANIFEST.in``.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

#: The folder of the sensor models in the source tree.
MODELS_SOURCE = Path(__file__).resolve().parent / "models"
#: Where the models go inside the built package (``graphcal/models/*.toml``).
MODELS_TARGET = ("graphcal", "models")


def model_files() -> list[Path]:
    """The sensor model files to ship, sorted by name.

    Returns
    -------
    list of Path
        Every ``*.toml`` file of ``models/``.

    Raises
    ------
    RuntimeError
        If ``models/`` is missing or holds no model (a package without its models
        would fail at run time, so the build stops instead).
    """
    files = sorted(MODELS_SOURCE.glob("*.toml"))
    if not files:
        raise RuntimeError(f"{MODELS_SOURCE}: no sensor model files (*.toml) to package")
    return files


class BuildPyWithModels(build_py):
    """``build_py`` that also copies ``models/*.toml`` into ``graphcal/models/``."""

    def _models_target(self) -> Path:
        """The models folder inside the build folder."""
        return Path(self.build_lib, *MODELS_TARGET)

    def run(self) -> None:
        """Build the package as usual, then copy exactly the files of ``models/``."""
        super().run()
        if self.editable_mode:  # an editable install reads the repository's models/
            return
        target = self._models_target()
        if target.exists():  # a build folder left from an earlier build: no stale files
            shutil.rmtree(target)
        target.mkdir(parents=True)
        for source in model_files():
            self.copy_file(str(source), str(target / source.name))

    def get_outputs(self, include_bytecode: bool = True) -> list[str]:
        """The files of the build, the copied models included."""
        outputs = list(super().get_outputs(include_bytecode))
        if not self.editable_mode:
            target = self._models_target()
            outputs += [str(target / source.name) for source in model_files()]
        return outputs


setup(cmdclass={"build_py": BuildPyWithModels})
