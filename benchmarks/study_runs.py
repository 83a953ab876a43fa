"""What the Monte Carlo studies share: one calibration run, timed, its failure recorded."""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable
from typing import Any


def timed_run(calibrate: Callable[[], Any]) -> tuple[Any | None, dict]:
    """Call ``calibrate()`` and time it: its Calibration (``None`` if it raised) and the
    run record (``seconds``, ``error`` with its ``traceback``, or the ``warnings``).  A study
    reports a failed run; it does not stop."""
    t0 = time.perf_counter()
    try:
        cal = calibrate()
    except Exception as exc:  # noqa: BLE001 - a study reports errors, it does not stop
        return None, {"seconds": time.perf_counter() - t0,
                      "error": f"{type(exc).__name__}: {exc}",
                      "traceback": traceback.format_exc()}
    return cal, {"seconds": time.perf_counter() - t0, "error": None,
                 "warnings": list(cal.warnings)}
