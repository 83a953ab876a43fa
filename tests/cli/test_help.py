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
def test_no_help_text_has_a_markup_escape(name: str) -> None:
    """The help is plain text (no rich markup): a unit is written ``[s]``, and an escape
    ``\\[s]`` would be printed as it stands."""
    command = _commands()[name]
    for text in [command.help or "", *(getattr(p, "help", None) or "" for p in command.params)]:
        assert "\\[" not in text, f"{name}: {text!r}"


def test_the_help_fits_80_columns_with_each_option_beside_its_text() -> None:
    """At 80 columns every line fits, and each command's line in the list is whole
    (its first docstring paragraph, wrapped, not cut short with '...')."""
    for args in (["--help"], *([name, "--help"] for name in COMMANDS)):
        result = runner.invoke(app, args, env={"COLUMNS": "80"}, terminal_width=80)
        assert result.exit_code == 0
        assert max(len(line) for line in result.output.splitlines()) <= 80, args
    listing = runner.invoke(app, ["--help"], env={"COLUMNS": "80"}, terminal_width=80).output
    assert "..." not in listing.split("Commands:")[1]
    assert "elevation) from its data." in listing  # noise's line, wrapped whole
    calibrate = runner.invoke(app, ["calibrate", "--help"], env={"COLUMNS": "80"},
                              terminal_width=80).output
    # An option's text starts on its own line or beside it, never in a narrow column.
    assert re.search(r"--window DURATION\s+Biases over time: calibrate each window", calibrate)


@pytest.mark.parametrize(("name", "unit"), [
    ("calibrate", "interpolation [s]"), ("fuse", "density [m^2/s^3]"),
    ("noise", "azimuth bin [deg]"), ("observability", "segment length [s]"),
])
def test_units_show_in_the_help(name: str, unit: str) -> None:
    result = runner.invoke(app, [name, "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    assert unit in " ".join(result.output.split())
