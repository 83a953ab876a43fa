"""``python -m graphcal``: the command line."""

from graphcal.cli import app

app()
