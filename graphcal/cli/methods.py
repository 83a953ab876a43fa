"""``graphcal methods``: the available estimators, one line each."""

from __future__ import annotations

from graphcal.cli.common import console


def methods_command() -> None:
    """List the available estimators."""
    from graphcal.solvers.registry import METHODS

    for name, function in METHODS.items():
        summary = (function.__doc__ or "").strip().splitlines()[0]
        console.print(f"{name:12s} {summary}", highlight=False)


__all__ = ["methods_command"]
