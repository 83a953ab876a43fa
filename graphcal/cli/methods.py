"""``graphcal methods``: the available estimators, one line each."""

from __future__ import annotations

from graphcal.cli.common import console


def methods_command() -> None:
    """List the available estimators."""
    from graphcal.solvers.registry import METHODS, describe

    for name in METHODS:  # the names and their summaries, without importing the estimators
        console.print(f"{name:12s} {describe(name)}", highlight=False)


__all__ = ["methods_command"]
