"""The allocator settings the command line makes (graphcal.core.allocator)."""

from __future__ import annotations

import ctypes.util
import sys

import pytest

from graphcal.core.allocator import keep_freed_memory


@pytest.mark.skipif(not sys.platform.startswith("linux") or ctypes.util.find_library("c") is None,
                    reason="glibc's mallopt is Linux's")
def test_the_thresholds_are_set_on_linux() -> None:
    # mallopt returns 1 on success: both settings are accepted, and again.
    assert keep_freed_memory()
    assert keep_freed_memory()


def test_nothing_is_done_elsewhere(monkeypatch) -> None:
    monkeypatch.setattr(sys, "platform", "darwin")
    assert not keep_freed_memory()
