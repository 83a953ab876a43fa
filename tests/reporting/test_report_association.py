"""The report's association section (``info["association"]``, radars without addresses):
the figures per radar as recorded, a tail fraction above 1 % flagged, the rounds or the
windows of the association, and no section for a result without association."""

from __future__ import annotations

import copy
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset
from graphcal.reporting.html import (
    ASSOCIATION_SECTION,
    SECTIONS,
    TAIL_FLAG,
    build_report,
    page_sections,
)
from graphcal.solvers.registry import METHODS
from tests.reporting.test_report import BIASES, TRACKS
from tests.synthetic import make_dataset, site_at

#: ``info["association"]`` as ``graphcal calibrate`` records it (one round).
ASSOCIATION: dict[str, Any] = {
    "radars": {
        "RA": {"plots": 6691, "associated": 5276, "own_paths": 812, "ambiguous": 0,
               "left_out": 1415,
               "scans": 180, "detection_probability": 0.8981954375212802,
               "false_plots_per_scan": 7.861111111111111, "mode_3a_consistency": None,
               "tail_fraction": 0.0},
        "RB": {"plots": 7112, "associated": 7069, "own_paths": 0, "ambiguous": 3,
               "left_out": 40,
               "scans": 222, "detection_probability": 0.966502597757725,
               "false_plots_per_scan": 0.18018018018018017, "mode_3a_consistency": 1.0,
               "tail_fraction": 0.0007073136228603763},
    },
    "rounds": 2,
    "seconds": 2.0599730260000797,
}


@pytest.fixture(scope="module")
def scenario() -> tuple[Dataset, Calibration]:
    sites = [site_at("RA", -20e3, 0.0), site_at("RB", 30e3, 5e3, sigma_elevation_mrad=2.0)]
    dataset = make_dataset(np.random.default_rng(3), [(s, BIASES[s.id]) for s in sites], TRACKS)
    return dataset, METHODS["graph"](dataset)


def _with_association(cal: Calibration, association: dict[str, Any] | None) -> Calibration:
    """A copy of ``cal`` whose ``info["association"]`` is ``association`` (none: removed)."""
    out = copy.copy(cal)
    out.info = {k: v for k, v in cal.info.items() if k != "association"}
    if association is not None:
        out.info["association"] = copy.deepcopy(association)
    return out


def _section(page: str, sid: str) -> str:
    return page.split(f'<h2 id="{sid}">')[1].split("<h2 id=")[0]


def _row(section: str, radar: str) -> tuple[str, list[str]]:
    """The class attribute and the cells of ``radar``'s row."""
    match = re.search(rf'<tr( class="[^"]*")?><td class="l">{radar}</td>(.*?)</tr>', section)
    assert match, radar
    return match.group(1) or "", [radar, *re.findall(r"<td>(.*?)</td>", match.group(2))]


@pytest.fixture(scope="module")
def page(scenario, tmp_path_factory) -> str:
    """The report of a result with an association, through its JSON (as ``report`` reads it)."""
    dataset, cal = scenario
    path = Path(tmp_path_factory.mktemp("association")) / "result.json"
    _with_association(cal, ASSOCIATION).write_json(path)
    return build_report(Calibration.read_json(path), dataset, crlb=False)


def test_section_shows_each_radars_figures(page) -> None:
    section = _section(page, "association")
    assert '<a href="#association">Association</a>' in page
    assert page.index('<h2 id="association">') < page.index('<h2 id="data">')
    for radar, figures in ASSOCIATION["radars"].items():
        css, cells = _row(section, radar)
        assert "flag" not in css
        assert cells[1:7] == [f"{figures[k]:,}" for k in
                              ("plots", "associated", "own_paths", "ambiguous", "left_out",
                               "scans")]
        assert cells[7] == f"{100 * figures['detection_probability']:.1f} %"
        assert cells[8] == f"{figures['false_plots_per_scan']:.2f}"
    assert _row(section, "RA")[1][1:] == ["6,691", "5,276", "812", "0", "1,415", "180",
                                         "89.8 %", "7.86", "–", "0.00 %"]
    assert _row(section, "RB")[1][9:] == ["100.0 %", "0.07 %"]
    assert "Left out</b>: plots not associated with any known aircraft" in section
    assert "Associated and calibrated in turn: 2 rounds, 2.1 s." in section
    assert 'class="warn"' not in section and "⚠" not in section


def test_tail_fraction_above_one_percent_is_flagged(scenario) -> None:
    dataset, cal = scenario
    association = copy.deepcopy(ASSOCIATION)
    association["radars"]["RA"]["tail_fraction"] = 0.0123
    association["radars"]["RB"]["tail_fraction"] = TAIL_FLAG  # at 1 %: not above
    section = _section(build_report(_with_association(cal, association), dataset, crlb=False),
                       "association")
    css, cells = _row(section, "RA")
    assert css == ' class="flag"'
    assert cells[-1] == '<span class="zflag" title="above 1 %">⚠ 1.23 %</span>'
    css, cells = _row(section, "RB")
    assert css == "" and cells[-1] == "1.00 %"
    warning = re.search(r'<p class="warn">(.*?)</p>', section)
    assert warning and "RA (1.2 %)" in warning.group(1) and "RB" not in warning.group(1)


def test_windows_are_reported(scenario) -> None:
    dataset, cal = scenario
    association = {"radars": copy.deepcopy(ASSOCIATION["radars"]), "windows": 6}
    section = _section(build_report(_with_association(cal, association), dataset, crlb=False),
                       "association")
    assert "Associated window by window: 6 windows" in section
    assert "round" not in section
    assert _row(section, "RA")[1][2] == "5,276"


def test_no_section_without_association(scenario) -> None:
    dataset, cal = scenario
    page = build_report(_with_association(cal, None), dataset, crlb=False)
    assert 'id="association"' not in page and 'href="#association"' not in page
    assert re.findall(r'<h2 id="([^"]+)">', page) == [sid for sid, _ in SECTIONS]
    assert page_sections(False) == SECTIONS
    assert page_sections(True) == (*SECTIONS[:-1], ASSOCIATION_SECTION, SECTIONS[-1])
