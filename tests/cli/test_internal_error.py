"""A defect of graphcal ends in one line and status 1, not a traceback (``GRAPHCAL_DEBUG``
lets the traceback through); memory and interrupts are named."""

from __future__ import annotations

import pytest

from graphcal.cli import app as app_module


def _run_main(monkeypatch: pytest.MonkeyPatch, error: BaseException) -> int:
    def failing() -> None:
        raise error

    statuses: list[object] = []
    monkeypatch.setattr(app_module, "app", failing)
    monkeypatch.setattr(app_module, "exit_at_once", statuses.append)
    # main's process-wide set-up would outlive the test in pytest's process
    monkeypatch.setattr(app_module, "install_signal_handlers", lambda: None)
    monkeypatch.setattr(app_module, "route_warnings", lambda: None)
    app_module.main()
    assert len(statuses) == 1
    return int(statuses[0])  # type: ignore[call-overload]


def test_defect_is_one_line_and_status_1(monkeypatch, capsys):
    monkeypatch.delenv(app_module.DEBUG_ENV, raising=False)
    status = _run_main(monkeypatch, ValueError("Number of rows must be positive"))
    err = capsys.readouterr().err
    assert status == app_module.EXIT_INTERNAL_ERROR == 1
    assert err.count("\n") == 1
    assert err.startswith("error: internal error (ValueError: Number of rows must be positive)")
    assert "GRAPHCAL_DEBUG=1" in err and "Traceback" not in err


def test_debug_lets_the_traceback_through(monkeypatch):
    monkeypatch.setenv(app_module.DEBUG_ENV, "1")
    with pytest.raises(ValueError, match="boom"):
        _run_main(monkeypatch, ValueError("boom"))


def test_memory_error_names_the_remedy(monkeypatch, capsys):
    status = _run_main(monkeypatch, MemoryError())
    assert status == 2
    assert capsys.readouterr().err == (
        "error: out of memory; calibrate a long recording in windows (--window 1h)\n")


def test_interrupt_is_status_130(monkeypatch, capsys):
    assert _run_main(monkeypatch, KeyboardInterrupt()) == 130
    assert capsys.readouterr().err == "error: interrupted\n"


def test_sigterm_inside_an_import_is_status_143(monkeypatch, capsys):
    """SIGTERM's exit raised inside an extension's initialisation surfaces as an
    ImportError: still the termination (143), not a defect."""
    monkeypatch.setattr(app_module, "TERMINATED_BY", [15])
    assert _run_main(monkeypatch, ImportError("initialization failed")) == 143
    assert capsys.readouterr().err == "error: terminated\n"
