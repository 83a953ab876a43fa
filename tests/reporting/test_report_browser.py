"""The HTML report rendered by a real headless browser (Chromium).

Chromium (Debian package ``chromium``) loads the report from a file: the DOM
it builds must hold the header and every section, every embedded image must
decode (non-zero natural size), and a screenshot of the page must show
content (not a blank page).  Skipped, with the reason, where Chromium is absent.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import numpy as np
import pytest
from PIL import Image

from graphcal.reporting.html import SECTIONS, build_report
from graphcal.solvers.registry import METHODS
from tests.reporting.test_report import BIASES, TRACKS
from tests.synthetic import make_dataset, site_at

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")

pytestmark = pytest.mark.skipif(
    CHROMIUM is None,
    reason="Chromium is not installed (Debian package 'chromium'): the report is not "
    "checked in a browser")

#: Appended to the page: after load, counts the images and those that did not decode.
_PROBE = """<script>
window.addEventListener("load", () => {
  const images = Array.from(document.images);
  const broken = images.filter((i) => !i.complete || i.naturalWidth === 0);
  document.body.dataset.images = images.length;
  document.body.dataset.broken = broken.length;
});
</script>"""


def _chromium(tmp_path, *args: str) -> subprocess.CompletedProcess:
    command = [CHROMIUM, "--headless", "--disable-gpu", "--hide-scrollbars",
               "--no-first-run", f"--user-data-dir={tmp_path / 'profile'}", *args]
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        command.insert(1, "--no-sandbox")  # Chromium refuses to sandbox as root
    return subprocess.run(command, capture_output=True, text=True, timeout=60, check=False)


@pytest.fixture(scope="module")
def page() -> str:
    sites = [site_at("RA", -20e3, 0.0), site_at("RB", 30e3, 5e3, sigma_elevation_mrad=2.0)]
    dataset = make_dataset(np.random.default_rng(3), [(s, BIASES[s.id]) for s in sites], TRACKS)
    cal = METHODS["graph"](dataset)
    return build_report(cal, dataset, truth=BIASES, crlb=False,
                        command="graphcal report result.json ds")


def test_report_renders_in_headless_chromium(tmp_path, page) -> None:
    probed = tmp_path / "probed.html"
    probed.write_text(page.replace("</body>", _PROBE + "</body>"), encoding="utf-8")
    result = _chromium(tmp_path, "--virtual-time-budget=5000", "--dump-dom", probed.as_uri())
    assert result.returncode == 0, result.stderr[-2000:]
    dom = result.stdout
    assert '<header id="header">' in dom and "graphcal report result.json ds" in dom
    for sid, name in SECTIONS:
        assert re.search(rf'<h2 id="{sid}">', dom), f"section {sid} ({name}) not in the DOM"
    counts = re.search(r'data-images="(\d+)" data-broken="(\d+)"', dom)
    assert counts, "the probe did not run"
    assert int(counts.group(1)) == page.count("<img") and int(counts.group(1)) >= 7
    assert int(counts.group(2)) == 0, "broken images"


def test_report_screenshot_is_not_blank(tmp_path, page) -> None:
    report = tmp_path / "report.html"
    report.write_text(page, encoding="utf-8")
    shot = tmp_path / "shot.png"
    result = _chromium(tmp_path, f"--screenshot={shot}", "--window-size=1280,4000",
                       report.as_uri())
    assert result.returncode == 0 and shot.exists(), result.stderr[-2000:]
    with Image.open(shot) as image:
        assert image.size == (1280, 4000)
        pixels = np.asarray(image.convert("RGB"), dtype=np.int16)
    ink = np.any(pixels < 200, axis=2)
    assert ink.mean() > 0.02  # text, tables and figures, not a white page
    # Drawn figures: many pixels of the scatter's blue (matplotlib's tab:blue, 31 119 180).
    blue = (np.abs(pixels - [31, 119, 180]).max(axis=2) < 40)
    assert blue.sum() > 2000
    # Content all the way down the first 4000 px (the figures, not only the header).
    rows_with_ink = np.flatnonzero(ink.any(axis=1))
    assert rows_with_ink.max() > 3500
