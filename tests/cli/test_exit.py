"""The command line ends its process at once (graphcal.cli.app.exit_at_once), with the
status, the output and the exit handlers of a normal exit."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=120, check=False)


_SCRIPT = """
    import atexit, threading, time
    from graphcal.cli.app import exit_at_once

    class TornDown:
        def __del__(self):
            print("torn down")

    kept = TornDown()  # freed by the interpreter's teardown only
    if {thread}:
        def later():
            time.sleep(0.2)
            print("thread done", flush=True)

        threading.Thread(target=later).start()
    atexit.register(lambda: print("handler ran"))
    print("buffered", end="")
    exit_at_once({status})
    print("never")
"""


@pytest.mark.parametrize(("status", "code", "stderr"), [
    ("0", 0, ""), ("None", 0, ""), ("3", 3, ""), ("258", 2, ""),
    ("'error: no such folder'", 1, "error: no such folder\n")])
def test_status_output_and_exit_handlers_as_a_normal_exit(status, code, stderr) -> None:
    """The exit handlers run and the streams are flushed; the teardown is skipped."""
    result = _python(_SCRIPT.format(thread=False, status=status))
    assert result.returncode == code
    assert result.stdout == "bufferedhandler ran\n"
    assert result.stderr == stderr


def test_a_live_thread_gets_the_normal_exit() -> None:
    """A thread that is not a daemon is waited for, by Python's own exit."""
    result = _python(_SCRIPT.format(thread=True, status=3))
    assert result.returncode == 3
    assert result.stdout == "bufferedthread done\nhandler ran\ntorn down\n"


def test_the_command_line_exits_with_its_status() -> None:
    """python -m graphcal: help is status 0 and printed whole into a pipe; a missing
    folder is status 2 with its one-line error."""
    shown = subprocess.run([sys.executable, "-m", "graphcal", "--help"], capture_output=True,
                           text=True, timeout=120, check=False)
    assert shown.returncode == 0
    assert "calibrate" in shown.stdout
    missing = subprocess.run([sys.executable, "-m", "graphcal", "calibrate", "/no/such/folder"],
                             capture_output=True, text=True, timeout=120, check=False)
    assert missing.returncode == 2
    assert "/no/such/folder" in missing.stderr
