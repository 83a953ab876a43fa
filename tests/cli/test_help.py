"""The help texts: every command is listed, and units in brackets survive rich markup."""

from __future__ import annotations

import re

import pytest
import typer
from typer.testing import CliRunner

from graphcal.cli.app import app

runner = CliRunner()

COMMANDS = ["simulate", "calibrate", "noise", "fuse", "methods", "marginals", "compare",
            "import-asterix", "observability", "report", "correct", "history"]


def _commands() -> dict:
    """The click commands typer builds, by name (in registration order)."""
    return dict(typer.main.get_command(app).commands)


def test_every_command_is_registered_in_order() -> None:
    assert list(_commands()) == COMMANDS


@pytest.mark.parametrize("name", COMMANDS)
def test_no_help_text_has_an_unescaped_bracket(name: str) -> None:
    """Rich markup reads ``[s]`` as a style and drops it; a unit is written ``\\[s]``."""
    command = _commands()[name]
    for text in [command.help or "", *(getattr(p, "help", None) or "" for p in command.params)]:
        assert not re.search(r"(?<!\\)\[", text), f"{name}: {text!r}"


@pytest.mark.parametrize(("name", "unit"), [
    ("calibrate", "interpolation [s]"), ("fuse", "density [m^2/s^3]"),
    ("noise", "azimuth bin [deg]"), ("observability", "segment length [s]"),
])
def test_units_show_in_the_help(name: str, unit: str) -> None:
    result = runner.invoke(app, [name, "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    assert unit in " ".join(result.output.split())
