"""The package as a user installs it: a built wheel in a fresh venv, not the source tree.

The module builds an sdist from a copy of the packaging files (so ``MANIFEST.in`` must
carry what the build needs), a wheel from that sdist (as ``python -m build`` does), and
installs the wheel with ``--no-deps`` into a venv made in a temporary folder.  The
dependencies come from the project's own venv through a ``.pth`` file that holds its
site-packages path: a plain path line does not run the ``.pth`` files of that folder, so
the editable ``graphcal`` of the project's venv stays out of sight (checked below).
Every command runs from a working folder outside the repository.

The wheel is built without build isolation when this interpreter can build one
(setuptools >= 68 with ``bdist_wheel``); otherwise pip builds it in its usual isolated
environment, fetching setuptools as ``pip install .`` would.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from dataclasses import dataclass
from importlib import metadata
from importlib.util import find_spec
from pathlib import Path

import pytest

from tests.paths import MODELS, ROOT, SCENARIOS

#: What the sdist is built from: the packaging files and the package's sources.
PACKAGING_FILES = ("pyproject.toml", "setup.py", "MANIFEST.in", "README.md")
#: The demo network's radars (scenarios/demo_network.toml).
DEMO_RADARS = ("NORD", "SUD", "EST3D", "OUEST3D", "APP")


@dataclass(frozen=True)
class Installed:
    """A wheel installed into a fresh venv.

    Attributes
    ----------
    wheel : Path
        The built wheel.
    sdist : Path
        The sdist the wheel was built from.
    venv : Path
        The fresh venv.
    python : Path
        Its interpreter.
    script : Path
        Its ``graphcal`` console script.
    site_packages : Path
        Its site-packages folder.
    work : Path
        A working folder outside the repository, where every command runs.
    """

    wheel: Path
    sdist: Path
    venv: Path
    python: Path
    script: Path
    site_packages: Path
    work: Path


def _run(args: list[str | Path], cwd: Path, env: dict[str, str] | None = None,
         timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    """Run a command, failing the test with its output when its exit status is not 0."""
    done = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout, check=False)
    assert done.returncode == 0, (
        f"{' '.join(str(a) for a in args)} exited {done.returncode}\n"
        f"--- stdout\n{done.stdout[-4000:]}\n--- stderr\n{done.stderr[-4000:]}")
    return done


def _clean_env() -> dict[str, str]:
    """This process's environment without anything that could point at the source tree."""
    env = {key: value for key, value in os.environ.items()
           if key not in {"PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP", "VIRTUAL_ENV",
                          "GRAPHCAL_MODELS_DIR", "PYTHONSAFEPATH"}}
    env["PYTHONNOUSERSITE"] = "1"
    env["COLUMNS"] = "200"  # tables on one line each, whatever the terminal
    return env


def _can_build_wheels_here() -> bool:
    """True when this interpreter builds the wheel itself (no isolated build environment)."""
    try:
        version = tuple(int(part) for part in metadata.version("setuptools").split(".")[:2])
    except (metadata.PackageNotFoundError, ValueError):
        return False
    has_bdist_wheel = version >= (70, 1) or find_spec("wheel") is not None
    return version >= (68, 0) and has_bdist_wheel


def _copy_sources(target: Path) -> None:
    """The files an sdist is made of, without caches or earlier build products."""
    target.mkdir()
    for name in PACKAGING_FILES:
        shutil.copy2(ROOT / name, target / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    shutil.copytree(ROOT / "graphcal", target / "graphcal", ignore=ignore)
    shutil.copytree(MODELS, target / "models", ignore=ignore)


def _build(tmp: Path, env: dict[str, str]) -> tuple[Path, Path]:
    """An sdist of a copy of the sources, then a wheel built from that sdist."""
    source = tmp / "source"
    _copy_sources(source)
    dist = tmp / "dist"
    dist.mkdir()
    done = _run([sys.executable, "-c",
                 "import sys; from setuptools import build_meta; "
                 "print(build_meta.build_sdist(sys.argv[1]))", dist], cwd=source, env=env)
    sdist = dist / done.stdout.strip().splitlines()[-1]
    isolation = ["--no-build-isolation"] if _can_build_wheels_here() else []
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", *isolation, "--wheel-dir", dist,
          sdist], cwd=tmp, env=env, timeout=300.0)
    (wheel,) = dist.glob("graphcal-*.whl")
    return sdist, wheel


def _fresh_venv(venv: Path, install: list[str | Path], env: dict[str, str]) -> tuple[Path, Path]:
    """A venv without pip, ``pip install --no-deps *install`` into it (run by this
    interpreter's pip), and this interpreter's site-packages behind a ``.pth`` line.

    Returns
    -------
    python : Path
        The venv's interpreter.
    site_packages : Path
        Its site-packages folder.
    """
    _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=venv.parent, env=env)
    bin_dir = venv / ("Scripts" if os.name == "nt" else "bin")
    python = bin_dir / ("python.exe" if os.name == "nt" else "python")
    isolation = ["--no-build-isolation"] if _can_build_wheels_here() else []
    _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", *isolation,
          *install], cwd=venv.parent, env=env, timeout=300.0)
    site_packages = Path(_run([python, "-c", "import sysconfig; "
                               "print(sysconfig.get_paths()['purelib'])"],
                              cwd=venv.parent, env=env).stdout.strip())
    ours = Path(sysconfig.get_paths()["purelib"])
    (site_packages / "graphcal-test-dependencies.pth").write_text(f"{ours}\n")
    return python, site_packages


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Installed:
    """The wheel built from the sources, installed into a fresh venv."""
    tmp = tmp_path_factory.mktemp("wheel")
    env = _clean_env()
    sdist, wheel = _build(tmp, env)
    venv = tmp / "venv"
    python, site_packages = _fresh_venv(venv, ["--no-index", wheel], env)
    work = tmp / "work"
    work.mkdir()
    script = python.parent / ("graphcal.exe" if os.name == "nt" else "graphcal")
    return Installed(wheel, sdist, venv, python, script, site_packages, work)


def _python(installed: Installed, code: str, *args: str | Path,
            env: dict[str, str] | None = None) -> str:
    """Run ``code`` with the fresh venv's interpreter in the outside working folder."""
    return _run([installed.python, "-c", code, *args], cwd=installed.work,
                env=env or _clean_env()).stdout


def test_sdist_and_wheel_carry_exactly_the_models_folder(installed: Installed) -> None:
    expected = {path.name: path.read_bytes() for path in MODELS.glob("*.toml")}
    assert {"ssr-mode-s.toml", "adsb-nacp.toml"} <= set(expected)
    with zipfile.ZipFile(installed.wheel) as wheel:
        shipped = {Path(name).name: wheel.read(name) for name in wheel.namelist()
                   if name.startswith("graphcal/models/")}
        record = wheel.read(next(n for n in wheel.namelist() if n.endswith(".dist-info/RECORD")))
    assert shipped == expected  # the same files, byte for byte, and no others
    for name in expected:
        assert f"graphcal/models/{name},".encode() in record
    with tarfile.open(installed.sdist) as sdist:
        in_sdist = {Path(m.name).name for m in sdist.getmembers()
                    if Path(m.name).parent.name == "models" and m.name.endswith(".toml")}
    assert in_sdist == set(expected)
    installed_models = installed.site_packages / "graphcal" / "models"
    assert {p.name: p.read_bytes() for p in installed_models.iterdir()} == expected


def test_the_installed_package_is_imported_not_the_source_tree(installed: Installed) -> None:
    out = _python(installed, """
import json, sys
import graphcal
from graphcal.data.sensor_models import list_sensor_models, models_dir
print(json.dumps({
    "file": graphcal.__file__,
    "models_dir": str(models_dir()),
    "models": list_sensor_models(),
    "finders": [getattr(f, "__name__", type(f).__name__) for f in sys.meta_path],
    "editable_modules": [m for m in sys.modules if "editable" in m],
    "path": sys.path,
}))
""")
    info = json.loads(out)
    package = installed.site_packages / "graphcal"
    assert Path(info["file"]).is_relative_to(installed.venv)
    assert Path(info["file"]).parent == package
    assert Path(info["models_dir"]) == package / "models"
    assert {"ssr-mode-s", "air-defence-3d", "psr-approach"} <= set(info["models"])
    # The .pth line put the project's site-packages on the path, but none of its .pth
    # files ran: no editable finder, and the repository itself is not on the path.
    assert not info["editable_modules"]
    assert not any("Editable" in name for name in info["finders"])
    assert str(Path(sysconfig.get_paths()["purelib"])) in info["path"]
    assert str(ROOT) not in info["path"] and "" not in info["path"][1:]


def test_models_dir_variable_wins_over_the_packaged_models(installed: Installed,
                                                           tmp_path: Path) -> None:
    folder = tmp_path / "my-models"
    folder.mkdir()
    (folder / "adsb-nacp.toml").write_bytes((MODELS / "adsb-nacp.toml").read_bytes())
    (folder / "my-radar.toml").write_bytes((MODELS / "ssr-mode-s.toml").read_bytes())
    env = _clean_env() | {"GRAPHCAL_MODELS_DIR": str(folder)}
    out = _python(installed, "from graphcal.data.sensor_models import list_sensor_models, "
                  "models_dir; print(models_dir()); print(list_sensor_models())", env=env)
    assert out.splitlines() == [str(folder), "['my-radar']"]


def test_installed_script_simulates_calibrates_and_imports_asterix(installed: Installed) -> None:
    env = _clean_env()
    work = installed.work
    graphcal = installed.script

    # simulate: the demo network's sites name sensor models (ssr-mode-s, ...).
    done = _run([graphcal, "simulate", SCENARIOS / "demo_network.toml", "--out", "sim",
                 "--seed", "1"], cwd=work, env=env)
    assert "wrote sim: 5 radars" in done.stdout
    sites = (work / "sim" / "sites.toml").read_text()
    assert 'model = "ssr-mode-s"' in sites and 'model = "air-defence-3d"' in sites

    # calibrate: a quick closed-form method, then the default (graph) to a result file.
    done = _run([graphcal, "calibrate", "sim", "--method", "fl-ls"], cwd=work, env=env)
    assert "observability degree" in done.stdout
    assert all(radar in done.stdout for radar in DEMO_RADARS)
    done = _run([graphcal, "calibrate", "sim", "--out", "result.json"], cwd=work, env=env)
    result = json.loads((work / "result.json").read_text())
    assert result["method"] == "graph"
    assert set(result["radars"]) == set(DEMO_RADARS)
    assert result["observability"]["rank"] == result["observability"]["n_parameters"] == 21
    nord = result["radars"]["NORD"]
    assert abs(nord["range_offset_m"] - 45.0) < 4.0 * nord["sigma"]["range_offset_m"]

    # import-asterix: a small recording written by the installed package's own encoder,
    # with CAT021 ADS-B whose NACp needs models/adsb-nacp.toml.
    _python(installed, """
import sys
from pathlib import Path
from graphcal.io.asterix.encode import encode_dataset
from graphcal.io.folder import load_dataset
sim, rec, sites = (Path(arg) for arg in sys.argv[1:])
ds = load_dataset(sim)
ds.plots = ds.plots.groupby("radar_id").head(40).reset_index(drop=True)
ds.adsb = ds.adsb.head(300).reset_index(drop=True)
codes = {rid: (25, 10 + k) for k, rid in enumerate(sorted(ds.sites))}
rec.write_bytes(encode_dataset(ds, codes))
text = (sim / "sites.toml").read_text()
for rid, (sac, sic) in codes.items():
    text = text.replace(f'id = "{rid}"\\n', f'id = "{rid}"\\nsac = {sac}\\nsic = {sic}\\n')
sites.write_text(text)
""", "sim", "rec.ast", "rec-sites.toml")
    done = _run([graphcal, "import-asterix", "rec.ast", "--sites", "rec-sites.toml",
                 "--out", "imported"], cwd=work, env=env)
    assert "wrote imported" in done.stdout and "CAT048 200" in done.stdout
    plots = (work / "imported" / "plots.csv").read_text().splitlines()
    adsb = (work / "imported" / "adsb.csv").read_text().splitlines()
    assert len(plots) == 1 + 200 and len(adsb) == 1 + 300
    header = adsb[0].split(",")
    sigma = [float(row.split(",")[header.index("sigma_m")]) for row in adsb[1:]]
    assert all(0.0 < value < 1e4 for value in sigma)  # from the NACp table


def test_an_editable_install_reads_the_source_trees_models(tmp_path: Path) -> None:
    """``pip install -e`` (what ``make`` does) copies nothing: models/ of the tree is read,
    and an edit there counts at once."""
    env = _clean_env()
    source = tmp_path / "source"
    _copy_sources(source)
    python, _ = _fresh_venv(tmp_path / "venv", ["--editable", source], env)
    assert not (source / "graphcal" / "models").exists()
    (source / "models" / "my-radar.toml").write_bytes((MODELS / "ssr-mode-s.toml").read_bytes())
    work = tmp_path / "work"
    work.mkdir()
    out = _run([python, "-c", "import graphcal; from graphcal.data.sensor_models import "
                "list_sensor_models, models_dir; print(graphcal.__file__); print(models_dir()); "
                "print('my-radar' in list_sensor_models())"], cwd=work, env=env).stdout
    assert out.splitlines() == [str(source / "graphcal" / "__init__.py"), str(source / "models"),
                                "True"]
